"""The run-time monitor of Theorem 3's hypotheses (loop/monitor.py).

Each hypothesis is driven out of its bound and must be flagged (and only it); the
induction (held / voided / infeasible start) follows the monitor's definition; the
closed loop carries the verdict in every record and the simulation counts violations
separately where the guarantee held.
"""

from __future__ import annotations

import warnings
from dataclasses import replace

import numpy as np
import pytest

from ltv_lstm_mpc import MPCConfig, OffsetFreeController, certify, load_model, simulate
from ltv_lstm_mpc.loop.monitor import HYPOTHESES, AssumptionLog, AssumptionMonitor
from ltv_lstm_mpc.plants import LSTMPlant


@pytest.fixture(scope="module")
def model():
    return load_model("ph_lstm_n5.npz")


@pytest.fixture(scope="module")
def certification(model):
    return certify(model, MPCConfig().certification_settings(model))


@pytest.fixture
def monitor(model, certification):
    return AssumptionMonitor(model, certification)


def _nominal(model, certification):
    """A step at which every hypothesis holds: an equilibrium estimate measured exactly."""
    x_hat = model.equilibrium(np.array([0.1]))
    d_hat = np.array([0.02])
    y = model.W_y @ x_hat[model.n :] + model.b_y + d_hat  # y - y_hat = 0
    return {
        "y": y,
        "x_hat": x_hat,
        "d_hat": d_hat,
        "y0": np.array([0.1]),
        "e_hat": certification.tightening.e_inf,
        "setpoint_status": "ok",
        "feasible": True,
    }


def test_nominal_steps_hold(model, certification, monitor) -> None:
    step = _nominal(model, certification)
    for _ in range(3):
        check = monitor.check(**step)
        assert check.held and check.guarantee == "held" and check.failed() == []


def _flagged(monitor, first, second) -> list[str]:
    monitor.check(**first)
    check = monitor.check(**second)
    assert not check.held
    assert check.guarantee == "voided by " + ", ".join(check.failed())
    return check.failed()


def test_each_hypothesis_out_of_its_bound_is_flagged(model, certification, monitor) -> None:
    step = _nominal(model, certification)
    ob, rate = certification.observer, certification.rate_bound
    assert rate.holds  # the shipped model's defaults: the rate bound exists
    cases = {
        "d_in_bound": {"d_hat": np.array([ob.d_max]), "y": step["y"] + ob.d_max - 0.02},
        "d_rate_in_bound": {
            "d_hat": step["d_hat"] + 2 * ob.w_max,
            "y": step["y"] + 2 * ob.w_max,
        },
        "setpoint_rate_in_bound": {"y0": step["y0"] + 2 * rate.delta_y0_max},
        # above e_y_bar, below c_o e_inf (0.0386 > e_y_bar = 0.03 for this model)
        "output_error_in_bound": {"y": step["y"] + 1.1 * rate.e_y_bar},
        # below e_y_bar, above c_o e_hat: only the observer-error bound is contradicted
        "observer_error_consistent": {
            "y": step["y"] + 0.5 * rate.e_y_bar,
            "e_hat": 0.25 * rate.e_y_bar / float(ob.c_o[0]),
        },
        "setpoint_admissible": {"setpoint_status": "outside_admissible"},
    }
    assert 1.1 * rate.e_y_bar < float(ob.c_o[0]) * step["e_hat"]
    assert set(cases) == set(HYPOTHESES)
    for name, change in cases.items():
        monitor.reset()
        second = {**step, **change}
        if name == "d_in_bound":  # only the level: start from the same d_hat
            first = {**second}
        else:
            first = step
        if name == "observer_error_consistent":
            first = {**step, "e_hat": second["e_hat"]}
        assert _flagged(monitor, first, second) == [name], name


def test_within_bounds_is_not_flagged(model, certification, monitor) -> None:
    step = _nominal(model, certification)
    ob, rate = certification.observer, certification.rate_bound
    monitor.check(**step)
    inside = {
        **step,
        "d_hat": step["d_hat"] + 0.5 * ob.w_max,
        "y": step["y"] + 0.5 * ob.w_max,
        "y0": step["y0"] + 0.5 * rate.delta_y0_max,
        "setpoint_status": "target_outside_admissible",  # the set-point used is admissible
    }
    assert monitor.check(**inside).held


def test_induction_starts_at_a_feasible_step(model, certification, monitor) -> None:
    step = _nominal(model, certification)
    assert monitor.check(**{**step, "feasible": False}).guarantee == "voided by infeasible_start"
    assert monitor.check(**step).held  # a feasible FHOCP starts the induction
    # an infeasible FHOCP where the guarantee held: the record says so (the theorem excludes it)
    check = monitor.check(**{**step, "feasible": False})
    assert check.held and not check.fhocp_feasible
    assert not monitor.check(**{**step, "setpoint_status": "unreachable"}).held
    # the hypotheses hold again, but the induction needs a feasible start again
    assert monitor.check(**{**step, "feasible": False}).guarantee == "voided by infeasible_start"
    assert monitor.check(**step).held


def test_rate_bound_only_where_it_was_certified(model, certification, monitor) -> None:
    """The rate bound holds for set-points in its operating range and e_hat up to the one
    it was computed with: outside either, the set-point hypothesis is not established."""
    step = _nominal(model, certification)
    high = certification.rate_bound_y0_range[1]
    outside = {**step, "y0": np.array([float(high[0]) + 0.01])}
    assert monitor.check(**outside).failed() == ["setpoint_rate_in_bound"]
    monitor.reset()
    larger = {**step, "e_hat": 1.5 * certification.rate_bound.e_hat}
    assert monitor.check(**larger).failed() == ["setpoint_rate_in_bound"]
    monitor.reset()
    assert monitor.check(**step).held


def test_two_outputs_use_the_papers_norms() -> None:
    """With p = 2 (the quadruple tank): |Delta d_hat| is a 2-norm, as w in the paper, so two
    outputs each moving by 0.8 w_max (1.13 w_max together) void the guarantee, while d in
    D is the inf-norm ball."""
    model = load_model("quadtank_lstm_n8.npz")
    certification = certify(model, MPCConfig().certification_settings(model))
    monitor = AssumptionMonitor(model, certification)
    w_max = certification.observer.w_max
    low, high = certification.rate_bound_y0_range
    x_hat = model.equilibrium(np.array([0.1, 0.1]))
    d_hat = np.array([0.02, -0.02])
    y = model.W_y @ x_hat[model.n :] + model.b_y + d_hat
    step = {
        "y": y, "x_hat": x_hat, "d_hat": d_hat, "y0": 0.5 * (low + high),
        "e_hat": certification.tightening.e_inf, "setpoint_status": "ok", "feasible": True,
    }  # fmt: skip
    assert monitor.check(**step).held
    moved = d_hat + 0.8 * w_max
    check = monitor.check(**{**step, "d_hat": moved, "y": y + 0.8 * w_max})
    assert check.failed() == ["d_rate_in_bound"]
    monitor.reset()
    near = np.array([0.9, -0.9]) * certification.observer.d_max  # inside the inf-norm ball
    y_near = model.W_y @ x_hat[model.n :] + model.b_y + near
    assert monitor.check(**{**step, "d_hat": near, "y": y_near}).held


def test_void_rate_bound_voids_every_step(model, certification) -> None:
    void = replace(certification.rate_bound, holds=False, delta_y0_max=0.0)
    monitor = AssumptionMonitor(model, replace(certification, rate_bound=void))
    step = _nominal(model, certification)
    for _ in range(2):
        assert monitor.check(**step).failed() == ["setpoint_rate_in_bound"]


def test_d_margin(model, certification) -> None:
    monitor = AssumptionMonitor(model, certification, d_margin=0.5)
    step = _nominal(model, certification)
    d = 0.6 * certification.observer.d_max
    check = monitor.check(**{**step, "d_hat": np.array([d]), "y": step["y"] + d - 0.02})
    assert check.failed() == ["d_in_bound"]


def test_closed_loop_records_and_counts(model) -> None:
    """A disturbance step larger than d_max on the LSTM plant: d_hat saturates and the
    guarantee is voided there; every record carries the verdict, and the simulation's
    counts split the infeasible and violation steps by it."""
    config = MPCConfig(solver="daqp")
    controller = OffsetFreeController(model, config, kernels="numpy")
    plant = LSTMPlant(model, y0_phi=7.0)
    scale = float(model.normalization.y_scale[0])
    disturbance = np.r_[np.zeros(30), np.full(50, 0.3 * scale)]  # 0.3 > d_max = 0.1
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        sim = simulate(plant, controller, setpoints=7.0, disturbances=disturbance, steps=80)
    assert all(r.assumptions is not None for r in controller.records)
    assert sim.guarantee is not None and sim.hypotheses is not None
    assert set(sim.hypotheses) == set(HYPOTHESES)
    held = sim.guarantee_held
    assert held[:25].all()  # constant set-point, no disturbance yet
    assert not sim.hypotheses["d_in_bound"].all()  # the saturation is flagged
    saturated = sim.d_hat_saturated.any(axis=1)
    np.testing.assert_array_equal(~sim.hypotheses["d_in_bound"], saturated)
    assert not held[saturated].any()
    counts = sim.summary_counts()
    assert counts["guarantee_held_steps"] == int(held.sum())
    assert counts["d_in_bound_failed_steps"] == int(saturated.sum())
    assert counts["infeasible_steps_guarantee_held"] == int((~sim.feasible & held).sum())
    violated = sim.plant_violation > 1e-9
    assert counts["plant_violation_steps_guarantee_held"] == int((violated & held).sum())
    assert counts["plant_violation_steps_guarantee_voided"] == int((violated & ~held).sum())


def test_verdicts_are_computed_on_first_read_in_step_order(model) -> None:
    """The controller's step stores only the log and an index (nothing timed); reading a
    record's verdict checks the records before it first; reset starts a new log."""
    controller = OffsetFreeController(model, MPCConfig(solver="daqp"), kernels="numpy")
    plant = LSTMPlant(model, y0_phi=7.0)
    y = plant.output()
    for _ in range(6):
        y = plant.step(controller.step(y, 7.1), 0.0)
    log = controller.records[0].monitor_log
    assert log is not None and log._verdicts == []
    third = controller.records[2].assumptions
    assert len(log._verdicts) == 3 and third is log._verdicts[2]
    assert [v.guarantee for v in log.verdicts()] == ["held"] * 6
    controller.reset()
    assert controller.records == [] and controller.assumption_log is not log


def test_a_custom_mpc_with_its_own_certification_type_is_not_monitored(model) -> None:
    """A duck-typed MPC whose certification is not a Certification (the same attributes
    in another type): the loop runs, its records say None, the simulation counts nothing."""
    import types
    from dataclasses import fields

    from ltv_lstm_mpc import RobustMPC

    inner = RobustMPC(model, MPCConfig(solver="daqp"))
    real = inner.certification
    own = types.SimpleNamespace(**{f.name: getattr(real, f.name) for f in fields(real)})

    class Wrapped:
        certification = own
        tightening = inner.tightening

        def solve(self, *args, **kwargs):
            return inner.solve(*args, **kwargs)

        def reset(self) -> None:
            inner.reset()

    controller = OffsetFreeController(model, MPCConfig(solver="daqp"), mpc=Wrapped())
    assert controller.monitor is None
    sim = simulate(LSTMPlant(model, y0_phi=7.0), controller, setpoints=7.1, steps=5)
    assert all(r.assumptions is None for r in controller.records)
    assert sim.guarantee is None and sim.hypotheses is None
    assert "guarantee_held_steps" not in sim.summary_counts()
    assert sim.feasible.all()


def test_logs_of_two_runs_do_not_share_their_induction(model) -> None:
    """Reading an earlier run's records after a reset (and a new run) gives the verdicts
    that run has on its own; the new run's are not disturbed either."""
    controller = OffsetFreeController(model, MPCConfig(solver="daqp"), kernels="numpy")

    def run(jump: float) -> list:
        plant = LSTMPlant(model, y0_phi=7.0)
        y = plant.output()
        for k in range(8):
            y = plant.step(controller.step(y, 7.0 + (jump if k >= 4 else 0.0)), 0.0)
        return list(controller.records)

    first = run(0.3)  # a set-point jump at step 4: voided there
    controller.reset()
    second = run(0.0)
    second_verdicts = [r.assumptions.guarantee for r in second]
    first_verdicts = [r.assumptions.guarantee for r in first]  # read after the second run
    fresh = AssumptionLog(controller.monitor, first).verdicts()
    assert first_verdicts == [v.guarantee for v in fresh]
    assert second_verdicts == [
        v.guarantee for v in AssumptionLog(controller.monitor, second).verdicts()
    ]
    assert first_verdicts != second_verdicts
