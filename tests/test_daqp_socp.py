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
from ltv_lstm_mpc.solvers import DenseSession, SolverStatus, available_solvers

from ltv_lstm_mpc import OffsetFreeController
from ltv_lstm_mpc.lstm.shipped import load_model

pytestmark = pytest.mark.skipif(
    "daqp:socp" not in available_solvers() or "clarabel" not in available_solvers(),
    reason="needs DAQP bound natively and clarabel",
)


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
