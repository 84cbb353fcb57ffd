"""The whole controller step, side by side: one-call daqp, general daqp, two exact-cone paths.

Runs bench's scenario 1 (short) at each horizon, step by step interleaved (order
alternating ABBA, each controller with its own plant, the garbage collector paused as in
``simulate``), for

- ``daqp one-call``: the condensed QP on DAQP, each step one compiled call
  (:mod:`ltv_lstm_mpc.loop.compiled_step`);
- ``daqp general``: the same controller with ``one_call_step=False`` (the general path:
  one compiled call per stage, Python between them);
- ``exact cones``: the paper's SOC terminal set, condensed, on native CLARABEL;
- ``cones daqp:socp``: the same exact cones by SQP on DAQP (``solvers/daqp_socp.py``), also
  one compiled call per step;
- ``daqp prepared`` and ``socp prepared``: the first and the last, with the next step
  prepared between samples (``OffsetFreeController.prepare_next``, called after the plant
  step with the next set-point): ``step`` is then the time from the measurement to the
  input (feedback, exit gate, observer update), and ``between`` the preparation's own time;

and prints per controller the median, p95 and p99 of the full ``step``, the jitter
p95/median, the medians of ``prepare`` and ``feedback`` (microseconds), of the
preparation ``between`` samples and, for the one-call controllers, of the step's
``python`` time (the step's wall time less the time its records give to the compiled
calls of the step: the Python around them and the call boundary), the ratio of each
median step to the one-call daqp step,
and the largest difference of the applied input to the general daqp path (mL/s: 0 for the
one-call and prepared steps, which compute the same numbers).

acados' SQP-RTI on the same QPs is measured by ``experiments/acados_speed.py``; this script
compares our own paths.

``--alone`` runs each controller's whole loop on its own instead (one after the other): its
caches stay warm between steps, as a single controller's do, so the ``python`` column shows
what a single loop pays; the ratios then compare different times of the machine.

    python experiments/step_speed.py --steps 300 --N 5 20 50
    python experiments/step_speed.py --steps 300 --N 5 20 50 --alone
    python experiments/step_speed.py --steps 15 --N 5
"""

from __future__ import annotations

import argparse
import gc
import os
import time
from dataclasses import replace
from typing import Any

SKIP = 10  # first steps left out of the figures: cold caches, first reference solve


def build_parser() -> argparse.ArgumentParser:
    """The command line (``--help`` answers before numpy and the library are imported)."""
    parser = argparse.ArgumentParser(
        description=__doc__.split("\n\n")[0],
        epilog='Figures: docs/benchmarks.md, "One compiled call per step" (and the sections '
        'after it), and docs/user-guide/compiled.md, "How to measure".',
    )
    parser.add_argument(
        "--steps", type=int, default=300, help=f"closed-loop steps (300; more than {SKIP})"
    )
    parser.add_argument("--N", type=int, nargs="+", default=[5, 20, 50], help="horizons")
    parser.add_argument(
        "--alone",
        action="store_true",
        help="run each controller's loop on its own rather than step by step interleaved "
        "(warm caches, as a single controller runs; ratios then compare different times)",
    )
    return parser


if __name__ == "__main__":
    build_parser().parse_args()  # --help and bad options answer here, before the imports

for _name in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_name, "1")  # before numpy: small products, one thread

import numpy as np  # noqa: E402

from ltv_lstm_mpc import OffsetFreeController  # noqa: E402
from ltv_lstm_mpc.lstm.shipped import load_model  # noqa: E402
from ltv_lstm_mpc.solver_comparison.harness import bench_scenarios  # noqa: E402

#: (label, solver, one_call_step, prepared between samples)
CONTROLLERS = (
    ("daqp one-call", "daqp", True, False),
    ("daqp general", "daqp", False, False),
    ("exact cones", "clarabel", True, False),
    ("cones daqp:socp", "daqp:socp", True, False),
    ("daqp prepared", "daqp", True, True),
    ("socp prepared", "daqp:socp", True, True),
)
REFERENCE = "daqp general"


def run(N: int, steps: int, alone: bool = False) -> dict[str, dict[str, Any]]:
    """Interleaved closed loops of :data:`CONTROLLERS` at horizon ``N`` (``alone``: one
    controller's whole loop after the other's)."""
    model = load_model("ph_lstm_n5.npz")
    scenario = bench_scenarios(model)[0]
    steps = min(steps, len(scenario.setpoints))
    runs = []
    for label, solver, one_call, _ in CONTROLLERS:
        config = replace(scenario.config, N=N, solver=solver)
        ctrl = OffsetFreeController(
            model,
            config,
            setpoint_rate_limit=scenario.setpoint_rate_limit,
            kernels="compiled",
            one_call_step=one_call,
        )
        ctrl.records.reserve(steps + 1)
        runs.append((label, ctrl, scenario.make_plant(model)))
    outputs = [plant.output() for _, _, plant in runs]
    times: list[list[float]] = [[] for _ in runs]
    between: list[list[float]] = [[] for _ in runs]
    prepared = [entry[3] for entry in CONTROLLERS]
    inputs: list[list[float]] = [[] for _ in runs]
    gc.collect()
    gc.disable()
    try:
        if alone:  # each controller's loop on its own: its caches stay warm between steps
            schedule = [(k, j) for j in range(len(runs)) for k in range(steps)]
        else:  # step by step, order alternating ABBA
            schedule = [
                (k, j)
                for k in range(steps)
                for j in (range(len(runs)) if k % 2 == 0 else reversed(range(len(runs))))
            ]
        for k, j in schedule:
            _, ctrl, plant = runs[j]
            t0 = time.perf_counter()
            u = ctrl.step(outputs[j], scenario.setpoints[k])
            times[j].append(time.perf_counter() - t0)
            inputs[j].append(float(u[0]))
            d = scenario.disturbances[k]
            outputs[j] = plant.step(u, None if np.isnan(d) else d)
            if prepared[j] and k + 1 < steps:
                t0 = time.perf_counter()
                ctrl.prepare_next(scenario.setpoints[k + 1])
                between[j].append(time.perf_counter() - t0)
    finally:
        gc.enable()
    skip = SKIP
    out: dict[str, dict[str, Any]] = {}
    for j, (label, ctrl, _) in enumerate(runs):
        records = ctrl.records[skip:]
        mpc = [r.mpc for r in records]
        # time inside the compiled calls of the step (a prepared step: its feedback half)
        inside = [r.time_total - (r.time_reference + r.mpc.prepare_time) for r in records]
        if not prepared[j]:
            inside = [r.time_total for r in records]
        out[label] = {
            "python": np.array(times[j][skip:]) - np.array(inside),
            "total": np.array(times[j][skip:]),
            "prepare": np.array([s.prepare_time for s in mpc]),
            "feedback": np.array([s.feedback_time for s in mpc]),
            "between": np.array(between[j][skip:]),
            "u": np.array(inputs[j]),
            "one_call": ctrl.one_call,
        }
    return out


def report(N: int, result: dict[str, dict[str, Any]]) -> None:
    """Print one horizon's table."""
    base = float(np.median(result["daqp one-call"]["total"]))
    reference = result[REFERENCE]["u"]
    print(f"\nN = {N} (microseconds; ratio: median step / daqp one-call)")
    print(
        f"{'controller':>14} {'median':>8} {'p95':>8} {'p99':>8} {'p95/med':>8} "
        f"{'prepare':>8} {'feedback':>8} {'between':>8} {'python':>7} {'ratio':>6} "
        f"{'max |du|':>9}"
    )
    for label, data in result.items():
        total = data["total"] * 1e6
        median = float(np.median(total))
        p95, p99 = (float(v) for v in np.percentile(total, [95, 99]))
        gap = float(np.abs(data["u"] - reference).max())
        between = f"{np.median(data['between']) * 1e6:8.1f}" if data["between"].size else " " * 8
        python = f"{np.median(data['python']) * 1e6:7.1f}" if data["one_call"] else " " * 7
        print(
            f"{label:>14} {median:8.1f} {p95:8.1f} {p99:8.1f} {p95 / median:8.2f} "
            f"{np.median(data['prepare']) * 1e6:8.1f} {np.median(data['feedback']) * 1e6:8.1f} "
            f"{between} {python} {median / (base * 1e6):6.2f} {gap:9.1e}"
        )
    cones = float(np.median(result["exact cones"]["total"]))
    socp = float(np.median(result["cones daqp:socp"]["total"]))
    general = float(np.median(result["daqp general"]["total"]))
    latency = float(np.median(result["daqp prepared"]["total"]))
    print(
        f"exact cones: clarabel / daqp one-call = {cones / base:.2f}, daqp:socp / daqp "
        f"one-call = {socp / base:.2f}; daqp general / daqp one-call = {general / base:.2f}; "
        f"prepared step (measurement to input) / daqp one-call = {latency / base:.2f}"
    )


def main() -> None:
    parser = build_parser()
    args = parser.parse_args()
    if args.steps <= SKIP:
        parser.error(f"--steps must be more than {SKIP} (the first {SKIP} are left out)")
    for N in args.N:
        report(N, run(N, args.steps, args.alone))


if __name__ == "__main__":
    main()
