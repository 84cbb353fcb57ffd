r"""An LSTM model read from a Keras 3 model: one ``LSTM`` layer and a linear ``Dense``.

Keras stores an ``LSTM`` layer's weights as ``kernel`` (m, 4n), ``recurrent_kernel``
(n, 4n) and ``bias`` (4n,), gates stacked in the order (i, f, c, o); a ``Dense`` layer as
``kernel`` (n, p) and ``bias`` (p,). This module maps them onto eq. (lstm)'s
:math:`W, U, b` per gate and :math:`W_y, b_y`, and refuses by name what the equation does
not have: ``recurrent_activation`` other than ``"sigmoid"`` (Keras 2's default
``"hard_sigmoid"`` changes the dynamics), ``activation`` other than ``"tanh"``,
``go_backwards``, ``Bidirectional`` or stacked LSTM layers, an activation on the output
layer, any other layer (``Dropout`` excepted: the identity at inference). Keras' output
after reading :math:`u_k` is :math:`y(h_{k+1})`, as torch's (paper notes 1).
"""

from __future__ import annotations

import importlib.util
import os
import sys
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from ltv_lstm_mpc.exceptions import ModelFormatError

__all__ = ["read_keras"]

FloatArray = NDArray[np.float64]

#: Layers that are the identity at inference.
_IDENTITY_LAYERS = ("InputLayer", "Dropout")


def _keras() -> Any:
    if (
        "keras" not in sys.modules
        and "KERAS_BACKEND" not in os.environ
        and importlib.util.find_spec("tensorflow") is None
        and importlib.util.find_spec("torch") is not None
    ):
        os.environ["KERAS_BACKEND"] = "torch"  # Keras' default backend is not installed
    try:
        import keras
    except ImportError as error:  # pragma: no cover - depends on the installation
        raise ModelFormatError(
            "reading a Keras model needs keras (3.x) and a backend: pip install "
            "'ltv_lstm_mpc[keras]'"
        ) from error
    return keras


def read_keras(source: str | Path | Any) -> dict[str, FloatArray]:
    """The weights of eq. (lstm) (``W_f`` ... ``b_y``, float64) of a Keras model or a
    saved ``.keras`` file; :meth:`~ltv_lstm_mpc.LSTMModel.from_keras` builds the model.

    Raises
    ------
    ModelFormatError
        A layer or setting eq. (lstm) does not have; the message names it.
    """
    keras = _keras()
    model = source if hasattr(source, "layers") else keras.saving.load_model(str(source))
    layers = [layer for layer in model.layers if type(layer).__name__ not in _IDENTITY_LAYERS]
    kinds = [type(layer).__name__ for layer in layers]
    lstms = [layer for layer in layers if type(layer).__name__ == "LSTM"]
    if len(lstms) != 1:
        raise ModelFormatError(
            f"the Keras model has {len(lstms)} LSTM layers (layers: {kinds}); eq. (lstm) is "
            "one LSTM layer followed by a linear Dense layer"
        )
    if len(layers) != 2 or kinds[0] != "LSTM" or kinds[1] not in ("Dense", "TimeDistributed"):
        raise ModelFormatError(
            f"the Keras model's layers are {kinds}; eq. (lstm) is LSTM then Dense (Dropout "
            "and the input layer aside)"
        )
    lstm, dense = layers
    if type(dense).__name__ == "TimeDistributed":
        dense = dense.layer
        if type(dense).__name__ != "Dense":
            raise ModelFormatError(
                f"TimeDistributed wraps a {type(dense).__name__}; eq. (lstm)'s output layer is "
                "Dense"
            )
    config = lstm.get_config()
    for key, needed in (("recurrent_activation", "sigmoid"), ("activation", "tanh")):
        if config.get(key, needed) != needed:
            raise ModelFormatError(
                f"LSTM layer {lstm.name!r} has {key}={config[key]!r}; eq. (lstm) needs "
                f"{needed!r} (anything else changes the dynamics the certificates describe)"
            )
    if config.get("go_backwards", False):
        raise ModelFormatError(
            f"LSTM layer {lstm.name!r} has go_backwards=True; eq. (lstm) runs forward in time"
        )
    dense_config = dense.get_config()
    if dense_config.get("activation", "linear") != "linear":
        raise ModelFormatError(
            f"Dense layer {dense.name!r} has activation={dense_config['activation']!r}; eq. "
            "(lstm)'s output layer is linear, y = W_y h + b_y"
        )
    weights = [np.asarray(w, dtype=np.float64) for w in lstm.get_weights()]
    kernel, recurrent = weights[0], weights[1]
    n = recurrent.shape[0]
    bias = weights[2] if len(weights) > 2 else np.zeros(4 * n)
    if kernel.shape[1] != 4 * n or recurrent.shape != (n, 4 * n) or bias.shape != (4 * n,):
        raise ModelFormatError(
            f"LSTM layer {lstm.name!r} weights of shapes {[w.shape for w in weights]} are not "
            "kernel (m, 4n), recurrent_kernel (n, 4n), bias (4n,)"
        )
    dense_weights = [np.asarray(w, dtype=np.float64) for w in dense.get_weights()]
    W_y = dense_weights[0].T
    b_y = dense_weights[1] if len(dense_weights) > 1 else np.zeros(W_y.shape[0])
    if W_y.shape[1] != n:
        raise ModelFormatError(
            f"Dense kernel of shape {dense_weights[0].shape} does not fit n = {n}"
        )
    arrays: dict[str, FloatArray] = {"W_y": W_y, "b_y": b_y}
    for k, gate in enumerate("ifco"):  # Keras' gate order
        columns = slice(k * n, (k + 1) * n)
        arrays[f"W_{gate}"] = kernel[:, columns].T
        arrays[f"U_{gate}"] = recurrent[:, columns].T
        arrays[f"b_{gate}"] = bias[columns]
    return arrays
