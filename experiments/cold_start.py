"""Cold start of the controller: import, construction and first steps, empty and warm cache.

Copies this checkout's ``ltv_lstm_mpc`` and ``solvers`` into a temporary folder (so numba's
on-disk cache starts empty there), then runs one child process per row:

1. empty cache, ``kernels="auto"`` (the default): the controller runs the numpy reference
   while a background process compiles the kernels; the child then waits until the cache
   holds them (the background compilation's wall time);
2. warm cache, ``"auto"``: the compiled kernels, loaded from the cache;
3. (``--blocking``) a second empty cache with ``kernels="compiled"``: the first step waits
   for the compilation (the behaviour before ``"auto"``).

Each row prints wall times of ``import ltv_lstm_mpc``, of the first use of the names, of
the controller's construction (``OffsetFreeController(model, MPCConfig(solver=...))``), of
its first step on the pH plant and of the next 20 steps (and their mean step against the
median step of the 200 steps after them, ``--steps``: near 1 where no kernel loads during
the first steps), and the kernels it ran. The script exits 1 where a child failed.

``--source DIR`` measures the warm-cache row alone on a copy made before (a folder holding
``ltv_lstm_mpc`` with ``solvers`` inside it, its numba cache warm: e.g. ``git archive`` of
an older commit, warmed once; or an editable checkout's root), ``--repeats`` times.

    python experiments/cold_start.py [--solver daqp] [--blocking] [--source DIR] [--repeats K]
    python experiments/cold_start.py --source . --steps 20      # this checkout, its cache warm
"""

from __future__ import annotations

import argparse
import os
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]

CHILD = """
import time
t0 = time.perf_counter()
import ltv_lstm_mpc
t1 = time.perf_counter()
import numpy as np
from ltv_lstm_mpc import MPCConfig, OffsetFreeController, PHNeutralizationPlant, load_model
t2 = time.perf_counter()
model = load_model("ph_lstm_n5.npz")
config = MPCConfig(solver={solver!r}, L_d=0.1)
controller = OffsetFreeController(model, config, kernels={kernels!r})
t3 = time.perf_counter()
plant = PHNeutralizationPlant()
plant.reset()
u = controller.step(plant.output(), np.array([7.2]))
t4 = time.perf_counter()
for _ in range(20):
    u = controller.step(plant.step(u), np.array([7.2]))
t5 = time.perf_counter()
steps = []
for _ in range({steps}):
    start = time.perf_counter()
    u = controller.step(plant.step(u), np.array([7.2]))
    steps.append(time.perf_counter() - start)
median = float(np.median(steps))
print(f"import {{t1 - t0:.3f}} s, names {{t2 - t1:.2f}} s, construction {{t3 - t2:.2f}} s, "
      f"first step {{t4 - t3:.2f}} s, next 20 steps {{t5 - t4:.3f}} s "
      f"({{(t5 - t4) / 20 / median:.1f}}x the median step of the {steps} after them, "
      f"{{median * 1e3:.3f}} ms) ({{controller.kernels}})")
if {wait!r}:
    from ltv_lstm_mpc.loop.kernels import choose_kernels
    while choose_kernels(config)[1] and time.perf_counter() - t3 < 600:
        time.sleep(0.5)
    print(f"background compilation done {{time.perf_counter() - t3:.1f}} s after construction")
"""


def build_parser() -> argparse.ArgumentParser:
    """The command line."""
    parser = argparse.ArgumentParser(
        description=__doc__.split("\n\n")[0],
        epilog='Figures: docs/benchmarks.md, "Cold start", and docs/user-guide/compiled.md, '
        '"Cold and warm start".',
    )
    parser.add_argument("--solver", default="daqp")
    parser.add_argument(
        "--blocking", action="store_true", help="also: empty cache, kernels='compiled'"
    )
    parser.add_argument(
        "--source",
        type=Path,
        help="measure the warm-cache row alone on this copy (its numba cache warm)",
    )
    parser.add_argument(
        "--repeats", type=int, default=1, help="warm-cache rows (default: %(default)s)"
    )
    parser.add_argument(
        "--steps",
        type=int,
        default=200,
        help="timed steps after the first 21, for the median step (default: %(default)s)",
    )
    return parser


def main() -> int:
    parser = build_parser()
    args = parser.parse_args()
    if args.steps < 1:
        parser.error("--steps must be at least 1")
    failed = 0
    runs = [("empty cache", "auto", True, True)] if args.source is None else []
    runs += [("warm cache", "auto", False, False)] * args.repeats
    if args.blocking:
        runs.append(("empty cache", "compiled", False, True))
    source = args.source
    with tempfile.TemporaryDirectory() as tmp:
        for label, kernels, wait, fresh in runs:
            folder = Path(tmp) / f"{label}-{kernels}".replace(" ", "-")
            if fresh:
                source = folder
                package = source / "ltv_lstm_mpc"
                shutil.copytree(
                    ROOT / "ltv_lstm_mpc", package, ignore=shutil.ignore_patterns("__pycache__")
                )
                shutil.copytree(
                    ROOT / "solvers",
                    package / "solvers",
                    ignore=shutil.ignore_patterns("__pycache__"),
                )
            env = {**os.environ, "PYTHONPATH": str(source)}
            env.pop("LTV_LSTM_MPC_KERNEL", None)
            result = subprocess.run(
                [
                    sys.executable,
                    "-c",
                    CHILD.format(solver=args.solver, kernels=kernels, wait=wait, steps=args.steps),
                ],
                capture_output=True,
                text=True,
                env=env,
                cwd=source,
            )
            notice = [line for line in result.stderr.splitlines() if "ltv_lstm_mpc:" in line]
            print(f"{label:>11} ({kernels}): {result.stdout.strip()}")
            if notice:
                print(f"{'':>11}  stderr: {notice[0][:160]}...")
            if result.returncode:
                print(result.stderr[-2000:])
                failed += 1
    return 1 if failed else 0


if __name__ == "__main__":
    raise SystemExit(main())
