r"""Single-layer LSTM state-space model of the paper, eq. (lstm).

.. math::

    c_{k+1} &= \sigma(W_f u_k + U_f h_k + b_f) \circ c_k
              + \sigma(W_i u_k + U_i h_k + b_i) \circ \tanh(W_c u_k + U_c h_k + b_c) \\
    h_{k+1} &= \sigma(W_o u_k + U_o h_k + b_o) \circ \tanh(c_{k+1}) \\
    \xi_k   &= W_y h_k + b_y

The state is :math:`x = [c; h] \in \mathbb{R}^{2n}`, the input
:math:`u \in \mathbb{R}^m` and the output :math:`\xi \in \mathbb{R}^p`, all in
*normalized* units (paper notes 1). The output at time k depends on :math:`h_k`, not on
:math:`h_{k+1}`: the model has no direct feed-through.

Everything here is numpy float64; torch is never imported at module level.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from ltv_lstm_mpc.caller_warnings import warn_at_caller
from ltv_lstm_mpc.exceptions import (
    DimensionError,
    InvalidValueError,
    LtvMpcError,
    ModelFileNotFoundError,
    ModelFormatError,
)
from ltv_lstm_mpc.lstm.kernel import LSTMKernel
from ltv_lstm_mpc.validation import (
    expect_instance,
    expect_int,
    expect_real,
    finite_array,
    real_array,
)

__all__ = ["WEIGHT_NAMES", "LSTMModel", "ModelFormatError", "Normalization", "metadata_arrays"]

FloatArray = NDArray[np.float64]

#: Names of the weight arrays of eq. (lstm), exactly as stored in a model ``.npz`` file.
WEIGHT_NAMES: tuple[str, ...] = (
    "W_f",
    "U_f",
    "b_f",
    "W_i",
    "U_i",
    "b_i",
    "W_o",
    "U_o",
    "b_o",
    "W_c",
    "U_c",
    "b_c",
    "W_y",
    "b_y",
)
_NORMALIZATION_NAMES = ("u_phi_min", "u_phi_max", "y_phi_min", "y_phi_max")
_CONSTRAINT_NAMES = ("y_phi_constraint_min", "y_phi_constraint_max")
#: Optional scalar array of the file format: the sampling time in seconds.
_TS_NAME = "Ts"


def _as_finite_array(name: str, value: ArrayLike, shape: tuple[int, ...]) -> FloatArray:
    """Convert ``value`` to a float64 array of exactly ``shape``, rejecting NaN/inf."""
    array = np.array(real_array(name, value), dtype=np.float64, copy=True)
    if array.shape != shape:
        raise DimensionError(
            f"{name} has shape {array.shape}, expected {shape} "
            "(W_* (n, m), U_* (n, n), b_* (n,), W_y (p, n), b_y (p,))"
        )
    if not np.all(np.isfinite(array)):
        raise InvalidValueError(f"{name} contains NaN or inf values; all weights must be finite")
    array.setflags(write=False)
    return array


def _read_npz(path: Path) -> dict[str, Any]:
    """The arrays of an ``.npz`` file, or :class:`ModelFormatError` naming what is wrong."""
    import zipfile

    try:
        loaded = np.load(path, allow_pickle=False)
    except (ValueError, OSError, EOFError, zipfile.BadZipFile) as error:
        with open(path, "rb") as handle:
            head = handle.read(6)
        if head.startswith(b"PK"):
            what = f"a damaged or truncated .npz archive ({type(error).__name__}: {error})"
        elif head.startswith(b"\x93NUMPY"):
            what = "a single-array .npy file, not an .npz archive of named arrays"
        else:
            what = "not an .npz archive (neither a zip file nor numpy data)"
        raise ModelFormatError(
            f"{path}: {what}; a model file is an .npz written by LSTMModel.save"
        ) from None
    if not isinstance(loaded, np.lib.npyio.NpzFile):
        raise ModelFormatError(
            f"{path}: a single-array .npy file, not an .npz archive of named arrays; "
            "a model file is an .npz written by LSTMModel.save"
        )
    try:
        with loaded as data:
            return {name: np.array(data[name]) for name in data.files}
    except (ValueError, OSError, EOFError, zipfile.BadZipFile) as error:
        raise ModelFormatError(
            f"{path}: a damaged or truncated .npz archive ({type(error).__name__}: {error})"
        ) from None


def _sigmoid(z: FloatArray) -> FloatArray:
    # 0.5 (1 + tanh(z/2)) is the overflow-free logistic function.
    return 0.5 * (1.0 + np.tanh(0.5 * z))


def shipped_model_names() -> list[str]:
    """Names of the ``.npz`` models shipped in ``ltv_lstm_mpc/data``
    (:func:`ltv_lstm_mpc.shipped_models`)."""
    from importlib import resources

    folder = resources.files("ltv_lstm_mpc") / "data"
    return sorted(entry.name for entry in folder.iterdir() if entry.name.endswith(".npz"))


def missing_model(path: str | Path) -> ModelFileNotFoundError:
    """The error for a model that is neither a file at ``path`` nor a shipped model: it
    names the path looked at (absolute) and the shipped models."""
    absolute = Path(path).expanduser().absolute()
    return ModelFileNotFoundError(
        f"no model file {str(path)!r} (looked at {absolute}) and no shipped model of that "
        f"name; shipped models: {', '.join(shipped_model_names())}"
    )


@dataclass(frozen=True)
class Normalization:
    r"""Affine per-channel maps between physical and normalized signals (paper notes 1).

    A physical signal :math:`v_\phi` in ``[v_phi_min, v_phi_max]`` maps to
    :math:`v = 2 (v_\phi - v_{\phi,min}) / (v_{\phi,max} - v_{\phi,min}) - 1 \in [-1, 1]`.

    Attributes
    ----------
    u_phi_min, u_phi_max : ndarray, shape (m,)
        Physical input range used for normalization (training data min/max).
    y_phi_min, y_phi_max : ndarray, shape (p,)
        Physical output range used for normalization (training data min/max).
    """

    u_phi_min: FloatArray
    u_phi_max: FloatArray
    y_phi_min: FloatArray
    y_phi_max: FloatArray

    def __post_init__(self) -> None:
        for name in _NORMALIZATION_NAMES:
            real = real_array(name, getattr(self, name))
            value = np.atleast_1d(np.array(real, dtype=np.float64))
            if value.ndim != 1:
                raise DimensionError(f"{name} must be a 1-D array, got shape {value.shape}")
            if not np.all(np.isfinite(value)):
                raise InvalidValueError(f"{name} contains NaN or inf")
            value.setflags(write=False)
            object.__setattr__(self, name, value)
        for low, high in (("u_phi_min", "u_phi_max"), ("y_phi_min", "y_phi_max")):
            lo, hi = getattr(self, low), getattr(self, high)
            if lo.shape != hi.shape:
                raise DimensionError(f"{low} has shape {lo.shape} but {high} has shape {hi.shape}")
            if np.any(hi <= lo):
                raise InvalidValueError(
                    f"{high} must be strictly greater than {low} in every channel; got "
                    f"{low}={lo.tolist()}, {high}={hi.tolist()}"
                )

    @property
    def u_scale(self) -> FloatArray:
        """Physical units per normalized unit of input, (u_phi_max - u_phi_min) / 2."""
        return 0.5 * (self.u_phi_max - self.u_phi_min)

    @property
    def y_scale(self) -> FloatArray:
        """Physical units per normalized unit of output, (y_phi_max - y_phi_min) / 2."""
        return 0.5 * (self.y_phi_max - self.y_phi_min)

    def normalize_u(self, u_phi: ArrayLike) -> FloatArray:
        """Physical input -> normalized input."""
        return (np.asarray(u_phi, dtype=np.float64) - self.u_phi_min) / self.u_scale - 1.0

    def denormalize_u(self, u: ArrayLike) -> FloatArray:
        """Normalized input -> physical input."""
        return (np.asarray(u, dtype=np.float64) + 1.0) * self.u_scale + self.u_phi_min

    def normalize_y(self, y_phi: ArrayLike) -> FloatArray:
        """Physical output -> normalized output."""
        return (np.asarray(y_phi, dtype=np.float64) - self.y_phi_min) / self.y_scale - 1.0

    def denormalize_y(self, y: ArrayLike) -> FloatArray:
        """Normalized output -> physical output."""
        return (np.asarray(y, dtype=np.float64) + 1.0) * self.y_scale + self.y_phi_min


def metadata_arrays(
    normalization: Normalization | None = None,
    y_phi_constraint: tuple[ArrayLike, ArrayLike] | None = None,
    Ts: float | None = None,
) -> dict[str, Any]:
    """The file-format arrays (:meth:`LSTMModel.to_arrays` names) of the metadata given:
    what replaces a file's own where a loader or ``convert`` is given them."""
    arrays: dict[str, Any] = {}
    if normalization is not None:
        for name in _NORMALIZATION_NAMES:
            arrays[name] = np.array(getattr(normalization, name))
    if y_phi_constraint is not None:
        for name, value in zip(_CONSTRAINT_NAMES, y_phi_constraint, strict=True):
            arrays[name] = np.atleast_1d(np.asarray(value, dtype=np.float64))
    if Ts is not None:
        arrays[_TS_NAME] = np.array(Ts, dtype=np.float64)
    return arrays


class LSTMModel:
    r"""Single-layer LSTM network as a discrete-time state-space model, eq. (lstm).

    .. math::

        x_{k+1} = f(x_k, u_k), \qquad \xi_k = g(x_k) = W_y h_k + b_y,
        \qquad x = [c; h] \in \mathbb{R}^{2n}

    Parameters
    ----------
    W_f, W_i, W_o, W_c : array_like, shape (n, m)
        Input weights of the forget, input, output gates and of the cell candidate.
    U_f, U_i, U_o, U_c : array_like, shape (n, n)
        Recurrent weights.
    b_f, b_i, b_o, b_c : array_like, shape (n,)
        Biases.
    W_y : array_like, shape (p, n)
        Output weights of eq. (y_lstm).
    b_y : array_like, shape (p,)
        Output bias.
    normalization : Normalization, optional
        Physical <-> normalized maps (paper notes 1). Required by the ``*_phi`` helpers.
    y_phi_constraint : (low, high), optional
        Output constraint :math:`\mathcal Y_\phi` in physical units, each of shape (p,)
        (the shipped pH models: [6, 9] pH). The MPC uses it when its config gives no
        ``y_min/y_max``; stored in the file as ``y_phi_constraint_min/max``.
    Ts : float (or a one-element array), optional
        Sampling time of the model in seconds (the period of the data it was identified
        on); stored in the file as the scalar ``Ts``. None: not stated.

    Raises
    ------
    DimensionError
        An array has the wrong shape (the message names it and the expected shape).
    InvalidValueError
        An array contains NaN or inf.

    Notes
    -----
    Methods accept a single point (``x`` of shape (2n,), ``u`` of shape (m,)) or a
    batch (leading dimensions broadcast), so a whole horizon is evaluated in one
    numpy pass (PERF-NOTES: batched linearization is 4-20x faster than a loop).
    """

    def __init__(
        self,
        *,
        W_f: ArrayLike,
        U_f: ArrayLike,
        b_f: ArrayLike,
        W_i: ArrayLike,
        U_i: ArrayLike,
        b_i: ArrayLike,
        W_o: ArrayLike,
        U_o: ArrayLike,
        b_o: ArrayLike,
        W_c: ArrayLike,
        U_c: ArrayLike,
        b_c: ArrayLike,
        W_y: ArrayLike,
        b_y: ArrayLike,
        normalization: Normalization | None = None,
        y_phi_constraint: tuple[ArrayLike, ArrayLike] | None = None,
        Ts: ArrayLike | None = None,
    ) -> None:
        U_f_arr = np.asarray(real_array("U_f", U_f), dtype=np.float64)
        W_f_arr = np.asarray(real_array("W_f", W_f), dtype=np.float64)
        W_y_arr = np.asarray(real_array("W_y", W_y), dtype=np.float64)
        if U_f_arr.ndim != 2 or U_f_arr.shape[0] != U_f_arr.shape[1]:
            raise DimensionError(f"U_f must be a square (n, n) matrix, got shape {U_f_arr.shape}")
        n = U_f_arr.shape[0]
        if W_f_arr.ndim != 2:
            raise DimensionError(f"W_f must be an (n, m) matrix, got shape {W_f_arr.shape}")
        m = W_f_arr.shape[1]
        if W_y_arr.ndim != 2:
            raise DimensionError(f"W_y must be a (p, n) matrix, got shape {W_y_arr.shape}")
        p = W_y_arr.shape[0]
        if n < 1 or m < 1 or p < 1:
            raise DimensionError(f"need n, m, p >= 1, got n={n}, m={m}, p={p}")
        self.n, self.m, self.p = n, m, p
        given = dict(
            W_f=W_f, U_f=U_f, b_f=b_f, W_i=W_i, U_i=U_i, b_i=b_i,
            W_o=W_o, U_o=U_o, b_o=b_o, W_c=W_c, U_c=U_c, b_c=b_c,
            W_y=W_y, b_y=b_y,
        )  # fmt: skip
        expected = {
            "W": (n, m),
            "U": (n, n),
            "b": (n,),
        }
        weights: dict[str, FloatArray] = {}
        for name, value in given.items():
            if name == "W_y":
                shape: tuple[int, ...] = (p, n)
            elif name == "b_y":
                shape = (p,)
            else:
                shape = expected[name[0]]
            weights[name] = _as_finite_array(name, value, shape)
        self.W_f, self.U_f, self.b_f = weights["W_f"], weights["U_f"], weights["b_f"]
        self.W_i, self.U_i, self.b_i = weights["W_i"], weights["U_i"], weights["b_i"]
        self.W_o, self.U_o, self.b_o = weights["W_o"], weights["U_o"], weights["b_o"]
        self.W_c, self.U_c, self.b_c = weights["W_c"], weights["U_c"], weights["b_c"]
        self.W_y, self.b_y = weights["W_y"], weights["b_y"]
        if normalization is not None:
            if normalization.u_phi_min.shape != (m,):
                raise DimensionError(
                    f"normalization u_phi_min has shape {normalization.u_phi_min.shape}, "
                    f"expected ({m},) for a model with m={m} inputs"
                )
            if normalization.y_phi_min.shape != (p,):
                raise DimensionError(
                    f"normalization y_phi_min has shape {normalization.y_phi_min.shape}, "
                    f"expected ({p},) for a model with p={p} outputs"
                )
        self.normalization = normalization
        #: Output constraint :math:`\mathcal Y_\phi` (physical units, (p,) each), or None.
        self.y_phi_constraint: tuple[FloatArray, FloatArray] | None = None
        if y_phi_constraint is not None:
            low, high = (
                _as_finite_array(name, np.atleast_1d(value), (p,))
                for name, value in zip(_CONSTRAINT_NAMES, y_phi_constraint, strict=True)
            )
            if not np.all(low < high):
                raise InvalidValueError(
                    f"y_phi_constraint_min {low.tolist()} must be below "
                    f"y_phi_constraint_max {high.tolist()} on every output"
                )
            self.y_phi_constraint = (low, high)
        #: Sampling time in seconds, or None when the model does not state it.
        self.Ts: float | None = None
        if Ts is not None:
            ts = np.asarray(real_array("Ts", Ts), dtype=np.float64)
            if ts.size != 1 or not (np.isfinite(ts).all() and float(ts.reshape(-1)[0]) > 0):
                raise InvalidValueError(
                    f"Ts (sampling time, s) must be one positive finite number, got {Ts!r}"
                )
            self.Ts = float(ts.reshape(-1)[0])
        # Stacked gate weights, order (f, i, o, c): one matmul per step instead of four.
        self._W_gates = np.vstack([self.W_f, self.W_i, self.W_o, self.W_c])
        self._U_gates = np.vstack([self.U_f, self.U_i, self.U_o, self.U_c])
        self._b_gates = np.concatenate([self.b_f, self.b_i, self.b_o, self.b_c])
        #: The one implementation of eq. (lstm) and eq. (jacobian) (see :mod:`.kernel`).
        self.kernel = LSTMKernel(self)

    # ------------------------------------------------------------------ basics
    @property
    def state_dim(self) -> int:
        """Dimension 2n of the state x = [c; h]."""
        return 2 * self.n

    def weights(self) -> dict[str, FloatArray]:
        """All weights of eq. (lstm) by their file-format names (copies)."""
        return {name: np.array(getattr(self, name)) for name in WEIGHT_NAMES}

    def require_square(self) -> None:
        """Raise :class:`DimensionError` unless m = p (Assumption 1, needed for offset-free)."""
        if self.m != self.p:
            raise DimensionError(
                f"the offset-free scheme needs as many inputs as outputs (Assumption 1), but this "
                f"model has m={self.m} inputs and p={self.p} outputs; select p of the inputs for "
                "control and keep the others constant"
            )

    def split_state(self, x: ArrayLike) -> tuple[FloatArray, FloatArray]:
        """Return ``(c, h)`` views of a state (or batch of states) ``x = [c; h]``."""
        x_arr = self._check_state(x)
        return x_arr[..., : self.n], x_arr[..., self.n :]

    def _check_state(self, x: ArrayLike, name: str = "x") -> FloatArray:
        """A state (or batch) given to a public method: real, finite, last axis 2n."""
        x_arr = finite_array(name, x)
        if x_arr.ndim == 0 or x_arr.shape[-1] != 2 * self.n:
            raise DimensionError(
                f"{name} has shape {x_arr.shape}, expected (..., {2 * self.n}) = [c; h] "
                f"with n={self.n}"
            )
        return x_arr

    def _check_input(self, u: ArrayLike, name: str = "u") -> FloatArray:
        """An input (or batch) given to a public method: real, finite, last axis m."""
        u_arr = finite_array(name, u)
        if u_arr.ndim == 0 and self.m == 1:
            u_arr = u_arr.reshape(1)
        if u_arr.ndim == 0 or u_arr.shape[-1] != self.m:
            raise DimensionError(f"{name} has shape {u_arr.shape}, expected (..., {self.m})")
        return u_arr

    # ---------------------------------------------------------------- dynamics
    def _pairs(self, x_arr: FloatArray, u_arr: FloatArray) -> tuple[tuple[int, ...], Any, Any]:
        """Broadcast (x, u) batches to flat (K, 2n), (K, m) arrays."""
        try:
            batch = np.broadcast_shapes(x_arr.shape[:-1], u_arr.shape[:-1])
        except ValueError:
            raise DimensionError(
                f"x has shape {x_arr.shape} and u has shape {u_arr.shape}: their batch shapes "
                f"{x_arr.shape[:-1]} and {u_arr.shape[:-1]} do not broadcast; give one u per "
                "x (or one u for every x)"
            ) from None
        xs = np.broadcast_to(x_arr, (*batch, 2 * self.n)).reshape(-1, 2 * self.n)
        us = np.broadcast_to(u_arr, (*batch, self.m)).reshape(-1, self.m)
        return batch, xs, us

    def step(self, x: ArrayLike, u: ArrayLike) -> FloatArray:
        """State update :math:`x_{k+1} = f(x_k, u_k)` of eq. (lstm); batches broadcast.

        Evaluated by the one kernel :class:`~ltv_lstm_mpc.lstm.kernel.LSTMKernel`.
        """
        x_arr = self._check_state(x)
        u_arr = self._check_input(u)
        if x_arr.ndim == 1 and u_arr.ndim == 1:
            return self.kernel.step(x_arr, u_arr)
        batch, xs, us = self._pairs(x_arr, u_arr)
        traj = self.kernel.pairs(xs, us, jacobians=False)
        return np.array(traj.pair_next).reshape(*batch, 2 * self.n)  # type: ignore[attr-defined]

    def output(self, x: ArrayLike) -> FloatArray:
        r"""Output :math:`\xi_k = g(x_k) = W_y h_k + b_y`, eq. (y_lstm)."""
        x_arr = self._check_state(x)
        return x_arr[..., self.n :] @ self.W_y.T + self.b_y

    def simulate(self, x0: ArrayLike, u_seq: ArrayLike) -> tuple[FloatArray, FloatArray]:
        r"""Simulate eq. (lstm) from ``x0`` under the inputs ``u_seq``.

        Parameters
        ----------
        x0 : array_like, shape (2n,)
            Initial state :math:`x_0`.
        u_seq : array_like, shape (T, m)
            Inputs :math:`u_0, \dots, u_{T-1}` (shape (T,) accepted when m = 1).

        Returns
        -------
        x : ndarray, shape (T + 1, 2n)
            States :math:`x_0, \dots, x_T`.
        y : ndarray, shape (T + 1, p)
            Outputs :math:`\xi_k = g(x_k)` for k = 0..T. The output aligned with input
            :math:`u_k` is ``y[k]`` (no feed-through): ``y[1:]`` is the prediction of the
            next output.
        """
        x_current = self._check_state(x0, "x0")
        if x_current.shape != (2 * self.n,):
            raise DimensionError(f"x0 has shape {x_current.shape}, expected ({2 * self.n},)")
        u_arr = finite_array("u_seq", u_seq)
        if u_arr.ndim == 1 and self.m == 1:
            u_arr = u_arr[:, None]
        if u_arr.ndim != 2 or u_arr.shape[1] != self.m or u_arr.shape[0] == 0:
            raise DimensionError(
                f"u_seq has shape {u_arr.shape}, expected (T, {self.m}) with T >= 1"
            )
        states = self.kernel.simulate(x_current, u_arr)
        return states, self.output(states)

    def jacobians(self, x: ArrayLike, u: ArrayLike) -> tuple[FloatArray, FloatArray]:
        r"""Analytic Jacobians :math:`A = \partial f/\partial x`, :math:`B = \partial f/\partial u`.

        Parameters
        ----------
        x : array_like, shape (..., 2n)
        u : array_like, shape (..., m)

        Returns
        -------
        A : ndarray, shape (..., 2n, 2n)
        B : ndarray, shape (..., 2n, m)
        """
        _, A, B = self.step_and_jacobians(x, u)
        return A, B

    def step_and_jacobians(
        self, x: ArrayLike, u: ArrayLike
    ) -> tuple[FloatArray, FloatArray, FloatArray]:
        """Next state and both Jacobians in one pass (the RTI linearization kernel).

        Returns
        -------
        x_next : ndarray, shape (..., 2n)
        A : ndarray, shape (..., 2n, 2n)
        B : ndarray, shape (..., 2n, m)
        """
        return self.step_and_jacobians_arrays(self._check_state(x), self._check_input(u))

    def step_and_jacobians_arrays(
        self, x_arr: FloatArray, u_arr: FloatArray
    ) -> tuple[FloatArray, FloatArray, FloatArray]:
        """:meth:`step_and_jacobians` of arrays already checked (float64, the right
        shapes; the library's own loops: nothing is checked here)."""
        batch, xs, us = self._pairs(x_arr, u_arr)
        traj = self.kernel.pairs(xs, us, jacobians=True)
        n2, K = 2 * self.n, xs.shape[0]
        x_next = np.array(traj.pair_next).reshape(*batch, n2)  # type: ignore[attr-defined]
        A = np.array(traj.A[:K]).reshape(*batch, n2, n2)
        B = np.array(traj.B[:K]).reshape(*batch, n2, self.m)
        return x_next, A, B

    def output_jacobian(self) -> FloatArray:
        r""":math:`\partial g / \partial x = [0_{p,n}\; W_y]`, shape (p, 2n)."""
        return np.hstack([np.zeros((self.p, self.n)), self.W_y])

    def equilibrium(
        self,
        u: ArrayLike,
        *,
        x0: ArrayLike | None = None,
        tol: float = 1e-12,
        max_iter: int = 10_000,
    ) -> FloatArray:
        r"""Equilibrium :math:`x^* = f(x^*, u)` for a constant input ``u`` (Lemma 3).

        Unique for a delta-ISS model (Lemma 3). Computed by fixed-point iteration
        (which converges for a delta-ISS model) polished with Newton steps on
        :math:`f(x, u) - x = 0`.

        Raises
        ------
        LtvMpcError
            If neither iteration converges to ``tol`` (a model that is not delta-ISS
            may have no unique equilibrium).
        """
        u_arr = self._check_input(u)
        if u_arr.shape != (self.m,):
            raise DimensionError(f"u has shape {u_arr.shape}, expected ({self.m},)")
        x = np.zeros(2 * self.n) if x0 is None else self._check_state(x0, "x0").copy()
        if x.shape != (2 * self.n,):
            raise DimensionError(f"x0 has shape {x.shape}, expected ({2 * self.n},)")
        expect_real("tol", tol, low=0.0, low_open=True)
        max_iter = expect_int("max_iter", max_iter, minimum=1)
        eye = np.eye(2 * self.n)
        for _ in range(max_iter):
            x_next, A, _ = self.step_and_jacobians_arrays(x, u_arr)
            residual = x_next - x
            if np.max(np.abs(residual)) < tol:
                return x_next
            # Newton step when it reduces the residual, else a fixed-point step.
            try:
                newton = x - np.linalg.solve(A - eye, residual)
            except np.linalg.LinAlgError:
                newton = x_next
            if np.max(np.abs(self.kernel.step(newton, u_arr) - newton)) < np.max(np.abs(residual)):
                x = newton
            else:
                x = x_next
        raise LtvMpcError(
            f"equilibrium for u={u_arr.tolist()} did not converge in {max_iter} iterations "
            f"(last residual {np.max(np.abs(residual)):.3e}); is the model delta-ISS?"
        )

    # ------------------------------------------------------- physical signals
    def _require_normalization(self) -> Normalization:
        if self.normalization is None:
            raise LtvMpcError(
                "this model has no normalization (u_phi_min/u_phi_max/y_phi_min/y_phi_max); "
                "construct it with normalization=Normalization(...) or save them in the .npz"
            )
        return self.normalization

    def normalize_u(self, u_phi: ArrayLike) -> FloatArray:
        """Physical input u_phi -> normalized input u (paper notes 1)."""
        return self._require_normalization().normalize_u(u_phi)

    def denormalize_u(self, u: ArrayLike) -> FloatArray:
        """Normalized input u -> physical input u_phi (paper notes 1)."""
        return self._require_normalization().denormalize_u(u)

    def normalize_y(self, y_phi: ArrayLike) -> FloatArray:
        """Physical output y_phi -> normalized output y (paper notes 1)."""
        return self._require_normalization().normalize_y(y_phi)

    def denormalize_y(self, y: ArrayLike) -> FloatArray:
        """Normalized output y -> physical output y_phi (paper notes 1)."""
        return self._require_normalization().denormalize_y(y)

    # ----------------------------------------------------------------- file IO
    @classmethod
    def from_arrays(cls, arrays: Mapping[str, Any]) -> LSTMModel:
        """Build a model from a mapping with the file-format names (see :meth:`load`)."""
        missing = [name for name in WEIGHT_NAMES if name not in arrays]
        if missing:
            raise ModelFormatError(
                f"missing weight array(s) {missing}; a model needs exactly {list(WEIGHT_NAMES)} "
                f"(optionally {list(_NORMALIZATION_NAMES)})"
            )
        present_norm = [name for name in _NORMALIZATION_NAMES if name in arrays]
        optional = (*_NORMALIZATION_NAMES, *_CONSTRAINT_NAMES, _TS_NAME)
        unknown = sorted(set(arrays) - set(WEIGHT_NAMES) - set(optional))
        if unknown:
            raise ModelFormatError(
                f"unexpected array(s) {unknown}; allowed names are {list(WEIGHT_NAMES)} "
                f"and {list(optional)}"
            )
        present_constraint = [name for name in _CONSTRAINT_NAMES if name in arrays]
        if len(present_constraint) == 1:
            raise ModelFormatError(
                f"output constraint is incomplete: only {present_constraint} (give both of "
                f"{list(_CONSTRAINT_NAMES)} or none)"
            )
        constraint = (
            (arrays[_CONSTRAINT_NAMES[0]], arrays[_CONSTRAINT_NAMES[1]])
            if present_constraint
            else None
        )
        normalization = None
        if present_norm:
            if len(present_norm) != len(_NORMALIZATION_NAMES):
                absent = sorted(set(_NORMALIZATION_NAMES) - set(present_norm))
                raise ModelFormatError(
                    f"normalization is incomplete: {absent} missing (give all four of "
                    f"{list(_NORMALIZATION_NAMES)} or none)"
                )
            normalization = Normalization(*(arrays[name] for name in _NORMALIZATION_NAMES))
        return cls(
            **{name: arrays[name] for name in WEIGHT_NAMES},
            normalization=normalization,
            y_phi_constraint=constraint,
            Ts=arrays.get(_TS_NAME),
        )

    @classmethod
    def load(cls, path: str | Path, *, Ts: float | None = None) -> LSTMModel:
        r"""Load a model from an ``.npz`` file.

        The file holds float arrays named exactly ``W_f, U_f, b_f, W_i, U_i, b_i, W_o,
        U_o, b_o, W_c, U_c, b_c, W_y, b_y`` (shapes W_* (n, m), U_* (n, n), b_* (n,),
        W_y (p, n), b_y (p,)) and optionally ``u_phi_min, u_phi_max`` (m,) and
        ``y_phi_min, y_phi_max`` (p,) (the normalization), and
        ``y_phi_constraint_min, y_phi_constraint_max`` (p,) (the output constraint
        :math:`\mathcal Y_\phi` in physical units, used by the MPC when its config gives
        no ``y_min/y_max``) and the scalar ``Ts`` (sampling time, s). Files without the
        optional arrays load as before.

        Parameters
        ----------
        path : str or Path
        Ts : float, optional
            Sampling time (s) for a file that states none (a file that states another one
            is refused). A file without ``Ts`` and no ``Ts`` given loads with a warning:
            ``simulate`` can then not compare the model's sampling time with the plant's.
            Add it once with ``model = LSTMModel.load(path, Ts=10.0); model.save(path)``.
        """
        path = Path(path)
        if not path.exists():
            raise missing_model(path)
        if path.is_dir():
            raise ModelFormatError(f"{path} is a folder, not a model file (.npz)")
        arrays = _read_npz(path)
        if Ts is not None:
            stated = arrays.get(_TS_NAME)
            if stated is not None and not np.allclose(stated, Ts, rtol=1e-9, atol=0.0):
                raise ModelFormatError(
                    f"{path} states Ts = {float(np.asarray(stated).reshape(-1)[0])} s, but "
                    f"Ts = {Ts} was given: drop the argument, or re-save the model with the "
                    "sampling time it was identified at"
                )
            arrays[_TS_NAME] = Ts
        try:
            model = cls.from_arrays(arrays)
        except (ModelFormatError, DimensionError, InvalidValueError) as error:
            raise ModelFormatError(f"{path}: {error}") from None
        if model.Ts is None:
            warn_at_caller(
                f"model file {path} states no sampling time Ts: the closed loop cannot check "
                "it against the plant's. Add it once with "
                f"LSTMModel.load({str(path)!r}, Ts=<seconds>).save({str(path)!r})",
                UserWarning,
            )
        return model

    def to_arrays(self) -> dict[str, FloatArray]:
        """All arrays of the file format (weights and, if present, normalization, output
        constraint and Ts)."""
        arrays: dict[str, FloatArray] = self.weights()
        arrays.update(metadata_arrays(self.normalization, self.y_phi_constraint, self.Ts))
        return arrays

    def output_constraint(self) -> tuple[FloatArray, FloatArray] | None:
        """The stored output constraint in normalized units (paper notes 1), or None."""
        if self.y_phi_constraint is None:
            return None
        low, high = self.y_phi_constraint
        if self.normalization is None:  # the model works in physical units
            return low.copy(), high.copy()
        return self.normalize_y(low), self.normalize_y(high)

    def save(self, path: str | Path) -> Path:
        """Save to an ``.npz`` file in the documented format; returns the path written."""
        path = Path(path)
        if path.suffix != ".npz":
            path = path.with_suffix(".npz")
        path.parent.mkdir(parents=True, exist_ok=True)
        np.savez(path, **self.to_arrays())  # type: ignore[arg-type]
        return path

    @classmethod
    def from_torch_state_dict(
        cls,
        state_dict: Mapping[str, Any],
        *,
        normalization: Normalization | None = None,
        y_phi_constraint: tuple[ArrayLike, ArrayLike] | None = None,
        Ts: float | None = None,
    ) -> LSTMModel:
        """Build a model from a single-layer ``torch.nn.LSTM`` + ``torch.nn.Linear`` state dict.

        The LSTM keys end in ``weight_ih_l0`` (4n, m), ``weight_hh_l0`` (4n, n),
        ``bias_ih_l0``, ``bias_hh_l0`` (4n,), with gates stacked in torch's order
        (i, f, g, o); the Linear keys end in ``weight`` (p, n) and ``bias`` (p,).
        Values may be torch tensors or arrays; torch is not imported here.

        Note that a torch LSTM output after reading :math:`u_k` is :math:`h_{k+1}`, so
        its output sequence is this model's output shifted by one step (paper notes 1).
        """

        def to_numpy(value: Any) -> FloatArray:
            if hasattr(value, "detach"):
                value = value.detach().cpu().numpy()
            return np.asarray(value, dtype=np.float64)

        def find(suffix: str, exclude: tuple[str, ...] = ()) -> tuple[str, FloatArray]:
            keys = [
                key
                for key in state_dict
                if key.endswith(suffix) and not any(e in key for e in exclude)
            ]
            if len(keys) != 1:
                raise ModelFormatError(
                    f"expected exactly one state-dict key ending in '{suffix}', found {keys}; "
                    f"keys present: {sorted(state_dict)}"
                )
            return keys[0], to_numpy(state_dict[keys[0]])

        for key in state_dict:
            if "_l1" in key or "_reverse" in key or "weight_hr" in key:
                raise ModelFormatError(
                    f"state-dict key '{key}' shows a multi-layer, bidirectional or projected "
                    "LSTM; only a single-layer unidirectional LSTM without proj_size is supported"
                )
        _, w_ih = find("weight_ih_l0")
        _, w_hh = find("weight_hh_l0")
        _, b_ih = find("bias_ih_l0")
        _, b_hh = find("bias_hh_l0")
        lstm_keys = ("weight_ih_l0", "weight_hh_l0", "bias_ih_l0", "bias_hh_l0")
        _, w_y = find("weight", exclude=lstm_keys)
        _, b_y = find("bias", exclude=lstm_keys)
        if w_ih.ndim != 2 or w_ih.shape[0] % 4 != 0:
            raise DimensionError(f"weight_ih_l0 has shape {w_ih.shape}, expected (4n, m)")
        n = w_ih.shape[0] // 4
        if w_hh.shape != (4 * n, n):
            raise DimensionError(f"weight_hh_l0 has shape {w_hh.shape}, expected ({4 * n}, {n})")
        bias = b_ih + b_hh
        gates = {"i": slice(0, n), "f": slice(n, 2 * n), "c": slice(2 * n, 3 * n)}
        gates["o"] = slice(3 * n, 4 * n)
        arrays: dict[str, FloatArray] = {"W_y": w_y, "b_y": b_y}
        for gate, rows in gates.items():
            arrays[f"W_{gate}"] = w_ih[rows]
            arrays[f"U_{gate}"] = w_hh[rows]
            arrays[f"b_{gate}"] = bias[rows]
        return cls(**arrays, normalization=normalization, y_phi_constraint=y_phi_constraint, Ts=Ts)

    @classmethod
    def from_onnx(
        cls,
        source: str | Path | Any,
        *,
        normalization: Normalization | None = None,
        y_phi_constraint: tuple[ArrayLike, ArrayLike] | None = None,
        Ts: float | None = None,
    ) -> LSTMModel:
        """Read the model from an ONNX graph holding one ``LSTM`` operator and a linear
        output layer (:func:`~ltv_lstm_mpc.lstm.onnx_model.read_onnx`: ONNX's gate order
        (i, o, f, c) and split biases mapped onto eq. (lstm); peepholes, clipping, other
        activations, several layers and output activations refused by name).
        ``normalization``, ``y_phi_constraint`` and ``Ts`` not given are read from the
        graph's ``metadata_props``, else left unset (never guessed)."""
        from ltv_lstm_mpc.lstm.onnx_model import read_onnx

        arrays = read_onnx(source)
        arrays.update(metadata_arrays(normalization, y_phi_constraint, Ts))
        return cls.from_arrays(arrays)

    @classmethod
    def from_keras(
        cls,
        source: str | Path | Any,
        *,
        normalization: Normalization | None = None,
        y_phi_constraint: tuple[ArrayLike, ArrayLike] | None = None,
        Ts: float | None = None,
    ) -> LSTMModel:
        """Read the model from a Keras 3 model (or a saved ``.keras`` file) with one
        ``LSTM`` layer and a linear ``Dense`` output layer
        (:func:`~ltv_lstm_mpc.lstm.keras_model.read_keras`: Keras' gate order (i, f, c, o)
        mapped onto eq. (lstm); ``hard_sigmoid``, other activations, ``go_backwards``,
        bidirectional or stacked layers and output activations refused by name)."""
        from ltv_lstm_mpc.lstm.keras_model import read_keras

        arrays: dict[str, Any] = dict(read_keras(source))
        arrays.update(metadata_arrays(normalization, y_phi_constraint, Ts))
        return cls.from_arrays(arrays)

    def __repr__(self) -> str:
        norm = "with" if self.normalization is not None else "without"
        return f"LSTMModel(n={self.n}, m={self.m}, p={self.p}, {norm} normalization)"


#: How to get a model, appended to the error when something else is given.
MODEL_HINT = (
    "load one with ltv_lstm_mpc.load_model(name_or_path), e.g. load_model('ph_lstm_n5.npz'), "
    "or build it with LSTMModel(...)"
)


def require_model(value: Any, name: str = "model") -> LSTMModel:
    """``value`` when it is an :class:`LSTMModel`, else
    :class:`~ltv_lstm_mpc.ArgumentTypeError` saying how to get one (a file name
    given where the model is expected is the usual slip)."""
    return expect_instance(name, value, LSTMModel, MODEL_HINT, expected="an LSTMModel")
