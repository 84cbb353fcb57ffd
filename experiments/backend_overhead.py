"""Python call overhead of each dense QP backend on the controller's own condensed QPs.

The QPs are those of scenario 1's closed loop (``OffsetFreeController`` with DAQP, the
condensed transcription) at N = 5 and N = 20, captured at a few states. For every
backend with a dense session the script times, on the same QP, side by side:

- ``solve_point``: the hot-loop call of ``DenseSession`` (what the controller uses);
- ``solve``: the full call that builds a ``Solution`` (duals, objective, timings);
- the solver's own reported solve time (``Solution.solve_time``) where it reports one
  (for DAQP, which reports none here, the bare ``daqp.solve`` call),

and prints the medians (microseconds) and the Python overhead ``solve_point - reported``.
A second table times DAQP's entry points on the same QPs: ``daqp.solve`` (the package's
Python call), ``DaqpNative.solve`` (numba dispatch + DAQP's C ``daqp_quadprog``, the call
the controller's compiled feedback makes without the dispatch) and DAQP's own clock
(setup + solve) of that C call.

    python experiments/backend_overhead.py
    python experiments/backend_overhead.py --N 5 --solvers daqp --states 1 --repeats 5
"""

from __future__ import annotations

import argparse
import os
import time
from dataclasses import replace


def build_parser() -> argparse.ArgumentParser:
    """The command line (``--help`` answers before numpy and the library are imported)."""
    parser = argparse.ArgumentParser(
        description=__doc__.split("\n\n")[0],
        epilog='Figures: docs/benchmarks.md, "The compiled step" (backend overhead), and '
        'docs/user-guide/compiled.md, "How to measure".',
    )
    parser.add_argument("--N", type=int, nargs="+", default=[5, 20], help="horizons (5 20)")
    parser.add_argument(
        "--solvers",
        nargs="+",
        default=None,
        help="dense backends (default: every installed one with a native dense session)",
    )
    parser.add_argument(
        "--states", type=int, default=5, help="QPs captured per horizon, from 40 steps (5)"
    )
    parser.add_argument(
        "--repeats",
        type=int,
        default=None,
        help="timed calls per QP (default: 200, and 300 for the DAQP entry points)",
    )
    return parser


if __name__ == "__main__":
    build_parser().parse_args()  # --help and bad options answer here, before the imports

for _name in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_name, "1")

import numpy as np  # noqa: E402
from ltv_lstm_mpc.solvers import DenseQP, DenseSession, available_solvers, solver_info  # noqa: E402

from ltv_lstm_mpc import OffsetFreeController, RobustMPC, load_model  # noqa: E402
from ltv_lstm_mpc.solver_comparison.harness import bench_scenarios  # noqa: E402


def captured_qps(N: int, count: int = 5) -> list[DenseQP]:
    """Nominal condensed QPs of scenario 1 at ``count`` states of its first 40 steps."""
    model = load_model("ph_lstm_n5.npz")
    scenario = bench_scenarios(model)[0]
    config = replace(scenario.config, N=N, solver="daqp")
    # the general feedback path fills the session's DenseQP (the one-call path does not)
    mpc = RobustMPC(model, config, native_feedback=False)
    controller = OffsetFreeController(model, config, setpoint_rate_limit=0.01, mpc=mpc)
    plant = scenario.make_plant(model)
    y = plant.output()
    qps = []
    every = 40 // count
    for k in range(every * (count - 1) + 1):
        u = controller.step(y, scenario.setpoints[k])
        if k % every == 0:
            qps.append(mpc.last_problem("nominal"))  # a copy of the QP DAQP solved
        y = plant.step(u)
    return qps


def _daqp_data(qp: DenseQP) -> tuple[np.ndarray, ...]:
    """``(H, f, A, bupper, blower, sense)`` of ``qp`` as DAQP wants them (bounds stacked)."""
    upper = np.concatenate([qp.ub, qp.up])
    lower = np.concatenate([qp.lb, qp.lo])
    sense = np.zeros(upper.shape[0], dtype=np.intc)
    return np.ascontiguousarray(qp.H), qp.f, np.ascontiguousarray(qp.A), upper, lower, sense


def _raw_daqp(qp: DenseQP):  # type: ignore[no-untyped-def]
    """The bare ``daqp.solve`` call on ``qp``."""
    import daqp

    data = _daqp_data(qp)
    return lambda: daqp.solve(*data, primal_tol=1e-8, dual_tol=1e-8)


def daqp_entry_points(qps: list[DenseQP], repeats: int = 300) -> tuple[float, float, float]:
    """Medians (us) of ``daqp.solve``, ``DaqpNative.solve`` and DAQP's own clock."""
    from ltv_lstm_mpc.solvers import daqp_native

    native = daqp_native.native({"primal_tol": 1e-8, "dual_tol": 1e-8})
    if native is None:
        raise SystemExit(f"DAQP not bound natively: {daqp_native.unavailable_reason}")
    python_call, numba_call, clock = [], [], []
    for qp in qps:
        data = _daqp_data(qp)
        python_call.append(median_us(_raw_daqp(qp), repeats))
        numba_call.append(median_us(lambda: native.solve(*data), repeats))  # noqa: B023
        clock.append(1e6 * daqp_native.solver_seconds(native.result))
    return tuple(float(np.median(v)) for v in (python_call, numba_call, clock))  # type: ignore[return-value]


def median_us(function, repeats: int) -> float:  # type: ignore[no-untyped-def]
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        function()
        times.append(time.perf_counter() - start)
    return 1e6 * float(np.median(times))


def main() -> None:
    parser = build_parser()
    args = parser.parse_args()
    if not 1 <= args.states <= 40 or (args.repeats is not None and args.repeats < 1):
        parser.error("--states must be within 1..40 and --repeats at least 1")
    repeats = args.repeats or 200
    names = args.solvers or [s for s in available_solvers() if solver_info(s).native_dense]
    header = f"{'solve_point':>11} {'solve':>8} {'reported':>9} {'overhead':>9}"
    print(f"{'backend':>20} {'N':>3} | {header}")
    for N in args.N:
        qps = captured_qps(N, args.states)
        for name in names:
            session = DenseSession(name)
            point, full, reported = [], [], []
            for qp in qps:
                session.solve_point(qp)  # set up the workspace
                point.append(median_us(lambda qp=qp, s=session: s.solve_point(qp), repeats))
                full.append(median_us(lambda qp=qp, s=session: s.solve(qp), repeats))
                reported.append(1e6 * session.solve(qp).solve_time)
            if name == "daqp":  # DAQP reports no solve time here: time its raw C call instead
                reported = [median_us(_raw_daqp(qp), repeats) for qp in qps]
            p, f, r = (float(np.median(v)) for v in (point, full, reported))
            overhead = f"{p - r:9.1f}" if r > 0 else f"{'-':>9}"
            print(f"{name:>20} {N:>3} | {p:11.1f} {f:8.1f} {r:9.1f} {overhead}", flush=True)
    print(f"\n{'DAQP entry point':>20} {'N':>3} | {'daqp.solve':>10} {'numba+C':>8} {'C clock':>8}")
    for N in args.N:
        qps = captured_qps(N, args.states)
        python_call, numba_call, clock = daqp_entry_points(qps, args.repeats or 300)
        print(f"{'':>20} {N:>3} | {python_call:10.1f} {numba_call:8.1f} {clock:8.1f}", flush=True)


if __name__ == "__main__":
    main()
