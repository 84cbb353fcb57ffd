"""Native quadprog backend (``"quadprog"``): Goldfarb-Idnani dual active set, dense.

quadprog solves ``min 1/2 x'Gx - a'x  s.t.  C'x >= b`` (the first ``meq``
columns of ``C`` equalities) and needs a symmetric positive definite ``G``. It
has no workspace and no settings: a solve builds ``C`` from the finite bounds
(rows with ``lo == up`` become equalities) on buffers preallocated at setup.
It solves to machine precision (no tolerance option) and has no warm start (a
warm start is ignored with a note).

quadprog reports infeasibility and a non-positive-definite ``G`` by raising
``ValueError``; those two messages are statuses (:data:`STATUS_MAP`), any other
exception propagates. ConvexProblems go through the generic dense adapter
(equalities become rows with ``lo = up``; cones are refused).
"""

from __future__ import annotations

import time
from collections.abc import Mapping
from typing import Any, ClassVar

import numpy as np

from ._base import RawResult, WarmStart, check_settings, map_status, warm_start_vectors
from .dense import DenseBackend, DenseQP
from .problem import SolverStatus
from .tolerances import known_settings, solver_options

#: quadprog outcome (``"optimal"`` or the ``ValueError`` message) -> SolverStatus.
STATUS_MAP: Mapping[str, SolverStatus] = {
    "optimal": SolverStatus.OPTIMAL,
    "constraints are inconsistent, no solution": SolverStatus.INFEASIBLE,
    "matrix G is not positive definite": SolverStatus.FAILED,
}


class QuadprogDense(DenseBackend):
    """Dense quadprog backend (no workspace: ``update`` stores the values)."""

    backend: ClassVar[str] = "quadprog"
    supports_update: ClassVar[bool] = True
    supports_warm_start: ClassVar[bool] = False

    def __init__(self, name: str, tolerance: float, settings: Mapping[str, Any]) -> None:
        """Check the settings (quadprog has none) and the tolerance."""
        import quadprog

        check_settings("quadprog", settings, known_settings("quadprog"))
        super().__init__(name, "quadprog", solver_options("quadprog", tolerance, settings))
        self._solve_qp = quadprog.solve_qp

    def setup(self, qp: DenseQP) -> None:
        """Preallocate ``[I; -I; A; -A]`` and the right-hand side."""
        n, m = qp.n_variables, qp.n_rows
        self._n, self._m = n, m
        self._C = np.zeros((2 * n + 2 * m, n))
        self._C[:n] = np.eye(n)
        self._C[n : 2 * n] = -np.eye(n)
        self._b = np.empty(2 * n + 2 * m)
        self.update(qp)

    def update(self, qp: DenseQP) -> None:
        """Write ``A`` and the bounds into the buffers."""
        n, m = self._n, self._m
        C, b = self._C, self._b
        C[2 * n : 2 * n + m] = qp.A
        np.negative(qp.A, out=C[2 * n + m :])
        b[:n] = qp.lb
        np.negative(qp.ub, out=b[n : 2 * n])
        b[2 * n : 2 * n + m] = qp.lo
        np.negative(qp.up, out=b[2 * n + m :])
        self._eq = np.flatnonzero(qp.lo == qp.up)
        self._H = qp.H
        self._a = -qp.f

    def solve(self, warm_start: WarmStart | None) -> RawResult:
        """One ``quadprog.solve_qp`` call."""
        n, m = self._n, self._m
        b = self._b
        keep = np.isfinite(b)
        eq = self._eq
        if eq.size:
            keep[2 * n + eq] = False  # the lo row of an equality goes first as an equality,
            keep[2 * n + m + eq] = False  # its up row is dropped
            idx = np.concatenate([2 * n + eq, np.flatnonzero(keep)])
        else:
            idx = np.flatnonzero(keep)
        notes: tuple[str, ...] = ()
        if warm_start is not None:
            warm_start_vectors(warm_start, n)  # validated, then ignored
            notes = ("warm start ignored: quadprog has no warm start",)
        start = time.perf_counter()
        try:
            if idx.size:
                x, _f, _xu, iters, lagr, _act = self._solve_qp(
                    self._H, self._a, self._C[idx].T, b[idx], int(eq.size)
                )
            else:
                x, _f, _xu, iters, lagr, _act = self._solve_qp(self._H, self._a)
        except ValueError as exc:
            message = str(exc)
            if message not in STATUS_MAP:
                raise
            return RawResult(
                status=STATUS_MAP[message],
                native_status=message,
                z=None,
                duals=None,
                solve_time=time.perf_counter() - start,
                iterations=None,
                notes=notes,
            )
        wall = time.perf_counter() - start
        status, note = map_status(STATUS_MAP, "optimal")
        # KKT: H x + f = C lam; row i of the stacked [I; -I; A; -A] has sign +1/-1.
        y = np.zeros(2 * n + 2 * m)
        y[idx] = np.asarray(lagr, dtype=np.float64)
        bounds = y[n : 2 * n] - y[:n]
        ineq = y[2 * n + m :] - y[2 * n : 2 * n + m]
        return RawResult(
            status=status,
            native_status="optimal",
            z=np.asarray(x, dtype=np.float64),
            duals={"ineq": ineq, "bounds": bounds},
            solve_time=wall,
            iterations=int(iters[0]),
            notes=notes if note is None else (*notes, note),
        )


def make_dense(name: str, tolerance: float, settings: Mapping[str, Any]) -> DenseBackend:
    """Registry dense factory for ``"quadprog"``."""
    return QuadprogDense(name, tolerance, settings)
