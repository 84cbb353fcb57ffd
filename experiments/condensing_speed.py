"""Compiled condensing: Gram matrix vs backward recursion for H and g0, side by side.

``CondensedTranscription`` forms the Hessian and gradient of the condensed QP either as one
Gram matrix of the weighted prediction stack (one BLAS product, O(N^3 n m^2)) or by the
backward recursion of the cost-to-go weights (O(N n^3 + N^2 n m^2)); both give the same
QP (tests/test_kernel.py). This script times ``mpc/compiled_condensing.condense`` both ways,
interleaved call by call on the same data, for random delta-ISS models, and prints the
medians and their ratio: the crossover sets ``BACKWARD_CONDENSING_RATIO``.

    python experiments/condensing_speed.py [--repeats 300]
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path

for _name in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_name, "1")

import numpy as np  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))
from lstm_factories import random_delta_iss_lstm  # noqa: E402

from ltv_lstm_mpc import MPCConfig, RobustMPC  # noqa: E402
from ltv_lstm_mpc.exceptions import EmptySetpointIntervalError  # noqa: E402
from ltv_lstm_mpc.mpc import compiled_condensing  # noqa: E402
from ltv_lstm_mpc.mpc.condensed import BACKWARD_CONDENSING_RATIO  # noqa: E402


def times(n: int, m: int, N: int, repeats: int) -> tuple[float, float]:
    """Median seconds of condense with the Gram matrix and with the backward recursion."""
    model = random_delta_iss_lstm(np.random.default_rng(n + m), n, m, m)
    mpc = RobustMPC(model, MPCConfig(solver="daqp", N=N))
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
    gram, backward = [], []
    for _ in range(repeats):
        gram.append(call(False))
        backward.append(call(True))
    return float(np.median(gram)), float(np.median(backward))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--repeats", type=int, default=300)
    args = parser.parse_args()
    print(f"BACKWARD_CONDENSING_RATIO = {BACKWARD_CONDENSING_RATIO} (backward when N m > it * 2n)")
    print(
        f"{'n':>3} {'m':>2} {'N':>3} {'Nm/2n':>6} {'gram us':>9} {'backward us':>12} {'ratio':>6}"
    )
    for n, m, horizons in ((5, 1, (5, 20, 30, 40, 50)), (10, 1, (20, 50, 80)), (20, 2, (20, 50))):
        for N in horizons:
            try:
                gram, backward = times(n, m, N, args.repeats)
            except EmptySetpointIntervalError:  # the random model's tightening at this N
                print(f"{n:>3} {m:>2} {N:>3}  (no admissible set-point at this N: skipped)")
                continue
            print(
                f"{n:>3} {m:>2} {N:>3} {N * m / (2 * n):>6.2f} {gram * 1e6:>9.1f} "
                f"{backward * 1e6:>12.1f} {backward / gram:>6.2f}"
            )


if __name__ == "__main__":
    main()
