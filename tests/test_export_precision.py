"""The C export in single precision (``precision="single"``, ``export-c --float``): float
code throughout (no promotion to double in the controller's source), within the rounding
bound of ``ltv_lstm_mpc.export.precision`` on the model's step and the observer update,
the library's statuses and inputs to float's accuracy on a closed loop, clean under the
sanitizers, and refused where the certificates' margins do not cover float's rounding.
Skipped where no C compiler is installed."""

from __future__ import annotations

import ctypes
import shutil
import subprocess
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from test_export_step import closed_loop  # (scenario 3's library loop)

from ltv_lstm_mpc import MPCConfig, OffsetFreeController, simulate
from ltv_lstm_mpc.exceptions import InvalidValueError
from ltv_lstm_mpc.export import export_model_c
from ltv_lstm_mpc.export.c_model import _single_precision
from ltv_lstm_mpc.export.precision import (
    ACTIVATION_ERROR,
    UNIT_ROUNDOFF,
    _cell_rounding,
    _gamma,
    single_precision_margins,
)
from ltv_lstm_mpc.export.sil import (
    MPC_STATUS_NAMES,
    POLICY_NAMES,
    CController,
    compile_controller,
    daqp_flags,
    daqp_sources,
)
from ltv_lstm_mpc.lstm.shipped import load_model
from ltv_lstm_mpc.paper.scenarios import paper_scenarios

pytest.importorskip("daqp")

COMPILERS = [name for name in ("gcc", "clang") if shutil.which(name)]
STRICT = ["-std=c99", "-O2", "-Wall", "-Wextra", "-Wpedantic", "-Werror"]
#: No computation of the controller's own source in double, no silent narrowing.
FLOAT_ONLY = ["-Wdouble-promotion", "-Wfloat-conversion"]
needs_compiler = pytest.mark.skipif(not COMPILERS, reason="no C compiler (gcc or clang)")
_FLOAT_P = np.ctypeslib.ndpointer(dtype=np.float32, flags="C_CONTIGUOUS")


def test_literals_become_float_literals_outside_comments() -> None:
    source = (
        '/* 0.5 stays */ x = 0.5 * y + 1e-12 - 2.0e+3; // 3.0 stays\n#error "1.5"\n'
        "k = 0x4B400000L + 12;"
    )
    out = _single_precision(source)
    assert out == (
        '/* 0.5 stays */ x = 0.5f * y + 1e-12f - 2000.0f; // 3.0 stays\n#error "1.5"\n'
        "k = 0x4B400000L + 12;"
    )
    assert _single_precision('c = \'"\'; x = 2.5; s = "1.5";') == 'c = \'"\'; x = 2.5f; s = "1.5";'
    with pytest.raises(InvalidValueError, match="beyond the range of a float"):
        _single_precision("x = 1e100;")
    with pytest.raises(InvalidValueError, match="below the range of a float"):
        _single_precision("x = 1e-50;")
    with pytest.raises(InvalidValueError, match=r"hexadecimal floating constant 0x1\.8p3"):
        _single_precision("x = 0x1.8p3;")


def test_export_rejects_an_unknown_precision(tmp_path: Path) -> None:
    with pytest.raises(InvalidValueError, match="precision='half'"):
        export_model_c(load_model("ph_lstm_n5.npz"), tmp_path, precision="half")


def _controller(name: str = "ph_lstm_n5.npz", **config: Any) -> OffsetFreeController:
    return OffsetFreeController(
        load_model(name), MPCConfig(solver="daqp", N=5, **config), kernels="numpy",
        one_call_step=False,
    )  # fmt: skip


@needs_compiler
@pytest.mark.parametrize("compiler", COMPILERS)
def test_the_single_precision_source_computes_in_float_only(compiler: str, tmp_path: Path) -> None:
    """The controller's source compiles with -Wdouble-promotion -Wfloat-conversion as
    errors (no double arithmetic, no silent narrowing), DAQP with DAQP_SINGLE_PRECISION;
    the workspace's size is the one reported."""
    controller = _controller()
    exported = export_model_c(
        controller.model, tmp_path, controller=controller, prefix="fl", precision="single"
    )
    header = exported.header.read_text()
    assert "typedef float fl_real;" in header and "#define FL_SINGLE 1" in header
    assert "DAQP_SINGLE_PRECISION" in (tmp_path / "daqp" / "no_heap.h").read_text()
    probe = tmp_path / "probe.c"
    probe.write_text(
        '#include <stdio.h>\n#include "fl.h"\n'
        'int main(void) { printf("%zu\\n", sizeof(fl_workspace)); return 0; }\n'
    )
    done = subprocess.run(
        [compiler, *STRICT, *FLOAT_ONLY, *daqp_flags(tmp_path), "-c", "-o",
         str(tmp_path / "fl.o"), str(exported.source)],
        capture_output=True, text=True,
    )  # fmt: skip
    assert done.returncode == 0, done.stderr[-3000:]
    done = subprocess.run(
        [compiler, *STRICT, "-I", str(tmp_path), "-o", str(tmp_path / "probe"), str(probe)],
        capture_output=True, text=True,
    )  # fmt: skip
    assert done.returncode == 0, done.stderr[-3000:]
    size = subprocess.run([str(tmp_path / "probe")], capture_output=True, text=True).stdout
    assert int(size) == exported.workspace_bytes


def _load_model_library(source: Path, compiler: str, folder: Path) -> Any:
    library = folder / f"lib{source.stem}.so"
    command = [compiler, *STRICT, *FLOAT_ONLY, "-fPIC", "-shared", "-o", str(library),
               str(source), "-lm"]  # fmt: skip
    done = subprocess.run(command, capture_output=True, text=True)
    assert done.returncode == 0, done.stderr[-3000:]
    return ctypes.CDLL(str(library))


@needs_compiler
@pytest.mark.parametrize("name", ["ph_lstm_n5.npz", "quadtank_lstm_n8.npz"])
def test_the_float_step_and_observer_stay_within_the_rounding_bound(
    name: str, tmp_path: Path
) -> None:
    """On random points of the certified sets (|h| <= 1, |u| <= u_max, |c| within the
    invariant set's bound, |d_hat| <= d_max, plausible measurements), the float cell and
    observer update differ from the double ones at the same (float) point by at most
    the bound of ``ltv_lstm_mpc.export.precision``, unit by unit; the bound is not loose
    by more than 10^4."""
    controller = _controller(name)
    model, observer = controller.model, controller.observer
    certification = controller.certification
    n, m, p = model.n, model.m, model.p
    exported = export_model_c(model, tmp_path, observer=observer, prefix="fm", precision="single")
    lib = _load_model_library(exported.source, COMPILERS[0], tmp_path)
    lib.fm_step.argtypes = [ctypes.c_void_p, _FLOAT_P, _FLOAT_P, _FLOAT_P]
    lib.fm_observer_update.argtypes = [ctypes.c_void_p] + [_FLOAT_P] * 6
    workspace = ctypes.create_string_buffer(exported.workspace_bytes)
    # the bounds of one step (prediction) and one observer update
    WU = np.abs(model.kernel.WU)
    z_bound = np.concatenate([np.ones(n), np.ones(m), [1.0]])
    c_bound = float(certification.delta_iss.c_bound)
    step_c, step_h = _cell_rounding(_gamma(n + m + 1) * (WU @ z_bound), n, c_bound)
    margins = single_precision_margins(controller, 1e-4)
    rng = np.random.default_rng(3)
    worst_c = worst_h = worst_obs = 0.0
    for _ in range(400):
        x = np.concatenate([
            rng.uniform(-c_bound, c_bound, n), rng.uniform(-1.0, 1.0, n)
        ]).astype(np.float32)  # fmt: skip
        u = rng.uniform(-1.0, 1.0, m).astype(np.float32)
        out = np.empty(2 * n, np.float32)
        lib.fm_step(workspace, x, u, out)
        exact = model.step(x.astype(np.float64), u.astype(np.float64))
        dc, dh = np.abs(out[:n] - exact[:n]), np.abs(out[n:] - exact[n:])
        assert np.all(dc <= step_c) and np.all(dh <= step_h)
        worst_c, worst_h = (
            max(worst_c, float(np.max(dc / step_c))),
            max(worst_h, float(np.max(dh / step_h))),
        )
        d_hat = rng.uniform(-observer.d_max, observer.d_max, p).astype(np.float32)
        y = rng.uniform(-3.0, 3.0, p).astype(np.float32)
        x_out, d_out = np.empty(2 * n, np.float32), np.empty(p, np.float32)
        lib.fm_observer_update(workspace, x, d_hat, y, u, x_out, d_out)
        observer.reset(x.astype(np.float64), d_hat.astype(np.float64))
        observer.update(y.astype(np.float64), u.astype(np.float64))
        errors = (
            np.linalg.norm(x_out[:n] - observer.x_hat[:n]),
            np.linalg.norm(x_out[n:] - observer.x_hat[n:]),
            np.linalg.norm(d_out - observer.d_hat),
        )
        bounds = (margins.delta_c, margins.delta_h, margins.delta_d)
        assert all(e <= b for e, b in zip(errors, bounds, strict=True)), (errors, bounds)
        worst_obs = max(worst_obs, max(e / b for e, b in zip(errors, bounds, strict=True)))
    assert min(worst_c, worst_h, worst_obs) > 1e-4, (worst_c, worst_h, worst_obs)


def test_the_activation_error_bound_covers_the_float_activations() -> None:
    """The float sigmoid and tanh of ``model.c.in`` (their exp in float, emulated step by
    step in numpy's IEEE float32) err by less than :data:`ACTIVATION_ERROR`."""
    import math

    f = np.float32
    x = np.concatenate([
        np.linspace(-30.0, 30.0, 400_001),
        np.sign(np.sin(np.arange(200_000))) * np.exp(np.linspace(-40.0, 3.5, 200_000)),
    ]).astype(np.float32)  # fmt: skip

    def exp_parts(v: Any) -> tuple[Any, Any]:
        v = np.clip(v, f(-87.0), f(87.0))
        exponent = (v * f(1.44269504088896341) + f(256.5)).astype(np.int32) - 256
        k = exponent.astype(np.float32)
        r = (v - k * f(0.693145751953125)) - k * f(1.42860682030941723212e-06)
        c = [f(1.0 / math.factorial(j)) for j in range(8)]
        t = c[7] * r + c[6]
        for j in (5, 4, 3, 2):
            t = t * r + c[j]
        return np.ldexp(f(1.0), exponent).astype(np.float32), (t * r) * r + r

    s, q = exp_parts(-x)
    sigmoid = f(1.0) / (f(1.0) + (s + s * q))
    s, q = exp_parts(f(2.0) * x)
    m = (s - f(1.0)) + s * q
    tanh = np.copysign(m / (m + f(2.0)), x)
    assert sigmoid.dtype == tanh.dtype == np.float32
    xd = x.astype(np.float64)
    err_s = np.max(np.abs(sigmoid - 1.0 / (1.0 + np.exp(-xd))))
    err_t = np.max(np.abs(tanh - np.tanh(xd)))
    assert max(err_s, err_t) <= ACTIVATION_ERROR
    assert max(err_s, err_t) > UNIT_ROUNDOFF / 2  # (float's, not double's)


@needs_compiler
def test_the_float_step_follows_the_library_on_scenario_3(tmp_path: Path) -> None:
    """The paper's scenario 3 (set-point jumps, infeasible instants with the policy), 600
    steps replayed through the float controller step: the library's MPC statuses and
    policies on every step, inputs to 1e-4 (relative; measured 5e-6 over 2400 steps)."""
    controller, sim = closed_loop("ph", 5, 600)
    exported = export_model_c(
        controller.model, tmp_path, controller=controller, prefix="fs", precision="single"
    )
    c = CController(compile_controller(exported), exported)
    worst, policies = 0.0, set()
    e_inf = controller.mpc.tightening.e_inf
    for k, record in enumerate(controller.records):
        code, u_phi, r = c.step(sim.y_phi[k], sim.y0_phi[k])
        assert code == 0
        assert r.e_hat <= e_inf, (k, r.e_hat, e_inf)  # (float's rounding kept below)
        assert MPC_STATUS_NAMES[r.mpc.status] == record.mpc.status, k
        assert POLICY_NAMES[r.mpc.policy] == record.mpc.policy, k
        policies.add(record.mpc.policy)
        worst = max(
            worst, float(np.max(np.abs(u_phi - record.u_phi) / np.maximum(1.0, abs(record.u_phi))))
        )
    assert policies != {"nominal"}
    assert 1e-9 < worst <= 1e-4  # (float's accuracy: not double's)


@needs_compiler
def test_float_rounding_keeps_the_bounds_the_rate_bound_rests_on(tmp_path: Path) -> None:
    """Scenario 1 (set-points moved at Theorem 3's rate bound): in float the observer-error
    bound e_hat never exceeds the certificate's e_inf and no step of the set-point exceeds
    the rate limit (the limit and e_inf rounded down for float), so the run-time monitor's
    verdicts can hold as in double; statuses equal the library's."""
    model = load_model("ph_lstm_n5.npz")
    scenario = paper_scenarios(model)[0]
    limit = scenario.setpoint_rate_limit
    assert limit is not None
    controller = OffsetFreeController(
        model, replace(scenario.config, solver="daqp", N=5), setpoint_rate_limit=limit,
        one_call_step=False,
    )  # fmt: skip
    plant = scenario.make_plant(model, controller.certification)
    sim = simulate(
        plant, controller, scenario.setpoints, scenario.disturbances, 300, progress=False
    )
    exported = export_model_c(
        model, tmp_path, controller=controller, prefix="fr", precision="single"
    )
    c = CController(compile_controller(exported), exported)
    e_inf = controller.mpc.tightening.e_inf
    previous, largest = None, 0.0
    for k, record in enumerate(controller.records):
        code, _, r = c.step(sim.y_phi[k], sim.y0_phi[k])
        assert code == 0 and MPC_STATUS_NAMES[r.mpc.status] == record.mpc.status, k
        assert r.e_hat <= e_inf, (k, r.e_hat, e_inf)
        y0 = np.array(r.y0[:], dtype=np.float64)
        if previous is not None:
            largest = max(largest, float(np.max(np.abs(y0 - previous))))
        previous = y0
    assert limit * 0.99 < largest <= limit  # (the limiter moved at its limit, not beyond)


DRIVER = r"""
#include <stdio.h>
#include "fs.h"
int main(int argc, char **argv)
{
    static fs_controller c[2];
    float y[FS_P], y0[FS_P], u[2][FS_M];
    int k = 0, j;
    FILE *in = fopen(argv[argc - 1], "rb");
    if (!in) {
        return 2;
    }
    fs_controller_init(&c[0]);
    fs_controller_init(&c[1]);
    while (fread(y, sizeof y, 1, in) == 1 && fread(y0, sizeof y0, 1, in) == 1) {
        fs_controller_step(&c[0], y, y0, u[0], NULL);
        fs_controller_step(&c[1], y, y0, u[1], NULL);
        for (j = 0; j < FS_M; ++j) {
            if (u[0][j] != u[1][j]) {
                return 3;
            }
            printf("%.9g\n", (double)u[0][j]);
        }
        ++k;
    }
    fclose(in);
    return k > 0 ? 0 : 4;
}
"""


@needs_compiler
def test_the_float_step_runs_clean_under_the_sanitizers(tmp_path: Path) -> None:
    """Two float controllers in one program, 150 steps of the library's loop under
    AddressSanitizer and UndefinedBehaviorSanitizer: no report, the same inputs, within
    1e-4 of the library's."""
    controller, sim = closed_loop("ph", 5, 150)
    export_model_c(
        controller.model, tmp_path, controller=controller, prefix="fs", precision="single"
    )
    rows = np.hstack([sim.y_phi, sim.y0_phi]).astype(np.float32)
    (tmp_path / "steps.bin").write_bytes(rows.tobytes())
    (tmp_path / "driver.c").write_text(DRIVER)
    compiler = COMPILERS[0]  # (gcc first: clang's sanitizer runtimes are a separate package)
    binary = tmp_path / "driver"
    command = [
        compiler, *STRICT, "-g", "-fsanitize=address,undefined", "-fno-sanitize-recover=all",
        *daqp_flags(tmp_path), "-I", str(tmp_path), "-o", str(binary),
        str(tmp_path / "driver.c"), str(tmp_path / "fs.c"), *daqp_sources(tmp_path), "-lm",
    ]  # fmt: skip
    done = subprocess.run(command, capture_output=True, text=True)
    if done.returncode and ("asan" in done.stderr or "ubsan" in done.stderr):
        pytest.skip(f"{compiler} has no sanitizer runtime here: {done.stderr[-300:]}")
    assert done.returncode == 0, done.stderr[-3000:]
    run = subprocess.run(
        [str(binary), str(tmp_path / "steps.bin")], capture_output=True, text=True, timeout=300
    )
    assert run.returncode == 0 and not run.stderr, (run.returncode, run.stderr[-3000:])
    u = np.array([float(v) for v in run.stdout.split()])
    assert u.shape == (150,)
    assert np.max(np.abs(u - sim.u_phi[:, 0]) / np.maximum(1.0, np.abs(sim.u_phi[:, 0]))) <= 1e-4


def test_single_precision_is_refused_where_the_margins_do_not_cover_it(tmp_path: Path) -> None:
    """A certificate with a tiny w_bar leaves no room for float's rounding: the export and
    the c-single engine refuse it, saying the shares and what to do; the shipped pH
    controller is within them."""
    shipped = single_precision_margins(_controller(), 1e-4)
    assert shipped.holds and shipped.observer_rounding > 0.0
    tight = _controller(w_bar=1e-4)
    margins = single_precision_margins(tight, 1e-4)
    assert not margins.holds
    with pytest.raises(InvalidValueError, match=r"single precision is refused.*w_bar"):
        export_model_c(tight.model, tmp_path, controller=tight, precision="single")
    with pytest.raises(InvalidValueError, match=r"engine='c-single' cannot run"):
        OffsetFreeController(
            tight.model, MPCConfig(solver="daqp", N=5, w_bar=1e-4), engine="c-single"
        )
