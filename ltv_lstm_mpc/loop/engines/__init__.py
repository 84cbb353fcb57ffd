"""The engines that run the controller's step (:mod:`ltv_lstm_mpc.loop.engines.base`).

``ENGINES`` lists them fastest first; ``choose_engine`` builds the first that does not
refuse a controller's configuration. Adding an engine: a class with ``name``,
``refusal`` and the :class:`~ltv_lstm_mpc.loop.engines.base.StepEngine` methods, in its
own module here, and its place in ``ENGINES``.
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any

from ltv_lstm_mpc.exceptions import InvalidValueError
from ltv_lstm_mpc.loop.engines.base import StepEngine
from ltv_lstm_mpc.loop.engines.one_call_engine import OneCallEngine
from ltv_lstm_mpc.loop.engines.reference_engine import Handover, ReferenceEngine

if TYPE_CHECKING:
    from ltv_lstm_mpc.loop.controller import OffsetFreeController

__all__ = [
    "ENGINES",
    "ON_REQUEST",
    "Handover",
    "OneCallEngine",
    "ReferenceEngine",
    "StepEngine",
    "choose_engine",
]

#: The engine classes, fastest first (the reference engine, last, runs every configuration).
ENGINES: tuple[Any, ...] = (OneCallEngine, ReferenceEngine)


#: The engines built only when asked for by name (``OffsetFreeController(engine=...)``),
#: by import path: plugins from packages above this one (the C export depends on the loop,
#: not the other way), imported when asked for.
ON_REQUEST: dict[str, str] = {
    "c": "ltv_lstm_mpc.export.c_engine.CEngine",
    "c-single": "ltv_lstm_mpc.export.c_engine.SingleCEngine",
}


def _on_request(name: str) -> Any:
    """The engine class of :data:`ON_REQUEST` named ``name``, imported."""
    module, _, attribute = ON_REQUEST[name].rpartition(".")
    return getattr(importlib.import_module(module), attribute)


def choose_engine(
    controller: OffsetFreeController, requested: str = "auto"
) -> tuple[StepEngine, dict[str, str]]:
    """The engine named ``requested`` (``"auto"``: the first of :data:`ENGINES` that runs
    ``controller``'s configuration), built, and why each faster one refused it
    (``{name: reason}``); an engine asked for by name that refuses the configuration
    raises, with its reason."""
    if requested != "auto":
        by_name = {engine.name: engine for engine in ENGINES}
        if requested not in by_name and requested not in ON_REQUEST:
            names = sorted(set(by_name) | set(ON_REQUEST))
            raise InvalidValueError(
                f"engine={requested!r} is not an engine: use 'auto' or one of {names}"
            )
        engine = by_name[requested] if requested in by_name else _on_request(requested)
        reason = engine.refusal(controller)
        if reason is not None:
            raise InvalidValueError(f"engine={requested!r} cannot run this controller: {reason}")
        return engine(controller), {}
    refusals: dict[str, str] = {}
    for engine in ENGINES:
        reason = engine.refusal(controller)
        if reason is None:
            return engine(controller), refusals
        refusals[engine.name] = reason
    raise AssertionError("the reference engine refused a configuration")  # never
