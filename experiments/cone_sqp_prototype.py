"""Prototype, not a library path: exact terminal cones by SQP on an active-set QP solver.

The condensed exact-cone subproblem of eq. (optimization) is a QP plus three second-order
cones (:class:`~ltv_lstm_mpc.solvers.DenseQP` with ``cones``: ``||c_N - c_bar|| <= t_c``,
``||h_N - h_bar|| <= t_h``, ``||P_f^(1/2) t|| <= alpha_k``). Each cone
``||F z + g|| - e'z - f <= 0`` is a convex constraint, smooth wherever ``F z + g != 0``, so
SQP with the exact Hessian of the Lagrangian (``H + sum_i mu_i F'(I - v v'/r^2)F / r``) and
the cones linearized (outer cutting planes) converges quadratically; each iteration is one
DAQP solve. This script captures the subproblems of a closed loop on native CLARABEL
(bench's scenario 1, short), solves each again with CLARABEL and with this SQP (warm
started from the previous step's point and multipliers), and prints, per horizon, the SQP
iterations, the largest differences of the first input and of the objective to CLARABEL's,
the largest cone violation left, and the median times of both (Python around DAQP's own
call: an upper bound on what a compiled loop would take).

    python experiments/cone_sqp_prototype.py --steps 200 --N 5 20 50

Measured 2026-12-03 (200 steps per horizon, shipped pH model; times are this Python
prototype's and CLARABEL's through :class:`~ltv_lstm_mpc.solvers.DenseSession`, medians):

=== ================== ============ ================= ============== ============ ========
 N  SQP iterations      max |du_0|   max rel. dJ       cone slack     CLARABEL us  SQP us
=== ================== ============ ================= ============== ============ ========
 5  3 (max 3)           2.4e-9       3.5e-11           <= 1.5e-8       500          454
20  5 (max 5)           4.8e-11      1.6e-11           <= 1.9e-7       1514         821
50  6 (max 6)           6.9e-12      1.3e-11           <= 5.9e-7       7842         1456
=== ================== ============ ================= ============== ============ ========

On bench's scenario 3 (``--scenario 3_lstm_steps --steps 300``, set-point steps) the
terminal cone binds on 4 (N = 5) and 8 (N = 20) steps: 3 / 2 iterations median, 14 / 17 at
most, first inputs within 3.4e-8 / 5.9e-9 of CLARABEL's, and on all 44 / 1 steps that
CLARABEL reports infeasible DAQP finds no point either.

On scenario 1 the terminal cone itself was never active; the inner cones
``||c_N - c_bar|| <= t_c`` sit at their apex once the horizon brings x_N to x_bar
(N >= 20), where the plain linearization (smoothing 1e-8 or less) stalls: 30 iterations,
violations of 5e-7 left. The smoothing ``r = sqrt(||v||^2 + 1e-12)`` makes the cones
smooth and conservative (the slack column) at no measurable cost in the plan. With DAQP
called from compiled code (a few us at N = 5, tens of us at N = 50 per solve with a new
factorization) 3-6 solves per step would put exact cones within about 2x the QP step.
"""

from __future__ import annotations

import argparse
import os
import time
from dataclasses import replace

for _name in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_name, "1")

import daqp  # noqa: E402
import numpy as np  # noqa: E402
from ltv_lstm_mpc.solvers import DenseQP, DenseSession  # noqa: E402

from ltv_lstm_mpc import OffsetFreeController  # noqa: E402
from ltv_lstm_mpc.lstm.shipped import load_model  # noqa: E402
from ltv_lstm_mpc.solver_comparison.harness import bench_scenarios  # noqa: E402

BIG = 1e30  # DAQP's "no bound"
SMOOTHING = 1e-6  # r = sqrt(||v||^2 + SMOOTHING^2) >= ||v||: smooth and conservative


def _bounds(values: np.ndarray) -> np.ndarray:
    return np.clip(values, -BIG, BIG)


def cone_sqp(
    qp: DenseQP,
    z: np.ndarray,
    multipliers: np.ndarray,
    tolerance: float = 1e-9,
    max_iterations: int = 30,
) -> tuple[np.ndarray, np.ndarray, int, float]:
    """Solve ``qp`` (with its cones) by SQP on DAQP; returns (z, cone multipliers,
    iterations, largest cone violation)."""
    n = qp.n_variables
    m = qp.n_rows
    cones = qp.cones
    z = z.copy()
    mu = multipliers.copy()
    violation = np.inf
    for iteration in range(1, max_iterations + 1):
        hessian = qp.H.copy()
        rows = [qp.A]
        upper = [qp.up]
        lower = [qp.lo]
        for i, cone in enumerate(cones):
            v = cone.F @ z + cone.g
            r = float(np.sqrt(v @ v + SMOOTHING**2))
            gradient = cone.F.T @ (v / r) - cone.e
            value = r - cone.e @ z - cone.f
            if mu[i] > 0.0:
                curvature = (np.eye(v.size) - np.outer(v, v) / r**2) / r
                hessian += mu[i] * (cone.F.T @ curvature @ cone.F)
            rows.append(gradient[None, :])
            upper.append(np.array([gradient @ z - value]))
            lower.append(np.array([-np.inf]))
        A = np.vstack(rows)
        linear = qp.f + (qp.H - hessian) @ z
        b_upper = _bounds(np.concatenate([qp.ub, *upper]))
        b_lower = _bounds(np.concatenate([qp.lb, *lower]))
        sense = np.zeros(b_upper.size, dtype=np.int32)
        x, _, exitflag, info = daqp.solve(hessian, linear, A, b_upper, b_lower, sense)
        if exitflag < 0:
            raise RuntimeError(f"DAQP exit flag {exitflag} at SQP iteration {iteration}")
        step = float(np.max(np.abs(x - z)))
        z = np.asarray(x, dtype=np.float64)
        mu = np.maximum(np.asarray(info["lam"])[n + m :], 0.0)
        violation = max(float(c.violation(z)) for c in cones)
        if step <= tolerance and violation <= tolerance:
            return z, mu, iteration, violation
    return z, mu, max_iterations, violation


def run(N: int, steps: int, scenario_name: str = "1_lstm_theorem3") -> dict[str, float]:
    model = load_model("ph_lstm_n5.npz")
    scenario = next(s for s in bench_scenarios(model) if s.name == scenario_name)
    config = replace(scenario.config, N=N, solver="clarabel")
    controller = OffsetFreeController(
        model, config, setpoint_rate_limit=scenario.setpoint_rate_limit, kernels="compiled"
    )
    plant = scenario.make_plant(model)
    y = plant.output()
    clarabel = DenseSession("clarabel", tolerance=1e-10)
    z = None
    mu = None
    rows = []
    infeasible: list[bool] = []  # per step CLARABEL found infeasible: did the SQP agree?
    for k in range(min(steps, len(scenario.setpoints))):
        u = controller.step(y, scenario.setpoints[k])
        y = plant.step(u)
        qp = controller.mpc.last_problem("nominal")
        assert isinstance(qp, DenseQP) and qp.cones
        t0 = time.perf_counter()
        reference = clarabel.solve(qp)
        t1 = time.perf_counter()
        if z is None or mu is None:
            z = np.zeros(qp.n_variables)
            mu = np.zeros(len(qp.cones))
        if reference.z is None:  # infeasible for CLARABEL: the SQP must find no point
            try:
                _, _, _, violation = cone_sqp(qp, z, mu)
                both_infeasible = violation > 1e-6
            except RuntimeError:
                both_infeasible = True
            infeasible.append(both_infeasible)
            continue
        z_ref = np.asarray(reference.z)
        t2 = time.perf_counter()
        z, mu, iterations, violation = cone_sqp(qp, z, mu)
        t3 = time.perf_counter()
        objective = 0.5 * z @ qp.H @ z + qp.f @ z
        objective_ref = 0.5 * z_ref @ qp.H @ z_ref + qp.f @ z_ref
        rows.append(
            (
                iterations,
                abs(z[0] - z_ref[0]),
                abs(objective - objective_ref) / (1.0 + abs(objective_ref)),
                violation,
                t1 - t0,
                t3 - t2,
                qp.cones[-1].violation(z_ref),
            )
        )
    data = np.array(rows)
    return {
        "steps": len(rows),
        "iterations_median": float(np.median(data[:, 0])),
        "iterations_max": float(np.max(data[:, 0])),
        "u0_difference_max": float(np.max(data[:, 1])),
        "objective_difference_max": float(np.max(data[:, 2])),
        "cone_violation_max": float(np.max(data[:, 3])),
        "clarabel_us": float(np.median(data[:, 4]) * 1e6),
        "sqp_us": float(np.median(data[:, 5]) * 1e6),
        "terminal_active_steps": int(np.sum(data[:, 6] > -1e-7)),
        "infeasible_steps": len(infeasible),
        "infeasible_agreed": int(sum(infeasible)),
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--steps", type=int, default=60)
    parser.add_argument("--N", type=int, nargs="+", default=[5, 20, 50])
    parser.add_argument("--scenario", default="1_lstm_theorem3", help="a bench scenario name")
    args = parser.parse_args()
    header = (
        f"{'N':>3} {'steps':>5} {'SQP it med/max':>14} {'max |du0|':>10} {'max dJ rel':>10} "
        f"{'max viol':>9} {'terminal active':>15} {'CLARABEL us':>11} {'SQP us':>8} "
        f"{'infeasible (agreed)':>19}"
    )
    print(header)
    for N in args.N:
        r = run(N, args.steps, args.scenario)
        print(
            f"{N:>3} {r['steps']:>5} {r['iterations_median']:>6.0f} / {r['iterations_max']:<5.0f} "
            f"{r['u0_difference_max']:>10.2e} {r['objective_difference_max']:>10.2e} "
            f"{r['cone_violation_max']:>9.1e} {r['terminal_active_steps']:>15d} "
            f"{r['clarabel_us']:>11.0f} {r['sqp_us']:>8.0f} "
            f"{r['infeasible_steps']:>13d} ({r['infeasible_agreed']})"
        )


if __name__ == "__main__":
    main()
