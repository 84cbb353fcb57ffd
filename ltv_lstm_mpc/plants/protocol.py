"""The plant role of the closed loop (paper Fig. 1 and Fig. 2), as a typing Protocol.

Every plant (``reset()``, ``output()``, ``step(u_phi, d_phi)``) works with physical signals
(suffix ``_phi``, SPEC 1).
"""

from __future__ import annotations

from typing import Protocol, runtime_checkable

import numpy as np
from numpy.typing import ArrayLike, NDArray

__all__ = ["Plant"]

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
    then checks its disturbance schedule against it.
    """

    def reset(self) -> float | FloatArray: ...

    def output(self) -> FloatArray: ...

    def step(self, u_phi: ArrayLike, d_phi: ArrayLike | None = None) -> FloatArray: ...
