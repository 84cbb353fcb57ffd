"""The prototype of ``daqp:socp`` (``solvers/daqp_socp.py``): exact cones by SQP on DAQP.

The library's backend grew out of this script (the same SQP, with DAQP's working set
carried between the subproblems and a relative stopping step of 1e-8); the script is kept
as the measurement that chose the method. The rest of this docstring is as measured then.

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
the largest cone violation left, the median times of both (Python around DAQP's own
call), and of the same SQP compiled and of one DAQP solve of the problem without cones.

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

The same SQP compiled (numba around DAQP's C call, ``daqp_native.quadprog``; the same
iterates as the Python loop to 2e-17) took 31 / 109 / 586 us per subproblem (medians, the
other core busy with a test run), against 4.7 / 8.9 / 29 us for one DAQP solve of the
problem without its cones. Added to bench's daqp step (87 / 126 / 275 us, whose DAQP
solve it would replace) that estimates 1.3x / 1.8x / 3.0x the QP step (numbers of two runs
added up, not a measured step): within the 2x target at N = 5 and 20, not yet at N = 50,
where each iteration refactorizes a 52 x 52 Hessian
(the cone terms are low-rank updates of the constant H: the next thing to exploit).

On bench's scenario 3 (``--scenario 3_lstm_steps --steps 300``, set-point steps) the
terminal cone binds on 4 (N = 5) and 8 (N = 20) steps: 3 / 2 iterations median, 14 / 17 at
most, first inputs within 3.4e-8 / 5.9e-9 of CLARABEL's, and on all 44 / 1 steps that
CLARABEL reports infeasible DAQP finds no point either.

On scenario 1 the terminal cone itself was never active; the inner cones
``||c_N - c_bar|| <= t_c`` sit at their apex once the horizon brings x_N to x_bar
(N >= 20), where the plain linearization (smoothing 1e-8 or less) stalls: 30 iterations,
violations of 5e-7 left. The smoothing ``r = sqrt(||v||^2 + 1e-12)`` makes the cones
smooth and conservative (the slack column) at no measurable cost in the plan.
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
from ltv_lstm_mpc.solvers.daqp_native import native, quadprog  # noqa: E402

from ltv_lstm_mpc import OffsetFreeController  # noqa: E402
from ltv_lstm_mpc.lstm.shipped import load_model  # noqa: E402
from ltv_lstm_mpc.numba_support import njit  # noqa: E402
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


@njit(cache=True)
def _cone_sqp_compiled(
    H,
    f,
    A,
    lo,
    up,
    lb,
    ub,
    F,
    g,
    cone_rows,
    e,
    offsets,
    z,
    mu,
    tolerance,
    max_iterations,
    problem,
    result,
    settings,
):  # type: ignore[no-untyped-def]
    """:func:`cone_sqp` in numba around DAQP's C call (``daqp_native.quadprog``); the cones
    are stacked: cone ``i`` is rows ``cone_rows[i]:cone_rows[i+1]`` of ``F``/``g``, with
    ``e[i]`` and ``offsets[i]``. Returns (iterations, largest violation); ``z``/``mu`` in place."""
    n = H.shape[0]
    m = A.shape[0]
    cones = e.shape[0]
    rows = m + cones
    A_k = np.zeros((rows, n))
    A_k[:m] = A
    bupper = np.empty(n + rows)
    blower = np.empty(n + rows)
    bupper[:n] = np.minimum(ub, BIG)
    blower[:n] = np.maximum(lb, -BIG)
    bupper[n : n + m] = np.minimum(up, BIG)
    blower[n : n + m] = np.maximum(lo, -BIG)
    blower[n + m :] = -BIG
    sense = np.zeros(n + rows, dtype=np.intc)
    x = np.empty(n)
    lam = np.empty(n + rows)
    hessian = np.empty((n, n))
    # F_i' F_i and F_i' g_i do not change between iterations: once per call
    FtF = np.zeros((cones, n, n))
    for i in range(cones):
        Fi = F[cone_rows[i] : cone_rows[i + 1]]
        FtF[i] = Fi.T @ Fi
    v = np.empty(F.shape[0])
    w = np.empty(n)
    violation = np.inf
    for iteration in range(1, max_iterations + 1):
        hessian[:] = H
        for i in range(cones):
            # v = F_i z + g_i, r = sqrt(|v|^2 + s^2), w = F_i' v (loops: no temporaries)
            rr = SMOOTHING * SMOOTHING
            for a in range(cone_rows[i], cone_rows[i + 1]):
                acc = g[a]
                for b in range(n):
                    acc += F[a, b] * z[b]
                v[a] = acc
                rr += acc * acc
            r = np.sqrt(rr)
            ez = 0.0
            for b in range(n):
                acc = 0.0
                for a in range(cone_rows[i], cone_rows[i + 1]):
                    acc += F[a, b] * v[a]
                w[b] = acc
                ez += e[i, b] * z[b]
            value = r - ez - offsets[i]
            scale = mu[i] / r
            if scale > 0.0:
                inv_r2 = 1.0 / (r * r)
                for a in range(n):
                    for b in range(n):
                        hessian[a, b] += scale * (FtF[i, a, b] - w[a] * w[b] * inv_r2)
            bound = -value
            for b in range(n):
                gradient_b = w[b] / r - e[i, b]
                A_k[m + i, b] = gradient_b
                bound += gradient_b * z[b]
            bupper[n + m + i] = bound
        linear = f + (H - hessian) @ z
        flag, _ = quadprog(
            hessian, linear, A_k, bupper, blower, sense, x, lam, problem, result, settings
        )
        if flag < 0:
            return -iteration, np.inf
        step = 0.0
        for b in range(n):
            step = max(step, abs(x[b] - z[b]))
            z[b] = x[b]
        for i in range(cones):
            mu[i] = max(lam[n + m + i], 0.0)
        violation = -np.inf
        for i in range(cones):
            rr = 0.0
            for a in range(cone_rows[i], cone_rows[i + 1]):
                acc = g[a]
                for b in range(n):
                    acc += F[a, b] * z[b]
                rr += acc * acc
            ez = 0.0
            for b in range(n):
                ez += e[i, b] * z[b]
            violation = max(violation, np.sqrt(rr) - ez - offsets[i])
        if step <= tolerance and violation <= tolerance:
            return iteration, violation
    return max_iterations, violation


def _stack_cones(qp: DenseQP) -> tuple[np.ndarray, ...]:
    F = np.ascontiguousarray(np.vstack([c.F for c in qp.cones]))
    g = np.concatenate([c.g for c in qp.cones])
    rows = np.cumsum([0] + [c.F.shape[0] for c in qp.cones]).astype(np.int64)
    e = np.ascontiguousarray(np.vstack([c.e for c in qp.cones]))
    offsets = np.array([c.f for c in qp.cones])
    return F, g, rows, e, offsets


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
    daqp_buffers = native({})
    assert daqp_buffers is not None, "DAQP's C library is not bound here"
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
        z_start, mu_start = z.copy(), mu.copy()
        t2 = time.perf_counter()
        z, mu, iterations, violation = cone_sqp(qp, z, mu)
        t3 = time.perf_counter()
        stacked = _stack_cones(qp)
        z_c, mu_c = z_start.copy(), mu_start.copy()
        t4 = time.perf_counter()
        iterations_c, _ = _cone_sqp_compiled(
            qp.H, qp.f, qp.A, qp.lo, qp.up, qp.lb, qp.ub, *stacked, z_c, mu_c, 1e-9, 30,
            daqp_buffers.problem, daqp_buffers.result, daqp_buffers.settings,
        )  # fmt: skip
        t5 = time.perf_counter()
        relaxed_x = np.empty(qp.n_variables)
        relaxed_lam = np.empty(qp.n_variables + qp.n_rows)
        bounds_up = np.minimum(np.concatenate([qp.ub, qp.up]), BIG)
        bounds_lo = np.maximum(np.concatenate([qp.lb, qp.lo]), -BIG)
        sense = np.zeros(bounds_up.size, dtype=np.intc)
        t6 = time.perf_counter()
        quadprog(
            qp.H, qp.f, np.ascontiguousarray(qp.A), bounds_up, bounds_lo, sense, relaxed_x,
            relaxed_lam, daqp_buffers.problem, daqp_buffers.result, daqp_buffers.settings,
        )  # fmt: skip
        t7 = time.perf_counter()
        compiled_gap = float(np.max(np.abs(z_c - z)))
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
                t5 - t4,
                t7 - t6,
                compiled_gap,
                iterations_c,
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
        "compiled_us": float(np.median(data[1:, 7]) * 1e6),
        "one_daqp_solve_us": float(np.median(data[1:, 8]) * 1e6),
        "compiled_difference_max": float(np.max(data[:, 9])),
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
        f"{'infeasible (agreed)':>19} {'compiled SQP us':>15} {'one DAQP solve us':>17} "
        f"{'compiled vs Python':>18}"
    )
    print(header)
    for N in args.N:
        r = run(N, args.steps, args.scenario)
        print(
            f"{N:>3} {r['steps']:>5} {r['iterations_median']:>6.0f} / {r['iterations_max']:<5.0f} "
            f"{r['u0_difference_max']:>10.2e} {r['objective_difference_max']:>10.2e} "
            f"{r['cone_violation_max']:>9.1e} {r['terminal_active_steps']:>15d} "
            f"{r['clarabel_us']:>11.0f} {r['sqp_us']:>8.0f} "
            f"{r['infeasible_steps']:>13d} ({r['infeasible_agreed']}) "
            f"{r['compiled_us']:>15.1f} {r['one_daqp_solve_us']:>17.1f} "
            f"{r['compiled_difference_max']:>18.1e}"
        )


if __name__ == "__main__":
    main()
