"""cvxpy backend (``"cvxpy:<SOLVER>"``): one DPP problem per structure, re-solved with new values.

Construction (once per :meth:`ConvexProblem.structure_key`)
    All matrix nonzeros live in ONE parameter vector ``theta`` and all vector
    data in ONE parameter vector ``beta`` (PERF-NOTES: one parameter per stage
    made assignment alone cost milliseconds). A sparse product ``M z`` is
    written with the *parameter-on-nonzeros* trick,

    .. math:: M z = R \\,(\\theta_M \\circ (C z)),

    where the constant selectors ``C`` (nnz x n, picks ``z[col_k]``) and ``R``
    (rows x nnz, sums into ``row_k``) encode the pattern; ``theta_M * (C z)`` is
    a parameter times a parameter-free expression, so the problem is DPP and
    cvxpy caches its canonicalization after the first solve.

Objective
    ``quad_form(z, P)`` with a parameter ``P`` is not DPP, so the objective is
    ``1/2 ||L z||^2 + q'z`` with ``L'L = P``. ``L`` has a fixed pattern: one
    dense block per connected component of the sparsity graph of ``P``
    (``L_k = diag(sqrt(max(w, 0))) V'`` from ``eigh`` of the block, batched over
    blocks of equal size), so block-diagonal MPC Hessians stay cheap.

Infinite bounds
    Only rows with a finite ``l``/``u``/``lb``/``ub`` are constraints; which
    ones is part of the structure key.

Timing
    ``setup_time`` is the construction of the ``cp.Problem`` plus the solver's
    own setup time when cvxpy reports one; ``solve_time`` is
    ``problem.solver_stats.solve_time``; ``overhead_time`` is everything else
    of ``problem.solve`` (canonicalization on the first solve, DPP parameter
    mapping afterwards, retrieval).

Warm start
    ``warm_start`` sets ``z.value`` and calls ``solve(warm_start=True)``: cvxpy
    then reuses the solver's cached workspace / previous iterate (OSQP, SCS, ...)
    or the variable values (solver dependent). ``warm_start=None`` solves with
    ``warm_start=False``. ``cvxpy:PROXQP`` ignores a warm start (noted in
    ``info``): cvxpy 1.9.3 with proxsuite 0.8 raises ``TypeError`` in
    ``update()`` (PERF-NOTES).
"""

from __future__ import annotations

import dataclasses
import os
import sys
from collections.abc import Callable, Mapping, Sequence
from typing import Any, ClassVar

import numpy as np
import numpy.typing as npt
import scipy.sparse as sp
from scipy.sparse.csgraph import connected_components

from ltv_lstm_mpc.exceptions import SolverError

from ._base import (
    Backend,
    FloatArray,
    RawResult,
    WarmStart,
    check_settings,
    map_status,
    warm_start_vectors,
)
from .dense import DenseBackend, DenseQP
from .problem import ConvexProblem, SolverStatus
from .tolerances import known_settings, solver_options

#: cvxpy status string -> SolverStatus. cvxpy's ``*_inaccurate`` infeasible / unbounded
#: statuses come without a certificate that meets the solver's tolerance (SCS returned
#: ``unbounded_inaccurate`` on a solvable ill-conditioned SOCP): they map to FAILED, never to a
#: statement about the problem (``native_status`` keeps cvxpy's word).
STATUS_MAP: Mapping[str, SolverStatus] = {
    "optimal": SolverStatus.OPTIMAL,
    "optimal_inaccurate": SolverStatus.OPTIMAL_INACCURATE,
    "infeasible": SolverStatus.INFEASIBLE,
    "infeasible_inaccurate": SolverStatus.FAILED,
    "unbounded": SolverStatus.UNBOUNDED,
    "unbounded_inaccurate": SolverStatus.FAILED,
    "infeasible_or_unbounded": SolverStatus.FAILED,
    "user_limit": SolverStatus.MAX_ITER,
    "solver_error": SolverStatus.FAILED,
}

#: cvxpy solvers that take second-order cones (others get QPs only).
CONE_SOLVERS = frozenset({"CLARABEL", "ECOS", "SCS"})
#: cvxpy solvers offered by the registry when installed.
SUPPORTED = ("CLARABEL", "ECOS", "SCS", "OSQP", "PIQP", "PROXQP", "DAQP", "HIGHS")
#: cvxpy-level keyword accepted next to the native settings.
_INTERFACE_SETTINGS = ("verbose",)
#: cvxpy solvers whose warm start is broken in the installed stack (see module docstring).
_NO_WARM_START = frozenset({"PROXQP"})

IntArray = npt.NDArray[np.int64]


class _Pattern:
    """Row/column indices (CSC order) of a matrix pattern and its cvxpy product."""

    def __init__(self, rows: IntArray, cols: IntArray, shape: tuple[int, int]) -> None:
        self.rows = rows
        self.cols = cols
        self.shape = shape
        nnz = rows.size
        self.C = sp.csc_matrix((np.ones(nnz), (np.arange(nnz), cols)), shape=(nnz, shape[1]))
        self.R = sp.csc_matrix((np.ones(nnz), (rows, np.arange(nnz))), shape=(shape[0], nnz))

    @classmethod
    def of(cls, mat: sp.csc_matrix) -> _Pattern:
        cols = np.repeat(np.arange(mat.shape[1]), np.diff(mat.indptr)).astype(np.int64)
        return cls(np.asarray(mat.indices, dtype=np.int64), cols, mat.shape)

    def product(self, values: Any, z: Any) -> Any:
        import cvxpy as cp

        if self.rows.size == 0:
            return cp.Constant(np.zeros(self.shape[0]))
        return self.R @ cp.multiply(values, self.C @ z)


class _HessianFactor:
    """Fixed-pattern factor ``L`` with ``L'L = P``: one dense block per component of ``P``."""

    def __init__(self, P: sp.csc_matrix) -> None:
        n = P.shape[0]
        n_comp, labels = connected_components(P, directed=False)
        has_entry = np.zeros(n, dtype=bool)
        has_entry[np.asarray(P.indices)] = True
        groups: dict[int, list[IntArray]] = {}
        for c in range(n_comp):
            idx = np.flatnonzero(labels == c).astype(np.int64)
            if idx.size == 1 and not has_entry[idx[0]]:
                continue  # variable absent from P
            groups.setdefault(idx.size, []).append(idx)
        self.groups = {b: np.stack(v) for b, v in groups.items()}  # size -> (K, b)
        rows: list[IntArray] = []
        cols: list[IntArray] = []
        row0 = 0
        for b, idx in self.groups.items():
            K = idx.shape[0]
            # block k, factor row i, column j -> row row0 + k*b + i, column idx[k, j]
            r_blk = row0 + np.arange(K)[:, None, None] * b + np.arange(b)[None, :, None]
            c_blk = np.broadcast_to(idx[:, None, :], (K, b, b))
            rows.append(np.broadcast_to(r_blk, (K, b, b)).ravel())
            cols.append(c_blk.ravel())
            row0 += K * b
        self.n_rows = row0
        self.pattern = _Pattern(
            np.concatenate(rows) if rows else np.zeros(0, dtype=np.int64),
            np.concatenate(cols) if cols else np.zeros(0, dtype=np.int64),
            (row0, n),
        )

    def values(self, P: sp.csc_matrix) -> FloatArray:
        """Nonzero values of ``L`` in pattern order."""
        if not self.groups:
            return np.zeros(0)
        Pd = P.toarray()
        out = []
        for idx in self.groups.values():
            blocks = Pd[idx[:, :, None], idx[:, None, :]]  # (K, b, b)
            w, V = np.linalg.eigh(blocks)
            L = np.sqrt(np.maximum(w, 0.0))[:, :, None] * np.swapaxes(V, 1, 2)
            out.append(L.ravel())
        return np.concatenate(out)


class CvxpyBackend(Backend):
    """Persistent DPP cvxpy problem for one structure."""

    backend: ClassVar[str] = "cvxpy"
    supports_update: ClassVar[bool] = True
    supports_warm_start: ClassVar[bool] = True

    def __init__(
        self, name: str, solver: str, tolerance: float, settings: Mapping[str, Any]
    ) -> None:
        """``solver`` is the cvxpy solver name (``"CLARABEL"``, ``"OSQP"``, ...)."""
        known = known_settings(solver)
        if known is not None:
            extra = ("backend",) if solver == "PIQP" else ()
            known = (*known, *_INTERFACE_SETTINGS, *extra)
        check_settings(f"cvxpy:{solver}", settings, known)
        super().__init__(name, solver, solver_options(solver, tolerance, settings))

    def handles_cones(self) -> bool:
        """Cones are solved exactly by CLARABEL, ECOS and SCS."""
        return self.solver in CONE_SOLVERS

    def _beta(self, problem: ConvexProblem) -> FloatArray:
        parts: list[FloatArray] = [np.asarray(problem.q)]
        if problem.b_eq is not None:
            parts.append(np.asarray(problem.b_eq))
        if problem.G is not None:
            parts += [np.asarray(problem.u)[self._iu], np.asarray(problem.l)[self._il]]
        if problem.lb is not None:
            parts += [np.asarray(problem.ub)[self._iub], np.asarray(problem.lb)[self._ilb]]
        for cone in problem.cones:
            parts += [np.asarray(cone.g), np.asarray([cone.f])]
        return np.concatenate(parts)

    def setup(self, problem: ConvexProblem) -> None:
        """Build the DPP problem (its canonicalization happens at the first solve)."""
        import cvxpy as cp

        n = problem.n_variables
        self._n, self._p, self._m = n, problem.n_eq, problem.n_ineq
        self._factor = _HessianFactor(problem.P)
        self._iu = self._il = self._iub = self._ilb = np.zeros(0, dtype=np.int64)
        if problem.G is not None:
            self._iu = np.flatnonzero(np.isfinite(np.asarray(problem.u)))
            self._il = np.flatnonzero(np.isfinite(np.asarray(problem.l)))
        if problem.lb is not None:
            self._iub = np.flatnonzero(np.isfinite(np.asarray(problem.ub)))
            self._ilb = np.flatnonzero(np.isfinite(np.asarray(problem.lb)))
        # The e-patterns are taken from the setup problem; later problems must share them.
        self._e_patterns = [np.flatnonzero(cone.e) for cone in problem.cones]

        theta_sizes = [self._factor.pattern.rows.size]
        theta_sizes += [m.nnz for m in (problem.A_eq, problem.G) if m is not None]
        for cone, e_idx in zip(problem.cones, self._e_patterns, strict=True):
            theta_sizes += [cone.F.nnz, e_idx.size]
        beta_size = n + problem.n_eq + self._iu.size + self._il.size
        beta_size += self._iub.size + self._ilb.size
        beta_size += sum(cone.dim + 1 for cone in problem.cones)

        z = cp.Variable(n, name="z")
        theta = cp.Parameter(int(sum(theta_sizes)), name="theta")
        beta = cp.Parameter(beta_size, name="beta")
        self._z, self._theta_par, self._beta_par = z, theta, beta
        t_off = 0
        b_off = 0

        def take_theta(k: int) -> Any:
            nonlocal t_off
            sl = theta[t_off : t_off + k]
            t_off += k
            return sl

        def take_beta(k: int) -> Any:
            nonlocal b_off
            sl = beta[b_off : b_off + k]
            b_off += k
            return sl

        Lz = self._factor.pattern.product(take_theta(self._factor.pattern.rows.size), z)
        q = take_beta(n)
        objective = 0.5 * cp.sum_squares(Lz) + q @ z if self._factor.n_rows else q @ z
        constraints: list[Any] = []
        self._con: dict[str, Any] = {}
        if problem.A_eq is not None:
            Az = _Pattern.of(problem.A_eq).product(take_theta(problem.A_eq.nnz), z)
            self._con["eq"] = Az == take_beta(problem.n_eq)
            constraints.append(self._con["eq"])
        if problem.G is not None:
            Gz = _Pattern.of(problem.G).product(take_theta(problem.G.nnz), z)
            if self._iu.size:
                self._con["ineq_u"] = Gz[self._iu] <= take_beta(self._iu.size)
                constraints.append(self._con["ineq_u"])
            if self._il.size:
                self._con["ineq_l"] = Gz[self._il] >= take_beta(self._il.size)
                constraints.append(self._con["ineq_l"])
        if problem.lb is not None:
            if self._iub.size:
                self._con["ub"] = z[self._iub] <= take_beta(self._iub.size)
                constraints.append(self._con["ub"])
            if self._ilb.size:
                self._con["lb"] = z[self._ilb] >= take_beta(self._ilb.size)
                constraints.append(self._con["lb"])
        for cone, e_idx in zip(problem.cones, self._e_patterns, strict=True):
            Fz = _Pattern.of(cone.F).product(take_theta(cone.F.nnz), z)
            e_val = take_theta(e_idx.size)
            g = take_beta(cone.dim)
            f = take_beta(1)
            lhs = cp.sum(cp.multiply(e_val, z[e_idx])) + f[0] if e_idx.size else f[0]
            constraints.append(cp.SOC(lhs, Fz + g))
        self._problem = cp.Problem(cp.Minimize(objective), constraints)
        if not self._problem.is_dpp():  # pragma: no cover - guarded by construction
            raise SolverError("internal error: the cvxpy problem is not DPP")
        self._assign(problem)

    def _assign(self, problem: ConvexProblem) -> None:
        parts = [self._factor.values(problem.P)]
        parts += [np.asarray(m.data) for m in (problem.A_eq, problem.G) if m is not None]
        for cone, e_idx in zip(problem.cones, self._e_patterns, strict=True):
            parts += [np.asarray(cone.F.data), np.asarray(cone.e)[e_idx]]
        self._theta_par.value = np.concatenate(parts)
        self._beta_par.value = self._beta(problem)

    def update(self, problem: ConvexProblem) -> None:
        """Assign the parameter values of ``problem`` (same structure)."""
        self._assign(problem)

    def solve(self, warm_start: WarmStart | None) -> RawResult:
        """Solve the DPP problem with the current parameter values."""
        z0, _ = warm_start_vectors(warm_start, self._n)
        return _run(self._problem, self._z, self.solver, self.options, z0, self._duals)

    def _dual(self, key: str) -> FloatArray | None:
        con = self._con.get(key)
        if con is None or con.dual_value is None:
            return None
        return np.atleast_1d(np.asarray(con.dual_value, dtype=np.float64))

    def _duals(self) -> dict[str, FloatArray] | None:
        eq = self._dual("eq")
        ineq = np.zeros(self._m)
        bounds = np.zeros(self._n)
        for key, idx, sign, out in (
            ("ineq_u", self._iu, 1.0, ineq),
            ("ineq_l", self._il, -1.0, ineq),
            ("ub", self._iub, 1.0, bounds),
            ("lb", self._ilb, -1.0, bounds),
        ):
            if idx.size:
                d = self._dual(key)
                if d is None:
                    return None
                np.add.at(out, idx, sign * d)
        if self._p and eq is None:
            return None
        return {"eq": np.zeros(0) if eq is None else eq, "ineq": ineq, "bounds": bounds}


_highs_banner_silenced = False


def _silence_highs_banner() -> None:
    """HiGHS prints its banner on standard output (from C, whatever ``verbose`` says) when
    the first ``Highs`` object of the process is made: make that one with the output
    descriptor pointed at the null device, once, so solver comparisons print no banner."""
    global _highs_banner_silenced
    if _highs_banner_silenced:
        return
    _highs_banner_silenced = True
    try:
        import highspy
    except ImportError:  # cvxpy's HIGHS needs it; without it cvxpy raises its own error
        return
    sys.stdout.flush()
    saved = os.dup(1)
    try:
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, 1)
        os.close(devnull)
        highspy.Highs()
    finally:
        os.dup2(saved, 1)
        os.close(saved)


def _run(
    problem: Any,
    z: Any,
    solver: str,
    options: Mapping[str, Any],
    z0: FloatArray | None,
    duals: Callable[[], dict[str, FloatArray] | None],
) -> RawResult:
    """Solve a DPP ``problem`` in variable ``z`` (warm from ``z0``) and map the result."""
    import cvxpy as cp

    notes: list[str] = []
    use_warm = z0 is not None
    if use_warm and solver in _NO_WARM_START:
        notes.append(
            f"warm start ignored: cvxpy:{solver} fails on warm start "
            "(cvxpy 1.9.3 + proxsuite 0.8 TypeError in update())"
        )
        use_warm = False
    if use_warm:
        z.value = z0
    if solver == "HIGHS" and not options.get("verbose", False):
        _silence_highs_banner()
    try:
        problem.solve(solver=solver, warm_start=use_warm, **{"verbose": False, **options})
    except cp.error.SolverError as exc:
        return RawResult(
            status=SolverStatus.FAILED,
            native_status=f"cvxpy SolverError: {exc}",
            z=None,
            duals=None,
            solve_time=0.0,
            iterations=None,
            notes=tuple(notes),
        )
    stats = problem.solver_stats
    status, note = map_status(STATUS_MAP, problem.status)
    if note:
        notes.append(note)
    point = multipliers = None
    if status.has_solution and z.value is not None:
        point = np.array(z.value, dtype=np.float64)
        multipliers = duals()
    solve_time = stats.solve_time if stats.solve_time is not None else 0.0
    return RawResult(
        status=status,
        native_status=str(problem.status),
        z=point,
        duals=multipliers,
        solve_time=float(solve_time),
        iterations=None if stats.num_iters is None else int(stats.num_iters),
        extra_setup_time=float(stats.setup_time or 0.0),
        notes=tuple(notes),
    )


def _dual_of(constraint: Any) -> FloatArray | None:
    if constraint is None or constraint.dual_value is None:
        return None
    return np.atleast_1d(np.asarray(constraint.dual_value, dtype=np.float64))


def _hessian_factor(H: FloatArray) -> FloatArray:
    """``L`` with ``L'L = H`` (Cholesky; eigenvalues clipped at 0 where H is semidefinite)."""
    try:
        return np.ascontiguousarray(np.linalg.cholesky(H).T)
    except np.linalg.LinAlgError:
        w, V = np.linalg.eigh(0.5 * (H + H.T))
        return np.ascontiguousarray(np.sqrt(np.maximum(w, 0.0))[:, None] * V.T)


class CvxpyDense(DenseBackend):
    """Dense QPs (and cones) as one DPP problem with dense parameters, re-solved per call.

    ``min 1/2 ||L x||^2 + f'x`` with ``L'L = H`` (a dense ``(n, n)`` parameter, Cholesky
    or clipped eigenvalues), the rows as ``A[eq] x == up[eq]``, ``A[i] x <= up[i]``,
    ``A[j] x >= lo[j]`` over the rows where those bounds are finite (one ``(m_A, n)``
    parameter ``A``), the finite variable bounds, and each cone as
    ``SOC(e'x + f, F x + g)``. Dense parameters keep cvxpy's canonicalization and its
    parameter map at O(n^2 + n m_A) entries; the generic adapter (a :class:`ConvexProblem`
    with a parameter per nonzero) grows like the square of the nonzeros (0.8 GB at
    n = 80). Which rows are equalities and which bounds are finite is fixed at setup; a
    QP with another pattern sets the problem up afresh (noted in ``info``).
    """

    backend: ClassVar[str] = "cvxpy"
    supports_update: ClassVar[bool] = True
    supports_warm_start: ClassVar[bool] = True

    def __init__(
        self, name: str, solver: str, tolerance: float, settings: Mapping[str, Any]
    ) -> None:
        """``solver`` is the cvxpy solver name (``"CLARABEL"``, ``"OSQP"``, ...)."""
        known = known_settings(solver)
        if known is not None:
            extra = ("backend",) if solver == "PIQP" else ()
            known = (*known, *_INTERFACE_SETTINGS, *extra)
        check_settings(f"cvxpy:{solver}", settings, known)
        super().__init__(name, solver, solver_options(solver, tolerance, settings))
        self._notes: tuple[str, ...] = ()

    def handles_cones(self) -> bool:
        """Cones are solved exactly by CLARABEL, ECOS and SCS."""
        return self.solver in CONE_SOLVERS

    @staticmethod
    def _pattern(qp: DenseQP) -> tuple[bytes, ...]:
        eq = qp.lo == qp.up
        return (
            np.packbits(eq).tobytes(),
            np.packbits(np.isfinite(qp.up) & ~eq).tobytes(),
            np.packbits(np.isfinite(qp.lo) & ~eq).tobytes(),
            np.packbits(np.isfinite(qp.ub)).tobytes(),
            np.packbits(np.isfinite(qp.lb)).tobytes(),
        )

    def setup(self, qp: DenseQP) -> None:
        """Build the DPP problem for the pattern of ``qp`` and assign its values."""
        import cvxpy as cp

        n, m = qp.n_variables, qp.n_rows
        self._n, self._m = n, m
        self._key = self._pattern(qp)
        eq = qp.lo == qp.up
        self._ieq = np.flatnonzero(eq)
        self._iu = np.flatnonzero(np.isfinite(qp.up) & ~eq)
        self._il = np.flatnonzero(np.isfinite(qp.lo) & ~eq)
        self._iub = np.flatnonzero(np.isfinite(qp.ub))
        self._ilb = np.flatnonzero(np.isfinite(qp.lb))
        x = cp.Variable(n, name="x")
        self._x = x
        self._L = cp.Parameter((n, n), name="L")
        self._f = cp.Parameter(n, name="f")
        constraints: list[Any] = []
        self._con: dict[str, Any] = {}
        self._vec: dict[str, tuple[Any, IntArray]] = {}
        if m:
            self._A = cp.Parameter((m, n), name="A")
            Ax = self._A @ x
        for key, idx, kind in (
            ("eq", self._ieq, "=="),
            ("up", self._iu, "<="),
            ("lo", self._il, ">="),
        ):
            if idx.size:
                b = cp.Parameter(idx.size, name=key)
                rows = Ax if idx.size == m else Ax[idx]
                con = rows == b if kind == "==" else (rows <= b if kind == "<=" else rows >= b)
                self._con[key] = con
                self._vec[key] = (b, idx)
                constraints.append(con)
        for key, idx, upper in (("ub", self._iub, True), ("lb", self._ilb, False)):
            if idx.size:
                b = cp.Parameter(idx.size, name=key)
                xs = x if idx.size == n else x[idx]
                con = xs <= b if upper else xs >= b
                self._con[key] = con
                self._vec[key] = (b, idx)
                constraints.append(con)
        self._cones: list[tuple[Any, Any, Any, Any, Any]] = []
        for index, cone in enumerate(qp.cones):
            F = cp.Parameter(cone.F.shape, name=f"F{index}")
            g = cp.Parameter(cone.dim, name=f"g{index}")
            e = cp.Parameter(n, name=f"e{index}")
            f = cp.Parameter(name=f"f{index}")
            con = cp.SOC(e @ x + f, F @ x + g)
            constraints.append(con)
            self._cones.append((F, g, e, f, con))
        objective = 0.5 * cp.sum_squares(self._L @ x) + self._f @ x
        self._problem = cp.Problem(cp.Minimize(objective), constraints)
        self._assign(qp)
        self._notes = ()

    def _assign(self, qp: DenseQP) -> None:
        self._L.value = _hessian_factor(np.asarray(qp.H, dtype=np.float64))
        self._f.value = np.asarray(qp.f)
        if self._m:
            self._A.value = np.asarray(qp.A)
        sources = {"eq": qp.up, "up": qp.up, "lo": qp.lo, "ub": qp.ub, "lb": qp.lb}
        for key, (param, idx) in self._vec.items():
            param.value = np.asarray(sources[key])[idx]
        for (F, g, e, f, _), cone in zip(self._cones, qp.cones, strict=True):
            F.value, g.value, e.value, f.value = cone.F, cone.g, cone.e, cone.f

    def update(self, qp: DenseQP) -> None:
        """Assign the new values; a new equality / finite-bound pattern sets up afresh."""
        if self._pattern(qp) != self._key:
            self.setup(qp)
            self._notes = ("fresh setup (equality or finite-bound pattern changed)",)
            return
        self._assign(qp)
        self._notes = ()

    def solve(self, warm_start: WarmStart | None) -> RawResult:
        """Solve the DPP problem with the current values."""
        z0, _ = warm_start_vectors(warm_start, self._n)
        raw = _run(self._problem, self._x, self.solver, self.options, z0, self._duals)
        if self._notes:
            raw = dataclasses.replace(raw, notes=(*self._notes, *raw.notes))
        return raw

    def _duals(self) -> dict[str, FloatArray] | None:
        ineq = np.zeros(self._m)
        bounds = np.zeros(self._n)
        for key, sign, out in (
            ("eq", 1.0, ineq),
            ("up", 1.0, ineq),
            ("lo", -1.0, ineq),
            ("ub", 1.0, bounds),
            ("lb", -1.0, bounds),
        ):
            con = self._con.get(key)
            if con is None:
                continue
            d = _dual_of(con)
            if d is None:
                return None
            np.add.at(out, self._vec[key][1], sign * d)
        duals = {"ineq": ineq, "bounds": bounds}
        if self._cones:
            parts = []
            for *_, con in self._cones:
                values = con.dual_value
                if values is None:
                    return duals
                parts.append(
                    np.concatenate([np.asarray(v, dtype=np.float64).ravel() for v in values])
                )
            duals["cones"] = np.concatenate(parts)
        return duals


def supported_solvers(installed: Sequence[str]) -> list[str]:
    """The cvxpy solvers of ``installed`` this backend offers, in :data:`SUPPORTED` order."""
    return [s for s in SUPPORTED if s in installed]


def dense_factory(solver: str) -> Any:
    """Registry dense factory for ``"cvxpy:<solver>"``."""

    def make(name: str, tolerance: float, settings: Mapping[str, Any]) -> DenseBackend:
        return CvxpyDense(name, solver, tolerance, settings)

    return make


def factory(solver: str) -> Any:
    """Registry factory for ``"cvxpy:<solver>"``."""

    def make(name: str, tolerance: float, settings: Mapping[str, Any]) -> Backend:
        return CvxpyBackend(name, solver, tolerance, settings)

    return make
