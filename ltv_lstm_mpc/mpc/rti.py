r"""Robust MPC of eq. (optimization) solved by real-time iterations (SPEC section 4).

At step k the LSTM is linearized along the candidate of the proof of Theorem 3
(Part 2b): the previous optimal inputs shifted by one, with :math:`\bar u_k` appended
(:math:`\bar u_k` repeated at the first step). One convex subproblem
(:class:`~ltv_lstm_mpc.mpc.sparse.FHOCPSubproblem`) is solved; optional SQP iterations
re-linearize at the new iterate until the input step is small. Every plan is
re-simulated on the true LSTM and its nonlinear constraint residuals are recorded: a
linearized solution is a proposal, not a certificate.

Infeasibility (the i = 0 output row fails, :math:`\alpha_k \le 0`, or the solver
reports anything but optimal) triggers the configured policy:

``"paper"``
    re-solve without the output and terminal constraints (paper, Fig. 5);
``"soft"``
    re-solve with exact-penalty slacks on the output rows and the terminal level;
``"shift"``
    apply the shifted previous plan (the candidate).
"""

from __future__ import annotations

import time
from collections.abc import Iterable
from dataclasses import dataclass, field
from typing import Literal, Protocol

import numpy as np
from numpy.typing import ArrayLike, NDArray

from ltv_lstm_mpc.certificates.certify import Certification, CertificationSettings, certify
from ltv_lstm_mpc.certificates.tightening import TighteningCertificate
from ltv_lstm_mpc.exceptions import DimensionError, InvalidValueError
from ltv_lstm_mpc.lstm.model import LSTMModel
from ltv_lstm_mpc.mpc.sparse import FHOCPSubproblem
from ltv_lstm_mpc.solvers import Session, SolverStatus

__all__ = [
    "FHOCPInputs",
    "MPCConfig",
    "MPCSolution",
    "MPCSolver",
    "RobustMPC",
    "checked_vector",
    "fhocp_inputs",
    "plan_residuals",
    "precheck_status",
    "shifted_candidate",
]

FloatArray = NDArray[np.float64]
InfeasibilityPolicy = Literal["paper", "soft", "shift"]
_POLICIES = ("paper", "soft", "shift")


@dataclass(frozen=True)
class MPCConfig:
    r"""Tuning of the robust offset-free MPC; defaults are the paper's (Section V).

    Attributes
    ----------
    N : int
        Prediction horizon (5).
    Q : float or ndarray
        Stage state weight, scalar q meaning :math:`q I_{2n}` (1).
    R : float or ndarray
        Stage input weight, scalar r meaning :math:`r I_m` (1).
    u_max : float
        :math:`u_{max}` (1, normalized).
    y_min, y_max : float, optional
        Output constraint (normalized); ``None``: the paper's [6, 9] pH through the
        model's normalization, or [-1, 1] without one.
    d_max, w_bar : float
        :math:`d_{max}` (0.1) and :math:`\bar w` (0.01).
    Q_s, Q_o : float
        Lyapunov weights :math:`Q_s = q_s I_2`, :math:`Q_o = q_o I_3` (1000).
    L_d : float
        :math:`L_d = l_d I_p` (0.01).
    L_f, L_i, L_o : float
        Fill values of the observer gains (0: the certified fallback of Remark 3).
    design_gains : bool
        Choose :math:`L_f, L_i, L_o` by SPEC 2.11 instead.
    solver : str
        Backend name, e.g. ``"cvxpy:CLARABEL"`` (cones, exact), ``"osqp"``, ``"daqp"``,
        ``"qpsolvers:piqp"`` (QP-only: the terminal cones get the conservative
        :class:`~ltv_lstm_mpc.mpc.sparse.TerminalBoxReformulation`, recorded per step).
    tolerance : float
        Solver tolerance (mapped per solver).
    sqp_iterations : int
        Linearizations per step (1 = plain RTI).
    sqp_tolerance : float
        Stop the SQP iterations when :math:`\|u^{j+1} - u^j\|_\infty` falls below it.
    infeasibility_policy : {"paper", "soft", "shift"}
        What to apply when the FHOCP is infeasible (see the module docstring).
    soft_penalty : float
        Exact-penalty weight of the ``"soft"`` policy.
    e_hat0 : float, optional
        Initial observer-error bound :math:`\hat e_{o,0}` (SPEC 2.10b: default
        :math:`\bar e_\infty`).
    epsilon : float
        :math:`P_f` margin (SPEC 2.6).
    """

    N: int = 5
    Q: float | FloatArray = 1.0
    R: float | FloatArray = 1.0
    u_max: float = 1.0
    y_min: float | None = None
    y_max: float | None = None
    d_max: float = 0.1
    w_bar: float = 0.01
    Q_s: float = 1000.0
    Q_o: float = 1000.0
    L_d: float = 0.01
    L_f: float = 0.0
    L_i: float = 0.0
    L_o: float = 0.0
    design_gains: bool = False
    solver: str = "cvxpy:CLARABEL"
    tolerance: float = 1e-8
    sqp_iterations: int = 1
    sqp_tolerance: float = 1e-8
    infeasibility_policy: InfeasibilityPolicy = "paper"
    soft_penalty: float = 1e3
    e_hat0: float | None = None
    epsilon: float = 0.01
    solver_settings: dict[str, object] = field(default_factory=dict)

    def __post_init__(self) -> None:
        if self.infeasibility_policy not in _POLICIES:
            raise InvalidValueError(
                f"infeasibility_policy must be one of {_POLICIES}, "
                f"got {self.infeasibility_policy!r}"
            )
        if int(self.sqp_iterations) != self.sqp_iterations or self.sqp_iterations < 1:
            raise InvalidValueError(f"sqp_iterations must be >= 1, got {self.sqp_iterations}")
        if not self.soft_penalty > 0:
            raise InvalidValueError(f"soft_penalty must be positive, got {self.soft_penalty}")

    def weights(self, model: LSTMModel) -> tuple[FloatArray, FloatArray]:
        """Q (2n, 2n) and R (m, m) as matrices, validated."""
        n2, m = 2 * model.n, model.m
        Q = np.asarray(self.Q, dtype=np.float64)
        R = np.asarray(self.R, dtype=np.float64)
        Q = Q * np.eye(n2) if Q.ndim == 0 else Q
        R = R * np.eye(m) if R.ndim == 0 else R
        for name, W, size in (("Q", Q, n2), ("R", R, m)):
            if W.shape != (size, size):
                raise DimensionError(f"{name} has shape {W.shape}, expected ({size}, {size})")
            if not np.allclose(W, W.T) or np.min(np.linalg.eigvalsh(W)) <= 0:
                raise InvalidValueError(f"{name} must be symmetric positive definite")
        return Q, R

    def certification_settings(self, model: LSTMModel) -> CertificationSettings:
        """The certificate inputs implied by this configuration."""
        Q, _ = self.weights(model)
        return CertificationSettings(
            u_max=self.u_max,
            Q_s=self.Q_s,
            Q_o=self.Q_o,
            l_d=self.L_d,
            L_f=self.L_f,
            L_i=self.L_i,
            L_o=self.L_o,
            design_gains=self.design_gains,
            d_max=self.d_max,
            w_bar=self.w_bar,
            Q=float(np.max(np.linalg.eigvalsh(Q))),
            N=self.N,
            y_min=self.y_min,
            y_max=self.y_max,
            epsilon=self.epsilon,
        )


@dataclass(frozen=True)
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
        ``"optimal"``, or why the nominal FHOCP failed: ``"infeasible_initial"`` (the
        i = 0 output row fails), ``"alpha_nonpositive"`` (Assumption 5 violated), or the
        solver status (``"infeasible"``, ``"max_iter"``, ...).
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


def checked_vector(name: str, value: ArrayLike, size: int) -> FloatArray:
    """``value`` as a finite float64 vector of shape (size,); clear errors otherwise."""
    array = np.atleast_1d(np.asarray(value, dtype=np.float64))
    if array.shape != (size,):
        raise DimensionError(f"{name} has shape {array.shape}, expected ({size},)")
    if not np.all(np.isfinite(array)):
        raise InvalidValueError(f"{name} contains NaN or inf: {array}")
    return array


def shifted_candidate(previous_u: FloatArray | None, u_bar: FloatArray, N: int) -> FloatArray:
    """Candidate of Theorem 3's proof (Part 2b): the previous plan shifted by one with
    :math:`\\bar u_k` appended; :math:`\\bar u_k` repeated when there is no previous plan."""
    if previous_u is None:
        return np.tile(u_bar, (N, 1))
    return np.vstack([previous_u[1:], u_bar[None, :]])


def precheck_status(
    y_first: Iterable[float], lower_row: Iterable[float], upper_row: Iterable[float], alpha: float
) -> str:
    """Checks no solver can fix, made before any solver call.

    ``"infeasible_initial"``: the i = 0 tightened output row, which involves only
    :math:`\\hat h_k` (SPEC 1), fails; ``"alpha_nonpositive"``: :math:`\\alpha_k \\le 0`
    (Assumption 5 violated, empty terminal set); ``""``: both pass.
    """
    tol = 1e-12
    for y, low, high in zip(y_first, lower_row, upper_row, strict=True):
        if not low - tol <= y <= high + tol:
            return "infeasible_initial"
    return "alpha_nonpositive" if alpha <= 0 else ""


@dataclass(frozen=True)
class FHOCPInputs:
    """Validated data of one FHOCP, eq. (optimization) (see :func:`fhocp_inputs`)."""

    x_hat: FloatArray
    x_bar: FloatArray
    u_bar: FloatArray
    y0: FloatArray
    e_hat: float
    candidate: FloatArray
    lower: FloatArray
    upper: FloatArray
    alpha: float
    status: str


def fhocp_inputs(
    model: LSTMModel,
    tightening: TighteningCertificate,
    N: int,
    previous_u: FloatArray | None,
    x_hat: ArrayLike,
    x_bar: ArrayLike,
    u_bar: ArrayLike,
    y0: ArrayLike,
    e_hat: float,
    warm: ArrayLike | None,
) -> FHOCPInputs:
    r"""Check the arguments of an MPC ``solve`` and compute what every solver needs.

    The linearization/initial-guess sequence (``warm``, default :func:`shifted_candidate`),
    the tightened output bounds (eq. optimization_constraint_yub/ylb), :math:`\alpha_k`
    (eq. def_alpha) and the :func:`precheck_status`.
    """
    n2, m = 2 * model.n, model.m
    x_hat_arr = checked_vector("x_hat", x_hat, n2)
    x_bar_arr = checked_vector("x_bar", x_bar, n2)
    u_bar_arr = checked_vector("u_bar", u_bar, m)
    y0_arr = checked_vector("y0", y0, model.p)
    e_hat = float(e_hat)
    if not np.isfinite(e_hat) or e_hat < 0:
        raise InvalidValueError(f"e_hat must be a finite nonnegative number, got {e_hat}")
    if warm is None:
        candidate = shifted_candidate(previous_u, u_bar_arr, N)
    else:
        candidate = np.asarray(warm, dtype=np.float64)
        if candidate.shape != (N, m):
            raise DimensionError(f"warm has shape {candidate.shape}, expected ({N}, {m})")
    lower, upper = tightening.output_bounds(e_hat)
    alpha = tightening.alpha(y0_arr, e_hat)
    return FHOCPInputs(
        x_hat=x_hat_arr,
        x_bar=x_bar_arr,
        u_bar=u_bar_arr,
        y0=y0_arr,
        e_hat=e_hat,
        candidate=candidate,
        lower=lower,
        upper=upper,
        alpha=alpha,
        status=precheck_status(model.output(x_hat_arr), lower[0], upper[0], alpha),
    )


def plan_residuals(
    model: LSTMModel,
    tightening: TighteningCertificate,
    x_plan: FloatArray,
    y_plan: FloatArray,
    x_linear: FloatArray,
    x_bar: FloatArray,
    bounds: tuple[FloatArray, FloatArray],
    alpha: float,
) -> dict[str, float]:
    r"""Nonlinear checks of a plan re-simulated on the true LSTM (``MPCSolution.residuals``).

    ``output_violation``: largest violation (>= 0) of the tightened output rows
    i = 0..N-1, eq. (optimization_constraint_yub)/(ylb); ``terminal_residual``:
    :math:`\|[\|c_N-\bar c\|, \|h_N-\bar h\|]\|_{P_f} - \alpha_k` (<= 0 inside
    :math:`\mathcal{X}_f(k)`); ``linearization_gap``: :math:`\max|x - x_{linear}|` (NaN when
    no linearized prediction exists, e.g. the shift policy).
    """
    N, n = x_plan.shape[0] - 1, model.n
    lower, upper = bounds
    t = np.array(
        [np.linalg.norm(x_plan[N, :n] - x_bar[:n]), np.linalg.norm(x_plan[N, n:] - x_bar[n:])]
    )
    return {
        "output_violation": float(max(0.0, np.max(lower - y_plan[:N]), np.max(y_plan[:N] - upper))),
        "terminal_residual": float(np.sqrt(t @ tightening.P_f @ t) - alpha),
        "linearization_gap": float(np.max(np.abs(x_plan - x_linear)))
        if np.all(np.isfinite(x_linear))
        else float("nan"),
    }


class MPCSolver(Protocol):
    """What :class:`~ltv_lstm_mpc.loop.controller.OffsetFreeController` needs from an MPC.

    Implemented by :class:`RobustMPC`, ``fast.FastRobustMPC`` and ``nmpc.ExactNMPC``.
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

    def reset(self) -> None:
        """Forget the previous plan."""
        ...


class RobustMPC:
    r"""The robust MPC of eq. (optimization), solved RTI-style (SPEC 4).

    Parameters
    ----------
    model : LSTMModel
    config : MPCConfig, optional
    certification : Certification, optional
        Precomputed certificates (default: :func:`~ltv_lstm_mpc.certificates.certify.certify` with
        ``config.certification_settings(model)``).
    """

    def __init__(
        self,
        model: LSTMModel,
        config: MPCConfig | None = None,
        *,
        certification: Certification | None = None,
    ) -> None:
        model.require_square()
        self.model = model
        self.config = config = config or MPCConfig()
        self.certification = certification or certify(model, config.certification_settings(model))
        self.tightening = self.certification.tightening
        Q, R = config.weights(model)
        common = dict(
            n=model.n,
            m=model.m,
            p=model.p,
            N=config.N,
            Q=Q,
            R=R,
            P_f=np.asarray(self.tightening.P_f),
            W_y=model.W_y,
            b_y=model.b_y,
            u_max=config.u_max,
        )
        self._subproblems: dict[str, FHOCPSubproblem] = {
            "nominal": FHOCPSubproblem(**common),
        }
        if config.infeasibility_policy == "paper":
            self._subproblems["paper"] = FHOCPSubproblem(
                **common,
                output_constraints=False,
                terminal_set=False,
            )
        elif config.infeasibility_policy == "soft":
            self._subproblems["soft"] = FHOCPSubproblem(
                **common,
                soft_penalty=config.soft_penalty,
            )
        self._sessions: dict[str, Session] = {
            name: Session(
                config.solver,
                tolerance=config.tolerance,
                reformulation=sub.reformulation,
                **config.solver_settings,
            )
            for name, sub in self._subproblems.items()
        }
        self._previous_u: FloatArray | None = None
        self._solver_iterations = 0

    def reset(self) -> None:
        """Forget the previous plan (the next candidate is u_bar repeated)."""
        self._previous_u = None

    def candidate(self, u_bar: FloatArray) -> FloatArray:
        """Proof candidate: previous plan shifted by one with u_bar appended (SPEC 4)."""
        return shifted_candidate(self._previous_u, u_bar, self.config.N)

    def _solve_subproblem(
        self,
        name: str,
        x_hat: FloatArray,
        x_bar: FloatArray,
        u_bar: FloatArray,
        u_start: FloatArray,
        bounds: tuple[FloatArray, FloatArray],
        alpha: float,
    ) -> tuple[SolverStatus, FloatArray, FloatArray, int, float, float, str | None]:
        """SQP loop on one subproblem: returns status, u, x_linear, iterations, step, time."""
        model, config = self.model, self.config
        sub, session = self._subproblems[name], self._sessions[name]
        u_lin = u_start
        status = SolverStatus.FAILED
        x_linear = np.empty((config.N + 1, 2 * model.n))
        step = np.inf
        solver_time = 0.0
        reformulation = None
        iterations = 0
        for _ in range(config.sqp_iterations):
            iterations += 1
            x_traj, _ = model.simulate(x_hat, u_lin)
            f_lin, A, B = model.step_and_jacobians(x_traj[:-1], u_lin)
            problem = sub.build(
                x_hat=x_hat,
                x_bar=x_bar,
                u_bar=u_bar,
                x_lin=x_traj[:-1],
                u_lin=u_lin,
                f_lin=f_lin,
                A=A,
                B=B,
                y_lower=bounds[0],
                y_upper=bounds[1],
                alpha=alpha,
            )
            if session.structure_key is None:
                session.setup(problem)
            else:
                session.update(problem)
            solution = session.solve()
            solver_time += solution.setup_time + solution.solve_time + solution.overhead_time
            self._solver_iterations += int(solution.iterations or 0)
            if not solution.ok or solution.z is None:
                if iterations == 1:  # otherwise keep the last successful SQP iterate
                    status, reformulation = solution.status, solution.reformulation
                break
            status, reformulation = solution.status, solution.reformulation
            x_linear, u_new, _ = sub.layout.split(np.asarray(solution.z))
            u_new = np.clip(u_new, -config.u_max, config.u_max)  # solver tolerance
            step = float(np.max(np.abs(u_new - u_lin)))
            u_lin = u_new
            if step < config.sqp_tolerance:
                break
        return status, u_lin, x_linear, iterations, step, solver_time, reformulation

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
        r"""Solve the FHOCP at :math:`(\hat x_k, \bar x_k, \bar u_k, y^0_k, \hat e_{o,k})`.

        Parameters
        ----------
        x_hat : (2n,)
            Observer estimate :math:`\hat x_k` (eq. optimization_initialization).
        x_bar, u_bar : (2n,), (m,)
            Reference-calculator set-points.
        y0 : (p,)
            Normalized set-point (enters :math:`\alpha_k`).
        e_hat : float
            Observer-error bound :math:`\hat e_{o,k}`.
        warm : (N, m), optional
            Input sequence to linearize along; default the shifted previous plan with
            :math:`\bar u_k` appended (the proof's candidate).
        """
        start = time.perf_counter()
        model, config, ti = self.model, self.config, self.tightening
        n2, N = 2 * model.n, config.N
        self._solver_iterations = 0
        data = fhocp_inputs(model, ti, N, self._previous_u, x_hat, x_bar, u_bar, y0, e_hat, warm)
        x_hat_arr, x_bar_arr, u_bar_arr = data.x_hat, data.x_bar, data.u_bar
        candidate, lower, upper, alpha = data.candidate, data.lower, data.upper, data.alpha
        status_name = data.status
        solver_time = 0.0
        result = None
        if not status_name:
            result = self._solve_subproblem(
                "nominal", x_hat_arr, x_bar_arr, u_bar_arr, candidate, (lower, upper), alpha
            )
            solver_time += result[5]
            status_name = "optimal" if result[0].has_solution else result[0].name.lower()
            if result[0] is SolverStatus.OPTIMAL_INACCURATE:
                status_name = "optimal_inaccurate"
        feasible = status_name in ("optimal", "optimal_inaccurate")
        policy = "nominal"
        if not feasible:
            policy = config.infeasibility_policy
            if policy == "shift":
                result = (
                    SolverStatus.FAILED,
                    candidate,
                    np.full((N + 1, n2), np.nan),
                    0,
                    0.0,
                    0.0,
                    None,
                )
            else:
                result = self._solve_subproblem(
                    policy, x_hat_arr, x_bar_arr, u_bar_arr, candidate, (lower, upper), alpha
                )
                solver_time += result[5]
                if not result[0].has_solution:  # last resort: the candidate itself
                    policy = f"{policy}+shift"
                    result = (
                        result[0],
                        candidate,
                        np.full((N + 1, n2), np.nan),
                        result[3],
                        0.0,
                        0.0,
                        None,
                    )
        assert result is not None
        _, u_plan, x_linear, iterations, step, _, reformulation = result
        x_plan, y_plan = model.simulate(x_hat_arr, u_plan)
        self._previous_u = u_plan.copy()
        sub = self._subproblems["nominal"]
        residuals = plan_residuals(
            model, ti, x_plan, y_plan, x_linear, x_bar_arr, (lower, upper), alpha
        )
        return MPCSolution(
            u=u_plan,
            x=x_plan,
            x_linear=x_linear,
            status=status_name,
            feasible=feasible,
            policy=policy,
            solve_time=time.perf_counter() - start,
            solver_time=solver_time,
            iterations=iterations,
            sqp_step=step,
            alpha=alpha,
            cost=sub.cost(x_plan, u_plan, x_bar_arr, u_bar_arr),
            residuals=residuals,
            reformulation=reformulation,
            solver_iterations=self._solver_iterations,
        )
