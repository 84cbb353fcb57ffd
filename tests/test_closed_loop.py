"""OffsetFreeController and the closed loop on the LSTM plant with output disturbance (Fig. 2)."""

from __future__ import annotations

import numpy as np
import pytest

from ltv_lstm_mpc import CertificationSettings, certify, load_model
from ltv_lstm_mpc.controller import OffsetFreeController
from ltv_lstm_mpc.plants import LSTMPlant
from ltv_lstm_mpc.rti import MPCConfig
from ltv_lstm_mpc.simulation import simulate

MODEL = "example_delta_iss_n3.npz"


@pytest.fixture(scope="module")
def model():
    return load_model(MODEL)


def test_offset_free_on_lstm_plant_with_constant_output_disturbance(model) -> None:
    plant = LSTMPlant(model, y0_phi=7.0)
    controller = OffsetFreeController(model, MPCConfig(L_d=0.1, solver="osqp"))
    steps = 250
    result = simulate(plant, controller, np.full(steps, 7.4), 0.05, progress=False)
    assert abs(result.y_phi[-1, 0] - 7.4) < 1e-4
    scale = 0.5 * (model.normalization.y_phi_max - model.normalization.y_phi_min)[0]
    np.testing.assert_allclose(result.d_hat[-1], [0.05 / scale], atol=1e-5)
    assert result.feasible.all()


def test_constraints_hold_under_slow_setpoint_changes(model) -> None:
    """Theorem 3 conditions: rate-limited set-point inside the admissible interval."""
    controller = OffsetFreeController(
        model,
        MPCConfig(L_d=0.01, solver="cvxpy:CLARABEL"),
        setpoint_rate_limit=controller_rate(model),
    )
    plant = LSTMPlant(model, y0_phi=7.0)
    low, high = controller.certification.y0_interval_phi
    steps = 160
    setpoints = np.where(np.arange(steps) < 80, high[0] - 0.05, low[0] + 0.05)
    result = simulate(plant, controller, setpoints, 0.0, progress=False)
    assert result.feasible.all()
    assert np.all(result.output_violation == 0.0)
    y_min, y_max = 6.0, 9.0
    assert np.all(result.y_phi >= y_min) and np.all(result.y_phi <= y_max)


def controller_rate(model) -> float:
    bound = certify(model, CertificationSettings(l_d=0.01)).rate_bound
    assert bound.holds
    return bound.delta_y0_max
