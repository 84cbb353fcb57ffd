"""The paper's scenarios: `reproduce`, `simulate` and their outputs."""

from __future__ import annotations

import csv
import json

import numpy as np
import pytest
from optional_extras import requires_solver

from ltv_lstm_mpc import load_model
from ltv_lstm_mpc.cli.main import main
from ltv_lstm_mpc.paper.reproduce import reproduce
from ltv_lstm_mpc.paper.scenarios import paper_scenarios

SUMMARY_KEYS = {"max_output_violation", "infeasible_steps", "final_offset", "median_step_time_s"}


@pytest.fixture(scope="module")
def model():
    return load_model("ph_lstm_n5.npz")


@pytest.mark.parametrize("short", [False, True])
def test_scenarios_are_well_formed(model, short) -> None:
    scenarios = paper_scenarios(model, short=short)
    assert [s.name[0] for s in scenarios] == ["1", "2", "3", "4", "5"]
    for s in scenarios:
        assert s.setpoints.shape == s.disturbances.shape == (s.steps,)
        assert s.segments[-1][1] == s.steps
        low, high = 6.0, 9.0
        assert np.all((s.setpoints > low) & (s.setpoints < high))
    if short:
        return
    first = scenarios[0]
    # Theorem 3's conditions: rate limit from the certificate, |w| within w_max (in pH).
    assert first.setpoint_rate_limit is not None and first.setpoint_rate_limit < 0.01
    assert first.config.L_d == 0.01
    assert np.max(np.abs(np.diff(first.disturbances))) <= 1e-4


def test_reproduce_short_scenario_1_writes_everything(model, tmp_path) -> None:
    report = reproduce(model, tmp_path, only=["1_"], short=True, progress=False)
    (summary,) = report["scenarios"]
    assert SUMMARY_KEYS <= set(summary)
    assert summary["max_output_violation"] == 0.0
    assert summary["infeasible_steps"] == 0
    for suffix in (".png", ".csv", ".json"):
        assert (tmp_path / f"1_lstm_theorem3{suffix}").stat().st_size > 0
    data = json.loads((tmp_path / "summary.json").read_text())
    assert data["scenarios"][0]["name"] == "1_lstm_theorem3"
    assert data["certificates"]["paper"]["rho_s"] == 0.92
    with (tmp_path / "1_lstm_theorem3.csv").open() as handle:
        rows = list(csv.DictReader(handle))
    assert len(rows) == summary["steps"]
    y = np.array([float(r["y_phi"]) for r in rows])
    assert np.all((y >= 6.0) & (y <= 9.0))


@requires_solver("osqp")
def test_cli_reproduce(tmp_path, capsys) -> None:
    assert main(["reproduce", "--short", "--only", "3_", "--out", str(tmp_path), "--no-progress",
                 "--no-plots", "--solver", "osqp"]) == 0  # fmt: skip
    out = capsys.readouterr().out
    assert "3_lstm_steps" in out and "rho_s" in out
    summary = json.loads((tmp_path / "summary.json").read_text())["scenarios"][0]
    assert summary["infeasible_steps"] > 0  # set-point steps: the fallback is exercised
    assert summary["fallback_steps"] == summary["infeasible_steps"]
    assert summary["solver"] == "osqp"


def test_cli_simulate_and_reproduce_of_no_scenario(capsys) -> None:
    assert main(["simulate", "--plant", "lstm", "--setpoints", "7.2", "7.0", "--segment", "60",
                 "--no-progress", "--solver", "daqp"]) == 0  # fmt: skip
    assert "simulate" in capsys.readouterr().out
    assert main(["reproduce", "--only", "nothing"]) == 1


@pytest.mark.slow
def test_full_reproduction_meets_the_targets(model, tmp_path) -> None:
    report = reproduce(model, tmp_path, progress=False)
    by_name = {s["name"]: s for s in report["scenarios"]}
    for summary in report["scenarios"]:
        assert summary["max_output_violation"] == 0.0
    assert by_name["1_lstm_theorem3"]["infeasible_steps"] == 0
    assert by_name["1_lstm_theorem3"]["final_offset"] < 1e-3
    assert by_name["2_lstm_larger"]["infeasible_steps"] == 0
    assert by_name["3_lstm_steps"]["infeasible_steps"] > 0
    for name in ("4_ph_small_Ld", "5_ph_large_Ld"):
        assert by_name[name]["final_offset"] < 1e-3  # offset-free on the pH plant


def test_scenario_1_segments_fit_the_rate_limit(model) -> None:
    """Each set-point of scenario 1 is reached by the rate-limited ramp and then held for
    at least SETTLE_SAMPLES: the paper's 900/900/900/600 samples where the ramp fits in
    them, longer segments for a smaller rate bound (the shipped model's K_bar = 12.2 gives
    1081/1257/1433/905)."""
    from ltv_lstm_mpc.paper.scenarios import SETTLE_SAMPLES

    scenario = paper_scenarios(model)[0]
    lengths = [end - start for start, end in scenario.segments]
    assert lengths == [1081, 1257, 1433, 905]
    levels = [7.0, *[scenario.setpoints[start] for start, _ in scenario.segments]]
    jumps = np.abs(np.diff(model.normalize_y(np.array(levels)).ravel()))
    ramps = np.ceil(jumps / scenario.setpoint_rate_limit)
    assert np.all(np.array(lengths) >= ramps + SETTLE_SAMPLES)
    np.testing.assert_array_equal(lengths, np.maximum([900, 900, 900, 600], ramps + SETTLE_SAMPLES))
