"""The contract between the controller and the engines that run its step.

:class:`~ltv_lstm_mpc.OffsetFreeController` describes the loop of the paper's Fig. 1 (its
components, configuration, certification, records and warnings); a :class:`StepEngine`
runs one step of it. The controller builds the first engine of
``ENGINES`` (:mod:`ltv_lstm_mpc.loop.engines`) that does not refuse its configuration, once, at
construction, and says which (``controller.engine.name``) and why the others refused
(``controller.engine_refusals``).

An engine class provides

- ``name`` (class attribute): how the controller and its records name it;
- ``refusal(controller) -> str | None`` (static): why it does not support this
  controller's configuration (None: it does);
- ``EngineClass(controller)``: the engine, with its workspace built from the controller's
  components by name (their public workspaces: ``Observer.step_workspace``,
  ``ReferenceCalculator.chord_state``, ``RobustMPC.one_call_parts``);

and the engine the methods of :class:`StepEngine`. Each formula an engine evaluates
(normalization, rate limiter, tightening, :math:`\\alpha_k`, set-point interval, gate,
statuses) is called from its one home (:mod:`ltv_lstm_mpc.loop.signals`,
:mod:`ltv_lstm_mpc.certificates.tightening` and their compiled twins), never re-coded in
the engine.
"""

from __future__ import annotations

from typing import Protocol

import numpy as np
from numpy.typing import ArrayLike, NDArray

__all__ = ["StepEngine"]

FloatArray = NDArray[np.float64]


class StepEngine(Protocol):
    """One step of the controller's loop (measurement and set-point in, input out)."""

    #: How the controller names this engine (``"one-call"``, ``"reference"``, ...).
    name: str
    #: Row sizes ``(p, m, 2n, N)`` of the record arrays it writes (None: it appends
    #: finished records; :class:`~ltv_lstm_mpc.loop.records.ControllerRecords`).
    record_shape: tuple[int, int, int, int] | None

    def step(self, y_phi: ArrayLike, y0_phi: ArrayLike) -> FloatArray:
        """One sample (``OffsetFreeController.step``): appends the step's record to the
        controller's records and returns the physical input."""
        ...

    def prepare(self, y0_phi: FloatArray | None) -> bool:
        """Prepare the next step for the set-point ``y0_phi`` (``prepare_next``; None: no
        set-point known, put any preparation aside); False where this engine does not
        prepare between samples."""
        ...

    def reset(self) -> None:
        """Forget the run (``OffsetFreeController.reset``)."""
        ...

    def settle(self) -> None:
        """Write any state the engine keeps aside (e.g. in record rows) into its owners."""
        ...
