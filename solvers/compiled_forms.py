"""What a backend gives compiled (numba) callers: its :class:`CompiledForm`.

A controller whose kernels are compiled calls some of the solver layer's code from its own
compiled code (the one-call feedback solves its QP inside one numba call) or lists the
layer's compiled functions to load or compile ahead (numba's on-disk cache). Which ones
depends on the backend, and only the backend knows them: each built-in backend that has
any advertises them through the registry (:func:`~ltv_lstm_mpc.solvers.compiled_form`),
so that the MPC layer asks for the form of its solver and never names a solver or imports
a backend's private names.

=================  ===============================================================
backend            its form
=================  ===============================================================
``daqp``           DAQP's C entry point (``daqp_native.quadprog``) and its
                   buffers, where DAQP is bound natively (else ``bound=False``,
                   no kernels)
``daqp:socp``      the SQP of :mod:`~ltv_lstm_mpc.solvers.socp_sqp` around it,
                   its workspace; compiled only (no numpy twin)
``clarabel``       its data fill loops and the dense layer's point checks
other cone         the dense layer's point checks
solvers
=================  ===============================================================

Other solvers (the QP solvers but ``daqp``) have none: ``compiled_form`` returns None.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import Any

__all__ = ["CompiledForm", "dense_check_form"]


@dataclass(frozen=True)
class CompiledForm:
    """A backend's compiled form: what compiled callers take from it.

    Read once, where a caller is built (never per step): its fields are the compiled
    functions themselves, which compiled code binds at its own compilation.

    Attributes
    ----------
    name : str
        The registry name it was asked for.
    kernels : tuple
        The layer's compiled functions a controller on this solver calls (its solve,
        workspace constructors, loops): what compiles on an empty numba cache, to be loaded
        or compiled ahead. Empty where the compiled solve cannot run here.
    bound : bool
        The compiled solve (``quadprog``, ``socp_solve``) can run in this process: its
        native library is bound (DAQP's C entry point). False for forms without one.
    compiled_only : bool
        The backend's solve has no numpy or Python twin: it compiles at its first use, even
        for a caller that runs the numpy reference kernels.
    quadprog, solver_seconds : numba dispatcher or None
        DAQP's C entry point for compiled code and its clock
        (:func:`~ltv_lstm_mpc.solvers.daqp_native.quadprog`,
        :func:`~ltv_lstm_mpc.solvers.daqp_native.solver_seconds`).
    socp_solve : numba dispatcher or None
        The exact-cone SQP (:func:`~ltv_lstm_mpc.solvers.socp_sqp.socp_solve`);
        ``max_iterations`` is its iteration limit as the backend runs it.
    native_buffers : callable or None
        ``native_buffers(tolerance, settings)``: the C struct buffers of the compiled solve
        with the backend's settings (a :class:`~ltv_lstm_mpc.solvers.daqp_native.DaqpNative`),
        or None where it is not bound.
    new_socp_workspace, socp_arrays : callable or None
        The SQP's workspace: its arrays for given sizes
        (:func:`~ltv_lstm_mpc.solvers.socp_sqp.socp_arrays`) and the workspace from them
        (:func:`~ltv_lstm_mpc.solvers.socp_sqp.new_socp_workspace`).
    warm_up : callable or None
        Compiles (or loads from numba's cache) what the backend's Python entry calls, by a
        small solve.
    flag_outcome : callable or None
        ``flag_outcome(flag) -> (SolverStatus, info)``: what the backend's session reports
        for an exit flag of ``quadprog`` (the status and the info string of its
        ``solve_point``), so that a compiled caller that records only the flag reports the
        same status and reason.
    violation : numba dispatcher or None
        The dense layer's compiled ``bounds_rows_violation(x, lb, ub, A, lo, up)``: the
        largest violation of a point of a QP without cones, as
        :meth:`~ltv_lstm_mpc.solvers.DenseQP.max_violation` computes it; ``cone_violation``
        its cones' ``cone_violation(F, g, e, f, x)``.
    failure_outcome : callable or None
        ``failure_outcome(snapshot, flag, sqp, tolerance, settings) -> (SolverStatus,
        info)``: what the backend's session reports for a failed cone solve, from a copy of
        its workspace's arrays (``daqp:socp``: the certificate checks run when asked, off a
        compiled caller's step).
    """

    name: str
    kernels: tuple[Any, ...] = ()
    bound: bool = False
    compiled_only: bool = False
    quadprog: Any = None
    solver_seconds: Any = None
    socp_solve: Any = None
    max_iterations: int = 0
    native_buffers: Callable[[float, Mapping[str, Any]], Any] | None = None
    new_socp_workspace: Callable[..., Any] | None = None
    socp_arrays: Callable[..., dict[str, Any]] | None = None
    warm_up: Callable[[], None] | None = None
    flag_outcome: Callable[[int], tuple[Any, str]] | None = None
    violation: Any = None
    cone_violation: Any = None
    failure_outcome: Callable[..., tuple[Any, str]] | None = None


def dense_check_form(name: str) -> CompiledForm:
    """The form of a cone solver without compiled code of its own: the dense layer's
    compiled checks of a point of a problem with cones
    (:meth:`~ltv_lstm_mpc.solvers.DenseQP.max_violation`)."""
    from ._compiled import bounds_rows_violation, cone_violation

    return CompiledForm(name=name, kernels=(bounds_rows_violation, cone_violation))
