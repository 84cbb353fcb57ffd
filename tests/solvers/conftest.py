"""Shared fixtures of the solver-layer tests: solver list, per-solver tolerances, references."""

from __future__ import annotations

import functools
from dataclasses import dataclass

import numpy as np
import pytest
from ltv_lstm_mpc.solvers import (
    ConvexProblem,
    PolyhedralInnerApproximation,
    Solution,
    SolverStatus,
    available_solvers,
    solve,
)
from ltv_lstm_mpc.solvers.testing import random_mpc_problem, random_qp, random_socp
from optional_extras import require_solver

REFERENCE = "cvxpy:CLARABEL"


@dataclass(frozen=True)
class Tol:
    """Accepted deviation from the reference: relative to ``1 + |reference|``."""

    z: float = 1e-5
    objective: float = 1e-6
    kkt: float = 1e-5


#: Per-solver tolerances (solver-specific accuracy, all solved at tolerance=1e-8).
#: First-order methods (OSQP, SCS, PROXQP's ADMM-like outer loop) and ECOS (cvxpy
#: turns the quadratic objective into a cone for it) get looser ones.
TOLERANCES: dict[str, Tol] = {
    "cvxpy:ECOS": Tol(z=1e-3, objective=1e-5, kkt=1e-3),
    "qpsolvers:ecos": Tol(z=1e-3, objective=1e-5, kkt=1e-3),
    "cvxpy:SCS": Tol(z=1e-3, objective=1e-4, kkt=1e-3),
    "qpsolvers:scs": Tol(z=1e-3, objective=1e-4, kkt=1e-3),
    "cvxpy:OSQP": Tol(z=1e-4, objective=1e-5, kkt=1e-4),
    "qpsolvers:osqp": Tol(z=1e-4, objective=1e-5, kkt=1e-4),
    "osqp": Tol(z=1e-4, objective=1e-5, kkt=1e-4),
    "cvxpy:PROXQP": Tol(z=1e-4, objective=1e-5, kkt=1e-4),
    "qpsolvers:proxqp": Tol(z=1e-4, objective=1e-5, kkt=1e-4),
    "proxqp": Tol(z=1e-4, objective=1e-5, kkt=1e-4),
}
#: qpsolvers gives no native status for these: an infeasible problem is FAILED, not INFEASIBLE.
NO_NATIVE_STATUS = frozenset({"qpsolvers:daqp", "qpsolvers:highs", "qpsolvers:quadprog"})

SOLVERS = available_solvers()
CONE_SOLVERS = [
    s
    for s in SOLVERS
    if s in ("cvxpy:CLARABEL", "cvxpy:ECOS", "cvxpy:SCS", "clarabel", "daqp:socp")
]


def tol(solver: str) -> Tol:
    """Tolerances of ``solver``."""
    return TOLERANCES.get(solver, Tol())


def solver_params(solvers: list[str] | None = None) -> list[object]:
    """``pytest.param(name, id=name)`` for every installed solver."""
    return [pytest.param(s, id=s) for s in (SOLVERS if solvers is None else solvers)]


def assert_close(sol: Solution, ref: Solution, t: Tol) -> None:
    """Compare ``z`` and objective with the reference, relative to ``1 + |ref|``."""
    assert sol.status.has_solution, f"{sol.solver}: {sol.status.name} ({sol.info})"
    assert ref.z is not None and sol.z is not None
    scale = 1.0 + float(np.max(np.abs(ref.z)))
    err = float(np.max(np.abs(sol.z - ref.z)))
    assert err <= t.z * scale, f"{sol.solver}: max|z - z_ref| = {err:.3g} > {t.z * scale:.3g}"
    oerr = abs(sol.objective - ref.objective)
    assert oerr <= t.objective * (1.0 + abs(ref.objective)), (
        f"{sol.solver}: |obj - obj_ref| = {oerr:.3g} (obj_ref={ref.objective:.6g})"
    )


@functools.cache
def problem(name: str) -> ConvexProblem:
    """Named test problems (built once per session)."""
    if name == "qp":
        return random_qp(12, 9, 3, seed=3)
    if name == "qp_nobounds":
        return random_qp(8, 6, 0, seed=4, bounds=False)
    if name == "socp":
        return random_socp(10, 6, 2, 2, seed=5)
    if name.startswith("mpc"):
        return random_mpc_problem(int(name[3:]), seed=7)
    raise KeyError(name)


@functools.cache
def reference(name: str, reformulated: bool = False) -> Solution:
    """High-accuracy CLARABEL solution of ``problem(name)`` (or of its reformulation); skips
    the test where cvxpy is not installed."""
    require_solver(REFERENCE)
    p = problem(name)
    if reformulated:
        p = PolyhedralInnerApproximation().apply(p)
    ref = solve(p, REFERENCE, tolerance=1e-10)
    assert ref.status is SolverStatus.OPTIMAL, ref.info
    return ref
