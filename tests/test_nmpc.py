"""Exact NMPC baseline: matches a converged SQP on random feasible states."""

from __future__ import annotations

import numpy as np
import pytest

pytest.importorskip("casadi")

from ltv_lstm_mpc import MPCConfig, OffsetFreeController, RobustMPC, load_model
from ltv_lstm_mpc.loop.reference import ReferenceCalculator
from ltv_lstm_mpc.mpc.exact_nmpc import ExactNMPC


@pytest.fixture(scope="module")
def model():
    return load_model("ph_lstm_n5.npz")


@pytest.fixture(scope="module")
def sqp(model):
    return RobustMPC(model, MPCConfig(sqp_iterations=50, sqp_tolerance=1e-10))


@pytest.fixture(scope="module")
def nmpc(model, sqp):
    return ExactNMPC(model, MPCConfig(), certification=sqp.certification, smoothing=1e-12)


def test_matches_converged_sqp_on_random_feasible_states(model, sqp, nmpc) -> None:
    calculator = ReferenceCalculator(model, strict=False)
    rng = np.random.default_rng(7)
    e_hat = sqp.tightening.e_inf
    checked = 0
    for _ in range(8):
        y0 = np.array([rng.uniform(-0.1, 0.3)])
        ref = calculator.solve(y0, np.zeros(1))
        x = model.equilibrium(ref.u_bar + rng.uniform(-0.3, 0.3, 1))
        sqp.reset()
        nmpc.reset()
        a = sqp.solve(x, ref.x_bar, ref.u_bar, y0, e_hat)
        b = nmpc.solve(x, ref.x_bar, ref.u_bar, y0, e_hat)
        assert a.status == b.status
        if not a.feasible:
            continue
        checked += 1
        np.testing.assert_allclose(b.u, a.u, atol=1e-4)
        assert b.cost == pytest.approx(a.cost, rel=1e-5)
        assert b.residuals["output_violation"] <= 1e-9
        assert b.residuals["terminal_residual"] <= 1e-6
        assert b.iterations > 0 and b.reformulation is None
    assert checked >= 4


def test_infeasibility_checked_first_and_policy_applied(model, sqp, nmpc) -> None:
    x = model.equilibrium(np.array([0.3]))
    ref = ReferenceCalculator(model, strict=False).solve(np.array([0.1]), np.zeros(1))
    _, high = sqp.tightening.setpoint_interval()
    solution = nmpc.solve(x, ref.x_bar, ref.u_bar, high + 0.05, 0.5)
    assert solution.status == "alpha_nonpositive"
    assert not solution.feasible and solution.policy == "paper"
    assert np.all(np.abs(solution.u) <= 1.0)


def test_usable_in_controller(model, nmpc) -> None:
    from ltv_lstm_mpc.plants import LSTMPlant

    controller = OffsetFreeController(model, MPCConfig(), mpc=nmpc)
    plant = LSTMPlant(model, y0_phi=7.0)
    y = plant.output()
    for _ in range(3):
        y = plant.step(controller.step(y, 7.2), 0.0)
    assert all(r.mpc.status == "optimal" for r in controller.records)


def test_casadi_dynamics_is_the_models_state_update(model) -> None:
    """casadi_dynamics (the NLP's f, and the model acados generates C from) against
    LSTMModel.step at random states and inputs: 1e-14."""
    from ltv_lstm_mpc.mpc.nmpc import casadi_dynamics

    f = casadi_dynamics(model)
    rng = np.random.default_rng(3)
    for _ in range(20):
        x = rng.uniform(-1.0, 1.0, 2 * model.n)
        u = rng.uniform(-1.0, 1.0, model.m)
        np.testing.assert_allclose(
            np.asarray(f(x, u)).ravel(), model.step(x, u), rtol=0, atol=1e-14
        )
