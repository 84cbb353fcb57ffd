r"""Compiled (numba) versions of the controller's hot loops; the numpy code is the reference.

Compiled with ``numba.njit(cache=True)`` (once, cached on disk next to this file) and
used when the model's :class:`~ltv_lstm_mpc.lstm.kernel.LSTMKernel` is compiled (the
default; ``compiled=False`` or ``LTV_LSTM_MPC_KERNEL=numpy`` select the numpy reference):

- :func:`rollout`, :func:`pairs`, :func:`jacobians`: eq. (lstm) and eq. (jacobian) on the
  :class:`~ltv_lstm_mpc.lstm.kernel.Trajectory` buffers (reference: ``LSTMKernel``);
- :func:`condense`, :func:`insert_state`, :func:`expand_point`: the condensed QP of
  ``CondensedTranscription`` (reference: its numpy ``build`` / ``solve``);
- :func:`chord_newton`: the warm path of ``ReferenceCalculator`` (reference: ``_chord``);
- :func:`observer_update`: eq. (lstm_observer), innovation to next estimate (reference:
  ``Observer.update`` on the numpy kernel);
- :func:`plan_metrics`: re-simulation, cost and residuals of the applied plan (reference:
  ``PlanCost`` and ``plan_residuals`` in ``mpc/fhocp.py``).

The Jacobians follow the reference's order of operations (bit for bit on the same
activations); elsewhere sums run in another order (the LSTM cell, the feedback insertion,
the backward recursions and the plan checks may vectorize theirs: :data:`_REDUCTIONS`) and
the exponentials come from another library than numpy's, so the results agree to a few ulps
(every function is tested against its reference to 1e-12 in ``tests/test_kernel.py``).

:data:`AVAILABLE` is False when numba cannot be imported; the numpy reference then runs.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from ltv_lstm_mpc.numba_support import AVAILABLE, njit

#: LLVM flags of the loops whose sums may run in any order (vectorized reductions, fused
#: multiply-adds): results within a few ulps of the sequential sums. No "fast" flags that
#: assume finite values: NaN and inf still propagate and are caught by the callers' checks.
_REDUCTIONS = {"reassoc", "contract"}

__all__ = [
    "AVAILABLE",
    "chord_newton",
    "condense",
    "expand_point",
    "insert_state",
    "jacobians",
    "observer_update",
    "pairs",
    "plan_metrics",
    "rollout",
]


@njit(cache=True, fastmath=_REDUCTIONS)
def _cell(WU: Any, z: Any, t: Any, c: Any, c_next: Any, h_next: Any, tc: Any, extra: Any) -> None:
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
        _cell(WU, S[k, n:], T[k], S[k, :n], S[k + 1, :n], S[k + 1, n : 2 * n], TC[k], extra)


@njit(cache=True)
def observer_update(
    WU: Any, W_y: Any, b_y: Any, L_gates: Any, L_d: Any, d_max: float,
    x_hat: Any, d_hat: Any, y: Any, u: Any, S: Any, T: Any, TC: Any, extra: Any,
    x_out: Any, d_out: Any,
) -> None:  # fmt: skip
    r"""eq. (lstm_observer): :math:`(\hat x_k, \hat d_k, y_k, u_k) \to (\hat x_{k+1},
    \hat d_{k+1})` into ``x_out``, ``d_out``. The innovation is
    :math:`y_k - W_y \hat h_k - b_y - \hat d_k`; ``L_gates`` (4n, p) injects it into the
    gates (0 rows: no injection, Remark 3); :math:`\hat d` is saturated at ``d_max``.
    ``S`` (one row of a Trajectory), ``T``, ``TC`` and ``extra`` (4n) are scratch."""
    n = WU.shape[0] // 4
    p = W_y.shape[0]
    m = u.shape[0]
    innovation = np.empty(p)
    for j in range(p):
        acc = y[j] - b_y[j] - d_hat[j]
        for a in range(n):
            acc -= W_y[j, a] * x_hat[n + a]
        innovation[j] = acc
    for a in range(2 * n):
        S[a] = x_hat[a]
    for j in range(m):
        S[2 * n + j] = u[j]
    injected = extra[:0]
    if L_gates.shape[0]:
        for r in range(4 * n):
            acc = 0.0
            for j in range(p):
                acc += L_gates[r, j] * innovation[j]
            extra[r] = acc
        injected = extra
    _cell(WU, S[n:], T, S[:n], x_out[:n], x_out[n : 2 * n], TC, injected)
    for j in range(p):
        acc = d_hat[j]
        for l in range(p):
            acc += L_d[j, l] * innovation[l]
        d_out[j] = min(max(acc, -d_max), d_max)


@njit(cache=True)
def pairs(WU: Any, S: Any, T: Any, TC: Any, out: Any, K: int) -> None:
    """Independent pairs: ``out[k] = f(S[k, :2n], S[k, 2n:2n+m])`` (see ``LSTMKernel.pairs``)."""
    n = WU.shape[0] // 4
    empty = np.zeros(0)
    for k in range(K):
        _cell(WU, S[k, n:], T[k], S[k, :n], out[k, :n], out[k, n:], TC[k], empty)


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


#: State size n from which condense's Gamma recursion uses BLAS products (loops below).
_BLAS_RECURSION_N = 10


@njit(cache=True)
def condense(
    J: Any,
    S: Any,
    M: Any,
    Maug: Any,
    Lt: Any,
    Qs: Any,
    x_bar: Any,
    u_bar: Any,
    R: Any,
    W_y: Any,
    b_y: Any,
    lower: Any,
    upper: Any,
    unit_half: Any,
    alpha: float,
    u_max: float,
    H: Any,
    g0: Any,
    A: Any,
    lo0: Any,
    up0: Any,
    lb: Any,
    ub: Any,
    diagonal: bool,
    backward: bool,
) -> float:
    r"""The input part of the condensed QP (``CondensedTranscription.build``), in place.

    Input-to-state matrices by the recursion :math:`\Gamma_{i+1} = A_i \Gamma_i + B_i e_i`
    (only the causal columns; ``M[i][:, 2n:]``), then the Hessian ``H`` and gradient ``g0``
    :math:`H = \sum_i \Gamma_i^\top Q_i \Gamma_i + \mathrm{blkdiag}(R)`,
    :math:`g_0 = \sum_i \Gamma_i^\top Q_i (\tilde x_i - \bar x) + R(\tilde u - \bar u)`
    (``Qs[i]`` weighs :math:`x_{i+1}`, ``Lt[i]`` is its factor) in one of two ways with the
    same result (see :func:`_hessian_gram`, :func:`_hessian_backward`), the tightened output
    rows i = 1..N-1 and the terminal box rows in :math:`\delta u`, and the input bounds
    around the candidate. The part in :math:`\delta x_0` (``F`` and ``E`` of the numpy
    build) is not formed: :func:`insert_state` propagates :math:`\delta x_0` at feedback
    time. Returns the violation scale :math:`1 + \max(u_{max}, |lo_0|, |up_0|)`.

    The state Jacobian of eq. (lstm) has diagonal :math:`\partial c^+/\partial c` and
    :math:`\partial h^+/\partial c` blocks (the gates do not depend on c), so the recursion
    takes two n x n products per stage instead of one 2n x 2n product (half the flops);
    ``diagonal`` says the stage weights are diagonal (diagonal Q).
    """
    N = J.shape[0]
    n2 = J.shape[1]
    m = J.shape[2] - n2
    n = n2 // 2
    p = W_y.shape[0]
    nu = N * m
    cols = n2 + nu
    # Gamma_{i+1} = A_i Gamma_i on the causal columns, A_i = [[D_cc, J_ch], [D_hc, J_hh]]
    # with diagonal D: two n x n products per stage, for small n as row updates along the
    # columns (contiguous, no call or copy per stage), else two BLAS products on copies
    # (measured crossover n ~ 10, experiments/condensing_speed.py)
    for i in range(N):
        live = n2 + i * m  # columns of M[i] that can be nonzero
        if n >= _BLAS_RECURSION_N and live > n2:
            Gamma_h = np.ascontiguousarray(M[i, n:n2, n2:live])
            by_h = np.ascontiguousarray(J[i, :, n:n2]) @ Gamma_h  # [J_ch; J_hh] Gamma_h
            for r in range(n):
                d_cc = J[i, r, r]
                d_hc = J[i, n + r, r]
                for c in range(live - n2):
                    gamma_c = M[i, r, n2 + c]
                    M[i + 1, r, n2 + c] = by_h[r, c] + d_cc * gamma_c
                    M[i + 1, n + r, n2 + c] = by_h[n + r, c] + d_hc * gamma_c
        for r in range(n if n < _BLAS_RECURSION_N else 0):
            d_cc = J[i, r, r]
            d_hc = J[i, n + r, r]
            target_c = M[i + 1, r]
            target_h = M[i + 1, n + r]
            source_c = M[i, r]
            for c in range(n2, live):
                target_c[c] = d_cc * source_c[c]
                target_h[c] = d_hc * source_c[c]
            for q in range(n):
                j_c = J[i, r, n + q]
                j_h = J[i, n + r, n + q]
                source_h = M[i, n + q]
                for c in range(n2, live):
                    target_c[c] += j_c * source_h[c]
                    target_h[c] += j_h * source_h[c]
        for r in range(n2):
            for j in range(m):
                M[i + 1, r, live + j] = J[i, r, n2 + j]
            for c in range(live + m, cols):
                M[i + 1, r, c] = 0.0
    if backward:
        _hessian_backward(J, S, M, Qs, x_bar, H, g0, diagonal)
    else:
        _hessian_gram(S, M, Maug, Lt, x_bar, H, g0, diagonal)
    for i in range(N):
        for a in range(m):
            acc = 0.0
            for b in range(m):
                H[i * m + a, i * m + b] += R[a, b]
                acc += R[a, b] * (S[i, n2 + b] - u_bar[b])
            g0[i * m + a] += acc
    n_out = (N - 1) * p
    for i in range(1, N):
        for j in range(p):
            row = (i - 1) * p + j
            y_lin = b_y[j]
            for q in range(n):
                y_lin += W_y[j, q] * S[i, n + q]
            lo0[row] = lower[i, j] - y_lin
            up0[row] = upper[i, j] - y_lin
            for c in range(nu):
                A[row, c] = 0.0
            for q in range(n):
                w = W_y[j, q]
                source = M[i, n + q]
                for c in range(nu):
                    A[row, c] += w * source[n2 + c]
    level = alpha if alpha > 0.0 else 0.0
    for r in range(n2):
        row = n_out + r
        for c in range(nu):
            A[row, c] = M[N, r, n2 + c]
        half = unit_half[r] * level
        centre = x_bar[r] - S[N, r]
        lo0[row] = centre - half
        up0[row] = centre + half
    for i in range(N):
        for a in range(m):
            value = S[i, n2 + a]
            lb[i * m + a] = -u_max - value
            ub[i * m + a] = u_max - value
    scale = u_max
    for row in range(n_out + n2):
        if abs(lo0[row]) > scale:
            scale = abs(lo0[row])
        if abs(up0[row]) > scale:
            scale = abs(up0[row])
    return 1.0 + scale


@njit(cache=True)
def _hessian_gram(S: Any, M: Any, Maug: Any, Lt: Any, x_bar: Any, H: Any, g0: Any,
                  diagonal: bool) -> None:  # fmt: skip
    r"""``H`` and ``g0`` (without R) of the condensed stage cost of eq. (optimization_cost)
    as one Gram matrix: the weighted stack
    ``Maug[i] = [Lt_i \Gamma_{i+1}, Lt_i (\tilde x_{i+1} - \bar x)]`` (N, 2n, Nm + 1) and one
    BLAS product :math:`O(N^3 n m^2)`, the cheaper way for short horizons."""
    N, n2 = Maug.shape[0], Maug.shape[1]
    nu = Maug.shape[2] - 1
    m = nu // N
    for i in range(N):
        live = (i + 1) * m
        if diagonal:
            for r in range(n2):
                w = Lt[i, r, r]
                target = Maug[i, r]
                source = M[i + 1, r]
                for c in range(live):
                    target[c] = w * source[n2 + c]
                for c in range(live, nu):
                    target[c] = 0.0
                target[nu] = w * (S[i + 1, r] - x_bar[r])
        else:
            for r in range(n2):  # Lt_i Gamma_{i+1} as row updates (a full Q is rare)
                target = Maug[i, r]
                for c in range(nu):
                    target[c] = 0.0
                for q in range(n2):
                    w = Lt[i, r, q]
                    source = M[i + 1, q]
                    for c in range(live):
                        target[c] += w * source[n2 + c]
                acc = 0.0
                for q in range(n2):
                    acc += Lt[i, r, q] * (S[i + 1, q] - x_bar[q])
                target[nu] = acc
    flat = Maug.reshape(N * n2, nu + 1)
    gram = flat.T @ flat  # one BLAS product (faster than loops over the causal blocks)
    for a in range(nu):
        for b in range(nu):
            H[a, b] = gram[a, b]
        g0[a] = gram[a, nu]


@njit(cache=True, fastmath=_REDUCTIONS)
def _transpose_times(J: Any, i: int, s: Any, out: Any) -> None:
    r"""``out = A_i^T s`` for the state Jacobian :math:`A_i` (its diagonal c-column blocks)."""
    n2 = s.shape[0]
    n = n2 // 2
    for r in range(n):
        out[r] = J[i, r, r] * s[r] + J[i, n + r, r] * s[n + r]
        out[n + r] = 0.0
    for row in range(n2):  # along the rows of J (contiguous)
        weight = s[row]
        for q in range(n):
            out[n + q] += J[i, row, n + q] * weight


@njit(cache=True, fastmath=_REDUCTIONS)
def _weight_times(Qs: Any, i: int, v: Any, out: Any, diagonal: bool) -> None:
    """``out = Qs[i] v``."""
    n2 = v.shape[0]
    for r in range(n2):
        if diagonal:
            out[r] = Qs[i, r, r] * v[r]
            continue
        acc = 0.0
        for q in range(n2):
            acc += Qs[i, r, q] * v[q]
        out[r] = acc


@njit(cache=True, fastmath=_REDUCTIONS)
def _hessian_backward(J: Any, S: Any, M: Any, Qs: Any, x_bar: Any, H: Any, g0: Any,
                      diagonal: bool) -> None:  # fmt: skip
    r"""``H`` and ``g0`` (without R) of the condensed stage cost of eq. (optimization_cost)
    (stage N: the terminal weight of the transcription) by the backward recursion of the
    cost-to-go weights, :math:`O(N n^3 + N^2 n m^2)`, the cheaper way for long horizons.

    With :math:`W_N = Q_N`, :math:`W_i = Q_i + A_i^\top W_{i+1} A_i` and
    :math:`V_i = W_{i+1} B_i`: :math:`H_{ji} = \Gamma_{i+1}[:, j]^\top V_i` (j <= i; the
    causal column blocks of ``M``) and :math:`g_{0,i} = B_i^\top s_{i+1}` with
    :math:`s_N = Q_N (\tilde x_N - \bar x)`, :math:`s_i = Q_i (\tilde x_i - \bar x) +
    A_i^\top s_{i+1}`: the same sums as the Gram matrix, grouped by stage.
    """
    N, n2 = J.shape[0], J.shape[1]
    m = J.shape[2] - n2
    n = n2 // 2
    W = np.empty((n2, n2))
    WA = np.empty((n2, n2))
    V = np.empty((n2, m))
    for r in range(n2):
        for q in range(n2):
            W[r, q] = Qs[N - 1, r, q]
    s = np.empty(n2)
    dev = np.empty(n2)
    As = np.empty(n2)
    for q in range(n2):
        dev[q] = S[N, q] - x_bar[q]
    _weight_times(Qs, N - 1, dev, s, diagonal)
    for i in range(N - 1, -1, -1):
        # V_i = W_{i+1} B_i and the H blocks of input i against inputs j <= i
        for r in range(n2):
            for b in range(m):
                acc = 0.0
                for q in range(n2):
                    acc += W[r, q] * J[i, q, n2 + b]
                V[r, b] = acc
        for j in range(i + 1):
            for a in range(m):
                for b in range(m):
                    acc = 0.0
                    for r in range(n2):
                        acc += M[i + 1, r, n2 + j * m + a] * V[r, b]
                    H[j * m + a, i * m + b] = acc
                    H[i * m + b, j * m + a] = acc
        for b in range(m):
            acc = 0.0
            for r in range(n2):
                acc += J[i, r, n2 + b] * s[r]
            g0[i * m + b] = acc
        if i == 0:
            break
        # W_i = Q_i + A_i^T W_{i+1} A_i (A_i's c-columns are diagonal blocks); inner loops
        # run along rows (contiguous)
        for r in range(n2):
            for q in range(n):
                WA[r, q] = W[r, q] * J[i, q, q] + W[r, n + q] * J[i, n + q, q]
                WA[r, n + q] = 0.0
            for t in range(n2):
                w = W[r, t]
                for q in range(n):
                    WA[r, n + q] += w * J[i, t, n + q]
        for r in range(n):
            d_cc, d_hc = J[i, r, r], J[i, n + r, r]
            for q in range(n2):
                W[r, q] = d_cc * WA[r, q] + d_hc * WA[n + r, q] + Qs[i - 1, r, q]
                W[n + r, q] = Qs[i - 1, n + r, q]
        for t in range(n2):
            for r in range(n):
                j_tr = J[i, t, n + r]
                for q in range(n2):
                    W[n + r, q] += j_tr * WA[t, q]
        # s_i = Q_i (x_i - x_bar) + A_i^T s_{i+1}
        _transpose_times(J, i, s, As)
        for q in range(n2):
            dev[q] = S[i, q] - x_bar[q]
        _weight_times(Qs, i - 1, dev, s, diagonal)
        for q in range(n2):
            s[q] += As[q]


@njit(cache=True, fastmath=_REDUCTIONS)
def insert_state(
    x_hat: Any,
    S: Any,
    J: Any,
    Qs: Any,
    W_y: Any,
    g0: Any,
    lo0: Any,
    up0: Any,
    dX: Any,
    f: Any,
    lo: Any,
    up: Any,
    diagonal: bool,
) -> None:
    r"""Feedback data of the condensed QP for :math:`\delta x_0 = \hat x - \tilde x_0`.

    Propagates :math:`\delta x^0_{i+1} = A_i \delta x^0_i` into ``dX`` (N + 1, 2n), then
    :math:`f = g_0 + \sum_i \Gamma_i^\top Q_i \delta x^0_i` by the backward recursion
    :math:`s_N = Q_N \delta x^0_N`, :math:`s_i = Q_i \delta x^0_i + A_i^\top s_{i+1}`,
    :math:`f_i = g_{0,i} + B_i^\top s_{i+1}` (:math:`O(N n^2)`), and the rows
    :math:`lo_0 - W_y \delta h^0_i`, :math:`up_0 - W_y \delta h^0_i` (i = 1..N-1) and
    :math:`lo_0 - \delta x^0_N`, :math:`up_0 - \delta x^0_N` (terminal box). Both
    recursions use the diagonal blocks of the state Jacobian (see :func:`condense`);
    ``Qs[i]`` weighs :math:`x_{i+1}`, ``diagonal``: they are diagonal.
    """
    N = J.shape[0]
    n2 = J.shape[1]
    m = J.shape[2] - n2
    n = n2 // 2
    p = W_y.shape[0]
    for q in range(n2):
        dX[0, q] = x_hat[q] - S[0, q]
    for i in range(N):
        for r in range(n):
            acc_c = J[i, r, r] * dX[i, r]
            acc_h = J[i, n + r, r] * dX[i, r]
            for q in range(n):
                acc_c += J[i, r, n + q] * dX[i, n + q]
            for q in range(n):
                acc_h += J[i, n + r, n + q] * dX[i, n + q]
            dX[i + 1, r] = acc_c
            dX[i + 1, n + r] = acc_h
    s = np.empty(n2)
    As = np.empty(n2)
    _weight_times(Qs, N - 1, dX[N], s, diagonal)
    for i in range(N - 1, -1, -1):
        for b in range(m):
            acc = g0[i * m + b]
            for r in range(n2):
                acc += J[i, r, n2 + b] * s[r]
            f[i * m + b] = acc
        if i == 0:
            break
        _transpose_times(J, i, s, As)
        _weight_times(Qs, i - 1, dX[i], s, diagonal)
        for q in range(n2):
            s[q] += As[q]
    n_out = (N - 1) * p
    for i in range(1, N):
        for j in range(p):
            row = (i - 1) * p + j
            acc = 0.0
            for q in range(n):
                acc += W_y[j, q] * dX[i, n + q]
            lo[row] = lo0[row] - acc
            up[row] = up0[row] - acc
    for r in range(n2):
        lo[n_out + r] = lo0[n_out + r] - dX[N, r]
        up[n_out + r] = up0[n_out + r] - dX[N, r]


@njit(cache=True, fastmath=_REDUCTIONS)
def expand_point(
    z: Any, A: Any, low: Any, high: Any, rows: int, M: Any, S: Any, dX: Any, x_linear: Any, u: Any
) -> float:
    r"""From the QP point ``z`` (its first ``N m`` entries :math:`\delta u`): the largest
    violation of ``low <= [z; A z] <= high`` over the first ``rows`` entries, the linearized
    states :math:`\tilde x_i + \delta x^0_i + \Gamma_i \delta u` and the inputs
    :math:`\tilde u + \delta u`."""
    nu = A.shape[1]
    violation = 0.0
    for a in range(min(nu, rows)):
        value = z[a]
        if low[a] - value > violation:
            violation = low[a] - value
        if value - high[a] > violation:
            violation = value - high[a]
    for row in range(rows - nu):
        acc = 0.0
        for a in range(nu):
            acc += A[row, a] * z[a]
        if low[nu + row] - acc > violation:
            violation = low[nu + row] - acc
        if acc - high[nu + row] > violation:
            violation = acc - high[nu + row]
    N1, n2 = x_linear.shape
    m = u.shape[1]
    for i in range(N1):
        for r in range(n2):
            acc = S[i, r] + dX[i, r]
            if i:
                for a in range(nu):
                    acc += M[i, r, n2 + a] * z[a]
            x_linear[i, r] = acc
    for i in range(u.shape[0]):
        for j in range(m):
            u[i, j] = S[i, n2 + j] + z[i * m + j]
    return violation


@njit(cache=True)
def _equilibrium_residual(
    WU: Any, W_y: Any, b_y: Any, S: Any, T: Any, TC: Any, z: Any, target: Any, F: Any
) -> float:
    """:math:`F(z) = [f(x, u) - x; W_y h + b_y - target]` into ``F``; returns its inf-norm."""
    n = WU.shape[0] // 4
    n2 = 2 * n
    p = W_y.shape[0]
    for q in range(z.shape[0]):
        S[0, q] = z[q]
    _cell(WU, S[0, n:], T[0], S[0, :n], S[1, :n], S[1, n:n2], TC[0], np.zeros(0))
    norm = 0.0
    for q in range(n2):
        F[q] = S[1, q] - z[q]
        if abs(F[q]) > norm:
            norm = abs(F[q])
    for j in range(p):
        acc = b_y[j] - target[j]
        for q in range(n):
            acc += W_y[j, q] * z[n + q]
        F[n2 + j] = acc
        if abs(acc) > norm:
            norm = abs(acc)
    return norm


@njit(cache=True)
def chord_newton(
    WU: Any,
    WU_raw: Any,
    W_y: Any,
    b_y: Any,
    S: Any,
    T: Any,
    TC: Any,
    J: Any,
    z_start: Any,
    target: Any,
    step_target: Any,
    Jinv: Any,
    state: Any,
    tol: float,
    max_iter: int,
    F: Any,
    jac: Any,
    z_out: Any,
) -> float:
    r"""The chord-Newton warm path of ``ReferenceCalculator`` (eq. reference_calculation).

    ``state`` (int64, 4): [Jinv valid, iterations, factorizations, ok] (in and out);
    ``step_target`` is the change of the target since the last solution (predictor of
    Lemma 5 with the kept inverse Jacobian). The solution goes into ``z_out``; returns the
    residual. Same algorithm as the numpy ``ReferenceCalculator._chord``.
    """
    n = WU.shape[0] // 4
    n2 = 2 * n
    size = z_start.shape[0]
    z = z_start.copy()
    if state[0] == 1:
        for a in range(size):
            acc = 0.0
            for j in range(size - n2):
                acc += Jinv[a, n2 + j] * step_target[j]
            z[a] += acc
    norm = _equilibrium_residual(WU, W_y, b_y, S, T, TC, z, target, F)
    iterations = 0
    factorizations = 0
    fresh = False
    z_new = np.empty(size)
    while norm >= tol and iterations < max_iter:
        if state[0] == 0:
            jacobians(WU_raw, S[:2], T[:1], TC[:1], J[:1])
            for r in range(size):
                for c in range(size):
                    jac[r, c] = 0.0
            for r in range(n2):
                for c in range(size):
                    jac[r, c] = J[0, r, c]
                jac[r, r] -= 1.0
            for j in range(size - n2):
                for q in range(n):
                    jac[n2 + j, n + q] = W_y[j, q]
            inverse = np.linalg.inv(jac)
            for r in range(size):
                for c in range(size):
                    Jinv[r, c] = inverse[r, c]
            state[0] = 1
            factorizations += 1
            fresh = True
        for a in range(size):
            acc = 0.0
            for c in range(size):
                acc += Jinv[a, c] * F[c]
            z_new[a] = z[a] - acc
        iterations += 1
        norm_new = _equilibrium_residual(WU, W_y, b_y, S, T, TC, z_new, target, F)
        if not norm_new < norm:
            if fresh:
                break
            state[0] = 0
            norm = _equilibrium_residual(WU, W_y, b_y, S, T, TC, z, target, F)  # restore
            continue
        if norm_new > 1e-2 * norm:
            state[0] = 0  # slow contraction: refactorize at z_new
        for a in range(size):
            z[a] = z_new[a]
        norm = norm_new
        fresh = False
    for a in range(size):
        z_out[a] = z[a]
    state[1] = iterations
    state[2] = factorizations
    state[3] = 1 if norm < tol else 0
    return norm


@njit(cache=True, fastmath=_REDUCTIONS)
def plan_metrics(
    WU: Any,
    S: Any,
    T: Any,
    TC: Any,
    W_y: Any,
    b_y: Any,
    x_bar: Any,
    u_bar: Any,
    Q: Any,
    R: Any,
    P_terms: Any,
    lower: Any,
    upper: Any,
    x_linear: Any,
    x_plan: Any,
    out: Any,
    Q_diagonal: bool,
) -> None:
    r"""Re-simulate the plan in ``S`` (row 0 state, inputs given) and its checks.

    Writes the states into ``x_plan`` (N + 1, 2n) and ``out`` = [cost eq.
    (optimization_cost), terminal norm :math:`\|[\|c_N-\bar c\|, \|h_N-\bar h\|]\|_{P_f}`,
    largest tightened-output violation (>= 0), :math:`\max|x - x_{linear}|` (NaN when
    ``x_linear`` has no rows)]; ``P_terms`` = (P11, P12 + P21, P22); ``Q_diagonal``: Q is
    diagonal (its quadratic form in O(n) instead of O(n^2)).
    """
    N = x_plan.shape[0] - 1
    n = WU.shape[0] // 4
    n2 = 2 * n
    m = u_bar.shape[0]
    p = W_y.shape[0]
    no_extra = np.zeros(0)
    for k in range(N):
        _cell(WU, S[k, n:], T[k], S[k, :n], S[k + 1, :n], S[k + 1, n:n2], TC[k], no_extra)
    for k in range(N + 1):
        for q in range(n2):
            x_plan[k, q] = S[k, q]
    dx = np.empty(n2)
    du = np.empty(m)
    stage = 0.0
    violation = 0.0
    for k in range(N):
        for q in range(n2):
            dx[q] = x_plan[k, q] - x_bar[q]
        for a in range(m):
            du[a] = S[k, n2 + a] - u_bar[a]
        for a in range(n2):
            if Q_diagonal:
                stage += Q[a, a] * dx[a] * dx[a]
                continue
            acc = 0.0
            for b in range(n2):
                acc += Q[a, b] * dx[b]
            stage += dx[a] * acc
        for a in range(m):
            acc = 0.0
            for b in range(m):
                acc += R[a, b] * du[b]
            stage += du[a] * acc
        for j in range(p):
            y = b_y[j]
            for q in range(n):
                y += W_y[j, q] * x_plan[k, n + q]
            if lower[k, j] - y > violation:
                violation = lower[k, j] - y
            if y - upper[k, j] > violation:
                violation = y - upper[k, j]
    tc2 = 0.0
    th2 = 0.0
    for q in range(n):
        dc = x_plan[N, q] - x_bar[q]
        dh = x_plan[N, n + q] - x_bar[n + q]
        tc2 += dc * dc
        th2 += dh * dh
    level = P_terms[0] * tc2 + P_terms[1] * math.sqrt(tc2 * th2) + P_terms[2] * th2
    terminal = math.sqrt(level if level > 0.0 else 0.0)
    gap = np.nan
    if x_linear.shape[0]:
        gap = 0.0
        for k in range(N + 1):
            for q in range(n2):
                d = abs(x_plan[k, q] - x_linear[k, q])
                if d > gap:
                    gap = d
    out[0] = stage + terminal * terminal
    out[1] = terminal
    out[2] = violation
    out[3] = gap
