"""Setup time and peak memory of ``DenseSession`` against n, for every dense backend.

For each installed solver (or the ones named) and each n, one dense QP with n variables
and n rows (``random_dense_qp(n, n)``, bounds on every variable) is solved twice through a
fresh :class:`~ltv_lstm_mpc.solvers.DenseSession`: the first call sets the workspace up
(for ``cvxpy:*`` this includes cvxpy's canonicalization), the second updates it in place
with a new ``f``. Printed per (solver, n): the first and second call's wall time, the
status, and two memory figures:

- ``traced MB``: the peak of Python/numpy allocations during the first call
  (``tracemalloc``; solver-internal C allocations are not seen);
- ``RSS MB``: the growth of the process' resident high-water mark over the import baseline
  (``resource.getrusage``); one process per solver with n ascending, so it is the peak of
  the largest n so far.

Usage::

    python experiments/dense_session_scaling.py                     # every backend
    python experiments/dense_session_scaling.py --solvers cvxpy:OSQP --n 20 80 150 200
    python experiments/dense_session_scaling.py --solvers daqp --n 10

A solver is not run at a larger n once one call took more than ``--cap`` seconds, and
its process is stopped after ``--timeout`` seconds (cvxpy:HIGHS' QP solver took more than
10 minutes on one dense QP of n = 150 here).
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys

CHILD = r"""
import json, resource, sys, time, tracemalloc, warnings
warnings.simplefilter("ignore")
from ltv_lstm_mpc.solvers import DenseSession, available_solvers
from ltv_lstm_mpc.solvers.testing import random_dense_qp
available_solvers()
solver, sizes, cap = sys.argv[1], [int(v) for v in sys.argv[2].split(",")], float(sys.argv[3])
base = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
for n in sizes:
    qp = random_dense_qp(n, n, seed=0)
    session = DenseSession(solver)
    tracemalloc.start()
    t0 = time.perf_counter()
    try:
        first = session.solve(qp)
    except Exception as exc:  # report, do not stop the table
        tracemalloc.stop()
        print(json.dumps({"n": n, "error": f"{type(exc).__name__}: {exc}"[:120]}), flush=True)
        break
    t1 = time.perf_counter() - t0
    _, traced = tracemalloc.get_traced_memory()
    tracemalloc.stop()
    qp.f[:] *= 1.1
    t0 = time.perf_counter()
    second = session.solve(qp)
    t2 = time.perf_counter() - t0
    rss = (resource.getrusage(resource.RUSAGE_SELF).ru_maxrss - base) / 1024.0
    print(json.dumps({"n": n, "first_s": t1, "second_s": t2, "traced_mb": traced / 1e6,
                      "rss_mb": rss, "status": first.status.name,
                      "status2": second.status.name}), flush=True)
    if max(t1, t2) > cap:
        break
"""


def build_parser() -> argparse.ArgumentParser:
    """The command line."""
    parser = argparse.ArgumentParser(
        description=__doc__.split("\n\n")[0],
        epilog='Figures: docs/benchmarks.md, "The solver layer" (dense sessions through cvxpy).',
    )
    parser.add_argument("--solvers", nargs="*", help="registry names (default: all installed)")
    parser.add_argument("--n", nargs="*", type=int, default=[20, 50, 100, 150, 200])
    parser.add_argument("--cap", type=float, default=20.0, help="seconds per call (20)")
    parser.add_argument(
        "--timeout", type=float, default=120.0, help="seconds per solver process (120)"
    )
    parser.add_argument("--json", help="also write the rows to this file")
    return parser


def main(argv: list[str] | None = None) -> int:
    """Run the table; returns the exit status."""
    args = build_parser().parse_args(argv)
    if args.solvers:
        solvers = args.solvers
    else:
        from ltv_lstm_mpc.solvers import available_solvers

        solvers = available_solvers()
    sizes = ",".join(str(n) for n in sorted(args.n))
    rows = []
    print(
        f"{'solver':20s} {'n':>4s} {'first s':>9s} {'second s':>9s} {'traced MB':>10s} "
        f"{'RSS MB':>8s}  status"
    )
    for solver in solvers:
        try:
            proc = subprocess.run(
                [sys.executable, "-c", CHILD, solver, sizes, str(args.cap)],
                capture_output=True,
                text=True,
                check=False,
                timeout=args.timeout,
            )
            stdout, returncode, stderr = proc.stdout, proc.returncode, proc.stderr
        except subprocess.TimeoutExpired as exc:
            out = exc.stdout or b""
            stdout = out.decode() if isinstance(out, bytes) else out
            returncode, stderr = -1, f"one call took more than {args.timeout:.0f} s"
        lines = [line for line in stdout.splitlines() if line.startswith("{")]
        if returncode and not lines:
            tail = stderr.strip().splitlines()[-1:] or ["?"]
            print(f"{solver:20s} failed: {tail[0][:100]}")
            continue
        for line in lines:
            row = json.loads(line)
            row["solver"] = solver
            rows.append(row)
            if "error" in row:
                print(f"{solver:20s} {row['n']:4d}  error: {row['error']}")
                continue
            print(
                f"{solver:20s} {row['n']:4d} {row['first_s']:9.3f} {row['second_s']:9.3f} "
                f"{row['traced_mb']:10.1f} {row['rss_mb']:8.0f}  {row['status']}"
            )
        if returncode:
            why = stderr.strip().splitlines()[-1:] or [f"exit {returncode}"]
            print(f"{solver:20s} stopped at the next n: {why[0][:90]}")
    if args.json:
        with open(args.json, "w", encoding="utf-8") as handle:
            json.dump(rows, handle, indent=1)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
