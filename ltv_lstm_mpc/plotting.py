"""Shared pieces of the library's plots: signal names with units, bounds, clipped set-points.

Every closed-loop plot (``simulate``, ``reproduce``, the quadruple-tank benchmark) names its
signals with units from the plant registry (:mod:`ltv_lstm_mpc.plants.registry`: pH and q3
in mL/s for the pH plant, h1/h2 in cm and v1/v2 in V for the quadruple tank), draws the
output constraint and the input bounds U as horizontal lines, labels the disturbance
estimate :math:`\\hat d` (normalized output units) and marks a set-point that lies outside
the plotted range with a triangle at the axis edge, annotated with its value.

The artists these helpers draw carry a ``gid`` (:data:`OUTPUT_CONSTRAINT_GID`,
:data:`INPUT_BOUND_GID`, :data:`CLIPPED_SETPOINT_GID`, :data:`D_MAX_GID`), so tests and
readers of a saved SVG can find them. matplotlib is imported only by the functions that
draw (``import ltv_lstm_mpc`` stays light).
"""

from __future__ import annotations

import re
from collections.abc import Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

if TYPE_CHECKING:
    from matplotlib.axes import Axes
    from matplotlib.lines import Line2D

    from ltv_lstm_mpc.lstm.model import LSTMModel
    from ltv_lstm_mpc.plants.registry import RegisteredPlant

__all__ = [
    "CLIPPED_SETPOINT_GID",
    "D_MAX_GID",
    "INPUT_BOUND_GID",
    "OUTPUT_CONSTRAINT_GID",
    "SignalLabels",
    "axis_label",
    "bounds_text",
    "draw_bounds",
    "draw_d_hat",
    "fit_ylim",
    "legend",
    "mark_clipped_setpoints",
    "name_of",
    "shade_infeasible",
    "signal_labels",
    "titled",
    "unit_of",
]

#: ``gid`` of the output-constraint lines.
OUTPUT_CONSTRAINT_GID = "output-constraint"
#: ``gid`` of the input-bound (U) lines.
INPUT_BOUND_GID = "input-bound"
#: ``gid`` of the markers of set-points outside the plotted range.
CLIPPED_SETPOINT_GID = "clipped-setpoint"
#: ``gid`` of the +-d_max lines of the disturbance-estimate panel.
D_MAX_GID = "d-max"
#: At most this many clipped set-point markers per axis (a ramp could make hundreds).
MAX_CLIPPED_MARKERS = 12

FloatArray = NDArray[np.float64]


def unit_of(label: str) -> str:
    """The unit of a label: ``"h1 (cm)"`` -> ``"cm"``, ``"pH"`` -> ``"pH"`` (a label without
    parentheses is its own unit, as the pH is)."""
    if "(" in label and label.rstrip().endswith(")"):
        return label[label.rfind("(") + 1 : label.rstrip().rfind(")")]
    return label


def name_of(label: str) -> str:
    """The signal name of a label: ``"h1 (cm)"`` -> ``"h1"``, ``"pH"`` -> ``"pH"``."""
    if "(" in label and label.rstrip().endswith(")"):
        return label[: label.rfind("(")].strip()
    return label


def axis_label(labels: Sequence[str]) -> str:
    """A y-axis label for the signals of one panel: ``("h1 (cm)", "h2 (cm)")`` ->
    ``"h1, h2 (cm)"``, ``("pH",)`` -> ``"pH"``; different units are listed label by label."""
    labels = tuple(labels)
    if len(labels) == 1:
        return labels[0]
    units = {unit_of(label) for label in labels}
    if len(units) == 1:
        unit = units.pop()
        names = [name_of(label) for label in labels]
        return unit if all(name == unit for name in names) else f"{', '.join(names)} ({unit})"
    return "; ".join(labels)


@dataclass(frozen=True)
class SignalLabels:
    """Names with units of a plant's signals, for plots.

    Attributes
    ----------
    inputs, outputs : tuple of str
        One label per input / output, ``"name (unit)"`` or a bare unit (``"pH"``).
    disturbance : str
        The plant's disturbance ``d_phi`` with its unit (``"buffer flow q2 (mL/s)"``).
    plant : str
        The plant in a few words (``"pH plant"``).
    """

    inputs: tuple[str, ...]
    outputs: tuple[str, ...]
    disturbance: str
    plant: str

    @property
    def output_unit(self) -> str:
        """The outputs' common unit, or ``"output units"`` when they differ."""
        units = {unit_of(label) for label in self.outputs}
        return units.pop() if len(units) == 1 else "output units"


def signal_labels(plant: str | None, model: LSTMModel) -> SignalLabels:
    """Labels of the signals of ``plant`` (a registry name) controlled with ``model``.

    A plant that states no labels of the model's sizes (the LSTM plant of Fig. 2 is the
    model itself) takes those of the registered plant whose default model *is* this model
    (same weights and normalization: the shipped pH model on the LSTM plant is labelled pH
    and q3 in mL/s); otherwise generic names (``y (output units)``, ``u_0 (input units)``,
    ...), never another plant's units.
    """
    m, p = model.m, model.p
    entry = _entry(plant)
    inputs: tuple[str, ...] = () if entry is None else entry.input_labels
    outputs: tuple[str, ...] = () if entry is None else entry.output_labels
    if (len(inputs), len(outputs)) != (m, p):
        from ltv_lstm_mpc.plants.registry import plant_of_model

        twin = plant_of_model(model)
        inputs, outputs = ((), ()) if twin is None else (twin.input_labels, twin.output_labels)
    if len(inputs) != m:
        inputs = ("u (input units)",) if m == 1 else tuple(f"u_{j} (input units)" for j in range(m))
    if len(outputs) != p:
        outputs = (
            ("y (output units)",) if p == 1 else tuple(f"y_{j} (output units)" for j in range(p))
        )
    units = {unit_of(label) for label in outputs}
    output_unit = units.pop() if len(units) == 1 else "output units"
    if entry is None:
        return SignalLabels(inputs, outputs, "disturbance d_phi", plant or "plant")
    return SignalLabels(
        inputs,
        outputs,
        _disturbance_label(entry.disturbance, output_unit),
        entry.title or entry.name,
    )


def _entry(plant: str | None) -> RegisteredPlant | None:
    if not plant:
        return None
    from ltv_lstm_mpc.exceptions import LtvMpcError
    from ltv_lstm_mpc.plants.registry import resolve_plant

    try:
        return resolve_plant(plant)
    except LtvMpcError:
        return None


def _disturbance_label(text: str, output_unit: str) -> str:
    """``"buffer flow q2 in mL/s"`` -> ``"buffer flow q2 (mL/s)"``; ``"output units"`` is
    replaced by the outputs' unit."""
    text = text.replace("output units", output_unit).replace("^2", "\u00b2").strip()
    if text == "the plant's disturbance":
        return "disturbance d_phi"
    what, found, unit = text.rpartition(" in ")
    return f"{what} ({unit})" if found and what and unit else text


def titled(plant: str, title: str) -> str:
    """``title`` prefixed with the plant (``"pH plant: ..."``) unless it names it already."""
    words = re.split(r"[\s\-]+", plant.strip().lower())
    if not words or not words[0] or words[0] in title.lower():
        return title
    return f"{plant}: {title}"


# -- drawing -------------------------------------------------------------------------------


def draw_bounds(
    ax: Axes,
    low: ArrayLike,
    high: ArrayLike,
    *,
    label: str,
    gid: str,
    color: str = "tab:red",
    ls: str = "-",
    lw: float = 0.9,
) -> list[Line2D]:
    """Horizontal lines at every distinct finite value of ``low`` and ``high`` (one legend
    entry, ``label``); the lines extend the y-range to include them."""
    values = np.concatenate(
        [np.ravel(np.asarray(low, dtype=float)), np.ravel(np.asarray(high, dtype=float))]
    )
    lines: list[Line2D] = []
    for value in sorted({float(v) for v in values if np.isfinite(v)}):
        lines.append(
            ax.axhline(
                value,
                color=color,
                ls=ls,
                lw=lw,
                alpha=0.8,
                gid=gid,
                label="_nolegend_" if lines else label,
            )
        )
    return lines


def draw_inputs(
    ax: Axes,
    t: ArrayLike,
    u_phi: ArrayLike,
    bounds: tuple[ArrayLike, ArrayLike],
    labels: Sequence[str],
    colors: Sequence[str] | None = None,
) -> None:
    """Each input (a column of ``u_phi``) with its bounds U as dotted lines of its colour,
    named ``"bounds U of <name> [low, high] <unit>"``; the y-label from ``labels``."""
    u = np.asarray(u_phi, dtype=float).reshape(np.shape(t)[0], -1)
    u_low, u_high = (np.ravel(np.asarray(v, dtype=float)) for v in bounds)
    for j, label in enumerate(labels):
        color = colors[j] if colors is not None else f"C{j}"
        ax.plot(t, u[:, j], color=color, lw=1.0, label=label)
        draw_bounds(
            ax, u_low[j], u_high[j], gid=INPUT_BOUND_GID, color=color, ls=":",
            label=f"bounds U of {name_of(label)} "
            f"{bounds_text(u_low[j], u_high[j], unit_of(label))}",
        )  # fmt: skip
    ax.set_ylabel(axis_label(labels))


def bounds_text(low: ArrayLike, high: ArrayLike, unit: str) -> str:
    """``"[6, 9] pH"`` (one interval) or ``"[4, 20] cm"``; per-entry intervals joined."""
    lows, highs = np.ravel(np.asarray(low, dtype=float)), np.ravel(np.asarray(high, dtype=float))
    pairs = sorted({(float(a), float(b)) for a, b in zip(lows, highs, strict=True)})
    text = ", ".join(f"[{a:.3g}, {b:.3g}]" for a, b in pairs)
    return f"{text} {unit}".rstrip()


def fit_ylim(ax: Axes, *values: ArrayLike, margin: float = 0.06) -> tuple[float, float]:
    """Fix the y-range to the finite ``values`` with a margin (the set-point markers of
    :func:`mark_clipped_setpoints` refer to it); returns it."""
    data = np.concatenate([np.ravel(np.asarray(v, dtype=float)) for v in values])
    data = data[np.isfinite(data)]
    if data.size == 0:
        return ax.get_ylim()
    low, high = float(data.min()), float(data.max())
    pad = margin * (high - low) if high > low else max(abs(high) * 0.05, 0.5)
    ax.set_ylim(low - pad, high + pad)
    return low - pad, high + pad


def _runs(mask: NDArray[np.bool_]) -> list[tuple[int, int]]:
    edges = np.flatnonzero(np.diff(np.concatenate([[0], mask.astype(int), [0]])))
    return [(int(a), int(b)) for a, b in zip(edges[::2], edges[1::2], strict=True)]


def mark_clipped_setpoints(
    ax: Axes,
    t: ArrayLike,
    setpoints: ArrayLike,
    *,
    unit: str = "",
    color: str = "k",
    label: str = "set-point outside the plotted range",
) -> int:
    """Mark where ``setpoints`` leave the axis' current y-range: a triangle at the top (or
    bottom) edge at the start of every such stretch, annotated with the set-point's value.
    Call it after the y-range is final. Returns the number of markers."""
    from matplotlib.transforms import blended_transform_factory

    s = np.asarray(setpoints, dtype=float).reshape(-1)
    x = np.asarray(t, dtype=float).reshape(-1)[: s.size]
    s = s[: x.size]
    low, high = ax.get_ylim()
    transform = blended_transform_factory(ax.transData, ax.transAxes)
    count = 0
    for above, mask in ((True, s > high), (False, s < low)):
        for start, stop in _runs(mask):
            if count >= MAX_CLIPPED_MARKERS:
                return count
            stretch = s[start:stop]
            value = float(stretch.max() if above else stretch.min())
            edge = 0.97 if above else 0.03  # inside the axis, clear of the title
            ax.plot(
                [x[start]],
                [edge],
                ls="none",
                marker="^" if above else "v",
                ms=9,
                color=color,
                transform=transform,
                clip_on=False,
                zorder=5,
                gid=CLIPPED_SETPOINT_GID,
                label=label if count == 0 else "_nolegend_",
            )
            ax.annotate(
                f"set-point {value:.4g} {unit}".rstrip(),
                xy=(x[start], edge),
                xycoords=transform,
                xytext=(7, 0),
                textcoords="offset points",
                va="center",
                fontsize=7,
                color=color,
                bbox={"boxstyle": "round,pad=0.15", "fc": "white", "ec": "none", "alpha": 0.8},
                zorder=6,
            )
            count += 1
    return count


def shade_infeasible(ax: Axes, t: ArrayLike, mask: ArrayLike) -> None:
    """Grey bands over the samples where ``mask`` is true (FHOCP infeasible)."""
    flags = np.asarray(mask, dtype=bool).reshape(-1)
    x = np.asarray(t, dtype=float).reshape(-1)
    if not flags.any() or x.size < 1:
        return
    half = 0.5 * (x[1] - x[0]) if x.size > 1 else 0.5
    for start, stop in _runs(flags):
        ax.axvspan(x[start] - half, x[stop - 1] + half, color="0.82", lw=0, zorder=0)


def draw_d_hat(
    ax: Axes, t: ArrayLike, d_hat: ArrayLike, outputs: Sequence[str], d_max: float | None
) -> None:
    """The disturbance estimate per output, labelled ``d_hat on <output>``, with the
    saturation bounds +-``d_max`` (normalized output units, as the estimate)."""
    values = np.asarray(d_hat, dtype=float)
    values = values.reshape(values.shape[0], -1)
    x = np.asarray(t, dtype=float)
    for j in range(values.shape[1]):
        name = name_of(outputs[j]) if j < len(outputs) else f"y_{j}"
        ax.plot(x, values[:, j], color=f"C{j}", lw=1.0, label=f"$\\hat d$ on {name}")
    if d_max is not None and np.isfinite(d_max):
        draw_bounds(
            ax,
            -d_max,
            d_max,
            label=f"$\\pm d_{{max}}$ = {d_max:g} (saturation)",
            gid=D_MAX_GID,
            color="0.45",
            ls="--",
            lw=0.7,
        )
    ax.set_ylabel("$\\hat d$ (normalized)")


def legend(ax: Axes, **options: Any) -> None:
    """A small legend in the best corner (nothing when the axis has no labelled artist)."""
    handles, _ = ax.get_legend_handles_labels()
    if handles:
        ax.legend(loc=options.pop("loc", "best"), fontsize=options.pop("fontsize", 7), **options)
