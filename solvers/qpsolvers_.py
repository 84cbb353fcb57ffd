"""qpsolvers backend (``"qpsolvers:<name>"``): every solver qpsolvers finds installed.

The problem is passed as a :class:`qpsolvers.Problem` (``G z <= h``, ``A z = b``,
``lb <= z <= ub``): the two-sided rows ``l <= G z <= u`` become the finite
rows of ``G z <= u`` and ``-G z <= -l``. Matrices are CSC for the solvers in
``qpsolvers.sparse_solvers`` and dense arrays otherwise.

qpsolvers builds a new solver object at every call, so a session cannot update
in place: each :meth:`Session.update` is a fresh setup (recorded), and a warm
start is passed as ``initvals`` (qpsolvers warns when a solver ignores it; the
warning is copied to ``Solution.info``).

qpsolvers reports only ``found``; where it exposes the native status in
``Solution.extras`` (clarabel, ecos, osqp, piqp, proxqp, scs) the native code is
mapped, otherwise a failure is ``FAILED`` and ``info`` says that the native
status is not available (daqp, highs, quadprog: an infeasible problem is then
``FAILED``, not ``INFEASIBLE``).
"""

from __future__ import annotations

import time
import warnings
from collections.abc import Callable, Mapping
from typing import Any, ClassVar

import numpy as np
import scipy.sparse as sp

from . import daqp_, osqp_, piqp_
from ._base import (
    Backend,
    FloatArray,
    RawResult,
    WarmStart,
    check_settings,
    map_status,
    warm_start_vectors,
)
from .problem import ConvexProblem, SolverStatus
from .tolerances import known_settings, solver_options

#: clarabel ``SolverStatus`` name -> SolverStatus.
CLARABEL_STATUS_MAP: Mapping[str, SolverStatus] = {
    "Solved": SolverStatus.OPTIMAL,
    "AlmostSolved": SolverStatus.OPTIMAL_INACCURATE,
    "PrimalInfeasible": SolverStatus.INFEASIBLE,
    "AlmostPrimalInfeasible": SolverStatus.INFEASIBLE,
    "DualInfeasible": SolverStatus.UNBOUNDED,
    "AlmostDualInfeasible": SolverStatus.UNBOUNDED,
    "MaxIterations": SolverStatus.MAX_ITER,
    "MaxTime": SolverStatus.MAX_ITER,
    "NumericalError": SolverStatus.FAILED,
    "InsufficientProgress": SolverStatus.FAILED,
    "CallbackTerminated": SolverStatus.FAILED,
    "Unsolved": SolverStatus.FAILED,
}

#: ECOS exit flag -> SolverStatus (``ecos.h``; +10 marks "close to" the tolerances).
ECOS_STATUS_MAP: Mapping[int, SolverStatus] = {
    0: SolverStatus.OPTIMAL,  # ECOS_OPTIMAL
    1: SolverStatus.INFEASIBLE,  # ECOS_PINF
    2: SolverStatus.UNBOUNDED,  # ECOS_DINF
    10: SolverStatus.OPTIMAL_INACCURATE,  # ECOS_OPTIMAL + ECOS_INACC_OFFSET
    11: SolverStatus.INFEASIBLE,  # ECOS_PINF + ECOS_INACC_OFFSET
    12: SolverStatus.UNBOUNDED,  # ECOS_DINF + ECOS_INACC_OFFSET
    -1: SolverStatus.MAX_ITER,  # ECOS_MAXIT
    -2: SolverStatus.FAILED,  # ECOS_NUMERICS
    -3: SolverStatus.FAILED,  # ECOS_OUTCONE
    -4: SolverStatus.FAILED,  # ECOS_SIGINT
    -7: SolverStatus.FAILED,  # ECOS_FATAL
}

#: SCS ``status_val`` -> SolverStatus (SCS docs, "Exit flags").
SCS_STATUS_MAP: Mapping[int, SolverStatus] = {
    1: SolverStatus.OPTIMAL,  # SCS_SOLVED
    2: SolverStatus.OPTIMAL_INACCURATE,  # SCS_SOLVED_INACCURATE
    0: SolverStatus.FAILED,  # SCS_UNFINISHED
    -1: SolverStatus.UNBOUNDED,  # SCS_UNBOUNDED
    -2: SolverStatus.INFEASIBLE,  # SCS_INFEASIBLE
    -3: SolverStatus.FAILED,  # SCS_INDETERMINATE
    -4: SolverStatus.FAILED,  # SCS_FAILED
    -5: SolverStatus.FAILED,  # SCS_SIGINT
    -6: SolverStatus.UNBOUNDED,  # SCS_UNBOUNDED_INACCURATE
    -7: SolverStatus.INFEASIBLE,  # SCS_INFEASIBLE_INACCURATE
}

#: proxsuite ``QPSolverOutput`` name -> SolverStatus.
PROXQP_STATUS_MAP: Mapping[str, SolverStatus] = {
    "PROXQP_SOLVED": SolverStatus.OPTIMAL,
    "PROXQP_MAX_ITER_REACHED": SolverStatus.MAX_ITER,
    "PROXQP_PRIMAL_INFEASIBLE": SolverStatus.INFEASIBLE,
    "PROXQP_SOLVED_CLOSEST_PRIMAL_FEASIBLE": SolverStatus.INFEASIBLE,
    "PROXQP_DUAL_INFEASIBLE": SolverStatus.UNBOUNDED,
    "PROXQP_NOT_RUN": SolverStatus.FAILED,
}


def _name(code: Any) -> str:
    return str(getattr(code, "name", code)).split(".")[-1]


#: solver -> (extract native code from ``extras``, status table)
_NATIVE: Mapping[str, tuple[Callable[[Mapping[str, Any]], Any], Mapping[Any, SolverStatus]]] = {
    "clarabel": (lambda ex: _name(ex["status"]), CLARABEL_STATUS_MAP),
    "ecos": (lambda ex: int(ex["exitFlag"]), ECOS_STATUS_MAP),
    "osqp": (lambda ex: int(ex["info"].status_val), osqp_.STATUS_MAP),
    "piqp": (
        lambda ex: int(getattr(ex["info"].status, "value", ex["info"].status)),
        piqp_.STATUS_MAP,
    ),
    "proxqp": (lambda ex: _name(ex["info"].status), PROXQP_STATUS_MAP),
    "scs": (lambda ex: int(ex["status_val"]), SCS_STATUS_MAP),
    "daqp": (lambda ex: int(ex["exitflag"]), daqp_.STATUS_MAP),
}

#: Solvers that get the finite variable bounds as rows of ``G`` (ECOS rejects inf bounds).
_BOUNDS_AS_ROWS = frozenset({"ecos"})

#: qpsolvers-level keyword arguments accepted next to the native settings.
#: (qpsolvers' ``backend`` for piqp/proxqp is not offered: the matrix type decides it.)
_INTERFACE_SETTINGS: Mapping[str, tuple[str, ...]] = {}


class QpsolversBackend(Backend):
    """Calls :func:`qpsolvers.solve_problem` on stored data (no in-place update)."""

    backend: ClassVar[str] = "qpsolvers"
    supports_update: ClassVar[bool] = False
    supports_warm_start: ClassVar[bool] = True

    def __init__(
        self, name: str, solver: str, tolerance: float, settings: Mapping[str, Any]
    ) -> None:
        """``solver`` is the qpsolvers name (``"osqp"``, ``"quadprog"``, ...)."""
        known = known_settings(solver)
        if known is not None:
            known = (*known, *_INTERFACE_SETTINGS.get(solver, ()))
        check_settings(solver, settings, known)
        super().__init__(name, solver, solver_options(solver, tolerance, settings))

    def setup(self, problem: ConvexProblem) -> None:
        """Convert to a :class:`qpsolvers.Problem` (sparse or dense as the solver prefers).

        All arrays are copied (the problem's are read-only and some bindings
        reject those). For the solvers in :data:`_BOUNDS_AS_ROWS` the finite
        variable bounds become rows of ``G`` (ECOS rejects infinite bounds).
        """
        import qpsolvers

        sparse = self.solver in qpsolvers.sparse_solvers

        def mat(m: sp.csc_matrix | None) -> Any:
            if m is None:
                return None
            return sp.csc_matrix(m, copy=True) if sparse else m.toarray()

        def vec(v: FloatArray | None) -> FloatArray | None:
            return None if v is None else np.array(v, dtype=np.float64)

        n = problem.n_variables
        self._n, self._m = n, problem.n_ineq
        blocks: list[sp.csc_matrix] = []
        h_parts: list[FloatArray] = []
        self._iu = self._il = self._ibu = self._ibl = np.zeros(0, dtype=np.int64)
        if problem.G is not None and problem.l is not None and problem.u is not None:
            self._iu = np.flatnonzero(np.isfinite(problem.u))
            self._il = np.flatnonzero(np.isfinite(problem.l))
            blocks += [problem.G[self._iu], -problem.G[self._il]]
            h_parts += [problem.u[self._iu], -problem.l[self._il]]
        lb, ub = vec(problem.lb), vec(problem.ub)
        if self.solver in _BOUNDS_AS_ROWS and lb is not None and ub is not None:
            eye = sp.identity(n, format="csr")
            self._ibu = np.flatnonzero(np.isfinite(ub))
            self._ibl = np.flatnonzero(np.isfinite(lb))
            blocks += [eye[self._ibu], -eye[self._ibl]]
            h_parts += [ub[self._ibu], -lb[self._ibl]]
            lb = ub = None
        n_rows = sum(b.shape[0] for b in blocks)
        G = sp.csc_matrix(sp.vstack(blocks)) if n_rows else None
        h = np.concatenate(h_parts) if n_rows else None
        self._qp = qpsolvers.Problem(
            P=mat(problem.P),
            q=np.array(problem.q, dtype=np.float64),
            G=mat(G),
            h=h,
            A=mat(problem.A_eq),
            b=vec(problem.b_eq),
            lb=lb,
            ub=ub,
        )

    def solve(self, warm_start: WarmStart | None) -> RawResult:
        """Solve once with :func:`qpsolvers.solve_problem`."""
        import qpsolvers

        z0, _ = warm_start_vectors(warm_start, self._n)
        if z0 is not None:
            z0 = np.array(z0, dtype=np.float64)  # writeable copy for the bindings
        options = {"verbose": False, **self.options}
        notes: list[str] = []
        start = time.perf_counter()
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            try:
                sol = qpsolvers.solve_problem(self._qp, self.solver, initvals=z0, **options)
            except (qpsolvers.QPError, ValueError, ArithmeticError) as exc:
                return RawResult(
                    status=SolverStatus.FAILED,
                    native_status=f"exception {type(exc).__name__}: {exc}",
                    z=None,
                    duals=None,
                    solve_time=time.perf_counter() - start,
                    iterations=None,
                )
        wall = time.perf_counter() - start
        notes.extend(
            str(w.message)
            for w in caught
            if not issubclass(w.category, DeprecationWarning | PendingDeprecationWarning)
        )
        status, native = self._status(sol)
        if native.startswith("unknown"):
            notes.append(native)
        z = duals = None
        if status.has_solution and sol.x is not None:
            z = np.array(sol.x, dtype=np.float64)
            duals = self._duals(sol)
        solve_time = getattr(sol, "solve_time", None)
        build_time = getattr(sol, "build_time", None)
        return RawResult(
            status=status,
            native_status=native,
            z=z,
            duals=duals,
            solve_time=wall if solve_time is None else float(solve_time),
            iterations=None,
            extra_setup_time=0.0 if build_time is None else float(build_time),
            notes=tuple(notes),
        )

    def _status(self, sol: Any) -> tuple[SolverStatus, str]:
        extractor = _NATIVE.get(self.solver)
        if extractor is not None:
            try:
                code = extractor[0](sol.extras)
            except (KeyError, AttributeError, TypeError):
                code = None
            if code is not None:
                status, note = map_status(extractor[1], code)
                return status, (note or f"{code}")
        if sol.found:
            return SolverStatus.OPTIMAL, "found=True (native status not exposed by qpsolvers)"
        return (
            SolverStatus.FAILED,
            "found=False (native status not exposed by qpsolvers; may be infeasible)",
        )

    def _duals(self, sol: Any) -> dict[str, FloatArray] | None:
        if sol.z is None and sol.y is None and sol.z_box is None:
            return None
        ineq = np.zeros(self._m)
        bounds = (
            np.zeros(self._n)
            if sol.z_box is None or np.size(sol.z_box) == 0
            else np.array(sol.z_box, dtype=np.float64).reshape(self._n)
        )
        if sol.z is not None:
            zz = np.asarray(sol.z, dtype=np.float64)
            off = 0
            for idx, sign, out in (
                (self._iu, 1.0, ineq),
                (self._il, -1.0, ineq),
                (self._ibu, 1.0, bounds),
                (self._ibl, -1.0, bounds),
            ):
                np.add.at(out, idx, sign * zz[off : off + idx.size])
                off += idx.size
        return {
            "eq": np.zeros(0) if sol.y is None else np.asarray(sol.y, dtype=np.float64),
            "ineq": ineq,
            "bounds": bounds,
        }


def factory(solver: str) -> Callable[[str, float, Mapping[str, Any]], Backend]:
    """Registry factory for ``"qpsolvers:<solver>"``."""

    def make(name: str, tolerance: float, settings: Mapping[str, Any]) -> Backend:
        return QpsolversBackend(name, solver, tolerance, settings)

    return make
