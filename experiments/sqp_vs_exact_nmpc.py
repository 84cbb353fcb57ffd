"""Converged globalized SQP against the exact NMPC (CasADi + IPOPT) on random states.

Two sets on the shipped pH model: random states near equilibria with random set-points
in the admissible interval (the linearization along the default candidate), and random
equilibria whose linearization candidate is the input bound (u = +1 or -1 repeated), kept
where plain RTI along it is infeasible: the feasibility phase has to work there. For
each state the statuses are compared and, where both are feasible, the first inputs.

Run: ``python experiments/sqp_vs_exact_nmpc.py [--states 120] [--seed 5]`` (``--states 2``:
seconds). Needs CasADi (extra ``nmpc``).
"""

from __future__ import annotations

import argparse
import time
import warnings


def build_parser() -> argparse.ArgumentParser:
    """The command line (``--help`` answers before numpy, CasADi and the library load)."""
    parser = argparse.ArgumentParser(
        description=__doc__.splitlines()[0],
        epilog="Figures: docs/benchmarks.md, \"The paper's benchmark: model, certificates, "
        'closed loops" (converged SQP against the exact NMPC), and docs/user-guide/mpc.md.',
    )
    parser.add_argument("--states", type=int, default=120, help="states per set (120)")
    parser.add_argument("--seed", type=int, default=5)
    parser.add_argument("--iterations", type=int, default=300, help="SQP iterations (300)")
    return parser


if __name__ == "__main__":
    build_parser().parse_args()  # --help and bad options answer here, before the imports

import numpy as np  # noqa: E402

from ltv_lstm_mpc import MPCConfig, RobustMPC, load_model  # noqa: E402
from ltv_lstm_mpc.loop.reference import ReferenceCalculator  # noqa: E402
from ltv_lstm_mpc.mpc.exact_nmpc import ExactNMPC  # noqa: E402


def main() -> None:
    args = build_parser().parse_args()
    warnings.simplefilter("ignore", UserWarning)  # cvxpy's "may be inaccurate" notes
    model = load_model("ph_lstm_n5.npz")
    config = MPCConfig(sqp_iterations=args.iterations, sqp_tolerance=1e-9, tolerance=1e-10)
    sqp = RobustMPC(model, config)
    rti = RobustMPC(model, MPCConfig(tolerance=1e-10), certification=sqp.certification)
    nmpc = ExactNMPC(
        model, MPCConfig(tolerance=1e-10), certification=sqp.certification, smoothing=1e-12
    )
    calculator = ReferenceCalculator(model, strict=False)
    rng = np.random.default_rng(args.seed)
    e_hat = sqp.tightening.e_inf
    low, high = sqp.tightening.setpoint_interval()
    for name in ("default candidate", "candidate at the input bound, RTI infeasible"):
        counts = {"same status": 0, "different status": 0, "both feasible": 0}
        differences: list[float] = []
        iterations: list[int] = []
        rescued = 0
        start = time.perf_counter()
        tried = 0
        while tried < args.states:
            y0 = np.array([rng.uniform(low[0], high[0])])
            ref = calculator.solve(y0, np.zeros(1))
            x = model.equilibrium(np.clip(ref.u_bar + rng.uniform(-0.8, 0.8, 1), -1, 1))
            warm = None
            if name.startswith("default"):
                x = x + rng.normal(0, 0.01, x.shape)
            else:
                warm = np.full((sqp.N, 1), rng.choice([-1.0, 1.0]))
                rti.reset()
                if rti.solve(x, ref.x_bar, ref.u_bar, y0, e_hat, warm=warm).feasible:
                    continue
            tried += 1
            sqp.reset()
            nmpc.reset()
            a = sqp.solve(x, ref.x_bar, ref.u_bar, y0, e_hat, warm=warm)
            b = nmpc.solve(x, ref.x_bar, ref.u_bar, y0, e_hat)
            counts["same status" if a.feasible == b.feasible else "different status"] += 1
            if a.feasible and b.feasible:
                counts["both feasible"] += 1
                differences.append(float(np.abs(a.u[0] - b.u[0]).max()))
                iterations.append(a.iterations)
                rescued += a.feasibility_steps > 0
        print(f"\n{name}: {tried} states in {time.perf_counter() - start:.0f} s")
        print("  " + ", ".join(f"{key}: {value}" for key, value in counts.items()))
        if differences:
            print(
                f"  |u_0 SQP - u_0 IPOPT| max {max(differences):.2e}, median "
                f"{np.median(differences):.2e}; within 1e-5: "
                f"{sum(d <= 1e-5 for d in differences)}/{len(differences)}; SQP iterations "
                f"median {np.median(iterations):.0f}, max {max(iterations)}; "
                f"feasibility phase used: {rescued}"
            )


if __name__ == "__main__":
    main()
