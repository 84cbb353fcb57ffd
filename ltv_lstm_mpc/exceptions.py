"""Exception tree of :mod:`ltv_lstm_mpc`.

Every exception subclasses :class:`LtvMpcError` and, where it makes sense, the
built-in exception a user would expect (``TypeError`` for an argument of the wrong type,
``ValueError`` for bad values, ``ImportError`` for a missing solver), so both
``except LtvMpcError`` and ``except ValueError`` (or ``TypeError``) work.
"""

from __future__ import annotations

__all__ = [
    "ArgumentTypeError",
    "CampaignSpecError",
    "DimensionError",
    "InvalidValueError",
    "LtvMpcError",
    "ModelFileNotFoundError",
    "ModelFormatError",
    "NotDeltaISSError",
    "NumberTypeError",
    "ObserverGainError",
    "SamplingTimeError",
    "SolverError",
    "SolverNotFound",
    "UnknownPlantError",
    "UnreachableSetpointError",
]


class LtvMpcError(Exception):
    """Base class of every error raised by ltv_lstm_mpc."""


class ArgumentTypeError(LtvMpcError, TypeError):
    """An argument has the wrong type (a file name where a model is expected, a dict for a
    configuration, a string for a number, ...); the message names the argument, the type
    given and what is expected. A string where a number or an array of numbers is expected
    (``controller.step("7.0", 7.5)``) raises :class:`NumberTypeError`, which is also an
    :class:`InvalidValueError`; arrays whose entries are not real numbers (booleans,
    complex numbers, string entries) raise :class:`InvalidValueError`."""


class DimensionError(LtvMpcError, ValueError):
    """An array has the wrong shape; the message names the array and the expected shape."""


class InvalidValueError(LtvMpcError, ValueError):
    """A value is out of its admissible range (NaN, inf, negative weight, ...)."""


class NumberTypeError(ArgumentTypeError, InvalidValueError):
    """A string (or bytes) given where a number or an array of numbers is expected, e.g. a
    measurement ``"7.0"``: an :class:`ArgumentTypeError` (a ``TypeError``) and, as the
    other refusals of numeric arguments, an :class:`InvalidValueError` (a ``ValueError``)."""


class NotDeltaISSError(LtvMpcError, ValueError):
    """The LSTM model violates Assumption 2: rho(A_delta) >= 1.

    Attributes
    ----------
    rho_A_delta : float
        Spectral radius of A_delta (eq. delta_iss_matrix).
    r1, r2 : float
        Residuals of Remark 1 (both must be negative for delta-ISS).
    """

    def __init__(self, message: str, *, rho_A_delta: float, r1: float, r2: float) -> None:
        super().__init__(message)
        self.rho_A_delta = rho_A_delta
        self.r1 = r1
        self.r2 = r2


class ObserverGainError(LtvMpcError, ValueError):
    """Observer gains violate Assumption 3: rho(A_d) >= 1."""

    def __init__(self, message: str, *, rho_A_d: float) -> None:
        super().__init__(message)
        self.rho_A_d = rho_A_d


class UnreachableSetpointError(LtvMpcError, ValueError):
    """The reference calculator (eq. reference_calculation) found no admissible equilibrium."""


class EmptySetpointIntervalError(LtvMpcError, ValueError):
    """The admissible set-point interval of Assumption 5 is empty: no set-point is allowed."""


class SamplingTimeError(LtvMpcError, ValueError):
    """The model was identified at another sampling time than the plant runs at."""


class UnknownPlantError(LtvMpcError, ValueError):
    """A plant name is neither registered nor an importable ``"package.module:Class"``."""


class SolverNotFound(LtvMpcError, ImportError):
    """A requested solver backend is not installed; the message lists the installed ones."""


class SolverError(LtvMpcError, RuntimeError):
    """A solver failed in a way the caller asked to be raised rather than recorded."""


class ModelFileNotFoundError(LtvMpcError, FileNotFoundError):
    """No model file at the path given and no shipped model of that name; the message names
    the path looked at and the shipped models."""


class ModelFormatError(LtvMpcError, ValueError):
    """A model file, state dict or foreign graph (ONNX) lacks an array, holds an
    unexpected one, or describes a network that is not eq. (lstm)."""


class CampaignSpecError(LtvMpcError, ValueError):
    """A campaign spec (TOML) is invalid.

    The message starts with the bad entry (e.g. ``[factors].noise_std``) and says how to
    fix it; ``field`` holds that entry.
    """

    def __init__(self, field: str, message: str) -> None:
        super().__init__(f"{field}: {message}")
        self.field = field
