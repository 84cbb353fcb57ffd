"""(epsilon, beta) statements from campaigns: Clopper-Pearson bounds, the planner, the
[random] table of specs, the report's section and ``campaign --plan-epsilon``."""

from __future__ import annotations

import csv
import math
from typing import Any

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.stats import beta as beta_distribution
from scipy.stats import binom

from ltv_lstm_mpc.campaign import parse_spec, run_campaign
from ltv_lstm_mpc.campaign.statements import (
    campaign_statements,
    clopper_pearson_upper,
    loops_needed,
)
from ltv_lstm_mpc.cli import main
from ltv_lstm_mpc.exceptions import CampaignSpecError, InvalidValueError

# --------------------------------------------------------------------- the bounds


@pytest.mark.parametrize(
    ("failures", "loops", "beta"),
    [(0, 1, 0.05), (0, 59, 0.05), (0, 300, 0.01), (1, 10, 0.05), (3, 100, 0.05),
     (7, 20, 0.1), (49, 50, 0.05), (250, 1000, 1e-3)],
)  # fmt: skip
def test_clopper_pearson_matches_scipy(failures: int, loops: int, beta: float) -> None:
    expected = beta_distribution.ppf(1 - beta, failures + 1, loops - failures)
    bound = clopper_pearson_upper(failures, loops, beta)
    assert bound == pytest.approx(expected, rel=1e-10)
    # the defining property: at p = bound, P(Bin(N, p) <= k) = beta
    assert binom.cdf(failures, loops, bound) == pytest.approx(beta, rel=1e-7)


@given(
    loops=st.integers(1, 2000),
    failure_share=st.floats(0.0, 1.0),
    beta=st.floats(1e-6, 0.5),
)
@settings(max_examples=200, deadline=None)
def test_clopper_pearson_is_the_largest_p_with_enough_tail(
    loops: int, failure_share: float, beta: float
) -> None:
    failures = min(int(failure_share * loops), loops)
    bound = clopper_pearson_upper(failures, loops, beta)
    assert failures / loops <= bound <= 1.0
    if failures < loops:
        assert binom.cdf(failures, loops, bound) == pytest.approx(beta, rel=1e-5, abs=1e-12)
    else:
        assert bound == 1.0


@pytest.mark.parametrize(
    ("epsilon", "beta", "expected"),
    [(0.05, 0.05, 59), (0.01, 0.05, 299), (0.1, 0.01, 44), (0.01, 1e-6, 1375), (0.5, 0.5, 1)],
)
def test_loops_needed_for_zero_failures(epsilon: float, beta: float, expected: int) -> None:
    n = loops_needed(epsilon, beta)
    assert n == expected
    assert n == math.ceil(math.log(beta) / math.log(1 - epsilon))
    assert clopper_pearson_upper(0, n, beta) <= epsilon  # enough
    if n > 1:
        assert clopper_pearson_upper(0, n - 1, beta) > epsilon  # and the fewest


def test_bad_arguments_are_named() -> None:
    with pytest.raises(InvalidValueError, match="failures"):
        clopper_pearson_upper(5, 3, 0.05)
    with pytest.raises(InvalidValueError, match="beta"):
        clopper_pearson_upper(0, 3, 1.5)
    with pytest.raises(InvalidValueError, match="epsilon"):
        loops_needed(0.0, 0.05)


def test_statements_per_stratum_and_outcome() -> None:
    rows: list[dict[str, Any]] = []
    for level, violated in (("a", [0] * 59), ("b", [0] * 57 + [1, 2])):
        for count in violated:
            rows.append(
                {"status": "ok", "L_d": level, "violations": count, "final_offset": 1e-4,
                 "infeasible_steps": 0, "violations_guarantee_held": 0}
            )  # fmt: skip
    rows.append({"status": "error", "L_d": "a"})  # left out: not a draw
    statements = {
        (s.stratum["L_d"], s.outcome): s for s in campaign_statements(rows, ["L_d"], beta=0.05)
    }
    a, b = statements[("a", "violation")], statements[("b", "violation")]
    assert (a.failures, a.loops) == (0, 59) and (b.failures, b.loops) == (2, 59)
    assert a.upper_bound == pytest.approx(1 - 0.05 ** (1 / 59))
    assert b.upper_bound == pytest.approx(clopper_pearson_upper(2, 59, 0.05))
    assert statements[("a", "offset")].failures == 0
    assert "confidence 95%" in a.sentence() and "0 of 59" in a.sentence()


# ------------------------------------------------------------------- [random] in specs


def tiny_random(**random: Any) -> dict[str, Any]:
    return {
        "campaign": {
            "name": "random",
            "plant": "ph",
            "steps": 20,
            "setpoints": [7.3],
            "solver": "daqp",
        },
        "factors": {"L_d": [0.01, 0.1]},
        "random": {
            "samples": 4,
            "sampling_seed": 3,
            "noise_std": {"distribution": "uniform", "low": 0.0, "high": 0.02},
            "mismatch": {"A1": {"distribution": "normal", "mean": 1.0, "std": 0.05}},
            **random,
        },
    }


def test_random_draws_are_recorded_reproducible_and_common_to_strata() -> None:
    spec = parse_spec(tiny_random())
    assert len(spec.tasks) == 2 * 4
    assert spec.strata == ["L_d"]
    by_level: dict[float, list[dict[str, Any]]] = {}
    for task in spec.tasks:
        by_level.setdefault(task.settings["L_d"], []).append(task.settings)
    first, second = by_level[0.01], by_level[0.1]
    for j, (a, b) in enumerate(zip(first, second, strict=True)):
        assert a["sample"] == b["sample"] == j
        # the same draw in every stratum (common random numbers), the noise seed drawn too
        assert a["noise_std"] == b["noise_std"] and a["mismatch"] == b["mismatch"]
        assert a["seed"] == b["seed"]
        assert 0.0 <= a["noise_std"] <= 0.02 and set(a["mismatch"]) == {"A1"}
    assert len({s["seed"] for s in first}) == 4  # i.i.d. noise between draws
    rng = np.random.default_rng([3, 0])  # the documented stream of draw 0
    assert first[0]["mismatch"]["A1"] == pytest.approx(rng.normal(1.0, 0.05))
    assert first[0]["noise_std"] == pytest.approx(rng.uniform(0.0, 0.02))
    again = parse_spec(tiny_random())
    assert [t.key for t in again.tasks] == [t.key for t in spec.tasks]
    other = parse_spec(tiny_random(sampling_seed=4))
    assert {t.key for t in other.tasks}.isdisjoint({t.key for t in spec.tasks})


def test_log_uniform_and_fixed_noise_seed() -> None:
    data = tiny_random(noise_std={"distribution": "log-uniform", "low": 1e-4, "high": 1e-2})
    data["campaign"]["seed"] = 5  # the spec fixes the noise seed: not drawn
    spec = parse_spec(data)
    values = [t.settings["noise_std"] for t in spec.tasks]
    assert all(1e-4 <= v <= 1e-2 for v in values)
    assert {t.settings["seed"] for t in spec.tasks} == {5}
    assert not spec.random.noise_seed


@pytest.mark.parametrize(
    ("random", "where", "hint"),
    [
        ({"samples": 0}, "[random].samples", ">= 1"),
        ({"N": {"distribution": "uniform", "low": 1, "high": 3}}, "[random].N", "sampled"),
        ({"noise_std": {"distribution": "beta", "a": 1}}, "[random].noise_std", "uniform"),
        ({"noise_std": {"distribution": "uniform", "low": 1.0, "high": 0.5}}, "noise_std", "low"),
        ({"noise_std": {"distribution": "normal", "mean": 0.0}}, "noise_std", "missing"),
        (
            {"noise_std": {"distribution": "normal", "mean": 0.0, "std": 0.01}},
            "[random].noise_std",
            "choose a distribution",  # a draw below 0
        ),
        ({"mismatch": {"Z9": {"distribution": "normal", "mean": 1, "std": 0.1}}}, "Z9", "unknown"),
    ],
)
def test_random_errors_name_the_entry(random: dict[str, Any], where: str, hint: str) -> None:
    data = tiny_random(**random)
    with pytest.raises(CampaignSpecError) as caught:
        parse_spec(data)
    assert where in str(caught.value) and hint in str(caught.value)


def test_seeds_only_draws_and_nothing_to_draw() -> None:
    """[random] with samples only: the draws differ by their noise seed (a seeds-only
    i.i.d. campaign); with the seed fixed as well there is nothing to draw: refused."""
    data = tiny_random()
    data["random"] = {"samples": 5}
    spec = parse_spec(data)
    assert len(spec.tasks) == 2 * 5 and spec.random.noise_seed
    seeds = [t.settings["seed"] for t in spec.tasks if t.settings["L_d"] == 0.01]
    assert len(set(seeds)) == 5
    assert spec.strata == ["L_d"]
    data["campaign"]["seed"] = 3
    with pytest.raises(CampaignSpecError, match="nothing to draw"):
        parse_spec(data)


def test_drawn_mismatch_with_mismatch_levels_is_refused() -> None:
    """A mismatch factor and drawn mismatch parameters would blur the factor's levels
    (the strata): refused, naming the entry."""
    data = tiny_random()
    data["factors"]["mismatch"] = [{}, {"W_b3": 1.1}]
    with pytest.raises(CampaignSpecError, match=r"\[random\].mismatch.*blur its levels"):
        parse_spec(data)


def test_a_stratum_of_errors_only_is_stated_with_bound_one() -> None:
    rows = [
        {
            "status": "ok",
            "L_d": "a",
            "violations": 0,
            "final_offset": 0.0,
            "infeasible_steps": 0,
            "violations_guarantee_held": 0,
        }
    ] * 3
    rows += [{"status": "error", "L_d": "b"}] * 2 + [{"status": "error", "L_d": "a"}]
    statements = campaign_statements(rows, ["L_d"], beta=0.05)
    b = [s for s in statements if s.stratum["L_d"] == "b"]
    assert len(b) == 4 and all(s.loops == 0 and s.upper_bound == 1.0 for s in b)
    assert all(s.errors == 2 for s in b)
    a = next(s for s in statements if s.stratum["L_d"] == "a" and s.outcome == "violation")
    assert (a.failures, a.loops, a.errors) == (0, 3, 1)
    assert "1 task(s) with errors left out" in a.sentence()


def test_random_setting_also_fixed_is_refused() -> None:
    data = tiny_random()
    data["campaign"]["noise_std"] = 0.01
    with pytest.raises(CampaignSpecError, match=r"\[random\].noise_std.*also set in \[campaign\]"):
        parse_spec(data)
    data = tiny_random()
    data["cases"] = [{"mismatch": {"A1": 1.1}}]
    with pytest.raises(CampaignSpecError, match="also set in"):
        parse_spec(data)


def test_campaign_report_states_the_bounds(tmp_path) -> None:
    data = tiny_random(samples=3)
    run = run_campaign(parse_spec(data), tmp_path, serial=True, progress=False, beta=0.1)
    assert run.errors == 0 and len(run.rows) == 6
    for row in run.rows:
        assert row["guarantee_held_steps"] is not None
        assert (
            row["violations_guarantee_held"] + row["violations_guarantee_voided"]
            == (row["violations"])
        )
    report = (tmp_path / "report.md").read_text()
    assert "## Statistical statements" in report and "confidence 90%" in report
    assert "![statistical statements](plots/statements.png)" in report
    assert (tmp_path / "plots" / "statements.png").stat().st_size > 10_000
    with (tmp_path / "statements.csv").open() as handle:
        table = list(csv.DictReader(handle))
    violation = [r for r in table if r["outcome"] == "violation"]
    assert len(violation) == 2  # one per stratum (L_d)
    for r in violation:
        failures, loops = int(r["failures"]), int(r["loops"])
        assert loops == 3
        expected = clopper_pearson_upper(failures, loops, 0.1)
        assert float(r["upper_bound"]) == pytest.approx(expected)


def test_plan_epsilon_command(tmp_path, capsys) -> None:
    assert main(["campaign", "--plan-epsilon", "0.05", "--beta", "0.05"]) == 0
    assert capsys.readouterr().out.startswith("59 i.i.d. closed loops")
    spec = tmp_path / "spec.toml"
    spec.write_text(
        '[campaign]\nplant = "ph"\nsteps = 20\nsetpoints = [7.3]\n[random]\nsamples = 30\n'
        'noise_std = { distribution = "uniform", low = 0.0, high = 0.01 }\n'
    )
    assert main(["campaign", str(spec), "--plan-epsilon", "0.05"]) == 0
    out = capsys.readouterr().out
    assert "30 draws per stratum" in out and "set samples = 59" in out
    with pytest.raises(SystemExit) as exit_info:
        main(["campaign", "--plan-epsilon", "2"])
    assert exit_info.value.code == 2
