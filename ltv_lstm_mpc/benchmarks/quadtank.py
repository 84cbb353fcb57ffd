r"""The quadruple-tank benchmark (two pumps, two levels): closed-loop scenarios on the true plant.

The offset-free LSTM MPC (paper Fig. 1) runs on Johansson's quadruple-tank process
(:class:`~ltv_lstm_mpc.QuadrupleTankPlant`, minimum-phase parameters, pump
voltages in V, levels in cm, Ts = 10 s) with the shipped (2, 2) delta-ISS LSTM
:data:`QUADTANK_MODEL`. Two scenarios, each on the condensed QP path (``"daqp"``, conservative
terminal box) and on an exact-cone path (``"clarabel"``, condensed with second-order cones):

1. ``1_setpoints`` — set-point changes on both levels (h1, h2 in cm): both up to (14, 14)
   (the high-gain direction); then h2 alone down to (14, 11), which drives the levels apart
   (the low-gain direction: large opposite pump moves, the coupling through the upper tanks
   excited); then one up and one down to (10, 12); then both to (12.3, 12.8).
2. ``2_leak`` — constant set-point and an unmeasured disturbance: a leak opens in tank 1,
   then one in tank 2 as well, then both close (the leak areas are the plant's ``d_phi``).

Every segment is long enough to settle. The summary gives, per output, the offset
:math:`|y_\phi - y^0_\phi|` at the end of every segment, the tolerance
:data:`OFFSET_TOLERANCE_FRACTION` of the level range (the width of the level constraint),
the steps where a measured level leaves the level constraint (zero expected), infeasible
and fallback steps, set-point statuses, :math:`\hat d` saturation and step times. The
schedules are ours (no reference figures exist for this combination), fixed here so that
every run uses the same ones.
"""

from __future__ import annotations

import csv
import json
import time
from collections.abc import Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import NDArray

from ltv_lstm_mpc.benchmarks.benchmark import Benchmark
from ltv_lstm_mpc.exceptions import InvalidValueError
from ltv_lstm_mpc.loop.controller import OffsetFreeController
from ltv_lstm_mpc.loop.schedules import piecewise_constant
from ltv_lstm_mpc.loop.schedules import segments as schedule_segments
from ltv_lstm_mpc.loop.simulation import SimulationResult, simulate
from ltv_lstm_mpc.lstm.model import LSTMModel
from ltv_lstm_mpc.mpc.config import MPCConfig
from ltv_lstm_mpc.plants.quadtank import QUADTANK_TS, QuadrupleTankPlant

if TYPE_CHECKING:
    from matplotlib.figure import Figure

__all__ = [
    "DEFAULT_SOLVERS",
    "OFFSET_TOLERANCE_FRACTION",
    "QUADTANK_BENCHMARK",
    "QUADTANK_CONFIG",
    "QUADTANK_MODEL",
    "QuadTankResult",
    "QuadTankScenario",
    "format_quadtank_report",
    "format_quadtank_table",
    "plot_quadtank",
    "quadtank_figure",
    "quadtank_scenarios",
    "reproduce_quadtank",
    "run_quadtank_scenario",
    "write_quadtank_outputs",
]

FloatArray = NDArray[np.float64]

#: The shipped (2, 2) delta-ISS LSTM of the quadruple tank (``ltv_lstm_mpc/data``).
QUADTANK_MODEL = "quadtank_lstm_n8.npz"
#: The two solver paths every scenario runs on: condensed QP (terminal box) and exact cones.
DEFAULT_SOLVERS: tuple[str, ...] = ("daqp", "clarabel")
#: Offset tolerance at the end of a settled segment, as a fraction of the level range.
OFFSET_TOLERANCE_FRACTION = 1e-3
#: Controller tuning of the benchmark: the paper's values, with L_d = 0.1 (the paper's
#: faster observer of its second plant simulation).
QUADTANK_CONFIG = MPCConfig(L_d=0.1)
#: Largest normalized set-point change per step (as in the pH plant scenarios).
SETPOINT_RATE_LIMIT = 0.01


@dataclass(frozen=True)
class QuadTankScenario:
    """One closed-loop experiment on the quadruple-tank process.

    Attributes
    ----------
    name, title : str
        Identifier and plot title.
    setpoints : ndarray (steps, 2)
        Requested levels :math:`(h_1^0, h_2^0)`, cm, before the rate limiter.
    leaks : ndarray (steps, 2)
        Leak areas of tanks 1 and 2 (the plant's ``d_phi``), cm^2.
    config : MPCConfig
        Controller tuning.
    setpoint_rate_limit : float or None
        Normalized set-point change per step (None: no limiter).
    segments : list of (start, end)
        Constant segments [start, end), each long enough to settle.
    v_initial : (float, float)
        Pump voltages of the initial steady state, V.
    """

    name: str
    title: str
    setpoints: FloatArray
    leaks: FloatArray
    config: MPCConfig
    setpoint_rate_limit: float | None
    segments: list[tuple[int, int]] = field(default_factory=list)
    v_initial: tuple[float, float] = (3.0, 3.0)
    notes: str = ""

    @property
    def steps(self) -> int:
        """Number of samples."""
        return int(self.setpoints.shape[0])

    def make_plant(self, model: LSTMModel) -> QuadrupleTankPlant:
        """A fresh plant at the steady state of ``v_initial`` (Ts from the model file)."""
        plant = QuadrupleTankPlant(Ts=model.Ts if model.Ts is not None else QUADTANK_TS)
        plant.reset(self.v_initial)
        return plant

    def make_controller(
        self, model: LSTMModel, solver: str | None = None, engine: str = "auto"
    ) -> OffsetFreeController:
        """The controller of this scenario (optionally with another solver or engine)."""
        config = self.config if solver is None else replace(self.config, solver=solver)
        return OffsetFreeController(
            model, config, setpoint_rate_limit=self.setpoint_rate_limit, engine=engine
        )


@dataclass(frozen=True)
class QuadTankResult:
    """A scenario's simulation and its summary numbers (see :meth:`summary`)."""

    scenario: QuadTankScenario
    simulation: SimulationResult
    controller: OffsetFreeController
    wall_time_s: float = 0.0

    def level_constraint(self) -> tuple[FloatArray, FloatArray]:
        """The model's stored level constraint (cm), (low, high) per output."""
        constraint = self.controller.model.y_phi_constraint
        if constraint is None:
            raise InvalidValueError(
                "the quadruple-tank model carries no level constraint (y_phi_constraint_min/max)"
            )
        return constraint

    def summary(self) -> dict[str, Any]:
        """Per-output offsets, violations of the level constraint, counts and timings."""
        sim, sc = self.simulation, self.scenario
        low, high = self.level_constraint()
        tolerance = OFFSET_TOLERANCE_FRACTION * (high - low)
        offsets = np.array(
            [np.abs(sim.y_phi[end - 1] - sc.setpoints[end - 1]) for _, end in sc.segments]
        )
        violation = np.maximum(np.maximum(low - sim.y_phi, sim.y_phi - high), 0.0)
        cert = self.controller.certification
        counts = sim.summary_counts()
        interval = cert.y0_interval_phi
        return {
            "name": sc.name,
            "title": sc.title,
            "steps": sc.steps,
            "solver": self.controller.config.solver,
            "transcription": sim.transcription,
            "N": self.controller.config.N,
            "L_d": self.controller.config.L_d,
            "setpoint_rate_limit": sc.setpoint_rate_limit,
            "segment_offsets": offsets.tolist(),
            "final_offset": float(offsets.max()) if offsets.size else None,
            "offset_tolerance": tolerance.tolist(),
            "offset_free": bool(np.all(offsets <= tolerance)),
            "level_constraint": [low.tolist(), high.tolist()],
            "constraint_violation_steps": int(np.sum(violation.max(axis=1) > 0)),
            "max_constraint_violation": float(violation.max()),
            "min_level": sim.y_phi.min(axis=0).tolist(),
            "max_level": sim.y_phi.max(axis=0).tolist(),
            "max_predicted_violation": float(np.max(sim.output_violation)),
            "max_abs_d_hat": np.abs(sim.d_hat).max(axis=0).tolist(),
            "d_max": self.controller.config.d_max,
            "fallback_steps": int(np.sum(sim.policy != "nominal")),
            **counts,
            "median_step_time_s": float(np.median(sim.time_total)),
            "max_step_time_s": float(np.max(sim.time_total)),
            "wall_time_s": self.wall_time_s,
            "rho_o": cert.observer.rho_o,
            "e_inf": cert.tightening.e_inf,
            "y0_interval_phi": None
            if interval is None
            else [interval[0].tolist(), interval[1].tolist()],
        }


def quadtank_scenarios(*, short: bool = False) -> list[QuadTankScenario]:
    """The two scenarios of the benchmark (see the module docstring).

    Parameters
    ----------
    short : bool
        Segments of 120 instead of 300 samples (smoke runs; they may not settle fully).
    """
    length = 120 if short else 300
    setpoint_levels = [(14.0, 14.0), (14.0, 11.0), (10.0, 12.0), (12.3, 12.8)]
    lengths = [length] * len(setpoint_levels)
    leak_setpoint = (12.0, 12.0)
    leak_levels = [(0.0, 0.0), (0.002, 0.0), (0.002, 0.002), (0.0, 0.0)]
    return [
        QuadTankScenario(
            name="1_setpoints",
            title="Quadruple tank: set-point changes on both levels",
            setpoints=piecewise_constant(setpoint_levels, lengths),
            leaks=np.zeros((sum(lengths), 2)),
            config=QUADTANK_CONFIG,
            setpoint_rate_limit=SETPOINT_RATE_LIMIT,
            segments=schedule_segments(lengths),
            notes="both levels up; levels apart (coupling); one level; back (cm)",
        ),
        QuadTankScenario(
            name="2_leak",
            title="Quadruple tank: leaks in tanks 1 and 2 (unmeasured disturbance)",
            setpoints=piecewise_constant([leak_setpoint] * len(leak_levels), lengths),
            leaks=piecewise_constant(leak_levels, lengths),
            config=QUADTANK_CONFIG,
            setpoint_rate_limit=SETPOINT_RATE_LIMIT,
            segments=schedule_segments(lengths),
            notes="leak areas 0.002 cm^2 (about 3 % of the outlets) in tank 1, then tank 2",
        ),
    ]


def run_quadtank_scenario(
    scenario: QuadTankScenario,
    model: LSTMModel,
    *,
    solver: str | None = None,
    progress: bool = False,
    engine: str = "auto",
) -> QuadTankResult:
    """Simulate one scenario on the true plant in closed loop."""
    if model.m != 2 or model.p != 2:
        raise InvalidValueError(
            f"the quadruple tank has two pumps and two measured levels; this model has "
            f"m = {model.m}, p = {model.p} (use {QUADTANK_MODEL} or train one with "
            "`ltv-lstm-mpc train --plant quadtank`)"
        )
    controller = scenario.make_controller(model, solver, engine)
    plant = scenario.make_plant(model)
    start = time.perf_counter()
    result = simulate(
        plant,
        controller,
        scenario.setpoints,
        scenario.leaks,
        scenario.steps,
        progress=progress,
        description=f"{scenario.name} {controller.config.solver}",
    )
    return QuadTankResult(scenario, result, controller, time.perf_counter() - start)


def quadtank_figure(result: QuadTankResult) -> Figure:
    """The figure of :func:`plot_quadtank` (not saved): both levels with set-points, the
    level constraint and clipped set-point markers; both pump voltages with their bounds U;
    the leaks; :math:`\\hat d` with :math:`\\pm d_{max}` (grey bands: FHOCP infeasible).
    Names and units from the plant registry (``"quadtank"``: h1/h2 in cm, v1/v2 in V)."""
    from matplotlib.figure import Figure

    from ltv_lstm_mpc.plotting import (
        OUTPUT_CONSTRAINT_GID,
        bounds_text,
        draw_bounds,
        draw_d_hat,
        draw_inputs,
        fit_ylim,
        legend,
        mark_clipped_setpoints,
        name_of,
        shade_infeasible,
        signal_labels,
        titled,
        unit_of,
    )

    sim, sc = result.simulation, result.scenario
    controller = result.controller
    model = controller.model
    labels = signal_labels("quadtank", model)
    low, high = result.level_constraint()
    k = np.arange(sim.y_phi.shape[0])
    infeasible = ~sim.feasible
    fig = Figure(figsize=(9, 11.5), layout="constrained")
    axes = fig.subplots(5, 1, sharex=True, height_ratios=[2.2, 2.2, 1.6, 1.0, 1.3])
    for ax in axes:
        shade_infeasible(ax, k, infeasible)
        ax.grid(alpha=0.3)
    summary = result.summary()
    y0_used = model.denormalize_y(sim.y0)
    for j in range(2):
        ax = axes[j]
        output, unit = labels.outputs[j], unit_of(labels.outputs[j])
        ax.plot(
            k, sim.y_phi[:, j], color=f"C{j}", lw=1.3, label=f"{name_of(output)} (plant output)"
        )
        ax.plot(k, sc.setpoints[: k.size, j], "k--", lw=0.9, label="set-point (requested)")
        ax.plot(k, y0_used[:, j], color="0.45", lw=0.8, ls=":", label="rate-limited set-point")
        draw_bounds(
            ax, low[j], high[j], label=f"level constraint {bounds_text(low[j], high[j], unit)}",
            gid=OUTPUT_CONSTRAINT_GID,
        )  # fmt: skip
        fit_ylim(ax, sim.y_phi[:, j], low[j], high[j])
        mark_clipped_setpoints(ax, k, sc.setpoints[: k.size, j], unit=unit)
        ax.set_ylabel(output)
        legend(ax, loc="best", ncol=2)
    unit = labels.output_unit
    axes[0].set_title(
        f"{titled(labels.plant, sc.title)} ({summary['solver']}, {summary['transcription']})\n"
        f"final offset {summary['final_offset']:.1e} {unit}, constraint violations "
        f"{summary['constraint_violation_steps']}, infeasible steps {summary['infeasible_steps']}",
        fontsize=10,
    )
    draw_inputs(axes[2], k, sim.u_phi, controller.input_bounds_phi, labels.inputs, ("C2", "C3"))
    for j in range(2):
        axes[3].plot(k, sc.leaks[: k.size, j], color=f"C{j}", lw=1.0, ls="-.",
                     label=f"leak tank {j + 1} (cm\u00b2), unmeasured")  # fmt: skip
    axes[3].set_ylabel("leak area (cm\u00b2)")
    draw_d_hat(axes[4], k, sim.d_hat, labels.outputs, controller.config.d_max)
    for ax in axes[2:]:
        legend(ax, loc="best", ncol=2)
    Ts = model.Ts if model.Ts is not None else QUADTANK_TS
    note = "; grey: FHOCP infeasible" if infeasible.any() else ""
    axes[4].set_xlabel(f"sample k (Ts = {Ts:g} s){note}")
    return fig


def plot_quadtank(result: QuadTankResult, path: Path) -> Path:
    """PNG of :func:`quadtank_figure`."""
    quadtank_figure(result).savefig(path, dpi=100)
    return path


def write_quadtank_outputs(
    result: QuadTankResult, out: Path, *, plot: bool = True
) -> dict[str, Any]:
    """Write ``<name>_<solver>.csv``, ``.json`` and (optionally) ``.png``; return the summary."""
    out.mkdir(parents=True, exist_ok=True)
    sim, sc = result.simulation, result.scenario
    stem = f"{sc.name}_{result.controller.config.solver.replace(':', '_')}"
    y0_used = result.controller.model.denormalize_y(sim.y0)
    with (out / f"{stem}.csv").open("w", newline="") as handle:
        writer = csv.writer(handle)
        writer.writerow(
            ["k", "h1", "h2", "h1_setpoint", "h2_setpoint", "h1_setpoint_used",
             "h2_setpoint_used", "v1", "v2", "leak1", "leak2", "d_hat1", "d_hat2", "feasible",
             "policy", "status", "setpoint_status", "time_total_s"]
        )  # fmt: skip
        for k in range(sim.y_phi.shape[0]):
            writer.writerow(
                [k, *sim.y_phi[k], *sc.setpoints[k], *y0_used[k], *sim.u_phi[k], *sc.leaks[k],
                 *sim.d_hat[k], int(sim.feasible[k]), sim.policy[k], sim.status[k],
                 "" if sim.setpoint_status is None else sim.setpoint_status[k],
                 sim.time_total[k]]
            )  # fmt: skip
    summary = result.summary()
    (out / f"{stem}.json").write_text(json.dumps(summary, indent=2))
    if plot:
        plot_quadtank(result, out / f"{stem}.png")
    return summary


def format_quadtank_table(summaries: Sequence[dict[str, Any]]) -> str:
    """Plain-text table, one row per (scenario, solver): offsets per output in cm."""
    header = (
        f"{'scenario':<12} {'solver':<9} {'steps':>5} {'offset h1':>9} {'offset h2':>9} "
        f"{'tol':>7} {'ok':>3} {'viol':>4} {'infeas':>6} {'d_hat sat':>9} {'median ms':>9} "
        f"{'max ms':>7}"
    )
    lines = [header, "-" * len(header)]
    for s in summaries:
        offsets = np.asarray(s["segment_offsets"]).reshape(-1, 2)
        worst = offsets.max(axis=0)
        lines.append(
            f"{s['name']:<12} {s['solver']:<9} {s['steps']:>5} {worst[0]:>9.1e} {worst[1]:>9.1e} "
            f"{min(s['offset_tolerance']):>7.3f} {'yes' if s['offset_free'] else 'NO':>3} "
            f"{s['constraint_violation_steps']:>4} {s['infeasible_steps']:>6} "
            f"{s.get('d_hat_saturated_steps', 0):>9} {1e3 * s['median_step_time_s']:>9.2f} "
            f"{1e3 * s['max_step_time_s']:>7.1f}"
        )
    return "\n".join(lines)


def _certificate(model: LSTMModel, results: list[QuadTankResult]) -> dict[str, Any]:
    """The certificate numbers of the first run's controller (every path certifies alike)."""
    if not results:
        return {}
    result = results[0]
    cert = result.controller.certification
    return {
        "rho_A_delta": cert.delta_iss.rho_A_delta,
        "rho_s": cert.lyapunov.rho_s,
        "rho_o": cert.observer.rho_o,
        "e_inf": cert.tightening.e_inf,
        "K_bar": cert.K_bar.K_bar,
        "y0_interval_phi": None
        if cert.y0_interval_phi is None
        else [v.tolist() for v in cert.y0_interval_phi],
        "L_d": result.controller.config.L_d,
    }


def format_quadtank_report(report: dict[str, Any]) -> str:
    """The printed report of ``reproduce --benchmark quadtank``: table and certificate."""
    cert = report["certificate"]
    interval = cert["y0_interval_phi"]
    admissible = (
        "set-points -"
        if interval is None
        else "set-points "
        + ", ".join(f"h{j + 1} [{interval[0][j]:.2f}, {interval[1][j]:.2f}] cm" for j in range(2))
    )
    return (
        format_quadtank_table(report["scenarios"])
        + f"\n\nrho_A_delta {cert['rho_A_delta']:.4f}, rho_s {cert['rho_s']:.4f}, rho_o "
        f"{cert['rho_o']:.4f} (L_d = {cert['L_d']}), e_inf {cert['e_inf']:.4g}, admissible "
        + admissible
    )


#: The quadruple-tank benchmark: set-point changes on both levels and a leak, on the
#: condensed (daqp) and exact-cone (clarabel) paths.
QUADTANK_BENCHMARK = Benchmark(
    name="quadtank",
    plant="quadtank",
    model=QUADTANK_MODEL,
    scenarios=lambda model, short: quadtank_scenarios(short=short),
    run=lambda scenario, model, solver, progress, engine: run_quadtank_scenario(
        scenario, model, solver=solver, progress=progress, engine=engine
    ),
    write=lambda result, out, plot: write_quadtank_outputs(result, out, plot=plot),
    certificate_key="certificate",
    certificate=_certificate,
    format_report=format_quadtank_report,
    solvers=DEFAULT_SOLVERS,
)


def reproduce_quadtank(
    model: LSTMModel,
    out: Path | None = None,
    *,
    solvers: Sequence[str] = DEFAULT_SOLVERS,
    only: Sequence[str] | None = None,
    short: bool = False,
    progress: bool = True,
    plot: bool = True,
    model_info: dict[str, Any] | None = None,
) -> dict[str, Any]:
    """Run the benchmark's scenarios on every solver path; optionally write the outputs
    (:meth:`~ltv_lstm_mpc.benchmarks.benchmark.Benchmark.reproduce` of
    :data:`QUADTANK_BENCHMARK`).

    Returns
    -------
    dict
        ``{"scenarios": [summary, ...], "certificate": {...}, "wall_time_s": float}``;
        also written to ``out/summary.json`` when ``out`` is given.
    """
    return QUADTANK_BENCHMARK.reproduce(
        model, out, only=only, solvers=tuple(solvers), short=short, progress=progress,
        plot=plot, model_info=model_info,
    )  # fmt: skip
