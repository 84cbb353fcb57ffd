"""Native PIQP backend (``"piqp"``, ``"piqp:sparse"``, ``"piqp:dense"``): setup once, ``update``.

PIQP (a proximal interior-point method) takes the problem form of this layer
directly: ``A x = b``, ``h_l <= G x <= h_u``, ``x_l <= x <= x_u`` with infinite
entries allowed. ``"piqp"`` picks ``piqp.SparseSolver`` when the stacked data
``[P; A_eq; G]`` has density below 25 % (or more than 200 variables) and
``piqp.DenseSolver`` otherwise; the suffixed names force one.

PIQP has no warm start (interior-point iterates cannot be warm started
usefully); a warm start passed to it is ignored and said so in
``Solution.info``. ``compute_timings`` is switched on by default so that
``solve_time`` is PIQP's own.

:class:`PiqpDense` is the dense backend of ``"piqp"`` and ``"piqp:dense"`` for
:class:`~ltv_lstm_mpc.solvers.DenseSession`: a ``piqp.DenseSolver`` set up once
and updated in place (``G = A``, ``h_l = lo``, ``h_u = up``, ``x_l = lb``,
``x_u = ub``).
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any, ClassVar

import numpy as np
import numpy.typing as npt
import scipy.sparse as sp

from ._base import (
    Backend,
    RawResult,
    WarmStart,
    check_settings,
    map_status,
    warm_start_vectors,
)
from .dense import DenseBackend, DenseQP
from .problem import ConvexProblem, SolverStatus
from .tolerances import known_settings, solver_options

#: ``piqp.Status`` integer value -> SolverStatus.
STATUS_MAP: Mapping[int, SolverStatus] = {
    1: SolverStatus.OPTIMAL,  # PIQP_SOLVED
    -1: SolverStatus.MAX_ITER,  # PIQP_MAX_ITER_REACHED
    -2: SolverStatus.INFEASIBLE,  # PIQP_PRIMAL_INFEASIBLE
    -3: SolverStatus.UNBOUNDED,  # PIQP_DUAL_INFEASIBLE
    -8: SolverStatus.FAILED,  # PIQP_NUMERICS
    -9: SolverStatus.FAILED,  # PIQP_UNSOLVED
    -10: SolverStatus.FAILED,  # PIQP_INVALID_SETTINGS
}

#: Density of ``[P; A_eq; G]`` from which ``"piqp"`` uses the dense solver.
DENSE_THRESHOLD = 0.25
#: Above this many variables ``"piqp"`` always uses the sparse solver.
DENSE_MAX_VARIABLES = 200


def _vec(v: npt.NDArray[np.float64] | None) -> npt.NDArray[np.float64] | None:
    """Writeable copy (the problem's arrays are read-only; PIQP's binding rejects those)."""
    return None if v is None else np.array(v, dtype=np.float64)


def _is_dense_better(problem: ConvexProblem) -> bool:
    mats = [m for m in (problem.P, problem.A_eq, problem.G) if m is not None]
    rows = sum(m.shape[0] for m in mats)
    nnz = sum(m.nnz for m in mats)
    n = problem.n_variables
    return n <= DENSE_MAX_VARIABLES and nnz >= DENSE_THRESHOLD * rows * n


class PiqpBackend(Backend):
    """Persistent native PIQP workspace (sparse or dense)."""

    backend: ClassVar[str] = "piqp"
    supports_update: ClassVar[bool] = True
    supports_warm_start: ClassVar[bool] = False

    def __init__(self, name: str, tolerance: float, settings: Mapping[str, Any], kind: str) -> None:
        """``kind`` is ``"auto"``, ``"sparse"`` or ``"dense"``."""
        check_settings("piqp", settings, known_settings("piqp"))
        options = {
            "verbose": False,
            "compute_timings": True,
            **solver_options("piqp", tolerance, settings),
        }
        super().__init__(name, "piqp", options)
        self._kind = kind

    def _matrix(self, mat: sp.csc_matrix | None) -> Any:
        if mat is None:
            return None
        if self._dense:
            return np.asfortranarray(mat.toarray())
        return sp.csc_matrix(mat, copy=True)  # PIQP's binding needs writeable arrays

    def _data(self, problem: ConvexProblem) -> dict[str, Any]:
        P = sp.csc_matrix(sp.triu(problem.P, format="csc")) if not self._dense else problem.P
        return {
            "P": self._matrix(P),
            "c": _vec(problem.q),
            "A": self._matrix(problem.A_eq),
            "b": _vec(problem.b_eq),
            "G": self._matrix(problem.G),
            "h_l": _vec(problem.l),
            "h_u": _vec(problem.u),
            "x_l": _vec(problem.lb),
            "x_u": _vec(problem.ub),
        }

    def setup(self, problem: ConvexProblem) -> None:
        """Create the solver (sparse or dense) and run PIQP's setup."""
        import piqp

        self._dense = self._kind == "dense" or (self._kind == "auto" and _is_dense_better(problem))
        self._n = problem.n_variables
        self._p = problem.n_eq
        self._m = problem.n_ineq
        self._solver = piqp.DenseSolver() if self._dense else piqp.SparseSolver()
        for key, value in self.options.items():
            setattr(self._solver.settings, key, value)
        self._solver.setup(**self._data(problem))

    def update(self, problem: ConvexProblem) -> None:
        """Write new values (same patterns) with ``update``."""
        self._solver.update(**{k: v for k, v in self._data(problem).items() if v is not None})

    def solve(self, warm_start: WarmStart | None) -> RawResult:
        """Solve; a warm start is validated and then ignored (noted)."""
        z0, sol = warm_start_vectors(warm_start, self._n)
        notes = []
        if z0 is not None or sol is not None:
            notes.append("warm start ignored: PIQP (interior point) has no warm start")
        code = self._solver.solve()
        res = self._solver.result
        status, note = map_status(STATUS_MAP, int(code.value))
        if note:
            notes.append(note)
        z = duals = None
        if status.has_solution:
            z = np.array(res.x, dtype=np.float64)
            duals = {
                "eq": np.array(res.y, dtype=np.float64).reshape(self._p),
                "ineq": (np.asarray(res.z_u) - np.asarray(res.z_l)).reshape(self._m),
                "bounds": np.zeros(self._n)
                if len(res.z_bu) == 0
                else np.asarray(res.z_bu) - np.asarray(res.z_bl),
            }
        return RawResult(
            status=status,
            native_status=f"{code.name} ({int(code.value)})",
            z=z,
            duals=duals,
            solve_time=float(res.info.solve_time),
            iterations=int(res.info.iter),
            notes=tuple(notes),
        )


def make_auto(name: str, tolerance: float, settings: Mapping[str, Any]) -> Backend:
    """Registry factory for ``"piqp"`` (sparse or dense by density)."""
    return PiqpBackend(name, tolerance, settings, "auto")


def make_sparse(name: str, tolerance: float, settings: Mapping[str, Any]) -> Backend:
    """Registry factory for ``"piqp:sparse"``."""
    return PiqpBackend(name, tolerance, settings, "sparse")


def make_dense(name: str, tolerance: float, settings: Mapping[str, Any]) -> Backend:
    """Registry factory for ``"piqp:dense"``."""
    return PiqpBackend(name, tolerance, settings, "dense")


class PiqpDense(DenseBackend):
    """Dense PIQP workspace (``piqp.DenseSolver``), set up once, ``update`` in place."""

    backend: ClassVar[str] = "piqp"
    supports_update: ClassVar[bool] = True
    supports_warm_start: ClassVar[bool] = False

    def __init__(self, name: str, tolerance: float, settings: Mapping[str, Any]) -> None:
        """Merge tolerance options and settings and check the setting names."""
        import piqp

        check_settings("piqp", settings, known_settings("piqp"))
        options = {
            "verbose": False,
            "compute_timings": True,
            **solver_options("piqp", tolerance, settings),
        }
        super().__init__(name, "piqp", options)
        self._piqp = piqp

    @staticmethod
    def _data(qp: DenseQP) -> dict[str, Any]:
        data: dict[str, Any] = {"P": qp.H, "c": qp.f, "x_l": qp.lb, "x_u": qp.ub}
        if qp.A.shape[0]:
            data.update(G=qp.A, h_l=qp.lo, h_u=qp.up)
        return data

    def setup(self, qp: DenseQP) -> None:
        """Create the dense solver and run PIQP's setup."""
        self._n, self._m = qp.n_variables, qp.n_rows
        solver = self._piqp.DenseSolver()
        for key, value in self.options.items():
            setattr(solver.settings, key, value)
        solver.setup(**self._data(qp))
        self._solver = solver

    def update(self, qp: DenseQP) -> None:
        """Write new values with ``update``."""
        self._solver.update(**self._data(qp))

    def solve(self, warm_start: WarmStart | None) -> RawResult:
        """Solve; a warm start is ignored (noted)."""
        notes: tuple[str, ...] = ()
        if warm_start is not None:
            warm_start_vectors(warm_start, self._n)  # validated, then ignored
            notes = ("warm start ignored: PIQP (interior point) has no warm start",)
        code = self._solver.solve()
        res = self._solver.result
        status, note = map_status(STATUS_MAP, int(code.value))
        if note:
            notes = (*notes, note)
        z = duals = None
        if status.has_solution:
            z = np.array(res.x, dtype=np.float64)
            ineq = np.asarray(res.z_u) - np.asarray(res.z_l) if self._m else np.zeros(0)
            duals = {
                "ineq": np.asarray(ineq, dtype=np.float64).reshape(self._m),
                "bounds": np.asarray(res.z_bu, dtype=np.float64)
                - np.asarray(res.z_bl, dtype=np.float64),
            }
        return RawResult(
            status=status,
            native_status=f"{code.name} ({int(code.value)})",
            z=z,
            duals=duals,
            solve_time=float(res.info.solve_time),
            iterations=int(res.info.iter),
            notes=notes,
        )


def make_dense_qp(name: str, tolerance: float, settings: Mapping[str, Any]) -> DenseBackend:
    """Registry dense factory for ``"piqp"`` and ``"piqp:dense"``."""
    return PiqpDense(name, tolerance, settings)
