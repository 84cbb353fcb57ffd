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
:data:`~ltv_lstm_mpc.numba_support.REDUCTIONS`) and the cell's sigmoid and tanh are
polynomials of its own (:func:`_exp_parts`: libm's scalar ``exp`` and ``tanh`` would keep
its loops from vectorizing; within 4 ulps of numpy's for :math:`|x| \le 708`, sigmoid below
3.4e-308 for :math:`x < -708`), so the results agree to a few ulps
(every function is tested against its reference to 1e-12 in ``tests/test_kernel.py``).

:data:`AVAILABLE` is False when numba cannot be imported; the numpy reference then runs.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from ltv_lstm_mpc.numba_support import AVAILABLE, REDUCTIONS, njit

__all__ = ["AVAILABLE", "jacobians", "lstm_cell", "pairs", "rollout"]


#: exp(x) for |x| above this is clamped (exp(708) is finite; the activations below do not
#: need more: beyond it tanh is +-1 and sigmoid 1 to the last bit, or below 3.4e-308).
_EXP_LIMIT = 708.0
_LOG2_E = 1.4426950408889634
#: ln 2 in two parts (Cody and Waite): k ln2_high is exact for |k| < 2^20.
_LN2_HIGH = 6.93147180369123816490e-01
_LN2_LOW = 1.90821492927058770002e-10
#: 1.5 * 2^52: adding it to an integer-valued float puts the integer in the low bits.
_SHIFTER = 6755399441055744.0
_SHIFTER_BITS = 0x4338000000000000
#: 1/j! for j = 2..13, the Taylor coefficients of exp(r) - 1 - r on |r| <= ln2 / 2
#: (truncation below 5e-18 relative).
_TAYLOR = tuple(1.0 / math.factorial(j) for j in range(2, 14))


@njit(cache=True, fastmath=False, error_model="numpy")
def _exp_parts(x: float) -> tuple[float, float]:
    r"""``(s, q)`` with :math:`e^x = s (1 + q)`, :math:`s = 2^k`, :math:`k = \mathrm{round}(x /
    \ln 2)`, :math:`q = e^r - 1` for the reduced :math:`r = x - k \ln 2`.

    The building block of :func:`_sigmoid` and :func:`_tanh` in a form the compiler can
    vectorize (no library call, no branch: the calls to libm's ``exp`` and ``tanh`` keep
    the loops of :func:`lstm_cell` scalar). Accurate to a few ulps (tested against numpy):
    the reduction in two parts, a degree-13 Taylor polynomial, :math:`2^k` written into the
    exponent bits. ``fastmath=False`` is explicit: numba would otherwise give these
    functions the flags of their first caller (``lstm_cell``'s reassociation), which
    could undo the two-part reduction and the cancellation-free forms below. NaN
    propagates; :math:`|x|` is clamped to ``_EXP_LIMIT``.
    """
    x = _EXP_LIMIT if x > _EXP_LIMIT else x
    x = -_EXP_LIMIT if x < -_EXP_LIMIT else x
    k = np.floor(x * _LOG2_E + 0.5)
    r = (x - k * _LN2_HIGH) - k * _LN2_LOW
    c2, c3, c4, c5, c6, c7, c8, c9, c10, c11, c12, c13 = _TAYLOR
    q = c13 * r + c12
    q = q * r + c11
    q = q * r + c10
    q = q * r + c9
    q = q * r + c8
    q = q * r + c7
    q = q * r + c6
    q = q * r + c5
    q = q * r + c4
    q = q * r + c3
    q = q * r + c2
    q = (q * r) * r + r
    exponent = np.float64(k + _SHIFTER).view(np.int64) - _SHIFTER_BITS  # k, exactly
    scale = np.int64((exponent + 1023) << 52).view(np.float64)
    return scale, q


@njit(cache=True, fastmath=False, error_model="numpy")
def _activation(x: float, sigmoid: bool) -> float:
    r""":math:`\sigma(x) = 1 / (1 + e^{-x})` where ``sigmoid`` (the gates f, i, o of eq.
    (lstm)), else :math:`\tanh x = m / (m + 2)` with :math:`m = e^{2x} - 1` formed as
    :math:`(s - 1) + s q` (relative accuracy near 0 kept: no cancellation). One
    exponential either way, so that one loop of :func:`lstm_cell` over its 4n gates
    vectorizes."""
    scale, q = _exp_parts(-x if sigmoid else 2.0 * x)
    if sigmoid:
        return 1.0 / (1.0 + (scale + scale * q))
    m = (scale - 1.0) + scale * q
    return math.copysign(m / (m + 2.0), x)  # tanh is odd: the sign of x, -0.0 included


@njit(cache=True, fastmath=False, error_model="numpy")
def _sigmoid(x: float) -> float:
    r""":math:`\sigma(x) = 1 / (1 + e^{-x})` (:func:`_activation`)."""
    return _activation(x, True)


@njit(cache=True, fastmath=False, error_model="numpy")
def _tanh(x: float) -> float:
    r""":math:`\tanh x` (:func:`_activation`)."""
    return _activation(x, False)


@njit(cache=True, fastmath=REDUCTIONS, error_model="numpy")
def lstm_cell(
    WU: Any, z: Any, t: Any, c: Any, c_next: Any, h_next: Any, tc: Any, extra: Any
) -> None:
    """One step of eq. (lstm): gates ``t`` from ``z = [h; u; 1]``, next state, tanh(c+).

    The activations run in loops the compiler vectorizes (a third of the cell's time at
    n = 5 against libm's scalar calls): one over the 4n gates (:func:`_activation`:
    sigmoid on f, i, o, tanh on g), one over the n entries of c+, tanh(c+) and h+ (a loop
    over n = 5 entries alone is shorter than the vector width and runs scalar)."""
    rows, cols = WU.shape
    n = rows // 4
    for r in range(rows):
        acc = 0.0
        for j in range(cols):
            acc += WU[r, j] * z[j]
        t[r] = acc
    if extra.shape[0]:
        for r in range(rows):
            t[r] += extra[r]
    sigmoids = 3 * n
    for r in range(rows):
        t[r] = _activation(t[r], r < sigmoids)
    g = t[sigmoids:]
    for a in range(n):
        c_plus = t[a] * c[a] + t[n + a] * g[a]
        c_next[a] = c_plus
        tanh_c = _tanh(c_plus)
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
