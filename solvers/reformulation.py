"""Conservative cone reformulations for QP-only backends.

Contract of a :class:`ConeReformulation`
    ``apply(problem)`` returns a problem **without cones** whose feasible set,
    restricted to the original variables, is a **subset** of the original one
    (conservative: every point it admits satisfies the cones). It must keep the
    original ``n`` variables first and in order; it may append auxiliary
    variables and may replace the objective by an upper bound. ``name`` is
    recorded in :attr:`Solution.reformulation`.

The session applies a reformulation only when the chosen backend cannot take
cones and the problem has some; a cone solver given the same reformulation
solves the exact problem (so one reformulation can be passed to every solver of
a comparison). The controller supplies the terminal-set and terminal-cost ones
of paper notes section 4; :class:`PolyhedralInnerApproximation` is the generic one.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Protocol, runtime_checkable

import numpy as np
import scipy.sparse as sp

from .problem import ConvexProblem

__all__ = ["ConeReformulation", "PolyhedralInnerApproximation"]


@runtime_checkable
class ConeReformulation(Protocol):
    """Turns a cone problem into a cone-free, conservative one (see the module docstring)."""

    @property
    def name(self) -> str:
        """Short identifier recorded in the solution."""
        ...

    def apply(self, problem: ConvexProblem) -> ConvexProblem:
        """Return the cone-free conservative problem."""
        ...


@dataclass(frozen=True)
class PolyhedralInnerApproximation:
    """Replace each cone by the inner box ``|F_i z + g_i| <= (e'z + f) / sqrt(k)``.

    For a cone :math:`\\|F z + g\\|_2 \\le e^\\top z + f` with ``k`` rows,
    :math:`\\|v\\|_2 \\le \\sqrt{k}\\,\\|v\\|_\\infty` gives

    .. math:: |F_i z + g_i| \\le \\frac{e^\\top z + f}{\\sqrt{k}} \\;\\forall i
              \\;\\Rightarrow\\; \\|F z + g\\|_2 \\le e^\\top z + f,

    i.e. ``2k`` linear rows ``(±sqrt(k) F_i - e') z <= f ∓ sqrt(k) g_i`` appended
    to ``G`` (with ``l = -inf``). No variable is added and the objective is
    unchanged. Exact for ``k = 1``; for ``k > 1`` it shrinks the set by up to
    ``sqrt(k)`` along the diagonals and is exact along none of the axes, so it is
    a test and fallback device, not a tight approximation.
    """

    name: str = "polyhedral_inner_inf_norm"

    def apply(self, problem: ConvexProblem) -> ConvexProblem:
        """Return the problem with every cone replaced by ``2k`` linear rows."""
        if not problem.has_cones:
            return problem
        n = problem.n_variables
        rows: list[sp.coo_matrix] = []
        upper: list[np.ndarray] = []
        if problem.G is not None and problem.l is not None and problem.u is not None:
            rows.append(sp.coo_matrix(problem.G))
            upper.append(np.asarray(problem.u))
            lower = [np.asarray(problem.l)]
        else:
            lower = []
        for cone in problem.cones:
            k = cone.dim
            s = math.sqrt(k)
            F = sp.coo_matrix(cone.F)
            e_idx = np.flatnonzero(cone.e)
            # Build the 2k rows from COO triplets (duplicates summed, explicit zeros kept),
            # so the pattern depends on the patterns of F and e only, not on values.
            r_e = np.repeat(np.arange(k), e_idx.size)
            c_e = np.tile(e_idx, k)
            v_e = -np.tile(cone.e[e_idx], k)
            rr = np.concatenate([F.row, r_e, F.row + k, r_e + k])
            cc = np.concatenate([F.col, c_e, F.col, c_e])
            vv = np.concatenate([s * F.data, v_e, -s * F.data, v_e])
            rows.append(sp.coo_matrix((vv, (rr, cc)), shape=(2 * k, n)))
            upper.append(np.concatenate([cone.f - s * cone.g, cone.f + s * cone.g]))
            lower.append(np.full(2 * k, -np.inf))
        G = sp.csc_matrix(sp.vstack(rows, format="coo").tocsc())
        return ConvexProblem(
            P=problem.P,
            q=problem.q,
            A_eq=problem.A_eq,
            b_eq=problem.b_eq,
            G=G,
            l=np.concatenate(lower),
            u=np.concatenate(upper),
            lb=problem.lb,
            ub=problem.ub,
            cones=(),
        )
