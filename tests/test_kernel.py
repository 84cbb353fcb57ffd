"""The compiled kernel (numba) against the numpy reference of eq. (lstm) / eq. (jacobian)."""

from __future__ import annotations

import os
from typing import Any

import numpy as np
import pytest
from lstm_factories import random_lstm
from optional_extras import backend_params
from scipy.special import expit

from ltv_lstm_mpc.lstm import compiled
from ltv_lstm_mpc.lstm.kernel import LSTMKernel

pytestmark = pytest.mark.skipif(
    not compiled.AVAILABLE or os.environ.get("LTV_LSTM_MPC_KERNEL", "").lower() == "numpy",
    reason="compares the compiled kernel with the numpy one: needs numba and the default kernel",
)

SHAPES = [(1, 1, 1), (3, 1, 1), (5, 1, 1), (4, 2, 2), (8, 3, 3), (20, 2, 2)]


def _pair(n: int, m: int, p: int, seed: int) -> tuple[LSTMKernel, LSTMKernel]:
    model = random_lstm(np.random.default_rng(seed), n, m, p, scale=1.5)
    return LSTMKernel(model, compiled=True), LSTMKernel(model, compiled=False)


def _load(kernel: LSTMKernel, N: int, x0: np.ndarray, u: np.ndarray):  # type: ignore[no-untyped-def]
    traj = kernel.trajectory(N)
    n2, m = 2 * kernel.n, kernel.m
    traj.S[0, :n2] = x0
    traj.S[:N, n2 : n2 + m] = u
    return traj


def _ulps(value: np.ndarray, reference: np.ndarray) -> np.ndarray:
    """|value - reference| in units in the last place of the reference."""
    return np.abs(value - reference) / np.spacing(np.abs(reference))


def _activations(x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    sigmoid = np.array([compiled._sigmoid(float(v)) for v in x])
    tanh = np.array([compiled._tanh(float(v)) for v in x])
    return sigmoid, tanh


@pytest.mark.parametrize("n", [1, 3, 5, 8])
def test_the_cells_activations_are_the_scalar_ones_to_the_last_bit(n: int) -> None:
    """``lstm_cell`` applies its activations in vectorized loops (one over the 4n gates,
    one over c+, tanh(c+), h+): sigmoid on f, i, o and tanh on g and c+, each the scalar
    ``_sigmoid`` / ``_tanh`` to the last bit. Zero weights and c give the gates from
    ``extra`` alone and c+ = i g exactly, so every output has a scalar value to match."""
    rng = np.random.default_rng(n)
    WU = np.zeros((4 * n, n + 2))
    z = rng.normal(size=n + 2)
    c = np.zeros(n)
    for scale in (1e-3, 1.0, 30.0, 400.0):
        extra = rng.normal(size=4 * n) * scale
        t, tc = np.empty(4 * n), np.empty(n)
        c_next, h_next = np.empty(n), np.empty(n)
        compiled.lstm_cell(WU, z, t, c, c_next, h_next, tc, extra)
        sigmoid, tanh = _activations(extra)
        gates = np.concatenate([sigmoid[: 3 * n], tanh[3 * n :]])
        assert np.array_equal(t, gates)
        expected_c = gates[n : 2 * n] * gates[3 * n :]
        assert np.array_equal(c_next, expected_c)
        assert np.array_equal(tc, _activations(expected_c)[1])
        assert np.array_equal(h_next, gates[2 * n : 3 * n] * tc)


def test_the_compiled_activations_are_within_four_ulps_of_numpy() -> None:
    """The vectorizable sigmoid and tanh of the compiled cell against scipy's expit and
    numpy's tanh: at most 4 ulps over the range where sigmoid is a normal number, also
    near 0 (where tanh x ~ x needs relative accuracy), and exactly at the saturations."""
    rng = np.random.default_rng(7)
    x = np.concatenate(
        [
            rng.uniform(-40.0, 40.0, 20000),
            rng.uniform(-700.0, 700.0, 2000),
            rng.uniform(-1e-6, 1e-6, 1000),
            [0.0, -0.0, 1e-300, -1e-300, 0.5 * np.log(2.0), -0.5 * np.log(2.0), 36.0, -36.0],
        ]
    )
    sigmoid, tanh = _activations(x)
    reference_sigmoid, reference_tanh = expit(x), np.tanh(x)
    nonzero = reference_tanh != 0
    assert _ulps(sigmoid, reference_sigmoid).max() <= 4.0
    assert _ulps(tanh[nonzero], reference_tanh[nonzero]).max() <= 4.0
    assert np.array_equal(tanh[~nonzero], reference_tanh[~nonzero])
    # saturations: exactly 0, 1 and +-1 (or below 1e-307 where sigmoid underflows)
    sigmoid, tanh = _activations(np.array([-1e4, -800.0, 800.0, 1e4, np.inf, -np.inf]))
    assert np.all(sigmoid[:2] < 1e-307) and np.all(sigmoid[:2] >= 0.0)
    assert np.array_equal(sigmoid[2:5], [1.0, 1.0, 1.0]) and sigmoid[5] < 1e-307
    assert np.array_equal(tanh, [-1.0, -1.0, 1.0, 1.0, 1.0, -1.0])


def test_the_compiled_activations_propagate_nan_and_keep_the_sign_of_zero() -> None:
    sigmoid, tanh = _activations(np.array([np.nan, -0.0, 0.0, -1e-300]))
    assert np.isnan(sigmoid[0]) and np.isnan(tanh[0])
    assert np.array_equal(np.signbit(tanh[1:]), [True, False, True])
    assert sigmoid[1] == sigmoid[2] == 0.5


def test_the_compiled_cell_keeps_the_activations_accuracy() -> None:
    """The cell's activations, inlined into loops the compiler vectorizes (the cell itself
    compiled with reassociation flags), are those of the scalar functions to 4 ulps: the
    two-part argument reduction survives (gates driven over +-30 through large weights;
    weights and inputs are multiples of 1/8, so the pre-activations are exact in any
    summation order)."""
    rng = np.random.default_rng(3)
    n, m = 6, 1
    WU = rng.integers(-120, 121, (4 * n, n + m + 1)) / 8.0
    z = np.concatenate([rng.integers(-8, 9, n + m) / 8.0, [1.0]])
    c = rng.uniform(-3.0, 3.0, n)
    t, c_next, h_next, tc = np.empty(4 * n), np.empty(n), np.empty(n), np.empty(n)
    compiled.lstm_cell(WU, z, t, c, c_next, h_next, tc, np.zeros(0))
    pre = WU @ z
    assert np.abs(pre).max() > 20.0
    assert _ulps(t[: 3 * n], expit(pre[: 3 * n])).max() <= 4.0
    assert _ulps(t[3 * n :], np.tanh(pre[3 * n :])).max() <= 4.0
    np.testing.assert_allclose(tc, np.tanh(c_next), rtol=4e-16, atol=0)
    np.testing.assert_allclose(h_next, t[2 * n : 3 * n] * tc, rtol=0, atol=0)


def test_the_compiled_cell_keeps_relative_accuracy_near_zero() -> None:
    """Tiny pre-activations through a cell wide enough (n = 16) that every activation loop
    runs its vector body: tanh x ~ x keeps its relative accuracy (4 ulps), which a
    reassociated m / (m + 2) with m = e^(2x) - 1 would lose."""
    rng = np.random.default_rng(5)
    n, m = 16, 1
    WU = np.zeros((4 * n, n + m + 1))
    WU[:, -1] = rng.choice([-1.0, 1.0], 4 * n) * 2.0 ** rng.integers(-40, -20, 4 * n)
    z = np.concatenate([np.zeros(n + m), [1.0]])  # pre-activations: the bias column, exactly
    c = np.zeros(n)
    t, c_next, h_next, tc = np.empty(4 * n), np.empty(n), np.empty(n), np.empty(n)
    compiled.lstm_cell(WU, z, t, c, c_next, h_next, tc, np.zeros(0))
    pre = WU[:, -1]
    assert _ulps(t[3 * n :], np.tanh(pre[3 * n :])).max() <= 4.0
    assert _ulps(tc, np.tanh(c_next)).max() <= 4.0
    assert _ulps(t[: 3 * n], expit(pre[: 3 * n])).max() <= 4.0


@pytest.mark.parametrize(
    ("n", "m", "N", "diagonal_Q", "backward"),
    [
        (5, 1, 35, True, False),  # N m = 3.5 * 2n: the rank updates still
        (5, 1, 36, True, True),
        (5, 1, 7, False, False),  # N m = 0.7 * 2n: the Gram matrix still
        (5, 1, 8, False, True),
        (2, 2, 7, True, False),  # N m = 14 = 3.5 * 2n
        (2, 2, 8, True, True),
    ],
)
def test_the_condensing_chooses_the_backward_recursion_by_the_measured_crossover(
    n: int, m: int, N: int, diagonal_Q: bool, backward: bool
) -> None:
    """Backward from N m > 3.5 * 2n with diagonal stage weights (rank updates below it),
    from N m > 0.75 * 2n with full ones (the Gram matrix below it)."""
    from lstm_factories import random_delta_iss_lstm

    from ltv_lstm_mpc import MPCConfig, RobustMPC

    model = random_delta_iss_lstm(np.random.default_rng(n + 10 * m), n, m, m)
    Q = 1.0 if diagonal_Q else np.eye(2 * n) + 0.3 * np.ones((2 * n, 2 * n)) / (2 * n)
    mpc = RobustMPC(model, MPCConfig(solver="daqp", N=N, Q=Q))
    assert mpc._problem.backward_condensing is backward


@pytest.mark.parametrize(("n", "m", "p"), SHAPES)
@pytest.mark.parametrize("seed", [0, 1])
def test_rollout_and_jacobians_match_reference(n: int, m: int, p: int, seed: int) -> None:
    fast, ref = _pair(n, m, p, seed)
    assert fast.compiled and not ref.compiled
    rng = np.random.default_rng(100 + seed)
    N = 9
    x0 = rng.uniform(-0.9, 0.9, 2 * n)
    u = rng.uniform(-1.0, 1.0, (N, m))
    a, b = _load(fast, N, x0, u), _load(ref, N, x0, u)
    fast.rollout(a, 0, N)
    ref.rollout(b, 0, N)
    np.testing.assert_allclose(a.S, b.S, rtol=0, atol=1e-12)
    np.testing.assert_allclose(a.T, b.T, rtol=0, atol=1e-12)
    np.testing.assert_allclose(a.TC, b.TC, rtol=0, atol=1e-12)
    fast.jacobians(a)
    ref.jacobians(b)
    np.testing.assert_allclose(a.J, b.J, rtol=0, atol=1e-12)
    # On the same activations the Jacobians are the same products in the same order.
    b.S[:], b.T[:], b.TC[:] = a.S, a.T, a.TC
    ref.jacobians(b)
    assert np.array_equal(a.J, b.J)


@pytest.mark.parametrize(("n", "m", "p"), SHAPES[:4])
def test_partial_rollout_with_gate_injection(n: int, m: int, p: int) -> None:
    """Steps k0..k1 only, with the observer's extra gate term (eq. lstm_observer)."""
    fast, ref = _pair(n, m, p, 7)
    rng = np.random.default_rng(3)
    N = 6
    x0 = rng.uniform(-0.5, 0.5, 2 * n)
    u = rng.uniform(-1.0, 1.0, (N, m))
    extra = rng.normal(size=4 * n)
    a, b = _load(fast, N, x0, u), _load(ref, N, x0, u)
    a.S[2:, : 2 * n] = b.S[2:, : 2 * n] = 0.25  # rows before k0 = 2 must stay, after k1 too
    fast.rollout(a, 2, 4, extra)
    ref.rollout(b, 2, 4, extra)
    np.testing.assert_allclose(a.S, b.S, rtol=0, atol=1e-12)
    assert np.all(a.S[5:, : 2 * n] == 0.25)
    # the injection changes the result
    c = _load(fast, N, x0, u)
    c.S[2:, : 2 * n] = 0.25
    fast.rollout(c, 2, 4)
    assert np.abs(c.S[3] - a.S[3]).max() > 1e-6


@pytest.mark.parametrize(("n", "m", "p"), SHAPES)
def test_pairs_and_step_match_reference(n: int, m: int, p: int) -> None:
    fast, ref = _pair(n, m, p, 11)
    rng = np.random.default_rng(5)
    K = 13
    x = rng.uniform(-1.0, 1.0, (K, 2 * n))
    u = rng.uniform(-1.0, 1.0, (K, m))
    a = fast.pairs(x, u, jacobians=True)
    next_a, J_a = a.pair_next.copy(), a.J.copy()  # type: ignore[attr-defined]
    b = ref.pairs(x, u, jacobians=True)
    np.testing.assert_allclose(next_a, b.pair_next, rtol=0, atol=1e-12)  # type: ignore[attr-defined]
    np.testing.assert_allclose(J_a, b.J, rtol=0, atol=1e-12)
    for k in range(K):
        np.testing.assert_allclose(fast.step(x[k], u[k]), next_a[k], rtol=0, atol=0)
        np.testing.assert_allclose(ref.step(x[k], u[k]), b.pair_next[k], rtol=0, atol=0)  # type: ignore[attr-defined]


def test_environment_variable_selects_the_reference(monkeypatch: pytest.MonkeyPatch) -> None:
    model = random_lstm(np.random.default_rng(0), 3)
    monkeypatch.setenv("LTV_LSTM_MPC_KERNEL", "numpy")
    assert not LSTMKernel(model).compiled
    monkeypatch.setenv("LTV_LSTM_MPC_KERNEL", "numba")
    assert LSTMKernel(model).compiled
    monkeypatch.delenv("LTV_LSTM_MPC_KERNEL")
    assert LSTMKernel(model).compiled
    assert model.kernel.compiled


@pytest.mark.parametrize("backward", [False, True])
@pytest.mark.parametrize(
    ("n", "m", "N", "diagonal_Q"),
    [
        (5, 1, 5, True),
        (4, 2, 7, True),
        (3, 2, 4, False),
        (6, 3, 12, True),
        (2, 1, 30, False),
        (11, 2, 6, False),
    ],  # n >= 10: the BLAS branch of the recursion
)
def test_compiled_condensing_matches_the_numpy_build(
    n: int, m: int, N: int, diagonal_Q: bool, backward: bool
) -> None:
    """CondensedTranscription.build: numba version vs numpy reference, every QP array, with
    H and g0 forward (rank updates on the causal columns for diagonal stage weights, the
    Gram matrix for full ones) and from the backward recursion."""
    from lstm_factories import random_delta_iss_lstm

    from ltv_lstm_mpc import MPCConfig, RobustMPC

    model = random_delta_iss_lstm(np.random.default_rng(n + 10 * m), n, m, m)
    Q = 1.0 if diagonal_Q else np.eye(2 * n) + 0.3 * np.ones((2 * n, 2 * n)) / (2 * n)
    config = MPCConfig(solver="daqp", N=N, Q=Q)
    fast = RobustMPC(model, config)
    reference = RobustMPC(model, config, certification=fast.certification)
    assert fast._problem.compiled
    fast._problem.backward_condensing = backward
    reference._problem.compiled = False
    rng = np.random.default_rng(1)
    u_bar = rng.uniform(-0.3, 0.3, m)
    x_bar = model.equilibrium(u_bar)
    y0 = model.output(x_bar)
    x_hat = x_bar + rng.normal(scale=0.05, size=2 * n)
    warm = rng.uniform(-0.5, 0.5, (N, m))
    for mpc in (fast, reference):
        mpc.prepare(x_bar, u_bar, y0, 0.3, x_pred=x_hat, warm=warm)
    a, b = fast._problem, reference._problem
    for name in ("_H", "_g0", "_A", "_lo0", "_up0", "_lb", "_ub", "scale"):
        np.testing.assert_allclose(
            getattr(a, name), getattr(b, name), rtol=0, atol=1e-12, err_msg=name
        )
    # the delta x_0 part, propagated at feedback time, equals the numpy build's F and E
    x_fb = x_hat + rng.normal(scale=0.01, size=2 * n)
    step_a, step_b = a.solve("nominal", x_fb), b.solve("nominal", x_fb)
    dx0 = x_fb - b._traj.S[0, : 2 * n]
    np.testing.assert_allclose(a._f, b._F @ dx0 + b._g0, rtol=0, atol=1e-12)
    np.testing.assert_allclose(a._lo, b._lo0 - b._E @ dx0, rtol=0, atol=1e-12)
    np.testing.assert_allclose(a._up, b._up0 - b._E @ dx0, rtol=0, atol=1e-12)
    assert step_a.status is step_b.status
    if step_b.u is not None:
        np.testing.assert_allclose(step_a.u, step_b.u, rtol=0, atol=1e-10)
        np.testing.assert_allclose(step_a.x_linear, step_b.x_linear, rtol=0, atol=1e-10)
    np.testing.assert_allclose(fast.feedback(x_hat).u, reference.feedback(x_hat).u, atol=1e-10)


@pytest.mark.parametrize("policy", ["paper", "soft"])
def test_compiled_feedback_matches_the_numpy_feedback(policy: str) -> None:
    """insert_state / expand_point (numba) against the numpy feedback, every kind of QP."""
    from lstm_factories import random_delta_iss_lstm

    from ltv_lstm_mpc import MPCConfig, RobustMPC

    model = random_delta_iss_lstm(np.random.default_rng(4), 4, 2, 2)
    config = MPCConfig(solver="daqp", N=6, infeasibility_policy=policy)
    fast = RobustMPC(model, config)
    reference = RobustMPC(model, config, certification=fast.certification)
    reference._problem.compiled = False
    rng = np.random.default_rng(2)
    u_bar = rng.uniform(-0.3, 0.3, 2)
    x_bar = model.equilibrium(u_bar)
    for _ in range(4):
        x_hat = x_bar + rng.normal(scale=0.05, size=8)
        for mpc in (fast, reference):
            mpc.prepare(x_bar, u_bar, model.output(x_bar), 0.3, x_pred=x_hat)
        for kind in ("nominal", policy):
            a, b = fast._problem.solve(kind, x_hat), reference._problem.solve(kind, x_hat)
            assert a.status is b.status
            if b.u is None:
                assert a.u is None
                continue
            np.testing.assert_allclose(a.u, b.u, rtol=0, atol=1e-12)
            np.testing.assert_allclose(a.x_linear, b.x_linear, rtol=0, atol=1e-12)
            assert a.violation == pytest.approx(b.violation, abs=1e-14)


def _numpy_twin(model: Any) -> Any:
    """The same model on the numpy reference kernel."""
    from ltv_lstm_mpc import LSTMModel

    twin = LSTMModel(**model.weights(), y_phi_constraint=model.y_phi_constraint)
    twin.kernel = LSTMKernel(twin, compiled=False)
    return twin


@pytest.mark.parametrize(("n", "m"), [(5, 1), (4, 2)])
def test_compiled_chord_newton_matches_the_numpy_warm_path(n: int, m: int) -> None:
    """ReferenceCalculator's warm path: one numba call vs the numpy reference, on a moving
    target, with the same iterations and factorizations."""
    from lstm_factories import random_delta_iss_lstm

    from ltv_lstm_mpc.loop.reference import ReferenceCalculator

    model = random_delta_iss_lstm(np.random.default_rng(n), n, m, m)
    fast = ReferenceCalculator(model, strict=False, tol=1e-10)
    reference = ReferenceCalculator(_numpy_twin(model), strict=False, tol=1e-10)
    assert fast._compiled and not reference._compiled  # chosen once, at construction
    base = model.output(model.equilibrium(np.full(m, 0.1)))
    for k in range(40):
        target = base + 0.01 * np.sin(0.3 * k) * np.linspace(1.0, 0.5, m)
        d_hat = np.zeros(m)
        a, b = fast.solve(target, d_hat), reference.solve(target, d_hat)
        assert a.ok == b.ok and a.iterations == b.iterations
        np.testing.assert_allclose(a.x_bar, b.x_bar, rtol=0, atol=1e-12)
        np.testing.assert_allclose(a.u_bar, b.u_bar, rtol=0, atol=1e-12)
    assert fast.counts == reference.counts
    assert fast.counts["factorizations"] > 0


@pytest.mark.parametrize(("n", "m", "gains"), [(5, 1, False), (5, 1, True), (4, 2, True)])
def test_compiled_observer_update_matches_the_numpy_one(n: int, m: int, gains: bool) -> None:
    """eq. (lstm_observer): one numba call vs the numpy innovation + kernel step, with and
    without gate injection, d_hat reaching its saturation."""
    from ltv_lstm_mpc.certificates.stability import ObserverGains
    from ltv_lstm_mpc.loop.observer import Observer

    rng = np.random.default_rng(n + m)
    model = random_lstm(rng, n, m, m, scale=1.5)
    fill = 0.05 if gains else 0.0
    observer_gains = ObserverGains(
        L_f=np.full((n, m), fill),
        L_i=np.full((n, m), -fill),
        L_o=np.full((n, m), 0.5 * fill),
        L_d=0.3 * np.eye(m),
    )
    fast = Observer(model, observer_gains, d_max=0.05)
    reference = Observer(_numpy_twin(model), observer_gains, d_max=0.05)
    assert fast._compiled and not reference._compiled  # chosen once, at construction
    saturated = 0
    for _ in range(30):
        y, u = rng.normal(size=m), rng.uniform(-1, 1, size=m)
        fast.update(y, u)
        reference.update(y, u)
        np.testing.assert_allclose(fast.x_hat, reference.x_hat, rtol=0, atol=1e-12)
        np.testing.assert_allclose(fast.d_hat, reference.d_hat, rtol=0, atol=1e-14)
        saturated += int(np.any(np.abs(fast.d_hat) == 0.05))
    assert saturated > 0  # the saturation of eq. (d_lstm_observer) was exercised


@pytest.mark.parametrize("diagonal_Q", [True, False])
def test_compiled_plan_checks_match_the_numpy_ones(diagonal_Q: bool) -> None:
    """Re-simulation, cost and residuals (plan_metrics) vs the numpy core: a whole MPC on a
    compiled kernel against the same MPC on the numpy kernel."""
    from lstm_factories import random_delta_iss_lstm

    from ltv_lstm_mpc import LSTMModel, MPCConfig, RobustMPC

    base = random_delta_iss_lstm(np.random.default_rng(8), 4, 2, 2)
    twin = LSTMModel(**base.weights(), y_phi_constraint=base.y_phi_constraint)
    twin.kernel = LSTMKernel(twin, compiled=False)
    Q = 1.0 if diagonal_Q else np.eye(8) + 0.2 * np.ones((8, 8)) / 8
    config = MPCConfig(solver="daqp", N=6, Q=Q, R=0.5)
    fast = RobustMPC(base, config)
    reference = RobustMPC(twin, config, certification=fast.certification)
    assert fast._kernel.compiled and not reference._kernel.compiled
    rng = np.random.default_rng(3)
    u_bar = rng.uniform(-0.3, 0.3, 2)
    x_bar = base.equilibrium(u_bar)
    for _ in range(5):
        x_hat = x_bar + rng.normal(scale=0.05, size=8)
        a = fast.solve(x_hat, x_bar, u_bar, base.output(x_bar), 0.3)
        b = reference.solve(x_hat, x_bar, u_bar, base.output(x_bar), 0.3)
        assert a.status == b.status and a.policy == b.policy
        np.testing.assert_allclose(a.u, b.u, rtol=0, atol=1e-10)
        np.testing.assert_allclose(a.x, b.x, rtol=0, atol=1e-10)
        assert a.cost == pytest.approx(b.cost, rel=1e-10, abs=1e-12)
        for key, value in b.residuals.items():
            assert a.residuals[key] == pytest.approx(value, rel=1e-9, abs=1e-11, nan_ok=True), key


@pytest.mark.parametrize("solver", backend_params("daqp", "clarabel"))
def test_one_call_prepare_matches_the_python_prepare(solver: str, monkeypatch) -> None:
    """RobustMPC.prepare on the compiled condensing (linearize_and_build: one compiled call)
    against the Python steps with the numpy build: candidate from u_bar, then shifted, the
    re-simulation reused (x_pred = x_1 of the plan, or no x_pred) or not (x_pred moved)."""
    from lstm_factories import random_delta_iss_lstm

    from ltv_lstm_mpc import MPCConfig, RobustMPC

    model = random_delta_iss_lstm(np.random.default_rng(3), 4, 2, 2)
    config = MPCConfig(solver=solver, N=6)
    fast = RobustMPC(model, config)
    reference = RobustMPC(model, config, certification=fast.certification)
    reference._problem.compiled = False
    assert fast._problem.compiled and not reference._problem.compiled  # one call / Python
    import ltv_lstm_mpc.mpc.condensed as condensed_module

    calls = []
    one_call = condensed_module.prepare_condensed
    monkeypatch.setattr(
        condensed_module, "prepare_condensed", lambda *args: calls.append(1) or one_call(*args)
    )
    rng = np.random.default_rng(5)
    u_bar = rng.uniform(-0.3, 0.3, 2)
    x_bar = model.equilibrium(u_bar)
    y0 = model.output(x_bar)
    x_hat = x_bar + rng.normal(scale=0.05, size=8)
    for step in range(6):
        for mpc in (fast, reference):
            if step == 3:  # no x_pred: linearize from the plan's x_1 (reused)
                mpc.prepare(x_bar, u_bar, y0, 0.3)
            else:
                mpc.prepare(x_bar, u_bar, y0, 0.3, x_pred=x_hat)
        np.testing.assert_allclose(fast._traj.S, reference._traj.S, rtol=0, atol=1e-12)
        np.testing.assert_allclose(fast._traj.J, reference._traj.J, rtol=0, atol=1e-12)
        np.testing.assert_allclose(fast._cand, reference._cand, rtol=0, atol=1e-12)
        a, b = fast._problem, reference._problem
        np.testing.assert_allclose(a._H, b._H, rtol=0, atol=1e-12)
        np.testing.assert_allclose(a._g0, b._g0, rtol=0, atol=1e-12)
        assert a.scale == pytest.approx(b.scale, abs=1e-12)
        if step == 3:
            x_hat = fast._plan.S[1, :8].copy()
        else:
            solution_a, solution_b = fast.feedback(x_hat), reference.feedback(x_hat)
            np.testing.assert_allclose(solution_a.u, solution_b.u, rtol=0, atol=1e-9)
            # next start: the plan's prediction (reused) or a moved estimate (rolled out)
            x_hat = fast._plan.S[1, :8].copy()
            if step % 2:
                x_hat += 1e-3
    assert len(calls) == 6  # every prepare of `fast` was the one compiled call


def test_the_chord_inverse_in_place_matches_numpy_and_finds_a_singular_matrix() -> None:
    """The chord Newton's Gauss-Jordan inverse (loop/compiled_reference.py): random and
    badly scaled 11 x 11 matrices give numpy's inverse to 1e-12 relative; an exactly
    singular one returns False (the chord then ends, the damped Newton runs)."""
    from ltv_lstm_mpc.loop.compiled_reference import _invert

    rng = np.random.default_rng(3)
    for scale in (1.0, 1e-3, 1e3):
        matrix = rng.normal(size=(11, 11)) * scale + np.diag(rng.uniform(0.5, 2.0, 11))
        inverse = np.empty((11, 11))
        assert _invert(matrix.copy(), inverse)
        expected = np.linalg.inv(matrix)
        assert np.abs(inverse - expected).max() <= 1e-12 * np.abs(expected).max()
    singular = rng.normal(size=(11, 11))
    singular[:, 4] = 0.0
    assert not _invert(singular, np.empty((11, 11)))


def _textbook_inverse(matrix: np.ndarray) -> np.ndarray | None:
    """Gauss-Jordan with partial pivoting beside a separate identity, row by row (the
    textbook form of the chord's ``_invert``, and its form until 2026-12-06): the first
    row of largest magnitude as pivot; None where a pivot column is zero."""
    matrix = matrix.copy()
    size = matrix.shape[0]
    inverse = np.eye(size)
    for k in range(size):
        column = np.abs(matrix[k:, k])
        if column.max() == 0.0:
            return None
        pivot = k + int(np.argmax(column))
        matrix[[k, pivot]] = matrix[[pivot, k]]
        inverse[[k, pivot]] = inverse[[pivot, k]]
        scale = 1.0 / matrix[k, k]
        matrix[k] *= scale
        inverse[k] *= scale
        for r in range(size):
            factor = matrix[r, k]
            if r != k and factor != 0.0:
                matrix[r] -= factor * matrix[k]
                inverse[r] -= factor * inverse[k]
    return inverse


@pytest.mark.parametrize("seed", range(8))
def test_the_chord_inverse_is_the_textbook_elimination_to_the_last_bit(seed: int) -> None:
    """``_invert``'s compact elimination (the cleared columns hold the inverse's) does the
    textbook form's products and differences less those on its exact zeros: the same
    inverse, bit for bit, on matrices of 1 to 13 rows, badly row-scaled, with zeros
    (pivoting and skipped rows), and the same refusal of a singular one."""
    from ltv_lstm_mpc.loop.compiled_reference import _invert

    rng = np.random.default_rng(100 + seed)
    for _ in range(150):
        size = int(rng.integers(1, 14))
        matrix = rng.normal(size=(size, size)) * 10.0 ** rng.uniform(-6, 6, size=(size, 1))
        if rng.random() < 0.4:
            matrix[rng.random((size, size)) < 0.4] = 0.0
        expected = _textbook_inverse(matrix)
        inverse = np.full((size, size), np.nan)
        assert _invert(matrix.copy(), inverse) == (expected is not None)
        if expected is not None:
            assert np.array_equal(inverse, expected)


def test_the_damped_newton_solve_in_place_matches_numpy_and_finds_a_singular_matrix() -> None:
    """The damped Newton's LU solve (loop/compiled_reference.py ``_lu_solve``, in place of
    ``numpy.linalg.solve``): random, badly scaled and pivoting 11 x 11 systems give numpy's
    solution to 1e-12 relative, the right-hand side untouched; an exactly singular matrix
    returns False (where numpy raises LinAlgError: the damped Newton from that start ends)."""
    from ltv_lstm_mpc.loop.compiled_reference import _lu_solve

    rng = np.random.default_rng(4)
    pivots = np.empty(11, dtype=np.int64)
    for scale in (1.0, 1e-3, 1e3):
        matrix = rng.normal(size=(11, 11)) * scale
        matrix[0, 0] = 0.0  # the first column needs a row interchange
        rhs = rng.normal(size=11)
        kept = rhs.copy()
        out = np.empty(11)
        assert _lu_solve(matrix.copy(), rhs, out, pivots)
        expected = np.linalg.solve(matrix, rhs)
        assert np.abs(out - expected).max() <= 1e-12 * np.abs(expected).max()
        assert np.array_equal(rhs, kept)
    singular = rng.normal(size=(11, 11))
    singular[:, 4] = 0.0
    assert not _lu_solve(singular.copy(), np.ones(11), np.empty(11), pivots)
    with pytest.raises(np.linalg.LinAlgError):
        np.linalg.solve(singular, np.ones(11))
