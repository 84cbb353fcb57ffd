r"""The preparation phase of the condensed QP as one compiled call (``RobustMPC.prepare``).

:meth:`~ltv_lstm_mpc.mpc.rti.RobustMPC.prepare` builds the proof candidate (previous plan
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
from ltv_lstm_mpc.numba_support import njit

__all__ = ["CANDIDATE_GIVEN", "CANDIDATE_SHIFT", "CANDIDATE_U_BAR", "prepare_condensed"]

#: How :func:`prepare_condensed` forms the candidate: ``cand`` as given (``warm``),
#: :math:`\bar u` repeated, or the previous plan shifted with :math:`\bar u` appended.
CANDIDATE_GIVEN, CANDIDATE_U_BAR, CANDIDATE_SHIFT = 0, 1, 2


@njit(cache=True)
def prepare_condensed(
    WU: Any,
    WU_raw: Any,
    S: Any,
    T: Any,
    TC: Any,
    J: Any,
    PS: Any,
    PT: Any,
    PTC: Any,
    cand: Any,
    previous_u: Any,
    candidate: int,
    x0: Any,
    reuse_allowed: bool,
    reuse_tol: float,
    x_bar: Any,
    u_bar: Any,
    lower: Any,
    upper: Any,
    alpha: float,
    M: Any,
    Maug: Any,
    Lt: Any,
    Qs: Any,
    R: Any,
    W_y: Any,
    b_y: Any,
    unit_half: Any,
    u_max: float,
    H: Any,
    g0: Any,
    A: Any,
    lo0: Any,
    up0: Any,
    lb: Any,
    ub: Any,
    diagonal: bool,
    backward: bool,
) -> tuple[float, bool]:
    """Candidate, rollout (or the shifted re-simulation), Jacobians, condensing.

    ``S, T, TC, J``: the linearization trajectory; ``PS, PT, PTC``: the previous plan's
    re-simulation; ``candidate``: :data:`CANDIDATE_GIVEN` / :data:`CANDIDATE_U_BAR` /
    :data:`CANDIDATE_SHIFT` (``previous_u`` (N, m) used by the last); ``reuse_allowed``:
    the shift of the re-simulation may replace the rollout when ``x0`` is within
    ``reuse_tol`` (inf-norm) of the plan's :math:`x_1`. Returns ``(violation scale of the
    condensed rows, whether the re-simulation was reused)``.
    """
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
    reuse = reuse_allowed
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
    scale = condense(
        J, S, M, Maug, Lt, Qs, x_bar, u_bar, R, W_y, b_y, lower, upper, unit_half, alpha,
        u_max, H, g0, A, lo0, up0, lb, ub, diagonal, backward,
    )  # fmt: skip
    return scale, reuse
