r""":math:`\bar K` of Lemma 5 (the gain of the reference calculator), estimated by gridding.

:math:`\bar K` bounds how far the equilibrium :math:`(\bar x, \bar u)` of eq.
(reference_calculation) moves per unit change of set-point or disturbance estimate; Theorem
3's set-point rate bound (paper notes 2.10c) uses it. It is a certificate number computed
from the model alone, so it lives with the other certificates (the loop's reference
calculator re-exports it).
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from ltv_lstm_mpc.exceptions import InvalidValueError
from ltv_lstm_mpc.lstm.model import LSTMModel, require_model
from ltv_lstm_mpc.validation import expect_int, expect_real, finite_array

__all__ = ["KBarEstimate", "estimate_K_bar"]

FloatArray = NDArray[np.float64]


@dataclass(frozen=True)
class KBarEstimate:
    r""":math:`\bar K` of Lemma 5 estimated by gridding.

    Attributes
    ----------
    K_bar : float
        :math:`\max \|K_{\bar x}\|` over the grid points kept.
    u_grid : ndarray, shape (G, m)
        Grid of input set-points :math:`\bar u`.
    y_grid : ndarray, shape (G, p)
        Equilibrium outputs :math:`g(\bar x)` at the grid points.
    K_x_norms : ndarray, shape (G,)
        :math:`\|K_{\bar x}\|` at each grid point (NaN where excluded).
    argmax_u : ndarray, shape (m,)
        Grid input where the maximum is attained.
    """

    K_bar: float
    u_grid: FloatArray
    y_grid: FloatArray
    K_x_norms: FloatArray
    argmax_u: FloatArray


def estimate_K_bar(
    model: LSTMModel,
    *,
    u_max: float = 1.0,
    y0_range: tuple[ArrayLike, ArrayLike] | None = None,
    d_max: float = 0.1,
    grid_points: int = 201,
) -> KBarEstimate:
    r"""Estimate :math:`\bar K` of Lemma 5 by gridding the equilibrium manifold.

    At each equilibrium :math:`(\bar x, \bar u)` the implicit function theorem gives
    :math:`K = -J_\zeta^{-1} [0_{2n,p}; I_p]` (proof of Lemma 5); :math:`K_{\bar x}` is
    its first 2n rows and :math:`\bar K = \max \|K_{\bar x}\|`. The manifold is swept by
    gridding :math:`\bar u \in \mathcal{U}`; with ``y0_range`` only points whose output
    :math:`g(\bar x) = y^0 - \hat d` can occur for :math:`y^0` in the range and
    :math:`\|\hat d\|_\infty \le d_{max}` are kept.
    """
    model = require_model(model)
    expect_real("u_max", u_max, low=0.0, low_open=True)
    expect_real("d_max", d_max, low=0.0)
    expect_int("grid_points", grid_points, minimum=2)
    if y0_range is not None:
        if isinstance(y0_range, (str, bytes)) or len(y0_range) != 2:
            raise InvalidValueError(f"y0_range must be a pair (low, high), got {y0_range!r}")
        finite_array("y0_range[0]", y0_range[0])
        finite_array("y0_range[1]", y0_range[1])
    model.require_square()
    n2, m, p = 2 * model.n, model.m, model.p
    per_channel = max(2, round(grid_points ** (1.0 / m))) if m > 1 else grid_points
    axes = [np.linspace(-u_max, u_max, per_channel)] * m
    u_grid = np.array(list(itertools.product(*axes)), dtype=np.float64)
    y_grid = np.empty((u_grid.shape[0], p))
    norms = np.full(u_grid.shape[0], np.nan)
    J = np.zeros((n2 + p, n2 + m))
    J[n2:, model.n : n2] = model.W_y
    rhs = np.vstack([np.zeros((n2, p)), np.eye(p)])
    if y0_range is not None:
        low = np.atleast_1d(np.asarray(y0_range[0], dtype=np.float64)) - d_max
        high = np.atleast_1d(np.asarray(y0_range[1], dtype=np.float64)) + d_max
    x_start = None
    for k, u in enumerate(u_grid):
        x_bar = model.equilibrium(u, x0=x_start)
        x_start = x_bar
        y_grid[k] = model.output(x_bar)
        if y0_range is not None and (np.any(y_grid[k] < low) or np.any(y_grid[k] > high)):
            continue
        _, A, B = model.step_and_jacobians(x_bar, u)
        J[:n2, :n2] = A - np.eye(n2)
        J[:n2, n2:] = B
        K = -np.linalg.solve(J, rhs)
        norms[k] = np.linalg.norm(K[:n2], 2)
    if np.all(np.isnan(norms)):
        raise InvalidValueError(
            f"no equilibrium output over U lies in y0_range +- d_max; outputs span "
            f"[{y_grid.min(axis=0).tolist()}, {y_grid.max(axis=0).tolist()}]"
        )
    best = int(np.nanargmax(norms))
    return KBarEstimate(
        K_bar=float(norms[best]),
        u_grid=u_grid,
        y_grid=y_grid,
        K_x_norms=norms,
        argmax_u=u_grid[best].copy(),
    )
