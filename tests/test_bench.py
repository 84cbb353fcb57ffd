"""Benchmark command in smoke mode: the CSV has the columns and sane values."""

from __future__ import annotations

import argparse
import csv
import importlib.util
import math

import numpy as np
import pytest
from ltv_lstm_mpc.solvers import available_solvers

from ltv_lstm_mpc.solver_comparison import harness as bench

HAS_CASADI = importlib.util.find_spec("casadi") is not None
#: The exact-cone backend of the smoke run, where the extra `solvers` is installed.
CONE = ["cvxpy:CLARABEL"] if "cvxpy:CLARABEL" in available_solvers() else []


def _main(argv: list[str]) -> int:
    parser = argparse.ArgumentParser()
    bench.register(parser.add_subparsers())
    args = parser.parse_args(argv)
    return int(args.func(args))


def test_bench_smoke_writes_sane_csv(tmp_path) -> None:
    backends = ["daqp", "daqp@sparse", *CONE, *(["ipopt"] if HAS_CASADI else [])]
    out = tmp_path / "bench"
    code = _main(
        ["bench", "--smoke", "--steps", "15", "--quiet", "--out", str(out), "--backends", *backends]
    )
    assert code == 0
    with open(out / "bench.csv", newline="") as handle:
        reader = csv.DictReader(handle)
        assert tuple(reader.fieldnames or ()) == bench.CSV_COLUMNS
        rows = {row["backend"]: row for row in reader}
    assert set(rows) == set(backends)
    for row in rows.values():
        assert row["error"] == ""
        assert int(row["steps"]) == 15 and row["N"] == "5"
        median, p95, peak = (
            float(row[c]) for c in ("step_median_us", "step_p95_us", "step_max_us")
        )
        assert 0 < median <= p95 <= peak
        assert float(row["solve_median_us"]) > 0 and float(row["build_median_us"]) > 0
        assert float(row["ratio_to_fastest"]) >= 1.0
        counts = dict(item.split(":") for item in row["status_counts"].split(";"))
        assert sum(int(v) for v in counts.values()) == 15
        assert int(row["plant_violation_steps"]) == 0
        assert int(row["infeasible_steps"]) <= int(row["fallback_steps"]) + 15
    assert min(float(r["ratio_to_fastest"]) for r in rows.values()) == 1.0
    assert "terminal_box" in rows["daqp"]["reformulation"]
    assert rows["daqp"]["family"] == "condensed" and rows["daqp@sparse"]["family"] == "sparse"
    for name in CONE:
        assert rows[name]["reformulation"] == ""  # exact cones
    for row in rows.values():
        assert np.isfinite(float(row["prepare_median_us"]))
        assert np.isfinite(float(row["feedback_median_us"]))
    if HAS_CASADI:
        assert rows["ipopt"]["family"] == "nonlinear"
        assert float(rows["ipopt"]["ratio_to_nmpc"]) == 1.0
        for name in ("daqp", "daqp@sparse", *CONE):
            assert float(rows[name]["u0_diff_max"]) < 1e-2  # mL/s
            assert abs(float(rows[name]["cost_diff_pct"])) < 1.0
            # a ratio, not a speed claim: 15 steps on a fresh install may run the numpy
            # kernels while the compiled ones build in the background (bench measures speed)
            assert 0.0 < float(rows[name]["ratio_to_nmpc"]) < math.inf
    assert (out / "bench.md").read_text().count("\n|") >= len(rows) + 1
    assert (out / "bench_N5.png").stat().st_size > 0


def test_unknown_backend_is_a_clear_error(tmp_path) -> None:
    model = bench.LSTMModel.load(bench_model_path())
    scenario = bench.standin_scenario(model, steps=5)
    rows = bench.run_bench(model, scenarios=[scenario], horizons=[5], backends=["daqp"], steps=5)
    assert len(rows) == 1 and rows[0]["steps"] == 5 and rows[0]["family"] == "condensed"
    with pytest.raises(bench.InvalidValueError, match="daqp"):  # lists the valid names
        bench.run_bench(model, scenarios=[scenario], horizons=[5], backends=["fast:x"], steps=5)


def bench_model_path():
    from ltv_lstm_mpc.lstm.shipped import shipped_path

    return shipped_path("ph_lstm_n5.npz")


def test_bench_reports_overhead_and_the_ratio_to_the_numpy_kernel(tmp_path) -> None:
    out = tmp_path / "bench"
    argv = ["bench", "--smoke", "--steps", "12", "--quiet", "--out", str(out),
            "--backends", "daqp", "--numpy-kernel"]  # fmt: skip
    assert _main(argv) == 0
    with open(out / "bench.csv", newline="") as handle:
        (row,) = list(csv.DictReader(handle))
    step, solve = float(row["step_median_us"]), float(row["solve_median_us"])
    overhead = float(row["overhead_median_us"])
    assert 0 < overhead < step and solve > 0
    numpy_step = float(row["step_numpy_median_us"])
    assert float(row["ratio_to_numpy"]) == pytest.approx(step / numpy_step, rel=1e-12)
    assert "÷numpy kernel" in (out / "bench.md").read_text()
