"""Backend interface shared by every ``<solver>_.py`` module (internal)."""

from __future__ import annotations

import abc
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any, ClassVar, NoReturn

import numpy as np
import numpy.typing as npt
import scipy.sparse as sp

from ltv_lstm_mpc.exceptions import InvalidValueError, LtvMpcError, SolverError

from .problem import ConvexProblem, Solution, SolverStatus

FloatArray = npt.NDArray[np.float64]
IntArray = npt.NDArray[np.int64]
#: A warm start: a primal point ``z`` of shape ``(n,)`` or a previous :class:`Solution`.
WarmStart = FloatArray | Solution


@dataclass(frozen=True)
class RawResult:
    """What a backend's ``solve`` returns; the session turns it into a :class:`Solution`."""

    status: SolverStatus
    native_status: str
    z: FloatArray | None
    duals: Mapping[str, FloatArray] | None
    solve_time: float
    iterations: int | None
    extra_setup_time: float = 0.0
    notes: tuple[str, ...] = ()
    #: The solver's own objective value at ``z`` (dense sessions use it instead of
    #: re-evaluating it); ``None`` where the solver reports none.
    objective: float | None = None
    #: A certificate of the status where the backend returns one (checked by the layer,
    #: :mod:`~ltv_lstm_mpc.solvers.acceptance`): for ``INFEASIBLE`` a Farkas vector keyed
    #: like ``duals``; for ``UNBOUNDED`` ``{"direction": d}``.
    certificate: Mapping[str, FloatArray] | None = None


def raise_backend_error(solver: str, phase: str, exc: Exception) -> NoReturn:
    """Raise the error for an exception out of a backend's ``phase`` (call in ``except``).

    An error of the library's own (bad input the backend found, a :class:`SolverError`)
    is raised as it is; any other exception becomes a :class:`SolverError` that names the
    solver, the phase and the cause (chained).
    """
    if isinstance(exc, LtvMpcError):
        raise exc
    raise SolverError(f"{solver}: {phase} raised {type(exc).__name__}: {exc}") from exc


def map_status(table: Mapping[Any, SolverStatus], code: Any) -> tuple[SolverStatus, str | None]:
    """Look ``code`` up in a backend's ``STATUS_MAP``.

    Returns the mapped status and ``None``, or ``FAILED`` and a note naming the
    unknown native code.
    """
    try:
        return table[code], None
    except (KeyError, TypeError):
        return SolverStatus.FAILED, f"unknown native status {code!r} mapped to FAILED"


def check_settings(solver: str, settings: Mapping[str, Any], known: Sequence[str] | None) -> None:
    """Reject settings the solver does not know (``known=None``: the solver checks itself)."""
    if known is None:
        return
    unknown = sorted(set(settings) - set(known))
    if unknown:
        raise InvalidValueError(
            f"unknown setting(s) {unknown} for solver {solver!r}; known settings: {sorted(known)}"
        )


def warm_start_vectors(
    warm_start: WarmStart | None, n: int
) -> tuple[FloatArray | None, Solution | None]:
    """Split a warm start into a primal vector of length ``n`` and the solution it came from."""
    from ltv_lstm_mpc.exceptions import DimensionError

    if warm_start is None:
        return None, None
    if isinstance(warm_start, Solution):
        if warm_start.z is None:
            return None, warm_start
        z = np.asarray(warm_start.z, dtype=np.float64)
        sol: Solution | None = warm_start
    else:
        z = np.asarray(warm_start, dtype=np.float64)
        sol = None
    if z.shape != (n,):
        raise DimensionError(f"warm_start must have shape ({n},), got {z.shape}")
    if not np.all(np.isfinite(z)):
        raise InvalidValueError("warm_start has non-finite entries")
    return z, sol


class StackedMatrix:
    """Vertical stack of CSC blocks with a fixed pattern, updatable from the blocks' data.

    ``matrix`` is the stacked CSC matrix; :meth:`values` returns its ``.data``
    for new blocks of the same patterns (one gather, no scipy construction).
    """

    def __init__(self, blocks: Sequence[sp.csc_matrix], n: int) -> None:
        sizes = [b.nnz for b in blocks]
        self._offsets = np.concatenate([[0], np.cumsum(sizes)]).astype(np.int64)
        total = int(self._offsets[-1])
        tagged = []
        for b, off in zip(blocks, self._offsets[:-1], strict=False):
            t = sp.csc_matrix(
                (np.arange(1, b.nnz + 1, dtype=np.float64) + off, b.indices, b.indptr),
                shape=b.shape,
            )
            tagged.append(t)
        if tagged:
            stacked = sp.csc_matrix(sp.vstack(tagged, format="csc"))
        else:
            stacked = sp.csc_matrix((0, n))
        stacked.sort_indices()
        self._perm: IntArray = stacked.data.astype(np.int64) - 1
        if self._perm.size != total:
            raise AssertionError("internal error: stacked pattern lost entries")
        self.matrix = sp.csc_matrix(
            (self.values(blocks), stacked.indices.copy(), stacked.indptr.copy()),
            shape=stacked.shape,
        )

    def values(self, blocks: Sequence[sp.csc_matrix]) -> FloatArray:
        """Data of the stacked matrix in its CSC order for new block values."""
        if not blocks:
            return np.zeros(0)
        src = np.concatenate([np.asarray(b.data, dtype=np.float64) for b in blocks])
        return src[self._perm]


def bound_rows(problem: ConvexProblem) -> tuple[IntArray, sp.csc_matrix]:
    """Indices of variables with a finite bound and the selector matrix of those rows."""
    if problem.lb is None or problem.ub is None:
        idx = np.zeros(0, dtype=np.int64)
    else:
        idx = np.flatnonzero(np.isfinite(problem.lb) | np.isfinite(problem.ub)).astype(np.int64)
    sel = sp.csc_matrix(
        (np.ones(idx.size), (np.arange(idx.size), idx)), shape=(idx.size, problem.n_variables)
    )
    return idx, sel


class Backend(abc.ABC):
    """One solver workspace for one problem structure.

    Subclasses set the class attributes and implement :meth:`setup`,
    :meth:`solve` and, where possible, :meth:`update`.
    """

    #: Backend family name (``Solution.backend``).
    backend: ClassVar[str]
    #: Whether second-order cones are solved exactly.
    supports_cones: ClassVar[bool] = False
    #: Its cone points are the local SQP's solution (:meth:`refines_cone_points`).
    local_cone_solutions: ClassVar[bool] = False
    #: Whether :meth:`update` changes values in place.
    supports_update: ClassVar[bool] = False
    #: Whether a warm start is used (otherwise it is ignored with a note).
    supports_warm_start: ClassVar[bool] = False

    def __init__(self, name: str, solver: str, options: Mapping[str, Any]) -> None:
        """Store the registry name, the native solver name and the merged options."""
        self.name = name
        self.solver = solver
        self.options = dict(options)

    def handles_cones(self) -> bool:
        """Whether this workspace solves second-order cones exactly."""
        return self.supports_cones

    def refines_cone_points(self) -> bool:
        """Whether this workspace's ``OPTIMAL`` points on cone problems are already the
        local SQP's solution (``daqp:socp``): the acceptance layer's distance check
        (:func:`~ltv_lstm_mpc.solvers.cone_point.check_cone_point`) skips them."""
        return self.local_cone_solutions

    @abc.abstractmethod
    def setup(self, problem: ConvexProblem) -> None:
        """Build the solver data for ``problem`` (its structure is fixed from now on)."""

    def update(self, problem: ConvexProblem) -> None:
        """Replace the values (same structure) in place."""
        raise NotImplementedError(f"{self.name} cannot update in place")

    @abc.abstractmethod
    def solve(self, warm_start: WarmStart | None) -> RawResult:
        """Solve the current data."""


#: ``factory(name, tolerance, settings) -> Backend`` as stored in the registry.
BackendFactory = Callable[[str, float, Mapping[str, Any]], Backend]
