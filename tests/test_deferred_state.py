"""State a one-call step leaves deferred in its record row (ltv_lstm_mpc.deferred_state).

The mechanism on its own (reads and assignments settle every owner first, copies and
pickles see the values), and on the controller: whatever the caller reads or assigns
between steps, the steps equal those of a controller whose state is written into its
owners after every step, and the state read equals the general path's.
"""

from __future__ import annotations

import copy
import pickle
from typing import Any

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from ltv_lstm_mpc.solvers import daqp_native

from ltv_lstm_mpc import MPCConfig, OffsetFreeController
from ltv_lstm_mpc.deferred_state import Deferred, DeferredState, defer, settle
from ltv_lstm_mpc.lstm.shipped import load_model

pytestmark = pytest.mark.skipif(
    daqp_native.native({}) is None, reason="DAQP cannot be bound natively here"
)


class _Owner(DeferredState):
    value = Deferred[float]()
    other = Deferred[float]()

    def __init__(self) -> None:
        self.value = 0.0
        self.other = 0.0
        self.plain = "plain"


def _deferred_pair(rows: dict[str, float]) -> tuple[_Owner, _Owner, list[int]]:
    """Two owners whose values wait in ``rows`` (the settle function is counted)."""
    first, second = _Owner(), _Owner()
    calls = [0]

    def pending() -> None:
        calls[0] += 1
        settle(first, {"value": rows["first"], "other": rows["first"] + 1})
        settle(second, {"value": rows["second"], "other": rows["second"] + 1})

    defer(first, pending)
    defer(second, pending)
    return first, second, calls


def test_a_read_settles_every_owner_once() -> None:
    first, second, calls = _deferred_pair({"first": 1.0, "second": 2.0})
    assert first.plain == "plain" and calls[0] == 0  # plain attributes do not settle
    assert second.value == 2.0
    assert calls[0] == 1
    assert (first.value, first.other, second.other) == (1.0, 2.0, 3.0)
    assert calls[0] == 1
    assert first._pending is None and second._pending is None


def test_an_assignment_settles_first_and_keeps_the_assigned_value() -> None:
    first, second, calls = _deferred_pair({"first": 1.0, "second": 2.0})
    first.value = 5.0
    assert calls[0] == 1
    assert (first.value, first.other, second.value) == (5.0, 2.0, 2.0)


def test_copies_and_pickles_see_the_deferred_values() -> None:
    for duplicate in (copy.copy, copy.deepcopy, lambda o: pickle.loads(pickle.dumps(o))):
        first, _, calls = _deferred_pair({"first": 1.0, "second": 2.0})
        twin = duplicate(first)
        assert calls[0] == 1
        assert (twin.value, twin.other) == (1.0, 2.0)
        assert twin._pending is None


def test_an_unset_deferred_attribute_is_an_attribute_error() -> None:
    owner = DeferredState.__new__(_Owner)
    with pytest.raises(AttributeError, match="'_Owner' object has no attribute 'value'"):
        _ = owner.value
    assert not hasattr(owner, "other")
    assert isinstance(_Owner.value, Deferred)


# ------------------------------------------------------------------ on the controller
def _controllers(**options: Any) -> list[OffsetFreeController]:
    model = load_model("ph_lstm_n5.npz")
    config = MPCConfig(solver="daqp", N=5)
    return [OffsetFreeController(model, config, kernels="compiled", **options) for _ in range(2)]


def _written(controller: OffsetFreeController) -> tuple[Any, ...]:
    """Read every deferred attribute (so the controller settles after the step)."""
    mpc: Any = controller.mpc
    reference: Any = controller.reference
    return (
        controller.observer.x_hat, controller.observer.d_hat, reference._last_z,
        reference._last_target, reference._Jinv, mpc._previous_u, mpc.solver_time,
        mpc.prepare_time, mpc.feedback_time, mpc.qp_iterations, controller.y0_last,
    )  # fmt: skip


def test_the_state_left_deferred_is_the_general_paths() -> None:
    """After one-call steps the observer's estimates, the reference calculator's warm start
    and the MPC's plan read as the general path's (1e-12), and the MPC's times and
    iterations as the last record's; the steps ran from the deferred state."""
    model = load_model("ph_lstm_n5.npz")
    config = MPCConfig(solver="daqp", N=5)
    one_call = OffsetFreeController(model, config, kernels="compiled", setpoint_rate_limit=0.05)
    general = OffsetFreeController(
        model, config, kernels="compiled", setpoint_rate_limit=0.05, one_call_step=False
    )
    y = 7.0
    for setpoint in (7.0, 7.1, 7.2, 7.3, 7.3, 7.3):
        u = one_call.step(y, setpoint)
        np.testing.assert_allclose(u, general.step(y, setpoint), rtol=0, atol=1e-10)
        y = 0.5 * (y + setpoint)
    assert one_call.engine.deferred is not None  # deferred since the first one-call step
    assert one_call.engine.deferred.k == len(one_call.records) - 1
    mpc: Any = one_call.mpc
    for name in ("x_hat", "d_hat"):
        np.testing.assert_allclose(
            getattr(one_call.observer, name), getattr(general.observer, name), atol=1e-12
        )
    assert one_call.engine.deferred is None  # the read wrote it into the owners
    reference: Any = one_call.reference
    np.testing.assert_allclose(reference._last_z, general.reference._last_z, atol=1e-12)
    np.testing.assert_allclose(mpc._previous_u, general.mpc._previous_u, atol=1e-12)  # type: ignore[attr-defined]
    np.testing.assert_allclose(one_call.y0_last, general.y0_last, atol=1e-12)
    last = one_call.records[-1]
    assert mpc.solver_time == last.mpc.solver_time
    assert (mpc.prepare_time, mpc.feedback_time) == (
        last.mpc.prepare_time,
        last.mpc.feedback_time,
    )
    assert mpc.qp_iterations == last.mpc.solver_iterations
    assert one_call.reference.counts["factorizations"] >= 1


def test_an_estimate_assigned_while_deferred_is_the_one_the_next_step_uses() -> None:
    """``observer.x_hat = ...`` right after a one-call step (no read before): the next
    step starts from it, as a controller that wrote its state after every step does."""
    deferring, eager = _controllers()
    y = 7.0
    for setpoint in (7.0, 7.1, 7.2):
        for controller in (deferring, eager):
            controller.step(y, setpoint)
        _written(eager)
        y += 0.05
    assert deferring.engine.deferred is not None
    x_hat = eager.observer.x_hat + 0.01
    deferring.observer.x_hat = x_hat.copy()
    eager.observer.x_hat = x_hat.copy()
    np.testing.assert_array_equal(deferring.observer.x_hat, x_hat)
    np.testing.assert_array_equal(deferring.step(7.15, 7.2), eager.step(7.15, 7.2))
    np.testing.assert_array_equal(deferring.records[-1].x_hat, x_hat)


def test_a_setting_assigned_while_deferred_is_the_one_the_next_step_uses() -> None:
    """The reference calculator's tolerance assigned right after a one-call step: the next
    steps use it (a new one-call workspace), as the general path does with the same
    assignment (a loose tolerance stops the chord earlier: other equilibria)."""
    model = load_model("ph_lstm_n5.npz")
    config = MPCConfig(solver="daqp", N=5)
    one_call = OffsetFreeController(model, config, kernels="compiled")
    general = OffsetFreeController(model, config, kernels="compiled", one_call_step=False)
    y = 7.0
    for setpoint in (7.0, 7.1, 7.2):
        for controller in (one_call, general):
            controller.step(y, setpoint)
        y += 0.05
    assert one_call.engine.deferred is not None
    workspace = one_call.engine.workspace
    for controller in (one_call, general):
        controller.reference.tol = 1e-3
    for setpoint in (7.22, 7.24):  # small moves: the warm chord, in the one-call step
        u = one_call.step(y, setpoint)
        np.testing.assert_allclose(u, general.step(y, setpoint), rtol=0, atol=1e-10)
        y += 0.05
    assert one_call.engine.workspace is not workspace
    assert one_call.records[-1].mpc.feedback_time > 0  # one-call records
    for mine, theirs in zip(one_call.records, general.records, strict=True):
        np.testing.assert_allclose(mine.x_bar, theirs.x_bar, rtol=0, atol=1e-10)


_ACTIONS = ["step", "prepare", "read", "assign x_hat", "assign d_hat", "assign e_hat", "reset"]
_PAIR: list[OffsetFreeController] = []


@settings(max_examples=15, deadline=None)
@given(
    actions=st.lists(
        st.tuples(st.sampled_from(_ACTIONS), st.sampled_from([6.9, 7.0, 7.2, 7.4])),
        min_size=5,
        max_size=25,
    )
)
def test_any_sequence_of_reads_and_assignments_matches_a_controller_that_writes_its_state(
    actions: list[tuple[str, float]],
) -> None:
    """Random interleavings of steps, preparations, reads of the state, assignments of
    estimates and of e_hat, and resets: every input and record of a controller that
    leaves its state deferred equals those of one that writes it after every step (bit
    for bit), and the values read are the same."""
    if not _PAIR:
        _PAIR.extend(_controllers(setpoint_rate_limit=0.05))
    deferring, eager = _PAIR
    for controller in _PAIR:
        controller.reset()
    y = 7.0
    for action, value in actions:
        if action == "step":
            u = deferring.step(y, value)
            np.testing.assert_array_equal(u, eager.step(y, value))
            _written(eager)
            y = 0.5 * (y + value)
        elif action == "prepare":
            deferring.prepare_next(value)
            eager.prepare_next(value)
            _written(eager)
        elif action == "read":
            mine, theirs = _written(deferring), _written(eager)
            for index in (0, 1, 2, 3, 4, 5, 9, 10):  # not the times (6, 7, 8): wall times
                read, expected = mine[index], theirs[index]
                if read is None or expected is None:
                    assert read is expected
                else:
                    np.testing.assert_array_equal(read, expected)
        elif action == "reset":
            for controller in _PAIR:
                controller.reset()
            y = 7.0
        elif action == "assign e_hat":
            for controller in _PAIR:
                controller.e_hat = 0.5 * value / 7.0
        else:
            name = action.removeprefix("assign ")
            for controller in _PAIR:
                shifted = getattr(controller.observer, name) + 1e-3 * (value - 7.0)
                setattr(controller.observer, name, shifted)
    assert len(deferring.records) == len(eager.records)
    for mine, theirs in zip(deferring.records, eager.records, strict=True):
        for name in ("y", "y0", "u", "u_phi", "x_hat", "d_hat", "x_bar", "u_bar"):
            np.testing.assert_array_equal(getattr(mine, name), getattr(theirs, name))
        assert mine.e_hat == theirs.e_hat
        assert mine.mpc.cost == theirs.mpc.cost
