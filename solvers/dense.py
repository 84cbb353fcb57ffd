r"""Dense (condensed) QPs: the :class:`DenseQP` data class and the dense backend interface.

A condensed MPC subproblem is small and dense,

.. math::

    \min_x \tfrac12 x^\top H x + f^\top x \quad\text{s.t.}\quad
    lo \le A x \le up, \quad lb \le x \le ub,

and is solved once per control step, so the per-call Python overhead matters as
much as the solver. :class:`DenseSession` keeps one dense workspace
(:class:`DenseBackend`) and per call only writes the new values into it
(``update``) and solves. It validates the data (:meth:`DenseQP.check`) only when
it sets a workspace up (first call, or a new :meth:`DenseQP.structure_key`),
never on the update path.

Every registered solver accepts a :class:`DenseQP`: the ones with a dedicated
dense backend (``native_dense`` of :class:`~ltv_lstm_mpc.solvers.SolverInfo`: ``daqp``,
``quadprog``, ``proxqp``, ``piqp``, ``piqp:dense``, ``osqp``, ``qpsolvers:*``)
use it, the others go through :meth:`DenseQP.to_convex_problem` and their
:class:`~ltv_lstm_mpc.solvers.ConvexProblem` backend (correct, not fast).

A :class:`DenseQP` may carry second-order cones :math:`\|F x + g\| \le e^\top x + f`
(:class:`DenseCone`, dense data, e.g. the terminal set of a condensed MPC with exact
cones). Only backends that solve cones (:attr:`DenseBackend.supports_cones`: the native
``clarabel``, or a cone solver through the ConvexProblem adapter) accept such a QP; every
other backend refuses it with an error naming the ones that do (never dropped silently).

Multipliers (``Solution.duals``) of a dense solve follow the layer's KKT sign
convention ``H x + f + A' y_ineq + y_bounds = 0``: ``"ineq"`` has shape
``(m_A,)`` (``> 0`` where ``A x = up`` is active, ``< 0`` where ``A x = lo``
is), ``"bounds"`` has shape ``(n,)``.
"""

from __future__ import annotations

import abc
import math
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from os import PathLike
from pathlib import Path
from typing import Any, ClassVar

import numpy as np
import numpy.typing as npt
import scipy.sparse as sp

from ltv_lstm_mpc.exceptions import DimensionError, InvalidValueError
from ltv_lstm_mpc.validation import real_array, real_scalar

from ._base import FloatArray, RawResult, WarmStart
from ._compiled import CompiledOrPython, bounds_rows_violation, cone_violation
from .problem import ConvexProblem, SecondOrderCone, SolverStatus, _check_bounds

__all__ = [
    "DenseBackend",
    "DenseBackendFactory",
    "DenseCone",
    "DenseQP",
    "bounds_rows_violation",
    "cone_violation",
]

_FORMAT = "dense_qp"
_FORMAT_VERSION = 1
#: Relative tolerance of the symmetry check on ``H`` (as for ``ConvexProblem.P``).
_SYMMETRY_RTOL = 1e-9
_FIELDS = ("H", "f", "A", "lo", "up", "lb", "ub")


def _full_csc(M: FloatArray) -> sp.csc_matrix:
    """CSC matrix holding every entry of ``M`` (zeros explicit: a value-independent pattern)."""
    r, c = M.shape
    return sp.csc_matrix(
        (
            np.asarray(M, dtype=np.float64).ravel(order="F"),
            np.tile(np.arange(r, dtype=np.int64), c),
            np.arange(c + 1, dtype=np.int64) * r,
        ),
        shape=(r, c),
    )


def _bounds_rows_violation_numpy(
    x: FloatArray, lb: FloatArray, ub: FloatArray, A: FloatArray, lo: FloatArray, up: FloatArray
) -> float:
    """The numpy reference of ``_compiled.bounds_rows_violation``."""
    violation = max(0.0, float(np.max(lb - x)), float(np.max(x - ub)))
    if A.shape[0]:
        rows = A @ x
        violation = max(violation, float(np.max(lo - rows)), float(np.max(rows - up)))
    return violation


def _cone_violation_numpy(
    F: FloatArray, g: FloatArray, e: FloatArray, f: float, x: FloatArray
) -> float:
    r"""The numpy reference of ``_compiled.cone_violation``:
    :math:`\|F x + g\| - e^\top x - f`."""
    r = F @ x
    r += g
    return math.sqrt(float(r @ r)) - float(e @ x) - f


# DenseQP.max_violation's loops: compiled where ready, else the numpy references above
_bounds_rows_violation = CompiledOrPython(bounds_rows_violation, _bounds_rows_violation_numpy)
_cone_violation = CompiledOrPython(cone_violation, _cone_violation_numpy)


@dataclass(eq=False)
class DenseCone:
    r"""Second-order cone :math:`\|F x + g\|_2 \le e^\top x + f` on the variables of a DenseQP.

    Mutable like :class:`DenseQP` (values are overwritten in place every step).

    Parameters
    ----------
    F : (k, n) array
        Dense, ``k >= 1``.
    g : (k,) array
    e : (n,) array
    f : float
    """

    F: FloatArray
    g: FloatArray
    e: FloatArray
    f: float

    def __post_init__(self) -> None:
        self.F = real_array("cone F", self.F).astype(np.float64, copy=False)
        self.g = real_array("cone g", self.g).astype(np.float64, copy=False)
        self.e = real_array("cone e", self.e).astype(np.float64, copy=False)
        self.f = real_scalar("cone f", self.f)

    @property
    def dim(self) -> int:
        """Number of rows ``k`` of ``F`` (the cone has dimension ``k + 1``)."""
        return int(self.F.shape[0])

    def violation(self, x: FloatArray) -> float:
        r""":math:`\|F x + g\| - e^\top x - f` (positive where the cone is violated)."""
        return _cone_violation_numpy(self.F, self.g, self.e, self.f, x)

    def check(self, index: int, n: int) -> None:
        """Validate shapes and values (``index`` names the cone in messages)."""
        name = f"cones[{index}]"
        if self.F.ndim != 2 or self.F.shape[1] != n or self.F.shape[0] == 0:
            raise DimensionError(
                f"{name}.F must have shape (k, {n}) with k >= 1, got {self.F.shape}"
            )
        k = self.F.shape[0]
        if self.g.shape != (k,):
            raise DimensionError(f"{name}.g must have shape ({k},), got {self.g.shape}")
        if self.e.shape != (n,):
            raise DimensionError(f"{name}.e must have shape ({n},), got {self.e.shape}")
        for label, arr in (("F", self.F), ("g", self.g), ("e", self.e), ("f", self.f)):
            if not np.all(np.isfinite(arr)):
                raise InvalidValueError(f"{name}.{label} has non-finite entries (NaN or inf)")

    def copy(self) -> DenseCone:
        """Deep copy (new arrays)."""
        return DenseCone(self.F.copy(), self.g.copy(), self.e.copy(), self.f)


@dataclass(eq=False)
class DenseQP:
    r"""Dense QP :math:`\min_x \tfrac12 x'Hx + f'x` s.t. :math:`lo \le Ax \le up, lb \le x \le ub`.

    Mutable on purpose: a controller preallocates the arrays and overwrites them
    in place every step (keep them ``float64``; the constructor converts, a
    later reassignment of a field does not). Values are checked by
    :meth:`check`, which :class:`DenseSession` calls at setup only.

    Parameters
    ----------
    H : (n, n) array
        Symmetric positive (semi)definite Hessian (active-set solvers such as
        quadprog need it positive definite).
    f : (n,) array
    A : (m_A, n) array
        Constraint rows; ``m_A`` may be 0 (shape ``(0, n)``).
    lo, up : (m_A,) arrays
        Row bounds, ``-inf`` / ``+inf`` allowed; ``lo == up`` is an equality.
    lb, ub : (n,) arrays
        Variable bounds, ``-inf`` / ``+inf`` allowed.
    cones : tuple of DenseCone
        Second-order cones (default none: a QP). Only cone-capable backends accept them.
    hessian_floor : float
        A lower bound on the smallest eigenvalue of ``H`` that the caller knows (default 0:
        none), such as the MPC's input weight (the condensed ``H`` is a Gram matrix plus
        :math:`I_N \otimes R`). Where every variable has finite bounds, DAQP takes from it a
        bound on the objective that proves an infeasible QP infeasible sooner and changes no
        solve that finds a point (:func:`~ltv_lstm_mpc.solvers.daqp_.objective_bound`); other
        backends ignore it.
    """

    H: FloatArray
    f: FloatArray
    A: FloatArray
    lo: FloatArray
    up: FloatArray
    lb: FloatArray
    ub: FloatArray
    cones: tuple[DenseCone, ...] = ()
    hessian_floor: float = 0.0

    def __post_init__(self) -> None:
        for name in _FIELDS:
            setattr(
                self, name, real_array(name, getattr(self, name)).astype(np.float64, copy=False)
            )
        self.cones = tuple(self.cones)

    # ----------------------------------------------------------------------------------
    @property
    def n_variables(self) -> int:
        """Number of variables ``n``."""
        return int(self.f.shape[0])

    @property
    def n_rows(self) -> int:
        """Number of rows ``m_A`` of ``A``."""
        return int(self.A.shape[0])

    def structure_key(self) -> tuple[int, ...]:
        """``(n, m_A)``, then the row count of each cone: QPs with one key differ only in values."""
        if self.cones:
            return (self.f.shape[0], self.A.shape[0], *(c.F.shape[0] for c in self.cones))
        return (self.f.shape[0], self.A.shape[0])

    def check(self) -> None:
        """Validate shapes and values.

        Raises
        ------
        DimensionError
            If an array has the wrong shape (the message names it).
        InvalidValueError
            If ``H``, ``f`` or ``A`` has non-finite entries, ``H`` is not
            symmetric, a bound is NaN, ``lo``/``lb`` has ``+inf``, ``up``/``ub``
            has ``-inf``, ``lo > up`` / ``lb > ub`` somewhere, or ``hessian_floor`` is
            negative or not finite.
        """
        f = np.asarray(self.f)
        if f.ndim != 1 or f.shape[0] == 0:
            raise DimensionError(f"f must have shape (n,) with n >= 1, got {f.shape}")
        n = f.shape[0]
        H = np.asarray(self.H)
        if H.shape != (n, n):
            raise DimensionError(f"H must have shape ({n}, {n}), got {H.shape}")
        A = np.asarray(self.A)
        if A.ndim != 2 or A.shape[1] != n:
            raise DimensionError(f"A must have shape (m_A, {n}), got {A.shape}")
        m = A.shape[0]
        for name, length in (("lo", m), ("up", m), ("lb", n), ("ub", n)):
            shape = np.shape(getattr(self, name))
            if shape != (length,):
                raise DimensionError(f"{name} must have shape ({length},), got {shape}")
        for name in _FIELDS:
            if np.asarray(getattr(self, name)).dtype != np.float64:
                raise InvalidValueError(f"{name} must be a float64 array")
        for name in ("H", "f", "A"):
            arr = np.asarray(getattr(self, name))
            if not np.all(np.isfinite(arr)):
                bad = np.argwhere(~np.isfinite(arr))[:5].tolist()
                raise InvalidValueError(f"{name} has non-finite entries (NaN or inf) at {bad}")
        asym = float(np.max(np.abs(H - H.T)))
        if asym > _SYMMETRY_RTOL * max(1.0, float(np.max(np.abs(H)))):
            raise InvalidValueError(f"H must be symmetric; max |H - H^T| = {asym:.3g}")
        for name in ("lo", "up", "lb", "ub"):
            arr = np.asarray(getattr(self, name))
            if np.any(np.isnan(arr)):
                raise InvalidValueError(
                    f"{name} has NaN entries at indices {np.flatnonzero(np.isnan(arr))[:10]}"
                )
        _check_bounds("lo", self.lo, "up", self.up)
        _check_bounds("lb", self.lb, "ub", self.ub)
        floor = self.hessian_floor
        if not (
            isinstance(floor, (int, float, np.integer, np.floating))
            and not isinstance(floor, bool)
            and 0.0 <= floor < np.inf
        ):
            raise InvalidValueError(
                f"hessian_floor must be a finite number >= 0 (a lower bound on the smallest "
                f"eigenvalue of H; 0 for none), got {floor!r}"
            )
        for index, cone in enumerate(self.cones):
            if not isinstance(cone, DenseCone):
                raise InvalidValueError(
                    f"cones[{index}] must be a DenseCone, got {type(cone).__name__}"
                )
            cone.check(index, n)

    # ----------------------------------------------------------------------------------
    def objective(self, x: npt.ArrayLike) -> float:
        """Evaluate :math:`\\tfrac12 x^\\top H x + f^\\top x`."""
        xx = np.asarray(x, dtype=np.float64)
        if xx.shape != self.f.shape:
            raise DimensionError(f"x must have shape {self.f.shape}, got {xx.shape}")
        return float(0.5 * xx @ (self.H @ xx) + self.f @ xx)

    def max_violation(self, x: npt.ArrayLike) -> float:
        """Largest violation of the rows and bounds at ``x`` (0 when feasible, ``inf``
        for a non-finite ``x``)."""
        xx = np.asarray(x, dtype=np.float64)
        if xx.shape != self.f.shape:
            raise DimensionError(f"x must have shape {self.f.shape}, got {xx.shape}")
        if not math.isfinite(float(xx.sum())) and not np.all(np.isfinite(xx)):
            return float("inf")
        viol = _bounds_rows_violation(xx, self.lb, self.ub, self.A, self.lo, self.up)
        for cone in self.cones:
            viol = max(viol, _cone_violation(cone.F, cone.g, cone.e, cone.f, xx))
        return float(viol)

    def to_convex_problem(self) -> ConvexProblem:
        """The same QP as a :class:`ConvexProblem` (rows in ``G``, ``l = lo``, ``u = up``).

        ``H`` is symmetrized (same objective) and ``H`` and ``A`` keep every
        entry in their pattern, so the structure key depends on ``(n, m_A)`` and
        on which bounds are infinite, not on the values.
        """
        H = np.asarray(self.H, dtype=np.float64)
        P = _full_csc(0.5 * (H + H.T))
        m = self.A.shape[0]
        kwargs: dict[str, Any] = {"lb": self.lb, "ub": self.ub}
        if m:
            kwargs.update(G=_full_csc(self.A), l=self.lo, u=self.up)
        if self.cones:
            kwargs["cones"] = tuple(
                SecondOrderCone(_full_csc(c.F), c.g, c.e, c.f) for c in self.cones
            )
        return ConvexProblem(P=P, q=self.f, **kwargs)

    @classmethod
    def from_convex_problem(cls, problem: ConvexProblem) -> DenseQP:
        """``problem`` as a dense QP: rows ``[A_eq; G]`` with ``lo = up = b_eq`` for the
        equalities, missing bounds infinite, cones as :class:`DenseCone` (a QP-only backend
        refuses those). The inverse of :meth:`to_convex_problem` up to the row order."""
        n = problem.n_variables
        rows: list[FloatArray] = []
        lo: list[FloatArray] = []
        up: list[FloatArray] = []
        if problem.A_eq is not None and problem.b_eq is not None:
            rows.append(problem.A_eq.toarray())
            lo.append(np.asarray(problem.b_eq))
            up.append(np.asarray(problem.b_eq))
        if problem.G is not None and problem.l is not None and problem.u is not None:
            rows.append(problem.G.toarray())
            lo.append(np.asarray(problem.l))
            up.append(np.asarray(problem.u))
        A = np.vstack(rows) if rows else np.zeros((0, n))
        return cls(
            H=np.ascontiguousarray(problem.P.toarray()),
            f=np.array(problem.q, dtype=np.float64),
            A=np.ascontiguousarray(A),
            lo=np.concatenate(lo) if lo else np.zeros(0),
            up=np.concatenate(up) if up else np.zeros(0),
            lb=np.full(n, -np.inf) if problem.lb is None else np.array(problem.lb),
            ub=np.full(n, np.inf) if problem.ub is None else np.array(problem.ub),
            cones=tuple(DenseCone(c.F.toarray(), c.g, c.e, c.f) for c in problem.cones),
        )

    def copy(self) -> DenseQP:
        """Deep copy (new arrays)."""
        H, f, A, lo, up, lb, ub = (np.array(getattr(self, name)) for name in _FIELDS)
        return DenseQP(
            H,
            f,
            A,
            lo,
            up,
            lb,
            ub,
            cones=tuple(c.copy() for c in self.cones),
            hessian_floor=self.hessian_floor,
        )

    # ----------------------------------------------------------------------------------
    def save(self, path: str | PathLike[str]) -> Path:
        """Write the QP to an uncompressed ``.npz`` file (for replay); returns the path."""
        p = Path(path)
        if p.suffix != ".npz":
            p = p.with_name(p.name + ".npz")
        arrays = {name: np.asarray(getattr(self, name)) for name in _FIELDS}
        arrays["hessian_floor"] = np.asarray(float(self.hessian_floor))
        for i, cone in enumerate(self.cones):
            arrays |= {
                f"cone{i}_F": cone.F,
                f"cone{i}_g": cone.g,
                f"cone{i}_e": cone.e,
                f"cone{i}_f": np.asarray(cone.f),
            }
        np.savez(
            p,
            format=np.asarray(_FORMAT),
            format_version=np.asarray(_FORMAT_VERSION, dtype=np.int64),
            **arrays,  # type: ignore[arg-type]
        )
        return p

    @classmethod
    def load(cls, path: str | PathLike[str]) -> DenseQP:
        """Read a QP written by :meth:`save` (and :meth:`check` it)."""
        with np.load(Path(path), allow_pickle=False) as data:
            store = {k: data[k] for k in data.files}
        fmt = str(store.get("format", ""))
        version = int(store.get("format_version", -1))
        if fmt != _FORMAT or version != _FORMAT_VERSION:
            raise InvalidValueError(
                f"{path}: not a DenseQP file of format_version {_FORMAT_VERSION} "
                f"(format={fmt!r}, format_version={version})"
            )
        missing = [name for name in _FIELDS if name not in store]
        if missing:
            raise InvalidValueError(f"{path}: missing arrays {missing}")
        cones: list[DenseCone] = []
        while f"cone{len(cones)}_F" in store:
            i = len(cones)
            cones.append(
                DenseCone(
                    store[f"cone{i}_F"],
                    store[f"cone{i}_g"],
                    store[f"cone{i}_e"],
                    float(store[f"cone{i}_f"]),
                )
            )
        H, f, A, lo, up, lb, ub = (store[name] for name in _FIELDS)
        floor = float(store["hessian_floor"]) if "hessian_floor" in store else 0.0
        qp = cls(H, f, A, lo, up, lb, ub, cones=tuple(cones), hessian_floor=floor)
        qp.check()
        return qp


# --------------------------------------------------------------------------------------
# backend interface
# --------------------------------------------------------------------------------------
class DenseBackend(abc.ABC):
    """One dense solver workspace for one :meth:`DenseQP.structure_key`.

    Subclasses set the class attributes and implement :meth:`setup`,
    :meth:`solve` and, where the solver can, :meth:`update`. ``solve`` returns a
    :class:`~ltv_lstm_mpc.solvers.RawResult` whose ``z`` is a fresh array
    (the session copies it anyway) and whose duals follow the module's sign
    convention (``"ineq"``, ``"bounds"``). Native exceptions propagate.
    """

    #: Backend family name (``Solution.backend``).
    backend: ClassVar[str]
    #: Whether :meth:`update` writes new values into the workspace in place.
    supports_update: ClassVar[bool] = False
    #: Whether a warm start is used (otherwise it is ignored with a note).
    supports_warm_start: ClassVar[bool] = False
    #: Whether second-order cones (:attr:`DenseQP.cones`) are solved exactly.
    supports_cones: ClassVar[bool] = False
    #: Its cone points are the local SQP's solution (:meth:`refines_cone_points`).
    local_cone_solutions: ClassVar[bool] = False
    #: Entry point for compiled callers (see :attr:`DenseSession.native`); none by default.
    native: Any = None

    def compiled_workspace(self) -> tuple[Any, dict[str, Any]] | None:
        """The compiled workspace of the current setup and its arrays by name, for a
        compiled caller that solves on it (see :meth:`DenseSession.compiled_workspace`);
        None by default (and before a setup)."""
        return None

    def clear_state(self) -> bool:
        """Drop what the workspace keeps from earlier solves, in place (its problem data
        kept): as a fresh setup would, without replacing the workspace. False where the
        backend cannot (the default): :meth:`DenseSession.reset` then drops the workspace."""
        return False

    def __init__(self, name: str, solver: str, options: Mapping[str, Any]) -> None:
        """Store the registry name, the native solver name and the merged options."""
        self.name = name
        self.solver = solver
        self.options = dict(options)

    def handles_cones(self) -> bool:
        """Whether this workspace solves the cones of a :class:`DenseQP` exactly."""
        return self.supports_cones

    def refines_cone_points(self) -> bool:
        """Whether this workspace's ``OPTIMAL`` points on cone problems are already the
        local SQP's solution (``daqp:socp``): the acceptance layer's distance check
        (:func:`~ltv_lstm_mpc.solvers.cone_point.check_cone_point`) skips them."""
        return self.local_cone_solutions

    @abc.abstractmethod
    def setup(self, qp: DenseQP) -> None:
        """Build the workspace for ``qp`` (its ``(n, m_A)`` is fixed from now on)."""

    def update(self, qp: DenseQP) -> None:
        """Write the values of ``qp`` (same structure key) into the workspace."""
        raise NotImplementedError(f"{self.name} cannot update in place")

    @abc.abstractmethod
    def solve(self, warm_start: WarmStart | None) -> RawResult:
        """Solve the current data (``warm_start=None``: a cold start)."""

    def solve_point(self) -> tuple[SolverStatus, FloatArray | None, int, str]:
        """Cold solve of the current data: ``(status, z, iterations, native status)``.

        The hot-loop variant of :meth:`solve` (no duals, no result object); the
        default calls :meth:`solve`. A backend may override it with a leaner call
        that maps the status the same way.
        """
        raw = self.solve(None)
        info = raw.native_status if not raw.notes else "; ".join((raw.native_status, *raw.notes))
        return raw.status, raw.z, int(raw.iterations or 0), info


#: ``dense_factory(name, tolerance, settings) -> DenseBackend`` as stored in the registry.
DenseBackendFactory = Callable[[str, float, Mapping[str, Any]], DenseBackend]
