"""Exact terminal cones on the condensed transcription (native CLARABEL) and dense cones."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from ltv_lstm_mpc.solvers import (
    DenseCone,
    DenseQP,
    DenseSession,
    cone_solvers,
    solver_info,
)
from optional_extras import requires_solver

from ltv_lstm_mpc import MPCConfig, OffsetFreeController, RobustMPC, load_model
from ltv_lstm_mpc.exceptions import DimensionError, InvalidValueError
from ltv_lstm_mpc.loop.reference import ReferenceCalculator
from ltv_lstm_mpc.lstm.kernel import LSTMKernel
from ltv_lstm_mpc.mpc.rti import resolve_transcription

pytestmark = requires_solver("clarabel")
#: Cone solvers checked against each other on dense SOCPs.
DENSE_CONE = [s for s in ("clarabel", "cvxpy:CLARABEL", "cvxpy:ECOS") if s in cone_solvers()]


@pytest.fixture(scope="module")
def model():
    return load_model("ph_lstm_n5.npz")


@pytest.fixture(scope="module")
def sparse(model):
    return RobustMPC(model, MPCConfig(solver="cvxpy:CLARABEL"))


@pytest.fixture(scope="module")
def reference(model):
    return ReferenceCalculator(model, strict=False).solve(np.array([0.1]), np.zeros(1))


def random_socp(seed: int, n: int = 6) -> DenseQP:
    """A feasible dense QP with rows, bounds and two cones (one active at the optimum)."""
    rng = np.random.default_rng(seed)
    G = rng.normal(size=(n, n))
    A = rng.normal(size=(4, n))
    lo = np.array([-1.0, -np.inf, -0.5, 0.0])
    up = np.array([1.0, 0.5, np.inf, 0.0])  # last row: an equality
    lb, ub = -np.ones(n), np.ones(n)
    ub[2] = np.inf
    cones = (
        DenseCone(rng.normal(size=(3, n)), 0.1 * rng.normal(size=3), np.zeros(n), 0.3),
        DenseCone(rng.normal(size=(2, n)), np.zeros(2), np.eye(n)[0], 0.5),
    )
    return DenseQP(G @ G.T + np.eye(n), 3 * rng.normal(size=n), A, lo, up, lb, ub, cones=cones)


# ------------------------------------------------------------------------- dense layer
def test_clarabel_is_a_native_dense_cone_solver() -> None:
    info = solver_info("clarabel")
    assert info.supports_cones and info.native_dense and not info.first_order
    assert "clarabel" in cone_solvers()


@pytest.mark.parametrize("solver", DENSE_CONE)
def test_dense_socp_agrees_across_cone_solvers(solver) -> None:
    for seed in range(3):
        qp = random_socp(seed)
        reference = DenseSession("clarabel", tolerance=1e-10).solve(qp)
        sol = DenseSession(solver, tolerance=1e-10).solve(qp)
        assert sol.ok and reference.ok
        assert qp.max_violation(sol.z) < 1e-7
        active = max(cone.violation(reference.z) for cone in qp.cones)
        assert active > -1e-6  # a cone is active: the test sees the cones
        np.testing.assert_allclose(sol.z, reference.z, atol=2e-5)
        assert sol.objective == pytest.approx(reference.objective, abs=1e-7)


def test_in_place_update_equals_a_fresh_setup() -> None:
    qp = random_socp(0)
    session = DenseSession("clarabel", tolerance=1e-10)
    session.solve(qp)
    rng = np.random.default_rng(5)
    for _ in range(3):
        qp.f[:] = 3 * rng.normal(size=qp.f.shape)
        qp.A[:] += 0.1 * rng.normal(size=qp.A.shape)
        qp.cones[0].F[:] += 0.1 * rng.normal(size=qp.cones[0].F.shape)
        qp.cones[0].f = float(rng.uniform(0.2, 0.5))
        a = session.solve(qp)
        assert session.last_update == "in_place"
        b = DenseSession("clarabel", tolerance=1e-10).solve(qp)
        np.testing.assert_allclose(a.z, b.z, atol=1e-6)  # interior point: same tolerance
        assert a.objective == pytest.approx(b.objective, abs=1e-9)
    qp.up[1] = np.inf  # a new finite-bound pattern: set up afresh inside the backend
    a = session.solve(qp)
    b = DenseSession("clarabel", tolerance=1e-10).solve(qp)
    np.testing.assert_allclose(a.z, b.z, atol=1e-6)


def test_multipliers_follow_the_dense_sign_convention() -> None:
    """On a cone-free QP, CLARABEL's multipliers equal DAQP's (same KKT convention)."""
    qp = random_socp(1)
    qp = dataclasses.replace(qp, cones=())
    a = DenseSession("clarabel", tolerance=1e-11).solve(qp)
    b = DenseSession("daqp").solve(qp)
    np.testing.assert_allclose(a.z, b.z, atol=1e-8)
    np.testing.assert_allclose(a.duals["ineq"], b.duals["ineq"], atol=1e-7)
    np.testing.assert_allclose(a.duals["bounds"], b.duals["bounds"], atol=1e-7)
    residual = qp.H @ a.z + qp.f + qp.A.T @ a.duals["ineq"] + a.duals["bounds"]
    assert np.max(np.abs(residual)) < 1e-7


def test_qp_only_backends_refuse_cones() -> None:
    qp = random_socp(0)
    with pytest.raises(InvalidValueError, match=r"never dropped silently.*clarabel"):
        DenseSession("daqp").solve(qp)


def test_cone_checks_name_the_field() -> None:
    qp = random_socp(0)
    bad = dataclasses.replace(qp, cones=(DenseCone(np.zeros((2, 5)), np.zeros(2), np.zeros(6), 0),))
    with pytest.raises(DimensionError, match=r"cones\[0\]\.F"):
        bad.check()
    bad = dataclasses.replace(qp, cones=(DenseCone(np.zeros((2, 6)), [np.nan, 0], np.zeros(6), 0),))
    with pytest.raises(InvalidValueError, match=r"cones\[0\]\.g"):
        bad.check()


def test_save_and_load_keep_the_cones(tmp_path) -> None:
    qp = random_socp(2)
    loaded = DenseQP.load(qp.save(tmp_path / "socp.npz"))
    assert loaded.structure_key() == qp.structure_key() == (6, 4, 3, 2)
    a = DenseSession("clarabel").solve(qp)
    b = DenseSession("clarabel").solve(loaded)
    np.testing.assert_array_equal(a.z, b.z)


# ---------------------------------------------------------------------- the MPC path
def test_auto_transcription_of_native_clarabel_is_condensed_with_exact_cones(model, sparse):
    assert resolve_transcription(MPCConfig(solver="clarabel")) == "condensed"
    mpc = RobustMPC(model, MPCConfig(solver="clarabel"), certification=sparse.certification)
    assert mpc.transcription == "condensed" and mpc.reformulation is None


@pytest.mark.parametrize("solver", ["clarabel", "cvxpy:CLARABEL"])
def test_condensed_cones_equal_sparse_cones_on_fixed_subproblems(
    model, sparse, reference, solver
) -> None:
    """Same FHOCP (exact terminal cones) in fewer variables: the same plan as cvxpy's sparse
    transcription within the solvers' tolerance (at tolerance 1e-8 these plans are weakly
    determined: the costs agree to 1e-5 while the inputs differ by up to 6.7e-5 (clarabel)
    and 7.3e-5 (cvxpy:CLARABEL) with the shipped model; cvxpy's ECOS and CLARABEL differed
    by 1.2e-4 on the same sparse problem with an earlier model, and the gap shrank with the
    tolerance)."""
    config = MPCConfig(solver=solver, transcription="condensed")
    condensed = RobustMPC(model, config, certification=sparse.certification)
    assert condensed.reformulation is None
    rng = np.random.default_rng(1)
    y0 = np.array([0.1])
    worst = 0.0
    for _ in range(3):
        x = model.equilibrium(np.array([rng.uniform(-0.4, 0.6)]))
        for mpc in (condensed, sparse):
            mpc.reset()
        for _ in range(3):
            a = sparse.solve(x, reference.x_bar, reference.u_bar, y0, 0.5)
            b = condensed.solve(x, reference.x_bar, reference.u_bar, y0, 0.5)
            assert a.status == b.status and a.policy == b.policy
            assert b.reformulation is None and a.reformulation is None
            worst = max(worst, float(np.max(np.abs(b.u - a.u))))
            assert b.cost == pytest.approx(a.cost, rel=1e-5, abs=1e-8)
            x = a.x[1]
    assert worst < 1e-4


@pytest.mark.parametrize("policy", ["paper", "soft", "shift"])
def test_policies_on_an_infeasible_instant(model, sparse, reference, policy) -> None:
    config = MPCConfig(solver="clarabel", infeasibility_policy=policy)
    mpc = RobustMPC(model, config, certification=sparse.certification)
    reference_mpc = RobustMPC(
        model,
        dataclasses.replace(config, solver="cvxpy:CLARABEL"),
        certification=sparse.certification,
    )
    x = model.equilibrium(np.array([0.3]))
    _, high = mpc.tightening.setpoint_interval()
    y0 = high + 0.05  # outside Assumption 5: alpha <= 0
    sol = mpc.solve(x, reference.x_bar, reference.u_bar, y0, 0.5)
    ref = reference_mpc.solve(x, reference.x_bar, reference.u_bar, y0, 0.5)
    assert sol.status == ref.status == "alpha_nonpositive" and not sol.feasible
    assert sol.policy == ref.policy == policy
    np.testing.assert_allclose(sol.u, ref.u, atol=1e-4)
    assert np.max(np.abs(sol.u)) <= config.u_max + 1e-9


def test_numpy_and_compiled_condensing_give_the_same_cone_plan(model, sparse, reference):
    plans = []
    for compiled in (True, False):
        m = load_model("ph_lstm_n5.npz")
        m.kernel = LSTMKernel(m, compiled=compiled)
        mpc = RobustMPC(m, MPCConfig(solver="clarabel"), certification=sparse.certification)
        x = m.equilibrium(np.array([0.2]))
        plans.append(mpc.solve(x, reference.x_bar, reference.u_bar, np.array([0.1]), 0.5).u)
    np.testing.assert_allclose(plans[0], plans[1], atol=1e-9)


def test_closed_loop_same_inputs_native_condensed_and_cvxpy_sparse(model) -> None:
    from ltv_lstm_mpc.solver_comparison.harness import bench_scenarios

    scenario = bench_scenarios(model)[0]
    rate = scenario.setpoint_rate_limit
    runs = {}
    for solver in ("clarabel", "cvxpy:CLARABEL"):
        config = dataclasses.replace(scenario.config, solver=solver)
        controller = OffsetFreeController(model, config, setpoint_rate_limit=rate)
        plant = scenario.make_plant(model)
        y = plant.output()
        us = []
        for k in range(30):
            u = controller.step(y, scenario.setpoints[k])
            us.append(u[0])
            y = plant.step(u, scenario.disturbances[k])
        runs[solver] = np.array(us)
        assert all(r.mpc.feasible for r in controller.records)
        assert {r.mpc.reformulation for r in controller.records} == {None}
    np.testing.assert_allclose(runs["clarabel"], runs["cvxpy:CLARABEL"], atol=1e-5)


@pytest.mark.parametrize("policy", ["paper", "soft"])
def test_policies_on_the_states_of_scenario_3_with_exact_cones(model, policy) -> None:
    """Scenario 3 (short) on the exact-cone condensed path: every infeasible instant is
    handled by the policy itself (the soft SOCP is feasible by construction: no +shift), as
    many infeasible instants as cvxpy's sparse cones give under the paper policy (82 with
    the shipped model, at the same steps), and no output violation."""
    from ltv_lstm_mpc.paper.scenarios import paper_scenarios, run_scenario

    scenario = next(s for s in paper_scenarios(model, short=True) if s.name.startswith("3"))
    config = dataclasses.replace(scenario.config, solver="clarabel", infeasibility_policy=policy)
    result = run_scenario(dataclasses.replace(scenario, config=config), model)
    infeasible = [r.mpc for r in result.controller.records if not r.mpc.feasible]
    assert len(infeasible) >= 50
    if policy == "paper":
        assert len(infeasible) == 82
    assert {s.policy for s in infeasible} == {policy}
    assert {s.reformulation for s in infeasible} == {None}
    assert result.summary()["max_output_violation"] == 0.0


# ------------------------------------------------------------------- fault injection
@pytest.mark.parametrize("fault", ["nan", "raise"])
def test_faults_on_native_clarabel_keep_the_exact_cones_in_closed_loop(model, fault) -> None:
    """``faulty("clarabel", ...)`` runs the exact-cone path: the faulted calls become
    recorded failures handled by the fallback policy, every other call solves the cones."""
    from ltv_lstm_mpc.solvers.testing import faulty

    from ltv_lstm_mpc.loop.simulation import simulate
    from ltv_lstm_mpc.plants.lstm_plant import LSTMPlant

    name = faulty("clarabel", fault, calls=[5])
    runs = {}
    for solver in ("clarabel", name):
        controller = OffsetFreeController(
            model, MPCConfig(solver=solver, infeasibility_policy="paper")
        )
        runs[solver] = simulate(
            LSTMPlant(model, y0_phi=7.0), controller, 7.3, steps=10, progress=False
        )
        assert controller.mpc._problem.exact_cones
        assert {r.mpc.reformulation for r in controller.records} == {None}
    clean, faulted = runs["clarabel"], runs[name]
    assert set(clean.status) == {"optimal"}
    expected = "failed" if fault == "nan" else "solver_error"
    # one nominal solve per step while it succeeds: call 5 is the nominal solve of step 5
    assert list(faulted.status) == ["optimal"] * 5 + [expected] + ["optimal"] * 4
    assert list(faulted.policy) == ["nominal"] * 5 + ["paper"] + ["nominal"] * 4
    np.testing.assert_array_equal(faulted.u_phi[:5], clean.u_phi[:5])
    assert np.all(np.isfinite(faulted.u_phi))
