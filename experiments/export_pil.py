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

    python experiments/export_pil.py [--steps 600]
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
    write_observer_replay,
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


if __name__ == "__main__":
    main()
