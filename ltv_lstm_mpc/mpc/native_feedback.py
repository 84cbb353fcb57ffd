r"""The nominal feedback as one compiled call, DAQP inside (``RobustMPC.feedback``'s fast path).

:meth:`~ltv_lstm_mpc.RobustMPC.feedback` on the condensed transcription does, for
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

from ltv_lstm_mpc.mpc.compiled_condensing import expand_point, insert_state
from ltv_lstm_mpc.mpc.compiled_plan import plan_metrics
from ltv_lstm_mpc.numba_support import build_workspace, njit, workspace_type

# compiled code binds its callees when it compiles: the public entry points that the
# solver layer's compiled forms of daqp and daqp:socp hold (solvers.compiled_form)
from ltv_lstm_mpc.solvers.daqp_native import quadprog, solver_seconds
from ltv_lstm_mpc.solvers.socp_sqp import MAX_ITERATIONS, socp_solve

__all__ = [
    "CONSTRUCTORS",
    "DAQP_FIELDS",
    "PRECHECK_MARGIN",
    "DaqpWorkspace",
    "cone_feedback",
    "new_daqp_workspace",
    "nominal_feedback",
]

#: The pre-check accepts ``y`` only within ``[lower - 1e-12, upper + 1e-12]`` shrunk by this
#: much (its sum runs in another order than the general path's, so ulps may differ there).
PRECHECK_MARGIN = 1e-13
_PRECHECK_TOL = 1e-12  # fhocp.precheck_status
_HUGE = 1e100  # entries beyond it go to the general path (its finiteness test sums them)


#: Fields of :data:`DaqpWorkspace`, in the order of its compiled constructor.
DAQP_FIELDS = ("sense", "z", "lam", "problem", "result", "settings", "tolerance")

DaqpWorkspace = workspace_type(
    "DaqpWorkspace",
    DAQP_FIELDS,
    """DAQP's buffers for :func:`nominal_feedback`.

    ``sense`` (int32): the working set (cold: zeros); ``z``, ``lam``: the point and the
    multipliers; ``problem``, ``result``, ``settings``: the C structs of
    :class:`~ltv_lstm_mpc.solvers.daqp_native.DaqpNative`; ``tolerance``: the acceptance
    tolerance of the point (:func:`~ltv_lstm_mpc.solvers.feasibility_tolerance`).
    """,
    __name__,
)
DaqpWorkspaceType = getattr(DaqpWorkspace, "numba_type", None)


def new_daqp_workspace(**fields: Any) -> Any:
    """A :data:`DaqpWorkspace` from its fields by name (:data:`DAQP_FIELDS`)."""
    return build_workspace(_new_daqp_workspace, DAQP_FIELDS, fields)


@njit(cache=True)
def _new_daqp_workspace(sense, z, lam, problem, result, settings, tolerance):  # type: ignore[no-untyped-def]
    """The compiled constructor (no constructor compile at run time; cached)."""
    return DaqpWorkspace(sense, z, lam, problem, result, settings, tolerance)


@njit(cache=True)
def nominal_feedback(
    condensing: Any,
    daqp: Any,
    plan: Any,
    x_hat: Any,
    x_bar: Any,
    u_bar: Any,
    lower: Any,
    upper: Any,
    alpha: float,
    scale: float,
    x_linear: Any,
    u: Any,
    x_plan: Any,
) -> tuple[int, int, float, float]:
    """Pre-check, insert, solve, expand, accept, re-simulate.

    Returns ``(code, iterations, sqp step, solver seconds)``: code 1 (optimal) or 2
    (optimal, inaccurate) when accepted, with the plan in ``u``/``x_linear``/``x_plan`` and
    the metrics in ``plan.out`` as :func:`plan_metrics` writes them; 0: not accepted here
    (general path). ``condensing``: the transcription's
    :data:`~ltv_lstm_mpc.mpc.compiled_condensing.CondensingWorkspace` (its ``low``/``high``
    are ``[lb; lo]`` and ``[ub; up]``, DAQP's layout, simple bounds first); ``daqp``: a
    :data:`DaqpWorkspace`; ``plan``: the
    :data:`~ltv_lstm_mpc.mpc.compiled_plan.PlanWorkspace`; ``lower``/``upper``: the
    tightened output bounds (N, p).
    """
    W_y, b_y, H, A = condensing.W_y, condensing.b_y, condensing.H, condensing.A
    f, low, high, S, u_max = (
        condensing.f,
        condensing.low,
        condensing.high,
        condensing.S,
        condensing.u_max,
    )
    sense, z, lam, tolerance = daqp.sense, daqp.z, daqp.lam, daqp.tolerance
    problem, result, settings = daqp.problem, daqp.result, daqp.settings
    P = plan.S
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
    insert_state(condensing, x_hat)
    flag, iterations = quadprog(H, f, A, high, low, sense, z, lam, problem, result, settings)
    seconds = solver_seconds(result)
    if flag != 1 and flag != 2:
        return 0, iterations, 0.0, seconds
    violation = expand_point(condensing, z, high.shape[0], x_linear, u)
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
    plan_metrics(plan, x_bar, u_bar, lower, upper, x_linear, x_plan)
    return flag, iterations, step, seconds


@njit(cache=True)
def cone_feedback(
    condensing: Any,
    socp: Any,
    plan: Any,
    x_hat: Any,
    x_bar: Any,
    u_bar: Any,
    lower: Any,
    upper: Any,
    alpha: float,
    scale: float,
    tolerance: float,
    x_linear: Any,
    u: Any,
    x_plan: Any,
) -> tuple[int, int, float, float]:
    """:func:`nominal_feedback` with the exact terminal cones, by SQP on DAQP.

    The same pre-check, insertion, expansion, acceptance and re-simulation; the QP is the
    exact-cone problem of ``CondensedTranscription._cone_data`` (variables
    ``[du, t_c, t_h]``: the output rows, the bounds of ``du``, the cones
    :math:`\\|c_N - \\bar c\\| \\le t_c`, :math:`\\|h_N - \\bar h\\| \\le t_h`,
    :math:`\\|P_f^{1/2} t\\| \\le \\alpha_k`) written into ``socp`` (a
    :data:`~ltv_lstm_mpc.solvers.socp_sqp.SocpWorkspace` whose constant parts the
    transcription wrote once) and solved by
    :func:`~ltv_lstm_mpc.solvers.socp_sqp.socp_solve` from a cold start, as the general
    path's ``daqp:socp`` session does. Returns ``(code, DAQP iterations, sqp step, DAQP's
    time)``; code 0: not accepted here (the general path runs). ``tolerance``: the
    acceptance tolerance of the point (the transcription's).
    """
    W_y, b_y, A = condensing.W_y, condensing.b_y, condensing.A
    H, f, lo, up = condensing.H, condensing.f, condensing.lo, condensing.up
    S, u_max = condensing.S, condensing.u_max
    P = plan.S
    n2 = x_linear.shape[1]
    n = n2 // 2
    p = W_y.shape[0]
    N, m = u.shape
    nu = N * m
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
    # ---- insert, then the exact-cone QP (CondensedTranscription._cone_data)
    insert_state(condensing, x_hat)
    ns = socp.A.shape[0]
    for a in range(nu):
        for b in range(nu):
            socp.H[a, b] = H[a, b]
        socp.f[a] = f[a]
        socp.lb[a] = condensing.lb[a]
        socp.ub[a] = condensing.ub[a]
    for row in range(ns):
        for b in range(nu):
            socp.A[row, b] = A[row, b]
        socp.lo[row] = lo[row]
        socp.up[row] = up[row]
    for r in range(n2):  # cone rows: c_N - c_bar, then h_N - h_bar
        for b in range(nu):
            socp.F[r, b] = A[ns + r, b]
        socp.g[r] = -0.5 * (lo[ns + r] + up[ns + r])
    socp.offsets[2] = alpha
    flag, sqp, iterations, violation, seconds = socp_solve(socp, False, MAX_ITERATIONS)
    if (flag != 1 and flag != 2) or sqp > MAX_ITERATIONS:
        return 0, iterations, 0.0, seconds
    z = socp.z
    rows = nu + ns
    violation_rows = expand_point(condensing, z, rows, x_linear, u)
    violation = max(violation_rows, violation)
    # ---- acceptance (RobustMPC._checked_solve)
    for a in range(z.shape[0]):
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
    plan_metrics(plan, x_bar, u_bar, lower, upper, x_linear, x_plan)
    return flag, iterations, step, seconds


#: This module's compiled constructors (the compiled workspace constructor): what compiles with it
#: (:func:`~ltv_lstm_mpc.loop.kernels.controller_kernels`).
CONSTRUCTORS = (_new_daqp_workspace,)
