r"""Campaign specs: fixed settings and factors in a TOML file; the tasks are their product.

A spec has three parts::

    [campaign]                      # fixed settings (and the campaign's name, trace subset)
    name = "ph_robustness"
    plant = "ph"
    model = "ph_lstm_n5.npz"        # a path (relative to the spec file) or a shipped model
    steps = 900
    setpoints = [7.5, 6.8, 8.0]     # physical units, held for equal segments
    q2 = [0.55, 0.7]                # pH plant buffer flow, mL/s, equal segments
    solver = "daqp"
    trace = { seed = [0] }          # per-step traces for the tasks with seed 0

    [factors]                       # every key is a setting mapped to a list of values
    noise_std = [0.0, 0.01, 0.05]
    L_d = [0.01, 0.1]
    seed = [0, 1, 2]

    [[cases]]                       # optional: an explicit list of setting overrides
    mismatch = {}
    [[cases]]
    mismatch = { W_a1 = 1.1 }

    [random]                        # optional: i.i.d. draws, `samples` per stratum
    samples = 59
    sampling_seed = 7               # recorded: the same spec draws the same tasks
    noise_std = { distribution = "uniform", low = 0.0, high = 0.02 }
    mismatch.A1 = { distribution = "normal", mean = 1.0, std = 0.05 }

The tasks are ``cases x product(factors) x draws`` (one empty case when there are none;
one draw without ``[random]``), each one closed loop
(:func:`ltv_lstm_mpc.campaign.task.run_task`). Every setting is checked when the spec is
read: a bad entry raises
:class:`~ltv_lstm_mpc.exceptions.CampaignSpecError` naming it (``[factors].noise_std[1]``)
and the fix.

Settings (:data:`SETTINGS` documents each): ``plant``, ``model``, ``scenario`` (one of the
paper's scenarios, :data:`SCENARIO_NAMES`; it fixes plant, schedule and rate limit),
``short``, ``steps``, ``setpoints``, ``q2`` (pH plant) or ``disturbances`` (pH plant: q2;
LSTM plant: output disturbance), ``y0_initial``, ``L_d``, ``N``, ``solver`` (``"installed"``
in a factor list means every installed backend), ``transcription``, ``policy``,
``sqp_iterations``, ``rate_limit``, ``d_max``, ``noise_std``, ``seed``, ``mismatch``,
``max_seconds`` (and ``sample``, the index of a ``[random]`` draw).

``[random]`` samples the settings of :data:`RANDOM_SETTINGS` and pH-plant mismatch
parameters (``mismatch.<parameter>``, scale factors) from :data:`DISTRIBUTIONS`
(``uniform`` low/high, ``normal`` mean/std, ``log-uniform`` low/high); unless the spec sets
``seed`` itself, every draw also draws its own measurement-noise seed. Draw j is the same
in every stratum (common random numbers; :class:`RandomFactors`). The strata of the
statistical statements (:mod:`~ltv_lstm_mpc.campaign.statements`) are the levels of the
``[factors]`` and ``[[cases]]`` settings (:attr:`CampaignSpec.strata`): within one, the
draws are i.i.d., which is what the Clopper-Pearson bound assumes.

Replications are not strata: a ``seed`` factor (``seed = [0, 1, ..., 7]``, the natural way
to ask for eight replications) and any factor listed in ``[campaign].replications``
(default ``["seed"]``; an explicit list replaces it, ``[]`` keeps the seeds as strata) are
pooled into their stratum's statement, so eight seeds give one statement over eight loops
(bound 0.31 at 95 % without a failure). With ``[random]``, replication r takes the draws
``r * samples + j`` so that no two pooled loops share a draw; seeds without measurement
noise (``noise_std = 0``) repeat one deterministic loop and count once.

The ``offset`` outcome of the statements tests the offset measured over the last
``offset_window`` samples of each constant segment (a setting, default
:data:`DEFAULT_OFFSET_WINDOW`; the mean of the noise-free plant output's error) against
``[campaign].offset_tolerance`` (output units, default 1e-3; ``campaign
--offset-tolerance`` overrides it).
"""

from __future__ import annotations

import hashlib
import importlib.util
import itertools
import math
import tomllib
import typing
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field, fields
from pathlib import Path
from typing import Any

from ltv_lstm_mpc.campaign.task import DEFAULT_OFFSET_WINDOW, Task, task_key
from ltv_lstm_mpc.exceptions import CampaignSpecError
from ltv_lstm_mpc.mpc.config import DEFAULT_L_D, TRANSCRIPTIONS, InfeasibilityPolicy, default_solver
from ltv_lstm_mpc.plants.ph import PHParameters
from ltv_lstm_mpc.plants.registry import resolve_plant

__all__ = [
    "DEFAULTS",
    "DISTRIBUTIONS",
    "INSTALLED",
    "RANDOM_SETTINGS",
    "SCENARIO_NAMES",
    "SETTINGS",
    "CampaignSpec",
    "Distribution",
    "RandomFactors",
    "Setting",
    "TraceSelector",
    "load_spec",
    "parse_spec",
]

#: The paper's scenarios (:func:`ltv_lstm_mpc.paper.scenarios.paper_scenarios`) and their plant.
SCENARIO_NAMES: dict[str, str] = {
    "1_lstm_theorem3": "lstm",
    "2_lstm_larger": "lstm",
    "3_lstm_steps": "lstm",
    "4_ph_small_Ld": "ph",
    "5_ph_large_Ld": "ph",
}
#: In a ``solver`` factor list: every backend of ``ltv_lstm_mpc.solvers.available_solvers()``.
INSTALLED = "installed"
#: Settings a scenario fixes itself (a task with ``scenario`` must not set them).
SCENARIO_FIXED = ("plant", "steps", "setpoints", "q2", "disturbances", "rate_limit", "y0_initial")
#: Keys of ``[campaign]`` that are not settings.
CAMPAIGN_ONLY = ("name", "trace", "replications", "offset_tolerance")
#: Factors that are replications by default (``[campaign].replications`` replaces the list):
#: their levels repeat a stratum's loop with other noise and are pooled into its statement.
DEFAULT_REPLICATIONS: tuple[str, ...] = ("seed",)
#: Default tolerance of the ``offset`` outcome of the statements (output units).
DEFAULT_OFFSET_TOLERANCE = 1e-3
#: Values of the settings a task does not set (``L_d`` and ``rate_limit`` of a scenario task
#: come from the scenario).
DEFAULTS: dict[str, Any] = {
    "plant": "ph",
    "model": "ph_lstm_n5.npz",
    "L_d": DEFAULT_L_D,  # the library's and every command's (MPCConfig)
    "N": 5,
    "solver": default_solver(),  # the fastest installed solver with exact terminal cones
    "transcription": "auto",
    "policy": "paper",
    "sqp_iterations": 1,
    "rate_limit": 0.01,
    "d_max": 0.1,
    "noise_std": 0.0,
    "seed": 0,
    "mismatch": {},
}
_POLICIES: tuple[str, ...] = typing.get_args(InfeasibilityPolicy)
_PH_PARAMETERS = tuple(f.name for f in fields(PHParameters))


class _Bad(Exception):
    """A value failed its check; the message says what is expected."""


Checker = Callable[[Any], Any]


def _type_name(value: Any) -> str:
    return type(value).__name__


def _choice(*allowed: str) -> Checker:
    def check(value: Any) -> str:
        if not isinstance(value, str) or value not in allowed:
            raise _Bad(f"expected one of {list(allowed)}, got {value!r}")
        return value

    return check


def _plant(value: Any) -> str:
    """A plant name of the registry (:func:`ltv_lstm_mpc.resolve_plant`)."""
    from ltv_lstm_mpc.exceptions import LtvMpcError

    if not isinstance(value, str):
        raise _Bad(f"expected a plant name, got {value!r}")
    try:
        return resolve_plant(value).name
    except LtvMpcError as error:
        raise _Bad(str(error)) from None


def _string(value: Any) -> str:
    if not isinstance(value, str) or not value:
        raise _Bad(f"expected a non-empty string, got {value!r}")
    return value


def _boolean(value: Any) -> bool:
    if not isinstance(value, bool):
        raise _Bad(f"expected true or false, got {value!r}")
    return value


def _integer(minimum: int) -> Checker:
    def check(value: Any) -> int:
        if isinstance(value, bool) or not isinstance(value, int):
            raise _Bad(f"expected an integer >= {minimum}, got {_type_name(value)} {value!r}")
        if value < minimum:
            raise _Bad(f"expected an integer >= {minimum}, got {value}")
        return int(value)

    return check


def _real(value: Any) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise _Bad(f"expected a number, got {_type_name(value)} {value!r}")
    number = float(value)
    if not math.isfinite(number):
        raise _Bad(f"expected a finite number, got {value!r}")
    return number


def _number(low: float | None = None, high: float | None = None, *, open_low: bool) -> Checker:
    def check(value: Any) -> float:
        number = _real(value)
        if low is not None and (number <= low if open_low else number < low):
            raise _Bad(f"expected a number {'>' if open_low else '>='} {low:g}, got {value!r}")
        if high is not None and not number < high:
            raise _Bad(f"expected a number < {high:g}, got {value!r}")
        return number

    return check


def _number_list(*, nonnegative: bool) -> Checker:
    def check(value: Any) -> list[float]:
        if not isinstance(value, list) or not value:
            raise _Bad(f"expected a non-empty list of numbers (one per segment), got {value!r}")
        numbers = []
        for index, item in enumerate(value):
            try:
                number = _real(item)
            except _Bad as error:
                raise _Bad(f"entry {index}: {error}") from None
            if nonnegative and number < 0:
                raise _Bad(f"entry {index}: expected a number >= 0, got {item!r}")
            numbers.append(number)
        return numbers

    return check


def _mismatch(value: Any) -> dict[str, float]:
    if not isinstance(value, dict):
        raise _Bad(
            "expected a table of pH-plant parameter scale factors, e.g. "
            f"{{ W_a1 = 1.1, A1 = 0.9 }} ({{}} = nominal), got {value!r}"
        )
    nominal = PHParameters()
    scales: dict[str, float] = {}
    for name in sorted(value):
        if name not in _PH_PARAMETERS:
            raise _Bad(f"unknown pH-plant parameter {name!r}; parameters: {list(_PH_PARAMETERS)}")
        try:
            scale = _number(0.0, open_low=True)(value[name])
        except _Bad as error:
            raise _Bad(f"{name}: {error} (a scale factor of the nominal value)") from None
        if getattr(nominal, name) == 0.0 and scale != 1.0:
            raise _Bad(
                f"{name} is 0 in the nominal plant, so scaling it changes nothing; "
                "scale a nonzero parameter"
            )
        if scale != 1.0:  # a factor of 1 is the nominal value: same task as without it
            scales[name] = scale
    return scales


def _scenario(value: Any) -> str:
    if isinstance(value, str):
        if value in SCENARIO_NAMES:
            return value
        matches = [name for name in SCENARIO_NAMES if name.split("_", 1)[1] == value]
        if matches:
            return matches[0]
    raise _Bad(f"expected a paper scenario name {list(SCENARIO_NAMES)}, got {value!r}")


def solver_names() -> list[str]:
    """Solver names a spec accepts: the installed backends, and IPOPT with the nmpc extra."""
    from ltv_lstm_mpc.mpc.rti import NLP_SOLVERS
    from ltv_lstm_mpc.solvers import available_solvers

    names = list(available_solvers())
    if importlib.util.find_spec("casadi") is not None:
        names.extend(NLP_SOLVERS)
    return names


def _solver(value: Any) -> str:
    names = solver_names()
    if not isinstance(value, str) or value not in names:
        raise _Bad(f"unknown or uninstalled solver {value!r}; installed: {names}")
    return value


@dataclass(frozen=True)
class Setting:
    """One setting of a task: its check (returns the canonical value) and meaning."""

    check: Checker
    doc: str


#: Every setting a spec understands (keys of ``[campaign]``, ``[factors]`` and ``[[cases]]``).
SETTINGS: dict[str, Setting] = {
    "plant": Setting(
        _plant,
        "pH process (Fig. 1), LSTM + output disturbance, any registered plant name or "
        "'package.module:Class' (importable on the workers too)",
    ),
    "model": Setting(_string, "model .npz path (relative to the spec) or shipped name"),
    "scenario": Setting(_scenario, "a paper scenario: fixes plant, schedule and rate limit"),
    "short": Setting(_boolean, "scenario tasks: the quarter-length schedules"),
    "steps": Setting(_integer(1), "samples of the closed loop"),
    "setpoints": Setting(
        _number_list(nonnegative=False), "set-points (physical), one per equal segment"
    ),
    "q2": Setting(
        _number_list(nonnegative=True), "pH plant buffer flow q2 (mL/s), one per equal segment"
    ),
    "disturbances": Setting(
        _number_list(nonnegative=False), "pH plant: q2 (mL/s); LSTM plant: output disturbance"
    ),
    "y0_initial": Setting(
        _real,
        "LSTM plant: initial output (default: the middle of the model's admissible set-point "
        "interval, as in simulate)",
    ),
    "L_d": Setting(_number(0.0, 2.0, open_low=True), "observer gain L_d = l_d I_p"),
    "N": Setting(_integer(1), "prediction horizon"),
    "solver": Setting(_solver, "solver backend (ltv_lstm_mpc.solvers.available_solvers())"),
    "transcription": Setting(_choice(*TRANSCRIPTIONS), "FHOCP transcription"),
    "policy": Setting(_choice(*_POLICIES), "infeasibility policy"),
    "sqp_iterations": Setting(_integer(1), "linearizations per step (1 = RTI)"),
    "rate_limit": Setting(
        _number(0.0, open_low=False), "normalized set-point change per step (0: none)"
    ),
    "d_max": Setting(_number(0.0, open_low=True), "disturbance bound d_max (normalized)"),
    "noise_std": Setting(
        _number(0.0, open_low=False), "std of Gaussian measurement noise, output units"
    ),
    "seed": Setting(_integer(0), "seed of the measurement noise"),
    "mismatch": Setting(_mismatch, "pH plant parameter scale factors, e.g. {W_a1 = 1.1}"),
    "max_seconds": Setting(
        _number(0.0, open_low=True), "stop a closed loop after this wall time, s"
    ),
    "offset_window": Setting(
        _integer(1),
        "samples at the end of each constant segment over which the offset outcome "
        f"averages the noise-free plant output's error (default {DEFAULT_OFFSET_WINDOW}; "
        "1: the last sample)",
    ),
    "sample": Setting(_integer(0), "index of the draw of the [random] factors (set by them)"),
}

#: Settings a ``[random]`` table may sample (real numbers), besides ``mismatch.<parameter>``.
RANDOM_SETTINGS = ("noise_std", "d_max", "L_d", "rate_limit", "y0_initial")
#: Distributions of ``[random]`` and their parameters.
DISTRIBUTIONS: dict[str, tuple[str, ...]] = {
    "uniform": ("low", "high"),
    "normal": ("mean", "std"),
    "log-uniform": ("low", "high"),
}


@dataclass(frozen=True)
class Distribution:
    """One sampled setting of ``[random]``: ``kind`` (:data:`DISTRIBUTIONS`) and parameters."""

    kind: str
    parameters: dict[str, float]

    def draw(self, rng: Any) -> float:
        """One value from ``rng`` (a numpy Generator)."""
        p = self.parameters
        if self.kind == "uniform":
            return float(rng.uniform(p["low"], p["high"]))
        if self.kind == "normal":
            return float(rng.normal(p["mean"], p["std"]))
        return float(math.exp(rng.uniform(math.log(p["low"]), math.log(p["high"]))))


@dataclass(frozen=True)
class RandomFactors:
    """The ``[random]`` table: i.i.d. draws of some settings, ``samples`` per stratum.

    Attributes
    ----------
    samples : int
        Draws per stratum (combination of ``[[cases]]`` and ``[factors]`` levels).
    sampling_seed : int
        Seed of the draws: draw j uses ``numpy.random.default_rng([sampling_seed, j])``,
        so every stratum gets the same j-th draw (common random numbers) and a rerun the
        same tasks.
    distributions : dict
        Setting (or ``"mismatch.<parameter>"``) -> :class:`Distribution`.
    noise_seed : bool
        Each draw also draws the measurement-noise ``seed`` (True unless the spec sets
        ``seed`` itself); with no distributions the draws differ by their noise only.
    active : bool
        The spec has a ``[random]`` table (False: one task per stratum, nothing drawn).
    """

    samples: int = 1
    sampling_seed: int = 0
    distributions: dict[str, Distribution] = field(default_factory=dict)
    noise_seed: bool = False
    active: bool = False

    def draw(self, sample: int) -> dict[str, Any]:
        """The settings of draw ``sample`` (mismatch parameters gathered in ``mismatch``)."""
        import numpy as np

        rng = np.random.default_rng([self.sampling_seed, sample])
        values: dict[str, Any] = {}
        for name in sorted(self.distributions):
            value = self.distributions[name].draw(rng)
            if name.startswith("mismatch."):
                values.setdefault("mismatch", {})[name.split(".", 1)[1]] = value
            else:
                values[name] = value
        if self.noise_seed:
            values["seed"] = int(rng.integers(0, 2**31 - 1))
        return values


@dataclass(frozen=True)
class TraceSelector:
    """Which tasks also write per-step traces.

    Attributes
    ----------
    every : bool
        All tasks (``trace = true``).
    match : dict
        Setting -> accepted values (``trace = { seed = [0], noise_std = [0.05] }``): a task
        is traced when each of its settings is among the values given.
    """

    every: bool = False
    match: dict[str, list[Any]] = field(default_factory=dict)

    def selects(self, settings: Mapping[str, Any]) -> bool:
        """Whether the task with these settings writes a trace."""
        if self.every:
            return True
        if not self.match:
            return False
        return all(
            name in settings and settings[name] in values for name, values in self.match.items()
        )


@dataclass(frozen=True)
class CampaignSpec:
    """A parsed, validated campaign.

    Attributes
    ----------
    name : str
        Campaign name (``[campaign].name``, default the spec file's stem).
    fixed : dict
        Settings of ``[campaign]`` (canonical values).
    factors : dict
        Setting -> list of values of ``[factors]`` (``"installed"`` expanded).
    cases : list of dict
        The ``[[cases]]`` overrides (``[{}]`` when there are none).
    trace : TraceSelector
    tasks : tuple of Task
        The product, in order (outer: cases; then the factors in the spec's order; inner:
        the draws of ``[random]``).
    source : Path or None
        The spec file.
    text : str
        The spec's TOML text (copied into the output folder).
    random : RandomFactors
        The ``[random]`` table (no distributions: one draw, nothing sampled).
    replications : tuple of str
        The factors that are replications, not strata (``[campaign].replications``,
        default ``["seed"]`` where ``seed`` is a factor): their levels are pooled into
        their stratum's statement. With ``[random]``, replication r takes the draws
        ``r * samples + j``, so that no two pooled loops share a draw.
    offset_tolerance : float
        ``[campaign].offset_tolerance``: the ``offset`` outcome's tolerance (output units,
        default 1e-3), applied to the offset measured over ``offset_window``.
    """

    name: str
    fixed: dict[str, Any]
    factors: dict[str, list[Any]]
    cases: list[dict[str, Any]]
    trace: TraceSelector
    tasks: tuple[Task, ...]
    source: Path | None = None
    text: str = ""
    random: RandomFactors = field(default_factory=RandomFactors)
    replications: tuple[str, ...] = ()
    offset_tolerance: float = DEFAULT_OFFSET_TOLERANCE

    @property
    def strata(self) -> list[str]:
        """Settings whose levels define the strata of the statistical statements: the
        varying settings without the ``[random]`` ones and the replications
        (:mod:`.statements`)."""
        drawn = {name.split(".", 1)[0] for name in self.random.distributions}
        drawn |= {"sample", "seed"} if self.random.noise_seed else {"sample"}
        drawn |= set(self.replications)
        return [name for name in self.varying if name not in drawn]

    @property
    def varying(self) -> list[str]:
        """Settings that differ between tasks (factors and case keys), in spec order."""
        names = list(self.factors)
        for case in self.cases:
            names.extend(name for name in case if name not in names)
        return names


def _table(value: Any, where: str) -> dict[str, Any]:
    if not isinstance(value, dict):
        raise CampaignSpecError(where, f"expected a table, got {_type_name(value)} {value!r}")
    return value


def _check_key(name: str, where: str) -> Setting:
    if name not in SETTINGS:
        raise CampaignSpecError(
            f"{where}.{name}",
            f"unknown setting; settings: {list(SETTINGS)}"
            + (f" (and {list(CAMPAIGN_ONLY)} in [campaign])" if where == "[campaign]" else ""),
        )
    return SETTINGS[name]


def _checked(name: str, value: Any, where: str) -> Any:
    setting = _check_key(name, where)
    try:
        return setting.check(value)
    except _Bad as error:
        raise CampaignSpecError(f"{where}.{name}", str(error)) from None


def _factor_values(name: str, values: Any) -> list[Any]:
    where = f"[factors].{name}"
    _check_key(name, "[factors]")
    if not isinstance(values, list):
        raise CampaignSpecError(
            where, f"expected a list of values, got {values!r}; write {name} = [{values!r}]"
        )
    if not values:
        raise CampaignSpecError(where, "empty list: give at least one value (or remove the key)")
    if name == "solver" and INSTALLED in values:
        from ltv_lstm_mpc.solvers import available_solvers

        expanded: list[Any] = []
        for value in values:
            for item in available_solvers() if value == INSTALLED else [value]:
                if item not in expanded:
                    expanded.append(item)
        values = expanded
    checked = []
    for index, value in enumerate(values):
        try:
            checked.append(SETTINGS[name].check(value))
        except _Bad as error:
            raise CampaignSpecError(f"{where}[{index}]", str(error)) from None
        # The same value written twice (values that only mean the same, like a mismatch
        # scale of 1 and none, stay one task: see the task keys).
        for earlier, value_before in enumerate(values[:index]):
            if type(value_before) is type(value) and value_before == value:
                raise CampaignSpecError(
                    f"{where}[{index}]",
                    f"{values[index]!r} is listed twice ({name}[{earlier}] and {name}[{index}]); "
                    "every value of a factor is one level: remove the repeat",
                )
    return checked


def _trace_selector(value: Any) -> TraceSelector:
    where = "[campaign].trace"
    if isinstance(value, bool):
        return TraceSelector(every=value)
    if not isinstance(value, dict):
        raise CampaignSpecError(
            where,
            "expected true, false or a table setting -> list of values, e.g. "
            f"{{ seed = [0] }}, got {value!r}",
        )
    match: dict[str, list[Any]] = {}
    for name, values in value.items():
        _check_key(name, where)
        listed = values if isinstance(values, list) else [values]
        try:
            match[name] = [SETTINGS[name].check(v) for v in listed]
        except _Bad as error:
            raise CampaignSpecError(f"{where}.{name}", str(error)) from None
    return TraceSelector(match=match)


def _resolve_model(name: str, base_dir: Path | None, field_name: str) -> str:
    """Where a worker finds the model: an absolute path, or a shipped model name."""
    from ltv_lstm_mpc.lstm.shipped import shipped_models

    path = Path(name)
    candidates = [path] if path.is_absolute() else [(base_dir or Path.cwd()) / path, path]
    # one entry per place (relative to the spec's folder and to the working folder)
    candidates = list({str(c.resolve()): c for c in candidates}.values())
    for candidate in candidates:
        if candidate.is_file():
            return str(candidate.resolve())
    if name in shipped_models():
        return name
    raise CampaignSpecError(
        field_name,
        f"no model file {name!r} (looked in {[str(c.resolve()) for c in candidates]}) and no "
        f"shipped model of that name; shipped models: {shipped_models()}",
    )


def _resolve_task(
    given: dict[str, Any], where: dict[str, str], base_dir: Path | None
) -> tuple[dict[str, Any], str]:
    """Complete one task's settings with the defaults and check their combination."""

    def fail(name: str, message: str) -> CampaignSpecError:
        return CampaignSpecError(where.get(name, f"[campaign].{name}"), message)

    settings = dict(given)
    scenario = settings.get("scenario")
    if scenario is not None:
        for name in SCENARIO_FIXED:
            if name in settings:
                raise fail(
                    name,
                    f"the scenario {scenario!r} fixes its own plant, schedule and rate limit; "
                    f"remove {name} or the scenario",
                )
        plant = SCENARIO_NAMES[scenario]
        entry = resolve_plant(plant)
    else:
        if "short" in settings:
            raise fail("short", "applies to scenario tasks only: set scenario or remove short")
        for name in ("steps", "setpoints"):
            if name not in settings:
                raise fail(name, f"{name} is required unless a scenario is set")
        plant = settings.setdefault("plant", DEFAULTS["plant"])
        settings.setdefault("rate_limit", DEFAULTS["rate_limit"])
        if "q2" in settings and "disturbances" in settings:
            raise fail("q2", "give q2 or disturbances, not both (for the pH plant they are q2)")
        entry = resolve_plant(plant)
        if "q2" in settings and plant != "ph":
            raise fail(
                "q2",
                f"q2 is the pH plant's buffer flow; for plant = {plant!r} use disturbances "
                f"({entry.disturbance})",
            )
        steps = settings["steps"]
        for name in ("setpoints", "q2", "disturbances"):
            if name in settings and len(settings[name]) > steps:
                raise fail(name, f"{len(settings[name])} segments for steps = {steps}")
        if "y0_initial" in settings and "y0_phi" not in entry.options:
            raise fail(
                "y0_initial",
                f"applies to the LSTM plant (the {entry.title} starts where its reset() puts it)",
            )
        if "disturbances" not in settings and "q2" not in settings and entry.nominal_disturbance:
            nominal = [float(entry.nominal_disturbance[0])]
            settings["q2" if plant == "ph" else "disturbances"] = nominal
    if settings.get("mismatch") and "mismatch" not in entry.options:
        raise fail("mismatch", "parameter mismatch applies to the pH plant only")
    if plant == "ph":
        for name in ("q2", "disturbances"):
            negative = [v for v in settings.get(name, []) if v < 0]
            if negative:
                raise fail(name, f"the pH plant's buffer flow q2 is >= 0 mL/s, got {negative}")
    from_scenario = ("plant", "rate_limit", "L_d") if scenario is not None else ()
    for name, value in DEFAULTS.items():
        if name not in from_scenario:
            settings.setdefault(name, value)
    if scenario is not None:
        settings.setdefault("short", False)
    _check_transcription(settings, fail)
    model = _resolve_model(settings["model"], base_dir, where.get("model", "[campaign].model"))
    ordered = {name: settings[name] for name in SETTINGS if name in settings}
    return ordered, model


def _check_transcription(settings: dict[str, Any], fail: Any) -> None:
    """The solver / transcription / SQP combination, checked now instead of in every task."""
    from ltv_lstm_mpc.exceptions import LtvMpcError
    from ltv_lstm_mpc.mpc.config import MPCConfig
    from ltv_lstm_mpc.mpc.rti import resolve_transcription

    try:
        resolve_transcription(
            MPCConfig(
                solver=settings["solver"],
                transcription=settings["transcription"],
                sqp_iterations=settings["sqp_iterations"],
            )
        )
    except LtvMpcError as error:
        raise fail("transcription", str(error)) from None


@dataclass(frozen=True)
class _ModelFile:
    """What the tasks carry of one model: its digest and, for a file, its bytes."""

    sha256: str
    data: bytes | None
    Ts: float | None = None  # the model's sampling time, s


def _model_file(location: str, field_name: str, cache: dict[str, _ModelFile]) -> _ModelFile:
    """Read (once per campaign) the model at ``location``; refuse multi-output models."""
    if location in cache:
        return cache[location]
    from ltv_lstm_mpc.lstm.shipped import load_model, shipped_models, shipped_path

    shipped = location in shipped_models() and not Path(location).is_absolute()
    data = (shipped_path(location) if shipped else Path(location)).read_bytes()
    model = load_model(location)
    if model.p != 1:
        raise CampaignSpecError(
            field_name,
            f"{location!r} has p = {model.p} outputs; campaigns run single-output models "
            "(the pH loop and its LSTM plant)",
        )
    cache[location] = _ModelFile(
        hashlib.sha256(data).hexdigest(), None if shipped else data, model.Ts
    )
    return cache[location]


def _check_plant_sampling_time(model_file: _ModelFile, plant: str, field_name: str) -> None:
    """A plant that states its Ts (the pH plant: the benchmark's) refuses a model identified
    at another one; the LSTM plant runs at the model's own Ts."""
    from ltv_lstm_mpc.exceptions import SamplingTimeError
    from ltv_lstm_mpc.plants.protocol import check_sampling_time

    entry = resolve_plant(plant)
    try:
        check_sampling_time(model_file.Ts, entry.Ts, entry.title)
    except SamplingTimeError as error:
        raise CampaignSpecError(field_name, str(error)) from None


def _random_factors(
    value: Any,
    fixed: Mapping[str, Any],
    factors: Mapping[str, Any],
    cases: Sequence[Mapping[str, Any]],
) -> RandomFactors:
    """Check the ``[random]`` table (see the module docstring)."""
    if value is None:
        return RandomFactors()
    table = _table(value, "[random]")
    if "samples" not in table:
        raise CampaignSpecError(
            "[random].samples", "required: the number of draws per stratum, e.g. samples = 59"
        )
    try:
        samples = _integer(1)(table["samples"])
        sampling_seed = _integer(0)(table.get("sampling_seed", 0))
    except _Bad as error:
        key = "samples" if "sampling_seed" not in table else "samples/sampling_seed"
        raise CampaignSpecError(f"[random].{key}", str(error)) from None
    entries: dict[str, Any] = {}
    for key, item in table.items():
        if key in ("samples", "sampling_seed"):
            continue
        if key == "mismatch":
            for parameter, spec in _table(item, "[random].mismatch").items():
                if parameter not in _PH_PARAMETERS:
                    raise CampaignSpecError(
                        f"[random].mismatch.{parameter}",
                        f"unknown pH-plant parameter; parameters: {list(_PH_PARAMETERS)}",
                    )
                entries[f"mismatch.{parameter}"] = spec
        elif key in RANDOM_SETTINGS:
            entries[key] = item
        else:
            raise CampaignSpecError(
                f"[random].{key}",
                f"not a setting that can be sampled; these can: {list(RANDOM_SETTINGS)} and "
                "mismatch.<parameter> (or samples, sampling_seed)",
            )
    distributions = {name: _distribution(name, spec) for name, spec in entries.items()}
    places = [("[campaign]", fixed), ("[factors]", factors)]
    places += [(f"[[cases]][{index}]", case) for index, case in enumerate(cases)]
    for name in distributions:
        setting, _, mismatch_parameter = name.partition(".")
        for where, settings in places:
            if setting not in settings:
                continue
            values = settings[setting] if where == "[factors]" else [settings[setting]]
            if not mismatch_parameter or any(mismatch_parameter in v for v in values):
                raise CampaignSpecError(
                    f"[random].{name}", f"also set in {where}: keep one of the two"
                )
    if any(name.startswith("mismatch.") for name in distributions) and (
        "mismatch" in factors or any("mismatch" in case for case in cases)
    ):
        raise CampaignSpecError(
            "[random].mismatch",
            "the mismatch also varies in [factors] or [[cases]]: the drawn parameters would "
            "blur its levels (the strata of the statements). Fix the other parameters in "
            "[campaign].mismatch, or draw them all in [random]",
        )
    seed_set = "seed" in fixed or "seed" in factors or any("seed" in case for case in cases)
    if not distributions and seed_set:
        raise CampaignSpecError(
            "[random]",
            "nothing to draw: no distributions and the noise seed is set in the spec; add a "
            "distribution, or drop seed so that every draw gets its own noise seed",
        )
    return RandomFactors(samples, sampling_seed, distributions, not seed_set, active=True)


def _replications(
    value: Any, factors: Mapping[str, Sequence[Any]], random: RandomFactors
) -> tuple[str, ...]:
    """Check ``[campaign].replications`` (default: ``seed`` where it is a factor)."""
    where = "[campaign].replications"
    if value is None:
        return tuple(name for name in DEFAULT_REPLICATIONS if name in factors)
    if not isinstance(value, list) or not all(isinstance(v, str) for v in value):
        raise CampaignSpecError(
            where, f'expected a list of factor names, e.g. ["seed"], got {value!r}'
        )
    drawn = {name.split(".", 1)[0] for name in random.distributions}
    for name in value:
        if name not in factors:
            raise CampaignSpecError(
                where,
                f"{name!r} is not a [factors] entry; replications are factors whose levels "
                f"repeat a stratum's loop (factors: {list(factors)})",
            )
        if name in drawn:
            raise CampaignSpecError(where, f"{name!r} is drawn in [random]: it is no factor")
    if len(set(value)) != len(value):
        raise CampaignSpecError(where, f"{value!r} lists a factor twice")
    return tuple(value)


def _distribution(name: str, value: Any) -> Distribution:
    where = f"[random].{name}"
    table = _table(value, where)
    kind = table.get("distribution")
    if kind not in DISTRIBUTIONS:
        raise CampaignSpecError(
            where,
            f"expected distribution = one of {list(DISTRIBUTIONS)}, got {kind!r}; e.g. "
            '{ distribution = "uniform", low = 0.0, high = 0.02 }',
        )
    wanted = DISTRIBUTIONS[kind]
    extra = sorted(set(table) - {"distribution", *wanted})
    missing = [key for key in wanted if key not in table]
    if extra or missing:
        raise CampaignSpecError(
            where, f"a {kind} distribution takes {list(wanted)}; missing {missing}, unknown {extra}"
        )
    parameters = {}
    for key in wanted:
        try:
            parameters[key] = _real(table[key])
        except _Bad as error:
            raise CampaignSpecError(f"{where}.{key}", str(error)) from None
    if kind in ("uniform", "log-uniform") and not parameters["low"] < parameters["high"]:
        raise CampaignSpecError(where, f"needs low < high, got {parameters}")
    if kind == "log-uniform" and parameters["low"] <= 0:
        raise CampaignSpecError(
            where, f"a log-uniform distribution needs low > 0, got {parameters}"
        )
    if kind == "normal" and not parameters["std"] > 0:
        raise CampaignSpecError(where, f"needs std > 0, got {parameters}")
    return Distribution(kind, parameters)


def _drawn_settings(
    drawn: dict[str, Any], mismatch: dict[str, float], sample: int
) -> dict[str, Any]:
    """The drawn values of one sample, checked like written ones (the mismatch merged
    with the task's own)."""
    settings: dict[str, Any] = {}
    for name, value in drawn.items():
        where = f"[random].{name}"
        try:
            if name == "mismatch":
                settings[name] = _mismatch({**mismatch, **value})
            else:
                settings[name] = SETTINGS[name].check(value)
        except _Bad as error:
            raise CampaignSpecError(
                where,
                f"draw {sample} gave {value!r}: {error}; choose a distribution that stays "
                "in the setting's range (e.g. uniform or log-uniform bounds)",
            ) from None
    return settings


def parse_spec(
    data: Mapping[str, Any],
    *,
    name: str | None = None,
    base_dir: Path | None = None,
    source: Path | None = None,
    text: str = "",
) -> CampaignSpec:
    """Validate a spec given as a mapping (the parsed TOML) and build its tasks.

    Parameters
    ----------
    data : mapping
        ``{"campaign": {...}, "factors": {...}, "cases": [...]}``; every part optional.
    name : str, optional
        Default campaign name (``[campaign].name`` wins).
    base_dir : Path, optional
        Folder that relative model paths are relative to (default: the working folder).

    Raises
    ------
    CampaignSpecError
        The first bad entry, named (``[factors].L_d[2]``), with the fix.
    """
    for key in data:
        if key not in ("campaign", "factors", "cases", "random"):
            raise CampaignSpecError(
                f"[{key}]",
                "unknown table; a spec has [campaign], [factors], [[cases]] and [random]",
            )
    campaign = _table(data.get("campaign", {}), "[campaign]")
    factors_table = _table(data.get("factors", {}), "[factors]")
    raw_cases = data.get("cases", [{}])
    if not isinstance(raw_cases, list) or not raw_cases:
        raise CampaignSpecError("[[cases]]", "expected one or more [[cases]] tables")

    campaign_name = campaign.get("name", name or "campaign")
    if not isinstance(campaign_name, str) or not campaign_name:
        raise CampaignSpecError(
            "[campaign].name", f"expected a non-empty string, got {campaign_name!r}"
        )
    trace = _trace_selector(campaign.get("trace", False))
    fixed = {
        key: _checked(key, value, "[campaign]")
        for key, value in campaign.items()
        if key not in CAMPAIGN_ONLY
    }
    factors = {key: _factor_values(key, values) for key, values in factors_table.items()}
    cases: list[dict[str, Any]] = []
    for index, case in enumerate(raw_cases):
        where = f"[[cases]][{index}]"
        table = _table(case, where)
        cases.append({key: _checked(key, value, where) for key, value in table.items()})
    for key in factors:
        if key in fixed:
            raise CampaignSpecError(
                f"[factors].{key}", "also set in [campaign]: keep one of the two"
            )
    for index, case in enumerate(cases):
        for key in case:
            if key in factors:
                raise CampaignSpecError(
                    f"[[cases]][{index}].{key}", "also a factor: keep one of the two"
                )
    random = _random_factors(data.get("random"), fixed, factors, cases)
    replications = _replications(campaign.get("replications"), factors, random)
    offset_tolerance = DEFAULT_OFFSET_TOLERANCE
    if "offset_tolerance" in campaign:
        try:
            offset_tolerance = _number(0.0, open_low=False)(campaign["offset_tolerance"])
        except _Bad as error:
            raise CampaignSpecError("[campaign].offset_tolerance", str(error)) from None

    tasks: list[Task] = []
    seen: set[str] = set()
    models: dict[str, _ModelFile] = {}
    names = list(factors)
    levels = {name: {repr(v): i for i, v in enumerate(factors[name])} for name in replications}
    for index, case in enumerate(cases):
        for combination, j in itertools.product(
            itertools.product(*(factors[n] for n in names)), range(random.samples)
        ):
            chosen = dict(zip(names, combination, strict=True))
            # replication r of a stratum takes the draws r * samples + j (none shared)
            replication = 0
            for name in replications:
                replication = replication * len(factors[name]) + levels[name][repr(chosen[name])]
            sample = replication * random.samples + j
            drawn = random.draw(sample) if random.active else {}
            given = {**fixed, **case, **chosen}
            origin = {name: f"[campaign].{name}" for name in fixed}
            origin.update({name: f"[[cases]][{index}].{name}" for name in case})
            origin.update({name: f"[factors].{name}" for name in names})
            if random.active:
                given.update(_drawn_settings(drawn, given.get("mismatch", {}), sample))
                origin.update({name: f"[random].{name}" for name in drawn})
                given["sample"] = sample
            settings, model = _resolve_task(given, origin, base_dir)
            model_file = _model_file(model, origin.get("model", "[campaign].model"), models)
            scenario = settings.get("scenario")
            plant = SCENARIO_NAMES[scenario] if scenario is not None else settings["plant"]
            _check_plant_sampling_time(model_file, plant, origin.get("model", "[campaign].model"))
            key = task_key(settings, model_sha256=model_file.sha256)
            if key in seen:
                continue
            seen.add(key)
            tasks.append(
                Task(
                    key=key,
                    settings=settings,
                    model_location=model,
                    trace=trace.selects(settings),
                    model_sha256=model_file.sha256,
                    model_bytes=model_file.data,
                )
            )
    spec = CampaignSpec(
        name=campaign_name,
        fixed=fixed,
        factors=factors,
        cases=cases,
        trace=trace,
        tasks=tuple(tasks),
        source=source,
        text=text,
        random=random,
        replications=replications,
        offset_tolerance=offset_tolerance,
    )
    for name_ in spec.trace.match:
        if name_ not in fixed and name_ not in spec.varying and name_ not in DEFAULTS:
            raise CampaignSpecError(
                f"[campaign].trace.{name_}", "is never set by this campaign: no task matches"
            )
    return spec


def load_spec(path: str | Path) -> CampaignSpec:
    """Read and validate a campaign spec from a TOML file (see the module docstring).

    Raises
    ------
    CampaignSpecError
        Bad TOML (with the parser's line and column) or a bad entry.
    OSError
        The file cannot be read.
    """
    file = Path(path)
    text = file.read_text(encoding="utf-8")
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as error:
        raise CampaignSpecError(str(file), f"not valid TOML: {error}") from None
    return parse_spec(data, name=file.stem, base_dir=file.parent, source=file, text=text)


def describe_settings() -> Sequence[tuple[str, str]]:
    """(setting, meaning and default) pairs, for help texts."""
    return [
        (name, setting.doc + (f" (default {DEFAULTS[name]!r})" if name in DEFAULTS else ""))
        for name, setting in SETTINGS.items()
    ]
