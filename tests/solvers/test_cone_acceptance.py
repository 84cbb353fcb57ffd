"""The acceptance layer on cone problems: Farkas vectors' cone entries, the
distance of an OPTIMAL point from the local solution, daqp:socp's certified statuses."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from conftest import SOLVERS
from ltv_lstm_mpc.solvers import (
    DenseCone,
    DenseQP,
    DenseSession,
    SolverStatus,
    solve,
)
from ltv_lstm_mpc.solvers._base import RawResult
from ltv_lstm_mpc.solvers.acceptance import ProblemView, check_infeasibility_certificate
from ltv_lstm_mpc.solvers.cone_point import POINT_FACTOR, check_cone_point
from ltv_lstm_mpc.solvers.testing import epigraph_socp
from test_peer_problems import peers

needs_socp = pytest.mark.skipif("daqp:socp" not in SOLVERS, reason="needs daqp:socp")


def _outside_cone_problem() -> DenseQP:
    """``x >= 10`` and the cone ``|x| <= -1`` (infeasible: the cone alone)."""
    cone = DenseCone(np.array([[1.0]]), np.zeros(1), np.zeros(1), -1.0)
    return DenseQP(
        H=np.eye(1), f=np.zeros(1), A=np.array([[1.0]]), lo=np.array([10.0]),
        up=np.array([np.inf]), lb=np.array([-np.inf]), ub=np.array([np.inf]), cones=(cone,),
    )  # fmt: skip


def test_farkas_cone_entries_must_lie_in_their_cone() -> None:
    """A vector that meets the linear Farkas conditions with cone entries outside the
    second-order cone proves nothing and is refused; the one inside is accepted."""
    view = ProblemView.of_dense(_outside_cone_problem())
    inside = {"ineq": np.zeros(1), "bounds": np.zeros(1), "cones": np.array([1.0, 0.0])}
    valid, numbers = check_infeasibility_certificate(view, inside, 1e-5)
    assert valid, numbers
    # y = -5 at the lower bound 10 and (lambda_0, lambda_1) = (1, -5): sum M'y - F'lambda_1
    # = 0 and the support value -51 < 0, but |lambda_1| = 5 > lambda_0 = 1
    outside = {"ineq": np.array([-5.0]), "bounds": np.zeros(1), "cones": np.array([1.0, -5.0])}
    valid, numbers = check_infeasibility_certificate(view, outside, 1e-5)
    assert not valid and "outside their cone" in numbers, numbers


@needs_socp
def test_cone_point_far_from_the_local_solution_is_inaccurate() -> None:
    """An OPTIMAL point 10x the limit away from the solution becomes OPTIMAL_INACCURATE
    with the distance; the solution itself stays OPTIMAL."""
    qp = DenseQP.from_convex_problem(epigraph_socp(peers()["QPTEST (Maros-Meszaros)"].problem))
    exact = DenseSession("daqp:socp").solve(qp)
    assert exact.status is SolverStatus.OPTIMAL and exact.z is not None
    optimality = 1e-6
    raw = RawResult(
        status=SolverStatus.OPTIMAL, native_status="test", z=np.array(exact.z),
        duals=exact.duals, solve_time=0.0, iterations=0,
    )  # fmt: skip
    assert check_cone_point(qp, raw, optimality).status is SolverStatus.OPTIMAL
    scale = 1.0 + float(np.max(np.abs(exact.z)))
    moved = np.array(exact.z)
    moved[0] += 10 * POINT_FACTOR * optimality * scale
    checked = check_cone_point(qp, dataclasses.replace(raw, z=moved), optimality)
    assert checked.status is SolverStatus.OPTIMAL_INACCURATE
    assert "from the local SQP's solution" in checked.notes[-1]


@needs_socp
@pytest.mark.parametrize(
    ("name", "status"),
    [
        ("infeasible (x1 >= 1, x1 <= 0)", SolverStatus.INFEASIBLE),
        ("unbounded (P = vv', q not in range)", SolverStatus.UNBOUNDED),
    ],
)
def test_daqp_socp_certified_statuses(name: str, status: SolverStatus) -> None:
    """INFEASIBLE / UNBOUNDED from daqp:socp come with a certificate the layer checked."""
    sol = solve(epigraph_socp(peers()[name].problem), "daqp:socp")
    assert sol.status is status, sol.info
    assert sol.certificate is not None and "certificate checked" in sol.info


@needs_socp
def test_daqp_socp_unbounded_first_subproblem_goes_on() -> None:
    """QPTEST as an SOCP: the first subproblem is unbounded (no cone curvature yet); the
    SQP goes on with a proximal step and reaches the QP's solution (it once
    returned UNBOUNDED, "exitflag -3 at SQP iteration 1")."""
    sol = DenseSession("daqp:socp").solve(
        DenseQP.from_convex_problem(epigraph_socp(peers()["QPTEST (Maros-Meszaros)"].problem))
    )
    assert sol.status is SolverStatus.OPTIMAL, sol.info
    assert sol.z is not None
    np.testing.assert_allclose(sol.z[:2], [0.7625, 0.475], atol=1e-7)
