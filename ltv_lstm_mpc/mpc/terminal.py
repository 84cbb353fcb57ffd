r"""The terminal set and terminal cost of eq. (optimization), in every form the library uses.

The terminal ingredients of the FHOCP (paper eq. (optimization_cost) and eq.
(terminal_constraint), with :math:`P_f` from eq. (terminal_cost_matrix)):

.. math::

    V_f(x_N) = \|[\,\|c_N - \bar c\|, \|h_N - \bar h\|\,]\|_{P_f}^2, \qquad
    \mathcal{X}_f(k) = \{x_N : \|[\,\|c_N - \bar c\|, \|h_N - \bar h\|\,]\|_{P_f}
    \le \alpha_k\}

with :math:`\alpha_k` from the tightening (:mod:`ltv_lstm_mpc.certificates.tightening`).
This module is their one home; changing the terminal set touches the tightening (which
computes :math:`P_f` and :math:`\alpha_k`) and this file:

* :class:`TerminalSet` — the numbers every form shares: :math:`P_f`, its square root for
  the cone rows :math:`\|P_f^{1/2} t\| \le \alpha_k` (exact cones, both transcriptions),
  the numeric norm of a state (plan checks, :class:`~ltv_lstm_mpc.mpc.fhocp.PlanCost`), the
  level as an expression of :math:`t_c, t_h` (the CasADi NLP of the exact NMPC) and the
  box data of the QP reformulation.
* :func:`terminal_box_data` and :class:`TerminalBoxReformulation` — the conservative QP
  form for QP-only backends (paper notes 4), named in every result that uses it.
* :func:`terminal_norm_of_squares` — the norm from :math:`\|c_N-\bar c\|^2` and
  :math:`\|h_N-\bar h\|^2`, compiled (numba) for the plan-check kernel; the same formula as
  :meth:`TerminalSet.norm`, its reference.

Why the relaxation through :math:`t = (t_c, t_h)` is exact: :math:`P_f \ge 0` entrywise,
so :math:`\|\cdot\|_{P_f}` is monotone on the nonnegative orthant (paper notes 4).
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING, Any

import numpy as np
import scipy.sparse as sp
from numpy.typing import NDArray

from ltv_lstm_mpc.exceptions import DimensionError, InvalidValueError
from ltv_lstm_mpc.numba_support import REDUCTIONS, njit
from ltv_lstm_mpc.solvers import ConvexProblem

if TYPE_CHECKING:
    from ltv_lstm_mpc.mpc.sparse import FHOCPSubproblem

__all__ = [
    "TerminalBoxReformulation",
    "TerminalSet",
    "terminal_box_data",
    "terminal_norm_of_squares",
]

FloatArray = NDArray[np.float64]


@njit(cache=True, fastmath=REDUCTIONS)  # the plan-check kernel's flags
def terminal_norm_of_squares(tc2: float, th2: float, P_terms: Any) -> float:
    r""":math:`\sqrt{P_{11} t_c^2 + (P_{12}+P_{21}) t_c t_h + P_{22} t_h^2}` from
    ``tc2`` = :math:`t_c^2`, ``th2`` = :math:`t_h^2` and ``P_terms`` =
    :attr:`TerminalSet.terms` (compiled twin of :meth:`TerminalSet.norm`)."""
    level = P_terms[0] * tc2 + P_terms[1] * math.sqrt(tc2 * th2) + P_terms[2] * th2
    return math.sqrt(level if level > 0.0 else 0.0)


def terminal_box_data(P_f: FloatArray) -> tuple[float, float, FloatArray]:
    r"""The numbers of :class:`TerminalBoxReformulation` (paper notes 4), for both transcriptions.

    Returns
    -------
    weight_c, weight_h : float
        :math:`P_{11}+P_{12}` and :math:`P_{22}+P_{12}`: the terminal cost bound
        :math:`t^\top P_f t \le w_c\|c_N-\bar c\|^2 + w_h\|h_N-\bar h\|^2`.
    unit_tau : ndarray, shape (2,)
        :math:`\tau` for :math:`\alpha_k = 1`: with :math:`\tau^\top P_f \tau = 1` and
        :math:`P_{11}\tau_c^2 = P_{22}\tau_h^2` (the largest-volume box); the box of level
        :math:`\alpha_k` has half-widths :math:`\alpha_k \tau / \sqrt n`.
    """
    P_f = np.asarray(P_f, dtype=np.float64)
    weight_c = float(P_f[0, 0] + P_f[0, 1])
    weight_h = float(P_f[1, 1] + P_f[0, 1])
    direction = np.array([1.0, np.sqrt(P_f[0, 0] / P_f[1, 1])])
    unit_tau = direction / np.sqrt(direction @ P_f @ direction)
    return weight_c, weight_h, unit_tau


class TerminalSet:
    r"""The terminal set :math:`\mathcal{X}_f(k)` and cost :math:`V_f` of eq. (optimization).

    Parameters
    ----------
    P_f : array (2, 2)
        Terminal weight (eq. (terminal_cost_matrix)), symmetric positive definite and
        entrywise nonnegative (paper notes 2.6).
    n : int
        LSTM state size n (the vectors :math:`c, h` have n entries each).

    Attributes
    ----------
    terms : tuple of float
        :math:`(P_{11}, P_{12} + P_{21}, P_{22})`, the coefficients of the level.
    square_root : ndarray (2, 2)
        :math:`P_f^{1/2}` (Cholesky factor, transposed): :math:`\|P_f^{1/2} t\|^2 =
        t^\top P_f t`, the matrix of the terminal cone row.
    weight_c, weight_h, unit_tau
        :func:`terminal_box_data`.
    unit_half_widths : ndarray (2n,)
        Box half-widths per state entry at :math:`\alpha_k = 1`
        (:math:`\tau_c/\sqrt n` on c, :math:`\tau_h/\sqrt n` on h).
    box_weights : ndarray (2n,)
        :math:`(w_c, \dots, w_c, w_h, \dots, w_h)`: the box reformulation's terminal cost
        :math:`\sum_j w_j (x_{N,j} - \bar x_j)^2`.
    """

    def __init__(self, P_f: Any, n: int) -> None:
        P_f = np.array(P_f, dtype=np.float64)
        if P_f.shape != (2, 2):
            raise DimensionError(f"P_f has shape {P_f.shape}, expected (2, 2)")
        if not np.all(np.isfinite(P_f)) or np.any(P_f < 0):
            raise InvalidValueError(f"P_f must be a (2, 2) entrywise nonnegative matrix, got {P_f}")
        self.P_f = P_f
        self.n = int(n)
        self.terms = (float(P_f[0, 0]), float(P_f[0, 1] + P_f[1, 0]), float(P_f[1, 1]))
        self.square_root = np.linalg.cholesky(P_f).T  # any square root: ||S t||^2 = t'P_f t
        self.weight_c, self.weight_h, self.unit_tau = terminal_box_data(P_f)
        self.unit_half_widths = np.repeat(np.asarray(self.unit_tau) / np.sqrt(self.n), self.n)
        self.box_weights = np.concatenate(
            [np.full(self.n, self.weight_c), np.full(self.n, self.weight_h)]
        )

    def level(self, t_c: Any, t_h: Any) -> Any:
        r""":math:`P_{11} t_c^2 + (P_{12}+P_{21}) t_c t_h + P_{22} t_h^2` (= :math:`V_f`).

        Plain arithmetic, so ``t_c``, ``t_h`` may be floats, arrays or CasADi expressions
        (the exact NMPC's smoothed norms).
        """
        p11, p12, p22 = self.terms
        return p11 * t_c**2 + p12 * t_c * t_h + p22 * t_h**2

    def norm(self, x_N: FloatArray, x_bar: FloatArray) -> float:
        r""":math:`\|[\|c_N - \bar c\|, \|h_N - \bar h\|]\|_{P_f}`, the terminal-set norm."""
        n = self.n
        d = x_N - x_bar
        dc, dh = d[:n], d[n:]
        tc2, th2 = float(np.vdot(dc, dc)), float(np.vdot(dh, dh))
        p11, p12, p22 = self.terms
        return math.sqrt(max(p11 * tc2 + p12 * math.sqrt(tc2 * th2) + p22 * th2, 0.0))

    def contains(self, x_N: FloatArray, x_bar: FloatArray, alpha: float) -> bool:
        r""":math:`x_N \in \mathcal{X}_f(k)` for level ``alpha`` = :math:`\alpha_k`."""
        return self.norm(x_N, x_bar) <= alpha


class TerminalBoxReformulation:
    r"""Conservative QP replacement of the terminal cones (paper notes 4), for QP-only backends.

    * Terminal cost: since :math:`2 t_c t_h \le t_c^2 + t_h^2` and :math:`P_{f,12} \ge 0`,
      :math:`t^\top P_f t \le (P_{11}+P_{12})\|c_N-\bar c\|^2 + (P_{22}+P_{12})\|h_N-\bar h\|^2`
      (an upper bound: the QP minimizes a larger cost).
    * Terminal set: the box :math:`|c_{N,j} - \bar c_j| \le \tau_c/\sqrt n`,
      :math:`|h_{N,j} - \bar h_j| \le \tau_h/\sqrt n` implies
      :math:`\|c_N - \bar c\| \le \tau_c`, :math:`\|h_N - \bar h\| \le \tau_h`; with
      :math:`\tau^\top P_f \tau = \alpha_k^2` and :math:`P_{11}\tau_c^2 = P_{22}\tau_h^2`
      (the largest-volume such box) it lies inside :math:`\mathcal{X}_f(k)`.

    The t variables are kept (fixed to 0) so the variable layout does not change. In the
    soft problem the box has the level :math:`\max(\alpha_k, 0) + s_T` with the terminal
    level's exact-penalty slack :math:`s_T \ge 0` (rows in :math:`(x_N, s_T)`), as the
    condensed transcription's soft QP: with the output slacks the soft QP is then feasible
    by construction on QP-only backends too.
    """

    name = "terminal_box_and_quadratic_cost_bound"

    def __init__(self, subproblem: FHOCPSubproblem) -> None:
        self.subproblem = subproblem
        terminal = subproblem.terminal
        #: tau for alpha_k = 1: (||c_N - c_bar||, ||h_N - h_bar||) bounds on the P_f-ellipse
        self.weight_c, self.weight_h, self.unit_tau = (
            terminal.weight_c, terminal.weight_h, terminal.unit_tau
        )  # fmt: skip
        self._weights = terminal.box_weights

    def apply(self, problem: ConvexProblem) -> ConvexProblem:
        """Return the cone-free problem (see the class docstring)."""
        sub = self.subproblem
        layout, n, N = sub.layout, sub.n, sub.N
        c_bar = -problem.cones[0].g
        h_bar = -problem.cones[1].g
        xN = layout.x(N)
        weights = self._weights
        diag = np.zeros(layout.n_variables)
        diag[xN] = 2.0 * weights
        # t is pinned to 0 below; a unit diagonal there (instead of 2 P_f) keeps P positive
        # definite for solvers that need it (quadprog) without changing the solution.
        diag[layout.t_start : layout.t_start + 2] = 1.0 - 2.0 * np.diag(sub.P_f)
        P = problem.P + sp.diags(diag, format="csc")
        t_block = sp.lil_matrix((layout.n_variables, layout.n_variables))
        t_block[layout.t_start, layout.t_start + 1] = -2.0 * sub.P_f[0, 1]
        t_block[layout.t_start + 1, layout.t_start] = -2.0 * sub.P_f[0, 1]
        P = (P + t_block.tocsc()).tocsc()
        P.eliminate_zeros()
        q = problem.q.copy()
        q[xN] += -2.0 * weights * np.concatenate([c_bar, h_bar])
        assert problem.lb is not None and problem.ub is not None  # set by FHOCPSubproblem
        lb, ub = problem.lb.copy(), problem.ub.copy()
        lb[layout.t_start : layout.t_start + 2] = 0.0
        ub[layout.t_start : layout.t_start + 2] = 0.0
        G, l_rows, u_rows = problem.G, problem.l, problem.u
        if len(problem.cones) == 3:
            level = max(problem.cones[2].f, 0.0)
            unit = np.concatenate(
                [np.full(n, self.unit_tau[0]), np.full(n, self.unit_tau[1])]
            ) / np.sqrt(n)  # half-widths of the box of level 1
            centre = np.concatenate([c_bar, h_bar])
            if sub.soft_penalty is None:
                lb[xN] = centre - level * unit
                ub[xN] = centre + level * unit
            else:  # the box of level max(alpha_k, 0) + s_T, s_T the last variable
                G, l_rows, u_rows = self._soft_box_rows(problem, xN, centre, unit, level)
        return ConvexProblem(
            P=P,
            q=q,
            A_eq=problem.A_eq,
            b_eq=problem.b_eq,
            G=G,
            l=l_rows,
            u=u_rows,
            lb=lb,
            ub=ub,
            cones=(),
        )

    @staticmethod
    def _soft_box_rows(
        problem: ConvexProblem, xN: slice, centre: FloatArray, unit: FloatArray, level: float
    ) -> tuple[Any, FloatArray, FloatArray]:
        r"""The rows of the soft problem's terminal box
        :math:`|x_{N,j} - \bar x_j| \le (\max(\alpha_k, 0) + s_T)\, w_j` (``unit`` = w,
        the half-widths of the box of level 1; :math:`s_T \ge 0` the last variable, the
        exact-penalty slack of the terminal level), appended to the problem's rows:
        :math:`x_{N,j} - w_j s_T \le \bar x_j + \max(\alpha_k, 0) w_j` and
        :math:`x_{N,j} + w_j s_T \ge \bar x_j - \max(\alpha_k, 0) w_j`. Returns
        ``(G, l, u)``."""
        n_variables = problem.q.shape[0]
        size = unit.shape[0]
        columns = np.arange(n_variables)[xN]
        slack = n_variables - 1
        rows = np.repeat(np.arange(2 * size), 2)
        cols = np.column_stack([np.tile(columns, 2), np.full(2 * size, slack)]).ravel()
        values = np.column_stack([np.ones(2 * size), np.concatenate([-unit, unit])]).ravel()
        box = sp.csc_matrix((values, (rows, cols)), shape=(2 * size, n_variables))
        inf = np.full(size, np.inf)
        box_l = np.concatenate([-inf, centre - level * unit])
        box_u = np.concatenate([centre + level * unit, inf])
        if problem.G is None:
            return box, box_l, box_u
        m = problem.G.shape[0]
        l_rows = np.full(m, -np.inf) if problem.l is None else problem.l
        u_rows = np.full(m, np.inf) if problem.u is None else problem.u
        G = sp.vstack([problem.G, box], format="csc")
        return G, np.concatenate([l_rows, box_l]), np.concatenate([u_rows, box_u])
