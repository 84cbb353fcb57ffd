r"""Compiled (numba) observer update, eq. (lstm_observer); the numpy reference is
:meth:`ltv_lstm_mpc.Observer.update` on the numpy kernel (tested to 1e-12 in
``tests/test_kernel.py``). Used when the model's kernel is compiled.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from ltv_lstm_mpc.lstm.compiled import lstm_cell
from ltv_lstm_mpc.numba_support import build_workspace, njit, workspace_type

__all__ = [
    "CONSTRUCTORS",
    "OBSERVER_FIELDS",
    "ObserverWorkspace",
    "new_observer_workspace",
    "observer_update",
]

#: Fields of :data:`ObserverWorkspace`, in the order of its compiled constructor.
OBSERVER_FIELDS = ("WU", "W_y", "b_y", "L_gates", "L_d", "S", "T", "TC", "extra")

ObserverWorkspace = workspace_type(
    "ObserverWorkspace",
    OBSERVER_FIELDS,
    """Buffers of :func:`observer_update`, shared with the observer.

    ``WU``: the kernel's stacked gate weights; ``W_y``, ``b_y``: the output map;
    ``L_gates`` (4n, p): the gate gains (0 rows: no injection, Remark 3); ``L_d`` (p, p):
    the disturbance gain; ``S`` (2n + m + 1), ``T`` (4n), ``TC`` (n), ``extra`` (4n):
    scratch.
    """,
    __name__,
)
ObserverWorkspaceType = getattr(ObserverWorkspace, "numba_type", None)


def new_observer_workspace(**fields: Any) -> Any:
    """A :data:`ObserverWorkspace` from its fields by name (:data:`OBSERVER_FIELDS`)."""
    return build_workspace(_new_observer_workspace, OBSERVER_FIELDS, fields)


@njit(cache=True)
def _new_observer_workspace(
    WU: Any,
    W_y: Any,
    b_y: Any,
    L_gates: Any,
    L_d: Any,
    S: Any,
    T: Any,
    TC: Any,
    extra: Any,
) -> Any:
    """The compiled constructor (no constructor compile at run time; cached)."""
    return ObserverWorkspace(WU, W_y, b_y, L_gates, L_d, S, T, TC, extra)


@njit(cache=True)
def observer_update(
    workspace: Any,
    d_max: float,
    x_hat: Any,
    d_hat: Any,
    y: Any,
    u: Any,
    x_out: Any,
    d_out: Any,
) -> None:
    r"""eq. (lstm_observer): :math:`(\hat x_k, \hat d_k, y_k, u_k) \to (\hat x_{k+1},
    \hat d_{k+1})` into ``x_out``, ``d_out``. The innovation is
    :math:`y_k - W_y \hat h_k - b_y - \hat d_k`; the workspace's ``L_gates`` injects it
    into the gates; :math:`\hat d` is saturated at ``d_max``."""
    WU, W_y, b_y = workspace.WU, workspace.W_y, workspace.b_y
    L_gates, L_d = workspace.L_gates, workspace.L_d
    S, T, TC, extra = workspace.S, workspace.T, workspace.TC, workspace.extra
    n = WU.shape[0] // 4
    p = W_y.shape[0]
    m = u.shape[0]
    innovation = np.empty(p)
    for j in range(p):
        acc = y[j] - b_y[j] - d_hat[j]
        for a in range(n):
            acc -= W_y[j, a] * x_hat[n + a]
        innovation[j] = acc
    for a in range(2 * n):
        S[a] = x_hat[a]
    for j in range(m):
        S[2 * n + j] = u[j]
    injected = extra[:0]
    if L_gates.shape[0]:
        for r in range(4 * n):
            acc = 0.0
            for j in range(p):
                acc += L_gates[r, j] * innovation[j]
            extra[r] = acc
        injected = extra
    lstm_cell(WU, S[n:], T, S[:n], x_out[:n], x_out[n : 2 * n], TC, injected)
    for j in range(p):
        acc = d_hat[j]
        for l in range(p):
            acc += L_d[j, l] * innovation[l]
        d_out[j] = min(max(acc, -d_max), d_max)


#: This module's compiled constructors (the compiled workspace constructor): what compiles with it
#: (:func:`~ltv_lstm_mpc.loop.kernels.controller_kernels`).
CONSTRUCTORS = (_new_observer_workspace,)
