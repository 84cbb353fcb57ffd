"""The distance of a cone problem's ``OPTIMAL`` point from its solution (acceptance).

A module of its own, beside :mod:`~ltv_lstm_mpc.solvers.acceptance`: the check runs the
local SQP of :mod:`~ltv_lstm_mpc.solvers.daqp_socp`, which itself uses the acceptance
layer's certificate checks (one direction of import, no cycle).
"""

from __future__ import annotations

import dataclasses
from typing import Any

import numpy as np

from ._base import RawResult
from .acceptance import _inf_norm
from .problem import SolverStatus

__all__ = ["POINT_FACTOR", "check_cone_point"]


#: A cone problem's ``OPTIMAL`` point farther than this times the optimality tolerance
#: (relative to ``1 + |z|``) from the local SQP's solution is ``OPTIMAL_INACCURATE``
#: (:func:`check_cone_point`).
POINT_FACTOR = 10.0


def check_cone_point(qp: Any, raw: RawResult, optimality: float) -> RawResult:
    r"""Hold an ``OPTIMAL`` point of a problem with cones to the distance from the solution.

    The KKT residuals of :func:`~ltv_lstm_mpc.solvers.acceptance.accept` bound a QP's
    distance from its solution (the Hessian is positive definite), not a second-order-cone
    problem's: where the curvature is all in a cone (a QP's epigraph written as a cone, the
    form qpsolvers hands QPs to ECOS in) residuals of :math:`\epsilon` allow a distance of
    order :math:`\sqrt{\epsilon}` (CLARABEL at tolerance 1e-8: residuals 1e-9, distance up
    to 9e-5 on the SOCP versions of qpsolvers' test problems). So the point is refined by
    the local method, the SQP of ``daqp:socp`` started from it and its cone multipliers
    (``daqp_socp.local_solution``: quadratic convergence near the
    solution), and a point farther than :data:`POINT_FACTOR` times ``optimality`` (relative
    to ``1 + |z|``) from the refined one becomes ``OPTIMAL_INACCURATE`` with the distance in
    the notes. Where ``daqp:socp`` is unavailable or does not converge, the status stays and
    a note says the point was not checked.

    Parameters
    ----------
    qp : DenseQP
        The problem solved (with cones; without, ``raw`` is returned as it is).
    raw : RawResult
        The answer after :func:`accept`.
    optimality : float
        :func:`~ltv_lstm_mpc.solvers.optimality_tolerance` of the solver.
    """
    if raw.status is not SolverStatus.OPTIMAL or raw.z is None or not qp.cones:
        return raw
    from .daqp_socp import local_solution  # imported here: DAQP is an optional extra

    cones = None if raw.duals is None else raw.duals.get("cones")
    refined, why = local_solution(qp, np.asarray(raw.z), cones)
    if refined is None:
        return dataclasses.replace(
            raw, notes=(*raw.notes, f"distance from the solution not checked: {why}")
        )
    distance = _inf_norm(refined - raw.z) / (1.0 + _inf_norm(refined))
    limit = POINT_FACTOR * optimality
    if distance <= limit:
        return raw
    note = (
        f"acceptance: OPTIMAL -> OPTIMAL_INACCURATE: the point is {distance:.1e} (relative) "
        f"from the local SQP's solution from it ({why}), above {limit:.1e}"
    )
    return dataclasses.replace(
        raw, status=SolverStatus.OPTIMAL_INACCURATE, notes=(*raw.notes, note)
    )
