"""Campaign report: a markdown summary and plots of the results table.

:func:`write_report` writes ``report.md`` and, under ``plots/``,

* ``by_<factor>.png`` for every factor with more than one level: the distributions
  (box plots) of the final offset, the true-plant violations and the median step time per
  level;
* ``violations_vs_noise.png`` when the measurement noise varies: violations (and their
  largest size) against ``noise_std``, one mean line per plant mismatch;
* ``step_time_heatmap.png`` when the backend or the horizon varies: median step time per
  backend x N;

and the statistical statements (:mod:`~ltv_lstm_mpc.campaign.statements`): the
Clopper-Pearson bound per stratum and outcome, in ``report.md`` and ``statements.csv``.
"""

from __future__ import annotations

import csv
import io
import math
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np
from matplotlib.figure import Figure
from matplotlib.ticker import MaxNLocator

from ltv_lstm_mpc.campaign.statements import Statement, campaign_statements, format_statements
from ltv_lstm_mpc.campaign.store import atomic_write

__all__ = ["factor_levels", "output_unit", "plant_title", "write_report"]

#: (column, axis label, scale) of the distribution plots and tables ("output units" is
#: replaced by the plant's output unit).
_METRICS = (
    ("final_offset", "final offset (output units)", 1.0),
    ("violations", "violations (samples)", 1.0),
    ("median_step_s", "median step (ms)", 1e3),
)

#: Most lines (levels) a plot draws one by one; more (sampled values) are pooled.
MAX_LINES = 12

#: Units of the factors on a plot axis ("output units": the plant's output unit).
_FACTOR_UNITS = {
    "noise_std": "output units",
    "N": "horizon, samples",
    "d_max": "normalized",
    "rate_limit": "normalized per step",
    "solver": "backend",
}


#: Columns of the overall table in the plant's output unit.
_OUTPUT_UNIT_COLUMNS = ("final_offset", "max_violation")


def output_unit(rows: Sequence[Mapping[str, Any]]) -> str:
    """The output unit of the campaign's plant(s) for labels and tables: the rows'
    ``output_unit`` (each task's, from the plant registry), else the registry's output labels
    ("pH", "h1 (cm)" -> "cm"); "output units" when the plants differ, state none, or a
    plant class is not importable here."""
    from ltv_lstm_mpc.exceptions import LtvMpcError
    from ltv_lstm_mpc.plants.registry import resolve_plant

    recorded = {str(r["output_unit"]) for r in rows if r.get("output_unit")}
    if recorded:  # the task's own (the plant's, or the model's on the LSTM plant)
        return recorded.pop() if len(recorded) == 1 else "output units"
    units = set()
    for plant in {str(r.get("plant")) for r in rows if r.get("plant")}:
        try:
            labels = resolve_plant(plant).output_labels
        except LtvMpcError:
            return "output units"
        for label in labels:
            units.add(label[label.find("(") + 1 : label.rfind(")")] if "(" in label else label)
    return units.pop() if len(units) == 1 else "output units"


def plant_title(rows: Sequence[Mapping[str, Any]]) -> str:
    """The campaign's plant(s) in words, from the plant registry ("pH plant"); the names
    as given when a plant class is not importable here."""
    from ltv_lstm_mpc.exceptions import LtvMpcError
    from ltv_lstm_mpc.plants.registry import resolve_plant

    titles = []
    for plant in dict.fromkeys(str(r.get("plant")) for r in rows if r.get("plant")):
        try:
            titles.append(resolve_plant(plant).title or plant)
        except LtvMpcError:
            titles.append(plant)
    return ", ".join(titles) or "plant not recorded"


def _suptitle(rows: Sequence[Mapping[str, Any]], title: str, what: str) -> str:
    return f"campaign {title} ({plant_title(rows)}): {what}"


def _factor_label(rows: Sequence[Mapping[str, Any]], name: str) -> str:
    unit = _FACTOR_UNITS.get(name)
    if unit is None:
        return name
    return f"{name} ({unit.replace('output units', output_unit(rows))})"


def _number(value: Any) -> float:
    if value is None or isinstance(value, (bool, str)):
        return math.nan
    try:
        return float(value)
    except (TypeError, ValueError):
        return math.nan


def factor_levels(rows: Sequence[Mapping[str, Any]], name: str) -> list[Any]:
    """Distinct values of a column: numbers sorted, anything else in order of appearance."""
    levels = list(dict.fromkeys(row.get(name) for row in rows))
    if all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in levels):
        return sorted(levels)
    return levels


def _values(rows: Sequence[Mapping[str, Any]], column: str, scale: float = 1.0) -> list[float]:
    values = [_number(row.get(column)) * scale for row in rows if row.get("status") == "ok"]
    return [v for v in values if math.isfinite(v)]


def _label(value: Any) -> str:
    text = f"{value:g}" if isinstance(value, float) else str(value)
    return text if len(text) <= 28 else text[:25] + "..."


def _fmt(value: float, digits: int = 3) -> str:
    return "-" if not math.isfinite(value) else f"{value:.{digits}g}"


def _stats(values: Sequence[float]) -> tuple[float, float, float]:
    if not values:
        return math.nan, math.nan, math.nan
    return float(np.mean(values)), float(np.median(values)), float(np.max(values))


def _save(figure: Figure, path: Path) -> Path:
    import io

    buffer = io.BytesIO()
    figure.savefig(buffer, format="png", dpi=110)
    atomic_write(path, buffer.getvalue())
    return path


def _factor_plot(
    rows: Sequence[Mapping[str, Any]], name: str, path: Path, title: str = "campaign"
) -> Path:
    levels = factor_levels(rows, name)
    figure = Figure(figsize=(4.0 * len(_METRICS), 3.8), layout="constrained")
    axes = figure.subplots(1, len(_METRICS))
    unit = output_unit(rows)
    for ax, (column, label, scale) in zip(axes, _METRICS, strict=True):
        label = label.replace("output units", unit)
        data = [_values([r for r in rows if r.get(name) == lv], column, scale) for lv in levels]
        positions = [i for i, d in enumerate(data) if d]
        if positions:
            ax.boxplot([data[i] for i in positions], positions=positions, widths=0.6)
        ax.set_xticks(range(len(levels)), [_label(lv) for lv in levels], rotation=30, ha="right")
        ax.set_xlim(-0.6, len(levels) - 0.4)
        ax.set_title(label.split(" (")[0])
        ax.set_ylabel(label)
        ax.set_xlabel(_factor_label(rows, name))
        ax.grid(alpha=0.3)
    figure.suptitle(_suptitle(rows, title, f"distributions per {name}"))
    return _save(figure, path)


def _noise_plot(rows: Sequence[Mapping[str, Any]], path: Path, title: str = "campaign") -> Path:
    noise = factor_levels(rows, "noise_std")
    groups = factor_levels(rows, "mismatch") if "mismatch" in rows[0] else [None]
    if len(groups) > MAX_LINES:  # sampled mismatch ([random]): one cloud, no legend of draws
        groups = [None]
    if len(noise) > MAX_LINES:  # sampled noise: means over equal-width bins of it
        values = [v for v in (_number(level) for level in noise) if math.isfinite(v)]
        edges = np.linspace(min(values), max(values), 9)
        noise = [float(v) for v in 0.5 * (edges[1:] + edges[:-1])]
        binned = True
    else:
        edges, binned = np.zeros(0), False
    figure = Figure(figsize=(10, 4.0), layout="constrained")
    axes = figure.subplots(1, 2)
    unit = output_unit(rows)
    panels = (
        ("violations", "violations (samples)"),
        ("max_violation", f"largest violation ({unit})"),
    )
    for ax, (column, label) in zip(axes, panels, strict=True):
        for group in groups:
            subset = [r for r in rows if group is None or r.get("mismatch") == group]
            means = []
            for index, level in enumerate(noise):
                if binned:
                    low, high = edges[index], edges[index + 1]
                    members = [
                        r
                        for r in subset
                        if low <= _number(r.get("noise_std")) <= high
                        and (index == len(noise) - 1 or _number(r.get("noise_std")) < high)
                    ]
                else:
                    members = [r for r in subset if r.get("noise_std") == level]
                values = _values(members, column)
                means.append(float(np.mean(values)) if values else math.nan)
            ok = [r for r in subset if r.get("status") == "ok"]
            name = "all" if group is None else _label(group)
            if binned:
                name += " (mean per noise bin)"
            (line,) = ax.plot(noise, means, marker="o", label=name)
            ax.scatter(
                [_number(r.get("noise_std")) for r in ok],
                [_number(r.get(column)) for r in ok],
                s=8,
                alpha=0.35,
                color=line.get_color(),
            )
        numeric = [v for v in (_number(level) for level in noise) if math.isfinite(v)]
        if numeric and len(numeric) <= 12 and not binned:
            ax.set_xticks(numeric, [f"{v:g}" for v in numeric])
        elif binned:
            ax.xaxis.set_major_locator(MaxNLocator(5))
        ax.set_xlabel(f"measurement noise std ({unit})")
        ax.set_ylabel(label)
        ax.set_title(label.split(" (")[0] + " of the true plant output")
        ax.grid(alpha=0.3)
    axes[0].legend(title="mismatch" if groups != [None] else None, fontsize=8)
    figure.suptitle(_suptitle(rows, title, "output-constraint violations vs measurement noise"))
    return _save(figure, path)


def _statements_plot(
    statements: Sequence[Statement], rows: Sequence[Mapping[str, Any]], path: Path, title: str
) -> Path:
    """The Clopper-Pearson bound (bar) and the observed failure share (marker) per
    outcome, one bar per stratum."""
    outcomes = list(dict.fromkeys(s.outcome for s in statements))
    strata = list(dict.fromkeys(tuple(s.stratum.items()) for s in statements))
    figure = Figure(figsize=(10, 4.2), layout="constrained")
    ax = figure.subplots()
    width = 0.8 / max(len(strata), 1)
    for j, stratum in enumerate(strata):
        chosen = [s for s in statements if tuple(s.stratum.items()) == stratum]
        by_outcome = {s.outcome: s for s in chosen}
        x = np.arange(len(outcomes)) + (j - (len(strata) - 1) / 2) * width
        bounds = [by_outcome[o].upper_bound if o in by_outcome else math.nan for o in outcomes]
        shares = [
            by_outcome[o].failures / by_outcome[o].loops
            if o in by_outcome and by_outcome[o].loops
            else math.nan
            for o in outcomes
        ]
        label = ", ".join(f"{k} = {_label(v)}" for k, v in stratum) or "all loops"
        ax.bar(x, bounds, width * 0.9, label=f"{label}: bound", alpha=0.75)
        ax.plot(x, shares, "k_", markersize=14, markeredgewidth=2)
        for xi, bound in zip(x, bounds, strict=True):
            if math.isfinite(bound):
                ax.annotate(f"{bound:.3g}", (xi, bound), ha="center", va="bottom", fontsize=8)
    ax.plot([], [], "k_", markersize=14, markeredgewidth=2, label="observed failure share")
    ax.set_xticks(np.arange(len(outcomes)), [o.replace("_", " ") for o in outcomes])
    ax.set_ylim(0, 1.08)
    ax.set_ylabel("P(failure in a closed loop)")
    beta = statements[0].beta
    ax.set_title(f"one-sided Clopper-Pearson upper bounds, confidence {1 - beta:.0%}")
    ax.grid(axis="y", alpha=0.3)
    ax.legend(fontsize=8)
    figure.suptitle(_suptitle(rows, title, "statistical statements"))
    return _save(figure, path)


def _heatmap(rows: Sequence[Mapping[str, Any]], path: Path, title: str = "campaign") -> Path:
    solvers = factor_levels(rows, "solver")
    horizons = factor_levels(rows, "N")
    grid = np.full((len(solvers), len(horizons)), np.nan)
    for i, solver in enumerate(solvers):
        for j, N in enumerate(horizons):
            subset = [r for r in rows if r.get("solver") == solver and r.get("N") == N]
            values = _values(subset, "median_step_s", 1e3)
            if values:
                grid[i, j] = float(np.median(values))
    figure = Figure(
        figsize=(3.5 + 1.3 * len(horizons), 1.6 + 0.38 * len(solvers)), layout="constrained"
    )
    ax = figure.subplots()
    shown = np.log10(np.where(np.isfinite(grid) & (grid > 0), grid, np.nan))
    image = ax.imshow(shown, aspect="auto", cmap="viridis")
    low, high = np.nanmin(shown, initial=np.inf), np.nanmax(shown, initial=-np.inf)
    for i in range(len(solvers)):
        for j in range(len(horizons)):
            if math.isfinite(grid[i, j]):
                bright = high > low and (shown[i, j] - low) / (high - low) > 0.6
                ax.text(
                    j, i, f"{grid[i, j]:.3g}", ha="center", va="center", fontsize=8,
                    color="k" if bright else "w",
                )  # fmt: skip
    ax.set_xticks(range(len(horizons)), [str(n) for n in horizons])
    ax.set_yticks(range(len(solvers)), [str(s) for s in solvers])
    ax.set_xlabel("horizon N (samples)")
    ax.set_ylabel("backend")
    figure.colorbar(image, ax=ax, label="log10 of the median step in ms")
    ax.set_title("median controller step (ms; numbers in the cells)", fontsize=10)
    figure.suptitle(_suptitle(rows, title, "step time, backend x N"), fontsize=10)
    return _save(figure, path)


def _varying(rows: Sequence[Mapping[str, Any]], names: Sequence[str]) -> list[str]:
    return [n for n in names if len(factor_levels(rows, n)) > 1]


def _write_statements(statements: Sequence[Statement], path: Path) -> Path:
    """``statements.csv``: one row per stratum and outcome."""
    buffer = io.StringIO()
    writer = csv.writer(buffer)
    strata = list(statements[0].stratum)
    writer.writerow(
        [*strata, "outcome", "failures", "loops", "errors", "beta", "upper_bound", "statement"]
    )
    for statement in statements:
        writer.writerow(
            [
                *statement.stratum.values(),
                statement.outcome,
                statement.failures,
                statement.loops,
                statement.errors,
                statement.beta,
                statement.upper_bound,
                statement.sentence(),
            ]
        )
    atomic_write(path, buffer.getvalue().encode("utf-8"))
    return path


def write_report(
    rows: Sequence[Mapping[str, Any]],
    factors: Sequence[str],
    out: str | Path,
    *,
    title: str = "campaign",
    plots: bool = True,
    strata: Sequence[str] | None = None,
    beta: float = 0.05,
    offset_tolerance: float = 1e-3,
    replications: Sequence[str] = (),
    offset_window: int | None = None,
) -> list[Path]:
    """Write ``report.md`` (and the plots, and ``statements.csv``) for a results table.

    Parameters
    ----------
    rows : sequence of dict
        The rows (:class:`~ltv_lstm_mpc.campaign.runner.CampaignRun` ``rows``, or the
        results table read back).
    factors : sequence of str
        The campaign's varying settings (columns to break the results down by).
    out : path
        The campaign folder.
    strata : sequence of str, optional
        Settings whose levels define the strata of the statistical statements
        (:attr:`~ltv_lstm_mpc.campaign.spec.CampaignSpec.strata`; default ``factors``).
    beta : float
        1 - confidence of the statements (:mod:`~ltv_lstm_mpc.campaign.statements`).
    offset_tolerance : float
        Final offset above which a loop counts as a failure (output units).
    replications : sequence of str
        Replication settings pooled into the strata (``campaign_statements``).
    offset_window : int, optional
        Window of the measured offset, named in the statements.

    Returns
    -------
    list of Path
        The files written.
    """
    root = Path(out)
    ok = [r for r in rows if r.get("status") == "ok"]
    errors = [r for r in rows if r.get("status") != "ok"]
    varying = _varying(rows, factors)
    files: list[Path] = []
    figures: list[tuple[str, Path]] = []
    if plots and ok:
        for name in varying:
            figures.append(
                (f"by {name}", _factor_plot(rows, name, root / "plots" / f"by_{name}.png", title))
            )
        if "noise_std" in rows[0] and len(factor_levels(rows, "noise_std")) > 1:
            figures.append(
                (
                    "violations vs noise",
                    _noise_plot(rows, root / "plots" / "violations_vs_noise.png", title),
                )
            )
        if "solver" in rows[0] and "N" in rows[0] and ({"solver", "N"} & set(varying)):
            figures.append(
                (
                    "step time, backend x N",
                    _heatmap(rows, root / "plots" / "step_time_heatmap.png", title),
                )
            )
    levels = ", ".join(f"`{n}` ({len(factor_levels(rows, n))})" for n in factors)
    truncated = [r for r in ok if r.get("truncated") is True]
    truncated_note = (
        [
            f"**{len(truncated)} task(s) stopped early** (`max_seconds`; column `truncated`): "
            "their offsets cover only the segments they reached.",
            "",
        ]
        if truncated
        else []
    )
    unit = output_unit(rows)
    wall = sum(v for v in (_number(r.get("wall_s")) for r in rows) if math.isfinite(v))
    lines = [
        f"# Campaign `{title}`",
        "",
        f"{len(rows)} tasks: {len(ok)} ok, {len(errors)} errors; task time {wall:.1f} s in total.",
        f"Factors (levels): {levels or 'none'}.",
        "",
        *truncated_note,
        f"Metrics in physical units ({unit}) on the true plant output; step times of the "
        "controller.",
        "",
        "## Overall",
        "",
        "| metric | mean | median | max |",
        "|---|---|---|---|",
    ]
    for column in (
        "final_offset",
        "violations",
        "max_violation",
        "infeasible_steps",
        "fallback_steps",
        "d_hat_saturated_steps",
        "closed_loop_cost",
    ):
        mean, median, top = _stats(_values(rows, column))
        shown = f"{column} ({unit})" if column in _OUTPUT_UNIT_COLUMNS else column
        lines.append(f"| {shown} | {_fmt(mean)} | {_fmt(median)} | {_fmt(top)} |")
    for column in ("median_step_s", "p95_step_s", "max_step_s"):
        mean, median, top = _stats(_values(rows, column, 1e3))
        lines.append(f"| {column[:-2]} (ms) | {_fmt(mean)} | {_fmt(median)} | {_fmt(top)} |")
    for name in varying:
        lines += [
            "",
            f"## By `{name}`",
            "",
            f"| {name} | tasks | errors | final offset mean / max ({unit}) | violations mean | "
            "infeasible mean | median step (ms) |",
            "|---|---|---|---|---|---|---|",
        ]
        for level in factor_levels(rows, name):
            subset = [r for r in rows if r.get(name) == level]
            failed = sum(1 for r in subset if r.get("status") != "ok")
            offset = _stats(_values(subset, "final_offset"))
            violations = _stats(_values(subset, "violations"))
            infeasible = _stats(_values(subset, "infeasible_steps"))
            step = _stats(_values(subset, "median_step_s", 1e3))
            lines.append(
                f"| {_label(level)} | {len(subset)} | {failed} | {_fmt(offset[0])} / "
                f"{_fmt(offset[2])} | {_fmt(violations[0])} | {_fmt(infeasible[0])} | "
                f"{_fmt(step[1])} |"
            )
    stated = campaign_statements(
        rows,
        [n for n in (factors if strata is None else strata) if n in _varying(rows, factors)],
        beta=beta,
        offset_tolerance=offset_tolerance,
        replications=replications,
        offset_window=offset_window,
    )
    if stated:
        lines += [
            "",
            "## Statistical statements",
            "",
            f"One-sided Clopper-Pearson bounds at confidence {1 - beta:.0%} on the probability "
            "of each outcome in a closed loop of each stratum (fixed settings), valid when the "
            "loops of a stratum are i.i.d. draws of its random settings ([random] of the spec: "
            f"sampled mismatch, noise, seeds); tasks with errors are left out (column `errors`). "
            "Zero failures in N loops give 1 - beta^(1/N); `ltv-lstm-mpc campaign --plan-epsilon "
            "EPS` sizes N.",
            "",
            *(line.replace("(output units)", f"({unit})") for line in format_statements(stated)),
        ]
        files.append(_write_statements(stated, root / "statements.csv"))
        if plots:
            figures.append(
                (
                    "statistical statements",
                    _statements_plot(stated, rows, root / "plots" / "statements.png", title),
                )
            )
    if errors:
        lines += [
            "",
            "## Errors",
            "",
            "| key | " + " | ".join(factors) + " | error |",
            "|---|" + "---|" * len(factors) + "---|",
        ]
        for row in errors[:50]:
            error = str(row.get("error", "")).replace("|", "/").replace("\n", " ")[:300]
            cells = " | ".join(_label(row.get(n)) for n in factors)
            lines.append(f"| {row.get('key')} | {cells} | {error} |")
        if len(errors) > 50:
            lines.append(f"\n... and {len(errors) - 50} more (see the results table).")
    if figures:
        lines += ["", "## Plots", ""]
        for caption, path in figures:
            lines.append(f"![{caption}]({path.relative_to(root).as_posix()})")
        files.extend(path for _, path in figures)
    report = root / "report.md"
    atomic_write(report, ("\n".join(lines) + "\n").encode("utf-8"))
    files.append(report)
    return files
