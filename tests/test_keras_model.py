"""LSTM models read from Keras 3 (ltv_lstm_mpc/lstm/keras_model.py), checked against
Keras' own predictions (float32) and the ONNX/torch routes' weights."""

from __future__ import annotations

import os

import numpy as np
import pytest

pytest.importorskip("torch")
os.environ.setdefault("KERAS_BACKEND", "torch")
keras = pytest.importorskip("keras")

from ltv_lstm_mpc import LSTMModel, ModelFormatError, certify, load_model  # noqa: E402


def _sequential(*layers):
    return keras.Sequential([keras.Input((None, 1)), *layers])


def _keras_from(model):
    """A Keras network holding ``model``'s weights (Keras' gate order i, f, c, o)."""
    net = _sequential(
        keras.layers.LSTM(model.n, return_sequences=True), keras.layers.Dense(model.p)
    )
    order = "ifco"
    kernel = np.hstack([getattr(model, f"W_{g}").T for g in order])
    recurrent = np.hstack([getattr(model, f"U_{g}").T for g in order])
    bias = np.concatenate([getattr(model, f"b_{g}") for g in order])
    net.layers[0].set_weights([kernel, recurrent, bias])
    net.layers[1].set_weights([model.W_y.T, model.b_y])
    return net


def test_a_keras_model_reads_back_as_eq_lstm(tmp_path) -> None:
    """The shipped pH model through Keras and a saved .keras file: weights to float32
    precision, the open loop over 300 steps equal to Keras' predict, the certificates equal
    to the shipped model's within float32 rounding."""
    shipped = load_model("ph_lstm_n5.npz")
    net = _keras_from(shipped)
    path = tmp_path / "ph.keras"
    net.save(path)
    model = LSTMModel.from_keras(
        path, normalization=shipped.normalization, y_phi_constraint=shipped.y_phi_constraint
    )
    for name in ("W_f", "U_i", "b_o", "W_c", "U_c", "W_y", "b_y"):
        np.testing.assert_allclose(getattr(model, name), getattr(shipped, name), atol=1e-6)
    u = np.random.default_rng(2).uniform(-1, 1, (300, 1))
    reference = np.asarray(net.predict(u[None].astype(np.float32), verbose=0))[0]
    ours = model.simulate(np.zeros(2 * model.n), u)[1][1:]  # Keras' output: y(h_{k+1})
    assert np.max(np.abs(ours - reference)) < 2e-5
    ours_cert, original = certify(model).to_dict(), certify(shipped).to_dict()
    for key in ("rho_A_delta", "rho_s", "rho_o", "L_max", "c_o"):
        assert ours_cert[key] == pytest.approx(original[key], rel=1e-4), key
    assert load_model(path).n == shipped.n  # .keras through load_model


@pytest.mark.parametrize(
    ("layers", "message"),
    [
        (
            [keras.layers.LSTM(3, return_sequences=True, recurrent_activation="hard_sigmoid"),
             keras.layers.Dense(1)],
            "recurrent_activation='hard_sigmoid'",
        ),
        (
            [keras.layers.LSTM(3, return_sequences=True, activation="relu"), keras.layers.Dense(1)],
            "activation='relu'",
        ),
        (
            [keras.layers.LSTM(3, return_sequences=True, go_backwards=True),
             keras.layers.Dense(1)],
            "go_backwards=True",
        ),
        (
            [keras.layers.LSTM(3, return_sequences=True),
             keras.layers.Dense(1, activation="tanh")],
            "Dense layer .* activation='tanh'",
        ),
        (
            [keras.layers.LSTM(3, return_sequences=True),
             keras.layers.LSTM(3, return_sequences=True), keras.layers.Dense(1)],
            "2 LSTM layers",
        ),
        (
            [keras.layers.Bidirectional(keras.layers.LSTM(3, return_sequences=True)),
             keras.layers.Dense(1)],
            r"0 LSTM layers \(layers: \['Bidirectional', 'Dense'\]",
        ),
        (
            [keras.layers.GRU(3, return_sequences=True), keras.layers.Dense(1)],
            r"0 LSTM layers \(layers: \['GRU', 'Dense'\]",
        ),
        (
            [keras.layers.LSTM(3, return_sequences=True), keras.layers.Dense(4),
             keras.layers.Dense(1)],
            r"layers are \['LSTM', 'Dense', 'Dense'\]",
        ),
    ],
)  # fmt: skip
def test_refusals_name_the_layer_or_setting(layers, message) -> None:
    with pytest.raises(ModelFormatError, match=message):
        LSTMModel.from_keras(_sequential(*layers))


def test_dropout_is_the_identity_at_inference() -> None:
    net = _sequential(
        keras.layers.LSTM(3, return_sequences=True),
        keras.layers.Dropout(0.2),
        keras.layers.Dense(1),
    )
    model = LSTMModel.from_keras(net)
    np.testing.assert_allclose(model.W_y, np.asarray(net.layers[2].get_weights()[0]).T)
