"""The worst case of the controller step: its tail over closed loops with infeasible steps.

A real-time controller's sampling period is set by its slowest step, not its median. This
runs, per solver and horizon, closed loops that leave the nominal path (the paper's
scenario 3: set-point steps without a rate limiter, whose infeasible instants take the
infeasibility policy; the same with its set-point levels cycled every 40 samples, for
more of them; bench's scenario 1 beside it, where every step is nominal), timing
each whole ``OffsetFreeController.step`` (the first 10 steps of each loop left out), and
prints per run:

- the median, p95, p99 and largest step (us) and p99 / median, max / median;
- the steps that took the infeasibility policy (a fallback: the nominal subproblem was
  infeasible) and their own median, against the nominal steps' median;
- the steps that left the one-call compiled engine for the reference engine (handed over:
  ``ControllerStep.engine == "reference"``; before the worst-case work every fallback
  step and the reference calculator's damped Newton did), with their median;
- the largest time of the reference calculator in a step (us; at a set-point step whose
  warm chord fails, the damped Newton with restarts);
- with ``--repeats 3`` or more, a second row: the same statistics of each step's smallest
  time over the repeats (the loop is deterministic, so step k does the same work in every
  repeat; the machine's noise seldom hits one step in all of them: the work's own tail,
  what an isolated core would show), and the fallback steps' median over the nominal one;
- the slowest step: its index k, its observer, reference calculator and MPC times (us,
  from its record) and the MPC's policy (``nominal`` or the infeasibility policy), which
  say what set the max (a set-point step whose warm chord fails runs the damped Newton
  in the reference calculator; an infeasible step the policy in the MPC).

With ``--parts``, each ``daqp:socp`` run also prints its fallback steps split: the failed
nominal SQP and the paper policy's SQP, each re-solved cold from the step's record
(:func:`fallback_parts`), against the fallback steps' median.

Per solver and horizon it also prints the first steps: the first step after the
controller's construction and the one after it, then the same after a ``reset()`` (the
median of 5 resets), and which engine ran them (the first step has run in the one call
since the worst-case work; before, on the reference engine).

The first 10 steps aside, the targets of the worst-case work are p99 / median <= 1.5 and
max / median <= 3 on a run where at least 5 % of the steps fall back, and a fallback step
within 2x the nominal median. The machine's own jitter is in every tail: read it against
a step that does fixed work (``experiments/gc_jitter.py``) or a C solver timed in the same
run (``experiments/acados_speed.py``).

    python experiments/worst_case.py [--solvers daqp daqp:socp] [--N 5 20 50] [--steps 2400]
"""

from __future__ import annotations

import argparse
import gc
import os
import time
from dataclasses import replace
from typing import Any


def build_parser() -> argparse.ArgumentParser:
    """The command line (``--help`` answers before numpy and the library are imported)."""
    parser = argparse.ArgumentParser(
        description=__doc__.split("\n\n")[0],
        epilog='Figures: docs/benchmarks.md, "The worst case". Smallest run: --N 5 --steps 40 '
        "--solvers daqp.",
    )
    parser.add_argument("--solvers", nargs="+", default=["daqp", "daqp:socp"])
    parser.add_argument("--N", type=int, nargs="+", default=[5, 20, 50], help="horizons")
    parser.add_argument(
        "--steps",
        type=int,
        default=2400,
        help="closed-loop steps of scenario 3 (at most its 2400; bench's scenario 1: 300)",
    )
    parser.add_argument("--repeats", type=int, default=1, help="closed loops per run, pooled")
    parser.add_argument(
        "--parts",
        action="store_true",
        help="daqp:socp: also split the fallback steps of each run (failed SQP, policy's SQP)",
    )
    return parser


if __name__ == "__main__":
    build_parser().parse_args()  # --help and bad options answer here, before the imports

for _name in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_name, "1")

import numpy as np  # noqa: E402

from ltv_lstm_mpc import OffsetFreeController  # noqa: E402
from ltv_lstm_mpc.lstm.shipped import load_model  # noqa: E402
from ltv_lstm_mpc.paper.scenarios import paper_scenarios  # noqa: E402
from ltv_lstm_mpc.solver_comparison.harness import bench_scenarios  # noqa: E402

SKIP = 10
#: The controller of the last closed loop (``--parts`` reads its failed solves' records).
records_owner: list[Any] = []


def closed_loop(scenario: Any, model: Any, solver: str, N: int, steps: int) -> tuple[Any, Any]:
    """One closed loop: (step times in s, records), the first ``SKIP`` steps left out."""
    config = replace(scenario.config, solver=solver, N=N)
    controller = OffsetFreeController(
        model, config, setpoint_rate_limit=scenario.setpoint_rate_limit
    )
    plant = scenario.make_plant(model)
    controller.records.reserve(steps + 1)
    y = plant.output()
    times = np.empty(steps)
    gc.collect()
    gc.disable()
    try:
        for k in range(steps):
            start = time.perf_counter()
            u = controller.step(y, scenario.setpoints[k])
            times[k] = time.perf_counter() - start
            d = scenario.disturbances[k]
            y = plant.step(u, None if np.isnan(d) else d)
    finally:
        gc.enable()
    records_owner[:] = [controller]
    return times[SKIP:], controller.records[SKIP:]


def first_steps(scenario: Any, model: Any, solver: str, N: int, resets: int = 5) -> str:
    """The first two steps' times (us) after construction and after a reset (median of
    ``resets``), with the engines that ran them: one line of the output."""
    config = replace(scenario.config, solver=solver, N=N)
    controller = OffsetFreeController(
        model, config, setpoint_rate_limit=scenario.setpoint_rate_limit
    )
    times = []
    for run in range(resets + 1):
        if run:
            controller.reset()
        plant = scenario.make_plant(model)
        y = plant.output()
        pair = []
        for k in range(2):
            start = time.perf_counter()
            u = controller.step(y, scenario.setpoints[k])
            pair.append(time.perf_counter() - start)
            y = plant.step(u, None)
        times.append(pair)
    us = np.array(times) * 1e6
    engines = "/".join(record.engine for record in list(controller.records)[:2])
    return (
        f"{solver} N={N} first steps (us): after construction {us[0, 0]:.1f}, then "
        f"{us[0, 1]:.1f}; after a reset (median of {resets}) {np.median(us[1:, 0]):.1f}, then "
        f"{np.median(us[1:, 1]):.1f}; engines {engines}"
    )


def report(label: str, times: Any, records: Any, per_loop: int) -> None:
    """One row of the table (module docstring); ``per_loop``: timed steps per closed loop."""
    us = times * 1e6
    median = float(np.median(us))
    fallback = np.array([not r.mpc.feasible for r in records])
    reference = np.array([r.engine == "reference" for r in records])
    p95, p99, largest = np.percentile(us, 95), np.percentile(us, 99), float(us.max())

    def median_of(mask: Any) -> str:
        return f"{np.median(us[mask]):7.1f}" if mask.any() else "      -"

    nominal = float(np.median(us[~fallback])) if (~fallback).any() else float("nan")
    ratio = np.median(us[fallback]) / nominal if fallback.any() else float("nan")
    slowest = int(np.argmax(us))
    r = records[slowest]
    reference_us = np.array([rec.time_reference for rec in records]) * 1e6
    print(
        f"{label:<36} {median:7.1f} {p95:7.1f} {p99:7.1f} {largest:8.1f} | "
        f"{p99 / median:5.2f} {largest / median:6.2f} | {fallback.sum():4d} "
        f"({100 * fallback.mean():4.1f} %) {median_of(fallback)} {ratio:5.2f} | "
        f"{reference.sum():4d} {median_of(reference)} | {reference_us.max():7.1f} | "
        f"k={SKIP + slowest % per_loop} "
        f"{r.time_observer * 1e6:.0f}/{r.time_reference * 1e6:.0f}/{r.time_mpc * 1e6:.0f} "
        f"{r.mpc.policy}"
    )


def quiet(times: Any, loops: Any) -> None:
    """With three repeats or more: the tail of each step's smallest time over the repeats
    (the loop is deterministic, so step k does the same work in every repeat, and the
    machine's noise seldom hits one step in all of them: the work's own tail, what an
    isolated core would show); ``times`` (repeats, steps), ``loops`` their records."""
    fallback = np.array([not r.mpc.feasible for r in loops[0]])
    same = all(np.array_equal(fallback, np.array([not r.mpc.feasible for r in rs])) for rs in loops)
    us = times.min(axis=0) * 1e6
    median = float(np.median(us))
    p99, largest = float(np.percentile(us, 99)), float(us.max())
    ratio = (
        np.median(us[fallback]) / np.median(us[~fallback])
        if fallback.any() and (~fallback).any()
        else float("nan")
    )
    print(
        f"{'  per-step minimum of ' + str(times.shape[0]) + ' repeats':<36} {median:7.1f} "
        f"{'':>7} {p99:7.1f} {largest:8.1f} | {p99 / median:5.2f} {largest / median:6.2f} | "
        f"fallback / nominal {ratio:5.2f}" + ("" if same else " (fallbacks differ by repeat)")
    )


def fallback_parts(scenario: Any, model: Any, N: int, steps: int) -> str:
    """``daqp:socp``'s fallback steps split (``--parts``; the ``"paper"`` policy, the
    scenarios' own): one more closed loop, then, in step order, each failed nominal solve
    re-solved cold from its record's copy of the SQP's arrays (the problem, and the
    epigraph prediction the copy keeps, the one its solve left), and the paper policy's
    problem (the same cost and bounds, the cones ``c_N``, ``h_N`` alone: no output rows, no
    terminal set) from the prediction the policy's solve before left, as the step's
    session carries it. Each time is the smallest of 5 solves; the first ``SKIP`` steps
    are left out, as in the table. One line: their medians (us), the SQP and DAQP
    iterations, how many nominal re-solves end as the step's solve did (its exit flag
    and SQP iterations in the record), and the fallback steps' median with the rest of it:
    the preparation, the pre-check, writing the two problems, the policy's plan, the
    failure's copy and the record, and what separates a step's own solves from the best of
    5 cold re-solves (caches)."""
    from ltv_lstm_mpc.solvers.daqp_socp import native, problem_workspace, snapshot_qp
    from ltv_lstm_mpc.solvers.dense import DenseQP
    from ltv_lstm_mpc.solvers.socp_sqp import (
        MAX_ITERATIONS,
        snapshot_views,
        socp_solve,
    )
    from ltv_lstm_mpc.solvers.tolerances import solver_options

    from ltv_lstm_mpc.loop.compiled_step import FAILURE_FLAG_COLUMN, FAILURE_SQP_COLUMN

    config = replace(scenario.config, solver="daqp:socp", N=N)
    if config.infeasibility_policy != "paper":
        return f"  (--parts: the paper policy only, not {config.infeasibility_policy!r})"
    times, records = closed_loop(scenario, model, "daqp:socp", N, steps)
    controller = records_owner[0]
    options = solver_options("daqp", config.tolerance, dict(config.solver_settings))
    buffers = native(options)
    template = controller.mpc.one_call_parts().socp_arrays
    integer = controller.records.rows.integer

    def timed(qp: Any, first_active: Any) -> tuple[float, tuple[int, int, int], Any]:
        """(the smallest time of 5 cold solves, (flag, SQP, DAQP iterations), the
        epigraph prediction the solve leaves)."""
        best, outcome, left = float("inf"), (0, 0, 0), first_active
        for _ in range(5):
            ws, arrays = problem_workspace(qp, buffers)
            arrays["first_active"][...] = first_active
            start = time.perf_counter()
            flag, sqp, iterations, _violation, _seconds = socp_solve(ws, False, MAX_ITERATIONS)
            best = min(best, time.perf_counter() - start)
            outcome, left = (int(flag), int(sqp), int(iterations)), arrays["first_active"].copy()
        return best, outcome, left

    failed, policy, outcomes, policy_sqp = [], [], [], []
    same = 0
    prediction = np.zeros(2, dtype=np.int64)  # the policy's session starts without one
    for k in sorted(controller.records.extras):
        real, copied = controller.records.extras[k]
        views = snapshot_views(real, copied, template)
        qp = snapshot_qp(views)
        paper = DenseQP(
            H=qp.H, f=qp.f, A=np.zeros((0, qp.H.shape[0])), lo=np.zeros(0), up=np.zeros(0),
            lb=qp.lb, ub=qp.ub, cones=qp.cones[:2],
        )  # fmt: skip
        spent, policy_outcome, prediction = timed(paper, prediction)
        if k < SKIP:  # (as the steps timed; the policy's prediction carried on)
            continue
        seconds, outcome, _ = timed(qp, views["first_active"])
        failed.append(seconds)
        outcomes.append(outcome)
        recorded = (int(integer[k, FAILURE_FLAG_COLUMN]), int(integer[k, FAILURE_SQP_COLUMN]))
        same += outcome[:2] == recorded
        policy.append(spent)
        policy_sqp.append(policy_outcome[1])
    if not failed:
        return "  fallback parts: no failed nominal solve"
    fallback = np.array([not r.mpc.feasible for r in records])
    step = float(np.median(times[fallback])) * 1e6 if fallback.any() else float("nan")
    us_failed, us_policy = np.median(failed) * 1e6, np.median(policy) * 1e6
    sqp = [o[1] for o in outcomes]
    daqp = [o[2] for o in outcomes]
    return (
        f"  fallback parts (us, medians of {len(failed)}): failed nominal SQP {us_failed:.1f} "
        f"({min(sqp)}-{max(sqp)} SQP, {min(daqp)}-{max(daqp)} DAQP iterations; {same} end as "
        f"the step's), paper policy's SQP {us_policy:.1f} ({min(policy_sqp)}-"
        f"{max(policy_sqp)} SQP iterations); the fallback step's median {step:.1f} (the rest "
        f"{step - us_failed - us_policy:.1f}), the nominal one's "
        f"{float(np.median(times[~fallback])) * 1e6:.1f}"
    )


def main() -> None:
    args = build_parser().parse_args()
    model = load_model("ph_lstm_n5.npz")
    scenario3 = paper_scenarios(model)[2]
    runs = [
        ("scenario 3", scenario3, args.steps),
        ("scenario 3, steps/40", scenario3.cycled(40), args.steps),
        ("bench 1", bench_scenarios(model)[0], min(args.steps, 300)),
    ]
    print(
        f"{'run (us; first ' + str(SKIP) + ' steps aside)':<36} {'median':>7} {'p95':>7} "
        f"{'p99':>7} {'max':>8} | {'p99/':>5} {'max/':>6} | fallback steps, median, "
        "/ nominal | handed over, median | largest reference calculator | the slowest step: k, "
        "observer/reference/MPC (us), policy"
    )
    for solver in args.solvers:
        for N in args.N:
            print(first_steps(scenario3, model, solver, N))
            for name, scenario, steps in runs:
                steps = min(steps, scenario.steps)
                pooled = [
                    closed_loop(scenario, model, solver, N, steps) for _ in range(args.repeats)
                ]
                times = np.concatenate([t for t, _ in pooled])
                records = [r for _, rs in pooled for r in rs]
                report(f"{solver} N={N} {name}", times, records, steps - SKIP)
                if args.repeats >= 3:
                    quiet(np.stack([t for t, _ in pooled]), [rs for _, rs in pooled])
                if args.parts and solver == "daqp:socp":
                    print(fallback_parts(scenario, model, N, steps))


if __name__ == "__main__":
    main()
