"""DAQP's C entry point from numba (solvers/daqp_native.py) and the one-call nominal feedback."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from ltv_lstm_mpc.solvers import DenseQP, DenseSession, available_solvers
from optional_extras import requires_daqp_binding

from ltv_lstm_mpc import MPCConfig, OffsetFreeController, RobustMPC, load_model

pytestmark = pytest.mark.skipif("daqp" not in available_solvers(), reason="needs daqp")

daqp_native = pytest.importorskip("ltv_lstm_mpc.solvers.daqp_native")
needs_binding = requires_daqp_binding()


def random_qp(seed: int, n: int = 6, rows: int = 9, feasible: bool = True):
    """Dense QP data in DAQP's layout (simple bounds first); infeasible rows when asked."""
    rng = np.random.default_rng(seed)
    G = rng.normal(size=(n, n))
    H = G @ G.T + 0.1 * np.eye(n)
    f = 3.0 * rng.normal(size=n)
    A = rng.normal(size=(rows, n))
    upper = np.concatenate([np.full(n, 0.5), rng.uniform(0.0, 0.4, rows)])
    lower = -upper
    if not feasible:  # two copies of one row with disjoint intervals
        A[1] = A[0]
        lower[n], upper[n] = 1.0, 2.0
        lower[n + 1], upper[n + 1] = -2.0, -1.0
    sense = np.zeros(n + rows, dtype=np.intc)
    return H, f, A, upper, lower, sense


@needs_binding
@pytest.mark.parametrize("seed", range(6))
@pytest.mark.parametrize("feasible", [True, False])
def test_binding_equals_daqp_solve_bit_for_bit(seed: int, feasible: bool) -> None:
    """Same C function, same settings: the same point, multipliers, flag and iterations."""
    import daqp

    H, f, A, upper, lower, sense = random_qp(seed, feasible=feasible)
    options = {"primal_tol": 1e-8, "dual_tol": 1e-8}
    x, lam, flag, iterations = daqp_native.native(options).solve(H, f, A, upper, lower, sense)
    x_ref, _, flag_ref, info = daqp.solve(H, f, A, upper, lower, sense, **options)
    assert flag == flag_ref
    assert flag == (1 if feasible else -1)
    assert iterations == info["iterations"]
    if feasible:
        np.testing.assert_array_equal(x, x_ref)
        np.testing.assert_array_equal(lam, info["lam"])
        assert np.abs(x).max() <= 0.5 + 1e-8


@needs_binding
def test_binding_honours_settings_and_equality_rows() -> None:
    """An iteration limit reaches DAQP (exit flag -4); sense 5 makes a row an equality."""
    H, f, A, upper, lower, sense = random_qp(3)
    limited = daqp_native.native({"iter_limit": 1}).solve(H, f, A, upper, lower, sense)
    assert limited[2] == -4
    sense[6] = 5
    lower[6] = upper[6] = 0.1
    x, _, flag, _ = daqp_native.native({}).solve(H, f, A, upper, lower, sense)
    assert flag == 1
    assert A[0] @ x == pytest.approx(0.1, abs=1e-10)


def test_unknown_setting_disables_the_binding_with_its_name() -> None:
    assert daqp_native.native({"no_such_setting": 1.0}) is None
    assert "no_such_setting" in daqp_native.unavailable_reason


@needs_binding
def test_dense_backend_solves_the_same_with_and_without_the_binding() -> None:
    """DenseSession.solve_point: the C entry point and daqp.solve give the same point."""
    H, f, A, upper, lower, _ = random_qp(5)
    n = H.shape[0]
    qp = DenseQP(H=H, f=f, A=A, lo=lower[n:], up=upper[n:], lb=lower[:n], ub=upper[:n])
    bound, plain = DenseSession("daqp"), DenseSession("daqp")
    bound.solve_point(qp)  # sets the workspaces up
    plain.solve_point(qp)
    plain._backend._native, plain._backend._native_bound = None, True  # daqp.solve from here on
    status_a, z_a, it_a, info_a = bound.solve_point(qp)
    status_b, z_b, it_b, info_b = plain.solve_point(qp)
    assert bound.native is not None and plain.native is None
    assert (status_a, it_a, info_a) == (status_b, it_b, info_b)
    np.testing.assert_array_equal(z_a, z_b)


def _same_solutions(a, b) -> None:
    """Every field of two MPCSolutions equal, numbers within 1e-12 (the compiled loops may
    sum in another order where they are inlined; timings excepted)."""
    for field in dataclasses.fields(a):
        if field.name.endswith("time"):
            continue
        x, y = getattr(a, field.name), getattr(b, field.name)
        if isinstance(x, np.ndarray):
            np.testing.assert_allclose(x, y, rtol=1e-12, atol=1e-12, err_msg=field.name)
        elif isinstance(x, dict):
            assert x.keys() == y.keys(), field.name
            for key in x:
                assert x[key] == pytest.approx(y[key], rel=1e-9, abs=1e-12, nan_ok=True), key
        elif isinstance(x, float):
            assert x == pytest.approx(y, rel=1e-9, abs=1e-12, nan_ok=True), field.name
        else:
            assert x == y, field.name


def _closed_loop(model, config, scenario, native: bool, steps: int):
    mpc = RobustMPC(model, config, native_feedback=native)
    controller = OffsetFreeController(
        model, config, setpoint_rate_limit=scenario.setpoint_rate_limit, mpc=mpc
    )
    plant = scenario.make_plant(model)
    y = plant.output()
    for k in range(steps):
        u = controller.step(y, scenario.setpoints[k])
        d = scenario.disturbances[k]
        y = plant.step(u, None if np.isnan(d) else d)
    return mpc, controller.records


@needs_binding
@pytest.mark.parametrize("index", [0, 2])  # set-point steps; an unreachable set-point (infeasible)
def test_one_call_feedback_equals_the_general_path_in_closed_loop(index: int) -> None:
    """Bench scenarios on the shipped pH model: the same MPCSolution at every step (scenario
    3 includes infeasible steps, which the general path handles)."""
    from ltv_lstm_mpc.solver_comparison.harness import bench_scenarios

    model = load_model("ph_lstm_n5.npz")
    scenario = bench_scenarios(model)[index]
    config = dataclasses.replace(scenario.config, solver="daqp")
    steps = min(len(scenario.setpoints), 300)
    fast, fast_records = _closed_loop(model, config, scenario, True, steps)
    general, general_records = _closed_loop(model, config, scenario, False, steps)
    assert fast._native_feedback is not None and general._native_feedback is None
    for a, b in zip(fast_records, general_records, strict=True):
        _same_solutions(a.mpc, b.mpc)
    statuses = {r.mpc.status for r in fast_records}
    assert "optimal" in statuses
    if index == 2:
        assert any(not r.mpc.feasible for r in fast_records)


@needs_binding
def test_one_call_feedback_is_taken_and_equals_the_general_path_mimo() -> None:
    """A random (2, 2) delta-ISS model: the general path is not run on accepted steps, and
    both paths give the same solution from the same prepared problem."""
    from lstm_factories import random_delta_iss_lstm

    model = random_delta_iss_lstm(np.random.default_rng(4), 4, 2, 2)
    config = MPCConfig(solver="daqp", N=6)
    fast = RobustMPC(model, config)
    general = RobustMPC(model, config, certification=fast.certification, native_feedback=False)
    calls = []
    original = fast._checked_solve
    fast._checked_solve = lambda *args: calls.append(args) or original(*args)
    rng = np.random.default_rng(2)
    u_bar = rng.uniform(-0.3, 0.3, 2)
    x_bar = model.equilibrium(u_bar)
    accepted = 0
    for _ in range(6):
        x_hat = x_bar + rng.normal(scale=0.05, size=8)
        solutions = []
        for mpc in (fast, general):
            mpc.prepare(x_bar, u_bar, model.output(x_bar), 0.3, x_pred=x_hat)
            solutions.append(mpc.feedback(x_hat))
        _same_solutions(*solutions)
        accepted += solutions[0].feasible
    assert accepted >= 4
    assert len(calls) == 6 - accepted


def test_without_numba_the_numpy_path_and_daqp_solve_run() -> None:
    """numba missing: the package imports, the kernel is numpy, DAQP runs through daqp.solve
    (the binding says why it is off) and the controller still solves."""
    import subprocess
    import sys

    code = (
        "import sys; sys.modules['numba'] = None\n"
        "import warnings; warnings.simplefilter('always')\n"
        "import numpy as np\n"
        "from ltv_lstm_mpc import MPCConfig, RobustMPC, load_model\n"
        "from ltv_lstm_mpc.solvers import daqp_native\n"
        "model = load_model('ph_lstm_n5.npz'); load_model('ph_lstm_n5.npz')\n"
        "mpc = RobustMPC(model, MPCConfig(solver='daqp'))\n"
        "u = np.array([0.1]); x = model.equilibrium(u)\n"
        "solution = mpc.solve(x, x, u, model.output(x), 0.01)\n"
        "print(solution.status, model.kernel.compiled, daqp_native.native({}) is None,\n"
        "      'numba' in daqp_native.unavailable_reason, abs(solution.u[0, 0] - 0.1) < 1e-6)\n"
    )
    result = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert result.returncode == 0, result.stderr[-2000:]
    assert result.stdout.split() == ["optimal", "False", "True", "True", "True"]
    # said once, however many kernels are built
    assert result.stderr.count("numba cannot be imported: the controller runs its numpy") == 1
