"""A user's plant that is not the pH process (tests only): a small gravity-drained tank.

``GravityTank`` is what a user brings in a module of their own: the Torricelli tank of
:mod:`gravity_tank` (``A dh/dt = q + d - k sqrt(h)``, level ``h`` in cm, sampled every 5 s)
with a cross-section of 20 cm^2, ``k = 2`` cm^2.5/s and a pump of 6-14 cm^3/s, so the input
range gives equilibrium levels of 9-49 cm against the level constraint [10, 45] cm; ``d`` is
an unmeasured extra inflow (cm^3/s). It states no default set-points (they follow from the
model's admissible interval). Nothing of it is pH: the tests check that no pH number or
label reaches any output of the library's commands on it (``tests/test_own_plant.py``).
"""

from __future__ import annotations

import gravity_tank


class GravityTank(gravity_tank.GravityTank):
    """Gravity-drained tank: pump inflow q (cm^3/s) -> level h (cm), Ts = 5 s."""

    u_phi_min = 6.0
    u_phi_max = 14.0
    u_phi_initial = 10.0
    default_setpoints = ()
    input_labels = ("inflow q (cm^3/s)",)
    output_labels = ("level h (cm)",)
    area = 20.0
    orifice = 2.0
