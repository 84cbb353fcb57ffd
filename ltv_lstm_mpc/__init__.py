"""ltv_lstm_mpc: robust offset-free constrained MPC with LSTM models.

Implements Schimperna & Magni, "Robust offset-free constrained Model Predictive Control
with Long Short-Term Memory Networks": the LSTM model (eq. lstm), its delta-ISS,
incremental-Lyapunov and observer certificates, the observer (eq. lstm_observer), the
reference calculator (eq. reference_calculation) and the constraint tightening of the
robust MPC. The solver layer is :mod:`ltv_lstm_mpc.solvers`.
"""

from __future__ import annotations

__version__ = "0.1.0"

from ltv_lstm_mpc.certificates.certify import Certification, CertificationSettings, certify
from ltv_lstm_mpc.certificates.stability import (
    DeltaISSCertificate,
    IncrementalLyapunovCertificate,
    ObserverCertificate,
    ObserverGains,
    delta_iss_certificate,
    design_observer_gains,
    incremental_lyapunov_certificate,
    observer_certificate,
)
from ltv_lstm_mpc.certificates.tightening import (
    SetpointRateBound,
    TighteningCertificate,
    tightening_certificate,
)
from ltv_lstm_mpc.exceptions import (
    ArgumentTypeError,
    DimensionError,
    EmptySetpointIntervalError,
    InvalidValueError,
    LtvMpcError,
    NotDeltaISSError,
    ObserverGainError,
    SamplingTimeError,
    SolverError,
    SolverNotFound,
    UnknownPlantError,
    UnreachableSetpointError,
)
from ltv_lstm_mpc.loop.controller import ControllerStep, OffsetFreeController
from ltv_lstm_mpc.loop.observer import Observer
from ltv_lstm_mpc.loop.reference import (
    KBarEstimate,
    ReferenceCalculator,
    ReferenceSolution,
    estimate_K_bar,
)
from ltv_lstm_mpc.loop.simulation import SimulationResult, simulate
from ltv_lstm_mpc.lstm.model import LSTMModel, ModelFormatError, Normalization
from ltv_lstm_mpc.lstm.shipped import load_model, shipped_models, shipped_path
from ltv_lstm_mpc.mpc.config import MPCConfig
from ltv_lstm_mpc.mpc.exact_nmpc import ExactNMPC
from ltv_lstm_mpc.mpc.fhocp import MPCSolution
from ltv_lstm_mpc.mpc.rti import RobustMPC, resolve_transcription
from ltv_lstm_mpc.plants.lstm_plant import LSTMPlant
from ltv_lstm_mpc.plants.ph import PHNeutralizationPlant
from ltv_lstm_mpc.plants.protocol import Plant
from ltv_lstm_mpc.plants.quadtank import QuadrupleTankPlant
from ltv_lstm_mpc.plants.registry import register_plant, registered_plants, resolve_plant
from ltv_lstm_mpc.training.mismatch import DMaxEstimate, estimate_d_max

__all__ = [
    "ArgumentTypeError",
    "Certification",
    "CertificationSettings",
    "ControllerStep",
    "DMaxEstimate",
    "DeltaISSCertificate",
    "DimensionError",
    "EmptySetpointIntervalError",
    "ExactNMPC",
    "IncrementalLyapunovCertificate",
    "InvalidValueError",
    "KBarEstimate",
    "LSTMModel",
    "LSTMPlant",
    "LtvMpcError",
    "MPCConfig",
    "MPCSolution",
    "ModelFormatError",
    "Normalization",
    "NotDeltaISSError",
    "Observer",
    "ObserverCertificate",
    "ObserverGainError",
    "ObserverGains",
    "OffsetFreeController",
    "PHNeutralizationPlant",
    "Plant",
    "QuadrupleTankPlant",
    "ReferenceCalculator",
    "ReferenceSolution",
    "RobustMPC",
    "SamplingTimeError",
    "SetpointRateBound",
    "SimulationResult",
    "SolverError",
    "SolverNotFound",
    "TighteningCertificate",
    "UnknownPlantError",
    "UnreachableSetpointError",
    "__version__",
    "certify",
    "delta_iss_certificate",
    "design_observer_gains",
    "estimate_K_bar",
    "estimate_d_max",
    "incremental_lyapunov_certificate",
    "load_model",
    "observer_certificate",
    "register_plant",
    "registered_plants",
    "resolve_plant",
    "resolve_transcription",
    "shipped_models",
    "shipped_path",
    "simulate",
    "tightening_certificate",
]
