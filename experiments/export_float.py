"""The exported C controller in single precision (float) against double, in closed loop.

For each run (the paper's five scenarios on the pH plant, the quadruple tank's set-point
changes) and horizon: the closed loop of the plant with the C step in double
(``engine="c"``) and in float (``engine="c-single"``), the same plant, set-points and
disturbances. Prints per run: the share of the certificates' margins float's rounding
takes (``ltv_lstm_mpc.export.precision``), the largest difference of the physical inputs
(relative to max(1, |u|)) and outputs (physical units) between the two loops, the steps
whose MPC status or policy differ, and the largest plant violation of the output
constraint in each.

    python experiments/export_float.py [--N 5 20] [--steps 0] [--only 3 quadtank]
"""

from __future__ import annotations

import argparse
import os
import warnings
from typing import Any


def build_parser() -> argparse.ArgumentParser:
    """The command line (``--help`` answers before numpy and the library are imported)."""
    parser = argparse.ArgumentParser(
        description=__doc__.split("\n\n")[0],
        epilog='Figures: docs/user-guide/export-c.md, "Single precision". Smallest run: '
        "--N 5 --steps 50 --only 3.",
    )
    parser.add_argument("--N", type=int, nargs="+", default=[5, 20], help="horizons (5 20)")
    parser.add_argument(
        "--steps", type=int, default=0, help="steps per run (0: the scenario's own length)"
    )
    parser.add_argument(
        "--only", nargs="+", default=None, help="runs to do: 1..5 (paper scenarios), quadtank"
    )
    return parser


if __name__ == "__main__":
    build_parser().parse_args()

for _name in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_name, "1")

from dataclasses import replace  # noqa: E402

import numpy as np  # noqa: E402
from export_sil import runs  # noqa: E402  (experiments/ is the script's folder)

from ltv_lstm_mpc import OffsetFreeController, simulate  # noqa: E402


def closed_loop(model: Any, scenario: Any, ph: bool, N: int, engine: str, steps: int) -> Any:
    """The scenario's closed loop with the C step of ``engine``: (controller, result)."""
    config = replace(scenario.config, solver="daqp", N=N)
    controller = OffsetFreeController(
        model, config, setpoint_rate_limit=scenario.setpoint_rate_limit, engine=engine
    )
    if ph:
        plant = scenario.make_plant(model, controller.certification)
        disturbances = scenario.disturbances
    else:
        plant, disturbances = scenario.make_plant(model), scenario.leaks
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        sim = simulate(
            plant, controller, scenario.setpoints, disturbances, steps or scenario.steps,
            progress=False,
        )  # fmt: skip
    return controller, sim


def main() -> None:
    args = build_parser().parse_args()
    print(
        f"{'run':<9} {'N':>3} {'steps':>6} {'w_bar share':>11} {'d_max share':>11} "
        f"{'max |du|/|u|':>13} {'max |dy|':>10} {'status diff':>11} "
        f"{'violation double':>16} {'float':>9}"
    )
    for label, model, scenario, ph in runs(args.only):
        for N in args.N:
            c_double, sim_double = closed_loop(model, scenario, ph, N, "c", args.steps)
            c_single, sim_single = closed_loop(model, scenario, ph, N, "c-single", args.steps)
            margins = c_single.engine.exported.single_precision_margins
            u_d, u_s = sim_double.u_phi, sim_single.u_phi
            du = float(np.max(np.abs(u_s - u_d) / np.maximum(1.0, np.abs(u_d))))
            dy = float(np.max(np.abs(sim_single.y_phi - sim_double.y_phi)))
            differ = sum(
                a.mpc.status != b.mpc.status or a.mpc.policy != b.mpc.policy
                for a, b in zip(c_double.records, c_single.records, strict=True)
            )

            def violation(sim: Any) -> str:
                v = sim.plant_violation
                return "n/a" if v is None or np.all(np.isnan(v)) else f"{np.nanmax(v):.3g}"

            print(
                f"{label:<9} {N:>3} {len(u_d):>6} "
                f"{margins.observer_rounding / margins.w_bar:>11.2%} "
                f"{margins.output_rounding / margins.d_max:>11.2%} {du:>13.1e} {dy:>10.2e} "
                f"{differ:>11} {violation(sim_double):>16} {violation(sim_single):>9}",
                flush=True,
            )


if __name__ == "__main__":
    main()
