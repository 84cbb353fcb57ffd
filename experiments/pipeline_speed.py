"""Controller step time of the one pipeline, optionally side by side with another version.

Runs scenario 1 (bench's short variant) with ``OffsetFreeController(model,
MPCConfig(solver=...))`` for each backend and horizon and prints the median / p95 of the
full ``step`` and the medians of ``prepare`` and ``feedback`` (microseconds).

Side by side, in the same process, step by step interleaved (order alternating ABBA, each
controller with its own plant), so that the machine's drift hits both alike and the ratio
new / old of the medians means something:

- ``--baseline REV``: a git revision of this repository (e.g. the commit before a
  refactor), exported into a temporary folder and renamed to the package
  ``ltv_lstm_mpc_baseline``; for the versions that still had it, the baseline runs the
  former ``FastOffsetFreeController`` for the QP backends;
- ``--numpy-kernel``: this version on the numpy reference kernel (``compiled=False``).

    python experiments/pipeline_speed.py --steps 300
    python experiments/pipeline_speed.py --baseline <revision> --steps 300 --rounds 3
    python experiments/pipeline_speed.py --numpy-kernel --steps 300 --rounds 3
    python experiments/pipeline_speed.py --numpy-kernel --steps 15 --solvers daqp --N 5

The cases are daqp at N = 5, 20, 50 and cvxpy:CLARABEL at N = 5 (at most 120 steps for the
latter); ``--solvers`` or ``--N`` run every solver named at every horizon named instead.
"""

from __future__ import annotations

import argparse
import importlib
import inspect
import os
import re
import shutil
import subprocess
import sys
import tempfile
import time
from dataclasses import replace
from pathlib import Path
from types import ModuleType
from typing import Any

CASES = [("daqp", 5), ("daqp", 20), ("daqp", 50), ("cvxpy:CLARABEL", 5)]
BASELINE = "ltv_lstm_mpc_baseline"
ROOT = Path(__file__).resolve().parents[1]
SKIP = 10  # first steps left out of the figures: cold caches, first reference solve


def build_parser() -> argparse.ArgumentParser:
    """The command line (``--help`` answers before numpy and the library are imported)."""
    parser = argparse.ArgumentParser(
        description=__doc__.split("\n\n")[0],
        epilog='Figures: docs/benchmarks.md, "The pipeline against earlier versions" (and the '
        'revision comparisons of "The compiled step"), and docs/user-guide/compiled.md, "How '
        'to measure".',
    )
    parser.add_argument("--baseline", default=None, help="git revision to compare with")
    parser.add_argument(
        "--numpy-kernel",
        action="store_true",
        help="compare with this version on the numpy kernel (LSTMKernel(compiled=False))",
    )
    parser.add_argument("--rounds", type=int, default=1, help="repetitions of every case")
    parser.add_argument(
        "--steps", type=int, default=300, help=f"closed-loop steps (300; more than {SKIP})"
    )
    parser.add_argument("--solvers", nargs="+", default=None, help="backends (see above)")
    parser.add_argument("--N", type=int, nargs="+", default=None, help="horizons (see above)")
    return parser


if __name__ == "__main__":
    build_parser().parse_args()  # --help and bad options answer here, before the imports

for _name in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_name, "1")  # before numpy: small products, one thread

import numpy as np  # noqa: E402


def export_baseline(revision: str, folder: Path) -> ModuleType:
    """``git archive`` ``revision`` into ``folder`` as the package ``ltv_lstm_mpc_baseline``."""
    archive = subprocess.run(
        ["git", "-C", str(ROOT), "archive", revision, "ltv_lstm_mpc", "solvers"],
        capture_output=True,
        check=True,
    ).stdout
    subprocess.run(["tar", "-x", "-C", str(folder)], input=archive, check=True)
    package = folder / BASELINE
    (folder / "ltv_lstm_mpc").rename(package)
    if (folder / "solvers").is_dir() and not (package / "solvers").exists():
        shutil.move(str(folder / "solvers"), str(package / "solvers"))
    pattern = re.compile(r"""\bltv_lstm_mpc(?=[. \n"'])""")  # imports and resource names
    for path in package.rglob("*.py"):
        text = path.read_text()
        path.write_text(pattern.sub(BASELINE, text))
    sys.path.insert(0, str(folder))
    return importlib.import_module(BASELINE)


def _controller(
    lib: ModuleType, solver: str, N: int, numpy_kernel: bool = False
) -> tuple[Any, Any, Any]:
    """(controller, plant, scenario) of scenario 1 in the library ``lib``."""
    name = lib.__name__
    model = lib.load_model("ph_lstm_n5.npz")
    if numpy_kernel:  # the numpy reference of eq. (lstm) and of the condensing
        kernel = importlib.import_module(f"{name}.lstm.kernel")
        model.kernel = kernel.LSTMKernel(model, compiled=False)
    harness = None
    # today's layout, then the older ones (a baseline may be any earlier revision)
    for module in ("solver_comparison.harness", "bench.harness", "bench"):
        try:
            harness = importlib.import_module(f"{name}.{module}")
            break
        except ImportError:
            continue
    assert harness is not None, f"no solver-comparison harness in {name}"
    scenario = harness.bench_scenarios(model)[0]
    config = replace(scenario.config, N=N, solver=solver)
    rate = scenario.setpoint_rate_limit
    fast = None
    try:
        fast = importlib.import_module(f"{name}.fast")
    except ImportError:
        pass
    if fast is not None and not solver.startswith("cvxpy"):
        ctrl = fast.FastOffsetFreeController(model, config, solver=solver, setpoint_rate_limit=rate)
    else:
        extra = {}  # compiled now, not the numpy reference while compiling (kernels="auto")
        if "kernels" in inspect.signature(lib.OffsetFreeController).parameters:
            extra["kernels"] = "numpy" if numpy_kernel else "compiled"
        ctrl = lib.OffsetFreeController(model, config, setpoint_rate_limit=rate, **extra)
    return ctrl, scenario.make_plant(model), scenario


def compare(
    libs: list[tuple[ModuleType, bool]], solver: str, N: int, steps: int
) -> list[dict[str, Any]]:
    """Run the loops of ``libs`` ((module, numpy kernel) pairs) interleaved; per entry:
    step times and first inputs."""
    runs = [_controller(lib, solver, N, numpy_kernel) for lib, numpy_kernel in libs]
    outputs = [plant.output() for _, plant, _ in runs]
    times: list[list[float]] = [[] for _ in runs]
    inputs: list[list[float]] = [[] for _ in runs]
    for k in range(steps):
        order = range(len(runs)) if k % 2 == 0 else reversed(range(len(runs)))
        for j in order:
            ctrl, plant, scenario = runs[j]
            t0 = time.perf_counter()
            u = ctrl.step(outputs[j], scenario.setpoints[k])
            times[j].append(time.perf_counter() - t0)
            inputs[j].append(float(u[0]))
            d = scenario.disturbances[k]
            outputs[j] = plant.step(u, None if np.isnan(d) else d)
    skip = SKIP
    result = []
    for j, (ctrl, _, _) in enumerate(runs):
        mpc = [r.mpc for r in ctrl.records[skip:]]
        result.append(
            {
                "total": np.array(times[j][skip:]),
                "prepare": np.array([getattr(s, "prepare_time", np.nan) for s in mpc]),
                "feedback": np.array([getattr(s, "feedback_time", np.nan) for s in mpc]),
                "u": np.array(inputs[j]),
            }
        )
    return result


def main() -> None:
    parser = build_parser()
    args = parser.parse_args()
    if args.steps <= SKIP:
        parser.error(f"--steps must be more than {SKIP} (the first {SKIP} are left out)")
    cases = CASES
    if args.solvers is not None or args.N is not None:
        cases = [
            (solver, N)
            for solver in args.solvers or sorted({s for s, _ in CASES})
            for N in args.N or sorted({n for _, n in CASES})
        ]
    import ltv_lstm_mpc

    libs: list[tuple[ModuleType, bool]] = [(ltv_lstm_mpc, False)]
    with tempfile.TemporaryDirectory() as tmp:
        if args.baseline:
            libs.append((export_baseline(args.baseline, Path(tmp)), False))
        elif args.numpy_kernel:
            libs.append((ltv_lstm_mpc, True))
        print(
            f"{'backend':>16} {'N':>3} | {'step med':>8} {'p95':>7} {'prep':>6} {'feed':>6}"
            + (" | old med  new/old  max|du_phi|" if len(libs) > 1 else "")
        )
        for solver, N in cases:
            steps = args.steps if solver == "daqp" else min(args.steps, 120)
            parts: list[list[dict[str, Any]]] = [[] for _ in libs]
            for _ in range(args.rounds):
                for j, res in enumerate(compare(libs, solver, N, steps)):
                    parts[j].append(res)

            def pooled(j: int, key: str) -> np.ndarray:
                return np.concatenate([r[key] for r in parts[j]])  # noqa: B023

            us = 1e6
            new = pooled(0, "total")
            line = (
                f"{solver:>16} {N:>3} | {us * np.median(new):8.0f} "
                f"{us * np.percentile(new, 95):7.0f} {us * np.median(pooled(0, 'prepare')):6.0f} "
                f"{us * np.median(pooled(0, 'feedback')):6.0f}"
            )
            if len(libs) > 1:
                old = pooled(1, "total")
                du = max(
                    float(np.max(np.abs(a["u"] - b["u"])))
                    for a, b in zip(parts[0], parts[1], strict=True)
                )
                ratio = np.median(new) / np.median(old)
                line += f" | {us * np.median(old):7.0f}  {ratio:7.3f}  {du:.1e}"
            print(line, flush=True)


if __name__ == "__main__":
    main()
