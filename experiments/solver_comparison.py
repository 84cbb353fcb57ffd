"""Solver comparison experiment: every backend on the paper's closed loops.

Same as ``ltv-lstm-mpc bench`` (see :mod:`ltv_lstm_mpc.solver_comparison.harness` for the
columns); writes
``bench.csv``, ``bench.md`` and ``bench_N<N>.png`` under ``--out`` (default
``bench_results/``), optionally replayable subproblems (``--save-subproblems DIR``, then
``ltv-lstm-mpc replay DIR``).

Examples
--------
    python experiments/solver_comparison.py                 # default run (~10 min)
    python experiments/solver_comparison.py --smoke         # seconds (CI)
    python experiments/solver_comparison.py --N 5 --backends "fast:*" nmpc:ipopt
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence

from ltv_lstm_mpc.solver_comparison import harness as bench


def main(argv: Sequence[str] | None = None) -> int:
    """Parse the bench arguments and run it."""
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    subparsers = parser.add_subparsers(dest="command")
    bench.register(subparsers)
    args = parser.parse_args(["bench", *(sys.argv[1:] if argv is None else argv)])
    return int(args.func(args))


if __name__ == "__main__":
    sys.exit(main())
