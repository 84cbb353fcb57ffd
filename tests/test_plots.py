"""Plots a control engineer reads without the code: signal names with units from the plant
registry, the output constraint and the input bounds U drawn, set-points outside the plotted
range marked at the axis edge, d_hat labelled, the scenario in the title; the bench plot
shows every part of the step. Each test inspects the matplotlib figure itself."""

from __future__ import annotations

import argparse
import warnings
from pathlib import Path
from typing import Any

import numpy as np
import pytest

pytest.importorskip("matplotlib")

from matplotlib.figure import Figure

from ltv_lstm_mpc.benchmarks.quadtank import (
    QUADTANK_CONFIG,
    QUADTANK_MODEL,
    QuadTankScenario,
    quadtank_figure,
    run_quadtank_scenario,
)
from ltv_lstm_mpc.cli.simulate_mimo import mimo_figure
from ltv_lstm_mpc.loop.schedules import piecewise_constant
from ltv_lstm_mpc.loop.schedules import segments as schedule_segments
from ltv_lstm_mpc.lstm.shipped import load_model
from ltv_lstm_mpc.mpc.config import MPCConfig
from ltv_lstm_mpc.paper.reproduce import plot_scenario, scenario_figure
from ltv_lstm_mpc.paper.scenarios import Scenario, run_scenario
from ltv_lstm_mpc.plotting import (
    CLIPPED_SETPOINT_GID,
    D_MAX_GID,
    INPUT_BOUND_GID,
    OUTPUT_CONSTRAINT_GID,
    axis_label,
    fit_ylim,
    mark_clipped_setpoints,
    signal_labels,
    titled,
    unit_of,
)


def lines_with(ax: Any, gid: str) -> list[Any]:
    return [line for line in ax.get_lines() if line.get_gid() == gid]


def levels(ax: Any, gid: str) -> list[float]:
    """The y-values of the horizontal lines with ``gid`` (sorted)."""
    return sorted(float(line.get_ydata()[0]) for line in lines_with(ax, gid))


def legend_texts(ax: Any) -> list[str]:
    legend = ax.get_legend()
    return [] if legend is None else [t.get_text() for t in legend.get_texts()]


# ----------------------------------------------------------------------------- helpers


def test_labels_come_from_the_plant_registry() -> None:
    ph, quadtank = load_model("ph_lstm_n5.npz"), load_model(QUADTANK_MODEL)
    labels = signal_labels("ph", ph)
    assert (labels.inputs, labels.outputs) == (("q3 (mL/s)",), ("pH",))
    assert labels.disturbance == "buffer flow q2 (mL/s)" and labels.plant == "pH plant"
    # the LSTM plant is the shipped pH model here: it is labelled like the pH plant
    lstm = signal_labels("lstm", ph)
    assert lstm.outputs == ("pH",) and lstm.disturbance == "output offset (pH)"
    tank = signal_labels("quadtank", quadtank)
    assert tank.outputs == ("h1 (cm)", "h2 (cm)") and tank.inputs == ("v1 (V)", "v2 (V)")
    assert tank.output_unit == "cm" and "cm\u00b2" in tank.disturbance
    # a model no plant ships: generic names, never another plant's units
    other = load_model("example_delta_iss_n3.npz")
    generic = signal_labels("lstm", other)
    assert generic.outputs == ("y (output units)",) and generic.inputs == ("u (input units)",)
    assert generic.disturbance == "output offset (output units)"
    assert signal_labels("nowhere.module:Plant", other).plant == "nowhere.module:Plant"
    assert unit_of("h1 (cm)") == "cm" and unit_of("pH") == "pH"
    assert axis_label(("h1 (cm)", "h2 (cm)")) == "h1, h2 (cm)"
    assert axis_label(("v1 (V)",)) == "v1 (V)"
    assert titled("pH plant", "set-points") == "pH plant: set-points"
    assert titled("quadruple-tank process", "Quadruple tank: leaks") == "Quadruple tank: leaks"


def test_clipped_setpoint_marker_appears_only_outside_the_plotted_range() -> None:
    fig = Figure()
    ax = fig.subplots()
    t = np.arange(40.0)
    ax.plot(t, 7.0 + 0.01 * t)
    fit_ylim(ax, 7.0 + 0.01 * t, 6.0, 9.0)
    assert mark_clipped_setpoints(ax, t, np.full(40, 8.0), unit="pH") == 0
    setpoints = np.r_[np.full(20, 7.5), np.full(10, 10.5), np.full(10, 4.0)]
    assert mark_clipped_setpoints(ax, t, setpoints, unit="pH") == 2
    up, down = lines_with(ax, CLIPPED_SETPOINT_GID)
    assert (up.get_marker(), down.get_marker()) == ("^", "v")
    assert float(up.get_xdata()[0]) == 20.0 and float(down.get_xdata()[0]) == 30.0
    assert float(up.get_ydata()[0]) > 0.9 and float(down.get_ydata()[0]) < 0.1  # axis edges
    texts = [child.get_text() for child in ax.texts]
    assert "set-point 10.5 pH" in texts and "set-point 4 pH" in texts
    assert ax.get_ylim()[1] < 10.5  # the range is the data's and the constraint's


# ----------------------------------------------------------------------------- SISO


@pytest.fixture(scope="module")
def ph_result() -> Any:
    model = load_model("ph_lstm_n5.npz")
    steps = [20, 20]
    scenario = Scenario(
        name="plot_test",
        title="pH plant: set-points 7.5 -> 10.5 pH; daqp",
        plant="ph",
        setpoints=piecewise_constant([7.5, 10.5], steps),
        disturbances=np.full(40, 0.55),
        config=MPCConfig(solver="daqp"),
        setpoint_rate_limit=0.01,
        segments=schedule_segments(steps),
    )
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # 10.5 pH is outside the admissible interval
        return run_scenario(scenario, model)


def test_siso_plot_names_units_and_draws_bounds(ph_result: Any, tmp_path: Path) -> None:
    fig = scenario_figure(ph_result)
    out, inp, dist, dhat = fig.axes
    assert out.get_ylabel() == "pH" and inp.get_ylabel() == "q3 (mL/s)"
    assert "mL/s" in dist.get_ylabel() and "hat d" in dhat.get_ylabel()
    assert "sample k (Ts = 10 s)" in dhat.get_xlabel()
    low, high = ph_result.controller.model.y_phi_constraint
    assert levels(out, OUTPUT_CONSTRAINT_GID) == [float(low[0]), float(high[0])]
    u_low, u_high = ph_result.controller.input_bounds_phi
    assert levels(inp, INPUT_BOUND_GID) == pytest.approx([u_low[0], u_high[0]])
    d_max = ph_result.controller.config.d_max
    assert levels(dhat, D_MAX_GID) == pytest.approx([-d_max, d_max])
    # 10.5 pH lies above the plotted range: marked at the top edge, with its value
    (marker,) = lines_with(out, CLIPPED_SETPOINT_GID)
    assert float(marker.get_xdata()[0]) == 20.0 and out.get_ylim()[1] < 10.5
    assert any("output constraint [6, 9] pH" in t for t in legend_texts(out))
    assert any("bounds U of q3 [12.5, 17] mL/s" in t for t in legend_texts(inp))
    assert "$\\hat d$ on pH" in legend_texts(dhat)
    assert any("buffer flow q2 (mL/s)" in t for t in legend_texts(dist))
    title = out.get_title()
    assert "pH plant" in title and "7.5 -> 10.5" in title and "final offset" in title
    path = plot_scenario(ph_result, tmp_path / "scenario.png")
    assert path.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_simulate_title_names_plant_setpoints_and_unit() -> None:
    from ltv_lstm_mpc.cli.main import _plot_labels, _plot_title
    from ltv_lstm_mpc.plants.registry import resolve_plant

    args = argparse.Namespace(solver="daqp", N=5, L_d=0.1)
    ph = resolve_plant("ph")
    title = _plot_title(ph, load_model("ph_lstm_n5.npz"), ["7.5", "8.0"], args)
    assert title == "pH plant: set-points 7.5 -> 8.0 pH; daqp, N = 5, L_d = 0.1"
    tank, model = resolve_plant("quadtank"), load_model(QUADTANK_MODEL)
    title = _plot_title(tank, model, ["14,14", "13,11"], args)
    assert title.startswith("quadruple-tank process: set-points (14, 14) -> (13, 11) cm;")
    assert _plot_labels(resolve_plant("lstm"), model) == (("v1 (V)", "v2 (V)"),
                                                           ("h1 (cm)", "h2 (cm)"))  # fmt: skip


# ----------------------------------------------------------------------------- MIMO


@pytest.fixture(scope="module")
def tank_result() -> Any:
    model = load_model(QUADTANK_MODEL)
    steps = [15, 15]
    scenario = QuadTankScenario(
        name="plot_test",
        title="Quadruple tank: h2 set-point above the tank",
        setpoints=piecewise_constant([(14.0, 14.0), (13.0, 25.0)], steps),
        leaks=np.zeros((30, 2)),
        config=QUADTANK_CONFIG,
        setpoint_rate_limit=0.01,
        segments=schedule_segments(steps),
    )
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # 25 cm is outside the admissible interval
        return run_quadtank_scenario(scenario, model, solver="daqp")


def test_quadtank_plot_names_units_and_draws_bounds(tank_result: Any) -> None:
    fig = quadtank_figure(tank_result)
    h1, h2, inputs, leaks, dhat = fig.axes
    assert (h1.get_ylabel(), h2.get_ylabel()) == ("h1 (cm)", "h2 (cm)")
    assert inputs.get_ylabel() == "v1, v2 (V)" and "cm\u00b2" in leaks.get_ylabel()
    low, high = tank_result.level_constraint()
    for j, ax in enumerate((h1, h2)):
        assert levels(ax, OUTPUT_CONSTRAINT_GID) == pytest.approx([low[j], high[j]])
    u_low, u_high = tank_result.controller.input_bounds_phi
    expected = sorted({*u_low.tolist(), *u_high.tolist()})
    assert sorted(set(levels(inputs, INPUT_BOUND_GID))) == pytest.approx(expected)
    assert not lines_with(h1, CLIPPED_SETPOINT_GID)  # h1's set-points lie inside
    (marker,) = lines_with(h2, CLIPPED_SETPOINT_GID)  # 25 cm: above the 20 cm constraint
    assert float(marker.get_xdata()[0]) == 15.0 and h2.get_ylim()[1] < 25.0
    assert {"$\\hat d$ on h1", "$\\hat d$ on h2"} <= set(legend_texts(dhat))
    assert len(lines_with(dhat, D_MAX_GID)) == 2
    assert "Quadruple tank" in h1.get_title() and "cm" in h1.get_title()


def test_mimo_simulate_plot_names_units_and_draws_bounds(tank_result: Any) -> None:
    sim, model = tank_result.simulation, tank_result.controller.model
    bounds = tank_result.controller.input_bounds_phi
    labels = (("v1 (V)", "v2 (V)"), ("h1 (cm)", "h2 (cm)"))
    title = "quadruple-tank process: set-points (14, 14) -> (13, 25) cm"
    fig = mimo_figure(sim, tank_result.scenario.setpoints, model, bounds, labels, title, 0.1)
    outputs, inputs, dhat = fig.axes
    assert outputs.get_ylabel() == "h1, h2 (cm)" and inputs.get_ylabel() == "v1, v2 (V)"
    assert dhat.get_xlabel() == "time (min)" and "hat d" in dhat.get_ylabel()
    assert levels(outputs, OUTPUT_CONSTRAINT_GID) == pytest.approx([4.0, 20.0])
    assert len(lines_with(inputs, INPUT_BOUND_GID)) == 4
    (marker,) = lines_with(outputs, CLIPPED_SETPOINT_GID)
    assert float(marker.get_xdata()[0]) == pytest.approx(15 * model.Ts / 60.0)
    assert levels(dhat, D_MAX_GID) == pytest.approx([-0.1, 0.1])
    assert "(13, 25) cm" in fig.get_suptitle()


# ----------------------------------------------------------------------------- bench


def bench_rows() -> list[dict[str, Any]]:
    parts = {  # microseconds: daqp's observer below 10 us, its solve about 2 us
        "daqp": (9.0, 26.0, 47.0, 1.96),
        "clarabel": (17.0, 34.0, 870.0, 3200.0),
        "ipopt": (18.0, 34.0, float("nan"), 3300.0),  # no build part
    }
    rows = []
    for backend, (observer, reference, build, solve) in parts.items():
        total = observer + reference + np.nan_to_num(build) + solve
        rows.append({
            "scenario": "1_lstm_theorem3", "N": 5, "backend": backend, "steps": 30,
            "step_median_us": total, "step_p95_us": 1.5 * total,
            "observer_median_us": observer, "reference_median_us": reference,
            "build_median_us": build, "solve_median_us": solve,
        })  # fmt: skip
    return rows


def test_bench_plot_shows_every_part_of_the_step(tmp_path: Path) -> None:
    from ltv_lstm_mpc.solver_comparison.harness import _plots, bench_figure

    rows = bench_rows()
    fig = bench_figure(rows, 5)
    assert fig is not None and bench_figure(rows, 7) is None
    total, parts = fig.axes
    assert "µs" in total.get_xlabel() and "µs" in parts.get_xlabel()
    assert total.get_xscale() == parts.get_xscale() == "log"
    smallest = min(min(r[c] for c in ("observer_median_us", "solve_median_us")) for r in rows)
    floor = parts.get_xlim()[0]
    assert floor < smallest / 2  # the 1.96 us solve and the 9 us observer both show
    for column in ("observer_median_us", "reference_median_us", "solve_median_us"):
        bars = [p for p in parts.patches if p.get_gid() == column]
        assert len(bars) == len(rows)
        by_end = sorted(bar.get_x() + bar.get_width() for bar in bars)
        assert by_end == pytest.approx(sorted(r[column] for r in rows))
        assert all(bar.get_x() == pytest.approx(floor) for bar in bars)
    assert total.get_xlim()[0] < min(r["step_median_us"] for r in rows)
    assert "1_lstm_theorem3" in fig.get_suptitle() and "N = 5" in fig.get_suptitle()
    _plots(rows, tmp_path)
    assert (tmp_path / "bench_N5.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


# ----------------------------------------------------------------------------- campaign


def test_campaign_plots_name_plant_units_and_campaign(tmp_path: Path, monkeypatch: Any) -> None:
    from ltv_lstm_mpc.campaign import report

    figures: dict[str, Figure] = {}

    def keep(figure: Figure, path: Path) -> Path:
        figures[path.name] = figure
        return path

    monkeypatch.setattr(report, "_save", keep)
    rows = [
        {"status": "ok", "plant": "quadtank", "solver": solver, "N": N, "noise_std": noise,
         "final_offset": 0.01 * N, "violations": 0, "max_violation": 0.0,
         "median_step_s": 1e-4 * N}
        for solver in ("daqp", "clarabel") for N in (3, 5) for noise in (0.0, 0.05)
    ]  # fmt: skip
    report.write_report(rows, ["solver", "N", "noise_std"], tmp_path, title="demo")
    assert set(figures) >= {"by_solver.png", "by_noise_std.png", "violations_vs_noise.png",
                            "step_time_heatmap.png"}  # fmt: skip
    for figure in figures.values():
        assert figure.get_suptitle().startswith("campaign demo (quadruple-tank process):")
    offset, _, step = figures["by_noise_std.png"].axes
    assert offset.get_ylabel() == "final offset (cm)" and step.get_ylabel() == "median step (ms)"
    assert offset.get_xlabel() == "noise_std (cm)"
    _, largest = figures["violations_vs_noise.png"].axes
    assert largest.get_ylabel() == "largest violation (cm)"
    assert largest.get_xlabel() == "measurement noise std (cm)"
    heat = figures["step_time_heatmap.png"].axes[0]
    assert heat.get_ylabel() == "backend" and "N" in heat.get_xlabel()
