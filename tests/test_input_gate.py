"""The controller's exit gate: every input handed to the plant lies in U, whatever produced it.

A property test drives the controller on every installed backend through random plant
states, set-points (reachable or not), output disturbances and injected solver faults.
"""

from __future__ import annotations

import importlib.util
import warnings

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from ltv_lstm_mpc.solvers import available_solvers
from ltv_lstm_mpc.solvers.testing import faulty

from ltv_lstm_mpc import (
    LSTMModel,
    MPCConfig,
    OffsetFreeController,
    PHNeutralizationPlant,
    RobustMPC,
    UnreachableSetpointError,
    certify,
    load_model,
    simulate,
)
from ltv_lstm_mpc.plants import LSTMPlant

MODEL = "ph_lstm_n5.npz"
FAULTS = ("nan", "garbage", "raise", "infeasible")
BACKENDS = list(available_solvers())
if importlib.util.find_spec("casadi") is not None:
    BACKENDS.append("ipopt")


@pytest.fixture(scope="module")
def model():
    return load_model(MODEL)


@pytest.fixture(scope="module")
def certification(model):
    config = MPCConfig(L_d=0.1)
    return certify(model, config.certification_settings(model))


def _bounds(model):
    norm = model.normalization
    return norm.u_phi_min, norm.u_phi_max


def _controller(model, certification, solver: str, policy: str = "paper"):
    config = MPCConfig(L_d=0.1, solver=solver, infeasibility_policy=policy)
    mpc = RobustMPC(model, config, certification=certification)
    return OffsetFreeController(model, config, mpc=mpc)


@pytest.mark.parametrize("setpoint", [9.3, 9.45])
def test_failing_solver_and_unreachable_setpoint_keep_the_input_in_u(
    model, certification, setpoint
) -> None:
    """The case that handed the plant q3 = 17.1-18.8 mL/s while U = [12.53, 16.97]: the
    ``+shift`` fallback's candidate now appends u_bar projected onto U."""
    controller = _controller(model, certification, faulty("daqp", "raise"))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        result = simulate(
            PHNeutralizationPlant(), controller, np.full(60, setpoint), progress=False
        )
    low, high = _bounds(model)
    assert set(result.policy) == {"paper+shift"}
    assert set(result.setpoint_status) == {"unreachable"}
    assert np.all(result.u_phi >= low) and np.all(result.u_phi <= high)
    np.testing.assert_allclose(result.u_phi, high[0], rtol=0, atol=1e-12)  # u_bar projected
    assert "u_bar projected onto U" in controller.records[0].mpc.reason


def test_setpoint_beyond_every_equilibrium_of_the_model_stops_with_its_value(
    model, certification
) -> None:
    """10 pH lies above every equilibrium output of the shipped model (about 9.5 pH at
    most): no equilibrium, not even one outside U, exists to fall back on, so the first
    step raises and names the set-point and the fix."""
    controller = _controller(model, certification, "daqp")
    with pytest.raises(UnreachableSetpointError, match=r"set-point \[10\.0\] \(physical") as info:
        simulate(PHNeutralizationPlant(), controller, np.full(5, 10.0), progress=False)
    assert "setpoint_rate_limit" in str(info.value) and "y0_interval" in str(info.value)


def test_shift_policy_applies_the_projected_candidate(model, certification) -> None:
    controller = _controller(model, certification, faulty("daqp", "infeasible"), "shift")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        result = simulate(PHNeutralizationPlant(), controller, np.full(10, 9.45), progress=False)
    low, high = _bounds(model)
    assert set(result.policy) == {"shift"}
    assert np.all(result.u_phi >= low) and np.all(result.u_phi <= high)


def test_user_plant_with_its_own_input_range_never_sees_an_input_outside_u() -> None:
    """A model trained on U = [0, 10] controlling its own LSTM plant at an unreachable
    set-point with a solver that always fails (received u = 26-32 before)."""
    arrays = load_model(MODEL).to_arrays()
    arrays.update(u_phi_min=np.array([0.0]), u_phi_max=np.array([10.0]))
    model = LSTMModel.from_arrays(arrays)
    controller = OffsetFreeController(model, MPCConfig(L_d=0.1, solver=faulty("daqp", "raise")))
    plant = LSTMPlant(model, y0_phi=7.0)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        result = simulate(plant, controller, np.full(40, 9.45), progress=False)
    assert np.all(result.u_phi >= 0.0) and np.all(result.u_phi <= 10.0)


class _BrokenMPC:
    """A custom MPC (the ``mpc=`` hook) whose first input is replaced by ``value``."""

    def __init__(self, inner: RobustMPC, value: float) -> None:
        self.inner, self.value = inner, value
        self.certification = inner.certification

    def reset(self) -> None:
        self.inner.reset()

    def solve(self, x_hat, x_bar, u_bar, y0, e_hat):
        self.inner.prepare(x_bar, u_bar, y0, e_hat, x_pred=x_hat)
        solution = self.inner.feedback(x_hat)
        solution.u[0] = self.value
        return solution


@pytest.mark.parametrize("value", [3.0, -7.5, np.nan, np.inf])
def test_exit_gate_projects_or_replaces_a_custom_mpc_input(model, certification, value) -> None:
    config = MPCConfig(L_d=0.1, solver="daqp")
    mpc = _BrokenMPC(RobustMPC(model, config, certification=certification), value)
    controller = OffsetFreeController(model, config, mpc=mpc)
    low, high = _bounds(model)
    with pytest.warns(RuntimeWarning, match="input") as caught:
        result = simulate(PHNeutralizationPlant(), controller, np.full(5, 7.0), progress=False)
    assert np.all(result.u_phi >= low) and np.all(result.u_phi <= high)
    clipped = result.input_clipped
    if np.isfinite(value):
        expected = abs(value) - config.u_max
        np.testing.assert_allclose(clipped, expected, rtol=1e-12)
        edge = high if value > 0 else low
        np.testing.assert_allclose(result.u_phi[:, 0], edge[0], rtol=0, atol=1e-12)
    else:
        assert np.all(np.isinf(clipped))
        # the first step has no last input: u_bar projected; then the last input is held
        np.testing.assert_allclose(result.u_phi[1:, 0], result.u_phi[0, 0], rtol=0, atol=0)
    assert result.summary_counts()["input_clipped_steps"] == 5
    assert result.warning_counts["input_clipped"] == 5
    gate_warnings = [
        w
        for w in caught
        if "projected onto U" in str(w.message) or "was not finite" in str(w.message)
    ]
    assert len(gate_warnings) == 1  # once per run, counted every step
    assert gate_warnings[0].filename == __file__  # the caller's line, not the library's


def test_healthy_solver_needs_no_clipping(model, certification) -> None:
    controller = _controller(model, certification, "daqp")
    result = simulate(PHNeutralizationPlant(), controller, np.full(30, 7.5), progress=False)
    assert np.all(result.input_clipped == 0.0)
    assert result.summary_counts()["input_clipped_steps"] == 0


@pytest.mark.parametrize("solver", BACKENDS)
@settings(
    max_examples=5,
    deadline=None,
    derandomize=True,
    suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow],
)
@given(
    y_start=st.floats(6.0, 8.9),
    setpoints=st.lists(st.floats(4.0, 11.0), min_size=2, max_size=2),
    disturbance=st.floats(-0.3, 0.3),
    fault=st.sampled_from((None, *FAULTS)),
    calls=st.sets(st.integers(0, 12), max_size=6),
    policy=st.sampled_from(("paper", "soft", "shift")),
)
def test_property_every_input_lies_in_u(
    model, certification, solver, y_start, setpoints, disturbance, fault, calls, policy
) -> None:
    if solver == "ipopt":  # the nonlinear transcription: not a registry backend
        fault, policy = None, "paper" if policy == "soft" else policy
    name = solver if fault is None else faulty(solver, fault, calls=sorted(calls) or None)
    controller = _controller(model, certification, name, policy)
    plant = LSTMPlant(model, y0_phi=y_start)
    schedule = np.repeat(setpoints, 4)
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            result = simulate(plant, controller, schedule, disturbance, progress=False)
    except UnreachableSetpointError:
        # no equilibrium at all for the first set-point: refused before any input
        assert not controller.records
        return
    low, high = controller.input_bounds_phi
    assert np.all(result.u_phi >= low) and np.all(result.u_phi <= high), (
        result.u_phi.ravel(),
        result.policy,
    )
    norm = model.normalization
    assert np.all(result.u_phi >= norm.u_phi_min) and np.all(result.u_phi <= norm.u_phi_max)
    assert np.all(result.input_clipped >= 0.0)
