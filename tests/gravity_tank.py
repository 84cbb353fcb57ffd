"""A plant that exists only in the tests: a gravity-drained tank, as a user brings it.

``GravityTank`` is one cylindrical tank filled by a pump and drained through an orifice
(Torricelli): :math:`A \\dot h = q - a \\sqrt{2 g h}`, level :math:`h` in cm, inflow
:math:`q` in cm^3/s, sampled every ``Ts = 5`` s. Nothing about it is the pH plant's: other
units, another sampling time, an output range of about 8..50 cm against the constraint
[10, 45] cm. It is the plant the default training settings were not tuned for.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import ArrayLike, NDArray


class GravityTank:
    """Gravity-drained tank: inflow (cm^3/s) -> level (cm), Ts = 5 s (tests only)."""

    Ts = 5.0
    u_phi_min = 65.0
    u_phi_max = 155.0
    u_phi_initial = 110.0
    y_phi_constraint = (10.0, 45.0)
    default_setpoints = ("25", "30")
    nominal_disturbance = 0.0
    input_labels = ("q (cm^3/s)",)
    output_labels = ("h (cm)",)
    disturbance_size = 1
    #: Tank cross-section (cm^2) and orifice coefficient a sqrt(2 g) (cm^2.5/s: outlet area
    #: 0.5 cm^2, gravity 981 cm/s^2).
    area = 200.0
    orifice = 0.5 * math.sqrt(2.0 * 981.0)
    #: Euler substeps per sample.
    substeps = 10

    def __init__(self) -> None:
        self.h = 0.0
        self.reset()

    def steady_level(self, q: float) -> float:
        """Level (cm) at which the outflow equals the inflow ``q`` (cm^3/s)."""
        return (q / self.orifice) ** 2

    def reset(self) -> float:
        """The steady state of ``u_phi_initial``; returns the level (cm)."""
        self.h = self.steady_level(self.u_phi_initial)
        return self.h

    def output(self) -> NDArray[np.float64]:
        """Level (cm), shape (1,)."""
        return np.array([self.h])

    def step(self, u_phi: ArrayLike, d_phi: ArrayLike | None = None) -> NDArray[np.float64]:
        """One sample with inflow ``u_phi`` (saturated to the pump's range) and an additive
        inflow disturbance ``d_phi`` (cm^3/s)."""
        u = np.asarray(u_phi, dtype=np.float64).reshape(-1)[0]
        q = float(np.clip(u, self.u_phi_min, self.u_phi_max))
        d = 0.0 if d_phi is None else float(np.asarray(d_phi, dtype=np.float64).reshape(-1)[0])
        dt = self.Ts / self.substeps
        k = self.orifice
        for _ in range(self.substeps):
            self.h = max(self.h + dt * (q + d - k * math.sqrt(max(self.h, 0.0))) / self.area, 0.0)
        return self.output()
