"""qpsolvers backend (``"qpsolvers:<name>"``): every solver qpsolvers finds installed.

The problem is passed as a :class:`qpsolvers.Problem` (``G z <= h``, ``A z = b``,
``lb <= z <= ub``): the two-sided rows ``l <= G z <= u`` become the finite
rows of ``G z <= u`` and ``-G z <= -l``. Matrices are CSC for the solvers in
``qpsolvers.sparse_solvers`` and dense arrays otherwise.

:class:`DenseQpsolversBackend` is the dense backend of the same names (for
:class:`~ltv_lstm_mpc.solvers.DenseSession`): rows with ``lo = up`` become
equalities ``A_eq x = b``, the others ``lo <= A x <= up`` the finite rows of
``A x <= up`` and ``-A x <= -lo``; it stores the values at ``update`` and calls
qpsolvers at ``solve``.

The setting ``tolerance_options=False`` passes the other settings as given, without this
layer's tolerance options (:func:`~ltv_lstm_mpc.solvers.tolerances.solver_options`): the
solver's own defaults wherever they set none, as benchmark harnesses such as qpbenchmark
call it (``ltv-lstm-mpc bench --qpbenchmark-set``); the session's ``tolerance`` still sets
the acceptance check.

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

import dataclasses
import time
import warnings
from collections.abc import Callable, Mapping
from typing import Any, ClassVar

import numpy as np
import scipy.sparse as sp

from ltv_lstm_mpc.exceptions import InvalidValueError

from . import daqp_, osqp_, piqp_, proxqp_
from ._base import (
    Backend,
    FloatArray,
    RawResult,
    WarmStart,
    check_settings,
    map_status,
    warm_start_vectors,
)
from .clarabel_ import STATUS_MAP as CLARABEL_STATUS_MAP
from .dense import DenseBackend, DenseQP
from .problem import ConvexProblem, SolverStatus
from .tolerances import known_settings, solver_options

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

#: proxsuite status table (the one of the native backend, :mod:`.proxqp_`).
PROXQP_STATUS_MAP = proxqp_.STATUS_MAP


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


class _QpsolversCore:
    """Conversion to :class:`qpsolvers.Problem` and the call, shared by both backends."""

    solver: str
    options: dict[str, Any]

    def _init_core(
        self, solver: str, tolerance: float, settings: Mapping[str, Any]
    ) -> dict[str, Any]:
        settings = dict(settings)
        own = settings.pop("tolerance_options", True)
        if not isinstance(own, bool):
            raise InvalidValueError(
                f"tolerance_options must be True or False, got {own!r} (False: the solver's "
                "own tolerance defaults, the other settings as given)"
            )
        known = known_settings(solver)
        if known is not None:
            known = (*known, *_INTERFACE_SETTINGS.get(solver, ()))
        check_settings(solver, settings, known)
        if not own:
            solver_options(solver, tolerance, {})  # (checks the tolerance)
            return settings
        return solver_options(solver, tolerance, settings)

    def _build(
        self,
        P: Any,
        q: FloatArray,
        A_eq: Any,
        b_eq: FloatArray | None,
        G: Any,
        l: FloatArray | None,
        u: FloatArray | None,
        lb: FloatArray | None,
        ub: FloatArray | None,
    ) -> None:
        """Store a :class:`qpsolvers.Problem` (matrices sparse or dense as the solver prefers).

        All arrays are copied (read-only arrays are rejected by some bindings).
        For the solvers in :data:`_BOUNDS_AS_ROWS` the finite variable bounds
        become rows of ``G`` (ECOS rejects infinite bounds).
        """
        import qpsolvers

        sparse = self.solver in qpsolvers.sparse_solvers

        def mat(m: Any) -> Any:
            if m is None:
                return None
            if sparse:
                return sp.csc_matrix(m, dtype=np.float64, copy=True)
            return m.toarray() if sp.issparse(m) else np.array(m, dtype=np.float64)

        def vec(v: FloatArray | None) -> FloatArray | None:
            return None if v is None else np.array(v, dtype=np.float64)

        stack = (lambda bs: sp.csc_matrix(sp.vstack(bs))) if sparse else np.vstack
        n = int(np.shape(q)[0])
        self._n = n
        self._m = 0 if G is None else int(G.shape[0])
        blocks: list[Any] = []
        h_parts: list[FloatArray] = []
        self._iu = self._il = self._ibu = self._ibl = np.zeros(0, dtype=np.int64)
        if G is not None and l is not None and u is not None:
            Gm = mat(G)
            if sparse:
                Gm = sp.csr_matrix(Gm)
            self._iu = np.flatnonzero(np.isfinite(u))
            self._il = np.flatnonzero(np.isfinite(l))
            blocks += [Gm[self._iu], -Gm[self._il]]
            h_parts += [np.asarray(u)[self._iu], -np.asarray(l)[self._il]]
        lbv, ubv = vec(lb), vec(ub)
        if self.solver in _BOUNDS_AS_ROWS and lbv is not None and ubv is not None:
            eye = sp.identity(n, format="csr") if sparse else np.eye(n)
            self._ibu = np.flatnonzero(np.isfinite(ubv))
            self._ibl = np.flatnonzero(np.isfinite(lbv))
            blocks += [eye[self._ibu], -eye[self._ibl]]
            h_parts += [ubv[self._ibu], -lbv[self._ibl]]
            lbv = ubv = None
        n_rows = sum(b.shape[0] for b in blocks)
        G_all = stack(blocks) if n_rows else None
        h = np.concatenate(h_parts) if n_rows else None
        if A_eq is not None and A_eq.shape[0] == 0:  # zero rows: none (quadprog and SCS
            A_eq = b_eq = None  # fail on an empty equality block)
        self._qp = qpsolvers.Problem(
            P=mat(P),
            q=np.array(q, dtype=np.float64),
            G=G_all,
            h=h,
            A=mat(A_eq),
            b=vec(b_eq),
            lb=lbv,
            ub=ubv,
        )

    def _run(self, warm_start: WarmStart | None) -> RawResult:
        """Solve once with :func:`qpsolvers.solve_problem`."""
        import qpsolvers

        z0, _ = warm_start_vectors(warm_start, self._n)
        if z0 is not None:
            z0 = np.array(z0, dtype=np.float64)  # writeable copy for the bindings
        options = {"verbose": False, **self.options}
        notes: list[str] = []
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            start = time.perf_counter()  # the qpsolvers call alone
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
        # the solver's own solve time where qpsolvers reports it; the rest of the call
        # (qpsolvers' conversions, the solver's build) is setup: the two add up to the call
        solve_time = getattr(sol, "solve_time", None)
        solve = wall if solve_time is None else min(float(solve_time), wall)
        return RawResult(
            status=status,
            native_status=native,
            z=z,
            duals=duals,
            solve_time=solve,
            iterations=None,
            extra_setup_time=wall - solve,
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


class QpsolversBackend(_QpsolversCore, Backend):
    """Calls :func:`qpsolvers.solve_problem` on stored data (no in-place update)."""

    backend: ClassVar[str] = "qpsolvers"
    supports_update: ClassVar[bool] = False
    supports_warm_start: ClassVar[bool] = True

    def __init__(
        self, name: str, solver: str, tolerance: float, settings: Mapping[str, Any]
    ) -> None:
        """``solver`` is the qpsolvers name (``"osqp"``, ``"quadprog"``, ...)."""
        Backend.__init__(self, name, solver, self._init_core(solver, tolerance, settings))

    def setup(self, problem: ConvexProblem) -> None:
        """Convert to a :class:`qpsolvers.Problem` (sparse or dense as the solver prefers)."""
        self._build(
            problem.P,
            problem.q,
            problem.A_eq,
            problem.b_eq,
            problem.G,
            problem.l,
            problem.u,
            problem.lb,
            problem.ub,
        )

    def solve(self, warm_start: WarmStart | None) -> RawResult:
        """Solve once with :func:`qpsolvers.solve_problem`."""
        return self._run(warm_start)


class DenseQpsolversBackend(_QpsolversCore, DenseBackend):
    """Dense QPs through :func:`qpsolvers.solve_problem` (no workspace; ``update`` stores)."""

    backend: ClassVar[str] = "qpsolvers"
    supports_update: ClassVar[bool] = True
    supports_warm_start: ClassVar[bool] = True

    def __init__(
        self, name: str, solver: str, tolerance: float, settings: Mapping[str, Any]
    ) -> None:
        """``solver`` is the qpsolvers name (``"osqp"``, ``"quadprog"``, ...)."""
        DenseBackend.__init__(self, name, solver, self._init_core(solver, tolerance, settings))

    def setup(self, qp: DenseQP) -> None:
        """Convert to a :class:`qpsolvers.Problem`."""
        self.update(qp)

    def update(self, qp: DenseQP) -> None:
        """Convert the new values (qpsolvers has no workspace to update)."""
        eq = qp.lo == qp.up
        self._eq = np.flatnonzero(eq) if eq.any() else None
        if self._eq is None:
            G = qp.A if qp.A.shape[0] else None
            lo = qp.lo if G is not None else None
            up = qp.up if G is not None else None
            self._build(qp.H, qp.f, None, None, G, lo, up, qp.lb, qp.ub)
            return
        ineq = ~eq
        self._ineq = np.flatnonzero(ineq)
        Gi = qp.A[ineq] if ineq.any() else None
        self._build(
            qp.H,
            qp.f,
            qp.A[eq],
            qp.lo[eq],
            Gi,
            None if Gi is None else qp.lo[ineq],
            None if Gi is None else qp.up[ineq],
            qp.lb,
            qp.ub,
        )

    def solve(self, warm_start: WarmStart | None) -> RawResult:
        """Solve once with :func:`qpsolvers.solve_problem` (duals without ``"eq"``)."""
        raw = self._run(warm_start)
        if raw.duals is not None:
            duals = {k: v for k, v in raw.duals.items() if k != "eq"}
            if self._eq is not None:
                rows = np.zeros(self._eq.size + self._ineq.size)
                rows[self._eq] = raw.duals["eq"]
                rows[self._ineq] = raw.duals["ineq"]
                duals["ineq"] = rows
            raw = dataclasses.replace(raw, duals=duals)
        return raw


def factory(solver: str) -> Callable[[str, float, Mapping[str, Any]], Backend]:
    """Registry factory for ``"qpsolvers:<solver>"``."""

    def make(name: str, tolerance: float, settings: Mapping[str, Any]) -> Backend:
        return QpsolversBackend(name, solver, tolerance, settings)

    return make


def dense_factory(solver: str) -> Callable[[str, float, Mapping[str, Any]], DenseBackend]:
    """Registry dense factory for ``"qpsolvers:<solver>"``."""

    def make(name: str, tolerance: float, settings: Mapping[str, Any]) -> DenseBackend:
        return DenseQpsolversBackend(name, solver, tolerance, settings)

    return make
