"""The shipped quadruple-tank model: file contents, certificates, FIT on regenerated data,
offset-free closed loop on the true plant (daqp and clarabel) and the CLI paths."""

from __future__ import annotations

import json
import re
from pathlib import Path

import numpy as np
import pytest
from optional_extras import backend_params

from ltv_lstm_mpc.benchmarks.quadtank import (
    OFFSET_TOLERANCE_FRACTION,
    QUADTANK_CONFIG,
    QUADTANK_MODEL,
    QuadTankScenario,
    quadtank_scenarios,
    run_quadtank_scenario,
)
from ltv_lstm_mpc.certificates.certify import certify
from ltv_lstm_mpc.cli import main
from ltv_lstm_mpc.lstm.shipped import load_model, shipped_path
from ltv_lstm_mpc.plants import QuadrupleTankPlant
from ltv_lstm_mpc.plants.quadtank import QUADTANK_LEVEL_CONSTRAINT
from ltv_lstm_mpc.training.datasets import generate_split
from ltv_lstm_mpc.training.train import fit_index, simulate_sequences

REPORT = json.loads(shipped_path(QUADTANK_MODEL.replace(".npz", "_report.json")).read_text())


@pytest.fixture(scope="module")
def model():  # type: ignore[no-untyped-def]
    return load_model(QUADTANK_MODEL)


def test_shipped_model_file_holds_ts_constraint_and_normalization(model) -> None:  # type: ignore[no-untyped-def]
    assert (model.m, model.p) == (2, 2) and model.n == REPORT["config"]["n"]
    assert model.Ts == 10.0 and REPORT["Ts"] == 10.0
    # The CLI defaults name this file and its size.
    from ltv_lstm_mpc.cli.main import QUADTANK_MODEL as CLI_MODEL
    from ltv_lstm_mpc.training.cli import QUADTANK_NEURONS

    assert CLI_MODEL == QUADTANK_MODEL == f"quadtank_lstm_n{QUADTANK_NEURONS}.npz"
    assert model.y_phi_constraint is not None and model.normalization is not None
    low, high = model.y_phi_constraint
    np.testing.assert_array_equal(low, [QUADTANK_LEVEL_CONSTRAINT[0]] * 2)
    np.testing.assert_array_equal(high, [QUADTANK_LEVEL_CONSTRAINT[1]] * 2)
    norm = model.normalization
    np.testing.assert_allclose(norm.u_phi_min, REPORT["normalization"]["u_phi_min"], rtol=1e-15)
    np.testing.assert_allclose(norm.y_phi_max, REPORT["normalization"]["y_phi_max"], rtol=1e-15)


def test_shipped_model_is_certified_as_reported(model) -> None:  # type: ignore[no-untyped-def]
    cert = certify(model)
    assert cert.delta_iss.is_delta_iss and cert.delta_iss.r1 < 0 and cert.delta_iss.r2 < 0
    assert cert.delta_iss.rho_A_delta == pytest.approx(REPORT["rho_A_delta"], abs=1e-12)
    assert cert.lyapunov.rho_s == pytest.approx(REPORT["rho_s"], abs=1e-12)
    assert REPORT["rho_A_delta"] < 1 and REPORT["rho_s"] < 1
    # The benchmark's tuning leaves an admissible set-point box that holds its set-points.
    bench = certify(model, QUADTANK_CONFIG.certification_settings(model))
    assert bench.y0_interval_phi is not None
    low, high = bench.y0_interval_phi
    for scenario in quadtank_scenarios():
        assert np.all(scenario.setpoints >= low) and np.all(scenario.setpoints <= high)


def test_shipped_model_reaches_its_reported_fit_on_regenerated_test_data(model) -> None:  # type: ignore[no-untyped-def]
    meta = REPORT["dataset"]
    u, y = generate_split(
        "test", seed=meta["seed"], sequences=meta["sequences"], steps=meta["steps"],
        split_sizes=tuple(meta["split_sizes"]), plant=QuadrupleTankPlant(),
        min_hold=meta["hold_range"][0], max_hold=meta["hold_range"][1],
        levels=meta.get("levels", 0),
    )  # fmt: skip
    pred = simulate_sequences(model, u, meta["u_phi_initial"])
    fits = [fit_index(y[..., j], pred[..., j]) for j in range(2)]
    np.testing.assert_allclose(fits, REPORT["fit_per_output"]["test"], atol=1e-9)
    assert min(fits) == pytest.approx(REPORT["fit"]["test"], abs=1e-9)
    assert min(fits) > 90.0


@pytest.mark.parametrize("solver", backend_params("daqp", "clarabel"))
def test_short_mimo_closed_loop_is_offset_free_without_violations(model, solver: str) -> None:  # type: ignore[no-untyped-def]
    """Levels driven apart (the coupling direction), then a leak in tank 1."""
    length = 250
    scenario = QuadTankScenario(
        name="short",
        title="short",
        setpoints=np.tile([13.0, 11.0], (2 * length, 1)),
        leaks=np.vstack([np.zeros((length, 2)), np.tile([0.002, 0.0], (length, 1))]),
        config=QUADTANK_CONFIG,
        setpoint_rate_limit=0.01,
        segments=[(0, length), (length, 2 * length)],
    )
    result = run_quadtank_scenario(scenario, model, solver=solver)
    summary = result.summary()
    tolerance = OFFSET_TOLERANCE_FRACTION * (
        QUADTANK_LEVEL_CONSTRAINT[1] - QUADTANK_LEVEL_CONSTRAINT[0]
    )
    offsets = np.array(summary["segment_offsets"])
    assert offsets.shape == (2, 2) and np.all(offsets < tolerance), offsets
    assert summary["offset_free"] and summary["constraint_violation_steps"] == 0
    assert summary["infeasible_steps"] == 0 and summary["d_hat_saturated_steps"] == 0
    assert summary["transcription"] == "condensed"
    sim = result.simulation
    # Both pumps moved apart to drive the levels apart, and d_hat took up the leak.
    assert sim.u_phi[length - 1, 0] > sim.u_phi[0, 0] + 0.2
    assert sim.u_phi[length - 1, 1] < sim.u_phi[0, 1] - 0.2
    assert sim.u_phi[-1, 0] > sim.u_phi[length - 1, 0] + 0.02
    assert abs(sim.d_hat[-1, 0] - sim.d_hat[length - 1, 0]) > 1e-3


def test_cli_certify_prints_the_mimo_numbers(model, capsys) -> None:  # type: ignore[no-untyped-def]
    assert main(["certify", QUADTANK_MODEL]) == 0
    out = capsys.readouterr().out
    cert = certify(model)
    line = next(row for row in out.splitlines() if row.strip().startswith("y0_interval_phi"))
    numbers = [float(v) for v in re.findall(r"-?\d+\.\d+(?:e-?\d+)?", line)]
    assert cert.y0_interval_phi is not None
    expected = np.concatenate(cert.y0_interval_phi).ravel()  # [[low1, low2], [high1, high2]]
    np.testing.assert_allclose(np.array(numbers), expected, rtol=1e-5)
    rho = next(row for row in out.splitlines() if row.strip().startswith("rho_A_delta"))
    assert float(rho.split()[-1]) == pytest.approx(cert.delta_iss.rho_A_delta, rel=1e-5)
    assert "L_d=[[0.01, 0], [0, 0.01]]" in out


def test_cli_simulate_quadtank_runs_briefly(tmp_path: Path, capsys) -> None:  # type: ignore[no-untyped-def]
    code = main(
        ["simulate", "--plant", "quadtank", "--solver", "daqp", "--segment", "200", "--L-d", "0.1",
         "--setpoints", "13,11", "13,11", "--disturbances", "0,0", "0.002,0", "--no-progress",
         "--max-offset", "0.016", "--out", str(tmp_path)]
    )  # fmt: skip
    out = capsys.readouterr().out
    assert code == 0, out
    rows = [line.split() for line in out.splitlines() if re.match(r"\s+\d+\s+\d", line)]
    offsets = np.array([[float(v) for v in row[1:]] for row in rows])
    assert offsets.shape == (2, 2) and np.all(offsets < 0.016)
    assert "constraint violations 0 steps" in out
    summary = json.loads((tmp_path / "simulate.json").read_text())
    assert summary["constraint_violation_steps"] == 0 and summary["outputs"] == 2
    assert (tmp_path / "simulate.png").stat().st_size > 1000


def test_cli_reproduce_quadtank_short(tmp_path: Path, capsys) -> None:  # type: ignore[no-untyped-def]
    code = main(
        ["reproduce", "--benchmark", "quadtank", "--short", "--only", "2_leak", "--solver",
         "daqp", "--no-progress", "--no-plots", "--out", str(tmp_path)]
    )  # fmt: skip
    out = capsys.readouterr().out
    assert code == 0, out
    assert "2_leak" in out and "rho_A_delta" in out and "admissible set-points h1" in out
    summary = json.loads((tmp_path / "summary.json").read_text())
    (only,) = summary["scenarios"]
    assert only["solver"] == "daqp" and only["constraint_violation_steps"] == 0
    assert (tmp_path / "2_leak_daqp.csv").exists()


@pytest.mark.slow
def test_full_benchmark_is_offset_free_on_both_paths(model) -> None:  # type: ignore[no-untyped-def]
    from ltv_lstm_mpc.benchmarks.quadtank import reproduce_quadtank

    report = reproduce_quadtank(model, progress=False, plot=False)
    for summary in report["scenarios"]:
        assert summary["offset_free"], summary["segment_offsets"]
        assert summary["constraint_violation_steps"] == 0


def test_cli_refuses_a_single_output_model_on_the_quadruple_tank(capsys) -> None:  # type: ignore[no-untyped-def]
    code = main(["simulate", "--plant", "quadtank", "--model", "ph_lstm_n5.npz", "--no-progress"])
    assert code == 2
    error = capsys.readouterr().err
    assert "2 input(s) and 2 output(s) (v1 (V), v2 (V) -> h1 (cm), h2 (cm))" in error
    assert "this model has m = 1, p = 1: use --plant lstm, or --model quadtank_lstm_n8.npz" in error
    code = main(["reproduce", "--benchmark", "quadtank", "--model", "ph_lstm_n5.npz", "--short"])
    assert code == 1
    assert "m = 1, p = 1" in capsys.readouterr().err
