"""Globalized SQP (mpc/sqp.py): merit line search, feasibility phase, KKT-residual stop.

Two levels: :func:`globalized_sqp` on one-input problems whose subproblems are solved in
closed form (the algorithm alone), and :class:`RobustMPC` with ``sqp_iterations > 1``
against the exact NMPC (CasADi + IPOPT) on the pH model, including a state whose first
linearization is infeasible although the nonlinear FHOCP is feasible.
"""

from __future__ import annotations

import warnings

import numpy as np
import pytest
from ltv_lstm_mpc.solvers import available_solvers, solver_info
from optional_extras import first_installed
from scipy.optimize import minimize_scalar

from ltv_lstm_mpc import MPCConfig, RobustMPC, load_model
from ltv_lstm_mpc.loop.reference import ReferenceCalculator
from ltv_lstm_mpc.mpc.sqp import Subproblem, globalized_sqp, required_penalty

U_MAX = 3.0  # the toy problems' input bound


def cubic_problem(level: float, model_curvature: float = 1.0, soft_weight: float = 1e3):
    r"""min u^2 s.t. u^3 >= level, |u| <= 3, as the callbacks of :func:`globalized_sqp`.

    The "state" is [u, u^3]; the subproblem linearizes u^3 at the iterate and its cost
    is the exact u^2 times ``model_curvature`` in the step (a wrong curvature makes the
    full step overshoot: the line search has to damp it). ``"soft"`` minimizes the cost
    plus ``soft_weight`` times the linearized violation (the feasibility phase).
    """
    point = {}

    def states(u: float) -> np.ndarray:
        return np.array([[u, u**3]])

    def theta(x: np.ndarray) -> float:
        return max(0.0, level - float(x[0, 1]))

    def linearize(u: np.ndarray) -> np.ndarray:
        point["u"] = float(u[0, 0])
        return states(point["u"])

    def model_cost(u0: float, d: float) -> float:
        return u0**2 + 2 * u0 * d + model_curvature * d**2

    def solve(kind: str) -> Subproblem:
        u0 = point["u"]
        f, g = u0**3, 3 * u0**2
        low, high = -U_MAX - u0, U_MAX - u0
        if kind == "nominal":
            d_min = (level - f) / g if g > 0 else (0.0 if f >= level else np.inf)
            if d_min > high:
                return Subproblem(None, None, "infeasible", "linearization infeasible", 1e-9)
            d = min(max(-u0 / model_curvature, d_min, low), high)
        else:
            result = minimize_scalar(
                lambda d: model_cost(u0, d) + soft_weight * max(0.0, level - f - g * d),
                bounds=(low, high),
                method="bounded",
                options={"xatol": 1e-13},
            )
            d = float(result.x)
        x_linear = np.array([[u0 + d, f + g * d]])
        return Subproblem(np.array([[u0 + d]]), x_linear, "optimal", "", 1e-9)

    def evaluate(u: np.ndarray) -> tuple[float, float]:
        v = float(u[0, 0])
        return v**2, theta(states(v))

    def evaluate_linear(x: np.ndarray, u: np.ndarray) -> tuple[float, float]:
        return model_cost(point["u"], float(u[0, 0]) - point["u"]), theta(x)

    return {
        "linearize": linearize,
        "solve": solve,
        "evaluate": evaluate,
        "evaluate_linear": evaluate_linear,
    }


def test_feasibility_phase_reaches_the_solution_from_an_infeasible_linearization() -> None:
    # At u = 0.01 the linearized constraint needs a step of ~1700 > U: infeasible, while
    # the nonlinear problem is feasible with solution u* = 0.5^(1/3).
    outcome = globalized_sqp(
        np.array([[0.01]]), **cubic_problem(0.5), iterations=60, tolerance=1e-10, penalty=1e3
    )
    assert outcome.converged and outcome.status == "optimal"
    assert outcome.feasibility_steps >= 1
    assert outcome.u is not None
    assert outcome.u[0, 0] == pytest.approx(0.5 ** (1 / 3), abs=1e-9)
    assert outcome.kkt_residual <= 1e-10
    assert outcome.infeasibility <= 1e-12


def test_line_search_damps_an_overshooting_model() -> None:
    # min u^2 with the model's curvature 0.2 of the true one: the full step is -5 u
    # (|u| grows 4x per full step); the Armijo backtracking makes it converge.
    outcome = globalized_sqp(
        np.array([[1.0]]),
        **cubic_problem(-100.0, model_curvature=0.2),
        iterations=200,
        tolerance=1e-9,
        penalty=1e3,
    )
    assert outcome.converged and outcome.status == "optimal"
    assert outcome.u is not None and abs(outcome.u[0, 0]) <= 1e-9
    assert outcome.feasibility_steps == 0


def test_local_infeasibility_stops_early_with_the_reason() -> None:
    # u^3 >= 30 with |u| <= 3 (u^3 <= 27): infeasible; the feasibility phase stops at the
    # edge without spending all its iterations.
    outcome = globalized_sqp(
        np.array([[0.5]]), **cubic_problem(30.0), iterations=100, tolerance=1e-10, penalty=1e3
    )
    assert outcome.status == "infeasible" and not outcome.converged
    assert outcome.infeasibility == pytest.approx(3.0, abs=1e-6)
    assert outcome.iterations < 100
    assert "local infeasibility" in outcome.reason


def test_iteration_limit_reports_a_feasible_unconverged_point() -> None:
    outcome = globalized_sqp(
        np.array([[2.0]]),
        **cubic_problem(0.5, model_curvature=0.2),
        iterations=2,
        tolerance=1e-12,
        penalty=1e3,
    )
    assert outcome.status == "optimal_inaccurate" and not outcome.converged
    assert outcome.iterations == 2 and outcome.infeasibility == 0.0
    assert outcome.kkt_residual > 1e-12
    assert "KKT residual" in outcome.reason


@pytest.mark.parametrize(
    ("cost_decrease", "infeasibility_decrease", "penalty", "expected"),
    [
        (1.0, 2.0, 10.0, 10.0),  # the cost decreases too: keep mu
        (-1.0, 0.0, 10.0, 10.0),  # no feasibility progress to trade
        (-1.0, 1.0, 10.0, 10.0),  # mu = 10 already owes rho * mu * 1 <= 9
        (-90.0, 1.0, 10.0, 110.0),  # needs 90 / 0.9 = 100, times 1.1
    ],
)
def test_penalty_update(cost_decrease, infeasibility_decrease, penalty, expected) -> None:
    mu = required_penalty(cost_decrease, infeasibility_decrease, penalty)
    assert mu == pytest.approx(expected)
    if infeasibility_decrease > 0:  # the predicted decrease covers rho * mu * decrease
        assert cost_decrease + mu * infeasibility_decrease >= 0.1 * mu * infeasibility_decrease


# ----------------------------------------------------------------- against exact NMPC


@pytest.fixture(scope="module")
def pH():
    pytest.importorskip("casadi")
    from ltv_lstm_mpc.mpc.exact_nmpc import ExactNMPC

    model = load_model("ph_lstm_n5.npz")
    sqp = RobustMPC(model, MPCConfig(sqp_iterations=300, sqp_tolerance=1e-9, tolerance=1e-10))
    rti = RobustMPC(model, MPCConfig(tolerance=1e-10), certification=sqp.certification)
    nmpc = ExactNMPC(
        model, MPCConfig(tolerance=1e-10), certification=sqp.certification, smoothing=1e-12
    )
    return model, sqp, rti, nmpc, ReferenceCalculator(model, strict=False)


def _states(model, calculator, sqp):
    """Random states (equilibria of perturbed inputs, perturbed), random set-points in
    the admissible interval, e_hat, and the linearization's candidate (None: u_bar
    repeated)."""
    rng = np.random.default_rng(5)
    low, high = sqp.tightening.setpoint_interval()
    cases = []
    for _ in range(10):
        y0 = np.array([rng.uniform(0.6 * low[0], 0.6 * high[0])])
        ref = calculator.solve(y0, np.zeros(1))
        x = model.equilibrium(np.clip(ref.u_bar + rng.uniform(-0.5, 0.5, 1), -0.7, 0.7))
        cases.append((x + rng.normal(0, 0.003, x.shape), y0, 0.1, ref, None))
    # A constructed state whose first linearization (along u = -1) is infeasible
    # although the nonlinear FHOCP is feasible.
    y0 = np.array([-0.25])
    reference = calculator.solve(y0, np.zeros(1))
    cases.append((model.equilibrium(np.array([0.3])), y0, sqp.tightening.e_inf, reference, -1))
    return cases


def test_converged_sqp_matches_exact_nmpc(pH) -> None:
    model, sqp, rti, nmpc, calculator = pH
    feasible = rescued = 0
    for x, y0, e_hat, ref, warm_value in _states(model, calculator, sqp):
        warm = None if warm_value is None else np.full((sqp.N, 1), float(warm_value))
        for mpc in (sqp, rti, nmpc):
            mpc.reset()
        a = sqp.solve(x, ref.x_bar, ref.u_bar, y0, e_hat, warm=warm)
        b = nmpc.solve(x, ref.x_bar, ref.u_bar, y0, e_hat)
        assert a.feasible == b.feasible, (a.status, a.reason, b.status, b.reason)
        if not b.feasible:
            continue
        feasible += 1
        np.testing.assert_allclose(a.u[0], b.u[0], atol=1e-5)
        assert a.cost == pytest.approx(b.cost, rel=1e-6)
        assert a.residuals["output_violation"] <= 1e-9
        assert a.residuals["terminal_residual"] <= 1e-8
        assert a.kkt_residual <= 1e-5
        first = rti.solve(x, ref.x_bar, ref.u_bar, y0, e_hat, warm=warm)
        if not first.feasible:  # the first linearization was infeasible
            assert a.feasibility_steps >= 1
            rescued += 1
    assert feasible >= 6
    assert rescued >= 1


def test_rti_unchanged_by_the_sqp(pH) -> None:
    model, _, rti, _, calculator = pH
    y0 = np.array([0.1])
    ref = calculator.solve(y0, np.zeros(1))
    rti.reset()
    solution = rti.solve(model.equilibrium(ref.u_bar + 0.1), ref.x_bar, ref.u_bar, y0, 0.1)
    assert solution.iterations == 1 and solution.feasible
    assert np.isnan(solution.kkt_residual) and solution.feasibility_steps == 0
    assert solution.step_length == 1.0


# ------------------------------------------------------------------- every backend


@pytest.fixture(scope="module")
def interior_state():
    """A feasible state whose converged first input is inside U (0.3155)."""
    model = load_model("ph_lstm_n5.npz")
    y0 = np.array([0.1])
    ref = ReferenceCalculator(model, strict=False).solve(y0, np.zeros(1))
    return model, model.equilibrium(ref.u_bar + 0.1), ref, y0


def _converged(model, solver, state):
    _, x, ref, y0 = state
    config = MPCConfig(solver=solver, sqp_iterations=100, sqp_tolerance=1e-8, tolerance=1e-9)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # cvxpy's "may be inaccurate" notes
        return RobustMPC(model, config).solve(x, ref.x_bar, ref.u_bar, y0, 0.1)


@pytest.mark.parametrize("solver", available_solvers())
def test_every_backend_converges_to_its_nlp(solver, interior_state) -> None:
    """Exact-cone backends reach eq. (optimization)'s KKT point, QP-only ones that of its
    box reformulation: the same first input as clarabel / daqp, whatever the solver."""
    model = interior_state[0]
    exact = solver_info(solver).supports_cones
    reference_solver = first_installed("clarabel", "cvxpy:CLARABEL") if exact else "daqp"
    reference = _converged(model, reference_solver, interior_state)
    solution = _converged(model, solver, interior_state)
    assert solution.feasible and reference.status == "optimal"
    assert solution.residuals["output_violation"] <= 1e-9
    assert solution.residuals["terminal_residual"] < 0
    first_order = any(name in solver.lower() for name in ("osqp", "scs", "proxqp", "ecos"))
    tolerance = 1e-4 if first_order else 1e-6
    np.testing.assert_allclose(solution.u[0], reference.u[0], atol=tolerance)
    if solution.status == "optimal":
        assert solution.kkt_residual <= 1e-4
