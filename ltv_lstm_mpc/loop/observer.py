r"""State and disturbance observer of the augmented LSTM, eq. (lstm_observer).

.. math::

    \hat c_{k+1} &= \sigma(W_f u_k + U_f \hat h_k + b_f + L_f (y_k - \hat y_k)) \circ \hat c_k \\
      &\quad + \sigma(W_i u_k + U_i \hat h_k + b_i + L_i (y_k - \hat y_k))
         \circ \tanh(W_c u_k + U_c \hat h_k + b_c) \\
    \hat h_{k+1} &= \sigma(W_o u_k + U_o \hat h_k + b_o + L_o (y_k - \hat y_k))
         \circ \tanh(\hat c_{k+1}) \\
    \hat d_{k+1} &= \mathrm{sat}(\hat d_k + L_d (y_k - \hat y_k), d_{max}) \\
    \hat y_k &= W_y \hat h_k + b_y + \hat d_k

Timing convention: at time k the controller uses :math:`(\hat x_k, \hat d_k)`; after the
input :math:`u_k` is chosen, ``step(y_k, u_k)`` returns :math:`(\hat x_{k+1}, \hat d_{k+1})`.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from ltv_lstm_mpc.caller_warnings import warn_at_caller
from ltv_lstm_mpc.certificates.stability import ObserverGains
from ltv_lstm_mpc.deferred_state import Deferred, DeferredState, settle
from ltv_lstm_mpc.exceptions import DimensionError, InvalidValueError
from ltv_lstm_mpc.loop.compiled_observer import new_observer_workspace, observer_update
from ltv_lstm_mpc.loop.reference import ReferenceCalculator
from ltv_lstm_mpc.lstm.model import LSTMModel, require_model
from ltv_lstm_mpc.validation import expect_instance, expect_real, finite_array

__all__ = ["Observer"]

FloatArray = NDArray[np.float64]


class Observer(DeferredState):
    r"""LSTM state and output-disturbance observer, eq. (lstm_observer).

    Parameters
    ----------
    model : LSTMModel
    gains : ObserverGains
        :math:`L_f, L_i, L_o` (n, p) and :math:`L_d` (p, p); certify them with
        :func:`~ltv_lstm_mpc.observer_certificate`.
    d_max : float
        Saturation bound of :math:`\hat d` (:math:`\mathcal{D}`).
    x_hat0, d_hat0 : array_like, optional
        Initial estimate; default zero state and zero disturbance. Use
        :meth:`initialize` to start at the equilibrium matching a measurement.
    """

    #: The state estimate :math:`\hat x` (2n,). Rebound at each update, never mutated; a
    #: one-call step of the controller leaves it in its record row until it is first
    #: used (:mod:`ltv_lstm_mpc.deferred_state`).
    x_hat = Deferred[FloatArray]()
    #: The disturbance estimate :math:`\hat d` (p,), saturated to ``d_max``; like ``x_hat``.
    d_hat = Deferred[FloatArray]()

    def __init__(
        self,
        model: LSTMModel,
        gains: ObserverGains,
        *,
        d_max: float = 0.1,
        x_hat0: ArrayLike | None = None,
        d_hat0: ArrayLike | None = None,
    ) -> None:
        model = require_model(model)
        gains = expect_instance(
            "gains",
            gains,
            ObserverGains,
            "build them with ObserverGains(L_f, L_i, L_o, L_d) or take "
            "certify(model).observer.gains",
            expected="ObserverGains",
        )
        gains.check_model(model)
        expect_real("d_max", d_max, low=0.0, low_open=True)
        self.model = model
        self.gains = gains
        self.d_max = float(d_max)
        n, p = model.n, model.p
        # Gate gains in the kernel's (f, i, o, c) order; None when all are zero (Remark 3).
        L_gates = np.vstack([gains.L_f, gains.L_i, gains.L_o, np.zeros((n, p))])
        self._L_gates: FloatArray | None = L_gates if np.any(L_gates) else None
        # Compiled update (loop/compiled_observer.py) on a compiled kernel; the numpy
        # code of advance() is its reference.
        self._compiled = model.kernel.compiled
        self._update = self._update_numpy
        if self._compiled:
            self._update = self._update_compiled
            self._W_y = np.ascontiguousarray(model.W_y, dtype=np.float64)
            self._b_y = np.ascontiguousarray(model.b_y, dtype=np.float64)
            self._L_gates_c = np.ascontiguousarray(
                np.zeros((0, p)) if self._L_gates is None else self._L_gates
            )
            self._L_d = np.ascontiguousarray(gains.L_d, dtype=np.float64)
            self._S = np.zeros(2 * n + model.m + 1)
            self._S[-1] = 1.0
            self._T = np.zeros(4 * n)
            self._TC = np.zeros(n)
            self._extra = np.zeros(4 * n)
            self._workspace = new_observer_workspace(
                WU=model.kernel.WU,
                W_y=self._W_y,
                b_y=self._b_y,
                L_gates=self._L_gates_c,
                L_d=self._L_d,
                S=self._S,
                T=self._T,
                TC=self._TC,
                extra=self._extra,
            )
        self.x_hat = np.zeros(2 * n)
        self.d_hat = np.zeros(p)
        self.reset(
            np.zeros(2 * n) if x_hat0 is None else x_hat0,
            np.zeros(p) if d_hat0 is None else d_hat0,
        )

    def step_workspace(self) -> Any:
        """The compiled update's :data:`~ltv_lstm_mpc.loop.compiled_observer.ObserverWorkspace`
        (what a compiled step engine calls eq. lstm_observer with); None on the numpy kernel."""
        return getattr(self, "_workspace", None)

    def settle_estimates(self, x_hat: FloatArray, d_hat: FloatArray) -> None:
        """Take :math:`(\\hat x, \\hat d)` that a compiled step left in its record row (views,
        never written again), ending a deferral (:mod:`ltv_lstm_mpc.deferred_state`)."""
        settle(self, {"x_hat": x_hat, "d_hat": d_hat})

    def reset(self, x_hat: ArrayLike, d_hat: ArrayLike) -> None:
        """Set the estimate :math:`(\\hat x, \\hat d)` (d_hat is saturated to d_max)."""
        x_arr = np.array(finite_array("x_hat", x_hat))
        d_arr = np.atleast_1d(np.array(finite_array("d_hat", d_hat)))
        if x_arr.shape != (2 * self.model.n,):
            raise DimensionError(f"x_hat has shape {x_arr.shape}, expected ({2 * self.model.n},)")
        if d_arr.shape != (self.model.p,):
            raise DimensionError(f"d_hat has shape {d_arr.shape}, expected ({self.model.p},)")
        if not (np.all(np.isfinite(x_arr)) and np.all(np.isfinite(d_arr))):
            raise InvalidValueError("x_hat and d_hat must be finite")
        self.x_hat = x_arr
        self.d_hat = np.clip(d_arr, -self.d_max, self.d_max)

    def initialize(self, y: ArrayLike, *, reference: ReferenceCalculator | None = None) -> None:
        r"""Start at the LSTM equilibrium whose output equals ``y``, with :math:`\hat d_0 = 0`.

        This is the paper's initialization (Section V, paper notes 2.10b). When ``y`` is outside
        the model's equilibrium output range, the closest equilibrium is used and a
        warning names the mismatch.
        """
        calculator = reference or ReferenceCalculator(self.model, strict=False)
        y_arr = np.atleast_1d(np.asarray(y, dtype=np.float64))
        solution = calculator.solve(y_arr, np.zeros(self.model.p))
        if not solution.converged:
            warn_at_caller(
                f"no LSTM equilibrium has output {y_arr.tolist()}; the observer starts at the "
                f"closest one found (residual {solution.residual:.3e})",
                RuntimeWarning,
            )
        elif not solution.u_admissible:
            warn_at_caller(
                f"the LSTM equilibrium with output {y_arr.tolist()} needs u = "
                f"{solution.u_bar.tolist()} outside U: the initial estimate may lie outside "
                "the invariant set of Lemma 4 assumed by Theorem 2",
                RuntimeWarning,
            )
        self.reset(solution.x_bar, np.zeros(self.model.p))

    @property
    def y_hat(self) -> FloatArray:
        r""":math:`\hat y_k = W_y \hat h_k + b_y + \hat d_k`, eq. (y_lstm_observer)."""
        return np.asarray(self.model.output(self.x_hat) + self.d_hat, dtype=np.float64)

    def advance(self, innovation: FloatArray, u: FloatArray) -> None:
        r"""eq. (lstm_observer) for a computed innovation :math:`y_k - \hat y_k` (no checks).

        The state update is the model's kernel with the gate injection
        :math:`[L_f; L_i; L_o; 0](y_k - \hat y_k)`; then
        :math:`\hat d_{k+1} = \mathrm{sat}_{d_{max}}(\hat d_k + L_d (y_k - \hat y_k))`.
        The hot-loop entry point of the controller; :meth:`step` validates and calls it.
        """
        extra = None if self._L_gates is None else self._L_gates @ innovation
        self.x_hat = self.model.kernel.step(self.x_hat, u, extra)
        d_new = self.gains.L_d @ innovation
        d_new += self.d_hat
        np.minimum(d_new, self.d_max, out=d_new)
        np.maximum(d_new, -self.d_max, out=d_new)
        self.d_hat = d_new

    def update(self, y: FloatArray, u: FloatArray) -> None:
        r"""eq. (lstm_observer) from a measurement :math:`y_k` and input :math:`u_k` (no checks).

        The controller's hot-loop call: one compiled call on a compiled kernel
        (``loop/compiled_observer.py``), else the innovation
        :math:`y_k - \hat y_k` and :meth:`advance` (the numpy reference); chosen once, when
        the observer is built.
        """
        self._update(y, u)

    def _update_compiled(self, y: FloatArray, u: FloatArray) -> None:
        """:meth:`update` in one numba call (``loop/compiled_observer.py``)."""
        x_new = np.empty_like(self.x_hat)
        d_new = np.empty_like(self.d_hat)
        observer_update(self._workspace, self.d_max, self.x_hat, self.d_hat, y, u, x_new, d_new)
        self.x_hat, self.d_hat = x_new, d_new  # rebound, never mutated (see controller)

    def _update_numpy(self, y: FloatArray, u: FloatArray) -> None:
        """:meth:`update` by the innovation and :meth:`advance` (the numpy reference)."""
        model = self.model
        innovation = model.W_y @ self.x_hat[model.n :]
        innovation += model.b_y
        innovation += self.d_hat
        np.subtract(y, innovation, out=innovation)
        self.advance(innovation, u)

    def step(self, y: ArrayLike, u: ArrayLike) -> tuple[FloatArray, FloatArray]:
        r"""Update with measurement :math:`y_k` and applied input :math:`u_k`.

        Returns
        -------
        x_hat : ndarray, shape (2n,)
            :math:`\hat x_{k+1}`.
        d_hat : ndarray, shape (p,)
            :math:`\hat d_{k+1}`.
        """
        model = self.model
        p = model.p
        y_arr = np.atleast_1d(np.asarray(y, dtype=np.float64))
        u_arr = np.atleast_1d(np.asarray(u, dtype=np.float64))
        if y_arr.shape != (p,):
            raise DimensionError(f"y has shape {y_arr.shape}, expected ({p},)")
        if u_arr.shape != (model.m,):
            raise DimensionError(f"u has shape {u_arr.shape}, expected ({model.m},)")
        if not (np.all(np.isfinite(y_arr)) and np.all(np.isfinite(u_arr))):
            raise InvalidValueError(f"y and u must be finite, got y={y_arr}, u={u_arr}")
        self.update(y_arr, u_arr)
        return self.x_hat.copy(), self.d_hat.copy()
