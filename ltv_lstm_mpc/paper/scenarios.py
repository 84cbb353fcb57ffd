r"""The paper's five closed-loop simulations (Section V, Figs. 3-7) on the shipped model.

1. ``lstm_theorem3`` — LSTM plant (Fig. 2), slow set-point and disturbance changes that
   satisfy Theorem 3's conditions: the set-point passes through the rate limiter
   :math:`\Delta y^0_{max}` of paper notes 2.10c and the disturbance ramps with
   :math:`|w| \le w_{max}`. Expected: zero violations, every step feasible, zero
   steady-state error (Fig. 3).
2. ``lstm_larger`` — larger set-point rate and disturbance steps that violate the
   sufficient conditions; feasibility is kept in practice (Fig. 4).
3. ``lstm_steps`` — still larger set-point steps: infeasible instants (shaded), where the
   paper's fallback (no output/terminal constraints) is applied (Fig. 5).
4. ``ph_small_Ld`` — the pH plant with :math:`L_d = 0.01`: offset-free, slowly (Fig. 6).
5. ``ph_large_Ld`` — the pH plant with :math:`L_d = 0.1`: offset-free, faster, constraints
   respected (Fig. 7).

The paper gives no numeric schedules for its figures; these are ours, chosen to show each
figure's point, and fixed here so every run (and the solver comparison) uses the same ones.
Physical units: pH for outputs and the LSTM plant's output disturbance, mL/s for q2.

Another single-output model (``reproduce --model``): scenarios 1-3 run on its LSTM plant
with the same schedules mapped affinely from the pH band [6.5, 8.5] onto the model's
admissible set-point interval (Assumption 5, :attr:`Certification.y0_interval_phi`) within
its equilibrium outputs over the input range, output disturbances scaled alike; scenarios
4-5 need the pH plant and run only for a pH model (one
whose stored output constraint is the paper's [6, 9] pH).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np
from numpy.typing import NDArray

from ltv_lstm_mpc.certificates.certify import Certification, certify
from ltv_lstm_mpc.exceptions import InvalidValueError
from ltv_lstm_mpc.loop.controller import OffsetFreeController
from ltv_lstm_mpc.loop.monitor import AssumptionMonitor
from ltv_lstm_mpc.loop.schedules import piecewise_constant
from ltv_lstm_mpc.loop.schedules import segments as schedule_segments
from ltv_lstm_mpc.loop.simulation import SimulationResult, output_constraint, simulate
from ltv_lstm_mpc.lstm.model import LSTMModel
from ltv_lstm_mpc.mpc.config import MPCConfig
from ltv_lstm_mpc.mpc.fhocp import MPCSolver
from ltv_lstm_mpc.plants.ph import PH_INITIAL_OUTPUT, PH_OUTPUT_CONSTRAINT
from ltv_lstm_mpc.plants.protocol import Plant
from ltv_lstm_mpc.plants.registry import resolve_plant

__all__ = [
    "ADMISSIBLE_SETPOINT_FRACTIONS",
    "PH_SCHEDULE_BAND",
    "SETTLE_SAMPLES",
    "Scenario",
    "ScenarioResult",
    "admissible_setpoints",
    "initial_output",
    "is_ph_model",
    "paper_scenarios",
    "run_scenario",
]

FloatArray = NDArray[np.float64]

#: The pH band the schedules are written in; another model's scenarios map it onto its
#: admissible set-point interval.
PH_SCHEDULE_BAND = (6.5, 8.5)


def _ramped(
    levels: Sequence[float], lengths: Sequence[int], slope: float, start: float
) -> FloatArray:
    """Piecewise-constant targets reached by ramps of at most ``slope`` per step."""
    target = piecewise_constant(levels, lengths)
    out = np.empty_like(target)
    value = start
    for k, goal in enumerate(target):
        value += float(np.clip(goal - value, -slope, slope))
        out[k] = value
    return out


@dataclass(frozen=True)
class Scenario:
    """One closed-loop experiment.

    Attributes
    ----------
    name, title : str
        Identifier and plot title.
    plant : str
        A plant name of the registry (:mod:`ltv_lstm_mpc.plants.registry`): ``"lstm"``,
        LSTM + output disturbance (Fig. 2), ``"ph"``, the pH process (Fig. 1), or another
        registered name or ``"package.module:Class"``.
    setpoints : ndarray (steps,)
        Requested set-point :math:`y^0_\\phi` per sample (the plant's output unit; pH in
        the paper's scenarios), before the rate limiter.
    disturbances : ndarray (steps,)
        The plant's disturbance (LSTM plant: output disturbance in output units; pH plant:
        buffer flow q2 in mL/s); NaN everywhere: the plant's own default disturbance.
    config : MPCConfig
        Controller tuning.
    setpoint_rate_limit : float or None
        Normalized :math:`\\Delta y^0_{max}` per step (None: no limiter).
    segments : list of (start, end)
        Constant set-point/disturbance segments [start, end) long enough to settle;
        ``final_offset`` is evaluated at their last sample.
    y0_phi_initial : float or None
        Initial plant output (physical units) of a plant that takes one (the LSTM plant:
        the equilibrium giving it). None: a plant's own ``reset()`` state, the LSTM plant's
        from the model (:func:`initial_output`).
    notes : str
        What the scenario's numbers come from, in words.
    rate_certification : Certification, optional
        The certification whose rate bound the limiter uses (its own set-point range);
        the controller's assumption monitor checks against it
        (:mod:`ltv_lstm_mpc.loop.monitor`). None: the controller's own.
    """

    name: str
    title: str
    plant: str
    setpoints: FloatArray
    disturbances: FloatArray
    config: MPCConfig
    setpoint_rate_limit: float | None
    segments: list[tuple[int, int]] = field(default_factory=list)
    y0_phi_initial: float | None = None
    notes: str = ""
    rate_certification: Certification | None = None

    @property
    def steps(self) -> int:
        """Number of samples."""
        return int(self.setpoints.shape[0])

    def make_plant(self, model: LSTMModel, certification: Certification | None = None) -> Plant:
        """A fresh plant at its initial condition (through the plant registry).

        A plant that takes an initial output (the LSTM plant) starts at
        :attr:`y0_phi_initial`, or, when that is None, at :func:`initial_output` of the
        model (``certification``: the controller's, for its admissible interval). Any other
        plant starts from its own ``reset()``.

        Raises
        ------
        InvalidValueError
            :attr:`y0_phi_initial` is given for a plant that starts from its own state.
        """
        entry = resolve_plant(self.plant)
        if "y0_phi" not in entry.options:
            if self.y0_phi_initial is not None:
                raise InvalidValueError(
                    f"the initial output {self.y0_phi_initial:g} cannot be set on plant "
                    f"{entry.name!r}: it starts from its own reset() state; an initial output "
                    "applies to the LSTM plant (--plant lstm) only"
                )
            return entry.build(model)
        y0 = self.y0_phi_initial
        if y0 is None:
            y0 = initial_output(model, certification)
        return entry.build(model, y0_phi=y0)

    def make_controller(
        self,
        model: LSTMModel,
        *,
        mpc: MPCSolver | None = None,
        solver: str | None = None,
        N: int | None = None,
        engine: str = "auto",
    ) -> OffsetFreeController:
        """The controller of this scenario (optionally another solver, horizon, MPC or step
        engine)."""
        config = self.config
        if solver is not None:
            config = replace(config, solver=solver)
        if N is not None:
            config = replace(config, N=N)
        monitor = None
        if self.rate_certification is not None:
            monitor = AssumptionMonitor(model, self.rate_certification)
        return OffsetFreeController(
            model, config, setpoint_rate_limit=self.setpoint_rate_limit, mpc=mpc, monitor=monitor,
            engine=engine,
        )  # fmt: skip

    def cycled(self, period: int) -> Scenario:
        """This scenario with its set-point levels (each value its schedule moves to, in
        order) cycled every ``period`` samples, its disturbance schedule kept: more
        set-point steps, so more infeasible instants (the worst-case benchmarks' dense
        schedule: ``experiments/worst_case.py``)."""
        if not (isinstance(period, int | np.integer) and period >= 1):
            raise InvalidValueError(
                f"period must be a whole number of samples >= 1, got {period!r}"
            )
        setpoints = np.asarray(self.setpoints, dtype=float)
        levels = [float(setpoints[0])]
        for value in setpoints[1:].tolist():
            if value != levels[-1]:
                levels.append(value)
        steps = setpoints.shape[0]
        cycled = np.array([levels[(k // period) % len(levels)] for k in range(steps)])
        return replace(self, setpoints=cycled)


@dataclass(frozen=True)
class ScenarioResult:
    """A scenario's simulation and its summary numbers (see :meth:`summary`)."""

    scenario: Scenario
    simulation: SimulationResult
    controller: OffsetFreeController
    plant: Plant | None = None

    @property
    def output_constraint(self) -> tuple[FloatArray, FloatArray] | None:
        """The output constraint the violations are measured against (physical units): the
        plant's ``y_phi_constraint``, else the model's
        (:func:`~ltv_lstm_mpc.loop.simulation.output_constraint`)."""
        return output_constraint(self.plant, self.controller.model)

    def summary(self) -> dict[str, Any]:
        """Numbers of ``summary.json``: violations, infeasible steps, offsets, timings.

        ``max_output_violation`` is the largest violation of the output constraint by the
        true plant output, measured against the same constraint as ``plant_violation_steps``
        (:func:`~ltv_lstm_mpc.loop.simulation.output_constraint`: the plant's, else the
        model's; its bounds are ``output_constraint``); None when neither states one.
        ``output_unit`` is the output's unit from the plant registry.
        """
        from ltv_lstm_mpc.plotting import signal_labels

        sim, sc = self.simulation, self.scenario
        y = sim.y_phi[:, 0]
        measured = sim.plant_violation
        violation = (
            None
            if measured is None or measured.size == 0 or np.all(np.isnan(measured))
            else float(np.nanmax(measured))
        )
        constraint = self.output_constraint
        offsets = [abs(float(y[end - 1] - sc.setpoints[end - 1])) for _, end in sc.segments]
        cert = self.controller.certification
        return {
            "name": sc.name,
            "title": sc.title,
            "plant": sc.plant,
            "steps": sc.steps,
            "solver": self.controller.config.solver,
            "N": self.controller.config.N,
            "L_d": self.controller.config.L_d,
            "setpoint_rate_limit": sc.setpoint_rate_limit,
            "output_unit": signal_labels(sc.plant, self.controller.model).output_unit,
            "output_constraint": None
            if constraint is None
            else [float(constraint[0][0]), float(constraint[1][0])],
            "max_output_violation": violation,
            "max_predicted_violation": float(np.max(sim.output_violation)),
            "infeasible_steps": int(np.sum(~sim.feasible)),
            "fallback_steps": int(np.sum(sim.policy != "nominal")),
            **{k: v for k, v in sim.summary_counts().items() if k != "infeasible_steps"},
            "final_offset": max(offsets) if offsets else None,
            "segment_offsets": offsets,
            "median_step_time_s": float(np.median(sim.time_total)),
            "max_step_time_s": float(np.max(sim.time_total)),
            "median_mpc_time_s": float(np.median(sim.time_mpc)),
            "rho_o": cert.observer.rho_o,
            "L_max": cert.observer.L_max,
            "e_inf": cert.tightening.e_inf,
            "y0_interval_phi": [float(v[0]) for v in cert.y0_interval_phi]
            if cert.y0_interval_phi is not None
            else None,
        }


#: Samples scenario 1 leaves after the rate-limited set-point has arrived (to settle).
SETTLE_SAMPLES = 200


def is_ph_model(model: LSTMModel) -> bool:
    """Whether ``model`` is a pH model: one input and output and the paper's stored output
    constraint [6, 9] pH (:data:`~ltv_lstm_mpc.plants.ph.PH_OUTPUT_CONSTRAINT`)."""
    constraint = model.y_phi_constraint
    if model.m != 1 or model.p != 1 or constraint is None:
        return False
    stored = (float(constraint[0][0]), float(constraint[1][0]))
    return bool(np.allclose(stored, PH_OUTPUT_CONSTRAINT, rtol=0.0, atol=1e-9))


def initial_output(model: LSTMModel, certification: Certification | None = None) -> float:
    """The initial output of the LSTM plant when none is given: the middle of the model's
    admissible set-point interval (Assumption 5, ``certification.y0_interval_phi``; default
    the certification of ``MPCConfig()``), physical units, moved into the range of
    equilibrium outputs of the input range's ends where it lies outside it (the plant starts
    at an equilibrium, :class:`~ltv_lstm_mpc.plants.lstm_plant.LSTMPlant`): the middle of
    the admissible interval narrowed to the equilibrium outputs between those of the input
    range's ends (1 % inside).

    Raises
    ------
    InvalidValueError
        The model has more than one output, or its admissible interval is empty (the
        message says to give the initial output).
    """
    if model.p != 1:
        raise InvalidValueError(
            f"an initial output is chosen for a single-output model only (p = {model.p})"
        )
    if certification is None:
        certification = certify(model, MPCConfig().certification_settings(model))
    interval = certification.y0_interval_phi
    if interval is None:
        raise InvalidValueError(
            "the model's admissible set-point interval (Assumption 5) is empty, so no initial "
            "output is implied: give it (simulate --y0-initial, campaign y0_initial, "
            "Scenario.y0_phi_initial) in the model's physical output units"
        )
    low, high = _reachable(model, interval)
    return 0.5 * (float(low[0]) + float(high[0]))


def _reachable(model: LSTMModel, interval: tuple[Any, Any]) -> tuple[FloatArray, FloatArray]:
    """The admissible interval narrowed, for m = p = 1, to the equilibrium outputs between
    those of the input range's ends (1 % inside; a set-point or start outside them has no
    equilibrium with the input in U, Assumption 5 does not exclude that); as given where
    the two do not overlap or the model has several inputs or outputs."""
    low, high = (np.ravel(np.asarray(v, dtype=np.float64)).copy() for v in interval)
    if model.m != 1 or model.p != 1:
        return low, high
    ends = [
        float(model.denormalize_y(model.output(model.equilibrium(np.full(1, u))))[0])
        for u in (-1.0, 1.0)
    ]
    margin = 0.01 * (max(ends) - min(ends))
    narrowed = (max(float(low[0]), min(ends) + margin), min(float(high[0]), max(ends) - margin))
    if narrowed[0] >= narrowed[1]:
        return low, high
    return np.array([narrowed[0]]), np.array([narrowed[1]])


#: Where default set-points lie in the admissible interval (fractions from its low end).
ADMISSIBLE_SETPOINT_FRACTIONS = (0.25, 0.75, 0.5)


def admissible_setpoints(model: LSTMModel, certification: Certification) -> list[str]:
    """Default set-points of a model with none of its own: one per segment at
    :data:`ADMISSIBLE_SETPOINT_FRACTIONS` of the admissible set-point interval
    (Assumption 5, ``certification.y0_interval_phi``) within the model's equilibrium
    outputs over the input range (:func:`initial_output`), physical units, as ``simulate
    --setpoints`` tokens (comma-separated per output for p > 1), 4 significant digits.

    Raises
    ------
    InvalidValueError
        The admissible interval is empty (the message says to give the set-points).
    """
    interval = certification.y0_interval_phi
    if interval is None:
        raise InvalidValueError(
            "the model's admissible set-point interval (Assumption 5) is empty, so no default "
            "set-points follow from it: give them (--setpoints) in the model's output units"
        )
    low, high = _reachable(model, interval)
    return [
        ",".join(f"{a + f * (b - a):.4g}" for a, b in zip(low, high, strict=True))
        for f in ADMISSIBLE_SETPOINT_FRACTIONS
    ]


def paper_scenarios(model: LSTMModel, *, short: bool = False) -> list[Scenario]:
    """The five scenarios of the paper's Section V for ``model`` (the shipped pH model).

    Parameters
    ----------
    model : LSTMModel
        Used for Theorem 3's rate bound and the disturbance-variation bound. A model that
        is not a pH model (:func:`is_ph_model`) gets scenarios 1-3 on its own LSTM plant,
        the pH schedules mapped from :data:`PH_SCHEDULE_BAND` onto its admissible set-point
        interval (no pH number reaches it); scenarios 4-5 need the pH plant and are left out.
    short : bool
        Shorter schedules (about a quarter of the samples) for smoke tests; the segments
        may then be too short to settle.

    Raises
    ------
    InvalidValueError
        A model with p > 1, or whose admissible set-point interval is empty, or for which
        Theorem 3's rate condition cannot hold.
    """
    from ltv_lstm_mpc.plotting import signal_labels

    scale = 1 if not short else 4
    base = MPCConfig()
    ph = is_ph_model(model)
    if ph:
        unit = "pH"

        def level(values: Sequence[float]) -> list[float]:
            return [float(v) for v in values]

        size = 1.0  # output units per pH
    else:
        if model.p != 1:
            raise InvalidValueError(
                f"the paper's scenarios are single-output; this model has p = {model.p} outputs "
                "(use simulate, or reproduce --benchmark quadtank for the quadruple tank)"
            )
        interval = certify(model, base.certification_settings(model)).y0_interval_phi
        if interval is None:
            raise InvalidValueError(
                "the model's admissible set-point interval (Assumption 5) is empty: the "
                "paper's scenarios set their set-points inside it (train a model with a "
                "non-empty interval, or lower d_max)"
            )
        reachable = _reachable(model, interval)
        low, high = float(reachable[0][0]), float(reachable[1][0])
        band_low, band_high = PH_SCHEDULE_BAND
        size = (high - low) / (band_high - band_low)
        unit = signal_labels("lstm", model).output_unit

        def level(values: Sequence[float]) -> list[float]:
            return [low + (float(v) - band_low) * size for v in values]

    start = level([PH_INITIAL_OUTPUT])[0]
    levels1 = level([7.5, 6.9, 7.6, 7.2])
    range1 = (min(*levels1, start), max(*levels1, start))  # with the initial output
    # Theorem 3's rate bound with the smallest alpha over scenario 1's set-point range.
    operating = model.normalize_y(np.array(range1))
    settings = replace(
        base.certification_settings(model),
        y0_operating_range=(float(operating[0]), float(operating[1])),
    )
    slow_cert = certify(model, settings)
    if not slow_cert.rate_bound.holds:
        raise InvalidValueError(
            "Theorem 3's rate condition (paper notes 2.10c) cannot hold for this model over "
            f"scenario 1's set-point range [{range1[0]:.4g}, {range1[1]:.4g}] {unit}, so the "
            "paper's scenario 1 has no rate limit to use: run this model with simulate, or "
            "certify it (ltv-lstm-mpc certify) to see K_bar and the rate bound"
        )
    rate = slow_cert.rate_bound.delta_y0_max
    y_scale = float(model.normalization.y_scale[0]) if model.normalization is not None else 1.0
    w_max_phi = slow_cert.observer.w_max * y_scale  # output units per step
    scenarios: list[Scenario] = []

    # 1: Theorem 3's conditions (rate-limited set-point, |w| <= w_max). Each segment is
    # long enough for the limited set-point to arrive and settle: a model with a smaller
    # rate bound (larger K_bar, Lemma 5) gets longer segments, the shipped one 900/600.
    L = [900 // scale, 900 // scale, 900 // scale, 600 // scale]
    if not short:
        steps_normalized = np.abs(np.diff(model.normalize_y(np.array([start, *levels1]))))
        ramps = np.ceil(steps_normalized.ravel() / rate).astype(int)
        L = [max(length, int(ramp) + SETTLE_SAMPLES) for length, ramp in zip(L, ramps, strict=True)]
    d_ramp = np.clip(np.arange(sum(L)) - 50 // scale, 0, None) * 0.8 * w_max_phi
    d_ramp = np.minimum(d_ramp, 0.02 * size)
    scenarios.append(
        Scenario(
            name="1_lstm_theorem3",
            title="LSTM plant, slow changes satisfying Theorem 3",
            plant="lstm",
            setpoints=piecewise_constant(levels1, L),
            disturbances=d_ramp,
            config=base,
            setpoint_rate_limit=rate,
            segments=schedule_segments(L),
            y0_phi_initial=start,
            notes=(
                f"rate limit {rate:.4g} (normalized/step, paper notes 2.10c, valid over "
                f"[{range1[0]:.4g}, {range1[1]:.4g}] {unit}); |w| <= 0.8 w_max"
            ),
            rate_certification=slow_cert,
        )
    )
    # 2: larger changes: 10x faster set-point, disturbance steps.
    L2 = [600 // scale] * 4
    scenarios.append(
        Scenario(
            name="2_lstm_larger",
            title="LSTM plant, larger set-point and disturbance changes",
            plant="lstm",
            setpoints=piecewise_constant(level([7.8, 6.7, 8.2, 7.0]), L2),
            disturbances=piecewise_constant([size * d for d in (0.0, 0.08, -0.06, 0.04)], L2),
            config=base,
            setpoint_rate_limit=10 * rate,
            segments=schedule_segments(L2),
            y0_phi_initial=start,
            notes=(
                "10x Theorem 3's rate, output-disturbance steps of "
                f"{0.06 * size:.2g}-{0.14 * size:.2g} {unit}"
            ),
        )
    )
    # 3: set-point steps, no limiter: infeasible instants.
    scenarios.append(
        Scenario(
            name="3_lstm_steps",
            title="LSTM plant, large set-point steps (infeasible instants shaded)",
            plant="lstm",
            setpoints=piecewise_constant(level([8.3, 6.6, 8.4, 7.0]), L2),
            disturbances=piecewise_constant([size * d for d in (0.0, 0.1, -0.1, 0.0)], L2),
            config=base,
            setpoint_rate_limit=None,
            segments=schedule_segments(L2),
            y0_phi_initial=start,
            notes="set-point steps without rate limiter",
        )
    )
    if not ph:  # 4 and 5 run the pH plant itself
        return scenarios
    # 4 and 5: the pH plant with a q2 step.
    L4 = [1500 // scale, 1500 // scale, 1500 // scale]
    q2 = piecewise_constant([0.55, 0.7], [L4[0], L4[1] + L4[2]])  # q2 step with the 2nd set-point
    for name, title, l_d, lengths, disturbance in (
        ("4_ph_small_Ld", "pH plant, L_d = 0.01 (offset-free, slow)", 0.01, L4, q2),
        (
            "5_ph_large_Ld",
            "pH plant, L_d = 0.1 (offset-free, faster)",
            0.1,
            [500 // scale] * 4,
            piecewise_constant([0.55, 0.7, 0.45, 0.55], [500 // scale] * 4),
        ),
    ):
        levels = [7.5, 6.8, 8.0, 7.0][: len(lengths)]
        scenarios.append(
            Scenario(
                name=name,
                title=title,
                plant="ph",
                setpoints=piecewise_constant(levels, lengths),
                disturbances=disturbance[: sum(lengths)],
                config=replace(base, L_d=l_d),
                setpoint_rate_limit=0.01,
                segments=schedule_segments(lengths),
                notes="q2 steps; set-point rate limit 0.01 normalized/step",
            )
        )
    return scenarios


def run_scenario(
    scenario: Scenario,
    model: LSTMModel,
    *,
    mpc: MPCSolver | None = None,
    solver: str | None = None,
    N: int | None = None,
    progress: bool = False,
    check_sampling_time: bool = True,
    engine: str = "auto",
) -> ScenarioResult:
    """Simulate one scenario in closed loop and return it with its summary
    (``check_sampling_time``: as :func:`~ltv_lstm_mpc.simulate`'s)."""
    controller = scenario.make_controller(model, mpc=mpc, solver=solver, N=N, engine=engine)
    plant = scenario.make_plant(model, controller.certification)
    disturbances = scenario.disturbances
    result = simulate(
        plant,
        controller,
        scenario.setpoints,
        None if np.all(np.isnan(disturbances)) else disturbances,
        scenario.steps,
        progress=progress,
        description=scenario.name,
        check_sampling_time=check_sampling_time,
    )
    return ScenarioResult(scenario=scenario, simulation=result, controller=controller, plant=plant)
