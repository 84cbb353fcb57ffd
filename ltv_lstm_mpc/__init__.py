"""ltv_lstm_mpc: robust offset-free constrained MPC with LSTM models.

Implements Schimperna & Magni, "Robust offset-free constrained Model Predictive Control
with Long Short-Term Memory Networks": the LSTM model (eq. lstm), its delta-ISS,
incremental-Lyapunov and observer certificates, the observer (eq. lstm_observer), the
reference calculator (eq. reference_calculation) and the constraint tightening of the
robust MPC. The solver layer is :mod:`ltv_lstm_mpc.solvers`.
"""

from __future__ import annotations

__version__ = "0.1.0"

from .certificates import (
    DeltaISSCertificate,
    IncrementalLyapunovCertificate,
    ObserverCertificate,
    ObserverGains,
    delta_iss_certificate,
    design_observer_gains,
    incremental_lyapunov_certificate,
    observer_certificate,
)
from .certify import Certification, CertificationSettings, certify
from .controller import ControllerStep, OffsetFreeController
from .exceptions import (
    DimensionError,
    InvalidValueError,
    LtvMpcError,
    NotDeltaISSError,
    ObserverGainError,
    SolverError,
    SolverNotFound,
    UnreachableSetpointError,
)
from .model import LSTMModel, ModelFormatError, Normalization
from .observer import Observer
from .plants import LSTMPlant, PHNeutralizationPlant, Plant
from .reference import KBarEstimate, ReferenceCalculator, ReferenceSolution, estimate_K_bar
from .rti import MPCConfig, MPCSolution, RobustMPC
from .shipped import load_model, shipped_models, shipped_path
from .simulation import SimulationResult, simulate
from .tightening import SetpointRateBound, TighteningCertificate, tightening_certificate

__all__ = [
    "Certification",
    "CertificationSettings",
    "ControllerStep",
    "DeltaISSCertificate",
    "DimensionError",
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
    "ReferenceCalculator",
    "ReferenceSolution",
    "RobustMPC",
    "SetpointRateBound",
    "SimulationResult",
    "SolverError",
    "SolverNotFound",
    "TighteningCertificate",
    "UnreachableSetpointError",
    "__version__",
    "certify",
    "delta_iss_certificate",
    "design_observer_gains",
    "estimate_K_bar",
    "incremental_lyapunov_certificate",
    "load_model",
    "observer_certificate",
    "shipped_models",
    "shipped_path",
    "simulate",
    "tightening_certificate",
]
