"""The one benchmark abstraction that ``reproduce`` runs (paper and quadruple tank)."""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import pytest

from ltv_lstm_mpc import load_model
from ltv_lstm_mpc.benchmarks.benchmark import Benchmark
from ltv_lstm_mpc.benchmarks.quadtank import QUADTANK_BENCHMARK
from ltv_lstm_mpc.exceptions import InvalidValueError
from ltv_lstm_mpc.paper.reproduce import PAPER_BENCHMARK


@dataclass
class _Result:
    name: str
    solver: str | None

    def summary(self) -> dict[str, Any]:
        return {"name": self.name, "solver": self.solver, "final_offset": 0.0}


def _toy(calls: list[tuple[str, str | None]]) -> Benchmark:
    @dataclass
    class Scenario:
        name: str

    def run(scenario: Any, model: Any, solver: str | None, progress: bool, engine: str) -> _Result:
        calls.append((scenario.name, solver))
        return _Result(scenario.name, solver)

    def write(result: _Result, out: Path, plot: bool) -> dict[str, Any]:
        out.mkdir(parents=True, exist_ok=True)
        (out / f"{result.name}_{result.solver}.json").write_text(json.dumps(result.summary()))
        return result.summary()

    return Benchmark(
        name="toy",
        plant="lstm",
        model="ph_lstm_n5.npz",
        scenarios=lambda model, short: [Scenario("steps"), Scenario("leak")][: 1 if short else 2],
        run=run,
        write=write,
        certificate_key="certificate",
        certificate=lambda model, results: {"runs": len(results)},
        format_report=lambda report: f"{len(report['scenarios'])} runs",
        solvers=("a", "b"),
    )


def test_reproduce_runs_every_scenario_on_every_solver_path_and_writes_the_summary(
    tmp_path: Path,
) -> None:
    calls: list[tuple[str, str | None]] = []
    toy = _toy(calls)
    report = toy.reproduce(None, tmp_path, progress=False)  # type: ignore[arg-type]
    assert calls == [("steps", "a"), ("steps", "b"), ("leak", "a"), ("leak", "b")]
    assert report["certificate"] == {"runs": 4} and len(report["scenarios"]) == 4
    written = json.loads((tmp_path / "summary.json").read_text())
    assert written["scenarios"] == report["scenarios"]
    assert (tmp_path / "leak_b.json").exists()
    calls.clear()
    toy.reproduce(None, only=["leak"], solvers=("c",), progress=False)  # type: ignore[arg-type]
    assert calls == [("leak", "c")]


@pytest.mark.parametrize("bench", [PAPER_BENCHMARK, QUADTANK_BENCHMARK], ids=lambda b: b.name)
def test_both_benchmarks_refuse_an_unknown_scenario_alike(bench: Benchmark) -> None:
    model = load_model(bench.model)
    names = [scenario.name for scenario in bench.scenarios(model, True)]
    with pytest.raises(InvalidValueError, match=f"no {bench.name} scenario matches") as error:
        bench.select(model, ["nothing"], short=True)
    assert str(names) in str(error.value)
    assert bench.plant in ("ph", "quadtank")


def test_a_scenario_cycles_its_setpoint_levels() -> None:
    """Scenario.cycled(period): the schedule's levels in order, each held for ``period``
    samples, then again; the disturbances kept; a period that is not a whole number of
    samples >= 1 is refused, named."""
    import numpy as np

    from ltv_lstm_mpc.paper.scenarios import paper_scenarios

    scenario = paper_scenarios(load_model("ph_lstm_n5.npz"))[2]
    levels = list(dict.fromkeys(np.asarray(scenario.setpoints).tolist()))  # (each once here)
    cycled = scenario.cycled(40)
    assert cycled.steps == scenario.steps
    np.testing.assert_array_equal(cycled.disturbances, scenario.disturbances)
    assert [cycled.setpoints[40 * k] for k in range(len(levels))] == levels
    assert cycled.setpoints[40 * len(levels)] == levels[0]
    assert len(set(cycled.setpoints[:40].tolist())) == 1
    for period in (0, 2.5, "40"):
        with pytest.raises(InvalidValueError, match=f"got {period!r}"):
            scenario.cycled(period)  # type: ignore[arg-type]
