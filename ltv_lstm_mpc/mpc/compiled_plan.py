r"""Compiled (numba) plan checks: re-simulation, cost and residuals of the applied plan.

The twin of :class:`~ltv_lstm_mpc.mpc.fhocp.PlanCost` and
:func:`~ltv_lstm_mpc.mpc.fhocp.plan_residuals` (their reference, tested to 1e-12 in
``tests/test_kernel.py``); the terminal norm is
:func:`~ltv_lstm_mpc.mpc.terminal.terminal_norm_of_squares`. Used when the model's kernel is
compiled.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from ltv_lstm_mpc.lstm.compiled import lstm_cell
from ltv_lstm_mpc.mpc.terminal import terminal_norm_of_squares
from ltv_lstm_mpc.numba_support import REDUCTIONS, build_workspace, njit, workspace_type

__all__ = ["CONSTRUCTORS", "PLAN_FIELDS", "PlanWorkspace", "new_plan_workspace", "plan_metrics"]

#: Fields of :data:`PlanWorkspace`, in the order of its compiled constructor.
PLAN_FIELDS = ("WU", "S", "T", "TC", "W_y", "b_y", "Q", "R", "P_terms", "out", "Q_diagonal")

PlanWorkspace = workspace_type(
    "PlanWorkspace",
    PLAN_FIELDS,
    r"""Buffers of :func:`plan_metrics`, shared with ``RobustMPC``.

    ``WU``: the kernel's stacked gate weights; ``S``, ``T``, ``TC``: the plan's Trajectory
    (row 0 state, inputs given); ``W_y``, ``b_y``: the output map; ``Q``, ``R``: the stage
    weights; ``P_terms``: the ``terms`` of the
    :class:`~ltv_lstm_mpc.mpc.terminal.TerminalSet`; ``out`` (4,): the metrics written;
    ``Q_diagonal``: Q is diagonal.
    """,
    __name__,
)
PlanWorkspaceType = getattr(PlanWorkspace, "numba_type", None)


def new_plan_workspace(**fields: Any) -> Any:
    """A :data:`PlanWorkspace` from its fields by name (:data:`PLAN_FIELDS`)."""
    return build_workspace(_new_plan_workspace, PLAN_FIELDS, fields)


@njit(cache=True)
def _new_plan_workspace(WU, S, T, TC, W_y, b_y, Q, R, P_terms, out, Q_diagonal):  # type: ignore[no-untyped-def]
    """The compiled constructor (no constructor compile at run time; cached)."""
    return PlanWorkspace(WU, S, T, TC, W_y, b_y, Q, R, P_terms, out, Q_diagonal)


@njit(cache=True, fastmath=REDUCTIONS)
def plan_metrics(
    workspace: Any,
    x_bar: Any,
    u_bar: Any,
    lower: Any,
    upper: Any,
    x_linear: Any,
    x_plan: Any,
) -> None:
    r"""Re-simulate the plan in the workspace's ``S`` (row 0 state, inputs given) and its
    checks.

    Writes the states into ``x_plan`` (N + 1, 2n) and the workspace's ``out`` = [cost eq.
    (optimization_cost), terminal norm :math:`\|[\|c_N-\bar c\|, \|h_N-\bar h\|]\|_{P_f}`,
    largest tightened-output violation (>= 0), :math:`\max|x - x_{linear}|` (NaN when
    ``x_linear`` has no rows)]; ``Q_diagonal``: Q's quadratic form in O(n) instead of
    O(n^2).
    """
    WU, S, T, TC = workspace.WU, workspace.S, workspace.T, workspace.TC
    W_y, b_y, Q, R = workspace.W_y, workspace.b_y, workspace.Q, workspace.R
    P_terms, out, Q_diagonal = workspace.P_terms, workspace.out, workspace.Q_diagonal
    N = x_plan.shape[0] - 1
    n = WU.shape[0] // 4
    n2 = 2 * n
    m = u_bar.shape[0]
    p = W_y.shape[0]
    no_extra = np.zeros(0)
    for k in range(N):
        lstm_cell(WU, S[k, n:], T[k], S[k, :n], S[k + 1, :n], S[k + 1, n:n2], TC[k], no_extra)
    for k in range(N + 1):
        for q in range(n2):
            x_plan[k, q] = S[k, q]
    dx = np.empty(n2)
    du = np.empty(m)
    stage = 0.0
    violation = 0.0
    for k in range(N):
        for q in range(n2):
            dx[q] = x_plan[k, q] - x_bar[q]
        for a in range(m):
            du[a] = S[k, n2 + a] - u_bar[a]
        for a in range(n2):
            if Q_diagonal:
                stage += Q[a, a] * dx[a] * dx[a]
                continue
            acc = 0.0
            for b in range(n2):
                acc += Q[a, b] * dx[b]
            stage += dx[a] * acc
        for a in range(m):
            acc = 0.0
            for b in range(m):
                acc += R[a, b] * du[b]
            stage += du[a] * acc
        for j in range(p):
            y = b_y[j]
            for q in range(n):
                y += W_y[j, q] * x_plan[k, n + q]
            if lower[k, j] - y > violation:
                violation = lower[k, j] - y
            if y - upper[k, j] > violation:
                violation = y - upper[k, j]
    tc2 = 0.0
    th2 = 0.0
    for q in range(n):
        dc = x_plan[N, q] - x_bar[q]
        dh = x_plan[N, n + q] - x_bar[n + q]
        tc2 += dc * dc
        th2 += dh * dh
    terminal = terminal_norm_of_squares(tc2, th2, P_terms)
    gap = np.nan
    if x_linear.shape[0]:
        gap = 0.0
        for k in range(N + 1):
            for q in range(n2):
                d = abs(x_plan[k, q] - x_linear[k, q])
                if d > gap:
                    gap = d
    out[0] = stage + terminal * terminal
    out[1] = terminal
    out[2] = violation
    out[3] = gap


#: This module's compiled constructor: what compiles with it
#: (:func:`~ltv_lstm_mpc.mpc.kernels.compiled_kernels`).
CONSTRUCTORS = (_new_plan_workspace,)
