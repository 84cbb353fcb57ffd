"""The controller step as one compiled call (loop/compiled_step.py) against the general path.

Both paths run the same compiled kernels, so the records agree to 1e-12 (measured: bit for
bit) over 300-step closed loops, SISO and (2, 2), infeasible steps and the fallbacks
included; the records of one-call steps are built from preallocated rows when read.
"""

from __future__ import annotations

import dataclasses
import math
import sys
import warnings
from collections import Counter
from dataclasses import replace
from typing import Any

import numpy as np
import pytest
from ltv_lstm_mpc.solvers import available_solvers
from optional_extras import requires_daqp_binding, requires_solver

from ltv_lstm_mpc import MPCConfig, OffsetFreeController, simulate
from ltv_lstm_mpc.loop import compiled_step
from ltv_lstm_mpc.loop.engines import OneCallEngine
from ltv_lstm_mpc.lstm.shipped import load_model

needs_binding = requires_daqp_binding()
pytestmark = needs_binding

TOLERANCE = 1e-12


def _differences(a: Any, b: Any, prefix: str = "") -> dict[str, float]:
    """Largest difference per field of two records (times and the engine that ran the step
    excluded); strings and flags must be equal (a difference of inf)."""
    out: dict[str, float] = {}
    for field in dataclasses.fields(a):
        name = field.name
        if name.startswith("time") or name.endswith("_time") or name in ("monitor_log", "engine"):
            continue
        left, right = getattr(a, name), getattr(b, name)
        if dataclasses.is_dataclass(left):
            out.update(_differences(left, right, prefix=f"{name}."))
        elif isinstance(left, dict):
            for key in left:
                out[f"{prefix}{name}.{key}"] = abs(left[key] - right[key])
        elif isinstance(left, np.ndarray):
            both = np.isnan(left.astype(float)) & np.isnan(right.astype(float))
            gap = np.where(both, 0.0, np.abs(left.astype(float) - right.astype(float)))
            out[prefix + name] = float(gap.max()) if gap.size else 0.0
        elif isinstance(left, float) and not isinstance(right, bool):
            out[prefix + name] = (
                0.0 if math.isnan(left) and math.isnan(right) else abs(left - right)
            )
        else:
            out[prefix + name] = 0.0 if left == right else math.inf
    return out


def _worst(records_a: Any, records_b: Any) -> tuple[float, str]:
    worst, where = 0.0, ""
    for k, (a, b) in enumerate(zip(records_a, records_b, strict=True)):
        for name, gap in _differences(a, b).items():
            if gap > worst:
                worst, where = gap, f"step {k}: {name}"
    return worst, where


@pytest.fixture
def codes(monkeypatch: pytest.MonkeyPatch) -> Counter[int]:
    """Counts of the one-call step's return codes (both entries: with the state as
    arguments, and read from the rows; through ``_compiled`` and through the entry point
    the common step calls directly, in ``OneCallEngine.step``)."""
    counts: Counter[int] = Counter()
    original = OneCallEngine._compiled
    names = ("controller_step", "controller_step_from_rows", "controller_first_step")

    class CountingEntries(dict[str, Any]):
        """The controller's entry points, each handed out wrapped in a counter."""

        def get(self, key: str, default: Any = None) -> Any:
            entry = super().get(key, default)
            if not entry or key not in names:
                return entry

            def counted(*arguments: Any) -> Any:
                answer = entry(*arguments)
                counts[answer[0]] += 1
                return answer

            return counted

    def counting(self: Any, name: str, fast: bool, arguments: Any) -> Any:
        if not isinstance(self.entries, CountingEntries):
            self.entries = CountingEntries(self.entries)
        through_entry = fast and bool(dict.get(self.entries, name))  # counted there
        answer = original(self, name, fast, arguments)
        if name in names and not through_entry:
            counts[answer[0]] += 1
        return answer

    # at the controller's calls, not by replacing the compiled functions (the "_from_rows"
    # ones call them from compiled code: a Python stand-in cannot be compiled into them)
    monkeypatch.setattr(OneCallEngine, "_compiled", counting)
    return counts


def _loop(model: Any, config: MPCConfig, scenario: Any, one_call: bool, steps: int) -> Any:
    controller = OffsetFreeController(
        model,
        config,
        setpoint_rate_limit=scenario.setpoint_rate_limit,
        kernels="compiled",
        one_call_step=one_call,
    )
    assert controller.one_call is one_call
    plant = scenario.make_plant(model)
    y = plant.output()
    for k in range(steps):
        u = controller.step(y, scenario.setpoints[k])
        d = scenario.disturbances[k]
        y = plant.step(u, None if np.isnan(d) else d)
    return controller


SOLVERS = ["daqp"] + (["daqp:socp"] if "daqp:socp" in available_solvers() else [])


@pytest.mark.parametrize("solver", SOLVERS)
@pytest.mark.parametrize(("index", "N"), [(0, 5), (0, 20), (2, 5)])
def test_one_call_step_equals_the_general_path_siso(
    index: int, N: int, solver: str, codes: Counter[int]
) -> None:
    """Bench scenarios on the shipped pH model, 300 steps: every record field the same
    (scenario 3 has infeasible steps: the one call runs the policy; on daqp:socp the
    status and reason of a failed exact-cone solve, from its certificate, come when the
    record is read); daqp:socp: the exact terminal cones in the one call."""
    from ltv_lstm_mpc.solver_comparison.harness import bench_scenarios

    model = load_model("ph_lstm_n5.npz")
    scenario = bench_scenarios(model)[index]
    config = replace(scenario.config, solver=solver, N=N)
    steps = min(len(scenario.setpoints), 300)
    fast = _loop(model, config, scenario, True, steps)
    taken = dict(codes)
    general = _loop(model, config, scenario, False, steps)
    assert dict(codes) == taken  # the general controller never calls the one-call step
    worst, where = _worst(fast.records, general.records)
    assert worst <= TOLERANCE, where
    assert fast.warning_counts == general.warning_counts
    assert fast.e_hat == general.e_hat
    np.testing.assert_array_equal(fast.observer.x_hat, general.observer.x_hat)
    assert taken.get(compiled_step.STEP_DONE, 0) >= 200
    infeasible = sum(not r.mpc.feasible for r in fast.records)
    if index == 2:  # the policy runs in the one call
        assert infeasible > 0
        assert taken.get(compiled_step.STEP_DONE, 0) == steps
    else:
        assert infeasible == 0
        assert taken.get(compiled_step.STEP_DONE, 0) == steps  # the first step too


@pytest.mark.parametrize("solver", SOLVERS)
@pytest.mark.parametrize("policy", ["paper", "soft", "shift"])
@pytest.mark.parametrize("N", [5, 20])
def test_infeasibility_policies_run_in_the_one_call(
    policy: str, N: int, solver: str, codes: Counter[int]
) -> None:
    """Bench scenario 3 (set-point steps, infeasible instants): the nominal problem's
    infeasible steps take the policy inside the compiled call (none handed over to the
    reference engine's feedback), on daqp's QP and daqp:socp's exact cones, with every
    record field (statuses and reasons, the certificates' numbers included) as the
    reference engine's."""
    from ltv_lstm_mpc.solver_comparison.harness import bench_scenarios

    model = load_model("ph_lstm_n5.npz")
    scenario = bench_scenarios(model)[2]
    config = replace(scenario.config, solver=solver, N=N, infeasibility_policy=policy)
    steps = min(len(scenario.setpoints), 300)
    fast = _loop(model, config, scenario, True, steps)
    taken = dict(codes)
    general = _loop(model, config, scenario, False, steps)
    worst, where = _worst(fast.records, general.records)
    assert worst <= TOLERANCE, where
    fallbacks = [r for r in fast.records if not r.mpc.feasible]
    assert taken.get(compiled_step.STEP_FEEDBACK, 0) == 0
    handed_over = sum(r.engine == "reference" for r in fallbacks)  # (a damped Newton's)
    assert handed_over <= taken.get(compiled_step.STEP_REFERENCE, 0)
    assert len(fallbacks) - handed_over >= (5 if N == 5 else 1)
    assert {r.mpc.policy for r in fallbacks} <= {policy, f"{policy}+shift", "shift"}
    assert all(r.mpc.reason for r in fallbacks)


@pytest.mark.parametrize("solver", SOLVERS)
def test_one_call_step_equals_the_general_path_mimo(solver: str, codes: Counter[int]) -> None:
    """The quadruple tank (2, 2), 300 steps of its set-point scenario through simulate."""
    from ltv_lstm_mpc.benchmarks.quadtank import QUADTANK_MODEL, quadtank_scenarios

    model = load_model(QUADTANK_MODEL)
    scenario = quadtank_scenarios(short=True)[0]
    config = replace(scenario.config, solver=solver)
    steps = min(scenario.steps, 300)
    results = []
    for one_call in (True, False):
        controller = OffsetFreeController(
            model, config, setpoint_rate_limit=scenario.setpoint_rate_limit,
            kernels="compiled", one_call_step=one_call,
        )  # fmt: skip
        result = simulate(
            scenario.make_plant(model), controller, scenario.setpoints[:steps],
            scenario.leaks[:steps], steps,
        )  # fmt: skip
        results.append((controller, result))
    (fast, fast_result), (general, general_result) = results
    assert codes[compiled_step.STEP_DONE] == steps
    worst, where = _worst(fast.records, general.records)
    assert worst <= TOLERANCE, where
    np.testing.assert_array_equal(fast_result.u_phi, general_result.u_phi)


def test_damped_newton_runs_in_the_one_call(codes: Counter[int]) -> None:
    """The paper's scenario 3 (short): at a set-point step the warm chord does not reach an
    admissible equilibrium and the damped Newton with restarts runs inside the compiled
    call (no step handed over), with the reference engine's records and counts."""
    from ltv_lstm_mpc.paper.scenarios import paper_scenarios

    model = load_model("ph_lstm_n5.npz")
    scenario = paper_scenarios(model, short=True)[2]
    config = replace(scenario.config, solver="daqp", N=5)
    fast = _loop(model, config, scenario, True, scenario.steps)
    taken = dict(codes)
    general = _loop(model, config, scenario, False, scenario.steps)
    assert fast.reference.counts["fallbacks"] >= 1
    assert fast.reference.counts == general.reference.counts
    assert taken.get(compiled_step.STEP_REFERENCE, 0) == 0
    assert taken.get(compiled_step.STEP_DONE, 0) == scenario.steps
    worst, where = _worst(fast.records, general.records)
    assert worst <= TOLERANCE, where


def test_mimo_restarts_and_policies_run_in_the_one_call(codes: Counter[int]) -> None:
    """The quadruple tank (2, 2) with set-point jumps between the corners of its schedule
    (no limiter): the damped Newton from the grid's restarts and the infeasibility policy
    run inside the compiled call, with the reference engine's records and counts."""
    from ltv_lstm_mpc.benchmarks.quadtank import QUADTANK_MODEL, quadtank_scenarios

    model = load_model(QUADTANK_MODEL)
    scenario = quadtank_scenarios(short=True)[0]
    config = replace(scenario.config, solver="daqp")
    setpoints = np.array(scenario.setpoints)
    jumps = [setpoints[0]] * 30 + [setpoints.max(axis=0)] * 60 + [setpoints.min(axis=0)] * 60
    controllers = []
    for one_call in (True, False):
        controller = OffsetFreeController(model, config, kernels="compiled", one_call_step=one_call)
        plant = scenario.make_plant(model)
        y = plant.output()
        for setpoint in jumps:
            y = plant.step(controller.step(y, setpoint))
        controllers.append(controller)
    fast, general = controllers
    assert fast.reference.counts["fallbacks"] >= 1
    assert fast.reference.counts == general.reference.counts
    assert any(not r.mpc.feasible for r in fast.records)
    assert codes.get(compiled_step.STEP_DONE, 0) == len(jumps)  # the first step too
    worst, where = _worst(fast.records, general.records)
    assert worst <= TOLERANCE, where


@pytest.mark.parametrize("rate_limit", [None, 0.05])
def test_unreachable_setpoint_keeps_the_stale_reference_in_the_one_call(
    rate_limit: float | None, codes: Counter[int]
) -> None:
    """A set-point step to 9.45 pH (no equilibrium with u_bar in U), without and with the
    rate limiter: neither the warm chord nor the damped Newton with restarts gives an
    admissible equilibrium, and the compiled call keeps the last admissible one (the stale
    reference, with the set-point it encodes for alpha_k): the same records, counts and
    warnings as the reference engine, no step handed over."""
    model = load_model("ph_lstm_n5.npz")
    config = MPCConfig(solver="daqp", N=5)
    setpoints = [7.0] * 20 + [9.45] * 60 + [7.5] * 40
    runs = []
    for one_call in (True, False):
        controller = OffsetFreeController(
            model, config, kernels="compiled", one_call_step=one_call,
            setpoint_rate_limit=rate_limit,
        )  # fmt: skip
        from ltv_lstm_mpc.plants import PHNeutralizationPlant

        plant = PHNeutralizationPlant()
        y = plant.output()
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            for setpoint in setpoints:
                y = plant.step(controller.step(y, setpoint))
        messages = sorted(str(w.message) for w in caught)
        runs.append((controller, messages))
    (fast, fast_messages), (general, general_messages) = runs
    # (the run's first set-point warning: "not reachable", or with the limiter the target
    # outside the admissible interval, which comes first)
    assert any("set-point" in message for message in fast_messages)
    assert fast_messages == general_messages
    assert codes.get(compiled_step.STEP_REFERENCE, 0) == 0
    assert codes.get(compiled_step.STEP_DONE, 0) == len(setpoints)  # the first step too
    assert any(r.stale_reference and r.engine == "one-call" for r in fast.records)
    assert fast.reference.counts == general.reference.counts
    assert fast.warning_counts == general.warning_counts
    worst, where = _worst(fast.records, general.records)
    assert worst <= TOLERANCE, where


def test_records_are_a_read_only_sequence_built_on_reading() -> None:
    """Records of one-call steps: placeholders until read, then kept; a list's reading
    API (len, indexing, negative indices, slices, iteration, == list); an earlier run's
    records stay readable after reset and another run (own rows, own assumption log)."""
    model = load_model("ph_lstm_n5.npz")
    controller = OffsetFreeController(model, MPCConfig(solver="daqp", N=5), kernels="compiled")
    plant_y = np.array([7.0])
    for _ in range(5):
        controller.step(plant_y, np.array([7.2]))
    first_run = controller.records
    assert len(first_run) == 5 and first_run.slots[1:] == [None] * 4
    last = first_run[-1]
    assert first_run[4] is last and first_run.slots[4] is last  # kept once built
    assert [r.index for r in first_run[1:3]] == [1, 2]
    assert list(first_run) == [first_run[k] for k in range(5)]
    assert first_run == list(first_run) and first_run != []
    u_first = [r.u.copy() for r in first_run]
    verdict = last.assumptions
    assert verdict is not None and verdict.guarantee  # read from this run's log
    controller.reset()
    assert controller.records == [] and not controller.records
    for _ in range(3):
        controller.step(np.array([7.1]), np.array([6.8]))
    for r, u in zip(first_run, u_first, strict=True):
        np.testing.assert_array_equal(r.u, u)
    assert first_run[2].monitor_log is not controller.records[2].monitor_log


class NoCommonStep(dict[str, Any]):
    """Entry points without the common step's: every step takes the longer path."""

    def get(self, key: str, default: Any = None) -> Any:
        return None if key == "controller_step_from_rows" else super().get(key, default)


def test_common_step_takes_the_short_python_path(monkeypatch: pytest.MonkeyPatch) -> None:
    """After a one-call step, the next one with float, numpy float64 or float64-vector
    signals runs through the common step of ``OneCallEngine.step`` (not
    ``_step_one_call``) and gives the same inputs as a controller made to take the longer
    path; other signal types (0-d arrays, lists) and a setting assigned between steps take
    the longer path."""
    from ltv_lstm_mpc.solver_comparison.harness import bench_scenarios

    model = load_model("ph_lstm_n5.npz")
    scenario = bench_scenarios(model)[0]
    config = replace(scenario.config, solver="daqp", N=5)
    longer_calls = Counter[str]()
    original = OneCallEngine._step_one_call

    def counted(self: Any, y_phi: Any, y0_phi: Any) -> Any:
        longer_calls[self.controller.label] += 1
        return original(self, y_phi, y0_phi)

    monkeypatch.setattr(OneCallEngine, "_step_one_call", counted)
    short, longer = (
        OffsetFreeController(
            model, config, setpoint_rate_limit=scenario.setpoint_rate_limit, kernels="compiled"
        )
        for _ in range(2)
    )
    short.label, longer.label = "short", "longer"  # type: ignore[attr-defined]
    longer.engine.entries = NoCommonStep(longer.engine.entries)  # type: ignore[attr-defined]
    plants = [scenario.make_plant(model) for _ in range(2)]
    y = [plant.output() for plant in plants]
    kinds = ["float"] * 10 + ["vector"] * 10 + ["float64"] * 10
    kinds += ["0-d array", "list", "float", "setting"] * 5
    for k, kind in enumerate(kinds):
        u = []
        for i, controller in enumerate((short, longer)):
            y_phi = float(np.ravel(y[i])[0])
            y0_phi = float(np.ravel(scenario.setpoints[k])[0])
            if kind == "vector":
                y_phi, y0_phi = np.array([y_phi]), np.array([y0_phi])
            elif kind == "float64":
                y_phi, y0_phi = np.float64(y_phi), np.float64(y0_phi)
            elif kind == "0-d array":
                y_phi, y0_phi = np.array(y_phi), np.array(y0_phi)
            elif kind == "list":
                y_phi, y0_phi = [y_phi], [y0_phi]
            elif kind == "setting":
                controller.reference.tol = controller.reference.tol  # ends the deferral
            u.append(controller.step(y_phi, y0_phi).copy())
            d = scenario.disturbances[k]
            y[i] = plants[i].step(u[-1], None if np.isnan(d) else d)
        np.testing.assert_array_equal(u[0], u[1])
    assert longer_calls["longer"] == len(kinds) - 1  # (the first step: its own call)
    # the longer path: per block the 0-d array, the list and the step after the setting
    # (step 1 takes the common step: the compiled first step left its state in its row)
    assert longer_calls["short"] == 3 * 5, longer_calls
    worst, where = _worst(short.records, longer.records)
    assert worst <= TOLERANCE, where


@pytest.mark.skipif(sys.platform != "linux", reason="minor page faults counted by getrusage")
def test_steps_write_their_record_rows_without_page_faults() -> None:
    """The record rows are written when reserved, so that the steps that fill them take
    no page fault (lazily mapped zeros cost one per new 4 KiB page inside the timed step:
    two per step at N = 50)."""
    import resource

    from ltv_lstm_mpc.solver_comparison.harness import bench_scenarios

    model = load_model("ph_lstm_n5.npz")
    scenario = bench_scenarios(model)[0]
    controller = OffsetFreeController(
        model,
        replace(scenario.config, solver="daqp", N=50),
        setpoint_rate_limit=scenario.setpoint_rate_limit,
        kernels="compiled",
    )
    controller.records.reserve(400)
    plant = scenario.make_plant(model)
    y = plant.output()
    faults = 0
    for k in range(200):
        before = resource.getrusage(resource.RUSAGE_SELF).ru_minflt
        u = controller.step(y, scenario.setpoints[k])
        if k >= 20:  # after compiling and warming the workspaces
            faults += resource.getrusage(resource.RUSAGE_SELF).ru_minflt - before
        d = scenario.disturbances[k]
        y = plant.step(u, None if np.isnan(d) else d)
    assert controller.one_call and all(r.mpc.feasible for r in controller.records[20:])
    assert faults <= 10, f"{faults} page faults in 180 steps"


def test_inputs_of_other_layouts_and_bad_inputs() -> None:
    """Read-only and strided measurements run the one-call step (as copies: one compiled
    signature) with the same input; a NaN measurement and an implausible one with
    implausible_measurements='raise' are refused by the general path before anything is
    updated."""
    from ltv_lstm_mpc.exceptions import InvalidValueError

    model = load_model("ph_lstm_n5.npz")
    config = MPCConfig(solver="daqp", N=5)
    inputs = []
    for variant in range(3):
        controller = OffsetFreeController(
            model, config, kernels="compiled", implausible_measurements="raise"
        )
        controller.step(7.0, 7.0)
        y = np.array([7.05, 0.0])[:1] if variant == 0 else np.array([[7.05, 0.0]])[0, ::2]
        if variant == 1:
            y.flags.writeable = False
        setpoint = 7.3 if variant < 2 else np.array([7.3])
        inputs.append(controller.step(y, setpoint).copy())
        length = len(controller.records)
        x_hat = controller.observer.x_hat.copy()
        with pytest.raises(InvalidValueError, match="NaN"):
            controller.step(np.array([np.nan]), 7.3)
        with pytest.raises(InvalidValueError, match=r"implausible|range width"):
            controller.step(np.array([100.0]), 7.3)
        assert len(controller.records) == length
        np.testing.assert_array_equal(controller.observer.x_hat, x_hat)
    np.testing.assert_array_equal(inputs[0], inputs[1])
    np.testing.assert_array_equal(inputs[0], inputs[2])


def test_implausible_measurements_flagged_in_the_one_call(codes: Counter[int]) -> None:
    """Implausible measurements (a sensor fault: 30 pH for five steps) with the default
    implausible_measurements='flag': flagged, warned once and used inside the compiled
    call, with the reference engine's records and warning counts."""
    model = load_model("ph_lstm_n5.npz")
    config = MPCConfig(solver="daqp", N=5)
    runs = []
    for one_call in (True, False):
        controller = OffsetFreeController(model, config, kernels="compiled", one_call_step=one_call)
        from ltv_lstm_mpc.plants import PHNeutralizationPlant

        plant = PHNeutralizationPlant()
        y = plant.output()
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            for k in range(40):
                measured = np.array([30.0]) if 20 <= k < 25 else y
                y = plant.step(controller.step(measured, 7.2))
        assert sum("range width" in str(w.message) for w in caught) == 1
        runs.append(controller)
    fast, general = runs
    assert sum(r.measurement_status == "implausible" for r in fast.records) == 5
    assert fast.warning_counts == general.warning_counts
    assert codes.get(compiled_step.STEP_GENERAL, 0) == 0
    assert codes.get(compiled_step.STEP_DONE, 0) == 40
    worst, where = _worst(fast.records, general.records)
    assert worst <= TOLERANCE, where


def test_one_call_applies_only_where_it_can() -> None:
    """The numpy kernels, a globalized SQP and a given mpc run the general path (other
    solvers: the next test); the flag is checked."""
    from ltv_lstm_mpc import RobustMPC
    from ltv_lstm_mpc.exceptions import ArgumentTypeError

    model = load_model("ph_lstm_n5.npz")
    assert OffsetFreeController(model, MPCConfig(solver="daqp"), kernels="compiled").one_call
    assert not OffsetFreeController(model, MPCConfig(solver="daqp"), kernels="numpy").one_call
    assert not OffsetFreeController(
        model, MPCConfig(solver="daqp", sqp_iterations=3), kernels="compiled"
    ).one_call
    config = MPCConfig(solver="daqp")
    given = OffsetFreeController(model, config, mpc=RobustMPC(model, config))
    assert not given.one_call
    with pytest.raises(ArgumentTypeError, match="one_call_step"):
        OffsetFreeController(model, config, one_call_step="yes")  # type: ignore[arg-type]


@requires_solver("osqp")
def test_no_one_call_with_another_solver() -> None:
    """Another solver (OSQP) runs the general path."""
    model = load_model("ph_lstm_n5.npz")
    assert not OffsetFreeController(model, MPCConfig(solver="osqp"), kernels="compiled").one_call


@pytest.mark.parametrize("solver", SOLVERS)
def test_entry_points_give_the_dispatched_numbers(solver: str) -> None:
    """Unpatched, the one-call and prepared steps call the compiled entry points directly
    (resolved once, numba's type dispatch skipped while the state is the step's own
    rows): the same records bit for bit as the general path."""
    from ltv_lstm_mpc.solver_comparison.harness import bench_scenarios

    model = load_model("ph_lstm_n5.npz")
    scenario = bench_scenarios(model)[0]
    config = replace(scenario.config, solver=solver, N=5)
    steps = 120
    fast = _loop(model, config, scenario, True, steps)
    general = _loop(model, config, scenario, False, steps)
    assert callable(fast.engine.entries.get("controller_step_from_rows"))
    worst, where = _worst(fast.records, general.records)
    assert worst == 0.0, where
    prepared = OffsetFreeController(
        model, config, setpoint_rate_limit=scenario.setpoint_rate_limit, kernels="compiled"
    )
    plant = scenario.make_plant(model)
    y = plant.output()
    for k in range(steps):
        u = prepared.step(y, scenario.setpoints[k])
        d = scenario.disturbances[k]
        y = plant.step(u, None if np.isnan(d) else d)
        assert prepared.prepare_next(scenario.setpoints[min(k + 1, steps - 1)])
    assert callable(prepared.engine.entries.get("feedback_step_from_rows"))
    assert callable(prepared.engine.entries.get("prepare_step_from_rows"))
    worst, where = _worst(prepared.records, general.records)
    assert worst == 0.0, where


def _first_steps(model: Any, config: MPCConfig, limit: float | None, one_call: bool) -> Any:
    """30 steps of the paper's scenario 3 from a set-point away from the measurement, a
    reset, 30 more from another: (controller, records of both runs, warnings' messages)."""
    from ltv_lstm_mpc.paper.scenarios import paper_scenarios

    scenario = paper_scenarios(model, short=True)[2]
    controller = OffsetFreeController(
        model, config, setpoint_rate_limit=limit, kernels="compiled", one_call_step=one_call
    )
    runs, messages = [], []
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        for run, offset in enumerate((0.6, -0.4)):
            plant = scenario.make_plant(model)
            y = plant.output()
            for k in range(30):
                y = plant.step(controller.step(y, scenario.setpoints[k] + offset))
            runs.append(list(controller.records))
            if run == 0:
                controller.reset()
    messages = [str(w.message) for w in caught]
    return controller, runs, messages


@pytest.mark.parametrize("solver", SOLVERS)
@pytest.mark.parametrize("limit", [None, 0.05])
def test_the_first_step_and_a_reset_run_in_one_call(
    solver: str, limit: float | None, codes: Counter[int]
) -> None:
    """The first step after construction and after a reset (the observer's start at the
    equilibrium whose output is the measurement, the reference from the calculator's cold
    solve, u_bar repeated as the candidate; here with a set-point step, so the first
    problem may be infeasible) runs in one compiled call, with every record field, the
    warnings and the calculator's counts of the reference engine (which solves its cold
    restarts with the same compiled twin); the step after it takes the common step."""
    model = load_model("ph_lstm_n5.npz")
    config = MPCConfig(solver=solver, N=5)
    fast, fast_runs, fast_messages = _first_steps(model, config, limit, True)
    taken = dict(codes)
    general, general_runs, general_messages = _first_steps(model, config, limit, False)
    for fast_records, general_records in zip(fast_runs, general_runs, strict=True):
        assert fast_records[0].engine == "one-call" and fast_records[1].engine == "one-call"
        assert general_records[0].engine == "reference"
        worst, where = _worst(fast_records, general_records)
        assert worst <= TOLERANCE, where
    assert taken.get(compiled_step.STEP_DONE, 0) == 60
    assert fast_messages == general_messages
    assert fast.reference.counts == general.reference.counts
    assert fast.warning_counts == general.warning_counts


def test_a_first_step_the_one_call_declines_runs_on_the_reference_engine() -> None:
    """The first steps the compiled call hands back whole, with the reference engine's
    errors and warnings: a first measurement beyond the plausible range (refused, as is a
    non-finite one), one whose output no admissible equilibrium has (the observer starts
    at the closest and warns), and a first set-point no admissible equilibrium reaches
    (no last reference to keep)."""
    from ltv_lstm_mpc.exceptions import InvalidValueError, UnreachableSetpointError

    model = load_model("ph_lstm_n5.npz")
    config = MPCConfig(solver="daqp", N=5)
    norm = model.normalization
    assert norm is not None
    width = float(norm.y_phi_max[0] - norm.y_phi_min[0])
    for bad in (float(norm.y_phi_max[0]) + 2.5 * width, float("nan")):
        messages = []
        for one_call in (True, False):
            controller = OffsetFreeController(
                model, config, kernels="compiled", one_call_step=one_call
            )
            with pytest.raises((InvalidValueError, ValueError)) as error:
                controller.step(bad, 7.0)
            messages.append(str(error.value))
        assert messages[0] == messages[1]
    controller = OffsetFreeController(model, config, kernels="compiled")
    low, high = controller.reference.reachable_output_range
    beyond = float(model.denormalize_y(np.array([float(high[0]) + 0.3]))[0])
    inside = float(model.denormalize_y(np.array([0.5 * float(low[0] + high[0])]))[0])
    results = []  # the measurement's equilibrium needs u outside U: a warning, then the step
    for one_call in (True, False):
        controller = OffsetFreeController(model, config, kernels="compiled", one_call_step=one_call)
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            u = controller.step(beyond, inside)
        results.append((u, [str(w.message) for w in caught], controller.records[0]))
    (u_fast, fast_messages, fast_record), (u_general, general_messages, general_record) = results
    assert fast_record.engine == "reference"
    assert fast_messages == general_messages
    assert any("LSTM equilibrium with output" in message for message in fast_messages)
    np.testing.assert_array_equal(u_fast, u_general)
    worst, where = _worst([fast_record], [general_record])
    assert worst <= TOLERANCE, where
    unreachable = float(model.denormalize_y(np.array([float(high[0]) + 0.5]))[0])
    messages = []  # a first set-point without an admissible equilibrium: no reference to keep
    for one_call in (True, False):
        controller = OffsetFreeController(model, config, kernels="compiled", one_call_step=one_call)
        with pytest.raises(UnreachableSetpointError) as error:
            controller.step(inside, unreachable)
        messages.append(str(error.value))
    assert messages[0] == messages[1]


def test_a_first_step_whose_feedback_declines_is_not_solved_twice(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """A first step whose one-call feedback declines the point (here: an acceptance
    tolerance no point passes) goes to the reference engine with the feedback declined,
    which then runs the general feedback only (the one-call feedback is not run again),
    as for any later step; the record is the reference engine's."""
    from ltv_lstm_mpc.mpc import condensed, rti

    monkeypatch.setattr(condensed, "feasibility_tolerance", lambda *arguments: -1.0)
    calls: Counter[bool] = Counter()
    native = rti.RobustMPC._feedback_native

    def counted(self: Any, *arguments: Any) -> Any:
        calls[self is controller.mpc] += 1
        return native(self, *arguments)

    monkeypatch.setattr(rti.RobustMPC, "_feedback_native", counted)
    model = load_model("ph_lstm_n5.npz")
    records = []
    for one_call in (True, False):
        controller = OffsetFreeController(
            model, MPCConfig(solver="daqp", N=5), kernels="compiled", one_call_step=one_call
        )
        calls.clear()
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            controller.step(7.0, 7.1)
        assert controller.records[0].engine == "reference"
        assert calls[True] == (0 if one_call else 1), (one_call, calls)
        records.append(controller.records[0])
    assert records[0].mpc.policy != "nominal"
    worst, where = _worst(records[:1], records[1:])
    assert worst <= TOLERANCE, where


def daqp_native_no_bound() -> float:
    from ltv_lstm_mpc.solvers.daqp_native import NO_BOUND

    return NO_BOUND


@pytest.mark.parametrize("own", [None, 50.0])
def test_the_objective_bound_is_the_same_on_both_engines(own: float | None) -> None:
    """Bench's scenario 3 (infeasible steps) with daqp at N = 20: DAQP's objective bound
    (solvers.daqp_.objective_bound), the smaller of it and the settings' own fval_bound
    where they name one, gives both engines the same records (DAQP's iterations included)."""
    from ltv_lstm_mpc.solver_comparison.harness import bench_scenarios

    model = load_model("ph_lstm_n5.npz")
    scenario = bench_scenarios(model)[2]
    settings = {} if own is None else {"fval_bound": own}
    config = replace(scenario.config, solver="daqp", N=20, solver_settings=settings)
    fast = _loop(model, config, scenario, True, 200)
    general = _loop(model, config, scenario, False, 200)
    worst, where = _worst(fast.records, general.records)
    assert worst <= TOLERANCE, where
    assert any(not r.mpc.feasible for r in fast.records)
    # the bound is given on the loop's QPs, and the settings' own is the smaller
    from ltv_lstm_mpc.solvers import daqp_

    problem = general.mpc._problem  # (its last condensed QP)
    bound = daqp_.objective_bound(
        problem._H, problem._f, problem._lb, problem._ub, problem.hessian_floor, 1e-8
    )
    assert bound < daqp_native_no_bound()
    assert own is None or own < bound
