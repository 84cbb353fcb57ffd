r"""The SQP of ``"daqp:socp"``: exact second-order cones by sequential QPs on DAQP, compiled.

The dense problem of :class:`~ltv_lstm_mpc.solvers.DenseQP` with cones,

.. math::

    \min_z \tfrac12 z^\top H z + f^\top z \quad\text{s.t.}\quad lo \le A z \le up,\;
    lb \le z \le ub,\; \|F_j z + g_j\|_2 \le e_j^\top z + f_j,

is solved as a sequence of QPs on DAQP (an active-set QP solver). Each cone is the smooth
convex constraint :math:`c_j(z) = r_j(z) - e_j^\top z - f_j \le 0` with
:math:`r_j = \sqrt{\|F_j z + g_j\|^2 + s^2}` (:data:`SMOOTHING` :math:`s = 10^{-6}`: smooth at
the apex of the cone, and conservative: :math:`\|F_j z + g_j\| \le r_j`, by at most
:math:`s` at the apex and :math:`s^2 / (2\|F_j z + g_j\|)` elsewhere). Iteration k solves

.. math::

    \min_x \tfrac12 x^\top W_k x + (f + (H - W_k) z_k)^\top x \quad\text{s.t. the rows, the
    bounds and}\quad \nabla c_j(z_k)^\top (x - z_k) + c_j(z_k) \le 0,

with the exact Hessian of the Lagrangian :math:`W_k = H + \sum_j \mu_j \nabla^2 c_j(z_k)`,
:math:`\nabla^2 c_j = F_j^\top (I - v_j v_j^\top / r_j^2) F_j / r_j` (positive semidefinite:
each subproblem is a convex QP), the cone multipliers :math:`\mu_j` of the previous
subproblem and DAQP warm-started from its working set. It stops when the step and the
cones' violation are below the tolerances (:data:`STEP_TOLERANCE`,
:data:`CONE_TOLERANCE`); convergence is
quadratic near the solution (3-6 iterations on the MPC's terminal cones, measured in
``experiments/cone_sqp_prototype.py``). The multipliers are returned in the solver layer's
convention: rows and bounds as DAQP's, each cone's :math:`(\lambda_0, \lambda_1) = \mu_j
(1, -v_j / r_j)`.

Globalization: the first :data:`FULL_STEPS` iterations take full steps (the local method,
quadratic near the solution). Far from it, full steps can cycle (two points visited in
turn, seen on small random problems whose cost pulls an epigraph variable far below its
cone), so from then on the step to the subproblem's solution is shortened by backtracking
until the l1 merit function :math:`\tfrac12 z^\top H z + f^\top z + w \sum_j
\max(c_j(z), 0)` decreases enough (Armijo, :data:`ARMIJO`), with :math:`w` at least twice
the largest cone multiplier so far (the SQP direction then descends on it). The stop test
reads the full step. Solutions at a cone's apex stay slow: the smoothed cone's curvature
:math:`\mu_j / r_j` grows as :math:`r_j \to s` and the accepted steps shrink; such a
problem converges slowly, or ends with ``MAX_ITER`` naming the cone (an interior-point solver
such as CLARABEL suits it).

Row screening: DAQP forms :math:`M = A R^{-1}` for every general row of a subproblem
(:math:`R^\top R = W_k`), which is most of its time on the MPC's problems, whose output
rows are rarely active. Each subproblem therefore gets only the rows that were active in the
previous one or lie within :data:`SCREENING_MARGIN` times :math:`\|a_i\|_1` times the last
SQP step of their bounds at :math:`z_k`, with the cones' rows; the others are checked at the
subproblem's solution, and any that it violates is added and the subproblem solved again
(the same :math:`W_k`, warm-started from the working set just found). A convex QP whose
solution satisfies the rows it was not given has the same solution with them, so the SQP
takes the same iterates; ``screen_rows=False`` gives DAQP every row (the reference the tests
compare with: the same iterates to rounding, bit for bit on the closed loops measured).

Epigraph elimination: a cone :math:`\|F_j z + g_j\| \le t_j` whose right side is one
unbounded variable :math:`t_j` (an epigraph variable, as in the MPC's terminal cost
:math:`\|c_N - \bar c\| \le t_c`, :math:`\|h_N - \bar h\| \le t_h`) binds whenever its
multiplier is positive. A subproblem in which such cones are predicted active (positive
multipliers in the previous subproblem; for the first subproblem of a solve, active in the
first subproblem of the previous solve) is solved first with their linearized rows as
equalities, :math:`t_j` substituted, over the other variables: DAQP then sees no active
row where it saw one per cone, and where nothing else binds it stops at the unconstrained
minimizer after one Cholesky factorization, without the inverse factor and the row products
an active row costs (41 against 16 us per subproblem at N = 50). Each cone's multiplier
then follows from the stationarity of the whole subproblem at :math:`t_j`; if all are
nonnegative, the point and multipliers satisfy the whole subproblem's optimality
conditions, so they are its solution (a convex QP); otherwise the whole subproblem is
solved. Where DAQP calls the subproblem without them infeasible, that is a verdict on the
whole subproblem too wherever each :math:`t_j` could move onto its own row's equality
without leaving another row (:func:`_reduction_proves`: no other row bounds it on that
side; on the MPC's problems the terminal set's linearized row has only an upper bound,
with coefficients :math:`(P_f t)_j / \|P_f^{1/2} t\| \ge 0` on :math:`t` where
:math:`P_f t \ge 0`), and where the substitution keeps the reduced QP's scale
(:data:`REDUCTION_SCALE`, :data:`REDUCED_HESSIAN_LIMIT`): the solve then ends as the
whole subproblem's verdict would end it (on a safely positive definite :math:`W_k`,
below), which the SQP would otherwise have solved from its start. That halves a failed
solve's DAQP iterations at N = 50 (149 against 76 on the dense schedule of
``experiments/worst_case.py``, 78 without the elimination: the failed solve now costs
what it costs without it). In exact arithmetic
the solve ends at the same SQP iteration, with the same certificate (built from the
iterate); in floating point it rests on DAQP's verdict on the reduced QP, which two
reviews found wrong on badly scaled problems (now declined by the scale guards). Over
20,000 random problems with epigraph cones predicted active (the first review's
generator), none ends infeasible where the SQP without the elimination converges, and
one ends -1 where it ended -2 (DAQP's cycling) before; over 3,000 each of the second
review's (a cost of 1e4 or 1e6 on the epigraph variables), no outcome differs from
before. The prediction changes only the time otherwise: the SQP takes the same
iterates, to rounding (``eliminate=False`` gives the reference the tests compare with).
Where one such cone's :math:`F_j` holds another's epigraph variable, none is eliminated.

Unbounded and infeasible subproblems: the first subproblem of a solve knows no
cone curvature (:math:`\mu = 0`, :math:`W_1 = H`), so where the curvature of a variable is
all in a cone (an epigraph variable with a linear cost, the form qpsolvers hands a QP to
ECOS in) it is unbounded; DAQP's "unbounded" (exit flag -3) is a verdict on that
subproblem, not on the problem. A subproblem DAQP calls infeasible (exit flag -1) ends the
solve where :math:`W_k` is safely positive definite (its Cholesky pivots at least
:data:`DEFINITE_PIVOT` times its largest diagonal entry, factored then: DAQP's verdict on a
strictly convex QP's feasibility holds; the MPC's problems, whose :math:`H` is positive
definite, take this path and skip the second proof, a third of a failed solve's DAQP
iterations). Such an unbounded subproblem (and an infeasible one on another
:math:`W_k`, where the verdict need not hold) is solved again with the proximal term
:math:`\tfrac\rho2 \|x - z_k\|^2` (:math:`\rho` = :data:`PROXIMAL` times ``1 +`` the
largest diagonal entry of :math:`W_k`: strictly convex, so bounded, and DAQP's verdict on
feasibility reliable), and the SQP goes on with its multipliers, which bring the cones'
curvature into the next subproblem; over consecutive such iterations :math:`\rho` shrinks
tenfold each (:data:`PROXIMAL_DECREASE`, down to :data:`PROXIMAL_FLOOR` of the first), so
the steps grow where the first weight misjudged the problem's scale. A converged point is a
KKT point of the problem (the proximal term vanishes with the step). What a finished
solve proves (the multipliers in the layer's convention, certificates of infeasibility and
unboundedness) is read by :mod:`~ltv_lstm_mpc.solvers.socp_certificates`; the backend
``daqp:socp`` (:mod:`~ltv_lstm_mpc.solvers.daqp_socp`) maps it to the layer's statuses.

Infeasibility check: each cone's linearized row at an iterate :math:`z_i`, shifted by
:math:`s^2 / r_j(z_i)`, is a plane of the cone itself (not only of the smoothed one:
:math:`\|v\| \ge (v_i / r_i)^\top v` as :math:`\|v_i\| < r_i`), valid for every point of the
cone, not only near the iterate it was taken at. On an infeasible problem the SQP's
subproblems can stay feasible for many iterations (each holds the planes of one iterate
only) while the cone multipliers grow without bound (the MPC's infeasible steps: up to 21
SQP iterations on the paper's scenario 3 at N = 5). The planes of the last
:data:`CUT_ROUNDS` iterates are therefore kept (``cuts``, ``cut_bounds``, the iterates in
``cut_points``; ``plane_slack``: each cone's :math:`s^2 / r_j` at the iterate); from
iteration :data:`CUT_FROM` on, at an iteration whose largest cone multiplier grew more than
:data:`CUT_GROWTH` times (from 0 too; the symptom; the MPC's feasible problems seldom show
it, so the check costs them almost nothing) and whose solution violates a kept plane, the
subproblem is solved again with its cones' rows as such planes and every kept plane added,
each loosened by :data:`CUT_MARGIN` (DAQP warm-started from its working set). Where DAQP
calls that infeasible on a safely positive definite :math:`W_k`, every point of the problem
would satisfy it, so the problem is infeasible (up to DAQP's arithmetic: the status still
needs a checked certificate) and the solve ends there (``cut_state[2]``: the iterates whose
planes were kept); otherwise the SQP goes on from the subproblem's own solution, so a solve
the check does not end takes the same iterates, bit for bit (``cut_check=False`` gives the
reference the tests compare with). Its certificate sums each cone's multipliers over its
planes (a sum of cone elements is in the cone):
:func:`~ltv_lstm_mpc.solvers.socp_certificates.infeasibility_certificate`. On the scenario
above (``python experiments/worst_case.py --solvers daqp:socp --N 5``, 74 fallback steps
after the first 10) 60 of the 74 failed nominal solves then end at SQP iteration 2 or 3 (19
did before; the median was 6, now 2), and the fallback steps' median fell from 2.78 to
1.94-1.97 times the nominal one (docs/benchmarks.md, "The worst case").

This module is the algorithm: the compiled kernels (:func:`socp_solve` and its callees),
the workspace (:data:`SocpWorkspace`, :func:`socp_arrays`, :func:`new_socp_workspace`) and
the constants above. It needs DAQP's C entry point bound natively
(:mod:`ltv_lstm_mpc.solvers.daqp_native`): the loop is compiled around it. Compiled
callers reach it through the registry's compiled form of ``daqp:socp``
(:func:`~ltv_lstm_mpc.solvers.compiled_form`).
"""

from __future__ import annotations

from typing import Any

import numpy as np

from ltv_lstm_mpc.numba_support import build_workspace, njit, workspace_type

from .daqp_native import quadprog, solver_seconds

__all__ = [
    "ARMIJO",
    "BACKTRACKS",
    "CONE_TOLERANCE",
    "CUT_FROM",
    "CUT_GROWTH",
    "CUT_MARGIN",
    "CUT_ROUNDS",
    "CUT_TOLERANCE",
    "DEFINITE_PIVOT",
    "FAILURE_FIELDS",
    "FULL_STEPS",
    "MAX_ITERATIONS",
    "PROXIMAL",
    "PROXIMAL_DECREASE",
    "PROXIMAL_FLOOR",
    "REDUCED_HESSIAN_LIMIT",
    "REDUCTION_SCALE",
    "SCREENING_MARGIN",
    "SMOOTHING",
    "SOCP_FIELDS",
    "STEP_TOLERANCE",
    "STORED_PRODUCTS",
    "SocpWorkspace",
    "cone_violation",
    "max_abs",
    "new_socp_workspace",
    "new_socp_workspace_kernel",
    "snapshot_into",
    "snapshot_sizes",
    "snapshot_views",
    "socp_arrays",
    "socp_solve",
]

#: :math:`s` of :math:`r_j = \sqrt{\|F_j z + g_j\|^2 + s^2}` (smooth at the apex, conservative).
SMOOTHING = 1e-6
#: Stop when the step (inf-norm, relative to ``1 + |z|``) is below this and the cones hold
#: to :data:`CONE_TOLERANCE`. The error left is a fraction of the last step: on the MPC's
#: terminal cones at N = 50 the iterates' distances to the solution were 1.1e-6, 8.8e-8,
#: 5.8e-9, 2.2e-12 (steps 1e-6, 8.2e-8, 5.8e-9), so a stop at a step below 1e-7 leaves
#: about 6e-9, the accuracy CLARABEL reaches at its tolerance 1e-8 (first inputs of both
#: within 3.4e-8 on the closed loops of ``tests/test_daqp_socp.py``).
STEP_TOLERANCE = 1e-7
#: Largest cone violation :math:`\|F_j z + g_j\| - e_j^\top z - f_j` accepted at the end.
CONE_TOLERANCE = 1e-9
#: Most SQP iterations per solve (then ``MAX_ITER``).
MAX_ITERATIONS = 50
#: Iterations taken as full steps (the local method, quadratic near the solution: the MPC's
#: subproblems converge in 3-6); from the next one on, each step's length comes from a
#: line search on the l1 merit function (module docstring, globalization).
FULL_STEPS = 8
#: Proximal weight of an unbounded subproblem's second solve, relative to ``1 +`` the
#: largest diagonal entry of :math:`W_k` (module docstring, unbounded subproblems).
PROXIMAL = 1.0
#: Factor of the proximal weight from one regularized iteration to the next (the steps
#: grow tenfold: a problem whose scale the first weight misjudges is reached in a few
#: iterations; an unbounded one runs out along its direction), and its floor relative to
#: the first weight of a run of regularized iterations (smaller weights leave DAQP with a
#: numerically singular Hessian).
PROXIMAL_DECREASE = 0.1
PROXIMAL_FLOOR = 1e-8
#: DAQP's "infeasible" (exit flag -1) on a subproblem without the proximal term is its
#: verdict where :math:`W_k` is positive definite with every Cholesky pivot at least this
#: times its largest diagonal entry (:func:`_definite`: a condition number up to about
#: 1e6, where DAQP's factor loses at most half the digits its infeasibility test reads;
#: about 0.16 on the shipped pH model's MPC subproblems); on another :math:`W_k` the subproblem is
#: solved again with the proximal term (module docstring).
DEFINITE_PIVOT = 1e-6
#: Sufficient decrease of the line search (Armijo) and its most halvings.
ARMIJO = 1e-4
BACKTRACKS = 30
#: Row screening (module docstring): a row whose slack at the iterate is at most this times
#: its 1-norm times the last SQP step goes into the next subproblem. Only speed depends on
#: it: a row left out that the subproblem's solution violates is added and the subproblem
#: solved again.
SCREENING_MARGIN = 2.0
#: The infeasibility check (module docstring): the cones' cutting planes of up to this many
#: earlier iterates are kept, ...
CUT_ROUNDS = 4
#: ... and checked from this SQP iteration on ...
CUT_FROM = 2
#: ... at an iteration whose largest cone multiplier grew more than this factor (the
#: symptom of an infeasible problem: the multipliers grow without bound; at 1.5 the check
#: also ran on the feasible problems of a near-infeasible run at N = 50, +8 % on its
#: median step, at 4 not) ...
CUT_GROWTH = 4.0
#: ... where the subproblem's solution violates one by more than this, relative to
#: ``1 +`` its right side; the check's planes (the kept ones and the iterate's) are then
#: loosened by :data:`CUT_MARGIN` relative to ``1 +`` their right side: DAQP's verdict on
#: planes that only just touch the problem (a feasible problem whose only points are at a
#: cone's apex) is not reliable, and a proof on looser planes is still a proof.
CUT_TOLERANCE = 1e-9
CUT_MARGIN = 1e-6
#: The reduced subproblem's verdict (epigraph elimination) ends a solve only where the
#: substitution :math:`t_j = \ldots + \tau_j^\top y` keeps the QP's scale
#: (:func:`_reduction_proves`): no entry of an eliminated cone's linearized row beyond this
#: times its epigraph variable's coefficient (:math:`|\tau_j| \le` this), and no diagonal
#: entry of the reduced Hessian :math:`T^\top W_k T` beyond this times :math:`W_k`'s
#: largest. Reviews found feasible problems whose reduced QPs DAQP called infeasible: a
#: cone :math:`\|F z + g\| \le 10^{-4} t` with :math:`F` of order 1e2 (:math:`\tau` about
#: 1e6, a reduced Hessian of 1e12 against 1), and cones :math:`\|F z + g\| \le 0.1 t`
#: with a cost of 1e6 on :math:`t` (:math:`|\tau|` about 300-500, the reduced Hessian
#: 1.7e12, 100 times :math:`W_k`'s largest entry: :data:`REDUCED_HESSIAN_LIMIT` declines
#: it); the whole subproblem is solved there instead. On the MPC's problems :math:`\tau`
#: holds the terminal states' sensitivities (order 1).
REDUCTION_SCALE = 1e3
#: ... nor where a diagonal entry of the reduced Hessian exceeds this: DAQP's tests are
#: absolute (its ``zero_tol``, 1e-11, against squared norms of rows times the inverse
#: factor, about 1 / that entry for a variable's bound). The second review's problem
#: (``solvers.testing.badly_scaled_epigraph_socp(1)``) had 1.7e12, 100 times
#: :math:`W_k`'s largest, at the SQP iteration where DAQP called its feasible reduced QP
#: infeasible; the MPC's failed solves reach 361 (the paper's scenario 3 with its dense
#: schedule, N = 5 and 50).
REDUCED_HESSIAN_LIMIT = 1e6
#: Largest number of entries of the cones' :math:`F_j^\top F_j` a workspace stores (formed
#: once per solve rather than once per SQP iteration; the same numbers either way).
STORED_PRODUCTS = 1 << 22
_BIG = 1e30  # DAQP's "no bound"
_ACTIVE, _LOWER = 1, 2  # DAQP's sense bits

#: Fields of :data:`SocpWorkspace`, in the order of its compiled constructor.
SOCP_FIELDS = (
    "H", "f", "A", "lb", "ub", "lo", "up", "F", "g", "cone_rows", "e", "offsets", "z", "mu",
    "hessian", "A_k", "bupper", "blower", "sense", "x", "lam", "v", "w", "linear", "gradients",
    "gradient_bounds", "cone_products", "formed", "kept", "lam_k", "row_values", "row_norms",
    "epigraph", "eliminated", "first_active", "reduced_index", "tau", "tau_offset", "coupled",
    "reduced_hessian", "reduced_linear", "reduced_rows", "reduced_upper", "reduced_lower",
    "reduced_sense", "reduced_x", "reduced_lam", "direction", "regularized", "cuts",
    "cut_bounds", "cut_points", "cut_state", "saved_x", "plane_slack", "problem", "result",
    "settings",
)  # fmt: skip

SocpWorkspace = workspace_type(
    "SocpWorkspace",
    SOCP_FIELDS,
    """Buffers of :func:`socp_solve`.

    The problem: ``H``, ``f``, ``A``, ``lb``, ``ub``, ``lo``, ``up``; the cones stacked: cone
    j is rows ``cone_rows[j]:cone_rows[j + 1]`` of ``F``/``g``, with ``e[j]`` and
    ``offsets[j]`` (its :math:`f_j`). The iterate ``z`` and the cone multipliers ``mu`` (a
    warm start in, the solution out), and ``lam``: the multipliers of the last subproblem,
    bounds, rows, then cones (a row left out has 0). Scratch: the subproblem as DAQP gets
    it: ``A_k`` (the kept rows, then one linearized row per cone), ``bupper``, ``blower``,
    ``sense`` (DAQP's working set, carried from one subproblem to the next), ``lam_k``
    (its multipliers), in their first entries; ``kept`` (1 for a row the subproblem has),
    ``hessian``, ``x``, ``v``, ``w``, ``linear``, ``gradients`` and ``gradient_bounds`` (the
    cones' linearized rows), ``cone_products`` (each cone's :math:`F_j^\top F_j`, formed
    once per solve, where ``formed[j]`` is 1; none, formed as needed, where they would
    take more than :data:`STORED_PRODUCTS` numbers), ``row_values`` (:math:`A z` at the
    iterate) and ``row_norms`` (each row's 1-norm, formed once per solve), which the row
    screening reads; for the epigraph elimination: ``epigraph`` (each cone's epigraph
    variable, or -1), ``eliminated`` (1 for a cone eliminated in the last subproblem),
    ``first_active`` (1 for an epigraph cone active in the first subproblem of the last
    solve: the prediction for the next), ``reduced_index`` (the variables left, in
    order), ``tau``, ``tau_offset`` (:math:`t_j` = ``tau_offset[j]`` + ``tau[j]`` times
    them), ``coupled`` (rows of :math:`W_k T` at the eliminated variables) and the reduced
    subproblem as DAQP gets it (``reduced_hessian`` and ``reduced_rows`` flat, row by row,
    ``reduced_linear``, ``reduced_upper``, ``reduced_lower``, ``reduced_sense``,
    ``reduced_x``, ``reduced_lam``); for the proximal steps (module docstring,
    unbounded subproblems): ``direction`` (the last regularized step) and ``regularized``
    (the number of regularized iterations of the last solve, and 1 where its last
    iteration was one); for the infeasibility check (module docstring): ``cuts``,
    ``cut_bounds`` (the kept planes, :data:`CUT_ROUNDS` slots of one row per cone),
    ``cut_points`` (the iterates they were taken at), ``cut_state`` (the slots filled,
    the next slot, and the iterates whose planes ended the last solve: 0 where the check
    did not), ``plane_slack`` (each cone's :math:`s^2 / r_j` at the iterate), ``saved_x``
    (the subproblem's solution while the check runs); ``problem``, ``result``,
    ``settings``: DAQP's C structs.
    """,
    __name__,
)
SocpWorkspaceType = getattr(SocpWorkspace, "numba_type", None)


@njit(cache=True)
def _new_socp_workspace(  # type: ignore[no-untyped-def]
    H, f, A, lb, ub, lo, up, F, g, cone_rows, e, offsets, z, mu, hessian, A_k, bupper, blower,
    sense, x, lam, v, w, linear, gradients, gradient_bounds, cone_products, formed, kept, lam_k,
    row_values, row_norms, epigraph, eliminated, first_active, reduced_index, tau, tau_offset,
    coupled, reduced_hessian, reduced_linear, reduced_rows, reduced_upper, reduced_lower,
    reduced_sense, reduced_x, reduced_lam, direction, regularized, cuts, cut_bounds,
    cut_points, cut_state, saved_x, plane_slack, problem, result, settings,
):  # fmt: skip
    """The compiled constructor (no constructor compile at run time; cached)."""
    return SocpWorkspace(
        H, f, A, lb, ub, lo, up, F, g, cone_rows, e, offsets, z, mu, hessian, A_k, bupper, blower,
        sense, x, lam, v, w, linear, gradients, gradient_bounds, cone_products, formed, kept, lam_k,
        row_values, row_norms, epigraph, eliminated, first_active, reduced_index, tau, tau_offset,
        coupled, reduced_hessian, reduced_linear, reduced_rows, reduced_upper, reduced_lower,
        reduced_sense, reduced_x, reduced_lam, direction, regularized, cuts, cut_bounds,
        cut_points, cut_state, saved_x, plane_slack, problem, result, settings,
    )  # fmt: skip


@njit(cache=True)
def _cone_values(ws: Any, j: int) -> tuple[float, float]:
    """``v = F_j z + g_j`` into ``ws.v`` (its rows), ``w = F_j' v`` into ``ws.w``; returns
    ``(r_j, e_j' z)``."""
    F, g, z, v, w, e = ws.F, ws.g, ws.z, ws.v, ws.w, ws.e
    n = z.shape[0]
    start, stop = ws.cone_rows[j], ws.cone_rows[j + 1]
    rr = SMOOTHING * SMOOTHING
    for a in range(start, stop):
        acc = g[a]
        for b in range(n):
            acc += F[a, b] * z[b]
        v[a] = acc
        rr += acc * acc
    for b in range(n):
        w[b] = 0.0
    for a in range(start, stop):  # w = F_j' v along the rows of F (the same sums, in order)
        va = v[a]
        for b in range(n):
            w[b] += F[a, b] * va
    ez = 0.0
    for b in range(n):
        ez += e[j, b] * z[b]
    return np.sqrt(rr), ez


@njit(cache=True)
def _cone_value(ws: Any, j: int, point: Any, smoothing: float) -> float:
    r""":math:`\sqrt{\|F_j z + g_j\|^2 + s^2} - e_j^\top z - f_j` at ``point`` with
    :math:`s` = ``smoothing`` (0: the cone's own violation)."""
    F, g, e = ws.F, ws.g, ws.e
    n = point.shape[0]
    rr = smoothing * smoothing
    for a in range(ws.cone_rows[j], ws.cone_rows[j + 1]):
        acc = g[a]
        for b in range(n):
            acc += F[a, b] * point[b]
        rr += acc * acc
    ez = 0.0
    for b in range(n):
        ez += e[j, b] * point[b]
    return np.sqrt(rr) - ez - ws.offsets[j]


@njit(cache=True)
def cone_violation(ws: Any) -> float:
    r"""Largest :math:`\|F_j z + g_j\| - e_j^\top z - f_j` at ``ws.z`` (unsmoothed)."""
    worst = -np.inf
    for j in range(ws.offsets.shape[0]):
        worst = max(worst, _cone_value(ws, j, ws.z, 0.0))
    return worst


@njit(cache=True)
def _form_products(ws: Any, j: int) -> None:
    """The upper triangle of :math:`F_j^\\top F_j` into ``ws.cone_products[j]`` (the sums of
    :func:`_column_product`, in its order, along the rows of ``F``)."""
    F, products = ws.F, ws.cone_products
    n = F.shape[1]
    for a in range(n):
        target = products[j, a, a:]  # slices: loops from 0 vectorize (from a, they did not)
        for b in range(target.shape[0]):
            target[b] = 0.0
        for c in range(ws.cone_rows[j], ws.cone_rows[j + 1]):
            fa = F[c, a]
            source = F[c, a:]
            for b in range(target.shape[0]):
                target[b] += fa * source[b]


@njit(cache=True)
def _column_product(ws: Any, j: int, a: int, b: int) -> float:
    """Entry ``(a, b)`` of :math:`F_j^\\top F_j`."""
    F = ws.F
    acc = 0.0
    for c in range(ws.cone_rows[j], ws.cone_rows[j + 1]):
        acc += F[c, a] * F[c, b]
    return acc


@njit(cache=True)
def _sense(multiplier: float) -> int:
    """DAQP's sense of a constraint with ``multiplier`` in the last subproblem (its
    working set: active at the upper bound, at the lower bound, or not)."""
    if multiplier > 0.0:
        return _ACTIVE
    if multiplier < 0.0:
        return _ACTIVE | _LOWER
    return 0


@njit(cache=True)
def _row_values(ws: Any, point: Any) -> None:
    """``ws.row_values``: :math:`A` times ``point`` (every row)."""
    A, values = ws.A, ws.row_values
    n, m = A.shape[1], A.shape[0]
    row = 0
    while row + 4 <= m:  # four rows per pass: four independent sums (each in its order)
        a0, a1, a2, a3 = A[row], A[row + 1], A[row + 2], A[row + 3]
        v0 = v1 = v2 = v3 = 0.0
        for b in range(n):
            x = point[b]
            v0 += a0[b] * x
            v1 += a1[b] * x
            v2 += a2[b] * x
            v3 += a3[b] * x
        values[row], values[row + 1], values[row + 2], values[row + 3] = v0, v1, v2, v3
        row += 4
    for rest in range(row, m):
        value = 0.0
        for b in range(n):
            value += A[rest, b] * point[b]
        values[rest] = value


@njit(cache=True)
def _row_norms(ws: Any) -> None:
    """``ws.row_norms``: the 1-norm of every row of :math:`A` (once per solve)."""
    A, norms = ws.A, ws.row_norms
    for row in range(A.shape[0]):
        norm = 0.0
        for b in range(A.shape[1]):
            norm += abs(A[row, b])
        norms[row] = norm


@njit(cache=True)
def _screen(ws: Any, screen_rows: bool, last_step: float) -> None:
    """``ws.kept``: the rows of the next subproblem (module docstring, row screening):
    active in the last one, or within :data:`SCREENING_MARGIN` of their bounds at
    ``ws.z`` (``ws.row_values`` holds :math:`A z`, ``ws.row_norms`` the rows' 1-norms);
    every row without ``screen_rows``."""
    lo, up, lam, kept = ws.lo, ws.up, ws.lam, ws.kept
    values, norms = ws.row_values, ws.row_norms
    n = ws.z.shape[0]
    for row in range(kept.shape[0]):
        if not screen_rows or lam[n + row] != 0.0:
            kept[row] = 1
            continue
        value = values[row]
        slack = min(up[row] - value, value - lo[row])
        kept[row] = 1 if slack <= SCREENING_MARGIN * norms[row] * last_step else 0


@njit(cache=True)
def _subproblem(ws: Any) -> int:
    """Write the kept rows and the cones' linearized rows into DAQP's arrays (``A_k``,
    ``bupper``, ``blower``, ``sense`` from the multipliers ``ws.lam``); returns the number
    of rows."""
    A, lam, kept, A_k = ws.A, ws.lam, ws.kept, ws.A_k
    bupper, blower, sense = ws.bupper, ws.blower, ws.sense
    n = A.shape[1]
    m = A.shape[0]
    for b in range(n):
        sense[b] = _sense(lam[b])
    count = 0
    for row in range(m):
        if kept[row]:
            for b in range(n):
                A_k[count, b] = A[row, b]
            bupper[n + count] = min(ws.up[row], _BIG)
            blower[n + count] = max(ws.lo[row], -_BIG)
            sense[n + count] = _sense(lam[n + row])
            count += 1
    for j in range(ws.offsets.shape[0]):
        for b in range(n):
            A_k[count, b] = ws.gradients[j, b]
        bupper[n + count] = ws.gradient_bounds[j]
        blower[n + count] = -_BIG
        sense[n + count] = _sense(lam[n + m + j])
        count += 1
    return count


@njit(cache=True)
def _epigraph_cones(ws: Any) -> int:
    r"""``ws.epigraph``: for each cone :math:`\|F_j z + g_j\| \le e_j^\top z + f_j` whose
    :math:`e_j` has one nonzero entry, at an unbounded variable :math:`t_j` that is no
    other such cone's and that neither its :math:`F_j` nor another such cone's holds,
    the index of :math:`t_j`; else -1 (module docstring, epigraph elimination); none
    where one such cone's :math:`F_j` holds another's variable. Returns the number
    marked."""
    F, e, epigraph, cone_rows = ws.F, ws.e, ws.epigraph, ws.cone_rows
    cones, n = e.shape[0], e.shape[1]
    count = 0
    for j in range(cones):
        epigraph[j] = -1
        index = -1
        for b in range(n):
            if e[j, b] != 0.0:
                index = b if index == -1 else -2
        if index < 0 or ws.lb[index] > -_BIG or ws.ub[index] < _BIG:
            continue
        for i in range(j):
            if epigraph[i] == index:
                index = -1
        if index >= 0:
            epigraph[j] = index
            count += 1
    for j in range(cones):  # no epigraph cone's F holds an epigraph variable
        if epigraph[j] < 0:
            continue
        for i in range(cones):
            if epigraph[i] >= 0:
                for c in range(cone_rows[i], cone_rows[i + 1]):
                    if F[c, epigraph[j]] != 0.0:
                        count = 0
    if count >= n:
        count = 0
    if count == 0:
        for j in range(cones):
            epigraph[j] = -1
    return count


@njit(cache=True)
def _take(source: Any, index: Any, leading: bool, target: Any) -> None:
    """``target[q] = source[index[q]]`` for the entries of ``target``; ``leading``: the
    index is 0, 1, ... (a contiguous copy, which vectorizes)."""
    if leading:
        head = source[: target.shape[0]]
        for q in range(target.shape[0]):
            target[q] = head[q]
    else:
        for q in range(target.shape[0]):
            target[q] = source[index[q]]


@njit(cache=True)
def _reduced_solve(ws: Any, rows: int) -> tuple[bool, int, int, float]:
    """The subproblem in ``ws`` (as :func:`_subproblem` wrote it, ``rows`` rows) with the
    linearized rows of the epigraph cones marked in ``ws.eliminated`` as equalities,
    solved for the other variables (module docstring, epigraph elimination). Returns
    ``(accepted, DAQP exit flag, DAQP iterations, DAQP's time)``. Accepted: every such
    cone's multiplier, from the stationarity of the whole subproblem at its variable, is
    nonnegative, so the point and the multipliers, in ``ws.x`` and ``ws.lam_k`` (in the
    layout of the whole subproblem), solve the whole subproblem; else the caller solves
    the whole subproblem."""
    W, linear, A_k = ws.hessian, ws.linear, ws.A_k
    bupper, blower, sense = ws.bupper, ws.blower, ws.sense
    tau, offset, coupled = ws.tau, ws.tau_offset, ws.coupled
    epigraph, eliminated, index = ws.epigraph, ws.eliminated, ws.reduced_index
    n = W.shape[0]
    cones = epigraph.shape[0]
    first_cone = rows - cones  # the cones' rows follow the kept rows
    reduced = 0
    for b in range(n):  # y: the variables left, in order
        left = True
        for j in range(cones):
            if eliminated[j] and epigraph[j] == b:
                left = False
        if left:
            index[reduced] = b
            reduced += 1
    leading = index[reduced - 1] == reduced - 1  # y is the leading block of x
    # t_j = offset_j + tau_j' y from row first_cone + j: gamma_j t_j + a' y = bupper
    for j in range(cones):
        if not eliminated[j]:
            continue
        row = first_cone + j
        gamma = A_k[row, epigraph[j]]
        if gamma == 0.0:
            return False, 0, 0, 0.0
        offset[j] = bupper[n + row] / gamma
        for p in range(reduced):
            tau[j, p] = -A_k[row, index[p]] / gamma
    # W T's rows at the eliminated variables: coupled_j = W[k_j, y] + sum_i W[k_j, k_i] tau_i
    for j in range(cones):
        if not eliminated[j]:
            continue
        k = epigraph[j]
        target = coupled[j, :reduced]
        _take(W[k], index, leading, target)
        for i in range(cones):
            if eliminated[i]:
                weight = W[k, epigraph[i]]
                tau_i = tau[i, :reduced]
                for q in range(reduced):
                    target[q] += weight * tau_i[q]
    # T' W T by rows (slices: the loops vectorize)
    hessian = ws.reduced_hessian[: reduced * reduced].reshape((reduced, reduced))
    for p in range(reduced):
        target = hessian[p]
        a = index[p]
        _take(W[a], index, leading, target)
        for j in range(cones):
            if eliminated[j]:
                left, right = W[a, epigraph[j]], tau[j, p]
                tau_j, coupled_j = tau[j, :reduced], coupled[j, :reduced]
                for q in range(reduced):
                    target[q] += left * tau_j[q] + right * coupled_j[q]
    # T' (W c + linear), c: the offsets at the eliminated variables
    gradient = ws.w  # scratch: the cones' values are formed
    for a in range(n):
        acc = linear[a]
        for j in range(cones):
            if eliminated[j]:
                acc += W[a, epigraph[j]] * offset[j]
        gradient[a] = acc
    reduced_linear = ws.reduced_linear
    for p in range(reduced):
        acc = gradient[index[p]]
        for j in range(cones):
            if eliminated[j]:
                acc += tau[j, p] * gradient[epigraph[j]]
        reduced_linear[p] = acc
    # the simple bounds of y, then the other rows times T, their bounds less A c
    upper, lower, reduced_sense = ws.reduced_upper, ws.reduced_lower, ws.reduced_sense
    for p in range(reduced):
        upper[p] = bupper[index[p]]
        lower[p] = blower[index[p]]
        reduced_sense[p] = sense[index[p]]
    kept = 0
    for row in range(rows):
        if row >= first_cone and eliminated[row - first_cone]:
            continue
        target = ws.reduced_rows[kept * reduced : (kept + 1) * reduced]
        _take(A_k[row], index, leading, target)
        shift = 0.0
        for j in range(cones):
            if eliminated[j] and A_k[row, epigraph[j]] != 0.0:
                weight = A_k[row, epigraph[j]]
                shift += weight * offset[j]
                tau_j = tau[j, :reduced]
                for q in range(reduced):
                    target[q] += weight * tau_j[q]
        up, low = bupper[n + row], blower[n + row]
        upper[reduced + kept] = up - shift if up < _BIG else up
        lower[reduced + kept] = low - shift if low > -_BIG else low
        reduced_sense[reduced + kept] = sense[n + row]
        kept += 1
    used = reduced + kept
    matrix = ws.reduced_rows[: kept * reduced].reshape((kept, reduced))
    y, multipliers = ws.reduced_x[:reduced], ws.reduced_lam[:used]
    flag, iterations = quadprog(
        hessian, reduced_linear[:reduced], matrix, upper[:used], lower[:used],
        reduced_sense[:used], y, multipliers, ws.problem, ws.result, ws.settings,
    )  # fmt: skip
    seconds = solver_seconds(ws.result)
    if flag == -6:  # the carried working set was overdetermined: once more, cold
        for q in range(used):
            reduced_sense[q] = 0
        flag, more = quadprog(
            hessian, reduced_linear[:reduced], matrix, upper[:used], lower[:used],
            reduced_sense[:used], y, multipliers, ws.problem, ws.result, ws.settings,
        )  # fmt: skip
        iterations += more
        seconds += solver_seconds(ws.result)
    if flag < 0:  # with equalities for inequalities: no verdict on the whole subproblem
        return False, flag, iterations, seconds
    # the point and the multipliers in the layout of the whole subproblem
    x, lam_k = ws.x, ws.lam_k
    for p in range(reduced):
        x[index[p]] = y[p]
        lam_k[index[p]] = multipliers[p]
    for j in range(cones):
        if eliminated[j]:
            acc = offset[j]
            for p in range(reduced):
                acc += tau[j, p] * y[p]
            x[epigraph[j]] = acc
            lam_k[epigraph[j]] = 0.0  # unbounded
    kept = 0
    for row in range(rows):
        if row >= first_cone and eliminated[row - first_cone]:
            continue
        lam_k[n + row] = multipliers[reduced + kept]
        kept += 1
    # each cone's multiplier from the stationarity of the whole subproblem at t_j
    for j in range(cones):
        if not eliminated[j]:
            continue
        k = epigraph[j]
        acc = linear[k]
        for b in range(n):
            acc += W[k, b] * x[b]
        for row in range(rows):
            if not (row >= first_cone and eliminated[row - first_cone]):
                acc += lam_k[n + row] * A_k[row, k]
        row = first_cone + j
        multiplier = -acc / A_k[row, k]
        if not multiplier >= 0.0:
            return False, flag, iterations, seconds
        lam_k[n + row] = multiplier
    return True, flag, iterations, seconds


@njit(cache=True)
def _reduction_proves(ws: Any, rows: int) -> bool:
    r"""Whether the subproblem in ``ws`` (``rows`` rows) is infeasible where its reduced
    form (:func:`_reduced_solve`: the eliminated cones' rows as equalities) is: each
    eliminated epigraph variable :math:`t_j` of a point of the whole subproblem can move to
    its cone's row's equality value (towards its row's bound: :math:`\gamma_j \Delta t_j
    \ge 0`, :math:`\gamma_j` its coefficient there) without leaving any other row's
    bounds: every other row with a coefficient :math:`c` on it is no other eliminated
    cone's (an equality of the reduced subproblem; none is where no eliminated cone's
    :math:`F` holds another's variable, :func:`_epigraph_cones`) and has no finite upper
    bound where :math:`c` and :math:`\gamma_j` have the same sign and no finite lower
    bound where they differ (the variable itself is unbounded). A point of the whole
    subproblem then gives one of the reduced (module docstring, epigraph elimination).
    DAQP's verdict on the reduced subproblem is taken only where the substitution
    :math:`t_j = \ldots + \tau_j^\top y` keeps its scale (:data:`REDUCTION_SCALE`): no
    entry of an eliminated cone's row beyond that times :math:`|\gamma_j|`, and no
    diagonal entry of the reduced Hessian :math:`T^\top W_k T` beyond that times
    :math:`W_k`'s largest, nor beyond :data:`REDUCED_HESSIAN_LIMIT`. Read only on the rare
    path where DAQP calls the reduced subproblem infeasible."""
    A_k, bupper, blower = ws.A_k, ws.bupper, ws.blower
    W, tau, index = ws.hessian, ws.tau, ws.reduced_index
    epigraph, eliminated = ws.epigraph, ws.eliminated
    n = A_k.shape[1]
    cones = epigraph.shape[0]
    first_cone = rows - cones
    largest = 0.0
    reduced = n
    for a in range(n):
        largest = max(largest, W[a, a])
    for j in range(cones):
        reduced -= eliminated[j]
    for p in range(reduced):  # the diagonal of T' W_k T (as _reduced_solve forms it)
        a = index[p]
        entry = W[a, a]
        for j in range(cones):
            if eliminated[j]:
                entry += 2.0 * tau[j, p] * W[a, epigraph[j]]
                for i in range(cones):
                    if eliminated[i]:
                        entry += tau[i, p] * tau[j, p] * W[epigraph[i], epigraph[j]]
        if entry > REDUCTION_SCALE * largest or entry > REDUCED_HESSIAN_LIMIT:
            return False
    for j in range(cones):
        if not eliminated[j]:
            continue
        t = epigraph[j]
        own = first_cone + j
        gamma = A_k[own, t]
        limit = REDUCTION_SCALE * abs(gamma)
        for b in range(n):
            if abs(A_k[own, b]) > limit:
                return False  # t_j = offset + tau' y with |tau| > REDUCTION_SCALE
        for row in range(rows):
            c = A_k[row, t]
            if row == own or c == 0.0:
                continue
            if row >= first_cone and eliminated[row - first_cone]:
                return False  # an equality of the reduced subproblem
            if (c > 0.0) == (gamma > 0.0):
                if bupper[n + row] < _BIG:
                    return False
            elif blower[n + row] > -_BIG:
                return False
    return True


@njit(cache=True)
def _add_violated_rows(ws: Any) -> bool:
    """Spread the subproblem's multipliers ``ws.lam_k`` into ``ws.lam`` (0 for the rows
    left out), form ``ws.row_values`` (:math:`A` times its solution ``ws.x``, the next
    iterate), then mark the rows left out that ``ws.x`` violates as kept; True where there
    are any (the subproblem is then solved again)."""
    A, x, lam, lam_k, kept = ws.A, ws.x, ws.lam, ws.lam_k, ws.kept
    n = A.shape[1]
    m = A.shape[0]
    for b in range(n):
        lam[b] = lam_k[b]
    count = n
    for row in range(m):
        if kept[row]:
            lam[n + row] = lam_k[count]
            count += 1
        else:
            lam[n + row] = 0.0
    for j in range(ws.offsets.shape[0]):
        lam[n + m + j] = lam_k[count + j]
    _row_values(ws, x)
    values = ws.row_values
    added = False
    for row in range(m):
        if not kept[row]:
            value = values[row]
            if value > ws.up[row] or value < ws.lo[row]:
                kept[row] = 1
                added = True
    return added


@njit(cache=True)
def _store_cuts(ws: Any) -> None:
    """Keep the cones' linearized rows at the iterate ``ws.z`` (``ws.gradients``,
    ``ws.gradient_bounds``) and the iterate itself in the next slot of the ring ``ws.cuts``,
    ``ws.cut_bounds``, ``ws.cut_points`` (:data:`CUT_ROUNDS` slots; ``ws.cut_state``: the
    slots filled, the next slot)."""
    state, points = ws.cut_state, ws.cut_points
    rounds = points.shape[0]
    if rounds == 0:
        return
    slot = state[1]
    cones = ws.offsets.shape[0]
    z = ws.z
    for j in range(cones):
        row = slot * cones + j
        for b in range(z.shape[0]):
            ws.cuts[row, b] = ws.gradients[j, b]
        ws.cut_bounds[row] = ws.gradient_bounds[j] + ws.plane_slack[j]
    for b in range(z.shape[0]):
        points[slot, b] = z[b]
    state[1] = (slot + 1) % rounds
    state[0] = min(state[0] + 1, rounds)


@njit(cache=True)
def _cut_proof(ws: Any) -> tuple[bool, int, float]:
    """The infeasibility check (module docstring): where the subproblem's solution ``ws.x``
    violates a kept cutting plane of an earlier iterate, the subproblem just solved (its
    rows, DAQP warm-started from its working set, read from the multipliers ``ws.lam``)
    is solved again with its cones' rows shifted onto the cones and every kept plane
    added, all loosened by :data:`CUT_MARGIN`. Returns ``(proved, DAQP iterations, DAQP's time)``:
    proved where DAQP calls it infeasible on a safely positive definite :math:`W_k`
    (``ws.cut_state[2]``: the iterates whose planes it held); ``ws.x`` is left as it was."""
    state = ws.cut_state
    cones = ws.offsets.shape[0]
    stored = state[0] * cones
    x, cuts, bounds = ws.x, ws.cuts, ws.cut_bounds
    n = x.shape[0]
    violated = False
    for i in range(stored):
        acc = 0.0
        for b in range(n):
            acc += cuts[i, b] * x[b]
        if acc - bounds[i] > CUT_TOLERANCE * (1.0 + abs(bounds[i])):
            violated = True
            break
    if not violated:
        return False, 0, 0.0
    saved = ws.saved_x
    for b in range(n):
        saved[b] = x[b]
    rows = _subproblem(ws)
    A_k, bupper, blower, sense = ws.A_k, ws.bupper, ws.blower, ws.sense
    for j in range(cones):  # this iterate's rows as the unsmoothed cones' planes, loosened
        bound = bupper[n + rows - cones + j] + ws.plane_slack[j]
        bupper[n + rows - cones + j] = bound + CUT_MARGIN * (1.0 + abs(bound))
    for i in range(stored):
        for b in range(n):
            A_k[rows + i, b] = cuts[i, b]
        bupper[n + rows + i] = bounds[i] + CUT_MARGIN * (1.0 + abs(bounds[i]))
        blower[n + rows + i] = -_BIG
        sense[n + rows + i] = 0
    rows += stored
    used = n + rows
    flag, iterations = quadprog(
        ws.hessian, ws.linear, A_k[:rows], bupper[:used], blower[:used], sense[:used], x,
        ws.lam_k[:used], ws.problem, ws.result, ws.settings,
    )  # fmt: skip
    seconds = solver_seconds(ws.result)
    proved = flag == -1 and _definite(ws)
    for b in range(n):
        x[b] = saved[b]
    if proved:
        state[2] = state[0]
    return proved, iterations, seconds


@njit(cache=True)
def _definite(ws: Any) -> bool:
    """Whether :math:`W_k` (``ws.hessian``, both triangles) is positive definite with every
    Cholesky pivot (the squared diagonal of its factor) at least :data:`DEFINITE_PIVOT`
    times its largest diagonal entry; the factor goes into ``ws.reduced_hessian`` (scratch,
    row by row)."""
    hessian, factor = ws.hessian, ws.reduced_hessian
    n = hessian.shape[0]
    largest = 0.0
    for a in range(n):
        largest = max(largest, hessian[a, a])
    if not largest > 0.0:
        return False
    floor = DEFINITE_PIVOT * largest
    for a in range(n):
        for b in range(a + 1):
            acc = hessian[a, b]
            for c in range(b):
                acc -= factor[a * n + c] * factor[b * n + c]
            if a == b:
                if not acc >= floor:  # (a NaN too)
                    return False
                factor[a * n + a] = np.sqrt(acc)
            else:
                factor[a * n + b] = acc / factor[b * n + b]
    return True


@njit(cache=True)
def _merit_parts(ws: Any, point: Any) -> tuple[float, float]:
    r"""The two parts of the l1 merit function :math:`\tfrac12 z^\top H z + f^\top z + w
    \sum_j \max(c_j(z), 0)` at ``point``: the cost and the smoothed cones' violations
    :math:`\sum_j \max(c_j(z), 0)` (the rows and bounds hold on the segment between two
    subproblem solutions)."""
    H, f = ws.H, ws.f
    n = point.shape[0]
    cost = 0.0
    for a in range(n):
        acc = 0.5 * H[a, a] * point[a] + f[a]
        for b in range(a + 1, n):
            acc += 0.5 * (H[a, b] + H[b, a]) * point[b]
        cost += acc * point[a]
    violations = 0.0
    for j in range(ws.offsets.shape[0]):
        violations += max(_cone_value(ws, j, point, SMOOTHING), 0.0)
    return cost, violations


@njit(cache=True)
def _line_search(ws: Any, weight: float) -> float:
    """The step length along ``ws.x - ws.z`` by backtracking from 1 on the l1 merit
    function (:func:`_merit_parts`) with ``weight`` (at least the cones' multipliers: the
    SQP direction then descends), until the Armijo condition holds (:data:`ARMIJO`); the
    shortest tried where it never does. ``ws.linear`` holds the trial points."""
    H, f, z, x, trial = ws.H, ws.f, ws.z, ws.x, ws.linear
    n = z.shape[0]
    cost, violations = _merit_parts(ws, z)
    start = cost + weight * violations
    slope = -weight * violations  # the merit's directional derivative bound:
    for a in range(n):  # grad q' d - w sum max(c_j, 0)
        acc = f[a]
        for b in range(n):
            acc += 0.5 * (H[a, b] + H[b, a]) * z[b]
        slope += acc * (x[a] - z[a])
    length = 1.0
    for _ in range(BACKTRACKS):
        for a in range(n):
            trial[a] = z[a] + length * (x[a] - z[a])
        cost, violations = _merit_parts(ws, trial)
        if cost + weight * violations <= start + ARMIJO * length * slope:
            return length
        length *= 0.5
    return 2.0 * length


@njit(cache=True)
def socp_solve(
    ws: Any,
    warm: bool,
    max_iterations: int,
    screen_rows: bool = True,
    eliminate: bool = True,
    cut_check: bool = True,
) -> tuple[int, int, int, float, float]:
    """The SQP of the module docstring on the workspace ``ws``.

    ``warm``: start from ``ws.z``, ``ws.mu`` (else zeros). ``screen_rows``: give each
    subproblem only the rows the row screening keeps (else all). ``eliminate``: solve a
    subproblem whose epigraph cones are all predicted active without their variables
    first (epigraph elimination; else always the whole subproblem). ``cut_check``: the
    infeasibility check with the earlier iterates' cutting planes (else none). Returns
    ``(DAQP exit flag of the last subproblem, SQP iterations, DAQP iterations in all, cone
    violation, DAQP's own time in all (s))``: flag 1 or 2 with at most ``max_iterations``
    SQP iterations is converged; a negative flag is DAQP's verdict on a subproblem (-1:
    infeasible; where the infeasibility check ended the solve, ``cut_state[2]`` > 0);
    ``z``, ``mu``, ``lam`` hold the last iterate.
    """
    H, f, z, mu = ws.H, ws.f, ws.z, ws.mu
    hessian, A_k, bupper, blower, sense = ws.hessian, ws.A_k, ws.bupper, ws.blower, ws.sense
    x, lam, lam_k, w, linear = ws.x, ws.lam, ws.lam_k, ws.w, ws.linear
    products = ws.cone_products
    n = H.shape[0]
    cones = ws.offsets.shape[0]
    for b in range(n):
        bupper[b] = min(ws.ub[b], _BIG)
        blower[b] = max(ws.lb[b], -_BIG)
    if not warm:
        for b in range(n):
            z[b] = 0.0
        for j in range(cones):
            mu[j] = 0.0
    for q in range(lam.shape[0]):  # the first subproblem starts from an empty working set
        lam[q] = 0.0
    F, v = ws.F, ws.v
    _row_norms(ws)  # the rows' 1-norms and A z, for the row screening
    _row_values(ws, z)
    formed = ws.formed
    for j in range(cones):
        formed[j] = 0
    stored = products.shape[0] > 0
    if eliminate:
        _epigraph_cones(ws)
    else:
        for j in range(cones):
            ws.epigraph[j] = -1
    symmetric = True
    for a in range(n):
        for b in range(a + 1, n):
            if H[a, b] != H[b, a]:
                symmetric = False
    flag = 0
    total = 0
    seconds = 0.0
    violation = np.inf
    step = 0.0
    weight = 0.0  # of the merit function's cone violations, once it is used
    counts = ws.regularized  # regularized iterations, and whether the last one was
    proximal = 0.0  # the last proximal weight
    first_weight = 0.0  # the first of a run of regularized iterations
    counts[0] = 0
    counts[1] = 0
    cut_state = ws.cut_state
    cut_state[0] = cut_state[1] = cut_state[2] = 0
    for iteration in range(1, max_iterations + 1):
        rho = 0.0  # the proximal weight of this iteration's subproblem (0: none)
        for a in range(n):  # W_k on the upper triangle (mirrored below), from H's
            target = hessian[a, a:]  # symmetric part (H itself where it is symmetric)
            if symmetric:
                source = H[a, a:]
                for b in range(target.shape[0]):
                    target[b] = source[b]
            else:
                for b in range(target.shape[0]):
                    target[b] = 0.5 * (H[a, a + b] + H[a + b, a])
        for a in range(n):
            linear[a] = f[a]
        predicted = False
        for j in range(cones):
            r, ez = _cone_values(ws, j)
            value = r - ez - ws.offsets[j]
            # eliminate the epigraph cones predicted active: in the last subproblem, or
            # (first iteration) in the first subproblem of the last solve
            active = mu[j] > 0.0 or (iteration == 1 and ws.first_active[j] > 0)
            ws.eliminated[j] = 1 if ws.epigraph[j] >= 0 and active else 0
            predicted = predicted or ws.eliminated[j] > 0
            if mu[j] > 0.0:
                # mu_j times the curvature F_j' (I - v v' / r^2) F_j / r into W_k, and its
                # product with z_k out of the linear term: (H - W_k) z_k with
                # F_j' F_j z_k = F_j' (F_j z_k), whose F_j z_k goes into v's rows
                if stored and not formed[j]:
                    _form_products(ws, j)
                    formed[j] = 1
                scale = mu[j] / r
                inv_r2 = 1.0 / (r * r)
                for a in range(n):
                    wa = w[a]
                    target = hessian[a, a:]
                    w_tail = w[a:]
                    if stored:
                        product = products[j, a, a:]
                        for b in range(target.shape[0]):
                            target[b] += scale * (product[b] - wa * w_tail[b] * inv_r2)
                    else:
                        for b in range(target.shape[0]):
                            entry = _column_product(ws, j, a, a + b)
                            target[b] += scale * (entry - wa * w_tail[b] * inv_r2)
                start, stop = ws.cone_rows[j], ws.cone_rows[j + 1]
                wz = 0.0
                for b in range(n):
                    wz += w[b] * z[b]
                for c in range(start, stop):
                    acc = 0.0
                    for b in range(n):
                        acc += F[c, b] * z[b]
                    v[c] = acc
                wz *= inv_r2
                for b in range(n):
                    acc = 0.0
                    for c in range(start, stop):
                        acc += F[c, b] * v[c]
                    linear[b] -= scale * (acc - w[b] * wz)
            bound = -value
            for b in range(n):
                gradient = w[b] / r - ws.e[j, b]
                ws.gradients[j, b] = gradient
                bound += gradient * z[b]
            ws.gradient_bounds[j] = bound
            ws.plane_slack[j] = SMOOTHING * SMOOTHING / r  # (the unsmoothed cone's plane)
        for a in range(n):
            for b in range(a + 1, n):
                hessian[b, a] = hessian[a, b]
        _screen(ws, screen_rows, step)
        while True:
            rows = _subproblem(ws)
            used = n + rows
            if predicted:
                solved, flag, iterations, spent = _reduced_solve(ws, rows)
                total += iterations
                seconds += spent
                if solved:
                    if not _add_violated_rows(ws):
                        break
                    continue
                if flag == -1 and rho == 0.0 and _reduction_proves(ws, rows) and _definite(ws):
                    # the reduced subproblem's infeasibility is the whole one's: the
                    # verdict the whole subproblem's solve below would reach
                    return flag, iteration, total, np.inf, seconds
            flag, iterations = quadprog(
                hessian, linear, A_k[:rows], bupper[:used], blower[:used], sense[:used], x,
                lam_k[:used], ws.problem, ws.result, ws.settings,
            )  # fmt: skip
            total += iterations
            seconds += solver_seconds(ws.result)
            if flag == -6:  # the carried working set was overdetermined: once more, cold
                for q in range(used):
                    sense[q] = 0
                flag, iterations = quadprog(
                    hessian, linear, A_k[:rows], bupper[:used], blower[:used], sense[:used],
                    x, lam_k[:used], ws.problem, ws.result, ws.settings,
                )  # fmt: skip
                total += iterations
                seconds += solver_seconds(ws.result)
            if flag == -1 and rho == 0.0 and _definite(ws):
                # infeasible by DAQP on a safely positive definite W_k: the subproblem's
                # verdict stands (no second proof with the proximal term)
                return flag, iteration, total, np.inf, seconds
            if (flag == -3 or flag == -1) and rho == 0.0:
                # unbounded subproblem (the cones' curvature is not known yet, e.g. the
                # first one, with mu = 0), or infeasible by DAQP on a singular W_k: solve
                # it again with the proximal term rho/2 |x - z_k|^2 (strictly convex:
                # bounded, and DAQP's verdict on feasibility reliable), and go on; rho
                # shrinks tenfold per consecutive such iteration (module docstring)
                if counts[1] and proximal > 0.0:
                    rho = max(proximal * PROXIMAL_DECREASE, PROXIMAL_FLOOR * first_weight)
                else:
                    largest = 0.0
                    for a in range(n):
                        largest = max(largest, abs(hessian[a, a]))
                    rho = PROXIMAL * (1.0 + largest)
                    first_weight = rho
                proximal = rho
                for a in range(n):
                    hessian[a, a] += rho
                    linear[a] -= rho * z[a]
                for q in range(lam.shape[0]):  # cold: DAQP's working set from none
                    lam[q] = 0.0
                continue
            if flag < 0:
                return flag, iteration, total, np.inf, seconds
            if not _add_violated_rows(ws):
                break
        largest, last_largest = 0.0, 0.0
        for j in range(cones):
            last_largest = max(last_largest, mu[j])
            mu[j] = max(lam[n + ws.A.shape[0] + j], 0.0)
            largest = max(largest, mu[j])
        if (
            cut_check
            and iteration >= CUT_FROM
            and rho == 0.0
            and largest > CUT_GROWTH * last_largest
        ):
            # the subproblem with the earlier iterates' cutting planes (module docstring)
            proved, iterations, spent = _cut_proof(ws)
            total += iterations
            seconds += spent
            if proved:
                return -1, iteration, total, np.inf, seconds
        _store_cuts(ws)  # this iterate's planes, for the next check
        for j in range(cones):
            if iteration == 1 and ws.epigraph[j] >= 0:
                ws.first_active[j] = 1 if mu[j] > 0.0 else 0
        step = 0.0
        for b in range(n):
            step = max(step, abs(x[b] - z[b]))
        counts[1] = 0
        if rho > 0.0:
            counts[0] += 1
            counts[1] = 1
            for b in range(n):
                ws.direction[b] = x[b] - z[b]
        if iteration > FULL_STEPS:  # a line search on the l1 merit function
            weight = max(weight, 2.0 * largest)
            length = _line_search(ws, weight)
            for b in range(n):
                z[b] += length * (x[b] - z[b])
            if length < 1.0:
                _row_values(ws, z)  # A z for the next screening (A x was formed)
        else:
            for b in range(n):
                z[b] = x[b]
        violation = cone_violation(ws)
        if step <= STEP_TOLERANCE * (1.0 + max_abs(z)) and violation <= CONE_TOLERANCE:
            return flag, iteration, total, violation, seconds
    return flag, max_iterations + 1, total, violation, seconds


@njit(cache=True)
def max_abs(values: Any) -> float:
    """Largest absolute entry (0 for none)."""
    largest = 0.0
    for a in range(values.shape[0]):
        largest = max(largest, abs(values[a]))
    return largest


#: The arrays of a :data:`SocpWorkspace` that a failed solve's status is read from (the
#: problem, the last iterate, and the epigraph prediction its certificate's rerun starts
#: from, and the infeasibility check's kept iterates), in the order :func:`snapshot_into`
#: lays them out: the float64 ones one after the other in one flat array, the int64 ones
#: (``cone_rows``, ``regularized``, ``first_active``, ``cut_state``) in another.
FAILURE_FIELDS = (
    "H", "f", "A", "lb", "ub", "lo", "up", "F", "g", "cone_rows", "e", "offsets", "z", "mu",
    "lam", "regularized", "direction", "first_active", "cut_points", "cut_state",
)  # fmt: skip
_INTEGER_FIELDS = ("cone_rows", "regularized", "first_active", "cut_state")


@njit(cache=True)
def _put_vector(target: Any, at: int, source: Any) -> int:
    """``source`` (1-D) into ``target`` from ``at``; returns the next free index."""
    for a in range(source.shape[0]):
        target[at + a] = source[a]
    return at + source.shape[0]


@njit(cache=True)
def _put_matrix(target: Any, at: int, source: Any) -> int:
    """``source`` (2-D) into ``target`` from ``at``, row by row; the next free index."""
    for a in range(source.shape[0]):
        at = _put_vector(target, at, source[a])
    return at


@njit(cache=True)
def snapshot_into(ws: Any, real: Any, integer: Any) -> None:
    """Copy the :data:`FAILURE_FIELDS` of ``ws`` into the flat arrays ``real`` (float64)
    and ``integer`` (int64), sized by :func:`snapshot_sizes` (read back with
    :func:`snapshot_views`): a failed solve's record, taken in the compiled step where it
    fails, in one pass (the one-call step engine keeps a copy of the two arrays)."""
    at = _put_matrix(real, 0, ws.H)
    at = _put_vector(real, at, ws.f)
    at = _put_matrix(real, at, ws.A)
    at = _put_vector(real, at, ws.lb)
    at = _put_vector(real, at, ws.ub)
    at = _put_vector(real, at, ws.lo)
    at = _put_vector(real, at, ws.up)
    at = _put_matrix(real, at, ws.F)
    at = _put_vector(real, at, ws.g)
    at = _put_matrix(real, at, ws.e)
    at = _put_vector(real, at, ws.offsets)
    at = _put_vector(real, at, ws.z)
    at = _put_vector(real, at, ws.mu)
    at = _put_vector(real, at, ws.lam)
    at = _put_vector(real, at, ws.direction)
    _put_matrix(real, at, ws.cut_points)
    at = _put_vector(integer, 0, ws.cone_rows)
    at = _put_vector(integer, at, ws.regularized)
    at = _put_vector(integer, at, ws.first_active)
    _put_vector(integer, at, ws.cut_state)


def snapshot_sizes(arrays: dict[str, Any]) -> tuple[int, int]:
    """The lengths of :func:`snapshot_into`'s ``real`` and ``integer`` for the workspace
    whose arrays (:func:`socp_arrays`) are ``arrays``."""
    sizes = [0, 0]
    for name in FAILURE_FIELDS:
        sizes[name in _INTEGER_FIELDS] += int(np.size(arrays[name]))
    return sizes[0], sizes[1]


def snapshot_views(real: Any, integer: Any, arrays: dict[str, Any]) -> dict[str, Any]:
    """The :data:`FAILURE_FIELDS` of a :func:`snapshot_into` copy as views of ``real`` and
    ``integer``, shaped as the workspace's ``arrays`` it was taken from."""
    views: dict[str, Any] = {}
    at = [0, 0]
    for name in FAILURE_FIELDS:
        which = int(name in _INTEGER_FIELDS)
        shape = np.shape(arrays[name])
        size = int(np.prod(shape, dtype=np.int64))
        source = integer if which else real
        views[name] = source[at[which] : at[which] + size].reshape(shape)
        at[which] += size
    return views


def new_socp_workspace(**fields: Any) -> Any:
    """A :data:`SocpWorkspace` from its fields by name (:data:`SOCP_FIELDS`)."""
    return build_workspace(_new_socp_workspace, SOCP_FIELDS, fields)


#: The compiled constructor that :func:`new_socp_workspace` calls: a kernel for the lists of
#: compiled functions to load or compile ahead (numba's cache), e.g. where a compiled
#: workspace holds a :data:`SocpWorkspace` field.
new_socp_workspace_kernel = _new_socp_workspace


def socp_arrays(n: int, m: int, sizes: list[int], buffers: Any) -> dict[str, Any]:
    """Zeroed arrays of a :data:`SocpWorkspace` for ``n`` variables, ``m`` rows and cones
    of ``sizes`` rows, on DAQP's struct ``buffers``
    (:class:`~ltv_lstm_mpc.solvers.daqp_native.DaqpNative`)."""
    cones = len(sizes)
    rows = int(sum(sizes))
    extra = CUT_ROUNDS * cones  # the stored cutting planes of the infeasibility check
    return {
        "H": np.zeros((n, n)), "f": np.zeros(n), "A": np.zeros((m, n)),
        "lb": np.zeros(n), "ub": np.zeros(n), "lo": np.zeros(m), "up": np.zeros(m),
        "F": np.zeros((rows, n)), "g": np.zeros(rows),
        "cone_rows": np.cumsum([0, *sizes]).astype(np.int64),
        "e": np.zeros((cones, n)), "offsets": np.zeros(cones), "z": np.zeros(n),
        "mu": np.zeros(cones), "hessian": np.zeros((n, n)),
        "A_k": np.zeros((m + cones + extra, n)), "bupper": np.zeros(n + m + cones + extra),
        "blower": np.zeros(n + m + cones + extra),
        "sense": np.zeros(n + m + cones + extra, dtype=np.intc), "x": np.zeros(n),
        "lam": np.zeros(n + m + cones), "v": np.zeros(rows), "w": np.zeros(n),
        "linear": np.zeros(n), "gradients": np.zeros((cones, n)),
        "gradient_bounds": np.zeros(cones),
        "cone_products": np.zeros((cones if cones * n * n <= STORED_PRODUCTS else 0, n, n)),
        "formed": np.zeros(cones, dtype=np.int64), "kept": np.zeros(m, dtype=np.int64),
        "lam_k": np.zeros(n + m + cones + extra),
        "row_values": np.zeros(m), "row_norms": np.zeros(m),
        "epigraph": np.zeros(cones, dtype=np.int64),
        "eliminated": np.zeros(cones, dtype=np.int64),
        "first_active": np.zeros(cones, dtype=np.int64),
        "reduced_index": np.zeros(n, dtype=np.int64),
        "tau": np.zeros((cones, n)), "tau_offset": np.zeros(cones), "coupled": np.zeros((cones, n)),
        "reduced_hessian": np.zeros(n * n), "reduced_linear": np.zeros(n),
        "reduced_rows": np.zeros((m + cones) * n), "reduced_upper": np.zeros(n + m + cones),
        "reduced_lower": np.zeros(n + m + cones),
        "reduced_sense": np.zeros(n + m + cones, dtype=np.intc), "reduced_x": np.zeros(n),
        "reduced_lam": np.zeros(n + m + cones),
        "direction": np.zeros(n), "regularized": np.zeros(2, dtype=np.int64),
        "cuts": np.zeros((CUT_ROUNDS * cones, n)), "cut_bounds": np.zeros(CUT_ROUNDS * cones),
        "cut_points": np.zeros((CUT_ROUNDS, n)), "cut_state": np.zeros(3, dtype=np.int64),
        "saved_x": np.zeros(n), "plane_slack": np.zeros(cones),
        "problem": buffers.problem, "result": buffers.result, "settings": buffers.settings,
    }  # fmt: skip
