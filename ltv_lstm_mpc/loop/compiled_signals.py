r"""Compiled twins of :mod:`ltv_lstm_mpc.loop.signals` (the same numbers, in place).

- :func:`limit_rate_into`: the set-point rate limiter
  (:func:`~ltv_lstm_mpc.loop.signals.limit_rate`);
- :func:`project_into`: the exit gate's projection onto :math:`\mathcal U`
  (:func:`~ltv_lstm_mpc.loop.signals.project_onto_box`);
- :func:`measurement_code`: the measurement status
  (:func:`~ltv_lstm_mpc.loop.signals.measurement_code`);
- :func:`setpoint_code`: the set-point status (:func:`~ltv_lstm_mpc.loop.signals.setpoint_code`).
"""

from __future__ import annotations

from typing import Any

from ltv_lstm_mpc.numba_support import njit

__all__ = ["limit_rate_into", "measurement_code", "project_into", "setpoint_code"]


@njit(cache=True)
def limit_rate_into(y0: Any, y0_previous: Any, limit: float, requested: Any) -> None:
    """``y0`` (holding the requested set-point) moved from ``y0_previous`` towards it by at
    most ``limit`` per output, in place; the requested one is kept in ``requested``."""
    for j in range(y0.shape[0]):
        requested[j] = y0[j]
        change = min(max(y0[j] - y0_previous[j], -limit), limit)
        y0[j] = change + y0_previous[j]


@njit(cache=True)
def project_into(u: Any, u_max: float) -> float:
    """``u`` (finite) projected onto ``[-u_max, u_max]`` in place; returns how far it moved
    (inf-norm)."""
    moved = 0.0
    for a in range(u.shape[0]):
        gated = min(max(u[a], -u_max), u_max)
        moved = max(moved, abs(gated - u[a]))
        u[a] = gated
    return moved


@njit(cache=True)
def measurement_code(largest: float, implausible: float) -> int:
    """0 within the training range, 1 up to ``implausible``, 2 beyond."""
    if largest <= 1.0:
        return 0
    return 1 if largest <= implausible else 2


@njit(cache=True)
def setpoint_code(used_inside: bool, limited: bool, target_inside: bool) -> int:
    """1 outside the admissible interval, 2 inside while the limiter moves towards a
    target outside it, else 0."""
    if not used_inside:
        return 1
    if limited and not target_inside:
        return 2
    return 0
