"""The engines that run the controller's step (:mod:`ltv_lstm_mpc.loop.engines.base`).

``ENGINES`` lists them fastest first; ``choose_engine`` builds the first that does not
refuse a controller's configuration. Adding an engine: a class with ``name``,
``refusal`` and the :class:`~ltv_lstm_mpc.loop.engines.base.StepEngine` methods, in its
own module here, and its place in ``ENGINES``.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

from ltv_lstm_mpc.loop.engines.base import StepEngine
from ltv_lstm_mpc.loop.engines.one_call_engine import OneCallEngine
from ltv_lstm_mpc.loop.engines.reference_engine import Handover, ReferenceEngine

if TYPE_CHECKING:
    from ltv_lstm_mpc.loop.controller import OffsetFreeController

__all__ = ["ENGINES", "Handover", "OneCallEngine", "ReferenceEngine", "StepEngine", "choose_engine"]

#: The engine classes, fastest first (the reference engine, last, runs every configuration).
ENGINES: tuple[Any, ...] = (OneCallEngine, ReferenceEngine)


def choose_engine(controller: OffsetFreeController) -> tuple[StepEngine, dict[str, str]]:
    """The first engine of :data:`ENGINES` that runs ``controller``'s configuration, built,
    and why each faster one refused it (``{name: reason}``)."""
    refusals: dict[str, str] = {}
    for engine in ENGINES:
        reason = engine.refusal(controller)
        if reason is None:
            return engine(controller), refusals
        refusals[engine.name] = reason
    raise AssertionError("the reference engine refused a configuration")  # never
