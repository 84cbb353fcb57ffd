r"""The preparation phase of the condensed QP as one compiled call (``RobustMPC.prepare``).

:meth:`~ltv_lstm_mpc.RobustMPC.prepare` builds the proof candidate (previous plan
shifted by one, :math:`\bar u_k` appended; paper notes 4), reuses the previous re-simulation when
the linearization starts at its predicted :math:`x_{1|k-1}`, rolls the LSTM out along the
candidate (eq. lstm), linearizes it (eq. jacobian) and condenses the QP. On the condensed
transcription with the compiled kernel, :func:`prepare_condensed` does all of it in one call:
the same steps as the Python code of ``prepare`` (its readable reference, tested against it
in ``tests/test_kernel.py``) on the same compiled functions
(:func:`~ltv_lstm_mpc.lstm.compiled.rollout`, :func:`~ltv_lstm_mpc.lstm.compiled.jacobians`,
:func:`~ltv_lstm_mpc.mpc.compiled_condensing.condense`).
"""

from __future__ import annotations

from typing import Any

import numpy as np

from ltv_lstm_mpc.lstm.compiled import jacobians, rollout
from ltv_lstm_mpc.mpc.compiled_condensing import condense
from ltv_lstm_mpc.numba_support import build_workspace, njit, workspace_type

__all__ = [
    "CANDIDATE_GIVEN",
    "CANDIDATE_SHIFT",
    "CANDIDATE_U_BAR",
    "CONSTRUCTORS",
    "PREPARE_FIELDS",
    "PrepareWorkspace",
    "new_prepare_workspace",
    "prepare_condensed",
]

#: Fields of :data:`PrepareWorkspace`, in the order of its compiled constructor.
PREPARE_FIELDS = ("WU", "WU_raw", "S", "T", "TC", "J", "PS", "PT", "PTC")

PrepareWorkspace = workspace_type(
    "PrepareWorkspace",
    PREPARE_FIELDS,
    """The trajectories of :func:`prepare_condensed`, shared with ``RobustMPC``.

    ``WU``, ``WU_raw``: the kernel's stacked gate weights (scaled and raw); ``S``, ``T``,
    ``TC``, ``J``: the linearization trajectory; ``PS``, ``PT``, ``PTC``: the previous
    plan's re-simulation.
    """,
    __name__,
)
PrepareWorkspaceType = getattr(PrepareWorkspace, "numba_type", None)


def new_prepare_workspace(**fields: Any) -> Any:
    """A :data:`PrepareWorkspace` from its fields by name (:data:`PREPARE_FIELDS`)."""
    return build_workspace(_new_prepare_workspace, PREPARE_FIELDS, fields)


@njit(cache=True)
def _new_prepare_workspace(WU, WU_raw, S, T, TC, J, PS, PT, PTC):  # type: ignore[no-untyped-def]
    """The compiled constructor (no constructor compile at run time; cached)."""
    return PrepareWorkspace(WU, WU_raw, S, T, TC, J, PS, PT, PTC)


#: How :func:`prepare_condensed` forms the candidate: ``cand`` as given (``warm``),
#: :math:`\bar u` repeated, or the previous plan shifted with :math:`\bar u` appended.
CANDIDATE_GIVEN, CANDIDATE_U_BAR, CANDIDATE_SHIFT = 0, 1, 2


@njit(cache=True)
def prepare_condensed(
    trajectories: Any,
    condensing: Any,
    cand: Any,
    previous_u: Any,
    candidate: int,
    x0: Any,
    reuse_tol: float,
    x_bar: Any,
    u_bar: Any,
    lower: Any,
    upper: Any,
    alpha: float,
    backward: bool,
) -> tuple[float, bool]:
    """Candidate, rollout (or the shifted re-simulation), Jacobians, condensing.

    ``trajectories`` is a :data:`PrepareWorkspace` (the linearization trajectory and the
    previous plan's re-simulation), ``condensing`` the transcription's
    :data:`~ltv_lstm_mpc.mpc.compiled_condensing.CondensingWorkspace`; ``candidate``:
    :data:`CANDIDATE_GIVEN` / :data:`CANDIDATE_U_BAR` / :data:`CANDIDATE_SHIFT`
    (``previous_u`` (N, m) used by the last); the shift of the re-simulation replaces the
    rollout when ``x0`` is within ``reuse_tol`` (inf-norm) of the plan's :math:`x_1`
    (``reuse_tol < 0``: never); ``backward``: H and g0 by the backward recursion. Returns
    ``(violation scale of the condensed rows, whether the re-simulation was reused)``.
    """
    WU, WU_raw = trajectories.WU, trajectories.WU_raw
    S, T, TC, J = trajectories.S, trajectories.T, trajectories.TC, trajectories.J
    PS, PT, PTC = trajectories.PS, trajectories.PT, trajectories.PTC
    N, m = cand.shape
    n2 = J.shape[1]
    if candidate == CANDIDATE_U_BAR:
        for i in range(N):
            for a in range(m):
                cand[i, a] = u_bar[a]
    elif candidate == CANDIDATE_SHIFT:
        for i in range(N - 1):
            for a in range(m):
                cand[i, a] = previous_u[i + 1, a]
        for a in range(m):
            cand[N - 1, a] = u_bar[a]
    reuse = reuse_tol >= 0.0
    if reuse:
        for q in range(n2):
            if not abs(x0[q] - PS[1, q]) <= reuse_tol:
                reuse = False
                break
    if reuse:  # the shifted candidate from x_{1|k-1} is the re-simulated plan shifted by one
        for i in range(N):  # explicit loops: slice assignments cost seconds of compile time
            for q in range(S.shape[1]):
                S[i, q] = PS[i + 1, q]
        for i in range(N - 1):
            for q in range(T.shape[1]):
                T[i, q] = PT[i + 1, q]
            for q in range(TC.shape[1]):
                TC[i, q] = PTC[i + 1, q]
        for a in range(m):
            S[N - 1, n2 + a] = cand[N - 1, a]
        rollout(WU, S, T, TC, N - 1, N, np.empty(0))
    else:
        for q in range(n2):
            S[0, q] = x0[q]
        for i in range(N):
            for a in range(m):
                S[i, n2 + a] = cand[i, a]
        rollout(WU, S, T, TC, 0, N, np.empty(0))
    jacobians(WU_raw, S, T, TC, J)
    scale = condense(condensing, x_bar, u_bar, lower, upper, alpha, backward)
    return scale, reuse


#: This module's compiled constructor: what compiles with it
#: (:func:`~ltv_lstm_mpc.mpc.kernels.compiled_kernels`).
CONSTRUCTORS = (_new_prepare_workspace,)
