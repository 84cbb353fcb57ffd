r"""Compiled (numba) condensing of the FHOCP subproblem and its feedback insertion.

The twins of :class:`~ltv_lstm_mpc.mpc.condensed.CondensedTranscription`'s numpy ``build``
and ``solve`` (their reference, tested to 1e-12 in ``tests/test_kernel.py``):
:func:`condense` (the condensed QP in delta u: Hessian by rank updates on the causal
columns, the Gram matrix or the backward recursion, gradient, output and terminal-box rows),
:func:`insert_state` (the measured :math:`\delta x_0` into gradient and row bounds at
feedback time) and :func:`expand_point` (the QP point back to states and inputs, with the
largest row violation). Used when the model's kernel is compiled.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from ltv_lstm_mpc.numba_support import REDUCTIONS, build_workspace, njit, workspace_type

__all__ = [
    "CONDENSING_FIELDS",
    "CONSTRUCTORS",
    "CondensingWorkspace",
    "condense",
    "expand_point",
    "insert_state",
    "new_condensing_workspace",
]

#: Fields of :data:`CondensingWorkspace`, in the order of its compiled constructor.
CONDENSING_FIELDS = (
    "J",
    "S",
    "M",
    "Maug",
    "Lt",
    "Qs",
    "R",
    "W_y",
    "b_y",
    "unit_half",
    "H",
    "g0",
    "A",
    "lo0",
    "up0",
    "lb",
    "ub",
    "dX",
    "f",
    "lo",
    "up",
    "low",
    "high",
    "u_max",
    "diagonal",
)

CondensingWorkspace = workspace_type(
    "CondensingWorkspace",
    CONDENSING_FIELDS,
    r"""Buffers of the condensed QP, shared with ``CondensedTranscription`` (one per
    linearization trajectory).

    ``J``, ``S``: the trajectory's Jacobians and states/inputs; ``M`` (N + 1, 2n, 2n + N m):
    :math:`\Gamma_i` and the state part; ``Maug``, ``Lt``, ``Qs``: the Gram stack, the stage
    weights' factors and the stage weights (``Qs[i]`` weighs :math:`x_{i+1}`); ``R``;
    ``W_y``, ``b_y``: the output map; ``unit_half``: the terminal box half-widths at
    :math:`\alpha_k = 1` (:class:`~ltv_lstm_mpc.mpc.terminal.TerminalSet`); ``H``, ``g0``,
    ``A``, ``lo0``, ``up0``, ``lb``, ``ub``: the QP before :math:`\delta x_0`; ``dX``, ``f``,
    ``lo``, ``up``: its feedback data; ``low``, ``high``: ``[lb; lo]`` and ``[ub; up]`` (the
    same memory); ``u_max``; ``diagonal``: the stage weights are diagonal.
    """,
    __name__,
)
CondensingWorkspaceType = getattr(CondensingWorkspace, "numba_type", None)


def new_condensing_workspace(**fields: Any) -> Any:
    """A :data:`CondensingWorkspace` from its fields by name (:data:`CONDENSING_FIELDS`)."""
    return build_workspace(_new_condensing_workspace, CONDENSING_FIELDS, fields)


@njit(cache=True)
def _new_condensing_workspace(  # type: ignore[no-untyped-def]
    J, S, M, Maug, Lt, Qs, R, W_y, b_y, unit_half, H, g0, A, lo0, up0, lb, ub, dX, f, lo, up,
    low, high, u_max, diagonal,
):  # fmt: skip
    """The compiled constructor (no constructor compile at run time; cached)."""
    return CondensingWorkspace(
        J, S, M, Maug, Lt, Qs, R, W_y, b_y, unit_half, H, g0, A, lo0, up0, lb, ub, dX, f, lo,
        up, low, high, u_max, diagonal,
    )  # fmt: skip


#: State size n from which condense's Gamma recursion uses BLAS products (loops below).
_BLAS_RECURSION_N = 10


@njit(cache=True)
def condense(
    workspace: Any,
    x_bar: Any,
    u_bar: Any,
    lower: Any,
    upper: Any,
    alpha: float,
    backward: bool,
) -> float:
    r"""The input part of the condensed QP (``CondensedTranscription.build``), in place.

    Input-to-state matrices by the recursion :math:`\Gamma_{i+1} = A_i \Gamma_i + B_i e_i`
    (only the causal columns; ``M[i][:, 2n:]``), then the Hessian ``H`` and gradient ``g0``
    :math:`H = \sum_i \Gamma_i^\top Q_i \Gamma_i + \mathrm{blkdiag}(R)`,
    :math:`g_0 = \sum_i \Gamma_i^\top Q_i (\tilde x_i - \bar x) + R(\tilde u - \bar u)`
    (``Qs[i]`` weighs :math:`x_{i+1}`, ``Lt[i]`` is its factor) in one of three ways with
    the same result (see :func:`_hessian_causal`, :func:`_hessian_gram`,
    :func:`_hessian_backward`), the tightened output
    rows i = 1..N-1 and the terminal box rows in :math:`\delta u`, and the input bounds
    around the candidate. The part in :math:`\delta x_0` (``F`` and ``E`` of the numpy
    build) is not formed: :func:`insert_state` propagates :math:`\delta x_0` at feedback
    time. Returns the violation scale :math:`1 + \max(u_{max}, |lo_0|, |up_0|)`.

    The state Jacobian of eq. (lstm) has diagonal :math:`\partial c^+/\partial c` and
    :math:`\partial h^+/\partial c` blocks (the gates do not depend on c), so the recursion
    takes two n x n products per stage instead of one 2n x 2n product (half the flops);
    ``diagonal`` says the stage weights are diagonal (diagonal Q); ``backward``: H and g0 by
    the backward recursion, else by rank updates on the causal columns (diagonal weights)
    or by the Gram matrix (full weights).
    """
    J, S, M, Maug, Lt = workspace.J, workspace.S, workspace.M, workspace.Maug, workspace.Lt
    Qs, R, W_y, b_y = workspace.Qs, workspace.R, workspace.W_y, workspace.b_y
    unit_half, u_max, diagonal = workspace.unit_half, workspace.u_max, workspace.diagonal
    H, g0, A, lo0, up0 = workspace.H, workspace.g0, workspace.A, workspace.lo0, workspace.up0
    lb, ub = workspace.lb, workspace.ub
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
            # rows r and n + r of M[i + 1] in passes over the columns that each take three
            # or two h-columns of A_i (fewer loads and stores of the target rows than one
            # pass per column: 0.75x the time at n = 5, N = 50); the rows are sliced to
            # the causal columns and indexed from 0, so that LLVM vectorizes the passes
            # (an index numba cannot prove nonnegative keeps a loop scalar; the sums per
            # entry are the same, so the values too: 0.5x the time at n = 5, N = 50)
            d_cc = J[i, r, r]
            d_hc = J[i, n + r, r]
            target_c = M[i + 1, r, n2:live]
            target_h = M[i + 1, n + r, n2:live]
            source_c = M[i, r, n2:live]
            width = live - n2
            q = 0
            if n >= 3:
                a0, a1, a2 = J[i, r, n], J[i, r, n + 1], J[i, r, n + 2]
                b0, b1, b2 = J[i, n + r, n], J[i, n + r, n + 1], J[i, n + r, n + 2]
                s0, s1, s2 = M[i, n, n2:live], M[i, n + 1, n2:live], M[i, n + 2, n2:live]
                for c in range(width):
                    x_c, x0, x1, x2 = source_c[c], s0[c], s1[c], s2[c]
                    target_c[c] = d_cc * x_c + a0 * x0 + a1 * x1 + a2 * x2
                    target_h[c] = d_hc * x_c + b0 * x0 + b1 * x1 + b2 * x2
                q = 3
            else:
                for c in range(width):
                    target_c[c] = d_cc * source_c[c]
                    target_h[c] = d_hc * source_c[c]
            while q + 1 < n:
                a0, a1 = J[i, r, n + q], J[i, r, n + q + 1]
                b0, b1 = J[i, n + r, n + q], J[i, n + r, n + q + 1]
                s0, s1 = M[i, n + q, n2:live], M[i, n + q + 1, n2:live]
                for c in range(width):
                    x0, x1 = s0[c], s1[c]
                    target_c[c] += a0 * x0 + a1 * x1
                    target_h[c] += b0 * x0 + b1 * x1
                q += 2
            if q < n:
                a0, b0 = J[i, r, n + q], J[i, n + r, n + q]
                s0 = M[i, n + q, n2:live]
                for c in range(width):
                    target_c[c] += a0 * s0[c]
                    target_h[c] += b0 * s0[c]
        for r in range(n2):
            for j in range(m):
                M[i + 1, r, live + j] = J[i, r, n2 + j]
            beyond = M[i + 1, r, live + m : cols]  # (sliced: see above)
            for c in range(beyond.shape[0]):
                beyond[c] = 0.0
    if backward:
        _hessian_backward(J, S, M, Qs, x_bar, H, g0, diagonal)
    elif diagonal:
        _hessian_causal(S, M, Qs, x_bar, H, g0)
    else:
        _hessian_gram(S, M, Maug, Lt, x_bar, H, g0)
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
            target = A[row, :nu]
            for c in range(nu):
                target[c] = 0.0
            for q in range(n):
                w = W_y[j, q]
                source = M[i, n + q, n2:cols]  # (sliced to index from 0: vectorized)
                for c in range(nu):
                    target[c] += w * source[c]
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


@njit(cache=True, fastmath=REDUCTIONS)
def _hessian_causal(S: Any, M: Any, Qs: Any, x_bar: Any, H: Any, g0: Any) -> None:
    r"""``H`` and ``g0`` (without R) of the condensed stage cost of eq. (optimization_cost)
    for diagonal stage weights, as rank updates on the causal columns only.

    Stage i adds :math:`\Gamma_{i+1}^\top Q_i \Gamma_{i+1}` and
    :math:`\Gamma_{i+1}^\top Q_i (\tilde x_{i+1} - \bar x)` to the first
    :math:`(i + 1) m` rows and columns (:math:`\Gamma_{i+1}` is zero beyond them), four
    rows of :math:`\Gamma_{i+1}` per pass over the rows of H. About
    :math:`\tfrac{2}{3} N^3 n m^2` products (whole causal blocks, so the loops vectorize),
    a third of the Gram matrix's, read from ``M`` in place: no weighted copy of
    the stack and no BLAS call (whose code and buffers a step runs cold). H is mirrored
    from its upper triangle, so it is exactly symmetric."""
    N, n2 = Qs.shape[0], Qs.shape[1]
    nu = H.shape[0]
    m = nu // N
    for a in range(nu):
        g0[a] = 0.0
        row = H[a]
        for c in range(nu):
            row[c] = 0.0
    for i in range(N):
        live = (i + 1) * m  # the causal columns of Gamma_{i+1}
        gamma = M[i + 1]
        r = 0
        while r < n2:
            if r + 4 <= n2:
                q0, q1, q2, q3 = (
                    Qs[i, r, r],
                    Qs[i, r + 1, r + 1],
                    Qs[i, r + 2, r + 2],
                    Qs[i, r + 3, r + 3],
                )
                s0, s1, s2, s3 = (
                    gamma[r, n2:],
                    gamma[r + 1, n2:],
                    gamma[r + 2, n2:],
                    gamma[r + 3, n2:],
                )
                d0 = q0 * (S[i + 1, r] - x_bar[r])
                d1 = q1 * (S[i + 1, r + 1] - x_bar[r + 1])
                d2 = q2 * (S[i + 1, r + 2] - x_bar[r + 2])
                d3 = q3 * (S[i + 1, r + 3] - x_bar[r + 3])
                for a in range(live):
                    w0, w1, w2, w3 = q0 * s0[a], q1 * s1[a], q2 * s2[a], q3 * s3[a]
                    target = H[a]
                    for c in range(live):  # whole rows from 0: the loop vectorizes
                        target[c] += w0 * s0[c] + w1 * s1[c] + w2 * s2[c] + w3 * s3[c]
                    g0[a] += d0 * s0[a] + d1 * s1[a] + d2 * s2[a] + d3 * s3[a]
                r += 4
            else:
                q0 = Qs[i, r, r]
                s0 = gamma[r, n2:]
                d0 = q0 * (S[i + 1, r] - x_bar[r])
                for a in range(live):
                    w0 = q0 * s0[a]
                    target = H[a]
                    for c in range(live):
                        target[c] += w0 * s0[c]
                    g0[a] += d0 * s0[a]
                r += 1
    for a in range(nu):
        for c in range(a):
            H[a, c] = H[c, a]


@njit(cache=True)
def _hessian_gram(S: Any, M: Any, Maug: Any, Lt: Any, x_bar: Any, H: Any, g0: Any) -> None:
    r"""``H`` and ``g0`` (without R) of the condensed stage cost of eq. (optimization_cost)
    for full stage weights as one Gram matrix: the weighted stack
    ``Maug[i] = [Lt_i \Gamma_{i+1}, Lt_i (\tilde x_{i+1} - \bar x)]`` (N, 2n, Nm + 1) and one
    BLAS product :math:`O(N^3 n m^2)`, the cheaper way for short horizons (diagonal weights:
    :func:`_hessian_causal`)."""
    N, n2 = Maug.shape[0], Maug.shape[1]
    nu = Maug.shape[2] - 1
    m = nu // N
    for i in range(N):
        live = (i + 1) * m
        for r in range(n2):  # Lt_i Gamma_{i+1} as row updates
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


@njit(cache=True, fastmath=REDUCTIONS)
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


@njit(cache=True, fastmath=REDUCTIONS)
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


@njit(cache=True, fastmath=REDUCTIONS)
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
    G = np.empty((n2, n2))
    K = np.empty((n, n2))
    V = np.empty((m, n2))
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
        # V_i^T = B_i^T W_{i+1} (W symmetric: contiguous rows), then row block i of H over
        # the causal columns j <= i, H[i, :] = V_i^T M[i + 1], mirrored into column block i
        for b in range(m):
            for c in range(n2):
                acc = 0.0
                for q in range(n2):
                    acc += J[i, q, n2 + b] * W[c, q]
                V[b, c] = acc
        live = (i + 1) * m
        for b in range(m):
            row = i * m + b
            target = H[row, :live]
            for c in range(live):
                target[c] = 0.0
            for r in range(n2):
                v = V[b, r]
                source = M[i + 1, r, n2 : n2 + live]  # (sliced to index from 0: vectorized)
                for c in range(live):
                    target[c] += v * source[c]
            for c in range(live):
                H[c, row] = H[row, c]
        for b in range(m):
            acc = 0.0
            for r in range(n2):
                acc += J[i, r, n2 + b] * s[r]
            g0[i * m + b] = acc
        if i == 0:
            break
        # W_i = Q_i + A_i^T W_{i+1} A_i with A_i = [[D_cc, K_c], [D_hc, K_h]] (D diagonal,
        # K = A_i's h-columns, copied transposed): G = A_i^T W_{i+1}, then the upper
        # triangle of G A_i (W is symmetric), mirrored; inner loops along contiguous rows
        for q in range(n):
            for t in range(n2):
                K[q, t] = J[i, t, n + q]
        for r in range(n):
            d_cc, d_hc = J[i, r, r], J[i, n + r, r]
            for c in range(n2):
                G[r, c] = d_cc * W[r, c] + d_hc * W[n + r, c]
        for q in range(n):
            for c in range(n2):
                acc = 0.0
                for t in range(n2):
                    acc += K[q, t] * W[c, t]
                G[n + q, c] = acc
        for r in range(n2):
            for q in range(r, n):
                W[r, q] = G[r, q] * J[i, q, q] + G[r, n + q] * J[i, n + q, q] + Qs[i - 1, r, q]
            for q in range(max(r - n, 0), n):
                acc = Qs[i - 1, r, n + q]
                for t in range(n2):
                    acc += G[r, t] * K[q, t]
                W[r, n + q] = acc
        for r in range(n2):
            for q in range(r):
                W[r, q] = W[q, r]
        # s_i = Q_i (x_i - x_bar) + A_i^T s_{i+1}
        _transpose_times(J, i, s, As)
        for q in range(n2):
            dev[q] = S[i, q] - x_bar[q]
        _weight_times(Qs, i - 1, dev, s, diagonal)
        for q in range(n2):
            s[q] += As[q]


@njit(cache=True, fastmath=REDUCTIONS)
def insert_state(workspace: Any, x_hat: Any) -> None:
    r"""Feedback data of the condensed QP for :math:`\delta x_0 = \hat x - \tilde x_0`.

    Propagates :math:`\delta x^0_{i+1} = A_i \delta x^0_i` into ``dX`` (N + 1, 2n), then
    :math:`f = g_0 + \sum_i \Gamma_i^\top Q_i \delta x^0_i` by the backward recursion
    :math:`s_N = Q_N \delta x^0_N`, :math:`s_i = Q_i \delta x^0_i + A_i^\top s_{i+1}`,
    :math:`f_i = g_{0,i} + B_i^\top s_{i+1}` (:math:`O(N n^2)`), and the rows
    :math:`lo_0 - W_y \delta h^0_i`, :math:`up_0 - W_y \delta h^0_i` (i = 1..N-1) and
    :math:`lo_0 - \delta x^0_N`, :math:`up_0 - \delta x^0_N` (terminal box). Both
    recursions use the diagonal blocks of the state Jacobian (see :func:`condense`);
    ``Qs[i]`` weighs :math:`x_{i+1}`, ``diagonal``: they are diagonal. Writes the
    workspace's ``dX``, ``f``, ``lo``, ``up``.
    """
    S, J, Qs, W_y, g0 = workspace.S, workspace.J, workspace.Qs, workspace.W_y, workspace.g0
    lo0, up0, dX, f = workspace.lo0, workspace.up0, workspace.dX, workspace.f
    lo, up, diagonal = workspace.lo, workspace.up, workspace.diagonal
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


@njit(cache=True, fastmath=REDUCTIONS)
def expand_point(workspace: Any, z: Any, rows: int, x_linear: Any, u: Any) -> float:
    r"""From the QP point ``z`` (its first ``N m`` entries :math:`\delta u`): the largest
    violation of ``low <= [z; A z] <= high`` over the first ``rows`` entries, the linearized
    states :math:`\tilde x_i + \delta x^0_i + \Gamma_i \delta u` into ``x_linear`` and the
    inputs :math:`\tilde u + \delta u` into ``u``."""
    A, low, high, M = workspace.A, workspace.low, workspace.high, workspace.M
    S, dX = workspace.S, workspace.dX
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


#: This module's compiled constructor: what compiles with it
#: (:func:`~ltv_lstm_mpc.mpc.kernels.compiled_kernels`).
CONSTRUCTORS = (_new_condensing_workspace,)
