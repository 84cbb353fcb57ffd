"""Random LSTM models for the tests (delta-ISS by construction or by rejection)."""

from __future__ import annotations

import numpy as np

from ltv_lstm_mpc.certificates.stability import delta_iss_certificate
from ltv_lstm_mpc.lstm.model import LSTMModel, Normalization


def random_lstm(
    rng: np.random.Generator,
    n: int = 3,
    m: int = 1,
    p: int = 1,
    *,
    scale: float = 0.3,
    forget_bias: float = 0.0,
) -> LSTMModel:
    """An LSTM with Gaussian weights; not necessarily delta-ISS."""
    weights: dict[str, np.ndarray] = {}
    for gate in "fioc":
        weights[f"W_{gate}"] = rng.normal(scale=scale, size=(n, m))
        weights[f"U_{gate}"] = rng.normal(scale=scale / np.sqrt(n), size=(n, n))
        weights[f"b_{gate}"] = rng.normal(scale=scale, size=n)
    weights["b_f"] = weights["b_f"] + forget_bias
    weights["W_y"] = rng.normal(size=(p, n))
    weights["b_y"] = rng.normal(scale=0.1, size=p)
    # no normalization: the output constraint [-1, 1] is in the model's own units
    return LSTMModel(**weights, y_phi_constraint=(-np.ones(p), np.ones(p)))


def random_delta_iss_lstm(
    rng: np.random.Generator,
    n: int = 3,
    m: int = 1,
    p: int = 1,
    *,
    scale: float = 0.3,
    normalization: bool = False,
) -> LSTMModel:
    """A random LSTM with rho(A_delta) < 1 (rejection sampling, shrinking the weights)."""
    for _ in range(100):
        model = random_lstm(rng, n, m, p, scale=scale)
        if delta_iss_certificate(model).rho_A_delta < 0.97:
            break
        scale *= 0.9
    else:  # pragma: no cover - the shrinking makes this unreachable in practice
        raise RuntimeError("could not sample a delta-ISS model")
    if normalization:
        norm = Normalization(
            u_phi_min=np.full(m, 12.5),
            u_phi_max=np.full(m, 17.0),
            y_phi_min=np.full(p, 5.9),
            y_phi_max=np.full(p, 9.1),
        )
        model = LSTMModel(**model.weights(), normalization=norm)
    return model
