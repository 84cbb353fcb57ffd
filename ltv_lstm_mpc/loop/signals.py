r"""The loop's signal formulas, numpy reference (compiled twins: ``compiled_signals.py``).

One implementation of each, called by every step engine (:mod:`ltv_lstm_mpc.loop.engines`):

- :class:`SignalScaling`: physical <-> normalized signals (paper notes 1) and
  :math:`\mathcal U` in physical units;
- :func:`limit_rate`: the set-point rate limiter (Theorem 3's :math:`\Delta y^0_{max}`);
- :func:`project_onto_box`: the exit gate's projection onto
  :math:`\mathcal U = \{\|u\|_\infty \le u_{max}\}`;
- :func:`measurement_code`: the measurement status
  (:data:`~ltv_lstm_mpc.loop.statuses.MEASUREMENT_STATUSES`);
- :func:`setpoint_code`: the set-point status of a step with an admissible equilibrium
  (:data:`~ltv_lstm_mpc.loop.statuses.SETPOINT_STATUSES`).

The compiled twins compute the same numbers in the same order of operations
(``tests/test_signals.py`` compares them).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from ltv_lstm_mpc.lstm.model import LSTMModel

__all__ = [
    "SignalScaling",
    "limit_rate",
    "measurement_code",
    "project_onto_box",
    "setpoint_code",
]

FloatArray = NDArray[np.float64]


@dataclass(frozen=True, slots=True)
class SignalScaling:
    r"""The model's normalization and :math:`\mathcal U` (paper notes 1).

    Physical = (normalized + 1) scale + min, output by output and input by input.

    Attributes
    ----------
    y_min, y_scale, u_min, u_scale : ndarray
        The normalization of the outputs (p) and inputs (m).
    u_max : float
        :math:`\mathcal U = \{\|u\|_\infty \le u_{max}\}` (normalized).
    u_phi_low, u_phi_high : ndarray (m,)
        :math:`\mathcal U` in physical units: the de-normalized :math:`\pm u_{max}`, never
        beyond the stored range where :math:`u_{max} \le 1` (the de-normalization of 1
        may round one ulp above it).
    """

    y_min: FloatArray
    y_scale: FloatArray
    u_min: FloatArray
    u_scale: FloatArray
    u_max: float
    u_phi_low: FloatArray
    u_phi_high: FloatArray

    @classmethod
    def of(cls, model: LSTMModel, u_max: float) -> SignalScaling:
        """The scaling of ``model`` (which has a normalization) with the bound ``u_max``."""
        norm = model.normalization
        assert norm is not None  # the controller checks it first
        u_max = float(u_max)
        low = norm.denormalize_u(np.full(model.m, -u_max))
        high = norm.denormalize_u(np.full(model.m, u_max))
        if u_max <= 1.0:
            np.maximum(low, norm.u_phi_min, out=low)
            np.minimum(high, norm.u_phi_max, out=high)
        return cls(norm.y_phi_min, norm.y_scale, norm.u_phi_min, norm.u_scale, u_max, low, high)

    # The Normalization's formulas (lstm/model.py) on scales computed once: the reference
    # engine's per-step conversions.
    def normalize_y(self, y_phi: FloatArray) -> FloatArray:
        """Normalized outputs from physical ones."""
        return np.asarray((y_phi - self.y_min) / self.y_scale - 1.0, dtype=np.float64)

    def denormalize_u(self, u: FloatArray) -> FloatArray:
        """Physical input from the normalized one."""
        return np.asarray((u + 1.0) * self.u_scale + self.u_min, dtype=np.float64)

    def physical_y(self, y: FloatArray) -> list[float]:
        """Physical outputs from normalized ones, as a list (for messages)."""
        return [float(v) for v in (y + 1.0) * self.y_scale + self.y_min]


def limit_rate(y0_target: FloatArray, y0_previous: FloatArray, limit: float) -> FloatArray:
    r"""The set-point moved from ``y0_previous`` towards ``y0_target`` by at most ``limit``
    per output (a new array): :math:`y^0_k = y^0_{k-1} + \mathrm{clip}(y^0_{target} -
    y^0_{k-1}, -\Delta, \Delta)`."""
    change = np.minimum(np.maximum(y0_target - y0_previous, -limit), limit)  # np.clip, faster
    change += y0_previous
    return change


def project_onto_box(u: FloatArray, u_max: float) -> tuple[FloatArray, float]:
    """``u`` (finite) projected onto the box ``[-u_max, u_max]`` and how far it moved
    (inf-norm)."""
    gated = np.clip(u, -u_max, u_max)
    return gated, float(np.abs(gated - u).max())


def measurement_code(largest: float, implausible: float) -> int:
    """The index in :data:`~ltv_lstm_mpc.loop.statuses.MEASUREMENT_STATUSES` of a
    measurement whose largest normalized magnitude is ``largest``: 0 within the training
    range [-1, 1], 1 up to ``implausible``, 2 beyond."""
    if largest <= 1.0:
        return 0
    return 1 if largest <= implausible else 2


def setpoint_code(used_inside: bool, limited: bool, target_inside: bool) -> int:
    """The index in :data:`~ltv_lstm_mpc.loop.statuses.SETPOINT_STATUSES` of a step whose
    equilibrium is admissible, from the tests against the admissible interval of
    Assumption 5: 1 (``"outside_admissible"``) where the set-point used lies outside it; 2
    (``"target_outside_admissible"``) where it lies inside but the rate limiter is moving
    it towards a requested one outside (``limited``: a limiter moved it this step;
    ``target_inside``: the requested one's test, read only in that case); else 0."""
    if not used_inside:
        return 1
    if limited and not target_inside:
        return 2
    return 0
