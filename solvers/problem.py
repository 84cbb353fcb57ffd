"""Problem and solution data classes of the solver layer.

The convex subproblem (paper notes section 4) is

.. math::

    \\min_z \\; \\tfrac12 z^\\top P z + q^\\top z
    \\quad \\text{s.t.} \\quad
    A_{eq} z = b_{eq}, \\quad l \\le G z \\le u, \\quad
    lb \\le z \\le ub, \\quad
    \\|F_j z + g_j\\|_2 \\le e_j^\\top z + f_j \\;\\; (j = 1, \\dots, J).

:class:`ConvexProblem` stores it (all matrices as ``scipy.sparse.csc_matrix``),
:class:`Solution` is what every backend returns.
"""

from __future__ import annotations

import enum
import hashlib
import math
import weakref
from collections.abc import Mapping
from dataclasses import dataclass, field, fields
from os import PathLike
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
import numpy.typing as npt
import scipy.sparse as sp

from ltv_lstm_mpc.exceptions import DimensionError, InvalidValueError
from ltv_lstm_mpc.validation import real_array, real_scalar

if TYPE_CHECKING:
    from .acceptance import Residuals

__all__ = [
    "ConvexProblem",
    "MatrixLike",
    "SecondOrderCone",
    "Solution",
    "SolverStatus",
    "frozen_csc",
]

FloatArray = npt.NDArray[np.float64]
#: Anything accepted where a matrix is expected: a dense array or any scipy sparse matrix/array.
MatrixLike = npt.ArrayLike | sp.spmatrix | sp.sparray

_FORMAT_VERSION = 1
#: Relative tolerance of the symmetry check on ``P``.
_SYMMETRY_RTOL = 1e-9


# --------------------------------------------------------------------------------------
# validation helpers
# --------------------------------------------------------------------------------------
def _is_frozen(value: Any) -> bool:
    """A CSC matrix already validated by :func:`frozen_csc` (canonical, finite, read-only)."""
    return (
        isinstance(value, sp.csc_matrix)
        and value.dtype == np.float64
        and not value.data.flags.writeable
        and not value.indices.flags.writeable
        and not value.indptr.flags.writeable
        and bool(value.has_canonical_format)
    )


def frozen_csc(value: Any, name: str = "matrix") -> sp.csc_matrix:
    """Validated, canonical, read-only float64 CSC copy of ``value``.

    Passing the result to :class:`ConvexProblem` again costs no copy and no check: a
    constant matrix reused every step of a loop (cost Hessian, output rows, cone
    matrices) is validated once.
    """
    return _as_csc(name, value, None)


def _as_csc(name: str, value: Any, shape: tuple[int, int] | None) -> sp.csc_matrix:
    """Convert ``value`` to a canonical float64 CSC matrix and check its shape and values.

    Explicit zeros of a sparse input are *kept* (they are part of the sparsity
    pattern used by :meth:`ConvexProblem.structure_key`); zeros of a dense input
    are dropped. A matrix that is already frozen (see :func:`frozen_csc`) is returned
    as it is: its arrays are read-only, so it cannot have changed since its check.
    """
    if _is_frozen(value):
        if shape is not None and value.shape != shape:
            raise DimensionError(f"{name} must have shape {shape}, got {value.shape}")
        return value
    if sp.issparse(value):
        mat = sp.csc_matrix(value, dtype=np.float64, copy=True)
    else:
        arr = real_array(name, value).astype(np.float64, copy=False)
        if arr.ndim != 2:
            raise DimensionError(
                f"{name} must be a 2-D matrix"
                + (f" of shape {shape}" if shape is not None else "")
                + f", got an array of shape {arr.shape}"
            )
        mat = sp.csc_matrix(arr)
    if shape is not None and mat.shape != shape:
        raise DimensionError(f"{name} must have shape {shape}, got {mat.shape}")
    mat.sum_duplicates()  # also sorts indices; keeps explicit zeros
    mat.sort_indices()
    if not np.all(np.isfinite(mat.data)):
        raise InvalidValueError(f"{name} has non-finite entries (NaN or inf)")
    mat.data.setflags(write=False)
    mat.indices.setflags(write=False)
    mat.indptr.setflags(write=False)
    return mat


def _as_vector(name: str, value: Any, length: int, *, allow_inf: bool = False) -> FloatArray:
    """Return a read-only float64 copy of ``value`` with shape ``(length,)``."""
    arr = np.array(real_array(name, value), dtype=np.float64, copy=True)
    if arr.ndim == 0 and length == 1:
        arr = arr.reshape(1)
    if arr.shape != (length,):
        raise DimensionError(f"{name} must have shape ({length},), got {arr.shape}")
    if np.any(np.isnan(arr)):
        raise InvalidValueError(
            f"{name} has NaN entries at indices {np.flatnonzero(np.isnan(arr))}"
        )
    if not allow_inf and not np.all(np.isfinite(arr)):
        raise InvalidValueError(
            f"{name} has infinite entries at {np.flatnonzero(~np.isfinite(arr))}"
        )
    arr.setflags(write=False)
    return arr


def _check_bounds(lname: str, low: FloatArray, uname: str, up: FloatArray) -> None:
    if np.any(low == np.inf):
        raise InvalidValueError(f"{lname} has +inf entries at {np.flatnonzero(low == np.inf)}")
    if np.any(up == -np.inf):
        raise InvalidValueError(f"{uname} has -inf entries at {np.flatnonzero(up == -np.inf)}")
    bad = np.flatnonzero(low > up)
    if bad.size:
        raise InvalidValueError(
            f"{lname} > {uname} at indices {bad[:10].tolist()} "
            f"(e.g. {low[bad[0]]!r} > {up[bad[0]]!r})"
        )


def _pattern_digest(h: Any, name: str, mat: sp.csc_matrix | None) -> None:
    h.update(name.encode())
    if mat is None:
        h.update(b"none")
        return
    h.update(np.asarray(mat.shape, dtype=np.int64).tobytes())
    h.update(np.asarray(mat.indptr, dtype=np.int64).tobytes())
    h.update(np.asarray(mat.indices, dtype=np.int64).tobytes())


def _finite_digest(h: Any, name: str, vec: FloatArray | None) -> None:
    h.update(name.encode())
    if vec is None:
        h.update(b"none")
        return
    h.update(np.asarray(vec.shape, dtype=np.int64).tobytes())
    h.update(np.packbits(np.isfinite(vec)).tobytes())


# --------------------------------------------------------------------------------------
# cones
# --------------------------------------------------------------------------------------
@dataclass(frozen=True, eq=False)
class SecondOrderCone:
    """Second-order cone constraint :math:`\\|F z + g\\|_2 \\le e^\\top z + f`.

    Parameters
    ----------
    F : (k, n) matrix
        Dense or sparse; stored as ``scipy.sparse.csc_matrix``.
    g : (k,) array
    e : (n,) array
        Stored dense.
    f : float

    Notes
    -----
    ``n`` is not known to the cone on its own; :class:`ConvexProblem` checks
    that ``F`` has ``n`` columns and ``e`` has length ``n``.
    """

    F: sp.csc_matrix
    g: FloatArray
    e: FloatArray
    f: float

    def __post_init__(self) -> None:
        F = _as_csc("cone F", self.F, None)
        k, n = F.shape
        if k == 0:
            raise DimensionError("cone F must have at least one row, got shape (0, n)")
        object.__setattr__(self, "F", F)
        object.__setattr__(self, "g", _as_vector("cone g", self.g, k))
        object.__setattr__(self, "e", _as_vector("cone e", self.e, n))
        f = real_scalar("cone f", self.f)
        if not math.isfinite(f):
            raise InvalidValueError(f"cone f must be finite, got {f!r}")
        object.__setattr__(self, "f", f)

    @property
    def dim(self) -> int:
        """Number of rows ``k`` of ``F`` (the cone has dimension ``k + 1``)."""
        return int(self.F.shape[0])

    def residual(self, z: FloatArray) -> float:
        """Constraint value :math:`\\|F z + g\\|_2 - (e^\\top z + f)` (``<= 0`` when satisfied)."""
        return float(np.linalg.norm(self.F @ z + self.g) - (self.e @ z + self.f))


# --------------------------------------------------------------------------------------
# problem
# --------------------------------------------------------------------------------------
#: Frozen Hessians already checked for symmetry, by id (weak values: an entry vanishes
#: with its matrix, so a reused id never matches a stale entry).
_SYMMETRIC: weakref.WeakValueDictionary[int, sp.csc_matrix] = weakref.WeakValueDictionary()
_MATRIX_FIELDS = ("P", "A_eq", "G")
_VECTOR_FIELDS = ("q", "b_eq", "l", "u", "lb", "ub")


@dataclass(frozen=True, eq=False)
class ConvexProblem:
    """Convex quadratic (cone) program, the RTI subproblem of paper notes section 4.

    .. math::

        \\min_z \\tfrac12 z^\\top P z + q^\\top z \\;\\text{s.t.}\\;
        A_{eq} z = b_{eq},\\; l \\le G z \\le u,\\; lb \\le z \\le ub,\\;
        \\|F_j z + g_j\\|_2 \\le e_j^\\top z + f_j.

    Parameters
    ----------
    P : (n, n) matrix
        Symmetric positive semidefinite Hessian; dense or sparse, stored as CSC
        (both triangles). Symmetry is checked; semidefiniteness is the caller's
        contract (it is not checked, it costs a factorization).
    q : (n,) array
        Linear cost.
    A_eq, b_eq : (p, n) matrix and (p,) array, optional
        Equality constraints (both or neither).
    G, l, u : (m, n) matrix and (m,) arrays, optional
        Two-sided inequalities; ``l`` may hold ``-inf`` and ``u`` ``+inf``.
        With ``G`` given, a missing ``l`` means ``-inf`` (one-sided
        ``G z <= u``) and a missing ``u`` means ``+inf``; at least one is needed.
    lb, ub : (n,) arrays, optional
        Variable bounds (``-inf``/``+inf`` allowed); a missing one means unbounded.
    cones : tuple of SecondOrderCone
        Second-order cone constraints.

    Notes
    -----
    The sparsity pattern of each matrix (explicit zeros of sparse inputs
    included) and the finite/infinite pattern of the bounds make up the
    problem's *structure* (:meth:`structure_key`). Persistent sessions update a
    solver in place only while the structure is unchanged, so inside a loop pass
    sparse matrices with a fixed pattern (a dense input drops its zeros, so a
    value that happens to be 0 changes the structure).
    """

    P: sp.csc_matrix
    q: FloatArray
    A_eq: sp.csc_matrix | None = None
    b_eq: FloatArray | None = None
    G: sp.csc_matrix | None = None
    l: FloatArray | None = None
    u: FloatArray | None = None
    lb: FloatArray | None = None
    ub: FloatArray | None = None
    cones: tuple[SecondOrderCone, ...] = field(default=())
    _key: str = field(default="", init=False, repr=False)

    def __post_init__(self) -> None:
        q = np.asarray(self.q)
        if q.ndim != 1:
            raise DimensionError(f"q must have shape (n,), got {q.shape}")
        n = q.shape[0]
        if n == 0:
            raise DimensionError("the problem needs at least one variable (q has shape (0,))")
        setattr_ = object.__setattr__
        setattr_(self, "q", _as_vector("q", q, n))
        P = _as_csc("P", self.P, (n, n))
        if _SYMMETRIC.get(id(P)) is not P:  # a frozen P is checked once, not every step
            asym = abs(P - P.T).max() if P.nnz else 0.0
            scale = max(1.0, abs(P).max() if P.nnz else 0.0)
            if asym > _SYMMETRY_RTOL * scale:
                raise InvalidValueError(f"P must be symmetric; max |P - P^T| = {asym:.3g}")
            if _is_frozen(P):
                _SYMMETRIC[id(P)] = P
        setattr_(self, "P", P)

        if (self.A_eq is None) != (self.b_eq is None):
            raise InvalidValueError("A_eq and b_eq must be given together (or both omitted)")
        if self.A_eq is not None:
            A_eq = self.A_eq if sp.issparse(self.A_eq) else np.atleast_2d(self.A_eq)
            A = _as_csc("A_eq", A_eq, None)
            if A.shape[1] != n:
                raise DimensionError(f"A_eq must have shape (p, {n}), got {A.shape}")
            setattr_(self, "A_eq", A)
            setattr_(self, "b_eq", _as_vector("b_eq", self.b_eq, A.shape[0]))

        if self.G is None:
            if self.l is not None or self.u is not None:
                raise InvalidValueError("l or u given without G")
        else:
            G = self.G if sp.issparse(self.G) else np.atleast_2d(self.G)
            Gm = _as_csc("G", G, None)
            if Gm.shape[1] != n:
                raise DimensionError(f"G must have shape (m, {n}), got {Gm.shape}")
            m = Gm.shape[0]
            if self.l is None and self.u is None:
                raise InvalidValueError("G given without l or u (give at least one)")
            low = (
                np.full(m, -np.inf)
                if self.l is None
                else _as_vector("l", self.l, m, allow_inf=True)
            )
            up = (
                np.full(m, np.inf) if self.u is None else _as_vector("u", self.u, m, allow_inf=True)
            )
            low.setflags(write=False)
            up.setflags(write=False)
            _check_bounds("l", low, "u", up)
            setattr_(self, "G", Gm)
            setattr_(self, "l", low)
            setattr_(self, "u", up)

        if self.lb is not None or self.ub is not None:
            lo = (
                np.full(n, -np.inf)
                if self.lb is None
                else _as_vector("lb", self.lb, n, allow_inf=True)
            )
            hi = (
                np.full(n, np.inf)
                if self.ub is None
                else _as_vector("ub", self.ub, n, allow_inf=True)
            )
            lo.setflags(write=False)
            hi.setflags(write=False)
            _check_bounds("lb", lo, "ub", hi)
            setattr_(self, "lb", lo)
            setattr_(self, "ub", hi)

        cones = tuple(self.cones)
        for j, cone in enumerate(cones):
            if not isinstance(cone, SecondOrderCone):
                raise InvalidValueError(
                    f"cones[{j}] must be a SecondOrderCone, got {type(cone).__name__}"
                )
            if cone.F.shape[1] != n:
                raise DimensionError(f"cones[{j}].F must have shape (k, {n}), got {cone.F.shape}")
        setattr_(self, "cones", cones)
        setattr_(self, "_key", self._compute_key())

    # ----------------------------------------------------------------------------------
    @property
    def n_variables(self) -> int:
        """Number of decision variables ``n``."""
        return int(self.q.shape[0])

    @property
    def n_eq(self) -> int:
        """Number of equality constraints ``p``."""
        return 0 if self.A_eq is None else int(self.A_eq.shape[0])

    @property
    def n_ineq(self) -> int:
        """Number of rows ``m`` of ``G``."""
        return 0 if self.G is None else int(self.G.shape[0])

    @property
    def has_cones(self) -> bool:
        """Whether the problem has at least one second-order cone."""
        return len(self.cones) > 0

    @property
    def has_bounds(self) -> bool:
        """Whether variable bounds ``lb``/``ub`` are present."""
        return self.lb is not None

    def structure_key(self) -> str:
        """Hash of shapes, sparsity patterns and finite-bound patterns.

        Two problems with the same key differ only in values, so a session set up
        for one can be updated in place with the other.
        """
        return self._key

    def _compute_key(self) -> str:
        h = hashlib.sha1(usedforsecurity=False)
        _pattern_digest(h, "P", self.P)
        _pattern_digest(h, "A_eq", self.A_eq)
        _pattern_digest(h, "G", self.G)
        _finite_digest(h, "l", self.l)
        _finite_digest(h, "u", self.u)
        _finite_digest(h, "lb", self.lb)
        _finite_digest(h, "ub", self.ub)
        h.update(f"cones{len(self.cones)}".encode())
        for cone in self.cones:
            _pattern_digest(h, "F", cone.F)
            h.update(np.packbits(cone.e != 0).tobytes())
        return h.hexdigest()

    # ----------------------------------------------------------------------------------
    def objective(self, z: npt.ArrayLike) -> float:
        """Evaluate :math:`\\tfrac12 z^\\top P z + q^\\top z`."""
        zz = np.asarray(z, dtype=np.float64)
        if zz.shape != (self.n_variables,):
            raise DimensionError(f"z must have shape ({self.n_variables},), got {zz.shape}")
        return float(0.5 * zz @ (self.P @ zz) + self.q @ zz)

    def max_violation(self, z: npt.ArrayLike) -> float:
        """Largest constraint violation of ``z`` (0 when feasible), cones included."""
        zz = np.asarray(z, dtype=np.float64)
        if zz.shape != (self.n_variables,):
            raise DimensionError(f"z must have shape ({self.n_variables},), got {zz.shape}")
        viol = [0.0]
        if self.A_eq is not None and self.b_eq is not None:
            viol.append(float(np.max(np.abs(self.A_eq @ zz - self.b_eq), initial=0.0)))
        if self.G is not None and self.l is not None and self.u is not None:
            Gz = self.G @ zz
            viol.append(float(np.max(np.maximum(self.l - Gz, Gz - self.u), initial=0.0)))
        if self.lb is not None and self.ub is not None:
            viol.append(float(np.max(np.maximum(self.lb - zz, zz - self.ub), initial=0.0)))
        viol.extend(max(0.0, cone.residual(zz)) for cone in self.cones)
        return max(viol)

    def with_values(self, **values: Any) -> ConvexProblem:
        """Return a new problem with some data replaced, same structure expected.

        Parameters
        ----------
        **values
            Any of ``P, q, A_eq, b_eq, G, l, u, lb, ub, cones``. A matrix may be
            given as a 1-D array of its new nonzero values (``.data`` in the CSC
            order of the stored matrix), which keeps its sparsity pattern
            exactly; this is the fast path inside a loop.

        Returns
        -------
        ConvexProblem
            A new, validated problem. Its :meth:`structure_key` is not forced to
            match; compare keys if that matters.
        """
        allowed = set(_MATRIX_FIELDS) | set(_VECTOR_FIELDS) | {"cones"}
        unknown = sorted(set(values) - allowed)
        if unknown:
            raise InvalidValueError(f"unknown field(s) {unknown}; allowed: {sorted(allowed)}")
        kwargs: dict[str, Any] = {f.name: getattr(self, f.name) for f in fields(self) if f.init}
        for name, value in values.items():
            if name in _MATRIX_FIELDS and value is not None and not sp.issparse(value):
                arr = real_array(name, value).astype(np.float64, copy=False)
                old = getattr(self, name)
                if arr.ndim == 1 and old is not None:
                    if arr.shape != (old.nnz,):
                        raise DimensionError(
                            f"new nonzero values of {name} must have shape ({old.nnz},), "
                            f"got {arr.shape}"
                        )
                    value = sp.csc_matrix((arr, old.indices, old.indptr), shape=old.shape)
            kwargs[name] = value
        return ConvexProblem(**kwargs)

    # ----------------------------------------------------------------------------------
    def save(self, path: str | PathLike[str]) -> Path:
        """Write the problem to an uncompressed ``.npz`` file (sparse as data/indices/indptr).

        Returns
        -------
        pathlib.Path
            The path written (numpy appends ``.npz`` when missing).
        """
        out: dict[str, FloatArray | npt.NDArray[np.int64]] = {
            "format_version": np.asarray(_FORMAT_VERSION, dtype=np.int64),
            "n_cones": np.asarray(len(self.cones), dtype=np.int64),
        }

        def put_mat(prefix: str, mat: sp.csc_matrix) -> None:
            out[f"{prefix}_data"] = np.asarray(mat.data)
            out[f"{prefix}_indices"] = np.asarray(mat.indices, dtype=np.int64)
            out[f"{prefix}_indptr"] = np.asarray(mat.indptr, dtype=np.int64)
            out[f"{prefix}_shape"] = np.asarray(mat.shape, dtype=np.int64)

        for name in _MATRIX_FIELDS:
            mat = getattr(self, name)
            if mat is not None:
                put_mat(name, mat)
        for name in _VECTOR_FIELDS:
            vec = getattr(self, name)
            if vec is not None:
                out[name] = np.asarray(vec)
        for j, cone in enumerate(self.cones):
            put_mat(f"cone{j}_F", cone.F)
            out[f"cone{j}_g"] = np.asarray(cone.g)
            out[f"cone{j}_e"] = np.asarray(cone.e)
            out[f"cone{j}_f"] = np.asarray(cone.f)
        p = Path(path)
        if p.suffix != ".npz":
            p = p.with_name(p.name + ".npz")
        np.savez(p, **out)  # type: ignore[arg-type]
        return p

    @classmethod
    def load(cls, path: str | PathLike[str]) -> ConvexProblem:
        """Read a problem written by :meth:`save`."""
        with np.load(Path(path), allow_pickle=False) as data:
            store = {k: data[k] for k in data.files}
        version = int(store.get("format_version", -1))
        if version != _FORMAT_VERSION:
            raise InvalidValueError(
                f"{path}: unsupported format_version {version} (expected {_FORMAT_VERSION})"
            )

        def get_mat(prefix: str) -> sp.csc_matrix | None:
            if f"{prefix}_data" not in store:
                return None
            shape = tuple(int(s) for s in store[f"{prefix}_shape"])
            return sp.csc_matrix(
                (store[f"{prefix}_data"], store[f"{prefix}_indices"], store[f"{prefix}_indptr"]),
                shape=shape,
            )

        kwargs: dict[str, Any] = {name: get_mat(name) for name in _MATRIX_FIELDS}
        for name in _VECTOR_FIELDS:
            kwargs[name] = store.get(name)
        kwargs["cones"] = tuple(
            SecondOrderCone(
                F=get_mat(f"cone{j}_F"),
                g=store[f"cone{j}_g"],
                e=store[f"cone{j}_e"],
                f=float(store[f"cone{j}_f"]),
            )
            for j in range(int(store["n_cones"]))
        )
        return cls(**kwargs)


# --------------------------------------------------------------------------------------
# solution
# --------------------------------------------------------------------------------------
class SolverStatus(enum.Enum):
    """Outcome of a solve, mapped from each backend's native status code."""

    OPTIMAL = "optimal"
    OPTIMAL_INACCURATE = "optimal_inaccurate"
    INFEASIBLE = "infeasible"
    UNBOUNDED = "unbounded"
    MAX_ITER = "max_iter"
    FAILED = "failed"

    @property
    def has_solution(self) -> bool:
        """Whether ``z`` is meaningful (``OPTIMAL`` or ``OPTIMAL_INACCURATE``)."""
        return self in (SolverStatus.OPTIMAL, SolverStatus.OPTIMAL_INACCURATE)


@dataclass(frozen=True, eq=False)
class Solution:
    """Result of one solve.

    Attributes
    ----------
    status : SolverStatus
        Mapped from the backend's native code (``info`` names the native code).
    z : (n,) array or None
        Primal solution for the variables of the problem passed in (auxiliary
        variables appended by a reformulation are not included); ``None`` when
        the solver returned no primal point.
    objective : float
        :math:`\\tfrac12 z^\\top P z + q^\\top z` computed by us from ``z`` on the
        problem actually solved (the reformulated one when a reformulation was
        applied), never taken from the solver; ``nan`` without ``z``.
    duals : dict or None
        Multipliers where the backend gives them, with the sign convention of
        the KKT stationarity condition
        ``P z + q + A_eq' y_eq + G' y_ineq + y_bounds = 0`` (``"eq"``,
        ``"ineq"``, ``"bounds"``; ``y_ineq > 0`` where ``G z = u`` is active,
        ``< 0`` where ``G z = l`` is). Cones' multipliers are not reported.
    setup_time : float
        Seconds spent building or updating the solver's data in this call
        (our wall clock around the backend's setup/update, plus cvxpy's problem
        construction; for a ``qpsolvers:`` backend, also the part of the
        :func:`qpsolvers.solve_problem` call that is not the solver's reported solve time:
        qpsolvers' conversions and the solver's build, so that ``setup_time +
        solve_time`` of a re-solve is that call's wall time); 0 when a session re-solves
        unchanged data with another backend.
    solve_time : float
        The solver's own reported solve time in seconds (wall clock around the
        solver call where it reports none).
    overhead_time : float
        Remaining wall time of the call: data conversion, cvxpy
        canonicalization / parameter mapping, result extraction.
    iterations : int or None
        Solver iterations where reported.
    backend : str
        ``"cvxpy"``, ``"qpsolvers"``, ``"osqp"``, ``"piqp"`` or ``"daqp"``.
    solver : str
        Full registry name, e.g. ``"cvxpy:CLARABEL"``.
    reformulation : str or None
        Name of the cone reformulation applied, ``None`` if the cones were
        solved exactly (or there were none).
    info : str
        Native status and notes (warm start ignored, fresh setup, the acceptance check's
        verdict where it changed the status, ...).
    residuals : Residuals or None
        The acceptance check's relative residuals of the returned point (primal,
        stationarity, complementarity; :mod:`~ltv_lstm_mpc.solvers.acceptance`), ``None``
        where the backend returned no point.
    certificate : dict or None
        For ``INFEASIBLE``, a Farkas vector keyed like ``duals``; for ``UNBOUNDED``,
        ``{"direction": d}``: only where the backend returned one and it checked.
    """

    status: SolverStatus
    z: FloatArray | None
    objective: float
    duals: Mapping[str, FloatArray] | None
    setup_time: float
    solve_time: float
    overhead_time: float
    iterations: int | None
    backend: str
    solver: str
    reformulation: str | None = None
    info: str = ""
    residuals: Residuals | None = None
    certificate: Mapping[str, FloatArray] | None = None

    @property
    def total_time(self) -> float:
        """``setup_time + solve_time + overhead_time`` in seconds."""
        return self.setup_time + self.solve_time + self.overhead_time

    @property
    def ok(self) -> bool:
        """Whether the status is ``OPTIMAL`` or ``OPTIMAL_INACCURATE``."""
        return self.status.has_solution
