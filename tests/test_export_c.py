"""The C99 export of the LSTM model, observer and reference calculator
(ltv_lstm_mpc/export/c_model.py): it
compiles warning-free under the strict flags with every C compiler installed, equals the
compiled kernels to rounding, allocates nothing, and runs clean under AddressSanitizer and
UndefinedBehaviorSanitizer. Skipped where no C compiler is installed."""

from __future__ import annotations

import ctypes
import shutil
import subprocess
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from ltv_lstm_mpc import MPCConfig, Observer, ObserverGains, OffsetFreeController
from ltv_lstm_mpc.exceptions import InvalidValueError
from ltv_lstm_mpc.export import export_model_c
from ltv_lstm_mpc.lstm.shipped import load_model

COMPILERS = [name for name in ("gcc", "clang") if shutil.which(name)]
STRICT = ["-std=c99", "-O2", "-Wall", "-Wextra", "-Wpedantic", "-Werror"]
MODELS = ("ph_lstm_n5.npz", "quadtank_lstm_n8.npz", "example_delta_iss_n3.npz")

needs_compiler = pytest.mark.skipif(not COMPILERS, reason="no C compiler (gcc or clang)")

_DOUBLE_P = np.ctypeslib.ndpointer(dtype=np.float64, flags="C_CONTIGUOUS")


def _build(source: Path, compiler: str, out: Path, extra: tuple[str, ...] = ()) -> Path:
    """Compile ``source`` into a shared library with the strict flags (errors shown)."""
    library = out / f"lib{source.stem}_{compiler}.so"
    command = [compiler, *STRICT, *extra, "-fPIC", "-shared", "-o", str(library), str(source)]
    done = subprocess.run([*command, "-lm"], capture_output=True, text=True)
    assert done.returncode == 0, f"{' '.join(command)}\n{done.stderr}"
    return library


def _load(library: Path, prefix: str, observer: bool) -> Any:
    lib = ctypes.CDLL(str(library))
    ws = ctypes.c_void_p
    signatures = {
        "step": [ws, _DOUBLE_P, _DOUBLE_P, _DOUBLE_P],
        "rollout": [ws, _DOUBLE_P, _DOUBLE_P, ctypes.c_int, _DOUBLE_P],
        "jacobian": [ws, _DOUBLE_P, _DOUBLE_P, _DOUBLE_P, _DOUBLE_P, _DOUBLE_P],
        "output": [_DOUBLE_P, _DOUBLE_P],
    }
    if observer:
        signatures["observer_update"] = [ws] + [_DOUBLE_P] * 6
    for name, argtypes in signatures.items():
        function = getattr(lib, f"{prefix}_{name}")  # (lib[name] would be a new object)
        function.argtypes, function.restype = argtypes, None
    return lib


def _controller(name: str) -> OffsetFreeController:
    model = load_model(name)
    return OffsetFreeController(model, MPCConfig(solver="daqp", N=5), kernels="compiled")


def _close(actual: Any, expected: Any, rtol: float = 1e-13) -> None:
    scale = max(1.0, float(np.abs(expected).max()))
    assert np.abs(actual - expected).max() <= rtol * scale, np.abs(actual - expected).max()


@needs_compiler
@pytest.mark.parametrize("compiler", COMPILERS)
@pytest.mark.parametrize("name", MODELS)
def test_the_c_model_equals_the_compiled_kernels(name: str, compiler: str, tmp_path: Path) -> None:
    """Rollout, Jacobians, output map and observer update of the generated C equal the
    library's (compiled kernels) to 1e-13, on random states, inputs and measurements
    around the operating range, with the observer's gate injection where it has one."""
    controller = _controller(name)
    model, observer = controller.model, controller.observer
    exported = export_model_c(model, tmp_path, observer=observer, prefix="lstm_c")
    lib = _load(_build(exported.source, compiler, tmp_path), "lstm_c", observer=True)
    workspace = ctypes.create_string_buffer(exported.workspace_bytes)
    n, m, p = model.n, model.m, model.p
    rng = np.random.default_rng(0)
    K = 30
    for _ in range(5):
        x0 = rng.uniform(-0.8, 0.8, 2 * n)
        u = rng.uniform(-1.0, 1.0, (K, m))
        states = np.empty((K + 1, 2 * n))
        lib.lstm_c_rollout(workspace, x0, np.ascontiguousarray(u), K, states)
        expected, _ = model.simulate(x0, u)
        _close(states, expected)
        A, B = model.jacobians(x0, u[0])
        x_next, A_c, B_c = np.empty(2 * n), np.empty((2 * n, 2 * n)), np.empty((2 * n, m))
        lib.lstm_c_jacobian(workspace, x0, u[0].copy(), x_next, A_c, B_c)
        _close(x_next, model.step(x0, u[0]))
        _close(A_c, A)
        _close(B_c, B)
        y = np.empty(p)
        lib.lstm_c_output(x0, y)
        _close(y, model.output(x0))
        d_hat = rng.uniform(-0.5, 0.5, p) * observer.d_max
        y_meas = model.output(x0) + rng.normal(0.0, 0.05, p)
        observer.reset(x0, d_hat)
        observer.update(y_meas, u[0].copy())
        x_out, d_out = np.empty(2 * n), np.empty(p)
        lib.lstm_c_observer_update(workspace, x0, d_hat, y_meas, u[0].copy(), x_out, d_out)
        _close(x_out, observer.x_hat)
        _close(d_out, observer.d_hat)
    far = model.output(x0) + 10.0  # a measurement far off: d_hat saturates at d_max
    lib.lstm_c_observer_update(workspace, x0, d_hat, far, u[0].copy(), x_out, d_out)
    observer.reset(x0, d_hat)
    observer.update(far, u[0].copy())
    _close(d_out, observer.d_hat)
    assert np.all(np.abs(d_out) <= observer.d_max)


def _reference_targets(reference: Any, p: int) -> list[Any]:
    """Targets y0 - d_hat for the reference calculator: small steps (the warm chord),
    jumps across the reachable range (the damped Newton with restarts), one beyond it (no
    admissible equilibrium: the stale reference) and random ones."""
    low, high = reference.reachable_output_range
    mid = (low + high) / 2
    rng = np.random.default_rng(0)
    targets = [mid + 0.01 * (k + 1) * (high - mid) for k in range(10)]
    targets += [low + 0.9 * (high - low), high + 0.2 * (high - low) + 0.1, mid]
    targets += [low + 0.05 * (high - low)]
    targets += [low + rng.uniform(0.0, 1.0, p) * (high - low) for _ in range(20)]
    return [np.ascontiguousarray(t, dtype=np.float64) for t in targets]


@needs_compiler
@pytest.mark.parametrize("compiler", COMPILERS)
@pytest.mark.parametrize("name", MODELS)
def test_the_c_reference_calculator_equals_the_library(
    name: str, compiler: str, tmp_path: Path
) -> None:
    """eq. (reference_calculation) in C (warm chord, damped Newton with restarts, the
    stale reference) gives the library's equilibria to 1e-12 over a sequence of targets
    that takes every path, the same status where none is admissible, and its structs
    have the sizes the export reports (sizeof, compiled)."""
    controller = _controller(name)
    model, reference = controller.model, controller.reference
    reference.strict = False  # an unreachable target gives its flagged solution
    exported = export_model_c(model, tmp_path, reference=reference, prefix="ref_c")
    sizes = tmp_path / "sizes.c"
    sizes.write_text(
        '#include "ref_c.h"\n#include <stdio.h>\nint main(void) { printf("%lu %lu\\n", '
        "(unsigned long)sizeof(ref_c_workspace), (unsigned long)sizeof(ref_c_reference_state));"
        " return 0; }\n"
    )
    binary = tmp_path / "sizes"
    subprocess.run([compiler, *STRICT, "-I", str(tmp_path), "-o", str(binary), str(sizes)],
                   check=True)  # fmt: skip
    measured = subprocess.run([str(binary)], capture_output=True, text=True, check=True).stdout
    assert measured.split() == [str(exported.workspace_bytes), str(exported.reference_state_bytes)]
    lib = ctypes.CDLL(str(_build(exported.source, compiler, tmp_path)))
    lib.ref_c_reference_start.argtypes = [ctypes.c_void_p, _DOUBLE_P, _DOUBLE_P]
    lib.ref_c_reference.argtypes = [ctypes.c_void_p, ctypes.c_void_p, _DOUBLE_P, _DOUBLE_P,
                                    ctypes.POINTER(ctypes.c_double)]  # fmt: skip
    lib.ref_c_reference.restype = ctypes.c_int
    workspace = ctypes.create_string_buffer(exported.workspace_bytes)
    state = ctypes.create_string_buffer(exported.reference_state_bytes)
    p, size = model.p, 2 * model.n + model.m
    zero = np.zeros(p)
    low, high = reference.reachable_output_range
    start = np.ascontiguousarray((low + high) / 2)
    solution = reference.solve_arrays(start.copy(), zero)
    last = np.concatenate([solution.x_bar, solution.u_bar])
    lib.ref_c_reference_start(state, last, start)
    # the state's layout (double): last_z (size), last_target (p), inverse (size, size), int
    c_inverse = np.frombuffer(state, np.float64, size * size, 8 * (size + p)).reshape(size, size)

    def c_inverse_valid() -> bool:
        return int(np.frombuffer(state, np.intc, 1, 8 * (size + p + size * size))[0]) == 1

    statuses, inverses = set(), 0
    for target in _reference_targets(reference, p):
        fallbacks = reference.counts["fallbacks"]
        solution = reference.solve_arrays(target.copy(), zero)
        restarted = reference.counts["fallbacks"] > fallbacks  # the warm chord did not do
        admissible = solution.converged and solution.u_admissible
        expected = np.concatenate([solution.x_bar, solution.u_bar]) if admissible else last
        last = expected
        z, residual = np.empty(size), ctypes.c_double()
        status = lib.ref_c_reference(workspace, state, target, z, ctypes.byref(residual))
        statuses.add(status)
        assert status == (2 if not admissible else 1 if restarted else 0), (target, status)
        _close(z, expected, rtol=1e-12)
        if admissible:
            assert abs(residual.value - solution.residual) <= 1e-12
        kept = reference.warm_start()
        if kept is not None and kept.jinv_valid and c_inverse_valid():
            inverses += 1  # the chord's kept inverse Jacobian (its Gauss-Jordan), both sides
            _close(c_inverse, reference.chord_state().jinv, rtol=1e-10)
    assert {0, 2} <= statuses  # the warm chord and the stale reference ran
    assert inverses >= 10
    if name != "example_delta_iss_n3.npz":
        assert 1 in statuses  # and the damped Newton with restarts


@needs_compiler
@pytest.mark.parametrize("compiler", COMPILERS)
@pytest.mark.parametrize(("name", "N"), [(name, 5) for name in MODELS] + [(MODELS[0], 20)])
def test_the_c_tightening_and_signals_equal_the_library(
    name: str, N: int, compiler: str, tmp_path: Path
) -> None:
    """The tightened output bounds, alpha_k, e_tilde, the set-point interval test and the
    e_hat recursion of the certificate, the rate limiter and the exit gate in C give the
    library's numbers (TighteningCertificate, loop/signals.py) to 1e-15, set-points
    inside and outside the interval included."""
    from ltv_lstm_mpc.loop.signals import limit_rate, project_onto_box

    model = load_model(name)
    controller = OffsetFreeController(model, MPCConfig(solver="daqp", N=N), kernels="compiled")
    certificate = controller.mpc.tightening
    exported = export_model_c(model, tmp_path, tightening=certificate, prefix="ti")
    lib = ctypes.CDLL(str(_build(exported.source, compiler, tmp_path)))
    lib.ti_output_bounds.argtypes = [ctypes.c_double, _DOUBLE_P, _DOUBLE_P]
    for function in ("ti_alpha", "ti_setpoint_inside"):
        getattr(lib, function).argtypes = [_DOUBLE_P, ctypes.c_double]
    lib.ti_alpha.restype = ctypes.c_double
    lib.ti_setpoint_inside.restype = ctypes.c_int
    for function in ("ti_e_tilde", "ti_next_e_hat"):
        getattr(lib, function).argtypes = [ctypes.c_double]
        getattr(lib, function).restype = ctypes.c_double
    lib.ti_limit_rate.argtypes = [_DOUBLE_P, _DOUBLE_P, ctypes.c_double]
    lib.ti_gate.argtypes = [_DOUBLE_P, ctypes.c_double]
    lib.ti_gate.restype = ctypes.c_double
    p, m = model.p, model.m
    rng = np.random.default_rng(2)
    inside, draws = 0, 0
    for e_hat in (0.0, float(certificate.e_inf) / 2, float(certificate.e_inf) * 3, 0.05):
        lower, upper = np.empty((N, p)), np.empty((N, p))
        lib.ti_output_bounds(e_hat, lower, upper)
        expected_lower, expected_upper = certificate.output_bounds(e_hat)
        _close(lower, expected_lower, rtol=1e-15)
        _close(upper, expected_upper, rtol=1e-15)
        assert lib.ti_e_tilde(e_hat) == certificate.e_tilde(e_hat)
        assert abs(lib.ti_next_e_hat(e_hat) - certificate.next_e_hat(e_hat)) <= 1e-15
        low, high = certificate.setpoint_interval(e_hat)
        for _ in range(20):
            y0 = np.ascontiguousarray(rng.uniform(-1.0, 1.0, p))
            assert abs(lib.ti_alpha(y0, e_hat) - certificate.alpha(y0, e_hat)) <= 1e-15
            expected_inside = bool(np.all((low < y0) & (y0 < high)))
            assert bool(lib.ti_setpoint_inside(y0, e_hat)) == expected_inside
            inside, draws = inside + expected_inside, draws + 1
    assert 0 < inside < draws  # set-points inside and outside the interval were tried
    for _ in range(20):
        target, previous = rng.uniform(-1.0, 1.0, p), rng.uniform(-1.0, 1.0, p)
        limited = np.ascontiguousarray(target.copy())
        lib.ti_limit_rate(limited, np.ascontiguousarray(previous), 0.1)
        _close(limited, limit_rate(target, previous, 0.1), rtol=0.0)
        u = np.ascontiguousarray(rng.uniform(-2.0, 2.0, m))
        gated, moved = project_onto_box(u.copy(), 1.0)
        assert lib.ti_gate(u, 1.0) == moved
        _close(u, gated, rtol=0.0)
    # NaN as the compiled twins treat it (Python's min/max): a NaN input stays NaN, a NaN
    # limit does not limit, and the gate reports no move for it
    from ltv_lstm_mpc.loop.compiled_signals import limit_rate_into, project_into

    for value in (np.nan, 0.3, -5.0):
        u = np.full(m, value)
        expected_u = u.copy()
        expected_moved = project_into(expected_u, 1.0)
        moved = lib.ti_gate(u, 1.0)
        assert np.array_equal(u, expected_u, equal_nan=True)
        assert moved == expected_moved or (np.isnan(moved) and np.isnan(expected_moved))
        for limit in (0.1, np.nan):
            y0, before = np.full(p, value), np.full(p, 0.2)
            expected_y0, requested = y0.copy(), np.empty(p)
            limit_rate_into(expected_y0, before, limit, requested)
            lib.ti_limit_rate(y0, before, limit)
            assert np.array_equal(y0, expected_y0, equal_nan=True)
    assert np.isnan(lib.ti_e_tilde(np.nan)) == np.isnan(max(np.nan, certificate.e_inf))


@needs_compiler
@pytest.mark.parametrize("name", MODELS)
def test_the_c_observer_with_gate_injection_equals_the_kernel(name: str, tmp_path: Path) -> None:
    """With gains L_f, L_i, L_o that inject the innovation into the gates (not the
    certified defaults, which inject none: Remark 3), the generated observer update
    equals :meth:`Observer.update` to 1e-13."""
    model = load_model(name)
    n, m, p = model.n, model.m, model.p
    rng = np.random.default_rng(1)
    gains = ObserverGains(
        rng.normal(0.0, 0.2, (n, p)), rng.normal(0.0, 0.2, (n, p)),
        rng.normal(0.0, 0.2, (n, p)), 0.3 * np.eye(p),
    )  # fmt: skip
    observer = Observer(model, gains, d_max=0.2)
    exported = export_model_c(model, tmp_path, observer=observer, prefix="inj")
    assert "L_gates[4 * N][P] =" in exported.source.read_text()
    lib = _load(_build(exported.source, COMPILERS[0], tmp_path), "inj", observer=True)
    workspace = ctypes.create_string_buffer(exported.workspace_bytes)
    for _ in range(5):
        x0 = rng.uniform(-0.8, 0.8, 2 * n)
        d_hat = rng.uniform(-0.1, 0.1, p)
        u = rng.uniform(-1.0, 1.0, m)
        y = model.output(x0) + rng.normal(0.0, 0.1, p)
        x_out, d_out = np.empty(2 * n), np.empty(p)
        lib.inj_observer_update(workspace, x0, d_hat, y, u, x_out, d_out)
        observer.reset(x0, d_hat)
        observer.update(y, u)
        _close(x_out, observer.x_hat)
        _close(d_out, observer.d_hat)


@needs_compiler
def test_the_c_model_allocates_nothing_and_runs_clean_under_sanitizers(tmp_path: Path) -> None:
    """No malloc/free/printf among the library's undefined symbols (``nm``); a driver
    that runs the rollout, Jacobians, reference calculator (an unreachable target
    included) and observer (a NaN measurement included) under
    ``-fsanitize=address,undefined`` exits 0 with no report, and prints the numbers the
    library computes."""
    controller = _controller("quadtank_lstm_n8.npz")
    model = controller.model
    exported = export_model_c(
        model, tmp_path, observer=controller.observer, reference=controller.reference,
        tightening=controller.mpc.tightening, prefix="qt",
    )  # fmt: skip
    compiler = COMPILERS[0]
    library = _build(exported.source, compiler, tmp_path)
    if shutil.which("nm"):
        undefined = subprocess.run(
            ["nm", "-u", str(library)], capture_output=True, text=True, check=True
        ).stdout
        for name in ("malloc", "calloc", "realloc", "free", "printf", "puts", "fopen"):
            assert f" {name}" not in undefined and f" {name}@" not in undefined, undefined
    n, m = model.n, model.m
    driver = tmp_path / "driver.c"
    driver.write_text(
        """#include "qt.h"
#include <math.h>
#include <stdio.h>
int main(void) {
    qt_workspace w;
    double x[2 * QT_N], u[QT_M], y[QT_P], d[QT_P], xs[6 * 2 * QT_N], us[5 * QT_M];
    double xn[2 * QT_N], A[4 * QT_N * QT_N], B[2 * QT_N * QT_M], xo[2 * QT_N], dout[QT_P];
    int q;
    for (q = 0; q < 2 * QT_N; ++q) x[q] = 0.1 * (q % 5) - 0.2;
    for (q = 0; q < QT_M; ++q) u[q] = 0.3;
    for (q = 0; q < 5 * QT_M; ++q) us[q] = 0.05 * q - 0.1;
    for (q = 0; q < QT_P; ++q) { y[q] = 0.2; d[q] = 0.0; }
    qt_rollout(&w, x, us, 5, xs);
    qt_jacobian(&w, x, u, xn, A, B);
    qt_observer_update(&w, x, d, y, u, xo, dout);
    for (q = 0; q < 6 * 2 * QT_N; ++q) printf("%a\\n", xs[q]);
    for (q = 0; q < 4 * QT_N * QT_N; ++q) printf("%a\\n", A[q]);
    {
        qt_reference_state s;
        double z[2 * QT_N + QT_M], target[QT_P], residual;
        for (q = 0; q < 2 * QT_N; ++q) z[q] = xn[q];
        for (q = 0; q < QT_M; ++q) z[2 * QT_N + q] = u[q];
        qt_output(xn, target);
        qt_reference_start(&s, z, target);
        for (q = 0; q < QT_P; ++q) target[q] += 0.3;
        (void)qt_reference(&w, &s, target, z, &residual);
        for (q = 0; q < QT_P; ++q) target[q] = 50.0; /* unreachable: the stale reference */
        printf("%d\\n", qt_reference(&w, &s, target, z, &residual));
    }
    {
        double lower[QT_HORIZON][QT_P], upper[QT_HORIZON][QT_P], y0[QT_P] = {0.0};
        qt_output_bounds(0.01, lower, upper);
        (void)qt_alpha(y0, 0.01);
        (void)qt_setpoint_inside(y0, 0.01);
        qt_limit_rate(y0, lower[0], 0.1);
        (void)qt_gate(u, 0.5);
    }
    y[0] = NAN;
    qt_observer_update(&w, x, d, y, u, xo, dout);
    printf("%d\\n", isnan(dout[0]) ? 1 : 0);
    return 0;
}
"""
    )
    binary = tmp_path / "driver"
    sanitize = ["-fsanitize=address,undefined", "-fno-sanitize-recover=all", "-g"]
    command = [compiler, *STRICT[:1], "-O1", *sanitize, "-I", str(tmp_path), "-o", str(binary),
               str(driver), str(exported.source), "-lm"]  # fmt: skip
    built = subprocess.run(command, capture_output=True, text=True)
    if built.returncode != 0 and "asan" in built.stderr.lower():
        pytest.skip(f"{compiler} has no sanitizer runtime here: {built.stderr[-300:]}")
    assert built.returncode == 0, built.stderr
    ran = subprocess.run([str(binary)], capture_output=True, text=True, timeout=60)
    assert ran.returncode == 0, ran.stderr
    assert "runtime error" not in ran.stderr and "AddressSanitizer" not in ran.stderr
    values = [float.fromhex(v) for v in ran.stdout.split()[:-2]]
    x = np.array([0.1 * (q % 5) - 0.2 for q in range(2 * n)])
    us = np.array([0.05 * q - 0.1 for q in range(5 * m)]).reshape(5, m)
    states = np.array(values[: 6 * 2 * n]).reshape(6, 2 * n)
    _close(states, model.simulate(x, us)[0])
    A, _ = model.jacobians(x, np.full(m, 0.3))
    _close(np.array(values[6 * 2 * n :]).reshape(2 * n, 2 * n), A)
    assert ran.stdout.split()[-2] == "2"  # the unreachable target: the stale reference
    assert ran.stdout.split()[-1] == "1"  # a NaN measurement gives a NaN estimate: no UB


def test_export_refuses_a_bad_prefix_and_a_foreign_observer(tmp_path: Path) -> None:
    """The prefix must be a C identifier, the observer one of the exported model: each
    error names the value and the fix."""
    model = load_model("ph_lstm_n5.npz")
    with pytest.raises(InvalidValueError, match="not a C identifier"):
        export_model_c(model, tmp_path, prefix="3-model")
    other = load_model("example_delta_iss_n3.npz")
    gains = ObserverGains(
        np.zeros((other.n, other.p)), np.zeros((other.n, other.p)),
        np.zeros((other.n, other.p)), 0.1 * np.eye(other.p),
    )  # fmt: skip
    with pytest.raises(InvalidValueError, match="another model"):
        export_model_c(model, tmp_path, observer=Observer(other, gains, d_max=0.1))
    with pytest.raises(InvalidValueError, match=r"must be an ltv_lstm_mpc\.Observer"):
        export_model_c(model, tmp_path, observer="observer")


@needs_compiler
def test_the_export_refuses_fast_math(tmp_path: Path) -> None:
    """-ffast-math would remove the NaN checks: the generated source stops the build."""
    model = load_model("ph_lstm_n5.npz")
    exported = export_model_c(model, tmp_path, prefix="fm")
    command = [COMPILERS[0], "-std=c99", "-ffast-math", "-c", "-o", str(tmp_path / "fm.o"),
               str(exported.source)]  # fmt: skip
    done = subprocess.run(command, capture_output=True, text=True)
    assert done.returncode != 0 and "-ffast-math" in done.stderr
