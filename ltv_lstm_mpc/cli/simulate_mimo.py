"""``ltv-lstm-mpc simulate`` for multi-output models (m = p > 1).

The pH plant is single-input single-output, so a MIMO model runs on its own LSTM plant
(Fig. 2) with an output disturbance per output, or on a plant given by the caller (the
quadruple-tank process of ``--plant quadtank``, whose disturbances are the leak areas of
tanks 1 and 2). Set-points and disturbances are given
per segment, one comma-separated value per output (``--setpoints 0.2,0.1 0.3,0.0``), in
the model's physical output units. The summary gives, per output, the offset at the end
of every segment, the violations of the model's output constraint by the plant output,
and the set-point / saturation / infeasibility counts.
"""

from __future__ import annotations

import csv
import json
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import NDArray

from ltv_lstm_mpc.command_arguments import UsageError
from ltv_lstm_mpc.loop.controller import OffsetFreeController
from ltv_lstm_mpc.loop.simulation import SimulationResult, output_constraint, simulate
from ltv_lstm_mpc.lstm.model import LSTMModel
from ltv_lstm_mpc.mpc.config import MPCConfig
from ltv_lstm_mpc.plants.lstm_plant import LSTMPlant
from ltv_lstm_mpc.plants.protocol import Plant

if TYPE_CHECKING:
    from matplotlib.figure import Figure

__all__ = ["mimo_figure", "parse_vectors", "run_mimo"]

FloatArray = NDArray[np.float64]


def _is_number(text: str) -> bool:
    try:
        float(text)
    except ValueError:
        return False
    return True


def parse_vectors(name: str, tokens: list[str], size: int, *, repeat: bool = True) -> FloatArray:
    """``["a,b", "c,d"]`` -> array (segments, size).

    With ``repeat`` one number stands for the same value on every entry (a disturbance
    of 0 on every output); without it every token needs ``size`` values (set-points:
    one per output, ``--setpoints 14`` for two levels is refused, not guessed).
    """
    rows = []
    what = "one number" if size == 1 else f"{size} comma-separated numbers (one per output)"
    for number, token in enumerate(tokens, start=1):
        parts = [part for part in str(token).split(",") if part.strip()]
        try:
            values = [float(part) for part in parts]
        except ValueError:
            bad = next(part for part in parts if not _is_number(part)) if parts else token
            raise UsageError(
                f"{name}: {bad.strip()!r} (segment {number}) is not a number; give {what} "
                "per segment, in the output's physical units"
            ) from None
        if len(values) == 1 and repeat:
            values = values * size
        if len(values) != size:
            raise UsageError(
                f"{name}: {token!r} needs {size} finite value{'s' if size > 1 else ''} (one per "
                f"output), got {len(values)} (segment {number})"
            )
        if not np.all(np.isfinite(values)):
            raise UsageError(
                f"{name}: {token!r} (segment {number}) is not finite; give {what} per segment"
            )
        rows.append(values)
    return np.array(rows, dtype=np.float64)


def run_mimo(
    model: LSTMModel,
    config: MPCConfig,
    setpoint_tokens: list[str],
    disturbance_tokens: list[str] | None,
    segment: int,
    rate_limit: float | None,
    out: Path | None,
    progress: bool,
    *,
    plant: Plant | None = None,
    labels: tuple[tuple[str, ...], tuple[str, ...]] = ((), ()),
    title: str = "",
    check_sampling_time: bool = True,
) -> tuple[dict[str, Any], SimulationResult]:
    """Run the MIMO closed loop; returns (summary, simulation).

    ``plant`` defaults to the model's own :class:`LSTMPlant`; another plant is used as
    given (reset it first) and its disturbance has ``plant.disturbance_size`` entries per
    segment (default: p). ``labels`` = (input labels, output labels) with units for the
    plot (the plant registry's; empty: ``u_0``, ``y_0``, ...), ``title`` its title;
    ``check_sampling_time``: as :func:`~ltv_lstm_mpc.simulate`'s.
    """
    p = model.p
    size = None if plant is None else getattr(plant, "disturbance_size", None)
    q = p if size is None else int(size)
    setpoints = parse_vectors("--setpoints", setpoint_tokens, p, repeat=False)
    segments = setpoints.shape[0]
    if disturbance_tokens:
        disturbances = parse_vectors("--disturbances", disturbance_tokens, q)
    else:
        disturbances = np.zeros((segments, q))
    if disturbances.shape[0] != segments:
        raise UsageError(
            f"give one disturbance per set-point segment: {segments} set-points, "
            f"{disturbances.shape[0]} disturbances"
        )
    controller = OffsetFreeController(model, config, setpoint_rate_limit=rate_limit)
    plant = LSTMPlant(model) if plant is None else plant
    y0_schedule = np.repeat(setpoints, segment, axis=0)
    d_schedule = np.repeat(disturbances, segment, axis=0)
    steps = segments * segment
    sim = simulate(
        plant,
        controller,
        y0_schedule,
        d_schedule,
        steps,
        progress=progress,
        description="MIMO",
        check_sampling_time=check_sampling_time,
    )
    ends = [segment * (k + 1) - 1 for k in range(segments)]
    offsets = np.abs(sim.y_phi[ends] - y0_schedule[ends])  # (segments, p)
    summary: dict[str, Any] = {
        "outputs": p,
        "steps": steps,
        "solver": config.solver,
        "N": config.N,
        "segment_offsets": offsets.tolist(),
        "final_offset": float(offsets.max()),
        **sim.summary_counts(),
        "median_step_time_s": float(np.median(sim.time_total)),
    }
    constraint = output_constraint(plant, model)  # the same as sim.plant_violation's
    violation = sim.plant_violation
    if constraint is not None and violation is not None:
        summary["output_constraint"] = [constraint[0].tolist(), constraint[1].tolist()]
        summary["constraint_violation_steps"] = int(np.sum(violation > 1e-9))
        summary["max_constraint_violation"] = float(np.max(violation, initial=0.0))
    if out is not None:
        _write(out, sim, y0_schedule, d_schedule, summary)
        bounds = controller.input_bounds_phi
        _plot(out / "simulate.png", sim, y0_schedule, model, bounds, labels, title,
              config.d_max, constraint)  # fmt: skip
    return summary, sim


def _write(
    out: Path,
    sim: SimulationResult,
    y0: FloatArray,
    d: FloatArray,
    summary: dict[str, Any],
) -> None:
    out.mkdir(parents=True, exist_ok=True)
    p, m = sim.y_phi.shape[1], sim.u_phi.shape[1]
    header = ["k"]
    header += [f"y_phi_{j}" for j in range(p)] + [f"y0_phi_{j}" for j in range(p)]
    header += [f"u_phi_{j}" for j in range(m)] + [f"d_phi_{j}" for j in range(d.shape[1])]
    header += [f"d_hat_{j}" for j in range(p)] + ["setpoint_status", "status", "policy"]
    with (out / "simulate.csv").open("w", newline="") as handle:
        writer = csv.writer(handle)
        writer.writerow(header)
        for k in range(sim.y_phi.shape[0]):
            status = sim.setpoint_status[k] if sim.setpoint_status is not None else ""
            signals = [*sim.y_phi[k], *y0[k], *sim.u_phi[k], *d[k], *sim.d_hat[k]]
            writer.writerow([k, *signals, status, sim.status[k], sim.policy[k]])
    (out / "simulate.json").write_text(json.dumps(summary, indent=2))


def _plot(
    path: Path,
    sim: SimulationResult,
    y0: FloatArray,
    model: LSTMModel,
    input_bounds: tuple[FloatArray, FloatArray],
    labels: tuple[tuple[str, ...], tuple[str, ...]],
    title: str,
    d_max: float | None = None,
    constraint: tuple[FloatArray, FloatArray] | None = None,
) -> None:
    """Save :func:`mimo_figure` as a PNG."""
    mimo_figure(sim, y0, model, input_bounds, labels, title, d_max, constraint).savefig(
        path, dpi=110
    )


def mimo_figure(
    sim: SimulationResult,
    y0: FloatArray,
    model: LSTMModel,
    input_bounds: tuple[FloatArray, FloatArray],
    labels: tuple[tuple[str, ...], tuple[str, ...]],
    title: str,
    d_max: float | None = None,
    constraint: tuple[FloatArray, FloatArray] | None = None,
) -> Figure:
    """Outputs with set-points (a marker at the axis edge where one lies outside the plotted
    range) and the output constraint, inputs with their bounds U, and the disturbance
    estimate with +-``d_max``, against time; signals named with units where the plant
    states them (``labels`` = (input labels, output labels)). ``constraint``: the output
    constraint the violations were measured against (default: the model's)."""
    from matplotlib.figure import Figure

    from ltv_lstm_mpc.plotting import (
        OUTPUT_CONSTRAINT_GID,
        axis_label,
        bounds_text,
        draw_bounds,
        draw_d_hat,
        draw_inputs,
        fit_ylim,
        legend,
        mark_clipped_setpoints,
        name_of,
        unit_of,
    )

    p, m = sim.y_phi.shape[1], sim.u_phi.shape[1]
    inputs = labels[0] if len(labels[0]) == m else tuple(f"u_{j}" for j in range(m))
    outputs = labels[1] if len(labels[1]) == p else tuple(f"y_{j}" for j in range(p))
    Ts = model.Ts
    samples = np.arange(sim.y_phi.shape[0])
    t, unit = (samples * Ts / 60.0, "time (min)") if Ts else (samples, "sample k")
    fig = Figure(figsize=(9, 9), layout="constrained")
    axes = fig.subplots(3, 1, sharex=True)
    if constraint is None:
        constraint = model.y_phi_constraint
    for j in range(p):
        axes[0].plot(t, sim.y_phi[:, j], color=f"C{j}", label=outputs[j])
        axes[0].plot(t, y0[: samples.size, j], "--", color=f"C{j}", alpha=0.7,
                     label=f"set-point {name_of(outputs[j])}")  # fmt: skip
    if constraint is not None:
        output_unit = unit_of(outputs[0]) if len({unit_of(o) for o in outputs}) == 1 else ""
        low, high = (np.broadcast_to(np.asarray(v, dtype=float), (p,)) for v in constraint)
        draw_bounds(axes[0], low, high, gid=OUTPUT_CONSTRAINT_GID,
                    label=f"output constraint {bounds_text(low, high, output_unit)}")  # fmt: skip
    fit_ylim(axes[0], sim.y_phi, *(constraint or ()))
    for j in range(p):
        mark_clipped_setpoints(axes[0], t, y0[: samples.size, j], unit=unit_of(outputs[j]),
                               color=f"C{j}", label=f"set-point {name_of(outputs[j])} outside "
                               "the plotted range")  # fmt: skip
    axes[0].set_ylabel(axis_label(outputs))
    draw_inputs(axes[1], t, sim.u_phi, input_bounds, inputs)  # U: the controller's
    draw_d_hat(axes[2], t, sim.d_hat, outputs, d_max)
    panels = ("outputs, set-points and the output constraint", "inputs and their bounds U",
              "disturbance estimate $\\hat d$ (normalized output units)")  # fmt: skip
    for ax, panel in zip(axes, panels, strict=True):
        ax.set_title(panel, fontsize=10)
        legend(ax, loc="best", fontsize=8)
        ax.grid(alpha=0.3)
    axes[-1].set_xlabel(unit)
    if title:
        fig.suptitle(title)
    return fig
