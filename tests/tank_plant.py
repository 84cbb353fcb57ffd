"""A user's plant that is not the pH process (tests only): a gravity-drained tank.

``GravityTank`` is what a user brings in a module of their own: a tank of cross-section
``A`` fed by a pump (inflow ``q``, cm^3/s) and drained through an orifice at the bottom
(outflow ``k sqrt(h)``), level ``h`` in cm, sampled every 5 s:

.. math::

    A \\dot h = q + d - k \\sqrt{h},

with ``d`` an unmeasured extra inflow (cm^3/s). Equilibrium level ``(q / k)^2``: the input
range [6, 14] cm^3/s gives 9-49 cm; the level constraint is [10, 45] cm. Nothing of it is
pH: the tests check that no pH number or label reaches any output of the library's commands
on it (``tests/test_own_plant.py``).
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import ArrayLike, NDArray


class GravityTank:
    """Gravity-drained tank: pump inflow q (cm^3/s) -> level h (cm), Ts = 5 s."""

    Ts = 5.0
    u_phi_min = 6.0
    u_phi_max = 14.0
    u_phi_initial = 10.0
    y_phi_constraint = (10.0, 45.0)
    nominal_disturbance = 0.0
    input_labels = ("inflow q (cm^3/s)",)
    output_labels = ("level h (cm)",)
    disturbance_size = 1
    #: Cross-section, cm^2, and orifice coefficient, cm^2.5/s.
    A = 20.0
    k = 2.0
    #: Euler substeps per sampling period.
    substeps = 10

    def __init__(self) -> None:
        self.h = 0.0
        self.reset()

    def reset(self) -> float:
        """The steady state of ``u_phi_initial`` without disturbance; returns the level."""
        self.h = (self.u_phi_initial / self.k) ** 2
        return self.h

    def output(self) -> NDArray[np.float64]:
        """Level h in cm, shape (1,)."""
        return np.array([self.h])

    def step(self, u_phi: ArrayLike, d_phi: ArrayLike | None = None) -> NDArray[np.float64]:
        """One sampling period with inflow ``u_phi`` (saturated) and extra inflow ``d_phi``."""
        q = float(np.clip(np.asarray(u_phi, dtype=np.float64).reshape(-1)[0], 6.0, 14.0))
        d = 0.0 if d_phi is None else float(np.asarray(d_phi, dtype=np.float64).reshape(-1)[0])
        dt = self.Ts / self.substeps
        for _ in range(self.substeps):
            self.h = max(self.h + dt * (q + d - self.k * math.sqrt(self.h)) / self.A, 0.0)
        return self.output()
