"""Controller step time of the one pipeline, optionally side by side with an older checkout.

Runs scenario 1 (bench's short variant) with ``OffsetFreeController(model,
MPCConfig(solver=..., transcription=...))`` for each backend and horizon and prints the
median / p95 of the full step, of ``prepare`` and of ``feedback`` (microseconds). With
``--baseline DIR`` (a folder holding an older ``ltv_lstm_mpc`` package with its solver layer
installed as ``ltv_lstm_mpc/solvers``), the same loops run in that version too, alternating
the two in separate processes round by round, and the ratio new / old is printed: one run,
side by side (these machines drift, so only such ratios mean anything).

    python experiments/pipeline_speed.py --rounds 3
    python experiments/pipeline_speed.py --baseline /tmp/basepkg --rounds 3
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys

import numpy as np

CASES = [("daqp", 5), ("daqp", 20), ("daqp", 50), ("cvxpy:CLARABEL", 5)]

_CHILD = r"""
import json, sys, time
from dataclasses import replace
import numpy as np
import ltv_lstm_mpc as L
from ltv_lstm_mpc import load_model, OffsetFreeController
solver, N, steps, old = sys.argv[1], int(sys.argv[2]), int(sys.argv[3]), sys.argv[4] == "1"
model = load_model("ph_lstm_n5.npz")
if old:
    from ltv_lstm_mpc.bench import bench_scenarios
else:
    from ltv_lstm_mpc.bench.harness import bench_scenarios
sc = bench_scenarios(model)[0]
config = replace(sc.config, N=N, solver=solver)
rate = sc.setpoint_rate_limit
if old and solver != "cvxpy:CLARABEL":
    from ltv_lstm_mpc.fast import FastOffsetFreeController
    ctrl = FastOffsetFreeController(model, config, solver=solver, setpoint_rate_limit=rate)
else:
    ctrl = OffsetFreeController(model, config, setpoint_rate_limit=rate)
plant = sc.make_plant(model)
y = plant.output()
total, prep, feed = [], [], []
for k in range(steps):
    t0 = time.perf_counter()
    u = ctrl.step(y, sc.setpoints[k])
    total.append(time.perf_counter() - t0)
    r = ctrl.records[-1].mpc
    prep.append(getattr(r, "prepare_time", float("nan")))
    feed.append(getattr(r, "feedback_time", float("nan")))
    d = sc.disturbances[k]
    y = plant.step(u, None if np.isnan(d) else d)
skip = 10  # first steps: cold caches, first reference solve
print(json.dumps({"total": total[skip:], "prepare": prep[skip:], "feedback": feed[skip:],
                  "u": [float(r.u_phi[0]) for r in ctrl.records]}))
"""


def _run(solver: str, N: int, steps: int, path: str | None) -> dict[str, list[float]]:
    env = dict(os.environ, OMP_NUM_THREADS="1", OPENBLAS_NUM_THREADS="1", MKL_NUM_THREADS="1")
    if path is not None:
        env["PYTHONPATH"] = path
    old = "1" if path is not None else "0"
    out = subprocess.run(
        [sys.executable, "-c", _CHILD, solver, str(N), str(steps), old],
        capture_output=True,
        text=True,
        env=env,
        check=True,
        cwd="/tmp",
    )
    return json.loads(out.stdout.strip().splitlines()[-1])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--baseline", default=None, help="folder with an older ltv_lstm_mpc")
    parser.add_argument("--rounds", type=int, default=3)
    parser.add_argument("--steps", type=int, default=300)
    args = parser.parse_args()
    print(
        f"{'backend':>16} {'N':>3} | {'step med':>8} {'p95':>7} {'prep':>6} {'feed':>6}"
        + (" | old med  new/old  max|du_phi|" if args.baseline else "")
    )
    for solver, N in CASES:
        steps = args.steps if solver == "daqp" else min(args.steps, 120)
        new: list[float] = []
        old: list[float] = []
        prep: list[float] = []
        feed: list[float] = []
        du = 0.0
        for _ in range(args.rounds):
            a = _run(solver, N, steps, None)
            new += a["total"]
            prep += a["prepare"]
            feed += a["feedback"]
            if args.baseline:
                b = _run(solver, N, steps, args.baseline)
                old += b["total"]
                du = max(du, float(np.max(np.abs(np.subtract(a["u"], b["u"])))))
        us = 1e6
        line = (
            f"{solver:>16} {N:>3} | {us * np.median(new):8.0f} {us * np.percentile(new, 95):7.0f} "
            f"{us * np.median(prep):6.0f} {us * np.median(feed):6.0f}"
        )
        if args.baseline:
            ratio = np.median(new) / np.median(old)
            line += f" | {us * np.median(old):7.0f}  {ratio:7.2f}  {du:.1e}"
        print(line, flush=True)


if __name__ == "__main__":
    main()
