"""One controller, one MPC core: transcriptions, kernel, faults, policies, config."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from ltv_lstm_mpc.solvers import available_solvers, solver_info
from ltv_lstm_mpc.solvers.testing import faulty
from optional_extras import backend_params, requires_solver

from ltv_lstm_mpc import MPCConfig, OffsetFreeController, RobustMPC, load_model
from ltv_lstm_mpc.exceptions import InvalidValueError, LtvMpcError, SolverNotFound
from ltv_lstm_mpc.loop.reference import ReferenceCalculator
from ltv_lstm_mpc.mpc.rti import resolve_transcription

#: First-input agreement of the condensed path with the sparse QP path (same math) per solver.
# piqp: an interior-point method; 3.6e-6 from an active input bound on the shipped model
TOL = {"daqp": 1e-9, "quadprog": 1e-9, "osqp": 1e-5, "piqp": 1e-5, "proxqp": 1e-4}
DENSE = backend_params("daqp", "quadprog", "osqp", "piqp", "proxqp")
#: The transcriptions of the tests that give each its own solver, "daqp" if condensed else
#: "cvxpy:CLARABEL" (exact cones on the sparse QP).
KINDS = ["condensed", pytest.param("sparse", marks=requires_solver("cvxpy:CLARABEL"))]


@pytest.fixture(scope="module")
def model():
    return load_model("ph_lstm_n5.npz")


@pytest.fixture(scope="module")
def sparse(model):
    return RobustMPC(model, MPCConfig(solver="daqp", transcription="sparse"))


@pytest.fixture(scope="module")
def reference(model):
    return ReferenceCalculator(model, strict=False).solve(np.array([0.1]), np.zeros(1))


def _random_states(model, k: int, seed: int = 1):
    rng = np.random.default_rng(seed)
    return [model.equilibrium(np.array([rng.uniform(-0.4, 0.6)])) for _ in range(k)]


# ------------------------------------------------------------------------ transcriptions
def test_auto_transcription_follows_the_solver() -> None:
    assert resolve_transcription(MPCConfig(solver="daqp")) == "condensed"
    assert resolve_transcription(MPCConfig(solver="ipopt")) == "nonlinear"
    assert resolve_transcription(MPCConfig(solver="daqp", transcription="sparse")) == "sparse"
    with pytest.raises(InvalidValueError, match="transcription"):
        resolve_transcription(MPCConfig(solver="daqp", transcription="nonlinear"))
    with pytest.raises(InvalidValueError, match="transcription"):
        resolve_transcription(MPCConfig(solver="ipopt", transcription="condensed"))
    with pytest.raises(InvalidValueError, match="sqp_iterations"):
        resolve_transcription(MPCConfig(solver="ipopt", sqp_iterations=3))
    with pytest.raises(SolverNotFound):
        resolve_transcription(MPCConfig(solver="nope"))
    with pytest.raises(InvalidValueError, match="transcription"):
        MPCConfig(transcription="dense")  # type: ignore[arg-type]


@requires_solver("cvxpy:CLARABEL", "cvxpy:OSQP", "qpsolvers:quadprog")
def test_auto_transcription_of_cvxpy_and_qpsolvers() -> None:
    assert resolve_transcription(MPCConfig(solver="cvxpy:CLARABEL")) == "sparse"
    assert resolve_transcription(MPCConfig(solver="cvxpy:OSQP")) == "sparse"
    assert resolve_transcription(MPCConfig(solver="qpsolvers:quadprog")) == "condensed"


@pytest.mark.parametrize("solver", DENSE)
def test_condensed_equals_sparse_qp_on_fixed_subproblems(model, sparse, reference, solver) -> None:
    condensed = RobustMPC(model, MPCConfig(solver=solver), certification=sparse.certification)
    assert condensed.transcription == "condensed"
    assert (
        condensed.reformulation == sparse.reformulation == "terminal_box_and_quadratic_cost_bound"
    )
    rng = np.random.default_rng(1)
    y0 = np.array([0.1])
    for _ in range(3):
        x = model.equilibrium(np.array([rng.uniform(-0.4, 0.6)]))
        for mpc in (condensed, sparse):
            mpc.reset()
        for _ in range(3):  # also exercises the shifted candidate and the plan reuse
            a = sparse.solve(x, reference.x_bar, reference.u_bar, y0, 0.5)
            b = condensed.solve(x, reference.x_bar, reference.u_bar, y0, 0.5)
            assert a.status == b.status and a.policy == b.policy
            assert b.transcription == "condensed" and a.transcription == "sparse"
            np.testing.assert_allclose(b.u, a.u, atol=TOL.get(solver, 1e-6))
            np.testing.assert_allclose(b.x, a.x, atol=100 * TOL.get(solver, 1e-6))
            assert b.cost == pytest.approx(a.cost, rel=1e-6, abs=100 * TOL.get(solver, 1e-6))
            x = a.x[1]


def test_prepare_feedback_split(model, sparse, reference) -> None:
    mpc = RobustMPC(model, MPCConfig(solver="daqp"), certification=sparse.certification)
    x = _random_states(model, 1)[0]
    y0 = np.array([0.1])
    with pytest.raises(LtvMpcError, match="prepare"):
        mpc.feedback(x)
    with pytest.raises(InvalidValueError, match="x_pred"):
        mpc.prepare(reference.x_bar, reference.u_bar, y0, 0.5)  # no x_pred, no plan
    mpc.prepare(reference.x_bar, reference.u_bar, y0, 0.5, x_pred=x)
    a = mpc.feedback(x)
    assert a.prepare_time > 0 and a.feedback_time > 0
    assert a.solve_time == pytest.approx(a.prepare_time + a.feedback_time)
    # prepare from the previous plan's prediction, then feedback with a slightly other x
    mpc.prepare(reference.x_bar, reference.u_bar, y0, 0.5)
    b = mpc.feedback(a.x[1] + 1e-6)
    mpc.reset()
    mpc._previous_u = a.u.copy()
    c = mpc.solve(a.x[1] + 1e-6, reference.x_bar, reference.u_bar, y0, 0.5)
    np.testing.assert_allclose(b.u, c.u, atol=1e-9)


def test_sqp_iterations_honoured_on_condensed(model, sparse, reference) -> None:
    x = _random_states(model, 1, seed=4)[0]
    y0 = np.array([0.1])
    results = {}
    for kind in ("condensed", "sparse"):
        config = MPCConfig(solver="daqp", transcription=kind, sqp_iterations=4, sqp_tolerance=1e-12)
        mpc = RobustMPC(model, config, certification=sparse.certification)
        results[kind] = mpc.solve(x, reference.x_bar, reference.u_bar, y0, 0.5)
    assert results["condensed"].iterations > 1
    np.testing.assert_allclose(results["condensed"].u, results["sparse"].u, atol=1e-8)


@pytest.mark.parametrize("policy", ["paper", "soft", "shift"])
@pytest.mark.parametrize("kind", KINDS)
def test_policies_on_an_infeasible_instant(model, sparse, reference, policy, kind) -> None:
    solver = "daqp" if kind == "condensed" else "cvxpy:CLARABEL"
    config = MPCConfig(solver=solver, transcription=kind, infeasibility_policy=policy)
    mpc = RobustMPC(model, config, certification=sparse.certification)
    x = model.equilibrium(np.array([0.3]))
    _, high = mpc.tightening.setpoint_interval()
    y0 = high + 0.05  # outside Assumption 5: alpha <= 0
    sol = mpc.solve(x, reference.x_bar, reference.u_bar, y0, 0.5)
    assert sol.status == "alpha_nonpositive" and not sol.feasible
    assert sol.policy == policy  # the soft QP is feasible by construction: no "+shift"
    assert np.all(np.isfinite(sol.u)) and np.max(np.abs(sol.u)) <= config.u_max + 1e-12


def test_soft_qp_is_an_exact_penalty_on_condensed(model, sparse, reference) -> None:
    """Where the nominal QP is feasible, the soft QP (L1 slacks, large enough penalty) has the
    same solution; where it is not, the soft QP still solves (feasible by construction)."""
    config = MPCConfig(solver="daqp", infeasibility_policy="soft", soft_penalty=1e4)
    mpc = RobustMPC(model, config, certification=sparse.certification)
    checked = 0
    for x in _random_states(model, 6, seed=7):
        mpc.reset()
        mpc.prepare(reference.x_bar, reference.u_bar, np.array([0.1]), 0.5, x_pred=x)
        nominal = mpc._problem.solve("nominal", x)
        soft = mpc._problem.solve("soft", x)
        assert soft.u is not None  # always: feasible by construction
        if nominal.u is not None:
            np.testing.assert_allclose(soft.u, nominal.u, atol=1e-6)
            checked += 1
    assert checked >= 2
    # scenario 3's kind of instant: alpha_k <= 0 and output rows violated at once
    x = model.equilibrium(np.array([0.3]))
    _, high = sparse.tightening.setpoint_interval()
    sol = mpc.solve(x, reference.x_bar, reference.u_bar, high + 0.05, 3.0)
    assert sol.policy == "soft" and np.all(np.isfinite(sol.u))


# --------------------------------------------------------------------------- faults
FAULTS = ("nan", "garbage", "raise", "infeasible")


@pytest.mark.parametrize("fault", FAULTS)
@pytest.mark.parametrize("kind", ["condensed", "sparse"])
def test_fault_on_nominal_solve_applies_the_policy(model, sparse, reference, fault, kind) -> None:
    name = faulty("daqp", fault, calls=[0])
    config = MPCConfig(solver=name, transcription=kind, infeasibility_policy="paper")
    mpc = RobustMPC(model, config, certification=sparse.certification)
    x = _random_states(model, 1)[0]
    sol = mpc.solve(x, reference.x_bar, reference.u_bar, np.array([0.1]), 0.5)
    expected = {"nan": "failed", "garbage": "failed", "raise": "solver_error"}
    assert sol.status == expected.get(fault, "infeasible")
    assert not sol.feasible and sol.policy == "paper"  # the fallback solve (call 1) is fine
    assert np.all(np.isfinite(sol.u)) and np.max(np.abs(sol.u)) <= 1.0
    if fault != "infeasible":
        assert sol.reason  # says why


@pytest.mark.parametrize("fault", FAULTS)
@pytest.mark.parametrize("kind", ["condensed", "sparse"])
def test_fault_on_every_solve_keeps_the_loop_finite(model, fault, kind) -> None:
    name = faulty("daqp", fault, calls=None)
    config = MPCConfig(solver=name, transcription=kind, infeasibility_policy="soft")
    controller = OffsetFreeController(model, config)
    y = 7.0
    for _ in range(5):
        u = controller.step([y], [7.2])
        assert np.all(np.isfinite(u))
        assert np.all(np.isfinite(controller.observer.x_hat))
        assert np.all(np.isfinite(controller.observer.d_hat))
    policies = {r.mpc.policy for r in controller.records}
    assert policies == {"soft+shift"}
    assert all(not r.mpc.feasible for r in controller.records)


# ------------------------------------------------------------------------ one kernel
def test_one_kernel_bit_for_bit(model, sparse, reference) -> None:
    rng = np.random.default_rng(3)
    x0 = model.equilibrium(np.array([0.2])) + 0.05 * rng.standard_normal(2 * model.n)
    u = rng.uniform(-1, 1, (4, 1))
    kernel = model.kernel
    traj = kernel.trajectory(4)
    traj.x[0] = x0
    traj.u[:4] = u
    kernel.rollout(traj, 0, 4)
    kernel.jacobians(traj)
    states, _ = model.simulate(x0, u)
    assert np.array_equal(states, traj.x)
    assert np.array_equal(model.step(x0, u[0]), traj.x[1])
    x_next, A, B = model.step_and_jacobians(states[:-1], u)
    assert np.array_equal(x_next, traj.x[1:])
    assert np.array_equal(A, traj.A) and np.array_equal(B, traj.B)
    # the MPC's re-simulated plan is the kernel's rollout
    mpc = RobustMPC(model, MPCConfig(solver="daqp"), certification=sparse.certification)
    sol = mpc.solve(x0, reference.x_bar, reference.u_bar, np.array([0.1]), 0.5)
    plan, _ = model.simulate(x0, sol.u)
    assert np.array_equal(sol.x, plan)
    # the observer with zero gates is the model step
    from ltv_lstm_mpc import Observer, ObserverGains

    n, p = model.n, model.p
    gains = ObserverGains(
        L_f=np.zeros((n, p)), L_i=np.zeros((n, p)), L_o=np.zeros((n, p)), L_d=np.eye(p) * 0.01
    )
    observer = Observer(model, gains, x_hat0=x0)
    observer.step(model.output(x0) + 0.01, u[0])
    assert np.array_equal(observer.x_hat, traj.x[1])


def test_reference_warm_path_matches_damped_newton(model) -> None:
    warm = ReferenceCalculator(model, strict=False)
    for y0, d in [(0.1, 0.0), (0.11, 0.001), (0.12, 0.002), (-0.2, 0.0), (-0.2, 0.0)]:
        cold = ReferenceCalculator(model, strict=False)
        a = cold.solve(np.array([y0]), np.array([d]))
        b = warm.solve(np.array([y0]), np.array([d]))
        assert b.converged and b.residual < 1e-10
        np.testing.assert_allclose(b.x_bar, a.x_bar, atol=1e-9)
        np.testing.assert_allclose(b.u_bar, a.u_bar, atol=1e-9)


def test_cached_alpha_equals_the_tightening_definition(model, sparse, reference) -> None:
    mpc = RobustMPC(model, MPCConfig(solver="daqp"), certification=sparse.certification)
    tightening = sparse.tightening
    x = model.equilibrium(np.array([0.1]))
    for y0 in np.linspace(-0.6, 0.6, 7):
        for e_hat in (0.0, tightening.e_inf, 3.0 * tightening.e_inf):
            solution = mpc.solve(x, reference.x_bar, reference.u_bar, [y0], e_hat)
            assert solution.alpha == tightening.alpha([y0], e_hat)


# --------------------------------------------------------------------- config fields
#: A non-default value of every MPCConfig field, and how it shows in the MPC.
FIELD_VALUES = {
    "N": 4, "Q": 2.0, "R": 0.5, "u_max": 0.9, "y_min": -0.7, "y_max": 0.8, "d_max": 0.05,
    "w_bar": 0.005, "Q_s": 900.0, "Q_o": 900.0, "L_d": 0.05, "L_f": 0.0, "L_i": 0.0,
    "L_o": 0.0, "design_gains": True, "tolerance": 1e-7, "sqp_iterations": 2,
    "sqp_tolerance": 1e-6, "infeasibility_policy": "soft", "soft_penalty": 500.0,
    "e_hat0": 0.01, "epsilon": 0.02, "solver_settings": {},
}  # fmt: skip


def test_field_table_covers_every_config_field() -> None:
    names = {f.name for f in dataclasses.fields(MPCConfig)} - {"solver", "transcription"}
    assert names == set(FIELD_VALUES)


@pytest.mark.parametrize("kind", KINDS)
@pytest.mark.parametrize("name", sorted(FIELD_VALUES))
def test_every_config_field_is_honoured(model, kind, name) -> None:
    solver = "daqp" if kind == "condensed" else "cvxpy:CLARABEL"
    values = {name: FIELD_VALUES[name]}
    if name in ("y_min", "y_max"):  # given together
        values = {"y_min": FIELD_VALUES["y_min"], "y_max": FIELD_VALUES["y_max"]}
    config = MPCConfig(solver=solver, transcription=kind, **values)
    controller = OffsetFreeController(model, config)
    mpc = controller.mpc
    assert mpc.config is config and mpc.transcription == kind
    for _ in range(3):
        controller.step([7.0], [7.1])
    sol = controller.records[-1].mpc
    assert sol.u.shape == (config.N, 1)
    assert np.max(np.abs(sol.u)) <= config.u_max + 1e-12
    assert sol.iterations <= config.sqp_iterations
    if name == "sqp_iterations":
        assert max(r.mpc.iterations for r in controller.records) == 2
    if name == "e_hat0":
        assert controller.records[0].e_hat == 0.01
    if name == "tolerance":
        session = next(iter(mpc._problem._sessions.values()))
        assert session.tolerance == 1e-7


def test_unknown_solver_settings_are_rejected_on_every_transcription(model) -> None:
    for kind, solver in (("condensed", "daqp"), ("sparse", "daqp")):
        config = MPCConfig(solver=solver, transcription=kind, solver_settings={"bogus": 1})
        with pytest.raises(InvalidValueError, match="bogus"):
            RobustMPC(model, config)


def test_solver_info_of_a_condensed_backend() -> None:
    assert solver_info("daqp").native_dense and not solver_info("daqp").supports_cones
    if "cvxpy:CLARABEL" in available_solvers():
        assert solver_info("cvxpy:CLARABEL").supports_cones


def test_closed_loop_same_inputs_condensed_and_sparse_qp(model) -> None:
    from ltv_lstm_mpc.solver_comparison.harness import bench_scenarios

    scenario = bench_scenarios(model)[0]
    rate = scenario.setpoint_rate_limit
    runs = {}
    for kind in ("condensed", "sparse"):
        config = dataclasses.replace(scenario.config, solver="daqp", transcription=kind)
        controller = OffsetFreeController(model, config, setpoint_rate_limit=rate)
        plant = scenario.make_plant(model)
        y = plant.output()
        us = []
        for k in range(30):
            u = controller.step(y, scenario.setpoints[k])
            us.append(u[0])
            y = plant.step(u, scenario.disturbances[k])
        runs[kind] = np.array(us)
        assert all(r.mpc.feasible for r in controller.records)
    np.testing.assert_allclose(runs["condensed"], runs["sparse"], atol=1e-7)


@pytest.mark.parametrize("solver", backend_params("daqp", "quadprog"))
def test_soft_policy_on_the_states_of_scenario_3(model, solver) -> None:
    """Scenario 3 (short): every infeasible instant is solved by the soft QP (no +shift)."""
    from dataclasses import replace

    from ltv_lstm_mpc.paper.scenarios import paper_scenarios, run_scenario

    scenario = next(s for s in paper_scenarios(model, short=True) if s.name.startswith("3"))
    config = replace(scenario.config, solver=solver, infeasibility_policy="soft")
    result = run_scenario(replace(scenario, config=config), model)
    records = result.controller.records
    infeasible = [r.mpc for r in records if not r.mpc.feasible]
    assert len(infeasible) >= 50  # the scenario has real infeasible instants
    assert {s.policy for s in infeasible} == {"soft"}
    assert all(np.all(np.isfinite(r.u)) for r in records)
    assert result.summary()["max_output_violation"] == 0.0
