"""Compiled forms: what each registered backend gives compiled callers, through the registry
(``solvers.compiled_form``), and that the MPC layer's compiled code uses exactly those."""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping
from typing import Any

import pytest
from ltv_lstm_mpc.solvers import (
    CompiledForm,
    available_solvers,
    compiled_form,
    register_backend,
    solver_info,
    unregister_backend,
)

from ltv_lstm_mpc import MPCConfig
from ltv_lstm_mpc.exceptions import SolverNotFound

#: Backends with a form of their own (the other cone solvers get the dense layer's checks).
OWN_FORMS = ("daqp", "daqp:socp", "clarabel")


@pytest.mark.parametrize("name", available_solvers())
def test_every_registered_backend_has_its_form_or_none(name: str) -> None:
    """A form for daqp, daqp:socp and every cone solver, none for the other QP solvers;
    only daqp:socp is compiled only."""
    form = compiled_form(name)
    if name not in OWN_FORMS and not solver_info(name).supports_cones:
        assert form is None
        return
    assert isinstance(form, CompiledForm) and form.name == name
    assert form.compiled_only == (name == "daqp:socp")
    assert all(hasattr(kernel, "py_func") for kernel in form.kernels)  # numba dispatchers
    with pytest.raises(dataclasses.FrozenInstanceError):
        form.bound = not form.bound  # type: ignore[misc]
    if name not in OWN_FORMS:  # a cone solver without compiled code of its own
        from ltv_lstm_mpc.solvers.compiled_forms import dense_check_form

        assert form == dense_check_form(name)
        assert not form.bound and form.quadprog is None and form.socp_solve is None


def test_the_daqp_form_holds_daqps_entry_point() -> None:
    if "daqp" not in available_solvers():
        pytest.skip("daqp is not installed")
    from ltv_lstm_mpc.solvers import daqp_native

    form = compiled_form("daqp")
    assert form is not None
    assert form.bound == daqp_native.bound()
    assert form.quadprog is daqp_native.quadprog
    assert form.solver_seconds is daqp_native.solver_seconds
    from ltv_lstm_mpc.solvers.dense import bounds_rows_violation

    kernels = (
        daqp_native.quadprog,
        daqp_native.quadprog_kept,
        daqp_native.box_quadprog_from,
        daqp_native.objective_bound,
        daqp_native.activity_infeasible,
        bounds_rows_violation,
    )
    assert form.kernels == (kernels if form.bound else ())
    assert form.violation is bounds_rows_violation
    status, info = form.flag_outcome(-1)
    assert (status.name, info) == ("INFEASIBLE", "exitflag -1")
    assert form.socp_solve is None and form.warm_up is None and form.native_buffers is not None
    if form.bound:
        buffers = form.native_buffers(1e-8, {})
        assert buffers is not None and buffers.settings.dtype.itemsize == 1


def test_the_daqp_socp_form_holds_the_sqp_and_its_workspace() -> None:
    if "daqp:socp" not in available_solvers():
        pytest.skip("daqp:socp needs DAQP bound natively")
    from ltv_lstm_mpc.solvers import daqp_native, daqp_socp, socp_sqp

    form = compiled_form("daqp:socp")
    assert form is not None and form.bound and form.compiled_only
    assert form.socp_solve is socp_sqp.socp_solve
    assert form.max_iterations == socp_sqp.MAX_ITERATIONS
    assert form.quadprog is daqp_native.quadprog
    assert form.new_socp_workspace is socp_sqp.new_socp_workspace
    assert form.socp_arrays is socp_sqp.socp_arrays
    assert form.kernels == (
        daqp_native.quadprog,
        daqp_native.quadprog_kept,
        daqp_native.box_quadprog_from,
        daqp_native.objective_bound,
        daqp_native.activity_infeasible,
        socp_sqp.socp_solve,
        socp_sqp.new_socp_workspace_kernel,
    )
    assert form.warm_up is daqp_socp.warm_up
    assert form.native_buffers is not None and form.native_buffers(1e-8, {}) is not None


def test_the_clarabel_form_lists_its_loops() -> None:
    if "clarabel" not in available_solvers():
        pytest.skip("clarabel is not installed")
    from ltv_lstm_mpc.solvers import _compiled

    form = compiled_form("clarabel")
    assert form is not None and not form.bound and form.quadprog is None
    assert form.kernels == (
        _compiled.clarabel_fill,
        _compiled.clarabel_cone_rows,
        _compiled.bounds_rows_violation,
        _compiled.cone_violation,
    )


def test_an_unknown_name_raises_as_solver_info_does() -> None:
    with pytest.raises(SolverNotFound, match="not available"):
        compiled_form("gurobi")


def _factory(name: str, tolerance: float, settings: Mapping[str, Any]) -> Any:
    raise AssertionError("never built here")


def test_user_backends_get_the_dense_checks_for_cones_else_none() -> None:
    from ltv_lstm_mpc.solvers.compiled_forms import dense_check_form

    qp = register_backend("user:form-qp", dense_factory=_factory)
    cone = register_backend("user:form-cone", dense_factory=_factory, supports_cones=True)
    try:
        assert compiled_form(qp) is None
        assert compiled_form(cone) == dense_check_form(cone)
        register_backend(qp, dense_factory=_factory, supports_cones=True, replace=True)
        assert compiled_form(qp) == dense_check_form(qp)  # replacing replaces the form
    finally:
        unregister_backend(qp)
        unregister_backend(cone)


@pytest.mark.parametrize("solver", ["daqp", "daqp:socp"])
def test_the_mpc_layer_compiles_and_calls_the_forms_functions(solver: str) -> None:
    """``mpc.kernels.compiled_kernels`` lists the form's kernels, and the one-call feedback
    (``mpc/native_feedback.py``, whose compiled code binds its callees at compilation)
    calls the very functions of the forms."""
    if solver not in available_solvers():
        pytest.skip(f"{solver} is not available")
    from ltv_lstm_mpc.mpc import native_feedback
    from ltv_lstm_mpc.mpc.kernels import compiled_kernels

    form = compiled_form(solver)
    assert form is not None
    listed = compiled_kernels(MPCConfig(solver=solver, transcription="condensed"))
    assert all(any(kernel is k for k in listed) for kernel in form.kernels)
    if not form.bound:
        return
    assert native_feedback.quadprog is form.quadprog
    assert native_feedback.solver_seconds is form.solver_seconds
    if form.socp_solve is not None:
        assert native_feedback.socp_solve is form.socp_solve
        assert native_feedback.MAX_ITERATIONS == form.max_iterations
        assert native_feedback.cone_feedback in listed
    else:
        assert native_feedback.nominal_feedback in listed


def test_a_cone_solver_without_own_code_lists_the_dense_checks() -> None:
    """A condensed controller on a cone solver calls ``DenseQP.max_violation``'s compiled
    loops, and only those of the solver layer (not CLARABEL's data fill)."""
    if "cvxpy:CLARABEL" not in available_solvers():
        pytest.skip("cvxpy:CLARABEL is not installed")
    from ltv_lstm_mpc.solvers import _compiled

    from ltv_lstm_mpc.mpc.kernels import compiled_kernels

    listed = compiled_kernels(MPCConfig(solver="cvxpy:CLARABEL", transcription="condensed"))
    assert _compiled.bounds_rows_violation in listed and _compiled.cone_violation in listed
    assert _compiled.clarabel_fill not in listed
