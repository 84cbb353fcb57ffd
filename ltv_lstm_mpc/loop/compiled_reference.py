r"""Compiled (numba) Newton methods of the reference calculator, eq. (reference_calculation).

The warm path of :class:`~ltv_lstm_mpc.ReferenceCalculator` in one call
(:func:`chord_newton`); its numpy reference is ``ReferenceCalculator._chord`` (same
algorithm, tested to 1e-12 in ``tests/test_kernel.py``). Used when the model's kernel is
compiled. And the calculator's fallback where the warm path does not reach an admissible
equilibrium, the damped Newton with restarts (:func:`newton_restarts`), whose readable
reference is ``ReferenceCalculator._newton`` with the restart loop of
``ReferenceCalculator.solve_arrays``: the one-call step engine runs it (tested against the
reference engine to 1e-12 over closed loops in ``tests/test_one_call_step.py``).
"""

from __future__ import annotations

from typing import Any

import numpy as np

from ltv_lstm_mpc.lstm.compiled import jacobians, lstm_cell
from ltv_lstm_mpc.numba_support import build_workspace, njit, workspace_type

__all__ = [
    "CHORD_CONVERGED",
    "CHORD_FACTORIZATIONS",
    "CHORD_FIELDS",
    "CHORD_ITERATIONS",
    "CHORD_JINV_VALID",
    "CHORD_REFRESH_CONTRACTION",
    "CONSTRUCTORS",
    "RESTART_FIELDS",
    "ChordWorkspace",
    "RestartWorkspace",
    "chord_newton",
    "new_chord_workspace",
    "new_restart_workspace",
    "newton_restarts",
]

#: The chord Newton refreshes its kept inverse Jacobian (eq. jacobian: the LSTM's Jacobians
#: and an inverse) after an iteration that reduced the residual by less than this factor.
#: A refresh costs as much as 15 chord iterations (n = 5, interleaved with acados: 2.7-3.1
#: us against about 0.2 us), so a slower contraction is cheaper to iterate through than to
#: refresh: with 0.1 the pH loop of bench's scenario 1 refreshed in 2 of 290 steps (4.2
#: iterations per step) against 37 with 1e-2 (2.3 iterations), at the same mean step
#: time, and the refresh no longer sets the p95 of the step (``experiments/acados_speed.py``,
#: ``docs/benchmarks.md``). Shared by the numpy reference
#: (``ReferenceCalculator._chord_numpy``).
CHORD_REFRESH_CONTRACTION = 0.1

#: Entries of ``ChordWorkspace.state`` (int64): the kept inverse Jacobian is valid (1/0),
#: iterations, factorizations, converged (1/0) of the last :func:`chord_newton`.
CHORD_JINV_VALID, CHORD_ITERATIONS, CHORD_FACTORIZATIONS, CHORD_CONVERGED = 0, 1, 2, 3

#: Fields of :data:`ChordWorkspace`, in the order of its compiled constructor.
CHORD_FIELDS = ("WU", "WU_raw", "W_y", "b_y", "S", "T", "TC", "J", "Jinv", "state", "F", "jacobian")

ChordWorkspace = workspace_type(
    "ChordWorkspace",
    CHORD_FIELDS,
    """Buffers of :func:`chord_newton`, shared with the reference calculator.

    ``WU``, ``WU_raw``: the kernel's stacked gate weights (scaled and raw); ``W_y``, ``b_y``:
    the output map; ``S``, ``T``, ``TC``, ``J``: a one-step Trajectory; ``Jinv``: the kept
    inverse Jacobian; ``state`` (int64, 4): [Jinv valid, iterations, factorizations, ok];
    ``F``, ``jacobian``: residual and Jacobian scratch.
    """,
    __name__,
)
ChordWorkspaceType = getattr(ChordWorkspace, "numba_type", None)


def new_chord_workspace(**fields: Any) -> Any:
    """A :data:`ChordWorkspace` from its fields by name (:data:`CHORD_FIELDS`)."""
    return build_workspace(_new_chord_workspace, CHORD_FIELDS, fields)


@njit(cache=True)
def _new_chord_workspace(
    WU: Any,
    WU_raw: Any,
    W_y: Any,
    b_y: Any,
    S: Any,
    T: Any,
    TC: Any,
    J: Any,
    Jinv: Any,
    state: Any,
    F: Any,
    jacobian: Any,
) -> Any:
    """The compiled constructor (no constructor compile at run time; cached)."""
    return ChordWorkspace(WU, WU_raw, W_y, b_y, S, T, TC, J, Jinv, state, F, jacobian)


@njit(cache=True)
def _equilibrium_residual(
    WU: Any, W_y: Any, b_y: Any, S: Any, T: Any, TC: Any, z: Any, target: Any, F: Any
) -> float:
    """:math:`F(z) = [f(x, u) - x; W_y h + b_y - target]` into ``F``; returns its inf-norm."""
    n = WU.shape[0] // 4
    n2 = 2 * n
    p = W_y.shape[0]
    for q in range(z.shape[0]):
        S[0, q] = z[q]
    lstm_cell(WU, S[0, n:], T[0], S[0, :n], S[1, :n], S[1, n:n2], TC[0], np.zeros(0))
    norm = 0.0
    for q in range(n2):
        F[q] = S[1, q] - z[q]
        if abs(F[q]) > norm:
            norm = abs(F[q])
    for j in range(p):
        acc = b_y[j] - target[j]
        for q in range(n):
            acc += W_y[j, q] * z[n + q]
        F[n2 + j] = acc
        if abs(acc) > norm:
            norm = abs(acc)
    return norm


@njit(cache=True)
def _pivot(matrix: Any, k: int) -> tuple[int, float]:
    """Partial pivoting's choice for column ``k`` of ``matrix``: the first row from ``k`` on
    whose entry has the largest magnitude (LAPACK's choice), and that magnitude (0.0: the
    column is zero from row ``k`` on, the matrix singular)."""
    pivot_row = k
    largest = abs(matrix[k, k])
    for r in range(k + 1, matrix.shape[0]):
        if abs(matrix[r, k]) > largest:
            largest = abs(matrix[r, k])
            pivot_row = r
    return pivot_row, largest


@njit(cache=True)
def _invert(matrix: Any, inverse: Any) -> bool:
    """``inverse`` = the inverse of ``matrix`` by Gauss-Jordan elimination with partial
    pivoting, in place (``matrix`` is overwritten): no allocation and no library call in
    the step. Returns False for an exactly singular matrix (a zero pivot column).

    The compact form of the elimination: step k scales the pivot row and subtracts its
    multiples from the other rows, and the column it clears takes the inverse's column
    that step k opens (the identity's column of the pivot row; the identity's columns
    still closed hold one 1 and are not stored). Each stored entry is the product and
    difference of the textbook form with a separate identity (the same pivots; only the
    operations on its exact zeros are left out), so the inverse is the same to the last
    bit (``tests/test_kernel.py``; a zero may differ in sign, which the chord's sums,
    started at +0.0, cannot see) at half the arithmetic; the row interchanges are
    undone on the columns at the end, their rows kept in ``inverse``'s first row until
    then."""
    size = matrix.shape[0]
    pivots = inverse[0]  # (scratch until the inverse is written)
    for k in range(size):
        pivot_row, largest = _pivot(matrix, k)
        pivots[k] = pivot_row
        if largest == 0.0:
            return False
        row_k = matrix[k]
        if pivot_row != k:
            row_pivot = matrix[pivot_row]
            for c in range(size):
                row_k[c], row_pivot[c] = row_pivot[c], row_k[c]
        scale = 1.0 / row_k[k]
        for c in range(size):
            row_k[c] *= scale
        row_k[k] = scale  # the opened column: the identity's 1, scaled
        for r in range(size):
            if r == k:
                continue
            row = matrix[r]
            factor = row[k]
            if factor != 0.0:
                for c in range(size):
                    row[c] -= factor * row_k[c]
                row[k] = 0.0 - factor * scale  # (the identity's 0 there, less factor*scale)
            else:
                row[k] = 0.0
    for k in range(size - 1, -1, -1):  # the interchanges undone on the columns
        swap = int(pivots[k])
        if swap != k:
            for r in range(size):
                matrix[r, k], matrix[r, swap] = matrix[r, swap], matrix[r, k]
    for r in range(size):
        target, source = inverse[r], matrix[r]
        for c in range(size):
            target[c] = source[c]
    return True


@njit(cache=True)
def chord_newton(
    workspace: Any,
    z_start: Any,
    target: Any,
    step_target: Any,
    tol: float,
    max_iter: int,
    z_out: Any,
) -> float:
    r"""The chord-Newton warm path of ``ReferenceCalculator`` (eq. reference_calculation).

    ``workspace`` is a :data:`ChordWorkspace`; its ``state`` is read and written;
    ``step_target`` is the change of the target since the last solution (predictor of
    Lemma 5 with the kept inverse Jacobian). The solution goes into ``z_out``; returns the
    residual. Same algorithm as the numpy ``ReferenceCalculator._chord``.
    """
    WU, WU_raw, W_y, b_y = workspace.WU, workspace.WU_raw, workspace.W_y, workspace.b_y
    S, T, TC, J = workspace.S, workspace.T, workspace.TC, workspace.J
    Jinv, state, F, jac = workspace.Jinv, workspace.state, workspace.F, workspace.jacobian
    n = WU.shape[0] // 4
    n2 = 2 * n
    size = z_start.shape[0]
    z = z_start.copy()
    if state[0] == 1:
        for a in range(size):
            acc = 0.0
            for j in range(size - n2):
                acc += Jinv[a, n2 + j] * step_target[j]
            z[a] += acc
    norm = _equilibrium_residual(WU, W_y, b_y, S, T, TC, z, target, F)
    iterations = 0
    factorizations = 0
    fresh = False
    z_new = np.empty(size)
    while norm >= tol and iterations < max_iter:
        if state[0] == 0:
            jacobians(WU_raw, S[:2], T[:1], TC[:1], J[:1])
            for r in range(size):
                for c in range(size):
                    jac[r, c] = 0.0
            for r in range(n2):
                for c in range(size):
                    jac[r, c] = J[0, r, c]
                jac[r, r] -= 1.0
            for j in range(size - n2):
                for q in range(n):
                    jac[n2 + j, n + q] = W_y[j, q]
            if not _invert(jac, Jinv):  # singular: no chord (the caller's Newton runs)
                break
            state[0] = 1
            factorizations += 1
            fresh = True
        for a in range(size):
            acc = 0.0
            for c in range(size):
                acc += Jinv[a, c] * F[c]
            z_new[a] = z[a] - acc
        iterations += 1
        norm_new = _equilibrium_residual(WU, W_y, b_y, S, T, TC, z_new, target, F)
        if not norm_new < norm:
            if fresh:
                break
            state[0] = 0
            norm = _equilibrium_residual(WU, W_y, b_y, S, T, TC, z, target, F)  # restore
            continue
        if norm_new > CHORD_REFRESH_CONTRACTION * norm:
            state[0] = 0  # slow contraction: refactorize at z_new
        for a in range(size):
            z[a] = z_new[a]
        norm = norm_new
        fresh = False
    for a in range(size):
        z_out[a] = z[a]
    state[1] = iterations
    state[2] = factorizations
    state[3] = 1 if norm < tol else 0
    return norm


#: Backtracking halvings per damped Newton iteration (``ReferenceCalculator._newton``).
BACKTRACKING_STEPS = 30
#: Admissibility of :math:`\bar u`: inside U up to this relative margin (as
#: ``ReferenceCalculator.solve_arrays``).
U_MARGIN = 1e-12

#: Fields of :data:`RestartWorkspace`, in the order of its compiled constructor.
RESTART_FIELDS = (
    "grid_x", "grid_u", "grid_y", "restarts", "u_max", "jacobian", "z", "trial", "best",
    "distance", "step", "pivots",
)  # fmt: skip

RestartWorkspace = workspace_type(
    "RestartWorkspace",
    RESTART_FIELDS,
    """The damped Newton with restarts of :func:`newton_restarts`.

    ``grid_x``, ``grid_u``, ``grid_y`` (G rows): the calculator's equilibrium grid (states,
    inputs, outputs); ``restarts``: the grid starts of a MIMO model (1 for SISO);
    ``u_max``: the bound of U; ``jacobian`` (2n + m, 2n + m), ``z``, ``trial``, ``best``,
    ``step`` (2n + m), ``pivots`` (int64, 2n + m), ``distance`` (G): scratch.
    """,
    __name__,
)
RestartWorkspaceType = getattr(RestartWorkspace, "numba_type", None)


def new_restart_workspace(**fields: Any) -> Any:
    """A :data:`RestartWorkspace` from its fields by name (:data:`RESTART_FIELDS`)."""
    return build_workspace(_new_restart_workspace, RESTART_FIELDS, fields)


@njit(cache=True)
def _new_restart_workspace(
    grid_x: Any,
    grid_u: Any,
    grid_y: Any,
    restarts: Any,
    u_max: Any,
    jacobian: Any,
    z: Any,
    trial: Any,
    best: Any,
    distance: Any,
    step: Any,
    pivots: Any,
) -> Any:
    """The compiled constructor (no constructor compile at run time; cached)."""
    return RestartWorkspace(
        grid_x, grid_u, grid_y, restarts, u_max, jacobian, z, trial, best, distance, step, pivots
    )


@njit(cache=True)
def _lu_solve(matrix: Any, rhs: Any, out: Any, pivots: Any) -> bool:
    """``out`` = the solution of ``matrix @ out = rhs`` by LU with partial pivoting (the
    algorithm of LAPACK's ``dgesv``, behind ``numpy.linalg.solve``: the first entry of
    largest magnitude as pivot), in place: ``matrix`` is overwritten by its factors and
    ``pivots`` (int64) by the row interchanges; no allocation and no library call in the
    step (``numpy.linalg.solve`` in compiled code copies its operands and loads LAPACK
    at first use). Returns False for an exactly singular matrix (a zero pivot: where
    ``numpy.linalg.solve`` raises ``LinAlgError``); ``out`` is then undefined."""
    size = matrix.shape[0]
    for k in range(size):
        pivot_row, largest = _pivot(matrix, k)
        pivots[k] = pivot_row
        if largest == 0.0:
            return False
        if pivot_row != k:
            for c in range(size):
                matrix[k, c], matrix[pivot_row, c] = matrix[pivot_row, c], matrix[k, c]
        scale = 1.0 / matrix[k, k]
        for r in range(k + 1, size):
            factor = matrix[r, k] * scale
            matrix[r, k] = factor
            if factor != 0.0:
                for c in range(k + 1, size):
                    matrix[r, c] -= factor * matrix[k, c]
    for r in range(size):
        out[r] = rhs[r]
    for k in range(size):  # the interchanges, then L y = P rhs (unit diagonal)
        swap = pivots[k]
        if swap != k:
            out[k], out[swap] = out[swap], out[k]
    for r in range(size):
        acc = out[r]
        for c in range(r):
            acc -= matrix[r, c] * out[c]
        out[r] = acc
    for r in range(size - 1, -1, -1):  # U out = y
        acc = out[r]
        for c in range(r + 1, size):
            acc -= matrix[r, c] * out[c]
        out[r] = acc / matrix[r, r]
    return True


@njit(cache=True)
def _newton_from(
    chord: Any, restart: Any, z_start: Any, target: Any, tol: float, max_iter: int
) -> tuple[float, int, bool]:
    """``ReferenceCalculator._newton`` from ``z_start``: the damped Newton on eq.
    (reference_calculation), each step backtracked on the residual's inf-norm. The point
    goes into ``restart.z``; returns (residual, iterations, converged)."""
    WU, WU_raw, W_y, b_y = chord.WU, chord.WU_raw, chord.W_y, chord.b_y
    S, T, TC, J, F = chord.S, chord.T, chord.TC, chord.J, chord.F
    jac, z, trial = restart.jacobian, restart.z, restart.trial
    step, pivots = restart.step, restart.pivots
    n = WU.shape[0] // 4
    n2 = 2 * n
    size = z.shape[0]
    for a in range(size):
        z[a] = z_start[a]
    norm = _equilibrium_residual(WU, W_y, b_y, S, T, TC, z, target, F)
    jacobians(WU_raw, S[:2], T[:1], TC[:1], J[:1])  # A, B at z
    for iteration in range(1, max_iter + 1):
        if norm < tol:
            return norm, iteration - 1, True
        for r in range(size):
            for c in range(size):
                jac[r, c] = J[0, r, c] if r < n2 else 0.0
            if r < n2:
                jac[r, r] -= 1.0
        for j in range(size - n2):
            for q in range(n):
                jac[n2 + j, n + q] = W_y[j, q]
        if not _lu_solve(jac, F, step, pivots):  # singular (numpy's LinAlgError)
            return norm, iteration, False
        t = 1.0
        accepted = False
        norm_trial = norm
        for _ in range(BACKTRACKING_STEPS):
            for a in range(size):
                trial[a] = z[a] - t * step[a]
            norm_trial = _equilibrium_residual(WU, W_y, b_y, S, T, TC, trial, target, F)
            if norm_trial < norm or norm_trial < tol:
                accepted = True
                break
            t *= 0.5
        if not accepted:
            return norm, iteration, False
        for a in range(size):
            z[a] = trial[a]
        norm = norm_trial
        jacobians(WU_raw, S[:2], T[:1], TC[:1], J[:1])  # at the accepted point
    return norm, max_iter, norm < tol


@njit(cache=True)
def newton_restarts(
    chord: Any,
    restart: Any,
    previous: Any,
    folded: Any,
    target: Any,
    tol: float,
    max_iter: int,
    z_out: Any,
) -> tuple[float, int, bool, bool]:
    r"""The restart loop of ``ReferenceCalculator.solve_arrays`` after the warm path: the
    damped Newton (:func:`_newton_from`) from ``folded`` (a MIMO warm-path solution that
    jumped: another branch of a fold? empty: none), the last solution ``previous`` (empty:
    none, the calculator's cold solve after a reset), and the grid equilibria closest in
    output to ``target`` (one for SISO, ``restart.restarts`` for MIMO models); the best
    start by the calculator's rank (admissible, then closest to ``previous``, then
    converged, then the smallest residual), stopping at an admissible solution from
    ``previous`` where nothing folded (without ``previous``: at the first admissible
    solution). The best point goes into ``z_out``;
    returns (residual, Newton iterations of all starts, converged, :math:`\bar u \in
    \mathcal U`)."""
    grid_x, grid_u, grid_y = restart.grid_x, restart.grid_u, restart.grid_y
    z, best, distance = restart.z, restart.best, restart.distance
    n2 = grid_x.shape[1]
    m = grid_u.shape[1]
    size = n2 + m
    warm = 1 if previous.shape[0] else 0  # the last solution is a start
    limit = restart.u_max * (1.0 + U_MARGIN)
    for g in range(grid_y.shape[0]):
        largest = 0.0
        for j in range(grid_y.shape[1]):
            largest = max(largest, abs(grid_y[g, j] - target[j]))
        distance[g] = largest
    order = np.argsort(distance, kind="mergesort")  # stable, as the reference's
    n_grid = 1 if m == 1 else min(restart.restarts, grid_y.shape[0])
    first = 1 if folded.shape[0] else 0
    starts = first + warm + n_grid
    total = 0
    have_best = False
    best_admissible, best_closeness, best_converged, best_norm = False, -np.inf, False, -np.inf
    norm_out, converged_out = np.inf, False
    start = np.empty(size)
    for number in range(starts):
        if number < first:
            for a in range(size):
                start[a] = folded[a]
        elif warm and number == first:
            for a in range(size):
                start[a] = previous[a]
        else:
            g = order[number - first - warm]
            for q in range(n2):
                start[q] = grid_x[g, q]
            for a in range(m):
                start[n2 + a] = grid_u[g, a]
        norm, iterations, converged = _newton_from(chord, restart, start, target, tol, max_iter)
        total += iterations
        largest_u = 0.0
        for a in range(m):
            largest_u = max(largest_u, abs(z[n2 + a]))
        admissible = converged and largest_u <= limit
        closeness = -np.inf
        if admissible:
            closeness = 0.0
            if warm:
                for a in range(size):
                    closeness = max(closeness, abs(z[a] - previous[a]))
            closeness = -closeness
        better = not have_best
        if have_best:  # the rank tuple (admissible, closeness, converged, -norm), compared
            if admissible != best_admissible:
                better = admissible
            elif closeness != best_closeness:
                better = closeness > best_closeness
            elif converged != best_converged:
                better = converged
            else:
                better = -norm > best_norm
        if better:
            have_best = True
            best_admissible, best_closeness = admissible, closeness
            best_converged, best_norm = converged, -norm
            norm_out, converged_out = norm, converged
            for a in range(size):
                best[a] = z[a]
        if admissible and first == 0 and (number == 0 or not warm):
            break  # from the previous solution itself (or none): take it
    largest_u = 0.0
    for a in range(size):
        z_out[a] = best[a]
    for a in range(m):
        largest_u = max(largest_u, abs(best[n2 + a]))
    return norm_out, total, converged_out, largest_u <= limit


#: This module's compiled constructors (the compiled workspace constructors): what compiles
#: with it (:func:`~ltv_lstm_mpc.loop.kernels.controller_kernels`).
CONSTRUCTORS = (_new_chord_workspace, _new_restart_workspace)
