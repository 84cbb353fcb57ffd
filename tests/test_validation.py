"""Every signal handed to the library is checked once, the same way (real_vector)."""

from __future__ import annotations

import numpy as np
import pytest
from lstm_factories import random_delta_iss_lstm

from ltv_lstm_mpc import (
    DimensionError,
    InvalidValueError,
    LSTMModel,
    MPCConfig,
    Normalization,
    OffsetFreeController,
    load_model,
    simulate,
)
from ltv_lstm_mpc.plants import LSTMPlant, PHNeutralizationPlant
from ltv_lstm_mpc.validation import real_vector


@pytest.mark.parametrize(
    ("value", "error", "text"),
    [
        (True, InvalidValueError, "must be real numbers, got bool True"),
        ("7.0", InvalidValueError, "must be real numbers, got str '7.0'"),
        ([True], InvalidValueError, "got boolean values"),
        ([7.0 + 1j], InvalidValueError, "got complex values"),
        (["7"], InvalidValueError, "got string values"),
        ([[7.0]], DimensionError, r"has shape \(1, 1\), expected \(1,\) or a number"),
        ([7.0, 7.5], DimensionError, r"has shape \(2,\), expected \(1,\) or a number"),
        ([np.nan], InvalidValueError, "contains NaN or inf"),
        (np.inf, InvalidValueError, "contains NaN or inf"),
    ],
)
def test_real_vector_rejects(value, error, text) -> None:
    with pytest.raises(error, match=text) as info:
        real_vector("y_phi", value, 1)
    assert str(info.value).startswith("y_phi ")


def test_real_vector_accepts_numbers_and_vectors() -> None:
    np.testing.assert_array_equal(real_vector("y", 7, 1), [7.0])
    np.testing.assert_array_equal(real_vector("y", np.float32(7.5), 1), [7.5])
    np.testing.assert_array_equal(real_vector("y", [1, 2], 2), [1.0, 2.0])
    assert real_vector("y", np.arange(3), 3).dtype == np.float64
    with pytest.raises(DimensionError, match=r"expected \(2,\)$"):
        real_vector("y", 1.0, 2)  # a scalar is only a vector of length 1


@pytest.fixture(scope="module")
def controller():
    ctrl = OffsetFreeController(load_model("ph_lstm_n5.npz"), MPCConfig(solver="daqp"))
    ctrl.step(7.0, 7.0)
    return ctrl


@pytest.mark.parametrize(
    ("y", "y0", "error", "name"),
    [
        ([[7.0]], 7.0, DimensionError, "y_phi"),
        ("7.0", 7.0, InvalidValueError, "y_phi"),
        (True, 7.0, InvalidValueError, "y_phi"),
        (7.0, False, InvalidValueError, "y0_phi"),
        (np.nan, 7.0, InvalidValueError, "y_phi"),
        (7.0, [7.0, 7.2], DimensionError, "y0_phi"),
    ],
)
def test_controller_step_checks_measurement_and_setpoint(controller, y, y0, error, name) -> None:
    steps = len(controller.records)
    with pytest.raises(error, match=f"^{name} "):
        controller.step(y, y0)
    assert len(controller.records) == steps  # nothing happened
    controller.step(np.array([7.0]), [7.0])  # the same numbers in accepted forms


def test_plants_check_their_inputs() -> None:
    model = load_model("ph_lstm_n5.npz")
    lstm_plant = LSTMPlant(model, y0_phi=7.0)
    with pytest.raises(InvalidValueError, match="u_phi contains NaN or inf"):
        lstm_plant.step([np.nan])
    with pytest.raises(DimensionError, match=r"d_phi has shape \(2,\)"):
        lstm_plant.step([15.0], [0.1, 0.2])
    ph = PHNeutralizationPlant()
    with pytest.raises(DimensionError, match=r"u_phi \(q3, mL/s\) has shape \(2,\)"):
        ph.step([15.0, 16.0])
    with pytest.raises(InvalidValueError, match="contains NaN or inf"):
        ph.step(15.0, np.nan)
    with pytest.raises(InvalidValueError, match="must be real numbers"):
        ph.step("15")


def test_simulate_checks_schedules_and_steps(controller) -> None:
    model = controller.model
    ph = PHNeutralizationPlant()
    with pytest.raises(InvalidValueError, match="steps must be a positive integer, got -5"):
        simulate(ph, controller, 7.0, steps=-5, progress=False)
    with pytest.raises(InvalidValueError, match="steps must be a positive integer, got 0"):
        simulate(ph, controller, [], progress=False)
    with pytest.raises(
        DimensionError, match=r"disturbances has shape \(10, 2\), expected \(steps, 1\)"
    ):
        simulate(ph, controller, 7.0, np.full((10, 2), 0.55), steps=10, progress=False)
    with pytest.raises(DimensionError, match="need at least steps=10"):
        simulate(ph, controller, np.full(5, 7.0), steps=10, progress=False)
    plant = LSTMPlant(model, y0_phi=7.0)
    result = simulate(plant, controller, 7.2, np.zeros(4), steps=4, progress=False)
    assert result.y0_phi.shape == (4, 1) and np.all(result.y0_phi == 7.2)


def test_simulate_reads_a_constant_mimo_setpoint_vector_as_a_constant() -> None:
    rng = np.random.default_rng(3)
    base = random_delta_iss_lstm(rng, 4, 2, 2)
    normalization = Normalization(
        u_phi_min=np.zeros(2), u_phi_max=np.ones(2), y_phi_min=np.zeros(2), y_phi_max=np.ones(2)
    )
    model = LSTMModel(
        **base.weights(), normalization=normalization, y_phi_constraint=(np.zeros(2), np.ones(2))
    )
    ctrl = OffsetFreeController(model, MPCConfig(solver="daqp"))
    plant = LSTMPlant(model)
    y_start = plant.output()
    target = y_start + 0.01
    result = simulate(plant, ctrl, target, steps=6, progress=False)  # (p,) = a constant
    assert result.y0_phi.shape == (6, 2)
    np.testing.assert_allclose(result.y0_phi, np.tile(target, (6, 1)))
    with pytest.raises(DimensionError, match="steps is required"):
        simulate(plant, ctrl, target, progress=False)
    with pytest.raises(DimensionError, match=r"give one row of 2 entries per step"):
        simulate(plant, ctrl, np.full(6, 0.5), steps=6, progress=False)


@pytest.mark.parametrize("bad", [-1.0, np.nan, np.inf])
def test_negative_e_hat0_is_rejected_at_construction(bad) -> None:
    with pytest.raises(
        InvalidValueError, match=r"e_hat0 must (lie in \[0, inf\)|be a finite number)"
    ):
        MPCConfig(e_hat0=bad)


def test_simulate_runs_on_one_blas_thread(controller, monkeypatch) -> None:
    from threadpoolctl import threadpool_info

    from ltv_lstm_mpc.loop import simulation

    seen: list[list[int]] = []
    original = controller.step

    def step(*args, **kwargs):  # type: ignore[no-untyped-def]
        seen.append(
            [pool["num_threads"] for pool in threadpool_info() if pool["user_api"] == "blas"]
        )
        return original(*args, **kwargs)

    monkeypatch.setattr(controller, "step", step)
    plant = PHNeutralizationPlant()
    plant.reset()
    simulation.simulate(plant, controller, 7.0, steps=3, progress=False)
    assert seen and all(threads == [1] * len(threads) for threads in seen)
