r"""Exact nonlinear MPC baseline: the FHOCP of eq. (optimization) solved by IPOPT.

The accuracy reference for the RTI answers (:class:`~ltv_lstm_mpc.RobustMPC`): the
*nonlinear* problem

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
from numpy.typing import NDArray

from ltv_lstm_mpc.certificates.tightening import TighteningCertificate
from ltv_lstm_mpc.exceptions import InvalidValueError
from ltv_lstm_mpc.lstm.kernel import Trajectory
from ltv_lstm_mpc.lstm.model import LSTMModel
from ltv_lstm_mpc.mpc.config import MPCConfig
from ltv_lstm_mpc.mpc.terminal import TerminalSet
from ltv_lstm_mpc.mpc.transcription import StepResult, TranscriptionBase
from ltv_lstm_mpc.solvers import SolverStatus

__all__ = [
    "NonlinearTranscription",
    "casadi_dynamics",
]  # ExactNMPC, the RTI core on it: mpc/exact_nmpc.py

FloatArray = NDArray[np.float64]

#: IPOPT return status -> SolverStatus (unknown ones: FAILED).
IPOPT_STATUS = {
    "Solve_Succeeded": SolverStatus.OPTIMAL,
    "Solved_To_Acceptable_Level": SolverStatus.OPTIMAL_INACCURATE,
    "Infeasible_Problem_Detected": SolverStatus.INFEASIBLE,
    "Maximum_Iterations_Exceeded": SolverStatus.MAX_ITER,
    "Maximum_CpuTime_Exceeded": SolverStatus.MAX_ITER,
    "Maximum_WallTime_Exceeded": SolverStatus.MAX_ITER,
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


def casadi_dynamics(model: LSTMModel) -> Any:
    """The LSTM's state update :math:`x^+ = f(x, u)` of eq. (lstm) as a CasADi function
    ``f(x, u)`` (symbolic: for CasADi's solvers and code generation, e.g. acados'), with
    :math:`x = [c; h]`."""
    ca = _import_casadi()
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


class NonlinearTranscription(TranscriptionBase):
    r"""The exact nonlinear FHOCP (see the module docstring) as a transcription of the core.

    The NLP of each kind (``"nominal"``, ``"paper"``, ``"soft"``) is built once with CasADi
    and re-solved with new parameter values, started from the core's candidate rollout.
    ``config.tolerance`` is IPOPT's ``tol`` (at most 1e-8) and ``config.solver_settings``
    are IPOPT options (e.g. ``{"max_iter": 200}``).

    Parameters
    ----------
    model, config, tightening, Q, R, kinds
        As the other transcriptions.
    smoothing : float
        :math:`\varepsilon` of the smoothed norms :math:`\sqrt{s + \varepsilon}`.
    """

    name = "nonlinear"

    def __init__(
        self,
        model: LSTMModel,
        config: MPCConfig,
        tightening: TighteningCertificate,
        Q: FloatArray,
        R: FloatArray,
        kinds: tuple[str, ...] = ("nominal",),
        *,
        smoothing: float = 1e-8,
    ) -> None:
        self._ca = _import_casadi()
        if not smoothing > 0:
            raise InvalidValueError(f"smoothing must be positive, got {smoothing}")
        self.model, self.config, self.tightening = model, config, tightening
        self.smoothing = float(smoothing)
        options: dict[str, Any] = {
            "tol": min(config.tolerance, 1e-8),
            "print_level": 0,
            "sb": "yes",
            "max_iter": 500,
        }
        options.update(config.solver_settings)
        self._ipopt = options
        self._Q, self._R = Q, R
        self._nlp: dict[str, dict[str, Any]] = {kind: self._build(kind) for kind in kinds}
        self.tolerance = max(1e-6, 100.0 * float(options["tol"]))
        self._data: dict[str, Any] = {}

    def _dynamics(self) -> Any:
        """CasADi function f(x, u) of eq. (lstm)."""
        return casadi_dynamics(self.model)

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
        terminal = TerminalSet(self.tightening.P_f, n)
        eps = self.smoothing
        cost = 0
        for i in range(N):
            dx = X[:, i] - x_bar
            du = U[:, i] - u_bar
            cost += ca.mtimes([dx.T, Q, dx]) + ca.mtimes([du.T, R, du])
        dN = X[:, N] - x_bar
        t_c = ca.sqrt(ca.sumsqr(dN[:n]) + eps)
        t_h = ca.sqrt(ca.sumsqr(dN[n:]) + eps)
        level = terminal.level(t_c, t_h)
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

    def build(
        self,
        traj: Trajectory,
        x_bar: FloatArray,
        u_bar: FloatArray,
        lower: FloatArray,
        upper: FloatArray,
        alpha: float,
    ) -> None:
        """Keep the parameters and the start (the candidate rollout)."""
        n2, m, N = 2 * self.model.n, self.model.m, self.config.N
        self._data = dict(
            x_bar=x_bar.copy(), u_bar=u_bar.copy(), alpha=float(alpha),
            lower=lower, upper=upper, x_start=traj.S[:, :n2].copy(),
            u_start=traj.S[:N, n2 : n2 + m].copy(),
        )  # fmt: skip

    def solve(self, kind: str, x_hat: FloatArray) -> StepResult:
        """Solve the NLP ``kind`` from the candidate (its states shifted to start at x_hat)."""
        model, N, d = self.model, self.config.N, self._data
        nlp = self._nlp[kind]
        n_x, n_u, n_s = nlp["sizes"]
        x_start = d["x_start"] + (x_hat - d["x_start"][0])
        w0 = np.concatenate([x_start.ravel(), d["u_start"].ravel(), np.zeros(n_s)])
        params = np.concatenate(
            [x_hat, d["x_bar"], d["u_bar"], [d["alpha"]], d["lower"][1:].ravel(),
             d["upper"][1:].ravel()]
        )  # fmt: skip
        start = time.perf_counter()
        result = nlp["solver"](
            x0=w0, p=params, lbx=nlp["lbw"], ubx=nlp["ubw"], lbg=nlp["lbg"], ubg=nlp["ubg"]
        )
        elapsed = time.perf_counter() - start
        stats = nlp["solver"].stats()
        native = str(stats.get("return_status"))
        status = IPOPT_STATUS.get(native, SolverStatus.FAILED)
        iterations = int(stats.get("iter_count", 0))
        if not status.has_solution:
            return StepResult(status, None, None, float("nan"), self.tolerance, elapsed, iterations,
                              f"IPOPT: {native}")  # fmt: skip
        w = np.asarray(result["x"], dtype=np.float64).ravel()
        g = np.asarray(result["g"], dtype=np.float64).ravel()
        violation = float(np.max(np.maximum(nlp["lbg"] - g, g - nlp["ubg"]), initial=0.0))
        X = w[:n_x].reshape(N + 1, 2 * model.n)
        U = w[n_x : n_x + n_u].reshape(N, model.m)
        return StepResult(status, U.copy(), X.copy(), violation, self.tolerance, elapsed,
                          iterations, f"IPOPT: {native}")  # fmt: skip
