"""Campaign statements: replications are not strata, and the offset outcome is
measured as a window mean of the noise-free plant output with a spec-level tolerance."""

from __future__ import annotations

import csv
import math
from pathlib import Path
from typing import Any

import pytest

from ltv_lstm_mpc.campaign import load_spec, parse_spec, run_campaign
from ltv_lstm_mpc.campaign.statements import campaign_statements, clopper_pearson_upper
from ltv_lstm_mpc.exceptions import CampaignSpecError

EXPERIMENTS = Path(__file__).resolve().parents[1] / "experiments" / "campaigns"


def tiny(campaign: dict[str, Any] | None = None, **factors: Any) -> dict[str, Any]:
    """A pH campaign of 30-step closed loops (about 0.05 s each)."""
    fixed = {
        "name": "tiny",
        "plant": "ph",
        "steps": 30,
        "setpoints": [7.4, 7.2],
        "q2": [0.55, 0.65],
        "solver": "daqp",
        **(campaign or {}),
    }
    return {"campaign": {k: v for k, v in fixed.items() if k not in factors}, "factors": factors}


def fake_rows(spec: Any, **metrics: Any) -> list[dict[str, Any]]:
    """One finished row per task with the given metrics (no failures by default)."""
    base = {
        "status": "ok",
        "violations": 0,
        "violations_guarantee_held": 0,
        "final_offset": 0.0,
        "final_offset_mean": 0.0,
        "infeasible_steps": 0,
    }
    return [{**task.settings, **base, **metrics} for task in spec.tasks]


def statements_csv(out: Path) -> list[dict[str, str]]:
    with (out / "statements.csv").open() as handle:
        return list(csv.DictReader(handle))


# ----------------------------------------------------------------- replications
def test_eight_seeds_are_one_stratum_with_the_bound_of_eight_loops() -> None:
    """Eight seeds listed under [factors] gave eight strata of one loop, each bound 0.95."""
    spec = parse_spec(tiny(noise_std=[0.02], seed=list(range(8))))
    violation = [
        s for s in campaign_statements(fake_rows(spec), spec.strata) if s.outcome == "violation"
    ]
    assert [s.upper_bound for s in violation] != [pytest.approx(0.95)] * 8
    assert len(violation) == 1
    (statement,) = violation
    assert statement.loops == 8 and statement.failures == 0
    assert statement.upper_bound == pytest.approx(1 - 0.05 ** (1 / 8))
    assert statement.upper_bound == pytest.approx(0.312, abs=1e-3)
    assert spec.replications == ("seed",) and "seed" not in spec.strata
    stated = campaign_statements(fake_rows(spec), spec.strata, replications=spec.replications)
    (pooled,) = [s for s in stated if s.outcome == "violation"]
    assert pooled.pooled == ("seed",) and "seed pooled" in pooled.sentence()


def test_seeds_without_noise_are_one_loop_not_eight() -> None:
    """A noise seed changes nothing without measurement noise: eight such rows are one
    deterministic loop, and a bound for eight independent loops would be false."""
    spec = parse_spec(tiny(noise_std=[0.0, 0.02], seed=list(range(8))))
    stated = campaign_statements(fake_rows(spec), spec.strata, replications=spec.replications)
    by_noise = {s.stratum["noise_std"]: s for s in stated if s.outcome == "violation"}
    assert by_noise[0.0].loops == 1 and by_noise[0.0].duplicates == 7
    assert by_noise[0.0].upper_bound == pytest.approx(0.95)
    assert "7 noise-free replication(s) of the same loop counted once" in (by_noise[0.0].sentence())
    assert by_noise[0.02].loops == 8 and by_noise[0.02].duplicates == 0


def test_declared_replications_and_their_checks() -> None:
    spec = parse_spec(
        tiny({"replications": ["seed", "L_d"]}, noise_std=[0.02], L_d=[0.05, 0.1], seed=[0, 1])
    )
    assert spec.replications == ("seed", "L_d") and spec.strata == ["noise_std"]
    # an explicit empty list keeps the seeds as strata
    spec = parse_spec(tiny({"replications": []}, noise_std=[0.02], seed=[0, 1]))
    assert spec.replications == () and "seed" in spec.strata
    with pytest.raises(CampaignSpecError, match=r"\[campaign\]\.replications.*'q2' is not"):
        parse_spec(tiny({"replications": ["q2"]}, seed=[0, 1]))
    with pytest.raises(CampaignSpecError, match="list of factor names"):
        parse_spec(tiny({"replications": "seed"}, seed=[0, 1]))


def test_pooled_replications_never_share_a_draw() -> None:
    """With [random], replication r takes the draws r * samples + j: the pooled loops of a
    stratum are all different draws, and each stratum still gets the same draws."""
    data = tiny(L_d=[0.05, 0.1], seed=[0, 1, 2])
    data["random"] = {
        "samples": 4,
        "sampling_seed": 3,
        "noise_std": {"distribution": "uniform", "low": 0.0, "high": 0.02},
    }
    spec = parse_spec(data)
    assert spec.strata == ["L_d"]
    for level in (0.05, 0.1):
        tasks = [t for t in spec.tasks if t.settings["L_d"] == level]
        assert sorted(t.settings["sample"] for t in tasks) == list(range(12))
        assert len({t.settings["noise_std"] for t in tasks}) == 12
    first = {t.settings["sample"]: t.settings["noise_std"] for t in spec.tasks[:12]}
    second = {t.settings["sample"]: t.settings["noise_std"] for t in spec.tasks[12:]}
    assert first == second  # common random numbers between strata
    # without a replication factor the draws are the ones they always were
    plain = tiny(L_d=[0.05, 0.1])
    plain["random"] = data["random"]
    assert [t.settings["sample"] for t in parse_spec(plain).tasks] == [0, 1, 2, 3] * 2


def test_campaign_report_states_one_bound_for_the_seeds(tmp_path: Path) -> None:
    spec = parse_spec(tiny(noise_std=[0.01], seed=list(range(8))))
    run_campaign(spec, tmp_path, serial=True, progress=False)
    rows = [r for r in statements_csv(tmp_path) if r["outcome"] == "violation"]
    assert len(rows) == 1 and int(rows[0]["loops"]) == 8
    failures = int(rows[0]["failures"])
    assert float(rows[0]["upper_bound"]) == pytest.approx(
        clopper_pearson_upper(failures, 8, 0.05), rel=1e-9
    )


# ----------------------------------------------------------------------- offset
def test_offset_outcome_reads_the_window_mean_not_one_sample() -> None:
    """One sample of the plant output scatters with the loop's reaction to the noise: 59 /
    59 loops of ph_statistical.toml failed at 1e-3 pH on it."""
    spec = parse_spec(tiny(noise_std=[0.02], seed=[0, 1, 2]))
    rows = fake_rows(spec, final_offset=0.01, final_offset_mean=2e-4)
    stated = campaign_statements(rows, [n for n in spec.strata if n != "seed"])
    (offset,) = [s for s in stated if s.outcome == "offset"]
    assert offset.failures == 0 and offset.loops == 3
    assert "mean error" in offset.description and "noise-free" in offset.description
    # rows of older results (no window mean) keep the last-sample offset
    old = [{k: v for k, v in r.items() if k != "final_offset_mean"} for r in rows]
    (offset_old,) = [s for s in campaign_statements(old, spec.strata) if s.outcome == "offset"]
    assert offset_old.failures == 3


def test_task_rows_carry_the_window_mean_of_the_noise_free_output(tmp_path: Path) -> None:
    spec = parse_spec(
        tiny({"offset_window": 10, "offset_tolerance": 0.5}, noise_std=[0.02], seed=[0, 1])
    )
    assert spec.offset_tolerance == 0.5
    run = run_campaign(spec, tmp_path, serial=True, progress=False)
    for row in run.rows:
        assert row["offset_window"] == 10
        assert math.isfinite(row["final_offset_mean"]) and row["final_offset_mean"] >= 0.0
    (offset,) = [r for r in statements_csv(tmp_path) if r["outcome"] == "offset"]
    assert "above 0.5" in offset["statement"] and "last 10 samples" in offset["statement"]
    assert int(offset["failures"]) == 0
    # the command line's --offset-tolerance still wins over the spec's
    run_campaign(spec, tmp_path, serial=True, progress=False, offset_tolerance=1e-9)
    (offset,) = [r for r in statements_csv(tmp_path) if r["outcome"] == "offset"]
    assert "above 1e-09" in offset["statement"]


def test_spec_checks_the_offset_settings() -> None:
    with pytest.raises(CampaignSpecError, match=r"\[campaign\]\.offset_tolerance"):
        parse_spec(tiny({"offset_tolerance": -1.0}))
    with pytest.raises(CampaignSpecError, match=r"offset_window"):
        parse_spec(tiny({"offset_window": 0}))


def test_ph_statistical_states_its_offset_measure() -> None:
    spec = load_spec(EXPERIMENTS / "ph_statistical.toml")
    assert spec.offset_tolerance == 0.01
    assert {t.settings["offset_window"] for t in spec.tasks} == {100}
    robustness = load_spec(EXPERIMENTS / "ph_robustness.toml")
    assert robustness.replications == ("seed",) and "seed" not in robustness.strata


def test_plan_counts_the_pooled_replications(tmp_path: Path, capsys: Any) -> None:
    from ltv_lstm_mpc.cli import main

    spec = tmp_path / "spec.toml"
    spec.write_text(
        '[campaign]\nplant = "ph"\nsteps = 20\nsetpoints = [7.3]\nnoise_std = 0.01\n'
        "[factors]\nL_d = [0.05, 0.1]\nseed = [0, 1, 2, 3, 4, 5, 6, 7]\n"
    )
    assert main(["campaign", str(spec), "--plan-epsilon", "0.05"]) == 0
    out = capsys.readouterr().out
    assert "8 loops per stratum (replications seed pooled), 2 strata, 16 tasks" in out
    assert "59 needed" in out
