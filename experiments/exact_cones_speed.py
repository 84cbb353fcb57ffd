"""Exact terminal cones, fast: the condensed transcription on native CLARABEL, side by side.

Runs bench's scenario 1 (short) step by step interleaved (order alternating ABBA, each
controller with its own plant) for

- ``daqp:socp``: condensed transcription, exact second-order cones by the SQP over DAQP
  (the default solver where DAQP is installed);
- ``clarabel``: condensed transcription, exact second-order cones, CLARABEL's own API;
- ``cvxpy:CLARABEL``: sparse transcription through cvxpy (the general path and the
  reference the first is checked against);
- ``daqp``: condensed QP with the conservative terminal box (for scale),

and prints per controller the median / p95 / p99 of the full ``step`` and the jitter
p95/median, the medians of ``prepare``, ``feedback`` and the solver call (microseconds),
the ratios of the median step to ``daqp`` (the QP path; the ``daqp:socp`` and ``clarabel``
rows are the cost of exact cones relative to it) and to ``cvxpy:CLARABEL``, and the largest
difference of the applied input to the latter (mL/s).

    python experiments/exact_cones_speed.py --steps 200 --N 5 20 50
    python experiments/exact_cones_speed.py --steps 15 --N 5
"""

from __future__ import annotations

import argparse
import os
import time
from dataclasses import replace
from typing import Any

SKIP = 10  # first steps left out of the figures: cold caches, first reference solve


def build_parser() -> argparse.ArgumentParser:
    """The command line (``--help`` answers before numpy and the library are imported)."""
    parser = argparse.ArgumentParser(
        description=__doc__.split("\n\n")[0],
        epilog='Figures: docs/benchmarks.md, "The compiled step" (exact cones) and "Exact '
        'cones: epigraph elimination".',
    )
    parser.add_argument(
        "--steps", type=int, default=200, help=f"closed-loop steps (200; more than {SKIP})"
    )
    parser.add_argument("--N", type=int, nargs="+", default=[5, 20, 50], help="horizons")
    return parser


if __name__ == "__main__":
    build_parser().parse_args()  # --help and bad options answer here, before the imports

for _name in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_name, "1")  # before numpy: small products, one thread

import numpy as np  # noqa: E402

from ltv_lstm_mpc import OffsetFreeController  # noqa: E402
from ltv_lstm_mpc.lstm.shipped import load_model  # noqa: E402
from ltv_lstm_mpc.solver_comparison.harness import bench_scenarios  # noqa: E402

SOLVERS = ("daqp:socp", "clarabel", "cvxpy:CLARABEL", "daqp")
REFERENCE = "cvxpy:CLARABEL"


def run(N: int, steps: int) -> dict[str, dict[str, Any]]:
    """Interleaved closed loops of every solver in :data:`SOLVERS` at horizon ``N``."""
    model = load_model("ph_lstm_n5.npz")
    scenario = bench_scenarios(model)[0]
    runs = []
    for solver in SOLVERS:
        config = replace(scenario.config, N=N, solver=solver)
        ctrl = OffsetFreeController(
            model, config, setpoint_rate_limit=scenario.setpoint_rate_limit, kernels="compiled"
        )
        runs.append((solver, ctrl, scenario.make_plant(model)))
    outputs = [plant.output() for _, _, plant in runs]
    times: list[list[float]] = [[] for _ in runs]
    inputs: list[list[float]] = [[] for _ in runs]
    steps = min(steps, len(scenario.setpoints))
    for k in range(steps):
        order = range(len(runs)) if k % 2 == 0 else reversed(range(len(runs)))
        for j in order:
            _, ctrl, plant = runs[j]
            t0 = time.perf_counter()
            u = ctrl.step(outputs[j], scenario.setpoints[k])
            times[j].append(time.perf_counter() - t0)
            inputs[j].append(float(u[0]))
            d = scenario.disturbances[k]
            outputs[j] = plant.step(u, None if np.isnan(d) else d)
    skip = SKIP
    result: dict[str, dict[str, Any]] = {}
    for j, (solver, ctrl, _) in enumerate(runs):
        mpc = [r.mpc for r in ctrl.records[skip:]]
        result[solver] = {
            "total": np.array(times[j][skip:]),
            "prepare": np.array([s.prepare_time for s in mpc]),
            "feedback": np.array([s.feedback_time for s in mpc]),
            "solve": np.array([s.solver_time for s in mpc]),
            "u": model.denormalize_u(np.array(inputs[j])[:, None])[:, 0],
            "transcription": ctrl.mpc.transcription,
            "reformulation": ctrl.mpc.reformulation,
        }
    return result


def main() -> None:
    parser = build_parser()
    args = parser.parse_args()
    if args.steps <= SKIP:
        parser.error(f"--steps must be more than {SKIP} (the first {SKIP} are left out)")
    us = 1e6
    print(
        f"{'solver':>15} {'N':>3} {'transcription':>13} {'terminal':>9} | {'step':>6} {'p95':>6} "
        f"{'p99':>6} {'p95/med':>7} {'prep':>6} {'feed':>6} {'solve':>6} | {'/daqp':>6} "
        f"{'/cvxpy':>6} {'max|du| mL/s':>12}"
    )
    for N in args.N:
        res = run(N, args.steps)
        reference, qp = res[REFERENCE], res["daqp"]
        for solver, r in res.items():
            median = np.median(r["total"])
            p95, p99 = np.percentile(r["total"], [95, 99])
            du = float(np.max(np.abs(r["u"] - reference["u"])))
            terminal = "box" if r["reformulation"] else "cones"
            print(
                f"{solver:>15} {N:>3} {r['transcription']:>13} {terminal:>9} | "
                f"{us * median:6.0f} {us * p95:6.0f} {us * p99:6.0f} {p95 / median:7.2f} "
                f"{us * np.median(r['prepare']):6.0f} {us * np.median(r['feedback']):6.0f} "
                f"{us * np.median(r['solve']):6.0f} | {median / np.median(qp['total']):6.2f} "
                f"{median / np.median(reference['total']):6.3f} {du:12.1e}",
                flush=True,
            )


if __name__ == "__main__":
    main()
