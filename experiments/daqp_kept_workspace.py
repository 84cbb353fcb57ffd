"""DAQP's kept workspace for the "paper" QP: the crossover ``KEEP_FROM``, on the MPC's QPs.

Where DAQP proves the nominal condensed QP infeasible, the ``"paper"`` policy solves the
same cost on the inputs' box alone (paper, Fig. 5). The one-call step can keep DAQP's
workspace of the failed QP, whose Cholesky factor of H (and its inverse) the box QP
needs too, and solve the box QP on it (``solvers.daqp_native.quadprog_kept`` and
``box_quadprog_from``): the same bits as a fresh solve, without factoring H again. Where
the box QP's unconstrained optimum holds (one iteration), the kept solve is redone fresh
(DAQP's set-up computes that point by triangular solves, a kept workspace by H's
inverse), which costs more than it saved. This script collects, per horizon, the failed
nominal QPs of the paper's scenario 3 with its set-point levels cycled every 40 samples
(``Scenario.cycled``, ``worst_case.py``'s dense schedule) on ``daqp``, and times both
sequences on each (the failed QP, then the box QP; the smallest of ``--repeats`` calls
each, interleaved): fresh (``quadprog`` twice) against kept. It checks that both give
the same bits and prints the medians, their ratio and how many box QPs took one
iteration; the smallest number of variables at which kept wins is ``KEEP_FROM``.

    python experiments/daqp_kept_workspace.py [--N 5 10 15 20 30 50] [--repeats 20]
    python experiments/daqp_kept_workspace.py --N 5 --steps 200 --repeats 3
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from dataclasses import replace
from typing import Any


def build_parser() -> argparse.ArgumentParser:
    """The command line (``--help`` answers before numpy and the library are imported)."""
    parser = argparse.ArgumentParser(
        description=__doc__.split("\n\n")[0],
        epilog='Figures: docs/benchmarks.md, "The worst case" (a kept DAQP workspace).',
    )
    parser.add_argument(
        "--N", type=int, nargs="+", default=[5, 10, 15, 20, 30, 50], help="horizons"
    )
    parser.add_argument("--steps", type=int, default=2400, help="closed-loop steps (at most 2400)")
    parser.add_argument(
        "--repeats", type=int, default=20, help="timed calls per QP and sequence (20)"
    )
    return parser


if __name__ == "__main__":
    build_parser().parse_args()  # --help and bad options answer here, before the imports

for _name in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_name, "1")

import numpy as np  # noqa: E402
from ltv_lstm_mpc.solvers import daqp_native  # noqa: E402

from ltv_lstm_mpc import OffsetFreeController  # noqa: E402
from ltv_lstm_mpc.lstm.shipped import load_model  # noqa: E402
from ltv_lstm_mpc.numba_support import njit  # noqa: E402
from ltv_lstm_mpc.paper.scenarios import paper_scenarios  # noqa: E402


@njit
def _condensed_qp(condensing: Any) -> tuple[Any, ...]:
    """Copies of the one-call step's last nominal QP (its condensing workspace)."""
    return (
        condensing.H.copy(), condensing.f.copy(), condensing.A.copy(),
        condensing.high.copy(), condensing.low.copy(),
    )  # fmt: skip


def failed_qps(model: Any, N: int, steps: int) -> tuple[list[tuple[Any, ...]], Any]:
    """The nominal QPs DAQP proved infeasible (``"paper"`` fallback steps whose QP the
    activity bounds do not prove infeasible before DAQP) of the dense schedule at horizon
    N, (H, f, A, upper, lower) each, and the controller's DAQP buffers (its settings)."""
    scenario = paper_scenarios(model)[2].cycled(40)
    config = replace(scenario.config, solver="daqp", N=N, infeasibility_policy="paper")
    controller = OffsetFreeController(
        model, config, setpoint_rate_limit=scenario.setpoint_rate_limit, kernels="compiled"
    )
    condensing = controller.mpc.one_call_parts().condensing
    transcription = controller.mpc._problem  # (its DAQP session's settings, H's floor)
    daqp = transcription._sessions["nominal"].native
    daqp.hessian_floor = transcription.hessian_floor
    daqp.fval_bound = daqp_native.NO_BOUND  # (the library's settings name none)
    tolerance = daqp_native.primal_tolerance(daqp.settings)
    plant = scenario.make_plant(model)
    y = plant.output()
    found = []
    for k in range(min(steps, scenario.steps)):
        u = controller.step(y, scenario.setpoints[k])
        d = scenario.disturbances[k]
        y = plant.step(u, None if np.isnan(d) else d)
        record = controller.records[k].mpc
        if record.policy == "nominal" or not record.policy.startswith("paper"):
            continue
        H, f, A, high, low = _condensed_qp(condensing)
        if A.shape[0] and not daqp_native.activity_infeasible(A, low, high, tolerance):
            found.append((H, f, A, high, low))
    return found, daqp


def time_both(qp: tuple[Any, ...], daqp: Any, repeats: int) -> tuple[float, float, int, bool]:
    """(fresh s, kept s, the box QP's iterations, same bits) on one QP (DAQP's objective
    bound written as the one-call step writes it)."""
    H, f, A, high, low = qp
    n = H.shape[0]
    sense = np.zeros(high.shape[0], dtype=np.intc)
    x, lam = np.empty(n), np.empty(high.shape[0])
    box = (high[:n].copy(), low[:n].copy(), sense[:n].copy())
    fresh_x, fresh_lam, kept_x, kept_lam = np.empty(n), np.empty(n), np.empty(n), np.empty(n)
    work = np.zeros(daqp_native.WORKSPACE_BYTES // 8, dtype=np.int64).view(np.uint8)
    structs = (daqp.problem, daqp.result, daqp.settings)
    daqp_native.set_objective_bound(
        daqp.settings, H, f, low[:n], high[:n], daqp.hessian_floor, daqp.fval_bound
    )  # (the same for both QPs: the same H, f and box)

    def fresh() -> tuple[int, int]:
        daqp_native.quadprog(H, f, A, high, low, sense, x, lam, *structs)
        return daqp_native.quadprog(H, f, A[:0], *box, fresh_x, fresh_lam, *structs)

    def kept() -> tuple[int, int]:
        flag, _, held = daqp_native.quadprog_kept(
            H, f, A, high, low, sense, x, lam, *structs, work, True
        )
        if not held:
            return flag, -1
        return daqp_native.box_quadprog_from(work, H, f, A[:0], *box, kept_x, kept_lam, *structs)

    best = [np.inf, np.inf]
    for _ in range(repeats):
        for i, run in enumerate((fresh, kept)):
            start = time.perf_counter()
            run()
            best[i] = min(best[i], time.perf_counter() - start)
    flag, iterations = fresh()
    kept_flag, kept_iterations = kept()
    same = (
        (kept_flag, kept_iterations) == (flag, iterations)
        and np.array_equal(fresh_x, kept_x)
        and np.array_equal(fresh_lam, kept_lam)
    )
    return best[0], best[1], iterations, same


def main() -> None:
    args = build_parser().parse_args()
    model = load_model("ph_lstm_n5.npz")
    print(
        f"{'N':>3} {'QPs':>5} {'box QP in 1 iteration':>22} {'fresh (us)':>11} "
        f"{'kept (us)':>10} {'kept / fresh':>13} {'same bits':>10}"
    )
    for N in args.N:
        qps, daqp = failed_qps(model, N, args.steps)
        if daqp.work.shape[0] == 0:
            sys.exit(f"DAQP's workspace cannot be kept here: {daqp_native.unavailable_reason}")
        if not qps:
            print(f"{N:>3} {0:>5} (no QP that DAQP proves infeasible)")
            continue
        rows = [time_both(qp, daqp, args.repeats) for qp in qps]
        fresh, kept, iterations, same = (np.array(column) for column in zip(*rows, strict=True))
        print(
            f"{N:>3} {len(rows):>5} {int((iterations == 1).sum()):>22} "
            f"{np.median(fresh) * 1e6:>11.2f} {np.median(kept) * 1e6:>10.2f} "
            f"{np.median(kept / fresh):>13.3f} {f'{int(same.sum())}/{len(rows)}':>10}"
        )


if __name__ == "__main__":
    main()
