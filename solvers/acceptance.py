r"""The layer's acceptance check of every backend's answer (one rule for all backends).

A backend's own status is a claim; this module checks it on the problem that was solved
before :class:`~ltv_lstm_mpc.solvers.Session` or :class:`~ltv_lstm_mpc.solvers.DenseSession`
passes it on, so a wrong ``OPTIMAL`` never reaches a caller.

The rule
--------
Both problem forms are read as rows :math:`lo \le M z \le up` (equalities have
``lo = up``; variable bounds are rows with :math:`M = I`) and cones
:math:`\|F z + g\| \le e^\top z + f`, with multipliers in the layer's sign convention
(:math:`P z + q + \sum M^\top y - \sum (\lambda_0 e + F^\top \lambda_1) = 0`, ``y > 0``
where the upper bound is active, ``y < 0`` where the lower one is, :math:`(\lambda_0,
\lambda_1)` in the second-order cone). Three relative residuals (:class:`Residuals`):

``primal``
    the largest violation of a row or cone, each divided by ``1 + |bound|``;
``stationarity``
    the largest component of :math:`P z + q + \sum M^\top y - \dots`, each divided by
    ``1 +`` the largest of its own terms (per variable, so a change of units of one
    variable does not hide its residual behind another's large terms; multipliers of the
    wrong sign for an infinite bound count as 0);
``complementarity``
    the duality gap :math:`\sum_i y_i^+ (up_i - M_i z) + y_i^- (M_i z - lo_i) + \dots`
    divided by ``1 + max(|z'Pz|, |q'z|, sum |y_i bound_i|)``.

A point reported ``OPTIMAL`` (or ``OPTIMAL_INACCURATE``) keeps its status when it is
finite, ``primal <= feasibility_tolerance(solver, tolerance)`` and, where the backend
returned every multiplier the residuals need, ``stationarity`` and ``complementarity``
``<= optimality_tolerance(solver, tolerance)``. Within ``INACCURATE_FACTOR`` (100) times
those tolerances it becomes ``OPTIMAL_INACCURATE`` with the residuals in ``info``;
beyond, ``FAILED`` with the reason, and no point is returned (the layer also tries the
point's own direction as a certificate of unboundedness first: a backend that stopped
far out on a ray of unbounded descent is reported ``UNBOUNDED``). Without multipliers
(backends that give none, or the cones' where they are not reported) only ``primal`` is
checked, and :attr:`Residuals.unchecked` says why.

``INFEASIBLE`` and ``UNBOUNDED`` are passed on as the backend reports them, except
where it returns a certificate (:attr:`RawResult.certificate`: native OSQP and
CLARABEL do): a Farkas vector ``y`` (:math:`\sum M^\top y = 0` and
:math:`\sum up_i y_i^+ - lo_i y_i^- < 0`, to ``certificate_tolerance`` relative to
``||y||``) or a direction ``d`` of unbounded descent (:math:`P d = 0`, :math:`q^\top
d < 0`, ``d`` in the recession cone of the rows and cones). A certificate that does
not check turns the status into ``FAILED`` with the measured numbers.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np
import scipy.sparse as sp

from ._base import FloatArray, RawResult
from ._compiled import dense_kkt_residuals
from .problem import SolverStatus

__all__ = [
    "CERTIFICATE_TOLERANCE",
    "INACCURATE_FACTOR",
    "ConeBlock",
    "ProblemView",
    "Residuals",
    "RowBlock",
    "accept",
    "check_infeasibility_certificate",
    "check_unbounded_direction",
    "qpbenchmark_residuals",
    "residuals",
]

#: A point within this factor of the tolerances is ``OPTIMAL_INACCURATE``, beyond ``FAILED``.
INACCURATE_FACTOR = 100.0
#: Relative tolerance of the certificate checks (OSQP's default ``eps_prim_inf``).
CERTIFICATE_TOLERANCE = 1e-5


@dataclass(frozen=True)
class RowBlock:
    """Rows ``lower <= matrix @ z <= upper`` whose multipliers are ``duals[key]``.

    ``matrix=None`` is the identity (variable bounds).
    """

    key: str
    matrix: Any
    lower: FloatArray
    upper: FloatArray

    def product(self, z: FloatArray) -> FloatArray:
        """``matrix @ z``."""
        return z if self.matrix is None else np.asarray(self.matrix @ z, dtype=np.float64)

    def transpose_product(self, y: FloatArray) -> FloatArray:
        """``matrix.T @ y``."""
        return y if self.matrix is None else np.asarray(self.matrix.T @ y, dtype=np.float64)

    @property
    def size(self) -> int:
        """Number of rows."""
        return int(self.lower.shape[0])


@dataclass(frozen=True)
class ConeBlock:
    r"""One cone :math:`\|F z + g\| \le e^\top z + f`."""

    F: Any
    g: FloatArray
    e: FloatArray
    f: float


class ProblemView:
    """Either problem form as rows and cones (:meth:`of_convex`, :meth:`of_dense`).

    A DenseQP's rows and cones are built only when asked for: the compiled residuals of a
    cone-free DenseQP read the QP itself (:attr:`dense`).
    """

    def __init__(
        self,
        P: Any,
        q: FloatArray,
        rows: tuple[RowBlock, ...] | None = None,
        cones: tuple[ConeBlock, ...] | None = None,
        dense: Any = None,
    ) -> None:
        """``rows``/``cones`` may be left out only with ``dense`` (built from it on use)."""
        self.P = P
        self.q = q
        #: the DenseQP viewed (its cone-free residuals run compiled), ``None`` otherwise
        self.dense = dense
        self._rows = rows
        self._cones = cones

    @classmethod
    def of_convex(cls, problem: Any) -> ProblemView:
        """Rows ``eq`` (``A_eq``, ``b_eq``), ``ineq`` (``G``, ``l``, ``u``), ``bounds``."""
        rows = []
        if problem.A_eq is not None:
            rows.append(RowBlock("eq", problem.A_eq, problem.b_eq, problem.b_eq))
        if problem.G is not None:
            rows.append(RowBlock("ineq", problem.G, problem.l, problem.u))
        if problem.lb is not None:
            rows.append(RowBlock("bounds", None, problem.lb, problem.ub))
        cones = tuple(ConeBlock(c.F, c.g, c.e, c.f) for c in problem.cones)
        return cls(problem.P, np.asarray(problem.q), tuple(rows), cones)

    @classmethod
    def of_dense(cls, qp: Any) -> ProblemView:
        """Rows ``ineq`` (``A``, ``lo``, ``up``) and ``bounds`` of a DenseQP."""
        return cls(qp.H, qp.f, dense=qp)

    @property
    def rows(self) -> tuple[RowBlock, ...]:
        """The row blocks (a DenseQP's: ``ineq`` where it has rows, then ``bounds``)."""
        if self._rows is None:
            qp = self.dense
            rows = [RowBlock("bounds", None, np.asarray(qp.lb), np.asarray(qp.ub))]
            if qp.A.shape[0]:
                rows.insert(0, RowBlock("ineq", qp.A, np.asarray(qp.lo), np.asarray(qp.up)))
            self._rows = tuple(rows)
        return self._rows

    @property
    def cones(self) -> tuple[ConeBlock, ...]:
        """The second-order cones."""
        if self._cones is None:
            self._cones = tuple(ConeBlock(c.F, c.g, c.e, float(c.f)) for c in self.dense.cones)
        return self._cones

    @property
    def n(self) -> int:
        """Number of variables."""
        return int(self.q.shape[0])


@dataclass(frozen=True, slots=True)
class Residuals:
    """Relative residuals of a returned point (see the module docstring).

    ``stationarity`` and ``complementarity`` are ``None`` where they could not be
    computed; ``unchecked`` says why (empty when every residual was computed).
    """

    primal: float
    stationarity: float | None
    complementarity: float | None
    unchecked: str = ""

    def describe(self) -> str:
        """One line: ``primal 1.2e-09, stationarity 3.4e-10, complementarity 5.6e-11``."""
        parts = [f"primal {self.primal:.2e}"]
        if self.stationarity is not None:
            parts.append(f"stationarity {self.stationarity:.2e}")
        if self.complementarity is not None:
            parts.append(f"complementarity {self.complementarity:.2e}")
        if self.unchecked:
            parts.append(f"KKT not checked: {self.unchecked}")
        return ", ".join(parts)


def _inf_norm(v: FloatArray) -> float:
    return float(np.max(np.abs(v), initial=0.0))


@dataclass(frozen=True)
class _Stacked:
    """Every row block of a view at one point, as flat arrays (few numpy calls per check)."""

    r: FloatArray
    lower: FloatArray
    upper: FloatArray
    finite_lower: Any
    finite_upper: Any
    offsets: tuple[int, ...]

    @classmethod
    def at(cls, view: ProblemView, z: FloatArray) -> _Stacked:
        blocks = view.rows
        if len(blocks) == 1:
            b = blocks[0]
            r, lower, upper = b.product(z), b.lower, b.upper
        else:
            r = np.concatenate([b.product(z) for b in blocks]) if blocks else np.zeros(0)
            lower = np.concatenate([b.lower for b in blocks]) if blocks else np.zeros(0)
            upper = np.concatenate([b.upper for b in blocks]) if blocks else np.zeros(0)
        offsets = tuple(np.cumsum([0, *(b.size for b in blocks)]).tolist())
        return cls(r, lower, upper, np.isfinite(lower), np.isfinite(upper), offsets)


def _primal(view: ProblemView, z: FloatArray, stacked: _Stacked) -> float:
    r, lower, upper = stacked.r, stacked.lower, stacked.upper
    worst = 0.0
    if r.size:
        # an infinite bound gives 0 / inf = 0 (never NaN: r is finite)
        over = np.maximum(r - upper, 0.0) / (1.0 + np.abs(upper))
        under = np.maximum(lower - r, 0.0) / (1.0 + np.abs(lower))
        worst = max(float(over.max()), float(under.max()))
    for cone in view.cones:
        s0 = float(cone.e @ z) + cone.f
        s1 = np.asarray(cone.F @ z) + cone.g
        worst = max(worst, (math.sqrt(float(s1 @ s1)) - s0) / (1.0 + abs(s0)))
    return worst


def _dual_vector(
    duals: Mapping[str, FloatArray] | None, key: str, size: int
) -> tuple[FloatArray | None, str]:
    if duals is None:
        return None, "the backend returned no multipliers"
    y = duals.get(key)
    if y is None:
        return None, f"no multipliers for the {key!r} rows"
    y = np.asarray(y, dtype=np.float64)
    if y.shape != (size,) or not math.isfinite(float(np.add.reduce(y))):
        return None, f"multipliers for the {key!r} rows are malformed or non-finite"
    return y, ""


def _admissible(y: FloatArray, block: RowBlock) -> FloatArray:
    """``y`` with the entries of the wrong sign for an infinite bound set to 0."""
    return np.where(
        (y > 0) & ~np.isfinite(block.upper) | (y < 0) & ~np.isfinite(block.lower), 0.0, y
    )


def residuals(
    view: ProblemView, z: FloatArray, duals: Mapping[str, FloatArray] | None
) -> Residuals:
    """The :class:`Residuals` of ``z`` with the multipliers ``duals`` (may be ``None``).

    A cone-free DenseQP with every multiplier runs the same arithmetic compiled
    (:func:`~ltv_lstm_mpc.solvers._compiled.dense_kkt_residuals`, tested against this code).
    """
    qp = view.dense
    if qp is not None and not qp.cones and duals is not None:
        m, n = qp.A.shape
        y_rows = duals.get("ineq") if m else _EMPTY
        y_bounds = duals.get("bounds")
        if (
            isinstance(y_rows, np.ndarray)
            and isinstance(y_bounds, np.ndarray)
            and y_rows.shape == (m,)
            and y_bounds.shape == (n,)
            and y_rows.dtype == y_bounds.dtype == np.float64
        ):
            out = np.empty(4)
            dense_kkt_residuals(
                qp.H, qp.f, qp.A, qp.lo, qp.up, qp.lb, qp.ub, z, y_rows, y_bounds, out
            )
            if out[3] == 0.0:  # else a multiplier is not finite: the numpy path says which
                return Residuals(float(out[0]), float(out[1]), float(out[2]))
    return _residuals(view, z, duals)


_EMPTY = np.zeros(0)


def _residuals(
    view: ProblemView, z: FloatArray, duals: Mapping[str, FloatArray] | None
) -> Residuals:
    """The numpy residuals (the reference of the compiled kernel; every problem form)."""
    stacked = _Stacked.at(view, z)
    primal = _primal(view, z, stacked)
    parts = []
    for block in view.rows:
        y, why = _dual_vector(duals, block.key, block.size)
        if y is None:
            return Residuals(primal, None, None, why)
        parts.append(y)
    lam: FloatArray | None = None
    if view.cones:
        size = sum(int(c.g.shape[0]) + 1 for c in view.cones)
        lam, why = _dual_vector(duals, "cones", size)
        if lam is None:
            why = "cone multipliers not reported" if duals is not None else why
            return Residuals(primal, None, None, why)
    Pz = np.asarray(view.P @ z, dtype=np.float64)
    gradient = Pz + view.q
    # per variable: the largest term of that component of the gradient (scale-invariant)
    scale = np.maximum(np.abs(Pz), np.abs(view.q))
    gap_scale = max(abs(float(z @ Pz)), abs(float(view.q @ z)))
    gap = 0.0
    if parts:
        y = parts[0] if len(parts) == 1 else np.concatenate(parts)
        fin_lo, fin_up = stacked.finite_lower, stacked.finite_upper
        # multipliers of the wrong sign for an infinite bound count as 0
        y_up = np.where(fin_up, np.maximum(y, 0.0), 0.0)
        y_lo = np.where(fin_lo, np.minimum(y, 0.0), 0.0)
        y = y_up + y_lo
        offsets = stacked.offsets
        for k, block in enumerate(view.rows):
            term = block.transpose_product(y[offsets[k] : offsets[k + 1]])
            gradient += term
            np.maximum(scale, np.abs(term), out=scale)
        slack_up = np.where(fin_up, stacked.upper - stacked.r, 0.0)
        slack_lo = np.where(fin_lo, stacked.r - stacked.lower, 0.0)
        gap = float(y_up @ np.maximum(slack_up, 0.0)) - float(y_lo @ np.maximum(slack_lo, 0.0))
        bound_up = np.where(fin_up, stacked.upper, 0.0)
        bound_lo = np.where(fin_lo, stacked.lower, 0.0)
        gap_scale = max(
            gap_scale,
            float(np.abs(y_up) @ np.abs(bound_up)) + float(np.abs(y_lo) @ np.abs(bound_lo)),
        )
    outside = 0.0
    if lam is not None:
        offset = 0
        for cone in view.cones:
            k = int(cone.g.shape[0])
            l0, l1 = float(lam[offset]), lam[offset + 1 : offset + 1 + k]
            offset += k + 1
            term = l0 * np.asarray(cone.e) + np.asarray(cone.F.T @ l1)
            gradient -= term
            np.maximum(scale, np.abs(term), out=scale)
            s0 = float(cone.e @ z) + cone.f
            s1 = np.asarray(cone.F @ z) + cone.g
            gap += abs(l0 * s0 + float(l1 @ s1))
            gap_scale = max(gap_scale, abs(l0 * cone.f) + abs(float(l1 @ cone.g)))
            # a multiplier outside the second-order cone is a dual infeasibility
            outside = max(outside, (math.sqrt(float(l1 @ l1)) - l0) / (1.0 + abs(l0)))
    stationarity = max(float((np.abs(gradient) / (1.0 + scale)).max(initial=0.0)), outside)
    complementarity = gap / (1.0 + gap_scale)
    return Residuals(primal, stationarity, complementarity)


def qpbenchmark_residuals(
    view: ProblemView, z: FloatArray, duals: Mapping[str, FloatArray] | None
) -> tuple[float, float, float]:
    r"""qpbenchmark's metrics of the point ``z`` with the multipliers ``duals``: the
    absolute primal residual, dual residual and duality gap of qpsolvers' ``Solution``
    (``primal_residual``, ``dual_residual``, ``duality_gap``), read on the rows and bounds
    of ``view`` in this layer's sign convention (module docstring).

    With :math:`lo \le M z \le up` for every row block (equalities ``lo = up``, bounds
    :math:`M = I`):

    .. math::

        r_p = \max(0, \max_i (M_i z - up_i), \max_i (lo_i - M_i z)), \quad
        r_d = \|P z + q + \textstyle\sum M^\top y\|_\infty, \quad
        r_g = |z^\top P z + q^\top z + \textstyle\sum_i g_i|

    over the finite sides, with the multipliers as the solver gave them (no clipping) and
    :math:`g_i` qpsolvers' term of row ``i``: :math:`up_i y_i` for a row with only an upper
    side (its ``G x <= h`` row), :math:`lo_i y_i` for one with only a lower side, and
    :math:`up_i y_i^+ + lo_i y_i^-` for the variable bounds and two-sided rows (the finite
    sides of ``lb``, ``ub`` in qpsolvers: :math:`y^+ = \max(y, 0)`, :math:`y^- = \min(y,
    0)`). On a problem whose rows are one-sided (``G x <= h``, ``A x = b``) and whose bounds
    are finite, as qpbenchmark's, these are qpsolvers' numbers for the same point and
    multipliers; on a two-sided row this layer holds one multiplier where qpsolvers' split
    form holds two, so a solver that returns both sides nonzero (interior-point methods, by
    tiny amounts) gets a slightly different gap. ``inf`` where a multiplier the residuals
    need is missing; a problem with cones is refused (qpbenchmark is QP-only).

    Raises
    ------
    ValueError
        ``view`` has cones.
    """
    if view.cones:
        raise ValueError("qpbenchmark's residuals are defined for QPs; this problem has cones")
    z = np.asarray(z, dtype=np.float64)
    stacked = _Stacked.at(view, z)
    r, lower, upper = stacked.r, stacked.lower, stacked.upper
    fin_up, fin_lo = stacked.finite_upper, stacked.finite_lower
    primal = 0.0
    if r.size:
        over = np.where(fin_up, r - np.where(fin_up, upper, 0.0), -np.inf)
        under = np.where(fin_lo, np.where(fin_lo, lower, 0.0) - r, -np.inf)
        primal = max(0.0, float(over.max()), float(under.max()))
    Pz = np.asarray(view.P @ z, dtype=np.float64)
    gradient = Pz + view.q
    gap = float(z @ Pz) + float(view.q @ z)
    for k, block in enumerate(view.rows):
        y, _ = _dual_vector(duals, block.key, block.size)
        if y is None:
            return primal, math.inf, math.inf
        part = slice(stacked.offsets[k], stacked.offsets[k + 1])
        up, lo = fin_up[part], fin_lo[part]
        gradient += block.transpose_product(y)
        u = np.where(up, upper[part], 0.0)
        lw = np.where(lo, lower[part], 0.0)
        split = (up & lo) | (block.key == "bounds")  # both sides in one multiplier
        term = np.where(
            split,
            u * np.maximum(y, 0.0) + lw * np.minimum(y, 0.0),
            np.where(up, u * y, lw * y),
        )
        gap += float(np.sum(term))
    return primal, _inf_norm(gradient), abs(gap)


def check_infeasibility_certificate(
    view: ProblemView, certificate: Mapping[str, FloatArray], tolerance: float
) -> tuple[bool, str]:
    r"""Check a Farkas vector: :math:`\sum M^\top y \approx 0` and the support value ``< 0``.

    Cones' entries (``certificate["cones"]``, :math:`(\lambda_0, \lambda_1)` per cone)
    are included where the problem has cones, and must lie in the (self-dual) cone,
    :math:`\|\lambda_1\| \le \lambda_0`, to the tolerance relative to ``|y|``.
    Returns ``(valid, measured numbers)``.
    """
    total = np.zeros(view.n)
    support = 0.0
    size = 0.0
    outside = 0.0  # largest |lambda_1| - lambda_0 of the cones' entries
    for block in view.rows:
        y, why = _dual_vector(certificate, block.key, block.size)
        if y is None:
            return False, why
        y = _admissible(y, block)  # a ray may not use an infinite bound
        pos, neg = y > 0, y < 0
        total += block.transpose_product(y)
        support += float(np.sum(y[pos] * block.upper[pos])) + float(
            np.sum(y[neg] * block.lower[neg])
        )
        size = max(size, _inf_norm(y))
    if view.cones:
        n_cone = sum(int(c.g.shape[0]) + 1 for c in view.cones)
        lam, why = _dual_vector(certificate, "cones", n_cone)
        if lam is None:
            return False, why
        offset = 0
        for cone in view.cones:
            k = int(cone.g.shape[0])
            l0, l1 = float(lam[offset]), lam[offset + 1 : offset + 1 + k]
            offset += k + 1
            total -= l0 * np.asarray(cone.e) + np.asarray(cone.F.T @ l1)
            support += l0 * cone.f + float(l1 @ cone.g)
            size = max(size, abs(l0), _inf_norm(l1))
            outside = max(outside, math.sqrt(float(l1 @ l1)) - l0)
    if size == 0.0:
        return False, "the certificate is zero"
    residual = _inf_norm(total) / size
    value = support / size
    valid = residual <= tolerance and value < -tolerance and outside / size <= tolerance
    numbers = f"|sum M'y| / |y| = {residual:.2e}, support value / |y| = {value:.2e}"
    if outside > 0.0:
        numbers += f", cone multipliers outside their cone by {outside / size:.2e} (relative)"
    return valid, numbers


def check_unbounded_direction(
    view: ProblemView, direction: FloatArray, tolerance: float
) -> tuple[bool, str]:
    r"""Check a direction of unbounded descent ``d``: :math:`P d = 0`, :math:`q^\top d < 0`,
    ``d`` in the recession cone of every row and cone (relative to ``||d||``).

    Returns ``(valid, measured numbers)``.
    """
    d = np.asarray(direction, dtype=np.float64)
    size = _inf_norm(d)
    if d.shape != view.q.shape or not math.isfinite(size) or size == 0.0:
        return False, "the direction is zero, non-finite or of the wrong shape"
    d = d / size
    curvature = _inf_norm(np.asarray(view.P @ d)) / (1.0 + _matrix_scale(view.P))
    descent = float(view.q @ d) / (1.0 + _inf_norm(view.q))
    recession = 0.0
    for block in view.rows:
        r = block.product(d)
        scale = 1.0 + (1.0 if block.matrix is None else _matrix_scale(block.matrix))
        up = np.where(np.isfinite(block.upper), r, 0.0)
        lo = np.where(np.isfinite(block.lower), -r, 0.0)
        recession = max(recession, float(np.max(up, initial=0.0)) / scale)
        recession = max(recession, float(np.max(lo, initial=0.0)) / scale)
    for cone in view.cones:
        s1 = np.asarray(cone.F @ d)
        recession = max(recession, math.sqrt(float(s1 @ s1)) - float(cone.e @ d))
    valid = curvature <= tolerance and descent < -tolerance and recession <= tolerance
    return valid, (
        f"|P d| = {curvature:.2e}, q'd = {descent:.2e}, recession violation {recession:.2e} "
        "(relative, |d| = 1)"
    )


def _matrix_scale(M: Any) -> float:
    if sp.issparse(M):
        return float(abs(M).max()) if M.nnz else 0.0
    return _inf_norm(np.asarray(M).ravel())


def _describe_tolerances(feasibility: float, optimality: float) -> str:
    return f"tolerances: feasibility {feasibility:.1e}, optimality {optimality:.1e}"


def accept(
    view: ProblemView,
    raw: RawResult,
    feasibility: float,
    optimality: float,
    *,
    certificate_tolerance: float = CERTIFICATE_TOLERANCE,
) -> tuple[RawResult, Residuals | None]:
    """Apply the acceptance rule to a backend's answer (``raw.z`` already finite, shape n).

    Returns the answer with its status, point and notes as the rule decides, and the
    residuals of the point (``None`` where no point was returned).
    """
    status = raw.status
    if status.has_solution and raw.z is not None:
        res = residuals(view, raw.z, raw.duals)
        dual = max(res.stationarity or 0.0, res.complementarity or 0.0)
        if res.primal <= feasibility and dual <= optimality:
            return raw, res
        tolerances = _describe_tolerances(feasibility, optimality)
        if res.primal <= INACCURATE_FACTOR * feasibility and dual <= (
            INACCURATE_FACTOR * optimality
        ):
            note = (
                f"acceptance: {status.name} -> OPTIMAL_INACCURATE ({res.describe()}; {tolerances})"
            )
            return dataclasses.replace(
                raw, status=SolverStatus.OPTIMAL_INACCURATE, notes=(*raw.notes, note)
            ), res
        valid, numbers = check_unbounded_direction(view, raw.z, certificate_tolerance)
        if valid and res.primal <= INACCURATE_FACTOR * feasibility:
            note = (
                f"acceptance: {status.name} -> UNBOUNDED: the returned point is far out on a "
                f"direction of unbounded descent ({numbers})"
            )
            return dataclasses.replace(
                raw,
                status=SolverStatus.UNBOUNDED,
                z=None,
                duals=None,
                objective=None,
                certificate={"direction": raw.z / _inf_norm(raw.z)},
                notes=(*raw.notes, note),
            ), res
        note = (
            f"acceptance: {status.name} -> FAILED, not a solution ({res.describe()}; {tolerances})"
        )
        return dataclasses.replace(
            raw,
            status=SolverStatus.FAILED,
            z=None,
            duals=None,
            objective=None,
            notes=(*raw.notes, note),
        ), res
    certificate = raw.certificate
    if certificate is not None and status is SolverStatus.INFEASIBLE:
        valid, numbers = check_infeasibility_certificate(view, certificate, certificate_tolerance)
        return _certified(raw, valid, "infeasibility", numbers), None
    if certificate is not None and status is SolverStatus.UNBOUNDED:
        direction = certificate.get("direction")
        if direction is None:
            return _certified(raw, False, "unboundedness", "no 'direction' given"), None
        valid, numbers = check_unbounded_direction(view, direction, certificate_tolerance)
        return _certified(raw, valid, "unboundedness", numbers), None
    return raw, None


def _certified(raw: RawResult, valid: bool, what: str, numbers: str) -> RawResult:
    if valid:
        return dataclasses.replace(
            raw, notes=(*raw.notes, f"{what} certificate checked ({numbers})")
        )
    return dataclasses.replace(
        raw,
        status=SolverStatus.FAILED,
        certificate=None,
        notes=(
            *raw.notes,
            f"acceptance: {raw.status.name} -> FAILED: the {what} certificate does not "
            f"check ({numbers})",
        ),
    )
