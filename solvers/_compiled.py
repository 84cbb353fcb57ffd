"""Compiled (numba) helpers of the dense layer's hot calls; the numpy code is the reference.

:meth:`~ltv_lstm_mpc.solvers.DenseQP.max_violation` checks every solver point of the
controller loop; on the small QPs of MPC its dozen numpy reductions cost more than the
arithmetic. These loops give the same values (sums in another order: a few ulps) and are
tested against the numpy expressions in ``tests/solvers/test_dense_compiled.py``.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from ltv_lstm_mpc.numba_support import (
    njit,  # without numba the loops run as Python
    ready,
)


class CompiledOrPython:
    """A compiled helper called through its compiled code where that is ready
    (:func:`~ltv_lstm_mpc.numba_support.ready`, decided at the first call in a process),
    else through ``fallback`` (default: its Python loops, ``py_func``; or a numpy twin
    with the same values): a caller on the numpy kernels never waits for a compilation."""

    def __init__(self, dispatcher: Any, fallback: Any = None) -> None:
        self.dispatcher = dispatcher
        self.fallback = (
            fallback if fallback is not None else getattr(dispatcher, "py_func", dispatcher)
        )
        self._call: Any = None

    def __call__(self, *args: Any) -> Any:
        if self._call is None:
            self._call = self.dispatcher if ready([self.dispatcher]) else self.fallback
        return self._call(*args)


__all__ = [
    "CompiledOrPython",
    "bounds_rows_violation",
    "clarabel_cone_rows",
    "clarabel_fill",
    "cone_violation",
    "dense_kkt_residuals",
]


@njit(cache=True)
def bounds_rows_violation(x: Any, lb: Any, ub: Any, A: Any, lo: Any, up: Any) -> float:
    """Largest violation (>= 0) of ``lb <= x <= ub`` and ``lo <= A x <= up``."""
    violation = 0.0
    for j in range(x.shape[0]):
        violation = max(violation, lb[j] - x[j], x[j] - ub[j])
    for i in range(A.shape[0]):
        acc = 0.0
        for j in range(x.shape[0]):
            acc += A[i, j] * x[j]
        violation = max(violation, lo[i] - acc, acc - up[i])
    return violation


@njit(cache=True)
def cone_violation(F: Any, g: Any, e: Any, f: float, x: Any) -> float:
    r""":math:`\|F x + g\| - e^\top x - f` (positive where the cone is violated)."""
    square = 0.0
    for i in range(F.shape[0]):
        acc = g[i]
        for j in range(x.shape[0]):
            acc += F[i, j] * x[j]
        square += acc * acc
    level = f
    for j in range(x.shape[0]):
        level += e[j] * x[j]
    return math.sqrt(square) - level


@njit(cache=True)
def clarabel_fill(
    H: Any,
    A: Any,
    lo: Any,
    up: Any,
    lb: Any,
    ub: Any,
    blocks: Any,
    M: Any,
    b: Any,
    take: Any,
    A_data: Any,
    P_rows: Any,
    P_cols: Any,
    P_data: Any,
) -> None:
    """The values of a dense QP in CLARABEL's data (``ClarabelDense._fill``, same layout).

    ``blocks``: (kind, source index, target row) per bound / row entry of the CLARABEL
    matrix, kind 0: ``A`` row ``i`` with right-hand side ``up[i]``; 1: ``-A`` row, ``-lo``;
    2: unit row of variable ``j`` (``+1``) with ``ub[j]``; 3: unit row (``-1``) with
    ``-lb[j]``; 4: equality row of ``A`` with ``up[i]``; 5: fixed variable ``j``, ``ub[j]``.
    Unit rows keep their constant matrix entries (written at setup); the cones' rows are
    written before, by :func:`clarabel_cone_rows`.
    """
    n = A.shape[1]
    for k in range(blocks.shape[0]):
        kind, i, row = blocks[k, 0], blocks[k, 1], blocks[k, 2]
        if kind == 0 or kind == 4:
            for j in range(n):
                M[row, j] = A[i, j]
            b[row] = up[i]
        elif kind == 1:
            for j in range(n):
                M[row, j] = -A[i, j]
            b[row] = -lo[i]
        elif kind == 2 or kind == 5:
            b[row] = ub[i]
        else:
            b[row] = -lb[i]
    rows = M.shape[0]
    for k in range(take.shape[0]):  # M in Fortran order: entry k is M[k % rows, k // rows]
        index = take[k]
        A_data[k] = M[index % rows, index // rows]
    for k in range(P_rows.shape[0]):
        P_data[k] = H[P_rows[k], P_cols[k]]


@njit(cache=True)
def clarabel_cone_rows(F: Any, g: Any, e: Any, f: float, start: int, M: Any, b: Any) -> None:
    """The rows ``[-e'; -F]`` of one second-order cone from row ``start``, with ``[f; g]``."""
    n = F.shape[1]
    for j in range(n):
        M[start, j] = -e[j]
    b[start] = f
    for r in range(F.shape[0]):
        for j in range(n):
            M[start + 1 + r, j] = -F[r, j]
        b[start + 1 + r] = g[r]


@njit(cache=True)
def _row_terms(
    r: float, lower: float, upper: float, y: float, out: Any
) -> float:  # pragma: no cover - compiled
    """One row's primal violation, and its admissible multiplier (0 for the wrong sign at an
    infinite bound); adds its gap and gap-scale terms to ``out[2]``, ``out[3]``."""
    violation = 0.0
    finite_up = upper < math.inf
    finite_lo = lower > -math.inf
    if finite_up:
        violation = max(violation, (r - upper) / (1.0 + abs(upper)))
    if finite_lo:
        violation = max(violation, (lower - r) / (1.0 + abs(lower)))
    if y > 0.0 and finite_up:
        out[2] += y * max(upper - r, 0.0)
        out[3] += abs(y * upper)
        return violation
    if y < 0.0 and finite_lo:
        out[2] += -y * max(r - lower, 0.0)
        out[3] += abs(y * lower)
    return violation


@njit(cache=True)
def dense_kkt_residuals(
    H: Any, f: Any, A: Any, lo: Any, up: Any, lb: Any, ub: Any, z: Any, y_rows: Any,
    y_bounds: Any, out: Any,
) -> None:  # fmt: skip
    """The acceptance check's residuals of a cone-free DenseQP (``acceptance.residuals`` is
    the reference): ``out[0]`` primal, ``out[1]`` stationarity, ``out[2]`` complementarity;
    ``out[3]`` is 0, or 1 when a multiplier is not finite (the other entries are then
    meaningless)."""
    n = z.shape[0]
    m = A.shape[0]
    for i in range(m):
        if not math.isfinite(y_rows[i]):
            out[3] = 1.0
            return
    for j in range(n):
        if not math.isfinite(y_bounds[j]):
            out[3] = 1.0
            return
    gradient = np.empty(n)
    scale = np.empty(n)
    zHz = 0.0
    fz = 0.0
    for i in range(n):
        acc = 0.0
        for j in range(n):
            acc += H[i, j] * z[j]
        gradient[i] = acc + f[i]
        scale[i] = max(abs(acc), abs(f[i]))
        zHz += z[i] * acc
        fz += f[i] * z[i]
    out[2] = 0.0
    out[3] = 0.0
    primal = 0.0
    At_y = np.zeros(n)
    for i in range(m):
        r = 0.0
        for j in range(n):
            r += A[i, j] * z[j]
        primal = max(primal, _row_terms(r, lo[i], up[i], y_rows[i], out))
        y = y_rows[i]
        if (y > 0.0 and up[i] < math.inf) or (y < 0.0 and lo[i] > -math.inf):
            for j in range(n):
                At_y[j] += A[i, j] * y
    for j in range(n):
        primal = max(primal, _row_terms(z[j], lb[j], ub[j], y_bounds[j], out))
        y = y_bounds[j]
        yb = y if (y > 0.0 and ub[j] < math.inf) or (y < 0.0 and lb[j] > -math.inf) else 0.0
        gradient[j] += At_y[j] + yb
        scale[j] = max(scale[j], abs(At_y[j]), abs(yb))
    stationarity = 0.0
    for j in range(n):
        stationarity = max(stationarity, abs(gradient[j]) / (1.0 + scale[j]))
    gap_scale = max(abs(zHz), abs(fz), out[3])
    out[0] = primal
    out[1] = stationarity
    out[2] = out[2] / (1.0 + gap_scale)
    out[3] = 0.0
