"""The exported C step on the host against the library's one-call step, per step.

The paper's scenario 3 on the pH plant (set-point jumps, steps on the infeasibility
policy) at each horizon: the library's closed loop is run once (the reference engine) for
its measurements and set-points; then, in this one run, a fresh controller on the default
engine (the one-call compiled step) and the exported C step built with ``gcc -O2``
(``ltv_lstm_mpc.export.pil``, ``-DPIL_TIMING``) replay them, each step timed (best of
``--repeats`` replays; Python: ``time.perf_counter`` around ``controller.step``, C:
``CLOCK_MONOTONIC`` around ``<prefix>_controller_step``). Prints the median, p95 and max
per horizon and the ratios C / Python, and checks both give the same inputs.

With ``--acados DIR`` (acados built from source with DAQP, as ``experiments/acados_speed.py``
describes), acados' SQP-RTI with full condensing and DAQP (``FULL_CONDENSING_DAQP``) is timed
in the same run: a fresh controller replays the steps again and, after each step from k = 1
on, acados is fed that step's data (``acados_speed.feed``: the same linearization point,
set-points, tightened bounds and terminal box) and its ``solve()`` is timed (the Python call;
best of ``--repeats`` per step). acados' time covers its MPC step only (linearization,
condensing, QP), not an observer or a reference calculator; where ours took the
infeasibility policy, acados' solve fails (it has no policy) and is timed all the same.

With ``--float``, the C step exported in single precision is timed too (host build as for
the Cortex-M4F comparison). With ``--solver daqp:socp``, both steps solve the exact
terminal cones (the SQP on DAQP) instead of the box.

    python experiments/export_speed.py [--N 5 20 50] [--steps 600] [--repeats 3] \
        [--cflags "-O2"] [--float] [--acados DIR] [--solver daqp|daqp:socp]
"""

from __future__ import annotations

import argparse
import os
import tempfile
import time
from pathlib import Path
from typing import Any


def build_parser() -> argparse.ArgumentParser:
    """The command line (``--help`` answers before numpy and the library are imported)."""
    parser = argparse.ArgumentParser(
        description=__doc__.split("\n\n")[0],
        epilog='Figures: docs/user-guide/export-c.md, "Speed on the host". Smallest run: '
        "--N 5 --steps 30 --repeats 1.",
    )
    parser.add_argument("--N", type=int, nargs="+", default=[5, 20, 50], help="horizons")
    parser.add_argument("--steps", type=int, default=600, help="steps replayed (600)")
    parser.add_argument("--repeats", type=int, default=3, help="replays timed, best kept (3)")
    parser.add_argument(
        "--cflags", default="-O2", help='the C step\'s optimization flags ("-O2"; e.g. "-O3")'
    )
    parser.add_argument(
        "--float", action="store_true",
        help="also the C step exported in single precision (float) on the host",
    )  # fmt: skip
    parser.add_argument(
        "--solver", choices=["daqp", "daqp:socp"], default="daqp",
        help="daqp (the terminal box, default) or daqp:socp (the exact cones by SQP on DAQP; "
        "without --float and --acados, which solve the box)",
    )  # fmt: skip
    parser.add_argument(
        "--acados", type=Path, default=None,
        help="an acados source tree built with DAQP (experiments/acados_speed.py): time its "
        "SQP-RTI solve() in the same run",
    )  # fmt: skip
    return parser


if __name__ == "__main__":
    build_parser().parse_args()

for _name in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_name, "1")

from dataclasses import replace  # noqa: E402

import numpy as np  # noqa: E402

from ltv_lstm_mpc import OffsetFreeController, simulate  # noqa: E402
from ltv_lstm_mpc.export import export_model_c  # noqa: E402
from ltv_lstm_mpc.export.pil import run_step_host, write_step_replay  # noqa: E402
from ltv_lstm_mpc.lstm.shipped import load_model  # noqa: E402
from ltv_lstm_mpc.paper.scenarios import paper_scenarios  # noqa: E402


def python_times(model: Any, config: Any, limit: Any, sim: Any, repeats: int) -> Any:
    """Each step's best time over ``repeats`` replays through a fresh controller on the
    default engine, and the inputs of the last replay."""
    best = np.full(len(sim.y_phi), np.inf)
    inputs = np.zeros_like(sim.u_phi)
    for _ in range(repeats):
        controller = OffsetFreeController(model, config, setpoint_rate_limit=limit,
                                          kernels="compiled")  # fmt: skip
        for k, (y, y0) in enumerate(zip(sim.y_phi, sim.y0_phi, strict=True)):
            start = time.perf_counter()
            inputs[k] = controller.step(y, y0)
            best[k] = min(best[k], time.perf_counter() - start)
    return best, inputs, controller.engine.name


def acados_times(acados: Any, model: Any, config: Any, limit: Any, sim: Any, repeats: int,
                 folder: Path) -> tuple[Any, int]:  # fmt: skip
    """acados' ``solve()`` per step from k = 1 on (best of ``repeats``; module docstring) and
    how many of its solves failed (last replay)."""
    from acados_speed import build_solver, feed  # experiments/ is the script's folder

    from ltv_lstm_mpc.mpc.nmpc import casadi_dynamics

    def new_controller() -> Any:
        return OffsetFreeController(model, config, setpoint_rate_limit=limit,
                                    kernels="compiled")  # fmt: skip

    solver = build_solver(acados, model, new_controller(), "FULL_CONDENSING_DAQP", folder)
    dynamics = casadi_dynamics(model)
    best = np.full(len(sim.y_phi), np.inf)
    failed = 0
    for _ in range(repeats):
        controller, failed = new_controller(), 0
        for k, (y, y0) in enumerate(zip(sim.y_phi, sim.y0_phi, strict=True)):
            controller.step(y, y0)
            if k == 0:
                continue
            feed(solver, controller, model, dynamics)
            start = time.perf_counter()
            status = solver.solve()
            best[k] = min(best[k], time.perf_counter() - start)
            failed += int(status != 0)
    return best, failed


def stats(seconds: Any) -> tuple[float, float, float]:
    """Median, p95 and max over the steps after the first, us."""
    tail = 1e6 * np.asarray(seconds)[1:]
    return float(np.median(tail)), float(np.percentile(tail, 95)), float(tail.max())


def main() -> None:
    parser = build_parser()
    args = parser.parse_args()
    if args.solver != "daqp" and (args.float or args.acados is not None):
        parser.error(
            f"--solver {args.solver} goes without --float and --acados (the exact cones are "
            "exported in double precision; acados solves the terminal box): drop them"
        )
    model = load_model("ph_lstm_n5.npz")
    scenario = paper_scenarios(model)[2]
    acados = None
    if args.acados is not None:
        from acados_speed import load_acados  # experiments/ is the script's folder

        acados = load_acados(args.acados.resolve())
    else:
        print("acados: not in this run (--acados DIR: experiments/acados_speed.py)")
    print(
        f"solver {args.solver}\n{'N':>3} {'engine':<9} {'median us':>9} {'p95 us':>8} "
        f"{'max us':>8}   "
        f"C / Python: median, p95, max   inputs |C - Python|"
    )
    for N in args.N:
        config = replace(scenario.config, solver=args.solver, N=N)
        limit = scenario.setpoint_rate_limit
        reference = OffsetFreeController(model, config, setpoint_rate_limit=limit,
                                         one_call_step=False)  # fmt: skip
        plant = scenario.make_plant(model, reference.certification)
        sim = simulate(plant, reference, scenario.setpoints, scenario.disturbances, args.steps,
                       progress=False)  # fmt: skip
        py_seconds, py_inputs, engine = python_times(model, config, limit, sim, args.repeats)
        with tempfile.TemporaryDirectory() as scratch:
            exported = export_model_c(model, Path(scratch), controller=reference, prefix="c")
            main_c = write_step_replay(exported, sim.y_phi, sim.y0_phi)
            c = run_step_host(main_c, exported, timing_repeats=args.repeats,
                              cflags=tuple(args.cflags.split()))  # fmt: skip
            single = None
            if args.float:
                folder = Path(scratch) / "float"
                folder.mkdir()
                exported_f = export_model_c(model, folder, controller=reference, prefix="c",
                                            precision="single")  # fmt: skip
                single = run_step_host(
                    write_step_replay(exported_f, sim.y_phi, sim.y0_phi), exported_f,
                    timing_repeats=args.repeats, cflags=tuple(args.cflags.split()),
                )  # fmt: skip
            if acados is not None:
                cwd = os.getcwd()
                os.chdir(scratch)  # acados writes some files next to the caller
                try:
                    theirs, failed = acados_times(acados, model, config, limit, sim,
                                                  args.repeats, Path(scratch))  # fmt: skip
                finally:
                    os.chdir(cwd)
        python, native = stats(py_seconds), stats(c.seconds)
        gap = float(np.abs(c.u_phi - py_inputs).max())
        print(f"{N:>3} {engine:<9} {python[0]:>9.1f} {python[1]:>8.1f} {python[2]:>8.1f}")
        print(
            f"{N:>3} {'C (gcc)':<9} {native[0]:>9.1f} {native[1]:>8.1f} {native[2]:>8.1f}   "
            f"{native[0] / python[0]:.2f}, {native[1] / python[1]:.2f}, "
            f"{native[2] / python[2]:.2f}   {gap:.1e}",
            flush=True,
        )
        if single is not None:
            floats = stats(single.seconds)
            scale = max(1.0, float(np.abs(py_inputs).max()))
            print(
                f"{N:>3} {'C float':<9} {floats[0]:>9.1f} {floats[1]:>8.1f} {floats[2]:>8.1f}   "
                f"{floats[0] / python[0]:.2f}, {floats[1] / python[1]:.2f}, "
                f"{floats[2] / python[2]:.2f}   "
                f"{float(np.abs(single.u_phi - py_inputs).max()) / scale:.1e} (relative); "
                f"float / double median {floats[0] / native[0]:.2f}",
                flush=True,
            )
        if acados is not None:
            other = stats(theirs)
            print(
                f"{N:>3} {'acados':<9} {other[0]:>9.1f} {other[1]:>8.1f} {other[2]:>8.1f}   "
                f"C / acados: {native[0] / other[0]:.2f}, {native[1] / other[1]:.2f}, "
                f"{native[2] / other[2]:.2f}   (FULL_CONDENSING_DAQP; {failed} failed solves, "
                "ours on the policy)",
                flush=True,
            )


if __name__ == "__main__":
    main()
