r"""Measurement noise on any plant: :class:`NoisyMeasurement` (the sensor of Fig. 1).

The plant's outputs reach the controller as :math:`y_k + \sigma \varepsilon_k`,
:math:`\varepsilon_k \sim \mathcal N(0, I)`; the plant's state is never affected, and the
true output stays available (:meth:`NoisyMeasurement.true_output`), so that
:func:`~ltv_lstm_mpc.simulate` judges constraint violations and offsets on
the true plant, not on the noisy measurement.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from ltv_lstm_mpc.exceptions import InvalidValueError

__all__ = ["NoisyMeasurement"]

FloatArray = NDArray[np.float64]


class NoisyMeasurement:
    """A plant whose measured outputs carry Gaussian noise (same ``Plant`` protocol).

    Parameters
    ----------
    plant : Plant
        Any plant (pH process, quadruple tank, LSTM plant); every other attribute
        (``disturbance_size``, ``Ts``, ``saturate``, ...) is the plant's own.
    noise_std : float
        Standard deviation, output units (0: exact measurements).
    seed : int, optional
        Seed of ``numpy.random.default_rng``; :meth:`reset` restarts the sequence. The
        same seed gives the same standard-normal draws whatever ``noise_std`` is (common
        random numbers across noise levels).

    Raises
    ------
    InvalidValueError
        ``noise_std`` negative or not finite.
    """

    def __init__(self, plant: Any, noise_std: float, seed: int | None = None) -> None:
        if isinstance(noise_std, bool) or not (
            math.isfinite(float(noise_std)) and float(noise_std) >= 0
        ):
            raise InvalidValueError(
                f"noise_std must be a finite number >= 0 (output units), got {noise_std!r}"
            )
        self.plant = plant
        self.noise_std = float(noise_std)
        self.seed = seed
        self._rng = np.random.default_rng(seed)
        self._true = np.atleast_1d(np.asarray(plant.output(), dtype=np.float64)).copy()

    def __getattr__(self, name: str) -> Any:
        # only called for attributes this wrapper lacks: the plant's own
        return getattr(self.__dict__["plant"], name)

    def _measure(self, y: ArrayLike) -> FloatArray:
        self._true = np.atleast_1d(np.asarray(y, dtype=np.float64)).copy()
        noise = self._rng.standard_normal(self._true.shape)
        return self._true + self.noise_std * noise if self.noise_std > 0 else self._true.copy()

    def true_output(self) -> FloatArray:
        """The plant's true output behind the last measurement (a copy)."""
        return self._true.copy()

    def reset(self, *args: Any, **kwargs: Any) -> Any:
        """Reset the plant (arguments passed on) and restart the noise sequence."""
        self._rng = np.random.default_rng(self.seed)
        result = self.plant.reset(*args, **kwargs)
        self._true = np.atleast_1d(np.asarray(self.plant.output(), dtype=np.float64)).copy()
        return result

    def output(self) -> FloatArray:
        """Noisy measurement of the current output."""
        return self._measure(self.plant.output())

    def step(self, u_phi: ArrayLike, d_phi: ArrayLike | None = None) -> FloatArray:
        """Step the plant and return the noisy measurement of its new output."""
        return self._measure(self.plant.step(u_phi, d_phi))
