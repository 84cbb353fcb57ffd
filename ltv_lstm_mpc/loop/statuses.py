"""The per-step status values the closed loop records (one home for their names).

See :class:`~ltv_lstm_mpc.ControllerStep` for what each value means.
"""

from __future__ import annotations

__all__ = [
    "IMPLAUSIBLE_MEASUREMENT_LIMIT",
    "MEASUREMENT_STATUSES",
    "SETPOINT_STATUSES",
    "SETPOINT_STATUSES_ADMISSIBLE",
    "UNREACHABLE_STALE",
]

#: ``ControllerStep.setpoint_status`` values.
SETPOINT_STATUSES = (
    "ok",
    "outside_admissible",
    "target_outside_admissible",
    "unreachable_stale",
    "unreachable",
)

#: The index of ``"unreachable_stale"`` (the compiled step records statuses by index).
UNREACHABLE_STALE = SETPOINT_STATUSES.index("unreachable_stale")

#: The set-point statuses under which Assumptions 4 and 5 hold at the step (the set-point
#: used is admissible; with ``"target_outside_admissible"`` only the requested one is not).
SETPOINT_STATUSES_ADMISSIBLE = ("ok", "target_outside_admissible")

#: ``ControllerStep.measurement_status`` values.
MEASUREMENT_STATUSES = ("ok", "outside_training_range", "implausible")

#: A measurement is implausible when its normalized value exceeds this in magnitude: the
#: normalization maps the training range onto [-1, 1] (width 2), so 3 is one range width
#: beyond it on either side. Between 1 and 3 it is ``"outside_training_range"``.
IMPLAUSIBLE_MEASUREMENT_LIMIT = 3.0
