r"""Globalized SQP on eq. (optimization): merit line search and a feasibility phase.

With ``MPCConfig(sqp_iterations > 1)`` the core (:class:`~ltv_lstm_mpc.RobustMPC`)
iterates on the nonlinear FHOCP of eq. (optimization) in single-shooting form: the
inputs :math:`u = (u_0, \dots, u_{N-1}) \in \mathcal U^N` are the unknowns, the states
follow from eq. (lstm) from :math:`\hat x_k`, and the nonlinear constraints are the
tightened output rows (eq. optimization_constraint_yub/ylb) and the terminal set
(eq. terminal_constraint). Iteration :math:`j`:

1. linearize the LSTM along :math:`u^j` from :math:`\hat x_k` and solve the convex
   subproblem (``"nominal"``: every constraint linearized); its solution is
   :math:`u^j + d^j`;
2. **feasibility phase**: when the linearized subproblem is infeasible (or its solver
   fails), solve the ``"soft"`` subproblem instead (exact-penalty slacks on the output
   rows and the terminal level: the linearized infeasibility is minimized) and take its
   step; the next iteration tries the nominal subproblem again. The phase stops
   (local infeasibility, status ``"infeasible"``) when its step vanishes or when
   ``STALL_ITERATIONS`` feasibility steps in a row do not reduce :math:`\theta` by
   ``STALL_DECREASE`` (relative);
3. **stop** when the KKT residual :math:`r^j = \max(\|d^j\|_\infty, \theta(u^j))` is
   at most ``sqp_tolerance`` (below), applying :math:`u^j + d^j`; or when
   :math:`u^j` is feasible and the nominal step predicts no decrease of the merit
   function beyond rounding (:math:`\Delta^j \le` ``ROUNDING`` :math:`(1 + |\phi_\mu|)`):
   stationary to the accuracy of the subproblem's solver, whose answers carry errors
   of its tolerance's order in :math:`d` (the KKT residual then reports that floor);
4. **line search** on the exact penalty (merit) function
   :math:`\phi_\mu(u) = J(u) + \mu\, \theta(u)`, with :math:`J` the cost eq.
   (optimization_cost) of the re-simulated plan and :math:`\theta(u) \ge 0` the largest
   violation of the nonlinear constraints (output rows and terminal level,
   :func:`~ltv_lstm_mpc.mpc.fhocp.plan_residuals`): backtrack
   :math:`t = 1, 1/2, 1/4, \dots` until the Armijo condition
   :math:`\phi_\mu(u^j + t d^j) \le \phi_\mu(u^j) - \eta\, t\, \Delta^j` holds, where
   :math:`\Delta^j = J(u^j) - J_{lin}(u^j + d^j) + \mu(\theta(u^j) - \theta_{lin}(u^j + d^j))`
   is the decrease the linearized model predicts (merit values are compared with a
   relative rounding allowance of ``ROUNDING``). The penalty :math:`\mu` grows so that
   :math:`\Delta^j \ge \rho\, \mu\, (\theta(u^j) - \theta_{lin})` (Nocedal & Wright,
   *Numerical Optimization*, 2nd ed., eq. (18.36)): then :math:`d^j` is a descent
   direction of :math:`\phi_\mu` whenever :math:`u^j` is not a KKT point.

**The KKT residual.** The subproblem's Hessian (Gauss-Newton of eq. optimization_cost)
is positive definite and its gradient at :math:`d = 0` is the gradient of :math:`J`, so
:math:`d = 0` solves the subproblem at :math:`u^j` exactly when :math:`u^j` is a KKT point
of the nonlinear FHOCP (the subproblem's multipliers are then the NLP's). Hence
:math:`\|d^j\|_\infty` measures stationarity and complementarity together, and
:math:`\theta(u^j)` primal feasibility. With a QP-only backend the subproblem carries
the conservative terminal box (:class:`~ltv_lstm_mpc.mpc.terminal.TerminalBoxReformulation`),
and :math:`J`, :math:`\theta` are those of the FHOCP with that box (the terminal cost bound
:math:`\sum_j w_j (x_{N,j} - \bar x_j)^2`, :math:`\theta` measured against the box): the
point reached is a KKT point of that conservative problem.

**The answer.** Converged: the last subproblem's solution, status ``"optimal"`` (or
``"optimal_inaccurate"`` from the solver). Iterations spent (or the line search stalled)
at a point satisfying the nonlinear constraints: that point, ``"optimal_inaccurate"``.
Otherwise ``"infeasible"`` with the reason, and the core applies its infeasibility
policy. One iteration (``sqp_iterations=1``) is plain RTI and does not come here.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

__all__ = [
    "ARMIJO",
    "BACKTRACK",
    "MIN_STEP_LENGTH",
    "PENALTY_RHO",
    "ROUNDING",
    "STALL_DECREASE",
    "STALL_ITERATIONS",
    "SQPOutcome",
    "Subproblem",
    "globalized_sqp",
    "required_penalty",
]

FloatArray = NDArray[np.float64]

#: :math:`\eta` of the Armijo condition.
ARMIJO = 1e-4
#: Backtracking factor of the line search.
BACKTRACK = 0.5
#: Smallest step length tried before the line search gives up (2**-30).
MIN_STEP_LENGTH = 2.0**-30
#: Relative rounding allowed in merit comparisons (about 50 ulps).
ROUNDING = 1e-14
#: Feasibility steps in a row without a relative decrease of :math:`\theta` by
#: ``STALL_DECREASE`` after which the SQP stops (local infeasibility).
STALL_ITERATIONS = 10
STALL_DECREASE = 0.01
#: :math:`\rho` of the penalty update (share of the predicted decrease owed to feasibility).
PENALTY_RHO = 0.1


@dataclass(slots=True)
class Subproblem:
    r"""One solved convex subproblem, as :func:`globalized_sqp` sees it.

    Attributes
    ----------
    u : ndarray (N, m) or None
        Its solution :math:`u^j + d^j` (None: it failed).
    x_linear : ndarray (N + 1, 2n) or None
        The states its linearized model predicts for ``u``.
    status : str
        ``"optimal"``/``"optimal_inaccurate"``, or why it failed.
    reason : str
        The failure in words (empty when it succeeded).
    tolerance : float
        The violation its solver's answers may have (accepted as feasible).
    """

    u: FloatArray | None
    x_linear: FloatArray | None
    status: str
    reason: str
    tolerance: float


@dataclass(slots=True)
class SQPOutcome:
    r"""What :func:`globalized_sqp` returns.

    Attributes
    ----------
    u : ndarray (N, m) or None
        The plan to apply (None: no subproblem was ever solved).
    x_linear : ndarray (N + 1, 2n) or None
        States of the linearized model at ``u`` (the last linearization).
    status : str
        ``"optimal"``, ``"optimal_inaccurate"`` or ``"infeasible"`` (or the failure of
        the first subproblem when nothing was solved).
    converged : bool
        Whether the iteration stopped at a stationary point: the KKT residual reached the
        tolerance, or the nominal step promised no decrease of the merit function beyond
        rounding at a feasible point (stationary to the subproblem solver's accuracy;
        ``kkt_residual`` then says how far that is).
    iterations : int
        Subproblems solved (linearizations).
    feasibility_steps : int
        Iterations that took the feasibility phase's (soft) step.
    kkt_residual : float
        :math:`\max(\|d\|_\infty, \theta)` at the last linearization point.
    infeasibility : float
        :math:`\theta` of the returned plan's nonlinear re-simulation.
    step : float
        :math:`\|d\|_\infty` of the last subproblem.
    step_length : float
        The last line search's :math:`t` (1: full step).
    penalty : float
        The merit function's final :math:`\mu`.
    reason : str
        Why the answer is not ``"optimal"``, in words (empty otherwise).
    """

    u: FloatArray | None
    x_linear: FloatArray | None
    status: str
    converged: bool
    iterations: int
    feasibility_steps: int
    kkt_residual: float
    infeasibility: float
    step: float
    step_length: float
    penalty: float
    reason: str


def required_penalty(
    cost_decrease: float, infeasibility_decrease: float, penalty: float, rho: float = PENALTY_RHO
) -> float:
    r"""The merit penalty :math:`\mu` after the update of Nocedal & Wright eq. (18.36).

    Parameters
    ----------
    cost_decrease : float
        :math:`\Delta J = J(u^j) - J_{lin}(u^j + d^j)`, predicted by the linearized model.
    infeasibility_decrease : float
        :math:`\Delta\theta = \theta(u^j) - \theta_{lin}(u^j + d^j)`.
    penalty : float
        The current :math:`\mu`.
    rho : float
        :math:`\rho` in (0, 1).

    Returns
    -------
    float
        The smallest :math:`\mu' \ge \mu` with
        :math:`\Delta J + \mu' \Delta\theta \ge \rho\, \mu' \Delta\theta`, times 1.1 when
        it has to grow (:math:`\mu` itself when :math:`\Delta\theta \le 0` or
        :math:`\Delta J \ge 0`).
    """
    if infeasibility_decrease <= 0.0 or cost_decrease >= 0.0:
        return penalty
    needed = -cost_decrease / ((1.0 - rho) * infeasibility_decrease)
    return penalty if needed <= penalty else 1.1 * needed


def globalized_sqp(
    u_start: FloatArray,
    *,
    linearize: Callable[[FloatArray], FloatArray],
    solve: Callable[[str], Subproblem],
    evaluate: Callable[[FloatArray], tuple[float, float]],
    evaluate_linear: Callable[[FloatArray, FloatArray], tuple[float, float]],
    iterations: int,
    tolerance: float,
    penalty: float,
) -> SQPOutcome:
    r"""Run the globalized SQP of the module docstring from ``u_start``.

    Parameters
    ----------
    u_start : (N, m)
        The first linearization point (the candidate of Theorem 3, Part 2b), in U^N.
    linearize : callable
        ``linearize(u)`` linearizes the LSTM along ``u`` from :math:`\hat x_k`, builds
        the subproblems and returns the nonlinear rollout's states (N + 1, 2n).
    solve : callable
        ``solve(kind)`` solves the built subproblem ``"nominal"`` or ``"soft"``.
    evaluate : callable
        ``evaluate(u)`` -> :math:`(J(u), \theta(u))` of the nonlinear re-simulation.
    evaluate_linear : callable
        ``evaluate_linear(x, u)`` -> :math:`(J, \theta)` of given states (the
        linearized model's prediction).
    iterations : int
        Most subproblems to solve (>= 2).
    tolerance : float
        Stop when the KKT residual is at most this.
    penalty : float
        Initial :math:`\mu` (> 0).

    Returns
    -------
    SQPOutcome
        The plan, its status and the iteration's figures.
    """
    u = np.array(u_start, dtype=np.float64)
    cost, theta = evaluate(u)
    solved = 0
    feasibility_steps = 0
    kkt = step = float("nan")
    step_length = 1.0
    x_linear: FloatArray | None = None
    last_tolerance = 0.0
    reason = ""
    stall_theta, stalled = float("inf"), 0
    for _ in range(iterations):
        x_rollout = linearize(u)
        sub = solve("nominal")
        if sub.u is None:
            nominal_reason = sub.reason or sub.status
            sub = solve("soft")
            if sub.u is None:
                if not solved:  # nothing solved: the core's policy takes over
                    return SQPOutcome(
                        None, None, "infeasible", False, 0, 0, float("nan"), theta,
                        float("nan"), 1.0, penalty,
                        f"the linearized FHOCP failed ({nominal_reason}) and so did its "
                        f"feasibility phase ({sub.reason or sub.status})",
                    )  # fmt: skip
                reason = (
                    f"SQP iteration {solved + 1}: the linearized FHOCP failed "
                    f"({nominal_reason}) and so did its feasibility phase "
                    f"({sub.reason or sub.status})"
                )
                break
            feasibility_steps += 1
            kind = "soft"
        else:
            kind = "nominal"
        assert sub.u is not None and sub.x_linear is not None
        solved += 1
        last_tolerance = max(last_tolerance, sub.tolerance)
        d = sub.u - u
        step = float(np.abs(d).max())
        kkt = max(step, theta)
        if kind == "nominal" and kkt <= tolerance:
            final_theta = evaluate(sub.u)[1]
            return SQPOutcome(
                sub.u, sub.x_linear, sub.status, True, solved, feasibility_steps, kkt,
                final_theta, step, 1.0, penalty, "",
            )  # fmt: skip
        model_cost, model_theta = evaluate_linear(sub.x_linear, sub.u)
        cost_decrease = cost - model_cost
        theta_decrease = theta - model_theta
        penalty = required_penalty(cost_decrease, theta_decrease, penalty)
        predicted = cost_decrease + penalty * theta_decrease
        merit = cost + penalty * theta
        # Merit values are exact to a few ulps only: near the solution the predicted
        # decrease falls below that and the comparison only sees rounding.
        rounding = ROUNDING * (1.0 + abs(merit))
        if kind == "soft":
            if theta < (1.0 - STALL_DECREASE) * stall_theta:
                stall_theta, stalled = theta, 0
            else:
                stalled += 1
        if kind == "soft" and stalled >= STALL_ITERATIONS:
            reason = (
                f"SQP iteration {solved}: {STALL_ITERATIONS} feasibility steps did not "
                f"reduce the nonlinear constraint violation {theta:.3e} by "
                f"{STALL_DECREASE:.0%} (local infeasibility)"
            )
            break
        if kind == "soft" and step <= max(tolerance, sub.tolerance):
            reason = (
                f"SQP iteration {solved}: the feasibility phase is stationary at a point "
                f"that violates the nonlinear constraints by {theta:.3e} (local "
                "infeasibility)"
            )
            break
        if predicted <= rounding:
            # Stationary to the subproblem solver's accuracy: the step promises no
            # decrease of the model merit beyond rounding.
            if kind == "nominal" and theta <= sub.tolerance:
                final_theta = evaluate(sub.u)[1]
                if final_theta <= max(tolerance, sub.tolerance):
                    return SQPOutcome(
                        sub.u, sub.x_linear, sub.status, True, solved, feasibility_steps,
                        kkt, final_theta, step, 1.0, penalty, "",
                    )  # fmt: skip
            elif theta > max(tolerance, sub.tolerance):
                reason = (
                    f"SQP iteration {solved}: a stationary point of the merit function "
                    f"that violates the nonlinear constraints by {theta:.3e} (local "
                    "infeasibility: the feasibility phase cannot reduce it)"
                )
                break
        predicted = max(predicted, 0.0)
        t = 1.0
        accepted = False
        while t >= MIN_STEP_LENGTH:
            trial = u + t * d
            trial_cost, trial_theta = evaluate(trial)
            if trial_cost + penalty * trial_theta <= merit - ARMIJO * t * predicted + rounding:
                accepted = True
                break
            t *= BACKTRACK
        if not accepted:
            reason = (
                f"SQP iteration {solved}: the line search found no decrease of the merit "
                f"function (KKT residual {kkt:.2e})"
            )
            break
        u, cost, theta, step_length = trial, trial_cost, trial_theta, t
        # the linearized model is affine in d: its prediction at u^j + t d^j
        x_linear = x_rollout + t * (sub.x_linear - x_rollout)
    if not solved:  # pragma: no cover - the loop returns or breaks with solved > 0
        raise AssertionError("globalized_sqp ended without a subproblem")
    feasible = theta <= max(tolerance, last_tolerance)
    if feasible:
        status = "optimal_inaccurate"
        if not reason:
            reason = (
                f"SQP stopped after {solved} iterations with KKT residual {kkt:.2e} > "
                f"{tolerance:.1e} (the plan satisfies the nonlinear constraints)"
            )
    else:
        status = "infeasible"
        reason = (
            reason + "; " if reason else f"SQP stopped after {solved} iterations: "
        ) + f"the plan violates the nonlinear constraints by {theta:.3e}"
    return SQPOutcome(
        u, x_linear, status, False, solved, feasibility_steps, kkt, theta, step, step_length,
        penalty, reason,
    )  # fmt: skip
