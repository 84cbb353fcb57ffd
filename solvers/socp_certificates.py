r"""What a finished ``daqp:socp`` solve proves: multipliers and certificates, checked.

The SQP of :mod:`~ltv_lstm_mpc.solvers.socp_sqp` leaves its last iterate, its cone
multipliers :math:`\mu_j` and the multipliers of its last subproblem in the workspace's
arrays (:func:`~ltv_lstm_mpc.solvers.socp_sqp.socp_arrays`). This module reads them, in numpy
(rare paths: once per solve at most):

- :func:`cone_multipliers`: the multipliers in the solver layer's convention, rows and bounds
  as DAQP's, each cone's :math:`(\lambda_0, \lambda_1) = \mu_j (1, -v_j / r_j)`, fitted to
  the stationarity condition at a cone's apex (:func:`apex_cones`);
- :func:`infeasibility_certificate`, :func:`multiplier_certificate`: a Farkas vector of the
  cone problem itself, from the last subproblem's rows and cutting planes or from the SQP's
  growing multipliers;
- :func:`unbounded_certificate`: the last proximal step as a direction of unbounded descent;
- :func:`failure_status`, :func:`max_iter_status`: the layer's status of a solve that did
  not converge, with its reason: ``INFEASIBLE`` or ``UNBOUNDED`` only with a certificate of
  the cone problem itself, never from one subproblem's exit flag; otherwise ``FAILED`` or
  ``MAX_ITER``, naming the cones at whose apex the iterate is (:func:`apex_cones`).

Every certificate is checked on the problem by the acceptance layer
(:mod:`~ltv_lstm_mpc.solvers.acceptance`) before it is returned.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np

from ._base import FloatArray
from .acceptance import (
    CERTIFICATE_TOLERANCE,
    ProblemView,
    check_infeasibility_certificate,
    check_unbounded_direction,
)
from .daqp_ import dense_status
from .problem import SolverStatus
from .socp_sqp import _BIG, MAX_ITERATIONS, SMOOTHING, socp_solve

__all__ = [
    "CERTIFICATE_ROUNDS",
    "apex_cones",
    "cone_multipliers",
    "failure_status",
    "infeasibility_certificate",
    "max_iter_status",
    "multiplier_certificate",
    "unbounded_certificate",
]

#: Rounds of alternating projections of :func:`multiplier_certificate`.
CERTIFICATE_ROUNDS = 20
#: A status with its reason and, for ``INFEASIBLE`` and ``UNBOUNDED``, the checked certificate.
Verdict = tuple[SolverStatus, str, Mapping[str, FloatArray] | None]


def failure_status(
    arrays: Mapping[str, Any],
    ws: Any,
    start: tuple[bool, FloatArray, FloatArray],
    flag: int,
    sqp: int,
    view: ProblemView,
) -> Verdict:
    """The status of a solve that ended with DAQP's exit flag ``flag`` (negative) at SQP
    iteration ``sqp`` on the workspace ``ws`` (arrays ``arrays``, started from ``start``,
    as :func:`multiplier_certificate` takes it) of the problem ``view``: ``INFEASIBLE``
    with a checked certificate of the SOCP's infeasibility, ``UNBOUNDED`` with a checked
    direction of unbounded descent, else ``FAILED`` (or DAQP's other verdicts) with the
    reason."""
    a = arrays
    where = f"exitflag {flag} at SQP iteration {sqp}"
    kept = int(a["cut_state"][2])
    if kept:
        where += f" (its subproblem with the cutting planes of {kept} earlier iterate(s))"
    if flag == -1:  # a subproblem is infeasible: certify the SOCP's infeasibility
        certificate, numbers = infeasibility_certificate(a, view)
        if certificate is None and sqp > 1:
            # the last subproblem solved: the check's own at iteration sqp (the rerun ends
            # there again), else the one before the infeasible one
            rerun = sqp if kept else sqp - 1
            certificate, numbers = multiplier_certificate(a, ws, start, rerun, view, numbers)
        if certificate is not None:
            return SolverStatus.INFEASIBLE, f"{where}; {numbers}", certificate
        why = (
            f"{where}: a subproblem is infeasible, but no certificate of the problem's "
            f"infeasibility checks ({numbers})"
        )
        return SolverStatus.FAILED, why, None
    if flag == -3 and a["regularized"][0]:  # unbounded even with the proximal term
        certificate, numbers = unbounded_certificate(a, view)
        if certificate is not None:
            return SolverStatus.UNBOUNDED, f"{where}; {numbers}", certificate
        where += f"; the last proximal step is no direction of unbounded descent ({numbers})"
    status, _notes = dense_status(flag)
    if status in (SolverStatus.INFEASIBLE, SolverStatus.UNBOUNDED):
        status = SolverStatus.FAILED  # a subproblem's verdict is not the problem's
    return status, where, None


def max_iter_status(arrays: Mapping[str, Any], violation: float, view: ProblemView) -> Verdict:
    """The status after :data:`~ltv_lstm_mpc.solvers.socp_sqp.MAX_ITERATIONS` SQP
    iterations (the cones violated by ``violation``): ``UNBOUNDED`` where the last
    iterations were proximal steps of unbounded subproblems along a checked direction of
    unbounded descent, else ``MAX_ITER`` with the reason."""
    a = arrays
    where = f"{MAX_ITERATIONS} SQP iterations, cone violation {violation:.1e}"
    regularized = int(a["regularized"][0])
    if a["regularized"][1]:
        certificate, numbers = unbounded_certificate(a, view)
        if certificate is not None:
            why = f"{where}; {regularized} subproblems unbounded; {numbers}"
            return SolverStatus.UNBOUNDED, why, certificate
        where += (
            f"; {regularized} subproblems unbounded (proximal steps), the last step is "
            f"no direction of unbounded descent ({numbers})"
        )
    apex = apex_cones(a)
    if apex:
        where += (
            f"; the iterate is at the apex of cone(s) {apex}, where the smoothed cone's "
            "curvature grows and the steps shrink (an interior-point solver, e.g. "
            "clarabel, suits such a problem)"
        )
    return SolverStatus.MAX_ITER, where, None


def cone_multipliers(arrays: Mapping[str, Any]) -> dict[str, FloatArray]:
    """The multipliers of the last iterate in the layer's convention (module docstring).

    At a cone's apex (:func:`apex_cones`) the smoothed cone's :math:`-\\mu_j v_j /
    r_j` is no multiplier of the cone (:math:`v_j \\approx 0` there, while the
    cone's :math:`\\lambda_1` may have any norm up to :math:`\\lambda_0`): those
    cones' :math:`\\lambda_1` are then the least-squares solution of the
    stationarity condition, each shortened into its cone where it is outside, so the
    acceptance check reads the multipliers of the cone itself.
    """
    a = arrays
    n, m, cones = a["H"].shape[0], a["A"].shape[0], a["offsets"].shape[0]
    lam = a["lam"]
    pieces = []
    for j in range(cones):
        v, _F, r = _cone_parts(a, j)
        mu = float(a["mu"][j])
        pieces.append(np.concatenate([[mu], -mu * v / r]))
    apex = apex_cones(a) if cones else []
    if apex:
        _apex_multipliers(a, pieces, apex)
    stacked = np.concatenate(pieces) if pieces else np.zeros(0)
    return {"ineq": lam[n : n + m].copy(), "bounds": lam[:n].copy(), "cones": stacked}


def _apex_multipliers(arrays: Mapping[str, Any], pieces: list[FloatArray], apex: list[int]) -> None:
    """Replace the :math:`\\lambda_1` of the cones in ``apex`` (see :func:`cone_multipliers`)."""
    a = arrays
    n, m = a["H"].shape[0], a["A"].shape[0]
    z, lam = a["z"], a["lam"]
    rhs = a["H"] @ z + a["f"] + a["A"].T @ lam[n : n + m] + lam[:n]
    for j in range(len(pieces)):
        rhs -= pieces[j][0] * a["e"][j]
        if j not in apex:
            _v, F, _r = _cone_parts(a, j)
            rhs -= F.T @ pieces[j][1:]
    blocks = [_cone_parts(a, j)[1] for j in apex]
    solution = np.linalg.lstsq(np.vstack(blocks).T, rhs, rcond=None)[0]
    start = 0
    for j, F in zip(apex, blocks, strict=True):
        lam1 = solution[start : start + F.shape[0]]
        start += F.shape[0]
        size = float(np.linalg.norm(lam1))
        if size > pieces[j][0]:
            lam1 = lam1 * (pieces[j][0] / size)
        pieces[j] = np.concatenate([[pieces[j][0]], lam1])


def multiplier_certificate(
    arrays: Mapping[str, Any],
    ws: Any,
    start: tuple[bool, FloatArray, FloatArray],
    iterations: int,
    view: ProblemView,
    why: str,
) -> tuple[dict[str, FloatArray] | None, str]:
    """A Farkas vector from the multipliers of the last solved subproblem.

    On an infeasible problem the SQP's multipliers grow without bound along a Farkas
    direction (the cutting planes at the last iterate may still be feasible, so that
    :func:`infeasibility_certificate` finds none). The solve on the workspace ``ws`` (whose
    arrays are ``arrays``) is run again from ``start`` (``(warm, z, mu)`` of the solve)
    for ``iterations`` (the same iterates: it is deterministic), and the multipliers of
    its last subproblem, rows, bounds and each cone's :math:`\\mu_j (1, -v_j / r_j)`,
    are projected onto :math:`\\sum M^\\top y - \\sum (\\lambda_0 e +
    F^\\top \\lambda_1) = 0` (least change of their nonzero entries), then checked
    by :func:`~ltv_lstm_mpc.solvers.acceptance.check_infeasibility_certificate` on
    ``view``. Returns ``(None, why)`` with the reasons where it does not check.
    """
    a = arrays
    warm, z0, mu0 = start
    a["z"][:] = z0
    a["mu"][:] = mu0
    socp_solve(ws, warm, iterations)
    n, m, cones = a["H"].shape[0], a["A"].shape[0], a["offsets"].shape[0]
    lam = a["lam"]
    y = np.concatenate([lam[n : n + m], lam[:n]])
    columns = [a["A"].T, np.eye(n)]  # d total / d y, rows then bounds
    pieces = []
    for j in range(cones):
        v, F, r = _cone_parts(a, j)
        mu = float(a["mu"][j])
        pieces.append(np.concatenate([[mu], -mu * v / r]))
        columns.append(-np.hstack([a["e"][j][:, None], F.T]))
    vector = np.concatenate([y, *pieces])
    K = np.hstack(columns)
    free = vector != 0.0  # the nonzero entries move (a zero stays: its sign is free)
    for j, piece in enumerate(pieces):  # a cone with mu > 0: all its entries
        if piece[0] > 0.0:
            begin = m + n + sum(p.shape[0] for p in pieces[:j])
            free[begin : begin + piece.shape[0]] = True
    if not free.any():
        return None, why
    sizes = [p.shape[0] for p in pieces]
    vector = vector.copy()
    numbers = ""
    for _ in range(CERTIFICATE_ROUNDS):  # alternating projections
        delta = np.linalg.lstsq(K[:, free], -(K @ vector), rcond=None)[0]
        vector[free] += delta
        certificate = {
            "ineq": vector[:m].copy(),
            "bounds": vector[m : m + n].copy(),
            "cones": vector[m + n :].copy(),
        }
        valid, numbers = check_infeasibility_certificate(view, certificate, CERTIFICATE_TOLERANCE)
        if valid:
            return certificate, f"infeasibility certificate of the SOCP ({numbers})"
        begin = m + n
        for size in sizes:  # each cone's entries onto the second-order cone
            vector[begin : begin + size] = _cone_projection(vector[begin : begin + size])
            begin += size
    return None, f"{why}; from the multipliers: {numbers}"


def _cone_parts(
    arrays: Mapping[str, Any], j: int, point: FloatArray | None = None
) -> tuple[FloatArray, FloatArray, float]:
    """Cone j's :math:`v = F_j z + g_j` at the iterate (or at ``point``), its rows of ``F``
    and the smoothed :math:`r_j = \\sqrt{\\|v\\|^2 + s^2}`."""
    start, stop = int(arrays["cone_rows"][j]), int(arrays["cone_rows"][j + 1])
    F = arrays["F"][start:stop]
    v = F @ (arrays["z"] if point is None else point) + arrays["g"][start:stop]
    return v, F, float(np.sqrt(v @ v + SMOOTHING**2))


def _cone_projection(entries: FloatArray) -> FloatArray:
    """The projection of :math:`(\\lambda_0, \\lambda_1)` onto the second-order cone."""
    l0, l1 = float(entries[0]), entries[1:]
    size = float(np.linalg.norm(l1))
    if size <= l0:
        return entries
    if size <= -l0:
        return np.zeros_like(entries)
    scale = 0.5 * (l0 + size)
    return np.concatenate([[scale], scale * l1 / size])


def apex_cones(arrays: Mapping[str, Any]) -> list[int]:
    """The cones whose :math:`\\|F_j z + g_j\\|` at the iterate is within 100 times
    :data:`SMOOTHING` of the apex (relative to ``1 + |z|``)."""
    scale = 1.0 + float(np.max(np.abs(arrays["z"]), initial=0.0))
    out = []
    for j in range(arrays["offsets"].shape[0]):
        v, _F, _r = _cone_parts(arrays, j)
        if float(np.linalg.norm(v)) <= 100.0 * SMOOTHING * scale:
            out.append(j)
    return out


def infeasibility_certificate(
    arrays: Mapping[str, Any], view: ProblemView
) -> tuple[dict[str, FloatArray] | None, str]:
    r"""A Farkas vector of the SOCP from its last subproblem, checked; ``(None, why)`` if none.

    The subproblem's rows are the problem's rows and bounds and each cone's linearization
    at the iterate :math:`z_k`, :math:`a_j^\top x \le b_j` with :math:`a_j = F_j^\top
    v_j / r_j - e_j` (an outer cutting plane of the smoothed cone); where the SQP's
    infeasibility check ended the solve (``cut_state[2]`` > 0), also each cone's
    linearizations at the earlier iterates it kept (``cut_points``), all of them then as
    the check has them: planes of the unsmoothed cones (each bound relaxed by
    :math:`s^2 / r`, :mod:`~ltv_lstm_mpc.solvers.socp_sqp`'s infeasibility check). Stacked as
    :math:`l \le C x \le u`, the vector :math:`y = y^+ - y^-` of the least-norm problem

    .. math::

        \min_{y^\pm \ge 0} \tfrac12 \|y^+\|^2 + \tfrac12 \|y^-\|^2 + u^\top y^+ -
        l^\top y^- \quad\text{s.t.}\quad C^\top (y^+ - y^-) = 0

    (the dual of the least squared violation; solved by DAQP) has a negative support value
    :math:`u^\top y^+ - l^\top y^- = -\|y\|^2` where the subproblem is infeasible. A
    cut's multiplier :math:`\mu` is the cone multiplier :math:`(\lambda_0, \lambda_1)
    = \mu (1, -v / r)` (in the cone: :math:`\|v\| \le r`), and the sum of a cone's
    over its cuts is in the cone too, so :math:`y` is a certificate of the SOCP itself,
    checked on it by :func:`~ltv_lstm_mpc.solvers.acceptance.check_infeasibility_certificate`
    (its support value exceeds the subproblem's by :math:`\mu s^2 / r` per smoothed cut).
    """
    import daqp

    H, A = arrays["H"], arrays["A"]
    n, m = H.shape[0], A.shape[0]
    cones = arrays["offsets"].shape[0]
    kept = int(arrays["cut_state"][2])
    points = [arrays["z"], *arrays["cut_points"][:kept]]
    cuts = np.zeros((cones * len(points), n))
    cut_bounds = np.zeros(cones * len(points))
    parts: list[tuple[int, FloatArray, float]] = []
    for point in points:
        for j in range(cones):
            v, F, r = _cone_parts(arrays, j, point)
            row = len(parts)
            cuts[row] = F.T @ v / r - arrays["e"][j]
            value = r - float(arrays["e"][j] @ point) - float(arrays["offsets"][j])
            # the check's planes are the unsmoothed cones' (shifted by s^2 / r)
            slack = SMOOTHING**2 / r if kept else 0.0
            cut_bounds[row] = float(cuts[row] @ point) - value + slack
            parts.append((j, v, r))
    C = np.vstack([A, np.eye(n), cuts])
    upper = np.concatenate([arrays["up"], arrays["ub"], cut_bounds])
    lower = np.concatenate([arrays["lo"], arrays["lb"], np.full(cut_bounds.shape[0], -np.inf)])
    p = C.shape[0]
    upper_w = np.where(np.isfinite(upper), np.inf, 0.0)  # y+ only at a finite upper bound
    lower_w = np.where(np.isfinite(lower), np.inf, 0.0)
    cost = np.concatenate([np.where(np.isfinite(upper), upper, 0.0),
                           -np.where(np.isfinite(lower), lower, 0.0)])  # fmt: skip
    rows = np.hstack([C.T, -C.T])
    bounds_up = np.concatenate([np.minimum(np.concatenate([upper_w, lower_w]), _BIG), np.zeros(n)])
    bounds_lo = np.concatenate([np.zeros(2 * p), np.zeros(n)])
    sense = np.zeros(2 * p + n, dtype=np.int32)
    sense[2 * p :] = 5  # equalities (DAQP: active and immutable)
    w, _value, flag, _info = daqp.solve(np.eye(2 * p), cost, rows, bounds_up, bounds_lo, sense)
    if flag not in (1, 2):
        return None, f"the certificate's QP ended with DAQP exit flag {flag}"
    y = w[:p] - w[p:]
    pieces = [np.zeros(1 + v.shape[0]) for (_j, v, _r) in parts[:cones]]
    for row, (j, v, r) in enumerate(parts):  # each cone's cuts' multipliers, summed
        pieces[j][0] += y[m + n + row]
        pieces[j][1:] -= y[m + n + row] * v / r
    lam = np.concatenate(pieces) if cones else np.zeros(0)
    certificate = {"ineq": y[:m], "bounds": y[m : m + n], "cones": lam}
    valid, numbers = check_infeasibility_certificate(view, certificate, CERTIFICATE_TOLERANCE)
    if not valid:
        return None, numbers
    return certificate, f"infeasibility certificate of the SOCP ({numbers})"


def unbounded_certificate(
    arrays: Mapping[str, Any], view: ProblemView
) -> tuple[dict[str, FloatArray] | None, str]:
    """The last proximal step (``arrays["direction"]``) as a direction of unbounded descent
    of the SOCP, checked by
    :func:`~ltv_lstm_mpc.solvers.acceptance.check_unbounded_direction`; ``(None, why)``
    where it does not check."""
    direction = np.array(arrays["direction"])
    valid, numbers = check_unbounded_direction(view, direction, CERTIFICATE_TOLERANCE)
    if not valid:
        return None, numbers
    size = float(np.max(np.abs(direction)))
    return {"direction": direction / size}, f"direction of unbounded descent ({numbers})"
