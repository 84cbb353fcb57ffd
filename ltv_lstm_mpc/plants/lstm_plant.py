"""The LSTM model used as a plant, with an additive output disturbance (paper Fig. 2)."""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

from ltv_lstm_mpc.exceptions import DimensionError, InvalidValueError
from ltv_lstm_mpc.lstm.model import LSTMModel, require_model
from ltv_lstm_mpc.validation import expect_real, finite_array, real_vector

__all__ = ["LSTMPlant"]

FloatArray = NDArray[np.float64]


class LSTMPlant:
    r"""The LSTM model with an additive output disturbance, eq. (augmented_lstm) / Fig. 2.

    .. math::

        x_{k+1} = f(x_k, u_k), \qquad y_k = W_y h_k + b_y + d_k

    in normalized units; this class exposes physical units through the model's normalization.
    ``step(u_phi, d_phi)`` takes the physical input and **the output disturbance in physical
    output units** (e.g. pH units; it is converted to normalized units by dividing by the
    output scale), applies ``u_phi`` for one step and returns the physical output
    :math:`y_{\phi,k+1} = N_y^{-1}(W_y h_{k+1} + b_y + d_{k+1})`, with :math:`d_{k+1}` the given
    disturbance (``None`` keeps the previous one; initially 0). The input is *not* saturated.

    Parameters
    ----------
    model : LSTMModel
        Must carry a normalization.
    x0 : array_like, shape (2n,), optional
        Initial state; default: the equilibrium of ``u0_phi`` (or of the input whose
        equilibrium output is ``y0_phi``), else the equilibrium of the mid-range input.
    u0_phi, y0_phi : float or array_like, optional
        Start at the equilibrium for this physical input, or for the physical output (the
        input is then found by bisection on the equilibrium output; needs m = p = 1).
    """

    def __init__(
        self,
        model: LSTMModel,
        x0: ArrayLike | None = None,
        *,
        u0_phi: ArrayLike | None = None,
        y0_phi: float | None = None,
    ) -> None:
        model = require_model(model)
        if model.normalization is None:
            raise InvalidValueError("LSTMPlant needs a model with a normalization")
        if u0_phi is not None:
            u0_phi = real_vector("u0_phi", u0_phi, model.m)
        if y0_phi is not None:
            y0_phi = expect_real("y0_phi", y0_phi)
        self.model = model
        #: Entries of ``d_phi`` in :meth:`step` (the output disturbance, one per output).
        self.disturbance_size = model.p
        #: Sampling period, s: the model's (None if it states none).
        self.Ts = model.Ts
        self._x0_arg = None if x0 is None else finite_array("x0", x0)
        self._u0_phi = u0_phi
        self._y0_phi = y0_phi
        self.x: FloatArray = np.zeros(2 * model.n)
        self.d: FloatArray = np.zeros(model.p)
        self.reset()

    def equilibrium_for_output(self, y_phi: float, tol: float = 1e-10) -> FloatArray:
        """Equilibrium state whose physical output is ``y_phi`` (m = p = 1; bisection on u)."""
        model = self.model
        if model.m != 1 or model.p != 1:
            raise DimensionError("equilibrium_for_output needs m = p = 1")
        target = float(model.normalize_y(y_phi)[0])

        def out(u: float) -> tuple[float, FloatArray]:
            x = model.equilibrium(np.array([u]))
            return float(model.output(x)[0]) - target, x

        lo, hi = -1.0, 1.0
        r_lo, x_lo = out(lo)
        r_hi, _ = out(hi)
        if r_lo * r_hi > 0:
            raise InvalidValueError(
                f"no equilibrium in the input range [-1, 1] has output {y_phi} "
                f"(range {model.denormalize_y([r_lo + target])[0]:.4f}.."
                f"{model.denormalize_y([r_hi + target])[0]:.4f})"
            )
        x_mid = x_lo
        while hi - lo > tol:
            mid = 0.5 * (lo + hi)
            r_mid, x_mid = out(mid)
            if (r_mid > 0) == (r_hi > 0):
                hi, r_hi = mid, r_mid
            else:
                lo, r_lo = mid, r_mid
        return x_mid

    def reset(self) -> FloatArray:
        """Back to the initial state with d = 0; returns the state x = [c; h]."""
        model = self.model
        if self._x0_arg is not None:
            x = model._check_state(self._x0_arg, "x0")
            if x.shape != (2 * model.n,):
                raise DimensionError(f"x0 has shape {x.shape}, expected ({2 * model.n},)")
        elif self._y0_phi is not None:
            x = self.equilibrium_for_output(float(self._y0_phi))
        else:
            if self._u0_phi is not None:
                u0 = model.normalize_u(np.atleast_1d(np.asarray(self._u0_phi, dtype=np.float64)))
            else:
                u0 = np.zeros(model.m)
            x = model.equilibrium(u0)
        self.x = np.array(x, dtype=np.float64)
        self.d = np.zeros(model.p)
        return self.x.copy()

    def output(self) -> FloatArray:
        """Current physical output :math:`N_y^{-1}(W_y h_k + b_y + d_k)`, shape (p,)."""
        return self.model.denormalize_y(self.model.output(self.x) + self.d)

    def step(self, u_phi: ArrayLike, d_phi: ArrayLike | None = None) -> FloatArray:
        """Apply the physical input for one step; ``d_phi`` is the output disturbance at the
        next instant in physical output units (``None``: unchanged). Returns the output."""
        model = self.model
        u = model.normalize_u(real_vector("u_phi", u_phi, model.m))
        if d_phi is not None:
            scale = 0.5 * (
                model.denormalize_y(np.ones(model.p)) - model.denormalize_y(-np.ones(model.p))
            )
            self.d = real_vector("d_phi", d_phi, model.p) / scale
        self.x = model.kernel.step(self.x, u)  # x and u checked: no second check
        return self.output()
