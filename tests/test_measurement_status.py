"""Measurements and set-points judged once per step; run warnings at the caller, once per run."""

from __future__ import annotations

import warnings

import numpy as np
import pytest

from ltv_lstm_mpc import (
    InvalidValueError,
    MPCConfig,
    OffsetFreeController,
    PHNeutralizationPlant,
    load_model,
    simulate,
)
from ltv_lstm_mpc.caller_warnings import RunWarnings, warn_at_caller
from ltv_lstm_mpc.loop.statuses import IMPLAUSIBLE_MEASUREMENT_LIMIT

MODEL = "ph_lstm_n5.npz"


@pytest.fixture(scope="module")
def model():
    return load_model(MODEL)


def _physical(model, normalized: float) -> float:
    return float(model.denormalize_y(np.array([normalized]))[0])


def test_implausible_measurement_is_flagged_and_warned_at_the_caller(model) -> None:
    controller = OffsetFreeController(model, MPCConfig(solver="daqp"))
    controller.step(7.0, 7.5)
    with pytest.warns(RuntimeWarning, match="more than one range width") as caught:
        controller.step(1e6, 7.5)
    assert controller.records[-1].measurement_status == "implausible"
    assert caught[0].filename == __file__
    assert controller.warning_counts["measurement_implausible"] == 1


@pytest.mark.parametrize(
    ("normalized", "status"),
    [
        (0.99, "ok"),
        (-1.0, "ok"),
        (1.5, "outside_training_range"),
        (-IMPLAUSIBLE_MEASUREMENT_LIMIT + 1e-9, "outside_training_range"),
        (IMPLAUSIBLE_MEASUREMENT_LIMIT + 1e-6, "implausible"),
        (-10.0, "implausible"),
    ],
)
def test_measurement_status_thresholds(model, normalized, status) -> None:
    controller = OffsetFreeController(model, MPCConfig(solver="daqp"))
    controller.step(7.0, 7.0)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        controller.step(_physical(model, normalized), 7.0)
    assert controller.records[-1].measurement_status == status


def test_implausible_measurement_refused_on_request(model) -> None:
    controller = OffsetFreeController(
        model, MPCConfig(solver="daqp"), implausible_measurements="raise"
    )
    controller.step(7.0, 7.5)
    x_hat = controller.observer.x_hat.copy()
    with pytest.raises(InvalidValueError, match="Refused"):
        controller.step(1e6, 7.5)
    assert len(controller.records) == 1  # nothing recorded
    np.testing.assert_array_equal(controller.observer.x_hat, x_hat)  # nor updated
    with pytest.raises(InvalidValueError, match="implausible_measurements"):
        OffsetFreeController(model, implausible_measurements="ignore")


@pytest.mark.parametrize("target", [12.0, 1e6])
def test_rate_limited_setpoint_reports_an_inadmissible_target_from_the_first_step(
    model, target
) -> None:
    """Before, the run was 'ok' until the limited set-point left the interval (step 112)
    and the warning pointed at simulation.py."""
    controller = OffsetFreeController(model, MPCConfig(solver="daqp"), setpoint_rate_limit=0.01)
    with pytest.warns(RuntimeWarning, match="rate-limited set-point") as caught:
        result = simulate(PHNeutralizationPlant(), controller, np.full(20, target), progress=False)
    assert result.setpoint_status[0] == "target_outside_admissible"
    assert set(result.setpoint_status) == {"target_outside_admissible"}
    assert result.summary_counts()["setpoint_target_outside_admissible_steps"] == 20
    setpoint_warnings = [w for w in caught if "set-point" in str(w.message)]
    assert len(setpoint_warnings) == 1
    assert setpoint_warnings[0].filename == __file__


def test_admissible_target_under_the_limiter_is_ok(model) -> None:
    controller = OffsetFreeController(model, MPCConfig(solver="daqp"), setpoint_rate_limit=0.01)
    result = simulate(PHNeutralizationPlant(), controller, np.full(20, 7.5), progress=False)
    assert set(result.setpoint_status) == {"ok"}


def test_warnings_are_shown_once_per_run_and_again_in_the_next_run(model) -> None:
    """Python's registry shows a warning once per location; the loop's own registry shows it
    once per run, and counts every step."""
    controller = OffsetFreeController(model, MPCConfig(solver="daqp"))
    for run in range(2):
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("default")  # the registry decides, as outside pytest
            result = simulate(PHNeutralizationPlant(), controller, np.full(8, 9.45), progress=False)
        shown = [w for w in caught if "set-point" in str(w.message)]
        assert len(shown) == 1, run
        assert shown[0].filename == __file__
        assert result.warning_counts["setpoint"] == 8


def test_run_warnings_counts_and_resets() -> None:
    run = RunWarnings()
    assert run.first("a") and not run.first("a") and run.first("b")
    assert run.counts == {"a": 2, "b": 1}
    run.reset()
    assert run.counts == {} and run.first("a")


def test_warn_at_caller_points_outside_the_library() -> None:
    with pytest.warns(UserWarning, match="here") as caught:
        warn_at_caller("here", UserWarning)
    assert caught[0].filename == __file__
