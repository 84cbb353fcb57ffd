r"""Diagonal equilibration (Ruiz) of dense QPs, optional in :class:`~.dense.DenseSession`.

A badly scaled QP (rows or variables of very different magnitude) slows or defeats the
solvers that do not scale their data themselves (DAQP, quadprog; OSQP, SCS, PIQP,
ProxQP and CLARABEL equilibrate internally). Ruiz's method (D. Ruiz, "A scaling algorithm
to equilibrate both rows and columns norms in matrices", RAL-TR-2001-034) scales the
variables by ``D`` and the rows by ``E`` so that every column of ``[H; A]`` and every row
of ``A`` has an infinity norm near 1:

.. math::

    x = D \tilde x, \quad
    \tilde H = D H D, \quad \tilde f = D f, \quad \tilde A = E A D, \quad
    E\,lo \le \tilde A \tilde x \le E\,up, \quad D^{-1} lb \le \tilde x \le D^{-1} ub,

cones :math:`\|F D \tilde x + g\| \le (D e)^\top \tilde x + f`. The multipliers of the
original problem are :math:`y = E \tilde y` (rows) and :math:`y_b = D^{-1} \tilde y_b`
(bounds); a cone's are unchanged; a direction is :math:`D \tilde d`.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np

from ._base import FloatArray

if TYPE_CHECKING:  # the scaled QP is built with the type of the one given (no import cycle)
    from .dense import DenseQP

__all__ = ["Scaling", "ruiz"]

#: Bounds on one iteration's factor, as in OSQP's implementation of the method.
_MIN_NORM, _MAX_NORM = 1e-4, 1e4


@dataclass(frozen=True)
class Scaling:
    """Variable scaling ``D`` (n,) and row scaling ``E`` (m_A,)."""

    D: FloatArray
    E: FloatArray

    def apply(self, qp: DenseQP) -> DenseQP:
        """The scaled QP (new arrays)."""
        D, E = self.D, self.E
        cones = tuple(type(c)(c.F * D, c.g, c.e * D, c.f) for c in qp.cones)
        qp_type: Any = type(qp)
        return qp_type(
            H=(qp.H * D) * D[:, None],
            f=qp.f * D,
            A=np.ascontiguousarray((qp.A * D) * E[:, None]),
            lo=qp.lo * E,
            up=qp.up * E,
            lb=qp.lb / D,
            ub=qp.ub / D,
            cones=cones,
        )

    def point(self, z: FloatArray) -> FloatArray:
        """``D z``: a point (or direction) of the scaled QP in the original variables."""
        return z * self.D

    def multipliers(self, duals: Mapping[str, FloatArray]) -> dict[str, FloatArray]:
        """Multipliers (or a Farkas vector) of the scaled QP for the original one."""
        out = dict(duals)
        if "ineq" in out:
            out["ineq"] = np.asarray(out["ineq"]) * self.E
        if "bounds" in out:
            out["bounds"] = np.asarray(out["bounds"]) / self.D
        if "direction" in out:
            out["direction"] = self.point(np.asarray(out["direction"]))
        return out


def ruiz(qp: DenseQP, iterations: int = 10) -> Scaling:
    """Ruiz equilibration of ``[H A'; A 0]`` in ``iterations`` sweeps (infinity norms)."""
    n, m = qp.n_variables, qp.n_rows
    D = np.ones(n)
    E = np.ones(m)
    H = np.abs(np.asarray(qp.H, dtype=np.float64))
    A = np.abs(np.asarray(qp.A, dtype=np.float64))
    for _ in range(iterations):
        Hs = H * D * D[:, None]
        As = A * D * E[:, None]
        col = np.maximum(Hs.max(axis=0, initial=0.0), As.max(axis=0, initial=0.0))
        row = As.max(axis=1, initial=0.0)
        col = np.clip(np.where(col > 0.0, col, 1.0), _MIN_NORM, _MAX_NORM)
        row = np.clip(np.where(row > 0.0, row, 1.0), _MIN_NORM, _MAX_NORM)
        D = D / np.sqrt(col)
        E = E / np.sqrt(row)
    return Scaling(D, E)
