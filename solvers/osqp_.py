"""Native OSQP backend (``"osqp"``): set up once, ``update`` values, warm start.

OSQP solves ``min 1/2 x'Px + q'x  s.t.  l <= A x <= u``; the problem is mapped to
``A = [A_eq; G; I_bounds]`` (only the variables with a finite bound get a row)
and the upper triangle of ``P``. The sparsity patterns are fixed at setup and
values are written with ``OSQP.update(q=, l=, u=, Px=, Ax=)`` (osqp-python 1.x).

:class:`OsqpDense` is the dense backend (:class:`~ltv_lstm_mpc.solvers.DenseSession`):
a fixed dense pattern (the whole upper triangle of ``H``, ``[I; A]`` with every
entry), so any new values are one ``update`` away. ``warm_start=None`` resets
the iterates to zero, a :class:`Solution` restarts from its primal and dual
point, an array from that primal point.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from typing import Any, ClassVar

import numpy as np
import scipy.sparse as sp

from ._base import (
    Backend,
    FloatArray,
    RawResult,
    StackedMatrix,
    WarmStart,
    bound_rows,
    check_settings,
    map_status,
    warm_start_vectors,
)
from .dense import DenseBackend, DenseQP
from .problem import ConvexProblem, SolverStatus
from .tolerances import known_settings, solver_options

#: osqp ``info.status_val`` -> SolverStatus (osqp.SolverStatus in osqp-python 1.x).
STATUS_MAP: Mapping[int, SolverStatus] = {
    1: SolverStatus.OPTIMAL,  # OSQP_SOLVED
    2: SolverStatus.OPTIMAL_INACCURATE,  # OSQP_SOLVED_INACCURATE
    3: SolverStatus.INFEASIBLE,  # OSQP_PRIMAL_INFEASIBLE
    4: SolverStatus.INFEASIBLE,  # OSQP_PRIMAL_INFEASIBLE_INACCURATE
    5: SolverStatus.UNBOUNDED,  # OSQP_DUAL_INFEASIBLE
    6: SolverStatus.UNBOUNDED,  # OSQP_DUAL_INFEASIBLE_INACCURATE
    7: SolverStatus.MAX_ITER,  # OSQP_MAX_ITER_REACHED
    8: SolverStatus.MAX_ITER,  # OSQP_TIME_LIMIT_REACHED
    9: SolverStatus.FAILED,  # OSQP_NON_CVX
    10: SolverStatus.FAILED,  # OSQP_SIGINT
    11: SolverStatus.FAILED,  # OSQP_UNSOLVED
}


def _upper_mask(P: sp.csc_matrix) -> np.ndarray:
    cols = np.repeat(np.arange(P.shape[1]), np.diff(P.indptr))
    return np.asarray(P.indices <= cols)


class OsqpBackend(Backend):
    """Persistent native OSQP workspace."""

    backend: ClassVar[str] = "osqp"
    supports_update: ClassVar[bool] = True
    supports_warm_start: ClassVar[bool] = True

    def __init__(self, name: str, tolerance: float, settings: Mapping[str, Any]) -> None:
        """Merge tolerance options and settings and check the setting names."""
        check_settings("osqp", settings, known_settings("osqp"))
        options = {"verbose": False, **solver_options("osqp", tolerance, settings)}
        super().__init__(name, "osqp", options)

    def _vectors(self, problem: ConvexProblem) -> tuple[FloatArray, FloatArray]:
        lo = [np.asarray(problem.b_eq)] if problem.b_eq is not None else []
        hi = [np.asarray(problem.b_eq)] if problem.b_eq is not None else []
        if problem.G is not None:
            lo.append(np.asarray(problem.l))
            hi.append(np.asarray(problem.u))
        if self._bidx.size:
            lo.append(np.asarray(problem.lb)[self._bidx])
            hi.append(np.asarray(problem.ub)[self._bidx])
        if not lo:
            return np.zeros(0), np.zeros(0)
        return np.concatenate(lo), np.concatenate(hi)

    def _blocks(self, problem: ConvexProblem) -> list[sp.csc_matrix]:
        blocks = [m for m in (problem.A_eq, problem.G) if m is not None]
        if self._bidx.size:
            blocks.append(self._bsel)
        return blocks

    def setup(self, problem: ConvexProblem) -> None:
        """Create the OSQP workspace."""
        import osqp

        self._n = problem.n_variables
        self._p = problem.n_eq
        self._m = problem.n_ineq
        self._bidx, self._bsel = bound_rows(problem)
        self._upper = _upper_mask(problem.P)
        self._stack = StackedMatrix(self._blocks(problem), self._n)
        A = self._stack.matrix
        l, u = self._vectors(problem)
        P_up = sp.csc_matrix(sp.triu(problem.P, format="csc"))
        self._solver = osqp.OSQP()
        self._solver.setup(P=P_up, q=np.asarray(problem.q), A=A, l=l, u=u, **self.options)
        self._n_rows = A.shape[0]

    def update(self, problem: ConvexProblem) -> None:
        """Write new values into the workspace (``Px``, ``Ax``, ``q``, ``l``, ``u``)."""
        l, u = self._vectors(problem)
        kwargs: dict[str, Any] = {
            "q": np.asarray(problem.q),
            "Px": np.asarray(problem.P.data)[self._upper],
        }
        if self._n_rows:
            kwargs.update(l=l, u=u, Ax=self._stack.values(self._blocks(problem)))
        self._solver.update(**kwargs)

    def solve(self, warm_start: WarmStart | None) -> RawResult:
        """Solve; ``warm_start=None`` resets OSQP's iterates to zero (a cold start)."""
        z0, sol = warm_start_vectors(warm_start, self._n)
        y0 = np.zeros(self._n_rows)
        if sol is not None and sol.duals is not None:
            eq, ineq, bnd = (sol.duals.get(k) for k in ("eq", "ineq", "bounds"))
            if (
                eq is not None
                and ineq is not None
                and bnd is not None
                and (eq.shape, ineq.shape, bnd.shape) == ((self._p,), (self._m,), (self._n,))
            ):
                y0 = np.concatenate([eq, ineq, bnd[self._bidx]])
        self._solver.warm_start(x=np.zeros(self._n) if z0 is None else z0, y=y0)
        res = self._solver.solve(raise_error=False)
        info = res.info
        status, note = map_status(STATUS_MAP, int(info.status_val))
        z = np.array(res.x, dtype=np.float64) if status.has_solution else None
        duals = None
        if status.has_solution:
            duals = self._split(np.asarray(res.y, dtype=np.float64))
        return RawResult(
            status=status,
            native_status=f"{info.status} ({info.status_val})",
            z=z,
            duals=duals,
            solve_time=float(info.solve_time) + float(info.polish_time),
            iterations=int(info.iter),
            notes=() if note is None else (note,),
            certificate=_certificate(status, res, self._split),
        )

    def _split(self, y: FloatArray) -> dict[str, FloatArray]:
        """Row multipliers (or a Farkas vector) split into ``eq``, ``ineq``, ``bounds``."""
        bnd = np.zeros(self._n)
        bnd[self._bidx] = y[self._p + self._m :]
        return {
            "eq": y[: self._p].copy(),
            "ineq": y[self._p : self._p + self._m].copy(),
            "bounds": bnd,
        }


def _certificate(
    status: SolverStatus, res: Any, split: Callable[[FloatArray], dict[str, FloatArray]]
) -> dict[str, FloatArray] | None:
    """OSQP's certificate of infeasibility (``prim_inf_cert``, split like the multipliers)
    or of unboundedness (``dual_inf_cert``, a direction); ``None`` for other statuses."""
    if status is SolverStatus.INFEASIBLE and res.prim_inf_cert is not None:
        return split(np.array(res.prim_inf_cert, dtype=np.float64))
    if status is SolverStatus.UNBOUNDED and res.dual_inf_cert is not None:
        return {"direction": np.array(res.dual_inf_cert, dtype=np.float64)}
    return None


def make(name: str, tolerance: float, settings: Mapping[str, Any]) -> Backend:
    """Registry factory."""
    return OsqpBackend(name, tolerance, settings)


class OsqpDense(DenseBackend):
    """OSQP on a fixed dense pattern (upper triangle of ``H``, ``[I; A]``), ``update`` in place."""

    backend: ClassVar[str] = "osqp"
    supports_update: ClassVar[bool] = True
    supports_warm_start: ClassVar[bool] = True

    def __init__(self, name: str, tolerance: float, settings: Mapping[str, Any]) -> None:
        """Merge tolerance options and settings and check the setting names."""
        import osqp

        check_settings("osqp", settings, known_settings("osqp"))
        options = {"verbose": False, **solver_options("osqp", tolerance, settings)}
        super().__init__(name, "osqp", options)
        self._osqp = osqp

    def setup(self, qp: DenseQP) -> None:
        """Build the fixed patterns and the OSQP workspace."""
        n, m = qp.n_variables, qp.n_rows
        self._n, self._m = n, m
        cols = np.repeat(np.arange(n), np.arange(1, n + 1))
        rows = np.concatenate([np.arange(j + 1) for j in range(n)])
        self._p_idx = (rows, cols)  # CSC order of the upper triangle
        P = sp.csc_matrix(
            (qp.H[self._p_idx], rows, np.concatenate([[0], np.cumsum(np.arange(1, n + 1))])),
            shape=(n, n),
        )
        # [I; A] in CSC: column j holds (j, 1) then (n + i, A[i, j]) for every i.
        self._Ax2 = np.empty((n, 1 + m))
        self._Ax2[:, 0] = 1.0
        self._Ax2[:, 1:] = qp.A.T
        indices = np.empty((n, 1 + m), dtype=np.int64)
        indices[:, 0] = np.arange(n)
        indices[:, 1:] = n + np.arange(m)
        A = sp.csc_matrix(
            (self._Ax2.ravel(), indices.ravel(), np.arange(n + 1) * (1 + m)), shape=(n + m, n)
        )
        self._l = np.concatenate([qp.lb, qp.lo])
        self._u = np.concatenate([qp.ub, qp.up])
        self._y0 = np.zeros(n + m)
        self._x0 = np.zeros(n)
        solver = self._osqp.OSQP()
        solver.setup(P=P, q=qp.f, A=A, l=self._l, u=self._u, **self.options)
        self._solver = solver

    def update(self, qp: DenseQP) -> None:
        """Write ``H``, ``f``, ``A`` and the bounds with one ``update``."""
        n = self._n
        self._Ax2[:, 1:] = qp.A.T
        self._l[:n] = qp.lb
        self._l[n:] = qp.lo
        self._u[:n] = qp.ub
        self._u[n:] = qp.up
        self._solver.update(
            q=qp.f, l=self._l, u=self._u, Px=qp.H[self._p_idx], Ax=self._Ax2.ravel()
        )

    def solve(self, warm_start: WarmStart | None) -> RawResult:
        """Solve from zero (``None``), a previous solution, or a primal point."""
        n = self._n
        if warm_start is None:
            self._solver.warm_start(x=self._x0, y=self._y0)
        else:
            z0, sol = warm_start_vectors(warm_start, n)
            y0 = self._y0
            if sol is not None and sol.duals is not None:
                bnd, ineq = sol.duals.get("bounds"), sol.duals.get("ineq")
                if bnd is not None and ineq is not None and bnd.shape == (n,):
                    if ineq.shape == (self._m,):
                        y0 = np.concatenate([bnd, ineq])
            self._solver.warm_start(x=self._x0 if z0 is None else z0, y=y0)
        res = self._solver.solve(raise_error=False)
        info = res.info
        status, note = map_status(STATUS_MAP, int(info.status_val))
        z = duals = None
        if status.has_solution:
            z = np.array(res.x, dtype=np.float64)
            y = np.array(res.y, dtype=np.float64)
            duals = {"ineq": y[n:], "bounds": y[:n]}
        return RawResult(
            status=status,
            native_status=f"{info.status} ({info.status_val})",
            z=z,
            duals=duals,
            solve_time=float(info.solve_time) + float(info.polish_time),
            iterations=int(info.iter),
            notes=() if note is None else (note,),
            certificate=_certificate(
                status, res, lambda y: {"ineq": y[n:].copy(), "bounds": y[:n].copy()}
            ),
        )


def make_dense(name: str, tolerance: float, settings: Mapping[str, Any]) -> DenseBackend:
    """Registry dense factory for ``"osqp"``."""
    return OsqpDense(name, tolerance, settings)
