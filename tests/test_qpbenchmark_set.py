"""The controller's subproblems as a qpbenchmark test set (solver_comparison/qpbenchmark_set.py)."""

from __future__ import annotations

import csv
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import scipy.sparse as sp
from ltv_lstm_mpc.solvers import ConvexProblem, SecondOrderCone
from ltv_lstm_mpc.solvers.acceptance import ProblemView, qpbenchmark_residuals
from optional_extras import require_solver

from ltv_lstm_mpc.exceptions import InvalidValueError
from ltv_lstm_mpc.solver_comparison import qpbenchmark_set as qpb

qpsolvers = pytest.importorskip("qpsolvers")


def _random_qp(seed: int, *, equalities: bool = True) -> ConvexProblem:
    """A QP whose solution has active upper and lower rows and bounds (a cost pulling far
    outside the feasible set)."""
    rng = np.random.default_rng(seed)
    n, m = 6, 4
    M = rng.standard_normal((n, n))
    G = rng.standard_normal((m, n))
    lo = np.array([-0.2, -np.inf, -0.1, -0.3])
    up = np.array([0.2, 0.1, np.inf, 0.3])
    lb = np.full(n, -0.5)
    ub = np.full(n, 0.5)
    lb[0] = -np.inf  # a partly infinite box: its finite entries become rows
    return ConvexProblem(
        P=M @ M.T + np.eye(n),
        q=20.0 * rng.standard_normal(n),
        A_eq=rng.standard_normal((1, n)) if equalities else None,
        b_eq=np.array([0.1]) if equalities else None,
        G=G,
        l=lo,
        u=up,
        lb=lb,
        ub=ub,
    )


def _ours_from_qpsolvers(solution, arrays) -> dict:
    """qpsolvers' multipliers of the exported form in this layer's convention (the rows
    G x <= h one-sided: y = z; A x = b: y; the bounds: z_box)."""
    duals = {"ineq": np.asarray(solution.z, dtype=float)}
    if arrays["A"] is not None:
        duals["eq"] = np.asarray(solution.y, dtype=float)
    if arrays["lb"] is not None:
        duals["bounds"] = np.asarray(solution.z_box, dtype=float)
    return duals


@pytest.mark.parametrize("solver", ["clarabel", "daqp", "proxqp", "osqp"])
@pytest.mark.parametrize("seed", range(3))
def test_residuals_are_qpsolvers_own(seed: int, solver: str) -> None:
    """On the exported form (one-sided rows, finite bounds), qpbenchmark_residuals of a
    point and its multipliers are qpsolvers' Solution metrics of the same point and
    multipliers, to rounding; low accuracy, so that residuals are not all zero."""
    require_solver(f"qpsolvers:{solver}")
    base = _random_qp(seed)
    arrays = qpb.qpsolvers_arrays(base, dense=True)
    options = {"eps_abs": 1e-3, "eps_rel": 0.0} if solver in ("osqp", "proxqp") else {}
    for with_box in (False, True):
        parts = dict(arrays)
        if with_box:  # the finite box as lb/ub (every entry finite)
            parts["lb"], parts["ub"] = np.full(6, -0.5), np.full(6, 0.5)
        solution = qpsolvers.solve_problem(qpsolvers.Problem(**parts), solver, **options)
        assert solution.found
        active = np.abs(parts["G"] @ solution.x - parts["h"]) < 1e-2
        assert active.sum() >= 2  # some rows bind
        problem = qpb._convex_from_arrays(parts)
        view = ProblemView.of_convex(problem)
        primal, dual, gap = qpbenchmark_residuals(
            view, solution.x, _ours_from_qpsolvers(solution, parts)
        )
        assert primal == pytest.approx(solution.primal_residual(), rel=1e-9, abs=1e-14)
        assert dual == pytest.approx(solution.dual_residual(), rel=1e-9, abs=1e-13)
        assert gap == pytest.approx(solution.duality_gap(), rel=1e-9, abs=1e-12)


def test_residuals_of_a_wrong_answer() -> None:
    """A point off the optimum and multipliers of the wrong sign give the residuals of
    qpsolvers' formulas, written out."""
    problem = _random_qp(4)
    arrays = qpb.qpsolvers_arrays(problem, dense=True)
    parts = dict(arrays)
    parts["lb"], parts["ub"] = np.full(6, -0.5), np.full(6, 0.5)
    rng = np.random.default_rng(0)
    x = rng.standard_normal(6)
    z = rng.standard_normal(parts["G"].shape[0])  # both signs
    y = rng.standard_normal(1)
    z_box = rng.standard_normal(6)
    solution = qpsolvers.Solution(qpsolvers.Problem(**parts))
    solution.found, solution.x, solution.z, solution.y, solution.z_box = True, x, z, y, z_box
    view = ProblemView.of_convex(qpb._convex_from_arrays(parts))
    duals = {"ineq": z, "eq": y, "bounds": z_box}
    primal, dual, gap = qpbenchmark_residuals(view, x, duals)
    assert primal == pytest.approx(solution.primal_residual(), rel=1e-12)
    assert dual == pytest.approx(solution.dual_residual(), rel=1e-12)
    assert gap == pytest.approx(solution.duality_gap(), rel=1e-12)


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
    """near_infeasible: the solved nominal problems with the smallest margins; the other
    kinds evenly spaced; a problem is chosen once."""
    steps = [
        (0, "nominal", 0.5), (5, "nominal", 0.01), (7, "infeasible", -1.0),
        (7, "fallback", 1.0), (8, "nominal", 0.002), (9, "nominal", 0.3),
        (10, "nominal", 0.001), (20, "nominal", 0.2),
    ]  # fmt: skip
    captured = [
        qpb.Captured(f"s_N5_condensed_{k}_k{i:04d}", "s", 5, "condensed", k, i, "x", None, m)
        for i, k, m in steps
    ]
    chosen = qpb.select(captured, per_kind=2)
    assert [c.step for c in chosen if c.kind == "near_infeasible"] == [8, 10]
    assert all("_near_" in c.name for c in chosen if c.kind == "near_infeasible")
    assert [c.step for c in chosen if c.kind == "nominal"] == [0, 20]  # of 0, 5, 9, 20
    assert [c.step for c in chosen if c.kind == "infeasible"] == [7]
    with pytest.raises(InvalidValueError, match="per_kind"):
        qpb.select(captured, per_kind=0)


def test_feasibility_margin() -> None:
    """The margin of a box is its half-width in the units of z, negative where the rows
    cannot all hold; an equality (lo = up) is kept, not tightened."""
    box = ConvexProblem(P=np.eye(2), q=np.zeros(2), lb=np.array([-0.3, -1.0]), ub=np.ones(2))
    assert qpb.feasibility_margin(box) == pytest.approx(0.65, abs=1e-7)
    rows = ConvexProblem(
        P=np.eye(2), q=np.zeros(2), G=np.array([[1.0, 1.0], [1.0, 1.0]]),
        l=np.array([-np.inf, 2.0]), u=np.array([1.0, np.inf]),
    )  # fmt: skip  # x1 + x2 <= 1 and >= 2: half the gap over the rows' norm sqrt(2)
    assert qpb.feasibility_margin(rows) == pytest.approx(-0.5 / np.sqrt(2.0), abs=1e-7)
    fixed = ConvexProblem(P=np.eye(2), q=np.zeros(2), lb=np.array([0.2, -1.0]),
                          ub=np.array([0.2, 1.0]))  # fmt: skip
    assert qpb.feasibility_margin(fixed) == pytest.approx(1.0, abs=1e-7)
    cone = SecondOrderCone(F=np.eye(2), g=np.zeros(2), e=np.zeros(2), f=0.5)
    ball = ConvexProblem(P=np.eye(2), q=np.zeros(2), cones=(cone,))
    assert qpb.feasibility_margin(ball) == pytest.approx(0.5, abs=1e-6)


def _read_cbf(path: Path) -> dict:
    """A reader of what write_cbf writes (CBF: VAR, CON, OBJACOORD, ACOORD, BCOORD),
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
    np.testing.assert_allclose(np.asarray(solution.x)[:6], reference.z, atol=1e-4)


def test_cbf_read_by_mosek(tmp_path: Path) -> None:
    """MOSEK (where installed: reading needs no license) parses the file into the same
    variables and cones: the format as a conic benchmark's tool reads it."""
    mosek = pytest.importorskip("mosek")
    base = _random_qp(3)
    cone = SecondOrderCone(F=np.eye(2, 6), g=np.zeros(2), e=np.eye(6)[5], f=0.5)
    problem = ConvexProblem(
        P=base.P, q=base.q, A_eq=base.A_eq, b_eq=base.b_eq, G=base.G, l=base.l, u=base.u,
        lb=base.lb, ub=base.ub, cones=(cone,),
    )  # fmt: skip
    path = qpb.write_cbf(problem, tmp_path / "p.cbf")
    with mosek.Env() as env, env.Task() as task:
        task.readdata(str(path))
        assert task.getnumvar() == 7
        domains = [task.getdomaintype(task.getaccdomain(i)) for i in range(task.getnumacc())]
        assert domains.count(mosek.domaintype.quadratic_cone) == 1
        assert domains.count(mosek.domaintype.rquadratic_cone) == 1
        assert domains.count(mosek.domaintype.rzero) == 1  # the equality row


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
        assert r["nominal_status"] == ("optimal" if solved else "infeasible")
        margin = float(r["margin"])
        assert margin < 0 if r["kind"] == "infeasible" else margin > -1e-7, r
    for form in ("condensed", "sparse", "cone"):
        mine = [r for r in rows if r["form"] == form]
        near = [float(r["margin"]) for r in mine if r["kind"] == "near_infeasible"]
        others = [float(r["margin"]) for r in mine if r["kind"] == "nominal"]
        assert max(near) <= min(others)
    with pytest.raises(InvalidValueError, match="not empty"):
        qpb.export_test_set(exported, sources=qpb.SOURCES[:1], horizons=(5,), steps=2)
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
                sys.executable, "-c", "from qpbenchmark.benchmark import main; main()",
                str(exported / f"{module}.py"), "run", "--author", "test",
            ],
            capture_output=True, text=True, timeout=600, check=False,
        )  # fmt: skip  # the console script's call; no --results-path: results/ next to it
        assert done.returncode == 0, done.stderr[-3000:]
        assert (results / f"{module}.md").is_file()
        with open(results / f"{module}.csv", newline="") as handle:
            solvers = {r["solver"] for r in csv.DictReader(handle)}
        if form == "condensed":
            assert len(solvers) >= 6, solvers
    rows = qpb.qpbenchmark_metrics(exported)
    paths = qpb.write_metrics(exported, rows)
    assert "comparison_condensed" in paths and "comparison_sparse" in paths
    explained = (
        "acceptance layer refused",
        "the matrix type",
        "within a factor 100",
        "stopped inaccurate",
    )
    for form, module in qpb.MODULES.items():
        mine = [r for r in rows if r["form"] == form]
        table, differences = qpb.compare_results(mine, results / f"{module}.csv", exported)
        assert len(table) >= (6 if form == "condensed" else 4)
        # the same call under the same options: the same verdict on all but a few
        # (problem, solver, settings), each with a diagnosed cause
        assert len(differences) <= 0.05 * len(mine), differences
        for d in differences:
            assert any(cause in d["reason"] for cause in explained), d


def test_the_modules_other_invocations(exported: Path, tmp_path: Path) -> None:
    """`python <module>.py run --results-path X` writes X; `python -m qpbenchmark.benchmark
    <module> run` (qpbenchmark's module run as a script) writes results/ next to it; a
    set is loaded from its own folder even where another one's module is importable."""
    pytest.importorskip("qpbenchmark")
    module = exported / f"{qpb.MODULES['condensed']}.py"
    target = tmp_path / "mine.csv"
    for argv, written in (
        ([str(module), "--results-path", str(target)], target),
        (["-m", "qpbenchmark.benchmark", str(module)], None),
    ):
        copy = tmp_path / ("copy" if written is None else "first")
        shutil.copytree(exported, copy, ignore=shutil.ignore_patterns("results"))
        if written is None:
            argv = ["-m", "qpbenchmark.benchmark", str(copy / module.name)]
            written = copy / "results" / f"{qpb.MODULES['condensed']}.csv"
        done = subprocess.run(
            [sys.executable, *argv, "run", "--author", "test", "--solver", "daqp"],
            capture_output=True, text=True, timeout=600, check=False,
        )  # fmt: skip
        assert done.returncode == 0, done.stderr[-2000:]
        assert written.is_file()
    # another set's module of the same name first on sys.path: the folder's own is loaded
    other = tmp_path / "other"
    other.mkdir()
    (other / module.name).write_text(
        "class LtvLstmMpcDense:\n    solver_settings = {}\n    description = 'other'\n"
    )
    sys.path.insert(0, str(other))
    try:
        loaded = qpb._test_set(exported, "condensed")
    finally:
        sys.path.remove(str(other))
    assert "horizons 5" in loaded.description


def test_metrics_summary() -> None:
    pytest.importorskip("qpbenchmark")
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
    def run(*args: str) -> subprocess.CompletedProcess[str]:
        return subprocess.run(
            [sys.executable, "-m", "ltv_lstm_mpc.cli.main", "bench", *args],
            capture_output=True, text=True, check=False,
        )  # fmt: skip

    done = run("--qpbenchmark-set", str(tmp_path))
    assert done.returncode == 2 and "--export-qpbenchmark" in done.stderr
    done = run("--export-qpbenchmark", str(tmp_path / "new"), "--backends", "daqp")
    assert done.returncode == 2 and "--backends" in done.stderr
    (tmp_path / "full").mkdir()
    (tmp_path / "full" / "x").write_text("")
    done = run("--export-qpbenchmark", str(tmp_path / "full"))
    assert done.returncode == 2 and "not empty" in done.stderr


def test_export_names_the_missing_extra(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    import importlib.util

    real = importlib.util.find_spec
    monkeypatch.setattr(
        importlib.util, "find_spec", lambda name, *a: None if name == "clarabel" else real(name, *a)
    )
    with pytest.raises(InvalidValueError, match=r"\.\[bench\]"):
        qpb.export_test_set(tmp_path / "set", horizons=(5,), steps=2)
