"""Effect of ``DenseSession(..., equilibrate=True)`` (Ruiz) on badly scaled and MPC QPs.

Three families of dense QPs, each solved by every dense backend named (default: the
native ones) with and without equilibration:

- ``scaled 1e{k}``: a well-conditioned random QP (``random_dense_qp(12, 24)``) with its
  variables and rows rescaled by factors spread over ``10^-k ... 10^k`` (a change of units:
  the solution is known exactly, it is the rescaled solution of the original QP);
- ``ill-conditioned``: QPs built from their KKT conditions with cond(H) = 1e8 (known point);
- ``MPC``: MPC-shaped QPs (``random_mpc_problem``, box terminal set) as dense QPs; the
  reference is quadprog's solution without equilibration.

Printed per (family, solver, equilibrate): how many answers were OPTIMAL /
OPTIMAL_INACCURATE / other, and the largest relative point error among the OPTIMAL ones
(relative to ``1 + |x_ref|``).

Usage::

    python experiments/equilibration_effect.py [--solvers daqp quadprog osqp] [--count 20]
    python experiments/equilibration_effect.py --solvers daqp --count 2
"""

from __future__ import annotations

import argparse
import warnings
from collections.abc import Callable, Iterator


def build_parser() -> argparse.ArgumentParser:
    """The command line (``--help`` answers before numpy and the library are imported)."""
    parser = argparse.ArgumentParser(
        description=__doc__.split("\n\n")[0],
        epilog='Figures: docs/benchmarks.md, "The solver layer" (equilibration).',
    )
    parser.add_argument(
        "--solvers", nargs="*", default=["daqp", "quadprog", "osqp", "piqp", "proxqp", "clarabel"]
    )
    parser.add_argument("--count", type=int, default=20, help="QPs per family (20)")
    return parser


if __name__ == "__main__":
    build_parser().parse_args()  # --help and bad options answer here, before the imports

import numpy as np  # noqa: E402
from ltv_lstm_mpc.solvers import DenseQP, DenseSession, SolverStatus  # noqa: E402
from ltv_lstm_mpc.solvers.testing import random_dense_qp, random_mpc_problem  # noqa: E402

FloatArray = np.ndarray
Case = tuple[DenseQP, FloatArray]


def _rescaled(spread: float, count: int) -> Iterator[Case]:
    """x = S x' and rows scaled by R: the solution of the rescaled QP is S^-1 x*."""
    for seed in range(count):
        qp = random_dense_qp(12, 24, seed=seed)
        sol = DenseSession("quadprog").solve(qp)
        assert sol.z is not None
        rng = np.random.default_rng(100 + seed)
        S = 10.0 ** rng.uniform(-spread, spread, qp.n_variables)
        R = 10.0 ** rng.uniform(-spread, spread, qp.n_rows)
        bad = DenseQP(
            H=(qp.H * S) * S[:, None],
            f=qp.f * S,
            A=(qp.A * S) * R[:, None],
            lo=qp.lo * R,
            up=qp.up * R,
            lb=qp.lb / S,
            ub=qp.ub / S,
        )
        yield bad, np.asarray(sol.z) / S


def _ill_conditioned(count: int) -> Iterator[Case]:
    for seed in range(count):
        rng = np.random.default_rng(seed)
        n, m = 8, 6
        Q, _ = np.linalg.qr(rng.standard_normal((n, n)))
        H = (Q * np.geomspace(1.0, 1e8, n)) @ Q.T
        H = 0.5 * (H + H.T)
        x = rng.uniform(-1.0, 1.0, n)
        A = rng.standard_normal((m, n))
        y = np.where(np.arange(m) % 2 == 0, 1.0 + rng.random(m), 0.0)
        up = A @ x + np.where(y > 0, 0.0, 1.0)
        f = -(H @ x + A.T @ y)
        qp = DenseQP(H, f, A, np.full(m, -np.inf), up, np.full(n, -np.inf), np.full(n, np.inf))
        yield qp, x


def _mpc(count: int) -> Iterator[Case]:
    for seed in range(count):
        qp = DenseQP.from_convex_problem(random_mpc_problem(10, seed=seed, terminal_cone=False))
        sol = DenseSession("quadprog").solve(qp)
        if sol.z is not None:
            yield qp, np.asarray(sol.z)


def main(argv: list[str] | None = None) -> int:
    """Print the table; returns the exit status."""
    args = build_parser().parse_args(argv)
    families: dict[str, Callable[[], Iterator[Case]]] = {
        "scaled 1e2": lambda: _rescaled(2.0, args.count),
        "scaled 1e4": lambda: _rescaled(4.0, args.count),
        "scaled 1e6": lambda: _rescaled(6.0, args.count),
        "ill-conditioned": lambda: _ill_conditioned(args.count),
        "MPC": lambda: _mpc(args.count),
    }
    print(
        f"{'family':16s} {'solver':10s} {'equilibrate':>11s} {'optimal':>8s} "
        f"{'inaccurate':>10s} {'other':>6s} {'max point error':>16s}"
    )
    warnings.simplefilter("ignore")
    for family, make in families.items():
        cases = list(make())
        for solver in args.solvers:
            for equilibrate in (False, True):
                counts = {"optimal": 0, "inaccurate": 0, "other": 0}
                worst = 0.0
                for qp, x_ref in cases:
                    try:
                        sol = DenseSession(solver, equilibrate=equilibrate).solve(qp.copy())
                    except Exception:  # counted, the table goes on
                        counts["other"] += 1
                        continue
                    if sol.status is SolverStatus.OPTIMAL and sol.z is not None:
                        counts["optimal"] += 1
                        err = float(np.max(np.abs(sol.z - x_ref))) / (
                            1.0 + float(np.max(np.abs(x_ref)))
                        )
                        worst = max(worst, err)
                    elif sol.status is SolverStatus.OPTIMAL_INACCURATE:
                        counts["inaccurate"] += 1
                    else:
                        counts["other"] += 1
                print(
                    f"{family:16s} {solver:10s} {equilibrate!s:>11s} {counts['optimal']:8d} "
                    f"{counts['inaccurate']:10d} {counts['other']:6d} {worst:16.2e}"
                )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
