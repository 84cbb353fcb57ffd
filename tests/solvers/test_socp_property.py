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
from ltv_lstm_mpc.solvers import DenseQP, DenseSession, Solution, SolverStatus
from ltv_lstm_mpc.solvers.testing import SOCP_KINDS as KINDS
from ltv_lstm_mpc.solvers.testing import controller_socp
from optional_extras import requires_solver

hypothesis = pytest.importorskip("hypothesis")
st = hypothesis.strategies

pytestmark = requires_solver("daqp:socp", "clarabel")


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
