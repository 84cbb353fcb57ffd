r"""What single precision costs the certificates: a bound of the rounding of the exported
controller in ``float`` and the share of the certificates' margins it takes.

A controller exported with ``precision="single"`` computes in float (unit roundoff
:math:`u = 2^{-24} \approx 6 \cdot 10^{-8}` against double's :math:`1.1 \cdot 10^{-16}`).
Its rounding acts on the certified loop like disturbances the certificates must absorb:

* **the observer** (eq. lstm_observer): one update rounds :math:`\hat c, \hat h, \hat d`
  by at most :math:`\delta_c, \delta_h, \delta_d` (2-norms, below). In the proof of
  Theorem 2 they enter the error bound's dynamics beside the disturbance variation, so
  :math:`\hat e_{o,k+1} \le \rho_o \hat e_{o,k} + \bar w + \varepsilon_o` with
  :math:`\varepsilon_o = \|P_o^{1/2} [\delta_c, \delta_h, \delta_d]\|`: the float
  controller keeps the certificate's :math:`\bar w` (hence every :math:`a_i, b_i`,
  :math:`\bar e_\infty`) for disturbance variations up to
  :math:`(\bar w - \varepsilon_o) / \sqrt{P_{o(3,3)}}` instead of :math:`w_{max}`
  (paper notes 2.3, 3);
* **the predictions** (eq. optimization): the tightened output rows hold for the float
  model's outputs, which differ from the LSTM's by the output map's rounding
  :math:`\delta_y` plus the rollout's, at most
  :math:`\|W_{y(j*)}\| \frac{c_{s,u}}{c_{s,l}} \frac{1 - \rho_s^N}{1 - \rho_s} \delta_x`
  (Lemma 2's incremental Lyapunov function, one rounding :math:`\delta_x` per stage), and
  by the acceptance tolerance of a single-precision export: together
  :math:`\varepsilon_y`, taken from :math:`d_{max}` (the plant keeps the guarantee of
  Theorem 3 for output disturbances up to :math:`d_{max} - \varepsilon_y`).

:func:`single_precision_margins` computes both from the weights, by the standard bound of a
float sum of k products, :math:`\gamma_k = k u / (1 - k u)` times the sum of the products'
magnitudes, over the sets the certificates bound (:math:`|h| \le 1`, :math:`|u| \le
u_{max}`, :math:`|c| \le` the invariant set's bound, :math:`|\hat d| \le d_{max}`,
measurements within the plausibility limit), with the activations' own float error
:data:`ACTIVATION_ERROR` (measured: ``tests/test_export_precision.py``), the rounding of
the constants (one more rounding per product) and of the measurement's normalization. The
export is refused when either takes more than :data:`MARGIN_SHARE` of its margin.

Not covered by the bound (not margins of these two certificates): the terminal set's
:math:`\alpha_k` and the terminal constraint (Theorem 3's recursive feasibility; the
rollout's drift moves :math:`x_N` too), the reference calculator's residual tolerance
(raised to 1e-5 in float), the float rounding of the certificates' own constants
(:math:`a_i, b_i, \kappa`, the :math:`\hat e_o` recursion) and the set-point rate bound.
The closed-loop deviation from double is measured instead (``experiments/export_float.py``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

__all__ = [
    "ACTIVATION_ERROR",
    "MARGIN_SHARE",
    "UNIT_ROUNDOFF",
    "SinglePrecisionMargins",
    "single_precision_margins",
]

#: The unit roundoff of float (round to nearest): :math:`2^{-24}`.
UNIT_ROUNDOFF = 2.0**-24
#: The largest absolute error of the exported float sigmoid and tanh (``model.c.in``: the
#: activations on a float ``exp``), as a bound: 8 u. Measured over 7 million points
#: (a grid of [-30, 30] and random ones of magnitudes 1e-17 to 33): 1.5 u and 2.5 u.
ACTIVATION_ERROR = 8.0 * UNIT_ROUNDOFF
#: The share of :math:`\bar w` and of :math:`d_{max}` single precision may take: the float
#: controller's observer-error bound and tightened outputs then hold for at least half the
#: disturbances certified (what the bound covers: the module docstring).
MARGIN_SHARE = 0.5


def _gamma(k: int) -> float:
    """:math:`\\gamma_k = k u / (1 - k u)`: a float sum of k products errs by at most this
    times the sum of their magnitudes."""
    ku = k * UNIT_ROUNDOFF
    return ku / (1.0 - ku)


@dataclass(frozen=True)
class SinglePrecisionMargins:
    r"""The rounding of a single-precision export against the certificates' margins
    (module docstring).

    Attributes
    ----------
    delta_c, delta_h, delta_d : float
        Bounds of one observer update's rounding of :math:`\hat c, \hat h, \hat d`
        (2-norms, normalized units).
    observer_rounding : float
        :math:`\varepsilon_o = \|P_o^{1/2} [\delta_c, \delta_h, \delta_d]\|`.
    w_bar : float
        The certificate's :math:`\bar w`.
    delta_x : float
        One prediction step's rounding (2-norm of the state).
    output_rounding : float
        :math:`\varepsilon_y`: output map, prediction drift over N stages and the
        acceptance tolerance (largest over the outputs).
    d_max : float
        The certificate's :math:`d_{max}`.
    share : float
        The largest share of a margin allowed (:data:`MARGIN_SHARE`).
    """

    delta_c: float
    delta_h: float
    delta_d: float
    observer_rounding: float
    w_bar: float
    delta_x: float
    output_rounding: float
    d_max: float
    share: float

    @property
    def holds(self) -> bool:
        """Whether both roundings take at most :attr:`share` of their margins."""
        return (
            self.observer_rounding <= self.share * self.w_bar
            and self.output_rounding <= self.share * self.d_max
        )

    def summary(self) -> str:
        """One line: the two shares."""
        return (
            f"single precision takes {self.observer_rounding / self.w_bar:.2%} of w_bar "
            f"(observer rounding {self.observer_rounding:.3g} of {self.w_bar:.3g}) and "
            f"{self.output_rounding / self.d_max:.2%} of d_max (prediction rounding and "
            f"tolerance {self.output_rounding:.3g} of {self.d_max:.3g}); at most "
            f"{self.share:.0%} each allowed"
        )

    def refusal(self) -> str | None:
        """Why single precision is refused (None: it is not)."""
        if self.holds:
            return None
        return (
            f"single precision is refused for this controller: {self.summary()}. The "
            "certificates' margins do not cover float's rounding; export in double "
            "precision, or certify with a larger w_bar or d_max (MPCConfig w_bar, d_max)"
        )


def _gate_magnitude(model: Any, u_max: float) -> Any:
    """Per gate row, the sum of the magnitudes of WU [h; u; 1] over |h| <= 1, |u| <= u_max."""
    z_bound = np.concatenate([np.ones(model.n), np.full(model.m, u_max), [1.0]])
    return np.abs(np.asarray(model.kernel.WU, dtype=np.float64)) @ z_bound


def _observer_rounding(
    model: Any, observer: Any, certificate: Any, u_max: float, scaling: Any
) -> tuple[float, float, float]:
    """:math:`\\delta_c, \\delta_h, \\delta_d` of one float observer update (the
    measurement's normalization in float included)."""
    from ltv_lstm_mpc.loop.statuses import IMPLAUSIBLE_MEASUREMENT_LIMIT

    n, m, p = model.n, model.m, model.p
    gains = observer.gains
    d_max = float(observer.d_max)
    W_y, b_y = np.abs(model.W_y), np.abs(model.b_y)
    L_gates = np.abs(np.vstack([gains.L_f, gains.L_i, gains.L_o, np.zeros((n, p))]))
    L_d = np.abs(np.atleast_2d(gains.L_d))
    y_bound = IMPLAUSIBLE_MEASUREMENT_LIMIT
    # y = (y_phi - y_min) / y_scale - 1 in float, |y| <= y_bound: y_phi, y_min and y_scale
    # rounded to float, then a subtraction, a division and a subtraction, each rounded
    offset = np.abs(np.ravel(scaling.y_min)) / np.abs(np.ravel(scaling.y_scale))
    d_measurement = _gamma(6) * (2.0 * offset + 3.0 * (y_bound + 1.0))
    # the innovation y - W_y h - b_y - d_hat: its magnitude and rounding (with y's own)
    innovation = y_bound + b_y + d_max + W_y.sum(axis=1)
    d_innovation = _gamma(n + 4) * innovation + d_measurement
    magnitude = _gate_magnitude(model, u_max) + L_gates @ innovation
    d_pre = _gamma(n + m + p + 3) * magnitude + L_gates @ d_innovation
    d_c, d_h = _cell_rounding(d_pre, n, float(certificate.c_hat_bound))
    d_d = _gamma(p + 2) * (d_max + L_d @ innovation) + L_d @ d_innovation
    return (
        float(np.linalg.norm(d_c)),
        float(np.linalg.norm(d_h)),
        float(np.linalg.norm(d_d)),
    )


def _cell_rounding(d_pre: Any, n: int, c_bound: float) -> tuple[Any, Any]:
    """Per unit: the rounding of c+ and h+ from that of the gates' pre-activations
    (rows f, i, o, g): sigmoid' <= 1/4, tanh' <= 1, each activation's own error."""
    if not math.isfinite(c_bound):
        return np.full(n, math.inf), np.full(n, math.inf)
    e = ACTIVATION_ERROR
    d_f, d_i = d_pre[:n] / 4 + e, d_pre[n : 2 * n] / 4 + e
    d_o, d_g = d_pre[2 * n : 3 * n] / 4 + e, d_pre[3 * n :] + e
    d_c = d_f * c_bound + d_i + d_g + _gamma(3) * (c_bound + 1.0)
    d_h = d_o + d_c + e + UNIT_ROUNDOFF
    return d_c, d_h


def single_precision_margins(controller: Any, tolerance: float) -> SinglePrecisionMargins:
    """The rounding of ``controller`` exported in single precision against its
    certificates' margins (module docstring).

    Parameters
    ----------
    controller : OffsetFreeController
        The controller (its model, observer and certification).
    tolerance : float
        The export's acceptance tolerance in single precision (normalized outputs).
    """
    certification = controller.certification
    model = controller.model
    u_max = float(controller.config.u_max)
    d_c, d_h, d_d = _observer_rounding(
        model, controller.observer, certification.observer, u_max, controller.scaling
    )
    P_o = np.asarray(certification.observer.P_o, dtype=np.float64)
    r = np.array([d_c, d_h, d_d])
    observer_rounding = float(np.sqrt(r @ P_o @ r)) if np.all(np.isfinite(r)) else math.inf
    # the predictions: the cell without injection, from an estimate in the observer's
    # invariant set or the model's
    n, m = model.n, model.m
    d_pre = _gamma(n + m + 2) * _gate_magnitude(model, u_max)
    c_bound = max(float(certification.delta_iss.c_bound), float(certification.observer.c_hat_bound))
    p_c, p_h = _cell_rounding(d_pre, n, c_bound)
    delta_x = float(np.linalg.norm(np.concatenate([p_c, p_h])))
    lyapunov = certification.lyapunov
    N = int(controller.config.N)
    rho_s = float(lyapunov.rho_s)
    drift = float(lyapunov.c_s_u / lyapunov.c_s_l) * delta_x * (1.0 - rho_s**N) / (1.0 - rho_s)
    W_y = np.asarray(model.W_y, dtype=np.float64)
    y_magnitude = np.abs(W_y).sum(axis=1) + np.abs(model.b_y)
    d_y = _gamma(n + 2) * y_magnitude
    tightening = certification.tightening
    # the acceptance tests take a violation up to the tolerance times their scale, 1 + the
    # largest magnitude of the input bound and the rows' bounds at the candidate (output
    # rows: tightened bound minus output; terminal rows: half-width alpha times the unit
    # box's minus the state's offset from the reference)
    y_bounds = np.maximum(np.abs(tightening.y_min), np.abs(tightening.y_max))
    alpha_max = float(np.max((tightening.y_max - tightening.y_min) / (2.0 * tightening.kappa)))
    unit_half = np.asarray(getattr(controller.mpc._problem, "_unit_half", [0.0]), dtype=float)
    scale = 1.0 + max(
        u_max,
        float(np.max(y_bounds + np.max(y_magnitude))),
        float(np.max(unit_half)) * alpha_max + 2.0 * max(c_bound, 1.0),
    )
    output = d_y + np.linalg.norm(W_y, axis=1) * drift + float(tolerance) * scale
    return SinglePrecisionMargins(
        delta_c=d_c,
        delta_h=d_h,
        delta_d=d_d,
        observer_rounding=observer_rounding,
        w_bar=float(tightening.w_bar),
        delta_x=delta_x,
        output_rounding=float(np.max(output)),
        d_max=float(tightening.d_max),
        share=MARGIN_SHARE,
    )
