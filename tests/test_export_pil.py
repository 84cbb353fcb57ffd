"""Software and processor in the loop for the C export (ltv_lstm_mpc/export/pil.py): a
closed loop replayed through the exported observer on the host (gcc) and on a Cortex-M7
(QEMU's mps2-an500) equals the library's observer. Skipped without a C compiler, and the
Cortex-M7 part without Debian's gcc-arm-none-eabi, libnewlib-arm-none-eabi and
qemu-system-arm (.ci/run installs them)."""

from __future__ import annotations

import shutil
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from ltv_lstm_mpc import MPCConfig, Observer, OffsetFreeController, simulate
from ltv_lstm_mpc.exceptions import InvalidValueError
from ltv_lstm_mpc.export import export_model_c
from ltv_lstm_mpc.export.pil import find_toolchain, run_host, run_pil, write_observer_replay
from ltv_lstm_mpc.lstm.shipped import load_model
from ltv_lstm_mpc.paper.scenarios import paper_scenarios

needs_gcc = pytest.mark.skipif(shutil.which("gcc") is None, reason="no gcc")
TOOLCHAIN = find_toolchain()
needs_toolchain = pytest.mark.skipif(
    TOOLCHAIN is None,
    reason="no Cortex-M7 toolchain (gcc-arm-none-eabi, libnewlib-arm-none-eabi, qemu-system-arm)",
)
STEPS = 600
STEP_REPLAY = 200


def _scenario3_loop() -> tuple[Any, Any, Any, Any, Any]:
    """600 steps of the paper's scenario 3 (set-point steps with infeasible instants) on
    the pH plant: the model, the controller's observer, the first estimate, the normalized
    measurements and applied inputs."""
    model = load_model("ph_lstm_n5.npz")
    scenario = paper_scenarios(model)[2]
    controller = scenario.make_controller(model, solver="daqp", N=5)
    plant = scenario.make_plant(model, controller.certification)
    simulate(plant, controller, scenario.setpoints, scenario.disturbances, STEPS, progress=False)
    records = controller.records
    assert any(not r.mpc.feasible for r in records)  # the loop took the policy somewhere
    Y = np.array([r.y for r in records])
    U = np.array([r.u for r in records])
    return model, controller.observer, records[0].x_hat, records[0].d_hat, (Y, U)


def _reference(model: Any, observer: Any, x0: Any, d0: Any, Y: Any, U: Any) -> Any:
    """The library's observer over the same measurements and inputs."""
    replay = Observer(model, observer.gains, d_max=observer.d_max)
    replay.reset(x0, d0)
    rows = []
    for y, u in zip(Y, U, strict=True):
        replay.update(y, u)
        rows.append(np.concatenate([replay.x_hat, replay.d_hat]))
    return np.array(rows)


@pytest.fixture(scope="module")
def loop() -> tuple[Any, Any, Any, Any, Any]:
    return _scenario3_loop()


@needs_gcc
def test_the_host_replay_equals_the_library_observer(loop: Any, tmp_path: Path) -> None:
    """Software in the loop: 600 updates of the exported observer built with the host's
    gcc (strict flags) along the paper's scenario 3 equal the library's to 1e-12."""
    model, observer, x0, d0, (Y, U) = loop
    exported = export_model_c(model, tmp_path, observer=observer, prefix="ph")
    host = run_host(write_observer_replay(exported, x0, d0, Y, U), exported)
    expected = _reference(model, observer, x0, d0, Y, U)
    assert host.estimates.shape == (STEPS, 2 * model.n + model.p)
    assert np.abs(host.estimates - expected).max() <= 1e-12 * max(1.0, np.abs(expected).max())


@needs_gcc
@needs_toolchain
def test_the_cortex_m7_replay_equals_the_host(loop: Any, tmp_path: Path) -> None:
    """Processor in the loop: the same 600 updates cross-compiled for a Cortex-M7
    (double-precision FPU, hard float) and run on QEMU give the host's numbers to 1e-9
    (measured: bit for bit); the exported code's flash and RAM are within the C export's
    budget (64 KiB, 16 KiB) and the stack was measured."""
    assert TOOLCHAIN is not None
    model, observer, x0, d0, (Y, U) = loop
    exported = export_model_c(model, tmp_path, observer=observer, prefix="ph")
    main = write_observer_replay(exported, x0, d0, Y, U)
    host = run_host(main, exported)
    target = run_pil(main, exported, TOOLCHAIN)
    assert target.estimates.shape == host.estimates.shape
    assert np.abs(target.estimates - host.estimates).max() <= 1e-9
    assert target.sections is not None and target.stack_bytes is not None
    flash = target.sections["text"] + target.sections["rodata"] + target.sections["data"]
    ram = target.sections["data"] + target.sections["bss"] + exported.workspace_bytes
    assert 0 < flash <= 64 * 1024
    assert ram + target.stack_bytes <= 16 * 1024
    assert 0 < target.stack_bytes < 16384  # measured, inside the painted region


@needs_toolchain
@pytest.mark.parametrize("name", ["ph_lstm_n5.npz", "quadtank_lstm_n8.npz"])
def test_the_whole_export_cross_compiles_for_the_cortex_m7(name: str, tmp_path: Path) -> None:
    """Model, observer, reference calculator and tightening compile for the Cortex-M7 with
    the strict flags (warnings are errors)."""
    import subprocess

    from ltv_lstm_mpc.export.pil import CORTEX_M7_FLAGS, STRICT_FLAGS

    assert TOOLCHAIN is not None
    model = load_model(name)
    controller = OffsetFreeController(model, MPCConfig(solver="daqp", N=5))
    exported = export_model_c(
        model, tmp_path, observer=controller.observer, reference=controller.reference,
        tightening=controller.mpc.tightening, prefix="m7",
    )  # fmt: skip
    command = [TOOLCHAIN.gcc, *STRICT_FLAGS, *CORTEX_M7_FLAGS, "-c", "-o",
               str(tmp_path / "m7.o"), str(exported.source)]  # fmt: skip
    done = subprocess.run(command, capture_output=True, text=True)
    assert done.returncode == 0, done.stderr


def test_the_replay_refuses_an_export_without_observer_and_uneven_data(tmp_path: Path) -> None:
    """Errors name the problem and the fix."""
    model = load_model("ph_lstm_n5.npz")
    exported = export_model_c(model, tmp_path, prefix="bare")
    x0, d0 = np.zeros(2 * model.n), np.zeros(model.p)
    with pytest.raises(InvalidValueError, match="no observer update"):
        write_observer_replay(exported, x0, d0, np.zeros((3, 1)), np.zeros((3, 1)))
    controller = OffsetFreeController(model, MPCConfig(solver="daqp", N=5))
    exported = export_model_c(model, tmp_path, observer=controller.observer, prefix="obs")
    with pytest.raises(InvalidValueError, match="one row of each per step"):
        write_observer_replay(exported, x0, d0, np.zeros((3, 1)), np.zeros((2, 1)))
    with pytest.raises(InvalidValueError, match=r"pass 10 and 1"):
        write_observer_replay(exported, x0[:5], d0, np.zeros((3, 1)), np.zeros((3, 1)))
    with pytest.raises(InvalidValueError, match=r"pass y as \(K, 1\)"):
        write_observer_replay(exported, x0, d0, np.zeros((3, 2)), np.zeros((3, 1)))
    main = write_observer_replay(exported, x0, d0, np.zeros(3), np.zeros(3))  # SISO: (K,)
    assert "static const double Y[K][P]" in main.read_text()


def scenario3_steps(solver: str) -> tuple[Any, Any]:
    """Scenario 3's first STEP_REPLAY steps on ``solver`` (N = 5, the reference engine):
    the controller and its simulation."""
    from dataclasses import replace

    model = load_model("ph_lstm_n5.npz")
    scenario = paper_scenarios(model)[2]
    config = replace(scenario.config, solver=solver, N=5)
    controller = OffsetFreeController(
        model, config, setpoint_rate_limit=scenario.setpoint_rate_limit, one_call_step=False
    )
    plant = scenario.make_plant(model, controller.certification)
    sim = simulate(plant, controller, scenario.setpoints, scenario.disturbances, STEP_REPLAY,
                   progress=False)  # fmt: skip
    return controller, sim


@pytest.fixture(scope="module")
def step_loop() -> tuple[Any, Any]:
    """Scenario 3's first steps on daqp (the terminal box)."""
    return scenario3_steps("daqp")


@needs_gcc
@needs_toolchain
def test_the_whole_step_on_the_cortex_m7_equals_the_host_and_the_library(
    step_loop: Any, tmp_path: Path
) -> None:
    """Processor in the loop of the whole controller step: 200 steps of scenario 3 (the
    policy on some) replayed through <prefix>_controller_step on QEMU's Cortex-M7 give the
    host's inputs bit for bit and its codes, statuses and policies; the host's equal the
    library's to 1e-9; the first 8 steps' instructions are counted from QEMU's trace
    (experiments/export_pil.py replays 600 steps and counts 60)."""
    from ltv_lstm_mpc.export.pil import run_step_host, run_step_pil, write_step_replay

    assert TOOLCHAIN is not None
    controller, sim = step_loop
    exported = export_model_c(controller.model, tmp_path, controller=controller, prefix="ph")
    main = write_step_replay(exported, sim.y_phi, sim.y0_phi)
    host = run_step_host(main, exported)
    assert np.abs(host.u_phi - sim.u_phi).max() <= 1e-9 * np.abs(sim.u_phi).max()
    assert (host.codes[:, 2] > 0).sum() == sum(p != "nominal" for p in sim.policy) > 0
    target = run_step_pil(main, exported, TOOLCHAIN)
    assert np.array_equal(target.u_phi.view(np.uint64), host.u_phi.view(np.uint64))
    assert np.array_equal(target.codes, host.codes)
    assert target.stack_bytes is not None and target.stack_bytes > 0
    assert target.sections is not None and target.sections["text"] > 0
    assert target.controller_bytes is not None
    assert target.controller_bytes <= exported.mpc_workspace_bytes
    # The memory targets of the pH controller at N = 5 (-O2): flash (the controller's and
    # DAQP's code and constants) <= 64 KiB; RAM (its data and bss, the controller struct
    # and the measured stack) <= 16 KiB.
    sections = target.sections
    assert sections["text"] + sections["rodata"] + sections["data"] <= 64 * 1024, sections
    ram = sections["data"] + sections["bss"] + target.controller_bytes + target.stack_bytes
    assert ram <= 16 * 1024, (ram, target.controller_bytes, target.stack_bytes)
    short = tmp_path / "short"
    short.mkdir()
    exported = export_model_c(controller.model, short, controller=controller, prefix="ph")
    main = write_step_replay(exported, sim.y_phi[:8], sim.y0_phi[:8])
    counted = run_step_pil(main, exported, TOOLCHAIN, count_instructions=True)
    assert counted.instructions is not None and counted.instructions.shape == (8,)
    assert np.all((10_000 < counted.instructions) & (counted.instructions < 2_000_000))
    assert np.array_equal(counted.u_phi.view(np.uint64), target.u_phi[:8].view(np.uint64))


@needs_gcc
@needs_toolchain
def test_the_float_step_on_the_cortex_m4f_equals_the_host(step_loop: Any, tmp_path: Path) -> None:
    """Single precision on a Cortex-M4F (QEMU's mps2-an386, single-precision FPU): the
    replay of scenario 3 (the policy on some steps) gives the float host build's inputs
    bit for bit and its codes, within 1e-4 of the library's; the flash and RAM are within
    the double build's targets (64 KiB, 16 KiB); no double-precision arithmetic (software
    helpers) is linked but the harness's printf's; instructions counted."""
    import subprocess

    from ltv_lstm_mpc.export.pil import run_step_host, run_step_pil, write_step_replay

    assert TOOLCHAIN is not None
    controller, sim = step_loop
    exported = export_model_c(
        controller.model, tmp_path, controller=controller, prefix="pf", precision="single"
    )
    main = write_step_replay(exported, sim.y_phi[:100], sim.y0_phi[:100])
    host = run_step_host(main, exported)
    scale = np.abs(sim.u_phi).max()
    assert 0 < np.abs(host.u_phi - sim.u_phi[:100]).max() <= 1e-4 * scale
    target = run_step_pil(main, exported, TOOLCHAIN, count_instructions=True)
    assert np.array_equal(target.u_phi, host.u_phi)
    assert np.array_equal(target.codes, host.codes)
    assert (target.codes[:, 2] > 0).any()
    sections = target.sections
    assert sections is not None and target.controller_bytes is not None
    assert target.stack_bytes is not None
    assert sections["text"] + sections["rodata"] + sections["data"] <= 64 * 1024, sections
    ram = sections["data"] + sections["bss"] + target.controller_bytes + target.stack_bytes
    assert ram <= 16 * 1024, (ram, target.controller_bytes, target.stack_bytes)
    assert target.instructions is not None and target.instructions.shape == (100,)
    assert np.all((10_000 < target.instructions) & (target.instructions < 2_000_000))
    # the controller's and DAQP's objects reference no double-precision helper (__aeabi_d*)
    from ltv_lstm_mpc.export.pil import STRICT_FLAGS, target_of
    from ltv_lstm_mpc.export.sil import daqp_flags, daqp_sources

    nm = str(Path(TOOLCHAIN.size).with_name(Path(TOOLCHAIN.size).name.replace("size", "nm")))
    helpers = {}
    for source in [str(exported.source), *daqp_sources(tmp_path)]:
        obj = tmp_path / (Path(source).stem + "_m4f.o")
        subprocess.run(
            [TOOLCHAIN.gcc, *STRICT_FLAGS, *target_of(exported).flags, *daqp_flags(tmp_path),
             "-c", "-o", str(obj), source],
            check=True, capture_output=True,
        )  # fmt: skip
        undefined = subprocess.run(
            [nm, "-u", str(obj)], capture_output=True, text=True, check=True
        ).stdout.split()
        helpers[Path(source).name] = [name for name in undefined if name.startswith("__aeabi_d")]
    assert not any(helpers.values()), helpers
    with pytest.raises(InvalidValueError, match="double-precision exports"):
        write_observer_replay(exported, np.zeros(10), np.zeros(1), np.zeros(3), np.zeros(3))


@pytest.fixture(scope="module")
def cone_loop() -> tuple[Any, Any]:
    """Scenario 3's first steps on daqp:socp (the exact terminal cones)."""
    return scenario3_steps("daqp:socp")


@needs_gcc
def test_the_exact_cone_step_runs_clean_under_the_sanitizers(
    cone_loop: Any, tmp_path: Path
) -> None:
    """The daqp:socp controller step (the SQP on DAQP, its failed solves and the policy)
    built with -fsanitize=address,undefined: the replay of scenario 3 reports nothing and
    gives the library's inputs to 1e-9."""
    from ltv_lstm_mpc.export.pil import run_step_host, write_step_replay

    controller, sim = cone_loop
    exported = export_model_c(controller.model, tmp_path, controller=controller, prefix="pc")
    main = write_step_replay(exported, sim.y_phi, sim.y0_phi)
    flags = ("-g", "-fsanitize=address,undefined", "-fno-sanitize-recover=all")
    try:
        host = run_step_host(main, exported, cflags=flags)
    except InvalidValueError as error:
        if "asan" in str(error) or "ubsan" in str(error):
            pytest.skip(f"gcc has no sanitizer runtime here: {str(error)[-300:]}")
        raise
    assert np.abs(host.u_phi - sim.u_phi).max() <= 1e-9 * np.abs(sim.u_phi).max()
    assert (host.codes[:, 2] > 0).sum() == sum(p != "nominal" for p in sim.policy) > 0


@needs_gcc
@needs_toolchain
def test_the_exact_cone_step_on_the_cortex_m7_equals_the_host(
    cone_loop: Any, tmp_path: Path
) -> None:
    """Processor in the loop of the daqp:socp step: scenario 3's replay on QEMU's
    Cortex-M7 gives the host's inputs bit for bit and its codes (the policy on some
    steps); the controller struct is within the export's bound."""
    from ltv_lstm_mpc.export.pil import run_step_host, run_step_pil, write_step_replay

    assert TOOLCHAIN is not None
    controller, sim = cone_loop
    exported = export_model_c(controller.model, tmp_path, controller=controller, prefix="pc")
    main = write_step_replay(exported, sim.y_phi, sim.y0_phi)
    host = run_step_host(main, exported)
    assert np.abs(host.u_phi - sim.u_phi).max() <= 1e-9 * np.abs(sim.u_phi).max()
    target = run_step_pil(main, exported, TOOLCHAIN)
    assert np.array_equal(target.u_phi.view(np.uint64), host.u_phi.view(np.uint64))
    assert np.array_equal(target.codes, host.codes)
    assert (target.codes[:, 2] > 0).any()
    assert target.controller_bytes is not None
    assert target.controller_bytes <= exported.mpc_workspace_bytes
