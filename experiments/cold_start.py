"""Cold start of the controller: import, construction and first steps, empty and warm cache.

Copies this checkout's ``ltv_lstm_mpc`` and ``solvers`` into a temporary folder (so numba's
on-disk cache starts empty there), then runs the same child process twice: the first run
compiles every kernel the configuration uses, the second loads them from the cache. Each run
prints wall times of ``import ltv_lstm_mpc``, of the first use of the names, of the
controller's construction (``OffsetFreeController(model, MPCConfig(solver=...))``), of its
first step on the pH plant and of the next 20 steps.

    python experiments/cold_start.py [--solver daqp]
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
controller = OffsetFreeController(model, MPCConfig(solver={solver!r}, L_d=0.1))
t3 = time.perf_counter()
plant = PHNeutralizationPlant()
plant.reset()
u = controller.step(plant.output(), np.array([7.2]))
t4 = time.perf_counter()
for _ in range(20):
    u = controller.step(plant.step(u), np.array([7.2]))
t5 = time.perf_counter()
print(f"import {{t1 - t0:.3f}} s, names {{t2 - t1:.2f}} s, construction {{t3 - t2:.2f}} s, "
      f"first step {{t4 - t3:.2f}} s, next 20 steps {{t5 - t4:.3f}} s")
"""


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--solver", default="daqp")
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        package = Path(tmp) / "ltv_lstm_mpc"
        shutil.copytree(
            ROOT / "ltv_lstm_mpc", package, ignore=shutil.ignore_patterns("__pycache__")
        )
        shutil.copytree(
            ROOT / "solvers", package / "solvers", ignore=shutil.ignore_patterns("__pycache__")
        )
        env = {**os.environ, "PYTHONPATH": tmp}
        for label in ("empty cache", "warm cache"):
            result = subprocess.run(
                [sys.executable, "-c", CHILD.format(solver=args.solver)],
                capture_output=True,
                text=True,
                env=env,
                cwd=tmp,
            )
            notice = [line for line in result.stderr.splitlines() if "compiling" in line]
            print(f"{label:>11}: {result.stdout.strip()}")
            if notice:
                print(f"{'':>11}  stderr: {notice[0]}")
            if result.returncode:
                print(result.stderr[-2000:])


if __name__ == "__main__":
    main()
