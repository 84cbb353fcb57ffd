r"""One controller step as one compiled call: the kernels of the one-call step engine.

The one-call engine (:mod:`ltv_lstm_mpc.loop.engines.one_call_engine`; the condensed
transcription with DAQP bound natively, one SQP iteration, compiled kernels) runs, in
:func:`controller_step`, the stages of the reference engine, calling the same formulas'
compiled twins (:mod:`ltv_lstm_mpc.loop.compiled_signals`,
:mod:`ltv_lstm_mpc.certificates.compiled_tightening`) and the same compiled kernels:

1. the normalization of the measurement and the set-point (paper notes 1) and the
   set-point rate limiter (Theorem 3's :math:`\Delta y^0_{max}`);
2. the reference calculator, eq. (reference_calculation): its warm path by the chord
   Newton of :func:`~ltv_lstm_mpc.loop.compiled_reference.chord_newton`, with the
   acceptance test of ``ReferenceCalculator.solve_arrays``, and where that fails its
   damped Newton with restarts
   (:func:`~ltv_lstm_mpc.loop.compiled_reference.newton_restarts`), and where that finds no
   admissible equilibrium either, the last admissible one kept (the stale reference of
   Theorem 3, Part 2a, with the set-point it encodes for :math:`\alpha_k`);
3. the set-point status of Assumption 5 and the saturation flags of :math:`\hat d_k`;
4. the tightened output bounds (eq. optimization_constraint_yub/ylb) and :math:`\alpha_k`
   (eq. def_alpha) of :class:`~ltv_lstm_mpc.certificates.tightening.TighteningCertificate`
   (through their twins in ``certificates/compiled_tightening.py``);
5. the preparation (:func:`~ltv_lstm_mpc.mpc.compiled_prepare.prepare_condensed`) on the
   proof candidate (Theorem 3, Part 2b) and the feedback
   (:func:`~ltv_lstm_mpc.mpc.native_feedback.policy_feedback`: the nominal QP, and the
   infeasibility policy where it is infeasible; or
   :func:`~ltv_lstm_mpc.mpc.native_feedback.cone_feedback` with the exact terminal cones
   on ``daqp:socp``, the nominal problem only);
6. the exit gate onto :math:`\mathcal U`, the observer update eq. (lstm_observer)
   (:func:`~ltv_lstm_mpc.loop.compiled_observer.observer_update`), the recursion
   :math:`\hat e_{o,k+1} = \rho_o \hat e_{o,k} + \bar w` (eq. eo_evolution) and the
   de-normalization of the input.

Stages 1-5 do not use the measurement :math:`y_k`: the observer's :math:`\hat x_k,
\hat d_k` are known once step ``k - 1`` has returned its input (eq. lstm_observer updates
them with :math:`y_{k-1}`). :func:`prepare_step` runs them alone, between samples
(:meth:`~ltv_lstm_mpc.OffsetFreeController.prepare_next`), and :func:`feedback_step` runs
stage 6 when the measurement arrives, so that a sample costs only the feedback and the
observer update; :func:`controller_step` runs both in one call.
:func:`controller_first_step` runs the first step after construction or a reset: the
observer's start at the equilibrium whose output is the measurement, then the same stages
without a last reference solution or a previous plan.

Everything the step computed goes into row ``k`` of :data:`RecordArrays` (the updated
estimates into row ``k + 1``): the controller's records are built from those rows when
they are read (:class:`~ltv_lstm_mpc.loop.records.ControllerRecords`), not in the timed
step.

Like the one-call feedback, it only *accepts*. It returns :data:`STEP_DONE` when every
test passed; otherwise nothing the controller keeps has changed (the chord's kept inverse
Jacobian aside, which the reference engine takes over with the chord's outcome) and the
reference engine goes on with the step: :data:`STEP_GENERAL` (a measurement or set-point that
is not finite, or a measurement beyond the plausible range where the controller refuses
one: the reference engine raises),
:data:`STEP_REFERENCE` (the reference calculator has no last solution to keep) and
:data:`STEP_FEEDBACK` (the one-call feedback did not decide: a point within a margin of an
acceptance test, or on ``daqp:socp`` an infeasible exact-cone problem; the general
feedback runs, with its reasons and fallbacks). The same compiled
functions run as in the reference engine, so both give the same numbers (to a few ulps, tested
to 1e-12 over closed loops in ``tests/test_one_call_step.py``).
"""

from __future__ import annotations

from typing import Any

import numpy as np

from ltv_lstm_mpc.certificates.compiled_tightening import (
    inside_setpoint_interval,
    next_e_hat,
    output_bounds_into,
    terminal_alpha,
)
from ltv_lstm_mpc.loop.compiled_observer import observer_update
from ltv_lstm_mpc.loop.compiled_reference import (
    CHORD_CONVERGED,
    CHORD_FACTORIZATIONS,
    CHORD_ITERATIONS,
    CHORD_JINV_VALID,
    U_MARGIN,
    chord_newton,
    newton_restarts,
)
from ltv_lstm_mpc.loop.compiled_signals import (
    limit_rate_into,
    measurement_code,
    project_into,
    setpoint_code,
)
from ltv_lstm_mpc.loop.statuses import UNREACHABLE_STALE
from ltv_lstm_mpc.mpc.compiled_prepare import (
    CANDIDATE_GIVEN,
    CANDIDATE_SHIFT,
    CANDIDATE_U_BAR,
    prepare_condensed,
)
from ltv_lstm_mpc.mpc.native_feedback import (
    FAILURE_FLAG,
    FAILURE_SQP,
    PLAN_ITERATIONS,
    POLICY_CODE,
    STATUS_CODE,
    STATUS_CONE_FAILURE,
    cone_policy_feedback,
    placeholder_socp,
    policy_feedback,
)
from ltv_lstm_mpc.numba_support import AVAILABLE, build_workspace, njit, workspace_type

__all__ = [
    "CONSTRUCTORS",
    "RECORD_FIELDS",
    "STEP_DONE",
    "STEP_FEEDBACK",
    "STEP_FIELDS",
    "STEP_GENERAL",
    "STEP_REFERENCE",
    "RecordArrays",
    "StepWorkspace",
    "controller_first_step",
    "controller_step",
    "controller_step_from_rows",
    "feedback_step",
    "feedback_step_from_rows",
    "new_record_arrays",
    "new_step_workspace",
    "prepare_step",
    "prepare_step_from_rows",
]

#: Return codes of :func:`controller_step`.
STEP_DONE, STEP_GENERAL, STEP_REFERENCE, STEP_FEEDBACK = 1, 0, -1, -2

#: Columns of ``RecordArrays.real``.
(
    E_HAT, INPUT_CLIPPED, ALPHA, COST, OUTPUT_VIOLATION, TERMINAL_RESIDUAL,
    LINEARIZATION_GAP, SQP_STEP, SOLVER_TIME, PREPARE_TIME, FEEDBACK_TIME, TIME_OBSERVER,
    TIME_REFERENCE, TIME_MPC, REFERENCE_RESIDUAL, E_HAT_NEXT, SCALE,
) = range(17)  # fmt: skip
REAL_COLUMNS = 17
#: Columns of ``RecordArrays.integer``.
(
    STATUS, SOLVER_ITERATIONS, REFERENCE_ITERATIONS, SETPOINT_STATUS, MEASUREMENT_STATUS,
    FACTORIZATIONS, JINV_VALID, CHORD_OK, U_BAR_PROJECTED, POLICY, SQP_ITERATIONS,
    REFERENCE_FALLBACK, STALE_REFERENCE, FAILURE_FLAG_COLUMN, FAILURE_SQP_COLUMN,
) = range(15)  # fmt: skip
INTEGER_COLUMNS = 15
# ``SETPOINT_STATUS`` and ``MEASUREMENT_STATUS`` hold indices into
# :data:`~ltv_lstm_mpc.loop.statuses.SETPOINT_STATUSES` and ``MEASUREMENT_STATUSES``;
# ``STATUS`` the feedback's status code and ``POLICY`` its policy code
# (:data:`~ltv_lstm_mpc.mpc.native_feedback.POLICIES`; read by
# :func:`~ltv_lstm_mpc.mpc.native_feedback.feedback_outcome`).

#: Fields of :data:`StepWorkspace`, in the order of its compiled constructor.
STEP_FIELDS = (
    "y_min", "y_scale", "u_min", "u_scale", "u_phi_low", "u_phi_high", "a", "b",
    "bound_min", "bound_max", "kappa", "lower", "upper", "requested", "clock",
    "u_max", "implausible", "d_max", "tightening_d_max", "rho_o", "w_bar", "e_inf",
    "backward", "tol", "max_iter", "jump", "reuse_tol", "chord", "trajectories",
    "condensing", "daqp", "plan", "observer", "cand", "cones", "socp", "tolerance",
    "jinv_backup", "fallback", "restart", "flag_implausible",
)  # fmt: skip

StepWorkspace = workspace_type(
    "StepWorkspace",
    STEP_FIELDS,
    r"""Constants and buffers of :func:`controller_step`.

    ``y_min``, ``y_scale``, ``u_min``, ``u_scale``: the normalization (physical =
    (normalized + 1) scale + min); ``u_phi_low``, ``u_phi_high``: U in physical units;
    ``a``, ``b`` (N + 1, p), ``bound_min``, ``bound_max``, ``kappa`` (p): the tightening
    certificate's :math:`a_i, b_i, y_{min}, y_{max}, \kappa_j`; ``lower``, ``upper``
    (N, p): the tightened output bounds written at each step; ``requested`` (p): the
    set-point requested before the limiter;
    ``clock`` (int64, 2): a timespec. Scalars (fixed when the controller is built):
    ``u_max``; ``implausible`` (the plausible measurement limit); ``d_max`` (the
    observer's saturation), ``tightening_d_max``, ``rho_o``, ``w_bar``, ``e_inf`` (the
    tightening certificate's); ``backward`` (the condensing's recursion); ``tol``,
    ``max_iter``, ``jump`` (the reference calculator's) and ``reuse_tol`` (the MPC's; the
    controller builds a new workspace when one of these four changes). The other
    workspaces (one argument crosses the boundary instead of seven): ``chord``, the
    reference calculator's
    :data:`~ltv_lstm_mpc.loop.compiled_reference.ChordWorkspace`; ``trajectories``,
    ``condensing``, ``daqp``, ``plan``: the MPC's (preparation, condensing, DAQP, plan
    checks); ``observer``: the observer's; ``cand`` (N, m): the MPC's candidate buffer;
    ``cones``: the exact terminal cones by SQP on DAQP (``daqp:socp``: the feedback is
    :func:`~ltv_lstm_mpc.mpc.native_feedback.cone_feedback` on ``socp``, a
    :data:`~ltv_lstm_mpc.solvers.socp_sqp.SocpWorkspace`, with the acceptance
    ``tolerance``) rather than the QP on ``daqp`` (the other one of the two is a
    placeholder); ``jinv_backup``: the chord's inverse Jacobian as it was before the last
    :func:`prepare_step` (restored when a preparation is discarded); ``fallback``: the
    infeasibility policy's buffers of the QP feedback
    (:func:`~ltv_lstm_mpc.mpc.native_feedback.policy_feedback`; a placeholder with cones);
    ``restart``: the reference calculator's
    :data:`~ltv_lstm_mpc.loop.compiled_reference.RestartWorkspace` (its damped Newton with
    restarts, where the warm chord does not give an admissible equilibrium);
    ``flag_implausible``: an implausible measurement is flagged and used (the controller's
    ``implausible_measurements="flag"``), else it goes to the reference engine (which
    raises).
    """,
    __name__,
)
StepWorkspaceType = getattr(StepWorkspace, "numba_type", None)

#: Fields of :data:`RecordArrays`, in the order of its compiled constructor.
RECORD_FIELDS = (
    "y", "y0", "u", "u_phi", "x_hat", "d_hat", "x_bar", "u_bar", "z", "target",
    "saturated", "u_plan", "x_plan", "x_linear", "real", "integer",
)  # fmt: skip

RecordArrays = workspace_type(
    "RecordArrays",
    RECORD_FIELDS,
    """Preallocated per-step rows that :func:`controller_step` writes (capacity rows).

    ``y``, ``y0``, ``u``, ``u_phi``: measurement, set-point used, input (normalized and
    physical); ``x_hat``, ``d_hat``: the estimates used at step k (row k) and their update
    (row k + 1); ``x_bar``, ``u_bar``, ``z`` (= [x_bar; u_bar]), ``target`` (= y0 - d_hat):
    the reference; ``saturated`` (uint8, p): the saturation flags of d_hat; ``u_plan``
    (N, m), ``x_plan``, ``x_linear`` (N + 1, 2n): the MPC's plan; ``real``, ``integer``: the
    scalars, one column each (the column constants of this module).
    """,
    __name__,
)
RecordArraysType = getattr(RecordArrays, "numba_type", None)


def new_step_workspace(**fields: Any) -> Any:
    """A :data:`StepWorkspace` from its fields by name (:data:`STEP_FIELDS`)."""
    return build_workspace(_new_step_workspace, STEP_FIELDS, fields)


def _resident_zeros(shape: tuple[int, ...], dtype: Any = np.float64) -> Any:
    """Zeros written now (``np.full``), not the lazily mapped pages of ``np.zeros``: the
    first write to each page of a large ``np.zeros`` array costs a page fault, which would
    fall inside the timed steps that write their rows."""
    return np.full(shape, 0, dtype=dtype)


def new_record_arrays(capacity: int, p: int, m: int, n2: int, N: int) -> tuple[Any, dict[str, Any]]:
    """Empty :data:`RecordArrays` for ``capacity`` steps (the estimates use one row more),
    and its arrays by field name. The arrays are written (zeros) when allocated, so that
    no page fault falls inside a step (two per step at N = 50 otherwise: 3 to 9 % of the
    median step at N = 20 and 50, measured side by side)."""
    zeros = _resident_zeros
    fields = {
        "y": zeros((capacity, p)),
        "y0": zeros((capacity, p)),
        "u": zeros((capacity, m)),
        "u_phi": zeros((capacity, m)),
        "x_hat": zeros((capacity + 1, n2)),
        "d_hat": zeros((capacity + 1, p)),
        "x_bar": zeros((capacity, n2)),
        "u_bar": zeros((capacity, m)),
        "z": zeros((capacity, n2 + m)),
        "target": zeros((capacity, p)),
        "saturated": zeros((capacity, p), np.uint8),
        "u_plan": zeros((capacity, N, m)),
        "x_plan": zeros((capacity, N + 1, n2)),
        "x_linear": zeros((capacity, N + 1, n2)),
        "real": zeros((capacity, REAL_COLUMNS)),
        "integer": zeros((capacity, INTEGER_COLUMNS), np.int64),
    }
    return build_workspace(_new_record_arrays, RECORD_FIELDS, fields), fields


def placeholder_daqp() -> Any:
    """A DAQP workspace that is never solved with (the ``daqp`` of a cone controller's
    :data:`StepWorkspace`: the field's type must be there)."""
    from ltv_lstm_mpc.mpc.native_feedback import new_daqp_workspace

    empty = np.zeros(8, dtype=np.uint8)
    return new_daqp_workspace(
        sense=np.zeros(1, dtype=np.intc), z=np.zeros(1), lam=np.zeros(1), problem=empty,
        result=empty.copy(), settings=empty.copy(), work=empty[:0].copy(), tolerance=0.0,
        hessian_floor=0.0, fval_bound=0.0,
    )  # fmt: skip


def placeholder_fallback() -> Any:
    """A :data:`~ltv_lstm_mpc.mpc.native_feedback.FallbackWorkspace` that is never used
    (the ``fallback`` of a cone controller's :data:`StepWorkspace`)."""
    from ltv_lstm_mpc.mpc.native_feedback import new_fallback_workspace

    socp = placeholder_socp()
    return new_fallback_workspace(
        policy=0, ns=0, H=np.zeros((0, 0)), f=np.zeros(0), A=np.zeros((0, 0)),
        high=np.zeros(0), low=np.zeros(0), sense=np.zeros(0, dtype=np.intc), z=np.zeros(0),
        lam=np.zeros(0), regularization=0.0, codes=np.zeros(5, dtype=np.int64), socp=socp,
        policy_socp=socp, snapshot=np.zeros(0), snapshot_int=np.zeros(0, dtype=np.int64),
    )  # fmt: skip


@njit(cache=True)
def _new_step_workspace(
    y_min: Any,
    y_scale: Any,
    u_min: Any,
    u_scale: Any,
    u_phi_low: Any,
    u_phi_high: Any,
    a: Any,
    b: Any,
    bound_min: Any,
    bound_max: Any,
    kappa: Any,
    lower: Any,
    upper: Any,
    requested: Any,
    clock: Any,
    u_max: Any,
    implausible: Any,
    d_max: Any,
    tightening_d_max: Any,
    rho_o: Any,
    w_bar: Any,
    e_inf: Any,
    backward: Any,
    tol: Any,
    max_iter: Any,
    jump: Any,
    reuse_tol: Any,
    chord: Any,
    trajectories: Any,
    condensing: Any,
    daqp: Any,
    plan: Any,
    observer: Any,
    cand: Any,
    cones: Any,
    socp: Any,
    tolerance: Any,
    jinv_backup: Any,
    fallback: Any,
    restart: Any,
    flag_implausible: Any,
) -> Any:
    """The compiled constructor (no constructor compile at run time; cached)."""
    return StepWorkspace(
        y_min, y_scale, u_min, u_scale, u_phi_low, u_phi_high, a, b, bound_min, bound_max,
        kappa, lower, upper, requested, clock, u_max, implausible, d_max, tightening_d_max,
        rho_o, w_bar, e_inf, backward, tol, max_iter, jump, reuse_tol, chord, trajectories,
        condensing, daqp, plan, observer, cand, cones, socp, tolerance, jinv_backup, fallback,
        restart, flag_implausible,
    )  # fmt: skip


@njit(cache=True)
def _new_record_arrays(
    y: Any,
    y0: Any,
    u: Any,
    u_phi: Any,
    x_hat: Any,
    d_hat: Any,
    x_bar: Any,
    u_bar: Any,
    z: Any,
    target: Any,
    saturated: Any,
    u_plan: Any,
    x_plan: Any,
    x_linear: Any,
    real: Any,
    integer: Any,
) -> Any:
    """The compiled constructor (no constructor compile at run time; cached)."""
    return RecordArrays(
        y, y0, u, u_phi, x_hat, d_hat, x_bar, u_bar, z, target, saturated, u_plan, x_plan,
        x_linear, real, integer,
    )  # fmt: skip


_CLOCK_MONOTONIC = 1
_clock_gettime: Any = None
if AVAILABLE:  # the monotonic clock of time.perf_counter, from inside the compiled step
    from numba import types as _types

    _clock_gettime = _types.ExternalFunction(
        "clock_gettime", _types.int32(_types.int32, _types.voidptr)
    )


@njit(cache=True)
def _now(clock: Any) -> float:
    """``time.perf_counter()`` (CLOCK_MONOTONIC, s) into and from the timespec ``clock``."""
    _clock_gettime(_CLOCK_MONOTONIC, clock.ctypes.data)
    return clock[0] + clock[1] * 1e-9


@njit(cache=True)
def _normalize_measurement(step: Any, records: Any, k: int, y_phi: Any) -> bool:
    """The measurement normalized into row ``k`` with its status (paper notes 1); False
    where it is not finite (the reference engine raises), or lies beyond the plausible range
    and the controller refuses such (the reference engine raises)."""
    y = records.y[k]
    largest = 0.0
    for j in range(y_phi.shape[0]):
        y[j] = (y_phi[j] - step.y_min[j]) / step.y_scale[j] - 1.0
        if not np.isfinite(y[j]):
            return False
        largest = max(largest, abs(y[j]))
    code = measurement_code(largest, step.implausible)
    if code == 2 and not step.flag_implausible:
        return False
    records.integer[k, MEASUREMENT_STATUS] = code
    return True


@njit(cache=True)
def prepare_step(
    step: Any,
    records: Any,
    k: int,
    y0_phi: Any,
    y0_previous: Any,
    x_hat: Any,
    d_hat: Any,
    last_z: Any,
    last_target: Any,
    jinv_valid: int,
    previous_u: Any,
    e_hat: float,
    rate_limit: float,
) -> tuple[int, int, int]:
    r"""Stages 1-5 up to the feedback: everything step ``k`` needs that the measurement
    ``y_k`` does not enter (the set-point, the reference, the bounds, the condensed
    subproblem), from the estimates :math:`\hat x_k, \hat d_k` the previous step left.

    Returns ``(code, kept inverse Jacobian valid, factorizations)``; ``code`` is
    :data:`STEP_DONE`, :data:`STEP_GENERAL` (a set-point that is not finite) or
    :data:`STEP_REFERENCE`. The chord's inverse Jacobian as it was before is kept in
    ``step.jinv_backup`` (a caller that discards this preparation puts it back). Arguments
    as for :func:`controller_step`; the first step after a reset
    (:func:`controller_first_step`) passes ``last_z`` and ``previous_u`` empty: the
    reference then comes from the calculator's cold solve (the damped Newton from the grid
    equilibria, no warm chord), the candidate is :math:`\bar u` repeated, and the
    linearization starts from :math:`\hat x_k` (no plan to shift).
    """
    clock = step.clock
    t0 = _now(clock)
    chord, trajectories, condensing = step.chord, step.trajectories, step.condensing
    cand = step.cand
    backup, Jinv = step.jinv_backup, chord.Jinv
    for r in range(Jinv.shape[0]):  # first: whatever this call returns, the backup is its own
        for c in range(Jinv.shape[1]):
            backup[r, c] = Jinv[r, c]
    p = y0_phi.shape[0]
    m = step.u_min.shape[0]
    n2 = x_hat.shape[0]
    N = cand.shape[0]
    # ---- normalization of the set-point (paper notes 1)
    y0 = records.y0[k]
    for j in range(p):
        y0[j] = (y0_phi[j] - step.y_min[j]) / step.y_scale[j] - 1.0  # the target, for now
        if not np.isfinite(y0[j]):
            return STEP_GENERAL, 0, 0
    integer = records.integer[k]
    real = records.real[k]
    # ---- the rate limiter: y0 moves towards the target by at most rate_limit
    limited = not np.isnan(rate_limit)
    if limited:
        limit_rate_into(y0, y0_previous, rate_limit, step.requested)
    for q in range(n2):
        records.x_hat[k, q] = x_hat[q]
    for j in range(p):
        records.d_hat[k, j] = d_hat[j]
    # ---- reference calculator, warm path (ReferenceCalculator.solve_arrays)
    target = records.target[k]
    target_step = np.empty(p)
    for j in range(p):
        target[j] = y0[j] - d_hat[j]
        target_step[j] = target[j] - last_target[j] if last_target.shape[0] else 0.0
    chord.state[CHORD_JINV_VALID] = jinv_valid
    z = records.z[k]
    cold = last_z.shape[0] == 0  # no last solution (a reset): the cold solve, no chord
    state = chord.state
    if cold:
        state[CHORD_ITERATIONS] = 0
        state[CHORD_FACTORIZATIONS] = 0
        state[CHORD_CONVERGED] = 0
        state[CHORD_JINV_VALID] = 0
        residual = np.inf
    else:
        residual = chord_newton(chord, last_z, target, target_step, step.tol, step.max_iter, z)
    integer[REFERENCE_ITERATIONS] = state[CHORD_ITERATIONS]
    integer[FACTORIZATIONS] = state[CHORD_FACTORIZATIONS]
    integer[CHORD_OK] = state[CHORD_CONVERGED]
    integer[JINV_VALID] = state[CHORD_JINV_VALID]
    real[REFERENCE_RESIDUAL] = residual
    u_max = step.u_max
    largest_u = 0.0
    for a in range(m):
        largest_u = max(largest_u, abs(z[n2 + a]))
    admissible = state[CHORD_CONVERGED] == 1 and largest_u <= u_max * (1 + U_MARGIN)
    folded = z[:0]
    if admissible and m > 1:  # a MIMO equilibrium map can fold: another branch?
        largest_jump = 0.0
        for q in range(n2 + m):
            largest_jump = max(largest_jump, abs(z[q] - last_z[q]))
        if largest_jump > step.jump:
            folded, admissible = z.copy(), False
    integer[REFERENCE_FALLBACK] = 0
    integer[STALE_REFERENCE] = 0
    stale = False
    if not admissible:  # the damped Newton with restarts (ReferenceCalculator.solve_arrays)
        restart = step.restart
        residual, iterations, converged, inside = newton_restarts(
            chord, restart, last_z, folded, target, step.tol, step.max_iter, restart.best
        )
        stale = not (converged and inside)
        if stale and last_target.shape[0] == 0:  # (no last solution: the reference engine)
            return STEP_REFERENCE, int(state[CHORD_JINV_VALID]), int(state[CHORD_FACTORIZATIONS])
        # the new equilibrium, or with none admissible the last admissible one kept, with
        # its target (the stale reference of Theorem 3, Part 2a: ReferenceEngine._reference)
        source = last_z if stale else restart.best
        for q in range(n2 + m):
            z[q] = source[q]
        if stale:
            for j in range(p):
                target[j] = last_target[j]
        state[CHORD_JINV_VALID] = 0  # the chord refactorizes at the next step
        integer[REFERENCE_FALLBACK] = 0 if cold else 1  # (the calculator counts fallbacks
        # from its warm path only)
        integer[STALE_REFERENCE] = 1 if stale else 0
        integer[REFERENCE_ITERATIONS] = iterations
        integer[JINV_VALID] = 0
        real[REFERENCE_RESIDUAL] = residual
    x_bar = records.x_bar[k]
    u_bar = records.u_bar[k]
    for q in range(n2):
        x_bar[q] = z[q]
    for a in range(m):
        u_bar[a] = z[n2 + a]
    # ---- set-point status (Assumption 5) and saturation of d_hat
    saturation = step.d_max * (1.0 - 1e-12)
    for j in range(p):
        records.saturated[k, j] = 1 if abs(d_hat[j]) >= saturation else 0
    a_N, b_N = step.a[N], step.b[N]
    e_tilde = max(e_hat, step.e_inf)
    two_d = 2.0 * step.tightening_d_max
    y0_mpc = y0  # the set-point of alpha_k
    if stale:  # the set-point the kept equilibrium encodes: g(x_bar) + d_hat
        integer[SETPOINT_STATUS] = UNREACHABLE_STALE
        y0_mpc = np.empty(p)
        W_y, b_y = chord.W_y, chord.b_y
        n = n2 // 2
        for j in range(p):
            acc = 0.0
            for q in range(n):
                acc += W_y[j, q] * x_bar[n + q]
            y0_mpc[j] = acc + b_y[j] + d_hat[j]
    else:
        used_inside = inside_setpoint_interval(
            y0, step.bound_min, step.bound_max, two_d, a_N, b_N, e_tilde
        )
        target_inside = True  # (tested only where it decides)
        if used_inside and limited:
            target_inside = inside_setpoint_interval(
                step.requested, step.bound_min, step.bound_max, two_d, a_N, b_N, e_tilde
            )
        integer[SETPOINT_STATUS] = setpoint_code(used_inside, limited, target_inside)
    t2 = _now(clock)
    # ---- tightened bounds and alpha_k (TighteningCertificate.output_bounds, .alpha)
    lower, upper = step.lower, step.upper
    output_bounds_into(
        step.a, step.b, step.tightening_d_max, step.bound_min, step.bound_max, e_hat, lower, upper
    )
    alpha = terminal_alpha(
        y0_mpc, step.bound_min, step.bound_max, step.kappa, two_d, a_N, b_N, e_tilde
    )
    real[ALPHA] = alpha
    # ---- prepare: the candidate (Theorem 3, Part 2b), rollout, Jacobians, condensing
    projected = False
    for a in range(m):
        if not -u_max <= u_bar[a] <= u_max:
            projected = True
    planned = previous_u.shape[0] > 0  # else the first step: u_bar repeated, no shift
    candidate = CANDIDATE_SHIFT if planned else CANDIDATE_U_BAR
    if projected:  # an inadmissible equilibrium within the tolerance: append its projection
        shifted = N - 1 if planned else 0
        for i in range(shifted):
            for a in range(m):
                cand[i, a] = previous_u[i + 1, a]
        for i in range(shifted, N):
            for a in range(m):
                cand[i, a] = min(max(u_bar[a], -u_max), u_max)
        candidate = CANDIDATE_GIVEN
    integer[U_BAR_PROJECTED] = 1 if projected else 0
    scale, _ = prepare_condensed(
        trajectories, condensing, cand, previous_u, candidate, x_hat,
        step.reuse_tol if planned else -1.0, x_bar, u_bar, lower, upper, alpha, step.backward,
    )  # fmt: skip
    real[SCALE] = scale
    t3 = _now(clock)
    real[TIME_REFERENCE] = t2 - t0
    real[PREPARE_TIME] = t3 - t2
    return STEP_DONE, int(state[CHORD_JINV_VALID]), int(state[CHORD_FACTORIZATIONS])


@njit(cache=True)
def _feedback_and_update(
    step: Any, records: Any, k: int, x_hat: Any, d_hat: Any, e_hat: float, normalization: float
) -> tuple[int, int, float]:
    """Stage 6 on the subproblem :func:`prepare_step` left in row ``k``: the feedback, the
    exit gate, the observer update with the measurement of row ``k``, e_hat_{k+1} and the
    de-normalization. Returns ``(code, warnings, e_hat next)``; ``normalization``: the
    seconds the measurement's normalization took (counted as the observer's time)."""
    clock = step.clock
    t_feedback = _now(clock)
    daqp, plan, observer = step.daqp, step.plan, step.observer
    p = d_hat.shape[0]
    m = step.u_min.shape[0]
    integer = records.integer[k]
    real = records.real[k]
    x_bar, u_bar = records.x_bar[k], records.u_bar[k]
    lower, upper, alpha, scale = step.lower, step.upper, real[ALPHA], real[SCALE]
    # ---- feedback: insert x_hat, solve, accept (or the infeasibility policy), re-simulate
    u_plan = records.u_plan[k]
    if step.cones:
        code, iterations, sqp_step, seconds = cone_policy_feedback(
            step.condensing, step.fallback, plan, x_hat, x_bar, u_bar, lower, upper, alpha,
            scale, step.tolerance, records.x_linear[k], u_plan, records.x_plan[k],
        )  # fmt: skip
    else:
        code, iterations, sqp_step, seconds = policy_feedback(
            step.condensing, daqp, step.fallback, plan, x_hat, x_bar, u_bar, lower, upper,
            alpha, scale, records.x_linear[k], u_plan, records.x_plan[k],
        )  # fmt: skip
    if code == 0:
        return STEP_FEEDBACK, 0, 0.0
    outcome = step.fallback.codes
    status, policy = outcome[STATUS_CODE], outcome[POLICY_CODE]
    plan_iterations = outcome[PLAN_ITERATIONS]
    integer[FAILURE_FLAG_COLUMN] = outcome[FAILURE_FLAG]
    integer[FAILURE_SQP_COLUMN] = outcome[FAILURE_SQP]
    t3 = _now(clock)
    integer[STATUS] = status
    integer[POLICY] = policy
    integer[SQP_ITERATIONS] = plan_iterations
    integer[SOLVER_ITERATIONS] = iterations
    real[SQP_STEP] = sqp_step
    real[SOLVER_TIME] = seconds
    metrics = plan.out
    real[COST] = metrics[0]
    real[TERMINAL_RESIDUAL] = metrics[1] - alpha
    real[OUTPUT_VIOLATION] = metrics[2]
    real[LINEARIZATION_GAP] = metrics[3]
    real[FEEDBACK_TIME] = t3 - t_feedback
    # ---- the exit gate onto U
    u_max = step.u_max
    u = records.u[k]
    inside = True
    for a in range(m):
        u[a] = u_plan[0, a]
        if not -u_max < u[a] < u_max:  # strictly; on the boundary too
            inside = False
    moved = 0.0
    if not inside:
        moved = project_into(u, u_max)
    real[INPUT_CLIPPED] = moved
    t4 = _now(clock)
    # ---- observer update eq. (lstm_observer) and eq. (eo_evolution)
    observer_update(observer, step.d_max, x_hat, d_hat, records.y[k], u,
                    records.x_hat[k + 1], records.d_hat[k + 1])  # fmt: skip
    real[E_HAT] = e_hat
    e_hat_next = next_e_hat(step.rho_o, step.w_bar, e_hat)
    real[E_HAT_NEXT] = e_hat_next
    u_phi = records.u_phi[k]
    for a in range(m):
        u_phi[a] = (u[a] + 1.0) * step.u_scale[a] + step.u_min[a]
        if not inside:
            u_phi[a] = min(max(u_phi[a], step.u_phi_low[a]), step.u_phi_high[a])
    t5 = _now(clock)
    real[TIME_OBSERVER] = normalization + (t5 - t4)
    real[TIME_MPC] = real[PREPARE_TIME] + (t4 - t_feedback)
    warnings = 0
    for j in range(p):
        if records.saturated[k, j]:
            warnings |= 1
    if integer[SETPOINT_STATUS] != 0:
        warnings |= 2
    if moved > 0.0:
        warnings |= 4
    if integer[REFERENCE_FALLBACK]:
        warnings |= 8
    if integer[MEASUREMENT_STATUS] == 2:
        warnings |= 16
    if status == STATUS_CONE_FAILURE:
        warnings |= 32
    return STEP_DONE, warnings, e_hat_next


@njit(cache=True)
def feedback_step(
    step: Any, records: Any, k: int, y_phi: Any, x_hat: Any, d_hat: Any, e_hat: float
) -> tuple[int, int, float]:
    """Step ``k`` on the subproblem :func:`prepare_step` prepared for it (between samples,
    after step ``k - 1`` returned its input): the measurement in, the input out, the
    estimates updated.

    Returns ``(code, warnings, e_hat next)``: ``code`` :data:`STEP_DONE`,
    :data:`STEP_GENERAL` (the measurement is not finite or not plausible) or
    :data:`STEP_FEEDBACK`; ``warnings`` as for :func:`controller_step`.
    """
    t0 = _now(step.clock)
    if not _normalize_measurement(step, records, k, y_phi):
        return STEP_GENERAL, 0, 0.0
    normalization = _now(step.clock) - t0
    return _feedback_and_update(step, records, k, x_hat, d_hat, e_hat, normalization)


@njit(cache=True)
def controller_step(
    step: Any,
    records: Any,
    k: int,
    y_phi: Any,
    y0_phi: Any,
    y0_previous: Any,
    x_hat: Any,
    d_hat: Any,
    last_z: Any,
    last_target: Any,
    jinv_valid: int,
    previous_u: Any,
    e_hat: float,
    rate_limit: float,
) -> tuple[int, int, int, int, float]:
    r"""One controller step (module docstring): :func:`prepare_step` and
    :func:`feedback_step` in one call.

    Returns ``(code, warnings, kept inverse Jacobian valid, factorizations, e_hat next)``:
    ``code`` one of the ``STEP_*`` codes; ``warnings`` bit 0: d_hat saturated, bit 1: a
    set-point status other than ok, bit 2: the input was moved onto U, bit 3: the
    reference calculator's damped Newton ran (the warm chord did not reach an admissible
    equilibrium; the calculator counts these), bit 4: an implausible measurement was
    flagged and used, bit 5: the nominal exact-cone solve failed (its status is read from a
    copy of the cone workspace's arrays, which the caller takes now).

    ``step``: :data:`StepWorkspace` (with the other workspaces); ``records``:
    :data:`RecordArrays` with at least ``k + 2`` estimate rows; ``y_phi``, ``y0_phi``:
    physical measurement and set-point; ``y0_previous``: the limiter's last set-point
    (normalized; ignored without a limit); ``x_hat``, ``d_hat``: the estimates;
    ``last_z``, ``last_target``: the reference calculator's last solution and target
    (``last_target`` empty: none); ``jinv_valid``: whether its kept inverse Jacobian is
    valid; ``previous_u``: the MPC's previous plan;
    ``e_hat``: :math:`\hat e_{o,k}`; ``rate_limit``: the limiter's bound (NaN: none).
    """
    t0 = _now(step.clock)
    if not _normalize_measurement(step, records, k, y_phi):
        return STEP_GENERAL, 0, 0, 0, 0.0
    normalization = _now(step.clock) - t0
    code, inverse_valid, factorizations = prepare_step(
        step, records, k, y0_phi, y0_previous, x_hat, d_hat, last_z, last_target, jinv_valid,
        previous_u, e_hat, rate_limit,
    )  # fmt: skip
    if code != STEP_DONE:
        return code, 0, inverse_valid, factorizations, 0.0
    code, warnings, e_hat_next = _feedback_and_update(
        step, records, k, x_hat, d_hat, e_hat, normalization
    )
    return code, warnings, inverse_valid, factorizations, e_hat_next


@njit(cache=True)
def controller_first_step(
    step: Any, records: Any, k: int, y_phi: Any, y0_phi: Any, e_hat: float, rate_limit: float
) -> tuple[int, int, int, int, float]:
    r""":func:`controller_step` for the first step after construction or a reset
    (``ReferenceEngine._start``): the observer starts at the LSTM equilibrium whose output
    is the measurement, with :math:`\hat d_0 = 0` (paper notes 2.10b), found by the
    reference calculator's cold solve (the damped Newton from the grid equilibria closest
    in output: :func:`~ltv_lstm_mpc.loop.compiled_reference.newton_restarts` without a last
    solution); the limiter starts from the measurement; then the step, with no last
    reference solution and no previous plan (:func:`prepare_step`). Returns as
    :func:`controller_step`; :data:`STEP_GENERAL` (nothing kept: the reference engine runs
    the whole first step, with its errors and warnings) where the measurement is not
    finite or beyond the plausible range (refused as a first one), or no admissible
    equilibrium has its output (the reference engine starts at the closest and warns).
    """
    t0 = _now(step.clock)
    if not _normalize_measurement(step, records, k, y_phi):
        return STEP_GENERAL, 0, 0, 0, 0.0
    if records.integer[k, MEASUREMENT_STATUS] == 2:  # (check_first_measurement refuses it)
        return STEP_GENERAL, 0, 0, 0, 0.0
    y = records.y[k]
    p = y.shape[0]
    n2 = records.x_hat.shape[1]
    m = step.u_min.shape[0]
    start = np.empty(n2 + m)
    nothing = np.empty(0)
    _residual, _iterations, converged, inside = newton_restarts(
        step.chord, step.restart, nothing, nothing, y, step.tol, step.max_iter, start
    )
    if not (converged and inside):
        return STEP_GENERAL, 0, 0, 0, 0.0
    x_hat = start[:n2]
    d_hat = np.zeros(p)
    normalization = _now(step.clock) - t0
    code, inverse_valid, factorizations = prepare_step(
        step, records, k, y0_phi, y, x_hat, d_hat, nothing, nothing, 0,
        np.empty((0, m)), e_hat, rate_limit,
    )  # fmt: skip
    if code != STEP_DONE:
        return code, 0, inverse_valid, factorizations, 0.0
    code, warnings, e_hat_next = _feedback_and_update(
        step, records, k, x_hat, d_hat, e_hat, normalization
    )
    return code, warnings, inverse_valid, factorizations, e_hat_next


@njit(cache=True)
def controller_step_from_rows(
    step: Any,
    records: Any,
    k: int,
    y_phi: Any,
    y0_phi: Any,
    jinv_valid: int,
    e_hat: float,
    rate_limit: float,
) -> tuple[int, int, int, int, float]:
    """:func:`controller_step` on the state the one-call step ``k - 1`` left in the rows
    (the estimates of row ``k``; the set-point, reference and plan of row ``k - 1``): the
    same call with four arguments fewer to cross the boundary (``k >= 1``)."""
    return controller_step(
        step, records, k, y_phi, y0_phi, records.y0[k - 1], records.x_hat[k], records.d_hat[k],
        records.z[k - 1], records.target[k - 1], jinv_valid, records.u_plan[k - 1], e_hat,
        rate_limit,
    )  # fmt: skip


@njit(cache=True)
def prepare_step_from_rows(
    step: Any, records: Any, k: int, y0_phi: Any, jinv_valid: int, e_hat: float, rate_limit: float
) -> tuple[int, int, int]:
    """:func:`prepare_step` on the state the one-call step ``k - 1`` left in the rows."""
    return prepare_step(
        step, records, k, y0_phi, records.y0[k - 1], records.x_hat[k], records.d_hat[k],
        records.z[k - 1], records.target[k - 1], jinv_valid, records.u_plan[k - 1], e_hat,
        rate_limit,
    )  # fmt: skip


@njit(cache=True)
def feedback_step_from_rows(
    step: Any, records: Any, k: int, y_phi: Any, e_hat: float
) -> tuple[int, int, float]:
    """:func:`feedback_step` with the estimates of row ``k`` (left by the one-call step
    ``k - 1``)."""
    return feedback_step(step, records, k, y_phi, records.x_hat[k], records.d_hat[k], e_hat)


#: This module's compiled constructors (the workspace's and the record arrays'): what
#: compiles with it (:func:`~ltv_lstm_mpc.loop.kernels.controller_kernels`).
CONSTRUCTORS = (_new_step_workspace, _new_record_arrays)
