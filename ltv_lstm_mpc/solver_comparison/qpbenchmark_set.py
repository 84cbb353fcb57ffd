r"""The controller's subproblems as a qpbenchmark test set, and qpbenchmark's metrics.

`qpbenchmark <https://github.com/qpsolvers/qpbenchmark>`_ is the community's benchmark of
QP solvers (test sets such as Maros-Meszaros; metrics: success rate, shifted geometric
mean of runtime, primal and dual residuals, duality gap, under several accuracy settings).
This module writes the RTI subproblems of eq. (optimization) that the controller solved
along closed loops as such a test set, and computes qpbenchmark's metrics with this
library's own solver layer, so that the two can be put side by side.

:func:`export_test_set` (``ltv-lstm-mpc bench --export-qpbenchmark DIR``) runs closed loops
(:data:`SOURCES`: the paper's scenario 3 on the LSTM plant, which has infeasible steps, and
scenario 4 on the pH plant; the quadruple tank's set-point changes) at each horizon, on the
condensed transcription (dense QPs: what ``daqp`` solves) and the sparse one (sparse QPs:
states and inputs, with the model's equality rows), and keeps a stated selection of what
was solved (:func:`select`):

``nominal``
    the nominal FHOCP of a step whose solve succeeded;
``near_infeasible``
    the solved nominal FHOCPs with the smallest feasibility margin (:func:`feasibility_margin`:
    how far every row could be tightened, in units of its norm, before the problem
    became infeasible; written to ``problems.csv`` for every problem);
``infeasible``
    a nominal FHOCP the solver declared infeasible;
``fallback``
    the infeasibility policy's subproblem at such a step (``"paper"``: no output rows
    and no terminal set).

The terminal set of the QPs is in its QP form (the conservative box of a QP-only backend,
:mod:`~ltv_lstm_mpc.mpc.terminal`). The subproblems with the exact terminal cones come from
a closed loop of the same scenario with ``daqp:socp`` (condensed; its own trajectory) and
are written as SOCPs in the Conic Benchmark Format (CBF, version 1: CBLIB's format, read
by MOSEK and by CBLIB's tools), where the quadratic cost :math:`\tfrac12 z^\top P z`
becomes an epigraph variable :math:`s` with the rotated cone :math:`2 s \cdot 1 \ge
\|L^\top z\|^2` (:math:`P = L L^\top`).

:func:`qpbenchmark_metrics` (``ltv-lstm-mpc bench --qpbenchmark-set DIR``) solves the
exported QPs with this library's ``qpsolvers:<solver>`` backends under each settings group
of the test set, with exactly the options qpbenchmark passes (``tolerance_options=False``)
and the group's tolerance as this library's acceptance tolerance, and computes qpbenchmark's
metrics from each answer with
:func:`~ltv_lstm_mpc.solvers.acceptance.qpbenchmark_residuals` (qpsolvers' absolute
residuals): success rate (found, and each residual below the settings' tolerance), shifted
geometric mean of runtime (shift 10 s, a failure counted at the time limit, relative to the
best solver), and of the residuals (shift 10, floored at the tolerance).
:func:`compare_results` puts them beside qpbenchmark's own results file for the same set
and states, per problem, why a verdict differs (from the acceptance layer's message, or a
re-solve that isolates the cause).
"""

from __future__ import annotations

import csv
import json
import math
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np
import scipy.sparse as sp

from ltv_lstm_mpc.exceptions import InvalidValueError
from ltv_lstm_mpc.lstm.model import LSTMModel

__all__ = [
    "DATA_FOLDER",
    "FORMS",
    "KINDS",
    "LIBRARY_SETTINGS",
    "MARGIN_RANGE",
    "MODULES",
    "QPBENCHMARK_SOLVERS",
    "QPBENCHMARK_TOLERANCES",
    "SHIFT",
    "SOURCES",
    "Captured",
    "Source",
    "capture",
    "compare_results",
    "default_sources",
    "export_test_set",
    "feasibility_margin",
    "format_comparison",
    "library_options",
    "load_problem",
    "qpbenchmark_metrics",
    "qpsolvers_arrays",
    "select",
    "shifted_geometric_mean",
    "summarize",
    "write_cbf",
    "write_metrics",
    "write_rows",
]

#: The generated test-set modules, by form (qpbenchmark derives the class name from the
#: file name: ``LtvLstmMpcDense``, ``LtvLstmMpcSparse``). As qpbenchmark's own
#: Maros-Meszaros sets, the sparse one is for solvers with a sparse API only (qpsolvers
#: refuses sparse matrices for a dense solver).
MODULES = {"condensed": "ltv_lstm_mpc_dense", "sparse": "ltv_lstm_mpc_sparse"}
#: The folder of the problems' ``.npz`` files.
DATA_FOLDER = "problems"
#: The QP forms exported (``"cone"``: the exact-cone subproblems, CBF only).
FORMS = ("condensed", "sparse")
#: The classes of the selection, in order (module docstring).
KINDS = ("nominal", "near_infeasible", "infeasible", "fallback")
#: qpbenchmark's shift of the shifted geometric mean (its ``report.py``: 10).
SHIFT = 10.0
#: The settings group the test set adds to qpbenchmark's four: the options this library's
#: solver layer passes each solver at ``MPCConfig``'s default tolerance, 1e-8
#: (:func:`~ltv_lstm_mpc.solvers.tolerances.solver_options`), validated at 1e-6 (absolute,
#: qpbenchmark's ``mid_accuracy``).
LIBRARY_SETTINGS = "ltv_lstm_mpc"
_LIBRARY_TOLERANCE = 1e-8
_LIBRARY_VALIDATION = 1e-6
#: qpbenchmark's validation tolerances of its settings groups (its ``test_set.py``).
QPBENCHMARK_TOLERANCES = {
    "default": 1.0,
    "high_accuracy": 1e-9,
    "low_accuracy": 1e-3,
    "mid_accuracy": 1e-6,
    LIBRARY_SETTINGS: _LIBRARY_VALIDATION,
}
_TIME_LIMIT = 10.0  # qpbenchmark's default runtime tolerance (s)


@dataclass(frozen=True)
class Source:
    """A closed loop the subproblems come from.

    Attributes
    ----------
    name : str
        Short name used in the problems' names (``ph3``, ``tank1``, ...).
    description : str
        Where it comes from, in words (the README of the set).
    model : str
        The shipped model file.
    scenario : Callable[[LSTMModel], Any]
        Gives an object with ``setpoints``, ``disturbances`` (or ``leaks``), ``config``,
        ``setpoint_rate_limit`` and ``make_plant(model)``.
    """

    name: str
    description: str
    model: str
    scenario: Callable[[LSTMModel], Any]


def _paper(index: int) -> Callable[[LSTMModel], Any]:
    def scenario(model: LSTMModel) -> Any:
        from ltv_lstm_mpc.paper.scenarios import paper_scenarios

        return paper_scenarios(model, short=True)[index]

    return scenario


def _tank(model: LSTMModel) -> Any:
    from ltv_lstm_mpc.benchmarks.quadtank import quadtank_scenarios

    return quadtank_scenarios(short=True)[0]


def default_sources() -> tuple[Source, ...]:
    """:data:`SOURCES`: the paper's scenarios 3 (LSTM plant) and 4 (pH plant), the
    quadruple tank's set-point changes."""
    return (
        Source(
            "ph3",
            "paper scenario 3 (set-point steps, LSTM plant, shipped pH model): infeasible steps",
            "ph_lstm_n5.npz",
            _paper(2),
        ),
        Source(
            "ph4",
            "paper scenario 4 (pH plant, small load disturbance, shipped pH model)",
            "ph_lstm_n5.npz",
            _paper(3),
        ),
        Source(
            "tank1",
            "quadruple tank, set-point changes on both levels (shipped quadtank model, m = p = 2)",
            "quadtank_lstm_n8.npz",
            _tank,
        ),
    )


SOURCES = default_sources()


@dataclass
class Captured:
    """One subproblem the controller solved.

    Attributes
    ----------
    name : str
        ``<source>_N<N>_<form>_<kind>_k<step>``.
    source, form, kind : str
    N, step : int
    status : str
        The controller's status of the nominal solve at that step (for a ``fallback``
        problem: why the controller fell back).
    problem : ConvexProblem
        As the backend got it (QP form; ``form == "cone"``: with the terminal cones).
    margin : float
        :func:`feasibility_margin` (NaN until :func:`select` computes it).
    """

    name: str
    source: str
    N: int
    form: str
    kind: str
    step: int
    status: str
    problem: Any
    margin: float = math.nan


def capture(
    source: Source,
    N: int,
    form: str,
    *,
    steps: int | None = None,
    model: LSTMModel | None = None,
) -> list[Captured]:
    """Run the closed loop of ``source`` at horizon ``N`` and keep every subproblem solved.

    ``form``: ``"condensed"`` (solver ``daqp``), ``"sparse"`` (``daqp``, sparse
    transcription: the terminal cones in the QP form of the backend) or ``"cone"``
    (``daqp:socp``, condensed: the exact cones). Each step gives its nominal FHOCP where
    it was solved, and the policy's subproblem where the controller fell back; the kinds
    are set by :func:`select`'s rule (here ``nominal``, ``infeasible`` or ``fallback``).
    """
    from ltv_lstm_mpc import OffsetFreeController
    from ltv_lstm_mpc.lstm.shipped import load_model
    from ltv_lstm_mpc.mpc.rti import RobustMPC

    if form not in (*FORMS, "cone"):
        raise InvalidValueError(f"form {form!r}: choose condensed, sparse or cone")
    model = model if model is not None else load_model(source.model)
    scenario = source.scenario(model)
    solver = "daqp:socp" if form == "cone" else "daqp"
    transcription = "sparse" if form == "sparse" else "condensed"
    config = replace(scenario.config, N=N, solver=solver, transcription=transcription)
    mpc = RobustMPC(model, config, native_feedback=False)
    controller = OffsetFreeController(
        model, config, setpoint_rate_limit=scenario.setpoint_rate_limit, mpc=mpc
    )
    plant = scenario.make_plant(model)
    disturbances = getattr(scenario, "disturbances", None)
    if disturbances is None:
        disturbances = scenario.leaks
    total = int(np.shape(scenario.setpoints)[0])
    steps = total if steps is None else min(int(steps), total)
    y = np.atleast_1d(np.asarray(plant.output(), dtype=np.float64))
    out: list[Captured] = []
    for k in range(steps):
        u = controller.step(y, scenario.setpoints[k])
        solution = controller.records[-1].mpc
        kinds = []
        if solution.feasible:
            kinds.append(("nominal", "nominal"))
        elif solution.status == "infeasible":  # declared infeasible by the solver (not a
            kinds.append(("nominal", "infeasible"))  # pre-check, a stall or an error)
        if solution.policy in ("paper", "soft"):
            kinds.append((solution.policy, "fallback"))
        for which, kind in kinds:
            try:
                problem = mpc.last_problem(which)
            except InvalidValueError:  # not solved at this step (a pre-check decided)
                continue
            problem = _qp_form(mpc, which, problem, form)
            out.append(
                Captured(
                    f"{source.name}_N{N}_{form}_{kind}_k{k:04d}",
                    source.name,
                    N,
                    form,
                    kind,
                    k,
                    solution.status,
                    problem,
                )
            )
        d = np.asarray(disturbances[k], dtype=np.float64)
        d_arg = None if d.ndim == 0 and np.isnan(d) else d
        y = np.atleast_1d(np.asarray(plant.step(u, d_arg), dtype=np.float64))
    return out


def _qp_form(mpc: Any, kind: str, problem: Any, form: str) -> Any:
    """The subproblem as a :class:`~ltv_lstm_mpc.solvers.ConvexProblem`: the QP the backend
    solved (the sparse transcription's cones through its reformulation), or with cones."""
    from ltv_lstm_mpc.solvers import ConvexProblem

    if not isinstance(problem, ConvexProblem):
        problem = problem.to_convex_problem()
    if form == "sparse" and problem.cones:
        problem = mpc.subproblem(kind).reformulation.apply(problem)
    return problem


#: The range of :func:`feasibility_margin` (a margin beyond it is reported at its end).
MARGIN_RANGE = (-1e3, 1.0)


def _upper_rows(M: Any, lo: Any, up: Any) -> tuple[sp.csr_matrix, np.ndarray]:
    """The finite sides of ``lo <= M z <= up`` as rows ``A z <= h``: the upper sides, then
    the lower ones negated (the form of qpsolvers' ``G x <= h``, of CBF's ``L+`` and of
    :func:`feasibility_margin`'s tightened rows)."""
    M = sp.csr_matrix(M)
    fu, fl = np.isfinite(up), np.isfinite(lo)
    return sp.csr_matrix(sp.vstack([M[fu], -M[fl]])), np.concatenate([up[fu], -lo[fl]])


def feasibility_margin(problem: Any) -> float:
    r"""How far ``problem``'s constraints could all be tightened before it became
    infeasible: the largest :math:`t` with

    .. math::

        A_{eq} z = b_{eq}, \quad G_i z + t \|G_i\|_2 \le u_i, \quad
        l_i \le G_i z - t \|G_i\|_2, \quad lb + t \le z \le ub - t, \quad
        \|F_j z + g_j\| + t \le e_j^\top z + f_j

    over the finite sides (each row's distance to its bound in the units of ``z``, each
    cone's in those of its value; a row or bound with equal sides stays an equality),
    within :data:`MARGIN_RANGE`: negative for an infeasible problem (how far they would
    have to be relaxed). One LP or SOCP, solved by Clarabel's own interface to 1e-10 where
    it gets there, else to its default 1e-8 or "almost" (a margin within about that of 0
    has no reliable sign); NaN where it does not solve.
    """
    import clarabel

    n = problem.n_variables
    blocks: list[Any] = []  # (A, b, cone kind, size): A [z t] + s = b, s in the cone
    eq = problem.A_eq is not None and problem.A_eq.shape[0] > 0
    if eq:
        A_eq = sp.csr_matrix(problem.A_eq)
        zero = sp.csr_matrix((A_eq.shape[0], 1))
        blocks.append((sp.hstack([A_eq, zero]), problem.b_eq, "zero"))
    rows: list[Any] = []
    rhs: list[Any] = []
    eye = sp.identity(n, format="csr")
    for M, lo, up in ((problem.G, problem.l, problem.u), (eye, problem.lb, problem.ub)):
        if M is None or lo is None or up is None or M.shape[0] == 0:
            continue
        M = sp.csr_matrix(M)
        both = np.isfinite(up) & np.isfinite(lo)
        fixed = both & (np.where(both, up - lo, np.inf) <= 1e-12 * (1.0 + np.abs(up)))
        if fixed.any():  # lo = up: an equality (a fixed initial state), not tightened
            blocks.append(
                (sp.hstack([M[fixed], sp.csr_matrix((int(fixed.sum()), 1))]), up[fixed], "zero")
            )
            lo, up = np.where(fixed, -np.inf, lo), np.where(fixed, np.inf, up)
        A, h = _upper_rows(M, lo, up)
        norms = np.sqrt(np.asarray(A.multiply(A).sum(axis=1)).ravel())
        rows.append(sp.hstack([A, sp.csr_matrix(norms[:, None])]))
        rhs.append(h)
    low, high = MARGIN_RANGE
    rows.append(sp.csr_matrix(np.r_[np.zeros(n), 1.0][None, :]))  # t <= high
    rows.append(sp.csr_matrix(np.r_[np.zeros(n), -1.0][None, :]))  # -t <= -low
    rhs += [np.array([high]), np.array([-low])]
    blocks.append((sp.vstack(rows), np.concatenate(rhs), "nonnegative"))
    for cone in problem.cones:  # (e'z + f - t, F z + g) in the second-order cone
        head = sp.csr_matrix(np.r_[-np.asarray(cone.e), 1.0][None, :])
        body = sp.hstack([-sp.csr_matrix(cone.F), sp.csr_matrix((cone.F.shape[0], 1))])
        blocks.append((sp.vstack([head, body]), np.r_[cone.f, cone.g], "soc"))
    A = sp.csc_matrix(sp.vstack([b[0] for b in blocks]))
    b = np.concatenate([np.asarray(b[1], dtype=np.float64) for b in blocks])
    kinds = {
        "zero": clarabel.ZeroConeT,
        "nonnegative": clarabel.NonnegativeConeT,
        "soc": clarabel.SecondOrderConeT,
    }
    cones = [kinds[kind](int(M.shape[0])) for M, _, kind in blocks]
    c = np.zeros(n + 1)
    c[n] = -1.0
    for tolerance in (1e-10, None):  # tight first; else Clarabel's defaults (1e-8)
        settings = clarabel.DefaultSettings()
        settings.verbose = False
        if tolerance is not None:
            settings.tol_gap_abs = settings.tol_gap_rel = settings.tol_feas = tolerance
        P = sp.csc_matrix((n + 1, n + 1))
        solution = clarabel.DefaultSolver(P, c, A, b, cones, settings).solve()
        if str(solution.status) == "Solved" or (
            tolerance is None and str(solution.status) == "AlmostSolved"
        ):
            return float(solution.x[n])
    return math.nan


def select(captured: Sequence[Captured], per_kind: int) -> list[Captured]:
    """The selection of the module docstring: up to ``per_kind`` problems of each kind;
    ``near_infeasible``: the solved nominal ones with the smallest
    :func:`feasibility_margin`; the others evenly spaced along the loop (a nominal problem
    chosen as near-infeasible is not chosen again). Each chosen problem's margin is set."""
    expect = int(per_kind)
    if expect < 1:
        raise InvalidValueError(f"per_kind must be at least 1, got {per_kind!r}")
    solved = [c for c in captured if c.kind == "nominal"]
    for c in solved:
        if math.isnan(c.margin):
            c.margin = feasibility_margin(c.problem)
    ranked = sorted((c for c in solved if not math.isnan(c.margin)), key=lambda c: c.margin)
    near = [
        replace(c, kind="near_infeasible", name=c.name.replace("_nominal_", "_near_"))
        for c in ranked[:expect]
    ]
    near_steps = {c.step for c in near}
    groups = {
        "nominal": [c for c in solved if c.step not in near_steps],
        "infeasible": [c for c in captured if c.kind == "infeasible"],
        "fallback": [c for c in captured if c.kind == "fallback"],
    }
    chosen: list[Captured] = []
    for kind in KINDS:
        if kind == "near_infeasible":
            chosen += sorted(near, key=lambda c: c.step)
            continue
        group = groups[kind]
        if not group:
            continue
        picks = np.unique(np.linspace(0, len(group) - 1, min(expect, len(group))).astype(int))
        chosen += [group[i] for i in picks]
    for c in chosen:
        if math.isnan(c.margin):
            c.margin = feasibility_margin(c.problem)
    return chosen


# ------------------------------------------------------------------------ file formats
def qpsolvers_arrays(problem: Any, *, dense: bool) -> dict[str, Any]:
    r"""``problem`` (a cone-free :class:`~ltv_lstm_mpc.solvers.ConvexProblem`) in
    qpsolvers' form :math:`\min \tfrac12 x^\top P x + q^\top x` s.t. :math:`G x \le h`,
    :math:`A x = b`, :math:`lb \le x \le ub`: the two-sided rows become their finite
    sides (``u`` first, then ``-l``); variable bounds stay ``lb``/``ub`` where every
    entry is finite, else their finite entries become rows of ``G`` (qpsolvers' solvers
    differ on infinite bounds). Matrices dense (``dense``) or CSC; absent parts ``None``.
    """
    if problem.cones:
        raise InvalidValueError(
            "a problem with second-order cones has no qpsolvers form; write it with write_cbf"
        )
    n = problem.n_variables

    def mat(m: Any) -> Any:  # writeable copies (some bindings reject read-only arrays)
        return np.array(m.toarray(), dtype=np.float64) if dense else sp.csc_matrix(m, copy=True)

    blocks: list[Any] = []
    h: list[Any] = []
    if problem.G is not None and problem.G.shape[0]:
        A, upper = _upper_rows(problem.G, problem.l, problem.u)
        blocks.append(A)
        h.append(upper)
    lb, ub = problem.lb, problem.ub
    if lb is not None and ub is not None and not (np.isfinite(lb).all() and np.isfinite(ub).all()):
        A, upper = _upper_rows(sp.identity(n, format="csr"), lb, ub)
        blocks.append(A)
        h.append(upper)
        lb = ub = None
    rows = sum(b.shape[0] for b in blocks)
    out: dict[str, Any] = {
        "P": mat(problem.P),
        "q": np.array(problem.q, dtype=np.float64),
        "G": mat(sp.vstack(blocks)) if rows else None,
        "h": np.concatenate(h) if rows else None,
        "A": None,
        "b": None,
        "lb": None if lb is None else np.array(lb, dtype=np.float64),
        "ub": None if ub is None else np.array(ub, dtype=np.float64),
    }
    if problem.A_eq is not None and problem.A_eq.shape[0]:
        out["A"], out["b"] = mat(problem.A_eq), np.array(problem.b_eq, dtype=np.float64)
    return out


def _save_arrays(path: Path, arrays: dict[str, Any]) -> None:
    """``.npz`` of :func:`qpsolvers_arrays`: dense matrices under their name, CSC ones as
    ``<name>_data``, ``_indices``, ``_indptr``, ``_shape``; absent parts left out."""
    flat: dict[str, Any] = {}
    for key, value in arrays.items():
        if value is None:
            continue
        if sp.issparse(value):
            csc = sp.csc_matrix(value)
            flat[f"{key}_data"] = csc.data
            flat[f"{key}_indices"] = csc.indices
            flat[f"{key}_indptr"] = csc.indptr
            flat[f"{key}_shape"] = np.array(csc.shape)
        else:
            flat[key] = np.asarray(value)
    np.savez_compressed(path, **flat)


def load_problem(path: str | Path) -> dict[str, Any]:
    """The arrays of an exported ``.npz`` (:func:`qpsolvers_arrays`' keys; ``None`` where
    absent)."""
    data = np.load(path)
    out: dict[str, Any] = {}
    for key in ("P", "q", "G", "h", "A", "b", "lb", "ub"):
        if key in data.files:
            out[key] = np.array(data[key])
        elif f"{key}_data" in data.files:
            shape = tuple(int(s) for s in data[f"{key}_shape"])
            out[key] = sp.csc_matrix(
                (data[f"{key}_data"], data[f"{key}_indices"], data[f"{key}_indptr"]), shape=shape
            )
        else:
            out[key] = None
    return out


def _convex_from_arrays(arrays: dict[str, Any]) -> Any:
    """The :class:`~ltv_lstm_mpc.solvers.ConvexProblem` of qpsolvers' arrays (``G x <= h``
    as rows with ``l = -inf``)."""
    from ltv_lstm_mpc.solvers import ConvexProblem

    G, h = arrays["G"], arrays["h"]
    return ConvexProblem(
        P=arrays["P"],
        q=arrays["q"],
        A_eq=arrays["A"],
        b_eq=arrays["b"],
        G=G,
        l=None if G is None else np.full(h.shape, -np.inf),
        u=h,
        lb=arrays["lb"],
        ub=arrays["ub"],
    )


def write_cbf(problem: Any, path: str | Path) -> Path:
    r"""Write ``problem`` (a :class:`~ltv_lstm_mpc.solvers.ConvexProblem`, cones allowed) in
    the Conic Benchmark Format, version 1 (CBLIB's; every later version reads it).

    Variables ``z`` (the problem's), then ``s``; objective :math:`\min s + q^\top z`
    (``OBJACOORD``); the constraints :math:`A x + b \in K` (``ACOORD``, ``BCOORD``) in
    this order: the equality rows (``L=``), the finite sides of the rows and of the
    variable bounds as ``u - G z >= 0``, ``G z - l >= 0`` (one ``L+`` block each), each cone
    :math:`(e^\top z + f, F z + g)` (``Q``), and :math:`(s, 1, L^\top z)` (``QR``:
    :math:`2 s \ge \|L^\top z\|^2`, :math:`P = L L^\top` from the eigenvalues of ``P``
    above :math:`10^{-12}` times the largest).
    """
    path = Path(path)
    n = problem.n_variables
    s_index = n
    blocks: list[tuple[str, sp.csr_matrix, np.ndarray]] = []  # (cone, A block, b block)

    def add(cone: str, A: Any, b: Any) -> None:
        blocks.append((cone, sp.csr_matrix(A), np.asarray(b, dtype=np.float64)))

    def pad(M: Any) -> Any:  # one more column (s)
        return sp.hstack([sp.csr_matrix(M), sp.csr_matrix((M.shape[0], 1))])

    if problem.A_eq is not None and problem.A_eq.shape[0]:
        add("L=", pad(problem.A_eq), -problem.b_eq)
    eye = sp.identity(n, format="csr")
    for M, lo, up in ((problem.G, problem.l, problem.u), (eye, problem.lb, problem.ub)):
        if M is None or lo is None or up is None or M.shape[0] == 0:
            continue
        A, h = _upper_rows(M, lo, up)
        if A.shape[0]:
            add("L+", pad(-A), h)  # h - A z >= 0
    for cone in problem.cones:
        head = sp.csr_matrix(np.append(cone.e, 0.0)[None, :])
        add("Q", sp.vstack([head, pad(cone.F)]), np.concatenate([[cone.f], cone.g]))
    P = problem.P.toarray()
    w, V = np.linalg.eigh(0.5 * (P + P.T))
    keep = w > 1e-12 * max(float(w.max(initial=0.0)), 1e-300)
    L = V[:, keep] * np.sqrt(w[keep])
    s_row = np.zeros((1, n + 1))
    s_row[0, s_index] = 1.0
    add(
        "QR",
        sp.vstack([sp.csr_matrix(s_row), sp.csr_matrix((1, n + 1)), pad(L.T)]),
        np.concatenate([[0.0, 1.0], np.zeros(L.shape[1])]),
    )
    A = sp.vstack([b[1] for b in blocks]).tocoo()
    b = np.concatenate([b[2] for b in blocks])
    lines = ["VER", "1", "", "OBJSENSE", "MIN", "", "VAR", f"{n + 1} 1", f"F {n + 1}", ""]
    lines += ["CON", f"{A.shape[0]} {len(blocks)}"]
    lines += [f"{cone} {M.shape[0]}" for cone, M, _ in blocks]
    objective = [(j, float(v)) for j, v in enumerate(problem.q) if v != 0.0] + [(s_index, 1.0)]
    lines += ["", "OBJACOORD", str(len(objective))]
    lines += [f"{j} {v!r}" for j, v in objective]
    triples = zip(A.row, A.col, A.data, strict=True)
    entries = [(int(i), int(j), float(v)) for i, j, v in triples if v != 0.0]
    lines += ["", "ACOORD", str(len(entries))]
    lines += [f"{i} {j} {v!r}" for i, j, v in entries]
    nonzero = [(i, float(v)) for i, v in enumerate(b) if v != 0.0]
    lines += ["", "BCOORD", str(len(nonzero))]
    lines += [f"{i} {v!r}" for i, v in nonzero]
    path.write_text("\n".join(lines) + "\n")
    return path


# ------------------------------------------------------------------------ the test set
_MODULE = '''"""The subproblems of ltv_lstm_mpc's LSTM MPC as a qpbenchmark test set.

Generated by ltv_lstm_mpc {version} (`ltv-lstm-mpc bench --export-qpbenchmark`); where each
problem comes from: README.md and problems.csv next to this file.

Run: qpbenchmark {module}.py run --author NAME
 (or: python {module}.py run --author NAME); the results and qpbenchmark's report go to
results/{module}.csv and .md next to this file, unless --results-path names another file.
"""

import csv
import os
import sys

import numpy as np
import scipy.sparse as spa
import qpbenchmark.benchmark
import qpbenchmark.report
import qpbenchmark.results
from qpbenchmark import Problem, TestSet
from qpbenchmark.tolerance import Tolerance

HERE = os.path.dirname(os.path.abspath(__file__))
DATA = os.path.join(HERE, "{data}")
FORM = {form!r}

#: The settings group added to qpbenchmark's four: the options ltv_lstm_mpc's solver
#: layer passes each solver at its default tolerance ({tolerance:g}), validated at {validation:g}.
LIBRARY_SETTINGS = {library_settings!r}
LIBRARY_OPTIONS = {library_options!r}


_gpu_info_summary = qpbenchmark.report.get_gpu_info_summary


def _gpu_info_or_none():
    """qpbenchmark's report line on the GPU, or none: qpbenchmark 2.7 asks torch for a CUDA
    device's name, which a CPU build of torch answers with an AssertionError."""
    try:
        return _gpu_info_summary()
    except Exception:
        return ""


qpbenchmark.report.get_gpu_info_summary = _gpu_info_or_none


class _ResultsNextToTheSet(qpbenchmark.benchmark.Results):
    """qpbenchmark's Results, writing to results/{module}.csv next to this file where the
    command line names no --results-path (qpbenchmark 2.7 would save nowhere)."""

    def __init__(self, file_path, test_set):
        if file_path is None and type(test_set).__name__ == "{class_name}":
            file_path = os.path.join(HERE, "results", "{module}.csv")
            os.makedirs(os.path.dirname(file_path), exist_ok=True)
        super().__init__(file_path, test_set)


qpbenchmark.benchmark.Results = _ResultsNextToTheSet
_main = sys.modules.get("__main__")  # `python -m qpbenchmark.benchmark`: its own copy
if getattr(_main, "Results", None) is qpbenchmark.results.Results:
    _main.Results = _ResultsNextToTheSet


def _matrix(data, key):
    if key in data.files:
        return np.array(data[key], dtype=float)
    if key + "_data" in data.files:
        shape = tuple(int(s) for s in data[key + "_shape"])
        parts = (data[key + "_data"], data[key + "_indices"], data[key + "_indptr"])
        return spa.csc_matrix(parts, shape=shape)
    return None


class {class_name}(TestSet):
    """LSTM MPC subproblems (RTI linearizations) along closed loops, {form} form: see
    README.md."""

    @property
    def description(self) -> str:
        return (
            "Subproblems of the robust offset-free LSTM MPC of Schimperna and Magni, "
            "solved by ltv_lstm_mpc along closed loops (pH neutralization and quadruple "
            "tank; horizons {horizons}; {form} QPs; nominal, "
            "near-infeasible, infeasible and fallback subproblems): see README.md"
        )

    @property
    def title(self) -> str:
        return "LTV-LSTM-MPC test set ({form} QPs)"

    @property
    def sparse_only(self) -> bool:
        return {sparse_only!r}

    def define_tolerances(self, runtime: float = 10.0) -> None:
        super().define_tolerances(runtime)
        self.tolerances[LIBRARY_SETTINGS] = Tolerance(
            primal={validation!r}, dual={validation!r}, gap={validation!r}, runtime=runtime
        )

    def define_solver_settings(self) -> None:
        super().define_solver_settings()
        from qpbenchmark.solver_settings import SolverSettings

        library = SolverSettings()
        for solver, options in LIBRARY_OPTIONS.items():
            for name, value in options.items():
                library.set_param(solver, name, value)
        library.set_time_limit(self.tolerances[LIBRARY_SETTINGS].runtime)
        self.solver_settings[LIBRARY_SETTINGS] = library

    def __iter__(self):
        with open(os.path.join(HERE, "problems.csv"), newline="") as handle:
            names = [row["name"] for row in csv.DictReader(handle) if row["form"] == FORM]
        for name in names:
            with np.load(os.path.join(DATA, name + ".npz")) as data:
                parts = {{key: _matrix(data, key) for key in ("P", "G", "A")}}
                vectors = {{
                    key: (np.array(data[key], dtype=float) if key in data.files else None)
                    for key in ("q", "h", "b", "lb", "ub")
                }}
            yield Problem(
                parts["P"], vectors["q"], parts["G"], vectors["h"], parts["A"], vectors["b"],
                vectors["lb"], vectors["ub"], name=name,
            )


if __name__ == "__main__":  # --results-path as given, else results/ (above)
    qpbenchmark.benchmark.main(test_set_path=os.path.abspath(__file__))
'''

_PROBLEM_COLUMNS = (
    "name",
    "format",
    "source",
    "N",
    "form",
    "kind",
    "step",
    "nominal_status",
    "margin",
    "variables",
    "rows",
    "equalities",
    "cones",
)


def _class_name(module: str) -> str:
    """qpbenchmark's rule: ``name.title().replace("_", "")``."""
    return module.title().replace("_", "")


def library_options(solvers: Sequence[str]) -> dict[str, dict[str, Any]]:
    """:data:`LIBRARY_SETTINGS`' options of each solver (this library's, at 1e-8)."""
    from ltv_lstm_mpc.solvers.tolerances import solver_options

    return {s: solver_options(s, _LIBRARY_TOLERANCE, {}) for s in solvers}


#: qpbenchmark's solvers (its ``SolverSettings.IMPLEMENTED_SOLVERS``) this library's
#: ``qpsolvers:<name>`` backends can also run.
QPBENCHMARK_SOLVERS = (
    "clarabel",
    "daqp",
    "ecos",
    "highs",
    "osqp",
    "piqp",
    "proxqp",
    "quadprog",
    "scs",
)


def export_test_set(
    directory: str | Path,
    *,
    sources: Sequence[Source] = SOURCES,
    horizons: Sequence[int] = (5, 20, 50),
    forms: Sequence[str] = FORMS,
    per_kind: int = 3,
    steps: int | None = None,
    cones: bool = True,
    log: Callable[[str], None] | None = None,
) -> list[Path]:
    """Write the test set of the module docstring into ``directory``; returns the modules' paths.

    Files: ``ltv_lstm_mpc_dense.py`` and ``ltv_lstm_mpc_sparse.py`` (the
    ``qpbenchmark.TestSet`` subclasses ``LtvLstmMpcDense``, ``LtvLstmMpcSparse``: the
    condensed and the sparse QPs; the second for solvers with a sparse API, as
    qpbenchmark's sparse sets), ``problems/<name>.npz`` (qpsolvers' arrays,
    :func:`load_problem`), ``socp/<name>.cbf`` (the exact-cone subproblems, with
    ``cones``), ``problems.csv`` (where each problem comes from) and ``README.md``.

    Parameters
    ----------
    sources : sequence of Source
    horizons : sequence of int
    forms : sequence of {"condensed", "sparse"}
    per_kind : int
        Problems of each kind per (source, horizon, form).
    steps : int, optional
        Closed-loop samples per run (default: each scenario's).
    """
    import importlib.util

    from ltv_lstm_mpc import __version__
    from ltv_lstm_mpc.lstm.shipped import load_model

    if importlib.util.find_spec("clarabel") is None:
        raise InvalidValueError(
            "the export measures each problem's feasibility margin with Clarabel, which is "
            'not installed: pip install -e ".[bench]"'
        )
    for form in forms:
        if form not in FORMS:
            raise InvalidValueError(f"form {form!r}: choose from {', '.join(FORMS)}")
    out = Path(directory)
    if out.exists() and any(out.iterdir()):
        raise InvalidValueError(
            f"{out} is not empty; export into a new folder (qpbenchmark skips the problems "
            "its results file already has, so old results would stand for new problems)"
        )
    data = out / DATA_FOLDER
    data.mkdir(parents=True, exist_ok=True)
    (out / "results").mkdir(exist_ok=True)  # qpbenchmark writes there, but does not create it
    rows: list[dict[str, Any]] = []
    all_forms = [*forms, "cone"] if cones else list(forms)
    for source in sources:
        model = load_model(source.model)
        for N in horizons:
            for form in all_forms:
                start = time.perf_counter()
                chosen = select(capture(source, N, form, steps=steps, model=model), per_kind)
                for c in chosen:
                    p = c.problem
                    row = {
                        "name": c.name,
                        "format": "cbf" if form == "cone" else "npz",
                        "source": c.source,
                        "N": c.N,
                        "form": c.form,
                        "kind": c.kind,
                        "step": c.step,
                        "nominal_status": c.status,
                        "margin": c.margin,
                        "variables": p.n_variables,
                        "rows": p.n_ineq,
                        "equalities": p.n_eq,
                        "cones": len(p.cones),
                    }
                    if form == "cone":
                        (out / "socp").mkdir(exist_ok=True)
                        write_cbf(p, out / "socp" / f"{c.name}.cbf")
                    else:
                        arrays = qpsolvers_arrays(p, dense=form == "condensed")
                        _save_arrays(data / f"{c.name}.npz", arrays)
                    rows.append(row)
                if log is not None:
                    counts = {k: sum(c.kind == k for c in chosen) for k in KINDS}
                    log(
                        f"{source.name} N={N} {form}: {counts} "
                        f"({time.perf_counter() - start:.1f} s)"
                    )
    with open(out / "problems.csv", "w", newline="") as handle:
        writer = csv.DictWriter(handle, fieldnames=list(_PROBLEM_COLUMNS))
        writer.writeheader()
        writer.writerows(rows)
    modules = []
    for form in forms:
        name = MODULES[form]
        module = out / f"{name}.py"
        module.write_text(
            _MODULE.format(
                version=__version__,
                module=name,
                data=DATA_FOLDER,
                form=form,
                sparse_only=form == "sparse",
                class_name=_class_name(name),
                horizons="/".join(str(N) for N in horizons),
                library_settings=LIBRARY_SETTINGS,
                library_options=library_options(QPBENCHMARK_SOLVERS),
                tolerance=_LIBRARY_TOLERANCE,
                validation=_LIBRARY_VALIDATION,
            )
        )
        modules.append(module)
    (out / "README.md").write_text(_readme(rows, sources, horizons, per_kind, __version__))
    return modules


def _readme(
    rows: Sequence[dict[str, Any]],
    sources: Sequence[Source],
    horizons: Sequence[int],
    per_kind: int,
    version: str,
) -> str:
    lines = [
        "# LTV-LSTM-MPC subproblems: a qpbenchmark test set",
        "",
        f"Written by ltv_lstm_mpc {version} (`ltv-lstm-mpc bench --export-qpbenchmark`).",
        "Each problem is one convex subproblem (an RTI linearization of the LSTM along the",
        "shifted candidate) of the robust offset-free MPC of Schimperna and Magni, as the",
        "controller solved it in closed loop. Run with qpbenchmark:",
        "",
        f"    qpbenchmark {MODULES['condensed']}.py run --author NAME",
        f"    qpbenchmark {MODULES['sparse']}.py run --author NAME",
        "",
        "(results and qpbenchmark's report in `results/`; the second set is run by the",
        "solvers with a sparse API only, as qpbenchmark's",
        "sparse Maros-Meszaros set). Each module also adds the settings group",
        f"`{LIBRARY_SETTINGS}`: the options ltv_lstm_mpc's solver layer passes each solver.",
        "",
        "## Where the problems come from",
        "",
    ]
    lines += [f"- `{s.name}`: {s.description}" for s in sources]
    lines += [
        "",
        f"Horizons N = {', '.join(str(N) for N in horizons)}. Forms: `condensed` (dense QP over",
        "the input increments: what DAQP solves in the controller), `sparse` (states and inputs,",
        "the LSTM's linearization as equality rows), `cone` (condensed, with the exact terminal",
        "cones: `socp/*.cbf`, Conic Benchmark Format version 1; not part of the QP test set).",
        "The terminal set of the QPs is the conservative box of a QP-only backend.",
        "",
        f"Kinds (up to {per_kind} of each per source, horizon and form, evenly spaced along",
        "the loop):",
        "",
        "- `nominal`: the nominal FHOCP of a step that was solved;",
        "- `near_infeasible`: the solved nominal FHOCPs with the smallest feasibility margin",
        "  (column `margin`: how far every row could be tightened, in units of its norm,",
        "  before the problem became infeasible; negative: infeasible);",
        "- `infeasible`: a nominal FHOCP the solver declared infeasible (a correct answer is",
        '  "not found": qpbenchmark\'s correct rate, not its success rate);',
        "- `fallback`: the infeasibility policy's subproblem at such a step.",
        "",
        "## Counts",
        "",
        "| source | N | form | " + " | ".join(KINDS) + " |",
        "|---|---|---|" + "---|" * len(KINDS),
    ]
    keys = sorted({(r["source"], r["N"], r["form"]) for r in rows}, key=str)
    for key in keys:
        counts = [
            sum(1 for r in rows if (r["source"], r["N"], r["form"]) == key and r["kind"] == k)
            for k in KINDS
        ]
        lines.append(f"| {key[0]} | {key[1]} | {key[2]} | " + " | ".join(map(str, counts)) + " |")
    lines += ["", "`problems.csv`: every problem with its step, status and sizes.", ""]
    return "\n".join(lines)


# ---------------------------------------------------------------------------- metrics
def shifted_geometric_mean(values: Sequence[float], shift: float = SHIFT) -> float:
    """:math:`\\exp(\\frac1n \\sum \\log(v_i + sh)) - sh`: qpbenchmark's own ``shgeom``
    (the one its report uses), with this library's error for values it cannot average."""
    from qpbenchmark.shgeom import shgeom

    v = np.asarray(values, dtype=np.float64)
    if v.size == 0 or (v < 0).any():
        raise InvalidValueError("the shifted geometric mean needs nonnegative values")
    return float(shgeom(v, shift))


def _test_set(directory: Path, form: str) -> Any:
    """The generated test set of ``form`` in ``directory``: its module loaded from that
    file under a name of its own (qpbenchmark's loader appends the folder to ``sys.path``,
    where a module of the same name elsewhere would win), and its class instantiated."""
    import importlib.util

    path = (directory / f"{MODULES[form]}.py").resolve()
    spec = importlib.util.spec_from_file_location(f"_ltv_lstm_mpc_set_{form}_{id(path)}", path)
    if spec is None or spec.loader is None:
        raise InvalidValueError(f"cannot load the test set module {path}")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return getattr(module, _class_name(MODULES[form]))()


def _acceptance_tolerance(group: str) -> float:
    """This library's acceptance tolerance under a settings group: the group's validation
    tolerance (qpbenchmark's absolute one), this library's own for its group."""
    return _LIBRARY_TOLERANCE if group == LIBRARY_SETTINGS else QPBENCHMARK_TOLERANCES[group]


def qpbenchmark_metrics(
    directory: str | Path,
    *,
    solvers: Sequence[str] | None = None,
    settings: Sequence[str] | None = None,
    log: Callable[[str], None] | None = None,
) -> list[dict[str, Any]]:
    """Solve the exported QPs of ``directory`` with this library's ``qpsolvers:<solver>``
    backends under each test set's settings groups; one row per (problem, solver,
    settings) in qpbenchmark's results columns, then ``form``, ``status`` (this library's),
    ``info`` (its message: the acceptance layer's verdict where it refused a point) and
    ``options``.

    The options are exactly the group's (what qpbenchmark passes the solver; the backend's
    ``tolerance_options=False``), without the time limits (``time_limit``,
    ``time_limit_secs``); ECOS gets the variable bounds as rows (this library's backend:
    ECOS rejects infinite bounds); the acceptance tolerance is the
    group's (``ltv_lstm_mpc``: 1e-8, the library's default). ``runtime`` (s) is the
    backend's ``solve_time``: the wall time of its :func:`qpsolvers.solve_problem` call, the
    call qpbenchmark times. The residuals come from
    :func:`~ltv_lstm_mpc.solvers.acceptance.qpbenchmark_residuals`; ``found`` is this
    library's verdict (a status with a point: its acceptance layer may refuse a point the
    solver calls found). The solvers of each set are qpbenchmark's (the sparse set: those
    with a sparse API).

    Raises
    ------
    InvalidValueError
        A solver not installed through qpsolvers, a settings group the set lacks, or
        validation tolerances that differ from qpbenchmark's (another qpbenchmark version).
    """
    from ltv_lstm_mpc.solvers import Session, available_solvers
    from ltv_lstm_mpc.solvers.acceptance import ProblemView, qpbenchmark_residuals

    directory = Path(directory)
    installed = {s.split(":", 1)[1] for s in available_solvers() if s.startswith("qpsolvers:")}
    missing = [s for s in (solvers or ()) if s not in installed]
    if missing:
        raise InvalidValueError(
            f"solver(s) {', '.join(missing)} not installed through qpsolvers; "
            f"choose from {', '.join(sorted(installed))}"
        )
    with open(directory / "problems.csv", newline="") as handle:
        listed = list(csv.DictReader(handle))
    rows: list[dict[str, Any]] = []
    for form in FORMS:
        if not (directory / f"{MODULES[form]}.py").is_file():
            continue
        test_set = _test_set(directory, form)
        for group, tolerance in test_set.tolerances.items():
            expected = QPBENCHMARK_TOLERANCES.get(group)
            if expected is None or tolerance.primal != expected:
                raise InvalidValueError(
                    f"the test set's {group!r} tolerance is {tolerance.primal}, this library "
                    f"expects {expected} (qpbenchmark 2.7's); export the set again with this "
                    "qpbenchmark"
                )
        groups = list(settings or test_set.solver_settings)
        unknown = [g for g in groups if g not in test_set.solver_settings]
        if unknown:
            raise InvalidValueError(
                f"settings {', '.join(unknown)} not in the test set; choose from "
                f"{', '.join(test_set.solver_settings)}"
            )
        chosen = sorted(s for s in test_set.solvers if s in installed)
        if solvers is not None:
            chosen = [s for s in chosen if s in solvers]
        names = [r["name"] for r in listed if r["form"] == form]
        for index, name in enumerate(names):
            path = directory / DATA_FOLDER / f"{name}.npz"
            problem = _convex_from_arrays(load_problem(path))
            view = ProblemView.of_convex(problem)
            for solver in chosen:
                for group in groups:
                    options = {
                        k: v
                        for k, v in test_set.solver_settings[group][solver].items()
                        if "time_limit" not in k.lower() and k != "TimeLimit"
                    }
                    runtime = math.nan
                    try:
                        session = Session(
                            f"qpsolvers:{solver}",
                            tolerance=_acceptance_tolerance(group),
                            tolerance_options=False,
                            **options,
                        )
                        start = time.perf_counter()
                        session.setup(problem)  # (the conversion: qpbenchmark's is done)
                        conversion = time.perf_counter() - start
                        sol = session.solve()
                        # the qpsolvers call, as qpbenchmark times it
                        runtime = max(sol.setup_time - conversion, 0.0) + sol.solve_time
                        error = ""
                    except Exception as exc:  # a backend failure is a result
                        sol, error = None, f"{type(exc).__name__}: {exc}"
                    found = sol is not None and sol.status.has_solution and sol.z is not None
                    if found:
                        primal, dual, gap = qpbenchmark_residuals(view, sol.z, sol.duals)
                    else:
                        primal = dual = gap = math.inf
                    rows.append(
                        {
                            "problem": name,
                            "solver": solver,
                            "settings": group,
                            "runtime": runtime,
                            "found": found,
                            "primal_residual": primal,
                            "dual_residual": dual,
                            "duality_gap": gap,
                            "form": form,
                            "status": sol.status.name.lower() if sol is not None else "error",
                            "info": error or (sol.info if sol is not None else ""),
                            "options": json.dumps(options, sort_keys=True, default=str),
                        }
                    )
            if log is not None and (index + 1) % 10 == 0:
                log(f"{form}: {index + 1}/{len(names)} problems")
    return rows


def summarize(rows: Sequence[dict[str, Any]]) -> dict[tuple[str, str], dict[str, float]]:
    """qpbenchmark's metrics per (solver, settings): success rate (%), and the shifted
    geometric means of runtime (a failure at the time limit) and of the residuals (a
    failure at the tolerance; values floored at it), each relative to the best solver of
    the settings, as in qpbenchmark's report."""
    out: dict[tuple[str, str], dict[str, float]] = {}
    groups = sorted({r["settings"] for r in rows})
    solvers = sorted({r["solver"] for r in rows})
    for group in groups:
        tol = QPBENCHMARK_TOLERANCES[group]
        raw: dict[str, dict[str, float]] = {}
        for solver in solvers:
            mine = [r for r in rows if r["solver"] == solver and r["settings"] == group]
            if not mine:
                continue
            ok = [_success(r, tol) for r in mine]
            runtime = [float(r["runtime"]) if _found(r) else _TIME_LIMIT for r in mine]
            metrics = {
                "success_rate": 100.0 * float(np.mean(ok)),
                "runtime": shifted_geometric_mean(runtime),
            }
            for key in ("primal_residual", "dual_residual", "duality_gap"):
                values = [max(float(r[key]), tol) if _found(r) else tol for r in mine]
                metrics[key] = shifted_geometric_mean(values)
            raw[solver] = metrics
        for key in ("runtime", "primal_residual", "dual_residual", "duality_gap"):
            best = min((m[key] for m in raw.values()), default=math.nan)
            for m in raw.values():
                m[f"{key}_relative"] = m[key] / best if best > 0 else math.nan
        for solver, metrics in raw.items():
            out[(solver, group)] = metrics
    return out


def _found(row: dict[str, Any]) -> bool:
    value = row["found"]
    return value if isinstance(value, bool) else str(value).strip().lower() == "true"


def _success(row: dict[str, Any], tol: float) -> bool:
    return _found(row) and all(
        float(row[k]) < tol for k in ("primal_residual", "dual_residual", "duality_gap")
    )


def write_rows(rows: Sequence[dict[str, Any]], path: str | Path) -> Path:
    """``rows`` as CSV (qpbenchmark's results columns, then ``status``)."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    columns = list(rows[0]) if rows else ["problem"]
    with open(path, "w", newline="") as handle:
        writer = csv.DictWriter(handle, fieldnames=columns)
        writer.writeheader()
        writer.writerows(rows)
    return path


_RESIDUALS = ("primal_residual", "dual_residual", "duality_gap")


def compare_results(
    ours: Sequence[dict[str, Any]],
    theirs_csv: str | Path,
    directory: str | Path | None = None,
) -> tuple[list[dict[str, Any]], list[dict[str, Any]]]:
    """This library's metrics (:func:`qpbenchmark_metrics`' rows) beside qpbenchmark's
    results file of the same set.

    Returns ``(table, differences)``. ``table``: per (solver, settings) both success rates,
    both shifted geometric means of runtime (qpbenchmark's: a failure at the time limit) and
    the median ratio of the runtimes where both found a point. ``differences``: per
    (problem, solver, settings) whose success differs, both verdicts with their residuals
    and the reason (:func:`_reason`; with ``directory``, the folder of the exported set,
    a verdict that differs at the same options is re-solved to isolate the cause).
    """
    with open(theirs_csv, newline="") as handle:
        theirs = list(csv.DictReader(handle))
    index = {(r["problem"], r["solver"], r["settings"]): r for r in theirs}
    shared = [r for r in ours if (r["problem"], r["solver"], r["settings"]) in index]
    ours_summary = summarize(shared)
    their_summary = summarize([index[(r["problem"], r["solver"], r["settings"])] for r in shared])
    table = []
    for key in sorted(ours_summary):
        a, b = ours_summary[key], their_summary.get(key, {})
        mine = [r for r in shared if (r["solver"], r["settings"]) == key]
        ratios = [
            float(r["runtime"]) / float(index[(r["problem"], *key)]["runtime"])
            for r in mine
            if _found(r) and _found(index[(r["problem"], *key)])
        ]
        table.append(
            {
                "solver": key[0],
                "settings": key[1],
                "problems": len(mine),
                "success_ours": a["success_rate"],
                "success_qpbenchmark": b.get("success_rate", math.nan),
                "runtime_ours_s": a["runtime"],
                "runtime_qpbenchmark_s": b.get("runtime", math.nan),
                "runtime_ratio_found": float(np.median(ratios)) if ratios else math.nan,
            }
        )
    differences = []
    for r in shared:
        t = index[(r["problem"], r["solver"], r["settings"])]
        tol = QPBENCHMARK_TOLERANCES[r["settings"]]
        if _success(r, tol) != _success(t, tol):
            differences.append(
                {
                    "problem": r["problem"],
                    "solver": r["solver"],
                    "settings": r["settings"],
                    "ours": _verdict(r, tol),
                    "qpbenchmark": _verdict(t, tol),
                    "reason": _reason(r, t, tol, directory),
                }
            )
    return table, differences


def _verdict(row: dict[str, Any], tol: float) -> str:
    if not _found(row):
        return "not found" + (f" ({row['status']})" if row.get("status") else "")
    values = ", ".join(f"{k.split('_')[0]} {float(row[k]):.1e}" for k in _RESIDUALS)
    worst = max(float(row[k]) for k in _RESIDUALS)
    return ("success" if worst < tol else "found, above tolerance") + f" ({values})"


def _reason(
    ours: dict[str, Any], theirs: dict[str, Any], tol: float, directory: str | Path | None
) -> str:
    """Why the two verdicts on one problem differ, from what this library reported and,
    where both found a point, from re-solving the problem as each side called the solver."""
    if _found(theirs) and not _found(ours):
        info = str(ours.get("info", ""))
        if "acceptance" in info:
            return (
                "this library's acceptance layer refused the point the solver called found: "
                + info.split("acceptance", 1)[1].strip(" :")[:160]
            )
        return f"the solver answered {ours.get('status')} to this library ({info[:120]})"
    if _found(ours) and not _found(theirs):
        if ours.get("status") == "optimal_inaccurate":
            native = str(ours.get("info", "")).split(";")[-1].strip()
            return (
                f"the solver stopped inaccurate ({native[:100]}): qpsolvers reports no "
                "solution for that status, this library an inaccurate one whose point its "
                "acceptance layer checked"
            )
        return "the solver reported no solution to qpbenchmark, one to this library"
    if directory is not None:
        cause = _matrix_type_cause(ours, Path(directory), tol)
        if cause:
            return cause
    if ours["solver"] == "ecos":
        return (
            "the calls differ: this library passes ECOS the variable bounds as rows (ECOS "
            "rejects infinite bounds), qpbenchmark as lb/ub"
        )
    near = [
        k.replace("_", " ")
        for k in _RESIDUALS
        if 0.01 * tol <= max(float(ours[k]), float(theirs[k])) <= 100 * tol
    ]
    if near:
        return (
            f"{', '.join(near)} within a factor 100 of the tolerance {tol:g} on both sides, "
            "from calls with the same options and matrices: points that differ in the last "
            "digits fall on either side of it"
        )
    return "the two solves returned different points (cause not isolated)"


def _matrix_type_cause(row: dict[str, Any], directory: Path, tol: float) -> str:
    """The re-solve of one problem with qpsolvers as qpbenchmark calls it (the set's
    matrices) and as this library's backend does (CSC for a solver with a sparse API):
    a cause where the two calls' verdicts split as the two runs' did."""
    import qpsolvers

    solver = row["solver"]
    both = solver in qpsolvers.sparse_solvers and solver in qpsolvers.dense_solvers
    if row.get("form") != "condensed" or not both:  # (qpbenchmark hands a sparse-only
        return ""  # solver CSC matrices too)
    arrays = load_problem(directory / DATA_FOLDER / f"{row['problem']}.npz")
    options = {"verbose": False, **json.loads(row.get("options") or "{}")}  # the same both ways
    verdicts = []
    for as_csc in (False, True):
        parts = {
            k: (sp.csc_matrix(v) if as_csc and k in ("P", "G", "A") and v is not None else v)
            for k, v in arrays.items()
        }
        solution = qpsolvers.solve_problem(qpsolvers.Problem(**parts), solver, **options)
        ok = bool(solution.found) and all(
            value < tol
            for value in (
                solution.primal_residual(),
                solution.dual_residual(),
                solution.duality_gap(),
            )
        )
        verdicts.append(ok)
    if verdicts[0] != verdicts[1] and verdicts[1] == _success(row, tol):
        return (
            f"the matrix type: this library hands {solver} CSC matrices (qpsolvers then runs "
            "its sparse interface), qpbenchmark the set's dense arrays (its dense one); "
            f"re-solved both ways, {solver} succeeds with the "
            f"{'dense' if verdicts[0] else 'CSC'} call only"
        )
    return ""


def format_comparison(
    table: Sequence[dict[str, Any]], differences: Sequence[dict[str, Any]]
) -> str:
    """Markdown of :func:`compare_results`."""
    lines = [
        "| solver | settings | problems | success % (ltv_lstm_mpc) | success % (qpbenchmark) "
        "| runtime shgeom s (ltv_lstm_mpc) | runtime shgeom s (qpbenchmark) "
        "| runtime ratio where both found (median) |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for r in table:
        lines.append(
            f"| {r['solver']} | {r['settings']} | {r['problems']} | {r['success_ours']:.1f} | "
            f"{r['success_qpbenchmark']:.1f} | {r['runtime_ours_s']:.2e} | "
            f"{r['runtime_qpbenchmark_s']:.2e} | {r['runtime_ratio_found']:.2f} |"
        )
    lines += ["", f"Problems whose success differs: {len(differences)}", ""]
    if differences:
        lines += [
            "| problem | solver | settings | ltv_lstm_mpc | qpbenchmark | reason |",
            "|---|---|---|---|---|---|",
        ]
        lines += [
            f"| {d['problem']} | {d['solver']} | {d['settings']} | {d['ours']} | "
            f"{d['qpbenchmark']} | {d['reason']} |"
            for d in differences
        ]
    return "\n".join(lines) + "\n"


def write_metrics(directory: str | Path, rows: Sequence[dict[str, Any]]) -> dict[str, Path]:
    """``results/ltv_lstm_mpc.csv`` (the rows), ``results/ltv_lstm_mpc.md`` (the summary per
    form) and, for each set whose qpbenchmark results file is there
    (``results/<module>.csv``), ``results/comparison_<form>.md``."""
    directory = Path(directory)
    results = directory / "results"
    paths = {"rows": write_rows(rows, results / "ltv_lstm_mpc.csv")}
    lines = []
    for form in FORMS:
        mine = [r for r in rows if r.get("form") == form]
        if not mine:
            continue
        lines += [
            f"## {form} QPs ({len({r['problem'] for r in mine})} problems)",
            "",
            "| solver | settings | success % | runtime shgeom (s) | runtime (rel.) "
            "| primal (rel.) | dual (rel.) | gap (rel.) |",
            "|---|---|---|---|---|---|---|---|",
        ]
        for (solver, group), m in sorted(summarize(mine).items()):
            lines.append(
                f"| {solver} | {group} | {m['success_rate']:.1f} | {m['runtime']:.2e} | "
                f"{m['runtime_relative']:.1f} | {m['primal_residual_relative']:.1f} | "
                f"{m['dual_residual_relative']:.1f} | {m['duality_gap_relative']:.1f} |"
            )
        lines.append("")
        theirs = results / f"{MODULES[form]}.csv"
        if theirs.is_file():
            table, differences = compare_results(mine, theirs, directory)
            paths[f"comparison_{form}"] = results / f"comparison_{form}.md"
            paths[f"comparison_{form}"].write_text(format_comparison(table, differences))
    paths["summary"] = results / "ltv_lstm_mpc.md"
    paths["summary"].write_text("\n".join(lines) + "\n")
    return paths
