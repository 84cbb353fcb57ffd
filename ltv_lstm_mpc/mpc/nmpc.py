r"""Exact nonlinear MPC baseline: the FHOCP of eq. (optimization) solved by IPOPT (issue 6).

The accuracy reference for the RTI answers (:class:`~ltv_lstm_mpc.mpc.rti.RobustMPC`,
:class:`~ltv_lstm_mpc.mpc.fast.FastRobustMPC`): the *nonlinear* problem

.. math::

    \min_{x, u} \; & \sum_{i=0}^{N-1} \|x_i - \bar x\|_Q^2 + \|u_i - \bar u\|_R^2
        + \|[\,\|c_N - \bar c\|, \|h_N - \bar h\|\,]\|_{P_f}^2 \\
    \text{s.t.}\; & x_0 = \hat x_k, \quad x_{i+1} = f(x_i, u_i) \quad \text{(eq. lstm)} \\
    & \underline y_i \le W_y h_i + b_y \le \overline y_i \quad (i = 1..N-1,
      \text{ eq. optimization\_constraint\_yub/ylb}) \\
    & \|u_i\|_\infty \le u_{max}, \quad
      \|[\,\|c_N - \bar c\|, \|h_N - \bar h\|\,]\|_{P_f} \le \alpha_k
      \quad \text{(eq. terminal\_constraint)}

in multiple-shooting form, with the inner norms smoothed as
:math:`\|v\| \approx \sqrt{\|v\|^2 + \varepsilon}` (``smoothing`` = :math:`\varepsilon`,
1e-8: a bias of at most :math:`\sqrt\varepsilon` = 1e-4 in each norm). The NLP is built
once with CasADi (``nlpsol``; parameters :math:`\hat x, \bar x, \bar u, \alpha_k` and the
tightened bounds) and re-solved with new parameter values, warm-started from the shifted
previous solution (the proof candidate, simulated from :math:`\hat x_k`).

CasADi is an optional dependency: ``pip install -e ".[nmpc]"``.
"""

from __future__ import annotations

import time
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from ltv_lstm_mpc.certificates.certify import Certification, certify
from ltv_lstm_mpc.exceptions import InvalidValueError
from ltv_lstm_mpc.lstm.model import LSTMModel
from ltv_lstm_mpc.mpc.rti import (
    MPCConfig,
    MPCSolution,
    fhocp_inputs,
    plan_residuals,
    shifted_candidate,
)
from ltv_lstm_mpc.mpc.sparse import FHOCPSubproblem

__all__ = ["ExactNMPC"]

FloatArray = NDArray[np.float64]

#: IPOPT return status -> MPCSolution status.
IPOPT_STATUS = {
    "Solve_Succeeded": "optimal",
    "Solved_To_Acceptable_Level": "optimal_inaccurate",
    "Infeasible_Problem_Detected": "infeasible",
    "Maximum_Iterations_Exceeded": "max_iter",
    "Maximum_CpuTime_Exceeded": "max_iter",
    "Maximum_WallTime_Exceeded": "max_iter",
}


def _import_casadi() -> Any:
    try:
        import casadi
    except ImportError as error:  # pragma: no cover - depends on the environment
        raise ImportError(
            "ExactNMPC needs CasADi (with IPOPT), an optional dependency: "
            'pip install -e ".[nmpc]"  (or: pip install "ltv_lstm_mpc[nmpc]")'
        ) from error
    return casadi


class ExactNMPC:
    r"""Exact NMPC of eq. (optimization) with CasADi + IPOPT (the accuracy reference).

    Same interface as :class:`~ltv_lstm_mpc.mpc.rti.RobustMPC`: ``solve(x_hat, x_bar, u_bar,
    y0, e_hat, *, warm=None) -> MPCSolution``, ``reset()``, ``certification``,
    ``tightening``; usable as ``OffsetFreeController(model, config, mpc=ExactNMPC(...))``.
    The i = 0 output row and :math:`\alpha_k > 0` are checked first (SPEC 1); when they
    fail, or IPOPT does not converge, ``config.infeasibility_policy`` is applied as in
    RobustMPC (``"paper"``: re-solve without output and terminal constraints,
    ``"soft"``: L1 slacks on them, ``"shift"``: the candidate).

    Parameters
    ----------
    model : LSTMModel
    config : MPCConfig, optional
        ``solver``, ``tolerance``-mapping and SQP settings are not used; ``tolerance``
        is IPOPT's ``tol``.
    certification : Certification, optional
    smoothing : float
        :math:`\varepsilon` of the smoothed norms :math:`\sqrt{s + \varepsilon}`.
    ipopt_options : dict, optional
        Extra IPOPT options (e.g. ``{"max_iter": 200}``).

    Attributes
    ----------
    ipopt_iterations : int
        IPOPT iterations of the last call (all NLPs solved in it).
    """

    def __init__(
        self,
        model: LSTMModel,
        config: MPCConfig | None = None,
        *,
        certification: Certification | None = None,
        smoothing: float = 1e-8,
        ipopt_options: dict[str, Any] | None = None,
    ) -> None:
        self._ca = _import_casadi()
        model.require_square()
        if not smoothing > 0:
            raise InvalidValueError(f"smoothing must be positive, got {smoothing}")
        self.model = model
        self.config = config = config or MPCConfig()
        self.certification = certification or certify(model, config.certification_settings(model))
        self.tightening = ti = self.certification.tightening
        self.smoothing = float(smoothing)
        Q, R = config.weights(model)
        self._sub = FHOCPSubproblem(
            n=model.n, m=model.m, p=model.p, N=config.N, Q=Q, R=R, P_f=np.asarray(ti.P_f),
            W_y=model.W_y, b_y=model.b_y, u_max=config.u_max,
        )  # fmt: skip
        options: dict[str, Any] = {
            "tol": min(config.tolerance, 1e-8),
            "print_level": 0,
            "sb": "yes",
            "max_iter": 500,
        }
        options.update(ipopt_options or {})
        self._ipopt = options
        self._Q, self._R = Q, R
        self._nlp: dict[str, dict[str, Any]] = {"nominal": self._build("nominal")}
        if config.infeasibility_policy in ("paper", "soft"):
            self._nlp[config.infeasibility_policy] = self._build(config.infeasibility_policy)
        self._previous_u: FloatArray | None = None
        self.ipopt_iterations = 0

    # ------------------------------------------------------------------------------ NLP
    def _dynamics(self) -> Any:
        """CasADi function f(x, u) of eq. (lstm)."""
        ca, model = self._ca, self.model
        n, m = model.n, model.m
        x = ca.SX.sym("x", 2 * n)
        u = ca.SX.sym("u", m)
        c, h = x[:n], x[n:]

        def gate(W: FloatArray, U: FloatArray, b: FloatArray) -> Any:
            return ca.mtimes(ca.DM(W), u) + ca.mtimes(ca.DM(U), h) + ca.DM(b)

        sig = lambda z: 1.0 / (1.0 + ca.exp(-z))  # noqa: E731
        f = sig(gate(model.W_f, model.U_f, model.b_f))
        i = sig(gate(model.W_i, model.U_i, model.b_i))
        o = sig(gate(model.W_o, model.U_o, model.b_o))
        g = ca.tanh(gate(model.W_c, model.U_c, model.b_c))
        c_next = f * c + i * g
        h_next = o * ca.tanh(c_next)
        return ca.Function("f", [x, u], [ca.vertcat(c_next, h_next)])

    def _build(self, kind: str) -> dict[str, Any]:
        """Build the NLP once: ``kind`` is ``"nominal"``, ``"paper"`` or ``"soft"``."""
        ca, model, config = self._ca, self.model, self.config
        n, m, p, N = model.n, model.m, model.p, config.N
        n2 = 2 * n
        f = self._dynamics()
        X = ca.SX.sym("X", n2, N + 1)
        U = ca.SX.sym("U", m, N)
        x_hat = ca.SX.sym("x_hat", n2)
        x_bar = ca.SX.sym("x_bar", n2)
        u_bar = ca.SX.sym("u_bar", m)
        alpha = ca.SX.sym("alpha")
        y_lo = ca.SX.sym("y_lo", p, max(N - 1, 0))
        y_hi = ca.SX.sym("y_hi", p, max(N - 1, 0))
        Q, R = ca.DM(self._Q), ca.DM(self._R)
        P_f = np.asarray(self.tightening.P_f)
        eps = self.smoothing
        cost = 0
        for i in range(N):
            dx = X[:, i] - x_bar
            du = U[:, i] - u_bar
            cost += ca.mtimes([dx.T, Q, dx]) + ca.mtimes([du.T, R, du])
        dN = X[:, N] - x_bar
        t_c = ca.sqrt(ca.sumsqr(dN[:n]) + eps)
        t_h = ca.sqrt(ca.sumsqr(dN[n:]) + eps)
        level = P_f[0, 0] * t_c**2 + (P_f[0, 1] + P_f[1, 0]) * t_c * t_h + P_f[1, 1] * t_h**2
        cost += level
        g: list[Any] = [X[:, 0] - x_hat]
        lbg: list[float] = [0.0] * n2
        ubg: list[float] = [0.0] * n2
        for i in range(N):
            g.append(X[:, i + 1] - f(X[:, i], U[:, i]))
            lbg += [0.0] * n2
            ubg += [0.0] * n2
        W_y, b_y = ca.DM(model.W_y), ca.DM(model.b_y)
        slacks = ca.SX.sym("s", 0)
        if kind == "nominal":
            for i in range(1, N):
                y = ca.mtimes(W_y, X[n:, i]) + b_y
                g += [y - y_lo[:, i - 1], y_hi[:, i - 1] - y]
                lbg += [0.0] * (2 * p)
                ubg += [ca.inf] * (2 * p)
            g.append(alpha**2 - level)
            lbg.append(0.0)
            ubg.append(ca.inf)
        elif kind == "soft":
            slacks = ca.SX.sym("s", (N - 1) * p + 1)
            for i in range(1, N):
                y = ca.mtimes(W_y, X[n:, i]) + b_y
                s = slacks[(i - 1) * p : i * p]
                g += [y - y_lo[:, i - 1] + s, y_hi[:, i - 1] - y + s]
                lbg += [0.0] * (2 * p)
                ubg += [ca.inf] * (2 * p)
            g.append(alpha + slacks[-1] - ca.sqrt(level))
            lbg.append(0.0)
            ubg.append(ca.inf)
            cost += config.soft_penalty * ca.sum1(slacks)
        w = ca.vertcat(ca.vec(X), ca.vec(U), slacks)
        params = ca.vertcat(x_hat, x_bar, u_bar, alpha, ca.vec(y_lo), ca.vec(y_hi))
        solver = ca.nlpsol(
            f"nmpc_{kind}",
            "ipopt",
            {"x": w, "f": cost, "g": ca.vertcat(*g), "p": params},
            {"ipopt": self._ipopt, "print_time": False},
        )
        n_x, n_u, n_s = n2 * (N + 1), m * N, slacks.numel()
        inf = np.inf
        lbw = np.concatenate([np.full(n_x, -inf), np.full(n_u, -config.u_max), np.zeros(n_s)])
        ubw = np.concatenate([np.full(n_x, inf), np.full(n_u, config.u_max), np.full(n_s, inf)])
        return {
            "solver": solver,
            "lbg": np.array(lbg, dtype=float),
            "ubg": np.array(ubg, dtype=float),
            "lbw": lbw,
            "ubw": ubw,
            "sizes": (n_x, n_u, n_s),
            "lam_g": None,
            "lam_x": None,
        }

    # ---------------------------------------------------------------------------- solve
    def reset(self) -> None:
        """Forget the previous plan (the next candidate is u_bar repeated)."""
        self._previous_u = None
        for nlp in self._nlp.values():
            nlp["lam_g"] = nlp["lam_x"] = None

    def candidate(self, u_bar: FloatArray) -> FloatArray:
        """Proof candidate: previous plan shifted by one with u_bar appended (SPEC 4)."""
        return shifted_candidate(self._previous_u, u_bar, self.config.N)

    def _solve_nlp(
        self,
        kind: str,
        x_hat: FloatArray,
        x_bar: FloatArray,
        u_bar: FloatArray,
        alpha: float,
        bounds: tuple[FloatArray, FloatArray],
        u_start: FloatArray,
    ) -> tuple[str, FloatArray | None, FloatArray | None, int, float]:
        """Returns status, u (N, m), X (N+1, 2n), iterations, solver wall time."""
        model, N = self.model, self.config.N
        nlp = self._nlp[kind]
        n_x, n_u, n_s = nlp["sizes"]
        x_start, _ = model.simulate(x_hat, u_start)
        w0 = np.concatenate([x_start.ravel(), u_start.ravel(), np.zeros(n_s)])
        lower, upper = bounds
        params = np.concatenate(
            [x_hat, x_bar, u_bar, [alpha], lower[1:].ravel(), upper[1:].ravel()]
        )
        args: dict[str, Any] = dict(
            x0=w0, p=params, lbx=nlp["lbw"], ubx=nlp["ubw"], lbg=nlp["lbg"], ubg=nlp["ubg"]
        )
        start = time.perf_counter()
        result = nlp["solver"](**args)
        elapsed = time.perf_counter() - start
        stats = nlp["solver"].stats()
        status = IPOPT_STATUS.get(str(stats.get("return_status")), "failed")
        iterations = int(stats.get("iter_count", 0))
        if status not in ("optimal", "optimal_inaccurate"):
            return status, None, None, iterations, elapsed
        w = np.asarray(result["x"], dtype=np.float64).ravel()
        X = w[:n_x].reshape(N + 1, 2 * model.n)
        U = w[n_x : n_x + n_u].reshape(N, model.m)
        return status, np.clip(U, -self.config.u_max, self.config.u_max), X, iterations, elapsed

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
        r"""Solve the nonlinear FHOCP at :math:`(\hat x_k, \bar x_k, \bar u_k, y^0_k, \hat e_k)`.

        Parameters are those of :meth:`~ltv_lstm_mpc.mpc.rti.RobustMPC.solve`; ``warm`` is
        the initial input guess (default: the shifted previous plan).
        """
        start = time.perf_counter()
        model, config, ti = self.model, self.config, self.tightening
        n2, N = 2 * model.n, config.N
        data = fhocp_inputs(model, ti, N, self._previous_u, x_hat, x_bar, u_bar, y0, e_hat, warm)
        x_hat_a, x_bar_a, u_bar_a, cand = data.x_hat, data.x_bar, data.u_bar, data.candidate
        lower, upper, alpha, status = data.lower, data.upper, data.alpha, data.status
        solver_time = 0.0
        iterations = 0
        u_plan: FloatArray | None = None
        X: FloatArray | None = None
        if not status:
            status, u_plan, X, iterations, solver_time = self._solve_nlp(
                "nominal", x_hat_a, x_bar_a, u_bar_a, alpha, (lower, upper), cand
            )
        feasible = status in ("optimal", "optimal_inaccurate")
        policy = "nominal"
        if not feasible:
            policy = config.infeasibility_policy
            u_plan = X = None
            if policy != "shift":
                _, u_plan, X, its, elapsed = self._solve_nlp(
                    policy, x_hat_a, x_bar_a, u_bar_a, alpha, (lower, upper), cand
                )
                iterations += its
                solver_time += elapsed
                if u_plan is None:
                    policy = f"{policy}+shift"
        if u_plan is None:
            u_plan = cand.copy()
            X = np.full((N + 1, n2), np.nan)
        assert X is not None
        x_plan, y_plan = model.simulate(x_hat_a, u_plan)
        self._previous_u = u_plan.copy()
        self.ipopt_iterations = iterations
        residuals = plan_residuals(model, ti, x_plan, y_plan, X, x_bar_a, (lower, upper), alpha)
        return MPCSolution(
            u=u_plan,
            x=x_plan,
            x_linear=X,
            status=status,
            feasible=feasible,
            policy=policy,
            solve_time=time.perf_counter() - start,
            solver_time=solver_time,
            iterations=iterations,
            sqp_step=float(np.max(np.abs(u_plan - cand))),
            alpha=alpha,
            cost=self._sub.cost(x_plan, u_plan, x_bar_a, u_bar_a),
            residuals=residuals,
            reformulation=None,
            solver_iterations=iterations,
        )
