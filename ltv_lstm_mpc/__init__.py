"""ltv_lstm_mpc: robust offset-free constrained MPC with LSTM models.

Implements Schimperna & Magni, "Robust offset-free constrained Model Predictive Control
with Long Short-Term Memory Networks": the LSTM model (eq. lstm), its delta-ISS,
incremental-Lyapunov and observer certificates, the observer (eq. lstm_observer), the
reference calculator (eq. reference_calculation) and the constraint tightening of the
robust MPC. The solver layer is :mod:`ltv_lstm_mpc.solvers`.

The public names load lazily (PEP 562): ``import ltv_lstm_mpc`` reads no numerical
library; the first use of a name imports its module (numba, scipy and the solvers only then).
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any

__version__ = "0.1.0"

if TYPE_CHECKING:  # the names for type checkers and readers; loaded lazily below
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
        ModelFileNotFoundError,
        NotDeltaISSError,
        NumberTypeError,
        ObserverGainError,
        SamplingTimeError,
        SolverError,
        SolverNotFound,
        UnknownPlantError,
        UnreachableSetpointError,
    )
    from ltv_lstm_mpc.loop.controller import ControllerStep, OffsetFreeController
    from ltv_lstm_mpc.loop.monitor import AssumptionCheck, AssumptionMonitor
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

#: Public name -> the module that defines it (imported at first use).
_LAZY: dict[str, str] = {
    "ArgumentTypeError": "ltv_lstm_mpc.exceptions",
    "AssumptionCheck": "ltv_lstm_mpc.loop.monitor",
    "AssumptionMonitor": "ltv_lstm_mpc.loop.monitor",
    "Certification": "ltv_lstm_mpc.certificates.certify",
    "CertificationSettings": "ltv_lstm_mpc.certificates.certify",
    "ControllerStep": "ltv_lstm_mpc.loop.controller",
    "DMaxEstimate": "ltv_lstm_mpc.training.mismatch",
    "DeltaISSCertificate": "ltv_lstm_mpc.certificates.stability",
    "DimensionError": "ltv_lstm_mpc.exceptions",
    "EmptySetpointIntervalError": "ltv_lstm_mpc.exceptions",
    "ExactNMPC": "ltv_lstm_mpc.mpc.exact_nmpc",
    "IncrementalLyapunovCertificate": "ltv_lstm_mpc.certificates.stability",
    "InvalidValueError": "ltv_lstm_mpc.exceptions",
    "KBarEstimate": "ltv_lstm_mpc.loop.reference",
    "LSTMModel": "ltv_lstm_mpc.lstm.model",
    "LSTMPlant": "ltv_lstm_mpc.plants.lstm_plant",
    "LtvMpcError": "ltv_lstm_mpc.exceptions",
    "MPCConfig": "ltv_lstm_mpc.mpc.config",
    "MPCSolution": "ltv_lstm_mpc.mpc.fhocp",
    "ModelFileNotFoundError": "ltv_lstm_mpc.exceptions",
    "ModelFormatError": "ltv_lstm_mpc.lstm.model",
    "Normalization": "ltv_lstm_mpc.lstm.model",
    "NotDeltaISSError": "ltv_lstm_mpc.exceptions",
    "NumberTypeError": "ltv_lstm_mpc.exceptions",
    "Observer": "ltv_lstm_mpc.loop.observer",
    "ObserverCertificate": "ltv_lstm_mpc.certificates.stability",
    "ObserverGainError": "ltv_lstm_mpc.exceptions",
    "ObserverGains": "ltv_lstm_mpc.certificates.stability",
    "OffsetFreeController": "ltv_lstm_mpc.loop.controller",
    "PHNeutralizationPlant": "ltv_lstm_mpc.plants.ph",
    "Plant": "ltv_lstm_mpc.plants.protocol",
    "QuadrupleTankPlant": "ltv_lstm_mpc.plants.quadtank",
    "ReferenceCalculator": "ltv_lstm_mpc.loop.reference",
    "ReferenceSolution": "ltv_lstm_mpc.loop.reference",
    "RobustMPC": "ltv_lstm_mpc.mpc.rti",
    "SamplingTimeError": "ltv_lstm_mpc.exceptions",
    "SetpointRateBound": "ltv_lstm_mpc.certificates.tightening",
    "SimulationResult": "ltv_lstm_mpc.loop.simulation",
    "SolverError": "ltv_lstm_mpc.exceptions",
    "SolverNotFound": "ltv_lstm_mpc.exceptions",
    "TighteningCertificate": "ltv_lstm_mpc.certificates.tightening",
    "UnknownPlantError": "ltv_lstm_mpc.exceptions",
    "UnreachableSetpointError": "ltv_lstm_mpc.exceptions",
    "certify": "ltv_lstm_mpc.certificates.certify",
    "delta_iss_certificate": "ltv_lstm_mpc.certificates.stability",
    "design_observer_gains": "ltv_lstm_mpc.certificates.stability",
    "estimate_K_bar": "ltv_lstm_mpc.loop.reference",
    "estimate_d_max": "ltv_lstm_mpc.training.mismatch",
    "incremental_lyapunov_certificate": "ltv_lstm_mpc.certificates.stability",
    "load_model": "ltv_lstm_mpc.lstm.shipped",
    "observer_certificate": "ltv_lstm_mpc.certificates.stability",
    "register_plant": "ltv_lstm_mpc.plants.registry",
    "registered_plants": "ltv_lstm_mpc.plants.registry",
    "resolve_plant": "ltv_lstm_mpc.plants.registry",
    "resolve_transcription": "ltv_lstm_mpc.mpc.rti",
    "shipped_models": "ltv_lstm_mpc.lstm.shipped",
    "shipped_path": "ltv_lstm_mpc.lstm.shipped",
    "simulate": "ltv_lstm_mpc.loop.simulation",
    "tightening_certificate": "ltv_lstm_mpc.certificates.tightening",
}

__all__ = [
    "ArgumentTypeError",
    "AssumptionCheck",
    "AssumptionMonitor",
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
    "ModelFileNotFoundError",
    "ModelFormatError",
    "Normalization",
    "NotDeltaISSError",
    "NumberTypeError",
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


def __getattr__(name: str) -> Any:
    """Import the module of a public name at its first use (PEP 562)."""
    module = _LAZY.get(name)
    if module is None:
        raise AttributeError(f"module 'ltv_lstm_mpc' has no attribute {name!r}")
    value = getattr(importlib.import_module(module), name)
    globals()[name] = value  # later lookups skip this function
    return value


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(__all__))
