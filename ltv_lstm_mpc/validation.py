"""The checks of what is handed to the library: signals, numbers, objects, paths.

Every entry point that takes a signal vector (the controller's ``step``, the plants'
``step``, ``simulate``'s schedules, the MPC's ``solve``) calls :func:`real_vector`: shape
``(size,)`` (a scalar only when ``size == 1``), real numbers only (booleans, strings,
complex numbers and objects are refused, never converted), finite. The errors name the
argument, what was given and what is expected.

The other public entry points check their arguments once, where they are given (at
construction or at the top of the call, never per control step), with the helpers below:
:func:`expect_instance` (an object of a library type, e.g. a model where a file name was
given), :func:`expect_real` and :func:`expect_int` (a number of the right type in its
range), :func:`expect_bool`, :func:`expect_path` and :func:`expect_methods` (an object that
fills a role, e.g. a plant). A wrong type raises
:class:`~ltv_lstm_mpc.ArgumentTypeError` (a ``TypeError``), a value out of range
:class:`~ltv_lstm_mpc.InvalidValueError` (a ``ValueError``).
"""

from __future__ import annotations

import math
import numbers
import os
from collections.abc import Sequence
from pathlib import Path
from typing import Any, TypeVar

import numpy as np
from numpy.typing import NDArray

from ltv_lstm_mpc.exceptions import (
    ArgumentTypeError,
    DimensionError,
    InvalidValueError,
    NumberTypeError,
)

__all__ = [
    "expect_bool",
    "expect_instance",
    "expect_int",
    "expect_methods",
    "expect_output_bounds",
    "expect_pair",
    "expect_path",
    "expect_real",
    "finite_array",
    "real_array",
    "real_scalar",
    "real_vector",
]

T = TypeVar("T")

FloatArray = NDArray[np.float64]

_KIND_NAMES = {"b": "boolean", "c": "complex", "U": "string", "S": "bytes", "O": "object"}


def _describe(value: Any) -> str:
    text = repr(value)
    return text if len(text) <= 80 else text[:77] + "..."


def _string_for_number(name: str, value: str | bytes) -> NumberTypeError:
    """The error for a string given where numbers are expected (convert it first)."""
    hint = ""
    try:
        number = float(value)
    except ValueError:
        pass
    else:
        hint = f"; convert it first, e.g. {name}={number!r}"
    return NumberTypeError(
        f"{name} must be real numbers, got {type(value).__name__} {_describe(value)}{hint}"
    )


def real_array(name: str, value: Any, *, kinds: str = "biuf") -> NDArray[Any]:
    """``value`` as an array whose dtype kind is in ``kinds`` (real numbers; booleans too
    by default), else :class:`InvalidValueError` naming it: complex numbers, strings and
    objects are refused, never converted; a string itself is :class:`NumberTypeError` (an
    ``ArgumentTypeError``, ``TypeError``, and an ``InvalidValueError``)."""
    if isinstance(value, (str, bytes)):
        raise _string_for_number(name, value)
    try:
        array = value if isinstance(value, np.ndarray) else np.asarray(value)
    except (TypeError, ValueError):  # ragged nesting, objects numpy cannot convert
        raise InvalidValueError(
            f"{name} must be real numbers (an array of one shape), got {_describe(value)}"
        ) from None
    if array.dtype.kind not in kinds:
        what = _KIND_NAMES.get(array.dtype.kind, str(array.dtype))
        raise InvalidValueError(
            f"{name} must be real numbers, got {what} values {_describe(value)}"
        )
    return array


def real_scalar(name: str, value: Any) -> float:
    """``value`` (a number or a one-element array) as a float, else a library error:
    strings, objects, complex numbers (:func:`real_array`) or several entries
    (:class:`DimensionError`). Finiteness is left to the caller."""
    array = real_array(name, value)
    if array.size != 1:
        raise DimensionError(f"{name} must be one number, got shape {array.shape}")
    return float(array.reshape(-1)[0])


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
    if isinstance(value, (str, bytes)):
        raise _string_for_number(name, value)
    if isinstance(value, (bool, np.bool_)):
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


def _given(value: Any) -> str:
    """``"<type> <repr>"`` of a value, for the messages."""
    return f"{type(value).__name__} {_describe(value)}"


def _fail_type(name: str, value: Any, expected: str, hint: str | None) -> ArgumentTypeError:
    message = f"{name} must be {expected}, got {_given(value)}"
    return ArgumentTypeError(message + (f"; {hint}" if hint else ""))


def expect_instance(
    name: str,
    value: Any,
    types: type[T] | tuple[type, ...],
    hint: str | None = None,
    *,
    expected: str | None = None,
) -> T:
    """``value`` itself when it is an instance of ``types``, else :class:`ArgumentTypeError`.

    Parameters
    ----------
    name : str
        Argument name used in the message (e.g. ``"model"``).
    value : object
        What was given.
    types : type or tuple of types
        Accepted types.
    hint : str, optional
        How to fix it, appended to the message (e.g. ``"load it with load_model(...)"``).
    expected : str, optional
        What is expected, in words (default: the type names).
    """
    if isinstance(value, types):
        return value  # type: ignore[return-value]
    if expected is None:
        group = types if isinstance(types, tuple) else (types,)
        expected = "a " + " or ".join(kind.__name__ for kind in group)
    raise _fail_type(name, value, expected, hint)


def expect_real(
    name: str,
    value: Any,
    *,
    low: float | None = None,
    high: float | None = None,
    low_open: bool = False,
    high_open: bool = False,
    hint: str | None = None,
) -> float:
    """``value`` as a float when it is a finite real number in the range, else an error.

    ``low``/``high`` bound the range (inclusive unless ``low_open``/``high_open``).
    Booleans, strings, complex numbers, arrays and ``None`` raise
    :class:`ArgumentTypeError`; NaN, inf or a value out of range
    :class:`InvalidValueError`.
    """
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, numbers.Real):
        raise _fail_type(name, value, "a real number", hint)
    number = float(value)
    if not math.isfinite(number):
        raise InvalidValueError(f"{name} must be a finite number, got {value!r}")
    below = low is not None and (number <= low if low_open else number < low)
    above = high is not None and (number >= high if high_open else number > high)
    if below or above:
        left = "-inf" if low is None else f"{low:g}"
        right = "inf" if high is None else f"{high:g}"
        bracket = ("(" if low_open or low is None else "[") + f"{left}, {right}"
        bracket += ")" if high_open or high is None else "]"
        message = f"{name} must lie in {bracket}, got {value!r}"
        raise InvalidValueError(message + (f"; {hint}" if hint else ""))
    return number


def expect_int(
    name: str, value: Any, *, minimum: int | None = None, hint: str | None = None
) -> int:
    """``value`` as an int when it is an integer ``>= minimum``, else an error.

    Booleans, floats (even ``5.0``), strings and ``None`` raise :class:`ArgumentTypeError`
    naming the type given; a value below ``minimum`` :class:`InvalidValueError`.
    """
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, numbers.Integral):
        raise _fail_type(name, value, "an integer", hint)
    number = int(value)
    if minimum is not None and number < minimum:
        message = f"{name} must be an integer >= {minimum}, got {number}"
        raise InvalidValueError(message + (f"; {hint}" if hint else ""))
    return number


def expect_bool(name: str, value: Any) -> bool:
    """``value`` as a bool when it is ``True``/``False`` (numpy booleans too), else
    :class:`ArgumentTypeError`."""
    if not isinstance(value, (bool, np.bool_)):
        raise _fail_type(name, value, "True or False", None)
    return bool(value)


def expect_path(name: str, value: Any, hint: str | None = None) -> Path:
    """``value`` as a :class:`~pathlib.Path` when it is a ``str`` or ``os.PathLike``, else
    :class:`ArgumentTypeError`."""
    if isinstance(value, bytes) or not isinstance(value, (str, os.PathLike)):
        raise _fail_type(name, value, "a file path (str or pathlib.Path)", hint)
    return Path(value)


def expect_methods(
    name: str, value: Any, methods: Sequence[str], expected: str, hint: str | None = None
) -> Any:
    """``value`` itself when it has every callable in ``methods`` (duck typing: a plant, an
    MPC), else :class:`ArgumentTypeError` naming the missing ones."""
    missing = [method for method in methods if not callable(getattr(value, method, None))]
    if missing:
        raise _fail_type(
            name, value, f"{expected} (with {', '.join(m + '()' for m in missing)})", hint
        )
    return value


def finite_array(name: str, value: Any) -> FloatArray:
    """``value`` as a float64 array of real, finite numbers (any shape), else
    :class:`InvalidValueError` naming it."""
    if isinstance(value, (str, bytes)):
        raise _string_for_number(name, value)
    array = np.asarray(real_array(name, value, kinds="iuf"), dtype=np.float64)
    if not bool(np.isfinite(array).all()):
        raise InvalidValueError(f"{name} contains NaN or inf: {_describe(value)}")
    return array


def expect_output_bounds(y_min: Any, y_max: Any) -> None:
    """Optional normalized output bounds: each None or a finite real number, and
    ``y_min < y_max`` when both are given (:class:`InvalidValueError` otherwise)."""
    for name, value in (("y_min", y_min), ("y_max", y_max)):
        if value is not None:
            expect_real(name, value, hint="normalized units, or None")
    if y_min is not None and y_max is not None and not y_min < y_max:
        raise InvalidValueError(f"y_min must be below y_max, got y_min={y_min!r}, y_max={y_max!r}")


def expect_pair(name: str, value: Any) -> tuple[float, float]:
    """``value`` as ``(low, high)`` when it is two finite real numbers with low < high,
    else :class:`ArgumentTypeError` (not a pair of numbers) or :class:`InvalidValueError`
    (not finite, or low >= high; the message shows both and says to swap them)."""
    if isinstance(value, (str, bytes)) or not isinstance(value, (Sequence, np.ndarray)):
        raise _fail_type(name, value, "a pair (low, high) of numbers", None)
    if len(value) != 2:
        raise InvalidValueError(f"{name} must be a pair (low, high), got {_describe(value)}")
    low = expect_real(f"{name}[0] (low)", value[0])
    high = expect_real(f"{name}[1] (high)", value[1])
    if not low < high:
        raise InvalidValueError(
            f"{name} must have low < high, got low={value[0]!r}, high={value[1]!r}"
            + ("; swap them" if low > high else "")
        )
    return low, high
