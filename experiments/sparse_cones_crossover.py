"""Exact cones: CLARABEL on the sparse (stage-wise) subproblem against the condensed one.

The speed target for the paper's SOC terminal set asks whether handing the sparse
transcription of eq. (optimization) to CLARABEL natively (its sparse KKT solver, the data
updated in place) beats the dense condensed problem on native CLARABEL at long horizons.
This script runs bench's scenario 1 (short) with two controllers interleaved: the sparse
transcription (``cvxpy:CLARABEL``, whose subproblem :meth:`RobustMPC.last_problem` gives as a
:class:`~ltv_lstm_mpc.solvers.ConvexProblem`) and the condensed one on ``clarabel``. For each
step it solves the sparse subproblem with CLARABEL's own API, on a workspace built once and
updated in place (``solver.update(P=..., q=..., A=..., b=...)``: all data, as a controller
would), and the condensed subproblem through the library's native dense session; it prints
the medians (microseconds) of both, CLARABEL's iterations, and the largest difference of the
first input between the two formulations.

    python experiments/sparse_cones_crossover.py --steps 120 --N 5 20 50
    python experiments/sparse_cones_crossover.py --steps 15 --N 5

Measured 2026-12-03 on this 2-core VM (110 steps per horizon, medians, nothing else
running; CLARABEL's defaults with iterative refinement off, as the dense backend runs it):

=== ===================== =================== ================== ========== ============
 N  sparse: variables,     sparse, update +    condensed, native  sparse /   max |du_0|
    rows of A              solve (us)          dense session (us) condensed  (normalized)
=== ===================== =================== ================== ========== ============
 5  67, 95                 570                 701                0.81       7.2e-7
20  232, 305               1677                1497               1.12       1.6e-10
50  562, 725               4104                7309               0.56       6.9e-11
=== ===================== =================== ================== ========== ============

CLARABEL takes 8-9 interior-point iterations on both. The sparse formulation pays off only
from about N = 50 (0.56x the condensed solve there, about the same at N = 5 and 20), and
equilibration or presolve off changes nothing measurable (3.9-4.0 ms at N = 50; all
defaults 5.5 ms). Either way the exact cones stay far above the QP path: the one-call
daqp *step* takes 46 / 104 / 310 us at N = 5 / 20 / 50 (``experiments/step_speed.py``),
so a CLARABEL solve alone is 12-13x that step at every horizon. On this machine the sparse
CLARABEL route cannot bring exact cones within 2x of the QP path; an active-set route can
(``daqp:socp``, ``solvers/daqp_socp.py``: SQP on DAQP, 1.2-1.8x the QP step, see
docs/benchmarks.md, "One compiled call per step").
"""

from __future__ import annotations

import argparse
import os
import time
from dataclasses import replace
from typing import Any

SKIP = 10  # first steps left out of the figures


def build_parser() -> argparse.ArgumentParser:
    """The command line (``--help`` answers before numpy and the library are imported)."""
    parser = argparse.ArgumentParser(
        description=__doc__.split("\n\n")[0],
        epilog='Figures: docs/benchmarks.md, "One compiled call per step" (native sparse '
        "CLARABEL on the stage-wise problem).",
    )
    parser.add_argument(
        "--steps", type=int, default=120, help=f"closed-loop steps (120; more than {SKIP})"
    )
    parser.add_argument("--N", type=int, nargs="+", default=[5, 20, 50], help="horizons")
    return parser


if __name__ == "__main__":
    build_parser().parse_args()  # --help and bad options answer here, before the imports

for _name in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_name, "1")

import clarabel  # noqa: E402
import numpy as np  # noqa: E402
import scipy.sparse as sp  # noqa: E402
from ltv_lstm_mpc.solvers import ConvexProblem, DenseSession  # noqa: E402

from ltv_lstm_mpc import OffsetFreeController  # noqa: E402
from ltv_lstm_mpc.lstm.shipped import load_model  # noqa: E402
from ltv_lstm_mpc.solver_comparison.harness import bench_scenarios  # noqa: E402


def clarabel_data(problem: ConvexProblem) -> tuple[Any, ...]:
    """CLARABEL's (P upper triangle, q, A, b, cones) of ``problem``: equalities (zero cone),
    the finite one-sided rows of G and of the bounds (nonnegative cone), then each
    ``||F z + g|| <= e'z + f`` as ``[e'z + f; F z + g]`` in a second-order cone."""
    n = problem.n_variables
    blocks, rhs, cones = [], [], []
    if problem.A_eq is not None and problem.A_eq.shape[0]:
        blocks.append(problem.A_eq)
        rhs.append(problem.b_eq)
        cones.append(clarabel.ZeroConeT(problem.A_eq.shape[0]))
    rows, values = [], []
    if problem.G is not None:
        G = problem.G.tocsr()
        for sign, side in ((1.0, problem.u), (-1.0, problem.l)):
            if side is not None:
                finite = np.isfinite(side)
                rows.append(sign * G[finite])
                values.append(sign * side[finite])
    identity = sp.identity(n, format="csr")
    for sign, side in ((1.0, problem.ub), (-1.0, problem.lb)):
        if side is not None:
            finite = np.isfinite(side)
            rows.append(sign * identity[finite])
            values.append(sign * side[finite])
    if rows:
        stacked = sp.vstack(rows)
        blocks.append(stacked)
        rhs.append(np.concatenate(values))
        cones.append(clarabel.NonnegativeConeT(stacked.shape[0]))
    for cone in problem.cones:
        image = sp.vstack([sp.csr_matrix(cone.e[None, :]), cone.F.tocsr()])
        blocks.append(-image)
        rhs.append(np.concatenate([[cone.f], cone.g]))
        cones.append(clarabel.SecondOrderConeT(image.shape[0]))
    A = sp.vstack(blocks).tocsc()
    A.sort_indices()
    P = sp.triu(problem.P).tocsc()
    P.sort_indices()
    return P, np.asarray(problem.q, dtype=np.float64), A, np.concatenate(rhs), cones


def run(N: int, steps: int) -> dict[str, float]:
    """Interleaved loops at horizon ``N``; medians of both solves (s) and the gap."""
    model = load_model("ph_lstm_n5.npz")
    scenario = bench_scenarios(model)[0]
    controllers = []
    for solver, transcription in (("cvxpy:CLARABEL", "sparse"), ("clarabel", "condensed")):
        config = replace(scenario.config, N=N, solver=solver, transcription=transcription)
        controller = OffsetFreeController(
            model, config, setpoint_rate_limit=scenario.setpoint_rate_limit, kernels="compiled"
        )
        controllers.append([controller, scenario.make_plant(model), None])
    for entry in controllers:
        entry[2] = entry[1].output()
    settings = clarabel.DefaultSettings()
    settings.verbose = False
    settings.iterative_refinement_enable = False
    dense = DenseSession("clarabel", tolerance=1e-8)
    solver = None
    sparse_times, dense_times, iterations, gaps = [], [], [], []
    size = (0, 0)
    for k in range(min(steps, len(scenario.setpoints))):
        for entry in controllers:
            controller, plant, y = entry
            u = controller.step(y, scenario.setpoints[k])
            entry[2] = plant.step(u)
        problem = controllers[0][0].mpc.last_problem("nominal")
        P, q, A, b, cones = clarabel_data(problem)
        size = (problem.n_variables, A.shape[0])
        if solver is None:
            solver = clarabel.DefaultSolver(P, q, A, b, cones, settings)
            continue
        t0 = time.perf_counter()
        solver.update(P=P.data, q=q, A=A.data, b=b)
        solution = solver.solve()
        t1 = time.perf_counter()
        qp = controllers[1][0].mpc.last_problem("nominal")
        t2 = time.perf_counter()
        condensed = dense.solve(qp)
        t3 = time.perf_counter()
        if k < SKIP:
            continue
        sparse_times.append(t1 - t0)
        dense_times.append(t3 - t2)
        iterations.append(solution.iterations)
        u_sparse = float(controllers[0][0].records[-1].mpc.u[0, 0])
        u_dense = float(controllers[1][0].records[-1].mpc.u[0, 0])
        gaps.append(abs(u_sparse - u_dense))
        del condensed
    return {
        "variables": size[0],
        "rows": size[1],
        "sparse": float(np.median(sparse_times)),
        "dense": float(np.median(dense_times)),
        "iterations": float(np.median(iterations)),
        "gap": float(np.max(gaps)),
    }


def main() -> None:
    parser = build_parser()
    args = parser.parse_args()
    if args.steps <= SKIP:
        parser.error(f"--steps must be more than {SKIP} (the first {SKIP} are left out)")
    print(
        f"{'N':>3} {'variables':>9} {'rows':>5} {'sparse us':>10} {'condensed us':>13} "
        f"{'sparse/condensed':>17} {'iterations':>10} {'max |du0| (normalized)':>23}"
    )
    for N in args.N:
        r = run(N, args.steps)
        print(
            f"{N:3d} {r['variables']:9d} {r['rows']:5d} {r['sparse'] * 1e6:10.0f} "
            f"{r['dense'] * 1e6:13.0f} {r['sparse'] / r['dense']:17.2f} "
            f"{r['iterations']:10.0f} {r['gap']:23.1e}"
        )


if __name__ == "__main__":
    main()
