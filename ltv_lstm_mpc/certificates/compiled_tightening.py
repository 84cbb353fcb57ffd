r"""Compiled twins of :class:`~ltv_lstm_mpc.certificates.tightening.TighteningCertificate`'s
per-step formulas, for a step that runs as one compiled call.

Each function computes what its numpy twin in ``tightening.py`` computes, in the same
order of operations (so the same floating-point numbers; ``tests/test_tightening.py``
compares them), from the certificate's arrays rather than the object:

- :func:`output_bounds_into`: eq. (optimization_constraint_yub) and
  (optimization_constraint_ylb), :meth:`~TighteningCertificate.output_bounds`;
- :func:`terminal_alpha`: :math:`\alpha_k`, eq. (def_alpha), :meth:`~TighteningCertificate.alpha`;
- :func:`inside_setpoint_interval`: the admissible set-point interval of Assumption 5,
  :meth:`~TighteningCertificate.setpoint_interval` (strict inequalities);
- :func:`next_e_hat`: eq. (eo_evolution), :meth:`~TighteningCertificate.next_e_hat`.

``two_d`` is :math:`2 d_{max}`; ``e_tilde`` is :math:`\tilde e_{o,k} = \max\{\hat e_{o,k},
\bar e_\infty\}` (eq. e_ok_bar); ``a_N``, ``b_N`` are the rows N of the certificate's
:math:`a_i, b_i`.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from ltv_lstm_mpc.numba_support import njit

__all__ = ["inside_setpoint_interval", "next_e_hat", "output_bounds_into", "terminal_alpha"]


@njit(cache=True)
def output_bounds_into(
    a: Any, b: Any, d_max: float, y_min: Any, y_max: Any, e_hat: float, lower: Any, upper: Any
) -> None:
    r"""The tightened output bounds for i = 0..N-1 into ``lower``, ``upper`` (N, p):
    :math:`y_{min} + a_i \hat e_{o,k} + b_i + d_{max}` and
    :math:`y_{max} - a_i \hat e_{o,k} - b_i - d_{max}`."""
    for i in range(lower.shape[0]):
        for j in range(lower.shape[1]):
            shrink = a[i, j] * e_hat + b[i, j] + d_max
            lower[i, j] = y_min[j] + shrink
            upper[i, j] = y_max[j] - shrink


@njit(cache=True)
def terminal_alpha(
    y0: Any, y_min: Any, y_max: Any, kappa: Any, two_d: float, a_N: Any, b_N: Any,
    e_tilde: float,
) -> float:  # fmt: skip
    r""":math:`\alpha_k = \min_j \kappa_j^{-1}(\min\{y_{max(j)} - y^0_{k(j)}, y^0_{k(j)} -
    y_{min(j)}\} - 2 d_{max} - a_{N(j)} \tilde e_{o,k} - b_{N(j)})`; not positive: the
    set-point violates Assumption 5."""
    alpha = np.inf
    for j in range(y0.shape[0]):
        margin = two_d + a_N[j] * e_tilde + b_N[j]
        k = kappa[j]
        alpha = min(alpha, min((y_max[j] - y0[j] - margin) / k, (y0[j] - y_min[j] - margin) / k))
    return alpha


@njit(cache=True)
def inside_setpoint_interval(
    values: Any, y_min: Any, y_max: Any, two_d: float, a_N: Any, b_N: Any, e_tilde: float
) -> bool:
    r"""``values`` strictly inside :math:`(y_{min} + 2 d_{max} + a_N \tilde e_{o,k} + b_N,\;
    y_{max} - 2 d_{max} - a_N \tilde e_{o,k} - b_N)`, output by output."""
    for j in range(values.shape[0]):
        margin = two_d + a_N[j] * e_tilde + b_N[j]
        if not y_min[j] + margin < values[j] < y_max[j] - margin:
            return False
    return True


@njit(cache=True)
def next_e_hat(rho_o: float, w_bar: float, e_hat: float) -> float:
    r""":math:`\hat e_{o,k+1} = \rho_o \hat e_{o,k} + \bar w`."""
    return rho_o * e_hat + w_bar
