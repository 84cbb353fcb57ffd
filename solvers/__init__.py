"""Convex-subproblem solver layer, installed as :mod:`ltv_lstm_mpc.solvers`.

It knows nothing about LSTMs: it takes a problem data class (matrices and
cones) and returns a solution data class. The RTI controller poses one such
subproblem per step (paper notes section 4).

Representation
--------------
:class:`ConvexProblem` (``problem.py``)

.. math::

    \\min_z \\tfrac12 z^\\top P z + q^\\top z \\;\\text{s.t.}\\;
    A_{eq} z = b_{eq},\\; l \\le G z \\le u,\\; lb \\le z \\le ub,\\;
    \\|F_j z + g_j\\|_2 \\le e_j^\\top z + f_j \\;(\\text{SecondOrderCone}).

Shapes and values are checked at construction; ``save``/``load`` round-trip
through ``.npz`` (sparse as data/indices/indptr) so a subproblem met in a
closed loop can be replayed offline; ``structure_key()`` hashes shapes,
sparsity patterns and the finite-bound pattern; ``with_values(...)`` builds a
problem with new values (a matrix may be given as its new ``.data``).

:class:`Solution`: ``status`` (:class:`SolverStatus`: OPTIMAL,
OPTIMAL_INACCURATE, INFEASIBLE, UNBOUNDED, MAX_ITER, FAILED, mapped from each
backend's ``STATUS_MAP`` table, unknown codes -> FAILED with the code in
``info``), ``z``, ``objective`` (computed by us), ``duals``, ``setup_time``,
``solve_time`` (the solver's own), ``overhead_time`` (cvxpy canonicalization,
parameter mapping, conversions), ``iterations``, ``backend``, ``solver``,
``reformulation``, ``info``, ``residuals`` (the acceptance check's), ``certificate``.

Backends (``available_solvers()`` lists the installed ones)
-----------------------------------------------------------
============================  ===========================================================
name                          what it is
============================  ===========================================================
``cvxpy:<SOLVER>``            ``cvxpy_.py``: one DPP problem per structure (all matrix
                              nonzeros in one Parameter, all vectors in another), re-solved
                              with new values; dense QPs (``CvxpyDense``) with dense
                              parameters (O(n^2 + n m) canonicalization). CLARABEL, ECOS, SCS
                              take cones; OSQP, PIQP, PROXQP, DAQP, HIGHS take QPs. The
                              flexible, exact-cone path (ms per solve), not the real-time one.
``qpsolvers:<name>``          ``qpsolvers_.py``: every ``qpsolvers.available_solvers``
                              entry, sparse or dense as the solver prefers. No in-place
                              update (a session re-runs setup, recorded).
``osqp``                      ``osqp_.py``: native OSQP, setup once, ``update(Px, Ax, q, l,
                              u)``, warm start with primal and dual.
``piqp``, ``piqp:sparse``,    ``piqp_.py``: native PIQP ``SparseSolver``/``DenseSolver``
``piqp:dense``                (``piqp`` picks by density), setup once, ``update``.
``daqp``                      ``daqp_.py``: native DAQP ``Model`` (dense active set),
                              warm start through the working set; dense: the one-shot
                              ``daqp.solve`` (fastest on small condensed problems).
``daqp:socp``                 ``daqp_socp.py``: exact second-order cones by SQP on DAQP,
                              dense only; the compiled SQP is ``socp_sqp.py``, its
                              multipliers and certificates ``socp_certificates.py``
                              (only where DAQP's C entry point is bound natively).
``quadprog``                  ``quadprog_.py``: Goldfarb-Idnani dual active set, dense
                              only (ConvexProblems through the dense adapter), machine
                              precision, no settings, no warm start.
``proxqp``                    ``proxqp_.py``: proxsuite dense ProxQP, ``init`` once,
                              ``update``, warm start from the previous result; dense
                              only (ConvexProblems through the dense adapter).
user names                    :func:`register_backend` (``factory`` and/or
                              ``dense_factory``); ``testing.faulty`` registers
                              fault-injecting wrappers.
============================  ===========================================================

:func:`solver_info` gives a :class:`SolverInfo` (``family``, ``supports_cones``,
``native_dense``, ``first_order``) per name.

Dense QPs
---------
:class:`DenseQP` (``dense.py``) holds a condensed QP ``min 1/2 x'Hx + f'x``
s.t. ``lo <= A x <= up``, ``lb <= x <= ub`` in preallocated, mutable arrays;
:class:`DenseSession` ``(solver, tolerance=..., equilibrate=False, **settings)``
solves one per call with ``solve(qp, warm_start=None)`` (``equilibrate=True``: Ruiz
scaling of variables and rows first, ``equilibration.py``): a setup (with :meth:`DenseQP.check`)
on the first call or a new ``(n, m_A)``, else an in-place update, then the
solve, with a few µs of Python around the solver. Every registered solver
accepts a DenseQP: the ``native_dense`` ones (``daqp``, ``quadprog``,
``proxqp``, ``piqp``, ``piqp:dense``, ``osqp``, ``qpsolvers:*``) with a
dedicated dense backend, the others through ``DenseQP.to_convex_problem()``.

:func:`feasibility_tolerance` ``(solver, tolerance)`` is the tolerance to which
a caller should check a returned point (``max(1e-7, 100 tol)``, first-order
solvers ``max(1e-5, 1e3 tol)``); :func:`optimality_tolerance` the one of its KKT
residuals (the same; ECOS ``max(1e-4, 1e4 tol)``).

Acceptance
----------
Every answer of ``Session.solve``, ``solve()`` and ``DenseSession.solve`` passes one
check in the layer (``acceptance.py``): ``OPTIMAL`` only for a finite point within
the feasibility tolerance whose stationarity and complementarity residuals (with the
backend's multipliers, where it gives them) are within the optimality tolerance;
``OPTIMAL_INACCURATE`` within 100 times those, ``FAILED`` (no point) beyond, the
residuals in ``Solution.residuals`` and ``info``. Certificates of infeasibility or
unboundedness that a backend returns (native OSQP, CLARABEL) are checked and kept in
``Solution.certificate``. ``DenseSession.solve_point`` (the hot-loop call) is not
checked: its caller checks the point. An exception out of a backend becomes a
:class:`~ltv_lstm_mpc.SolverError` naming the solver, phase and cause.

``Session(solver, tolerance=..., reformulation=None, **settings)`` (``session.py``) keeps one
workspace per structure: ``setup(problem)``, then ``update(problem)`` (same
``structure_key``; backends that cannot update in place are set up afresh,
recorded in ``Session.last_update`` and ``Solution.info``) and
``solve(warm_start=None)``. ``solve(problem, solver, ...)`` is the one-shot
form. ``warm_start=None`` is always a cold start; a backend that cannot warm
start (PIQP, cvxpy:PROXQP) ignores a warm start and says so in ``info``.

Tolerance
---------
One ``tolerance`` (default ``1e-8``) is mapped to each solver's own options
(:data:`tolerances.TOLERANCE_OPTIONS`); user settings override them:

=========  ==================================================================
clarabel   ``tol_gap_abs``, ``tol_gap_rel``, ``tol_feas``
daqp       ``primal_tol``, ``dual_tol``
ecos       ``abstol``, ``reltol``, ``feastol``
highs      ``primal_feasibility_tolerance``, ``dual_feasibility_tolerance``
osqp       ``eps_abs``, ``eps_rel``
piqp       ``eps_abs``, ``eps_rel``, ``eps_duality_gap_abs``, ``eps_duality_gap_rel``
proxqp     ``eps_abs`` (and ``eps_rel = 0``: ProxQP's relative test is loose)
quadprog   none (solves to machine precision)
scs        ``eps_abs``, ``eps_rel``
=========  ==================================================================

Settings whose names the installed package exposes (osqp, piqp, daqp,
clarabel, ecos, quadprog) are checked and unknown names rejected with
:class:`~ltv_lstm_mpc.InvalidValueError`; others are passed through
to the solver's interface. ``verbose`` defaults to ``False``; PIQP's
``compute_timings`` to ``True``.

Cones on QP-only backends
-------------------------
Cones are never dropped. Without a ``reformulation`` a QP-only backend refuses
a problem with cones (``InvalidValueError`` naming the cone solvers). A
:class:`ConeReformulation` (``name``, ``apply(problem) -> ConvexProblem``)
must return a cone-free problem whose feasible set is **inside** the original
one (conservative), keeping the original variables first (it may append
auxiliaries and bound the objective from above). It is applied only when the
backend needs it, and ``Solution.reformulation`` records its name.
:class:`PolyhedralInnerApproximation` is the generic one
(``|F_i z + g_i| <= (e'z + f)/sqrt(k)``); the controller supplies the paper notes 4
terminal-set and terminal-cost ones.

Compiled callers
----------------
:func:`compiled_form` ``(solver)`` is what a backend gives compiled (numba) callers, a
:class:`CompiledForm` (``compiled_forms.py``): the compiled functions to load or compile
ahead, DAQP's C entry point and buffers (``daqp``), the SQP and its workspace
(``daqp:socp``, compiled only: no numpy twin), or None (the QP solvers but ``daqp``). The
MPC reads its solver's form where it builds its compiled kernels; it uses the layer's
public names only.

A missing or unknown solver raises :class:`~ltv_lstm_mpc.SolverNotFound`
(an ``ImportError``) that lists the installed ones and
``pip install "ltv_lstm_mpc[solvers]"``.
"""

from __future__ import annotations

from ._base import Backend, RawResult
from .acceptance import Residuals
from .compiled_forms import CompiledForm
from .dense import DenseBackend, DenseCone, DenseQP
from .dense_session import DenseSession
from .problem import ConvexProblem, SecondOrderCone, Solution, SolverStatus, frozen_csc
from .reformulation import ConeReformulation, PolyhedralInnerApproximation
from .registry import (
    DEFAULT_SOLVER,
    SolverInfo,
    available_solvers,
    compiled_form,
    cone_solvers,
    default_solver,
    get_backend,
    get_dense_backend,
    register_backend,
    solver_info,
    unregister_backend,
)
from .session import Session, solve
from .tolerances import TOLERANCE_OPTIONS, feasibility_tolerance, optimality_tolerance

__all__ = [
    "DEFAULT_SOLVER",
    "TOLERANCE_OPTIONS",
    "Backend",
    "CompiledForm",
    "ConeReformulation",
    "ConvexProblem",
    "DenseBackend",
    "DenseCone",
    "DenseQP",
    "DenseSession",
    "PolyhedralInnerApproximation",
    "RawResult",
    "Residuals",
    "SecondOrderCone",
    "Session",
    "Solution",
    "SolverInfo",
    "SolverStatus",
    "available_solvers",
    "compiled_form",
    "cone_solvers",
    "default_solver",
    "feasibility_tolerance",
    "frozen_csc",
    "get_backend",
    "get_dense_backend",
    "optimality_tolerance",
    "register_backend",
    "solve",
    "solver_info",
    "unregister_backend",
]
