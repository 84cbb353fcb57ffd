"""Plants for the closed loop (the "Plant" block of Fig. 1 / Fig. 2), physical signals.

Modules
-------
protocol
    :class:`Plant`, the role every plant fills.
ph
    :class:`PHNeutralizationPlant`, the pH-neutralization benchmark (paper Section V).
lstm_plant
    :class:`LSTMPlant`, the LSTM model with an additive output disturbance (Fig. 2).
"""

from ltv_lstm_mpc.plants.lstm_plant import LSTMPlant
from ltv_lstm_mpc.plants.ph import (
    PHNeutralizationPlant,
    PHParameters,
    ph_from_state,
    simulate_ph_batch,
)
from ltv_lstm_mpc.plants.protocol import Plant

__all__ = [
    "LSTMPlant",
    "PHNeutralizationPlant",
    "PHParameters",
    "Plant",
    "ph_from_state",
    "simulate_ph_batch",
]
