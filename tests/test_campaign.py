"""Campaigns: spec validation, one task = one closed loop, resume, faults, Dask, report."""

from __future__ import annotations

import csv
import json
import math
import subprocess
import sys
import textwrap
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from optional_extras import requires_solver

from ltv_lstm_mpc.campaign import load_spec, parse_spec, run_campaign
from ltv_lstm_mpc.campaign.store import ResultStore
from ltv_lstm_mpc.campaign.task import run_task, task_key
from ltv_lstm_mpc.campaign.testing import (
    CountingTask,
    CrashOnce,
    RaisingTask,
    executions,
)
from ltv_lstm_mpc.cli.main import main
from ltv_lstm_mpc.exceptions import CampaignSpecError
from ltv_lstm_mpc.mpc.config import DEFAULT_L_D

#: Columns that hold wall times (differ between runs).
TIMING = {
    "wall_s",
    "setup_s",
    "median_step_s",
    "p95_step_s",
    "max_step_s",
    "median_mpc_s",
    "started_at",
    "finished_at",
    "worker",
}


def tiny(**factors: Any) -> dict[str, Any]:
    """A pH campaign of 30-step closed loops (about 0.05 s each); factors replace fixed ones."""
    factors = factors or {"noise_std": [0.0, 0.02], "seed": [0, 1]}
    campaign = {
        "name": "tiny",
        "plant": "ph",
        "steps": 30,
        "setpoints": [7.4, 7.2],
        "q2": [0.55, 0.65],
        "solver": "daqp",
        "trace": {"seed": [0]},
    }
    return {
        "campaign": {k: v for k, v in campaign.items() if k not in factors},
        "factors": factors,
    }


def untimed(row: dict[str, Any]) -> dict[str, Any]:
    return {k: v for k, v in row.items() if k not in TIMING}


def read_trace(out: Path, key: str) -> dict[str, np.ndarray]:
    """The trace of task ``key``: its Parquet file, or the CSV written without pyarrow
    (extra `campaign`), numeric columns as floats."""
    stem = out / "traces" / key
    if stem.with_suffix(".parquet").exists():
        import pyarrow.parquet as pq

        table = pq.read_table(stem.with_suffix(".parquet"))
        return {name: np.asarray(table.column(name).to_pylist()) for name in table.column_names}
    with open(stem.with_suffix(".csv"), newline="") as handle:
        rows = list(csv.DictReader(handle))
    trace = {}
    for name in rows[0]:
        column = [row[name] for row in rows]
        try:
            trace[name] = np.array([float(cell) for cell in column])
        except ValueError:
            trace[name] = np.asarray(column)
    return trace


# ----------------------------------------------------------------------------- spec


def test_spec_tasks_are_the_product_in_order_with_stable_keys() -> None:
    spec = parse_spec(tiny(noise_std=[0, 0.02, 0.05], seed=[0, 1]))
    assert len(spec.tasks) == 6
    assert [(t.settings["noise_std"], t.settings["seed"]) for t in spec.tasks] == [
        (0.0, 0),
        (0.0, 1),
        (0.02, 0),
        (0.02, 1),
        (0.05, 0),
        (0.05, 1),
    ]
    assert isinstance(spec.tasks[0].settings["noise_std"], float)  # 0 -> 0.0: one key
    assert len({t.key for t in spec.tasks}) == 6
    assert [t.key for t in parse_spec(tiny(noise_std=[0.0, 0.02, 0.05], seed=[0, 1])).tasks] == [
        t.key for t in spec.tasks
    ]
    first = spec.tasks[0]
    settings = first.settings
    assert task_key(settings, model_sha256=first.model_sha256) == first.key
    assert task_key(settings, version="999.0", model_sha256=first.model_sha256) != first.key
    assert task_key(settings) != first.key  # the model file's digest is part of the key
    assert [t.trace for t in spec.tasks] == [True, False] * 3
    assert spec.varying == ["noise_std", "seed"]
    # defaults filled in
    assert settings["N"] == 5 and settings["L_d"] == DEFAULT_L_D and settings["mismatch"] == {}


def test_a_retrained_model_makes_new_tasks_and_travels_with_them(tmp_path) -> None:
    """The key holds the model file's SHA-256 (a model retrained in place is not served
    from the old results) and a model file travels inside its tasks (remote workers)."""
    from ltv_lstm_mpc import load_model
    from ltv_lstm_mpc.campaign.task import load_task_model

    shipped = load_model("ph_lstm_n5.npz")
    path = tmp_path / "m.npz"
    shipped.save(path)
    first = parse_spec(tiny(model=[str(path)])).tasks[0]
    assert first.model_bytes == path.read_bytes()
    np.testing.assert_array_equal(load_task_model(first).W_y, shipped.W_y)
    other = load_model("ph_lstm_n5.npz")
    other.W_y = other.W_y * 1.01
    other.save(path)
    second = parse_spec(tiny(model=[str(path)])).tasks[0]
    assert second.settings == first.settings and second.key != first.key
    assert parse_spec(tiny()).tasks[0].model_bytes is None  # shipped: workers have it


def test_spec_checks_combinations_before_running() -> None:
    with pytest.raises(CampaignSpecError, match=r"q2.*>= 0"):
        parse_spec(tiny(q2=[[0.55, -0.5]]))
    with pytest.raises(CampaignSpecError, match=r"transcription.*nonlinear"):
        parse_spec(tiny(transcription=["nonlinear"]))
    with pytest.raises(CampaignSpecError, match=r"model.*p = 2 outputs"):
        parse_spec(tiny(model=["quadtank_lstm_n8.npz"]))
    nominal = parse_spec(tiny(mismatch=[{}, {"A1": 1.0}]))
    assert len(nominal.tasks) == 1  # a scale factor of 1 is the nominal plant


def test_cases_multiply_the_factors_and_installed_expands() -> None:
    from ltv_lstm_mpc.solvers import available_solvers

    data = tiny(seed=[0, 1])
    data["cases"] = [{"mismatch": {}}, {"mismatch": {"W_a1": 1.1, "A1": 0.9}}]
    spec = parse_spec(data)
    assert [(t.settings["mismatch"], t.settings["seed"]) for t in spec.tasks] == [
        ({}, 0),
        ({}, 1),
        ({"A1": 0.9, "W_a1": 1.1}, 0),
        ({"A1": 0.9, "W_a1": 1.1}, 1),
    ]
    assert spec.varying == ["seed", "mismatch"]
    spec = parse_spec(tiny(solver=["daqp", "installed"]))
    expected = ["daqp", *(name for name in available_solvers() if name != "daqp")]
    assert [t.settings["solver"] for t in spec.tasks] == expected  # each once, first mention


@pytest.mark.parametrize(
    ("edit", "field", "hint"),
    [
        (lambda d: d["campaign"].update(noise=0.1), "[campaign].noise", "unknown setting"),
        (lambda d: d["factors"].update(N=5), "[factors].N", "write N = [5]"),
        (lambda d: d["factors"].update(L_d=[]), "[factors].L_d", "empty list"),
        (lambda d: d["factors"].update(L_d=[0.1, 3.0]), "[factors].L_d[1]", "< 2"),
        (
            lambda d: d["factors"].update(solver=["daqp", "nosuch"]),
            "[factors].solver[1]",
            "installed:",
        ),
        (
            lambda d: d["campaign"].update(plant="cstr"),
            "[campaign].plant",
            "use one of lstm, ph, quadtank",
        ),
        (lambda d: d["campaign"].update(steps=2.5), "[campaign].steps", "integer"),
        (lambda d: d["campaign"].update(setpoints=[7.0, "x"]), "[campaign].setpoints", "entry 1"),
        (lambda d: d["campaign"].update(plant="lstm"), "[campaign].q2", "use disturbances"),
        (lambda d: d["campaign"].pop("steps"), "[campaign].steps", "required"),
        (
            lambda d: d["factors"].update(mismatch=[{"W_x": 1.1}]),
            "[factors].mismatch[0]",
            "unknown pH-plant parameter",
        ),
        (
            lambda d: d["factors"].update(mismatch=[{"W_b1": 1.1}]),
            "[factors].mismatch[0]",
            "0 in the nominal plant",
        ),
        (
            lambda d: d["campaign"].update(scenario="4_ph_small_Ld"),
            "[campaign].plant",
            "fixes its own",
        ),
        (
            lambda d: d["factors"].update(scenario=["nope"]),
            "[factors].scenario[0]",
            "5_ph_large_Ld",
        ),
        (
            lambda d: d["campaign"].update(trace={"colour": [1]}),
            "[campaign].trace.colour",
            "unknown setting",
        ),
        (lambda d: d["factors"].update(steps=[30]), "[factors].steps", "also set in [campaign]"),
        (lambda d: d["campaign"].update(solver="installed"), "[campaign].solver", "installed:"),
        (lambda d: d.update(extra={}), "[extra]", "unknown table"),
    ],
)
def test_spec_errors_name_the_bad_field(edit: Any, field: str, hint: str) -> None:
    data = tiny()
    edit(data)
    with pytest.raises(CampaignSpecError) as caught:
        parse_spec(data)
    assert caught.value.field == field
    assert str(caught.value).startswith(field)
    assert hint in str(caught.value)


def test_load_spec_reports_bad_toml_and_resolves_models_next_to_the_spec(tmp_path) -> None:
    from ltv_lstm_mpc.lstm.shipped import shipped_path

    bad = tmp_path / "bad.toml"
    bad.write_text("[campaign]\nsteps = = 3\n")
    with pytest.raises(CampaignSpecError, match="not valid TOML"):
        load_spec(bad)
    (tmp_path / "m.npz").write_bytes(shipped_path("ph_lstm_n5.npz").read_bytes())
    good = tmp_path / "good.toml"
    good.write_text('[campaign]\nmodel = "m.npz"\nsteps = 10\nsetpoints = [7.2]\n')
    spec = load_spec(good)
    assert spec.name == "good"
    assert spec.tasks[0].model_location == str((tmp_path / "m.npz").resolve())
    assert spec.tasks[0].settings["model"] == "m.npz"  # the key does not depend on the folder
    good.write_text('[campaign]\nmodel = "absent.npz"\nsteps = 10\nsetpoints = [7.2]\n')
    with pytest.raises(CampaignSpecError, match=r"\[campaign\].model: no model file"):
        load_spec(good)


# ----------------------------------------------------------------------------- one task


def test_task_metrics_agree_with_its_trace_and_noise_is_common_random_numbers(tmp_path) -> None:
    data = tiny(noise_std=[0.0, 0.02, 0.05], seed=[0])
    run = run_campaign(parse_spec(data), tmp_path, serial=True, progress=False, report=False)
    assert run.executed == 3 and run.errors == 0
    traces = {row["noise_std"]: read_trace(tmp_path, row["key"]) for row in run.rows}
    for row in run.rows:
        trace = traces[row["noise_std"]]
        error = np.abs(trace["y_phi"] - trace["y0_phi"])
        assert row["segment_offsets"] == json.dumps([error[14], error[29]])
        assert row["final_offset"] == max(error[14], error[29])
        low, high = 6.0, 9.0
        outside = np.maximum(np.maximum(low - trace["y_phi"], trace["y_phi"] - high), 0)
        assert row["violations"] == int(np.sum(outside > 1e-9))
        assert row["median_step_s"] == pytest.approx(np.median(trace["time_total_s"]))
        assert row["closed_loop_cost"] == pytest.approx(np.mean(error**2))
        assert row["steps_done"] == 30 and row["optimal_steps"] == 30
        assert row["status"] == "ok" and row["attempts"] == 1 and row["error"] == ""
        assert row["transcription_used"] == "condensed"
    clean = traces[0.0]
    np.testing.assert_array_equal(clean["y_measured_phi"], clean["y_phi"])
    z2 = (traces[0.02]["y_measured_phi"] - traces[0.02]["y_phi"]) / 0.02
    z5 = (traces[0.05]["y_measured_phi"] - traces[0.05]["y_phi"]) / 0.05
    np.testing.assert_allclose(z2, z5, atol=1e-9)  # same seed, same noise sequence
    np.testing.assert_allclose(z2, np.random.default_rng(0).standard_normal(31)[:30], atol=1e-9)
    assert run.rows[0]["final_offset"] != run.rows[2]["final_offset"]  # noise matters


def test_mismatch_changes_the_plant_and_scenario_tasks_match_the_paper_scenarios(
    tmp_path,
) -> None:
    from ltv_lstm_mpc.lstm.shipped import load_model
    from ltv_lstm_mpc.paper.scenarios import paper_scenarios, run_scenario
    from ltv_lstm_mpc.plants.ph import PHNeutralizationPlant, PHParameters

    data = tiny(mismatch=[{}, {"W_a1": 1.1}])
    data["campaign"]["L_d"] = 0.1  # d_hat moves fast enough to saturate in 30 steps
    spec = parse_spec(data)
    nominal, mismatched = (run_task(t).row for t in spec.tasks)
    assert mismatched["mismatch"] == "W_a1*1.1" and nominal["mismatch"] == "nominal"
    plant = PHNeutralizationPlant(params=PHParameters(W_a1=3.3e-3))
    assert plant.output()[0] < PHNeutralizationPlant().output()[0] - 0.3
    assert mismatched["d_hat_saturated_steps"] > nominal["d_hat_saturated_steps"]

    spec = parse_spec(
        {"campaign": {"scenario": "ph_large_Ld", "short": True, "solver": "daqp", "N": 5}}
    )
    (task,) = spec.tasks
    assert task.settings["scenario"] == "5_ph_large_Ld" and "L_d" not in task.settings
    row = run_task(task).row
    model = load_model("ph_lstm_n5.npz")
    (scenario,) = [s for s in paper_scenarios(model, short=True) if s.name == "5_ph_large_Ld"]
    reference = run_scenario(scenario, model, solver="daqp", N=5).summary()
    assert (row["plant"], row["steps"], row["L_d"]) == ("ph", scenario.steps, 0.1)
    assert row["final_offset"] == pytest.approx(reference["final_offset"], abs=1e-12)
    assert row["infeasible_steps"] == reference["infeasible_steps"]
    assert json.loads(row["segment_offsets"]) == pytest.approx(reference["segment_offsets"])


def test_lstm_plant_task_starts_where_simulate_does(tmp_path) -> None:
    """Without y0_initial the LSTM plant of a campaign task starts in the middle of the
    controller's admissible set-point interval, as simulate's (paper.scenarios.initial_output),
    not at the equilibrium of the mid-range input."""
    from ltv_lstm_mpc import MPCConfig, OffsetFreeController
    from ltv_lstm_mpc.lstm.shipped import load_model
    from ltv_lstm_mpc.paper.scenarios import initial_output

    data = {
        "campaign": {
            "plant": "lstm",
            "steps": 10,
            "setpoints": [7.2],
            "disturbances": [0.0],
            "solver": "daqp",
            "trace": True,
        }
    }
    run = run_campaign(parse_spec(data), tmp_path, serial=True, progress=False, report=False)
    (row,) = run.rows
    trace = read_trace(tmp_path, row["key"])
    model = load_model("ph_lstm_n5.npz")
    controller = OffsetFreeController(model, MPCConfig(solver="daqp", L_d=DEFAULT_L_D))
    expected = initial_output(model, controller.certification)
    assert abs(expected - 7.0) > 0.1  # not the mid-range input's equilibrium (about 7.0 pH)
    assert trace["y_phi"][0] == pytest.approx(expected, abs=1e-8)


def test_lstm_plant_task_applies_its_output_disturbance_schedule(tmp_path) -> None:
    data = {
        "campaign": {
            "plant": "lstm",
            "steps": 30,
            "setpoints": [7.2],
            "disturbances": [0.0, 0.05],
            "y0_initial": 7.1,
            "solver": "daqp",
            "trace": True,
        }
    }
    run = run_campaign(parse_spec(data), tmp_path, serial=True, progress=False, report=False)
    (row,) = run.rows
    trace = read_trace(tmp_path, row["key"])
    assert row["plant"] == "lstm" and row["status"] == "ok"
    assert trace["y_phi"][0] == pytest.approx(7.1, abs=1e-8)
    np.testing.assert_array_equal(trace["d_phi"], [0.0] * 15 + [0.05] * 15)
    assert json.loads(row["segment_offsets"]) == pytest.approx(
        [abs(trace["y_phi"][k] - 7.2) for k in (14, 29)]
    )


# ----------------------------------------------------------------------------- faults, resume


def test_raising_task_is_recorded_after_one_retry_and_the_rest_complete(tmp_path) -> None:
    spec = parse_spec(tiny())
    calls = tmp_path / "calls"
    function = CountingTask(calls, RaisingTask({"seed": 1}))
    run = run_campaign(spec, tmp_path / "out", serial=True, progress=False, task_function=function)
    by_seed = {(r["noise_std"], r["seed"]): r for r in run.rows}
    assert run.errors == 2 and len(run.rows) == 4
    for (_, seed), row in by_seed.items():
        assert row["status"] == ("error" if seed == 1 else "ok")
    failed = [r for r in run.rows if r["status"] == "error"]
    assert all("RuntimeError: injected failure for {'seed': 1}" in r["error"] for r in failed)
    assert all(r["attempts"] == 2 and r["final_offset"] is None for r in failed)
    counts = executions(calls)
    assert sorted(counts[t.key] for t in spec.tasks) == [1, 1, 2, 2]
    # A rerun skips every stored task; --retry-errors reruns the failed ones only.
    again = run_campaign(spec, tmp_path / "out", serial=True, progress=False, report=False)
    assert (again.executed, again.skipped, again.errors) == (0, 4, 2)
    fixed = run_campaign(
        spec,
        tmp_path / "out",
        serial=True,
        progress=False,
        report=False,
        retry_errors=True,
        task_function=CountingTask(tmp_path / "calls2"),
    )
    assert (fixed.executed, fixed.errors) == (2, 0)
    assert set(executions(tmp_path / "calls2")) == {r["key"] for r in failed}


def test_resume_after_the_process_is_killed_recomputes_only_unfinished_tasks(tmp_path) -> None:
    spec_file = tmp_path / "spec.toml"
    spec_file.write_text(
        textwrap.dedent(
            """
            [campaign]
            steps = 30
            setpoints = [7.4, 7.2]
            solver = "daqp"
            [factors]
            seed = [0, 1, 2, 3, 4, 5]
            noise_std = [0.01]
            """
        )
    )
    out = tmp_path / "out"
    script = (
        "import sys; from ltv_lstm_mpc.campaign import load_spec, run_campaign; "
        "from ltv_lstm_mpc.campaign.testing import ExitAfter; "
        "run_campaign(load_spec(sys.argv[1]), sys.argv[2], serial=True, progress=False, "
        "task_function=ExitAfter(sys.argv[3], 4))"
    )
    killed = subprocess.run(
        [sys.executable, "-c", script, str(spec_file), str(out), str(tmp_path / "started")],
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert killed.returncode == 71, killed.stderr[-2000:]  # died inside the 4th task
    spec = load_spec(spec_file)
    store = ResultStore(out)
    before = store.finished(t.key for t in spec.tasks)
    assert len(before) == 3 and not (out / "results.csv").exists()
    calls = tmp_path / "calls"
    run = run_campaign(
        spec, out, serial=True, progress=False, report=False, task_function=CountingTask(calls)
    )
    assert (run.executed, run.skipped, run.errors) == (3, 3, 0)
    assert set(executions(calls)) == {t.key for t in spec.tasks} - set(before)
    assert all(store.load(key) == row for key, row in before.items())  # finished ones kept
    assert [r["seed"] for r in run.rows] == [0, 1, 2, 3, 4, 5]
    # a corrupt row file (not written by this library's atomic writes) counts as unfinished
    store.row_path(spec.tasks[0].key).write_text('{"key": ')
    run = run_campaign(spec, out, serial=True, progress=False, report=False)
    assert (run.executed, run.skipped) == (1, 5)
    assert not list((out / "tasks").glob(".*.tmp"))


def test_results_tables_hold_every_row(tmp_path) -> None:
    pq = pytest.importorskip("pyarrow.parquet")

    run = run_campaign(parse_spec(tiny()), tmp_path, serial=True, progress=False, report=False)
    table = pq.read_table(tmp_path / "results.parquet").to_pylist()
    assert table == run.rows
    with open(tmp_path / "results.csv", newline="") as handle:
        rows = list(csv.DictReader(handle))
    assert [r["key"] for r in rows] == [r["key"] for r in run.rows]
    assert [float(r["final_offset"]) for r in rows] == [r["final_offset"] for r in run.rows]


# ----------------------------------------------------------------------------- Dask


@pytest.fixture(scope="module")
def cluster() -> Any:
    distributed = pytest.importorskip("distributed")
    with distributed.LocalCluster(
        n_workers=2, threads_per_worker=1, processes=True, dashboard_address=":0"
    ) as local:
        yield local


def test_dask_gives_the_serial_results(tmp_path, cluster) -> None:
    spec = parse_spec(tiny(noise_std=[0.0, 0.03], seed=[0, 1], L_d=[0.01, 0.1]))
    serial = run_campaign(spec, tmp_path / "serial", serial=True, progress=False, report=False)
    dask = run_campaign(
        spec,
        tmp_path / "dask",
        scheduler=cluster.scheduler_address,
        progress=False,
        report=False,
    )
    assert dask.executed == serial.executed == 8 and dask.errors == 0
    assert [untimed(r) for r in dask.rows] == [untimed(r) for r in serial.rows]
    for row in serial.rows[:2]:
        a, b = (
            read_trace(tmp_path / "serial", row["key"]),
            read_trace(tmp_path / "dask", row["key"]),
        )
        np.testing.assert_array_equal(a["y_phi"], b["y_phi"])
        np.testing.assert_array_equal(a["u_phi"], b["u_phi"])


def test_a_worker_killed_during_a_task_still_yields_every_result(tmp_path, cluster) -> None:
    spec = parse_spec(tiny(seed=[0, 1, 2, 3]))
    calls = tmp_path / "calls"
    function = CountingTask(calls, CrashOnce(tmp_path / "markers", {"seed": 2}))
    run = run_campaign(
        spec,
        tmp_path / "out",
        scheduler=cluster.scheduler_address,
        progress=False,
        report=False,
        task_function=function,
    )
    assert run.errors == 0 and [r["seed"] for r in run.rows] == [0, 1, 2, 3]
    (crashed,) = [t for t in spec.tasks if t.settings["seed"] == 2]
    assert (tmp_path / "markers" / f"{crashed.key}.crashed").exists()
    counts = executions(calls)
    assert counts[crashed.key] == 2  # the killed attempt and the rescheduled one
    # a result still in the dead worker's memory (not yet gathered) is recomputed too
    assert set(counts) == {t.key for t in spec.tasks} and set(counts.values()) <= {1, 2}
    reference = run_task(crashed).row
    assert untimed(next(r for r in run.rows if r["seed"] == 2)) == untimed(reference)


def test_raising_task_on_dask_is_recorded(tmp_path, cluster) -> None:
    spec = parse_spec(tiny(seed=[0, 1, 2]))
    run = run_campaign(
        spec,
        tmp_path,
        scheduler=cluster.scheduler_address,
        progress=False,
        report=False,
        task_function=RaisingTask({"seed": 1}),
    )
    assert [r["status"] for r in run.rows] == ["ok", "error", "ok"]
    assert "injected failure" in run.rows[1]["error"] and run.rows[1]["attempts"] == 2


# ----------------------------------------------------------------------------- report, CLI


@requires_solver("quadprog")
def test_report_has_tables_and_plots(tmp_path) -> None:
    data = tiny(solver=["daqp", "quadprog"], N=[3, 5], noise_std=[0.0, 0.02])
    data["campaign"]["trace"] = False
    run = run_campaign(parse_spec(data), tmp_path, serial=True, progress=False)
    report = (tmp_path / "report.md").read_text()
    assert "8 tasks: 8 ok, 0 errors" in report
    for name in ("solver", "N", "noise_std"):
        assert f"## By `{name}`" in report
        png = tmp_path / "plots" / f"by_{name}.png"
        assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert "| daqp | 4 | 0 |" in report and "| quadprog | 4 | 0 |" in report
    mean = np.mean([r["final_offset"] for r in run.rows if r["noise_std"] == 0.02])
    assert f"| 0.02 | 4 | 0 | {mean:.3g} /" in report
    for name in ("violations_vs_noise", "step_time_heatmap"):
        assert (tmp_path / "plots" / f"{name}.png").stat().st_size > 1000
        assert f"(plots/{name}.png)" in report
    assert not list((tmp_path / "traces").iterdir())


def test_cli_dry_run_run_resume_and_usage_errors(tmp_path, capsys) -> None:
    spec = tmp_path / "spec.toml"
    spec.write_text(
        '[campaign]\nsteps = 30\nsetpoints = [7.3]\nsolver = "daqp"\n[factors]\nseed = [0, 1]\n'
    )
    out = tmp_path / "out"
    assert main(["campaign", str(spec), "--out", str(out), "--dry-run", "--serial"]) == 0
    printed = capsys.readouterr().out
    assert "2 tasks (0 finished" in printed and "2 to run" in printed
    assert "calibration daqp, N = 5, auto" in printed and "estimated time:" in printed
    assert not (out / "tasks").exists()  # a dry run writes nothing
    assert main(["campaign", str(spec), "--out", str(out), "--serial", "--no-progress"]) == 0
    assert "2 tasks (2 run now, 0 already finished), 0 errors" in capsys.readouterr().out
    assert len(list((out / "tasks").glob("*.json"))) == 2
    assert main(["campaign", str(spec), "--out", str(out), "--serial", "--no-progress"]) == 0
    assert "(0 run now, 2 already finished)" in capsys.readouterr().out
    assert main(["campaign", str(spec), "--out", str(out), "--dry-run", "--serial"]) == 0
    assert "2 finished" in capsys.readouterr().out

    spec.write_text("[campaign]\nsteps = 30\nsetpoints = [7.3]\n[factors]\nN = 5\n")
    assert main(["campaign", str(spec), "--out", str(out), "--serial"]) == 2
    assert "[factors].N: expected a list" in capsys.readouterr().err
    assert main(["campaign", str(tmp_path / "none.toml"), "--out", str(out)]) == 2
    assert main(["campaign", str(spec), "--out", str(out), "--serial", "--workers", "2"]) == 2


def test_cli_runs_on_its_own_local_cluster(tmp_path, capsys) -> None:
    pytest.importorskip("distributed")
    spec = tmp_path / "spec.toml"
    spec.write_text(
        '[campaign]\nsteps = 20\nsetpoints = [7.3]\nsolver = "daqp"\n[factors]\nseed = [0, 1]\n'
    )
    code = main(
        ["campaign", str(spec), "--out", str(tmp_path / "o"), "--workers", "2", "--no-progress"]
    )
    assert code == 0
    assert "2 tasks (2 run now, 0 already finished), 0 errors" in capsys.readouterr().out
    rows = [json.loads(p.read_text()) for p in (tmp_path / "o" / "tasks").glob("*.json")]
    assert sorted(r["seed"] for r in rows) == [0, 1]
    assert all(r["status"] == "ok" and math.isfinite(r["final_offset"]) for r in rows)


def test_a_script_without_the_main_guard_is_told_what_to_do(tmp_path) -> None:
    """run_campaign(workers=2) at a script's top level: each worker process imports the
    script again; the worker says why it stops, and the script's own error names the
    guard (instead of multiprocessing's bootstrapping error and "Nanny failed to start")."""
    pytest.importorskip("distributed")
    script = tmp_path / "unguarded.py"
    script.write_text(
        textwrap.dedent(
            f"""
            from ltv_lstm_mpc.campaign import parse_spec, run_campaign
            spec = parse_spec({tiny(seed=[0, 1])!r})
            run_campaign(spec, {str(tmp_path / "out")!r}, workers=2, progress=False, report=False)
            """
        )
    )
    done = subprocess.run(
        [sys.executable, str(script)], capture_output=True, text=True, timeout=300
    )
    assert done.returncode != 0
    last = done.stderr.strip().splitlines()[-1]
    assert last.startswith("ltv_lstm_mpc.campaign.runner.CampaignError: the LocalCluster")
    assert 'if __name__ == "__main__":' in last
    assert "run_campaign was called while a worker process imported the script" in done.stderr
    assert "bootstrapping phase" not in done.stderr


def test_example_specs_parse() -> None:
    folder = Path(__file__).resolve().parents[1] / "experiments" / "campaigns"
    robustness = load_spec(folder / "ph_robustness.toml")
    assert len(robustness.tasks) == 3 * 3 * 2 * 4 * 10
    assert set(robustness.factors) == {"noise_std", "q2", "L_d", "mismatch", "seed"}


@requires_solver("cvxpy:CLARABEL")  # the spec traces its runs
def test_solver_comparison_spec_parses() -> None:
    folder = Path(__file__).resolve().parents[1] / "experiments" / "campaigns"
    comparison = load_spec(folder / "solver_comparison.toml")
    from ltv_lstm_mpc.solvers import available_solvers

    assert len(comparison.tasks) == len(available_solvers()) * 3 * 5
    assert {t.settings["N"] for t in comparison.tasks} == {5, 20, 50}


def test_tasks_the_cluster_lost_run_again_errors_only_when_asked(tmp_path) -> None:
    """A row with status "lost" (the cluster lost the task: KilledWorker, cancelled) is not a
    result: the next call runs it again; an "error" row (the task raised) is kept unless
    retry_errors."""
    from ltv_lstm_mpc.campaign.task import error_outcome

    spec = parse_spec(tiny())
    out = tmp_path / "out"
    store = ResultStore(out)
    store.prepare(spec.name, [t.key for t in spec.tasks])
    lost, failed = spec.tasks[0], spec.tasks[1]
    store.write(error_outcome(lost, "KilledWorker: ...", attempts=0, wall_s=0.0, status="lost"))
    store.write(error_outcome(failed, "ValueError: ...", attempts=2, wall_s=0.0))
    calls = tmp_path / "calls"
    run = run_campaign(
        spec, out, serial=True, progress=False, report=False, task_function=CountingTask(calls)
    )
    assert set(executions(calls)) == {t.key for t in spec.tasks} - {failed.key}
    assert (run.executed, run.skipped, run.errors) == (len(spec.tasks) - 1, 1, 1)
    run = run_campaign(spec, out, serial=True, progress=False, report=False, retry_errors=True)
    assert (run.executed, run.errors) == (1, 0)


def test_fallback_columns_by_policy_add_up(tmp_path) -> None:
    """fallback_steps = sum of the per-policy columns, "<policy>+shift" included."""
    from ltv_lstm_mpc.campaign.task import METRIC_COLUMNS, run_task

    spec = parse_spec(tiny(setpoints=[[7.4, 8.75]], policy=["soft"], rate_limit=[0.0]))
    row = run_task(spec.tasks[0]).row
    columns = [c for c in METRIC_COLUMNS if c.startswith("fallback_") and c != "fallback_steps"]
    assert "fallback_soft+shift_steps" in columns and "fallback_paper+shift_steps" in columns
    assert row["fallback_steps"] > 0
    assert sum(row[c] for c in columns) == row["fallback_steps"]
    assert row["truncated"] is False


#: Tasks of the interrupted campaigns: about 0.1 s each after the first, so seconds for a
#: signal to land before the campaign ends (it is interrupted: the number costs nothing).
INTERRUPTED_TASKS = 200


def _interrupted_campaign(
    tmp_path, where, signal_it, prelude: str = ""
) -> tuple[int, str, int, Any]:
    """Start ``ltv-lstm-mpc campaign`` (its own process group, as a terminal's job, with a
    terminal's SIGINT disposition; ``prelude``: Python run first in its process), call
    ``signal_it(process, out)`` (which signals it), and return (exit code, stderr, tasks
    stored when signalled, the output folder)."""
    import os
    import signal

    spec = tmp_path / "spec.toml"
    spec.write_text(
        '[campaign]\nsteps = 200\nsetpoints = [7.4, 7.2]\nsolver = "daqp"\n'
        f"[factors]\nseed = {list(range(INTERRUPTED_TASKS))}\n"
    )
    out = tmp_path / "out"
    script = (
        prelude + "\nimport sys\nfrom ltv_lstm_mpc.cli.main import main\n"
        "sys.exit(main(sys.argv[1:]))\n"
    )
    command = ["campaign", str(spec), "--out", str(out), *where, "--no-progress", "--no-report"]
    process = subprocess.Popen(
        [sys.executable, "-c", script, *command],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        start_new_session=True,  # its own process group, signalled like a terminal's
        # a test runner started with & from a script ignores SIGINT, and so would the
        # campaign (Python keeps an inherited SIG_IGN): give it a terminal's default
        preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL),
    )
    try:
        signal_it(process, out)
        signalled = len(list(out.glob("tasks/*.json")))
        _, stderr = process.communicate(timeout=120)
    finally:
        if process.poll() is None:
            os.killpg(process.pid, signal.SIGKILL)
    return process.returncode, stderr, signalled, out


def _check_one_line(code: int, stderr: str, signalled: int, out: Any, where) -> int:
    """Exit code 130, no traceback from any process (the LocalCluster's workers included),
    no leaked semaphore, and last the one line saying what is stored and how to resume;
    returns the tasks stored."""
    import re

    stored_now = len(list(out.glob("tasks/*.json")))
    assert code == 130, (
        f"{stored_now} of {INTERRUPTED_TASKS} tasks stored, {signalled} when signalled; "
        f"stderr: {stderr}"
    )
    assert "Traceback" not in stderr and "KeyboardInterrupt" not in stderr, stderr
    assert "Exception ignored" not in stderr, stderr  # (e.g. a half-built cluster at exit)
    assert "leaked" not in stderr, stderr  # no resource-tracker warning from a killed worker
    lines = [line for line in stderr.splitlines() if line.strip()]
    assert sum("interrupted" in line for line in lines) == 1, stderr
    match = re.fullmatch(
        rf"ltv-lstm-mpc campaign: interrupted; (\d+) of {INTERRUPTED_TASKS} tasks stored in "
        r"(.+); resume with: ltv-lstm-mpc campaign (.+)",
        lines[-1],
    )
    assert match, stderr
    stored = [json.loads(p.read_text()) for p in out.glob("tasks/*.json")]
    assert int(match[1]) == len(stored)
    assert all(row["status"] == "ok" for row in stored)
    assert f"--out {out}" in match[3] and where[0] in match[3]
    return len(stored)


@pytest.mark.parametrize("how", ["ctrl-c", "kill"])
@pytest.mark.parametrize("where", [["--workers", "2"], ["--serial"]], ids=["dask", "serial"])
def test_ctrl_c_prints_one_line_and_no_worker_traceback(tmp_path, where, how) -> None:
    """Once the first task is stored: Ctrl-C (SIGINT to the whole process group, as a
    terminal sends it) or ``kill PID`` (SIGTERM to the campaign's process alone): the one
    line, exit code 130, no traceback. (SIGTERM to the whole group, as a batch scheduler
    sends it, also reaches the Dask workers, which may log their end.)"""
    import os
    import signal
    import time

    if where[0] == "--workers":
        pytest.importorskip("distributed")

    def signal_it(process, out) -> None:
        deadline = time.monotonic() + 120
        while not list(out.glob("tasks/*.json")) and time.monotonic() < deadline:
            assert process.poll() is None, process.communicate()
            time.sleep(0.05)
        if how == "ctrl-c":
            os.killpg(process.pid, signal.SIGINT)
        else:
            os.kill(process.pid, signal.SIGTERM)

    code, stderr, signalled, out = _interrupted_campaign(tmp_path, where, signal_it)
    assert _check_one_line(code, stderr, signalled, out, where) >= 1


def test_kill_while_the_cluster_starts_closes_it_whole(tmp_path) -> None:
    """SIGTERM while the LocalCluster starts (sent from inside its start, once: the
    campaign's process signals itself from the cluster's state correction): deferred
    until the cluster is up, then it is closed as on Ctrl-C. Without the deferral the
    KeyboardInterrupt raised inside the cluster's start left it half-built, and its
    close at exit printed an "Exception ignored" traceback."""
    pytest.importorskip("distributed")
    where = ["--workers", "2"]
    prelude = textwrap.dedent(
        """
        import os, signal
        from distributed.deploy import spec

        correct = spec.SpecCluster._correct_state_internal
        sent = []

        def signalling(self, *args, **kwargs):
            if not sent:
                sent.append(1)
                os.kill(os.getpid(), signal.SIGTERM)
            return correct(self, *args, **kwargs)

        spec.SpecCluster._correct_state_internal = signalling
        """
    )

    def signal_it(process, out) -> None:
        pass  # (it signals itself)

    code, stderr, signalled, out = _interrupted_campaign(tmp_path, where, signal_it, prelude)
    assert _check_one_line(code, stderr, signalled, out, where) == 0


def test_report_plots_name_the_plant_output_unit() -> None:
    from ltv_lstm_mpc.campaign.report import output_unit

    assert output_unit([{"plant": "ph"}, {"plant": "ph"}]) == "pH"
    assert output_unit([{"plant": "quadtank"}]) == "cm"
    # the LSTM plant states none; mixed plants or an unimportable class: generic
    assert output_unit([{"plant": "lstm"}]) == "output units"
    assert output_unit([{"plant": "ph"}, {"plant": "quadtank"}]) == "output units"
    assert output_unit([{"plant": "nowhere.mod:Plant"}]) == "output units"
