"""Where the time of one controller step goes (the profile behind the speed targets).

Runs bench's scenario 1 (short) with ``OffsetFreeController(model, MPCConfig(solver=...))``
and prints

1. the split of the median step into observer, reference calculator, MPC prepare, MPC
   feedback (solver call inside it) and the rest (controller bookkeeping), from the
   controller's own per-step records (no profiler attached, microseconds);
2. a cProfile of the same loop: the functions with the most own time per step. cProfile
   adds about 1 us per Python call, so this table overstates Python-heavy code; read it
   for *where* the time goes, and part 1 for how much.

    python experiments/step_profile.py --solver daqp --N 5 --steps 300
    python experiments/step_profile.py --solver daqp --N 5 --steps 15 --top 5
"""

from __future__ import annotations

import argparse
import cProfile
import os
import pstats
import time
from dataclasses import replace

SKIP = 10  # first steps left out of part 1


def build_parser() -> argparse.ArgumentParser:
    """The command line (``--help`` answers before numpy and the library are imported)."""
    parser = argparse.ArgumentParser(
        description=__doc__.split("\n\n")[0],
        epilog='Figures: docs/benchmarks.md, "The compiled step" (where the step goes), and '
        'docs/user-guide/compiled.md, "How to measure".',
    )
    parser.add_argument("--solver", default="daqp")
    parser.add_argument("--N", type=int, default=5, help="horizon (5)")
    parser.add_argument(
        "--steps", type=int, default=300, help=f"closed-loop steps (300; more than {SKIP})"
    )
    parser.add_argument("--top", type=int, default=25, help="functions listed (25)")
    return parser


if __name__ == "__main__":
    build_parser().parse_args()  # --help and bad options answer here, before the imports

for _name in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_name, "1")  # before numpy: small products, one thread

import numpy as np  # noqa: E402

from ltv_lstm_mpc import OffsetFreeController  # noqa: E402
from ltv_lstm_mpc.lstm.shipped import load_model  # noqa: E402
from ltv_lstm_mpc.solver_comparison.harness import bench_scenarios  # noqa: E402


def loop(
    solver: str, N: int, steps: int, profiler: cProfile.Profile | None = None
) -> tuple[OffsetFreeController, list[float]]:
    """One closed loop; returns the controller and the wall time of each step (``profiler``:
    enabled around each ``step`` call only, not the construction or the plant)."""
    model = load_model("ph_lstm_n5.npz")
    scenario = bench_scenarios(model)[0]
    config = replace(scenario.config, N=N, solver=solver)
    ctrl = OffsetFreeController(
        model, config, setpoint_rate_limit=scenario.setpoint_rate_limit, kernels="compiled"
    )
    plant = scenario.make_plant(model)
    y = plant.output()
    times = []
    for k in range(min(steps, len(scenario.setpoints))):
        if profiler is not None:
            profiler.enable()
        t0 = time.perf_counter()
        u = ctrl.step(y, scenario.setpoints[k])
        times.append(time.perf_counter() - t0)
        if profiler is not None:
            profiler.disable()
        d = scenario.disturbances[k]
        y = plant.step(u, None if np.isnan(d) else d)
    return ctrl, times


def main() -> None:
    parser = build_parser()
    args = parser.parse_args()
    if args.steps <= SKIP:
        parser.error(f"--steps must be more than {SKIP} (the first {SKIP} are left out)")
    loop(args.solver, args.N, 20)  # JIT caches, imports
    ctrl, times = loop(args.solver, args.N, args.steps)
    skip = SKIP
    records = ctrl.records[skip:]
    us = 1e6

    def med(values: list[float]) -> float:
        return us * float(np.median(values))

    step = med(times[skip:])
    parts = {
        "observer": med([r.time_observer for r in records]),
        "reference calculator": med([r.time_reference for r in records]),
        "MPC prepare": med([r.mpc.prepare_time for r in records]),
        "MPC feedback": med([r.mpc.feedback_time for r in records]),
        "  of which the solver call": med([r.mpc.solver_time for r in records]),
    }
    print(f"{args.solver}, N = {args.N}: median step {step:.0f} us over {len(records)} steps")
    for name, value in parts.items():
        print(f"  {name:<28} {value:7.1f} us")
    rest = step - sum(v for k, v in parts.items() if not k.startswith(" "))
    print(f"  {'rest (controller, records)':<28} {rest:7.1f} us")

    profiler = cProfile.Profile()
    _, ptimes = loop(args.solver, args.N, args.steps, profiler)
    n_steps = len(ptimes)
    stats = pstats.Stats(profiler)
    rows = []
    for (filename, line, name), (_cc, nc, tt, ct, _callers) in stats.stats.items():  # type: ignore[attr-defined]
        rows.append(
            (
                tt / n_steps * us,
                ct / n_steps * us,
                nc / n_steps,
                f"{os.path.basename(filename)}:{line} {name}",
            )
        )
    rows.sort(reverse=True)
    print(f"\ncProfile, per step ({n_steps} steps, profiled step {med(ptimes):.0f} us):")
    print(f"{'own us':>8} {'cum us':>8} {'calls':>6}  function")
    for own, cum, calls, label in rows[: args.top]:
        print(f"{own:8.1f} {cum:8.1f} {calls:6.1f}  {label}")


if __name__ == "__main__":
    main()
