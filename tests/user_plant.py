"""A plant that exists only in the tests: what a user brings in a module of their own.

``HammersteinPH`` is a first-order Hammerstein approximation of the pH process: the static
titration curve of the pH plant (steady-state pH per base flow q3, interpolated) followed
by a first-order lag, plus an additive output disturbance. It states the defaults the plant
registry reads from a user class (``Ts``, input range, initial input, output constraint,
default model and set-points, nominal disturbance, labels), so
``--plant user_plant:HammersteinPH`` works from the command line, data generation and
campaign specs without any registration.
"""

from __future__ import annotations

from typing import ClassVar

import numpy as np
from numpy.typing import ArrayLike, NDArray

#: Steady-state pH of the pH plant per base flow q3 (mL/s), measured from the plant.
_Q3 = np.array([12.5, 13.5, 14.5, 15.0, 15.6, 16.0, 16.5, 17.0])
_PH = np.array([5.948, 6.279, 6.589, 6.764, 7.026, 7.279, 7.957, 8.991])


class HammersteinPH:
    """Hammerstein pH process: titration curve then a first-order lag (tests only)."""

    Ts = 10.0
    u_phi_min = 12.5
    u_phi_max = 17.0
    u_phi_initial = 15.6
    y_phi_constraint = (6.0, 9.0)
    default_model = "ph_lstm_n5.npz"
    default_setpoints = ("7.3", "7.0")
    nominal_disturbance = 0.0
    input_labels = ("q3 (mL/s)",)
    output_labels = ("pH",)
    disturbance_size = 1
    #: Pole of the lag (time constant about 95 s at Ts = 10 s).
    pole = 0.9
    #: Plants built in this process (the tests check the registry builds this class).
    built: ClassVar[int] = 0

    def __init__(self) -> None:
        type(self).built += 1
        self.y = 0.0
        self.reset()

    @staticmethod
    def titration(u_phi: float) -> float:
        """Steady-state pH of base flow ``u_phi`` (mL/s)."""
        return float(np.interp(u_phi, _Q3, _PH))

    def reset(self) -> float:
        """The steady state of ``u_phi_initial`` without disturbance; returns the pH."""
        self.y = self.titration(self.u_phi_initial)
        return self.y

    def output(self) -> NDArray[np.float64]:
        """Measured pH, shape (1,)."""
        return np.array([self.y])

    def step(self, u_phi: ArrayLike, d_phi: ArrayLike | None = None) -> NDArray[np.float64]:
        """One sample with base flow ``u_phi`` (saturated) and output offset ``d_phi``."""
        u = float(np.clip(np.asarray(u_phi, dtype=np.float64).reshape(-1)[0], 12.5, 17.0))
        d = 0.0 if d_phi is None else float(np.asarray(d_phi, dtype=np.float64).reshape(-1)[0])
        self.y = self.pole * self.y + (1.0 - self.pole) * (self.titration(u) + d)
        return self.output()


def replay(u_phi: ArrayLike, disturbances: ArrayLike | None = None) -> NDArray[np.float64]:
    """Outputs y[0..T-1] of a fresh plant under inputs u[0..T-2] (y[k] before u[k] acts)."""
    plant = HammersteinPH()
    u = np.asarray(u_phi, dtype=np.float64).reshape(-1)
    d = np.zeros(u.size) if disturbances is None else np.asarray(disturbances).reshape(-1)
    y = [plant.output()[0]]
    for k in range(u.size - 1):
        y.append(plant.step(u[k], d[k])[0])
    return np.array(y)


class NotAPlant:
    """Has no step(): the registry refuses it."""

    def reset(self) -> None:
        """Nothing to reset."""
