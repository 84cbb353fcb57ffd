r"""The FHOCP of eq. (optimization) as one convex subproblem (paper notes section 4).

At step k the LSTM is linearized along a trajectory :math:`(\tilde x_i, \tilde u_i)`
(the shifted candidate of the proof of Theorem 3, Part 2b), and the FHOCP becomes

.. math::

    \min_{x, u, t} \; & \sum_{i=0}^{N-1} \|x_i - \bar x\|_Q^2 + \|u_i - \bar u\|_R^2
        + t^\top P_f t \\
    \text{s.t.}\; & x_0 = \hat x_k, \quad
        x_{i+1} = f(\tilde x_i, \tilde u_i) + A_i (x_i - \tilde x_i) + B_i (u_i - \tilde u_i) \\
    & \underline{y}_i \le W_y h_i + b_y \le \overline{y}_i \quad (i = 1, \dots, N-1) \\
    & \|u_i\|_\infty \le u_{max} \\
    & \|c_N - \bar c\| \le t_c, \; \|h_N - \bar h\| \le t_h, \;
      \|P_f^{1/2} t\| \le \alpha_k, \; t \ge 0

The tightened bounds :math:`\underline y_i, \overline y_i` come from
eq. (optimization_constraint_yub)/(optimization_constraint_ylb); the i = 0 row involves
only :math:`\hat h_k` and is checked by the caller (paper notes 1). Because :math:`P_f \ge 0`
entrywise, :math:`\|\cdot\|_{P_f}` is monotone on the nonnegative orthant and the
relaxation through t is exact, both for the terminal set eq. (terminal_constraint) and
for the terminal cost.

Variables are stacked as ``z = [x_0, ..., x_N, u_0, ..., u_{N-1}, t_c, t_h, slacks]``.
The sparsity pattern is fixed at construction, so persistent solver sessions can update
values in place.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
import scipy.sparse as sp
from numpy.typing import NDArray

from ltv_lstm_mpc.certificates.tightening import TighteningCertificate
from ltv_lstm_mpc.exceptions import DimensionError, InvalidValueError
from ltv_lstm_mpc.lstm.kernel import Trajectory
from ltv_lstm_mpc.lstm.model import LSTMModel
from ltv_lstm_mpc.mpc.config import MPCConfig
from ltv_lstm_mpc.mpc.terminal import TerminalBoxReformulation, TerminalSet
from ltv_lstm_mpc.mpc.transcription import StepResult, TranscriptionBase
from ltv_lstm_mpc.solvers import (
    ConvexProblem,
    SecondOrderCone,
    Session,
    feasibility_tolerance,
    frozen_csc,
    solver_info,
)

__all__ = [
    "FHOCPSubproblem",
    "SparseTranscription",
    "SubproblemLayout",
]

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.int64]


@dataclass(frozen=True)
class SubproblemLayout:
    """Index map of the stacked decision vector z.

    Attributes
    ----------
    state_dim, input_dim, output_dim, N : int
        2n, m, p and the horizon.
    soft : bool
        Whether exact-penalty slacks are present (one per tightened output row, and one
        for the terminal level).
    """

    state_dim: int
    input_dim: int
    output_dim: int
    N: int
    soft: bool

    @property
    def n_states(self) -> int:
        """Number of state variables, (N + 1) * 2n."""
        return (self.N + 1) * self.state_dim

    @property
    def u_start(self) -> int:
        """Index of u_0 in z."""
        return self.n_states

    @property
    def t_start(self) -> int:
        """Index of t_c in z (t_h follows)."""
        return self.u_start + self.N * self.input_dim

    @property
    def s_start(self) -> int:
        """Index of the first slack (soft constraints only)."""
        return self.t_start + 2

    @property
    def n_output_slacks(self) -> int:
        """One slack per tightened output row i = 1..N-1 when soft."""
        return (self.N - 1) * self.output_dim if self.soft else 0

    @property
    def n_variables(self) -> int:
        """Length of z."""
        return self.s_start + (self.n_output_slacks + 1 if self.soft else 0)

    def x(self, i: int) -> slice:
        """Slice of x_i in z."""
        return slice(i * self.state_dim, (i + 1) * self.state_dim)

    def u(self, i: int) -> slice:
        """Slice of u_i in z."""
        start = self.u_start + i * self.input_dim
        return slice(start, start + self.input_dim)

    def split(self, z: FloatArray) -> tuple[FloatArray, FloatArray, FloatArray]:
        """``(x (N+1, 2n), u (N, m), t (2,))`` from a solution vector."""
        x = z[: self.n_states].reshape(self.N + 1, self.state_dim)
        u = z[self.u_start : self.t_start].reshape(self.N, self.input_dim)
        return x, u, z[self.t_start : self.t_start + 2]


class FHOCPSubproblem:
    r"""Builds the convex subproblem of paper notes 4 with a fixed sparsity pattern.

    Parameters
    ----------
    n, m, p : int
        LSTM size (state dimension 2n), inputs and outputs.
    N : int
        Horizon.
    Q : ndarray, shape (2n, 2n)
        Stage state weight (positive definite).
    R : ndarray, shape (m, m)
        Stage input weight (positive definite).
    P_f : ndarray, shape (2, 2)
        Terminal weight (paper notes 2.6), entrywise nonnegative.
    W_y, b_y : ndarray
        Output map of eq. (y_lstm).
    u_max : float
        Input bound.
    output_constraints : bool
        Include the tightened output rows (False: the paper's fallback problem).
    terminal_set : bool
        Include :math:`\|P_f^{1/2} t\| \le \alpha_k` (False: the paper's fallback).
    soft_penalty : float, optional
        If given, the output rows and the terminal level get nonnegative slacks with
        this exact-penalty (L1) weight: the problem is then always feasible, with cone
        solvers and, through the QP reformulation (its terminal box of level
        :math:`\max(\alpha_k, 0) + s_T`), with QP-only backends.
    """

    def __init__(
        self,
        *,
        n: int,
        m: int,
        p: int,
        N: int,
        Q: FloatArray,
        R: FloatArray,
        P_f: FloatArray,
        W_y: FloatArray,
        b_y: FloatArray,
        u_max: float,
        output_constraints: bool = True,
        terminal_set: bool = True,
        soft_penalty: float | None = None,
    ) -> None:
        n2 = 2 * n
        if Q.shape != (n2, n2):
            raise DimensionError(f"Q has shape {Q.shape}, expected ({n2}, {n2})")
        if R.shape != (m, m):
            raise DimensionError(f"R has shape {R.shape}, expected ({m}, {m})")
        if P_f.shape != (2, 2) or np.any(P_f < 0):
            raise InvalidValueError(f"P_f must be a (2, 2) entrywise nonnegative matrix, got {P_f}")
        if soft_penalty is not None and not soft_penalty > 0:
            raise InvalidValueError(f"soft_penalty must be positive, got {soft_penalty}")
        self.n, self.m, self.p, self.N = n, m, p, N
        self.output_constraints = output_constraints
        self.terminal_set = terminal_set
        self.soft_penalty = soft_penalty
        soft = soft_penalty is not None
        self.layout = layout = SubproblemLayout(n2, m, p, N, soft)
        self.P_f = P_f
        self.u_max = float(u_max)
        nz = layout.n_variables

        # ---- cost: 1/2 z'Pz + q'z (constant terms dropped)
        blocks = [2.0 * Q] * N + [np.zeros((n2, n2))] + [2.0 * R] * N + [2.0 * P_f]
        if soft:
            blocks.append(np.zeros((layout.n_output_slacks + 1, layout.n_output_slacks + 1)))
        P = sp.csc_matrix(sp.block_diag(blocks, format="csc"))
        P.eliminate_zeros()
        self._P = frozen_csc(P, "P")  # constant: validated once, reused every step
        self._Q, self._R = Q, R
        self._q = np.zeros(nz)
        if soft:
            self._q[layout.s_start :] = float(soft_penalty)  # type: ignore[arg-type]

        # ---- equalities: x_0 = x_hat; x_{i+1} - A_i x_i - B_i u_i = r_i
        rows: list[IntArray] = []
        cols: list[IntArray] = []
        eye_rows = np.arange(n2)
        rows.append(eye_rows)
        cols.append(eye_rows)
        dense_r, dense_c = np.meshgrid(np.arange(n2), np.arange(n2), indexing="ij")
        b_r, b_c = np.meshgrid(np.arange(n2), np.arange(m), indexing="ij")
        self._n_fixed = n2  # entries of the x_0 identity
        for i in range(N):
            base = n2 * (i + 1)
            rows.append(base + eye_rows)  # +I on x_{i+1}
            cols.append(layout.x(i + 1).start + eye_rows)
        for i in range(N):
            base = n2 * (i + 1)
            rows.append(base + dense_r.ravel())  # -A_i on x_i
            cols.append(layout.x(i).start + dense_c.ravel())
            rows.append(base + b_r.ravel())  # -B_i on u_i
            cols.append(layout.u(i).start + b_c.ravel())
        all_rows = np.concatenate(rows)
        all_cols = np.concatenate(cols)
        tags = np.arange(1, all_rows.size + 1, dtype=np.float64)
        A_tagged = sp.csc_matrix(
            (tags, (all_rows, all_cols)), shape=(n2 * (N + 1), nz)
        )  # no duplicates
        self._A_perm = A_tagged.data.astype(np.int64) - 1  # csc position -> entry index
        self._A_struct = A_tagged
        self._n_identity = n2 * (N + 1)
        self._A_values = np.empty(all_rows.size)
        self._A_values[: self._n_identity] = 1.0
        self._n_eq = n2 * (N + 1)

        # ---- tightened output rows on h_i, i = 1..N-1 (constant matrix)
        self._G: sp.csc_matrix | None = None
        if output_constraints and N > 1:
            blocks_G = []
            for i in range(1, N):
                row = sp.lil_matrix((p, nz))
                row[:, layout.x(i).start + n : layout.x(i).stop] = W_y
                blocks_G.append(row)
            G_out = sp.vstack(blocks_G).tocsc()
            if soft:
                # W_y h_i + s_i >= lower  and  W_y h_i - s_i <= upper
                S = sp.lil_matrix((layout.n_output_slacks, nz))
                for k in range(layout.n_output_slacks):
                    S[k, layout.s_start + k] = 1.0
                self._G = frozen_csc(sp.vstack([G_out + S.tocsc(), G_out - S.tocsc()]), "G")
            else:
                self._G = frozen_csc(G_out, "G")
        self._b_y = b_y

        # ---- bounds
        self._lb = np.full(nz, -np.inf)
        self._ub = np.full(nz, np.inf)
        self._lb[layout.u_start : layout.t_start] = -self.u_max
        self._ub[layout.u_start : layout.t_start] = self.u_max
        self._lb[layout.t_start :] = 0.0

        # ---- cone matrices (constant); g, f change every step
        F_c = sp.lil_matrix((n, nz))
        F_h = sp.lil_matrix((n, nz))
        for j in range(n):
            F_c[j, layout.x(N).start + j] = 1.0
            F_h[j, layout.x(N).start + n + j] = 1.0
        self._F_c, self._F_h = frozen_csc(F_c, "F_c"), frozen_csc(F_h, "F_h")
        self._e_c = np.zeros(nz)
        self._e_c[layout.t_start] = 1.0
        self._e_h = np.zeros(nz)
        self._e_h[layout.t_start + 1] = 1.0
        #: The terminal set of eq. (optimization) (cone row ||P_f^{1/2} t|| <= alpha_k).
        self.terminal = TerminalSet(P_f, n)
        F_t = sp.lil_matrix((2, nz))
        F_t[:, layout.t_start : layout.t_start + 2] = self.terminal.square_root
        self._F_t = frozen_csc(F_t, "F_t")
        self._e_t = np.zeros(nz)
        if soft:
            self._e_t[-1] = 1.0  # ||P_f^{1/2} t|| <= alpha + s_T
        self.reformulation = TerminalBoxReformulation(self)

    # ----------------------------------------------------------------------------- build
    def build(
        self,
        *,
        x_hat: FloatArray,
        x_bar: FloatArray,
        u_bar: FloatArray,
        x_lin: FloatArray,
        u_lin: FloatArray,
        f_lin: FloatArray,
        A: FloatArray,
        B: FloatArray,
        y_lower: FloatArray | None,
        y_upper: FloatArray | None,
        alpha: float | None,
    ) -> ConvexProblem:
        r"""The subproblem for one linearization.

        Parameters
        ----------
        x_hat : (2n,)
            :math:`\hat x_k`.
        x_bar, u_bar : (2n,), (m,)
            Set-points from the reference calculator.
        x_lin, u_lin : (N, 2n), (N, m)
            Linearization points :math:`\tilde x_i, \tilde u_i`, i = 0..N-1.
        f_lin, A, B : (N, 2n), (N, 2n, 2n), (N, 2n, m)
            :math:`f(\tilde x_i, \tilde u_i)` and its Jacobians.
        y_lower, y_upper : (N, p), optional
            Tightened bounds on :math:`W_y h_i + b_y` (row 0 is ignored: it is fixed by
            :math:`\hat x_k`). Needed when the problem has output constraints.
        alpha : float, optional
            Terminal level :math:`\alpha_k`; needed when the problem has the terminal set.
        """
        layout, N, n2 = self.layout, self.N, 2 * self.n
        # Equality values in entry order: identities, then (-A_i, -B_i) for each stage.
        values = self._A_values
        offset = self._n_identity
        m = self.m
        for i in range(N):
            values[offset : offset + n2 * n2] = -A[i].ravel()
            offset += n2 * n2
            values[offset : offset + n2 * m] = -B[i].ravel()
            offset += n2 * m
        A_eq = sp.csc_matrix(
            (values[self._A_perm], self._A_struct.indices, self._A_struct.indptr),
            shape=self._A_struct.shape,
        )
        residual = f_lin - np.einsum("kij,kj->ki", A, x_lin) - np.einsum("kij,kj->ki", B, u_lin)
        b_eq = np.concatenate([x_hat, residual.ravel()])

        q = self._q.copy()
        qx = -2.0 * (self._Q @ x_bar)
        qu = -2.0 * (self._R @ u_bar)
        q[: N * n2] = np.tile(qx, N)
        q[layout.u_start : layout.t_start] = np.tile(qu, N)

        G = l_vec = u_vec = None
        if self._G is not None:
            if y_lower is None or y_upper is None:
                raise InvalidValueError("output constraints need y_lower and y_upper")
            lower = (y_lower[1:] - self._b_y).ravel()
            upper = (y_upper[1:] - self._b_y).ravel()
            G = self._G
            if self.soft_penalty is not None:
                inf = np.full(lower.size, np.inf)
                l_vec = np.concatenate([lower, -inf])
                u_vec = np.concatenate([inf, upper])
            else:
                l_vec, u_vec = lower, upper

        n = self.n
        cones = [
            SecondOrderCone(self._F_c, -x_bar[:n], self._e_c, 0.0),
            SecondOrderCone(self._F_h, -x_bar[n:], self._e_h, 0.0),
        ]
        if self.terminal_set:
            if alpha is None:
                raise InvalidValueError("the terminal set needs alpha")
            cones.append(SecondOrderCone(self._F_t, np.zeros(2), self._e_t, float(alpha)))
        return ConvexProblem(
            P=self._P,
            q=q,
            A_eq=A_eq,
            b_eq=b_eq,
            G=G,
            l=l_vec,
            u=u_vec,
            lb=self._lb,
            ub=self._ub,
            cones=tuple(cones),
        )


class SparseTranscription(TranscriptionBase):
    """States and inputs as variables, exact cones (:class:`FHOCPSubproblem`), one Session each.

    Cone solvers (cvxpy:CLARABEL, ECOS, SCS) solve the exact second-order cones; QP-only
    backends get :class:`TerminalBoxReformulation`, named in every result.

    Parameters
    ----------
    model, config, tightening, Q, R, kinds
        As :class:`~ltv_lstm_mpc.mpc.condensed.CondensedTranscription`.
    """

    name = "sparse"

    def __init__(
        self,
        model: LSTMModel,
        config: MPCConfig,
        tightening: TighteningCertificate,
        Q: FloatArray,
        R: FloatArray,
        kinds: tuple[str, ...] = ("nominal",),
    ) -> None:
        common: dict[str, Any] = dict(
            n=model.n, m=model.m, p=model.p, N=config.N, Q=Q, R=R,
            P_f=np.asarray(tightening.P_f), W_y=model.W_y, b_y=model.b_y, u_max=config.u_max,
        )  # fmt: skip
        self._subproblems: dict[str, FHOCPSubproblem] = {}
        for kind in kinds:
            if kind == "nominal":
                self._subproblems[kind] = FHOCPSubproblem(**common)
            elif kind == "paper":
                self._subproblems[kind] = FHOCPSubproblem(
                    **common, output_constraints=False, terminal_set=False
                )
            else:
                self._subproblems[kind] = FHOCPSubproblem(
                    **common, soft_penalty=config.soft_penalty
                )
        self._sessions: dict[str, Session] = {
            kind: Session(
                config.solver,
                tolerance=config.tolerance,
                reformulation=sub.reformulation,
                **config.solver_settings,
            )
            for kind, sub in self._subproblems.items()
        }
        info = solver_info(config.solver)
        self.reformulation = None if info.supports_cones else TerminalBoxReformulation.name
        self.tolerance = feasibility_tolerance(config.solver, config.tolerance)
        self._data: dict[str, Any] = {}
        self._last: dict[str, ConvexProblem] = {}

        self.N, self.n2, self.m = config.N, 2 * model.n, model.m

    def subproblem(self, kind: str = "nominal") -> FHOCPSubproblem:
        """The builder of the subproblem ``kind`` (``"nominal"``, ``"paper"`` or ``"soft"``,
        where the configuration has it): what replay tools rebuild a step's problem with."""
        try:
            return self._subproblems[kind]
        except KeyError:
            raise InvalidValueError(
                f"no {kind!r} subproblem; this transcription has {sorted(self._subproblems)}"
            ) from None

    def last_problem(self, kind: str = "nominal") -> ConvexProblem:
        """The subproblem ``kind`` as solved for the current linearization (its exact-cone
        form; :meth:`FHOCPSubproblem.reformulation` gives the QP form).

        Raises
        ------
        InvalidValueError
            ``kind`` was not solved since the last linearization.
        """
        if kind not in self._last:
            raise InvalidValueError(
                f"the {kind!r} subproblem was not solved at this step (solved: "
                f"{sorted(self._last) or 'none'})"
            )
        return self._last[kind]

    def reset(self) -> None:
        """Nothing to forget: every solve is a cold start."""

    def _violation(self, problem: ConvexProblem, z: FloatArray) -> float:
        """Constraint violation at z: cones included when solved exactly; with the QP
        reformulation (t pinned to 0) the linear constraints only."""
        if self.reformulation is None:
            return problem.max_violation(z)
        viol = 0.0
        if problem.A_eq is not None and problem.b_eq is not None:
            viol = float(np.max(np.abs(problem.A_eq @ z - problem.b_eq), initial=0.0))
        if problem.G is not None and problem.l is not None and problem.u is not None:
            Gz = problem.G @ z
            viol = max(viol, float(np.max(np.maximum(problem.l - Gz, Gz - problem.u), initial=0.0)))
        if problem.lb is not None and problem.ub is not None:
            lay = self._subproblems["nominal"].layout if "nominal" in self._subproblems else None
            stop = lay.t_start if lay is not None else z.shape[0]
            lo, hi = problem.lb[:stop], problem.ub[:stop]
            viol = max(viol, float(np.max(np.maximum(lo - z[:stop], z[:stop] - hi), initial=0.0)))
        return viol

    def build(
        self,
        traj: Trajectory,
        x_bar: FloatArray,
        u_bar: FloatArray,
        lower: FloatArray,
        upper: FloatArray,
        alpha: float,
    ) -> None:
        """Keep the linearization (the sparse problem needs x_hat in its equalities)."""
        N, n2, m = self.N, self.n2, self.m
        self._last = {}
        self._data = dict(
            x_bar=x_bar, u_bar=u_bar, x_lin=traj.S[:N, :n2].copy(),
            u_lin=traj.S[:N, n2 : n2 + m].copy(), f_lin=traj.S[1 : N + 1, :n2].copy(),
            A=traj.A.copy(), B=traj.B.copy(), y_lower=lower, y_upper=upper, alpha=alpha,
        )  # fmt: skip

    def solve(self, kind: str, x_hat: FloatArray) -> StepResult:
        r"""Build the subproblem ``kind`` at :math:`\hat x_k` and solve it."""
        sub, session = self._subproblems[kind], self._sessions[kind]
        problem = sub.build(x_hat=x_hat, **self._data)
        self._last[kind] = problem
        if session.structure_key is None:
            session.setup(problem)
        else:
            session.update(problem)
        solution = session.solve()
        elapsed = solution.setup_time + solution.solve_time + solution.overhead_time
        if solution.z is None or not solution.status.has_solution:
            return StepResult(
                status=solution.status, u=None, x_linear=None, violation=float("nan"),
                tolerance=self.tolerance, solver_time=elapsed,
                iterations=int(solution.iterations or 0), info=solution.info,
            )  # fmt: skip
        z = np.asarray(solution.z)
        x_linear, u, _ = sub.layout.split(z)
        scale = 1.0 + max(
            float(np.max(np.abs(problem.b_eq), initial=0.0)) if problem.b_eq is not None else 0.0,
            float(np.max(np.abs(problem.u), initial=0.0)) if problem.u is not None else 0.0,
            self._data["alpha"] if np.isfinite(self._data["alpha"]) else 0.0,
            1.0,
        )
        return StepResult(
            status=solution.status,
            u=np.array(u),
            x_linear=np.array(x_linear),
            violation=self._violation(problem, z) / scale,
            tolerance=self.tolerance,
            solver_time=elapsed,
            iterations=int(solution.iterations or 0),
            info=solution.info,
        )
