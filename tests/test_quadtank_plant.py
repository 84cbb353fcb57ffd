"""Quadruple-tank process (Johansson 2000): parameters, integration accuracy, saturation,
leaks, noise and input checks; the optional sampling time of the model file."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.integrate import solve_ivp

from ltv_lstm_mpc.exceptions import DimensionError, InvalidValueError
from ltv_lstm_mpc.lstm.model import LSTMModel
from ltv_lstm_mpc.plants import (
    NoisyMeasurement,
    Plant,
    QuadrupleTankParameters,
    QuadrupleTankPlant,
    simulate_quadtank_batch,
)
from ltv_lstm_mpc.plants.quadtank import QUADTANK_TS, QUADTANK_U_RANGE


def _rhs(par: QuadrupleTankParameters, v: np.ndarray, leak: np.ndarray):  # type: ignore[no-untyped-def]
    """Johansson's eq. (1) written out independently of the module (with the leak term)."""

    def f(_t: float, h: np.ndarray) -> np.ndarray:
        s = np.sqrt(2 * par.g * np.maximum(h, 0.0))
        return np.array(
            [
                (-(par.a1 + leak[0]) * s[0] + par.a3 * s[2] + par.gamma1 * par.k1 * v[0]) / par.A1,
                (-(par.a2 + leak[1]) * s[1] + par.a4 * s[3] + par.gamma2 * par.k2 * v[1]) / par.A2,
                (-par.a3 * s[2] + (1 - par.gamma2) * par.k2 * v[1]) / par.A3,
                (-par.a4 * s[3] + (1 - par.gamma1) * par.k1 * v[0]) / par.A4,
            ]
        )

    return f


def test_parameters_are_johanssons_minimum_phase_point() -> None:
    par = QuadrupleTankParameters()
    assert (par.A1, par.A2, par.A3, par.A4) == (28.0, 32.0, 28.0, 32.0)
    assert (par.a1, par.a2, par.a3, par.a4) == (0.071, 0.057, 0.071, 0.057)
    assert (par.k1, par.k2, par.gamma1, par.gamma2, par.kc, par.g) == (
        3.33, 3.35, 0.70, 0.60, 0.50, 981.0
    )  # fmt: skip
    assert par.gamma1 + par.gamma2 > 1  # minimum phase
    nmp = QuadrupleTankParameters.non_minimum_phase()
    assert (nmp.k1, nmp.k2, nmp.gamma1, nmp.gamma2) == (3.14, 3.29, 0.43, 0.34)
    assert nmp.gamma1 + nmp.gamma2 < 1
    with pytest.raises(InvalidValueError, match="gamma1"):
        QuadrupleTankParameters(gamma1=1.2)
    with pytest.raises(InvalidValueError, match="a3"):
        QuadrupleTankParameters(a3=0.0)


def test_steady_state_near_table_ii_and_is_a_fixed_point() -> None:
    plant = QuadrupleTankPlant()
    assert isinstance(plant, Plant)
    h = plant.steady_state([3.0, 3.0])
    # Table II lists the measured (12.4, 12.7, 1.8, 1.4) cm at 3 V; the equations give:
    np.testing.assert_allclose(h, [12.263, 12.783, 1.634, 1.409], atol=1e-3)
    np.testing.assert_allclose(h, [12.4, 12.7, 1.8, 1.4], atol=0.2)
    np.testing.assert_allclose(plant.output(), h[:2])
    for _ in range(5):
        plant.step([3.0, 3.0])
    np.testing.assert_allclose(plant.h, h, atol=1e-10)
    # steady_state_input inverts the lower-level balance.
    for target in ([12.0, 12.0], [14.0, 10.0], [8.0, 13.0]):
        v = plant.steady_state_input(target)
        np.testing.assert_allclose(plant.steady_state(v)[:2], target, rtol=1e-12)
    # A leak lowers the level of its tank only (at the same voltages).
    leaky = plant.steady_state([3.0, 3.0], [0.002, 0.0])
    assert leaky[0] < h[0] - 0.5 and leaky[1] == pytest.approx(h[1])


@pytest.mark.parametrize("leak", [(0.0, 0.0), (0.004, 0.001)])
def test_one_step_accuracy_against_solve_ivp(leak: tuple[float, float]) -> None:
    plant = QuadrupleTankPlant()
    rng = np.random.default_rng(int(1000 * sum(leak)))
    worst = 0.0
    for _ in range(6):
        h0 = plant.steady_state(rng.uniform(*QUADTANK_U_RANGE, 2))
        v = rng.uniform(*QUADTANK_U_RANGE, 2)
        plant.h = h0.copy()
        plant.step(v, leak)
        sol = solve_ivp(
            _rhs(plant.params, v, np.array(leak)), (0.0, QUADTANK_TS), h0, method="DOP853",
            rtol=1e-13, atol=1e-13,
        )  # fmt: skip
        worst = max(worst, float(np.max(np.abs(sol.y[:, -1] - plant.h))))
    assert worst < 1e-8


def test_batch_integrator_equals_the_plant_and_saturation_clips() -> None:
    plant = QuadrupleTankPlant()
    rng = np.random.default_rng(1)
    v = rng.uniform(1.0, 4.5, (30, 2))  # partly outside the pump range
    leak = np.tile([0.001, 0.0], (30, 1))
    plant.reset()
    levels = [plant.h.copy()]
    for k in range(30):
        plant.step(v[k], leak[k])
        levels.append(plant.h.copy())
    batch = simulate_quadtank_batch(plant.steady_state([3, 3]), plant.saturate(v), leak)
    np.testing.assert_allclose(batch, np.array(levels), atol=1e-12)
    a, b = QuadrupleTankPlant(), QuadrupleTankPlant()
    np.testing.assert_array_equal(a.step([9.0, -2.0]), b.step(list(QUADTANK_U_RANGE)[::-1]))


def test_levels_never_negative_under_a_large_leak() -> None:
    plant = QuadrupleTankPlant(u_phi_min=0.0)
    plant.reset([1.5, 1.5])
    low = []
    for _ in range(300):
        y = plant.step([0.0, 0.0], [0.5, 0.5])  # pumps off, large leaks: the tanks empty
        low.append(plant.h.min())
    assert min(low) >= 0.0 and np.all(y >= 0.0)
    assert np.max(plant.h) < 0.05  # (almost) empty, never below zero
    plant.h = np.zeros(4)
    plant.step([0.0, 0.0], [0.5, 0.5])
    np.testing.assert_array_equal(plant.h, np.zeros(4))


def test_measurement_noise_is_seeded_and_leaves_the_state_alone() -> None:
    plant = NoisyMeasurement(QuadrupleTankPlant(), noise_std=0.05, seed=3)
    samples = np.array([plant.output() for _ in range(4000)])
    np.testing.assert_allclose(samples.mean(axis=0), plant.h[:2], atol=0.005)
    np.testing.assert_allclose(samples.std(axis=0), 0.05, rtol=0.05)
    np.testing.assert_array_equal(plant.true_output(), plant.h[:2])
    plant.reset()
    first = plant.output()
    plant.reset()
    np.testing.assert_array_equal(plant.output(), first)
    np.testing.assert_array_equal(plant.h, QuadrupleTankPlant().h)
    assert plant.disturbance_size == 2  # the plant's own attributes


def test_bad_inputs_name_the_value() -> None:
    plant = QuadrupleTankPlant()
    with pytest.raises(InvalidValueError, match="leak"):
        plant.step([3.0, 3.0], [-0.001, 0.0])
    with pytest.raises(DimensionError, match="u_phi"):
        plant.step([3.0])
    with pytest.raises(InvalidValueError, match="NaN"):
        plant.step([np.nan, 3.0])
    with pytest.raises(InvalidValueError, match="u_phi_min"):
        QuadrupleTankPlant(u_phi_min=4.0, u_phi_max=1.0)
    with pytest.raises(InvalidValueError, match="noise_std"):
        NoisyMeasurement(QuadrupleTankPlant(), noise_std=-1.0)
    with pytest.raises(DimensionError, match="h0"):
        simulate_quadtank_batch(np.zeros(3), np.zeros((4, 2)))


def test_model_file_stores_the_sampling_time(tmp_path) -> None:  # type: ignore[no-untyped-def]
    from lstm_factories import random_lstm

    base = random_lstm(np.random.default_rng(0), 3, 2, 2)
    assert base.Ts is None
    old = base.save(tmp_path / "old.npz")
    assert LSTMModel.load(old).Ts is None  # files without Ts load as before
    model = LSTMModel.from_arrays({**base.to_arrays(), "Ts": 10.0})
    loaded = LSTMModel.load(model.save(tmp_path / "with_ts.npz"))
    assert loaded.Ts == 10.0 and loaded.to_arrays()["Ts"] == 10.0
    with pytest.raises(InvalidValueError, match="Ts"):
        LSTMModel.from_arrays({**base.weights(), "Ts": -1.0})
