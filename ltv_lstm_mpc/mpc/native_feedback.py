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

:func:`policy_feedback` (the one-call step engine's feedback on DAQP) goes further: where
the pre-check fails by more than the margin or DAQP finds no solution of the nominal QP,
it runs the configured infeasibility policy as ``RobustMPC.feedback`` does (``"paper"``,
``"soft"``, ``"shift"``, then ``"<policy>+shift"``), on the same QPs with the same DAQP
call, and records the status and policy by code (:data:`POLICIES`,
:func:`feedback_outcome`); it hands over only a point within a margin of a test or an
outcome the general path words itself (tested to 1e-12 over closed loops in
``tests/test_one_call_step.py``).
"""

from __future__ import annotations

from typing import Any

import numpy as np

from ltv_lstm_mpc.mpc.compiled_condensing import expand_point, insert_state
from ltv_lstm_mpc.mpc.compiled_plan import plan_metrics
from ltv_lstm_mpc.mpc.fhocp import PRECHECK_TOL
from ltv_lstm_mpc.numba_support import build_workspace, njit, workspace_type

# compiled code binds its callees when it compiles: the public entry points that the
# solver layer's compiled forms of daqp and daqp:socp hold (solvers.compiled_form)
from ltv_lstm_mpc.solvers.daqp_native import (
    KEEP_FROM,
    NO_BOUND,
    WORKSPACE_BYTES,
    activity_infeasible,
    box_quadprog_from,
    primal_tolerance,
    quadprog,
    quadprog_kept,
    set_objective_bound,
    solver_seconds,
)
from ltv_lstm_mpc.solvers.dense import bounds_rows_violation, cone_violation
from ltv_lstm_mpc.solvers.socp_sqp import (
    MAX_ITERATIONS,
    new_socp_workspace_kernel,
    snapshot_into,
    socp_solve,
)

__all__ = [
    "CONSTRUCTORS",
    "DAQP_FIELDS",
    "FALLBACK_FIELDS",
    "FEEDBACK_POLICY",
    "POLICIES",
    "PRECHECK_MARGIN",
    "DaqpWorkspace",
    "FallbackWorkspace",
    "cone_feedback",
    "cone_policy_feedback",
    "feedback_outcome",
    "new_daqp_workspace",
    "new_fallback_workspace",
    "new_fallback_workspace_kernel",
    "nominal_feedback",
    "placeholder_socp",
    "policy_feedback",
]

#: The pre-check accepts ``y`` only within ``[lower - 1e-12, upper + 1e-12]`` shrunk by this
#: much (its sum runs in another order than the general path's, so ulps may differ there).
PRECHECK_MARGIN = 1e-13
#: Entries beyond it go to the general path (its finiteness test sums them).
HUGE_ENTRY = 1e100
_PRECHECK_TOL, _HUGE = PRECHECK_TOL, HUGE_ENTRY

#: ``MPCSolution.policy`` of each policy code (``fallback.codes[POLICY_CODE]``): a policy
#: whose QP gives no accepted point is ``SHIFT_AFTER`` further ("<policy>+shift").
POLICIES = ("nominal", "paper", "soft", "shift", "paper+shift", "soft+shift")
POLICY_NOMINAL, POLICY_PAPER, POLICY_SOFT, POLICY_SHIFT = 0, 1, 2, 3
SHIFT_AFTER = 3
#: :func:`policy_feedback`'s code of a plan from the infeasibility policy.
FEEDBACK_POLICY = 3
#: Entries of ``fallback.codes``: the status code (1, 2: the nominal QP, optimal or
#: inaccurate; DAQP's exit flag -1..-6 where it found no solution;
#: ``STATUS_INFEASIBLE_INITIAL``, ``STATUS_ALPHA_NONPOSITIVE``: the pre-check), the policy
#: code, and the SQP iterations of the plan (1 with a linearized plan, else 0).
STATUS_CODE, POLICY_CODE, PLAN_ITERATIONS, FAILURE_FLAG, FAILURE_SQP = 0, 1, 2, 3, 4
STATUS_INFEASIBLE_INITIAL, STATUS_ALPHA_NONPOSITIVE = -100, -101
#: The status code of a failed exact-cone solve (:func:`cone_policy_feedback`).
STATUS_CONE_FAILURE = -200
PRECHECK_PASSED, PRECHECK_UNDECIDED = 1, 0
_MIN_FAILURE_FLAG = -6  # DAQP's exit flags -1 .. -6 (solvers/daqp_.py STATUS_MAP)
#: Verdicts of :func:`_accept`.
ACCEPTED, REJECTED, UNDECIDED = 1, 0, -1


def feedback_outcome(code: int, flag_outcome: Any) -> tuple[str, str]:
    """The status and reason ``RobustMPC.feedback`` reports for a status code of
    ``fallback.codes`` (``flag_outcome``: the solver's
    ``flag_outcome`` of :class:`~ltv_lstm_mpc.solvers.CompiledForm`)."""
    if code == 1:
        return "optimal", ""
    if code == 2:
        return "optimal_inaccurate", ""
    if code == STATUS_INFEASIBLE_INITIAL:
        return "infeasible_initial", "infeasible_initial"
    if code == STATUS_ALPHA_NONPOSITIVE:
        return "alpha_nonpositive", "alpha_nonpositive"
    status, info = flag_outcome(code)
    return status.name.lower(), info


#: Fields of :data:`FallbackWorkspace`, in the order of its compiled constructor.
FALLBACK_FIELDS = (
    "policy", "ns", "H", "f", "A", "high", "low", "sense", "z", "lam", "regularization",
    "codes", "socp", "policy_socp", "snapshot", "snapshot_int",
)  # fmt: skip

FallbackWorkspace = workspace_type(
    "FallbackWorkspace",
    FALLBACK_FIELDS,
    """The infeasibility policy of :func:`policy_feedback` and its QP's buffers.

    ``policy``: :data:`POLICY_PAPER`, :data:`POLICY_SOFT` or :data:`POLICY_SHIFT`;
    ``ns``: the output rows (N - 1) p; ``H``, ``f``, ``A``, ``high`` (``[ub; up]``),
    ``low`` (``[lb; lo]``): the soft QP (variables ``[du; s; s_T]``, its constant blocks
    written once; empty for the other policies); ``sense`` (int32, cold: zeros), ``z``,
    ``lam``: DAQP's working set, point and multipliers (the paper QP uses their first
    N m entries); ``regularization``: the slacks' quadratic weight relative to max diag H;
    ``codes`` (int64, 5): the outcome (:data:`STATUS_CODE`, :data:`POLICY_CODE`,
    :data:`PLAN_ITERATIONS`; a failed exact-cone solve's :data:`FAILURE_FLAG` and
    :data:`FAILURE_SQP`). With the exact cones of ``daqp:socp``
    (:func:`cone_policy_feedback`): ``socp`` and ``policy_socp``, the
    :data:`~ltv_lstm_mpc.solvers.socp_sqp.SocpWorkspace` of the general path's sessions of
    the nominal problem and of the policy's (placeholders otherwise:
    :func:`placeholder_socp`), and ``snapshot``, ``snapshot_int``: where the nominal SQP
    fails, the copy of ``socp`` that its status is read from
    (:func:`~ltv_lstm_mpc.solvers.socp_sqp.snapshot_into`; empty otherwise).
    """,
    __name__,
)
FallbackWorkspaceType = getattr(FallbackWorkspace, "numba_type", None)


def new_fallback_workspace(**fields: Any) -> Any:
    """A :data:`FallbackWorkspace` from its fields by name (:data:`FALLBACK_FIELDS`)."""
    return build_workspace(_new_fallback_workspace, FALLBACK_FIELDS, fields)


def placeholder_socp() -> Any:
    """A :data:`~ltv_lstm_mpc.solvers.socp_sqp.SocpWorkspace` that is never solved with
    (where a workspace's field of that type is unused: a QP controller's)."""
    from types import SimpleNamespace

    from ltv_lstm_mpc.solvers.socp_sqp import new_socp_workspace, socp_arrays

    empty = np.zeros(8, dtype=np.uint8)
    buffers = SimpleNamespace(problem=empty, result=empty.copy(), settings=empty.copy())
    return new_socp_workspace(**socp_arrays(1, 0, [], buffers))


@njit(cache=True)
def _new_fallback_workspace(  # type: ignore[no-untyped-def]
    policy, ns, H, f, A, high, low, sense, z, lam, regularization, codes, socp, policy_socp,
    snapshot, snapshot_int,
):  # fmt: skip
    """The compiled constructor (no constructor compile at run time; cached)."""
    return FallbackWorkspace(
        policy, ns, H, f, A, high, low, sense, z, lam, regularization, codes, socp,
        policy_socp, snapshot, snapshot_int,
    )  # fmt: skip


#: The compiled constructor of :data:`FallbackWorkspace` (for the kernel lists).
new_fallback_workspace_kernel = _new_fallback_workspace


#: Fields of :data:`DaqpWorkspace`, in the order of its compiled constructor.
DAQP_FIELDS = (
    "sense", "z", "lam", "problem", "result", "settings", "work", "tolerance",
    "hessian_floor", "fval_bound",
)  # fmt: skip

DaqpWorkspace = workspace_type(
    "DaqpWorkspace",
    DAQP_FIELDS,
    """DAQP's buffers for :func:`nominal_feedback`.

    ``sense`` (int32): the working set (cold: zeros); ``z``, ``lam``: the point and the
    multipliers; ``problem``, ``result``, ``settings``: the C structs of
    :class:`~ltv_lstm_mpc.solvers.daqp_native.DaqpNative`; ``work``: its ``DAQPWorkspace``,
    kept from a nominal QP DAQP proved infeasible for the ``"paper"`` QP (the same H:
    :func:`~ltv_lstm_mpc.solvers.daqp_native.box_quadprog_from`; no bytes: never
    kept); ``tolerance``: the acceptance
    tolerance of the point (:func:`~ltv_lstm_mpc.solvers.feasibility_tolerance`);
    ``hessian_floor``: the QPs' (``CondensedTranscription.hessian_floor``), from which each
    DAQP call's objective bound is written into ``settings``
    (:func:`~ltv_lstm_mpc.solvers.daqp_native.set_objective_bound`), no larger than
    ``fval_bound``: the settings' own (DAQP's ``NO_BOUND`` unless they name one).
    """,
    __name__,
)
DaqpWorkspaceType = getattr(DaqpWorkspace, "numba_type", None)


def new_daqp_workspace(**fields: Any) -> Any:
    """A :data:`DaqpWorkspace` from its fields by name (:data:`DAQP_FIELDS`)."""
    return build_workspace(_new_daqp_workspace, DAQP_FIELDS, fields)


@njit(cache=True)
def _new_daqp_workspace(  # type: ignore[no-untyped-def]
    sense, z, lam, problem, result, settings, work, tolerance, hessian_floor, fval_bound
):
    """The compiled constructor (no constructor compile at run time; cached)."""
    return DaqpWorkspace(
        sense, z, lam, problem, result, settings, work, tolerance, hessian_floor, fval_bound
    )


@njit(cache=True)
def _precheck(W_y: Any, b_y: Any, x_hat: Any, lower: Any, upper: Any, alpha: float) -> int:
    """:func:`~ltv_lstm_mpc.mpc.fhocp.precheck_status`, decided only away from its
    tolerance: :data:`PRECHECK_PASSED` (the i = 0 output row holds within
    :data:`PRECHECK_MARGIN` inside its tolerance and :math:`\\alpha_k > 0`),
    :data:`STATUS_INFEASIBLE_INITIAL` (a row fails by more than the margin beyond it),
    :data:`STATUS_ALPHA_NONPOSITIVE`, or :data:`PRECHECK_UNDECIDED` (a row within the
    margin of its tolerance, or not finite: the general path decides; its sum runs in
    another order, so ulps may differ there)."""
    n = x_hat.shape[0] // 2
    inner = _PRECHECK_TOL - PRECHECK_MARGIN
    outer = _PRECHECK_TOL + PRECHECK_MARGIN
    undecided = False
    for j in range(W_y.shape[0]):
        y = b_y[j]
        for q in range(n):
            y += W_y[j, q] * x_hat[n + q]
        if y < lower[0, j] - outer or y > upper[0, j] + outer:
            return STATUS_INFEASIBLE_INITIAL
        if not lower[0, j] - inner <= y <= upper[0, j] + inner:
            undecided = True
    if undecided:
        return PRECHECK_UNDECIDED
    if not alpha > 0.0:
        return STATUS_ALPHA_NONPOSITIVE
    return PRECHECK_PASSED


@njit(cache=True)
def _accept(
    z: Any,
    x_linear: Any,
    u: Any,
    S: Any,
    violation: float,
    tolerance: float,
    scale: float,
    u_max: float,
) -> tuple[int, float]:
    """``RobustMPC._checked_solve``'s tests of an expanded point (finite; inputs in U
    within the tolerance; the scaled violation within it), then the inputs clipped onto U.
    Returns ``(verdict, sqp step)``: :data:`ACCEPTED` (the step: the largest change from
    the candidate, the inputs of ``S``), :data:`REJECTED` (by the tolerance tests, as the
    general path rejects it) or :data:`UNDECIDED` (an entry of ``z`` or ``x_linear`` beyond
    1e100 or not finite: the general path's finiteness test sums them)."""
    for a in range(z.shape[0]):
        if not abs(z[a]) < _HUGE:
            return UNDECIDED, 0.0
    N1, n2 = x_linear.shape
    for i in range(N1):
        for q in range(n2):
            if not abs(x_linear[i, q]) < _HUGE:
                return UNDECIDED, 0.0
    N, m = u.shape
    largest = 0.0
    for i in range(N):
        for a in range(m):
            largest = max(largest, abs(u[i, a]))
    outside = largest - u_max
    if outside > tolerance * (1.0 + u_max) or not max(violation, 0.0) / scale <= tolerance:
        return REJECTED, 0.0
    step = 0.0
    for i in range(N):
        for a in range(m):
            if outside > 0.0:
                u[i, a] = min(max(u[i, a], -u_max), u_max)
            step = max(step, abs(u[i, a] - S[i, n2 + a]))
    return ACCEPTED, step


@njit(cache=True)
def _simulate_plan(
    plan: Any,
    x_hat: Any,
    x_bar: Any,
    u_bar: Any,
    lower: Any,
    upper: Any,
    x_linear: Any,
    u: Any,
    x_plan: Any,
) -> None:
    """The plan ``u`` from :math:`\\hat x_k` on the true LSTM, its cost and residuals
    (``RobustMPC.feedback``; ``x_linear`` with no rows: no linearized plan)."""
    P = plan.S
    n2 = x_hat.shape[0]
    N, m = u.shape
    for q in range(n2):
        P[0, q] = x_hat[q]
    for i in range(N):
        for a in range(m):
            P[i, n2 + a] = u[i, a]
    plan_metrics(plan, x_bar, u_bar, lower, upper, x_linear, x_plan)


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
    if _precheck(condensing.W_y, condensing.b_y, x_hat, lower, upper, alpha) != PRECHECK_PASSED:
        return 0, 0, 0.0, 0.0
    insert_state(condensing, x_hat)
    flag, iterations, seconds, _ = _solve_nominal(condensing, daqp, False)
    if flag != 1 and flag != 2:
        return 0, iterations, 0.0, seconds
    high = condensing.high
    violation = expand_point(condensing, daqp.z, high.shape[0], x_linear, u)
    verdict, step = _accept(
        daqp.z, x_linear, u, condensing.S, violation, daqp.tolerance, scale, condensing.u_max
    )
    if verdict != ACCEPTED:
        return 0, iterations, 0.0, seconds
    _simulate_plan(plan, x_hat, x_bar, u_bar, lower, upper, x_linear, u, x_plan)
    return flag, iterations, step, seconds


@njit(cache=True)
def _solve_nominal(condensing: Any, daqp: Any, keep: bool) -> tuple[int, int, float, bool]:
    """DAQP on the nominal condensed QP (state inserted), cold (:func:`_solve_qp`)."""
    return _solve_qp(
        daqp, condensing.H, condensing.f, condensing.A, condensing.high, condensing.low,
        daqp.sense, daqp.z, daqp.lam, keep,
    )  # fmt: skip


@njit(cache=True)
def _solve_qp(
    daqp: Any, H: Any, f: Any, A: Any, high: Any, low: Any, sense: Any, z: Any, lam: Any,
    keep: bool,
) -> tuple[int, int, float, bool]:  # fmt: skip
    """DAQP, cold, on one of the MPC's QPs (DAQP's layout: the variables' bounds first),
    with the objective bound of its box: ``(flag, iterations, DAQP's seconds, kept)``; -1,
    no iteration, where a row's activity bounds prove the QP infeasible without DAQP
    (:func:`~ltv_lstm_mpc.solvers.daqp_native.activity_infeasible`). ``keep``: where DAQP
    proves the QP infeasible, keep its workspace in ``daqp.work`` for :func:`_solve_paper`
    (``kept``), where DAQP factored H unregularized (a finite objective bound) and H has
    at least :data:`~ltv_lstm_mpc.solvers.daqp_native.KEEP_FROM` rows (below, factoring
    H again is cheaper than a kept workspace's cost where the paper QP's unconstrained
    optimum holds)."""
    n = H.shape[0]
    if activity_infeasible(A, low, high, primal_tolerance(daqp.settings)):
        return -1, 0, 0.0, False
    bound = set_objective_bound(
        daqp.settings, H, f, low[:n], high[:n], daqp.hessian_floor, daqp.fval_bound
    )
    kept = False
    if keep and n >= KEEP_FROM and bound < NO_BOUND and daqp.work.shape[0] >= WORKSPACE_BYTES:
        flag, iterations, kept = quadprog_kept(
            H, f, A, high, low, sense, z, lam, daqp.problem, daqp.result, daqp.settings,
            daqp.work, True,
        )  # fmt: skip
    else:
        flag, iterations = quadprog(
            H, f, A, high, low, sense, z, lam, daqp.problem, daqp.result, daqp.settings
        )
    return flag, iterations, solver_seconds(daqp.result), kept


@njit(cache=True)
def _solve_paper(condensing: Any, daqp: Any, fallback: Any, kept: bool) -> tuple[int, int, float]:
    """The ``"paper"`` policy's QP (no output and terminal rows, paper Fig. 5) into
    ``fallback.z``: :func:`_solve_qp`, or, where the nominal QP's workspace was ``kept``
    (the same H and f, its bounds on the variables), on that workspace
    (:func:`~ltv_lstm_mpc.solvers.daqp_native.box_quadprog_from`: the same bits, H not
    factored again). ``(flag, iterations, DAQP's seconds)``."""
    H, f = condensing.H, condensing.f
    nu = H.shape[0]
    high, low = condensing.high[:nu], condensing.low[:nu]
    z, lam, sense = fallback.z[:nu], fallback.lam[:nu], fallback.sense[:nu]
    if not kept:
        flag, iterations, seconds, _ = _solve_qp(
            daqp, H, f, condensing.A[:0], high, low, sense, z, lam, False
        )
        return flag, iterations, seconds
    # (the settings hold the nominal QP's objective bound: the same H, f and box)
    flag, iterations = box_quadprog_from(
        daqp.work, H, f, condensing.A[:0], high, low, sense, z, lam, daqp.problem,
        daqp.result, daqp.settings,
    )  # fmt: skip
    return flag, iterations, solver_seconds(daqp.result)


@njit(cache=True)
def _write_soft_qp(condensing: Any, fallback: Any) -> None:
    """The ``"soft"`` QP of ``CondensedTranscription._data`` into ``fallback`` (the
    constant blocks were written once): H with the slacks' regularization, f with their
    penalty, the rows ``[A_out, I, 0]``, ``[A_out, -I, 0]``, ``[A_T, 0, unit]``,
    ``[A_T, 0, -unit]`` and their bounds, the bounds of ``[du; s; s_T]``."""
    H, A, f = condensing.H, condensing.A, condensing.f
    low, high = condensing.low, condensing.high
    nu = H.shape[0]
    ns = fallback.ns
    n2 = A.shape[0] - ns
    nz = nu + ns + 1
    Hs, As, fs = fallback.H, fallback.A, fallback.f
    largest = H[0, 0]
    for a in range(1, nu):
        largest = max(largest, H[a, a])
    reg = fallback.regularization * largest
    for a in range(nu):
        for b in range(nu):
            Hs[a, b] = H[a, b]
        fs[a] = f[a]
    for s in range(nu, nz):
        Hs[s, s] = reg
    lows, highs = fallback.low, fallback.high  # [lb_s; lo_s], [ub_s; up_s]
    for a in range(nu):
        lows[a] = low[a]
        highs[a] = high[a]
    for r in range(ns):
        for b in range(nu):
            As[r, b] = A[r, b]
            As[ns + r, b] = A[r, b]
        lows[nz + r] = low[nu + r]
        highs[nz + ns + r] = high[nu + r]
    for r in range(n2):
        for b in range(nu):
            As[2 * ns + r, b] = A[ns + r, b]
            As[2 * ns + n2 + r, b] = A[ns + r, b]
        lows[nz + 2 * ns + r] = low[nu + ns + r]
        highs[nz + 2 * ns + n2 + r] = high[nu + ns + r]


@njit(cache=True)
def _policy_plan(
    condensing: Any, fallback: Any, plan: Any, x_hat: Any, x_bar: Any, u_bar: Any,
    lower: Any, upper: Any, x_linear: Any, u: Any, x_plan: Any, linear: bool, status: int,
    policy: int,
) -> None:  # fmt: skip
    """The plan of an infeasibility policy (``RobustMPC.feedback``): without a linearized
    plan (``linear`` False: ``"shift"``, ``"<policy>+shift"``) the candidate of Theorem 3,
    Part 2b (the inputs of the condensing's trajectory) and NaN linearized states; then
    its re-simulation and the outcome in ``fallback.codes``."""
    if not linear:
        S = condensing.S
        N, m = u.shape
        n2 = x_hat.shape[0]
        for i in range(N):
            for a in range(m):
                u[i, a] = S[i, n2 + a]
    _simulate_plan(
        plan, x_hat, x_bar, u_bar, lower, upper, x_linear if linear else x_linear[:0], u, x_plan
    )
    if not linear:
        x_linear[:] = np.nan
    codes = fallback.codes
    codes[STATUS_CODE], codes[POLICY_CODE] = status, policy
    codes[PLAN_ITERATIONS] = 1 if linear else 0


@njit(cache=True)
def policy_feedback(
    condensing: Any,
    daqp: Any,
    fallback: Any,
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
    """``RobustMPC.feedback`` with one SQP iteration, every path of it: the nominal QP as
    :func:`nominal_feedback`, and where the pre-check fails or DAQP finds no solution, the
    infeasibility policy of ``fallback`` (a :data:`FallbackWorkspace`): ``"paper"`` (the
    QP without output and terminal rows, paper Fig. 5), ``"soft"`` (the exact-penalty
    slacks of ``CondensedTranscription._data``) or ``"shift"`` (the candidate), and
    ``"<policy>+shift"`` where the policy's QP gives no accepted point.

    Returns ``(code, iterations, sqp step, solver seconds)``: code 1 or 2 (the nominal QP,
    optimal or inaccurate), :data:`FEEDBACK_POLICY` (a policy's plan: its status code,
    policy code and SQP iterations in ``fallback.codes``, :data:`STATUS_CODE`,
    :data:`POLICY_CODE`, :data:`PLAN_ITERATIONS`), or 0: a point within a margin of a
    test, or a failure the general path reports in words of its own (a non-finite or
    rejected nominal point, an unknown exit flag): the general path runs. Arguments as
    for :func:`nominal_feedback`.
    """
    codes = fallback.codes
    status = _precheck(condensing.W_y, condensing.b_y, x_hat, lower, upper, alpha)
    if status == PRECHECK_UNDECIDED:
        return 0, 0, 0.0, 0.0
    insert_state(condensing, x_hat)
    iterations, seconds = 0, 0.0
    policy = fallback.policy
    kept = False  # (the nominal QP's workspace, for the paper QP: _solve_paper frees it)
    if status == PRECHECK_PASSED:
        flag, iterations, seconds, kept = _solve_nominal(condensing, daqp, policy == POLICY_PAPER)
        if flag == 1 or flag == 2:
            high = condensing.high
            violation = expand_point(condensing, daqp.z, high.shape[0], x_linear, u)
            verdict, step = _accept(
                daqp.z, x_linear, u, condensing.S, violation, daqp.tolerance, scale,
                condensing.u_max,
            )  # fmt: skip
            if verdict != ACCEPTED:  # the general path words its rejection
                return 0, iterations, 0.0, seconds
            _simulate_plan(plan, x_hat, x_bar, u_bar, lower, upper, x_linear, u, x_plan)
            codes[STATUS_CODE], codes[POLICY_CODE], codes[PLAN_ITERATIONS] = flag, POLICY_NOMINAL, 1
            return flag, iterations, step, seconds
        if not _MIN_FAILURE_FLAG <= flag <= -1:  # an unknown flag: the session's words
            return 0, iterations, 0.0, seconds  # (never kept: kept only at -1)
        status = flag
    linear = False
    step = 0.0
    nu = condensing.H.shape[0]
    if policy == POLICY_PAPER or policy == POLICY_SOFT:
        z = fallback.z
        if policy == POLICY_PAPER:  # no output and terminal rows (paper, Fig. 5)
            flag, more, spent = _solve_paper(condensing, daqp, fallback, kept)
        else:  # (the objective bound its own: the slacks are unbounded above)
            _write_soft_qp(condensing, fallback)
            flag, more, spent, _ = _solve_qp(
                daqp, fallback.H, fallback.f, fallback.A, fallback.high, fallback.low,
                fallback.sense, z, fallback.lam, False,
            )  # fmt: skip
        iterations += more
        seconds += spent
        finite = True
        size = nu if policy == POLICY_PAPER else z.shape[0]
        for a in range(size):
            if not np.isfinite(z[a]):
                finite = False
        if (flag == 1 or flag == 2) and finite:
            violation = expand_point(condensing, z, nu, x_linear, u)
            if policy == POLICY_SOFT:  # the soft QP's own rows and bounds
                nz = z.shape[0]
                violation = bounds_rows_violation(
                    z, fallback.low[:nz], fallback.high[:nz], fallback.A, fallback.low[nz:],
                    fallback.high[nz:],
                )  # fmt: skip
            verdict, step = _accept(
                z[:size], x_linear, u, condensing.S, violation, daqp.tolerance, scale,
                condensing.u_max,
            )  # fmt: skip
            if verdict == UNDECIDED:
                return 0, iterations, 0.0, seconds
            linear = verdict == ACCEPTED
        if not linear:
            policy += SHIFT_AFTER
    if not linear:
        step = 0.0
    _policy_plan(
        condensing, fallback, plan, x_hat, x_bar, u_bar, lower, upper, x_linear, u, x_plan,
        linear, status, policy,
    )  # fmt: skip
    return FEEDBACK_POLICY, iterations, step, seconds


@njit(cache=True)
def _write_cone_nominal(condensing: Any, socp: Any, alpha: float) -> None:
    """The nominal exact-cone QP of ``CondensedTranscription._cone_data`` into ``socp``
    (the condensed values; the constant parts were written once): H, f and the bounds of
    ``du``, the output rows, the cones' rows on ``du`` (:math:`c_N - \\bar c`, then
    :math:`h_N - \\bar h`) and :math:`\\alpha_k`."""
    A, H, f, lo, up = condensing.A, condensing.H, condensing.f, condensing.lo, condensing.up
    nu = H.shape[0]
    ns = socp.A.shape[0]
    n2 = A.shape[0] - ns
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


@njit(cache=True)
def _write_cone_policy(condensing: Any, policy: Any, soft: bool, alpha: float, reg: float) -> None:
    """The infeasibility policy's exact-cone QP of ``CondensedTranscription._cone_data``
    into ``policy`` (its constant parts written once): ``"paper"`` (no output rows, no
    terminal cone) or ``"soft"`` (the output rows twice with their slacks, the terminal
    cone's level :math:`\\alpha_k + s_T`, the slacks' regularization ``reg`` relative to
    max diag H)."""
    A, H, f, lo, up = condensing.A, condensing.H, condensing.f, condensing.lo, condensing.up
    nu = H.shape[0]
    nz = policy.H.shape[0]
    ns = condensing.A.shape[0] - policy.F.shape[0] + (2 if soft else 0)
    n2 = A.shape[0] - ns
    for a in range(nu):
        for b in range(nu):
            policy.H[a, b] = H[a, b]
        policy.f[a] = f[a]
        policy.lb[a] = condensing.lb[a]
        policy.ub[a] = condensing.ub[a]
    if soft:
        largest = H[0, 0]
        for a in range(1, nu):
            largest = max(largest, H[a, a])
        for q in range(nu + 2, nz):
            policy.H[q, q] = reg * largest
        for row in range(ns):
            for b in range(nu):
                policy.A[row, b] = A[row, b]
                policy.A[ns + row, b] = A[row, b]
            policy.lo[row] = lo[row]
            policy.up[ns + row] = up[row]
        policy.offsets[2] = alpha
    for r in range(n2):  # cone rows: c_N - c_bar, then h_N - h_bar
        for b in range(nu):
            policy.F[r, b] = A[ns + r, b]
        policy.g[r] = -0.5 * (lo[ns + r] + up[ns + r])


@njit(cache=True)
def _cone_qp_violation(socp: Any, z: Any) -> float:
    """``DenseQP.max_violation`` of the exact-cone QP in ``socp`` at ``z``: its bounds,
    rows and cones."""
    violation = bounds_rows_violation(z, socp.lb, socp.ub, socp.A, socp.lo, socp.up)
    rows = socp.cone_rows
    for j in range(socp.offsets.shape[0]):
        start, stop = rows[j], rows[j + 1]
        violation = max(
            violation,
            cone_violation(socp.F[start:stop], socp.g[start:stop], socp.e[j], socp.offsets[j], z),
        )
    return violation


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
) -> tuple[int, int, float, float, int, int]:
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
    time, DAQP's last exit flag, SQP iterations)``; code 0: not accepted here (the general
    path runs); :data:`STATUS_CONE_FAILURE`: the SQP ended on a subproblem DAQP could not
    solve (an exit flag other than 1 or 2): the general path takes that solve's outcome
    from ``socp`` (the ``"nominal"`` session's workspace) rather than solving again.
    ``tolerance``: the acceptance tolerance of the point (the transcription's).
    """
    W_y, b_y = condensing.W_y, condensing.b_y
    S, u_max = condensing.S, condensing.u_max
    N, m = u.shape
    nu = N * m
    if _precheck(W_y, b_y, x_hat, lower, upper, alpha) != PRECHECK_PASSED:
        return 0, 0, 0.0, 0.0, 0, 0
    # ---- insert, then the exact-cone QP (CondensedTranscription._cone_data)
    insert_state(condensing, x_hat)
    _write_cone_nominal(condensing, socp, alpha)
    flag, sqp, iterations, violation, seconds = socp_solve(socp, False, MAX_ITERATIONS)
    if flag != 1 and flag != 2:
        return STATUS_CONE_FAILURE, iterations, 0.0, seconds, flag, sqp
    if sqp > MAX_ITERATIONS:
        return 0, iterations, 0.0, seconds, flag, sqp
    z = socp.z
    violation_rows = expand_point(condensing, z, nu + socp.A.shape[0], x_linear, u)
    violation = max(violation_rows, violation)
    verdict, step = _accept(z, x_linear, u, S, violation, tolerance, scale, u_max)
    if verdict != ACCEPTED:
        return 0, iterations, 0.0, seconds, flag, sqp
    _simulate_plan(plan, x_hat, x_bar, u_bar, lower, upper, x_linear, u, x_plan)
    return flag, iterations, step, seconds, flag, sqp


@njit(cache=True)
def cone_policy_feedback(
    condensing: Any,
    fallback: Any,
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
    """:func:`cone_feedback`, and where the pre-check fails or the SQP ends with a negative
    DAQP exit flag, what ``RobustMPC.feedback`` does next on ``daqp:socp``: the
    infeasibility policy of ``fallback`` on its exact-cone problem (``fallback.policy_socp``,
    its session's: ``"paper"`` or ``"soft"``; the candidate for ``"shift"`` and
    ``"<policy>+shift"``). The nominal problem is solved once, on ``fallback.socp`` (the
    ``"nominal"`` session's workspace), as by :func:`cone_feedback`.

    Returns as :func:`policy_feedback`. A failed nominal solve is recorded with the status
    code :data:`STATUS_CONE_FAILURE` and its exit flag and SQP iterations in
    ``fallback.codes`` (:data:`FAILURE_FLAG`, :data:`FAILURE_SQP`), and ``fallback.socp``'s
    arrays copied into ``fallback.snapshot`` and ``fallback.snapshot_int``: its status and
    reason come from the certificate checks, which the caller runs on a copy of those when
    the step's record is read. Code 0 (the general path
    runs): a point within a margin of a test, or a solve that ran out of SQP iterations (its
    status names the cones it stalled at).
    """
    codes = fallback.codes
    socp, policy_socp = fallback.socp, fallback.policy_socp
    status = _precheck(condensing.W_y, condensing.b_y, x_hat, lower, upper, alpha)
    if status == PRECHECK_UNDECIDED:
        return 0, 0, 0.0, 0.0
    insert_state(condensing, x_hat)
    S, u_max = condensing.S, condensing.u_max
    N, m = u.shape
    nu = N * m
    iterations, seconds = 0, 0.0
    if status == PRECHECK_PASSED:
        _write_cone_nominal(condensing, socp, alpha)
        flag, sqp, iterations, violation, seconds = socp_solve(socp, False, MAX_ITERATIONS)
        if flag == 1 or flag == 2:
            if sqp > MAX_ITERATIONS:
                return 0, iterations, 0.0, seconds
            z = socp.z
            violation_rows = expand_point(condensing, z, nu + socp.A.shape[0], x_linear, u)
            violation = max(violation_rows, violation)
            verdict, step = _accept(z, x_linear, u, S, violation, tolerance, scale, u_max)
            if verdict != ACCEPTED:
                return 0, iterations, 0.0, seconds
            _simulate_plan(plan, x_hat, x_bar, u_bar, lower, upper, x_linear, u, x_plan)
            codes[STATUS_CODE], codes[POLICY_CODE], codes[PLAN_ITERATIONS] = flag, POLICY_NOMINAL, 1
            return flag, iterations, step, seconds
        status = STATUS_CONE_FAILURE  # (socp is the session's workspace: not solved again)
        codes[FAILURE_FLAG], codes[FAILURE_SQP] = flag, sqp
        snapshot_into(socp, fallback.snapshot, fallback.snapshot_int)  # (its record's copy)
    policy = fallback.policy
    linear = False
    step = 0.0
    if policy == POLICY_PAPER or policy == POLICY_SOFT:
        soft = policy == POLICY_SOFT
        _write_cone_policy(condensing, policy_socp, soft, alpha, fallback.regularization)
        flag, sqp, more, _violation, more_seconds = socp_solve(policy_socp, False, MAX_ITERATIONS)
        iterations += more
        seconds += more_seconds
        if flag == 1 or flag == 2:
            if sqp > MAX_ITERATIONS:
                return 0, iterations, 0.0, seconds
            z = policy_socp.z
            finite = True
            for a in range(z.shape[0]):
                if not np.isfinite(z[a]):
                    finite = False
            if finite:
                expand_point(condensing, z, nu, x_linear, u)
                violation = _cone_qp_violation(policy_socp, z)  # the QP's rows, bounds, cones
                verdict, step = _accept(z, x_linear, u, S, violation, tolerance, scale, u_max)
                if verdict == UNDECIDED:
                    return 0, iterations, 0.0, seconds
                linear = verdict == ACCEPTED
        if not linear:
            policy += SHIFT_AFTER
    if not linear:
        step = 0.0
    _policy_plan(
        condensing, fallback, plan, x_hat, x_bar, u_bar, lower, upper, x_linear, u, x_plan,
        linear, status, policy,
    )  # fmt: skip
    return FEEDBACK_POLICY, iterations, step, seconds


#: This module's compiled constructors (its workspaces', and the SQP workspace's of its
#: placeholders): what compiles with it (:func:`~ltv_lstm_mpc.loop.kernels.controller_kernels`).
CONSTRUCTORS = (_new_daqp_workspace, _new_fallback_workspace, new_socp_workspace_kernel)
