"""The controller's subproblems as a qpbenchmark test set (solver_comparison/qpbenchmark_set.py)."""

from __future__ import annotations

import csv
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import scipy.sparse as sp
from ltv_lstm_mpc.solvers import ConvexProblem, SecondOrderCone
from ltv_lstm_mpc.solvers.acceptance import ProblemView, qpbenchmark_residuals

from ltv_lstm_mpc.exceptions import InvalidValueError
from ltv_lstm_mpc.solver_comparison import qpbenchmark_set as qpb

qpsolvers = pytest.importorskip("qpsolvers")


def _random_qp(seed: int, *, equalities: bool = True) -> ConvexProblem:
    rng = np.random.default_rng(seed)
    n, m = 6, 4
    M = rng.standard_normal((n, n))
    G = rng.standard_normal((m, n))
    lo = np.array([-1.0, -np.inf, -2.0, -0.5])
    up = np.array([1.0, 0.5, np.inf, 0.5])
    lb = np.full(n, -1.0)
    ub = np.full(n, 1.0)
    lb[0] = -np.inf  # a partly infinite box: its finite entries become rows
    return ConvexProblem(
        P=M @ M.T + np.eye(n),
        q=rng.standard_normal(n),
        A_eq=rng.standard_normal((1, n)) if equalities else None,
        b_eq=np.array([0.1]) if equalities else None,
        G=G,
        l=lo,
        u=up,
        lb=lb,
        ub=ub,
    )


@pytest.mark.parametrize("seed", range(4))
def test_residuals_equal_qpsolvers_own(seed: int) -> None:
    """qpbenchmark_residuals of this layer's answer (its view, its multipliers) = qpsolvers'
    Solution metrics of the same solver on the exported form, to the solver's accuracy;
    and the primal residual at any point is the largest violation of a finite side."""
    problem = _random_qp(seed)
    arrays = qpb.qpsolvers_arrays(problem, dense=True)
    qp = qpsolvers.Problem(**arrays)
    solution = qpsolvers.solve_problem(qp, "clarabel")
    assert solution.found
    from ltv_lstm_mpc.solvers import solve

    mine = solve(problem, "qpsolvers:clarabel")
    view = ProblemView.of_convex(problem)
    primal, dual, gap = qpbenchmark_residuals(view, mine.z, mine.duals)
    assert primal == pytest.approx(solution.primal_residual(), abs=1e-7)
    assert dual == pytest.approx(solution.dual_residual(), abs=1e-6)
    assert gap == pytest.approx(solution.duality_gap(), abs=1e-6)
    # a perturbed point: the primal residual is the largest violation of a finite side
    z = mine.z + 0.3
    primal_z, _, _ = qpbenchmark_residuals(view, z, mine.duals)
    x = np.asarray(z)
    expected = max(
        0.0,
        float(np.max(arrays["G"] @ x - arrays["h"])),
        float(np.max(np.abs(arrays["A"] @ x - arrays["b"]))),
    )
    assert primal_z == pytest.approx(expected, rel=1e-12)


def test_residuals_need_multipliers_and_refuse_cones() -> None:
    problem = _random_qp(0)
    view = ProblemView.of_convex(problem)
    primal, dual, gap = qpbenchmark_residuals(view, np.zeros(6), None)
    assert np.isfinite(primal) and dual == np.inf and gap == np.inf
    cone = SecondOrderCone(F=np.eye(2, 6), g=np.zeros(2), e=np.zeros(6), f=1.0)
    with_cone = ConvexProblem(P=np.eye(6), q=np.zeros(6), cones=(cone,))
    with pytest.raises(ValueError, match="cones"):
        qpbenchmark_residuals(ProblemView.of_convex(with_cone), np.zeros(6), {})


def test_qpsolvers_arrays_round_trip(tmp_path: Path) -> None:
    """The exported arrays hold the same feasible set and objective (dense and CSC)."""
    problem = _random_qp(1)
    from ltv_lstm_mpc.solvers import solve

    reference = solve(problem, "daqp")
    for dense in (True, False):
        arrays = qpb.qpsolvers_arrays(problem, dense=dense)
        assert arrays["lb"] is None  # the partly infinite box went into G
        qpb._save_arrays(tmp_path / "p.npz", arrays)
        loaded = qpb.load_problem(tmp_path / "p.npz")
        assert sp.issparse(loaded["P"]) != dense
        again = solve(qpb._convex_from_arrays(loaded), "daqp")
        np.testing.assert_allclose(again.z, reference.z, atol=1e-9)


def test_selection_rule() -> None:
    steps = [
        (0, "nominal"), (5, "nominal"), (7, "infeasible"), (7, "fallback"),
        (8, "nominal"), (9, "nominal"), (10, "nominal"), (20, "nominal"),
    ]  # fmt: skip
    captured = [
        qpb.Captured(f"s_N5_condensed_{k}_k{i:04d}", "s", 5, "condensed", k, i, "x", None)
        for i, k in steps
    ]
    chosen = qpb.select(captured, per_kind=2)
    kinds = {c.step: c.kind for c in chosen if c.kind != "fallback"}
    assert qpb.NEAR_STEPS == 2
    assert kinds[7] == "infeasible"
    # within NEAR_STEPS = 2 of step 7: 5, 8, 9; two of them, evenly spaced: 5 and 9
    assert [c.step for c in chosen if c.kind == "near_infeasible"] == [5, 9]
    assert [c.step for c in chosen if c.kind == "nominal"] == [0, 20]  # of 0, 10, 20
    assert all("_near_" in c.name for c in chosen if c.kind == "near_infeasible")
    with pytest.raises(InvalidValueError, match="per_kind"):
        qpb.select(captured, per_kind=0)


def _read_cbf(path: Path) -> dict:
    """A reader of what write_cbf writes (CBF v3: VAR, CON, OBJACOORD, ACOORD, BCOORD),
    written from the format's description, not from the writer."""
    lines = [line.strip() for line in path.read_text().splitlines()]
    out: dict = {"cones": [], "obj": {}, "A": [], "b": {}}
    i = 0
    while i < len(lines):
        key = lines[i]
        if key == "VAR":
            out["n"] = int(lines[i + 1].split()[0])
            i += 3
        elif key == "CON":
            rows, count = map(int, lines[i + 1].split())
            out["m"] = rows
            pairs = (lines[i + 2 + k].split() for k in range(count))
            out["cones"] = [(c, int(d)) for c, d in pairs]
            i += 2 + count
        elif key in ("OBJACOORD", "BCOORD"):
            count = int(lines[i + 1])
            target = out["obj"] if key == "OBJACOORD" else out["b"]
            for k in range(count):
                j, v = lines[i + 2 + k].split()
                target[int(j)] = float(v)
            i += 2 + count
        elif key == "ACOORD":
            count = int(lines[i + 1])
            out["A"] = [tuple(lines[i + 2 + k].split()) for k in range(count)]
            i += 2 + count
        else:
            i += 1
    return out


def test_cbf_has_the_problems_solution(tmp_path: Path) -> None:
    """The CBF file, read back and solved by Clarabel's own API, has the optimal value of
    the problem solved through this library (with a cone and a quadratic cost)."""
    clarabel = pytest.importorskip("clarabel")
    from ltv_lstm_mpc.solvers import solve

    base = _random_qp(2, equalities=True)
    cone = SecondOrderCone(F=np.eye(3, 6), g=np.array([0.2, 0.0, -0.1]), e=np.zeros(6), f=0.4)
    problem = ConvexProblem(
        P=base.P, q=base.q, A_eq=base.A_eq, b_eq=base.b_eq, G=base.G, l=base.l, u=base.u,
        lb=base.lb, ub=base.ub, cones=(cone,),
    )  # fmt: skip
    reference = solve(problem, "clarabel")
    assert reference.status.has_solution
    data = _read_cbf(qpb.write_cbf(problem, tmp_path / "p.cbf"))
    n, m = data["n"], data["m"]
    A = np.zeros((m, n))
    for i, j, v in data["A"]:
        A[int(i), int(j)] = float(v)
    b = np.zeros(m)
    for i, v in data["b"].items():
        b[i] = v
    c = np.zeros(n)
    for j, v in data["obj"].items():
        c[j] = v
    # CBF: A x + b in K. Clarabel: A' x + s = b', s in K'. So A' = -A, b' = b; its cones:
    # zero (L=), nonnegative (L+), second-order (Q); QR (2 x1 x2 >= |x3..|^2) rotated by
    # (x1 + x2, x1 - x2, sqrt2 x3..) into a second-order cone
    rows, rhs, cones = [], [], []
    offset = 0
    for kind, dim in data["cones"]:
        block_A, block_b = A[offset : offset + dim], b[offset : offset + dim]
        offset += dim
        if kind == "QR":
            T = np.zeros((dim, dim))
            T[0, :2] = [1.0, 1.0]
            T[1, :2] = [1.0, -1.0]
            T[2:, 2:] = np.sqrt(2.0) * np.eye(dim - 2)
            block_A, block_b = T @ block_A, T @ block_b
            kind = "Q"
        rows.append(-block_A)
        rhs.append(block_b)
        kinds = {
            "L=": clarabel.ZeroConeT,
            "L+": clarabel.NonnegativeConeT,
            "Q": clarabel.SecondOrderConeT,
        }
        cones.append(kinds[kind](dim))
    settings = clarabel.DefaultSettings()
    settings.verbose = False
    solver = clarabel.DefaultSolver(
        sp.csc_matrix((n, n)), c, sp.csc_matrix(np.vstack(rows)), np.concatenate(rhs), cones,
        settings,
    )  # fmt: skip
    solution = solver.solve()
    assert str(solution.status) == "Solved"
    assert solution.obj_val == pytest.approx(reference.objective, rel=1e-6, abs=1e-7)
    np.testing.assert_allclose(np.asarray(solution.x)[:6], reference.z, atol=1e-5)


@pytest.fixture(scope="module")
def exported(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A small export: scenario 3 (infeasible steps) at N = 5, 40 samples, one of each kind."""
    folder = tmp_path_factory.mktemp("qpset")
    qpb.export_test_set(folder, sources=qpb.SOURCES[:1], horizons=(5,), per_kind=1, steps=40)
    return folder


def test_export_files(exported: Path) -> None:
    with open(exported / "problems.csv", newline="") as handle:
        rows = list(csv.DictReader(handle))
    kinds = {(r["form"], r["kind"]) for r in rows}
    for form in ("condensed", "sparse", "cone"):
        for kind in qpb.KINDS:
            assert (form, kind) in kinds, (form, kind)
    for r in rows:
        folder, suffix = ("socp", "cbf") if r["form"] == "cone" else ("problems", "npz")
        assert (exported / folder / f"{r['name']}.{suffix}").is_file()
        solved = r["kind"] in ("nominal", "near_infeasible")
        assert r["status"] == ("optimal" if solved else "infeasible")
    readme = (exported / "README.md").read_text()
    assert "near_infeasible" in readme and "qpbenchmark ltv_lstm_mpc_dense.py" in readme
    # the infeasible problem is infeasible for another solver too
    name = next(r["name"] for r in rows if r["form"] == "condensed" and r["kind"] == "infeasible")
    arrays = qpb.load_problem(exported / "problems" / f"{name}.npz")
    solution = qpsolvers.solve_problem(qpsolvers.Problem(**arrays), "clarabel")
    assert not solution.found


def test_qpbenchmark_runs_and_agrees(exported: Path) -> None:
    """qpbenchmark's own command line runs the exported sets with at least six solvers and
    writes its report; this library's success rates equal its own, or the reason is stated."""
    pytest.importorskip("qpbenchmark")
    results = exported / "results"
    for form, module in qpb.MODULES.items():
        done = subprocess.run(
            [
                sys.executable, "-m", "qpbenchmark.benchmark", str(exported / f"{module}.py"),
                "--results-path", str(results / f"{module}.csv"),
                "run", "--author", "test",
            ],
            capture_output=True, text=True, timeout=600, check=False,
        )  # fmt: skip
        assert done.returncode == 0, done.stderr[-3000:]
        assert (results / f"{module}.md").is_file()
        with open(results / f"{module}.csv", newline="") as handle:
            solvers = {r["solver"] for r in csv.DictReader(handle)}
        if form == "condensed":
            assert len(solvers) >= 6, solvers
    rows = qpb.qpbenchmark_metrics(exported)
    paths = qpb.write_metrics(exported, rows)
    for form, module in qpb.MODULES.items():
        table, differences = qpb.compare_results(
            [r for r in rows if r["form"] == form], results / f"{module}.csv"
        )
        assert table
        for d in differences:
            assert d["reason"], d
        # the library's settings group passes both the same options: the same verdicts
        # but for a stated exception (matrix types: module docstring)
        same = [t for t in table if t["settings"] == qpb.LIBRARY_SETTINGS]
        equal = [t for t in same if t["success_ours"] == t["success_qpbenchmark"]]
        assert len(equal) >= len(same) - 1, same
    assert "comparison_condensed" in paths and "comparison_sparse" in paths


def test_metrics_summary() -> None:
    rows = [
        {"problem": "a", "solver": "s", "settings": "default", "runtime": 0.001, "found": True,
         "primal_residual": 1e-9, "dual_residual": 1e-9, "duality_gap": 1e-9},
        {"problem": "b", "solver": "s", "settings": "default", "runtime": 0.002, "found": False,
         "primal_residual": np.inf, "dual_residual": np.inf, "duality_gap": np.inf},
    ]  # fmt: skip
    summary = qpb.summarize(rows)[("s", "default")]
    assert summary["success_rate"] == 50.0
    expected = np.exp(np.mean(np.log(np.array([0.001, 10.0]) + 10.0))) - 10.0
    assert summary["runtime"] == pytest.approx(expected)
    with pytest.raises(InvalidValueError):
        qpb.shifted_geometric_mean([-1.0])


def test_cli_usage_errors(tmp_path: Path) -> None:
    done = subprocess.run(
        [sys.executable, "-m", "ltv_lstm_mpc.cli.main", "bench", "--qpbenchmark-set",
         str(tmp_path)],
        capture_output=True, text=True, check=False,
    )  # fmt: skip
    assert done.returncode == 2
    assert "--export-qpbenchmark" in done.stderr
