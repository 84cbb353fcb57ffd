"""Property test: ``daqp:socp`` on random SOCPs of the controller's shape, against CLARABEL.

The exact-cone subproblem of the controller (``CondensedTranscription._cone_data``) has
the variables ``z = (du, t_c, t_h)``, boxes on ``du``, output rows ``lo <= A du <= up``
and the terminal cones :math:`\\|F_c du + g_c\\| \\le t_c`, :math:`\\|F_h du + g_h\\| \\le
t_h`, :math:`\\|P_f^{1/2} t\\| \\le \\alpha`. The problems drawn here have that shape and
are, by construction, one of

- ``feasible``: a strictly feasible point is built first (as in
  :mod:`~ltv_lstm_mpc.solvers.testing`);
- ``infeasible``: the boxes keep :math:`\\|F_c du + g_c\\|` above :math:`m_c > 0`, and
  :math:`\\alpha < \\sqrt{(P_f)_{11}}\\, m_c` (the cones and boxes contradict; no row alone
  does);
- ``unbounded``: one free ``du`` entry with no curvature, a linear cost, and in no row or
  cone;

with the terminal cost either :math:`t^\\top P_f t` (the controller's) or linear in
``t`` (all the curvature of ``t`` in the cones: the first SQP subproblem is unbounded).
CLARABEL's certified status (native ``clarabel``: its infeasibility and
unboundedness certificates are checked by the layer) is the reference. ``daqp:socp``
must never report ``INFEASIBLE`` / ``UNBOUNDED`` where the problem is not, must give them
only with a certificate the layer checked, never a point where there is none, and where
both are ``OPTIMAL`` the same point.
"""

from __future__ import annotations

import warnings

import numpy as np
import pytest
from ltv_lstm_mpc.solvers import DenseCone, DenseQP, DenseSession, Solution, SolverStatus
from optional_extras import requires_solver

hypothesis = pytest.importorskip("hypothesis")
st = hypothesis.strategies

pytestmark = requires_solver("daqp:socp", "clarabel")

KINDS = ("feasible", "infeasible", "unbounded")
P_F = np.array([[2.0, 0.5], [0.5, 1.0]])  # the terminal weight: >= 0 entrywise, definite


def controller_socp(seed: int, kind: str, linear_t: bool) -> DenseQP:
    """A random SOCP of the controller's shape, ``kind`` by construction (module docstring)."""
    rng = np.random.default_rng(seed)
    p = int(rng.integers(2, 7))  # inputs over the horizon
    k = int(rng.integers(1, 4))  # rows of each state cone
    rows = int(rng.integers(0, 4))
    n = p + 2
    Q, _ = np.linalg.qr(rng.standard_normal((p, p)))
    H = np.zeros((n, n))
    H[:p, :p] = (Q * np.geomspace(0.1, 10.0, p)) @ Q.T
    f = np.zeros(n)
    f[:p] = rng.standard_normal(p) * 3.0
    if linear_t:
        f[p:] = rng.uniform(0.1, 2.0, 2)
    else:
        H[p:, p:] = P_F
    u_max = rng.uniform(0.5, 2.0)
    lb = np.concatenate([np.full(p, -u_max), np.full(2, -np.inf)])
    ub = np.concatenate([np.full(p, u_max), np.full(2, np.inf)])
    du0 = rng.uniform(-0.5, 0.5, p) * u_max
    A = np.zeros((rows, n))
    A[:, :p] = rng.standard_normal((rows, p))
    if kind == "unbounded":  # du_0 in no row (below): the rows are centred without it
        A[:, 0] = 0.0
    center = A[:, :p] @ du0
    lo = center - rng.uniform(0.1, 1.0, rows)
    up = center + rng.uniform(0.1, 1.0, rows)
    F_c = np.zeros((k, n))
    F_h = np.zeros((k, n))
    F_c[:, :p] = rng.standard_normal((k, p))
    F_h[:, :p] = rng.standard_normal((k, p))
    g_c = rng.standard_normal(k)
    g_h = rng.standard_normal(k)
    if kind == "unbounded":  # du_0 free, flat, costed, in no row or cone
        H[0, :] = 0.0
        H[:, 0] = 0.0
        f[0] = rng.choice([-1.0, 1.0]) * rng.uniform(0.5, 2.0)
        lb[0], ub[0] = -np.inf, np.inf
        A[:, 0] = 0.0
        F_c[:, 0] = 0.0
        F_h[:, 0] = 0.0
    if kind == "infeasible":  # the boxes keep |F_c du + g_c| >= m_c > 0
        g_c = g_c / np.linalg.norm(g_c) * (np.abs(F_c[:, :p]).sum(axis=1).max() * u_max * 2 + 1)
        m_c = np.linalg.norm(g_c) - np.linalg.norm(F_c[:, :p], 2) * u_max * np.sqrt(p)
        assert m_c > 0
        alpha = 0.9 * np.sqrt(P_F[0, 0]) * m_c
    else:
        x0 = np.append(du0, [0.0, 0.0])
        t0 = np.array([np.linalg.norm(F_c @ x0 + g_c) + 0.1, np.linalg.norm(F_h @ x0 + g_h) + 0.1])
        w, V = np.linalg.eigh(P_F)
        alpha = float(np.linalg.norm((V * np.sqrt(w)) @ V.T @ t0)) * rng.uniform(1.05, 2.0)
    e_c = np.zeros(n)
    e_c[p] = 1.0
    e_h = np.zeros(n)
    e_h[p + 1] = 1.0
    w, V = np.linalg.eigh(P_F)
    F_t = np.zeros((2, n))
    F_t[:, p:] = (V * np.sqrt(w)) @ V.T
    cones = (
        DenseCone(F_c, g_c, e_c, 0.0),
        DenseCone(F_h, g_h, e_h, 0.0),
        DenseCone(F_t, np.zeros(2), np.zeros(n), float(alpha)),
    )
    return DenseQP(H=H, f=f, A=A, lo=lo, up=up, lb=lb, ub=ub, cones=cones)


def _solve(solver: str, qp: DenseQP) -> Solution:
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return DenseSession(solver).solve(qp)


@hypothesis.settings(max_examples=60, deadline=None, derandomize=True)
@hypothesis.given(
    seed=st.integers(0, 2**31 - 1), kind=st.sampled_from(KINDS), linear_t=st.booleans()
)
def test_daqp_socp_statuses_match_clarabel_certificates(
    seed: int, kind: str, linear_t: bool
) -> None:
    """``daqp:socp``'s status agrees with CLARABEL's certified one (module docstring)."""
    qp = controller_socp(seed, kind, linear_t)
    reference = _solve("clarabel", qp)
    ours = _solve("daqp:socp", qp)
    where = (
        f"seed {seed}, {kind}, linear t {linear_t}: daqp:socp {ours.status.name} ({ours.info}); "
        f"clarabel {reference.status.name} ({reference.info})"
    )
    truth = {
        "feasible": SolverStatus.OPTIMAL,
        "infeasible": SolverStatus.INFEASIBLE,
        "unbounded": SolverStatus.UNBOUNDED,
    }[kind]
    # the generator's claim, where CLARABEL settles it (a certificate, or an accepted point)
    if reference.status in (truth, SolverStatus.OPTIMAL, *truth_wrong(truth)):
        assert reference.status is truth, f"generator and CLARABEL disagree: {where}"
    if ours.status in (SolverStatus.INFEASIBLE, SolverStatus.UNBOUNDED):
        assert ours.status is truth, f"wrong status: {where}"
        # a certificate the layer checked: from the backend, or from the acceptance check of
        # a point returned far out on a direction of unbounded descent
        checked = (
            "certificate checked" in ours.info or "direction of unbounded descent" in ours.info
        )
        assert ours.certificate is not None and checked, where
    if truth is not SolverStatus.OPTIMAL:
        assert not ours.status.has_solution, f"a point on a problem without one: {where}"
        return
    assert ours.status in (SolverStatus.OPTIMAL, SolverStatus.MAX_ITER), where
    if ours.status is SolverStatus.OPTIMAL and reference.status is SolverStatus.OPTIMAL:
        assert ours.z is not None and reference.z is not None
        scale = 1.0 + float(np.max(np.abs(ours.z)))
        err = float(np.max(np.abs(ours.z - reference.z))) / scale
        assert err <= 1e-4, f"points differ by {err:.1e}: {where}"


def truth_wrong(truth: SolverStatus) -> tuple[SolverStatus, ...]:
    """The certified statuses other than ``truth`` (CLARABEL's, when it contradicts)."""
    return tuple(s for s in (SolverStatus.INFEASIBLE, SolverStatus.UNBOUNDED) if s is not truth)


@pytest.mark.parametrize("kind", KINDS)
@pytest.mark.parametrize("linear_t", [False, True])
def test_generator_kinds_certified_by_clarabel(kind: str, linear_t: bool) -> None:
    """The generator's kinds are what CLARABEL certifies (a few seeds)."""
    for seed in range(5):
        qp = controller_socp(seed, kind, linear_t)
        status = _solve("clarabel", qp).status
        expected = {
            "feasible": (SolverStatus.OPTIMAL, SolverStatus.OPTIMAL_INACCURATE),
            "infeasible": (SolverStatus.INFEASIBLE,),
            "unbounded": (SolverStatus.UNBOUNDED,),
        }[kind]
        assert status in expected, (seed, kind, linear_t, status)
