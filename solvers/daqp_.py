"""Native DAQP backend (``"daqp"``): dense dual active-set solver, persistent ``daqp.Model``.

DAQP solves ``min 1/2 x'Hx + f'x  s.t.  blower <= A x <= bupper`` with dense
data; the first ``n`` bounds are simple bounds on ``x`` when ``lb``/``ub`` are
present, equality rows get ``sense = 5`` (active and immutable). It is the
fastest path for small *condensed* problems (PERF-NOTES: 7 µs at N = 5); on a
sparse (state + input) problem it pays for dense linear algebra.

Simple bounds are always passed (``-inf``/``+inf`` where the problem has none), so a
problem without constraints is a model with ``n`` inactive bound rows.

The Hessian must be positive definite: DAQP's default ``eps_prox < 0``
regularizes a singular one automatically.

Dense backend (:class:`DaqpDense`, for :class:`~ltv_lstm_mpc.solvers.DenseSession`)
    Calls the one-shot ``daqp.solve(H, f, A, bupper, blower, sense, **options)``
    on preallocated bound/sense buffers. Measured against a persistent
    ``daqp.Model`` + ``update(H=, f=, A=, bupper=, blower=)`` on condensed QPs
    (n = 5/20/50, m_A = 10/40/60; all of H, f, A change every MPC step) the
    one-shot call was as fast or faster (7.1/37/386 µs vs 7.5/46/401 µs cold;
    4.2/13.6/93 µs vs 4.3/13.0/95 µs warm), so the model buys nothing here.
    A warm start sets the initial working set through ``sense`` as below. The cold hot-loop
    call (:meth:`DaqpDense.solve_point`) goes to the same C function, ``daqp_quadprog``,
    through :mod:`~ltv_lstm_mpc.solvers.daqp_native` where DAQP is bound natively (same
    results; no Python call of the ``daqp`` package); :attr:`DaqpDense.native` is also what
    compiled callers use, with the functions of :func:`compiled_form`.

Warm start
    ``warm_start=None`` resets the working set (a cold start). A warm start sets
    the initial working set through DAQP's ``sense`` flags (bit 1: active, bit 2:
    at the lower bound): from the multipliers of a previous :class:`Solution`
    when given, else from the constraints that are active (to ``1e-9``) at the
    primal point, as DAQP's own ``primal_start`` does.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any, ClassVar

import numpy as np

from ._base import (
    Backend,
    FloatArray,
    RawResult,
    WarmStart,
    check_settings,
    map_status,
    warm_start_vectors,
)
from .compiled_forms import CompiledForm
from .dense import DenseBackend, DenseQP
from .problem import ConvexProblem, Solution, SolverStatus
from .tolerances import known_settings, solver_options

#: DAQP exit flag -> SolverStatus (``include/constants.h`` of DAQP).
STATUS_MAP: Mapping[int, SolverStatus] = {
    1: SolverStatus.OPTIMAL,  # EXIT_OPTIMAL
    2: SolverStatus.OPTIMAL_INACCURATE,  # EXIT_SOFT_OPTIMAL (soft constraints violated)
    -1: SolverStatus.INFEASIBLE,  # EXIT_INFEASIBLE
    -2: SolverStatus.FAILED,  # EXIT_CYCLE
    -3: SolverStatus.UNBOUNDED,  # EXIT_UNBOUNDED
    -4: SolverStatus.MAX_ITER,  # EXIT_ITERLIMIT
    -5: SolverStatus.FAILED,  # EXIT_NONCONVEX
    -6: SolverStatus.FAILED,  # EXIT_OVERDETERMINED_INITIAL
}

_ACTIVE = 1
_LOWER = 2
_EQUALITY = 5
_ACTIVE_TOL = 1e-9
#: DAQP's default ``zero_tol`` (``daqp.Model().settings``).
DAQP_ZERO_TOL = 1e-11
#: The note of a QP that a row's activity bounds proved infeasible (no DAQP call).
_ACTIVITY_NOTE = "a row's activity bounds prove it infeasible (DAQP not called)"
#: DAQP sense of a multiplier sign -1, 0, +1: active at the lower bound, free, active at the upper.
_SENSE_OF_SIGN = np.array([_ACTIVE | _LOWER, 0, _ACTIVE], dtype=np.intc)


class DaqpBackend(Backend):
    """Persistent native DAQP workspace (dense)."""

    backend: ClassVar[str] = "daqp"
    supports_update: ClassVar[bool] = True
    supports_warm_start: ClassVar[bool] = True

    def __init__(self, name: str, tolerance: float, settings: Mapping[str, Any]) -> None:
        """Merge tolerance options and settings and check the setting names."""
        check_settings("daqp", settings, known_settings("daqp"))
        super().__init__(name, "daqp", solver_options("daqp", tolerance, settings))

    def _data(self, problem: ConvexProblem) -> dict[str, Any]:
        n = problem.n_variables
        rows = [m.toarray() for m in (problem.A_eq, problem.G) if m is not None]
        A = np.vstack(rows) if rows else np.zeros((0, n))
        up: list[FloatArray] = []
        lo: list[FloatArray] = []
        # Simple bounds always (infinite where absent): DAQP's Model needs at least one
        # constraint row, and a problem without any must still solve.
        up.append(np.full(n, np.inf) if problem.ub is None else np.asarray(problem.ub))
        lo.append(np.full(n, -np.inf) if problem.lb is None else np.asarray(problem.lb))
        if problem.b_eq is not None:
            up.append(np.asarray(problem.b_eq))
            lo.append(np.asarray(problem.b_eq))
        if problem.l is not None and problem.u is not None:
            up.append(np.asarray(problem.u))
            lo.append(np.asarray(problem.l))
        return {
            "H": np.ascontiguousarray(problem.P.toarray()),
            "f": np.asarray(problem.q, dtype=np.float64).copy(),
            "A": np.ascontiguousarray(A),
            "bupper": np.concatenate(up) if up else np.zeros(0),
            "blower": np.concatenate(lo) if lo else np.zeros(0),
        }

    def setup(self, problem: ConvexProblem) -> None:
        """Build the DAQP model."""
        import daqp

        self._n = problem.n_variables
        self._p = problem.n_eq
        self._m = problem.n_ineq
        self._ms = self._n  # simple bounds are always the first n rows (see _data)
        data = self._data(problem)
        self._sense = np.zeros(data["bupper"].shape[0], dtype=np.int32)
        self._sense[self._ms : self._ms + self._p] = _EQUALITY
        self._model = daqp.Model()
        flag, _ = self._model.setup(sense=self._sense.copy(), **data)
        # A negative flag (e.g. -6, overdetermined initial working set) leaves no model:
        # remember it so solve() reports a FAILED status instead of crashing in update().
        self._setup_flag: int | None = int(flag) if int(flag) < 0 else None
        settings = self._model.settings
        for key, value in self.options.items():
            settings[key] = value
        self._model.settings = settings
        self._data_now = data

    def update(self, problem: ConvexProblem) -> None:
        """Write new dense values into the model (a fresh setup if the last one failed)."""
        if self._setup_flag is not None:
            self.setup(problem)
            return
        data = self._data(problem)
        self._model.update(**data)
        self._data_now = data

    def _warm_sense(self, z0: FloatArray | None, duals: Mapping[str, FloatArray] | None) -> Any:
        sense = self._sense.copy()
        free = sense != _EQUALITY
        if duals is not None and all(k in duals for k in ("ineq", "bounds")):
            lam = np.concatenate([duals["bounds"][: self._ms], np.zeros(self._p), duals["ineq"]])
            if lam.shape == sense.shape:
                sense[free & (lam > 0)] |= _ACTIVE
                sense[free & (lam < 0)] |= _ACTIVE | _LOWER
                return sense
        if z0 is not None:
            d = self._data_now
            Az = np.concatenate([z0[: self._ms], d["A"] @ z0])
            scale = 1.0 + np.abs(Az)
            at_up = np.abs(Az - d["bupper"]) <= _ACTIVE_TOL * scale
            at_lo = np.abs(Az - d["blower"]) <= _ACTIVE_TOL * scale
            sense[free & at_up] |= _ACTIVE
            sense[free & at_lo & ~at_up] |= _ACTIVE | _LOWER
        return sense

    def solve(self, warm_start: WarmStart | None) -> RawResult:
        """Solve from the working set given by the warm start (empty when ``None``)."""
        if self._setup_flag is not None:
            status, note = map_status(STATUS_MAP, self._setup_flag)
            return RawResult(
                status=status,
                native_status=f"setup exitflag {self._setup_flag}",
                z=None,
                duals=None,
                solve_time=0.0,
                iterations=0,
                extra_setup_time=0.0,
                notes=("DAQP rejected the problem at setup",) + (() if note is None else (note,)),
            )
        z0, sol = warm_start_vectors(warm_start, self._n)
        duals = sol.duals if sol is not None else None
        self._model.update(sense=self._warm_sense(z0, duals))
        x, _fval, exitflag, info = self._model.solve()
        status, note = map_status(STATUS_MAP, int(exitflag))
        z = out_duals = None
        if status.has_solution:
            z = np.array(x, dtype=np.float64)
            lam = np.asarray(info["lam"], dtype=np.float64)
            bnd = np.zeros(self._n)
            bnd[: self._ms] = lam[: self._ms]
            out_duals = {
                "eq": lam[self._ms : self._ms + self._p].copy(),
                "ineq": lam[self._ms + self._p :].copy(),
                "bounds": bnd,
            }
        return RawResult(
            status=status,
            native_status=f"exitflag {int(exitflag)}",
            z=z,
            duals=out_duals,
            solve_time=float(info["solve_time"]),
            iterations=int(info["iterations"]),
            extra_setup_time=0.0,
            notes=() if note is None else (note,),
        )


def make(name: str, tolerance: float, settings: Mapping[str, Any]) -> Backend:
    """Registry factory."""
    return DaqpBackend(name, tolerance, settings)


class DaqpDense(DenseBackend):
    """Dense DAQP backend: one-shot ``daqp_quadprog`` on preallocated buffers (fastest per call).

    Simple bounds are the first ``n`` entries of ``bupper``/``blower``. The
    values are read at :meth:`update`/:meth:`setup` (bounds copied into the
    buffers, ``H``, ``f``, ``A`` referenced).
    """

    backend: ClassVar[str] = "daqp"
    supports_update: ClassVar[bool] = True
    supports_warm_start: ClassVar[bool] = True

    def __init__(self, name: str, tolerance: float, settings: Mapping[str, Any]) -> None:
        """Merge tolerance options and settings and check the setting names."""
        import daqp

        check_settings("daqp", settings, known_settings("daqp"))
        super().__init__(name, "daqp", solver_options("daqp", tolerance, settings))
        self._daqp_solve = daqp.solve
        from . import daqp_native

        self._daqp_native = daqp_native
        # the settings in effect (DAQP's defaults where not given), read once for the
        # objective bound of each solve (_objective_bound)
        effective = {**daqp.Model().settings, **self.options}
        self._own_bound = float(effective["fval_bound"])
        self._proximal = float(effective["eps_prox"]) > 0.0
        self._tolerances = (float(effective["primal_tol"]), float(effective["zero_tol"]))
        self._native: Any = None
        self._native_bound = False
        # The hot-loop solve_point goes through DAQP's C entry point where its compiled call
        # is ready (compiled in this process or in numba's cache); else through daqp.solve,
        # the same C function with the same results, so that a Python-only caller never
        # waits for a compilation. Compiled callers bind it through `native`.
        if daqp_native.ready():
            self._bind_native()

    def _bind_native(self) -> Any:
        if not self._native_bound:
            self._native = self._daqp_native.native(self.options)
            self._native_bound = True
        return self._native

    @property
    def native(self) -> Any:
        """DAQP's C entry point for compiled callers (a
        :class:`~ltv_lstm_mpc.solvers.daqp_native.DaqpNative`; bound, and compiled on an
        empty numba cache, at the first access), or None: ``daqp.solve`` only, the reason
        in ``daqp_native.unavailable_reason``."""
        return self._bind_native()

    def setup(self, qp: DenseQP) -> None:
        """Allocate the bound and sense buffers and store the data."""
        n, m = qp.n_variables, qp.n_rows
        self._n = n
        self._bu = np.empty(n + m)
        self._bl = np.empty(n + m)
        self._cold = np.zeros(n + m, dtype=np.intc)
        self._lam = np.empty(n + m)
        self.update(qp)

    def update(self, qp: DenseQP) -> None:
        """Copy the bounds into the buffers and reference ``H``, ``f``, ``A``."""
        n = self._n
        bu, bl = self._bu, self._bl
        bu[:n] = qp.ub
        bu[n:] = qp.up
        bl[:n] = qp.lb
        bl[n:] = qp.lo
        self._H = np.ascontiguousarray(qp.H)
        self._f = qp.f
        self._A = np.ascontiguousarray(qp.A)
        self._floor = float(qp.hessian_floor)

    def _objective_bound(self, native: Any) -> float:
        """DAQP's ``fval_bound`` for this QP: the smaller of the settings' own (DAQP's
        :data:`~ltv_lstm_mpc.solvers.daqp_native.NO_BOUND` unless they name one) and
        :func:`objective_bound` (compiled where DAQP is bound natively: ``native``); the
        settings' own where they ask for proximal iterations (``eps_prox`` > 0)."""
        own = self._own_bound
        if self._proximal:  # proximal iterations: another objective
            return own
        n = self._n
        tolerance, zero_tol = self._tolerances
        lower, upper = self._bl[:n], self._bu[:n]
        if native is not None:
            bound = self._daqp_native.objective_bound(
                self._H, self._f, lower, upper, self._floor, tolerance, zero_tol
            )
        else:
            bound = objective_bound(
                self._H, self._f, lower, upper, self._floor, tolerance, zero_tol
            )
        return min(own, float(bound))

    def _warm_sense(self, warm_start: WarmStart) -> Any:
        n = self._n
        if isinstance(warm_start, Solution) and warm_start.duals is not None:
            bnd = warm_start.duals.get("bounds")
            ineq = warm_start.duals.get("ineq")
            if (
                bnd is not None
                and ineq is not None
                and bnd.shape == (n,)
                and ineq.shape == (self._bu.shape[0] - n,)
            ):
                lam = self._lam
                lam[:n] = bnd
                lam[n:] = ineq
                return _SENSE_OF_SIGN[(np.sign(lam) + 1.0).astype(np.intp)]
        z0, _ = warm_start_vectors(warm_start, n)
        if z0 is None:
            return self._cold
        Az = np.concatenate([z0, self._A @ z0])
        scale = 1.0 + np.abs(Az)
        at_up = np.abs(Az - self._bu) <= _ACTIVE_TOL * scale
        at_lo = np.abs(Az - self._bl) <= _ACTIVE_TOL * scale
        sense = np.zeros_like(self._cold)
        sense[at_up] = _ACTIVE
        sense[at_lo & ~at_up] = _ACTIVE | _LOWER
        return sense

    def _activity_infeasible(self, native: Any) -> bool:
        """A row's activity bounds prove the QP infeasible (:func:`activity_infeasible`,
        compiled where DAQP is bound natively: ``native``): no DAQP call is needed."""
        tolerance = self._tolerances[0]
        if native is not None:
            return bool(
                self._daqp_native.activity_infeasible(self._A, self._bl, self._bu, tolerance)
            )
        return activity_infeasible(self._A, self._bl, self._bu, tolerance)

    def solve(self, warm_start: WarmStart | None) -> RawResult:
        """One ``daqp.solve`` call from the cold or warm working set (none where a row's
        activity bounds prove the QP infeasible: exit flag -1, no iteration)."""
        if self._activity_infeasible(None):
            status, notes = dense_status(-1)
            return RawResult(
                status=status,
                native_status="exitflag -1",
                z=None,
                duals=None,
                solve_time=0.0,
                iterations=0,
                notes=(*notes, _ACTIVITY_NOTE),
            )
        sense = self._cold if warm_start is None else self._warm_sense(warm_start)
        x, fval, exitflag, info = self._daqp_solve(
            self._H,
            self._f,
            self._A,
            self._bu,
            self._bl,
            sense,
            **{**self.options, "fval_bound": self._objective_bound(None)},
        )
        flag = int(exitflag)
        status, notes = dense_status(flag)
        z = duals = None
        if status.has_solution:
            z = np.asarray(x, dtype=np.float64)
            lam = np.asarray(info["lam"], dtype=np.float64)
            n = self._n
            duals = {"ineq": lam[n:], "bounds": lam[:n]}
        return RawResult(
            status=status,
            native_status=f"exitflag {flag}",
            z=z,
            duals=duals,
            solve_time=float(info["solve_time"]),
            iterations=int(info["iterations"]),
            extra_setup_time=float(info["setup_time"]),
            notes=notes,
            objective=float(fval) if z is not None else None,
        )

    def solve_point(self) -> tuple[SolverStatus, FloatArray | None, int, str]:
        """One cold solve (DAQP's C entry point where bound, else ``daqp.solve``); the status
        mapped as in :meth:`solve`."""
        native = self._native
        if self._activity_infeasible(native):
            status, info = point_outcome(-1)
            return status, None, 0, info
        bound = self._objective_bound(native)
        if native is not None:
            self._daqp_native.write_fval_bound(native.settings, bound)
            x, _lam, flag, iterations = native.solve(
                self._H, self._f, self._A, self._bu, self._bl, self._cold
            )
        else:
            x, _fval, exitflag, info = self._daqp_solve(
                self._H,
                self._f,
                self._A,
                self._bu,
                self._bl,
                self._cold,
                **{**self.options, "fval_bound": bound},
            )
            flag, iterations = int(exitflag), int(info["iterations"])
        status, info = point_outcome(flag)
        z = x if status.has_solution else None
        return status, z, iterations, info


def objective_bound(
    H: FloatArray,
    f: FloatArray,
    lower: FloatArray,
    upper: FloatArray,
    hessian_floor: float,
    tolerance: float,
    zero_tol: float = DAQP_ZERO_TOL,
) -> float:
    r"""DAQP's ``fval_bound`` for :math:`\min \tfrac12 x^\top H x + f^\top x` with every
    variable bounded, :math:`l \le x \le u`: past it DAQP declares the QP infeasible.

    A dual active-set method such as DAQP passes through points whose objective, the dual
    objective of a dual feasible working set, never exceeds the optimum of a feasible QP
    (weak duality) and grows without bound on an infeasible one. DAQP stops with exit flag
    -1 (infeasible) where its internal objective :math:`\|R x + v\|^2` (:math:`R^\top R =
    H`, :math:`v = R^{-\top} f`) exceeds twice ``fval_bound``. Every point of the box,
    widened by ``tolerance`` (DAQP's ``primal_tol``: the box a point it returns can reach),
    with :math:`r_i = \max(|l_i|, |u_i|) + \text{tolerance}`, has

    .. math::

        \tfrac12 \|R x + v\|^2 = \tfrac12 x^\top H x + f^\top x + \tfrac12 f^\top H^{-1} f
        \le \tfrac12 \operatorname{tr}(H) \|r\|^2 + |f|^\top r
        + \frac{\|f\|^2}{2 \lambda},

    with :math:`\lambda` = ``hessian_floor`` a lower bound on the smallest eigenvalue of
    :math:`H` (:math:`\lambda_{\max} \le \operatorname{tr} H` for :math:`H \succeq 0`). The
    bound returned is twice that, a margin no rounding reaches. So it never ends a solve
    that finds a point (its objective stays below the bound on the way there: the
    iterates, the point and the exit flag are the same as without it), and it ends an
    infeasible one as soon as the growing objective passes it: at N = 50 on the MPC's
    infeasible steps after 4 DAQP iterations instead of 52 (docs/benchmarks.md, "DAQP's
    objective bound").

    That holds for DAQP's objective of :math:`H` itself, not for its proximal mode, where
    it works on :math:`H + \epsilon I` and a moving linear term (a review found feasible QPs
    it then called infeasible): so the bound is given only where DAQP provably factors
    :math:`H` as it is (its checks in ``utils.c``, with :math:`\lambda_{\min} \ge \lambda`
    and :math:`\max H_{ii} \le \operatorname{tr} H`): :math:`\lambda` above ``zero_tol``
    (DAQP's absolute pivot test) and above ``zero_tol`` times :math:`\operatorname{tr} H`
    (its relative pivot and diagonal tests), :math:`n \epsilon_{mach}
    \operatorname{tr} H \le` :data:`~ltv_lstm_mpc.solvers.daqp_native.ROUNDING_MARGIN`
    :math:`\lambda` (its condition test, with a margin) and :math:`\operatorname{tr} H \le`
    :data:`~ltv_lstm_mpc.solvers.daqp_native.CONDITION_LIMIT` :math:`\lambda` (its
    condition limit with equality elimination, 1e8, with a margin). The MPC's condensed
    QPs (trace over floor of order 1e3-1e5) pass them.

    Returns :data:`~ltv_lstm_mpc.solvers.daqp_native.NO_BOUND` (DAQP's default, no bound)
    where ``hessian_floor`` is not positive, a bound is infinite or NaN,
    :math:`\operatorname{tr} H < 0`, or a test above fails. The compiled twin is
    :func:`ltv_lstm_mpc.solvers.daqp_native.objective_bound` (the same terms; the trace,
    which the tests above read, summed in the same order, the others to rounding; the
    backend calls it where DAQP is bound natively); the C
    export renders a third (``qp_objective_bound``). Callers give DAQP the smaller of this
    and the settings' own ``fval_bound``.
    """
    from .daqp_native import CONDITION_LIMIT, NO_BOUND, ROUNDING_MARGIN

    if not hessian_floor > 0.0:
        return NO_BOUND
    radius = np.maximum(np.abs(lower), np.abs(upper))
    if not np.all(radius < np.inf):
        return NO_BOUND
    radius = radius + tolerance
    trace = float(np.add.accumulate(np.diagonal(H))[-1])  # (in order: the twins' trace)
    epsilon = float(np.finfo(np.float64).eps)
    if not (
        trace >= 0.0
        and hessian_floor > zero_tol
        and hessian_floor > zero_tol * trace
        and f.shape[0] * epsilon * trace <= ROUNDING_MARGIN * hessian_floor
        and trace <= CONDITION_LIMIT * hessian_floor
    ):  # (DAQP could regularize H: its proximal mode, whose objective this does not bound)
        return NO_BOUND
    bound = 2.0 * (
        0.5 * trace * float(radius @ radius)
        + float(np.abs(f) @ radius)
        + 0.5 * float(f @ f) / hessian_floor
    )
    if not bound < NO_BOUND:
        return NO_BOUND
    return float(bound)


def activity_infeasible(
    A: FloatArray, lower: FloatArray, upper: FloatArray, tolerance: float
) -> bool:
    r"""Whether one row of :math:`lo \le A x \le up` cannot hold, to within DAQP's
    tolerance, anywhere in the box :math:`lb \le x \le ub`: then the QP is infeasible,
    which the callers report as DAQP reports it (exit flag -1) without calling it.

    ``lower`` / ``upper``: DAQP's layout, :math:`[lb; lo]` and :math:`[ub; up]` (one bound
    per variable first; :data:`~ltv_lstm_mpc.solvers.daqp_native.NO_BOUND` or beyond: none).
    A point DAQP returns satisfies every bound and row to within ``tolerance`` (its
    ``primal_tol``, absolute in the rows' own units: it scales each row and its tolerance
    alike). Over the box widened by ``tolerance``, row :math:`i` takes values between its
    activity bounds (LP presolve's) :math:`\sum_j \min(a_{ij} (lb_j - \tau), a_{ij} (ub_j +
    \tau))` and the same with max; where the smaller exceeds :math:`up_i + \tau` (or the
    larger stays below :math:`lo_i - \tau`) by more than a rounding margin
    (:data:`~ltv_lstm_mpc.solvers.daqp_native.ACTIVITY_MARGIN` times the terms' magnitudes
    and the bound's), no point is within DAQP's tolerance: the QP is infeasible, and a
    solve that would find a point is never ended.

    DAQP itself says -1 there, but on QPs it mishandles (a review's random search: a row so
    small against :math:`H` that DAQP drops it as a zero row and returns a point violating
    it; bounds equal to within ``zero_tol``, taken for dependent equalities: -6; cycling:
    -2). Those QPs are now reported infeasible, which they are; the MPC's are not among
    them (DAQP said -1 on each of the 35 that ``ltv-lstm-mpc reproduce --solver daqp``
    proves).

    A row on a variable without bounds (or with NaN) proves nothing, nor one that the
    origin satisfies where the widened box holds it (a nonnegative ``tolerance``): the
    check passes over it. On the MPC's nominal steps, whose shifted candidate (the origin
    of the condensed QP) satisfies every row, it then costs 0.02 / 0.03 / 0.07 us at N = 5
    / 20 / 50, against 0.1 / 0.5 / 2.6 us for every row. On its infeasible nominal QPs
    (the paper's scenario 3, its set-point levels cycled every 40 samples) one row proves
    it in 33 / 21 / 56 % of them at N = 5 / 20 / 50 (the terminal set's rows, beyond the
    inputs' reach), where DAQP's own proof of a failed nominal QP takes a median of 21 / 4
    iterations, 16 / 52 us at N = 20 / 50 (docs/benchmarks.md, "Row activity bounds before
    DAQP"). The compiled twin is
    :func:`ltv_lstm_mpc.solvers.daqp_native.activity_infeasible`, the C export's
    ``qp_activity_infeasible`` (in single precision with a margin of at least :math:`(n +
    2)` float epsilons): the same sums in the same order, the same rows passed over.
    """
    from .daqp_native import ACTIVITY_MARGIN, NO_BOUND

    rows, n = A.shape
    if rows == 0:
        return False
    if n == 0:  # (empty rows: their activity is 0)
        A = np.zeros((rows, 1))
        lower = np.concatenate([[0.0], lower])
        upper = np.concatenate([[0.0], upper])
        n = 1
    box_low, box_high = lower[:n], upper[:n]
    bounded = (np.abs(box_low) < NO_BOUND) & (np.abs(box_high) < NO_BOUND)
    used = A != 0.0
    with np.errstate(invalid="ignore", over="ignore"):
        low_terms = A * (box_low - tolerance)
        high_terms = A * (box_high + tolerance)
        smallest = np.where(used, np.minimum(low_terms, high_terms), 0.0)
        largest = np.where(used, np.maximum(low_terms, high_terms), 0.0)
        size = np.where(used, np.maximum(np.abs(low_terms), np.abs(high_terms)), 0.0)
        # (in order, as the twins sum)
        smallest = np.add.accumulate(smallest, axis=1)[:, -1]
        largest = np.add.accumulate(largest, axis=1)[:, -1]
        size = np.add.accumulate(size, axis=1)[:, -1]
    provable = ~np.any(used & ~bounded, axis=1)
    lo, up = lower[n:], upper[n:]
    # the origin in the widened box: the rows it satisfies prove nothing (their smallest
    # value is at most 0, a sum of terms at most 0, and their largest at least 0)
    if tolerance >= 0.0 and np.all((box_low - tolerance <= 0.0) & (0.0 <= box_high + tolerance)):
        provable &= ~((lo <= 0.0) & (0.0 <= up))
    with np.errstate(invalid="ignore", over="ignore"):
        above = (up < NO_BOUND) & (
            smallest - up > tolerance + ACTIVITY_MARGIN * (size + np.abs(up))
        )
        below = (lo > -NO_BOUND) & (
            lo - largest > tolerance + ACTIVITY_MARGIN * (size + np.abs(lo))
        )
    return bool(np.any(provable & (above | below)))


def dense_status(flag: int) -> tuple[SolverStatus, tuple[str, ...]]:
    """The dense backends' status of a DAQP exit flag, and a note for an unknown one."""
    status = STATUS_MAP.get(flag)
    if status is not None:
        return status, ()
    status, note = map_status(STATUS_MAP, flag)
    return status, (str(note),)


def point_outcome(flag: int) -> tuple[SolverStatus, str]:
    """The status and info string :meth:`DaqpDense.solve_point` reports for DAQP's exit
    ``flag`` (also the compiled callers' report of a flag they recorded:
    ``flag_outcome`` of :class:`~ltv_lstm_mpc.solvers.CompiledForm`)."""
    status, notes = dense_status(flag)
    return status, "; ".join((f"exitflag {flag}", *notes))


def make_dense(name: str, tolerance: float, settings: Mapping[str, Any]) -> DenseBackend:
    """Registry dense factory."""
    return DaqpDense(name, tolerance, settings)


def native_buffers(tolerance: float, settings: Mapping[str, Any]) -> Any:
    """DAQP's C struct buffers (:class:`~ltv_lstm_mpc.solvers.daqp_native.DaqpNative`) with
    the options this backend sets for ``tolerance`` and ``settings``, or None where DAQP is
    not bound natively (the reason in ``daqp_native.unavailable_reason``)."""
    from . import daqp_native

    return daqp_native.native(solver_options("daqp", tolerance, settings))


def compiled_form(name: str) -> CompiledForm:
    """What ``"daqp"`` gives compiled callers: DAQP's C entry point and its buffers where
    DAQP is bound natively (else ``bound=False`` and no kernels)."""
    from . import daqp_native
    from ._compiled import bounds_rows_violation

    bound = daqp_native.bound()
    return CompiledForm(
        name=name,
        kernels=((*daqp_native.SELF_TEST_KERNELS, bounds_rows_violation) if bound else ()),
        bound=bound,
        quadprog=daqp_native.quadprog,
        solver_seconds=daqp_native.solver_seconds,
        native_buffers=native_buffers,
        flag_outcome=point_outcome,
        violation=bounds_rows_violation,
    )
