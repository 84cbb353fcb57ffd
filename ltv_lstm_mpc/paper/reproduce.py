"""Reproduce the paper's five simulations: plots, CSV/JSON numbers and a summary table.

Used by ``ltv-lstm-mpc reproduce`` / ``ltv-lstm-mpc simulate``. Each scenario writes
``<name>.png`` (output vs set-point with the output constraint, input with its bounds U,
disturbance, and the estimate d_hat, named with units from the plant registry; grey bands
where the FHOCP was infeasible), ``<name>.csv`` (one row per sample) and ``<name>.json``
(its summary); ``summary.json`` collects all summaries and the certificate numbers next to
the paper's.
"""

from __future__ import annotations

import csv
import json
from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from ltv_lstm_mpc.benchmarks.benchmark import Benchmark
from ltv_lstm_mpc.certificates.certify import CertificationSettings, certify
from ltv_lstm_mpc.lstm.model import LSTMModel
from ltv_lstm_mpc.paper.scenarios import (
    Scenario,
    ScenarioResult,
    is_ph_model,
    paper_scenarios,
    run_scenario,
)

if TYPE_CHECKING:
    from matplotlib.figure import Figure

__all__ = [
    "PAPER_BENCHMARK",
    "PAPER_VALUES",
    "certificate_comparison",
    "format_report",
    "plot_scenario",
    "reproduce",
    "scenario_figure",
    "write_scenario_outputs",
]

#: Numbers the paper reports (Section V) for its own trained model.
PAPER_VALUES: dict[str, Any] = {
    "FIT_test_percent": 94.0,
    "rho_s": 0.92,
    "L_d=0.01": {"rho_o": 0.99, "L_max": 8.4e-4, "w_max": 4.3e-5, "e_inf": 1.04, "K_bar": 2.67,
                 "y0_interval_phi": [6.49, 8.51]},
    "L_d=0.1": {"rho_o": 0.97, "L_max": 8.5e-3, "e_inf": 0.38, "y0_interval_phi": [6.57, 8.43]},
}  # fmt: skip


def certificate_comparison(model: LSTMModel) -> dict[str, Any]:
    """Our certificate numbers for ``model`` next to the paper's, for L_d = 0.01 and 0.1.

    The paper's numbers belong to its pH model: for a model that is not a pH model
    (:func:`~ltv_lstm_mpc.paper.scenarios.is_ph_model`) ``"paper"`` is None (nothing to
    compare with) and ``"output_unit"`` names the unit of ``y0_interval_phi``.
    """
    from ltv_lstm_mpc.plotting import signal_labels

    ours: dict[str, Any] = {}
    for l_d in (0.01, 0.1):
        cert = certify(model, CertificationSettings(l_d=l_d))
        interval = cert.y0_interval_phi
        ours[f"L_d={l_d}"] = {
            "rho_A_delta": cert.delta_iss.rho_A_delta,
            "rho_s": cert.lyapunov.rho_s,
            "rho_o": cert.observer.rho_o,
            "L_max": cert.observer.L_max,
            "w_max": cert.observer.w_max,
            "e_inf": cert.tightening.e_inf,
            "K_bar": cert.K_bar.K_bar,
            "delta_y0_max": cert.rate_bound.delta_y0_max if cert.rate_bound.holds else None,
            "y0_interval_phi": None if interval is None else [float(v[0]) for v in interval],
        }
    ph = is_ph_model(model)
    return {
        "ours": ours,
        "paper": PAPER_VALUES if ph else None,
        "output_unit": "pH" if ph else signal_labels("lstm", model).output_unit,
    }


def scenario_figure(result: ScenarioResult) -> Figure:
    """The figure of :func:`plot_scenario` (not saved): output with set-point, output
    constraint and clipped set-point markers; input with its bounds U; the plant's
    disturbance; the disturbance estimate :math:`\\hat d` with :math:`\\pm d_{max}`.
    Names and units from the plant registry (:func:`ltv_lstm_mpc.plotting.signal_labels`)."""
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
    labels = signal_labels(sc.plant, model)
    output, unit = labels.outputs[0], unit_of(labels.outputs[0])
    k = np.arange(sim.y_phi.shape[0])
    infeasible = ~sim.feasible
    fig = Figure(figsize=(8.5, 9.0), layout="constrained")
    axes = fig.subplots(4, 1, sharex=True, height_ratios=[3, 1.5, 1.1, 1.3])
    for ax in axes:
        shade_infeasible(ax, k, infeasible)
        ax.grid(alpha=0.3)
    ax = axes[0]
    y = sim.y_phi[:, 0]
    ax.plot(k, y, color="tab:blue", lw=1.3, label=f"{name_of(output)} (plant output)")
    ax.plot(k, sc.setpoints[: k.size], "k--", lw=1.0, label="set-point (requested)")
    if sc.setpoint_rate_limit is not None:
        ax.plot(
            k,
            model.denormalize_y(sim.y0[:, 0]),
            color="0.4",
            lw=0.8,
            ls=":",
            label="rate-limited set-point",
        )
    constraint = result.output_constraint
    if constraint is not None:
        draw_bounds(
            ax,
            *constraint,
            label=f"output constraint {bounds_text(*constraint, unit)}",
            gid=OUTPUT_CONSTRAINT_GID,
        )
    fit_ylim(ax, y, *(constraint or ()))
    mark_clipped_setpoints(ax, k, sc.setpoints, unit=unit)
    ax.set_ylabel(output)
    legend(ax, loc="best", ncol=2)
    summary = result.summary()
    offset = summary["final_offset"]
    title = titled(labels.plant, sc.title)
    solver = controller.config.solver
    settings = "" if solver in title else f"{solver}: "
    violation = summary["max_output_violation"]
    ax.set_title(
        f"{title}\n{settings}infeasible steps {summary['infeasible_steps']}, max violation "
        + ("- (no output constraint)" if violation is None else f"{violation:.2g} {unit}")
        + ", final offset "
        + ("-" if offset is None else f"{offset:.1e} {unit}"),
        fontsize=10,
    )
    ax = axes[1]
    draw_inputs(ax, k, sim.u_phi, controller.input_bounds_phi, labels.inputs, ("tab:green",))
    legend(ax, loc="best", ncol=2)
    ax = axes[2]
    if np.all(np.isnan(sc.disturbances)):
        ax.text(
            0.5,
            0.5,
            "the plant's own default disturbance",
            transform=ax.transAxes,
            ha="center",
            va="center",
            fontsize=8,
        )
    else:
        ax.plot(
            k,
            sc.disturbances[: k.size],
            color="tab:orange",
            ls="-.",
            lw=1.2,
            label=f"{labels.disturbance}, unmeasured",
        )
    disturbance = labels.disturbance
    ax.set_ylabel(disturbance if len(disturbance) <= 22 else unit_of(disturbance))
    legend(ax, loc="best")
    ax = axes[3]
    draw_d_hat(ax, k, sim.d_hat, labels.outputs, controller.config.d_max)
    legend(ax, loc="best", ncol=2)
    Ts = model.Ts
    note = "; grey: FHOCP infeasible" if infeasible.any() else ""
    ax.set_xlabel(f"sample k{f' (Ts = {Ts:g} s)' if Ts else ''}{note}")
    return fig


def plot_scenario(result: ScenarioResult, path: Path) -> Path:
    """PNG like the paper's figures (see :func:`scenario_figure`)."""
    scenario_figure(result).savefig(path, dpi=110)
    return path


def write_scenario_outputs(
    result: ScenarioResult, out: Path, *, plot: bool = True
) -> dict[str, Any]:
    """Write ``<name>.csv``, ``<name>.json`` and (optionally) ``<name>.png``; return the summary."""
    out.mkdir(parents=True, exist_ok=True)
    sim, sc = result.simulation, result.scenario
    name = sc.name
    columns = {
        "k": np.arange(sc.steps),
        "y_phi": sim.y_phi[:, 0],
        "y0_phi": sc.setpoints,
        "y0_used": result.controller.model.denormalize_y(sim.y0[:, 0]),
        "u_phi": sim.u_phi[:, 0],
        "disturbance": sc.disturbances,
        "d_hat": sim.d_hat[:, 0],
        "e_hat": sim.e_hat,
        "alpha": sim.alpha,
        "feasible": sim.feasible.astype(int),
        "policy": sim.policy,
        "status": sim.status,
        "predicted_violation": sim.output_violation,
        "guarantee": sim.guarantee if sim.guarantee is not None else np.full(sc.steps, ""),
        "time_observer_s": sim.time_observer,
        "time_reference_s": sim.time_reference,
        "time_mpc_s": sim.time_mpc,
        "plant_violation": sim.plant_violation
        if sim.plant_violation is not None
        else np.full(sc.steps, np.nan),
    }
    with (out / f"{name}.csv").open("w", newline="") as handle:
        writer = csv.writer(handle)
        writer.writerow(columns)
        writer.writerows(zip(*columns.values(), strict=True))
    summary = result.summary()
    (out / f"{name}.json").write_text(json.dumps(summary, indent=2))
    if plot:
        plot_scenario(result, out / f"{name}.png")
    return summary


def format_table(summaries: Sequence[dict[str, Any]]) -> str:
    r"""Plain-text summary table, one row per scenario.

    ``segment offsets`` is :math:`|y_\phi - y^0_\phi|` (the plant's output unit,
    ``output_unit`` of the summaries) at the end of each constant segment; ``final offset``
    is their maximum; ``max viol`` the largest violation of the output constraint by the
    plant (``-``: no constraint stated). ``d_hat sat`` counts the steps with
    :math:`|\hat d| = d_{max}`, ``bad y0`` those whose set-point was not ``ok``
    (outside the admissible interval or unreachable). ``held`` counts the steps where
    Theorem 3's guarantee held (:mod:`ltv_lstm_mpc.loop.monitor`) and ``viol|held`` the
    steps among them where the plant violated its output constraint (Theorem 3 excludes
    them where its hypotheses hold; the monitor sees those through the estimates).
    """
    header = (
        f"{'scenario':<16} {'steps':>5} {'final offset':>12} {'max viol':>8} {'infeas':>6} "
        f"{'fallback':>8} {'d_hat sat':>9} {'bad y0':>6} {'held':>5} {'viol|held':>9} "
        f"{'median ms':>9} {'max ms':>7}  segment offsets ({_common_unit(summaries)})"
    )
    lines = [header, "-" * len(header)]
    for s in summaries:
        offset = "-" if s["final_offset"] is None else f"{s['final_offset']:.1e}"
        violation = s["max_output_violation"]
        violation_shown = "-" if violation is None else f"{violation:.2g}"
        segments = " ".join(f"{o:.1e}" for o in s["segment_offsets"])
        bad_y0 = s["steps"] - s.get("setpoint_ok_steps", s["steps"])
        lines.append(
            f"{s['name']:<16} {s['steps']:>5} {offset:>12} {violation_shown:>8} "
            f"{s['infeasible_steps']:>6} {s['fallback_steps']:>8} "
            f"{s.get('d_hat_saturated_steps', 0):>9} {bad_y0:>6} "
            f"{s.get('guarantee_held_steps', '-'):>5} "
            f"{s.get('plant_violation_steps_guarantee_held', '-'):>9} "
            f"{1e3 * s['median_step_time_s']:>9.2f} {1e3 * s['max_step_time_s']:>7.1f}  {segments}"
        )
    return "\n".join(lines)


def _common_unit(summaries: Sequence[dict[str, Any]]) -> str:
    """The output unit shared by the summaries (``output_unit``), else ``"output units"``."""
    units = {s.get("output_unit") or "output units" for s in summaries}
    return units.pop() if len(units) == 1 else "output units"


def format_certificates(comparison: dict[str, Any]) -> str:
    """Certificate numbers of the model next to the paper's (the paper's column only for a
    pH model; ``y0_interval_phi`` in the model's output unit)."""
    papers = comparison.get("paper")
    unit = comparison.get("output_unit")
    lines = [f"{'certificate':<22} {'ours':>22} {'paper':>16}"]
    if papers is None:
        lines = [
            f"{'certificate':<22} {'ours':>22}   (the paper's values belong to its own model: "
            "not compared)"
        ]
    for key in ("L_d=0.01", "L_d=0.1"):
        ours = comparison["ours"][key]
        paper = {} if papers is None else papers[key]
        for name in ("rho_o", "L_max", "w_max", "e_inf", "K_bar", "y0_interval_phi"):
            value = ours[name]
            if value is None:
                shown = "- (empty)" if name == "y0_interval_phi" else "-"
            elif isinstance(value, list):
                shown = f"[{value[0]:.4g}, {value[1]:.4g}]" if papers is None else (
                    f"[{value[0]:.2f}, {value[1]:.2f}]"
                )  # fmt: skip
            else:
                shown = f"{value:.3g}"
            ref = paper.get(name)
            ref_shown = "-" if ref is None else (
                f"[{ref[0]:.2f}, {ref[1]:.2f}]" if isinstance(ref, list) else f"{ref:.3g}"
            )  # fmt: skip
            if papers is None:
                if name == "y0_interval_phi" and unit:
                    shown = f"{shown} {unit}"
                lines.append(f"{key + ' ' + name:<22} {shown:>22}")
            else:
                lines.append(f"{key + ' ' + name:<22} {shown:>22} {ref_shown:>16}")
    rho_s = comparison["ours"]["L_d=0.01"]["rho_s"]
    if papers is None:
        lines.append(f"{'rho_s (Q_s = 1000 I)':<22} {rho_s:>22.3g}")
    else:
        lines.append(f"{'rho_s (Q_s = 1000 I)':<22} {rho_s:>22.3g} {papers['rho_s']:>16.3g}")
    return "\n".join(lines)


def _run(
    scenario: Scenario, model: LSTMModel, solver: str | None, progress: bool, engine: str
) -> Any:
    return run_scenario(scenario, model, solver=solver, progress=progress, engine=engine)


def _write(result: ScenarioResult, out: Path, plot: bool) -> dict[str, Any]:
    return write_scenario_outputs(result, out, plot=plot)


def format_report(report: dict[str, Any]) -> str:
    """The printed report of ``reproduce``: the scenario table and the certificates."""
    return format_table(report["scenarios"]) + "\n\n" + format_certificates(report["certificates"])


#: The paper's five closed loops of Section V on the pH plant and its LSTM (Fig. 1, Fig. 2).
PAPER_BENCHMARK = Benchmark(
    name="paper",
    plant="ph",
    model="ph_lstm_n5.npz",
    scenarios=lambda model, short: paper_scenarios(model, short=short),
    run=_run,
    write=_write,
    certificate_key="certificates",
    certificate=lambda model, results: certificate_comparison(model),
    format_report=format_report,
)


def reproduce(
    model: LSTMModel,
    out: Path | None = None,
    *,
    only: Sequence[str] | None = None,
    solver: str | None = None,
    short: bool = False,
    progress: bool = True,
    plot: bool = True,
    model_info: dict[str, Any] | None = None,
    engine: str = "auto",
) -> dict[str, Any]:
    """Run the paper's scenarios (all, or those whose name contains one of ``only``):
    :meth:`~ltv_lstm_mpc.benchmarks.benchmark.Benchmark.reproduce` of
    :data:`PAPER_BENCHMARK`.

    Returns
    -------
    dict
        ``{"scenarios": [summary, ...], "certificates": {...}, "wall_time_s": float}``;
        also written to ``out/summary.json`` when ``out`` is given.
    """
    return PAPER_BENCHMARK.reproduce(
        model, out, only=only, solvers=(solver,), short=short, progress=progress, plot=plot,
        model_info=model_info, engine=engine,
    )  # fmt: skip
