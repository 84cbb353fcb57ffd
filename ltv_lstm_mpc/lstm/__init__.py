"""The LSTM prediction model of eq. (lstm): the model class and the shipped model files.

Modules
-------
model
    :class:`LSTMModel` (eq. lstm, batched Jacobians eq. jacobian, equilibria of Lemma 3,
    normalization, ``.npz`` format, torch import) and :class:`Normalization`.
shipped
    :func:`load_model` and the models shipped in ``ltv_lstm_mpc/data``.
"""

from ltv_lstm_mpc.lstm.model import LSTMModel, ModelFormatError, Normalization
from ltv_lstm_mpc.lstm.shipped import load_model, shipped_models, shipped_path

__all__ = [
    "LSTMModel",
    "ModelFormatError",
    "Normalization",
    "load_model",
    "shipped_models",
    "shipped_path",
]
