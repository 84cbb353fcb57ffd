"""The persistent :class:`Session` (one solver workspace per problem structure) and the
one-shot :func:`solve`, for :class:`~ltv_lstm_mpc.solvers.ConvexProblem`.

Both take a registry name (:func:`~ltv_lstm_mpc.solvers.available_solvers`); every answer
passes the layer's acceptance check (:mod:`~ltv_lstm_mpc.solvers.acceptance`).
"""

from __future__ import annotations

import dataclasses
import time
from collections.abc import Mapping
from typing import Any

import numpy as np

from ltv_lstm_mpc.exceptions import InvalidValueError, SolverError
from ltv_lstm_mpc.validation import expect_bool, real_scalar

from ._base import Backend, FloatArray, RawResult, WarmStart, raise_backend_error
from .acceptance import ProblemView, accept
from .cone_point import check_cone_point
from .dense import DenseQP
from .problem import ConvexProblem, Solution, SolverStatus
from .reformulation import ConeReformulation
from .registry import DEFAULT_SOLVER, cone_solvers, get_backend
from .tolerances import feasibility_tolerance, optimality_tolerance

__all__ = ["Session", "solve"]


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
        self.tolerance = real_scalar("tolerance", tolerance)
        self.reformulation = reformulation
        self.raise_on_failure = expect_bool("raise_on_failure", raise_on_failure)
        self._feasibility = feasibility_tolerance(solver, self.tolerance)
        self._optimality = optimality_tolerance(solver, self.tolerance)
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
        # hold a cone problem's OPTIMAL point to its distance from the local solution
        # (cone_point.check_cone_point): set by solve(), off on the closed loops' sessions
        self._check_points = False

    # ---------------------------------------------------------------------------------
    @property
    def backend(self) -> str:
        """Backend family (``"cvxpy"``, ``"qpsolvers"``, ``"osqp"``, ``"daqp"``, ...)."""
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
        except Exception as exc:
            self._ready = False
            raise_backend_error(self.solver, "setup", exc)
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
            except Exception as exc:
                raise_backend_error(self.solver, "update", exc)
            self.last_update = "in_place"
            notes: list[str] = []
        else:
            self._backend = self._factory(self.solver, self.tolerance, self.settings)
            try:
                self._backend.setup(solved)
            except Exception as exc:
                self._ready = False
                raise_backend_error(self.solver, "setup", exc)
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
        try:
            raw = self._backend.solve(ws)
        except Exception as exc:
            raise_backend_error(self.solver, "solve", exc)
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
        elif raw.status.has_solution:
            raw = dataclasses.replace(
                raw, status=SolverStatus.FAILED, notes=(*raw.notes, "solver returned no point")
            )
        residuals = None
        if raw.z is not None or raw.certificate is not None:
            raw, residuals = accept(
                ProblemView.of_convex(self._solved), raw, self._feasibility, self._optimality
            )
            if (
                self._check_points
                and self._solved.has_cones
                and not self._backend.refines_cone_points()
            ):
                qp = DenseQP.from_convex_problem(self._solved)  # one-shot solve() only
                raw = check_cone_point(qp, raw, self._optimality)
            raw_z = raw.z
            if raw_z is not None:
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
            residuals=residuals,
            certificate=raw.certificate,
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
    session._check_points = True
    session.setup(problem)
    return session.solve(warm_start)
