"""Saved subproblems replay offline with the same numbers; backends agree on u_0."""

from __future__ import annotations

import numpy as np
import pytest
from ltv_lstm_mpc.solvers import available_solvers

from ltv_lstm_mpc import load_model
from ltv_lstm_mpc.bench import harness as bench

#: First-input tolerance per solver family (against the median over solvers of one form).
TOL = {"osqp": 1e-4, "scs": 1e-3, "proxqp": 1e-4, "highs": 1e-5, "clarabel": 1e-5, "ecos": 1e-5}


def _tol(solver: str) -> float:
    name = solver.split(":")[-1].lower()
    return TOL.get(name, 1e-6)


@pytest.fixture(scope="module")
def saved(tmp_path_factory):
    model = load_model("ph_lstm_n5.npz")
    scenario = bench.standin_scenario(model, steps=40)
    wanted = ["daqp", "osqp", "piqp", "qpsolvers:quadprog", "cvxpy:CLARABEL", "cvxpy:ECOS"]
    solvers = [s for s in wanted if s in available_solvers()]
    directory = tmp_path_factory.mktemp("subproblems")
    bench.save_subproblems(model, scenario, directory, count=3, steps=40, solvers=solvers)
    return directory, solvers


def test_replay_reproduces_saved_numbers(saved) -> None:
    directory, solvers = saved
    assert len(list(directory.glob("*_cone.npz"))) == 3
    assert len(list(directory.glob("*_qp.npz"))) == 3
    rows = bench.replay(directory)
    assert len(rows) == 3 * len(solvers)
    for row in rows:
        assert row["status_replayed"] == row["status_saved"] == "optimal"
        assert row["u0_diff"] <= 1e-9
        assert row["objective_diff"] <= 1e-8 * (1 + abs(row["u0_saved"]))
    assert (directory / "replay.csv").exists()


def test_backends_agree_on_first_input(saved) -> None:
    directory, _ = saved
    rows = bench.replay(directory)
    for form in ("_cone", "_qp"):
        for file in {r["file"] for r in rows if form in r["file"]}:
            group = [r for r in rows if r["file"] == file]
            values = np.array([r["u0_replayed"] for r in group])
            centre = np.median(values)
            for r, value in zip(group, values, strict=True):
                assert abs(value - centre) <= _tol(r["solver"]), (file, r["solver"])
