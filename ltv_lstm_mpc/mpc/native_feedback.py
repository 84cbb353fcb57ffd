r"""The nominal feedback as one compiled call, DAQP inside (``RobustMPC.feedback``'s fast path).

:meth:`~ltv_lstm_mpc.mpc.rti.RobustMPC.feedback` on the condensed transcription does, for
the ``"nominal"`` problem: the pre-checks of :func:`~ltv_lstm_mpc.mpc.fhocp.precheck_status`,
the insertion of :math:`\delta x_0 = \hat x_k - \tilde x_0`
(:func:`~ltv_lstm_mpc.mpc.compiled_condensing.insert_state`), the QP solve, the expansion of
the point (:func:`~ltv_lstm_mpc.mpc.compiled_condensing.expand_point`), the core's acceptance
tests (finite, inputs in U within tolerance, rows within tolerance; clipping onto U), and
the re-simulation of the plan with its cost and residuals
(:func:`~ltv_lstm_mpc.mpc.compiled_plan.plan_metrics`).
With DAQP bound natively (:mod:`ltv_lstm_mpc.solvers.daqp_native`), :func:`nominal_feedback`
does all of it without returning to Python: the same compiled functions and the same C call
as ``daqp.solve`` with the same settings, so the same numbers as the general path (to a few
ulps: inlined here, the vectorized sums may group differently).

It only *accepts*: whenever a test is not passed with a margin (pre-check within
:data:`PRECHECK_MARGIN` of its tolerance, exit flag other than optimal, a non-finite or huge
entry, inputs outside U or rows beyond tolerance) it returns 0 and the general Python path
runs instead, from the start, with its reasons and fallbacks. Equality of both paths is
tested in ``tests/test_daqp_native.py``.
"""

from __future__ import annotations

from typing import Any

from numba import njit

from ltv_lstm_mpc.mpc.compiled_condensing import expand_point, insert_state
from ltv_lstm_mpc.mpc.compiled_plan import plan_metrics
from ltv_lstm_mpc.solvers.daqp_native import quadprog, solver_seconds

__all__ = ["PRECHECK_MARGIN", "nominal_feedback"]

#: The pre-check accepts ``y`` only within ``[lower - 1e-12, upper + 1e-12]`` shrunk by this
#: much (its sum runs in another order than the general path's, so ulps may differ there).
PRECHECK_MARGIN = 1e-13
_PRECHECK_TOL = 1e-12  # fhocp.precheck_status
_HUGE = 1e100  # entries beyond it go to the general path (its finiteness test sums them)


@njit(cache=True)
def nominal_feedback(
    x_hat: Any,
    W_y: Any,
    b_y: Any,
    lower: Any,
    upper: Any,
    alpha: float,
    scale: float,
    S: Any,
    J: Any,
    Qs: Any,
    g0: Any,
    lo0: Any,
    up0: Any,
    dX: Any,
    f: Any,
    low: Any,
    high: Any,
    diagonal: bool,
    H: Any,
    A: Any,
    M: Any,
    sense: Any,
    z: Any,
    lam: Any,
    problem: Any,
    result: Any,
    settings: Any,
    tolerance: float,
    u_max: float,
    WU: Any,
    P: Any,
    PT: Any,
    PTC: Any,
    x_bar: Any,
    u_bar: Any,
    Q: Any,
    R: Any,
    P_terms: Any,
    Q_diagonal: bool,
    x_linear: Any,
    u: Any,
    x_plan: Any,
    metrics: Any,
) -> tuple[int, int, float, float]:
    """Pre-check, insert, solve, expand, accept, re-simulate.

    Returns ``(code, iterations, sqp step, solver seconds)``: code 1 (optimal) or 2
    (optimal, inaccurate) when accepted, with the plan in ``u``/``x_linear``/``x_plan`` and
    ``metrics`` as :func:`plan_metrics` writes them; 0: not accepted here (general path).
    ``low``/``high`` are ``[lb; lo]`` and ``[ub; up]`` (DAQP's layout, simple bounds first),
    ``P``/``PT``/``PTC`` the plan trajectory's buffers, ``lower``/``upper`` the tightened
    output bounds (N, p).
    """
    n2 = x_linear.shape[1]
    n = n2 // 2
    p = W_y.shape[0]
    N, m = u.shape
    # ---- pre-check (fhocp.precheck_status), with a margin
    margin = _PRECHECK_TOL - PRECHECK_MARGIN
    for j in range(p):
        y = b_y[j]
        for q in range(n):
            y += W_y[j, q] * x_hat[n + q]
        if not lower[0, j] - margin <= y <= upper[0, j] + margin:
            return 0, 0, 0.0, 0.0
    if not alpha > 0.0:
        return 0, 0, 0.0, 0.0
    # ---- insert, solve, expand (CondensedTranscription.solve)
    nu = f.shape[0]
    insert_state(x_hat, S, J, Qs, W_y, g0, lo0, up0, dX, f, low[nu:], high[nu:], diagonal)
    flag, iterations = quadprog(H, f, A, high, low, sense, z, lam, problem, result, settings)
    seconds = solver_seconds(result)
    if flag != 1 and flag != 2:
        return 0, iterations, 0.0, seconds
    violation = expand_point(z, A, low, high, high.shape[0], M, S, dX, x_linear, u)
    # ---- acceptance (RobustMPC._checked_solve)
    for a in range(nu):
        if not abs(z[a]) < _HUGE:
            return 0, iterations, 0.0, seconds
    for i in range(N + 1):
        for q in range(n2):
            if not abs(x_linear[i, q]) < _HUGE:
                return 0, iterations, 0.0, seconds
    largest = 0.0
    for i in range(N):
        for a in range(m):
            largest = max(largest, abs(u[i, a]))
    outside = largest - u_max
    if outside > tolerance * (1.0 + u_max) or not max(violation, 0.0) / scale <= tolerance:
        return 0, iterations, 0.0, seconds
    step = 0.0
    for i in range(N):
        for a in range(m):
            if outside > 0.0:
                u[i, a] = min(max(u[i, a], -u_max), u_max)
            step = max(step, abs(u[i, a] - S[i, n2 + a]))
    # ---- the plan on the true LSTM (RobustMPC.feedback)
    for q in range(n2):
        P[0, q] = x_hat[q]
    for i in range(N):
        for a in range(m):
            P[i, n2 + a] = u[i, a]
    plan_metrics(
        WU, P, PT, PTC, W_y, b_y, x_bar, u_bar, Q, R, P_terms, lower, upper, x_linear, x_plan,
        metrics, Q_diagonal,
    )  # fmt: skip
    return flag, iterations, step, seconds
