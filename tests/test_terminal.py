"""The terminal set of eq. (optimization) in its forms (mpc/terminal.py): they agree, and the
QP box reformulation (paper notes 4) is inside the set and over-bounds the cost."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st
from optional_extras import requires_solver

from ltv_lstm_mpc.exceptions import DimensionError, InvalidValueError
from ltv_lstm_mpc.mpc.terminal import TerminalSet, terminal_norm_of_squares


@st.composite
def terminal_sets(draw: st.DrawFn) -> TerminalSet:
    """An entrywise nonnegative, positive definite P_f and a state size n."""
    p11 = draw(st.floats(0.05, 50.0))
    p22 = draw(st.floats(0.05, 50.0))
    p12 = draw(st.floats(0.0, 0.95)) * math.sqrt(p11 * p22)
    n = draw(st.integers(1, 8))
    return TerminalSet(np.array([[p11, p12], [p12, p22]]), n)


def _point(terminal: TerminalSet, data: st.DataObject, scale: float) -> np.ndarray:
    entries = st.floats(-scale, scale, allow_nan=False)
    return np.array(data.draw(st.lists(entries, min_size=2 * terminal.n, max_size=2 * terminal.n)))


@given(terminal_sets(), st.data())
def test_every_form_of_the_norm_agrees(terminal: TerminalSet, data: st.DataObject) -> None:
    x_bar = _point(terminal, data, 1.0)
    x_N = x_bar + _point(terminal, data, 2.0)
    n = terminal.n
    t_c, t_h = np.linalg.norm(x_N[:n] - x_bar[:n]), np.linalg.norm(x_N[n:] - x_bar[n:])
    t = np.array([t_c, t_h])
    exact = math.sqrt(t @ terminal.P_f @ t)  # ||[t_c, t_h]||_{P_f}
    norm = terminal.norm(x_N, x_bar)
    assert norm == pytest.approx(exact, rel=1e-12, abs=1e-14)
    assert math.sqrt(terminal.level(t_c, t_h)) == pytest.approx(exact, rel=1e-12, abs=1e-14)
    compiled = terminal_norm_of_squares(t_c**2, t_h**2, np.array(terminal.terms))
    assert compiled == pytest.approx(norm, rel=1e-12, abs=1e-14)
    assert np.linalg.norm(terminal.square_root @ t) == pytest.approx(exact, rel=1e-12, abs=1e-14)


@given(terminal_sets(), st.floats(0.0, 5.0), st.data())
def test_the_box_lies_inside_the_terminal_set(
    terminal: TerminalSet, alpha: float, data: st.DataObject
) -> None:
    """paper notes 4: |x_N - x_bar| <= alpha * unit_half_widths entrywise implies
    x_N in X_f(k); the box's corner reaches the ellipse's boundary (largest such box)."""
    x_bar = _point(terminal, data, 1.0)
    half = alpha * terminal.unit_half_widths
    fractions = np.array(
        data.draw(st.lists(st.floats(-1.0, 1.0), min_size=half.size, max_size=half.size))
    )
    x_N = x_bar + fractions * half
    assert terminal.norm(x_N, x_bar) <= alpha * (1 + 1e-12) + 1e-15
    corner = x_bar + half
    assert terminal.norm(corner, x_bar) == pytest.approx(alpha, rel=1e-12, abs=1e-15)


@given(terminal_sets(), st.data())
def test_the_box_cost_bounds_the_terminal_cost(terminal: TerminalSet, data: st.DataObject) -> None:
    """paper notes 4: t'P_f t <= sum_j w_j (x_N,j - x_bar_j)^2 (the QP minimizes more)."""
    x_bar = _point(terminal, data, 1.0)
    x_N = x_bar + _point(terminal, data, 2.0)
    exact_cost = terminal.norm(x_N, x_bar) ** 2
    box_cost = float(terminal.box_weights @ (x_N - x_bar) ** 2)
    assert exact_cost <= box_cost * (1 + 1e-12) + 1e-15


def test_contains_and_bad_weights() -> None:
    terminal = TerminalSet(np.array([[2.0, 0.5], [0.5, 1.0]]), 2)
    x_bar = np.zeros(4)
    inside = np.array([0.1, 0.0, 0.1, 0.0])
    assert terminal.contains(inside, x_bar, 1.0)
    assert not terminal.contains(10 * inside, x_bar, 1.0)
    with pytest.raises(DimensionError, match=r"shape \(3, 3\)"):
        TerminalSet(np.eye(3), 2)
    with pytest.raises(InvalidValueError, match="entrywise nonnegative"):
        TerminalSet(np.array([[1.0, -0.1], [-0.1, 1.0]]), 2)


@requires_solver("piqp")
def test_the_soft_qp_box_grows_with_the_terminal_slack() -> None:
    """QP-only backends on the sparse transcription (PIQP): at the infeasible steps of bench
    scenario 3 the soft problem is solved (policy "soft", never "soft+shift": with the
    output slacks and the terminal level's slack s_T it is feasible by construction), and
    its terminal rows hold exactly where |x_N - x_bar| <= (max(alpha_k, 0) + s_T) w, w the
    half-widths of the box of level 1 (checked at random points). DAQP on the sparse soft
    QP gives the plans of DAQP on the condensed one (the same problem) at those steps."""
    from dataclasses import replace

    from ltv_lstm_mpc import OffsetFreeController, RobustMPC
    from ltv_lstm_mpc.lstm.shipped import load_model
    from ltv_lstm_mpc.solver_comparison.harness import bench_scenarios

    model = load_model("ph_lstm_n5.npz")
    scenario = bench_scenarios(model)[2]
    config = replace(
        scenario.config, N=5, solver="piqp", transcription="sparse", infeasibility_policy="soft"
    )
    controller = OffsetFreeController(
        model, config, setpoint_rate_limit=scenario.setpoint_rate_limit, kernels="compiled"
    )
    plant = scenario.make_plant(model)
    y = plant.output()
    soft_steps = []
    for k in range(150):
        u = controller.step(y, scenario.setpoints[k])
        d = scenario.disturbances[k]
        y = plant.step(u, None if np.isnan(d) else d)
        record = controller.records[-1]
        if record.mpc.policy == "soft":
            soft_steps.append((record.mpc.x[0], record.x_bar, record.u_bar, record.y0,
                               record.e_hat))  # fmt: skip
            if len(soft_steps) == 6:
                break
    policies = [r.mpc.policy for r in controller.records]
    assert len(soft_steps) == 6 and "soft+shift" not in policies
    subproblem = controller.mpc._problem.subproblem("soft")
    problem = controller.mpc.last_problem("soft")
    qp = subproblem.reformulation.apply(problem)
    n, N = model.n, config.N
    xN = subproblem.layout.x(N)
    level = max(problem.cones[2].f, 0.0)
    unit = np.repeat(np.asarray(subproblem.reformulation.unit_tau) / np.sqrt(n), n)
    centre = np.concatenate([-problem.cones[0].g, -problem.cones[1].g])
    box = slice(qp.G.shape[0] - 4 * n, qp.G.shape[0])
    rng = np.random.default_rng(0)
    agreed = 0
    for _ in range(400):
        z = np.zeros(qp.q.shape[0])
        z[xN] = centre + rng.normal(size=2 * n) * unit * (level + 1.0)
        z[-1] = rng.uniform(0.0, 2.0)
        inside = np.abs(z[xN] - centre) <= (level + z[-1]) * unit
        values = qp.G[box] @ z
        rows_hold = (qp.l[box] <= values) & (values <= qp.u[box])
        assert np.array_equal(rows_hold[: 2 * n] & rows_hold[2 * n :], inside)
        agreed += int(inside.all())
    assert 0 < agreed < 400  # both outcomes were sampled
    plans = []
    for transcription in ("sparse", "condensed"):
        mpc = RobustMPC(
            model, replace(config, solver="daqp", transcription=transcription),
            certification=controller.mpc.certification,
        )  # fmt: skip
        solutions = []
        for x_hat, x_bar, u_bar, y0, e_hat in soft_steps:
            mpc.reset()
            solution = mpc.solve(x_hat, x_bar, u_bar, y0, e_hat)
            assert solution.policy == "soft", (transcription, solution.status)
            solutions.append(solution.u)
        plans.append(np.array(solutions))
    np.testing.assert_allclose(plans[0], plans[1], rtol=0, atol=1e-7)
