"""A solver backend written from scratch (docs/user-guide/extending.md, "Your own solver"):
the documented example, run as it is shipped, in closed loops against the built-in one."""

from __future__ import annotations

import re
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("daqp")

from ltv_lstm_mpc.solvers import RawResult, available_solvers, unregister_backend

from ltv_lstm_mpc import OffsetFreeController, load_model
from ltv_lstm_mpc.solver_comparison.harness import bench_scenarios

GUIDE = Path(__file__).resolve().parents[1] / "docs" / "user-guide" / "extending.md"


@pytest.fixture(scope="module")
def by_hand():
    """Register the guide's DaqpByHand (the code block that defines it, executed)."""
    blocks = re.findall(r"```python\n(.*?)```", GUIDE.read_text(), flags=re.DOTALL)
    (source,) = [block for block in blocks if "class DaqpByHand" in block]
    namespace: dict = {}
    exec(compile(source, str(GUIDE), "exec"), namespace)
    assert "daqp_by_hand" in available_solvers()
    yield namespace["DaqpByHand"]
    unregister_backend("daqp_by_hand")


@pytest.mark.parametrize("index", [0, 2])
def test_the_guides_backend_drives_the_loop_like_the_built_in_one(by_hand, index) -> None:
    """Bench scenarios 1 and 3 (infeasible steps, the paper's fallback), 100 steps on
    "daqp_by_hand" and on "daqp": the same statuses and policies, applied inputs within
    1e-9; its solves return RawResults with the layer's multipliers."""
    model = load_model("ph_lstm_n5.npz")
    scenario = bench_scenarios(model)[index]
    runs = []
    for solver in ("daqp_by_hand", "daqp"):
        config = replace(scenario.config, N=5, solver=solver)
        controller = OffsetFreeController(
            model, config, setpoint_rate_limit=scenario.setpoint_rate_limit
        )
        plant = scenario.make_plant(model)
        y = plant.output()
        applied = []
        for k in range(100):
            u = controller.step(y, scenario.setpoints[k])
            applied.append(float(u[0]))
            d = scenario.disturbances[k]
            y = plant.step(u, None if np.isnan(d) else d)
        outcomes = [(r.mpc.status, r.mpc.policy) for r in controller.records]
        runs.append((np.array(applied), outcomes))
        if solver == "daqp_by_hand":
            assert controller.mpc.reformulation is not None  # QP-only: the terminal box
    assert runs[0][1] == runs[1][1]
    np.testing.assert_allclose(runs[0][0], runs[1][0], rtol=0, atol=1e-9)
    if index == 2:
        assert any(status == "infeasible" for status, _ in runs[0][1])


def test_the_guides_backend_returns_raw_results(by_hand) -> None:
    """One solve of a random dense QP: a RawResult with the point, bounds and row
    multipliers of the right sizes."""
    from ltv_lstm_mpc.solvers.testing import random_dense_qp

    qp = random_dense_qp(6, 4, seed=1)
    backend = by_hand("daqp_by_hand", "daqp", {})
    backend.setup(qp)
    raw = backend.solve(None)
    assert isinstance(raw, RawResult) and raw.status.has_solution
    assert raw.z.shape == (6,)
    assert raw.duals["bounds"].shape == (6,) and raw.duals["ineq"].shape == (4,)
