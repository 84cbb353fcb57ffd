"""Fast embedded-style RTI path (issue 6): kernel, condensed QP, fused controller."""

from __future__ import annotations

import numpy as np
import pytest

from ltv_lstm_mpc import MPCConfig, OffsetFreeController, RobustMPC, load_model
from ltv_lstm_mpc.exceptions import InvalidValueError, LtvMpcError, SolverNotFound
from ltv_lstm_mpc.loop.reference import ReferenceCalculator
from ltv_lstm_mpc.mpc.fast import (
    FastOffsetFreeController,
    FastReferenceCalculator,
    FastRobustMPC,
    LSTMKernel,
    fast_solvers,
)

#: First-input agreement with RobustMPC (same QP, TerminalBoxReformulation) per solver.
TOL = {"daqp": 1e-9, "quadprog": 1e-9, "osqp": 1e-5, "piqp": 1e-6, "proxqp": 1e-4}


@pytest.fixture(scope="module")
def model():
    return load_model("ph_lstm_n5.npz")


@pytest.fixture(scope="module")
def robust(model):
    return RobustMPC(model, MPCConfig(solver="daqp"))


@pytest.fixture(scope="module")
def reference(model):
    return ReferenceCalculator(model, strict=False).solve(np.array([0.1]), np.zeros(1))


def test_kernel_matches_model(model) -> None:
    kernel = LSTMKernel(model)
    rng = np.random.default_rng(0)
    N = 4
    traj = kernel.trajectory(N)
    x0 = model.equilibrium(np.array([0.2])) + 0.05 * rng.standard_normal(2 * model.n)
    u = rng.uniform(-1, 1, (N, 1))
    traj.x[0] = x0
    traj.u[:N] = u
    kernel.rollout(traj, 0, N)
    kernel.jacobians(traj)
    x_ref, _ = model.simulate(x0, u)
    np.testing.assert_allclose(traj.x, x_ref, atol=1e-14)
    _, A, B = model.step_and_jacobians(x_ref[:-1], u)
    np.testing.assert_allclose(traj.J[:, :, : 2 * model.n], A, atol=1e-14)
    np.testing.assert_allclose(traj.J[:, :, 2 * model.n :], B, atol=1e-14)


@pytest.mark.parametrize("solver", fast_solvers())
def test_fast_matches_robust_mpc_on_fixed_subproblems(model, robust, reference, solver) -> None:
    fast = FastRobustMPC(model, robust.config, solver=solver, certification=robust.certification)
    assert fast.reformulation == "terminal_box_and_quadratic_cost_bound"
    rng = np.random.default_rng(1)
    y0 = np.array([0.1])
    for _ in range(3):
        x = model.equilibrium(np.array([rng.uniform(-0.4, 0.6)]))
        robust.reset()
        fast.reset()
        for _ in range(3):  # also exercises the shifted candidate and the plan reuse
            a = robust.solve(x, reference.x_bar, reference.u_bar, y0, 0.5)
            b = fast.solve(x, reference.x_bar, reference.u_bar, y0, 0.5)
            assert a.status == b.status and a.policy == b.policy
            assert b.reformulation == a.reformulation
            np.testing.assert_allclose(b.u, a.u, atol=TOL[solver])
            np.testing.assert_allclose(b.x, a.x, atol=100 * TOL[solver])
            assert b.cost == pytest.approx(a.cost, rel=1e-6, abs=100 * TOL[solver])
            assert b.residuals["output_violation"] == pytest.approx(
                a.residuals["output_violation"], abs=1e-6
            )
            x = a.x[1]


def test_prepare_feedback_split(model, robust, reference) -> None:
    fast = FastRobustMPC(model, robust.config, certification=robust.certification)
    x = model.equilibrium(np.array([0.3]))
    y0 = np.array([0.1])
    with pytest.raises(LtvMpcError):
        fast.feedback(x)
    with pytest.raises(InvalidValueError):
        fast.prepare(reference.x_bar, reference.u_bar, y0, 0.5)  # no x_pred, no plan
    fast.prepare(reference.x_bar, reference.u_bar, y0, 0.5, x_pred=x)
    a = fast.feedback(x)
    assert fast.prepare_time > 0 and fast.feedback_time > 0
    # Default x_pred: the previous plan's x_{1|k-1}; a perturbed estimate enters linearly.
    fast.prepare(reference.x_bar, reference.u_bar, y0, 0.5)
    b = fast.feedback(a.x[1] + 1e-6)
    fast.reset()
    fast._previous_u = a.u.copy()
    c = fast.solve(a.x[1] + 1e-6, reference.x_bar, reference.u_bar, y0, 0.5)
    np.testing.assert_allclose(b.u, c.u, atol=1e-9)


@pytest.mark.parametrize("policy", ["paper", "soft", "shift"])
def test_infeasibility_policies_match_robust_mpc(model, reference, policy) -> None:
    # RobustMPC's native DAQP fails on the soft problem (singular slack block): OSQP there.
    solver = "osqp" if policy == "soft" else "daqp"
    config = MPCConfig(solver=solver, infeasibility_policy=policy, tolerance=1e-9)
    robust = RobustMPC(model, config)
    fast = FastRobustMPC(model, config, certification=robust.certification)
    x = model.equilibrium(np.array([0.3]))
    _, high = robust.tightening.setpoint_interval()
    y0 = high + 0.05  # outside Assumption 5: alpha <= 0
    a = robust.solve(x, reference.x_bar, reference.u_bar, y0, 0.5)
    b = fast.solve(x, reference.x_bar, reference.u_bar, y0, 0.5)
    assert a.status == b.status == "alpha_nonpositive"
    assert not b.feasible and b.policy == a.policy
    atol = 1e-5 if policy == "soft" else 1e-9
    np.testing.assert_allclose(b.u, a.u, atol=atol)


def test_unknown_solver(model, robust) -> None:
    with pytest.raises(SolverNotFound):
        FastRobustMPC(model, robust.config, solver="nope", certification=robust.certification)


def test_fast_reference_matches(model) -> None:
    slow = ReferenceCalculator(model, strict=False)
    fast = FastReferenceCalculator(model)
    for y0, d in [(0.1, 0.0), (0.11, 0.001), (0.12, 0.002), (-0.2, 0.0), (-0.2, 0.0)]:
        a = slow.solve(np.array([y0]), np.array([d]))
        b = fast.solve(np.array([y0]), np.array([d]))
        assert b.converged and b.residual < 1e-10
        np.testing.assert_allclose(b.x_bar, a.x_bar, atol=1e-9)
        np.testing.assert_allclose(b.u_bar, a.u_bar, atol=1e-9)


def _scenario_1(model, steps):
    from ltv_lstm_mpc.bench.harness import bench_scenarios

    return bench_scenarios(model)[0], steps


def _run(controller, scenario, model, steps):
    plant = scenario.make_plant(model)
    controller.reset()
    y = plant.output()
    us = []
    for k in range(steps):
        u = controller.step(y, scenario.setpoints[k])
        us.append(u[0])
        y = plant.step(u, scenario.disturbances[k])
    return np.array(us)


def test_fast_path_same_control_as_cvxpy_path_on_scenario_1(model) -> None:
    scenario, steps = _scenario_1(model, 40)
    config = scenario.config
    rate = scenario.setpoint_rate_limit
    cvx = OffsetFreeController(model, config, setpoint_rate_limit=rate)
    assert config.solver == "cvxpy:CLARABEL"
    fused = FastOffsetFreeController(model, config, setpoint_rate_limit=rate)
    inner = OffsetFreeController(
        model, config, setpoint_rate_limit=rate, mpc=FastRobustMPC(model, config)
    )
    u_cvx = _run(cvx, scenario, model, steps)
    u_fused = _run(fused, scenario, model, steps)
    u_inner = _run(inner, scenario, model, steps)
    np.testing.assert_allclose(u_fused, u_cvx, atol=1e-3)  # cones vs conservative box: mL/s
    np.testing.assert_allclose(u_fused, u_inner, atol=1e-8)  # fused step == same MPC
    assert all(r.mpc.feasible for r in fused.records)
    assert all(r.mpc.reformulation for r in fused.records)
    assert fused.records[-1].time_total > 0


def test_cached_alpha_equals_the_tightening_definition(model, robust, reference) -> None:
    """The fast path caches alpha_k (eq. def_alpha) in Python floats for speed; it must equal
    TighteningCertificate.alpha for every set-point and observer-error bound."""
    fast = FastRobustMPC(model, robust.config, certification=robust.certification)
    tightening = robust.tightening
    x = model.equilibrium(np.array([0.1]))
    for y0 in np.linspace(-0.6, 0.6, 7):
        for e_hat in (0.0, tightening.e_inf, 3.0 * tightening.e_inf):
            solution = fast.solve(x, reference.x_bar, reference.u_bar, [y0], e_hat)
            assert solution.alpha == pytest.approx(tightening.alpha([y0], e_hat), abs=1e-13)
