"""The one check of a signal handed to the library (measurements, set-points, inputs).

Every entry point that takes a signal vector (the controller's ``step``, the plants'
``step``, ``simulate``'s schedules, the MPC's ``solve``) calls :func:`real_vector`: shape
``(size,)`` (a scalar only when ``size == 1``), real numbers only (booleans, strings,
complex numbers and objects are refused, never converted), finite. The errors name the
argument, what was given and what is expected.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
from numpy.typing import NDArray

from ltv_lstm_mpc.exceptions import DimensionError, InvalidValueError

__all__ = ["real_array", "real_vector"]

FloatArray = NDArray[np.float64]

_KIND_NAMES = {"b": "boolean", "c": "complex", "U": "string", "S": "bytes", "O": "object"}


def _describe(value: Any) -> str:
    text = repr(value)
    return text if len(text) <= 80 else text[:77] + "..."


def real_array(name: str, value: Any, *, kinds: str = "biuf") -> NDArray[Any]:
    """``value`` as an array whose dtype kind is in ``kinds`` (real numbers; booleans too
    by default), else :class:`InvalidValueError` naming it: complex numbers, strings and
    objects are refused, never converted."""
    array = value if isinstance(value, np.ndarray) else np.asarray(value)
    if array.dtype.kind not in kinds:
        what = _KIND_NAMES.get(array.dtype.kind, str(array.dtype))
        raise InvalidValueError(
            f"{name} must be real numbers, got {what} values {_describe(value)}"
        )
    return array


def real_vector(name: str, value: Any, size: int) -> FloatArray:
    """``value`` as a finite float64 vector of shape ``(size,)``, or a clear error.

    Parameters
    ----------
    name : str
        Argument name used in the messages (e.g. ``"y_phi"``).
    value : array_like
        A sequence or array of ``size`` real numbers, or one real number when ``size == 1``.
    size : int
        Expected length.

    Raises
    ------
    InvalidValueError
        Booleans, strings, complex numbers or objects; NaN or inf entries.
    DimensionError
        Any other shape (e.g. ``[[7.0]]`` or two entries for one output).
    """
    # Fast paths for the common hot-loop inputs (same checks, fewer numpy calls).
    if isinstance(value, float) and size == 1:  # float and numpy.float64
        if not math.isfinite(value):
            raise InvalidValueError(f"{name} contains NaN or inf: {_describe(value)}")
        return np.array([value], dtype=np.float64)
    if type(value) is np.ndarray and value.dtype == np.float64 and value.shape == (size,):
        # the sum of a few scalars in Python; non-finite (or overflowing): the exact test
        if not math.isfinite(sum(value.tolist())) and not bool(np.isfinite(value).all()):
            raise InvalidValueError(f"{name} contains NaN or inf: {_describe(value)}")
        return value
    if isinstance(value, (bool, np.bool_, str, bytes)):
        raise InvalidValueError(
            f"{name} must be real numbers, got {type(value).__name__} {_describe(value)}"
        )
    array = real_array(name, value, kinds="iuf")
    if array.shape != (size,):
        if array.ndim == 0 and size == 1:
            array = array.reshape(1)
        else:
            expected = f"({size},)" + (" or a number" if size == 1 else "")
            raise DimensionError(f"{name} has shape {array.shape}, expected {expected}")
    array = array.astype(np.float64, copy=False)
    # One sum on the hot path; the exact test only when it is not finite.
    if not math.isfinite(float(array.sum())) and not bool(np.isfinite(array).all()):
        raise InvalidValueError(f"{name} contains NaN or inf: {_describe(value)}")
    return array
