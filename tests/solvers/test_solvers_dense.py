"""DenseQP / DenseSession on every installed solver, registry extension, fault injection."""

from __future__ import annotations

import functools
import re
from collections.abc import Iterator, Mapping
from pathlib import Path
from typing import Any, ClassVar

import numpy as np
import pytest
from conftest import NO_NATIVE_STATUS, SOLVERS, Tol, assert_close, problem, reference, tol
from conftest import solver_params as params
from ltv_lstm_mpc.solvers import (
    DenseBackend,
    DenseQP,
    DenseSession,
    Session,
    Solution,
    SolverStatus,
    available_solvers,
    feasibility_tolerance,
    register_backend,
    solve,
    solver_info,
    unregister_backend,
)
from ltv_lstm_mpc.solvers._base import RawResult, WarmStart
from ltv_lstm_mpc.solvers.testing import (
    GARBAGE,
    faulty,
    infeasible_dense_qp,
    random_dense_qp,
    random_socp,
)
from optional_extras import backend_params, first_installed, requires_solver

from ltv_lstm_mpc.exceptions import DimensionError, InvalidValueError, SolverNotFound


def dense_reference_solver() -> str:
    """The reference solver of the dense QPs (quadprog, else CLARABEL through cvxpy); skips
    the test where neither is installed."""
    return first_installed("quadprog", "cvxpy:CLARABEL")


#: dense problems: (n, m_A, seed, equalities)
CASES = {"small": (5, 10, 1, 0), "mpc": (20, 40, 2, 2), "nobounds": (12, 30, 3, 0)}


@functools.cache
def dense(name: str) -> DenseQP:
    n, m, seed, eq = CASES[name]
    return random_dense_qp(n, m, seed, equalities=eq, bounds=name != "nobounds")


@functools.cache
def dense_reference(name: str) -> Solution:
    sol = DenseSession(dense_reference_solver(), tolerance=1e-10).solve(dense(name).copy())
    assert sol.status is SolverStatus.OPTIMAL, sol.info
    return sol


def _check(sol: Solution, qp: DenseQP, ref: Solution, solver: str) -> None:
    assert_close(sol, ref, tol(solver))
    assert sol.z is not None
    assert qp.max_violation(sol.z) <= feasibility_tolerance(solver, 1e-8) * (
        1 + np.max(np.abs(sol.z))
    )
    assert sol.objective == pytest.approx(qp.objective(sol.z), rel=1e-12, abs=1e-12)
    assert min(sol.setup_time, sol.solve_time, sol.overhead_time) >= 0.0
    assert sol.solver == solver


# --------------------------------------------------------------------------------------
# DenseQP
# --------------------------------------------------------------------------------------
def test_dense_qp_check_names_the_array() -> None:
    qp = random_dense_qp(4, 3, 0)
    qp.check()
    assert qp.structure_key() == (4, 3) and qp.n_variables == 4 and qp.n_rows == 3
    cases: list[tuple[str, Any, type[Exception], str]] = [
        ("H", np.eye(3), DimensionError, r"H must have shape \(4, 4\)"),
        ("A", np.ones((3, 5)), DimensionError, r"A must have shape \(m_A, 4\)"),
        ("lo", np.zeros(2), DimensionError, r"lo must have shape \(3,\)"),
        ("ub", np.zeros(5), DimensionError, r"ub must have shape \(4,\)"),
        ("f", np.array([0.0, np.nan, 0, 0]), InvalidValueError, "f has non-finite"),
        ("A", np.full((3, 4), np.inf), InvalidValueError, "A has non-finite"),
        ("H", np.triu(np.ones((4, 4))) + 4 * np.eye(4), InvalidValueError, "symmetric"),
        ("lb", np.array([0.0, np.nan, 0, 0]), InvalidValueError, "lb has NaN"),
        ("lo", np.full(3, np.inf), InvalidValueError, r"lo has \+inf"),
        ("ub", np.full(4, -5.0), InvalidValueError, "lb > ub"),
    ]
    for name, value, exc, match in cases:
        bad = qp.copy()
        setattr(bad, name, value)
        with pytest.raises(exc, match=match):
            bad.check()


def test_dense_qp_violation_objective_and_conversion(tmp_path: Path) -> None:
    qp = dense("mpc")
    x = np.zeros(qp.n_variables)
    assert qp.objective(x) == 0.0
    assert qp.max_violation(np.full(qp.n_variables, np.nan)) == np.inf
    ref = dense_reference("mpc")
    assert ref.z is not None and qp.max_violation(ref.z) <= 1e-9
    cp = qp.to_convex_problem()
    assert cp.n_variables == qp.n_variables and cp.n_ineq == qp.n_rows and not cp.has_cones
    assert cp.objective(ref.z) == pytest.approx(qp.objective(ref.z))
    assert cp.max_violation(ref.z) == pytest.approx(qp.max_violation(ref.z), abs=1e-12)
    # the pattern of the converted problem does not depend on the values
    other = qp.copy()
    other.A[0, 0] = 0.0
    other.H[:] = np.eye(qp.n_variables)
    assert other.to_convex_problem().structure_key() == cp.structure_key()
    path = qp.save(tmp_path / "qp")
    loaded = DenseQP.load(path)
    for name in ("H", "f", "A", "lo", "up", "lb", "ub"):
        np.testing.assert_array_equal(getattr(loaded, name), getattr(qp, name))
    np.savez(tmp_path / "bad.npz", format_version=np.asarray(7))
    with pytest.raises(InvalidValueError, match="not a DenseQP file"):
        DenseQP.load(tmp_path / "bad.npz")


# --------------------------------------------------------------------------------------
# every solver on dense QPs
# --------------------------------------------------------------------------------------
@pytest.mark.parametrize("name", list(CASES))
@pytest.mark.parametrize("solver", params())
def test_dense_matches_reference(solver: str, name: str) -> None:
    qp = dense(name).copy()
    session = DenseSession(solver)
    sol = session.solve(qp)
    _check(sol, qp, dense_reference(name), solver)
    assert session.n_setups == 1 and session.last_update == "setup"
    assert session.backend == sol.backend


@pytest.mark.parametrize("solver", params())
def test_dense_infeasible(solver: str) -> None:
    sol = DenseSession(solver).solve(infeasible_dense_qp(seed=1))
    assert sol.z is None and np.isnan(sol.objective)
    if solver in NO_NATIVE_STATUS:
        assert sol.status is SolverStatus.FAILED
    else:
        assert sol.status is SolverStatus.INFEASIBLE, sol.info


@pytest.mark.parametrize("solver", params())
def test_dense_update_path_equals_fresh_session(solver: str) -> None:
    """Same structure, new values (in place, as an MPC does): same answer as a fresh session."""
    qp = dense("mpc").copy()
    session = DenseSession(solver)
    first = session.solve(qp)
    assert first.ok
    rng = np.random.default_rng(5)
    for step in range(3):
        qp.f[:] = dense("mpc").f * (1 + 0.1 * rng.standard_normal(qp.n_variables))
        qp.A[:] = dense("mpc").A + 0.01 * rng.standard_normal(qp.A.shape)
        warm = session.solve(qp, warm_start=first if step % 2 else None)
        assert session.last_update == "in_place" and session.n_setups == 1
        fresh = DenseSession(dense_reference_solver(), tolerance=1e-10).solve(qp.copy())
        _check(warm, qp, fresh, solver)
        first = warm


@pytest.mark.parametrize("solver", params())
def test_dense_structure_change_triggers_setup_and_warm_start(solver: str) -> None:
    session = DenseSession(solver)
    a = session.solve(dense("small").copy())
    assert session.structure_key == (5, 10)
    assert a.ok
    b = session.solve(dense("mpc").copy())  # a new structure: setup
    assert session.n_setups == 2 and session.last_update == "setup"
    assert session.structure_key == (20, 40)
    _check(b, dense("mpc"), dense_reference("mpc"), solver)
    assert b.z is not None
    c = session.solve(dense("mpc").copy(), warm_start=b)  # from a Solution
    d = session.solve(dense("mpc").copy(), warm_start=np.array(b.z))  # from a point
    for sol in (c, d):
        _check(sol, dense("mpc"), dense_reference("mpc"), solver)
    session.reset()
    e = session.solve(dense("mpc").copy())
    assert session.last_update == "setup"
    _check(e, dense("mpc"), dense_reference("mpc"), solver)
    with pytest.raises(DimensionError, match="warm_start must have shape"):
        session.solve(dense("mpc").copy(), warm_start=np.zeros(3))


@pytest.mark.parametrize("solver", params())
def test_dense_setup_checks_the_qp(solver: str) -> None:
    bad = dense("small").copy()
    bad.f = np.array([np.nan, 0.0, 0.0, 0.0, 0.0])
    with pytest.raises(InvalidValueError, match="f has non-finite"):
        DenseSession(solver).solve(bad)


@pytest.mark.parametrize(
    "solver",
    params(
        [
            s
            for s in SOLVERS
            if s.split(":")[-1].lower()
            in {"osqp", "piqp", "daqp", "quadprog", "proxqp", "clarabel", "ecos"}
        ]
    ),
)
def test_dense_rejects_unknown_settings(solver: str) -> None:
    with pytest.raises(InvalidValueError, match="unknown setting"):
        DenseSession(solver, not_a_setting=1)


@pytest.mark.parametrize("tolerance", [0.0, -1.0, float("nan"), float("inf")])
def test_dense_rejects_bad_tolerance(tolerance: float) -> None:
    with pytest.raises(InvalidValueError, match="tolerance"):
        DenseSession("daqp" if "daqp" in SOLVERS else SOLVERS[0], tolerance=tolerance)


def test_dense_unknown_solver() -> None:
    """A name that is no backend: the registry's message, which lists the installed ones
    (install advice only for a backend whose package is missing: tests/test_cli_design.py)."""
    with pytest.raises(SolverNotFound, match=r"solver 'nope' is not available.*Installed: "):
        DenseSession("nope")


def test_dense_malformed_z_is_failed() -> None:
    name = faulty(SOLVERS[-1], "nan")
    try:
        sol = DenseSession(name).solve(dense("small").copy())
        assert sol.status is SolverStatus.FAILED and sol.z is None
        assert "non-finite z" in sol.info
    finally:
        unregister_backend(name)


# --------------------------------------------------------------------------------------
# quadprog / proxqp through Session
# --------------------------------------------------------------------------------------
NEW_NATIVE = backend_params("quadprog", "proxqp")


@pytest.mark.parametrize("name", ["qp", "qp_nobounds"])
@pytest.mark.parametrize("solver", NEW_NATIVE)
def test_new_natives_solve_convex_problems(solver: str, name: str) -> None:
    sol = solve(problem(name), solver)
    assert_close(sol, reference(name), tol(solver))
    assert sol.backend == solver and sol.duals is not None
    assert set(sol.duals) == {"eq", "ineq", "bounds"}
    assert sol.duals["eq"].shape == (problem(name).n_eq,)


@pytest.mark.parametrize("solver", NEW_NATIVE)
def test_new_natives_refuse_cones(solver: str) -> None:
    with pytest.raises(InvalidValueError, match="second-order cone"):
        solve(random_socp(seed=1), solver)
    assert not solver_info(solver).supports_cones and solver_info(solver).native_dense


# --------------------------------------------------------------------------------------
# registry: info, user backends
# --------------------------------------------------------------------------------------
def test_solver_info() -> None:
    for name in SOLVERS:
        info = solver_info(name)
        assert info.name == name
    if "daqp" in SOLVERS:
        assert solver_info("daqp").native_dense and not solver_info("daqp").first_order
    if "osqp" in SOLVERS:
        assert solver_info("osqp").first_order
    if "cvxpy:CLARABEL" in SOLVERS:
        assert solver_info("cvxpy:CLARABEL").supports_cones
        assert solver_info("cvxpy:CLARABEL").native_dense  # its own dense backend (CvxpyDense)
    assert solver_info("cvxpy:SCS").first_order if "cvxpy:SCS" in SOLVERS else True
    with pytest.raises(SolverNotFound, match=re.escape(f"Installed: {SOLVERS[0]}")):
        solver_info("gurobi")


class _ClippedGradient(DenseBackend):
    """A toy user dense backend: box-constrained QP by projected gradient (no rows)."""

    backend: ClassVar[str] = "toy"
    supports_update = True

    def setup(self, qp: DenseQP) -> None:
        self.update(qp)

    def update(self, qp: DenseQP) -> None:
        self._qp = qp

    def solve(self, warm_start: WarmStart | None) -> RawResult:
        qp = self._qp
        assert qp.n_rows == 0
        step = 1.0 / np.linalg.eigvalsh(qp.H)[-1]
        x = np.clip(np.zeros(qp.n_variables), qp.lb, qp.ub)
        for _ in range(5000):
            x = np.clip(x - step * (qp.H @ x + qp.f), qp.lb, qp.ub)
        return RawResult(SolverStatus.OPTIMAL, "done", x, None, 0.0, 5000)


def _toy(name: str, tolerance: float, settings: Mapping[str, Any]) -> DenseBackend:
    return _ClippedGradient(name, "toy", settings)


@pytest.fixture
def toy() -> Iterator[str]:
    name = register_backend("user:toy", dense_factory=_toy)
    yield name
    unregister_backend(name)


def test_register_backend_end_to_end(toy: str) -> None:
    assert toy in available_solvers() and solver_info(toy).family == "user"
    assert solver_info(toy).native_dense
    qp = random_dense_qp(6, 0, 4)
    sol = DenseSession(toy).solve(qp)
    ref = DenseSession(dense_reference_solver(), tolerance=1e-10).solve(qp.copy())
    assert_close(sol, ref, Tol(z=1e-6, objective=1e-8))
    # the ConvexProblem side goes through the dense adapter
    sol2 = solve(qp.to_convex_problem(), toy)
    assert sol2.backend == "toy"
    assert_close(sol2, ref, Tol(z=1e-6, objective=1e-8))
    with pytest.raises(InvalidValueError, match="already registered"):
        register_backend(toy, dense_factory=_toy)
    register_backend(toy, dense_factory=_toy, replace=True)


@requires_solver("cvxpy:CLARABEL")
def test_register_backend_sparse_factory_serves_dense() -> None:
    from ltv_lstm_mpc.solvers import get_backend

    name = register_backend(
        "user:clarabel-copy", get_backend("cvxpy:CLARABEL"), supports_cones=True
    )
    try:
        assert solver_info(name).supports_cones and not solver_info(name).native_dense
        sol = DenseSession(name).solve(dense("small").copy())
        _check(sol, dense("small"), dense_reference("small"), name)
        assert Session(name).backend == "cvxpy"
    finally:
        unregister_backend(name)
    assert name not in available_solvers()
    with pytest.raises(SolverNotFound):
        unregister_backend(name)


@pytest.mark.parametrize("bad", ["", "has space", 3, None, "ünï"])
def test_register_backend_rejects_bad_names(bad: object) -> None:
    with pytest.raises(InvalidValueError, match="solver name"):
        register_backend(bad, dense_factory=_toy)  # type: ignore[arg-type]


def test_register_backend_needs_a_callable_factory() -> None:
    with pytest.raises(InvalidValueError, match="factory"):
        register_backend("user:none")
    with pytest.raises(InvalidValueError, match="callable"):
        register_backend("user:bad", dense_factory=3)  # type: ignore[arg-type]
    assert "user:none" not in available_solvers()


# --------------------------------------------------------------------------------------
# fault injection
# --------------------------------------------------------------------------------------
FAULT_BASE = "daqp" if "daqp" in SOLVERS else "cvxpy:CLARABEL"


@pytest.fixture
def cleanup() -> Iterator[list[str]]:
    names: list[str] = []
    yield names
    for name in names:
        if name in available_solvers():
            unregister_backend(name)


@pytest.mark.parametrize("fault", ["nan", "garbage", "raise", "infeasible"])
def test_faulty_on_dense_and_sparse_sessions(fault: str, cleanup: list[str]) -> None:
    name = faulty(FAULT_BASE, fault, calls=[1, 2])
    cleanup.append(name)
    assert name == f"faulty:{fault}@1,2:{FAULT_BASE}"
    assert name in available_solvers()
    base = solver_info(FAULT_BASE)
    info = solver_info(name)
    assert (info.supports_cones, info.native_dense, info.first_order) == (
        base.supports_cones,
        base.native_dense,
        base.first_order,
    )
    qp = dense("small").copy()
    p = problem("qp")
    dense_session = DenseSession(name)
    sparse_session = Session(name)
    sparse_session.setup(p)

    def check_fault(sol_fn: Any, n: int, feasible: Any) -> None:
        if fault == "raise":
            with pytest.raises(RuntimeError, match="injected fault"):
                sol_fn()
            return
        sol = sol_fn()
        if fault == "nan":
            assert sol.status is SolverStatus.FAILED and sol.z is None
        elif fault == "garbage":
            # reported OPTIMAL by the backend, refused by the layer's acceptance check
            assert sol.status is SolverStatus.FAILED and sol.z is None
            assert "acceptance: OPTIMAL -> FAILED" in sol.info
            assert sol.residuals is not None and sol.residuals.primal > 1.0
        else:
            assert sol.status is SolverStatus.INFEASIBLE and sol.z is None
        assert "injected fault" in sol.info

    # call 0 (dense): real; call 1 (sparse): fault; call 2 (dense): fault; call 3 (sparse): real
    assert dense_session.solve(qp).status is SolverStatus.OPTIMAL
    check_fault(sparse_session.solve, p.n_variables, p.max_violation)
    check_fault(lambda: dense_session.solve(qp), qp.n_variables, qp.max_violation)
    good = sparse_session.solve()
    if fault == "garbage":  # the hot-loop call leaves the check to its caller
        first = faulty(FAULT_BASE, fault, calls=[0])
        cleanup.append(first)
        status, z, _, _ = DenseSession(first).solve_point(qp)
        assert status is SolverStatus.OPTIMAL and z is not None and np.all(z == GARBAGE)
        assert qp.max_violation(z) > 1.0
    # re-registering gives a fresh counter
    assert faulty(FAULT_BASE, fault, calls=[1, 2]) == name
    assert DenseSession(name).solve(qp).ok
    assert_close(good, reference("qp"), tol(FAULT_BASE))  # last: it needs the reference solver


def test_faulty_every_call_and_errors(cleanup: list[str]) -> None:
    name = faulty(FAULT_BASE, "infeasible")
    cleanup.append(name)
    assert name == f"faulty:infeasible@all:{FAULT_BASE}"
    session = DenseSession(name)
    for _ in range(3):
        assert session.solve(dense("small").copy()).status is SolverStatus.INFEASIBLE
    one = faulty(FAULT_BASE, "nan", calls=0)
    cleanup.append(one)
    assert one == f"faulty:nan@0:{FAULT_BASE}"
    with pytest.raises(InvalidValueError, match=r"nan.*garbage.*raise.*infeasible"):
        faulty(FAULT_BASE, "explode")
    with pytest.raises(SolverNotFound):
        faulty("nope", "nan")
    with pytest.raises(InvalidValueError, match=">= 0"):
        faulty(FAULT_BASE, "nan", calls=[-1])


# --------------------------------------------------------------------------------------
# feasibility tolerance
# --------------------------------------------------------------------------------------
def test_feasibility_tolerance_values() -> None:
    assert feasibility_tolerance("daqp", 1e-8) == pytest.approx(1e-6)
    assert feasibility_tolerance("daqp", 1e-12) == pytest.approx(1e-7)
    assert feasibility_tolerance("cvxpy:CLARABEL", 1e-6) == pytest.approx(1e-4)
    for name in ("osqp", "proxqp", "cvxpy:SCS", "qpsolvers:osqp", "cvxpy:PROXQP"):
        assert feasibility_tolerance(name, 1e-8) == pytest.approx(1e-5)
        assert feasibility_tolerance(name, 1e-6) == pytest.approx(1e-3)
    with pytest.raises(InvalidValueError, match="tolerance"):
        feasibility_tolerance("osqp", 0.0)


# --------------------------------------------------------------------------------------
# solve_point: the hot-loop call
# --------------------------------------------------------------------------------------
@pytest.mark.parametrize("name", list(CASES))
@pytest.mark.parametrize("solver", params())
def test_solve_point_equals_solve(solver: str, name: str) -> None:
    """Same status and point as ``solve`` (cold), on the setup and the in-place path."""
    qp = dense(name).copy()
    lean, full = DenseSession(solver), DenseSession(solver)
    for step in range(2):
        if step:
            qp.f[:] = 1.1 * dense(name).f
        status, z, iterations, info = lean.solve_point(qp)
        sol = full.solve(qp)
        assert status is sol.status, info
        assert z is not None and sol.z is not None
        np.testing.assert_allclose(z, sol.z, rtol=0, atol=1e-12)
        assert iterations >= 0 and isinstance(info, str) and info
        assert qp.max_violation(z) <= feasibility_tolerance(solver, 1e-8) * (1 + np.abs(z).max())
    assert lean.last_update == ("in_place" if lean._in_place else "fresh_setup")


@pytest.mark.parametrize("solver", params())
def test_solve_point_infeasible(solver: str) -> None:
    status, z, _, info = DenseSession(solver).solve_point(infeasible_dense_qp(seed=1))
    assert z is None
    expected = SolverStatus.FAILED if solver in NO_NATIVE_STATUS else SolverStatus.INFEASIBLE
    assert status is expected, info


@pytest.mark.parametrize("fault", ["nan", "garbage", "raise", "infeasible"])
def test_solve_point_sees_faults(fault: str, cleanup: list[str]) -> None:
    name = faulty(FAULT_BASE, fault, calls=[1])
    cleanup.append(name)
    qp = dense("small").copy()
    session = DenseSession(name)
    assert session.solve_point(qp)[0] is SolverStatus.OPTIMAL
    if fault == "raise":
        with pytest.raises(RuntimeError, match="injected fault"):
            session.solve_point(qp)
        return
    status, z, _, info = session.solve_point(qp)
    assert "injected fault" in info
    if fault == "nan":
        assert status is SolverStatus.FAILED and z is None
        assert "non-finite" in info
    elif fault == "garbage":
        assert status is SolverStatus.OPTIMAL and z is not None and np.all(z == GARBAGE)
    else:
        assert status is SolverStatus.INFEASIBLE and z is None


#: Every installed backend the registry lists as solving cones exactly (no faulty names).
CONE_BASES = [s for s in SOLVERS if solver_info(s).supports_cones and not s.startswith("faulty:")]


@pytest.mark.parametrize("base", CONE_BASES)
def test_faulty_keeps_the_capabilities_of_a_cone_backend(base: str, cleanup: list[str]) -> None:
    """A faulty cone backend solves the cones on the calls it does not fault, on the dense
    and on the sparse session, with the wrapped backend's in-place update and warm start."""
    name = faulty(base, "nan", calls=[1, 4])
    cleanup.append(name)
    assert solver_info(name).supports_cones
    for make in (DenseSession, Session):
        wrapped, plain = make(name), make(base)
        for attribute in ("supports_cones", "supports_update", "supports_warm_start"):
            assert getattr(wrapped._backend, attribute) == getattr(plain._backend, attribute)
        assert wrapped._backend.handles_cones() == plain._backend.handles_cones()
    socp = problem("socp")
    qp = DenseQP.from_convex_problem(socp)
    assert qp.cones and socp.cones
    expected_dense = DenseSession(base).solve(qp)
    expected_sparse = solve(socp, base)
    dense_session = DenseSession(name)
    sparse_session = Session(name)
    sparse_session.setup(socp)
    # calls 0, 2: dense; 1, 3: sparse; 4: dense; 5: sparse (0-based, one shared counter)
    for call in range(6):
        if call % 2 == 0:
            sol = dense_session.solve(qp)
            expected = expected_dense
        else:
            sol = sparse_session.solve()
            expected = expected_sparse
        if call in (1, 4):
            assert sol.status is SolverStatus.FAILED and "injected fault" in sol.info
            continue
        assert sol.status is SolverStatus.OPTIMAL, sol.info
        assert sol.z is not None and expected.z is not None
        np.testing.assert_allclose(sol.z, expected.z, atol=10 * tol(base).z)


# --------------------------------------------------------------------------------------
# cvxpy dense sessions scale
# --------------------------------------------------------------------------------------
@requires_solver("cvxpy:OSQP")
def test_cvxpy_dense_session_memory_is_quadratic_in_n() -> None:
    """A dense QP with n = 60 variables and 60 rows through ``DenseSession("cvxpy:OSQP")``
    allocates a few MB, not the ~250 MB of a parameter per nonzero (which grows like n^4:
    0.8 GB at n = 80); the answer equals quadprog's."""
    import tracemalloc

    qp = random_dense_qp(60, 60, seed=4)
    session = DenseSession("cvxpy:OSQP")
    tracemalloc.start()
    try:
        sol = session.solve(qp)
        _, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    assert peak < 40e6, f"peak {peak / 1e6:.0f} MB"
    ref = DenseSession(dense_reference_solver()).solve(qp)
    assert sol.status is SolverStatus.OPTIMAL and sol.z is not None and ref.z is not None
    assert np.max(np.abs(sol.z - ref.z)) <= 1e-4 * (1.0 + np.max(np.abs(ref.z)))


# --------------------------------------------------------------------------------------
# optional Ruiz equilibration
# --------------------------------------------------------------------------------------
def _rescaled(qp: DenseQP, spread: float, seed: int) -> tuple[DenseQP, np.ndarray, np.ndarray]:
    """``qp`` in other units: variables x = S x', rows scaled by R (its solution is S^-1 x*)."""
    rng = np.random.default_rng(seed)
    S = 10.0 ** rng.uniform(-spread, spread, qp.n_variables)
    R = 10.0 ** rng.uniform(-spread, spread, qp.n_rows)
    bad = DenseQP(
        H=(qp.H * S) * S[:, None], f=qp.f * S, A=(qp.A * S) * R[:, None],
        lo=qp.lo * R, up=qp.up * R, lb=qp.lb / S, ub=qp.ub / S,
    )  # fmt: skip
    return bad, S, R


@pytest.mark.parametrize("solver", params([s for s in SOLVERS if solver_info(s).native_dense]))
def test_equilibrated_session_gives_the_same_answer(solver: str) -> None:
    """With ``equilibrate=True`` the point, objective and multipliers (mapped back) are
    those of the plain session, and they pass the acceptance check on the original QP."""
    qp = dense("small").copy()
    plain = DenseSession(solver).solve(qp)
    scaled = DenseSession(solver, equilibrate=True).solve(qp)
    assert scaled.status is SolverStatus.OPTIMAL, scaled.info
    assert "Ruiz-equilibrated" in scaled.info
    assert plain.z is not None and scaled.z is not None
    t = tol(solver)
    scale = 1.0 + float(np.max(np.abs(plain.z)))
    assert np.max(np.abs(scaled.z - plain.z)) <= t.z * scale
    assert scaled.residuals is not None and scaled.residuals.stationarity is not None
    status, z, _, _ = DenseSession(solver, equilibrate=True).solve_point(qp)
    assert status is SolverStatus.OPTIMAL and z is not None
    assert np.max(np.abs(z - scaled.z)) <= t.z * scale


@pytest.mark.parametrize("solver", backend_params("daqp", "osqp"))
def test_equilibration_rescues_a_badly_scaled_qp(solver: str) -> None:
    """A QP whose variables and rows are rescaled by factors spread over 1e-6 ... 1e6:
    without equilibration daqp / osqp give no OPTIMAL point (an honest status); with it,
    the point is the rescaled solution of the original QP."""
    qp = random_dense_qp(12, 24, seed=2)
    x_star = DenseSession(first_installed("quadprog", "clarabel")).solve(qp).z
    assert x_star is not None
    bad, S, _ = _rescaled(qp, 6.0, seed=102)
    plain = DenseSession(solver).solve(bad.copy())
    assert plain.status is not SolverStatus.OPTIMAL, plain.info
    fixed = DenseSession(solver, equilibrate=True).solve(bad.copy())
    assert fixed.status is SolverStatus.OPTIMAL and fixed.z is not None, fixed.info
    expected = x_star / S
    err = np.max(np.abs(fixed.z - expected) / (1.0 + np.abs(expected)))
    assert err <= 1e3 * tol(solver).z, err


def test_acceptance_catches_a_wrong_point_hidden_by_scaling() -> None:
    """x* = (1, 1) of H = diag(1e12, 1), f = -(1e12, 1); the point (1, 2) is 100 % off in
    the second variable. A global relative stationarity residual (1 / 1e12) misses it, the
    layer's per-variable one (1 / 2) does not, and such a point is not passed on."""
    from ltv_lstm_mpc.solvers.acceptance import ProblemView, accept, residuals

    qp = DenseQP(
        np.diag([1e12, 1.0]), -np.array([1e12, 1.0]), np.zeros((0, 2)), np.zeros(0),
        np.zeros(0), np.full(2, -np.inf), np.full(2, np.inf),
    )  # fmt: skip
    wrong = np.array([1.0, 2.0])
    duals = {"ineq": np.zeros(0), "bounds": np.zeros(2)}
    gradient = qp.H @ wrong + qp.f
    assert np.max(np.abs(gradient)) / (1.0 + np.max(np.abs(qp.H @ wrong))) < 1e-11
    res = residuals(ProblemView.of_dense(qp), wrong, duals)
    assert res.stationarity == pytest.approx(1.0 / 3.0)
    raw = RawResult(SolverStatus.OPTIMAL, "claimed", wrong, duals, 0.0, 1)
    checked, _ = accept(ProblemView.of_dense(qp), raw, 1e-6, 1e-6)
    assert checked.status is SolverStatus.FAILED and checked.z is None
