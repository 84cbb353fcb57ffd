"""The ``"daqp:socp"`` backend: exact second-order cones by SQP on DAQP, as a dense backend.

The algorithm is :mod:`~ltv_lstm_mpc.solvers.socp_sqp` (compiled around DAQP's C entry
point, bound natively by :mod:`~ltv_lstm_mpc.solvers.daqp_native`); what a finished solve
proves is read by :mod:`~ltv_lstm_mpc.solvers.socp_certificates`. :class:`DaqpSocpDense`
writes a :class:`~ltv_lstm_mpc.solvers.DenseQP` into the SQP's workspace, solves, and maps the
result to the layer's statuses: ``OPTIMAL`` for a converged solve; ``INFEASIBLE`` only with a
checked Farkas vector of the cone problem itself, ``UNBOUNDED`` only with a checked
direction of unbounded descent (never from one subproblem's exit flag); otherwise
``FAILED`` or ``MAX_ITER`` (after :data:`~ltv_lstm_mpc.solvers.socp_sqp.MAX_ITERATIONS`)
with the reason, naming the cones at whose apex the iterate is. :func:`compiled_form` is
what the backend advertises to compiled callers through the registry.
"""

from __future__ import annotations

import time
from collections.abc import Mapping
from typing import Any, ClassVar

import numpy as np

from ._base import FloatArray, RawResult, WarmStart, check_settings, warm_start_vectors
from ._compiled import bounds_rows_violation, cone_violation
from .acceptance import ProblemView
from .compiled_forms import CompiledForm
from .daqp_ import native_buffers
from .daqp_native import SELF_TEST_KERNELS, native, quadprog, solver_seconds
from .dense import DenseBackend, DenseCone, DenseQP
from .problem import SolverStatus
from .socp_certificates import cone_multipliers, failure_status, max_iter_status
from .socp_sqp import (
    FAILURE_FIELDS,
    MAX_ITERATIONS,
    new_socp_workspace,
    new_socp_workspace_kernel,
    socp_arrays,
    socp_solve,
)
from .tolerances import known_settings, solver_options

__all__ = [
    "FAILURE_FIELDS",
    "DaqpSocpDense",
    "compiled_form",
    "failure_outcome",
    "local_solution",
    "make_dense",
    "problem_workspace",
    "snapshot_qp",
    "warm_up",
    "write_problem",
]

# The problem's data and DAQP's buffers in the workspace's arrays (clear_state keeps them).
_PROBLEM_FIELDS = frozenset(
    ("H", "f", "A", "lb", "ub", "lo", "up", "F", "g", "cone_rows", "e", "offsets",
     "problem", "result", "settings")
)  # fmt: skip

#: (status, native status, iterations, wall time, certificate) of one solve.
Outcome = tuple[SolverStatus, str, int, float, Mapping[str, FloatArray] | None]


class DaqpSocpDense(DenseBackend):
    """Dense exact-cone backend: SQP on DAQP (see the module docstring)."""

    backend: ClassVar[str] = "daqp"
    supports_update: ClassVar[bool] = True
    supports_warm_start: ClassVar[bool] = True
    supports_cones: ClassVar[bool] = True
    local_cone_solutions: ClassVar[bool] = True

    def __init__(self, name: str, tolerance: float, settings: Mapping[str, Any]) -> None:
        """Check the settings against DAQP's and merge the tolerance options."""
        check_settings("daqp", settings, known_settings("daqp"))
        super().__init__(name, "daqp", solver_options("daqp", tolerance, settings))
        buffers = native(self.options)
        if buffers is None:  # pragma: no cover - registered only where DAQP is bound
            from .daqp_native import unavailable_reason

            raise RuntimeError(f"daqp:socp needs DAQP bound natively: {unavailable_reason}")
        self._buffers = buffers
        self._ws: Any = None

    def setup(self, qp: DenseQP) -> None:
        """Allocate the workspace for the sizes of ``qp`` and write its values."""
        n, m = qp.n_variables, qp.n_rows
        sizes = [int(c.F.shape[0]) for c in qp.cones]
        cones = len(sizes)
        self._arrays: dict[str, Any] = socp_arrays(n, m, sizes, self._buffers)
        self._ws = new_socp_workspace(**self._arrays)
        self._n, self._m, self._cones = n, m, cones
        self.update(qp)

    def compiled_workspace(self) -> tuple[Any, dict[str, Any]] | None:
        """The SQP's workspace and its arrays (None before a setup)."""
        return None if self._ws is None else (self._ws, self._arrays)

    def clear_state(self) -> bool:
        """Zero every array but the problem's data and DAQP's buffers: the state a fresh
        :meth:`setup` starts from (the epigraph prediction of the last solve included)."""
        if self._ws is None:
            return False
        for name, array in self._arrays.items():
            if name not in _PROBLEM_FIELDS:
                array[...] = 0
        return True

    def update(self, qp: DenseQP) -> None:
        """Copy the values of ``qp`` into the workspace."""
        self._qp = qp  # read only on the rare paths (certificates)
        write_problem(self._arrays, qp)

    def _run(self, warm_start: WarmStart | None) -> Outcome:
        """One SQP solve; (status, native status, iterations, wall time, certificate): the
        status of a solve that did not converge from
        :func:`~ltv_lstm_mpc.solvers.socp_certificates.failure_status` or
        :func:`~ltv_lstm_mpc.solvers.socp_certificates.max_iter_status`."""
        a = self._arrays
        z0, solution = warm_start_vectors(warm_start, self._n)
        warm = z0 is not None
        if z0 is not None:
            a["z"][:] = z0
            a["mu"][:] = 0.0
            cones = None if solution is None else (solution.duals or {}).get("cones")
            sizes = np.diff(a["cone_rows"]) + 1
            if self._cones and cones is not None and cones.shape == (int(sizes.sum()),):
                a["mu"][:] = cones[np.concatenate([[0], np.cumsum(sizes)[:-1]])]
        start = (warm, a["z"].copy(), a["mu"].copy())  # for a rerun on a rare path
        clock = time.perf_counter()
        flag, sqp, total, violation, _seconds = socp_solve(self._ws, warm, MAX_ITERATIONS)
        wall = time.perf_counter() - clock
        if (flag == 1 or flag == 2) and sqp <= MAX_ITERATIONS:
            native_status = f"exitflag {int(flag)}, {sqp} SQP iterations"
            return SolverStatus.OPTIMAL, native_status, total, wall, None
        view = ProblemView.of_dense(self._qp)  # the rare paths: certificates
        if flag == 1 or flag == 2:
            status, why, certificate = max_iter_status(a, violation, view)
        else:
            status, why, certificate = failure_status(a, self._ws, start, int(flag), sqp, view)
        return status, why, total, wall, certificate

    def solve(self, warm_start: WarmStart | None) -> RawResult:
        """One SQP solve (warm: from the given point and cone multipliers)."""
        status, native_status, iterations, wall, certificate = self._run(warm_start)
        z = duals = None
        objective = None
        if status.has_solution:
            a = self._arrays
            z = a["z"].copy()
            duals = cone_multipliers(a)
            objective = float(0.5 * z @ a["H"] @ z + a["f"] @ z)
        return RawResult(
            status=status,
            native_status=native_status,
            z=z,
            duals=duals,
            solve_time=wall,
            iterations=iterations,
            objective=objective,
            certificate=certificate,
        )

    def adopt_point(
        self, flag: int, sqp: int, iterations: int
    ) -> tuple[SolverStatus, FloatArray | None, int, str]:
        """The status :meth:`solve_point` gives a cold solve that ended with DAQP's exit
        flag ``flag`` (not 1 or 2) at SQP iteration ``sqp``, for such a solve that a
        compiled caller ran on this backend's workspace (:meth:`compiled_workspace`): the
        same certificate checks
        (:func:`~ltv_lstm_mpc.solvers.socp_certificates.failure_status`) on the workspace
        as it left it, without solving again. ``iterations``: its DAQP iterations."""
        a = self._arrays
        cones = a["offsets"].shape[0]
        start = (False, np.zeros(self._n), np.zeros(cones))  # (a cold solve's)
        view = ProblemView.of_dense(self._qp)
        status, why, _certificate = failure_status(a, self._ws, start, int(flag), int(sqp), view)
        return status, None, int(iterations), why

    def solve_point(self) -> tuple[SolverStatus, FloatArray | None, int, str]:
        """One cold SQP solve without multipliers; the status mapped as in :meth:`solve`."""
        status, native_status, iterations, _wall, _certificate = self._run(None)
        z = self._arrays["z"].copy() if status.has_solution else None
        return status, z, iterations, native_status


def write_problem(arrays: Mapping[str, Any], qp: DenseQP) -> None:
    """The values of ``qp`` (its cost, rows, bounds and cones) into the SQP's ``arrays``
    (:func:`~ltv_lstm_mpc.solvers.socp_sqp.socp_arrays`, sized for ``qp``)."""
    for name, value in (("H", qp.H), ("f", qp.f), ("A", qp.A), ("lb", qp.lb),
                        ("ub", qp.ub), ("lo", qp.lo), ("up", qp.up)):  # fmt: skip
        arrays[name][...] = value
    start = 0
    for j, cone in enumerate(qp.cones):
        k = int(cone.F.shape[0])
        arrays["F"][start : start + k] = cone.F
        arrays["g"][start : start + k] = cone.g
        arrays["e"][j] = cone.e
        arrays["offsets"][j] = cone.f
        start += k


def problem_workspace(qp: DenseQP, buffers: Any) -> tuple[Any, dict[str, Any]]:
    """A fresh SQP workspace holding ``qp`` (:func:`write_problem`) on DAQP's struct
    ``buffers`` (:class:`~ltv_lstm_mpc.solvers.daqp_native.DaqpNative`): ``(workspace,
    its arrays)``; everything else zero, as a cold solve starts."""
    sizes = [int(cone.F.shape[0]) for cone in qp.cones]
    arrays = socp_arrays(qp.n_variables, qp.n_rows, sizes, buffers)
    write_problem(arrays, qp)
    return new_socp_workspace(**arrays), arrays


def failure_outcome(
    snapshot: Mapping[str, Any], flag: int, sqp: int, tolerance: float, settings: Mapping[str, Any]
) -> tuple[SolverStatus, str]:
    """The status and info string :class:`DaqpSocpDense` reports for a cold solve that
    ended with DAQP's exit flag ``flag`` < 0 at SQP iteration ``sqp``, from a copy of its
    workspace's arrays taken right after it (``snapshot``: :data:`FAILURE_FIELDS`): the
    same certificate checks
    (:func:`~ltv_lstm_mpc.solvers.socp_certificates.failure_status`) on the same problem
    and iterate, so the same verdict and words. A compiled caller that solved the problem
    itself (the one-call step engine) calls it when the step's record is read, not in the
    step."""
    buffers = native(solver_options("daqp", tolerance, settings))
    if buffers is None:  # pragma: no cover - the snapshot came from a bound DAQP
        return SolverStatus.FAILED, f"exitflag {flag} at SQP iteration {sqp}"
    sizes = np.diff(np.asarray(snapshot["cone_rows"])).tolist()
    n, m = np.shape(snapshot["A"])[1], np.shape(snapshot["A"])[0]
    arrays = socp_arrays(n, m, [int(size) for size in sizes], buffers)
    for name in FAILURE_FIELDS:
        arrays[name][...] = snapshot[name]
    ws = new_socp_workspace(**arrays)
    start = (False, np.zeros(n), np.zeros(len(sizes)))
    status, why, _certificate = failure_status(
        arrays, ws, start, int(flag), int(sqp), ProblemView.of_dense(snapshot_qp(arrays))
    )
    return status, why


def snapshot_qp(arrays: Mapping[str, Any]) -> DenseQP:
    """The :class:`~ltv_lstm_mpc.solvers.DenseQP` (views, not copies) whose data the SQP
    arrays ``arrays`` hold (:func:`~ltv_lstm_mpc.solvers.socp_sqp.socp_arrays`' names;
    the problem of a workspace or of a snapshot of one)."""
    rows = arrays["cone_rows"]
    cones = tuple(
        DenseCone(
            arrays["F"][rows[j] : rows[j + 1]], arrays["g"][rows[j] : rows[j + 1]],
            arrays["e"][j], float(arrays["offsets"][j]),
        )
        for j in range(len(rows) - 1)
    )  # fmt: skip
    return DenseQP(
        H=arrays["H"], f=arrays["f"], A=arrays["A"], lo=arrays["lo"], up=arrays["up"],
        lb=arrays["lb"], ub=arrays["ub"], cones=cones,
    )  # fmt: skip


def local_solution(
    qp: DenseQP, z: FloatArray, cone_duals: FloatArray | None
) -> tuple[FloatArray | None, str]:
    """The point the SQP converges to from ``z`` (and the cone multipliers ``cone_duals``
    in the layer's convention, where given): a point another backend returned, refined by
    the local method (quadratic convergence near the solution, so from a point close to it
    one or two iterations). ``(None, why)`` where DAQP is not bound natively or the SQP
    does not converge."""
    if native({}) is None:
        return None, "daqp:socp is not available (DAQP not bound natively)"
    backend = DaqpSocpDense("daqp:socp", 1e-8, {})
    backend.setup(qp)
    a = backend._arrays
    a["z"][:] = z
    a["mu"][:] = 0.0
    sizes = np.diff(a["cone_rows"]) + 1
    if cone_duals is not None and np.shape(cone_duals) == (int(sizes.sum()),):
        a["mu"][:] = np.maximum(np.asarray(cone_duals)[np.cumsum(sizes) - sizes], 0.0)
    flag, sqp, _total, _violation, _seconds = socp_solve(backend._ws, True, MAX_ITERATIONS)
    if flag not in (1, 2) or sqp > MAX_ITERATIONS:
        return None, f"the SQP from the point did not converge (exit flag {flag}, {sqp} iterations)"
    return np.array(a["z"]), f"{sqp} SQP iterations"


def warm_up() -> None:
    """Solve a two-variable problem with one cone from Python, as :class:`DaqpSocpDense`
    does: compiles :func:`~ltv_lstm_mpc.solvers.socp_sqp.socp_solve` for those argument
    types (or loads it from numba's cache), so that a later first solve does not wait."""
    from .dense import DenseCone

    cone = DenseCone(np.array([[1.0, 0.0]]), np.zeros(1), np.array([0.0, 1.0]), 0.0)
    qp = DenseQP(
        H=np.eye(2), f=np.array([-2.0, 0.0]), A=np.zeros((0, 2)), lo=np.zeros(0),
        up=np.zeros(0), lb=np.array([-10.0, -np.inf]), ub=np.array([10.0, np.inf]),
        cones=(cone,),
    )  # fmt: skip
    backend = DaqpSocpDense("daqp:socp", 1e-8, {})
    backend.setup(qp)
    backend.solve(None)


def make_dense(name: str, tolerance: float, settings: Mapping[str, Any]) -> DenseBackend:
    """Registry dense factory for ``"daqp:socp"``."""
    return DaqpSocpDense(name, tolerance, settings)


def compiled_form(name: str) -> CompiledForm:
    """What ``"daqp:socp"`` gives compiled callers (registered only where DAQP is bound):
    the SQP, its workspace, DAQP's buffers; no numpy twin (it compiles at first use)."""
    return CompiledForm(
        name=name,
        # (DAQP's binding compiles its kernels at its self-test)
        kernels=(*SELF_TEST_KERNELS, socp_solve, new_socp_workspace_kernel),
        bound=True,
        compiled_only=True,
        quadprog=quadprog,
        solver_seconds=solver_seconds,
        socp_solve=socp_solve,
        max_iterations=MAX_ITERATIONS,
        native_buffers=native_buffers,
        new_socp_workspace=new_socp_workspace,
        socp_arrays=socp_arrays,
        warm_up=warm_up,
        failure_outcome=failure_outcome,
        violation=bounds_rows_violation,
        cone_violation=cone_violation,
    )
