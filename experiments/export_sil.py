"""The exported C controller step against the library: the paper's five scenarios and the
quadruple tank, software in the loop.

For each of the paper's five scenarios on the pH plant and the quadruple tank's set-point
changes, for each solver and horizon: runs the library's closed loop (the reference engine;
DAQP on the terminal box, or ``daqp:socp``'s exact cones),
exports the controller (``export_model_c(..., controller=...)``), builds the C code on the
host (``ltv_lstm_mpc.export.sil``) and replays the loop's measurements and requested
set-points through ``<prefix>_controller_step``. Prints per run: the steps, the steps on an
infeasibility policy, the set-point statuses met, the largest relative difference of the
physical inputs (C / library), and whether the MPC statuses, policies, set-point and
measurement statuses agree on every step.

    python experiments/export_sil.py [--N 5 20] [--steps 0] [--only 3 quadtank]
        [--solver daqp daqp:socp]
"""

from __future__ import annotations

import argparse
import itertools
import os
import tempfile
import warnings
from pathlib import Path
from typing import Any


def build_parser() -> argparse.ArgumentParser:
    """The command line (``--help`` answers before numpy and the library are imported)."""
    parser = argparse.ArgumentParser(
        description=__doc__.split("\n\n")[0],
        epilog='Figures: docs/user-guide/export-c.md, "The controller step". Smallest run: '
        "--N 5 --steps 20 --only 3.",
    )
    parser.add_argument("--N", type=int, nargs="+", default=[5, 20], help="horizons (5 20)")
    parser.add_argument(
        "--steps", type=int, default=0, help="steps per run (0: the scenario's own length)"
    )
    parser.add_argument(
        "--only", nargs="+", default=None, help="runs to do: 1..5 (paper scenarios), quadtank"
    )
    parser.add_argument(
        "--solver", nargs="+", default=["daqp"], choices=["daqp", "daqp:socp"],
        help="daqp (the terminal box) and/or daqp:socp (the exact cones); default daqp",
    )  # fmt: skip
    return parser


if __name__ == "__main__":
    build_parser().parse_args()

for _name in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_name, "1")

from dataclasses import replace  # noqa: E402

import numpy as np  # noqa: E402

from ltv_lstm_mpc import OffsetFreeController, simulate  # noqa: E402
from ltv_lstm_mpc.benchmarks.quadtank import quadtank_scenarios  # noqa: E402
from ltv_lstm_mpc.export import export_model_c  # noqa: E402
from ltv_lstm_mpc.export.sil import (  # noqa: E402
    POLICY_NAMES,
    CController,
    compile_controller,
)
from ltv_lstm_mpc.loop.statuses import MEASUREMENT_STATUSES, SETPOINT_STATUSES  # noqa: E402
from ltv_lstm_mpc.lstm.shipped import load_model  # noqa: E402
from ltv_lstm_mpc.paper.scenarios import paper_scenarios  # noqa: E402


def runs(only: list[str] | None) -> list[tuple[str, Any, Any, bool]]:
    """(label, model, scenario, is the pH plant) of the runs asked for."""
    ph = load_model("ph_lstm_n5.npz")
    found = [(str(i + 1), ph, s, True) for i, s in enumerate(paper_scenarios(ph))]
    found.append(("quadtank", load_model("quadtank_lstm_n8.npz"), quadtank_scenarios()[0], False))
    return [run for run in found if only is None or run[0] in only]


def compare(controller: Any, sim: Any, c: CController) -> tuple[float, bool]:
    """The C step on the loop's measurements and set-points: (largest relative input
    difference, every status equal)."""
    worst, equal = 0.0, True
    for k, record in enumerate(controller.records):
        code, u_phi, r = c.step(sim.y_phi[k], sim.y0_phi[k])
        equal = equal and code == 0
        equal = equal and c.mpc_status(r.mpc, controller.mpc.config) == record.mpc.status
        equal = equal and POLICY_NAMES[r.mpc.policy] == record.mpc.policy
        equal = equal and SETPOINT_STATUSES[r.setpoint_status] == record.setpoint_status
        equal = equal and MEASUREMENT_STATUSES[r.measurement_status] == record.measurement_status
        scale = np.maximum(1.0, np.abs(record.u_phi))
        worst = max(worst, float(np.max(np.abs(u_phi - record.u_phi) / scale)))
    return worst, equal


def main() -> None:
    args = build_parser().parse_args()
    print(
        f"{'run':<9} {'solver':<9} {'N':>3} {'steps':>6} {'policy steps':>12} "
        f"{'max |du|/|u|':>13} {'statuses':>9}  set-point statuses"
    )
    for (label, model, scenario, ph), solver, N in itertools.product(
        runs(args.only), args.solver, args.N
    ):
        config = replace(scenario.config, solver=solver, N=N)
        controller = OffsetFreeController(
            model, config, setpoint_rate_limit=scenario.setpoint_rate_limit,
            one_call_step=False,
        )  # fmt: skip
        if ph:
            plant = scenario.make_plant(model, controller.certification)
            disturbances = scenario.disturbances
        else:
            plant, disturbances = scenario.make_plant(model), scenario.leaks
        steps = args.steps or scenario.steps
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            sim = simulate(
                plant, controller, scenario.setpoints, disturbances, steps, progress=False
            )
        with tempfile.TemporaryDirectory() as scratch:
            exported = export_model_c(model, Path(scratch), controller=controller, prefix="c")
            c = CController(compile_controller(exported), exported)
            worst, equal = compare(controller, sim, c)
        records = controller.records
        policy_steps = sum(r.mpc.policy != "nominal" for r in records)
        statuses = sorted({r.setpoint_status for r in records})
        print(
            f"{label:<9} {solver:<9} {N:>3} {len(records):>6} {policy_steps:>12} {worst:>13.1e} "
            f"{'equal' if equal else 'DIFFER':>9}  {', '.join(statuses)}",
            flush=True,
        )


if __name__ == "__main__":
    main()
