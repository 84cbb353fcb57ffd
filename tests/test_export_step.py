"""The C99 controller step (ltv_lstm_mpc/export, ``controller=``): the whole loop of
Fig. 1 in C, replayed on the measurements and set-points of the library's closed loops,
gives the library's inputs and statuses on every step (software in the loop), and
refuses bad input as the library does, with the input held in U. Skipped where no C
compiler is installed."""

from __future__ import annotations

import ctypes
import shutil
import warnings
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from ltv_lstm_mpc import MPCConfig, OffsetFreeController, simulate
from ltv_lstm_mpc.benchmarks.quadtank import quadtank_scenarios
from ltv_lstm_mpc.exceptions import InvalidValueError, UnreachableSetpointError
from ltv_lstm_mpc.export import export_model_c
from ltv_lstm_mpc.export.sil import MPC_STATUS_NAMES as STATUS_NAMES
from ltv_lstm_mpc.export.sil import POLICY_NAMES as POLICIES
from ltv_lstm_mpc.export.sil import CController, compile_controller
from ltv_lstm_mpc.loop.statuses import MEASUREMENT_STATUSES, SETPOINT_STATUSES
from ltv_lstm_mpc.lstm.shipped import load_model
from ltv_lstm_mpc.paper.scenarios import paper_scenarios

pytest.importorskip("daqp")

COMPILERS = [name for name in ("gcc", "clang") if shutil.which(name)]
needs_compiler = pytest.mark.skipif(not COMPILERS, reason="no C compiler (gcc or clang)")


def closed_loop(
    plant_name: str, N: int, steps: int, policy: str = "paper", solver: str = "daqp"
) -> tuple[Any, Any]:
    """The library's closed loop (the reference engine) and its simulation result."""
    if plant_name == "ph":
        model = load_model("ph_lstm_n5.npz")
        scenario: Any = paper_scenarios(model)[2]
    else:
        model = load_model("quadtank_lstm_n8.npz")
        scenario = quadtank_scenarios(short=True)[0]
    config = replace(scenario.config, solver=solver, N=N, infeasibility_policy=policy)
    controller = OffsetFreeController(
        model, config, setpoint_rate_limit=scenario.setpoint_rate_limit, one_call_step=False
    )
    if plant_name == "ph":
        plant = scenario.make_plant(model, controller.certification)
        disturbances = scenario.disturbances
    else:
        plant, disturbances = scenario.make_plant(model), scenario.leaks
    sim = simulate(plant, controller, scenario.setpoints, disturbances, steps, progress=False)
    return controller, sim


def replay(
    controller: Any, sim: Any, folder: Path, compiler: str, c: CController | None = None
) -> dict[str, Any]:
    """The C step on the loop's measurements and set-points, compared on every step (``c``:
    the C controller to replay; by default ``controller`` exported into ``folder``)."""
    if c is None:
        exported = export_model_c(controller.model, folder, controller=controller, prefix="ctl")
        c = CController(compile_controller(exported, compiler), exported)
    worst = 0.0
    counts: dict[str, int] = {}
    statuses: dict[str, int] = {}
    for k, record in enumerate(controller.records):
        code, u_phi, r = c.step(sim.y_phi[k], sim.y0_phi[k])
        assert code == 0, (k, code)
        status = c.mpc_status(r.mpc, controller.mpc.config)  # (the cones': certificates)
        assert status == record.mpc.status, (k, r.mpc.status, record.mpc)
        assert POLICIES[r.mpc.policy] == record.mpc.policy, k
        assert SETPOINT_STATUSES[r.setpoint_status] == record.setpoint_status, k
        assert MEASUREMENT_STATUSES[r.measurement_status] == record.measurement_status, k
        assert (r.setpoint_status == 3) == record.stale_reference, k
        scale = np.maximum(1.0, np.abs(record.u_phi))
        worst = max(worst, float(np.max(np.abs(u_phi - record.u_phi) / scale)))
        counts[record.mpc.policy] = counts.get(record.mpc.policy, 0) + 1
        statuses[record.mpc.status] = statuses.get(record.mpc.status, 0) + 1
    return {"u_phi": worst, "policies": counts, "statuses": statuses}


@needs_compiler
@pytest.mark.parametrize("N", [5, 20])
def test_the_c_step_equals_the_library_on_scenario_3(N: int, tmp_path: Path) -> None:
    """The paper's scenario 3 on the pH plant (set-point jumps, the limiter, infeasible
    instants with the policy), 600 steps from the first: inputs to 1e-9 (relative),
    statuses, policies and set-point statuses exactly."""
    controller, sim = closed_loop("ph", N, 600)
    found = replay(controller, sim, tmp_path, COMPILERS[0])
    assert found["u_phi"] <= 1e-9, found
    if N == 5:
        assert set(found["policies"]) - {"nominal"}, found


@needs_compiler
def test_the_c_step_equals_the_library_on_the_quadruple_tank(tmp_path: Path) -> None:
    """The quadruple tank's set-point changes (n = 8, two pumps, two levels), 480 steps."""
    controller, sim = closed_loop("quadtank", 5, 480)
    found = replay(controller, sim, tmp_path, COMPILERS[-1])
    assert found["u_phi"] <= 1e-9, found


@needs_compiler
@pytest.mark.parametrize(
    ("plant", "N", "steps", "policy"),
    [("ph", 5, 300, "paper"), ("ph", 5, 150, "soft"), ("ph", 5, 150, "shift"),
     ("ph", 20, 150, "paper"), ("quadtank", 5, 240, "soft")],
)  # fmt: skip
def test_the_exact_cones_in_c_equal_the_library(
    plant: str, N: int, steps: int, policy: str, tmp_path: Path
) -> None:
    """solver="daqp:socp" (the exact terminal cones by SQP on DAQP): the C step on the
    library's closed loop, from the first step: inputs to 1e-9 (relative), statuses
    (those of failed SQPs from the certificate checks on the C SQP's last iterate),
    policies and set-point statuses exactly. Scenario 3's first 300 steps hold 15 whose
    nominal SQP ends on an infeasible subproblem, certified infeasible."""
    controller, sim = closed_loop(plant, N, steps, policy, solver="daqp:socp")
    found = replay(controller, sim, tmp_path, COMPILERS[0])
    assert found["u_phi"] <= 1e-9, found
    if (plant, N, policy) == ("ph", 5, "paper"):
        assert found["statuses"].get("infeasible", 0) >= 10, found
        assert found["policies"].get("paper", 0) >= 10, found


@needs_compiler
@pytest.mark.parametrize(
    ("fault", "policy"), [("nan", "paper"), ("garbage", "soft"), ("infeasible", "paper")]
)
def test_the_c_step_meets_a_faulty_solver_as_the_library(
    fault: str, policy: str, tmp_path: Path
) -> None:
    """solvers.testing.faulty("daqp", fault, calls) in the library's loop (scenario 3,
    200 steps: every 5th QP solve and every 7th faulted, the nominal and the policy's
    alike); the C step built with -D<PREFIX>_TEST_FAULTS, told the same calls, on the
    loop's measurements: a point reported solved but NaN or outside U gives "failed" and
    the policy, a faulted policy QP its "+shift", "infeasible" the policy; statuses,
    policies and set-point statuses exactly, inputs to 1e-9."""
    from ltv_lstm_mpc.solvers.testing import faulty

    calls = sorted(set(range(0, 400, 5)) | set(range(3, 400, 7)))
    controller, sim = closed_loop("ph", 5, 200, policy, solver=faulty("daqp", fault, calls))
    clean, _ = closed_loop("ph", 5, 1, policy)  # (the same controller on the plain daqp)
    exported = export_model_c(clean.model, tmp_path, controller=clean, prefix="ctl")
    library = compile_controller(exported, COMPILERS[0], ("-DCTL_TEST_FAULTS",))
    c = CController(library, exported)
    table = (ctypes.c_ubyte * (1 << 16)).in_dll(c.library, "ctl_test_fault_calls")
    for call in calls:
        table[call] = {"nan": 1, "garbage": 2, "infeasible": 3}[fault]
    found = replay(controller, sim, tmp_path, COMPILERS[0], c)
    assert found["u_phi"] <= 1e-9, found
    assert ctypes.c_long.in_dll(c.library, "ctl_test_fault_count").value > 100
    policies = found["policies"]
    assert policies.get(f"{policy}+shift", 0) > 0 and policies.get(policy, 0) > 0, policies
    if fault != "infeasible":
        assert found["statuses"].get("failed", 0) > 0, found


def unreachable_loop(limit: float | None) -> tuple[Any, Any]:
    """The pH plant through set-points the model cannot reach (9.6: the stale reference),
    outside the admissible interval (8.8, 6.0) and back, with or without the limiter."""
    model = load_model("ph_lstm_n5.npz")
    scenario = paper_scenarios(model)[2]
    config = replace(scenario.config, solver="daqp", N=5)
    controller = OffsetFreeController(model, config, setpoint_rate_limit=limit, one_call_step=False)
    plant = scenario.make_plant(model, controller.certification)
    levels = [7.0, 9.6, 8.8, 6.0, 7.5]
    setpoints = np.repeat(np.array(levels), 40)[:, None]
    with warnings.catch_warnings():  # (the loop warns of what it meets, once each)
        warnings.simplefilter("ignore")
        sim = simulate(
            plant, controller, setpoints, scenario.disturbances[:200], 200, progress=False
        )
    return controller, sim


@needs_compiler
@pytest.mark.parametrize("limit", [None, 0.01])
def test_the_c_step_keeps_the_statuses_of_unreachable_and_inadmissible_setpoints(
    limit: float | None, tmp_path: Path
) -> None:
    """An unreachable set-point (the last admissible equilibrium kept, alpha_k at the
    set-point it encodes), set-points outside the admissible interval, and with the
    limiter a target outside it: the library's inputs (1e-9) and statuses on every step."""
    controller, sim = unreachable_loop(limit)
    statuses = {r.setpoint_status for r in controller.records}
    expected = {"ok", "target_outside_admissible"} if limit else {"ok", "unreachable_stale"}
    assert expected <= statuses, statuses
    found = replay(controller, sim, tmp_path, COMPILERS[0])
    assert found["u_phi"] <= 1e-9, found


def first_step_loop(levels: list[float]) -> tuple[Any, Any]:
    """The pH plant from its first step through set-point levels (10 steps each, the last
    40), on the reference engine."""
    model = load_model("ph_lstm_n5.npz")
    scenario = paper_scenarios(model)[2]
    config = replace(scenario.config, solver="daqp", N=5)
    controller = OffsetFreeController(model, config, one_call_step=False)
    plant = scenario.make_plant(model, controller.certification)
    setpoints = np.concatenate([np.repeat(levels[:-1], 10), np.repeat(levels[-1:], 40)])
    with warnings.catch_warnings():  # (the loop warns of what it meets, once each)
        warnings.simplefilter("ignore")
        sim = simulate(plant, controller, setpoints[:, None], scenario.disturbances,
                       len(setpoints), progress=False)  # fmt: skip
    return controller, sim


@needs_compiler
def test_the_c_step_keeps_the_reference_rules_before_any_admissible_equilibrium(
    tmp_path: Path,
) -> None:
    """From the first step, before any admissible equilibrium: a set-point whose
    equilibrium needs an input outside U (9.3: kept as the last converged one, status
    unreachable, u_bar projected for the candidate), then one without any (9.6: that
    equilibrium kept, stale), 5.5 (outside U again), then 7.0 (admissible): the library's
    inputs (1e-9) and statuses on every step. A first set-point without any equilibrium:
    the library raises, the C step returns STEP_UNREACHABLE with the middle of U."""
    controller, sim = first_step_loop([9.3, 9.6, 5.5, 7.0])
    statuses = [r.setpoint_status for r in controller.records]
    assert statuses[0] == statuses[25] == "unreachable", statuses
    assert statuses[15] == "unreachable_stale" and statuses[-1] == "ok", statuses
    found = replay(controller, sim, tmp_path / "loop", COMPILERS[0])
    assert found["u_phi"] <= 1e-9, found
    with pytest.raises(UnreachableSetpointError):
        OffsetFreeController(controller.model, controller.config).step(sim.y_phi[0], [9.6])
    exported = export_model_c(controller.model, tmp_path, controller=controller, prefix="ctl")
    c = CController(compile_controller(exported, COMPILERS[0]), exported)
    code, u_phi, _ = c.step(sim.y_phi[0], np.array([9.6]))
    scaling = controller.scaling
    assert code == 3 and np.allclose(u_phi, (scaling.u_phi_low + scaling.u_phi_high) / 2)


@needs_compiler
def test_the_c_step_refuses_bad_input_and_holds_the_input(tmp_path: Path) -> None:
    """A NaN or infinite measurement, a NaN set-point, an implausible first measurement:
    the library raises; the C step returns its code, holds the last input (in U; the
    middle of U before any) and changes nothing, so the loop goes on as the library's."""
    controller, sim = closed_loop("ph", 5, 60)
    exported = export_model_c(controller.model, tmp_path, controller=controller, prefix="ctl")
    c = CController(compile_controller(exported, COMPILERS[0]), exported)
    norm = controller.model.normalization
    low, high = controller.scaling.u_phi_low, controller.scaling.u_phi_high
    middle = (low + high) / 2
    implausible = norm.y_phi_max + 5 * (norm.y_phi_max - norm.y_phi_min)
    code, u_phi, _ = c.step(implausible, sim.y0_phi[0])
    assert code == 1 and np.allclose(u_phi, middle)
    fresh = OffsetFreeController(controller.model, controller.config)
    for bad_y, bad_y0 in (
        (implausible, sim.y0_phi[0]), (np.full(1, np.nan), sim.y0_phi[0]),
        (sim.y_phi[0], np.full(1, np.inf)),
    ):  # fmt: skip
        with pytest.raises(InvalidValueError):
            fresh.step(bad_y, bad_y0)
    last = None
    for k, record in enumerate(controller.records):
        if k in (10, 30):
            for bad_y, bad_y0, expected in (
                (np.full(1, np.nan), sim.y0_phi[k], 1), (np.full(1, -np.inf), sim.y0_phi[k], 1),
                (sim.y_phi[k], np.full(1, np.nan), 2),
            ):  # fmt: skip
                code, u_phi, _ = c.step(bad_y, bad_y0)
                assert code == expected and np.array_equal(u_phi, last), (k, code)
                assert np.all((low <= u_phi) & (u_phi <= high))
        code, u_phi, r = c.step(sim.y_phi[k], sim.y0_phi[k])
        assert code == 0 and np.abs(u_phi - record.u_phi).max() <= 1e-9, k
        assert STATUS_NAMES[r.mpc.status] == record.mpc.status, k
        last = u_phi


@needs_compiler
def test_the_c_engine_runs_the_loop_with_the_library_records(tmp_path: Path) -> None:
    """OffsetFreeController(engine="c") in simulate: the records of the C step equal the
    reference engine's (inputs to 1e-9, MPC statuses, policies, set-point statuses, the
    estimates), after a reset too; bad input raises as the library does."""
    model = load_model("ph_lstm_n5.npz")
    scenario = paper_scenarios(model)[2]
    runs = {}
    for engine in ("reference", "c", "c"):
        controller = scenario.make_controller(model, solver="daqp", N=5, engine=engine)
        if engine == "c" and "c" in runs:  # the second C run: after a reset
            controller = runs["c"][0]
            controller.reset()
        plant = scenario.make_plant(model, controller.certification)
        sim = simulate(plant, controller, scenario.setpoints, scenario.disturbances, 300,
                       progress=False)  # fmt: skip
        runs[engine if engine not in runs else "c again"] = (controller, sim)
    reference, sim_reference = runs["reference"]
    for name in ("c", "c again"):
        controller, sim = runs[name]
        assert controller.engine.name == "c" and controller.records[3].engine == "c"
        assert np.abs(sim.u_phi - sim_reference.u_phi).max() <= 1e-9 * np.abs(sim.u_phi).max()
        assert list(sim.status) == list(sim_reference.status)
        assert list(sim.policy) == list(sim_reference.policy)
        assert any(p != "nominal" for p in sim.policy)
        for a, b in zip(controller.records, reference.records, strict=True):
            assert a.setpoint_status == b.setpoint_status
            assert np.abs(a.x_hat - b.x_hat).max() <= 1e-9
    controller = runs["c"][0]
    with pytest.raises(InvalidValueError):
        controller.step(np.array([np.nan]), sim.y0_phi[0])


@needs_compiler
def test_the_c_engine_runs_the_exact_cones() -> None:
    """engine="c" on solver="daqp:socp": 200 steps of scenario 3 through simulate give the
    reference engine's inputs (to 1e-9), statuses (a failed SQP's from the certificate
    checks, with their reasons), policies and estimates."""
    model = load_model("ph_lstm_n5.npz")
    scenario = paper_scenarios(model)[2]
    runs = {}
    for engine in ("reference", "c"):
        controller = scenario.make_controller(model, solver="daqp:socp", N=5, engine=engine)
        plant = scenario.make_plant(model, controller.certification)
        sim = simulate(plant, controller, scenario.setpoints, scenario.disturbances, 200,
                       progress=False)  # fmt: skip
        runs[engine] = (controller, sim)
    (reference, sim_reference), (controller, sim) = runs["reference"], runs["c"]
    assert controller.engine.name == "c"
    assert np.abs(sim.u_phi - sim_reference.u_phi).max() <= 1e-9 * np.abs(sim.u_phi).max()
    assert list(sim.status) == list(sim_reference.status)
    assert list(sim.policy) == list(sim_reference.policy)
    assert "infeasible" in list(sim.status)
    for a, b in zip(controller.records, reference.records, strict=True):
        assert np.abs(a.x_hat - b.x_hat).max() <= 1e-9
        if a.mpc.status == "infeasible":
            assert a.mpc.reason.split(";")[0] == b.mpc.reason.split(";")[0]


def test_the_c_engine_refuses_what_the_export_does_not_cover() -> None:
    """engine="c" for a configuration the C export does not cover, or an unknown engine:
    refused at construction, with the reason and the fix."""
    model = load_model("ph_lstm_n5.npz")
    with pytest.raises(InvalidValueError, match="sqp_iterations=1"):
        OffsetFreeController(model, replace(MPCConfig(solver="daqp"), sqp_iterations=3), engine="c")
    with pytest.raises(InvalidValueError, match="double precision only"):
        OffsetFreeController(model, MPCConfig(solver="daqp:socp"), engine="c-single")
    with pytest.raises(InvalidValueError, match="not an engine"):
        OffsetFreeController(model, MPCConfig(solver="daqp"), engine="fortran")
