"""The C export's model and observer on the host and on a Cortex-M7: agreement and memory.

For the shipped pH model (a 600-step closed loop of the paper's scenario 3, infeasible
steps included) and the quadruple-tank model (600 random inputs in U, measurements from
the model plus noise), exports the model with the controller's certified observer
(``ltv_lstm_mpc.export.export_model_c``), replays the loop's measurements and inputs
through the exported observer built on the host (software in the loop) and, where Debian's
gcc-arm-none-eabi, libnewlib-arm-none-eabi and qemu-system-arm are installed, on QEMU's
mps2-an500 Cortex-M7 (processor in the loop), and prints per model: the largest
difference host / library and target / host, and on the target the exported code's flash
(text + rodata + data) and RAM (data + bss, the caller's workspace, the measured stack of
the updates).

Then the whole controller step (``export_model_c(..., controller=...)``): the paper's
scenario 3 on the pH plant at N = 5 and 20 and the quadruple tank's set-point changes at
N = 5, each replayed through ``<prefix>_controller_step`` on the host and on the Cortex-M7
(the largest input difference host / library and target / host, the steps where the
codes differ), the controller code's flash (its and DAQP's symbols in the linked
program), ``sizeof(<prefix>_controller)``, the measured stack, and the instructions per
step of the first ``--count`` steps from QEMU's instruction trace (``-singlestep -d
exec``) with their time at 600 MHz and one instruction per cycle (an estimate: the
Cortex-M7 issues up to two instructions per cycle, and a double-precision division takes
many). The runs ``ph5f`` and ``tank5f`` export in single precision and run on QEMU's
mps2-an386 Cortex-M4F (single-precision FPU; the time at 168 MHz, a typical part's clock);
``ph5c``, ``ph20c`` and ``tank5c`` export the exact terminal cones (``daqp:socp``: the SQP
on DAQP) in double precision, on the Cortex-M7.

    python experiments/export_pil.py [--steps 600] [--count 60]
        [--step-runs ph5 ph20 tank5 ph5f tank5f ph5c ph20c tank5c]
"""

from __future__ import annotations

import argparse
import os
import tempfile
from pathlib import Path
from typing import Any


def build_parser() -> argparse.ArgumentParser:
    """The command line (``--help`` answers before numpy and the library are imported)."""
    parser = argparse.ArgumentParser(
        description=__doc__.split("\n\n")[0],
        epilog='Figures: docs/user-guide/export-c.md, "Checked on a Cortex-M7". Smallest run: '
        "--steps 20.",
    )
    parser.add_argument("--steps", type=int, default=600, help="updates replayed (600)")
    parser.add_argument(
        "--count", type=int, default=60, help="steps whose instructions are counted (60)"
    )
    parser.add_argument(
        "--step-runs",
        nargs="*",
        default=["ph5", "ph20", "tank5", "ph5f", "tank5f", "ph5c", "ph20c", "tank5c"],
        help="controller-step runs: ph5, ph20 (scenario 3 at N = 5, 20), tank5, in single "
        "precision on a Cortex-M4F ph5f, tank5f, with the exact cones (daqp:socp) ph5c, "
        "ph20c, tank5c (none: skip)",
    )
    return parser


if __name__ == "__main__":
    build_parser().parse_args()

for _name in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_name, "1")

import numpy as np  # noqa: E402

from ltv_lstm_mpc import MPCConfig, Observer, OffsetFreeController, simulate  # noqa: E402
from ltv_lstm_mpc.export import export_model_c  # noqa: E402
from ltv_lstm_mpc.export.pil import (  # noqa: E402
    find_toolchain,
    run_host,
    run_pil,
    run_step_host,
    run_step_pil,
    target_of,
    write_observer_replay,
    write_step_replay,
)
from ltv_lstm_mpc.lstm.shipped import load_model  # noqa: E402
from ltv_lstm_mpc.paper.scenarios import paper_scenarios  # noqa: E402


def ph_loop(steps: int) -> tuple[Any, Any, Any, Any, Any, Any]:
    """The paper's scenario 3 on the pH plant: model, observer, first estimate, y, u."""
    model = load_model("ph_lstm_n5.npz")
    scenario = paper_scenarios(model)[2]
    controller = scenario.make_controller(model, solver="daqp", N=5)
    plant = scenario.make_plant(model, controller.certification)
    simulate(plant, controller, scenario.setpoints, scenario.disturbances, steps, progress=False)
    records = controller.records
    Y = np.array([r.y for r in records])
    U = np.array([r.u for r in records])
    return model, controller.observer, records[0].x_hat, records[0].d_hat, Y, U


def quadtank_sequence(steps: int) -> tuple[Any, Any, Any, Any, Any, Any]:
    """Random inputs in U and the model's outputs plus noise (a replay needs no loop)."""
    model = load_model("quadtank_lstm_n8.npz")
    controller = OffsetFreeController(model, MPCConfig(solver="daqp", N=5))
    rng = np.random.default_rng(0)
    U = rng.uniform(-0.9, 0.9, (steps, model.m))
    x0 = model.equilibrium(np.zeros(model.m))
    states, _ = model.simulate(x0, U)
    Y = np.array([model.output(x) for x in states[:-1]]) + rng.normal(0.0, 0.01, (steps, model.p))
    return model, controller.observer, x0, np.zeros(model.p), Y, U


def main() -> None:
    args = build_parser().parse_args()
    toolchain = find_toolchain()
    if toolchain is None:
        print("no Cortex-M7 toolchain: host only (apt-get install gcc-arm-none-eabi "
              "libnewlib-arm-none-eabi qemu-system-arm)")  # fmt: skip
    print(
        f"{'model':<22} {'updates':>7} {'host - library':>15} {'target - host':>14} "
        f"{'flash B':>8} {'RAM B (data+bss / workspace / stack)':>38}"
    )
    for label, make in (("pH (n = 5)", ph_loop), ("quadruple tank (n = 8)", quadtank_sequence)):
        model, observer, x0, d0, Y, U = make(args.steps)
        replay = Observer(model, observer.gains, d_max=observer.d_max)
        replay.reset(x0, d0)
        expected = []
        for y, u in zip(Y, U, strict=True):
            replay.update(y, u)
            expected.append(np.concatenate([replay.x_hat, replay.d_hat]))
        with tempfile.TemporaryDirectory() as scratch:
            exported = export_model_c(model, Path(scratch), observer=observer, prefix="m")
            main_c = write_observer_replay(exported, x0, d0, Y, U)
            host = run_host(main_c, exported)
            gap = float(np.abs(host.estimates - np.array(expected)).max())
            target_gap, flash, ram = "-", "-", "-"
            if toolchain is not None:
                target = run_pil(main_c, exported, toolchain)
                target_gap = f"{float(np.abs(target.estimates - host.estimates).max()):.1e}"
                sections = target.sections or {}
                flash = str(sections["text"] + sections["rodata"] + sections["data"])
                ram = (
                    f"{sections['data'] + sections['bss']} / {exported.workspace_bytes} / "
                    f"{target.stack_bytes}"
                )
        print(f"{label:<22} {len(Y):>7} {gap:>15.1e} {target_gap:>14} {flash:>8} {ram:>38}")


def step_loop(name: str, N: int, steps: int, solver: str = "daqp") -> tuple[Any, Any]:
    """The library's closed loop (reference engine): the controller and its simulation."""
    from dataclasses import replace

    from ltv_lstm_mpc.benchmarks.quadtank import quadtank_scenarios

    if name == "ph":
        model = load_model("ph_lstm_n5.npz")
        scenario: Any = paper_scenarios(model)[2]
    else:
        model = load_model("quadtank_lstm_n8.npz")
        scenario = quadtank_scenarios()[0]
    config = replace(scenario.config, solver=solver, N=N)
    controller = OffsetFreeController(
        model, config, setpoint_rate_limit=scenario.setpoint_rate_limit, one_call_step=False
    )
    if name == "ph":
        plant = scenario.make_plant(model, controller.certification)
        disturbances = scenario.disturbances
    else:
        plant, disturbances = scenario.make_plant(model), scenario.leaks
    sim = simulate(plant, controller, scenario.setpoints, disturbances, steps, progress=False)
    return controller, sim


def step_rows(steps: int, count: int, runs: list[str], toolchain: Any) -> None:
    """The whole controller step: agreement, memory and instructions (module docstring)."""
    print(
        f"\n{'controller step':<30} {'steps':>5} {'host-lib':>8} {'MCU-host':>8} {'codes':>5} "
        f"{'flash B':>8} {'struct B':>8} {'stack B':>7}  instructions per step "
        "(median / p95 / max; at the clock)"
    )
    known = {
        "ph5": ("pH scenario 3, N = 5", "ph", 5, "double", "daqp"),
        "ph20": ("pH scenario 3, N = 20", "ph", 20, "double", "daqp"),
        "tank5": ("quadruple tank, N = 5", "quadtank", 5, "double", "daqp"),
        "ph5f": ("pH scenario 3, N = 5, float", "ph", 5, "single", "daqp"),
        "tank5f": ("quadruple tank, N = 5, float", "quadtank", 5, "single", "daqp"),
        "ph5c": ("pH scenario 3, N = 5, cones", "ph", 5, "double", "daqp:socp"),
        "ph20c": ("pH scenario 3, N = 20, cones", "ph", 20, "double", "daqp:socp"),
        "tank5c": ("quadruple tank, N = 5, cones", "quadtank", 5, "double", "daqp:socp"),
    }
    for label, name, N, precision, solver in (known[run] for run in runs):
        controller, sim = step_loop(name, N, steps, solver)
        with tempfile.TemporaryDirectory() as scratch:
            folder = Path(scratch)
            exported = export_model_c(
                controller.model, folder, controller=controller, prefix="c", precision=precision
            )
            main_c = write_step_replay(exported, sim.y_phi, sim.y0_phi)
            host = run_step_host(main_c, exported)
            scale = max(1.0, float(np.abs(sim.u_phi).max()))
            gap = float(np.abs(host.u_phi - sim.u_phi).max()) / scale
            if toolchain is None:
                print(f"{label:<30} {len(sim.u_phi):>5} {gap:>8.1e}   (no Cortex-M toolchain)")
                continue
            target = run_step_pil(main_c, exported, toolchain)
            target_gap = float(np.abs(target.u_phi - host.u_phi).max()) / scale
            differ = int(np.any(target.codes != host.codes, axis=1).sum())
            short = folder / "short"
            short.mkdir()
            exported_short = export_model_c(
                controller.model, short, controller=controller, prefix="c", precision=precision
            )
            counted = run_step_pil(
                write_step_replay(exported_short, sim.y_phi[:count], sim.y0_phi[:count]),
                exported_short, toolchain, count_instructions=True,
            )  # fmt: skip
            sections = target.sections or {}
            flash = sections.get("text", 0) + sections.get("rodata", 0) + sections.get("data", 0)
            ins = np.asarray(counted.instructions, dtype=float)[1:]  # (the first: start-up)
            median, p95, top = np.median(ins), np.percentile(ins, 95), ins.max()
            mcu = target_of(exported)
            clock = mcu.clock_mhz
            print(
                f"{label:<30} {len(sim.u_phi):>5} {gap:>8.1e} {target_gap:>8.1e} {differ:>5} "
                f"{flash:>8} {target.controller_bytes:>8} {target.stack_bytes:>7}  "
                f"{median:,.0f} / {p95:,.0f} / {top:,.0f}; {median / clock:.0f} / "
                f"{p95 / clock:.0f} / {top / clock:.0f} us on a {mcu.name} at {clock:.0f} MHz "
                f"(first step {counted.instructions[0]:,})",
                flush=True,
            )


if __name__ == "__main__":
    main()
    arguments = build_parser().parse_args()
    if arguments.step_runs:
        step_rows(arguments.steps, arguments.count, arguments.step_runs, find_toolchain())
