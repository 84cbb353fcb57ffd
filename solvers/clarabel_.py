r"""Native CLARABEL backend (``"clarabel"``): interior point, exact second-order cones, dense QPs.

CLARABEL (Goulart & Chen) solves

.. math::

    \min_x \tfrac12 x^\top P x + q^\top x \quad\text{s.t.}\quad A x + s = b,\; s \in \mathcal K

with :math:`\mathcal K` a product of zero, nonnegative and second-order cones. A
:class:`~ltv_lstm_mpc.solvers.DenseQP` maps onto it row block by row block, in
this order:

- zero cone: rows with ``lo == up`` (``A_i x = up_i``) and fixed variables (``lb == ub``);
- nonnegative cone: ``A_i x <= up_i`` and ``-A_i x <= -lo_i`` where finite, then the
  finite variable bounds ``x_j <= ub_j`` and ``-x_j <= -lb_j``;
- one second-order cone per :class:`~ltv_lstm_mpc.solvers.DenseCone`
  :math:`\|F x + g\| \le e^\top x + f`: :math:`s = (e^\top x + f, F x + g)`, i.e. the
  rows :math:`[-e^\top; -F]` with right-hand side :math:`[f; g]`.

``P`` is the upper triangle of ``H``. Every entry of the dense blocks is kept in the
sparsity pattern (zeros included) and the bound rows are unit rows, so the pattern
depends only on which bounds are finite: :meth:`ClarabelDense.update` writes new values
through CLARABEL's data update (no new factorization structure) and sets the workspace up
afresh only when that pattern changes. CLARABEL has no warm start (a warm start is ignored
with a note). ConvexProblems reach it through the generic dense adapter, cones included.

Iterative refinement of the KKT solves is off by default here
(``iterative_refinement_enable=False``; pass ``True`` to restore CLARABEL's default):
on the condensed exact-cone QPs of the pH benchmark (7 variables, 3 cones) it took a third
of the solve time (150 -> 104 us, the same 12 iterations, points within 6e-11). The
termination tests run on the unregularized residuals either way, so the tolerances hold;
without refinement an ill-conditioned problem may take more iterations instead.

Multipliers follow the dense layer's convention (``H x + f + A' y_ineq + y_bounds = 0``);
the cones' multipliers are in ``duals["cones"]`` (the cones' ``k + 1`` entries one after
the other, in the order of ``cones`` of :class:`~ltv_lstm_mpc.solvers.DenseQP`).
"""

from __future__ import annotations

import time
from collections.abc import Mapping
from typing import Any, ClassVar

import numpy as np
import scipy.sparse as sp

from ._base import (
    FloatArray,
    IntArray,
    RawResult,
    WarmStart,
    check_settings,
    map_status,
    warm_start_vectors,
)
from ._compiled import CompiledOrPython, bounds_rows_violation, cone_violation
from ._compiled import clarabel_cone_rows as _clarabel_cone_rows
from ._compiled import clarabel_fill as _clarabel_fill
from .compiled_forms import CompiledForm
from .dense import DenseBackend, DenseQP
from .problem import SolverStatus
from .tolerances import known_settings, solver_options

__all__ = ["STATUS_MAP", "ClarabelDense", "make_dense"]

# the compiled fill where it is ready, else its Python loops (no compile wait on numpy)
clarabel_cone_rows = CompiledOrPython(_clarabel_cone_rows)
clarabel_fill = CompiledOrPython(_clarabel_fill)


#: CLARABEL's ``SolverStatus`` name -> SolverStatus (also used by the qpsolvers backend).
STATUS_MAP: Mapping[str, SolverStatus] = {
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


def _index(idx: IntArray) -> IntArray | slice:
    """``idx`` as a slice where it is a contiguous range (views instead of copies)."""
    if idx.size == 0:
        return slice(0, 0)
    if idx[-1] - idx[0] + 1 == idx.size:
        return slice(int(idx[0]), int(idx[-1]) + 1)
    return idx


class ClarabelDense(DenseBackend):
    """Dense CLARABEL workspace with exact second-order cones (see the module docstring)."""

    backend: ClassVar[str] = "clarabel"
    supports_update: ClassVar[bool] = True
    supports_warm_start: ClassVar[bool] = False
    supports_cones: ClassVar[bool] = True

    def __init__(self, name: str, tolerance: float, settings: Mapping[str, Any]) -> None:
        """Check the settings against CLARABEL's and merge the tolerance options."""
        import clarabel

        check_settings("clarabel", settings, known_settings("clarabel"))
        super().__init__(name, "clarabel", solver_options("clarabel", tolerance, settings))
        self._clarabel = clarabel
        self._settings = clarabel.DefaultSettings()
        self._settings.verbose = False
        self._settings.iterative_refinement_enable = False  # see the module docstring
        for key, value in self.options.items():
            setattr(self._settings, key, value)
        self._solver: Any = None
        self._pattern = b""

    # ------------------------------------------------------------------------ structure
    @staticmethod
    def _finite_pattern(qp: DenseQP) -> bytes:
        """Which bounds are finite and which are equalities: the data the pattern depends on."""
        bounds = np.concatenate((qp.lo, qp.up, qp.lb, qp.ub))
        equal = np.concatenate((qp.lo == qp.up, qp.lb == qp.ub))
        return np.isfinite(bounds).tobytes() + equal.tobytes()

    def setup(self, qp: DenseQP) -> None:
        """Build the row blocks, the fixed sparsity pattern and the CLARABEL workspace."""
        clarabel = self._clarabel
        n = qp.n_variables
        eq_rows = np.flatnonzero(qp.lo == qp.up)
        eq_vars = np.flatnonzero(qp.lb == qp.ub)
        not_eq_row = qp.lo != qp.up
        not_eq_var = qp.lb != qp.ub
        up_rows = np.flatnonzero(np.isfinite(qp.up) & not_eq_row)
        lo_rows = np.flatnonzero(np.isfinite(qp.lo) & not_eq_row)
        ub_vars = np.flatnonzero(np.isfinite(qp.ub) & not_eq_var)
        lo_vars = np.flatnonzero(np.isfinite(qp.lb) & not_eq_var)
        self._eq_rows, self._up_rows, self._lo_rows = map(_index, (eq_rows, up_rows, lo_rows))
        self._eq_vars, self._ub_vars, self._lo_vars = map(_index, (eq_vars, ub_vars, lo_vars))
        self._has_eq = bool(eq_rows.size or eq_vars.size)
        n_zero = eq_rows.size + eq_vars.size
        n_rows_linear = up_rows.size + lo_rows.size
        n_bounds = ub_vars.size + lo_vars.size
        n_nonneg = n_rows_linear + n_bounds
        cone_dims = [c.dim + 1 for c in qp.cones]
        total = n_zero + n_nonneg + sum(cone_dims)
        # Dense image of the CLARABEL matrix (Fortran order: its ravel is CSC order).
        self._M = M = np.zeros((total, n), order="F")
        mask = np.zeros((total, n), dtype=bool)
        self._b = np.zeros(total)
        r = 0

        def dense_block(count: int) -> slice:
            """Rows copied from A or a cone: every entry is in the pattern."""
            nonlocal r
            rows = slice(r, r + count)
            mask[rows] = True
            r += count
            return rows

        def unit_block(variables: IntArray, sign: float) -> slice:
            """Rows sign * x_j of bounds: one constant entry per row."""
            nonlocal r
            rows = slice(r, r + variables.size)
            at = np.arange(rows.start, rows.stop)
            M[at, variables] = sign
            mask[at, variables] = True
            r = rows.stop
            return rows

        self._r_eq_rows = dense_block(eq_rows.size)
        self._r_eq_vars = unit_block(eq_vars, 1.0)
        self._r_up = dense_block(up_rows.size)
        self._r_lo = dense_block(lo_rows.size)
        self._r_ub = unit_block(ub_vars, 1.0)
        self._r_lb = unit_block(lo_vars, -1.0)
        self._r_cones = [dense_block(dim) for dim in cone_dims]
        self._A_take: IntArray = np.flatnonzero(mask.ravel(order="F"))
        # (kind, source, row) per bound / row entry, for the compiled fill (_compiled.py)
        entries = [
            (4, eq_rows, self._r_eq_rows), (5, eq_vars, self._r_eq_vars),
            (0, up_rows, self._r_up), (1, lo_rows, self._r_lo),
            (2, ub_vars, self._r_ub), (3, lo_vars, self._r_lb),
        ]  # fmt: skip
        self._blocks = np.array(
            [(kind, i, rows.start + k) for kind, src, rows in entries for k, i in enumerate(src)],
            dtype=np.int64,
        ).reshape(-1, 3)
        self._cone_start = np.array([rows.start for rows in self._r_cones], dtype=np.int64)
        _, cols = np.nonzero(mask.T)  # column-major: CSC order
        self._A_pattern = (cols.astype(np.int64), np.concatenate([[0], np.cumsum(mask.sum(0))]))
        # upper triangle of H, column by column (CSC order)
        iu_r, iu_c = np.triu_indices(n)
        order = np.lexsort((iu_r, iu_c))
        self._P_rows, self._P_cols = iu_r[order], iu_c[order]
        self._P_indptr = np.concatenate([[0], np.cumsum(np.arange(1, n + 1))]).astype(np.int64)
        self._A_data = np.empty(self._A_take.size)
        self._P_data = np.empty(self._P_rows.size)
        self._fill(qp)
        cones: list[Any] = []
        if n_zero:
            cones.append(clarabel.ZeroConeT(n_zero))
        if n_nonneg:
            cones.append(clarabel.NonnegativeConeT(n_nonneg))
        cones.extend(clarabel.SecondOrderConeT(d) for d in cone_dims)
        P = sp.csc_matrix((self._P_data, self._P_rows, self._P_indptr), shape=(n, n))
        A = sp.csc_matrix((self._A_data, self._A_pattern[0], self._A_pattern[1]), shape=(total, n))
        self._settings.input_sparse_dropzeros = False  # keep the pattern value-independent
        self._solver = clarabel.DefaultSolver(
            P, qp.f.copy(), A, self._b.copy(), cones, self._settings
        )
        self._pattern = self._finite_pattern(qp)
        self._n, self._m = n, qp.n_rows
        self._n_zero, self._n_nonneg = n_zero, n_nonneg

    def _fill(self, qp: DenseQP) -> None:
        """Write the values of ``qp`` into the dense image, ``b`` and the data vectors
        (one compiled call, ``solvers/_compiled.clarabel_fill``)."""
        M, b = self._M, self._b
        for start, cone in zip(self._cone_start.tolist(), qp.cones, strict=True):
            clarabel_cone_rows(cone.F, cone.g, cone.e, cone.f, start, M, b)
        clarabel_fill(
            qp.H, qp.A, qp.lo, qp.up, qp.lb, qp.ub, self._blocks, M, b, self._A_take,
            self._A_data, self._P_rows, self._P_cols, self._P_data,
        )  # fmt: skip

    def update(self, qp: DenseQP) -> None:
        """New values through CLARABEL's data update; a new finite pattern sets up afresh."""
        if self._finite_pattern(qp) != self._pattern:
            self.setup(qp)
            return
        self._fill(qp)
        self._solver.update(P=self._P_data, q=qp.f, A=self._A_data, b=self._b)

    # ---------------------------------------------------------------------------- solve
    def _solve(self) -> tuple[Any, SolverStatus, str, float]:
        start = time.perf_counter()
        solution = self._solver.solve()
        wall = time.perf_counter() - start
        native = str(solution.status)
        status, note = map_status(STATUS_MAP, native)
        return solution, status, native if note is None else f"{native}; {note}", wall

    def solve(self, warm_start: WarmStart | None) -> RawResult:
        """One CLARABEL solve (cold: CLARABEL has no warm start)."""
        notes: tuple[str, ...] = ()
        if warm_start is not None:
            warm_start_vectors(warm_start, self._n)  # validated, then ignored
            notes = ("warm start ignored: clarabel (interior point) has no warm start",)
        solution, status, native, wall = self._solve()
        if not status.has_solution:
            return RawResult(
                status=status,
                native_status=native,
                z=None,
                duals=None,
                solve_time=wall,
                iterations=int(solution.iterations),
                notes=notes,
                certificate=self._certificate(status, solution),
            )
        z = np.asarray(solution.x, dtype=np.float64)
        return RawResult(
            status=status,
            native_status=native,
            z=z,
            duals=self._split(np.asarray(solution.z, dtype=np.float64)),
            solve_time=wall,
            iterations=int(solution.iterations),
            notes=notes,
            objective=float(solution.obj_val),
        )

    def _split(self, y: FloatArray) -> dict[str, FloatArray]:
        """CLARABEL's conic multipliers (or Farkas vector) in the layer's convention."""
        ineq = np.zeros(self._m)
        bounds = np.zeros(self._n)  # (index sets are disjoint within ineq and within bounds)
        ineq[self._eq_rows] += y[self._r_eq_rows]
        ineq[self._up_rows] += y[self._r_up]
        ineq[self._lo_rows] -= y[self._r_lo]
        bounds[self._eq_vars] += y[self._r_eq_vars]
        bounds[self._ub_vars] += y[self._r_ub]
        bounds[self._lo_vars] -= y[self._r_lb]
        start = self._n_zero + self._n_nonneg
        return {"ineq": ineq, "bounds": bounds, "cones": y[start:].copy()}

    def _certificate(self, status: SolverStatus, solution: Any) -> dict[str, FloatArray] | None:
        """CLARABEL's certificate: ``z`` for infeasibility, ``x`` (a direction) for
        unboundedness (its documented meaning of the iterates at those statuses)."""
        if status is SolverStatus.INFEASIBLE:
            return self._split(np.asarray(solution.z, dtype=np.float64))
        if status is SolverStatus.UNBOUNDED:
            return {"direction": np.array(solution.x, dtype=np.float64)}
        return None

    def solve_point(self) -> tuple[SolverStatus, FloatArray | None, int, str]:
        """One CLARABEL solve without multipliers; the status mapped as in :meth:`solve`."""
        solution, status, native, _wall = self._solve()
        z = np.asarray(solution.x, dtype=np.float64) if status.has_solution else None
        return status, z, int(solution.iterations), native


def make_dense(name: str, tolerance: float, settings: Mapping[str, Any]) -> DenseBackend:
    """Registry dense factory for ``"clarabel"``."""
    return ClarabelDense(name, tolerance, settings)


def compiled_form(name: str) -> CompiledForm:
    """What ``"clarabel"`` gives compiled callers: no compiled solve, but its data fill loops
    and the dense layer's point checks, which run compiled where they are ready."""
    return CompiledForm(
        name=name,
        kernels=(_clarabel_fill, _clarabel_cone_rows, bounds_rows_violation, cone_violation),
    )
