"""The plant role of the closed loop (paper Fig. 1 and Fig. 2), as a typing Protocol.

Every plant (``reset()``, ``output()``, ``step(u_phi, d_phi)``) works with physical signals
(suffix ``_phi``, paper notes 1).
"""

from __future__ import annotations

from typing import Protocol, runtime_checkable

import numpy as np
from numpy.typing import ArrayLike, NDArray

from ltv_lstm_mpc.caller_warnings import warn_at_caller
from ltv_lstm_mpc.exceptions import SamplingTimeError

__all__ = ["Plant", "check_sampling_time"]

FloatArray = NDArray[np.float64]


@runtime_checkable
class Plant(Protocol):
    """Role of the plant in the closed loop (paper Fig. 1 and Fig. 2); physical signals.

    Methods
    -------
    reset()
        Put the plant at its initial condition; returns the initial state (plant-specific).
    output()
        Current measured output :math:`y_\\phi` (physical units), shape (p,).
    step(u_phi, d_phi=None)
        Apply the physical input ``u_phi`` (and the plant's disturbance ``d_phi``; ``None``
        means nominal) for one sampling period and return the new physical output, shape (p,).

    A plant may also state ``disturbance_size`` (the entries of ``d_phi``); ``simulate``
    then checks its disturbance schedule against it. It should state ``Ts``, its sampling
    period in seconds: ``simulate`` and campaigns then refuse a model identified at another
    one (:func:`check_sampling_time`). A plant without ``Ts`` is not checked.
    """

    def reset(self) -> float | FloatArray: ...

    def output(self) -> FloatArray: ...

    def step(self, u_phi: ArrayLike, d_phi: ArrayLike | None = None) -> FloatArray: ...


#: Relative tolerance of the sampling-time comparison.
SAMPLING_TIME_RTOL = 1e-9


def check_sampling_time(
    model_Ts: float | None, plant_Ts: float | None, what: str = "plant"
) -> None:
    """The model-plant contract on the sampling time (the one comparison of the library).

    Parameters
    ----------
    model_Ts : float or None
        The model's ``Ts`` (s); None: not stated (a warning says the check is skipped).
    plant_Ts : float or None
        The plant's ``Ts`` (s); None: a plant that states none (not checked).
    what : str
        The plant's name in the messages.

    Raises
    ------
    SamplingTimeError
        Both are stated and differ by more than :data:`SAMPLING_TIME_RTOL` (relative).
    """
    if plant_Ts is None:
        return
    if model_Ts is None:
        warn_at_caller(
            f"the model states no sampling time; the {what} runs at Ts = {plant_Ts} s and "
            "the two cannot be compared (set model.Ts, or load it with LSTMModel.load(path, "
            "Ts=...))",
            UserWarning,
        )
        return
    if abs(model_Ts - plant_Ts) > SAMPLING_TIME_RTOL * max(abs(model_Ts), abs(plant_Ts)):
        raise SamplingTimeError(
            f"the model was identified at Ts = {model_Ts} s but the {what} runs at "
            f"Ts = {plant_Ts} s: its one-step predictions do not describe this plant. Run "
            f"the {what} at Ts = {model_Ts} s, or identify a model at {plant_Ts} s; if the "
            "model's Ts is unknown and you accept the risk, pass check_sampling_time=False"
        )
