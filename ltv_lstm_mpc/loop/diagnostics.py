r"""What a step tells its caller besides the input: checks, statuses and run warnings.

Shared by every step engine (:mod:`ltv_lstm_mpc.loop.engines`), so that a status or a
warning reads the same whichever engine ran the step:

- :func:`check_first_measurement` and :func:`measurement_status`: the measurement against
  the model's training range (:data:`~ltv_lstm_mpc.loop.statuses.MEASUREMENT_STATUSES`);
- :func:`setpoint_status`: the set-point against the admissible interval of Assumption 5
  (:data:`~ltv_lstm_mpc.loop.statuses.SETPOINT_STATUSES`);
- :func:`warn_diagnosis` and :func:`warn_clipped`: the run's warnings (shown once per run,
  counted per step; :class:`~ltv_lstm_mpc.caller_warnings.RunWarnings`).
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from ltv_lstm_mpc.exceptions import InvalidValueError
from ltv_lstm_mpc.loop.signals import measurement_code, setpoint_code
from ltv_lstm_mpc.loop.statuses import (
    IMPLAUSIBLE_MEASUREMENT_LIMIT,
    MEASUREMENT_STATUSES,
    SETPOINT_STATUSES,
)

if TYPE_CHECKING:
    from ltv_lstm_mpc.loop.controller import OffsetFreeController

__all__ = [
    "check_first_measurement",
    "flag_implausible",
    "measurement_status",
    "setpoint_status",
    "warn_clipped",
    "warn_diagnosis",
]

FloatArray = NDArray[np.float64]


def _inside(lows: list[float], values: list[float], highs: list[float]) -> bool:
    return all(a < y < b for a, y, b in zip(lows, values, highs, strict=True))


def setpoint_status(
    interval: tuple[list[float], list[float]],
    y0: FloatArray,
    y0_target: FloatArray,
    stale: bool,
    u_admissible: bool,
) -> str:
    """The set-point status of a step (``ControllerStep.setpoint_status``): ``interval`` is
    the admissible interval of Assumption 5 at this :math:`\\hat e_{o,k}` (lows, highs as
    lists: p scalars, lists beat numpy here); ``y0_target`` is ``y0`` itself where no
    rate limiter moves the set-point."""
    if stale or not u_admissible:
        return "unreachable_stale" if stale else "unreachable"
    lows, highs = interval
    used_inside = _inside(lows, y0.tolist(), highs)
    limited = y0_target is not y0
    target_inside = not (used_inside and limited) or _inside(lows, y0_target.tolist(), highs)
    return SETPOINT_STATUSES[setpoint_code(used_inside, limited, target_inside)]


def check_first_measurement(
    controller: OffsetFreeController, y: FloatArray, y_phi: ArrayLike
) -> None:
    """Refuse a first measurement more than one range width outside the model's
    normalization range (in the measurement's own units), before any reference
    calculation: the observer (and the set-point rate limiter) start from it, so the
    controller would fail later naming a set-point the caller never gave."""
    if max(abs(v) for v in y.tolist()) <= IMPLAUSIBLE_MEASUREMENT_LIMIT:
        return
    norm = controller.model.normalization
    assert norm is not None  # checked at construction

    def physical(values: Any) -> str:
        numbers = [f"{float(v):.4g}" for v in np.ravel(values)]
        return numbers[0] if len(numbers) == 1 else "[" + ", ".join(numbers) + "]"

    raise InvalidValueError(
        f"the first measurement y_phi = {physical(y_phi)} lies far outside the model's "
        f"output range {physical(norm.y_phi_min)} .. {physical(norm.y_phi_max)} (the "
        "physical units of its normalization; more than one range width outside): "
        "wrong units or a sensor fault? The controller starts its observer and the "
        "set-point rate limiter from the first measurement, so it cannot start from this "
        "one; give the measurement in the model's units"
    )


def measurement_status(controller: OffsetFreeController, y: FloatArray, y_phi: ArrayLike) -> str:
    """``"ok"``, ``"outside_training_range"`` or ``"implausible"`` (see
    :class:`~ltv_lstm_mpc.ControllerStep`); warns once per run, or raises, on an
    implausible one (``implausible_measurements``)."""
    code = measurement_code(max(abs(v) for v in y.tolist()), IMPLAUSIBLE_MEASUREMENT_LIMIT)
    if code < 2:
        return MEASUREMENT_STATUSES[code]
    flag_implausible(controller, y, y_phi)
    return MEASUREMENT_STATUSES[code]


def flag_implausible(controller: OffsetFreeController, y: FloatArray, y_phi: ArrayLike) -> None:
    """An implausible measurement (:func:`measurement_status`): raises where the controller
    refuses them (``implausible_measurements="raise"``), else counts it and warns once per
    run."""
    norm = controller.model.normalization
    assert norm is not None  # checked at construction
    message = (
        f"measurement y_phi = {np.asarray(y_phi, dtype=np.float64).tolist()} at step "
        f"{len(controller.records)} lies more than one range width outside the model's "
        f"normalization range [{norm.y_phi_min.tolist()}, {norm.y_phi_max.tolist()}] "
        f"(normalized {y.tolist()}, limit +-{IMPLAUSIBLE_MEASUREMENT_LIMIT}): a sensor "
        "fault or wrong units?"
    )
    if controller.implausible_measurements == "raise":
        raise InvalidValueError(
            message + " Refused (implausible_measurements='raise'); pass "
            "implausible_measurements='flag' to record it and use it anyway"
        )
    if controller.warnings.first("measurement_implausible"):
        controller.warnings.warn(message + " It is used as it is and flagged per step.")


def warn_diagnosis(
    controller: OffsetFreeController,
    status: str,
    saturated: NDArray[np.bool_],
    y0: FloatArray,
    y0_target: FloatArray,
    stale: bool,
) -> None:
    """Count (and show once per run) the saturation of d_hat and a set-point status other
    than ``"ok"``."""
    warnings, config = controller.warnings, controller.config
    physical_y = controller.scaling.physical_y
    k = len(controller.records)
    if saturated.any() and warnings.first("d_hat_saturated"):
        j = int(np.flatnonzero(saturated)[0])
        scale = float(controller.scaling.y_scale[j])
        warnings.warn(
            f"d_hat reached its bound d_max = {config.d_max} (normalized; "
            f"{config.d_max * scale:.4g} in physical output units) on output {j} at "
            f"step {k}: the plant-model mismatch exceeds the disturbance bound the "
            "guarantees assume (|d| <= d_max), and offsets may remain. Raise d_max "
            "(MPCConfig d_max; estimate_d_max(model, data) measures the mismatch), which "
            "shrinks the admissible set-point interval, or use a model that fits this "
            "operating point better"
        )
    if status != "ok" and warnings.first("setpoint"):
        low, high = controller.certification.tightening.setpoint_interval(controller.e_hat)
        interval = (
            f"the admissible interval [{physical_y(low)}, {physical_y(high)}] of Assumption 5"
        )
        if status == "outside_admissible":
            where = (
                f"outside {interval} (no terminal set: the MPC is infeasible and its "
                "policy applies)"
            )
        elif status == "target_outside_admissible":
            where = (
                f"outside {interval}; the rate-limited set-point "
                f"{physical_y(y0)} is still inside and will leave it"
            )
        else:
            where = "not reachable: no equilibrium with the input inside its bounds" + (
                " (the previous target is kept)" if stale else ""
            )
        requested = y0_target if status == "target_outside_admissible" else y0
        warnings.warn(f"set-point {physical_y(requested)} (physical units) at step {k} is {where}")


def warn_clipped(controller: OffsetFreeController, u: FloatArray, moved: float) -> None:
    """Show that the MPC's input ``u`` was moved onto U (once per run)."""
    what = (
        f"was projected onto U (moved by {moved:.3e}, normalized)"
        if math.isfinite(moved)
        else "was not finite and was replaced by "
        + ("the last applied input" if controller.records else "u_bar projected onto U")
    )
    scaling = controller.scaling
    controller.warnings.warn(
        f"the MPC's input {u.tolist()} (normalized) at step {len(controller.records)} "
        f"{what}: U = [{scaling.u_phi_low.tolist()}, {scaling.u_phi_high.tolist()}] in "
        "physical units. Every such step is recorded in ControllerStep.input_clipped"
    )
