r"""Solver comparison benchmark: every backend on the same closed loops, side by side.

For each scenario (the paper's, :func:`ltv_lstm_mpc.paper.scenarios.paper_scenarios`), horizon N
and backend, the closed loop of Fig. 1 is run with the same plant, set-points and
disturbances, and one CSV row records

* controller step time (median, p95, max, microseconds) and its split into observer,
  reference calculator (eq. reference_calculation), linearize + build, and solve;
* first-input and closed-loop-cost difference to the exact NMPC
  (:class:`~ltv_lstm_mpc.ExactNMPC`) and the ratios of the median step to the exact
  NMPC and to the fastest backend of the same scenario and N;
* nonlinear (re-simulated) violations of the tightened output rows, plant output
  violations of :math:`\mathcal Y`, infeasible steps and fallback uses;
* solver status counts and iterations.

Backends
--------
A backend is a solver name of the one registry
(:func:`ltv_lstm_mpc.solvers.available_solvers`), optionally with ``@<transcription>``
(``"daqp@sparse"``, ``"cvxpy:OSQP@condensed"``), or ``"ipopt"`` (the exact NMPC,
:class:`~ltv_lstm_mpc.ExactNMPC`, needs the ``nmpc`` extra). Every run is
``OffsetFreeController(model, MPCConfig(solver=..., transcription=...))`` driven by
:func:`~ltv_lstm_mpc.simulate`: the one controller, the one loop.

Saved subproblems (``save_subproblems``) are the RTI subproblems of one closed loop as
``.npz`` (:meth:`ConvexProblem.save`), both with cones and in the conservative QP form,
with the numbers each backend produced; :func:`replay` re-solves them offline and
compares.
"""

from __future__ import annotations

import argparse
import csv
import fnmatch
import json
import math
import time
from collections import Counter
from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import NDArray

from ltv_lstm_mpc.certificates.certify import Certification, certify
from ltv_lstm_mpc.command_arguments import UsageError, output_folder, positive_float, positive_int
from ltv_lstm_mpc.exceptions import InvalidValueError
from ltv_lstm_mpc.loop.controller import OffsetFreeController
from ltv_lstm_mpc.loop.simulation import simulate
from ltv_lstm_mpc.lstm.kernel import LSTMKernel
from ltv_lstm_mpc.lstm.model import LSTMModel, require_model
from ltv_lstm_mpc.mpc.config import MPCConfig
from ltv_lstm_mpc.mpc.rti import RobustMPC, resolve_transcription
from ltv_lstm_mpc.validation import expect_int, expect_path, expect_real

if TYPE_CHECKING:
    from matplotlib.figure import Figure

__all__ = [
    "CSV_COLUMNS",
    "BenchScenario",
    "available_backends",
    "register",
    "replay",
    "run_bench",
    "save_subproblems",
]

FloatArray = NDArray[np.float64]
Y_PHI_BOUNDS = (6.0, 9.0)

#: Columns of ``bench.csv`` (fixed order; times in microseconds).
CSV_COLUMNS = (
    "scenario",
    "N",
    "backend",
    "family",
    "solver",
    "steps",
    "steps_requested",
    "subsampled",
    "step_median_us",
    "step_p95_us",
    "step_max_us",
    "observer_median_us",
    "reference_median_us",
    "build_median_us",
    "solve_median_us",
    "prepare_median_us",
    "feedback_median_us",
    "overhead_median_us",
    "step_numpy_median_us",
    "ratio_to_numpy",
    "ratio_to_nmpc",
    "ratio_to_fastest",
    "u0_diff_max",
    "u0_diff_median",
    "cost",
    "cost_diff_pct",
    "output_violation_steps",
    "output_violation_max",
    "plant_violation_steps",
    "infeasible_steps",
    "fallback_steps",
    "d_hat_saturated_steps",
    "setpoint_not_ok_steps",
    "status_counts",
    "iterations_median",
    "iterations_max",
    "reformulation",
    "wall_s",
    "error",
)


@dataclass(frozen=True)
class BenchScenario:
    """What the benchmark needs of a scenario (a view of ``scenarios.Scenario``).

    Attributes
    ----------
    name : str
    plant : {"lstm", "ph"}
    setpoints, disturbances : ndarray (steps,)
        Physical set-point and disturbance per sample (the model's output units).
    config : MPCConfig
    setpoint_rate_limit : float or None
    make_plant : callable model -> plant
    """

    name: str
    plant: str
    setpoints: FloatArray
    disturbances: FloatArray
    config: MPCConfig
    setpoint_rate_limit: float | None
    make_plant: Callable[[LSTMModel], Any]

    @property
    def steps(self) -> int:
        """Number of samples."""
        return int(self.setpoints.shape[0])


#: Normalized outputs of the stand-in scenario: start, then two set-points.
STANDIN_LEVELS = (-0.293, 0.0468, -0.429)


def standin_scenario(model: LSTMModel, steps: int = 300) -> BenchScenario:
    """LSTM plant from the normalized output -0.293, set-point steps to 0.0468 and -0.429
    (rate 0.01/step normalized) and an output disturbance of 1 % of the output range after
    step 100, in the model's own physical units (on the shipped pH model: pH 7.0 -> 7.5 ->
    6.8, 0.03 pH); used when the paper scenarios are absent."""
    from ltv_lstm_mpc.plants.lstm_plant import LSTMPlant

    k = np.arange(steps)
    first, second, third = (float(model.denormalize_y(np.array([v]))[0]) for v in STANDIN_LEVELS)
    setpoints = np.where(k < 60, first, np.where(k < 130, second, third)).astype(np.float64)
    span = float(model.denormalize_y(np.ones(1))[0] - model.denormalize_y(-np.ones(1))[0])
    disturbances = np.where(k < 100, 0.0, 0.01 * span).astype(np.float64)
    return BenchScenario(
        name="standin_lstm",
        plant="lstm",
        setpoints=setpoints,
        disturbances=disturbances,
        config=MPCConfig(),
        setpoint_rate_limit=0.01,
        make_plant=lambda m: LSTMPlant(m, y0_phi=first),
    )


def bench_scenarios(model: LSTMModel, *, short: bool = True) -> list[BenchScenario]:
    """The paper's scenarios (``ltv_lstm_mpc.paper.scenarios``), or the stand-in without it."""
    try:
        from ltv_lstm_mpc.paper.scenarios import paper_scenarios
    except ImportError:
        return [standin_scenario(model)]
    out = []
    for s in paper_scenarios(model, short=short):
        out.append(
            BenchScenario(
                name=s.name,
                plant=s.plant,
                setpoints=np.asarray(s.setpoints, dtype=np.float64).reshape(-1),
                disturbances=np.asarray(s.disturbances, dtype=np.float64).reshape(-1),
                config=s.config,
                setpoint_rate_limit=s.setpoint_rate_limit,
                make_plant=s.make_plant,
            )
        )
    return out


def available_backends() -> list[str]:
    """Every backend this installation can run (see the module docstring)."""
    import importlib.util

    from ltv_lstm_mpc.solvers import available_solvers

    names = ["ipopt"] if importlib.util.find_spec("casadi") is not None else []
    return names + available_solvers()


def backend_config(backend: str, config: MPCConfig) -> MPCConfig:
    """``config`` with the solver and transcription of ``backend`` (``solver[@transcription]``)."""
    solver, _, transcription = backend.partition("@")
    return replace(config, solver=solver, transcription=transcription or "auto")  # type: ignore[arg-type]


# -------------------------------------------------------------------------- one run
def _make_controller(
    backend: str, model: LSTMModel, scenario: BenchScenario, N: int, cert: Certification
) -> OffsetFreeController:
    """The one controller, configured for ``backend``."""
    config = backend_config(backend, replace(scenario.config, N=N))
    mpc = RobustMPC(model, config, certification=cert)
    return OffsetFreeController(
        model, config, setpoint_rate_limit=scenario.setpoint_rate_limit, mpc=mpc
    )


def _run(
    backend: str,
    model: LSTMModel,
    scenario: BenchScenario,
    N: int,
    cert: Certification,
    steps: int,
    time_cap: float,
) -> dict[str, Any]:
    """One closed loop; returns per-step series and the summary fields."""
    start = time.perf_counter()
    controller = _make_controller(backend, model, scenario, N, cert)
    plant = scenario.make_plant(model)
    disturbances = [None if np.isnan(d) else float(d) for d in scenario.disturbances[:steps]]
    result = simulate(
        plant,
        controller,
        np.asarray(scenario.setpoints[:steps], dtype=np.float64),
        lambda k: disturbances[k],  # type: ignore[arg-type, return-value]
        steps,
        progress=False,
        max_seconds=time_cap,
    )
    records = controller.records
    Q, R = replace(scenario.config, N=N).weights(model)
    dx = np.array([r.x_hat - r.x_bar for r in records])
    du = np.array([r.u - r.u_bar for r in records])
    stage = np.einsum("ki,ij,kj->k", dx, Q, dx) + np.einsum("ki,ij,kj->k", du, R, du)
    return {
        "records": records,
        "y_phi": result.y_phi,
        "u_phi": result.u_phi[:, 0],
        "stage_cost": stage,
        "iterations": np.array([r.mpc.solver_iterations for r in records], dtype=float),
        "prepare": result.time_prepare,
        "feedback": result.time_feedback,
        "transcription": result.transcription,
        "wall": time.perf_counter() - start,
    }


def _summary(run: dict[str, Any]) -> dict[str, Any]:
    records = run["records"]
    us = 1e6
    total = np.array([r.time_total for r in records]) * us
    solve = np.array([r.mpc.solver_time for r in records]) * us
    mpc = np.array([r.time_mpc for r in records]) * us
    violation = np.array([r.mpc.residuals["output_violation"] for r in records])
    y = run["y_phi"][:, 0]
    statuses = Counter(r.mpc.status for r in records)
    reformulations = {r.mpc.reformulation for r in records if r.mpc.reformulation}

    def med(values: FloatArray) -> float:
        return float(np.median(values)) if values.size and np.isfinite(values).any() else math.nan

    return {
        "steps": len(records),
        "step_median_us": med(total),
        "step_p95_us": float(np.percentile(total, 95)),
        "step_max_us": float(np.max(total)),
        "observer_median_us": med(np.array([r.time_observer for r in records]) * us),
        "reference_median_us": med(np.array([r.time_reference for r in records]) * us),
        "build_median_us": med(mpc - solve),
        "solve_median_us": med(solve),
        "prepare_median_us": med(run["prepare"] * us),
        "feedback_median_us": med(run["feedback"] * us),
        "overhead_median_us": med(total - solve),  # everything but the solver calls
        "cost": float(np.sum(run["stage_cost"])),
        "output_violation_steps": int(np.sum(violation > 1e-9)),
        "output_violation_max": float(np.max(violation)),
        "plant_violation_steps": int(
            np.sum((y < Y_PHI_BOUNDS[0] - 1e-9) | (y > Y_PHI_BOUNDS[1] + 1e-9))
        ),
        "infeasible_steps": int(sum(not r.mpc.feasible for r in records)),
        "fallback_steps": int(sum(r.mpc.policy != "nominal" for r in records)),
        "d_hat_saturated_steps": int(
            sum(r.d_hat_saturated is not None and bool(r.d_hat_saturated.any()) for r in records)
        ),
        "setpoint_not_ok_steps": int(sum(r.setpoint_status != "ok" for r in records)),
        "status_counts": ";".join(f"{k}:{v}" for k, v in sorted(statuses.items())),
        "iterations_median": med(run["iterations"]),
        "iterations_max": float(np.max(run["iterations"])),
        "reformulation": ";".join(sorted(reformulations)),
        "wall_s": run["wall"],
    }


# --------------------------------------------------------------------------- the bench
def _steps_for(backend: str, N: int, scenario: BenchScenario, steps: int, slow: int) -> int:
    """Steps to run: N >= 20 through cvxpy, qpsolvers or the sparse transcription is capped
    at ``slow`` (``subsampled`` = 1 in the CSV)."""
    n = min(steps, scenario.steps)
    if N >= 20 and backend != "ipopt":
        config = backend_config(backend, replace(scenario.config, N=N))
        slow_family = backend.split(":")[0] in ("cvxpy", "qpsolvers")
        if slow_family or resolve_transcription(config) == "sparse":
            n = min(n, slow)
    return n


def run_bench(
    model: LSTMModel,
    *,
    scenarios: Sequence[BenchScenario],
    horizons: Sequence[int] = (5, 20, 50),
    backends: Sequence[str] | None = None,
    steps: int = 200,
    slow_steps: int = 60,
    time_cap: float = 60.0,
    log: Callable[[str], None] | None = None,
    numpy_kernel: bool = False,
) -> list[dict[str, Any]]:
    """Run every backend on every scenario and horizon; returns the CSV rows.

    Parameters
    ----------
    model : LSTMModel
    scenarios : sequence of BenchScenario
    horizons : sequence of int
    backends : sequence of str, optional
        Backend names or fnmatch patterns (default :func:`available_backends`).
    steps : int
        Samples per run (the first ``steps`` of each scenario).
    slow_steps : int
        Cap for N >= 50 through cvxpy / qpsolvers / sparse DAQP (``subsampled`` = 1).
    time_cap : float
        Wall-time cap per run, s (the run stops early; ``steps`` says how far it got).
    numpy_kernel : bool
        Also run every backend on a twin of the model with the numpy reference kernel
        (``LSTMKernel(compiled=False)``) right after it, and report ``ratio_to_numpy``.
    """
    model = require_model(model)
    expect_real("time_cap", time_cap, low=0.0, low_open=True, hint="a wall time per run, s")
    expect_int("steps", steps, minimum=1)
    expect_int("slow_steps", slow_steps, minimum=1)
    chosen = resolve_backends(backends)
    twin: LSTMModel | None = None
    if numpy_kernel:
        twin = LSTMModel(
            **model.weights(),
            normalization=model.normalization,
            y_phi_constraint=model.y_phi_constraint,
        )
        twin.kernel = LSTMKernel(twin, compiled=False)
    rows: list[dict[str, Any]] = []
    for scenario in scenarios:
        for N in horizons:
            config = replace(scenario.config, N=N)
            cert = certify(model, config.certification_settings(model))
            runs: dict[str, dict[str, Any]] = {}
            group: list[dict[str, Any]] = []
            for backend in chosen:
                n_steps = _steps_for(backend, N, scenario, steps, slow_steps)
                solver, _, family = backend.partition("@")
                row: dict[str, Any] = {c: math.nan for c in CSV_COLUMNS}
                row.update(
                    scenario=scenario.name,
                    N=N,
                    backend=backend,
                    family=family,
                    solver=solver,
                    steps_requested=n_steps,
                    subsampled=int(n_steps < min(steps, scenario.steps)),
                    error="",
                )
                try:
                    run = _run(backend, model, scenario, N, cert, n_steps, time_cap)
                    row.update(_summary(run))
                    row["family"] = run["transcription"]
                    runs[backend] = run
                    if twin is not None:
                        slow = _summary(_run(backend, twin, scenario, N, cert, n_steps, time_cap))
                        row["step_numpy_median_us"] = slow["step_median_us"]
                        row["ratio_to_numpy"] = row["step_median_us"] / slow["step_median_us"]
                except Exception as error:  # a backend failure is a result, not a crash
                    row.update(error=f"{type(error).__name__}: {error}"[:200], steps=0)
                if log is not None:
                    log(
                        f"{scenario.name} N={N} {backend}: {row['steps']} steps, "
                        f"median {row['step_median_us']:.0f} us {row['error']}"
                    )
                group.append(row)
            _compare(group, runs)
            rows.extend(group)
    return rows


def _compare(group: list[dict[str, Any]], runs: dict[str, dict[str, Any]]) -> None:
    """Ratios and differences to the exact NMPC and to the fastest backend (in place)."""
    medians = [r["step_median_us"] for r in group if np.isfinite(r["step_median_us"])]
    fastest = min(medians) if medians else math.nan
    ref = runs.get("ipopt")
    ref_row = next((r for r in group if r["backend"] == "ipopt"), None)
    for row in group:
        row["ratio_to_fastest"] = row["step_median_us"] / fastest
        run = runs.get(row["backend"])
        if ref is None or run is None or ref_row is None:
            continue
        row["ratio_to_nmpc"] = row["step_median_us"] / ref_row["step_median_us"]
        k = min(len(run["u_phi"]), len(ref["u_phi"]))
        if k == 0:
            continue
        diff = np.abs(run["u_phi"][:k] - ref["u_phi"][:k])
        row["u0_diff_max"] = float(np.max(diff))
        row["u0_diff_median"] = float(np.median(diff))
        cost, cost_ref = np.sum(run["stage_cost"][:k]), np.sum(ref["stage_cost"][:k])
        row["cost_diff_pct"] = float(100.0 * (cost - cost_ref) / cost_ref)


# ------------------------------------------------------------------------------ output
_MD_COLUMNS = (
    ("scenario", "scenario"),
    ("N", "N"),
    ("backend", "backend"),
    ("steps", "steps"),
    ("step_median_us", "median µs"),
    ("step_p95_us", "p95 µs"),
    ("step_max_us", "max µs"),
    ("observer_median_us", "obs µs"),
    ("reference_median_us", "ref µs"),
    ("build_median_us", "lin+build µs"),
    ("solve_median_us", "solve µs"),
    ("prepare_median_us", "prepare µs"),
    ("feedback_median_us", "feedback µs"),
    ("overhead_median_us", "step-solve µs"),
    ("ratio_to_numpy", "÷numpy kernel"),
    ("ratio_to_nmpc", "÷NMPC"),
    ("ratio_to_fastest", "÷fastest"),
    ("u0_diff_max", "max |Δu| (mL/s)"),
    ("cost_diff_pct", "Δcost %"),
    ("output_violation_steps", "viol."),
    ("plant_violation_steps", "plant viol."),
    ("infeasible_steps", "infeas."),
    ("fallback_steps", "fallback"),
    ("d_hat_saturated_steps", "d̂ sat."),
    ("setpoint_not_ok_steps", "bad y0"),
    ("iterations_median", "iter."),
    ("status_counts", "status"),
)


def _fmt(value: Any) -> str:
    if isinstance(value, float):
        if math.isnan(value):
            return ""
        if abs(value) >= 100:
            return f"{value:.0f}"
        return f"{value:.3g}"
    return str(value)


def write_outputs(rows: list[dict[str, Any]], out: Path, notes: Sequence[str] = ()) -> None:
    """``bench.csv``, ``bench.md`` and ``bench_N<N>.png`` under ``out``."""
    out.mkdir(parents=True, exist_ok=True)
    with open(out / "bench.csv", "w", newline="") as handle:
        writer = csv.DictWriter(handle, fieldnames=list(CSV_COLUMNS))
        writer.writeheader()
        for row in rows:
            writer.writerow({c: row.get(c, "") for c in CSV_COLUMNS})
    lines = ["# Solver comparison (times in µs; all runs in one process, side by side)", ""]
    lines += [f"- {note}" for note in notes]
    lines += ["", "| " + " | ".join(h for _, h in _MD_COLUMNS) + " |"]
    lines.append("|" + "---|" * len(_MD_COLUMNS))
    for row in rows:
        lines.append("| " + " | ".join(_fmt(row.get(c)) for c, _ in _MD_COLUMNS) + " |")
    (out / "bench.md").write_text("\n".join(lines) + "\n")
    _plots(rows, out)


#: The parts of a controller step in the bench plot, (column, legend label).
_STEP_PARTS = (
    ("observer_median_us", "observer"),
    ("reference_median_us", "reference calculator"),
    ("build_median_us", "linearize + build"),
    ("solve_median_us", "solve"),
)


def _log_floor(values: Sequence[float]) -> float:
    """A power of ten at least 3x below the smallest positive finite value (so that the
    shortest bar of a log axis is visible)."""
    positive = [v for v in values if math.isfinite(v) and v > 0]
    if not positive:
        return 1.0
    return float(10.0 ** math.floor(math.log10(min(positive) / 3.0)))


def bench_figure(rows: Sequence[dict[str, Any]], N: int) -> Figure | None:
    """The figure of ``bench_N<N>.png`` (None when no run of horizon N finished): per
    backend of the first scenario, the median controller step with its p95 (left) and the
    median time of every part of the step (observer, reference calculator, linearize +
    build, solve) as its own bar (right); both axes logarithmic in microseconds with a floor
    below the smallest value, so that a part of a few microseconds shows."""
    from matplotlib.figure import Figure

    sub = [r for r in rows if r["N"] == N and np.isfinite(r["step_median_us"])]
    if not sub:
        return None
    scen = sorted({r["scenario"] for r in sub})
    first = sorted((r for r in sub if r["scenario"] == scen[0]), key=lambda r: r["step_median_us"])
    labels = [r["backend"] for r in first]
    count = len(first)
    fig = Figure(figsize=(13, 0.5 * count + 2.2), layout="constrained")
    axes = fig.subplots(1, 2, sharey=True)
    y = np.arange(count)
    med = np.array([r["step_median_us"] for r in first], dtype=float)
    p95 = np.array([r["step_p95_us"] for r in first], dtype=float)
    floor = _log_floor([*med, *p95])
    axes[0].barh(y, med - floor, left=floor, color="tab:blue", label="median", gid="step")
    axes[0].scatter(p95, y, color="k", marker="|", s=80, label="p95", zorder=3)
    axes[0].set_xscale("log")
    axes[0].set_xlim(floor, 2.0 * float(np.nanmax(np.concatenate([med, p95]))))
    axes[0].set_yticks(y, labels, fontsize=7)
    axes[0].set_xlabel("controller step time (µs, log scale)")
    axes[0].set_title("whole step: median and p95", fontsize=10)
    axes[0].legend(fontsize=7, loc="lower right")
    parts = {
        column: np.array([_number(r.get(column)) for r in first], dtype=float)
        for column, _ in _STEP_PARTS
    }
    floor = _log_floor([v for values in parts.values() for v in values])
    height = 0.8 / len(_STEP_PARTS)
    for index, (column, name) in enumerate(_STEP_PARTS):
        values = parts[column]
        shown = np.where(np.isfinite(values) & (values > floor), values, floor)
        offset = (index - (len(_STEP_PARTS) - 1) / 2) * height
        axes[1].barh(y - offset, shown - floor, left=floor, height=height, color=f"C{index}",
                     label=name, gid=column)  # fmt: skip
    top = max((float(np.nanmax(v)) for v in parts.values() if np.isfinite(v).any()), default=1.0)
    axes[1].set_xscale("log")
    axes[1].set_xlim(floor, 2.0 * top)
    axes[1].set_xlabel("median time per part of the step (µs, log scale)")
    axes[1].set_title("parts of the step, each from the axis floor (not stacked)", fontsize=10)
    axes[1].legend(fontsize=7, loc="best")
    for ax in axes:
        ax.grid(axis="x", which="both", alpha=0.25)
    axes[0].set_ylim(-0.6, count - 0.4)
    steps = sorted({int(r["steps"]) for r in first if r.get("steps") is not None})
    per_run = f", {'/'.join(str(v) for v in steps)} steps per backend" if steps else ""
    fig.suptitle(f"solver comparison: scenario {scen[0]}, N = {N}{per_run}")
    return fig


def _number(value: Any) -> float:
    try:
        return float(value)
    except (TypeError, ValueError):
        return math.nan


def _plots(rows: list[dict[str, Any]], out: Path) -> None:
    for N in sorted({r["N"] for r in rows}):
        fig = bench_figure(rows, N)
        if fig is not None:
            fig.savefig(out / f"bench_N{N}.png", dpi=110)


# ------------------------------------------------------------------- replay subproblems
def save_subproblems(
    model: LSTMModel,
    scenario: BenchScenario,
    directory: Path,
    *,
    N: int = 5,
    count: int = 8,
    steps: int = 120,
    solvers: Sequence[str] | None = None,
) -> Path:
    """Save ``count`` RTI subproblems of one closed loop and every backend's answer.

    Runs the scenario with ``RobustMPC`` (CLARABEL when installed) on the sparse
    transcription, keeps the subproblem it solved at evenly spaced steps
    (:meth:`RobustMPC.last_problem`), saves it with cones (``k<step>_cone.npz``) and in the
    conservative QP form (``k<step>_qp.npz``), solves both with every installed solver and
    writes the numbers to ``replay_reference.csv``.
    """
    from ltv_lstm_mpc.solvers import ConvexProblem, available_solvers, cone_solvers
    from ltv_lstm_mpc.solvers import solve as solve_problem

    directory.mkdir(parents=True, exist_ok=True)
    config = replace(scenario.config, N=N)
    cert = certify(model, config.certification_settings(model))
    cones = cone_solvers()
    solver = cones[0] if cones else "daqp"
    mpc = RobustMPC(
        model, replace(config, solver=solver, transcription="sparse"), certification=cert
    )
    ctrl = OffsetFreeController(
        model, config, setpoint_rate_limit=scenario.setpoint_rate_limit, mpc=mpc
    )
    plant = scenario.make_plant(model)
    y_phi = np.atleast_1d(np.asarray(plant.output(), dtype=np.float64))
    steps = min(steps, scenario.steps)
    picks = set(np.unique(np.linspace(1, steps - 1, count).astype(int)).tolist())
    solved: dict[int, ConvexProblem] = {}
    for k in range(steps):
        u_phi = ctrl.step(y_phi, scenario.setpoints[k])
        if k in picks:
            try:
                solved[k] = mpc.last_problem("nominal")  # what the backend got at step k
            except InvalidValueError:  # not solved at this step (e.g. a pre-check failed)
                pass
        d = scenario.disturbances[k]
        y_phi = np.atleast_1d(np.asarray(plant.step(u_phi, None if np.isnan(d) else d)))
    sub = mpc.subproblem("nominal")
    names = list(solvers) if solvers is not None else available_solvers()
    rows = []
    for k, problem in sorted(solved.items()):
        qp = sub.reformulation.apply(problem)
        files = {"cone": f"k{k:05d}_cone.npz", "qp": f"k{k:05d}_qp.npz"}
        problem.save(directory / files["cone"])
        qp.save(directory / files["qp"])
        for solver in names:
            kind = "cone" if solver in cones else "qp"
            loaded = ConvexProblem.load(directory / files[kind])
            rows.append(_replay_row(solve_problem, loaded, solver, files[kind], sub.layout.u_start))
    meta = {"u_index": int(sub.layout.u_start), "model_n": model.n, "N": N}
    (directory / "replay_meta.json").write_text(json.dumps(meta))
    _write_rows(directory / "replay_reference.csv", rows)
    return directory


def _replay_row(
    solve_problem: Callable[..., Any], problem: Any, solver: str, file: str, u_index: int
) -> dict[str, Any]:
    try:
        sol = solve_problem(problem, solver)
        ok = sol.z is not None
        return {
            "file": file,
            "solver": solver,
            "status": sol.status.name.lower(),
            "u0": float(sol.z[u_index]) if ok else math.nan,
            "objective": float(sol.objective) if ok and sol.objective is not None else math.nan,
            "iterations": int(sol.iterations or 0),
        }
    except Exception as error:
        return {
            "file": file,
            "solver": solver,
            "status": f"error: {type(error).__name__}",
            "u0": math.nan,
            "objective": math.nan,
            "iterations": 0,
        }


_REPLAY_COLUMNS = ("file", "solver", "status", "u0", "objective", "iterations")


def _write_rows(path: Path, rows: list[dict[str, Any]]) -> None:
    with open(path, "w", newline="") as handle:
        writer = csv.DictWriter(handle, fieldnames=list(_REPLAY_COLUMNS))
        writer.writeheader()
        writer.writerows(rows)


def replay(directory: str | Path, *, solvers: Sequence[str] | None = None) -> list[dict[str, Any]]:
    """Re-solve saved subproblems offline with every backend and compare.

    Returns one row per (file, solver): the saved and replayed status, first input and
    objective, their differences, and the spread of the first input across backends
    (``u0_spread``: replayed u0 minus the median over solvers of that file). Writes
    ``replay.csv`` next to the saved files.
    """
    from ltv_lstm_mpc.solvers import ConvexProblem
    from ltv_lstm_mpc.solvers import solve as solve_problem

    directory = expect_path("directory", directory)
    if not directory.is_dir():
        raise FileNotFoundError(
            f"{directory} is not a folder; give the folder written by "
            "`ltv-lstm-mpc bench --save-subproblems DIR`"
        )
    missing = [
        n for n in ("replay_meta.json", "replay_reference.csv") if not (directory / n).is_file()
    ]
    if missing:
        raise InvalidValueError(
            f"{directory} is not a folder of saved subproblems (no {' or '.join(missing)}); "
            "write one with `ltv-lstm-mpc bench --save-subproblems DIR`, then replay DIR"
        )
    meta = json.loads((directory / "replay_meta.json").read_text())
    with open(directory / "replay_reference.csv", newline="") as handle:
        saved = list(csv.DictReader(handle))
    wanted = set(solvers) if solvers is not None else None
    out = []
    for row in saved:
        if wanted is not None and row["solver"] not in wanted:
            continue
        problem = ConvexProblem.load(directory / row["file"])
        new = _replay_row(solve_problem, problem, row["solver"], row["file"], meta["u_index"])
        out.append(
            {
                "file": row["file"],
                "solver": row["solver"],
                "status_saved": row["status"],
                "status_replayed": new["status"],
                "u0_saved": float(row["u0"]),
                "u0_replayed": new["u0"],
                "u0_diff": abs(new["u0"] - float(row["u0"])),
                "objective_diff": abs(new["objective"] - float(row["objective"])),
            }
        )
    for file in {r["file"] for r in out}:
        values = [r["u0_replayed"] for r in out if r["file"] == file]
        centre = float(np.nanmedian(values)) if np.isfinite(values).any() else math.nan
        for r in out:
            if r["file"] == file:
                r["u0_spread"] = r["u0_replayed"] - centre
    if out:
        with open(directory / "replay.csv", "w", newline="") as handle:
            writer = csv.DictWriter(handle, fieldnames=list(out[0]))
            writer.writeheader()
            writer.writerows(out)
    return out


# --------------------------------------------------------------------------------- CLI
def _parser_args(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--model", default="ph_lstm_n5.npz", help="model .npz or shipped name")
    parser.add_argument("--out", type=output_folder, default="bench_results", help="output folder")
    parser.add_argument("--N", type=positive_int, nargs="+", default=[5, 20, 50], help="horizons")
    parser.add_argument(
        "--backends", nargs="+", default=None, help="backend names or patterns (default: all)"
    )
    parser.add_argument("--scenarios", nargs="+", default=None, help="scenario names (patterns)")
    parser.add_argument(
        "--steps",
        type=positive_int,
        default=None,
        help="samples per run (default: 200; with --export-qpbenchmark: each scenario's)",
    )
    parser.add_argument(
        "--slow-steps", type=positive_int, default=60, help="cap for N>=20 via cvxpy/qpsolvers"
    )
    parser.add_argument(
        "--all-scenarios", action="store_true", help="N > 5 on every scenario, not only the first"
    )
    parser.add_argument("--time-cap", type=positive_float, default=60.0, help="wall cap per run, s")
    parser.add_argument(
        "--smoke", action="store_true", help="seconds: 1 scenario, 30 steps, few backends, N=5"
    )
    parser.add_argument(
        "--save-subproblems", metavar="DIR", default=None, help="also save replayable subproblems"
    )
    parser.add_argument(
        "--export-qpbenchmark",
        metavar="DIR",
        default=None,
        help="write the subproblems solved along the closed loops as a qpbenchmark test set "
        "(and the exact-cone ones as CBF) into DIR, for the horizons of --N, instead of the "
        "bench table",
    )
    parser.add_argument(
        "--qpbenchmark-set",
        metavar="DIR",
        default=None,
        help="solve the test set exported into DIR with this library's backends and report "
        "qpbenchmark's metrics (beside qpbenchmark's own results where DIR/results has them)",
    )
    parser.add_argument(
        "--per-kind",
        type=positive_int,
        default=3,
        help="with --export-qpbenchmark: problems of each kind per scenario, horizon and form",
    )
    parser.add_argument("--quiet", action="store_true", help="no per-run log lines")
    parser.add_argument(
        "--numpy-kernel",
        action="store_true",
        help="also run each backend on the numpy reference kernel and report the ratio",
    )


DEFAULT_SCENARIOS = ("1_*", "4_*", "standin*")
#: The backends of ``bench --smoke`` without ``--backends``: those of them installed (DAQP
#: and daqp@sparse on the core install).
SMOKE_BACKENDS = ("ipopt", "daqp", "daqp@sparse", "cvxpy:CLARABEL")


def resolve_backends(backends: Sequence[str] | None) -> list[str]:
    """Backend names from names or fnmatch patterns (``None``: every available backend).

    Raises
    ------
    InvalidValueError
        A pattern that matches no installed backend (the message lists them).
    """
    everything = available_backends()
    if backends is None:
        return everything
    chosen: list[str] = []
    for pat in backends:
        base, _, suffix = pat.partition("@")
        if suffix and suffix not in ("condensed", "sparse"):
            raise InvalidValueError(
                f"backend {pat!r}: the suffix after @ must be condensed or sparse"
            )
        matched = [b for b in everything if fnmatch.fnmatch(b, base)]
        if not matched:
            raise InvalidValueError(
                f"backend {pat!r} matches no installed backend; choose from "
                f"{', '.join(everything)} (optionally with @condensed / @sparse)"
            )
        tail = f"@{suffix}" if suffix else ""
        chosen += [b + tail for b in matched if b + tail not in chosen]
    return chosen


def _main_qpbenchmark(args: argparse.Namespace) -> int:
    """``bench --export-qpbenchmark DIR`` / ``bench --qpbenchmark-set DIR``."""
    from ltv_lstm_mpc.solver_comparison import qpbenchmark_set as qpb

    exporting = args.export_qpbenchmark is not None
    ignored = [
        flag
        for flag, given in (
            ("--backends", args.backends is not None),
            ("--scenarios", args.scenarios is not None),
            ("--smoke", args.smoke),
            ("--all-scenarios", args.all_scenarios),
            ("--numpy-kernel", args.numpy_kernel),
            ("--save-subproblems", args.save_subproblems is not None),
            ("--model", args.model != "ph_lstm_n5.npz"),
            ("--time-cap", args.time_cap != 60.0),
            ("--slow-steps", args.slow_steps != 60),
            ("--out", str(args.out) != "bench_results"),
            ("--N", not exporting and list(args.N) != [5, 20, 50]),
            ("--steps", not exporting and args.steps is not None),
            ("--per-kind", not exporting and args.per_kind != 3),
        )
        if given
    ]
    if ignored:
        raise UsageError(
            f"{', '.join(ignored)}: not used by --export-qpbenchmark / --qpbenchmark-set "
            "(the set's sources are the paper's scenarios and the quadruple tank, its solvers "
            "qpbenchmark's; --N, --steps and --per-kind shape an export); leave them out"
        )
    log = None if args.quiet else (lambda line: print(line, flush=True))
    if args.export_qpbenchmark:
        try:
            folder = Path(args.export_qpbenchmark)
            if folder.exists() and any(folder.iterdir()):
                raise InvalidValueError(
                    f"--export-qpbenchmark {folder}: the folder is not empty; name a new one "
                    "(qpbenchmark skips problems its results file already has)"
                )
        except InvalidValueError as error:
            raise UsageError(str(error)) from None
        import importlib.util

        if importlib.util.find_spec("clarabel") is None:
            raise UsageError(
                "--export-qpbenchmark measures feasibility margins with Clarabel: "
                'pip install -e ".[bench]"'
            )
        modules = qpb.export_test_set(
            folder,
            horizons=args.N,
            per_kind=args.per_kind,
            steps=args.steps,
            log=log,
        )
        print(f"wrote {', '.join(str(m) for m in modules)} (see its README.md)")
    if args.qpbenchmark_set:
        import importlib.util

        if importlib.util.find_spec("qpbenchmark") is None:
            raise UsageError('--qpbenchmark-set needs qpbenchmark: pip install -e ".[bench]"')
        folder = Path(args.qpbenchmark_set)
        if not (folder / "problems.csv").is_file():
            raise UsageError(
                f"{folder} holds no exported test set (no problems.csv); write one with "
                f"`ltv-lstm-mpc bench --export-qpbenchmark {folder}`"
            )
        rows = qpb.qpbenchmark_metrics(folder, log=log)
        paths = qpb.write_metrics(folder, rows)
        print(f"wrote {', '.join(str(p) for p in paths.values())}")
    return 0


def main_bench(args: argparse.Namespace) -> int:
    """``ltv-lstm-mpc bench``."""
    from ltv_lstm_mpc.lstm.shipped import load_model, model_path

    if args.export_qpbenchmark or args.qpbenchmark_set:
        return _main_qpbenchmark(args)
    try:  # usage errors first, before any work
        resolve_backends(args.backends)
    except InvalidValueError as error:
        raise UsageError(str(error)) from None
    model = load_model(model_path(args.model))  # .npz, .onnx or .keras
    scenarios = bench_scenarios(model, short=True)
    patterns = args.scenarios or list(DEFAULT_SCENARIOS)
    names = [s.name for s in scenarios]
    # A pattern is a glob (fnmatch) or, like ``reproduce --only``, a substring of the name.
    scenarios = [
        s for s in scenarios if any(fnmatch.fnmatch(s.name, p) or p in s.name for p in patterns)
    ]
    if not scenarios:
        raise UsageError(f"no scenario matches {patterns}; scenarios: {names}")
    horizons, backends, steps = args.N, args.backends, args.steps or 200
    notes = []
    if args.smoke:
        scenarios, horizons, steps = scenarios[:1], [5], args.steps or 30
        installed = available_backends()
        backends = backends or [b for b in SMOKE_BACKENDS if b.partition("@")[0] in installed]
        notes.append("smoke mode: 1 scenario, N = 5, few backends, first steps only")
    notes.append(
        f"first {steps} samples of each scenario (short variants); N >= 20 through "
        f"cvxpy/qpsolvers/sparse DAQP capped at {args.slow_steps} samples (column subsampled)"
    )
    notes.append(
        "u0_diff and cost_diff compare the closed loops with the exact NMPC sample by "
        "sample; cost = sum of the stage cost ||x_hat - x_bar||_Q^2 + ||u - u_bar||_R^2"
    )
    log = None if args.quiet else (lambda line: print(line, flush=True))
    plan = [(scenarios, [N for N in horizons if N <= 5])]
    if args.all_scenarios:
        plan.append((scenarios, [N for N in horizons if N > 5]))
    else:
        plan.append((scenarios[:1], [N for N in horizons if N > 5]))
        if len(scenarios) > 1 and any(N > 5 for N in horizons):
            notes.append(f"N > 5 on {scenarios[0].name} only (--all-scenarios for all)")
    rows = []
    for group, group_horizons in plan:
        if group_horizons:
            rows += run_bench(
                model,
                scenarios=group,
                horizons=group_horizons,
                backends=backends,
                steps=steps,
                slow_steps=args.slow_steps,
                time_cap=args.time_cap,
                log=log,
                numpy_kernel=args.numpy_kernel,
            )
    out = Path(args.out)
    write_outputs(rows, out, notes)
    if args.save_subproblems:
        save_subproblems(model, scenarios[0], Path(args.save_subproblems), N=horizons[0])
    print(f"wrote {out / 'bench.csv'}, {out / 'bench.md'} and plots")
    return 0


def main_replay(args: argparse.Namespace) -> int:
    """``ltv-lstm-mpc replay DIR``."""
    rows = replay(args.directory, solvers=args.solvers)
    worst = max((r["u0_diff"] for r in rows if np.isfinite(r["u0_diff"])), default=0.0)
    changed = sum(r["status_saved"] != r["status_replayed"] for r in rows)
    print(f"replayed {len(rows)} solves: max |u0 replayed - saved| = {worst:.3e}, ")
    print(f"status changes: {changed}; details in {Path(args.directory) / 'replay.csv'}")
    return 0 if changed == 0 and worst <= 1e-8 else 1


def register(subparsers: Any) -> None:
    """Add the ``bench`` and ``replay`` subcommands to the ``ltv-lstm-mpc`` parser."""
    bench = subparsers.add_parser(
        "bench",
        help="compare every solver backend on the paper's closed loops",
        description=__doc__.split("\n\n")[0] if __doc__ else None,
    )
    _parser_args(bench)
    bench.set_defaults(func=main_bench)
    rep = subparsers.add_parser(
        "replay",
        help="re-solve saved subproblems (.npz) with every backend and compare",
        description=(
            "Re-solve the RTI subproblems saved by `ltv-lstm-mpc bench --save-subproblems DIR` "
            "(each with cones and in the conservative QP form) with every installed solver, "
            "or those of --solvers, and compare with the numbers stored at the time; exit "
            "code 1 where a solution changed."
        ),
    )
    rep.add_argument("directory", help="folder written by bench --save-subproblems")
    rep.add_argument(
        "--solvers", nargs="+", default=None, help="only these solvers (default: every installed)"
    )
    rep.set_defaults(func=main_replay)
