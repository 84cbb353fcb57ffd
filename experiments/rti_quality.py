"""RTI quality: one linearization per step vs converged SQP on scenario-1 states.

For the states visited by the RTI closed loop of scenario 1 (LSTM plant, Theorem 3's
conditions), solve the FHOCP also by SQP iterated to convergence from the same state and
set-points, and compare the first inputs. Then run the whole closed loop once with RTI and
once with converged SQP and compare the closed-loop costs
sum_k ||x_k - x_bar_k||_Q^2 + ||u_k - u_bar_k||_R^2 (normalized units).

Run: ``python experiments/rti_quality.py [--steps 900] [--out rti_quality.json]``
(``--steps 15``: a few seconds).
"""

from __future__ import annotations

import argparse
import json
from dataclasses import replace
from pathlib import Path


def build_parser() -> argparse.ArgumentParser:
    """The command line (``--help`` answers before numpy and the library are imported)."""
    parser = argparse.ArgumentParser(
        description=__doc__.splitlines()[0],
        epilog="Figures: docs/benchmarks.md, \"The paper's benchmark: model, certificates, "
        'closed loops" (RTI against converged SQP), docs/user-guide/mpc.md and the README.',
    )
    parser.add_argument("--steps", type=int, default=900, help="samples of scenario 1 (900)")
    parser.add_argument("--sqp-iterations", type=int, default=30)
    parser.add_argument("--out", type=Path, default=None, help="write the figures as JSON")
    return parser


if __name__ == "__main__":
    build_parser().parse_args()  # --help and bad options answer here, before the imports

import numpy as np  # noqa: E402

from ltv_lstm_mpc import load_model  # noqa: E402
from ltv_lstm_mpc.mpc.rti import RobustMPC  # noqa: E402
from ltv_lstm_mpc.paper.scenarios import (  # noqa: E402
    ScenarioResult,
    paper_scenarios,
    run_scenario,
)


def closed_loop_cost(result: ScenarioResult) -> float:
    """Sum of the stage costs along a closed loop (plant state = LSTM state here)."""
    records = result.controller.records
    Q, R = result.controller.config.weights(result.controller.model)
    cost = 0.0
    for record in records:
        dx = record.x_hat - record.x_bar
        du = record.u - record.u_bar
        cost += float(dx @ Q @ dx + du @ R @ du)
    return cost


def main() -> None:
    parser = build_parser()
    args = parser.parse_args()
    if args.steps < 2:
        parser.error("--steps must be at least 2")
    model = load_model("ph_lstm_n5.npz")
    scenario = paper_scenarios(model)[0]
    scenario = replace(
        scenario,
        setpoints=scenario.setpoints[: args.steps],
        disturbances=scenario.disturbances[: args.steps],
        segments=[],
    )
    rti = run_scenario(scenario, model, progress=True)
    sqp_config = replace(scenario.config, sqp_iterations=args.sqp_iterations, sqp_tolerance=1e-10)
    sqp_mpc = RobustMPC(model, sqp_config)
    differences = []
    for record in rti.controller.records:
        sqp_mpc.reset()  # start from u_bar repeated; converged SQP does not depend on it
        solution = sqp_mpc.solve(record.x_hat, record.x_bar, record.u_bar, record.y0, record.e_hat)
        differences.append(float(np.max(np.abs(solution.u[0] - record.u))))
    sqp = run_scenario(replace(scenario, config=sqp_config), model, progress=True)
    cost_rti, cost_sqp = closed_loop_cost(rti), closed_loop_cost(sqp)
    figures = {
        "steps": args.steps,
        "first_input_difference_max": max(differences),
        "first_input_difference_median": float(np.median(differences)),
        "closed_loop_cost_rti": cost_rti,
        "closed_loop_cost_sqp": cost_sqp,
        "closed_loop_cost_relative_difference": (cost_rti - cost_sqp) / cost_sqp,
        "median_step_time_rti_s": float(np.median(rti.simulation.time_total)),
        "median_step_time_sqp_s": float(np.median(sqp.simulation.time_total)),
    }
    print(json.dumps(figures, indent=2))
    if args.out is not None:
        args.out.write_text(json.dumps(figures, indent=2))


if __name__ == "__main__":
    main()
