"""Registry, errors for unknown/missing solvers, settings, tolerance mapping, sessions."""

from __future__ import annotations

import importlib.util

import numpy as np
import pytest
from conftest import SOLVERS, problem, solver_params
from ltv_lstm_mpc.solvers import (
    TOLERANCE_OPTIONS,
    Session,
    SolverStatus,
    available_solvers,
    cone_solvers,
    get_backend,
    solve,
)
from ltv_lstm_mpc.solvers.testing import infeasible_problem, random_mpc_problem
from ltv_lstm_mpc.solvers.tolerances import solver_options
from optional_extras import backend_params, require_solver, requires_package, requires_solver

from ltv_lstm_mpc.exceptions import InvalidValueError, SolverError, SolverNotFound


def test_available_solvers_lists_the_families() -> None:
    names = available_solvers()
    assert names == SOLVERS
    assert len(set(names)) == len(names)
    assert all(
        n.split(":")[0]
        in {"cvxpy", "qpsolvers", "osqp", "piqp", "daqp", "quadprog", "proxqp", "clarabel"}
        for n in names
    )
    if importlib.util.find_spec("cvxpy") is not None:
        assert "cvxpy:CLARABEL" in names  # the solver layer's default and the tests' reference
    assert set(cone_solvers()) <= {
        "cvxpy:CLARABEL",
        "cvxpy:ECOS",
        "cvxpy:SCS",
        "clarabel",
        "daqp:socp",
    }


@requires_package("cvxpy", "solvers")
@requires_package("qpsolvers", "solvers")
@pytest.mark.parametrize("name", ["gurobi", "cvxpy:NOPE", "qpsolvers:mosek"])
def test_unknown_or_missing_solver_error(name: str) -> None:
    with pytest.raises(SolverNotFound) as info:
        get_backend(name)
    msg = str(info.value)
    assert name in msg
    # cvxpy and qpsolvers are installed: installing the extra would not help
    assert "pip install" not in msg
    assert "cvxpy:CLARABEL" in msg  # lists the installed ones
    assert isinstance(info.value, ImportError)
    with pytest.raises(SolverNotFound):
        solve(problem("qp"), name)


@pytest.mark.parametrize(
    ("name", "meant"),
    [
        ("DAQP", "'daqp'"),
        ("clarabel ", "'clarabel'"),
        ("Daqp:SOCP", "'daqp:socp'"),
        ("osqpp", "'osqp'"),
    ],
)
def test_unknown_solver_says_did_you_mean(name: str, meant: str) -> None:
    require_solver(meant.strip("'"))
    with pytest.raises(SolverNotFound, match=f"did you mean {meant}"):
        get_backend(name)


def test_install_advice_only_where_the_package_is_missing(monkeypatch: pytest.MonkeyPatch) -> None:
    from ltv_lstm_mpc.solvers import registry

    with pytest.raises(SolverNotFound) as info:
        get_backend("gurobi")
    assert "not a name of this library" in str(info.value) and "cvxpy:GUROBI" in str(info.value)
    real = registry._installed
    monkeypatch.setattr(registry, "_installed", lambda module: module != "osqp" and real(module))
    message = registry._not_found_message("osqp", ["daqp"])  # as if osqp were missing
    assert "package 'osqp' is not installed: pip install" in message


def test_default_solver_is_the_fastest_exact_one_installed() -> None:
    from ltv_lstm_mpc.solvers import default_solver, solver_info

    from ltv_lstm_mpc import MPCConfig

    name = default_solver()
    assert solver_info(name).supports_cones
    assert MPCConfig().solver == name
    expected = next(s for s in ("daqp:socp", "clarabel", "cvxpy:CLARABEL") if s in SOLVERS)
    assert name == expected


@pytest.mark.parametrize(
    "solver",
    solver_params(
        [
            s
            for s in SOLVERS
            if s.split(":")[-1].lower() in {"osqp", "piqp", "daqp", "clarabel", "ecos", "quadprog"}
        ]
    ),
)
def test_unknown_setting_is_rejected(solver: str) -> None:
    with pytest.raises(InvalidValueError, match="unknown setting"):
        Session(solver, not_a_setting=1)


def test_tolerance_mapping_and_override() -> None:
    assert solver_options("osqp", 1e-7, {}) == {"eps_abs": 1e-7, "eps_rel": 1e-7}
    opts = solver_options("CLARABEL", 1e-6, {"tol_feas": 1e-3, "max_iter": 5})
    assert opts == {"tol_gap_abs": 1e-6, "tol_gap_rel": 1e-6, "tol_feas": 1e-3, "max_iter": 5}
    assert solver_options("proxqp", 1e-6, {}) == {"eps_abs": 1e-6, "eps_rel": 0.0}
    assert solver_options("quadprog", 1e-6, {}) == {}
    assert set(TOLERANCE_OPTIONS) >= {"osqp", "scs", "clarabel", "ecos", "piqp", "daqp"}
    with pytest.raises(InvalidValueError, match="tolerance"):
        solver_options("osqp", -1.0, {})


@pytest.mark.parametrize("solver", backend_params("osqp", "cvxpy:SCS"))
def test_tolerance_changes_accuracy(solver: str) -> None:
    """A loose tolerance gives a visibly less accurate answer than a tight one (it is applied)."""
    require_solver("cvxpy:CLARABEL")
    p = random_mpc_problem(5, seed=2, terminal_cone=False)
    ref = solve(p, "cvxpy:CLARABEL", tolerance=1e-10)
    assert ref.z is not None
    err = {}
    for t in (1e-2, 1e-8):
        s = solve(p, solver, tolerance=t)
        assert s.z is not None
        err[t] = float(np.max(np.abs(s.z - ref.z)))
    assert err[1e-8] < 0.1 * err[1e-2]


@requires_solver("osqp")
def test_max_iter_status_and_raise_on_failure() -> None:
    q = random_mpc_problem(5, seed=3, terminal_cone=False)
    sol = solve(q, "osqp", max_iter=3)
    assert sol.status is SolverStatus.MAX_ITER
    assert sol.z is None and sol.iterations == 3
    with pytest.raises(SolverError, match="MAX_ITER"):
        solve(q, "osqp", max_iter=3, raise_on_failure=True)
    with pytest.raises(SolverError, match="INFEASIBLE"):
        solve(infeasible_problem(), "osqp", raise_on_failure=True)


@requires_solver("cvxpy:CLARABEL")
def test_session_rejects_structure_change_and_use_before_setup() -> None:
    s = Session("cvxpy:CLARABEL")
    with pytest.raises(SolverError, match="before setup"):
        s.solve()
    with pytest.raises(SolverError, match="before setup"):
        s.update(problem("qp"))
    s.setup(random_mpc_problem(5, seed=0))
    with pytest.raises(InvalidValueError, match="structure"):
        s.update(random_mpc_problem(6, seed=0))
    # setup() accepts a new structure
    s.setup(random_mpc_problem(6, seed=0))
    assert s.n_setups == 2 and s.solve().ok


@requires_solver("cvxpy:CLARABEL")
def test_session_tracks_a_changing_sequence() -> None:
    """Five RTI-like steps: in-place updates give the same answers as fresh solves."""
    base = random_mpc_problem(5, seed=9)
    sess = Session("cvxpy:CLARABEL")
    sess.setup(base)
    prev = None
    rng = np.random.default_rng(0)
    for _ in range(5):
        p = base.with_values(q=np.asarray(base.q) + rng.standard_normal(base.n_variables))
        sess.update(p)
        sol = sess.solve(warm_start=prev)
        fresh = solve(p, "cvxpy:CLARABEL")
        assert sol.z is not None and fresh.z is not None
        np.testing.assert_allclose(sol.z, fresh.z, atol=1e-6 * (1 + np.max(np.abs(fresh.z))))
        assert sol.setup_time < 0.1  # no recompilation
        prev = sol
    assert sess.n_setups == 1


def test_bad_reformulation_object_is_rejected() -> None:
    with pytest.raises(InvalidValueError, match="reformulation"):
        Session("daqp", reformulation=object())  # type: ignore[arg-type]


@pytest.mark.parametrize("solver", backend_params("osqp", "daqp"))
def test_warm_start_shape_is_checked(solver: str) -> None:
    from ltv_lstm_mpc.exceptions import DimensionError

    with pytest.raises(DimensionError, match="warm_start must have shape"):
        solve(problem("qp"), solver, warm_start=np.zeros(3))
