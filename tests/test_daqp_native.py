"""DAQP's C entry point from numba (solvers/daqp_native.py) and the one-call nominal feedback."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from ltv_lstm_mpc.solvers import DenseQP, DenseSession, available_solvers
from optional_extras import requires_daqp_binding

from ltv_lstm_mpc import MPCConfig, OffsetFreeController, RobustMPC, load_model
from ltv_lstm_mpc.export.sil import find_c_compiler

pytestmark = pytest.mark.skipif("daqp" not in available_solvers(), reason="needs daqp")

daqp_native = pytest.importorskip("ltv_lstm_mpc.solvers.daqp_native")
needs_binding = requires_daqp_binding()


def random_qp(seed: int, n: int = 6, rows: int = 9, feasible: bool = True, scale: float = 3.0):
    """Dense QP data in DAQP's layout (simple bounds first); infeasible rows when asked;
    ``scale``: of f (small: the box QP's unconstrained optimum inside the box)."""
    rng = np.random.default_rng(seed)
    G = rng.normal(size=(n, n))
    H = G @ G.T + 0.1 * np.eye(n)
    f = scale * rng.normal(size=n)
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


# --- a kept DAQP workspace (quadprog_kept, box_quadprog_from) ---------------------------

#: Byte offsets in DAQP's workspace the tests read (types.h of the vendored release,
#: checked by test_kept_workspace_fits_the_vendored_layout): its sizes n and m.
_W_N, _W_M = 8, 12


def _kept_then_box(buffers, H, f, A, upper, lower, sense):
    """quadprog_kept on the QP, then box_quadprog_from on its box QP (if kept)."""
    n = H.shape[0]
    work = np.zeros(daqp_native.WORKSPACE_BYTES // 8, dtype=np.int64).view(np.uint8)
    structs = (buffers.problem, buffers.result, buffers.settings)
    x, lam = np.empty(n), np.empty(upper.shape[0])
    flag, _, kept = daqp_native.quadprog_kept(
        H, f, A, upper, lower, sense, x, lam, *structs, work, True
    )
    if not kept:
        return flag, kept, None
    box_x, box_lam = np.empty(n), np.empty(n)
    box_flag, iterations = daqp_native.box_quadprog_from(
        work, H, f, A[:0], upper[:n].copy(), lower[:n].copy(), sense[:n].copy(), box_x,
        box_lam, *structs,
    )  # fmt: skip
    assert work.view(np.int32)[_W_M // 4] == n  # the box QP was installed on the kept one
    return flag, kept, (box_x, box_lam, box_flag, iterations)


@needs_binding
@pytest.mark.skipif(find_c_compiler() is None, reason="no C compiler (cc, gcc or clang)")
def test_kept_workspace_fits_the_vendored_layout(tmp_path) -> None:
    """WORKSPACE_BYTES holds DAQP's workspace and WORKSPACE_SETTINGS_OFFSET (and the
    offsets these tests read) are its fields', compiled from the vendored headers of the
    bound release."""
    import subprocess
    from pathlib import Path

    import ltv_lstm_mpc.export
    from ltv_lstm_mpc.export.c_model import DAQP_VENDORED

    compiler = find_c_compiler()
    assert DAQP_VENDORED in daqp_native.BOUND_VERSIONS  # the headers of the bound release
    vendor = Path(ltv_lstm_mpc.export.__file__).parent / "vendor" / "daqp"
    source = tmp_path / "layout.c"
    source.write_text(
        '#include <stddef.h>\n#include <stdio.h>\n#include "types.h"\n'
        'int main(void) { printf("%zu %zu %zu %zu\\n", sizeof(DAQPWorkspace),\n'
        "  offsetof(DAQPWorkspace, settings), offsetof(DAQPWorkspace, n),\n"
        "  offsetof(DAQPWorkspace, m)); return 0; }\n"
    )
    program = tmp_path / "layout"
    subprocess.run(
        [compiler, f"-I{vendor / 'include'}", str(source), "-o", str(program)], check=True
    )
    size, settings, n, m = map(int, subprocess.run(
        [str(program)], check=True, capture_output=True, text=True
    ).stdout.split())  # fmt: skip
    assert size <= daqp_native.WORKSPACE_BYTES
    assert settings == daqp_native.WORKSPACE_SETTINGS_OFFSET
    assert (n, m) == (_W_N, _W_M)


@needs_binding
@pytest.mark.parametrize("n", [1, 3, 8, 20, 35])
@pytest.mark.parametrize("scale", [0.01, 1.0, 30.0])
@pytest.mark.parametrize("seed", range(4))
def test_the_box_qp_on_a_kept_workspace_is_a_fresh_solve_bit_for_bit(
    seed: int, scale: float, n: int
) -> None:
    """After DAQP proves a QP infeasible on a kept workspace, its box QP solved there
    gives the fresh solve's point, multipliers, exit flag and iterations to the last bit,
    with the box's unconstrained optimum inside the box (one iteration: redone fresh) and
    outside it (iterations on the kept factor of H)."""
    buffers = daqp_native.native({"primal_tol": 1e-9})
    assert buffers.work.shape[0] == daqp_native.WORKSPACE_BYTES  # the self-test passed
    H, f, A, upper, lower, sense = random_qp(seed, n, feasible=False, scale=scale)
    flag, kept, box = _kept_then_box(buffers, H, f, A, upper, lower, sense)
    assert flag == -1 and kept
    fresh_x, fresh_lam = np.empty(n), np.empty(n)
    fresh = daqp_native.quadprog(
        H, f, A[:0], upper[:n].copy(), lower[:n].copy(), sense[:n].copy(), fresh_x,
        fresh_lam, buffers.problem, buffers.result, buffers.settings,
    )  # fmt: skip
    box_x, box_lam, box_flag, iterations = box
    assert (box_flag, iterations) == fresh
    np.testing.assert_array_equal(box_x, fresh_x)
    np.testing.assert_array_equal(box_lam, fresh_lam)


@needs_binding
@pytest.mark.parametrize("seed", range(3))
def test_a_warm_box_qp_on_a_kept_workspace_is_solved_fresh(seed: int) -> None:
    """A box QP with a warm working set (an active bound in sense) is not what a kept
    workspace is for: box_quadprog_from frees it and solves fresh, the same bits as
    quadprog with that working set."""
    buffers = daqp_native.native({"primal_tol": 1e-9})
    n = 8
    H, f, A, upper, lower, sense = random_qp(seed, n, feasible=False, scale=30.0)
    work = np.zeros(daqp_native.WORKSPACE_BYTES // 8, dtype=np.int64).view(np.uint8)
    structs = (buffers.problem, buffers.result, buffers.settings)
    kept = daqp_native.quadprog_kept(
        H, f, A, upper, lower, sense, np.empty(n), np.empty(upper.shape[0]), *structs, work,
        True,
    )  # fmt: skip
    assert kept[2]
    warm = np.zeros(n, dtype=np.intc)
    warm[0] = 1  # the first variable's upper bound active
    x, lam, x_ref, lam_ref = np.empty(n), np.empty(n), np.empty(n), np.empty(n)
    box = (upper[:n].copy(), lower[:n].copy())
    out = daqp_native.box_quadprog_from(work, H, f, A[:0], *box, warm.copy(), x, lam, *structs)
    assert work.view(np.int64)[daqp_native.WORKSPACE_SETTINGS_OFFSET // 8] == 0  # freed
    ref = daqp_native.quadprog(H, f, A[:0], *box, warm.copy(), x_ref, lam_ref, *structs)
    assert out == ref
    np.testing.assert_array_equal(x, x_ref)
    np.testing.assert_array_equal(lam, lam_ref)


@needs_binding
def test_a_workspace_is_kept_only_for_an_infeasible_qp_without_equalities() -> None:
    """Kept: DAQP said -1, the caller asked, no row's bounds closer than zero_tol (an
    equality DAQP would eliminate); otherwise freed at once (a feasible QP, keep False, an
    equality row)."""
    buffers = daqp_native.native({"primal_tol": 1e-9})
    H, f, A, upper, lower, sense = random_qp(0, feasible=False, scale=30.0)
    assert _kept_then_box(buffers, H, f, A, upper, lower, sense)[:2] == (-1, True)
    assert _kept_then_box(buffers, *random_qp(0, scale=30.0))[:2] == (1, False)
    equality = random_qp(0, feasible=False, scale=30.0)
    equality[3][-1] = equality[4][-1] = 0.0  # a row held at 0: an equality
    assert _kept_then_box(buffers, *equality)[1] is False
    n = H.shape[0]
    work = np.zeros(daqp_native.WORKSPACE_BYTES // 8, dtype=np.int64).view(np.uint8)
    out = daqp_native.quadprog_kept(
        H, f, A, upper, lower, sense, np.empty(n), np.empty(upper.shape[0]), buffers.problem,
        buffers.result, buffers.settings, work, False,
    )  # fmt: skip
    assert out[0] == -1 and out[2] is False
    assert work.view(np.int64)[daqp_native.WORKSPACE_SETTINGS_OFFSET // 8] == 0  # freed


@needs_binding
@pytest.mark.parametrize("N", [15, 20])
def test_the_one_call_paper_policy_keeps_daqps_workspace_from_keep_from(
    N: int, monkeypatch: pytest.MonkeyPatch
) -> None:
    """The one-call step's "paper" QP runs on the failed nominal QP's DAQP workspace from
    KEEP_FROM variables on (not below), and the closed loop's records are those of a
    controller that never keeps it, bit for bit (the paper's scenario 3, set-points cycled
    every 40 samples, 600 steps)."""
    from ltv_lstm_mpc.paper.scenarios import paper_scenarios

    model = load_model("ph_lstm_n5.npz")
    scenario = paper_scenarios(model)[2].cycled(40)
    setpoints = scenario.setpoints
    config = dataclasses.replace(scenario.config, solver="daqp", N=N, infeasibility_policy="paper")

    def loop(keeps: bool):
        monkeypatch.setattr(daqp_native, "_KEEPS", keeps)
        controller = OffsetFreeController(
            model, config, setpoint_rate_limit=scenario.setpoint_rate_limit, kernels="compiled"
        )
        work = controller.mpc._problem._sessions["nominal"].native.work
        assert work.shape[0] == (daqp_native.WORKSPACE_BYTES if keeps else 0)
        plant = scenario.make_plant(model)
        y = plant.output()
        kept = 0
        for k in range(600):
            work[:] = 0
            u = controller.step(y, setpoints[k])
            kept += work.shape[0] > 0 and work.view(np.int32)[_W_M // 4] == N  # the box QP's m
            d = scenario.disturbances[k]
            y = plant.step(u, None if np.isnan(d) else d)
        assert all(record.engine == "one-call" for record in controller.records)
        return controller.records, kept

    records, kept = loop(True)
    plain, none = loop(False)
    assert none == 0
    if N >= daqp_native.KEEP_FROM:
        assert kept >= 10
    else:
        assert kept == 0
    assert sum(not r.mpc.feasible for r in records) >= 20
    for a, b in zip(records, plain, strict=True):
        np.testing.assert_array_equal(a.u, b.u)
        _same_solutions(a.mpc, b.mpc)
