r"""Compiled (numba) eq. (lstm) and eq. (jacobian) on the Trajectory buffers (numpy: reference).

Compiled with ``numba.njit(cache=True)`` (once, cached on disk next to this file) and used
when the model's :class:`~ltv_lstm_mpc.lstm.kernel.LSTMKernel` is compiled (the default;
``compiled=False`` or ``LTV_LSTM_MPC_KERNEL=numpy`` select the numpy reference):
:func:`lstm_cell` (one step of eq. (lstm), the building block of every compiled kernel of
the package), :func:`rollout`, :func:`pairs` and :func:`jacobians` (reference:
``LSTMKernel``).

The compiled twins of the other concepts live beside their numpy references:
``loop/compiled_observer.py`` (eq. (lstm_observer)), ``loop/compiled_reference.py`` (the
reference calculator's chord-Newton), ``mpc/compiled_condensing.py`` (the condensed QP and
its feedback insertion), ``mpc/compiled_plan.py`` (the plan checks) and
``mpc/compiled_prepare.py`` (the RTI preparation in one call).

The Jacobians follow the reference's order of operations (bit for bit on the same
activations); elsewhere sums run in another order (the LSTM cell, the feedback insertion,
the backward recursions and the plan checks may vectorize theirs:
:data:`~ltv_lstm_mpc.numba_support.REDUCTIONS`) and the exponentials come from another
library than numpy's, so the results agree to a few ulps (every function is tested against
its reference to 1e-12 in ``tests/test_kernel.py``).

:data:`AVAILABLE` is False when numba cannot be imported; the numpy reference then runs.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from ltv_lstm_mpc.numba_support import AVAILABLE, REDUCTIONS, njit

__all__ = ["AVAILABLE", "jacobians", "lstm_cell", "pairs", "rollout"]


@njit(cache=True, fastmath=REDUCTIONS)
def lstm_cell(
    WU: Any, z: Any, t: Any, c: Any, c_next: Any, h_next: Any, tc: Any, extra: Any
) -> None:
    """One step of eq. (lstm): gates ``t`` from ``z = [h; u; 1]``, next state, tanh(c+)."""
    rows, cols = WU.shape
    n = rows // 4
    for r in range(rows):
        acc = 0.0
        for j in range(cols):
            acc += WU[r, j] * z[j]
        if extra.shape[0]:
            acc += extra[r]
        if r < 3 * n:
            acc = 1.0 / (1.0 + math.exp(-acc))
        else:
            acc = math.tanh(acc)
        t[r] = acc
    for a in range(n):
        value = t[a] * c[a] + t[n + a] * t[3 * n + a]
        c_next[a] = value
        tanh_c = math.tanh(value)
        tc[a] = tanh_c
        h_next[a] = t[2 * n + a] * tanh_c


@njit(cache=True)
def rollout(WU: Any, S: Any, T: Any, TC: Any, k0: int, k1: int, extra: Any) -> None:
    """Steps ``k0..k1-1`` in place (see ``LSTMKernel.rollout``); ``extra`` of length 0 or 4n."""
    n = WU.shape[0] // 4
    for k in range(k0, k1):
        lstm_cell(WU, S[k, n:], T[k], S[k, :n], S[k + 1, :n], S[k + 1, n : 2 * n], TC[k], extra)


@njit(cache=True)
def pairs(WU: Any, S: Any, T: Any, TC: Any, out: Any, K: int) -> None:
    """Independent pairs: ``out[k] = f(S[k, :2n], S[k, 2n:2n+m])`` (see ``LSTMKernel.pairs``)."""
    n = WU.shape[0] // 4
    empty = np.zeros(0)
    for k in range(K):
        lstm_cell(WU, S[k, n:], T[k], S[k, :n], out[k, :n], out[k, n:], TC[k], empty)


@njit(cache=True)
def jacobians(WU_raw: Any, S: Any, T: Any, TC: Any, J: Any) -> None:
    r"""Batched :math:`[A_k\; B_k]` into ``J`` (see ``LSTMKernel.jacobians``).

    The same products in the same order as the numpy reference: :math:`D_f = (1-f) f c`,
    :math:`D_i = (1-i) i g`, :math:`D_o = (1-o) o \tanh c^+`, :math:`D_g = (1-g^2) i`,
    :math:`\partial c^+/\partial[h; u] = (D_f U_f + D_i U_i) + D_g U_g`,
    :math:`\partial h^+ = (1-\tanh^2 c^+) o\, \partial c^+ + D_o U_o`.
    """
    N = J.shape[0]
    n = WU_raw.shape[0] // 4
    cols = WU_raw.shape[1]  # n + m
    for k in range(N):
        for a in range(n):
            f = T[k, a]
            i = T[k, n + a]
            o = T[k, 2 * n + a]
            g = T[k, 3 * n + a]
            tc = TC[k, a]
            d_f = ((1.0 - f) * f) * S[k, a]
            d_i = ((1.0 - i) * i) * g
            d_o = ((1.0 - o) * o) * tc
            d_g = (1.0 - g * g) * i
            dh = (1.0 - tc * tc) * o
            for b in range(n):
                J[k, a, b] = 0.0
                J[k, n + a, b] = 0.0
            J[k, a, a] = f
            J[k, n + a, a] = dh * f
            for b in range(cols):
                jc = (d_f * WU_raw[a, b] + d_i * WU_raw[n + a, b]) + d_g * WU_raw[3 * n + a, b]
                J[k, a, n + b] = jc
                J[k, n + a, n + b] = dh * jc + d_o * WU_raw[2 * n + a, b]
