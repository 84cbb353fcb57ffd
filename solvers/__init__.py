"""Convex-subproblem solver layer, installed as :mod:`ltv_lstm_mpc.solvers`.

It knows nothing about LSTMs: it takes a problem data class (matrices and
cones) and returns a solution data class.
"""

from __future__ import annotations

__all__: list[str] = []
