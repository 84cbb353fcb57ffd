"""Tail latency of the controller step with Python's garbage collector on and paused.

One closed loop (bench's scenario 1 on the LSTM plant, DAQP, the compiled path) runs in
blocks of ``--block`` steps that alternate between the collector on and paused
(:func:`~ltv_lstm_mpc.loop.simulation.garbage_collection_paused`, what ``simulate`` does),
so both modes see the same machine in the same run. Per mode it prints the median, p95,
p99 and largest wall time of ``controller.step`` (record building included), the steps
above 1 ms and the collections the collector ran, and at the end the objects a full
collection finds unreachable (cycles the loop would leak with the collector off).

    python experiments/gc_jitter.py --steps 6000 --block 500 --N 5 20
    python experiments/gc_jitter.py --steps 40 --block 20 --N 5
"""

from __future__ import annotations

import argparse
import gc
import os
import time
from dataclasses import replace


def build_parser() -> argparse.ArgumentParser:
    """The command line (``--help`` answers before numpy and the library are imported)."""
    parser = argparse.ArgumentParser(
        description=__doc__.splitlines()[0],
        epilog='Figures: docs/benchmarks.md, "The compiled step" (garbage collector) and "The '
        'pipeline against earlier versions".',
    )
    parser.add_argument("--steps", type=int, default=6000, help="timed steps (both modes)")
    parser.add_argument("--block", type=int, default=500, help="steps per block")
    parser.add_argument("--N", type=int, nargs="+", default=[5, 20], help="horizons")
    return parser


if __name__ == "__main__":
    build_parser().parse_args()  # --help and bad options answer here, before the imports

for _name in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_name, "1")

import numpy as np  # noqa: E402

from ltv_lstm_mpc import OffsetFreeController  # noqa: E402
from ltv_lstm_mpc.loop.simulation import garbage_collection_paused  # noqa: E402
from ltv_lstm_mpc.lstm.shipped import load_model  # noqa: E402
from ltv_lstm_mpc.solver_comparison.harness import bench_scenarios  # noqa: E402


def run(N: int, steps: int, block: int) -> None:
    gc.collect()  # the previous run's controller and records (a cycle through the monitor)
    started: list[int] = []  # collections started, counted by the collector's callback
    gc.callbacks.append(lambda phase, info: started.append(1) if phase == "start" else None)
    model = load_model("ph_lstm_n5.npz")
    scenario = bench_scenarios(model)[0]
    config = replace(scenario.config, N=N, solver="daqp")
    controller = OffsetFreeController(
        model, config, setpoint_rate_limit=scenario.setpoint_rate_limit, kernels="compiled"
    )
    plant = scenario.make_plant(model)
    y = plant.output()
    setpoints = np.resize(np.asarray(scenario.setpoints), (steps + block, model.p))
    times: dict[bool, list[float]] = {False: [], True: []}
    collections = {False: 0, True: 0}
    for k in range(block):  # warm-up: compilation, caches
        y = plant.step(controller.step(y, setpoints[k]))
    k = block
    paused = False
    while k < steps + block:
        before = len(started)
        with garbage_collection_paused(paused):
            for _ in range(block):
                t0 = time.perf_counter()
                u = controller.step(y, setpoints[k])
                times[paused].append(time.perf_counter() - t0)
                y = plant.step(u)
                k += 1
            # inside the block: re-enabling the collector triggers one at the next allocation
            collections[paused] += len(started) - before
        paused = not paused
    for mode in (False, True):
        t = np.array(times[mode]) * 1e6
        print(
            f"N={N:<3} collector {'paused' if mode else 'on    '}: {t.size} steps, median "
            f"{np.median(t):6.1f} us, p95 {np.percentile(t, 95):6.1f}, p99 "
            f"{np.percentile(t, 99):7.1f}, max {t.max():7.0f}, steps > 1 ms "
            f"{int(np.sum(t > 1000)):3d}, collections {collections[mode]}"
        )
    gc.callbacks.clear()
    print(f"N={N:<3} unreachable objects after the loop: {gc.collect()}")


def main() -> None:
    parser = build_parser()
    args = parser.parse_args()
    if args.block < 1 or args.steps < 2 * args.block or args.steps % args.block:
        parser.error("--steps must be a multiple of --block, at least twice it (both modes)")
    for N in args.N:
        run(N, args.steps, args.block)


if __name__ == "__main__":
    main()
