r"""Constraint tightening and time-varying terminal set of the robust MPC.

Implements eq. (constraint_tightening_parameters) for :math:`a_i, b_i`, eq. (eo_evolution)
and eq. (eo-limit) for the observer-error bound :math:`\hat e_{o,k}`, the terminal weight
:math:`P_f` (paper notes 2.6), eq. (terminal_constraint), eq. (def_alpha) and eq. (e_ok_bar) for
:math:`\alpha_k`, the admissible set-point interval of Assumption 5, and the set-point
rate bound of Theorem 3 (paper notes 2.10c).

All values are in normalized units (paper notes 1).
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Callable
from dataclasses import dataclass
from functools import cached_property
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from ltv_lstm_mpc.certificates.stability import (
    DeltaISSCertificate,
    IncrementalLyapunovCertificate,
    ObserverCertificate,
    matrix_inverse_sqrt,
    solve_lyapunov,
)
from ltv_lstm_mpc.exceptions import (
    DimensionError,
    EmptySetpointIntervalError,
    InvalidValueError,
    LtvMpcError,
)
from ltv_lstm_mpc.lstm.model import LSTMModel, require_model
from ltv_lstm_mpc.validation import expect_instance, expect_int, expect_real, finite_array

__all__ = ["SetpointRateBound", "TighteningCertificate", "tightening_certificate"]

FloatArray = NDArray[np.float64]


@dataclass(frozen=True)
class SetpointRateBound:
    r"""Set-point rate bound :math:`\Delta y^0_{max}` of Theorem 3 (paper notes 2.10c).

    Recursive feasibility of the terminal constraint holds if

    .. math::

        \sqrt{\lambda_{max}(P_f)} \Big(\frac{c_{s,u}}{c_{s,l}} \rho_s^N L_{max} \hat e
        + \rho_f \bar K \|L_d\| \bar e_y + \rho_f \bar K |\Delta y^0|\Big)
        + \rho_f \max_j \kappa_j^{-1} |\Delta y^0| \le (1 - \rho_f)\,\alpha

    Attributes
    ----------
    delta_y0_max : float
        Largest admissible :math:`|\Delta y^0|` per step (normalized); 0 when void.
        Only meaningful when ``holds`` is True.
    holds : bool
        False when the inequality cannot hold for any :math:`\Delta y^0 \ge 0`: the
        guarantee of Theorem 3 is then void for these numbers.
    margin : float
        :math:`(1-\rho_f)\alpha` minus the :math:`\Delta y^0`-independent terms.
    slope : float
        Coefficient of :math:`|\Delta y^0|` on the left-hand side.
    alpha, e_hat, K_bar, e_y_bar : float
        The inputs used.
    """

    delta_y0_max: float
    holds: bool
    margin: float
    slope: float
    alpha: float
    e_hat: float
    K_bar: float
    e_y_bar: float


@dataclass(frozen=True)
class TighteningCertificate:
    r"""Tightening coefficients and terminal-set data of the FHOCP, eq. (optimization).

    Attributes
    ----------
    N : int
        Prediction horizon.
    d_max : float
        :math:`d_{max}`; the tightened constraints use the worst case :math:`\pm d_{max}`
        and :math:`\alpha_k` uses :math:`2 d_{max}` (paper notes 2.8).
    w_bar : float
        :math:`\bar w`.
    rho_o : float
        :math:`\rho_o` of Theorem 2 (drives eq. eo_evolution).
    y_min, y_max : ndarray, shape (p,)
        Output constraint :math:`\mathcal{Y}` (normalized), eq. (output_constraint).
    a : ndarray, shape (N + 1, p)
        :math:`a_0, \dots, a_N`: :math:`a_0 = c_o`,
        :math:`a_{i+1} = \rho_o a_i + \rho_s^i c_{s,u} L_{max} c_s` (paper notes 2.3).
    b : ndarray, shape (N + 1, p)
        :math:`b_0 = 0`, :math:`b_{i+1} = b_i + a_i \bar w`.
    e_inf : float
        :math:`\bar e_\infty = \bar w / (1 - \rho_o)`, eq. (eo-limit).
    q : float
        :math:`q = \lambda_{max}(Q)`.
    epsilon : float
        Margin of paper notes 2.6: :math:`A_\delta^\top P_f A_\delta - P_f = -(1+\epsilon) q I_2`.
    P_f : ndarray, shape (2, 2)
        Terminal weight; entrywise nonnegative (asserted).
    rho_f : float
        :math:`\rho_f = \sqrt{1 - q / \lambda_{max}(P_f)}` (proof of Theorem 3, Part 2c).
    kappa : ndarray, shape (p,)
        :math:`\kappa_j = \|[0\; \|W_{y(j*)}\|] P_f^{-1/2}\|` of eq. (alpha_ub)/(alpha_lb).
    c_s_ratio_term : float
        :math:`\frac{c_{s,u}}{c_{s,l}} \rho_s^N L_{max}` (used by the rate bound).
    L_d_norm : float
        :math:`\|L_d\|`.
    """

    N: int
    d_max: float
    w_bar: float
    rho_o: float
    y_min: FloatArray
    y_max: FloatArray
    a: FloatArray
    b: FloatArray
    e_inf: float
    q: float
    epsilon: float
    P_f: FloatArray
    rho_f: float
    kappa: FloatArray
    c_s_ratio_term: float
    L_d_norm: float

    # ----------------------------------------------------------- observer bound
    def next_e_hat(self, e_hat: float) -> float:
        r""":math:`\hat e_{o,k+1} = \rho_o \hat e_{o,k} + \bar w`, eq. (eo_evolution)."""
        return self.rho_o * float(e_hat) + self.w_bar

    def e_tilde(self, e_hat: float) -> float:
        r""":math:`\tilde e_{o,k} = \max\{\hat e_{o,k}, \bar e_\infty\}`, eq. (e_ok_bar)."""
        return max(float(e_hat), self.e_inf)

    # ------------------------------------------------------ tightened outputs
    def output_bounds(self, e_hat: float) -> tuple[FloatArray, FloatArray]:
        r"""Bounds on the model output :math:`W_y h_{i|k} + b_y` for i = 0..N-1.

        From eq. (optimization_constraint_yub) and (optimization_constraint_ylb):

        .. math::

            y_{min} + a_i \hat e_{o,k} + b_i + d_{max} \le W_y h_{i|k} + b_y
            \le y_{max} - a_i \hat e_{o,k} - b_i - d_{max}

        Returns
        -------
        lower, upper : ndarray, shape (N, p)
        """
        e = float(e_hat)
        shrink = self.a[: self.N] * e + self.b[: self.N] + self.d_max
        return self.y_min + shrink, self.y_max - shrink

    # --------------------------------------------------------- terminal set
    def alpha(self, y0: ArrayLike, e_hat: float) -> float:
        r"""Terminal-set level :math:`\alpha_k`, eq. (def_alpha), (alpha_ub), (alpha_lb).

        .. math::

            \alpha_k = \min_j \kappa_j^{-1} \min\{ y_{max(j)} - y^0_{k(j)},\;
            y^0_{k(j)} - y_{min(j)} \} - \kappa_j^{-1}(2 d_{max} + a_{N(j)} \tilde e_{o,k}
            + b_{N(j)})

        A non-positive value means Assumption 5 is violated: the FHOCP has no solution.
        """
        y_max, y_min, kappa, a_N, b_N = self._alpha_terms
        if isinstance(y0, np.ndarray) and y0.shape == self.y_min.shape:
            y0_list = y0.tolist()
        else:
            y0_arr = np.atleast_1d(np.asarray(y0, dtype=np.float64))
            if y0_arr.shape != self.y_min.shape:
                raise DimensionError(f"y0 has shape {y0_arr.shape}, expected {self.y_min.shape}")
            y0_list = y0_arr.tolist()
        cache = self._alpha_margins  # [e_hat, 2 d_max + a_N e_tilde + b_N] of the last call
        if cache[0] != e_hat:
            e_tilde = self.e_tilde(e_hat)
            two_d = 2.0 * self.d_max
            cache[:] = [e_hat, [two_d + a * e_tilde + b for a, b in zip(a_N, b_N, strict=True)]]
        # Scalar loop over the p outputs (hot path: no temporary arrays).
        return min(
            min((hi - y - margin) / k, (y - lo - margin) / k)
            for y, hi, lo, k, margin in zip(y0_list, y_max, y_min, kappa, cache[1], strict=True)
        )

    @cached_property
    def _alpha_margins(self) -> list[Any]:
        """Mutable cache of :meth:`alpha`'s margins: ``[e_hat, margins per output]``."""
        return [math.nan, []]

    @cached_property
    def _alpha_terms(self) -> tuple[list[float], ...]:
        """y_max, y_min, kappa, a_N, b_N as lists (for :meth:`alpha`)."""
        return (
            self.y_max.tolist(),
            self.y_min.tolist(),
            np.asarray(self.kappa, dtype=np.float64).tolist(),
            np.asarray(self.a[self.N], dtype=np.float64).tolist(),
            np.asarray(self.b[self.N], dtype=np.float64).tolist(),
        )

    def alpha_min(self, y0_low: ArrayLike, y0_high: ArrayLike, e_hat: float) -> float:
        r"""Smallest :math:`\alpha_k` over the set-point box [y0_low, y0_high].

        :math:`\alpha_k` is a minimum of affine functions of :math:`y^0`, hence concave, so
        its minimum over a box is attained at a corner.
        """
        low = np.atleast_1d(np.asarray(y0_low, dtype=np.float64))
        high = np.atleast_1d(np.asarray(y0_high, dtype=np.float64))
        corners = itertools.product(*zip(low, high, strict=True))
        return min(self.alpha(np.array(corner), e_hat) for corner in corners)

    def setpoint_interval(self, e_hat: float | None = None) -> tuple[FloatArray, FloatArray]:
        r"""Admissible set-point interval of Assumption 5 (normalized).

        .. math::

            y_{min} + 2 d_{max} + a_N \tilde e_{o,k} + b_N < y^0_k
            < y_{max} - 2 d_{max} - a_N \tilde e_{o,k} - b_N

        Parameters
        ----------
        e_hat : float, optional
            Current :math:`\hat e_{o,k}`; default the asymptotic value :math:`\bar e_\infty`
            (the interval the paper quotes, e.g. [6.49, 8.51] pH).

        Returns
        -------
        lower, upper : ndarray, shape (p,)
            Empty (lower >= upper) when no set-point is admissible.
        """
        e_tilde = self.e_inf if e_hat is None else self.e_tilde(e_hat)
        margin = 2.0 * self.d_max + self.a[self.N] * e_tilde + self.b[self.N]
        return self.y_min + margin, self.y_max - margin

    def require_setpoint_interval(
        self, to_physical: Callable[[FloatArray], FloatArray] | None = None
    ) -> None:
        """Raise :class:`EmptySetpointIntervalError` when Assumption 5 admits no set-point.

        The interval of :meth:`setpoint_interval` (at :math:`\\bar e_\\infty`) is empty when
        :math:`2 d_{max} + a_N \\tilde e_{o} + b_N` is at least half the output range
        :math:`y_{max} - y_{min}` on some output. ``to_physical`` (normalized -> physical
        output) adds physical units to the message.
        """
        low, high = self.setpoint_interval()
        empty = np.flatnonzero(~(low < high))
        if not empty.size:
            return
        margin = self.a[self.N] * self.e_inf + self.b[self.N]
        j = int(empty[0])
        phys = ""
        if to_physical is not None:
            y_lo = to_physical(self.y_min)[j]
            y_hi = to_physical(self.y_max)[j]
            phys = f" ([{y_lo:.6g}, {y_hi:.6g}] in physical units)"
        raise EmptySetpointIntervalError(
            f"no admissible set-point (Assumption 5) on output {j}: the output constraint "
            f"[y_min, y_max] = [{self.y_min[j]:.6g}, {self.y_max[j]:.6g}] (normalized){phys} "
            f"shrinks on each side by 2 d_max = {2.0 * self.d_max:.6g} plus "
            f"a_N e_tilde + b_N = {margin[j]:.6g} (e_tilde = e_inf = {self.e_inf:.6g}, N = "
            f"{self.N}), leaving [{low[j]:.6g}, {high[j]:.6g}]. Widen the output constraint "
            "(MPCConfig y_min/y_max, or the model's y_phi_constraint_min/max), reduce d_max, "
            "shorten the horizon N, or pick observer gains with a smaller e_inf."
        )

    def setpoint_rate_bound(
        self,
        alpha: float,
        e_hat: float,
        *,
        K_bar: float,
        e_y_bar: float,
    ) -> SetpointRateBound:
        r"""Largest set-point step :math:`\Delta y^0_{max}` of Theorem 3 (paper notes 2.10c).

        Parameters
        ----------
        alpha : float
            A lower bound of :math:`\alpha_{k+1}` over the set-points of interest (e.g.
            :meth:`alpha_min` over the operating range): the bound holds only there.
        e_hat : float
            :math:`\hat e_{o,k}`.
        K_bar : float
            :math:`\bar K` of Lemma 5 (estimate with
            :func:`ltv_lstm_mpc.estimate_K_bar`; paper: 2.67).
        e_y_bar : float
            Bound on :math:`|y - \hat y|` (paper: 0.03).
        """
        sqrt_lambda = float(np.sqrt(np.max(np.linalg.eigvalsh(self.P_f))))
        constant = sqrt_lambda * (
            self.c_s_ratio_term * float(e_hat) + self.rho_f * K_bar * self.L_d_norm * e_y_bar
        )
        margin = (1.0 - self.rho_f) * float(alpha) - constant
        slope = sqrt_lambda * self.rho_f * K_bar + self.rho_f * float(np.max(1.0 / self.kappa))
        holds = margin >= 0.0
        return SetpointRateBound(
            delta_y0_max=margin / slope if holds else 0.0,
            holds=holds,
            margin=margin,
            slope=slope,
            alpha=float(alpha),
            e_hat=float(e_hat),
            K_bar=float(K_bar),
            e_y_bar=float(e_y_bar),
        )


def tightening_certificate(
    model: LSTMModel,
    delta_iss: DeltaISSCertificate,
    lyapunov: IncrementalLyapunovCertificate,
    observer: ObserverCertificate,
    *,
    N: int = 5,
    Q: ArrayLike = 1.0,
    y_min: ArrayLike = -1.0,
    y_max: ArrayLike = 1.0,
    epsilon: float = 0.01,
) -> TighteningCertificate:
    r"""Compute :math:`a_i, b_i, \bar e_\infty, P_f, \rho_f, \kappa` for the FHOCP.

    Parameters
    ----------
    model : LSTMModel
    delta_iss, lyapunov, observer : certificates
        From :func:`~ltv_lstm_mpc.delta_iss_certificate`,
        :func:`~ltv_lstm_mpc.incremental_lyapunov_certificate`,
        :func:`~ltv_lstm_mpc.observer_certificate`.
    N : int
        Prediction horizon (paper: 5).
    Q : float or array_like, shape (2n, 2n)
        Stage state weight (paper: :math:`I_{2n}`); only :math:`q = \lambda_{max}(Q)` is used.
    y_min, y_max : float or array_like, shape (p,)
        Output constraint in normalized units.
    epsilon : float
        Margin of paper notes 2.6 for :math:`P_f`.
    """
    model = require_model(model)
    expect_instance("delta_iss", delta_iss, DeltaISSCertificate, expected="a DeltaISSCertificate")
    expect_instance(
        "lyapunov", lyapunov, IncrementalLyapunovCertificate,
        expected="an IncrementalLyapunovCertificate",
    )  # fmt: skip
    expect_instance("observer", observer, ObserverCertificate, expected="an ObserverCertificate")
    N = expect_int("N", N, minimum=1, hint="N is the prediction horizon, e.g. N=5")
    expect_real("epsilon", epsilon, low=0.0, high=1.0, low_open=True, high_open=True)
    for name, bound in (("y_min", y_min), ("y_max", y_max)):
        if finite_array(name, bound).shape not in ((), (1,), (model.p,)):
            raise DimensionError(
                f"{name} has shape {np.shape(bound)}, expected a number or ({model.p},)"
            )
    finite_array("Q", Q)
    delta_iss.require()
    p = model.p
    y_min_arr = np.broadcast_to(np.asarray(y_min, dtype=np.float64), (p,)).copy()
    y_max_arr = np.broadcast_to(np.asarray(y_max, dtype=np.float64), (p,)).copy()
    if not (np.all(np.isfinite(y_min_arr)) and np.all(np.isfinite(y_max_arr))):
        raise InvalidValueError("y_min and y_max must be finite")
    if np.any(y_max_arr <= y_min_arr):
        raise InvalidValueError(f"need y_max > y_min, got y_min={y_min_arr}, y_max={y_max_arr}")
    Q_arr = np.asarray(Q, dtype=np.float64)
    if Q_arr.ndim == 0:
        q = float(Q_arr)
    else:
        if Q_arr.shape != (2 * model.n, 2 * model.n):
            raise DimensionError(
                f"Q has shape {Q_arr.shape}, expected ({2 * model.n}, {2 * model.n}) or scalar"
            )
        q = float(np.max(np.linalg.eigvalsh(0.5 * (Q_arr + Q_arr.T))))
    if not np.isfinite(q) or q <= 0:
        raise InvalidValueError(f"Q must be positive definite (lambda_max(Q) = {q})")
    if not epsilon > 0:
        raise InvalidValueError(f"epsilon must be positive, got {epsilon}")

    # eq. (constraint_tightening_parameters) with paper notes 2.3 (c_{o,s} = c_s of Lemma 2).
    a = np.empty((N + 1, p))
    b = np.empty((N + 1, p))
    a[0] = observer.c_o
    b[0] = 0.0
    for i in range(N):
        a[i + 1] = (
            observer.rho_o * a[i]
            + lyapunov.rho_s**i * lyapunov.c_s_u * observer.L_max * lyapunov.c_s
        )
        b[i + 1] = b[i] + a[i] * observer.w_bar

    # paper notes 2.6: A_delta' P_f A_delta - P_f = -(1 + eps) q I_2.
    P_f = solve_lyapunov(delta_iss.A_delta, (1.0 + epsilon) * q * np.eye(2))
    scale = float(np.max(np.abs(P_f)))
    if np.any(P_f < -1e-12 * scale):
        raise LtvMpcError(
            f"P_f = {P_f.tolist()} has a negative entry; paper notes 4's exact cone relaxation "
            "needs P_f >= 0 entrywise (it holds in exact arithmetic since A_delta >= 0)"
        )
    P_f = np.maximum(P_f, 0.0)
    eig_P_f = np.linalg.eigvalsh(P_f)
    rho_f = float(np.sqrt(1.0 - q / eig_P_f[-1]))
    P_f_inv_sqrt = matrix_inverse_sqrt(P_f)
    row_norms = np.linalg.norm(model.W_y, axis=1)
    kappa = np.array([np.linalg.norm(np.array([0.0, r]) @ P_f_inv_sqrt) for r in row_norms])
    for array in (y_min_arr, y_max_arr, a, b, P_f, kappa):
        array.setflags(write=False)
    return TighteningCertificate(
        N=N,
        d_max=observer.d_max,
        w_bar=observer.w_bar,
        rho_o=observer.rho_o,
        y_min=y_min_arr,
        y_max=y_max_arr,
        a=a,
        b=b,
        e_inf=observer.e_inf,
        q=q,
        epsilon=float(epsilon),
        P_f=P_f,
        rho_f=rho_f,
        kappa=kappa,
        c_s_ratio_term=lyapunov.c_s_u / lyapunov.c_s_l * lyapunov.rho_s**N * observer.L_max,
        L_d_norm=float(np.linalg.norm(observer.gains.L_d, 2)),
    )
