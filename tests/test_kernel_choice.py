"""The controller's kernel choice (ltv_lstm_mpc/loop/kernels.py): compiled where numba's
cache holds the kernels, else the numpy reference while a background process compiles."""

from __future__ import annotations

import json
import pickle
import subprocess
import sys
import time
import types

import numpy as np
import pytest

from ltv_lstm_mpc import (
    InvalidValueError,
    MPCConfig,
    OffsetFreeController,
    PHNeutralizationPlant,
    load_model,
    numba_support,
)
from ltv_lstm_mpc.loop import kernels, warmup
from ltv_lstm_mpc.lstm.kernel import LSTMKernel

pytestmark = pytest.mark.skipif(not numba_support.AVAILABLE, reason="needs numba")

CONFIG = MPCConfig(solver="daqp", L_d=0.1)


@pytest.fixture
def auto(monkeypatch):
    """No environment override (the suite sets LTV_LSTM_MPC_KERNEL=numba), the once-per-
    process notice not yet said."""
    monkeypatch.delenv("LTV_LSTM_MPC_KERNEL", raising=False)
    monkeypatch.setattr(numba_support, "_compile_announced", False)


def test_modes_and_the_environment(monkeypatch, auto) -> None:
    with pytest.raises(InvalidValueError, match=r"kernels must be one of .*'fast'"):
        kernels.choose_kernels(CONFIG, "fast")
    monkeypatch.setattr(kernels, "uncached", lambda dispatchers: ["condense"])
    assert kernels.choose_kernels(CONFIG, "auto") == (False, ["condense"])
    assert kernels.choose_kernels(CONFIG, "compiled") == (True, ["condense"])
    assert kernels.choose_kernels(CONFIG, "numpy") == (False, [])
    monkeypatch.setenv("LTV_LSTM_MPC_KERNEL", "numba")
    assert kernels.choose_kernels(CONFIG, "auto") == (True, ["condense"])
    monkeypatch.setenv("LTV_LSTM_MPC_KERNEL", "numpy")
    assert kernels.choose_kernels(CONFIG, "auto") == (False, [])
    monkeypatch.delenv("LTV_LSTM_MPC_KERNEL")
    monkeypatch.setattr(kernels, "uncached", lambda dispatchers: [])
    assert kernels.choose_kernels(CONFIG, "auto") == (True, [])


def _closed_loop(controller: OffsetFreeController, steps: int = 40) -> np.ndarray:
    plant = PHNeutralizationPlant()
    plant.reset()
    u = controller.step(plant.output(), np.array([7.2]))
    inputs = [u]
    for k in range(steps - 1):
        u = controller.step(plant.step(u), np.array([7.2 if k < 20 else 6.8]))
        inputs.append(u)
    return np.array(inputs)


def test_auto_runs_numpy_while_compiling_then_compiled(monkeypatch, capsys, auto) -> None:
    """Missing kernels: numpy reference, one notice, one background compilation started;
    the closed loop equals the compiled one; once cached, the next controller on the same
    model is compiled again; a kernel the caller chose is kept."""
    started: list[list[str]] = []
    monkeypatch.setattr(kernels, "uncached", lambda dispatchers: ["condense"])
    monkeypatch.setattr(
        kernels, "start_background_compile", lambda m, c, missing: started.append(missing) or True
    )
    model = load_model("ph_lstm_n5.npz")
    controller = OffsetFreeController(model, CONFIG)
    assert controller.kernels == "numpy"
    assert not controller.model.kernel.compiled and controller.model.kernel.automatic
    assert model.kernel.compiled and controller.model is not model  # the caller's: untouched
    assert started == [["condense"]]
    err = capsys.readouterr().err
    assert err.count("runs the numpy reference kernels") == 1
    assert "kernels='compiled'" in err and "ltv-lstm-mpc warmup" in err
    numpy_inputs = _closed_loop(controller)

    reference = OffsetFreeController(load_model("ph_lstm_n5.npz"), CONFIG, kernels="compiled")
    assert reference.kernels == "compiled"
    compiled_inputs = _closed_loop(reference)
    assert np.max(np.abs(numpy_inputs - compiled_inputs)) < 1e-9

    monkeypatch.setattr(kernels, "uncached", lambda dispatchers: [])
    again = OffsetFreeController(model, CONFIG)
    assert again.kernels == "compiled" and model.kernel.compiled
    assert capsys.readouterr().err == ""

    chosen = load_model("ph_lstm_n5.npz")
    chosen.kernel = LSTMKernel(chosen, compiled=False)
    assert OffsetFreeController(chosen, CONFIG).kernels == "numpy"  # the caller's choice
    assert OffsetFreeController(chosen, CONFIG, kernels="compiled").kernels == "compiled"


def test_the_callers_model_is_never_modified() -> None:
    """A controller that needs another kernel than the model's works on its own copy; the
    caller's model (and its kernel) stays as it was, and keeps computing the same."""
    model = load_model("ph_lstm_n5.npz")
    kernel = model.kernel
    x = model.equilibrium(np.array([0.1]))
    numpy = OffsetFreeController(model, CONFIG, kernels="numpy")
    assert numpy.kernels == "numpy" and not numpy.model.kernel.compiled
    assert model.kernel is kernel and numpy.model is not model
    compiled = OffsetFreeController(model, CONFIG, kernels="compiled")
    assert compiled.kernels == "compiled" and model.kernel is kernel
    np.testing.assert_array_equal(model.equilibrium(np.array([0.1])), x)


def test_a_given_mpc_keeps_the_models_kernel(monkeypatch, auto) -> None:
    from ltv_lstm_mpc import RobustMPC

    monkeypatch.setattr(kernels, "uncached", lambda dispatchers: ["condense"])
    model = load_model("ph_lstm_n5.npz")
    controller = OffsetFreeController(model, CONFIG, mpc=RobustMPC(model, CONFIG))
    assert controller.kernels == "compiled" and model.kernel.compiled


#: Compiled functions called only from other compiled functions (never from Python): they
#: compile with their caller, and are not on the kernel lists.
CALLEES = {
    "lstm_cell",
    "_exp_parts",
    "_activation",
    "_sigmoid",
    "_tanh",
    "_hessian_causal",
    "_hessian_gram",
    "_invert",
    "_lu_solve",
    "_pivot",
    "_hessian_backward",
    "_transpose_times",
    "_weight_times",
    "_equilibrium_residual",
    "insert_state",
    "expand_point",
    "terminal_norm_of_squares",
    "solver_seconds",
    # inside the one-call step (loop/compiled_step.py): its clock, the shared formulas'
    # compiled twins (certificates/compiled_tightening.py, loop/compiled_signals.py), and the
    # exact-cone feedback it also holds (mpc/native_feedback.py, solvers/socp_sqp.py)
    "_now",
    "inside_setpoint_interval",
    "output_bounds_into",
    "terminal_alpha",
    "next_e_hat",
    "limit_rate_into",
    "project_into",
    "measurement_code",
    "setpoint_code",
    "_normalize_measurement",
    "_feedback_and_update",
    "nominal_feedback",
    "cone_feedback",
    "socp_solve",
    "_cone_values",
    "cone_violation",
    "max_abs",
    # inside socp_solve (solvers/socp_sqp.py), which warm-up also calls from Python
    "_add_violated_rows",
    "_cone_value",
    "_line_search",
    "_merit_parts",
    "_take",
    "_column_product",
    "_epigraph_cones",
    "_form_products",
    "_reduced_solve",
    "_row_norms",
    "_row_values",
    "_screen",
    "_sense",
    "_subproblem",
    "_definite",
    "_cut_proof",
    "_store_cuts",
    "_reduction_proves",
    # inside the one-call feedbacks (mpc/native_feedback.py) and the failed solve's copy
    "_accept",
    "_precheck",
    "_simulate_plan",
    "_policy_plan",
    "_solve_nominal",
    "_solve_qp",
    "_write_soft_qp",
    "_write_cone_nominal",
    "_write_cone_policy",
    "_cone_qp_violation",
    "bounds_rows_violation",
    "policy_feedback",
    "cone_policy_feedback",
    "snapshot_into",
    "_put_matrix",
    "_put_vector",
    "set_objective_bound",
    "primal_tolerance",
    # inside the reference calculator's damped Newton (loop/compiled_reference.py)
    "_newton_from",
}

USED = """
import json, sys
import numba.core.registry
from ltv_lstm_mpc import MPCConfig, load_model
from ltv_lstm_mpc.loop.kernels import controller_kernels
from ltv_lstm_mpc.loop.warmup import warm_up
from ltv_lstm_mpc.numba_support import uncached
config = MPCConfig(**json.loads(sys.argv[1]))
listed = controller_kernels(config)
missing_before = uncached(listed)
warm_up(load_model("ph_lstm_n5.npz"), config)
used = sorted({
    value.__name__
    for name, module in list(sys.modules.items()) if name.startswith("ltv_lstm_mpc")
    for value in vars(module).values()
    if isinstance(value, numba.core.registry.CPUDispatcher) and value.signatures
})
print(json.dumps({
    "used": used,
    "listed": [k.__name__ for k in listed],
    "missing_before": missing_before,
    "missing_after": uncached(listed),
}))
"""

CONFIGURATIONS = [
    {"solver": "daqp"},
    {"solver": "daqp", "sqp_iterations": 2},
    {"solver": "osqp"},
    {"solver": "cvxpy:CLARABEL"},
    {"solver": "clarabel"},
    {"solver": "daqp:socp"},
]


def _used_and_listed(config: dict, environment: dict | None = None) -> dict:
    from optional_extras import require_solver

    require_solver(config["solver"])
    result = subprocess.run(
        [sys.executable, "-c", USED, json.dumps(config)],
        capture_output=True,
        text=True,
        timeout=900,
        env=environment,
    )
    assert result.returncode == 0, result.stderr[-3000:]
    return json.loads(result.stdout.strip().splitlines()[-1])


@pytest.mark.parametrize("config", CONFIGURATIONS)
def test_the_kernel_list_names_every_kernel_called(config) -> None:
    """controller_kernels(config) names every compiled function a controller with config
    calls from Python (else "auto" would choose compiled and then wait for one); checked
    in a fresh process (functions called only from compiled code load with their caller)."""
    found = _used_and_listed(config)
    assert set(found["used"]) - CALLEES <= set(found["listed"])
    assert found["missing_after"] == []


@pytest.mark.slow
@pytest.mark.parametrize(
    "config", [CONFIGURATIONS[0], CONFIGURATIONS[2], CONFIGURATIONS[4], CONFIGURATIONS[5]]
)
def test_warm_up_caches_every_listed_kernel_from_an_empty_cache(config, tmp_path) -> None:
    """From an empty numba cache, warm_up leaves every listed function cached (else
    "auto" would run numpy forever); about 30 s per configuration."""
    import os

    environment = {**os.environ, "NUMBA_CACHE_DIR": str(tmp_path), "LTV_LSTM_MPC_KERNEL": "numba"}
    found = _used_and_listed(config, environment)
    assert found["missing_before"]  # the cache was empty
    assert found["missing_after"] == []
    assert set(found["used"]) - CALLEES <= set(found["listed"])


def test_the_background_process_compiles_and_cleans_up(tmp_path, monkeypatch) -> None:
    """start_background_compile: a detached process that runs warm_up and removes its
    folder (kept, with the traceback, on a failure: tests/test_background_compile.py);
    once per set of missing kernels."""
    monkeypatch.setattr(kernels, "_started", set())
    monkeypatch.setattr(kernels.tempfile, "tempdir", str(tmp_path))
    monkeypatch.setenv("TMPDIR", str(tmp_path))
    monkeypatch.setattr(kernels.tempfile, "mkdtemp", lambda prefix: str(tmp_path / "job"))
    (tmp_path / "job").mkdir()
    model = load_model("ph_lstm_n5.npz")
    assert kernels.start_background_compile(model, CONFIG, ["condense"])
    assert not kernels.start_background_compile(model, CONFIG, ["condense"])
    deadline = time.monotonic() + 300
    while (tmp_path / "job").exists() and time.monotonic() < deadline:
        time.sleep(0.2)
    log = tmp_path / "job" / "log.txt"
    assert not (tmp_path / "job").exists(), log.read_text() if log.exists() else "no log"

    failing = tmp_path / "failing"
    failing.mkdir()
    with open(failing / "config.pickle", "wb") as handle:
        pickle.dump(CONFIG, handle)
    monkeypatch.setattr(warmup, "uncached", lambda dispatchers: ["condense"])
    warmup.compile_in_background(str(failing))  # no model.npz: fails, folder kept
    assert not failing.exists()
    assert (kernels.failure_folder() / "config.pickle").exists()


LOADED = """
import json
from ltv_lstm_mpc import MPCConfig, OffsetFreeController, load_model
from ltv_lstm_mpc.loop.kernels import controller_kernels
config = MPCConfig(solver="daqp", L_d=0.1)
controller = OffsetFreeController(load_model("ph_lstm_n5.npz"), config)
print(json.dumps({
    "kernels": controller.kernels,
    "unloaded": sorted(k.__name__ for k in controller_kernels(config) if not k.signatures),
}))
"""


def test_a_warm_cache_is_loaded_at_construction() -> None:
    """Guards against: with a warm cache, numba loaded each kernel at its first call, so the
    first steps took some 5 ms each; now the construction loads every kernel of the
    configuration (checked in a fresh process: each has its compiled version)."""
    import os

    warmup.warm_up(load_model("ph_lstm_n5.npz"), CONFIG)  # the cache is warm
    environment = dict(os.environ)
    environment.pop("LTV_LSTM_MPC_KERNEL", None)  # "auto", as a user has it
    result = subprocess.run(
        [sys.executable, "-c", LOADED], capture_output=True, text=True, env=environment
    )
    assert result.returncode == 0, result.stderr
    assert json.loads(result.stdout.strip().splitlines()[-1]) == {
        "kernels": "compiled",
        "unloaded": sorted(kernels.PREPARED_STEP_KERNELS),  # at the first prepare_next
    }


def test_warm_up_leaves_the_configuration_cached() -> None:
    seconds = warmup.warm_up(load_model("ph_lstm_n5.npz"), CONFIG)
    assert seconds > 0
    assert kernels.choose_kernels(CONFIG, "auto") == (True, [])


def test_the_warmup_command(capsys) -> None:
    from ltv_lstm_mpc.cli import main

    assert main(["warmup", "--solver", "daqp", "--N", "5"]) == 0
    out = capsys.readouterr().out
    assert "daqp: 0 kernel(s) not in the cache" in out
    assert "daqp: ready in" in out and "still missing" not in out


def test_asking_for_a_native_solver_imports_no_modelling_layer() -> None:
    """solver_info('daqp') before anything else builds the daqp entry alone (cvxpy and
    qpsolvers take about a second to import); the full registry agrees with it."""
    code = (
        "import sys\n"
        "from ltv_lstm_mpc.solvers import solver_info, available_solvers\n"
        "info = solver_info('daqp')\n"
        "print('cvxpy' in sys.modules, 'qpsolvers' in sys.modules)\n"
        "available_solvers()\n"
        "print(info == solver_info('daqp'))\n"
    )
    result = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert result.returncode == 0, result.stderr
    assert result.stdout.split() == ["False", "False", "True"]


def test_a_daqp_session_solves_alike_with_or_without_the_compiled_entry(monkeypatch) -> None:
    """Where DAQP's compiled entry point is not ready (an empty cache), the session's hot
    solve goes through daqp.solve: the same C function, the same numbers, bit for bit."""
    from ltv_lstm_mpc.solvers import DenseQP, DenseSession, daqp_native

    if not daqp_native.bound():
        pytest.skip("DAQP's C library is not bound")
    rng = np.random.default_rng(3)
    M = rng.standard_normal((4, 4))
    qp = DenseQP(
        H=M @ M.T + np.eye(4),
        f=rng.standard_normal(4),
        A=rng.standard_normal((3, 4)),
        lo=-np.ones(3),
        up=np.ones(3) * 0.2,
        lb=-np.full(4, 0.5),
        ub=np.full(4, 0.5),
    )
    ready = DenseSession("daqp", tolerance=1e-9)
    assert ready._backend._native is not None
    monkeypatch.setattr(daqp_native, "ready", lambda: False)
    python_only = DenseSession("daqp", tolerance=1e-9)
    assert python_only._backend._native is None
    first, second = ready.solve_point(qp), python_only.solve_point(qp)
    assert first[0] == second[0] and first[2] == second[2]
    assert np.array_equal(first[1], second[1])
    assert python_only.native is not None  # compiled callers still bind it


def test_a_helper_not_ready_runs_its_python_loops(monkeypatch) -> None:
    """CompiledOrPython: the compiled helper where ready, else its py_func (the same
    numbers); compile_on_demand (a controller on compiled kernels) makes every helper ready."""
    from ltv_lstm_mpc.solvers import _compiled

    x, lb, ub = np.array([0.5, -2.0]), -np.ones(2), np.ones(2)
    A, lo, up = np.array([[1.0, 1.0]]), np.array([-1.0]), np.array([0.2])
    monkeypatch.setattr(_compiled, "ready", lambda dispatchers: False)
    python_loops = _compiled.CompiledOrPython(_compiled.bounds_rows_violation)
    assert python_loops(x, lb, ub, A, lo, up) == pytest.approx(1.0, abs=1e-15)
    assert python_loops._call is _compiled.bounds_rows_violation.py_func
    monkeypatch.setattr(_compiled, "ready", lambda dispatchers: True)
    compiled = _compiled.CompiledOrPython(_compiled.bounds_rows_violation)
    assert compiled(x, lb, ub, A, lo, up) == python_loops(x, lb, ub, A, lo, up)
    assert compiled._call is _compiled.bounds_rows_violation
    monkeypatch.setattr(numba_support, "_compile_on_demand", False)
    monkeypatch.setattr(numba_support, "uncached", lambda dispatchers: ["x"])
    # a helper neither compiled in this process (no signatures, whatever ran before) nor
    # held by the cache
    not_compiled = types.SimpleNamespace(signatures=[])
    assert not numba_support.ready([not_compiled])
    numba_support.compile_on_demand()
    assert numba_support.ready([not_compiled])
