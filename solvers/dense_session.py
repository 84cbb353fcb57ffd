r""":class:`DenseSession`: one dense solver workspace, one solve per control step.

The session sets a :class:`~ltv_lstm_mpc.solvers.DenseBackend` up for a
:class:`~ltv_lstm_mpc.solvers.DenseQP` (``dense.py``: the data classes and the backend
interface), writes new values into it in place, solves, and holds every answer of
:meth:`DenseSession.solve` to the layer's acceptance check (``acceptance.py``).
"""

from __future__ import annotations

import dataclasses
import math
import time
from collections.abc import Mapping
from typing import Any

import numpy as np

from ltv_lstm_mpc.exceptions import InvalidValueError, SolverError
from ltv_lstm_mpc.validation import expect_bool

from ._base import FloatArray, RawResult, WarmStart, raise_backend_error
from .acceptance import ProblemView, accept
from .cone_point import check_cone_point
from .dense import DenseBackend, DenseQP
from .problem import Solution, SolverStatus
from .registry import cone_solvers, get_dense_backend
from .tolerances import feasibility_tolerance, optimality_tolerance

__all__ = ["DenseSession"]


def _usable_point(z: FloatArray, qp: DenseQP) -> bool:
    """A solver point of the right shape with finite entries (one sum on the hot path: a
    non-finite entry makes it non-finite; the exact test runs only then)."""
    return z.shape == qp.f.shape and (math.isfinite(float(z.sum())) or bool(np.isfinite(z).all()))


# --------------------------------------------------------------------------------------
# session
# --------------------------------------------------------------------------------------
class DenseSession:
    """Persistent dense solver workspace: one :meth:`solve` per control step.

    The first call, or a call whose :meth:`DenseQP.structure_key` differs from
    the previous one, checks the QP (:meth:`DenseQP.check`) and sets a workspace
    up; every other call writes the new values in place (backends that cannot
    update set up afresh, noted in ``Solution.info``) and solves. Nothing is
    validated on that path, so keep the arrays finite and the shapes fixed.

    Parameters
    ----------
    solver : str
        Registry name (:func:`~ltv_lstm_mpc.solvers.available_solvers`).
    tolerance : float
        Mapped to the solver's own options
        (:data:`~ltv_lstm_mpc.solvers.tolerances.TOLERANCE_OPTIONS`).
    equilibrate : bool
        Ruiz-equilibrate every QP (variables and rows scaled to unit infinity norms,
        :mod:`~ltv_lstm_mpc.solvers.equilibration`) before the backend sees it, and map
        the point and multipliers back; off by default. Meant for the backends that do
        not scale internally (DAQP, quadprog) on badly scaled QPs.
    **settings
        Native settings; they override the tolerance mapping. Unknown names are
        rejected where the solver's settings can be listed.

    Examples
    --------
    >>> session = DenseSession("daqp", tolerance=1e-8)   # doctest: +SKIP
    >>> sol = session.solve(qp)                          # doctest: +SKIP
    >>> qp.f[:] = new_f; sol = session.solve(qp, warm_start=sol)  # doctest: +SKIP
    """

    def __init__(
        self,
        solver: str,
        *,
        tolerance: float = 1e-8,
        equilibrate: bool = False,
        **settings: Any,
    ) -> None:
        self._factory = get_dense_backend(solver)
        self.solver = solver
        self.tolerance = float(tolerance)
        #: Ruiz-equilibrate each QP before the backend sees it (:mod:`.equilibration`).
        self.equilibrate = expect_bool("equilibrate", equilibrate)
        self._feasibility = feasibility_tolerance(solver, self.tolerance)
        self._optimality = optimality_tolerance(solver, self.tolerance)
        self.settings: Mapping[str, Any] = dict(settings)
        # Built now: validates tolerance and settings early.
        self._backend: DenseBackend = self._factory(solver, self.tolerance, self.settings)
        self._fresh = True
        self._key: tuple[int, ...] | None = None
        self._qp: DenseQP | None = None
        self._in_place = self._backend.supports_update
        self._backend_name = self._backend.backend
        self._refines = self._backend.refines_cone_points()
        #: ``"setup"``, ``"in_place"`` or ``"fresh_setup"``: what the last call did.
        self.last_update: str | None = None
        #: Number of workspaces built so far.
        self.n_setups = 0

    @property
    def backend(self) -> str:
        """Backend family of the workspace (``"daqp"``, ``"osqp"``, ``"cvxpy"``, ...)."""
        return self._backend_name

    @property
    def native(self) -> Any:
        """The backend's entry point for compiled callers (``None`` where it has none).

        Only DAQP has one: a :class:`~ltv_lstm_mpc.solvers.daqp_native.DaqpNative` with this
        session's settings, for :func:`~ltv_lstm_mpc.solvers.daqp_native.quadprog`.
        """
        return self._backend.native

    @property
    def structure_key(self) -> tuple[int, ...] | None:
        """:meth:`DenseQP.structure_key` of the workspace (``None`` before the first solve)."""
        return self._key

    def reset(self) -> None:
        """Drop the workspace and any warm-start state: the next solve sets up afresh."""
        self._key = None
        self._qp = None
        self.last_update = None

    def clear_state(self) -> None:
        """Drop any state kept from earlier solves but keep the workspace (the same numbers
        as :meth:`reset`: the next solve starts as on a fresh setup), where the backend
        can do so in place; else :meth:`reset`. For a compiled caller that holds the
        workspace (:meth:`compiled_workspace`)."""
        if self._key is None or not self._backend.clear_state():
            self.reset()

    def compiled_workspace(self, qp: DenseQP) -> tuple[Any, dict[str, Any]] | None:
        """Set up for ``qp`` (if the workspace is not set up for its structure) and return
        the backend's compiled workspace and its arrays by name, on which a compiled caller
        solves as this session does (the same history, so the same iterates); None for a
        backend without one (only ``daqp:socp`` has one). Keep the workspace with
        :meth:`clear_state`, not :meth:`reset`, which replaces it at the next solve."""
        if qp.structure_key() != self._key:
            self.setup(qp)
        return self._backend.compiled_workspace()

    def setup(self, qp: DenseQP) -> None:
        """Check ``qp`` and build a workspace for it (any structure)."""
        if not isinstance(qp, DenseQP):
            raise InvalidValueError(f"qp must be a DenseQP, got {type(qp).__name__}")
        qp.check()
        if qp.cones and not self._backend.handles_cones():
            raise InvalidValueError(
                f"{self.solver} solves QPs only and the QP has {len(qp.cones)} second-order "
                "cone(s); cones are never dropped silently. Use a cone solver ("
                f"{', '.join(cone_solvers()) or 'none installed'}) or a QP without cones"
            )
        if not self._fresh:
            self._backend = self._factory(self.solver, self.tolerance, self.settings)
        self._fresh = False
        self._key = None
        try:
            self._backend.setup(qp)
        except Exception as exc:
            raise_backend_error(self.solver, "setup", exc)
        self.n_setups += 1
        self.last_update = "setup"
        self._key = qp.structure_key()
        self._qp = qp

    def update(self, qp: DenseQP) -> None:
        """Write the values of ``qp`` (same structure key as the workspace; not checked)."""
        if self._key is None:
            raise SolverError("DenseSession.update() called before setup()")
        try:
            if self._in_place:
                self._backend.update(qp)
                self.last_update = "in_place"
            else:
                self._backend = self._factory(self.solver, self.tolerance, self.settings)
                self._backend.setup(qp)
                self.n_setups += 1
                self.last_update = "fresh_setup"
        except Exception as exc:
            self._key = None
            raise_backend_error(self.solver, "update", exc)
        self._qp = qp

    def solve(self, qp: DenseQP, warm_start: WarmStart | None = None) -> Solution:
        """Set up or update with ``qp``, then solve.

        Parameters
        ----------
        qp : DenseQP
        warm_start : (n,) array or Solution, optional
            Primal point (and, from a :class:`Solution`, multipliers or, for
            some solvers, the workspace's previous iterate) to start from;
            ``None`` is a cold start. Backends without warm start ignore it and
            say so in ``info``.
        """
        start = time.perf_counter()
        work, scaling = self._equilibrated(qp)
        if scaling is not None and warm_start is not None:
            z0 = warm_start.z if isinstance(warm_start, Solution) else warm_start
            warm_start = None if z0 is None else np.asarray(z0, dtype=np.float64) / scaling.D
        if work.structure_key() != self._key:
            self.setup(work)
        else:
            self.update(work)
        mid = time.perf_counter()
        try:
            raw = self._backend.solve(warm_start)
        except Exception as exc:
            raise_backend_error(self.solver, "solve", exc)
        end = time.perf_counter()
        if scaling is not None:
            raw = dataclasses.replace(
                raw,
                z=None if raw.z is None else scaling.point(raw.z),
                duals=None if raw.duals is None else scaling.multipliers(raw.duals),
                certificate=(
                    None if raw.certificate is None else scaling.multipliers(raw.certificate)
                ),
                notes=(*raw.notes, "Ruiz-equilibrated"),
            )
        return self._to_solution(qp, raw, mid - start, end - mid)

    def _equilibrated(self, qp: DenseQP) -> tuple[DenseQP, Any]:
        """``qp`` and no scaling, or (with ``equilibrate=True``) the scaled QP and its scaling."""
        if not self.equilibrate:
            return qp, None
        if not isinstance(qp, DenseQP):
            raise InvalidValueError(f"qp must be a DenseQP, got {type(qp).__name__}")
        from .equilibration import ruiz

        scaling = ruiz(qp)
        return scaling.apply(qp), scaling

    def solve_point(self, qp: DenseQP) -> tuple[SolverStatus, FloatArray | None, int, str]:
        """The hot-loop call: cold solve, ``(status, z, iterations, info)``.

        The same setup / in-place update as :meth:`solve`, without building a
        :class:`Solution` (no duals, objective or timings) and without the acceptance
        check (:mod:`~ltv_lstm_mpc.solvers.acceptance`): only a malformed or non-finite
        ``z`` turns the status into ``FAILED`` and ``z`` into ``None``; the caller checks
        the point (the MPC core does, to :func:`feasibility_tolerance`). ``z`` is the
        backend's fresh array.
        """
        work, scaling = self._equilibrated(qp)
        if work.structure_key() != self._key:
            self.setup(work)
        else:
            self.update(work)
        try:
            status, z, iterations, info = self._backend.solve_point()
        except Exception as exc:
            raise_backend_error(self.solver, "solve", exc)
        if scaling is not None and z is not None:
            z = scaling.point(z)
        if z is not None:
            if not _usable_point(z, qp):
                return (
                    SolverStatus.FAILED,
                    None,
                    iterations,
                    f"{info}; solver returned a malformed or non-finite z",
                )
        elif status.has_solution:
            return SolverStatus.FAILED, None, iterations, f"{info}; solver returned no point"
        return status, z, iterations, info

    def adopt_point(
        self, qp: DenseQP, flag: int, sqp: int, iterations: int
    ) -> tuple[SolverStatus, FloatArray | None, int, str]:
        """:meth:`solve_point` for a solve that already ran on this session's compiled
        workspace (:meth:`compiled_workspace`; a compiled caller's, e.g. the MPC's one-call
        exact-cone feedback) and did not converge: ``flag``, ``sqp``, ``iterations`` its
        outcome. ``qp``'s values (the ones that solve ran on) are written as by
        :meth:`solve_point`, and the status is the backend's reading of the workspace as
        that solve left it (``adopt_point`` of the backend), without solving again."""
        work, _scaling = self._equilibrated(qp)
        if work.structure_key() != self._key:  # pragma: no cover - set up by the caller
            raise InvalidValueError("adopt_point() needs the workspace the solve ran on")
        self.update(work)
        adopt = getattr(self._backend, "adopt_point", None)
        if adopt is None:  # pragma: no cover - only daqp:socp hands out its workspace
            raise InvalidValueError(f"{self.solver} cannot adopt a compiled caller's solve")
        status, z, count, info = adopt(flag, sqp, iterations)
        if z is not None or status.has_solution:  # pragma: no cover - failed solves only
            return SolverStatus.FAILED, None, count, f"{info}; adopted solves have no point"
        return status, None, count, info

    def _to_solution(self, qp: DenseQP, raw: RawResult, setup: float, wall: float) -> Solution:
        z: FloatArray | None = None
        objective = float("nan")
        status = raw.status
        notes = raw.notes
        raw_z = raw.z
        duals = raw.duals
        if raw_z is not None:
            if _usable_point(raw_z, qp):
                if raw.objective is not None and math.isfinite(raw.objective):
                    objective = raw.objective
                else:
                    objective = 0.5 * float(raw_z @ (qp.H @ raw_z)) + float(qp.f @ raw_z)
                z = raw_z.copy()
                z.setflags(write=False)
            else:
                status = SolverStatus.FAILED
                notes = (*notes, "solver returned a malformed or non-finite z")
                duals = None
                objective = float("nan")
        elif status.has_solution:
            status = SolverStatus.FAILED
            notes = (*notes, "solver returned no point")
        residuals = None
        certificate = raw.certificate
        if z is not None or certificate is not None:
            if status is not raw.status or z is None or duals is not raw.duals:
                raw = dataclasses.replace(raw, status=status, z=z, duals=duals, notes=notes)
            checked, residuals = accept(
                ProblemView.of_dense(qp), raw, self._feasibility, self._optimality
            )
            if qp.cones and checked.status is SolverStatus.OPTIMAL and not self._refines:
                checked = check_cone_point(qp, checked, self._optimality)
            status, notes, certificate = checked.status, checked.notes, checked.certificate
            if checked.z is None:
                z, duals, objective = None, None, float("nan")
        last = self.last_update
        if last == "fresh_setup":
            notes = ("fresh setup (backend cannot update in place)", *notes)
        info = f"native status: {raw.native_status}"
        if notes:
            info = "; ".join((info, *notes))
        solve_time = raw.solve_time
        return Solution(
            status=status,
            z=z,
            objective=objective,
            duals=duals,
            setup_time=setup + raw.extra_setup_time,
            solve_time=solve_time,
            overhead_time=max(0.0, wall - solve_time - raw.extra_setup_time),
            iterations=raw.iterations,
            backend=self._backend_name,
            solver=self.solver,
            reformulation=None,
            info=info,
            residuals=residuals,
            certificate=certificate,
        )
