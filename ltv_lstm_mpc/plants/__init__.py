"""Plants for the closed loop (the "Plant" block of Fig. 1 / Fig. 2), physical signals.

Modules
-------
protocol
    :class:`Plant`, the role every plant fills.
ph
    :class:`PHNeutralizationPlant`, the pH-neutralization benchmark (paper Section V).
quadtank
    :class:`QuadrupleTankPlant`, Johansson's quadruple-tank process (two pumps, two levels).
lstm_plant
    :class:`LSTMPlant`, the LSTM model with an additive output disturbance (Fig. 2).
measurement
    :class:`NoisyMeasurement`, Gaussian measurement noise on any of them.
registry
    :func:`register_plant`, :func:`resolve_plant`: plant names (and ``"module:Class"``)
    with their defaults, for the command line, data generation and campaigns.
"""

from ltv_lstm_mpc.plants.lstm_plant import LSTMPlant
from ltv_lstm_mpc.plants.measurement import NoisyMeasurement
from ltv_lstm_mpc.plants.ph import (
    PHNeutralizationPlant,
    PHParameters,
    ph_from_state,
    simulate_ph_batch,
)
from ltv_lstm_mpc.plants.protocol import Plant
from ltv_lstm_mpc.plants.quadtank import (
    QuadrupleTankParameters,
    QuadrupleTankPlant,
    simulate_quadtank_batch,
)
from ltv_lstm_mpc.plants.registry import (
    RegisteredPlant,
    register_plant,
    registered_plants,
    resolve_plant,
)

__all__ = [
    "LSTMPlant",
    "NoisyMeasurement",
    "PHNeutralizationPlant",
    "PHParameters",
    "Plant",
    "QuadrupleTankParameters",
    "QuadrupleTankPlant",
    "RegisteredPlant",
    "ph_from_state",
    "register_plant",
    "registered_plants",
    "resolve_plant",
    "simulate_ph_batch",
    "simulate_quadtank_batch",
]
