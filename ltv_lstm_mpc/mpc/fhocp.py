r"""The FHOCP front-end shared by every transcription (paper notes section 4).

One definition of: the proof candidate (:func:`shifted_candidate`, Theorem 3 Part 2b),
the checks no solver can fix (:func:`precheck_status`), the cost eq. (optimization_cost)
(:class:`PlanCost`), the nonlinear residuals of a plan (:func:`plan_residuals`) and the
result (:class:`MPCSolution`). Argument checks: :func:`ltv_lstm_mpc.validation.real_vector`.
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass
from typing import Protocol

import numpy as np
from numpy.typing import ArrayLike, NDArray

from ltv_lstm_mpc.certificates.certify import Certification
from ltv_lstm_mpc.certificates.tightening import TighteningCertificate
from ltv_lstm_mpc.mpc.terminal import TerminalSet

__all__ = [
    "MPCSolution",
    "MPCSolver",
    "PlanCost",
    "plan_residuals",
    "precheck_status",
    "shifted_candidate",
]

FloatArray = NDArray[np.float64]


@dataclass(slots=True)  # one per control step: not frozen (2 us less to build)
class MPCSolution:
    """Result of one :meth:`RobustMPC.solve` call (normalized units throughout).

    Attributes
    ----------
    u : ndarray, shape (N, m)
        Planned inputs; ``u[0]`` is applied (eq. mpc).
    x : ndarray, shape (N + 1, 2n)
        The plan re-simulated on the true LSTM from :math:`\\hat x_k`.
    x_linear : ndarray, shape (N + 1, 2n)
        States predicted by the (last) linearized subproblem.
    status : str
        ``"optimal"`` (or ``"optimal_inaccurate"``), or why the nominal FHOCP failed:
        ``"infeasible_initial"`` (the i = 0 output row fails), ``"alpha_nonpositive"``
        (Assumption 5 violated), the solver status (``"infeasible"``, ``"max_iter"``,
        ...), ``"failed"`` (the solver's point was rejected: non-finite, or violating the
        input bounds or its own constraints; see ``reason``) or ``"solver_error"`` (the
        backend raised; see ``reason``).
    feasible : bool
        Whether the nominal FHOCP (all constraints) was solved.
    policy : str
        ``"nominal"``, or the fallback applied: ``"paper"``, ``"soft"``, ``"shift"``.
    solve_time : float
        Wall time of the whole call (linearization, build, solver, re-simulation), s.
    solver_time : float
        Time spent inside the solver calls (setup + solve), s.
    iterations : int
        Linearizations (SQP iterations) performed.
    sqp_step : float
        Last :math:`\\|u^{j+1} - u^j\\|_\\infty`.
    alpha : float
        :math:`\\alpha_k` used.
    cost : float
        Cost eq. (optimization_cost) of the re-simulated plan.
    residuals : dict
        Nonlinear checks of the applied plan: ``output_violation`` (largest violation
        of the tightened output rows i = 0..N-1, >= 0), ``terminal_residual``
        (:math:`\\|[\\|c_N-\\bar c\\|, \\|h_N-\\bar h\\|]\\|_{P_f} - \\alpha_k`, <= 0 inside),
        ``linearization_gap`` (:math:`\\max |x - x_{linear}|`).
    reformulation : str or None
        The conservative cone reformulation applied by a QP-only backend.
    solver_iterations : int
        Solver iterations spent in this call (all SQP iterations and fallbacks).
    transcription : str
        ``"condensed"``, ``"sparse"`` or ``"nonlinear"``.
    prepare_time, feedback_time : float
        Wall times of the two RTI phases, s (``solve_time`` is their sum): ``prepare``
        (candidate rollout, linearization, build) before the estimate arrives,
        ``feedback`` (insert :math:`\\hat x_k`, solve, validate, re-simulate).
    reason : str
        Why the nominal solve failed in words (the solver's message, the exception it
        raised, or the validation that rejected its point); empty when it succeeded
        (with SQP, why an ``"optimal_inaccurate"`` answer did not converge).
    kkt_residual : float
        Globalized SQP (``sqp_iterations > 1``, :mod:`~ltv_lstm_mpc.mpc.sqp`): the KKT
        residual of the nonlinear FHOCP at the last linearization point,
        :math:`\\max(\\|d\\|_\\infty, \\theta)` (subproblem step, nonlinear constraint
        violation); NaN for one iteration (RTI) or when no subproblem was solved.
    feasibility_steps : int
        SQP iterations that took the feasibility phase's step (linearized FHOCP
        infeasible: the soft subproblem's step instead).
    step_length : float
        The last SQP line search's step length :math:`t` (1: full step).
    """

    u: FloatArray
    x: FloatArray
    x_linear: FloatArray
    status: str
    feasible: bool
    policy: str
    solve_time: float
    solver_time: float
    iterations: int
    sqp_step: float
    alpha: float
    cost: float
    residuals: dict[str, float]
    reformulation: str | None
    solver_iterations: int = 0
    transcription: str = ""
    prepare_time: float = 0.0
    feedback_time: float = 0.0
    reason: str = ""
    kkt_residual: float = float("nan")
    feasibility_steps: int = 0
    step_length: float = 1.0


def shifted_candidate(previous_u: FloatArray | None, u_bar: FloatArray, N: int) -> FloatArray:
    """Candidate of Theorem 3's proof (Part 2b): the previous plan shifted by one with
    :math:`\\bar u_k` appended; :math:`\\bar u_k` repeated when there is no previous plan."""
    if previous_u is None:
        return np.tile(u_bar, (N, 1))
    return np.vstack([previous_u[1:], u_bar[None, :]])


#: The pre-check's tolerance on the i = 0 output row (:func:`precheck_status`).
PRECHECK_TOL = 1e-12


def precheck_status(
    y_first: Iterable[float], lower_row: Iterable[float], upper_row: Iterable[float], alpha: float
) -> str:
    """Checks no solver can fix, made before any solver call.

    ``"infeasible_initial"``: the i = 0 tightened output row, which involves only
    :math:`\\hat h_k` (paper notes 1), fails; ``"alpha_nonpositive"``: :math:`\\alpha_k \\le 0`
    (Assumption 5 violated, empty terminal set); ``""``: both pass.
    """
    tol = PRECHECK_TOL
    for y, low, high in zip(y_first, lower_row, upper_row, strict=True):
        if not low - tol <= y <= high + tol:
            return "infeasible_initial"
    return "alpha_nonpositive" if alpha <= 0 else ""


def plan_residuals(
    terminal_norm: float,
    x_plan: FloatArray,
    y_plan: FloatArray,
    x_linear: FloatArray | None,
    bounds: tuple[FloatArray, FloatArray],
    alpha: float,
) -> dict[str, float]:
    r"""Nonlinear checks of a plan re-simulated on the true LSTM (``MPCSolution.residuals``).

    ``output_violation``: largest violation (>= 0) of the tightened output rows
    i = 0..N-1, eq. (optimization_constraint_yub)/(ylb); ``terminal_residual``:
    :math:`\|[\|c_N-\bar c\|, \|h_N-\bar h\|]\|_{P_f} - \alpha_k` (<= 0 inside
    :math:`\mathcal{X}_f(k)`; ``terminal_norm`` from :meth:`PlanCost.evaluate`);
    ``linearization_gap``: :math:`\max|x - x_{linear}|` (NaN when no linearized
    prediction exists, e.g. the shift policy).
    """
    N = x_plan.shape[0] - 1
    lower, upper = bounds
    y = y_plan[:N]
    violation = max(0.0, float((lower - y).max()), float((y - upper).max()))
    gap = float("nan")
    if x_linear is not None:
        gap = float(np.abs(x_plan - x_linear).max())
    return {
        "output_violation": violation,
        "terminal_residual": terminal_norm - alpha,
        "linearization_gap": gap,
    }


class MPCSolver(Protocol):
    """What :class:`~ltv_lstm_mpc.OffsetFreeController` needs from an MPC.

    Implemented by :class:`~ltv_lstm_mpc.RobustMPC` (every transcription,
    :class:`~ltv_lstm_mpc.ExactNMPC` included).
    """

    certification: Certification
    tightening: TighteningCertificate

    def solve(
        self,
        x_hat: ArrayLike,
        x_bar: ArrayLike,
        u_bar: ArrayLike,
        y0: ArrayLike,
        e_hat: float,
        *,
        warm: ArrayLike | None = None,
    ) -> MPCSolution:
        """Solve the FHOCP of eq. (optimization) at the given estimates and set-points."""
        ...

    def prepare(
        self,
        x_bar: ArrayLike,
        u_bar: ArrayLike,
        y0: ArrayLike,
        e_hat: float,
        *,
        x_pred: ArrayLike | None = None,
        warm: ArrayLike | None = None,
    ) -> None:
        """RTI preparation phase: linearize and build before the estimate arrives."""
        ...

    def feedback(self, x_hat: ArrayLike) -> MPCSolution:
        """RTI feedback phase: insert the estimate, solve, validate, re-simulate."""
        ...

    def reset(self) -> None:
        """Forget the previous plan."""
        ...


class PlanCost:
    r"""Cost eq. (optimization_cost) of a plan, with the exact terminal term.

    .. math::

        J = \sum_{i=0}^{N-1} \|x_i - \bar x\|_Q^2 + \|u_i - \bar u\|_R^2
        + \|[\|c_N - \bar c\|, \|h_N - \bar h\|]\|_{P_f}^2
    """

    def __init__(self, Q: FloatArray, R: FloatArray, P_f: FloatArray, n: int) -> None:
        #: The terminal set and cost (:class:`~ltv_lstm_mpc.mpc.terminal.TerminalSet`).
        self.terminal_set = TerminalSet(P_f, n)
        self.Q, self.R, self.P_f, self.n = Q, R, self.terminal_set.P_f, n
        q0, r0 = float(Q[0, 0]), float(R[0, 0])
        self._q = q0 if np.array_equal(Q, q0 * np.eye(Q.shape[0])) else None
        self._r = r0 if np.array_equal(R, r0 * np.eye(R.shape[0])) else None
        #: :math:`(P_{11}, P_{12} + P_{21}, P_{22})` of the terminal norm (eq. terminal_constraint).
        self.terminal_terms = self.terminal_set.terms

    def __call__(self, x: FloatArray, u: FloatArray, x_bar: FloatArray, u_bar: FloatArray) -> float:
        """J of states ``x`` (N + 1, 2n) and inputs ``u`` (N, m)."""
        return self.evaluate(x, u, x_bar, u_bar)[0]

    def evaluate(
        self, x: FloatArray, u: FloatArray, x_bar: FloatArray, u_bar: FloatArray
    ) -> tuple[float, float]:
        """(J, terminal norm) of states ``x`` (N + 1, 2n) and inputs ``u`` (N, m).

        The terminal norm is :meth:`terminal` at ``x[N]``; J adds its square to the
        stage costs.
        """
        N = u.shape[0]
        dx = x[:N] - x_bar
        du = u - u_bar
        if self._q is not None:
            stage = self._q * float(np.vdot(dx, dx))
        else:
            stage = float(np.einsum("ki,ij,kj->", dx, self.Q, dx))
        if self._r is not None:
            stage += self._r * float(np.vdot(du, du))
        else:
            stage += float(np.einsum("ki,ij,kj->", du, self.R, du))
        terminal = self.terminal(x[N], x_bar)
        return stage + terminal**2, terminal

    def terminal(self, x_N: FloatArray, x_bar: FloatArray) -> float:
        r""":math:`\|[\|c_N - \bar c\|, \|h_N - \bar h\|]\|_{P_f}` (eq. terminal_constraint)."""
        return self.terminal_set.norm(x_N, x_bar)
