"""Reference calculator, eq. (reference_calculation), and K_bar of Lemma 5."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st
from lstm_factories import random_delta_iss_lstm

from ltv_lstm_mpc import (
    DimensionError,
    InvalidValueError,
    Observer,
    ObserverGains,
    ReferenceCalculator,
    UnreachableSetpointError,
    estimate_K_bar,
    load_model,
)


@given(seed=st.integers(0, 2**32 - 1), n=st.integers(1, 5), u_star=st.floats(-0.95, 0.95),
       d_hat=st.floats(-0.1, 0.1))  # fmt: skip
def test_reference_residual_on_random_models(
    seed: int, n: int, u_star: float, d_hat: float
) -> None:
    rng = np.random.default_rng(seed)
    model = random_delta_iss_lstm(rng, n)
    y_star = model.output(model.equilibrium(np.array([u_star])))
    y0 = y_star + d_hat  # reachable by construction: u_bar = u_star
    calculator = ReferenceCalculator(model)
    solution = calculator.solve(y0, [d_hat])
    assert solution.converged and solution.u_admissible
    assert solution.residual < 1e-10
    np.testing.assert_allclose(
        model.step(solution.x_bar, solution.u_bar), solution.x_bar, atol=1e-10
    )
    np.testing.assert_allclose(model.output(solution.x_bar) + d_hat, y0, atol=1e-10)
    grid_y = calculator._grid_y[:, 0]
    if np.all(np.diff(grid_y) > 0) or np.all(np.diff(grid_y) < 0):
        # Monotone equilibrium map: the solution is unique (Assumption 4), so u_bar = u_star.
        np.testing.assert_allclose(solution.u_bar, [u_star], atol=1e-7)
    assert np.isfinite(solution.jacobian_condition)
    # Warm start: a nearby set-point converges in few (chord) iterations.
    u_near = u_star - 0.01 * np.sign(u_star)
    nearby = calculator.solve(model.output(model.equilibrium(np.array([u_near]))) + d_hat, [d_hat])
    assert nearby.residual < 1e-10 and nearby.iterations <= 6


def test_unreachable_setpoint_raises_or_flags() -> None:
    model = load_model("example_delta_iss_n3.npz")
    calculator = ReferenceCalculator(model)
    _low, high = calculator.reachable_output_range
    with pytest.raises(UnreachableSetpointError, match="not reachable") as info:
        calculator.solve(high + 0.5, [0.0])
    assert "spans" in str(info.value)
    flagged = ReferenceCalculator(model, strict=False).solve(high + 0.5, [0.0])
    assert not flagged.ok
    assert not flagged.u_admissible or not flagged.converged


def test_reference_input_validation() -> None:
    calculator = ReferenceCalculator(load_model("example_delta_iss_n3.npz"))
    with pytest.raises(DimensionError, match=r"y0 has shape \(2,\), expected \(1,\)"):
        calculator.solve([0.0, 0.1], [0.0])
    with pytest.raises(InvalidValueError, match="d_hat contains NaN"):
        calculator.solve([0.0], [np.nan])


def test_K_bar_matches_finite_difference_of_the_reference_map() -> None:
    model = load_model("example_delta_iss_n3.npz")
    estimate = estimate_K_bar(model, grid_points=41)
    calculator = ReferenceCalculator(model)
    h = 1e-6
    for k in range(
        1, 40, 4
    ):  # interior points; ||K_x|| (Lemma 5's proof) = sensitivity of x_bar to y0
        y = estimate.y_grid[k]
        a = calculator.solve(y - h, [0.0]).x_bar
        b = calculator.solve(y + h, [0.0]).x_bar
        np.testing.assert_allclose(
            np.linalg.norm(b - a) / (2 * h), estimate.K_x_norms[k], rtol=1e-4
        )
    assert estimate.K_bar == pytest.approx(np.max(estimate.K_x_norms))
    restricted = estimate_K_bar(model, y0_range=([-0.2], [0.2]), d_max=0.1, grid_points=41)
    assert restricted.K_bar < estimate.K_bar
    kept = ~np.isnan(restricted.K_x_norms)
    assert kept.any() and not kept.all()
    assert np.all(np.abs(restricted.y_grid[kept, 0]) <= 0.3 + 1e-12)


def test_observer_initialization_at_matching_equilibrium() -> None:
    model = load_model("example_delta_iss_n3.npz")
    observer = Observer(model, ObserverGains.disturbance_only(model, 0.1), d_max=0.1)
    observer.initialize([0.3])
    np.testing.assert_allclose(observer.y_hat, [0.3], atol=1e-10)
    np.testing.assert_array_equal(observer.d_hat, [0.0])
    # It is an equilibrium: one step with the matching input leaves it unchanged.
    u_eq = ReferenceCalculator(model).solve([0.3], [0.0]).u_bar
    x_before = observer.x_hat.copy()
    observer.step([0.3], u_eq)
    np.testing.assert_allclose(observer.x_hat, x_before, atol=1e-10)
    with pytest.warns(RuntimeWarning, match="no LSTM equilibrium"):
        observer.initialize([5.0])


def test_observer_saturates_disturbance_and_checks_shapes() -> None:
    model = random_delta_iss_lstm(np.random.default_rng(0), 2)
    observer = Observer(model, ObserverGains.disturbance_only(model, 1.0), d_max=0.1)
    _, d_hat = observer.step([10.0], [0.0])
    np.testing.assert_array_equal(d_hat, [0.1])
    with pytest.raises(DimensionError, match=r"u has shape \(2,\)"):
        observer.step([0.0], [0.0, 1.0])
    with pytest.raises(InvalidValueError):
        observer.step([np.inf], [0.0])


def test_a_singular_chord_jacobian_ends_the_chord_and_newton_solves(monkeypatch) -> None:
    """Where the chord's Jacobian cannot be inverted (np.linalg.inv raising, as for a
    singular matrix), the numpy chord ends without an inverse and the damped Newton solves
    the set-point (one fallback counted), rather than the error reaching the caller; the
    compiled chord does the same (tests/test_kernel.py checks its in-place inverse)."""
    from ltv_lstm_mpc.lstm.kernel import LSTMKernel

    model = load_model("example_delta_iss_n3.npz")
    model.kernel = LSTMKernel(model, compiled=False)
    calculator = ReferenceCalculator(model)
    assert not calculator._compiled
    y_a = model.output(model.equilibrium(np.array([0.1])))
    y_b = model.output(model.equilibrium(np.array([0.12])))
    assert calculator.solve(y_a, [0.0]).converged
    calculator._Jinv = None  # the next chord factorizes

    def singular(matrix):
        raise np.linalg.LinAlgError("Singular matrix")

    monkeypatch.setattr(np.linalg, "inv", singular)
    fallbacks = calculator.counts["fallbacks"]
    solution = calculator.solve(y_b, [0.0])
    assert solution.converged and solution.residual < 1e-10
    assert calculator.counts["fallbacks"] == fallbacks + 1
    np.testing.assert_allclose(solution.u_bar, [0.12], atol=1e-7)


def test_the_chord_refreshes_its_inverse_only_after_a_slow_contraction() -> None:
    """The chord Newton's refresh rule (CHORD_REFRESH_CONTRACTION): over a ramp of the
    shipped pH model's set-point, the inverse Jacobian is recomputed after an accepted
    iteration exactly where that iteration reduced the residual by less than that factor,
    never after a faster one (every iteration on this ramp reduces the residual: no
    restore); so the refreshes are rare on a smooth ramp, and every step still converges
    in a few iterations."""
    from ltv_lstm_mpc.loop.compiled_reference import CHORD_REFRESH_CONTRACTION
    from ltv_lstm_mpc.lstm.kernel import LSTMKernel

    model = load_model("ph_lstm_n5.npz")
    model.kernel = LSTMKernel(model, compiled=False)
    calculator = ReferenceCalculator(model, tol=1e-12)
    assert not calculator._compiled
    events: list[tuple[str, float]] = []
    residual, factorize = calculator._chord_residual, calculator._chord_factorize

    def logged_residual(z, target):
        norm = residual(z, target)
        events.append(("residual", norm))
        return norm

    def logged_factorize():
        events.append(("factorize", 0.0))
        return factorize()

    calculator._chord_residual = logged_residual  # type: ignore[method-assign]
    calculator._chord_factorize = logged_factorize  # type: ignore[method-assign]
    y_low = model.output(model.equilibrium(np.array([-0.2])))
    y_high = model.output(model.equilibrium(np.array([0.2])))
    calculator.solve(y_low, [0.0])
    steps, slow_iterations = 200, 0
    for k in range(1, steps + 1):
        events.clear()
        solution = calculator.solve(y_low + (y_high - y_low) * k / steps, [0.0])
        assert solution.converged and solution.residual < 1e-12
        assert solution.iterations <= 8
        norms = [norm for kind, norm in events if kind == "residual"]
        # each residual after the first is an iteration's trial (no restores on this ramp)
        assert len(norms) == solution.iterations + 1
        at = 0
        for i, (kind, _) in enumerate(events):
            if kind != "residual":
                continue
            if 0 < at < len(norms) - 1:  # an accepted iteration with another one after it
                ratio = norms[at] / norms[at - 1]
                refreshed = events[i + 1][0] == "factorize"
                assert refreshed == (ratio > CHORD_REFRESH_CONTRACTION), (k, at, ratio)
                slow_iterations += refreshed
            at += 1
    assert calculator.counts["factorizations"] <= 0.05 * steps
    assert slow_iterations <= 0.05 * steps


def test_the_compiled_restart_loop_equals_the_numpy_one_and_checks_its_start() -> None:
    """On a compiled model the damped Newton with restarts runs its compiled twin: the same
    solution as the numpy loop (a calculator on the numpy kernel) from no warm start and
    from a given one, to 1e-12; a warm start of the wrong length is refused; with
    ``restarts`` assigned after construction the numpy loop runs (the compiled workspace
    holds the old value), with the same answer."""
    import copy

    from ltv_lstm_mpc.lstm.kernel import LSTMKernel

    model = load_model("ph_lstm_n5.npz")
    compiled = copy.copy(model)
    compiled.kernel = LSTMKernel(compiled, compiled=True)
    slow = copy.copy(model)
    slow.kernel = LSTMKernel(slow, compiled=False)
    fast_calc = ReferenceCalculator(compiled, u_max=1.0, strict=False)
    slow_calc = ReferenceCalculator(slow, u_max=1.0, strict=False)
    assert fast_calc._chord_parts is not None and slow_calc._chord_parts is None
    for y0 in (-0.5, 0.2, 0.9):
        fast = fast_calc.solve([y0], [0.0])
        slow_solution = slow_calc.solve([y0], [0.0])
        np.testing.assert_allclose(fast.x_bar, slow_solution.x_bar, rtol=0, atol=1e-12)
        np.testing.assert_allclose(fast.u_bar, slow_solution.u_bar, rtol=0, atol=1e-12)
        assert fast.converged == slow_solution.converged
        warm = (fast.x_bar + 0.01, fast.u_bar)
        again = fast_calc.solve([y0 + 0.1], [0.0], warm=warm)
        slow_again = slow_calc.solve([y0 + 0.1], [0.0], warm=warm)
        np.testing.assert_allclose(again.x_bar, slow_again.x_bar, rtol=0, atol=1e-12)
        fast_calc.reset()
        slow_calc.reset()
    with pytest.raises(DimensionError, match="warm x_bar"):
        fast_calc.solve([0.1], [0.0], warm=(fast.x_bar[:3], fast.u_bar))
    fast_calc.restarts = 3
    assert fast_calc._restart_settings != (fast_calc.restarts, fast_calc.u_max)
    moved = fast_calc.solve([0.3], [0.0])
    np.testing.assert_allclose(moved.x_bar, slow_calc.solve([0.3], [0.0]).x_bar, atol=1e-12)
