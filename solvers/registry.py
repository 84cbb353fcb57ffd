"""Registry of installed backends, the persistent :class:`Session`, the one-shot :func:`solve`."""

from __future__ import annotations

import functools
import importlib.util
import time
from collections.abc import Callable, Mapping
from typing import Any

import numpy as np

from ltv_lstm_mpc.exceptions import InvalidValueError, SolverError, SolverNotFound

from ._base import Backend, BackendFactory, FloatArray, RawResult, WarmStart
from .problem import ConvexProblem, Solution, SolverStatus
from .reformulation import ConeReformulation

__all__ = ["DEFAULT_SOLVER", "Session", "available_solvers", "get_backend", "solve"]

#: Solver used when none is named: exact cones, interior point, high accuracy.
DEFAULT_SOLVER = "cvxpy:CLARABEL"
_EXTRA_HINT = 'pip install "ltv_lstm_mpc[solvers]"'


def _installed(module: str) -> bool:
    return importlib.util.find_spec(module) is not None


def _native_factories() -> dict[str, Callable[[], BackendFactory]]:
    """Native backends: name -> loader of the factory (imports only when installed)."""
    out: dict[str, Callable[[], BackendFactory]] = {}
    if _installed("osqp"):
        out["osqp"] = lambda: __import__(f"{__package__}.osqp_", fromlist=["make"]).make
    if _installed("piqp"):
        out["piqp"] = lambda: __import__(f"{__package__}.piqp_", fromlist=["x"]).make_auto
        out["piqp:sparse"] = lambda: __import__(f"{__package__}.piqp_", fromlist=["x"]).make_sparse
        out["piqp:dense"] = lambda: __import__(f"{__package__}.piqp_", fromlist=["x"]).make_dense
    if _installed("daqp"):
        out["daqp"] = lambda: __import__(f"{__package__}.daqp_", fromlist=["make"]).make
    return out


@functools.cache
def _registry() -> dict[str, BackendFactory]:
    """Name -> factory for every backend that imports (guarded imports, computed once)."""
    reg: dict[str, BackendFactory] = {}
    try:
        import cvxpy as cp

        from . import cvxpy_

        for s in cvxpy_.supported_solvers(cp.installed_solvers()):
            reg[f"cvxpy:{s}"] = cvxpy_.factory(s)
    except ImportError:
        pass
    try:
        import qpsolvers

        from . import qpsolvers_

        for s in sorted(qpsolvers.available_solvers):
            reg[f"qpsolvers:{s}"] = qpsolvers_.factory(s)
    except ImportError:
        pass
    for name, loader in _native_factories().items():
        try:
            reg[name] = loader()
        except ImportError:
            continue
    return reg


def available_solvers() -> list[str]:
    """Names of the installed solvers, e.g. ``["cvxpy:CLARABEL", ..., "osqp", "piqp"]``.

    ``cvxpy:<SOLVER>`` for the cvxpy solvers this layer supports (CLARABEL, ECOS,
    SCS for cones; OSQP, PIQP, PROXQP, DAQP, HIGHS for QPs), ``qpsolvers:<name>``
    for every solver in ``qpsolvers.available_solvers``, and the native
    ``osqp``, ``piqp`` (``piqp:sparse``, ``piqp:dense``) and ``daqp``.
    """
    return list(_registry())


def cone_solvers() -> list[str]:
    """Installed solvers that solve second-order cones exactly."""
    from .cvxpy_ import CONE_SOLVERS

    return [s for s in available_solvers() if s.startswith("cvxpy:") and s[6:] in CONE_SOLVERS]


def get_backend(name: str) -> BackendFactory:
    """Factory of the backend ``name``.

    Raises
    ------
    SolverNotFound
        If ``name`` is not installed (or unknown); the message lists the
        installed solvers and the extra to install.
    """
    reg = _registry()
    if name in reg:
        return reg[name]
    raise SolverNotFound(
        f"solver {name!r} is not available. Installed: {', '.join(reg) or 'none'}. "
        f"Names are 'cvxpy:<SOLVER>', 'qpsolvers:<solver>', 'osqp', 'piqp', 'daqp'; "
        f"install the solvers with: {_EXTRA_HINT}"
    )


class Session:
    """Persistent solver workspace for one problem structure.

    ``setup`` once, then per step ``update`` (same :meth:`ConvexProblem.structure_key`,
    new values) and ``solve``. Backends that cannot update in place (qpsolvers)
    are set up afresh on ``update``; :attr:`last_update` and ``Solution.info``
    record it.

    Parameters
    ----------
    solver : str
        Registry name (see :func:`available_solvers`).
    tolerance : float
        Mapped to the solver's own tolerance options
        (:data:`~ltv_lstm_mpc.solvers.tolerances.TOLERANCE_OPTIONS`).
    reformulation : ConeReformulation, optional
        Applied when the problem has cones and the backend cannot take them;
        without it such a problem raises :class:`InvalidValueError`.
    raise_on_failure : bool
        Raise :class:`SolverError` when the status is not optimal (default:
        return the status in the solution, the closed-loop behaviour).
    **settings
        Native solver settings; they override the tolerance mapping. Unknown
        names are rejected where the solver's settings can be listed.

    Examples
    --------
    >>> s = Session("osqp", tolerance=1e-6)            # doctest: +SKIP
    >>> s.setup(problem); sol = s.solve()              # doctest: +SKIP
    >>> s.update(next_problem); sol = s.solve(warm_start=sol)  # doctest: +SKIP
    """

    def __init__(
        self,
        solver: str = DEFAULT_SOLVER,
        *,
        tolerance: float = 1e-8,
        reformulation: ConeReformulation | None = None,
        raise_on_failure: bool = False,
        **settings: Any,
    ) -> None:
        self._factory = get_backend(solver)
        if reformulation is not None and not isinstance(reformulation, ConeReformulation):
            raise InvalidValueError(
                "reformulation must have a 'name' and an 'apply(problem)' method, "
                f"got {type(reformulation).__name__}"
            )
        self.solver = solver
        self.tolerance = float(tolerance)
        self.reformulation = reformulation
        self.raise_on_failure = bool(raise_on_failure)
        self.settings: Mapping[str, Any] = dict(settings)
        # Build one backend now: validates tolerance and settings early.
        self._backend: Backend = self._factory(solver, self.tolerance, self.settings)
        self._ready = False
        self._key: str | None = None
        self._problem: ConvexProblem | None = None
        self._solved: ConvexProblem | None = None
        self._applied: str | None = None
        self._pending_setup = 0.0
        self._pending_notes: list[str] = []
        #: ``"setup"``, ``"in_place"`` or ``"fresh_setup"``: what the last setup/update did.
        self.last_update: str | None = None
        #: Number of solver workspaces built so far.
        self.n_setups = 0

    # ---------------------------------------------------------------------------------
    @property
    def backend(self) -> str:
        """Backend family (``"cvxpy"``, ``"qpsolvers"``, ``"osqp"``, ``"piqp"``, ``"daqp"``)."""
        return self._backend.backend

    @property
    def structure_key(self) -> str | None:
        """Structure key of the problem set up (``None`` before :meth:`setup`)."""
        return self._key

    @property
    def problem(self) -> ConvexProblem | None:
        """The problem last given to :meth:`setup` / :meth:`update`."""
        return self._problem

    def _prepare(self, problem: ConvexProblem) -> tuple[ConvexProblem, str | None]:
        if not isinstance(problem, ConvexProblem):
            raise InvalidValueError(
                f"problem must be a ConvexProblem, got {type(problem).__name__}"
            )
        if not problem.has_cones or self._backend.handles_cones():
            return problem, None
        if self.reformulation is None:
            from .registry import cone_solvers

            raise InvalidValueError(
                f"{self.solver} solves QPs only and the problem has {len(problem.cones)} "
                "second-order cone(s); cones are never dropped silently. Pass "
                "reformulation=... (a ConeReformulation, e.g. PolyhedralInnerApproximation()) "
                f"or use a cone solver: {', '.join(cone_solvers()) or 'none installed'}"
            )
        solved = self.reformulation.apply(problem)
        if not isinstance(solved, ConvexProblem) or solved.has_cones:
            raise SolverError(
                f"reformulation {self.reformulation.name!r} must return a ConvexProblem "
                "without cones"
            )
        if solved.n_variables < problem.n_variables:
            raise SolverError(
                f"reformulation {self.reformulation.name!r} removed variables "
                f"({problem.n_variables} -> {solved.n_variables}); it may only append"
            )
        return solved, self.reformulation.name

    def setup(self, problem: ConvexProblem) -> None:
        """Build the solver workspace for ``problem`` (any structure)."""
        solved, applied = self._prepare(problem)
        start = time.perf_counter()
        if self.n_setups:
            self._backend = self._factory(self.solver, self.tolerance, self.settings)
        try:
            self._backend.setup(solved)
        except (ValueError, TypeError, RuntimeError) as exc:
            self._ready = False
            raise SolverError(f"{self.solver}: setup failed: {exc}") from exc
        self._pending_setup = time.perf_counter() - start
        self._pending_notes = []
        self.n_setups += 1
        self.last_update = "setup"
        self._ready = True
        self._key = problem.structure_key()
        self._solved_key = solved.structure_key()
        self._problem, self._solved, self._applied = problem, solved, applied

    def update(self, problem: ConvexProblem) -> None:
        """Replace the values; ``problem`` must have the structure given to :meth:`setup`.

        Raises
        ------
        InvalidValueError
            If the structure key differs (call :meth:`setup` for a new structure).
        """
        if not self._ready:
            raise SolverError("Session.update() called before setup()")
        if problem.structure_key() != self._key:
            raise InvalidValueError(
                "problem structure (shapes, sparsity patterns or finite-bound pattern) "
                "differs from the one set up; call setup() for a new structure"
            )
        solved, applied = self._prepare(problem)
        in_place = self._backend.supports_update and solved.structure_key() == self._solved_key
        start = time.perf_counter()
        if in_place:
            try:
                self._backend.update(solved)
            except (ValueError, TypeError, RuntimeError) as exc:
                raise SolverError(f"{self.solver}: update failed: {exc}") from exc
            self.last_update = "in_place"
            notes: list[str] = []
        else:
            self._backend = self._factory(self.solver, self.tolerance, self.settings)
            self._backend.setup(solved)
            self.n_setups += 1
            self.last_update = "fresh_setup"
            why = (
                "backend cannot update in place"
                if not self._backend.supports_update
                else "reformulated structure changed"
            )
            notes = [f"fresh setup ({why})"]
        self._pending_setup = time.perf_counter() - start
        self._pending_notes = notes
        self._problem, self._solved, self._applied = problem, solved, applied

    def solve(self, warm_start: WarmStart | None = None) -> Solution:
        """Solve the current data.

        Parameters
        ----------
        warm_start : (n,) array or Solution, optional
            Primal point (and, from a :class:`Solution`, multipliers) to start
            from; ``None`` is a cold start. Backends without warm start ignore it
            and say so in ``info``.
        """
        if not self._ready or self._problem is None or self._solved is None:
            raise SolverError("Session.solve() called before setup()")
        n = self._problem.n_variables
        n_solved = self._solved.n_variables
        ws: WarmStart | None = warm_start
        if ws is not None and n_solved != n:
            z0 = ws.z if isinstance(ws, Solution) else np.asarray(ws, dtype=np.float64)
            ws = None if z0 is None else np.concatenate([z0, np.zeros(n_solved - n)])
        start = time.perf_counter()
        raw = self._backend.solve(ws)
        wall = time.perf_counter() - start
        solution = self._to_solution(raw, wall)
        self._pending_setup = 0.0
        self._pending_notes = []
        if self.raise_on_failure and solution.status is not SolverStatus.OPTIMAL:
            raise SolverError(f"{self.solver} returned {solution.status.name}: {solution.info}")
        return solution

    def _to_solution(self, raw: RawResult, wall: float) -> Solution:
        assert self._problem is not None and self._solved is not None  # for mypy
        n = self._problem.n_variables
        z: FloatArray | None = None
        objective: float | None = None
        raw_z = raw.z
        if raw_z is not None:
            if raw_z.shape != (self._solved.n_variables,) or not np.all(np.isfinite(raw_z)):
                extra = ("solver returned a malformed or non-finite z",)
                raw = RawResult(
                    status=SolverStatus.FAILED,
                    native_status=raw.native_status,
                    z=None,
                    duals=None,
                    solve_time=raw.solve_time,
                    iterations=raw.iterations,
                    extra_setup_time=raw.extra_setup_time,
                    notes=raw.notes + extra,
                )
            else:
                objective = self._solved.objective(raw_z)
                z = raw_z[:n].copy()
                z.setflags(write=False)
        info = "; ".join([f"native status: {raw.native_status}", *self._pending_notes, *raw.notes])
        overhead = max(0.0, wall - raw.solve_time - raw.extra_setup_time)
        return Solution(
            status=raw.status,
            z=z,
            objective=float("nan") if objective is None else objective,
            duals=raw.duals,
            setup_time=self._pending_setup + raw.extra_setup_time,
            solve_time=raw.solve_time,
            overhead_time=overhead,
            iterations=raw.iterations,
            backend=self._backend.backend,
            solver=self.solver,
            reformulation=self._applied,
            info=info,
        )


def solve(
    problem: ConvexProblem,
    solver: str = DEFAULT_SOLVER,
    *,
    tolerance: float = 1e-8,
    warm_start: WarmStart | None = None,
    reformulation: ConeReformulation | None = None,
    raise_on_failure: bool = False,
    **settings: Any,
) -> Solution:
    """Solve ``problem`` once (a throw-away :class:`Session`).

    Parameters are those of :class:`Session` plus ``warm_start`` (see
    :meth:`Session.solve`).
    """
    session = Session(
        solver,
        tolerance=tolerance,
        reformulation=reformulation,
        raise_on_failure=raise_on_failure,
        **settings,
    )
    session.setup(problem)
    return session.solve(warm_start)
