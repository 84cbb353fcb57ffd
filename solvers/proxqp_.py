"""Native ProxQP backend (``"proxqp"``): proxsuite's dense ``proxqp.dense.QP``, init once, update.

ProxQP (a primal-dual proximal augmented Lagrangian method, first-order-like
accuracy) solves ``min 1/2 x'Hx + g'x  s.t.  A x = b,  l <= C x <= u,
l_box <= x <= u_box``; a :class:`DenseQP` maps to ``C = A`` (rows with
``lo = up`` stay rows) and the box constraints. The workspace is built with
``init`` and updated with ``update`` (the preconditioner is kept).

Warm start
    ``warm_start=None`` is a cold start (``EQUALITY_CONSTRAINED_INITIAL_GUESS``,
    ProxQP's default). A previous :class:`Solution` (the MPC's usual warm
    start) uses ``WARM_START_WITH_PREVIOUS_RESULT``: the workspace's own last
    primal-dual iterate, cheaper than passing the vectors back. A primal array
    uses ``WARM_START`` from that point. After a failed solve the workspace is
    rebuilt with ``init`` at the next update (no stale iterate).

Settings are the attributes of ``qp.settings`` (checked); the tolerance sets
``eps_abs`` and ``eps_rel = 0`` (:mod:`.tolerances`).
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any, ClassVar

import numpy as np

from ._base import RawResult, WarmStart, check_settings, map_status, warm_start_vectors
from .dense import DenseBackend, DenseQP
from .problem import Solution, SolverStatus
from .tolerances import known_settings, solver_options

#: proxsuite ``QPSolverOutput`` name -> SolverStatus.
STATUS_MAP: Mapping[str, SolverStatus] = {
    "PROXQP_SOLVED": SolverStatus.OPTIMAL,
    "PROXQP_MAX_ITER_REACHED": SolverStatus.MAX_ITER,
    "PROXQP_PRIMAL_INFEASIBLE": SolverStatus.INFEASIBLE,
    "PROXQP_SOLVED_CLOSEST_PRIMAL_FEASIBLE": SolverStatus.INFEASIBLE,
    "PROXQP_DUAL_INFEASIBLE": SolverStatus.UNBOUNDED,
    "PROXQP_NOT_RUN": SolverStatus.FAILED,
}


def status_name(code: Any) -> str:
    """``QPSolverOutput.PROXQP_SOLVED`` -> ``"PROXQP_SOLVED"``."""
    return str(getattr(code, "name", code)).split(".")[-1]


class ProxqpDense(DenseBackend):
    """Persistent dense ProxQP workspace."""

    backend: ClassVar[str] = "proxqp"
    supports_update: ClassVar[bool] = True
    supports_warm_start: ClassVar[bool] = True

    def __init__(self, name: str, tolerance: float, settings: Mapping[str, Any]) -> None:
        """Merge tolerance options and settings and check the setting names."""
        import proxsuite

        check_settings("proxqp", settings, known_settings("proxqp"))
        options = {"compute_timings": True, **solver_options("proxqp", tolerance, settings)}
        super().__init__(name, "proxqp", options)
        self._px = proxsuite.proxqp
        guess = self._px.InitialGuess
        self._cold = guess.EQUALITY_CONSTRAINED_INITIAL_GUESS
        self._previous = guess.WARM_START_WITH_PREVIOUS_RESULT
        self._given = guess.WARM_START
        self._qp: Any = None

    def _args(self, qp: DenseQP) -> tuple[Any, ...]:
        if qp.n_rows:
            return (qp.H, qp.f, None, None, qp.A, qp.lo, qp.up, qp.lb, qp.ub)
        return (qp.H, qp.f, None, None, None, None, None, qp.lb, qp.ub)

    def _new_model(self) -> Any:
        model = self._px.dense.QP(self._n, 0, self._m, True)
        for key, value in self.options.items():
            setattr(model.settings, key, value)
        return model

    def setup(self, qp: DenseQP) -> None:
        """Create the ProxQP model and ``init`` it."""
        n, m = qp.n_variables, qp.n_rows
        self._n, self._m = n, m
        model = self._new_model()
        self._data = self._args(qp)
        model.init(*self._data)
        self._qp = model
        self._used = False
        self._stale = False
        self._solved = False

    def update(self, qp: DenseQP) -> None:
        """``update`` the values (a fresh ``init`` after a failed solve)."""
        if self._stale:
            self.setup(qp)
            return
        self._data = self._args(qp)
        self._qp.update(*self._data)

    def solve(self, warm_start: WarmStart | None) -> RawResult:
        """Solve from the cold, previous or given start."""
        previous = isinstance(warm_start, Solution) and self._solved
        if self._used and not previous:
            # proxsuite 0.8 keeps its internal state (penalties, iterates) in a used model:
            # a cold or given-point start on it ended at MAX_ITER or a false INFEASIBLE.
            # Such a start gets a fresh model (``init``) on the current data.
            self._qp = self._new_model()
            self._qp.init(*self._data)
        self._used = True
        model = self._qp
        settings = model.settings
        if warm_start is None:
            settings.initial_guess = self._cold
            model.solve()
        elif previous:
            settings.initial_guess = self._previous
            model.solve()
        else:
            z0, _ = warm_start_vectors(warm_start, self._n)
            if z0 is None:
                settings.initial_guess = self._cold
                model.solve()
            else:
                settings.initial_guess = self._given
                model.solve(z0, None, None)
        res = model.results
        info = res.info
        name = status_name(info.status)
        status, note = map_status(STATUS_MAP, name)
        z = duals = None
        if status.has_solution:
            z = np.array(res.x, dtype=np.float64)
            zz = np.asarray(res.z, dtype=np.float64)
            m = self._m
            duals = {"ineq": zz[:m].copy(), "bounds": zz[m : m + self._n].copy()}
            self._solved = True
        else:
            self._stale = True
            self._solved = False
        return RawResult(
            status=status,
            native_status=name,
            z=z,
            duals=duals,
            solve_time=float(info.solve_time) * 1e-6,  # proxsuite reports microseconds
            iterations=int(info.iter),
            extra_setup_time=0.0,
            notes=() if note is None else (note,),
        )


def make_dense(name: str, tolerance: float, settings: Mapping[str, Any]) -> DenseBackend:
    """Registry dense factory for ``"proxqp"``."""
    return ProxqpDense(name, tolerance, settings)
