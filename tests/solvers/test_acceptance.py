"""The layer's acceptance check (solvers/acceptance.py): residuals, verdicts, certificates."""

from __future__ import annotations

import numpy as np
import pytest
from ltv_lstm_mpc.solvers import (
    ConvexProblem,
    DenseCone,
    DenseQP,
    DenseSession,
    SolverStatus,
    solve,
)
from ltv_lstm_mpc.solvers._base import RawResult
from ltv_lstm_mpc.solvers.acceptance import (
    INACCURATE_FACTOR,
    ProblemView,
    accept,
    check_infeasibility_certificate,
    check_unbounded_direction,
    residuals,
)
from ltv_lstm_mpc.solvers.testing import infeasible_problem
from optional_extras import backend_params


def _qpsut04() -> tuple[ConvexProblem, np.ndarray, dict[str, np.ndarray]]:
    """min 1/2|x|^2 + 0.01 sum x s.t. x <= 1, sum x = 1: x = 1/3, y_eq = -(1/3 + 0.01)."""
    problem = ConvexProblem(
        P=np.eye(3), q=0.01 * np.ones(3), A_eq=np.ones((1, 3)), b_eq=[1.0],
        G=np.eye(3), u=np.ones(3),
    )  # fmt: skip
    x = np.ones(3) / 3.0
    duals = {"eq": np.array([-(1.0 / 3.0 + 0.01)]), "ineq": np.zeros(3)}
    return problem, x, duals


def _raw(z: np.ndarray | None, duals: dict[str, np.ndarray] | None, **kw: object) -> RawResult:
    status = kw.pop("status", SolverStatus.OPTIMAL)
    return RawResult(status, "test", z, duals, 0.0, 1, **kw)  # type: ignore[arg-type]


def test_residuals_vanish_at_the_kkt_point_and_grow_away_from_it() -> None:
    problem, x, duals = _qpsut04()
    view = ProblemView.of_convex(problem)
    exact = residuals(view, x, duals)
    assert exact.primal == pytest.approx(0.0, abs=1e-15)
    assert exact.stationarity == pytest.approx(0.0, abs=1e-15)
    assert exact.complementarity == pytest.approx(0.0, abs=1e-15)
    off = residuals(view, x + np.array([1e-3, -1e-3, 0.0]), duals)
    assert off.stationarity == pytest.approx(1e-3 / (1.0 + 0.01 + 1.0 / 3.0 + 1e-3), rel=0.5)
    infeasible = residuals(view, x + 0.1, duals)  # sum x = 1.3: eq row violated by 0.3
    assert infeasible.primal == pytest.approx(0.3 / 2.0)
    no_duals = residuals(view, x, None)
    assert no_duals.stationarity is None and "no multipliers" in no_duals.unchecked


def test_verdicts_optimal_inaccurate_failed() -> None:
    problem, x, duals = _qpsut04()
    view = ProblemView.of_convex(problem)
    ok, _ = accept(view, _raw(x, duals), 1e-6, 1e-6)
    assert ok.status is SolverStatus.OPTIMAL and ok.z is not None
    near = x + np.array([1e-5, -1e-5, 0.0])  # stationarity ~1e-5: within 100x
    inaccurate, res = accept(view, _raw(near, duals), 1e-6, 1e-6)
    assert inaccurate.status is SolverStatus.OPTIMAL_INACCURATE
    assert res is not None and 1e-6 < (res.stationarity or 0.0) <= INACCURATE_FACTOR * 1e-6
    assert "OPTIMAL -> OPTIMAL_INACCURATE" in inaccurate.notes[-1]
    failed, _ = accept(view, _raw(x + 0.1, duals), 1e-6, 1e-6)
    assert failed.status is SolverStatus.FAILED and failed.z is None and failed.duals is None
    assert "not a solution" in failed.notes[-1]


def test_a_point_far_out_on_a_ray_is_unbounded() -> None:
    """cvxpy:HIGHS' answer to a QP unbounded below: a point 1e7 out on the ray."""
    v = np.array([1.0, 2.0, -1.0])
    problem = ConvexProblem(P=np.outer(v, v), q=np.array([1.0, 0.0, 1.0]))
    view = ProblemView.of_convex(problem)
    d = np.array([1.0, 0.0, 1.0])  # P d = 0 (v'd = 0), q'd = 2 > 0: descent along -d
    checked, _ = accept(view, _raw(-1e7 * d, {}), 1e-6, 1e-6)
    assert checked.status is SolverStatus.UNBOUNDED and checked.z is None
    assert checked.certificate is not None
    np.testing.assert_allclose(checked.certificate["direction"], -d)


def test_certificates_checked_and_refused() -> None:
    problem = ConvexProblem(
        P=np.eye(2), q=np.ones(2), G=np.array([[1.0, 0.0], [1.0, 0.0]]),
        l=[1.0, -np.inf], u=[np.inf, 0.0],
    )  # fmt: skip
    view = ProblemView.of_convex(problem)
    farkas = {"ineq": np.array([-1.0, 1.0])}  # -(x1 >= 1) + (x1 <= 0): 0 <= -1
    valid, numbers = check_infeasibility_certificate(view, farkas, 1e-6)
    assert valid, numbers
    wrong = {"ineq": np.array([1.0, 1.0])}
    assert not check_infeasibility_certificate(view, wrong, 1e-6)[0]
    raw = _raw(None, None, status=SolverStatus.INFEASIBLE, certificate=wrong)
    checked, _ = accept(view, raw, 1e-6, 1e-6)
    assert checked.status is SolverStatus.FAILED and "does not check" in checked.notes[-1]
    bounded = ConvexProblem(P=np.diag([1.0, 0.0]), q=[0.0, -1.0], lb=[-1, -1], ub=[1, 1])
    assert not check_unbounded_direction(ProblemView.of_convex(bounded), np.eye(2)[1], 1e-6)[0]


@pytest.mark.parametrize("solver", backend_params("osqp", "clarabel"))
def test_native_certificates_reach_the_solution(solver: str) -> None:
    problem = infeasible_problem(seed=1)
    sol = solve(problem, solver)
    assert sol.status is SolverStatus.INFEASIBLE and sol.certificate is not None
    assert "infeasibility certificate checked" in sol.info
    valid, _ = check_infeasibility_certificate(
        ProblemView.of_convex(problem), sol.certificate, 1e-5
    )
    assert valid
    v = np.array([1.0, 2.0, -1.0])
    unbounded = ConvexProblem(
        P=np.outer(v, v), q=np.array([1.0, 0.0, 1.0]), lb=[-np.inf] * 3, ub=[5.0, np.inf, np.inf]
    )
    sol = solve(unbounded, solver)
    assert sol.status is SolverStatus.UNBOUNDED and sol.certificate is not None
    assert "unboundedness certificate checked" in sol.info


@pytest.mark.parametrize("solver", backend_params("clarabel", "cvxpy:CLARABEL"))
def test_cone_multipliers_are_checked_where_reported(solver: str) -> None:
    """A dense QP with a second-order cone: the cone's multipliers enter stationarity."""
    n = 4
    qp = DenseQP(
        np.eye(n), -np.ones(n), np.zeros((0, n)), np.zeros(0), np.zeros(0),
        np.full(n, -np.inf), np.full(n, np.inf),
        cones=(DenseCone(np.eye(n), np.zeros(n), np.zeros(n), 0.5),),
    )  # fmt: skip
    sol = DenseSession(solver).solve(qp)
    # (native CLARABEL stops 'AlmostSolved' here: its own OPTIMAL_INACCURATE)
    assert sol.status.has_solution and sol.z is not None, sol.info
    np.testing.assert_allclose(sol.z, 0.25 * np.ones(n), atol=1e-6)  # ||x|| <= 0.5 active
    assert sol.residuals is not None and sol.residuals.stationarity is not None
    assert sol.residuals.stationarity < 1e-6 and not sol.residuals.unchecked
