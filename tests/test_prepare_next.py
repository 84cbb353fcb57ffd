"""Preparing the next step between samples (``OffsetFreeController.prepare_next``).

A prepared step runs only the feedback of the subproblem prepared after the previous step
(loop/compiled_step.py: ``prepare_step`` then ``feedback_step``); its numbers must be those
of the unprepared one-call step bit for bit, and a preparation the step cannot use (another
set-point, a reset, a new estimate, a refused measurement) must leave no trace.
"""

from __future__ import annotations

from collections import Counter
from dataclasses import replace
from typing import Any

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from ltv_lstm_mpc.solvers import available_solvers, daqp_native
from test_one_call_step import _worst

from ltv_lstm_mpc import MPCConfig, OffsetFreeController, simulate
from ltv_lstm_mpc.exceptions import ArgumentTypeError, DimensionError, InvalidValueError
from ltv_lstm_mpc.loop import compiled_step
from ltv_lstm_mpc.loop.engines import OneCallEngine
from ltv_lstm_mpc.lstm.shipped import load_model

pytestmark = pytest.mark.skipif(
    daqp_native.native({}) is None,  # binds and self-tests (compiles on an empty cache)
    reason=f"DAQP not bound natively: {daqp_native.unavailable_reason}",
)

SOLVERS = ["daqp"] + (["daqp:socp"] if "daqp:socp" in available_solvers() else [])


@pytest.fixture
def feedback_codes(monkeypatch: pytest.MonkeyPatch) -> Counter[int]:
    """Counts of the prepared steps' return codes (``feedback_step`` and
    ``feedback_step_from_rows``)."""
    counts: Counter[int] = Counter()
    original = OneCallEngine._compiled
    names = ("feedback_step", "feedback_step_from_rows")

    def counting(self: Any, name: str, fast: bool, arguments: Any) -> Any:
        answer = original(self, name, fast, arguments)
        if name in names:
            counts[answer[0]] += 1
        return answer

    # at the controller's call, not by replacing the compiled functions (the "_from_rows"
    # ones call them from compiled code: a Python stand-in cannot be compiled into them)
    monkeypatch.setattr(OneCallEngine, "_compiled", counting)
    return counts


def _controller(model: Any, config: MPCConfig, scenario: Any, **options: Any) -> Any:
    return OffsetFreeController(
        model,
        config,
        setpoint_rate_limit=scenario.setpoint_rate_limit,
        kernels="compiled",
        **options,
    )


def _loop(
    model: Any, config: MPCConfig, scenario: Any, steps: int, prepare: Any = None
) -> tuple[Any, list[bool]]:
    """A closed loop on the scenario's plant; ``prepare(k)``: after step k, the set-point
    to prepare step k + 1 for (None: do not prepare; "last": ``prepare_next()``)."""
    controller = _controller(model, config, scenario)
    plant = scenario.make_plant(model)
    y = plant.output()
    prepared = []
    for k in range(steps):
        u = controller.step(y, scenario.setpoints[k])
        d = scenario.disturbances[k]
        y = plant.step(u, None if np.isnan(d) else d)
        if prepare is not None and k + 1 < steps:
            setpoint = prepare(k)
            if setpoint is not None:
                answer = controller.prepare_next(None if setpoint == "last" else setpoint)
                prepared.append(answer)
    return controller, prepared


@pytest.mark.parametrize("solver", SOLVERS)
@pytest.mark.parametrize(("index", "N"), [(0, 5), (0, 20), (2, 5)])
def test_prepared_steps_equal_the_one_call_step(
    index: int, N: int, solver: str, feedback_codes: Counter[int]
) -> None:
    """300 steps of bench scenarios 1 and 3 prepared with the next set-point: the same
    records bit for bit; in scenario 1 every step after the first two runs prepared, in
    scenario 3 (infeasible steps) the prepared feedback runs the policy too."""
    from ltv_lstm_mpc.solver_comparison.harness import bench_scenarios

    model = load_model("ph_lstm_n5.npz")
    scenario = bench_scenarios(model)[index]
    config = replace(scenario.config, solver=solver, N=N)
    steps = min(len(scenario.setpoints), 300)
    reference, _ = _loop(model, config, scenario, steps)
    assert not feedback_codes
    prepared, answers = _loop(
        model, config, scenario, steps, prepare=lambda k: scenario.setpoints[k + 1]
    )
    worst, where = _worst(prepared.records, reference.records)
    assert worst == 0.0, where
    assert prepared.warning_counts == reference.warning_counts
    assert prepared.e_hat == reference.e_hat
    np.testing.assert_array_equal(prepared.observer.x_hat, reference.observer.x_hat)
    done = feedback_codes[compiled_step.STEP_DONE]
    if index == 0:
        assert all(answers) and done == steps - 1
    else:  # the infeasibility policy runs in the prepared feedback too
        assert feedback_codes[compiled_step.STEP_FEEDBACK] == 0
        assert any(not r.mpc.feasible and r.engine == "one-call" for r in prepared.records)
        assert done >= 200 and sum(answers) >= done


def test_a_preparation_for_another_setpoint_is_put_aside(feedback_codes: Counter[int]) -> None:
    """Every fifth step prepared for a set-point 0.05 pH off, the others with
    ``prepare_next()`` (the last set-point: wrong where the schedule moves): those steps
    run as unprepared ones, and the loop is the same bit for bit (the chord's inverse
    Jacobian, which a preparation may refactor, is put back)."""
    from ltv_lstm_mpc.solver_comparison.harness import bench_scenarios

    model = load_model("ph_lstm_n5.npz")
    scenario = bench_scenarios(model)[0]
    config = replace(scenario.config, solver="daqp", N=5)
    steps = 300
    reference, _ = _loop(model, config, scenario, steps)

    def setpoint(k: int) -> Any:
        return scenario.setpoints[k + 1] + 0.05 if k % 5 == 0 else "last"

    prepared, _ = _loop(model, config, scenario, steps, prepare=setpoint)
    worst, where = _worst(prepared.records, reference.records)
    assert worst == 0.0, where
    assert reference.reference.counts == prepared.reference.counts
    used = feedback_codes[compiled_step.STEP_DONE]
    moves = sum(
        not np.array_equal(scenario.setpoints[k], scenario.setpoints[k + 1])
        for k in range(steps - 1)
    )
    assert moves > 0 and 0 < used <= steps - 1 - (steps - 1) // 5 - 1
    assert used >= steps - 1 - (steps + 4) // 5 - moves


def test_simulate_prepares_between_samples_on_the_quadruple_tank(
    feedback_codes: Counter[int],
) -> None:
    """(2, 2): ``simulate(..., prepare_between_samples=True)`` gives the same inputs and
    records; the prepared steps' own time excludes the preparation."""
    from ltv_lstm_mpc.benchmarks.quadtank import QUADTANK_MODEL, quadtank_scenarios

    model = load_model(QUADTANK_MODEL)
    scenario = quadtank_scenarios(short=True)[0]
    steps = min(scenario.steps, 200)
    runs = []
    config = replace(scenario.config, solver="daqp")
    for prepare in (False, True):
        controller = _controller(model, config, scenario)
        result = simulate(
            scenario.make_plant(model), controller, scenario.setpoints[:steps],
            scenario.leaks[:steps], steps, progress=False, prepare_between_samples=prepare,
        )  # fmt: skip
        runs.append((controller, result))
    (plain, plain_result), (prepared, prepared_result) = runs
    assert feedback_codes[compiled_step.STEP_DONE] == steps - 1
    np.testing.assert_array_equal(prepared_result.u_phi, plain_result.u_phi)
    np.testing.assert_array_equal(prepared_result.x_hat, plain_result.x_hat)
    worst, where = _worst(prepared.records, plain.records)
    assert worst == 0.0, where
    with pytest.raises(ArgumentTypeError, match="prepare_between_samples"):
        simulate(
            scenario.make_plant(model), prepared, scenario.setpoints[:5], None, 5,
            progress=False, prepare_between_samples="yes",  # type: ignore[arg-type]
        )  # fmt: skip


def test_prepare_next_where_it_does_not_apply_and_bad_setpoints() -> None:
    """False before the first step and where the one-call step does not apply (the
    general path prepares inside the step); set-points checked like ``step``'s."""
    model = load_model("ph_lstm_n5.npz")
    config = MPCConfig(solver="daqp", N=5)
    controller = OffsetFreeController(model, config, kernels="compiled")
    assert controller.prepare_next(7.0) is False  # nothing to prepare from yet
    controller.step(7.0, 7.0)
    controller.step(7.0, 7.2)
    assert controller.prepare_next() is True
    with pytest.raises(InvalidValueError, match="NaN"):
        controller.prepare_next(float("nan"))
    with pytest.raises(InvalidValueError, match="y0_phi"):
        controller.prepare_next("7.0")  # type: ignore[arg-type]
    with pytest.raises(DimensionError, match="y0_phi"):
        controller.prepare_next([7.0, 7.1])
    general = OffsetFreeController(model, config, kernels="compiled", one_call_step=False)
    general.step(7.0, 7.0)
    assert general.prepare_next(7.0) is False


def _pair(config: MPCConfig | None = None, **options: Any) -> tuple[Any, Any]:
    model = load_model("ph_lstm_n5.npz")
    config = config or MPCConfig(solver="daqp", N=5)
    pair = [OffsetFreeController(model, config, kernels="compiled", **options) for _ in range(2)]
    for controller in pair:
        y = 7.0
        for setpoint in (7.0, 7.1, 7.2, 7.3):
            u = controller.step(y, setpoint)
            y = 7.0 + 0.3 * float(u[0] > 0.5)
    return pair[0], pair[1]


def test_a_refused_measurement_after_a_preparation_leaves_no_trace() -> None:
    """NaN (refused) and implausible (raised on request) measurements after a preparation:
    the errors of an unprepared step, nothing updated, and the next steps the same as a
    controller's that never prepared."""
    prepared, plain = _pair(implausible_measurements="raise")
    length = len(prepared.records)
    x_hat = prepared.observer.x_hat.copy()
    for bad, error in ((np.nan, "NaN"), (100.0, r"implausible|range width")):
        assert prepared.prepare_next(7.3) is True
        with pytest.raises(InvalidValueError, match=error):
            prepared.step(np.array([bad]), 7.3)
        assert len(prepared.records) == length
        np.testing.assert_array_equal(prepared.observer.x_hat, x_hat)
    for y in (7.05, 7.1, 7.2):
        assert prepared.prepare_next(7.3) is True
        np.testing.assert_array_equal(prepared.step(y, 7.3), plain.step(y, 7.3))
    worst, where = _worst(prepared.records, plain.records)
    assert worst == 0.0, where


def test_an_implausible_measurement_flagged_after_a_preparation() -> None:
    """With ``implausible_measurements="flag"`` the general path takes an implausible
    measurement (the prepared feedback declines it): the same input and records."""
    prepared, plain = _pair()
    assert prepared.prepare_next(7.3) is True
    with pytest.warns(RuntimeWarning, match="implausible|range width"):
        u_prepared = prepared.step(12.0, 7.3)
    with pytest.warns(RuntimeWarning, match="implausible|range width"):
        u_plain = plain.step(12.0, 7.3)
    np.testing.assert_array_equal(u_prepared, u_plain)
    assert prepared.records[-1].measurement_status == "implausible"
    worst, where = _worst(prepared.records, plain.records)
    assert worst == 0.0, where


def test_a_reset_or_a_new_estimate_puts_the_preparation_aside() -> None:
    """``reset`` after a preparation: the next step initializes as after any reset; an
    estimate assigned after a preparation: the step uses it (as an unprepared step
    would), not the prepared subproblem."""
    prepared, plain = _pair()
    assert prepared.prepare_next(7.3) is True
    x_hat = prepared.observer.x_hat + 0.01
    prepared.observer.x_hat = x_hat
    plain.observer.x_hat = x_hat.copy()
    np.testing.assert_array_equal(prepared.step(7.1, 7.3), plain.step(7.1, 7.3))
    worst, where = _worst(prepared.records, plain.records)
    assert worst == 0.0, where
    assert prepared.prepare_next(7.3) is True
    prepared.reset()
    plain.reset()
    for y in (7.0, 7.05):
        np.testing.assert_array_equal(prepared.step(y, 7.3), plain.step(y, 7.3))
    worst, where = _worst(prepared.records, plain.records)
    assert worst == 0.0, where


def test_a_setting_changed_after_a_preparation_puts_it_aside() -> None:
    """The reference calculator's tolerance changed between ``prepare_next`` and ``step``:
    the controller rebuilds its one-call workspace, puts the preparation aside (the chord's
    inverse Jacobian as before it) and the steps are those of a controller that never
    prepared, with the same change."""
    prepared, plain = _pair()
    for y in (7.05, 7.1):
        assert prepared.prepare_next(7.3) is True
        np.testing.assert_array_equal(prepared.step(y, 7.3), plain.step(y, 7.3))
    assert prepared.prepare_next(7.3) is True
    for controller in (prepared, plain):
        controller.reference.tol = 1e-11
    for y in (7.12, 7.15, 7.2):
        np.testing.assert_array_equal(prepared.step(y, 7.3), plain.step(y, 7.3))
        assert prepared.prepare_next(7.3) is True
    worst, where = _worst(prepared.records, plain.records)
    assert worst == 0.0, where
    assert prepared.reference.counts == plain.reference.counts


@settings(max_examples=15)
@given(
    operations=st.lists(
        st.tuples(
            st.sampled_from(["step", "prepare next", "prepare wrong", "prepare last", "reset"]),
            st.sampled_from([6.9, 7.0, 7.2, 7.4]),
        ),
        min_size=5,
        max_size=25,
    )
)
def test_any_sequence_of_steps_and_preparations_matches_a_controller_that_never_prepares(
    operations: list[tuple[str, float]],
) -> None:
    """Random interleavings of steps (random set-points), preparations for the next step's
    set-point, a wrong one or the last one, and resets: every input and record equals
    those of a controller that only steps (same steps, same resets), and a preparation
    for the next step's set-point, followed by that step, is used by it."""
    prepared, plain, feedbacks = _cached_pair()
    prepared.reset()
    plain.reset()
    y, last = 7.0, None
    expect_used = False
    for index, (operation, setpoint) in enumerate(operations):
        if operation == "step":
            before = feedbacks[0]
            u = prepared.step(y, setpoint)
            np.testing.assert_array_equal(u, plain.step(y, setpoint))
            assert feedbacks[0] == before + (1 if expect_used else 0)
            y, last = 0.5 * (y + setpoint), setpoint  # a plausible measurement
            expect_used = False
        elif operation == "reset":
            prepared.reset()
            plain.reset()
            y, last, expect_used = 7.0, None, False
        else:
            following = [s for o, s in operations[index + 1 :] if o == "step"]
            if operation == "prepare last":
                for_setpoint = last
                answer = prepared.prepare_next()
            else:
                if operation == "prepare next" and following:
                    for_setpoint = following[0]
                else:
                    for_setpoint = setpoint + 0.05
                answer = prepared.prepare_next(for_setpoint)
            next_is_step = index + 1 < len(operations) and operations[index + 1][0] == "step"
            expect_used = answer and next_is_step and for_setpoint == following[0]
    worst, where = _worst(prepared.records, plain.records)
    assert worst == 0.0, where
    assert prepared.e_hat == plain.e_hat


_PAIR: list[Any] = []


def _cached_pair() -> tuple[Any, Any, list[int]]:
    """Two controllers built once for the property test (reset by it), and the count of
    the first one's prepared feedback calls."""
    if not _PAIR:
        model = load_model("ph_lstm_n5.npz")
        config = MPCConfig(solver="daqp", N=5)
        pair = [
            OffsetFreeController(model, config, kernels="compiled", setpoint_rate_limit=0.05)
            for _ in range(2)
        ]
        feedbacks = [0]
        compiled = pair[0].engine._compiled

        def counting(name: str, fast: bool, arguments: Any) -> Any:
            if name.startswith("feedback_step"):
                feedbacks[0] += 1
            return compiled(name, fast, arguments)

        pair[0].engine._compiled = counting  # type: ignore[method-assign]
        _PAIR.extend([*pair, feedbacks])
    return _PAIR[0], _PAIR[1], _PAIR[2]
