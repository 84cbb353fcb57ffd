"""RobustMPC: the FHOCP by RTI (paper notes 4), every backend, SQP, infeasibility policies."""

from __future__ import annotations

import numpy as np
import pytest
from ltv_lstm_mpc.solvers import available_solvers, solver_info
from optional_extras import backend_params, first_installed, requires_solver

from ltv_lstm_mpc import ReferenceCalculator, load_model
from ltv_lstm_mpc.mpc.config import MPCConfig
from ltv_lstm_mpc.mpc.rti import RobustMPC

MODEL = "example_delta_iss_n3.npz"

# Per-backend tolerance on the first input of a fixed subproblem vs CLARABEL (daqp:socp on
# the core install: the two agree to 1e-9 there). QP-only
# backends solve the conservative reformulation (box terminal set, cost upper bound),
# which is inactive/tight here, so they agree too; first-order solvers are looser.
FIRST_INPUT_TOL = {"cvxpy:SCS": 1e-4, "qpsolvers:scs": 1e-4, "cvxpy:ECOS": 1e-5}


@pytest.fixture(scope="module")
def model():
    return load_model(MODEL)


def fixed_subproblem(model, mpc: RobustMPC):
    reference = ReferenceCalculator(model).solve([0.3], [0.02])
    x_hat = model.equilibrium(np.array([-0.3]))
    return x_hat, reference


@pytest.fixture(scope="module")
def clarabel_first_input(model):
    solver = first_installed("cvxpy:CLARABEL", "clarabel", "daqp:socp")
    mpc = RobustMPC(model, MPCConfig(solver=solver, tolerance=1e-10))
    x_hat, ref = fixed_subproblem(model, mpc)
    return mpc.solve(x_hat, ref.x_bar, ref.u_bar, [0.3], mpc.tightening.e_inf).u[0]


@pytest.mark.parametrize("solver", [pytest.param(s, id=s) for s in available_solvers()])
def test_every_backend_gives_the_same_first_input(model, solver, clarabel_first_input) -> None:
    mpc = RobustMPC(model, MPCConfig(solver=solver, tolerance=1e-9))
    x_hat, ref = fixed_subproblem(model, mpc)
    solution = mpc.solve(x_hat, ref.x_bar, ref.u_bar, [0.3], mpc.tightening.e_inf)
    assert solution.feasible and solution.policy == "nominal"
    np.testing.assert_allclose(
        solution.u[0], clarabel_first_input, atol=FIRST_INPUT_TOL.get(solver, 2e-6)
    )
    if solver_info(solver).supports_cones:  # cvxpy's cone solvers, native clarabel
        assert solution.reformulation is None
    else:
        assert solution.reformulation == "terminal_box_and_quadratic_cost_bound"


def test_rti_first_input_close_to_converged_sqp(model) -> None:
    rti = RobustMPC(model, MPCConfig(sqp_iterations=1))
    sqp = RobustMPC(model, MPCConfig(sqp_iterations=30, sqp_tolerance=1e-10))
    x_hat, ref = fixed_subproblem(model, rti)
    e = rti.tightening.e_inf
    # Warm up both along the same closed-loop trajectory so the RTI candidate is the
    # shifted plan, as in operation.
    x = x_hat
    for _ in range(5):
        u = rti.solve(x, ref.x_bar, ref.u_bar, [0.3], e).u[0]
        sqp.solve(x, ref.x_bar, ref.u_bar, [0.3], e)
        x = model.step(x, u)
    a = rti.solve(x, ref.x_bar, ref.u_bar, [0.3], e)
    b = sqp.solve(x, ref.x_bar, ref.u_bar, [0.3], e)
    assert b.sqp_step < 1e-10  # SQP converged
    np.testing.assert_allclose(a.u[0], b.u[0], atol=1e-3)
    assert a.residuals["linearization_gap"] < 1e-3


@requires_solver("cvxpy:CLARABEL")
@pytest.mark.parametrize("policy", ["paper", "soft", "shift"])
def test_forced_infeasibility_uses_and_records_the_policy(model, policy) -> None:
    # A huge initial observer-error bound empties the tightened output set (paper notes 2.10).
    mpc = RobustMPC(model, MPCConfig(infeasibility_policy=policy, solver="cvxpy:CLARABEL"))
    x_hat, ref = fixed_subproblem(model, mpc)
    solution = mpc.solve(x_hat, ref.x_bar, ref.u_bar, [0.3], e_hat=1e3)
    assert not solution.feasible
    assert solution.status in ("infeasible_initial", "alpha_nonpositive")
    assert solution.policy == policy
    assert np.all(np.abs(solution.u) <= 1.0 + 1e-9)
    if policy == "shift":
        np.testing.assert_allclose(solution.u, np.tile(ref.u_bar, (5, 1)))


@requires_solver("cvxpy:CLARABEL")
def test_infeasible_subproblem_falls_back(model) -> None:
    """alpha > 0 but a tiny terminal set far from reach: the solver reports infeasible."""
    mpc = RobustMPC(model, MPCConfig(N=2, solver="cvxpy:CLARABEL"))
    reference = ReferenceCalculator(model).solve([0.5], [0.0])
    low, high = mpc.tightening.setpoint_interval()
    x_far = ReferenceCalculator(model).solve(low + 0.01, [0.0]).x_bar  # i = 0 row holds
    y0 = high - 1e-3  # alpha just above 0
    solution = mpc.solve(x_far, reference.x_bar, reference.u_bar, y0, mpc.tightening.e_inf)
    assert solution.alpha > 0
    assert not solution.feasible and solution.status == "infeasible"
    assert solution.policy == "paper"


def test_bad_inputs_are_rejected(model) -> None:
    mpc = RobustMPC(model)
    with pytest.raises(ValueError, match=r"x_hat has shape \(5,\), expected \(6,\)"):
        mpc.solve(np.zeros(5), np.zeros(6), [0.0], [0.0], 1.0)
    with pytest.raises(ValueError, match="e_hat"):
        mpc.solve(np.zeros(6), np.zeros(6), [0.0], [0.0], float("nan"))
    with pytest.raises(ValueError, match="infeasibility_policy"):
        MPCConfig(infeasibility_policy="ignore")  # type: ignore[arg-type]


@pytest.mark.parametrize("solver", backend_params("daqp", "osqp", "cvxpy:CLARABEL"))
def test_soft_policy_never_crashes_and_is_recorded(model, solver) -> None:
    """A backend that rejects the soft problem (DAQP: setup exit flag -6) is a recorded
    status with the shift fallback, never an exception inside the loop."""
    mpc = RobustMPC(model, MPCConfig(solver=solver, infeasibility_policy="soft"))
    x_hat, ref = fixed_subproblem(model, mpc)
    for _ in range(2):  # the second call exercises update() after a failed setup
        solution = mpc.solve(x_hat, ref.x_bar, ref.u_bar, [0.3], e_hat=1e3)
        assert not solution.feasible
        assert solution.policy in ("soft", "soft+shift")
        assert np.all(np.abs(solution.u) <= 1.0 + 1e-9)
