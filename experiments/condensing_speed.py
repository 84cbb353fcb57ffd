"""Compiled condensing: the forward forms vs the backward recursion for H and g0, side by side.

``CondensedTranscription`` forms the Hessian and gradient of the condensed QP either forward,
from the prediction matrices (O(N^3 n m^2): rank updates on their causal columns for
diagonal stage weights, one BLAS Gram matrix of the weighted stack for full ones), or by
the backward recursion of the cost-to-go weights (O(N n^3 + N^2 n m^2)); all give the same
QP (tests/test_kernel.py). This script times ``mpc/compiled_condensing.condense`` both ways,
interleaved call by call on the same data, for random delta-ISS models with diagonal and
with full stage weights, and prints the medians and their ratio: the crossovers set
``BACKWARD_CONDENSING_RATIO_DIAGONAL`` and ``BACKWARD_CONDENSING_RATIO``.

    python experiments/condensing_speed.py [--repeats 300]
    python experiments/condensing_speed.py --repeats 3 --n 5 --N 5
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path

#: (n, m, horizons) of the random models, diagonal and full stage weights each.
CASES = ((5, 1, (5, 20, 30, 40, 50)), (10, 1, (20, 50, 80)), (20, 2, (20, 50)))


def build_parser() -> argparse.ArgumentParser:
    """The command line (``--help`` answers before numpy and the library are imported)."""
    parser = argparse.ArgumentParser(
        description=__doc__.split("\n\n")[0],
        epilog='Figures: docs/benchmarks.md, "Vectorized activations and the causal Hessian" '
        '(the condensing crossovers), and docs/user-guide/compiled.md, "How to measure".',
    )
    parser.add_argument("--repeats", type=int, default=300, help="timed calls per case (300)")
    parser.add_argument(
        "--n",
        type=int,
        nargs="+",
        default=[n for n, _, _ in CASES],
        help="state sizes, of the cases (n, m) = (5, 1), (10, 1), (20, 2) (default: all)",
    )
    parser.add_argument(
        "--N",
        type=int,
        nargs="+",
        default=None,
        help="horizons for every n (default: each n's own)",
    )
    return parser


if __name__ == "__main__":
    build_parser().parse_args()  # --help and bad options answer here, before the imports

for _name in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_name, "1")

import numpy as np  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))
from lstm_factories import random_delta_iss_lstm  # noqa: E402

from ltv_lstm_mpc import MPCConfig, RobustMPC  # noqa: E402
from ltv_lstm_mpc.exceptions import EmptySetpointIntervalError  # noqa: E402
from ltv_lstm_mpc.mpc import compiled_condensing  # noqa: E402
from ltv_lstm_mpc.mpc.condensed import (  # noqa: E402
    BACKWARD_CONDENSING_RATIO,
    BACKWARD_CONDENSING_RATIO_DIAGONAL,
)


def times(n: int, m: int, N: int, repeats: int, diagonal: bool) -> tuple[float, float]:
    """Median seconds of condense forward (rank updates with diagonal weights, the Gram
    matrix with full ones) and with the backward recursion."""
    model = random_delta_iss_lstm(np.random.default_rng(n + m), n, m, m)
    Q = 1.0 if diagonal else np.eye(2 * n) + 0.3 * np.ones((2 * n, 2 * n)) / (2 * n)
    mpc = RobustMPC(model, MPCConfig(solver="daqp", N=N, Q=Q))
    rng = np.random.default_rng(0)
    u_bar = rng.uniform(-0.2, 0.2, m)
    x_bar = model.equilibrium(u_bar)
    mpc.prepare(x_bar, u_bar, model.output(x_bar), 0.01, x_pred=x_bar + 0.01)
    workspace = mpc.condensing_workspace()
    lower, upper = mpc.tightening.output_bounds(0.01)

    def call(backward: bool) -> float:
        start = time.perf_counter()
        compiled_condensing.condense(workspace, x_bar, u_bar, lower, upper, 0.5, backward)
        return time.perf_counter() - start

    call(False), call(True)
    forward, backward = [], []
    for _ in range(repeats):
        forward.append(call(False))
        backward.append(call(True))
    return float(np.median(forward)), float(np.median(backward))


def main() -> None:
    args = build_parser().parse_args()
    print(
        f"backward when N m > ratio * 2n: ratio {BACKWARD_CONDENSING_RATIO_DIAGONAL} with "
        f"diagonal stage weights (else rank updates), {BACKWARD_CONDENSING_RATIO} with full "
        "ones (else the Gram matrix)"
    )
    print(
        f"{'weights':>8} {'n':>3} {'m':>2} {'N':>3} {'Nm/2n':>6} {'forward us':>11} "
        f"{'backward us':>12} {'ratio':>6}"
    )
    for diagonal in (True, False):
        for n, m, horizons in CASES:
            if n not in args.n:
                continue
            for N in horizons if args.N is None else args.N:
                kind = "diagonal" if diagonal else "full"
                try:
                    forward, backward = times(n, m, N, args.repeats, diagonal)
                except EmptySetpointIntervalError:  # the random model's tightening at this N
                    print(f"{kind:>8} {n:>3} {m:>2} {N:>3}  (no admissible set-point: skipped)")
                    continue
                print(
                    f"{kind:>8} {n:>3} {m:>2} {N:>3} {N * m / (2 * n):>6.2f} "
                    f"{forward * 1e6:>11.1f} {backward * 1e6:>12.1f} {backward / forward:>6.2f}"
                )


if __name__ == "__main__":
    main()
