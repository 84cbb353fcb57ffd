"""Every installed solver vs the CLARABEL reference: QPs, SOCPs, MPC, infeasible, warm start."""

from __future__ import annotations

import numpy as np
import pytest
from conftest import (
    CONE_SOLVERS,
    NO_NATIVE_STATUS,
    REFERENCE,
    SOLVERS,
    assert_close,
    problem,
    reference,
    solver_params,
    tol,
)
from ltv_lstm_mpc.solvers import (
    ConvexProblem,
    PolyhedralInnerApproximation,
    Session,
    SolverStatus,
    solve,
)
from ltv_lstm_mpc.solvers.testing import infeasible_problem, perturb
from optional_extras import require_solver

from ltv_lstm_mpc.exceptions import InvalidValueError

REFORM = PolyhedralInnerApproximation()


def kkt_residual(p: ConvexProblem, z: np.ndarray, duals: dict[str, np.ndarray]) -> float:
    """Stationarity residual ``P z + q + A_eq' y_eq + G' y_ineq + y_bounds`` (no cones)."""
    r = p.P @ z + p.q + duals["bounds"]
    if p.A_eq is not None:
        r = r + p.A_eq.T @ duals["eq"]
    if p.G is not None:
        r = r + p.G.T @ duals["ineq"]
    return float(np.max(np.abs(r)))


@pytest.mark.parametrize("name", ["qp", "qp_nobounds"])
@pytest.mark.parametrize("solver", solver_params())
def test_random_qp_matches_reference(solver: str, name: str) -> None:
    p = problem(name)
    sol = solve(p, solver)
    assert_close(sol, reference(name), tol(solver))
    assert sol.reformulation is None
    assert sol.solver == solver
    assert p.max_violation(sol.z) <= 1e-5 * (1 + np.max(np.abs(sol.z)))
    assert sol.objective == pytest.approx(p.objective(sol.z))
    assert min(sol.setup_time, sol.solve_time, sol.overhead_time) >= 0.0


@pytest.mark.parametrize("solver", solver_params())
def test_qp_duals_satisfy_stationarity(solver: str) -> None:
    p = problem("qp")
    sol = solve(p, solver)
    assert sol.z is not None
    if sol.duals is None:
        pytest.skip(f"{solver} returns no multipliers")
    res = kkt_residual(p, sol.z, dict(sol.duals))
    assert res <= tol(solver).kkt * (1 + np.max(np.abs(p.q))), f"KKT residual {res:.3g}"


@pytest.mark.parametrize("solver", solver_params())
def test_socp_matches_reference(solver: str) -> None:
    p = problem("socp")
    if solver in CONE_SOLVERS:
        sol = solve(p, solver)
        assert sol.reformulation is None
        assert_close(sol, reference("socp"), tol(solver))
    else:
        sol = solve(p, solver, reformulation=REFORM)
        assert sol.reformulation == REFORM.name
        assert_close(sol, reference("socp", reformulated=True), tol(solver))
        # conservative: the original cones hold, and the optimum is no better than the exact one
        assert sol.z is not None
        assert p.max_violation(sol.z) <= 1e-6 * (1 + np.max(np.abs(sol.z)))
        assert sol.objective >= reference("socp").objective - 1e-6


@pytest.mark.parametrize("solver", solver_params([s for s in SOLVERS if s not in CONE_SOLVERS]))
def test_qp_only_refuses_cones_without_reformulation(solver: str) -> None:
    with pytest.raises(InvalidValueError, match="second-order cone"):
        solve(problem("socp"), solver)


def _mpc_cases() -> list[object]:
    """(solver, horizon) for every solver; horizon 50 through cvxpy's QP-only solvers is
    ``slow`` (each pays a ~2 s DPP compilation for the same canonicalization)."""
    cases: list[object] = []
    for s in SOLVERS:
        cases.append(pytest.param(s, 5, id=f"{s}-5"))
        slow = s.startswith("cvxpy:") and s not in CONE_SOLVERS
        marks = (pytest.mark.slow,) if slow else ()
        cases.append(pytest.param(s, 50, id=f"{s}-50", marks=marks))
    return cases


@pytest.mark.parametrize(("solver", "horizon"), _mpc_cases())
def test_mpc_problem_matches_reference(solver: str, horizon: int) -> None:
    name = f"mpc{horizon}"
    p = problem(name)
    exact = solver in CONE_SOLVERS
    sol = solve(p, solver, reformulation=REFORM)
    assert sol.reformulation == (None if exact else REFORM.name)
    assert_close(sol, reference(name, reformulated=not exact), tol(solver))
    assert sol.z is not None
    viol_tol = 1e-4 if solver in ("cvxpy:SCS", "cvxpy:ECOS") else 1e-5
    assert p.max_violation(sol.z) <= viol_tol * (1 + np.max(np.abs(sol.z)))


@pytest.mark.parametrize("solver", solver_params())
def test_infeasible_is_not_optimal(solver: str) -> None:
    sol = solve(infeasible_problem(seed=1), solver)
    assert sol.z is None
    assert np.isnan(sol.objective)
    if solver in NO_NATIVE_STATUS:
        # documented limitation: qpsolvers exposes no native status for these solvers
        assert sol.status is SolverStatus.FAILED
        assert "not exposed" in sol.info
    else:
        assert sol.status is SolverStatus.INFEASIBLE, sol.info


@pytest.mark.parametrize("solver", solver_params(CONE_SOLVERS))
def test_infeasible_socp(solver: str) -> None:
    sol = solve(infeasible_problem(seed=2, cone=True), solver)
    assert sol.status is SolverStatus.INFEASIBLE, sol.info


@pytest.mark.parametrize("name", ["qp", "mpc5"])
@pytest.mark.parametrize("solver", solver_params())
def test_warm_start_equals_cold_start(solver: str, name: str) -> None:
    p0 = problem(name)
    p1 = perturb(p0, 1e-2, seed=11)
    assert p1.structure_key() == p0.structure_key()
    session = Session(solver, reformulation=REFORM)
    session.setup(p0)
    first = session.solve()
    session.update(p1)
    warm = session.solve(warm_start=first)
    cold = solve(p1, solver, reformulation=REFORM)
    t = tol(solver)
    assert_close(warm, cold, t)
    if session.backend == "qpsolvers":
        assert session.last_update == "fresh_setup"
        assert "fresh setup" in warm.info
    else:
        assert session.last_update == "in_place"
        assert session.n_setups == 1
    if solver.startswith("piqp") or solver == "cvxpy:PROXQP":
        assert "warm start ignored" in warm.info
    # the warm-started session also agrees with a high-accuracy cold reference
    require_solver(REFERENCE)
    exact = solver in CONE_SOLVERS or not p1.has_cones
    ref = solve(p1 if exact else REFORM.apply(p1), REFERENCE, tolerance=1e-10)
    assert_close(warm, ref, t)


@pytest.mark.parametrize("solver", solver_params())
def test_session_resolve_without_update_reports_no_setup(solver: str) -> None:
    p = problem("qp")
    session = Session(solver)
    session.setup(p)
    a = session.solve()
    b = session.solve()
    assert a.setup_time > 0.0
    assert b.setup_time == pytest.approx(0.0, abs=1e-3) or session.backend in ("cvxpy", "qpsolvers")
    assert_close(b, a, tol(solver))


def test_qpsolvers_backend_without_its_tolerance_options() -> None:
    """``tolerance_options=False``: the solver gets exactly the settings given (its own
    defaults elsewhere), the acceptance check keeps the session's tolerance."""
    require_solver("qpsolvers:osqp")
    from ltv_lstm_mpc.solvers import Session

    default = Session("qpsolvers:osqp", tolerance=1e-7)._backend.options
    assert default["eps_abs"] == 1e-7 and default["eps_rel"] == 1e-7
    exact = Session(
        "qpsolvers:osqp", tolerance=1e-7, tolerance_options=False, eps_abs=1e-4
    )._backend.options
    assert exact == {"eps_abs": 1e-4}
    with pytest.raises(InvalidValueError, match="tolerance_options"):
        Session("qpsolvers:osqp", tolerance_options="no")
