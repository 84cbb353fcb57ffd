"""Exact cones by SQP on DAQP (``daqp:socp``) against CLARABEL on the MPC's own subproblems.

The solver layer's conformance suite (``tests/solvers``) runs ``daqp:socp`` like every
backend; here it meets the condensed exact-cone subproblems of closed loops: the same
plans as CLARABEL to solver accuracy, the cones held (the smoothing is conservative), and
the same verdict on the infeasible steps.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
from hypothesis import assume, given, settings
from hypothesis import strategies as st
from ltv_lstm_mpc.solvers import DenseSession, SolverStatus
from ltv_lstm_mpc.solvers.socp_sqp import FULL_STEPS
from ltv_lstm_mpc.solvers.testing import REDUCTION_SCALE_CASES, write_reduction_case
from optional_extras import requires_solver

from ltv_lstm_mpc import OffsetFreeController
from ltv_lstm_mpc.lstm.shipped import load_model

pytestmark = requires_solver("daqp:socp", "clarabel")


@pytest.mark.parametrize(("index", "N"), [(0, 5), (0, 20), (2, 5), (2, 20)])
def test_subproblems_of_a_closed_loop_match_clarabel(index: int, N: int) -> None:
    """Bench scenarios 1 and 3 on the shipped pH model, 120 steps on CLARABEL; each step's
    nominal subproblem solved again by both: first inputs within 1e-6 (normalized; measured
    at most 3.4e-8), objectives within 1e-8 relative, every cone held, and daqp:socp finds
    no point where CLARABEL proves the problem infeasible (scenario 3 has such steps)."""
    from ltv_lstm_mpc.solver_comparison.harness import bench_scenarios

    model = load_model("ph_lstm_n5.npz")
    scenario = bench_scenarios(model)[index]
    config = replace(scenario.config, N=N, solver="clarabel")
    controller = OffsetFreeController(
        model, config, setpoint_rate_limit=scenario.setpoint_rate_limit, kernels="compiled"
    )
    plant = scenario.make_plant(model)
    y = plant.output()
    socp = DenseSession("daqp:socp", tolerance=1e-8)
    clarabel = DenseSession("clarabel", tolerance=1e-10)
    solved = infeasible = 0
    for k in range(120):
        u = controller.step(y, scenario.setpoints[k])
        d = scenario.disturbances[k]
        y = plant.step(u, None if np.isnan(d) else d)
        qp = controller.mpc.last_problem("nominal")
        ours, theirs = socp.solve(qp), clarabel.solve(qp)
        if theirs.status is SolverStatus.INFEASIBLE:
            assert ours.z is None, f"step {k}: {ours.status} where CLARABEL is infeasible"
            infeasible += 1
            continue
        assert theirs.z is not None and ours.z is not None, f"step {k}: {ours.info}"
        solved += 1
        assert abs(ours.z[0] - theirs.z[0]) <= 1e-6, k
        objective, reference = qp.objective(ours.z), qp.objective(theirs.z)
        assert abs(objective - reference) <= 1e-8 * (1.0 + abs(reference)), k
        assert max(cone.violation(ours.z) for cone in qp.cones) <= 1e-12, k
    assert solved >= 60
    if index == 2 and N == 5:  # its infeasible steps come within the first 120
        assert infeasible > 0


def test_closed_loop_on_daqp_socp_follows_clarabels() -> None:
    """The closed loop on daqp:socp: no violations, the same statuses as on clarabel over
    scenario 1 (all optimal), applied inputs within 1e-5 mL/s of clarabel's."""
    from ltv_lstm_mpc.solver_comparison.harness import bench_scenarios

    model = load_model("ph_lstm_n5.npz")
    scenario = bench_scenarios(model)[0]
    inputs = []
    for solver in ("daqp:socp", "clarabel"):
        config = replace(scenario.config, N=5, solver=solver)
        controller = OffsetFreeController(
            model, config, setpoint_rate_limit=scenario.setpoint_rate_limit, kernels="compiled"
        )
        assert controller.mpc.reformulation is None  # exact cones
        plant = scenario.make_plant(model)
        y = plant.output()
        applied = []
        for k in range(150):
            u = controller.step(y, scenario.setpoints[k])
            applied.append(float(u[0]))
            y = plant.step(u)
        assert {r.mpc.status for r in controller.records} == {"optimal"}
        inputs.append(np.array(applied))
    np.testing.assert_allclose(inputs[0], inputs[1], rtol=0, atol=1e-5)


@pytest.mark.parametrize("index", [0, 2])
def test_one_call_cone_feedback_equals_the_general_path(index: int) -> None:
    """RobustMPC's one-call exact-cone feedback (mpc/native_feedback.cone_feedback) against
    its general path (native_feedback=False: the daqp:socp session), 200 steps of bench's
    scenarios 1 and 3: the same applied inputs and statuses."""
    from ltv_lstm_mpc import RobustMPC
    from ltv_lstm_mpc.solver_comparison.harness import bench_scenarios

    model = load_model("ph_lstm_n5.npz")
    scenario = bench_scenarios(model)[index]
    config = replace(scenario.config, N=5, solver="daqp:socp")
    runs = []
    for native in (True, False):
        mpc = RobustMPC(model, config, native_feedback=native)
        assert (mpc._native_feedback is not None) is native
        controller = OffsetFreeController(
            model, config, setpoint_rate_limit=scenario.setpoint_rate_limit, mpc=mpc
        )
        plant = scenario.make_plant(model)
        y = plant.output()
        applied = []
        for k in range(200):
            u = controller.step(y, scenario.setpoints[k])
            applied.append(float(u[0]))
            d = scenario.disturbances[k]
            y = plant.step(u, None if np.isnan(d) else d)
        runs.append((np.array(applied), [r.mpc.status for r in controller.records]))
    np.testing.assert_allclose(runs[0][0], runs[1][0], rtol=0, atol=1e-12)
    assert runs[0][1] == runs[1][1]
    if index == 2:
        assert "infeasible" in runs[0][1]


# ---------------------------------------------------------------- row screening
def _workspace(H, f, A, lo, up, lb, ub, cones):
    """A SocpWorkspace of the problem; ``cones``: (F, g, e, offset) each."""
    from ltv_lstm_mpc.solvers import daqp_native
    from ltv_lstm_mpc.solvers.socp_sqp import new_socp_workspace, socp_arrays
    from ltv_lstm_mpc.solvers.tolerances import solver_options

    buffers = daqp_native.native(solver_options("daqp", 1e-8, {}))
    n, m = H.shape[0], A.shape[0]
    arrays = socp_arrays(n, m, [F.shape[0] for F, _, _, _ in cones], buffers)
    for name, value in (("H", H), ("f", f), ("A", A), ("lo", lo), ("up", up), ("lb", lb),
                        ("ub", ub)):  # fmt: skip
        arrays[name][...] = value
    start = 0
    for j, (F, g, e, offset) in enumerate(cones):
        arrays["F"][start : start + F.shape[0]] = F
        arrays["g"][start : start + F.shape[0]] = g
        arrays["e"][j] = e
        arrays["offsets"][j] = offset
        start += F.shape[0]
    return arrays, new_socp_workspace(**arrays)


def _both(problem):
    """socp_solve with and without row screening: (result, z, lam) of each."""
    from ltv_lstm_mpc.solvers.socp_sqp import MAX_ITERATIONS, socp_solve

    out = []
    for screen in (False, True):
        arrays, ws = _workspace(*problem)
        result = socp_solve(ws, False, MAX_ITERATIONS, screen)
        out.append((result, arrays["z"].copy(), arrays["lam"].copy()))
    return out


def test_a_row_left_out_that_the_solution_violates_is_added() -> None:
    """min 1/2 |z - c|^2 with the row z_0 + z_1 <= 1 and ||z|| <= 3: the row has slack 1 at
    the first iterate z = 0, so the first subproblem leaves it out, its solution (near c)
    violates it, and the subproblem is solved again with it. Both ways: z = (0.5, 0.5),
    the row's multiplier 1.5, the same SQP iterates."""
    c = np.array([2.0, 2.0])
    problem = (
        np.eye(2), -c, np.array([[1.0, 1.0]]), np.array([-np.inf]), np.array([1.0]),
        np.full(2, -10.0), np.full(2, 10.0), [(np.eye(2), np.zeros(2), np.zeros(2), 3.0)],
    )  # fmt: skip
    (full, z_full, lam_full), (screened, z, lam) = _both(problem)
    assert full[0] > 0 and screened[0] > 0
    np.testing.assert_allclose(z, [0.5, 0.5], atol=1e-9)
    np.testing.assert_allclose(z, z_full, rtol=0, atol=1e-14)
    assert abs(lam[2] - 1.5) <= 1e-9  # bounds, then the row
    np.testing.assert_allclose(lam, lam_full, rtol=0, atol=1e-14)
    assert screened[1] == full[1]  # SQP iterations


def test_an_infeasible_row_left_out_is_found() -> None:
    """The row z_0 <= 5 with ||z - (10, 0)|| <= 1: infeasible. The row has slack 5 at the
    first iterate z = 0, so the first subproblem leaves it out; its solution (z_0 >= 9 by
    the cone's cut) violates it, the row is added and DAQP proves the subproblem, hence the
    problem, infeasible: the same verdict as with every row."""
    problem = (
        np.eye(2), np.zeros(2), np.array([[1.0, 0.0]]), np.array([-np.inf]), np.array([5.0]),
        np.full(2, -20.0), np.full(2, 20.0),
        [(np.eye(2), np.array([-10.0, 0.0]), np.zeros(2), 1.0)],
    )  # fmt: skip
    (full, _, _), (screened, _, _) = _both(problem)
    assert full[0] == screened[0] == -1
    assert screened[1] == full[1] == 1  # SQP iterations


@settings(max_examples=60, deadline=None)
@given(
    seed=st.integers(0, 2**32 - 1),
    n=st.integers(2, 8),
    m=st.integers(1, 10),
    cone_count=st.integers(1, 3),
    pull=st.floats(0.0, 20.0),
)
def test_screened_rows_give_the_same_solution(
    seed: int, n: int, m: int, cone_count: int, pull: float
) -> None:
    """Random strictly feasible problems (rows, bounds and cones around a feasible point;
    the cost pulls the solution ``pull`` away from it, so that rows and cones bind): the
    SQP with row screening converges where the one with all rows does, to the same point
    (1e-9) with the same multipliers (1e-7) and the same number of SQP iterations."""
    rng = np.random.default_rng(seed)
    B = rng.normal(size=(n, n))
    H = np.eye(n) + B.T @ B
    feasible = rng.normal(size=n)
    f = -H @ (feasible + pull * rng.normal(size=n))
    A = rng.normal(size=(m, n))
    centre = A @ feasible
    lo = centre - rng.uniform(0.1, 2.0, size=m)
    up = centre + rng.uniform(0.1, 2.0, size=m)
    lo[rng.random(m) < 0.3] = -np.inf
    lb, ub = feasible - rng.uniform(0.5, 5.0, size=n), feasible + rng.uniform(0.5, 5.0, size=n)
    cones = []
    for _ in range(cone_count):
        k = int(rng.integers(1, n + 1))
        F, g, e = rng.normal(size=(k, n)), rng.normal(size=k), 0.1 * rng.normal(size=n)
        offset = np.linalg.norm(F @ feasible + g) - e @ feasible + rng.uniform(0.1, 1.0)
        cones.append((F, g, e, offset))
    (full, z_full, lam_full), (screened, z, lam) = _both((H, f, A, lo, up, lb, ub, cones))
    assert full[0] > 0 and full[1] <= 50, full
    assert screened[0] > 0 and screened[1] == full[1], (screened, full)
    np.testing.assert_allclose(z, z_full, rtol=0, atol=1e-9 * (1.0 + np.abs(z_full).max()))
    np.testing.assert_allclose(lam, lam_full, rtol=0, atol=1e-7 * (1.0 + np.abs(lam_full).max()))


def test_cone_products_formed_as_needed_give_the_same_numbers(monkeypatch) -> None:
    """A workspace too large to store the cones' F_j' F_j forms them at each SQP iteration:
    the same iterates, bit for bit, as one that stores them."""
    from ltv_lstm_mpc.solvers import socp_sqp

    rng = np.random.default_rng(7)
    n = 6
    B = rng.normal(size=(n, n))
    H = np.eye(n) + B.T @ B
    cones = []
    for _ in range(2):  # strictly feasible at z = 0
        F, g = rng.normal(size=(3, n)), rng.normal(size=3)
        cones.append((F, g, np.zeros(n), np.linalg.norm(g) + 0.5))
    problem = (
        H, -H @ (5.0 * rng.normal(size=n)), rng.normal(size=(2, n)), np.full(2, -1.0),
        np.full(2, 1.0), np.full(n, -3.0), np.full(n, 3.0), cones,
    )  # fmt: skip
    stored = _both(problem)[1]
    monkeypatch.setattr(socp_sqp, "STORED_PRODUCTS", 0)
    arrays, _ = _workspace(*problem)
    assert arrays["cone_products"].shape[0] == 0
    formed = _both(problem)[1]
    assert stored[0][:3] == formed[0][:3] and stored[0][0] > 0
    assert (stored[2][-2:] > 0).all()  # both cones active: their curvature is in the Hessian
    assert np.array_equal(stored[1], formed[1]) and np.array_equal(stored[2], formed[2])


def _mpc_subproblems(index: int, steps: int):
    """A closed loop of bench scenario ``index + 1`` at N = 20 on ``daqp:socp``: after each
    step, ``(k, arrays, workspace)`` of the nominal exact-cone QP (its last subproblem is
    still in the workspace)."""
    from ltv_lstm_mpc.solver_comparison.harness import bench_scenarios

    model = load_model("ph_lstm_n5.npz")
    scenario = bench_scenarios(model)[index]
    config = replace(scenario.config, N=20, solver="daqp:socp")
    controller = OffsetFreeController(
        model, config, setpoint_rate_limit=scenario.setpoint_rate_limit, kernels="compiled"
    )
    problem = controller.mpc._problem
    arrays, ws = problem.socp_arrays, problem.socp_workspace
    assert ws is not None
    plant = scenario.make_plant(model)
    y = plant.output()
    for k in range(steps):
        u = controller.step(y, scenario.setpoints[k])
        d = scenario.disturbances[k]
        y = plant.step(u, None if np.isnan(d) else d)
        yield k, arrays, ws


@pytest.mark.parametrize("index", [0, 2])
def test_screened_rows_on_the_mpcs_subproblems(index: int) -> None:
    """The exact-cone subproblems of 60 closed-loop steps at N = 20 (bench scenarios 1 and
    3, this one with infeasible steps), solved with and without row screening: the same
    exit flags and SQP iterations, the same points and multipliers to 1e-12."""
    from ltv_lstm_mpc.solvers.socp_sqp import MAX_ITERATIONS, socp_solve

    flags = []
    for k, arrays, ws in _mpc_subproblems(index, 60):
        results = []
        for screen in (False, True):  # the step's last subproblem is still in the workspace
            result = socp_solve(ws, False, MAX_ITERATIONS, screen)
            results.append((result, arrays["z"].copy(), arrays["lam"].copy()))
        (full, z_full, lam_full), (screened, z, lam) = results
        assert screened[:2] == full[:2], k
        flags.append(full[0])
        if full[0] > 0:
            np.testing.assert_allclose(z, z_full, rtol=0, atol=1e-12)
            np.testing.assert_allclose(lam, lam_full, rtol=0, atol=1e-12)
    assert sum(flag > 0 for flag in flags) >= 40


# ---------------------------------------------------------------- epigraph elimination
def _solve(problem, eliminate: bool, times: int = 1):
    """socp_solve ``times`` on one workspace (later solves predict the first subproblem's
    active epigraph cones from the solve before): (result, z, lam, arrays) of the last."""
    from ltv_lstm_mpc.solvers.socp_sqp import MAX_ITERATIONS, socp_solve

    arrays, ws = _workspace(*problem)
    for _ in range(times):
        result = socp_solve(ws, False, MAX_ITERATIONS, True, eliminate)
    return result, arrays["z"].copy(), arrays["lam"].copy(), arrays


def _epigraph_problem(seed: int, free: int, epigraphs: int, pull: float, with_rows: bool):
    """A strictly feasible problem with ``epigraphs`` cones ||F_j x + g_j|| <= t_j on
    unbounded variables t_j at random places, F_j zero on every t, a cost on the t's (so
    that their cones bind) and on x pulling it away from a feasible point, and a cone
    ||S t|| <= alpha on the t's (the MPC's terminal set has this form)."""
    rng = np.random.default_rng(seed)
    n = free + epigraphs
    places = np.sort(rng.choice(n, size=epigraphs, replace=False))
    others = np.setdiff1d(np.arange(n), places)
    B = rng.normal(size=(n, n))
    H = np.eye(n) + 0.3 * B.T @ B
    feasible = np.zeros(n)
    feasible[others] = rng.normal(size=free)
    cones = []
    for k in places:
        rows = int(rng.integers(1, 4))
        F = np.zeros((rows, n))
        F[:, others] = rng.normal(size=(rows, free))
        g = rng.normal(size=rows)
        e = np.zeros(n)
        e[k] = 1.0
        feasible[k] = np.linalg.norm(F @ feasible + g) + rng.uniform(0.1, 1.0)
        cones.append((F, g, e, 0.0))
    S = np.zeros((2, n))
    S[:, places] = rng.normal(size=(2, epigraphs))
    cones.append((S, np.zeros(2), np.zeros(n), np.linalg.norm(S @ feasible) + 1.0))
    target = feasible + pull * rng.normal(size=n)
    target[places] = 0.5 * feasible[places]  # the cost pulls each t_j down onto its cone
    f = -H @ target
    m = 3 if with_rows else 0
    A = np.zeros((m, n))
    A[:, others] = rng.normal(size=(m, free))
    centre = A @ feasible
    lo, up = centre - rng.uniform(0.1, 2.0, size=m), centre + rng.uniform(0.1, 2.0, size=m)
    lb, ub = np.full(n, -np.inf), np.full(n, np.inf)
    lb[others] = feasible[others] - rng.uniform(0.5, 5.0, size=free)
    ub[others] = feasible[others] + rng.uniform(0.5, 5.0, size=free)
    return (H, f, A, lo, up, lb, ub, cones), places


@settings(max_examples=60, deadline=None)
@given(
    seed=st.integers(0, 2**32 - 1),
    free=st.integers(1, 8),
    epigraphs=st.integers(1, 3),
    pull=st.floats(0.0, 10.0),
    with_rows=st.booleans(),
)
def test_epigraph_elimination_gives_the_same_solution(
    seed: int, free: int, epigraphs: int, pull: float, with_rows: bool
) -> None:
    """Random problems with epigraph cones at random places (module docstring of
    solvers/daqp_socp.py, epigraph elimination): solved twice on one workspace (the second
    solve predicts its first subproblem's active cones from the first), with and without
    the elimination: points within 1e-9 and multipliers within 1e-7 (relative to their
    size), the same SQP iterations where it converges with full steps, and the eliminated
    variables found."""
    problem, places = _epigraph_problem(seed, free, epigraphs, pull, with_rows)
    eliminated, z, lam, arrays = _solve(problem, True, times=2)
    whole, z_whole, lam_whole, _ = _solve(problem, False, times=2)
    assume(whole[0] > 0 and whole[1] <= 50)  # a cone at its apex may take longer
    assert eliminated[0] > 0 and eliminated[1] <= 50, (eliminated, whole)
    if whole[1] <= FULL_STEPS:  # full steps: the same iterates (a line search's lengths
        assert eliminated[1] == whole[1], (eliminated, whole)  # may differ by rounding)
    assert list(arrays["epigraph"][:epigraphs]) == list(places)
    np.testing.assert_allclose(z, z_whole, rtol=0, atol=1e-9 * (1.0 + np.abs(z_whole).max()))
    np.testing.assert_allclose(lam, lam_whole, rtol=0, atol=1e-7 * (1.0 + np.abs(lam_whole).max()))


def test_a_wrongly_predicted_cone_falls_back_to_the_whole_subproblem() -> None:
    """min 1/2 (x - 2)^2 + 1/2 (t - c)^2 with |x| <= t: with c = 0 the cone binds
    (x = t = 1, multiplier 1), with c = 3 it does not (x = 2, t = 3). A solve with c = 0
    leaves the cone predicted active for the next first subproblem; solved again with
    c = 3, the subproblem without t gives the cone a negative multiplier, so the whole
    subproblem is solved: x = 2, t = 3, multiplier 0, as without the elimination."""
    from ltv_lstm_mpc.solvers.socp_sqp import MAX_ITERATIONS, socp_solve

    def problem(c: float):
        cone = (np.array([[1.0, 0.0]]), np.zeros(1), np.array([0.0, 1.0]), 0.0)
        return (
            np.eye(2), -np.array([2.0, c]), np.zeros((0, 2)), np.zeros(0), np.zeros(0),
            np.array([-10.0, -np.inf]), np.array([10.0, np.inf]), [cone],
        )  # fmt: skip

    arrays, ws = _workspace(*problem(0.0))
    first = socp_solve(ws, False, MAX_ITERATIONS)
    assert first[0] > 0
    np.testing.assert_allclose(arrays["z"], [1.0, 1.0], atol=1e-9)
    np.testing.assert_allclose(arrays["mu"], [1.0], atol=1e-9)
    assert arrays["first_active"][0] == 1
    for name, value in zip(("H", "f"), problem(3.0)[:2], strict=True):
        arrays[name][...] = value
    second = socp_solve(ws, False, MAX_ITERATIONS)
    assert second[0] > 0
    np.testing.assert_allclose(arrays["z"], [2.0, 3.0], atol=1e-9)
    assert arrays["mu"][0] == 0.0 and arrays["first_active"][0] == 0
    reference, z, lam, _ = _solve(problem(3.0), False)
    assert reference[1] == second[1]
    np.testing.assert_allclose(arrays["z"], z, rtol=0, atol=1e-12)
    np.testing.assert_allclose(arrays["lam"], lam, rtol=0, atol=1e-12)


def _parts(qp):
    """A DenseQP as the (H, f, A, lo, up, lb, ub, cones) of :func:`_workspace`."""
    cones = [(c.F, c.g, c.e, c.f) for c in qp.cones]
    return qp.H, qp.f, qp.A, qp.lo, qp.up, qp.lb, qp.ub, cones


def _predicted(qp):
    """``qp`` in a workspace whose cone 0 is predicted active (``first_active``)."""
    arrays, ws = _workspace(*_parts(qp))
    arrays["first_active"][0] = 1
    return arrays, ws


def test_an_infeasible_reduced_subproblem_ends_the_solve_where_it_proves_the_whole() -> None:
    """predicted_epigraph_socp(False): |x| <= t, |t| <= 1, x >= 3, with the first cone
    predicted active. Its subproblem without t is infeasible at SQP iteration 2 and no
    other row keeps t from its cone's row, so the solve ends there: the flag and SQP
    iteration of the whole subproblem's verdict (the SQP without the elimination), fewer
    DAQP iterations, and the same checked certificate."""
    from ltv_lstm_mpc.solvers.acceptance import ProblemView
    from ltv_lstm_mpc.solvers.socp_certificates import infeasibility_certificate
    from ltv_lstm_mpc.solvers.socp_sqp import MAX_ITERATIONS, socp_solve
    from ltv_lstm_mpc.solvers.testing import predicted_epigraph_socp

    qp = predicted_epigraph_socp("infeasible")
    arrays, ws = _predicted(qp)
    result = socp_solve(ws, False, MAX_ITERATIONS)
    reference_arrays, reference_ws = _predicted(qp)
    reference = socp_solve(reference_ws, False, MAX_ITERATIONS, True, False)
    assert result[:2] == reference[:2] == (-1, 2), (result, reference)
    assert arrays["eliminated"][0] == 1 and result[2] < reference[2], (result, reference)
    view = ProblemView.of_dense(qp)
    certificate, why = infeasibility_certificate(arrays, view)
    reference_certificate, _ = infeasibility_certificate(reference_arrays, view)
    assert certificate is not None and reference_certificate is not None, why
    for key, value in certificate.items():
        np.testing.assert_array_equal(value, reference_certificate[key])


@pytest.mark.parametrize(
    ("kind", "solution"), [("lower_row", 5.0), ("upper_row", 5.0), ("cone", 4.5)]
)
def test_an_infeasible_reduced_subproblem_of_a_feasible_one_does_not_end_the_solve(
    kind: str, solution: float
) -> None:
    """predicted_epigraph_socp's feasible kinds: |x - 1| <= t, x >= -3, and t kept at 5 or
    more by a row with a lower bound, by one with an upper bound, or at 4.5 or more by the
    cone |t - 5| <= 0.5; the cone predicted active. The subproblem without t is infeasible
    at the cold start, but that row or cone keeps t from its cone's row, so that is no
    verdict on the whole subproblem: it is solved, and the SQP converges as without the
    elimination (x = 2, t at its bound)."""
    from ltv_lstm_mpc.solvers.socp_sqp import MAX_ITERATIONS, socp_solve
    from ltv_lstm_mpc.solvers.testing import predicted_epigraph_socp

    qp = predicted_epigraph_socp(kind)
    arrays, ws = _predicted(qp)
    result = socp_solve(ws, False, MAX_ITERATIONS)
    assert result[0] > 0 and result[1] <= 50, result
    np.testing.assert_allclose(arrays["z"], [2.0, solution], atol=1e-8)
    reference_arrays, reference_ws = _predicted(qp)
    reference = socp_solve(reference_ws, False, MAX_ITERATIONS, True, False)
    assert reference[:2] == result[:2]
    np.testing.assert_allclose(arrays["z"], reference_arrays["z"], rtol=0, atol=1e-12)


@pytest.mark.parametrize("which", [0, 1])
def test_a_badly_scaled_reduced_subproblems_verdict_does_not_end_the_solve(which: int) -> None:
    """solvers.testing.badly_scaled_epigraph_socp: DAQP called their feasible reduced
    subproblems infeasible (a reduced Hessian of order 1e12 against 1, from |tau| about
    1e6; 1e5 times W_k's largest entry, from |tau| about 300-500 on a cost of 1e6 on t),
    which ended the solve FAILED where the SQP without the elimination converges; beyond
    REDUCTION_SCALE the whole subproblem is solved instead, and the solve converges as
    without the elimination, to a point that holds the rows, bounds and cones."""
    from ltv_lstm_mpc.solvers.socp_sqp import MAX_ITERATIONS
    from ltv_lstm_mpc.solvers.testing import badly_scaled_epigraph_socp

    qp = badly_scaled_epigraph_socp(which)
    problem = _parts(qp)
    result, z, _lam, _arrays = _solve(problem, True)
    reference, z_reference, _, _ = _solve(problem, False)
    assert reference[0] > 0 and reference[1] <= MAX_ITERATIONS
    assert result[0] > 0 and result[1] <= MAX_ITERATIONS, result
    np.testing.assert_allclose(z, z_reference, rtol=0, atol=1e-6)
    assert qp.max_violation(z) <= 1e-9


@pytest.mark.parametrize(
    ("epsilon", "cost_x", "cost_t", "proves"),
    [case[1:] for case in REDUCTION_SCALE_CASES],
    ids=[case[0] for case in REDUCTION_SCALE_CASES],
)
def test_a_reduced_verdict_is_taken_only_within_the_reduction_scale(
    epsilon: float, cost_x: float, cost_t: float, proves: bool
) -> None:
    """_reduction_proves on one eliminated cone's row x - epsilon t <= 0 (t = x / epsilon),
    W = diag(cost_x, cost_t) (solvers.testing.REDUCTION_SCALE_CASES): the reduced verdict
    is taken within scale and declined where one of the three tests fails alone (the row's
    entries against its coefficient on t; the reduced Hessian against W's largest entry,
    and against REDUCED_HESSIAN_LIMIT)."""
    from ltv_lstm_mpc.solvers.socp_sqp import _reduction_proves

    arrays, ws = _workspace(*reduction_case_problem(epsilon))
    write_reduction_case(arrays, epsilon, cost_x, cost_t)
    assert _reduction_proves(ws, 1) is proves


def reduction_case_problem(epsilon: float):
    """The problem of a REDUCTION_SCALE_CASES case: x, t free, the cone |x| <= epsilon t."""
    cone = (np.array([[1.0, 0.0]]), np.zeros(1), epsilon * np.array([0.0, 1.0]), 0.0)
    return (np.eye(2), np.zeros(2), np.zeros((0, 2)), np.zeros(0), np.zeros(0),
            np.full(2, -np.inf), np.full(2, np.inf), [cone])  # fmt: skip


def test_no_elimination_where_a_cone_holds_another_ones_variable() -> None:
    """Two epigraph cones whose first holds the second's variable: neither is eliminated
    (the substitution would couple them), and the solve is the whole-subproblem one."""
    F1 = np.array([[1.0, 0.0, 0.0, 1.0]])  # holds t_2 (index 3)
    F2 = np.array([[0.0, 1.0, 0.0, 0.0]])
    cones = [
        (F1, np.array([0.5]), np.array([0.0, 0.0, 1.0, 0.0]), 0.0),
        (F2, np.array([-0.5]), np.array([0.0, 0.0, 0.0, 1.0]), 0.0),
    ]
    problem = (
        np.eye(4), np.array([-1.0, -1.0, 1.0, 1.0]), np.zeros((0, 4)), np.zeros(0),
        np.zeros(0), np.array([-5.0, -5.0, -np.inf, -np.inf]),
        np.array([5.0, 5.0, np.inf, np.inf]), cones,
    )  # fmt: skip
    result, z, lam, arrays = _solve(problem, True, times=2)
    assert list(arrays["epigraph"]) == [-1, -1] and not arrays["eliminated"].any()
    reference, z_ref, lam_ref, _ = _solve(problem, False, times=2)
    assert result[:2] == reference[:2] and result[0] > 0
    assert np.array_equal(z, z_ref) and np.array_equal(lam, lam_ref)


@pytest.mark.parametrize("index", [0, 2])
def test_epigraph_elimination_on_the_mpcs_subproblems(index: int) -> None:
    """The exact-cone subproblems of 60 closed-loop steps at N = 20 (bench scenarios 1 and
    3), solved again with and without the epigraph elimination: the same exit flags and
    SQP iterations, points and multipliers within 1e-10 (measured: 1.5e-12, on t_c of
    about 2e-6; the SQP stops about 6e-9 from the solution); the two epigraph cones
    (||c_N - c_bar|| <= t_c, ||h_N - h_bar|| <= t_h, on the last two variables) were
    eliminated in the last subproblem of most steps."""
    from ltv_lstm_mpc.solvers.socp_sqp import MAX_ITERATIONS, socp_solve

    eliminated_steps = converged = 0
    for k, arrays, ws in _mpc_subproblems(index, 60):
        nz = arrays["H"].shape[0]
        results = []
        for eliminate in (False, True):
            result = socp_solve(ws, False, MAX_ITERATIONS, True, eliminate)
            results.append((result, arrays["z"].copy(), arrays["lam"].copy()))
        (whole, z_whole, lam_whole), (result, z, lam) = results
        assert result[:2] == whole[:2], k
        assert list(arrays["epigraph"]) == [nz - 2, nz - 1, -1]
        if whole[0] > 0:
            converged += 1
            eliminated_steps += list(arrays["eliminated"]) == [1, 1, 0]
            np.testing.assert_allclose(z, z_whole, rtol=0, atol=1e-10)
            np.testing.assert_allclose(lam, lam_whole, rtol=0, atol=1e-10)
    assert converged >= 40 and eliminated_steps >= 0.9 * converged


def test_a_problem_on_which_full_steps_cycle_converges_with_the_line_search() -> None:
    """Two variables, an epigraph cone whose cost pulls its variable far below it: the full
    SQP steps alternate between two points (the first FULL_STEPS iterations: z moves by
    more than 1 between consecutive iterates at the end), and the line search on the l1
    merit function that takes over then converges, to CLARABEL's solution (0.78784996,
    0.61185416), cone multiplier 2.8812936, computed with its tolerances at 1e-10)."""
    from ltv_lstm_mpc.solvers.socp_sqp import MAX_ITERATIONS, socp_solve

    H = np.array([[1.00853672, -0.04223842], [-0.04223842, 1.20912485]])
    cones = [
        (np.array([[1.30400005, 0.0], [0.94708096, 0.0]]),
         np.array([-0.70373524, -1.26542147]), np.array([0.0, 1.0]), 0.0),
        (np.array([[0.0, 0.04132598], [0.0, -2.32503077]]), np.zeros(2), np.zeros(2),
         5.1531471379105),
    ]  # fmt: skip
    problem = (
        H, np.array([-0.44011946, 2.17476306]), np.zeros((0, 2)), np.zeros(0), np.zeros(0),
        np.array([-0.92885524, -np.inf]), np.array([4.74590021, np.inf]), cones,
    )  # fmt: skip
    iterates = []
    for iterations in (FULL_STEPS - 1, FULL_STEPS):
        arrays, ws = _workspace(*problem)
        result = socp_solve(ws, False, iterations)
        assert result[1] > iterations  # not converged
        iterates.append(arrays["z"].copy())
    assert np.abs(iterates[1] - iterates[0]).max() > 1.0
    arrays, ws = _workspace(*problem)
    result = socp_solve(ws, False, MAX_ITERATIONS)
    assert result[0] > 0 and FULL_STEPS < result[1] <= MAX_ITERATIONS
    np.testing.assert_allclose(arrays["z"], [0.78784996, 0.61185416], atol=1e-6)
    np.testing.assert_allclose(arrays["mu"][0], 2.8812936, atol=1e-6)


def test_adopting_a_failed_solve_gives_the_status_of_solving_it() -> None:
    """DaqpSocpDense.adopt_point on the workspace as a compiled caller's failed SQP left it
    gives the status and reason that solve_point gives for the same solve (the certificate
    checks on the same workspace), on infeasible problems of the controller's shape."""
    from ltv_lstm_mpc.solvers.daqp_socp import DaqpSocpDense
    from ltv_lstm_mpc.solvers.socp_sqp import MAX_ITERATIONS, socp_solve
    from ltv_lstm_mpc.solvers.testing import controller_socp

    seen = 0
    for seed in range(6):
        qp = controller_socp(seed, "infeasible", bool(seed % 2))
        solved = DaqpSocpDense("daqp:socp", 1e-8, {})
        solved.setup(qp)
        status, _z, iterations, info = solved.solve_point()
        adopted = DaqpSocpDense("daqp:socp", 1e-8, {})
        adopted.setup(qp)
        flag, sqp, total, _violation, _seconds = socp_solve(adopted._ws, False, MAX_ITERATIONS)
        assert flag not in (1, 2), (seed, flag)
        verdict = adopted.adopt_point(flag, sqp, total)
        assert verdict == (status, None, iterations, info), (seed, verdict, info)
        seen += status is SolverStatus.INFEASIBLE
    assert seen >= 3


def test_a_failed_nominal_cone_solve_is_not_repeated() -> None:
    """Bench scenario 3 on daqp:socp, 300 steps, on the reference engine (every step
    through RobustMPC.feedback): where the one-call exact-cone feedback's nominal SQP fails,
    the general path takes that solve's outcome (the nominal session's adopt_point, once
    per such step) rather than solving the nominal problem again (its solve_point is not
    called on those steps); the records say infeasible, with the certificates' reasons."""
    from ltv_lstm_mpc.solvers.daqp_socp import DaqpSocpDense

    from ltv_lstm_mpc import simulate
    from ltv_lstm_mpc.solver_comparison.harness import bench_scenarios

    model = load_model("ph_lstm_n5.npz")
    scenario = bench_scenarios(model)[2]
    config = replace(scenario.config, solver="daqp:socp", N=5)
    controller = OffsetFreeController(
        model, config, setpoint_rate_limit=scenario.setpoint_rate_limit, one_call_step=False,
        kernels="compiled",
    )  # fmt: skip
    nominal = controller.mpc._problem._sessions["nominal"]._backend
    calls = {"adopt": 0, "solve": 0}
    adopt, solve = DaqpSocpDense.adopt_point, DaqpSocpDense.solve_point

    def counting_adopt(self, *args):  # type: ignore[no-untyped-def]
        calls["adopt"] += self is nominal
        return adopt(self, *args)

    def counting_solve(self):  # type: ignore[no-untyped-def]
        calls["solve"] += self is nominal
        return solve(self)

    with pytest.MonkeyPatch.context() as patch:
        patch.setattr(DaqpSocpDense, "adopt_point", counting_adopt)
        patch.setattr(DaqpSocpDense, "solve_point", counting_solve)
        simulate(scenario.make_plant(model), controller, scenario.setpoints[:300],
                 scenario.disturbances[:300], 300, progress=False)  # fmt: skip
    failed = [r for r in controller.records if r.mpc.status == "infeasible"]
    assert len(failed) >= 5
    assert calls["adopt"] == len(failed) and calls["solve"] == 0, (calls, len(failed))
    assert all(r.mpc.reason.startswith("exitflag -1 at SQP iteration") for r in failed)


def test_a_failed_solve_snapshot_holds_the_workspace_arrays() -> None:
    """snapshot_into (the compiled step's copy of a failed solve) then snapshot_views gives
    every array of FAILURE_FIELDS as the workspace holds it, bit for bit and in its shape
    and dtype, and failure_outcome reads the same status and reason from it as from a copy
    of the arrays by name (infeasible problems of the controller's shape; a wrong order or
    length in the flat layout changes some array)."""
    from ltv_lstm_mpc.solvers.daqp_socp import DaqpSocpDense, failure_outcome
    from ltv_lstm_mpc.solvers.socp_sqp import (
        FAILURE_FIELDS,
        MAX_ITERATIONS,
        snapshot_into,
        snapshot_sizes,
        snapshot_views,
        socp_solve,
    )
    from ltv_lstm_mpc.solvers.testing import controller_socp

    for seed in range(4):
        qp = controller_socp(seed, "infeasible", bool(seed % 2))
        backend = DaqpSocpDense("daqp:socp", 1e-8, {})
        backend.setup(qp)
        flag, sqp, *_ = socp_solve(backend._ws, False, MAX_ITERATIONS)
        assert flag < 0, (seed, flag)
        arrays = backend._arrays
        real_size, int_size = snapshot_sizes(arrays)
        real, integer = np.full(real_size, np.nan), np.full(int_size, -7, dtype=np.int64)
        snapshot_into(backend._ws, real, integer)
        assert not np.isnan(real).any() and not (integer == -7).any()
        views = snapshot_views(real, integer, arrays)
        assert set(views) == set(FAILURE_FIELDS)
        for name in FAILURE_FIELDS:
            assert views[name].shape == arrays[name].shape, name
            assert views[name].dtype == arrays[name].dtype, name
            np.testing.assert_array_equal(views[name], arrays[name], err_msg=name)
        copies = {name: arrays[name].copy() for name in FAILURE_FIELDS}
        assert failure_outcome(views, flag, sqp, 1e-8, {}) == failure_outcome(
            copies, flag, sqp, 1e-8, {}
        )


# ---------------------------------------------------------------- infeasible subproblems
def _definite_of(W: np.ndarray) -> tuple[bool, np.ndarray]:
    """socp_sqp._definite on W_k = W: (verdict, the factor it left, lower triangle)."""
    from ltv_lstm_mpc.solvers.socp_sqp import _definite

    n = W.shape[0]
    arrays, ws = _workspace(
        np.eye(n), np.zeros(n), np.zeros((0, n)), np.zeros(0), np.zeros(0), np.full(n, -1.0),
        np.ones(n), [],
    )  # fmt: skip
    arrays["hessian"][...] = W
    verdict = bool(_definite(ws))
    return verdict, np.tril(arrays["reduced_hessian"].reshape(n, n))


def test_the_definiteness_test_is_choleskys_with_a_relative_pivot_floor() -> None:
    """_definite (whether DAQP's "infeasible" on W_k is the subproblem's verdict) says yes
    to positive definite matrices, with numpy's Cholesky factor, and no to singular,
    indefinite, NaN and zero ones and to one whose smallest pivot is below DEFINITE_PIVOT
    times the largest diagonal entry (1e-7 against 1e-6), yes just above it."""
    from ltv_lstm_mpc.solvers.socp_sqp import DEFINITE_PIVOT

    rng = np.random.default_rng(7)
    for n in (1, 2, 5, 12):
        B = rng.standard_normal((n, n))
        W = B @ B.T + 0.1 * np.eye(n)
        verdict, factor = _definite_of(W)
        assert verdict, n
        np.testing.assert_allclose(factor, np.linalg.cholesky(W), rtol=1e-12, atol=1e-12)
        v = rng.standard_normal(n)
        assert not _definite_of(np.outer(v, v) if n > 1 else np.zeros((1, 1)))[0], n
        indefinite = W - 2.0 * np.linalg.eigvalsh(W).max() * np.outer(v, v) / (v @ v)
        assert not _definite_of(indefinite)[0], n
        W_nan = W.copy()
        W_nan[n - 1, n - 1] = np.nan
        assert not _definite_of(W_nan)[0], n
    assert DEFINITE_PIVOT == 1e-6
    assert not _definite_of(np.diag([1.0, 1e-7]))[0]
    assert _definite_of(np.diag([1.0, 2e-6]))[0]
    assert not _definite_of(np.zeros((3, 3)))[0]


def test_an_infeasible_subproblem_on_a_definite_hessian_ends_the_solve() -> None:
    """Infeasible SOCPs of the controller's shape (H positive definite, so every W_k is):
    the solve ends where DAQP first calls a subproblem infeasible, without solving it again
    with the proximal term: W_k is left as it was (the re-solve would add the proximal
    weight to its diagonal) and its Cholesky factor, from the definiteness test, is in the
    scratch; the status and certificate are those of the general backend, INFEASIBLE."""
    from ltv_lstm_mpc.solvers.daqp_socp import DaqpSocpDense
    from ltv_lstm_mpc.solvers.socp_sqp import MAX_ITERATIONS, socp_solve
    from ltv_lstm_mpc.solvers.testing import controller_socp

    infeasible = 0
    for seed in range(6):
        qp = controller_socp(seed, "infeasible", bool(seed % 2))
        if np.linalg.eigvalsh(0.5 * (qp.H + qp.H.T)).min() <= 1e-6:
            continue
        backend = DaqpSocpDense("daqp:socp", 1e-8, {})
        backend.setup(qp)
        flag, sqp, *_ = socp_solve(backend._ws, False, MAX_ITERATIONS)
        if flag != -1:
            continue
        arrays = backend._arrays
        W = arrays["hessian"]
        n = W.shape[0]
        L = np.tril(arrays["reduced_hessian"].reshape(n, n))
        np.testing.assert_allclose(L @ L.T, W, rtol=1e-12, atol=1e-12 * np.abs(W).max())
        status, _z, _iterations, info = backend.solve_point()
        assert status is SolverStatus.INFEASIBLE, (seed, info)
        assert info.startswith(f"exitflag -1 at SQP iteration {sqp};"), info
        infeasible += 1
    assert infeasible >= 3


# ---------------------------------------------------------------- infeasibility check
def _with_and_without_check(qp):
    """socp_solve of the DenseQP ``qp`` with and without the infeasibility check, each on a
    fresh workspace: ((result, z, mu, lam, cut_state) of each)."""
    from ltv_lstm_mpc.solvers.daqp_socp import DaqpSocpDense
    from ltv_lstm_mpc.solvers.socp_sqp import MAX_ITERATIONS, socp_solve

    out = []
    for check in (False, True):
        backend = DaqpSocpDense("daqp:socp", 1e-8, {})
        backend.setup(qp)
        a = backend._arrays
        result = socp_solve(backend._ws, False, MAX_ITERATIONS, True, True, check)
        out.append((result, a["z"].copy(), a["mu"].copy(), a["lam"].copy(), a["cut_state"].copy()))
    return out


@settings(max_examples=80, deadline=None)
@given(
    seed=st.integers(0, 2**32 - 1),
    kind=st.sampled_from(["feasible", "infeasible"]),
    linear_t=st.booleans(),
)
def test_the_infeasibility_check_changes_no_solve_it_does_not_end(
    seed: int, kind: str, linear_t: bool
) -> None:
    """Random SOCPs of the controller's shape: where the check proves nothing, the SQP takes
    the same iterates with and without it (exit flag, SQP iterations, point, multipliers,
    bit for bit: the check's solve leaves the subproblem's solution as it was); where it
    ends the solve, it does so with DAQP's "infeasible" no later than the SQP without it,
    on a problem that SQP did not solve either, INFEASIBLE with a checked certificate (the
    planes hold at every point of the cones). The check seldom runs on these: the fixed
    cases below make sure it does."""
    from ltv_lstm_mpc.solvers.socp_sqp import MAX_ITERATIONS
    from ltv_lstm_mpc.solvers.testing import controller_socp

    qp = controller_socp(seed, kind, linear_t)
    (plain, z0, mu0, lam0, _), (checked, z, mu, lam, state) = _with_and_without_check(qp)
    if state[2] == 0:
        assert checked[:2] == plain[:2]
        assert checked[3] == plain[3] or (np.isinf(checked[3]) and np.isinf(plain[3]))
        np.testing.assert_array_equal(z, z0)
        np.testing.assert_array_equal(mu, mu0)
        np.testing.assert_array_equal(lam, lam0)
    else:
        assert checked[0] == -1
        assert checked[1] <= plain[1]
        assert plain[0] not in (1, 2) or plain[1] > MAX_ITERATIONS
        assert kind == "infeasible"
        _assert_infeasible_by_the_check(qp)


def _assert_infeasible_by_the_check(qp) -> None:
    """The backend's status of ``qp``: INFEASIBLE with a checked certificate, the solve
    ended by the infeasibility check (its reason says so)."""
    from ltv_lstm_mpc.solvers.daqp_socp import DaqpSocpDense

    backend = DaqpSocpDense("daqp:socp", 1e-8, {})
    backend.setup(qp)
    status, _z, _iterations, info = backend.solve_point()
    assert status is SolverStatus.INFEASIBLE, info
    assert "cutting planes" in info and "infeasibility certificate" in info, info


#: Problems of controller_socp on which the check runs (its DAQP solves add iterations)
#: without ending the solve: (seed, kind, linear_t).
CHECKED_NOT_ENDED = [
    (6, "feasible", False), (43, "feasible", False), (84, "feasible", False),
    (93, "feasible", False), (138, "feasible", False), (34, "infeasible", True),
    (171, "infeasible", True),
]  # fmt: skip


@pytest.mark.parametrize(("seed", "kind", "linear_t"), CHECKED_NOT_ENDED)
def test_a_check_that_proves_nothing_leaves_the_iterates(
    seed: int, kind: str, linear_t: bool
) -> None:
    """Where the check runs (more DAQP iterations) and proves nothing, the solve is the one
    without it, bit for bit: exit flag, SQP iterations, point, multipliers."""
    from ltv_lstm_mpc.solvers.testing import controller_socp

    qp = controller_socp(seed, kind, linear_t)
    (plain, z0, mu0, lam0, _), (checked, z, mu, lam, state) = _with_and_without_check(qp)
    assert checked[2] > plain[2]  # the check's DAQP solves
    assert state[2] == 0
    assert checked[:2] == plain[:2]
    np.testing.assert_array_equal(z, z0)
    np.testing.assert_array_equal(mu, mu0)
    np.testing.assert_array_equal(lam, lam0)


def test_the_check_ends_an_infeasible_solve_with_a_certificate() -> None:
    """controller_socp(94, "infeasible", False): without the check DAQP finds a subproblem
    infeasible at SQP iteration 7; the check ends the solve at iteration 3 with the planes
    of 2 earlier iterates, INFEASIBLE with a certificate built from them."""
    from ltv_lstm_mpc.solvers.testing import controller_socp

    qp = controller_socp(94, "infeasible", False)
    (plain, *_), (checked, *_rest, state) = _with_and_without_check(qp)
    assert (plain[0], plain[1]) == (-1, 7)
    assert (checked[0], checked[1]) == (-1, 3)
    assert state[2] == 2
    _assert_infeasible_by_the_check(qp)


@pytest.mark.parametrize("seed", [18, 59])
def test_the_check_keeps_a_feasible_problem_at_a_cones_apex_feasible(seed: int) -> None:
    """apex_socp: feasible only at the cone's apex, where the smoothed cone (the SQP's) is
    empty. Planes of the smoothed cone ended seed 18 at SQP iteration 19, FAILED where the
    SQP without the check converges; with the planes shifted onto the cone itself but not
    loosened by CUT_MARGIN, DAQP still called seed 59's check infeasible at iteration 31
    (the apex on every plane within 3e-18). Now the SQP converges as without the check, to
    the apex."""
    from ltv_lstm_mpc.solvers.daqp_socp import DaqpSocpDense
    from ltv_lstm_mpc.solvers.testing import apex_socp

    qp = apex_socp(seed)
    p = qp.H.shape[0] - 1
    (plain, z0, *_), (checked, z, *_rest, state) = _with_and_without_check(qp)
    assert plain[0] == 1 and plain[1] <= 50
    assert checked[:2] == plain[:2] and state[2] == 0
    np.testing.assert_array_equal(z, z0)
    np.testing.assert_allclose(z[:p], -qp.cones[0].g, atol=1e-6)
    backend = DaqpSocpDense("daqp:socp", 1e-8, {})
    backend.setup(qp)
    status, *_ = backend.solve_point()
    assert status is SolverStatus.OPTIMAL


@pytest.mark.parametrize("seed", range(0, 300, 7))
def test_the_check_never_ends_a_solve_at_a_cones_apex(seed: int) -> None:
    """apex_socp over many seeds: the check never ends the solve (the problems are
    feasible)."""
    from ltv_lstm_mpc.solvers.testing import apex_socp

    (_plain, *_), (checked, *_rest, state) = _with_and_without_check(apex_socp(seed))
    assert state[2] == 0, (seed, checked)


def test_the_multiplier_certificate_reruns_to_the_checks_own_subproblem() -> None:
    """controller_socp(94, "infeasible", False), ended by the check at SQP iteration 3:
    the Farkas vector from the multipliers of the subproblem of that iteration (the rerun
    ends at the check again) checks on the problem."""
    from ltv_lstm_mpc.solvers.acceptance import ProblemView
    from ltv_lstm_mpc.solvers.daqp_socp import DaqpSocpDense
    from ltv_lstm_mpc.solvers.socp_certificates import multiplier_certificate
    from ltv_lstm_mpc.solvers.socp_sqp import MAX_ITERATIONS, socp_solve
    from ltv_lstm_mpc.solvers.testing import controller_socp

    qp = controller_socp(94, "infeasible", False)
    backend = DaqpSocpDense("daqp:socp", 1e-8, {})
    backend.setup(qp)
    a = backend._arrays
    start = (False, np.zeros(qp.H.shape[0]), np.zeros(len(qp.cones)))
    flag, sqp, *_ = socp_solve(backend._ws, False, MAX_ITERATIONS)
    assert (flag, sqp, a["cut_state"][2]) == (-1, 3, 2)
    certificate, why = multiplier_certificate(
        a, backend._ws, start, sqp, ProblemView.of_dense(qp), ""
    )
    assert certificate is not None, why
    assert a["cut_state"][2] == 2  # the rerun ended at the check again


def test_the_mpcs_infeasible_steps_end_at_the_check() -> None:
    """The paper's scenario 3 at N = 5 on the one-call step (its steps 590-618 are
    infeasible; the SQP without the check circles on most of them, its subproblems
    feasible while the multipliers grow): every nominal subproblem that fails is
    INFEASIBLE with a checked certificate, built from the kept planes where the check
    ended the solve (its reason says so); re-solved, the check ends it no later than the
    SQP without it, and sooner on most of them."""
    from ltv_lstm_mpc.solvers.socp_sqp import MAX_ITERATIONS, socp_solve

    from ltv_lstm_mpc.paper.scenarios import paper_scenarios

    model = load_model("ph_lstm_n5.npz")
    scenario = paper_scenarios(model)[2]
    config = replace(scenario.config, N=5, solver="daqp:socp")
    controller = OffsetFreeController(
        model, config, setpoint_rate_limit=scenario.setpoint_rate_limit, kernels="compiled"
    )
    problem = controller.mpc._problem
    ws = problem.socp_workspace
    plant = scenario.make_plant(model)
    y = plant.output()
    sooner = failed = 0
    for k in range(620):
        u = controller.step(y, scenario.setpoints[k])
        record = controller.records[-1]
        if not record.mpc.feasible:
            failed += 1
            assert record.mpc.status == SolverStatus.INFEASIBLE.value, (k, record.mpc.reason)
            checked = socp_solve(ws, False, MAX_ITERATIONS)
            ended_by_check = problem.socp_arrays["cut_state"][2] > 0
            plain = socp_solve(ws, False, MAX_ITERATIONS, True, True, False)
            assert checked[0] == plain[0] == -1
            assert checked[1] <= plain[1]
            sooner += checked[1] < plain[1]
            assert ("cutting planes" in record.mpc.reason) == ended_by_check, record.mpc.reason
            assert "infeasibility certificate" in record.mpc.reason
        d = scenario.disturbances[k]
        y = plant.step(u, None if np.isnan(d) else d)
    assert failed >= 25
    assert sooner >= failed // 2
