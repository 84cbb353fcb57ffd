"""Every public name answers wrong types, shapes and non-finite values with a library error.

Each callable of ``ltv_lstm_mpc.__all__`` and ``ltv_lstm_mpc.solvers.__all__`` is called
with a bad value in every required argument, and with a bad value in each keyword
argument (the required ones then valid where the test knows a valid value). Only
:class:`~ltv_lstm_mpc.exceptions.LtvMpcError` subclasses may come out (plus the documented
built-ins in ``DOCUMENTED``), never ``AttributeError``, ``IndexError``, ``KeyError`` or a
numpy/scipy/cvxpy/numba exception, and a result is never NaN.
"""

from __future__ import annotations

import inspect
import math
import warnings
from typing import Any

import ltv_lstm_mpc.solvers as solver_layer
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

import ltv_lstm_mpc
from ltv_lstm_mpc import LtvMpcError, load_model

#: Values of the wrong type, shape or finiteness for any argument.
BAD_VALUES: tuple[Any, ...] = (
    None,
    "text",
    {"a": 1},
    ["a", "b"],
    object(),
    True,
    math.nan,
    -math.inf,
    np.array([math.nan]),
    np.full((2, 3), math.inf),
    np.zeros((0,)),
    -1,
)

#: Built-in errors documented where they come out (a missing file is a FileNotFoundError,
#: as open() says; ``Plant`` is a typing Protocol, not something to call).
DOCUMENTED: tuple[type[BaseException], ...] = (FileNotFoundError,)

#: Not called: exception classes (constructing one with any message is fine), the Plant
#: protocol and the abstract Backend and DenseBackend (base classes to subclass: Python
#: refuses to instantiate them by design), the SolverStatus enum (calling it looks a member up by
#: value: ValueError, as for every Enum) and constants.
SKIP = {"Plant", "Backend", "DenseBackend", "SolverStatus", "__version__"}


def _public_callables() -> list[tuple[str, Any]]:
    found = []
    for module in (ltv_lstm_mpc, solver_layer):
        for name in module.__all__:
            if name in SKIP:
                continue
            value = getattr(module, name)
            if isinstance(value, type) and issubclass(value, BaseException):
                continue
            if callable(value):
                found.append((f"{module.__name__}.{name}", value))
    return found


CALLABLES = _public_callables()


def _required(function: Any) -> list[inspect.Parameter]:
    try:
        signature = inspect.signature(function)
    except (TypeError, ValueError):  # pragma: no cover - builtins without a signature
        return []
    return [
        p
        for p in signature.parameters.values()
        if p.default is inspect.Parameter.empty
        and p.kind in (p.POSITIONAL_ONLY, p.POSITIONAL_OR_KEYWORD, p.KEYWORD_ONLY)
    ]


def _keywords(function: Any) -> list[str]:
    try:
        signature = inspect.signature(function)
    except (TypeError, ValueError):  # pragma: no cover
        return []
    return [
        p.name
        for p in signature.parameters.values()
        if p.default is not inspect.Parameter.empty
        and p.kind in (p.POSITIONAL_OR_KEYWORD, p.KEYWORD_ONLY)
    ]


def _call(function: Any, args: list[Any], kwargs: dict[str, Any]) -> None:
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        try:
            result = function(*args, **kwargs)
        except LtvMpcError:
            return
        except DOCUMENTED:
            return
    _assert_not_nan(result)


def _assert_not_nan(result: Any) -> None:
    if isinstance(result, float):
        assert not math.isnan(result)
    elif isinstance(result, np.ndarray) and result.dtype.kind == "f":
        assert not np.isnan(result).any()


def test_there_is_something_to_fuzz() -> None:
    names = {name.rsplit(".", 1)[1] for name, _ in CALLABLES}
    assert {"OffsetFreeController", "simulate", "certify", "load_model", "solve"} <= names
    assert len(CALLABLES) > 50


@settings(max_examples=400, deadline=None, derandomize=True)
@given(
    entry=st.sampled_from(CALLABLES),
    bad=st.sampled_from(BAD_VALUES),
    where=st.integers(0, 50),
)
def test_bad_argument_gives_a_library_error(entry, bad, where) -> None:
    """A bad value in every required argument, or in one keyword argument."""
    _, function = entry
    required = _required(function)
    keywords = _keywords(function)
    if required:
        args = [bad for p in required if p.kind != p.KEYWORD_ONLY]
        kwargs = {p.name: bad for p in required if p.kind == p.KEYWORD_ONLY}
        _call(function, args, kwargs)
    elif keywords:
        _call(function, [], {keywords[where % len(keywords)]: bad})


@pytest.fixture(scope="module")
def model():
    return load_model("ph_lstm_n5.npz")


@settings(max_examples=120, deadline=None, derandomize=True)
@given(
    method=st.sampled_from(("step", "jacobians", "equilibrium", "simulate", "output")),
    bad=st.sampled_from(BAD_VALUES),
    position=st.integers(0, 1),
)
def test_model_methods_refuse_bad_arguments(model, method, bad, position) -> None:
    good_state = np.zeros(2 * model.n)
    good_input = np.zeros(model.m)
    good = {
        "step": [good_state, good_input],
        "jacobians": [good_state, good_input],
        "equilibrium": [good_input],
        "simulate": [good_state, np.zeros((3, model.m))],
        "output": [good_state],
    }[method]
    args = list(good)
    args[position % len(args)] = bad
    _call(getattr(model, method), args, {})
