"""OffsetFreeController and the closed loop on the LSTM plant with output disturbance (Fig. 2)."""

from __future__ import annotations

import numpy as np
import pytest
from optional_extras import requires_solver

from ltv_lstm_mpc import CertificationSettings, certify, load_model
from ltv_lstm_mpc.exceptions import ArgumentTypeError
from ltv_lstm_mpc.loop.controller import OffsetFreeController
from ltv_lstm_mpc.loop.simulation import simulate
from ltv_lstm_mpc.mpc.config import MPCConfig
from ltv_lstm_mpc.plants import LSTMPlant

MODEL = "example_delta_iss_n3.npz"


@pytest.fixture(scope="module")
def model():
    return load_model(MODEL)


@requires_solver("osqp")
def test_offset_free_on_lstm_plant_with_constant_output_disturbance(model) -> None:
    plant = LSTMPlant(model, y0_phi=7.0)
    controller = OffsetFreeController(model, MPCConfig(L_d=0.1, solver="osqp"))
    steps = 250
    result = simulate(plant, controller, np.full(steps, 7.4), 0.05, progress=False)
    assert abs(result.y_phi[-1, 0] - 7.4) < 1e-4
    scale = 0.5 * (model.normalization.y_phi_max - model.normalization.y_phi_min)[0]
    np.testing.assert_allclose(result.d_hat[-1], [0.05 / scale], atol=1e-5)
    assert result.feasible.all()


@requires_solver("cvxpy:CLARABEL")
def test_constraints_hold_under_slow_setpoint_changes(model) -> None:
    """Theorem 3 conditions: set-points in a range, rate-limited by the bound valid there."""
    low, high = 6.7, 7.6  # pH, inside the admissible interval, 7.0 (start) included
    rate = controller_rate(model, (low, high))
    controller = OffsetFreeController(
        model, MPCConfig(L_d=0.01, solver="cvxpy:CLARABEL"), setpoint_rate_limit=rate
    )
    plant = LSTMPlant(model, y0_phi=7.0)
    steps = 160
    setpoints = np.where(np.arange(steps) < 80, high, low)
    result = simulate(plant, controller, setpoints, 0.0, progress=False)
    assert result.feasible.all()
    assert np.all(result.output_violation == 0.0)
    y_min, y_max = 6.0, 9.0
    assert np.all(result.y_phi >= y_min) and np.all(result.y_phi <= y_max)


def controller_rate(model, range_phi: tuple[float, float]) -> float:
    normalized = model.normalize_y(np.array(range_phi))
    settings = CertificationSettings(l_d=0.01, y0_operating_range=tuple(normalized))
    bound = certify(model, settings).rate_bound
    assert bound.holds
    return bound.delta_y0_max


@requires_solver("osqp")  # a backend without the one-call step: solve_arrays is patched
def test_stale_reference_is_recorded_and_consistent(model) -> None:
    """A Newton failure reuses the last equilibrium, flags it, and hands the MPC the
    set-point that equilibrium encodes (g(x_bar) + d_hat), not the new one."""
    from dataclasses import replace

    controller = OffsetFreeController(model, MPCConfig(solver="osqp"))
    controller.step([7.0], [7.2])
    good = controller.records[-1]
    assert good.reference_ok and not good.stale_reference
    original = controller.reference.solve_arrays  # the controller's (checked-input) call

    def failing(y0, d_hat, *args):  # type: ignore[no-untyped-def]
        return replace(original(y0, d_hat, *args), converged=False)

    controller.reference.solve_arrays = failing  # type: ignore[method-assign]
    with pytest.warns(RuntimeWarning, match=r"set-point \[7.5\] \(physical units\) at step 1"):
        controller.step([7.05], [7.5])
    stale = controller.records[-1]
    assert stale.stale_reference and not stale.reference_ok
    assert stale.setpoint_status == "unreachable_stale"
    np.testing.assert_array_equal(stale.x_bar, good.x_bar)
    consistent_y0 = model.output(good.x_bar) + stale.d_hat
    expected_alpha = controller.certification.tightening.alpha(consistent_y0, stale.e_hat)
    assert stale.mpc.alpha == pytest.approx(expected_alpha, rel=1e-12)


def test_setpoint_status_outside_the_admissible_interval(model) -> None:
    controller = OffsetFreeController(model, MPCConfig(solver="daqp"))
    controller.step([7.0], [7.2])
    assert controller.records[-1].setpoint_status == "ok"
    high_phi = model.denormalize_y(controller.certification.tightening.setpoint_interval()[1])
    target = float(high_phi[0]) + 0.05
    with pytest.warns(RuntimeWarning, match="outside the admissible interval") as record:
        controller.step([7.0], [target])
        controller.step([7.0], [target])  # warned once per run
    assert len([w for w in record if "set-point" in str(w.message)]) == 1
    assert f"[{target}]" in str(record[0].message)
    assert [r.setpoint_status for r in controller.records] == [
        "ok",
        "outside_admissible",
        "outside_admissible",
    ]


def test_d_hat_saturation_on_a_q2_step_is_recorded_and_warned() -> None:
    """pH plant and the shipped pH model, q2 from 0.55 to 0.8 mL/s: the plant-model
    mismatch exceeds d_max."""
    from ltv_lstm_mpc import simulate
    from ltv_lstm_mpc.plants import PHNeutralizationPlant

    model = load_model("ph_lstm_n5.npz")
    controller = OffsetFreeController(model, MPCConfig(solver="daqp", L_d=0.1))
    plant = PHNeutralizationPlant()
    plant.reset()
    q2 = np.r_[np.full(50, 0.55), np.full(350, 0.8)]
    with pytest.warns(RuntimeWarning, match=r"d_hat reached its bound d_max = 0.1") as record:
        result = simulate(plant, controller, 7.0, q2, steps=400, progress=False)
    assert sum("d_hat reached" in str(w.message) for w in record) == 1
    saturated = result.d_hat_saturated[:, 0]
    assert not saturated[:50].any()
    assert saturated.sum() >= 50
    np.testing.assert_allclose(np.abs(result.d_hat[saturated, 0]), 0.1, rtol=1e-12)
    assert result.summary_counts()["d_hat_saturated_steps"] == int(saturated.sum())


def test_plant_violation_of_the_true_output_is_recorded() -> None:
    """A harsh q2 schedule can push the true pH outside [6, 9] while the plan on the model
    looks fine: the simulation records the true plant's violation."""
    from ltv_lstm_mpc import simulate
    from ltv_lstm_mpc.plants import PHNeutralizationPlant

    model = load_model("ph_lstm_n5.npz")
    controller = OffsetFreeController(model, MPCConfig(solver="daqp", L_d=0.1))
    plant = PHNeutralizationPlant()
    plant.reset()
    q2 = np.r_[np.full(20, 0.55), np.full(100, 0.0)]  # the buffer flow stops
    import warnings

    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        result = simulate(plant, controller, 6.4, q2, steps=120, progress=False)
    expected = np.maximum(np.maximum(6.0 - result.y_phi[:, 0], result.y_phi[:, 0] - 9.0), 0.0)
    np.testing.assert_allclose(result.plant_violation, expected, rtol=0, atol=1e-15)
    counts = result.summary_counts()
    assert counts["plant_violation_steps"] == int(np.sum(expected > 1e-9)) >= 50
    assert counts["d_hat_saturated_steps"] > 0  # and the cause is flagged


class _RecordingPlant(LSTMPlant):
    """Records whether the garbage collector was enabled at each step; may fail at a step."""

    def __init__(self, model, fail_at: int | None = None) -> None:
        super().__init__(model, y0_phi=7.0)
        self.collector_enabled: list[bool] = []
        self.fail_at = fail_at

    def step(self, u_phi, d_phi=None):  # type: ignore[no-untyped-def]
        import gc

        self.collector_enabled.append(gc.isenabled())
        if self.fail_at is not None and len(self.collector_enabled) > self.fail_at:
            raise RuntimeError("plant failure")
        return super().step(u_phi, d_phi)


def test_simulate_pauses_the_garbage_collector_and_restores_it(model) -> None:
    import gc

    from ltv_lstm_mpc.loop.simulation import garbage_collection_paused

    controller = OffsetFreeController(model, MPCConfig(L_d=0.1, solver="daqp"))
    assert gc.isenabled()
    paused = _RecordingPlant(model)
    simulate(paused, controller, 7.2, steps=5, progress=False)
    assert paused.collector_enabled == [False] * 5 and gc.isenabled()
    running = _RecordingPlant(model)
    simulate(running, controller, 7.2, steps=5, progress=False, pause_garbage_collection=False)
    assert running.collector_enabled == [True] * 5 and gc.isenabled()
    # an exception inside the loop re-enables it; a collector the caller disabled stays off
    failing = _RecordingPlant(model, fail_at=2)
    with pytest.raises(RuntimeError, match="plant failure"):
        simulate(failing, controller, 7.2, steps=5, progress=False)
    assert failing.collector_enabled == [False] * 3 and gc.isenabled()
    gc.disable()
    try:
        with garbage_collection_paused():
            assert not gc.isenabled()
        assert not gc.isenabled()
    finally:
        gc.enable()
    with pytest.raises(ArgumentTypeError, match="pause_garbage_collection"):
        simulate(paused, controller, 7.2, steps=2, pause_garbage_collection="yes")  # type: ignore[arg-type]


def test_a_closed_loop_creates_no_reference_cycles_per_step(model) -> None:
    """Why pausing the collector is safe: what a step allocates and does not keep in its
    record is freed by reference counting alone. (The records of a run form one cycle
    with the monitor's log; the collector frees them once it runs again.)"""
    import gc

    controller = OffsetFreeController(model, MPCConfig(L_d=0.1, solver="daqp"))
    plant = LSTMPlant(model, y0_phi=7.0)
    simulate(plant, controller, 7.2, steps=20, progress=False)
    controller.reset()  # the first run's records become garbage: collected now
    gc.collect()
    gc.disable()
    try:
        simulate(plant, controller, 7.2, steps=300, progress=False)
        found = gc.collect()  # the controller and its records still alive
    finally:
        gc.enable()
    # not one per step (that would be 300 or more): 13 here, 52 once in a clean-clone CI run
    # (a fixed amount per run: the reset's empty records and their log, and whatever else
    # the process collects at that moment)
    assert found < 150, found
