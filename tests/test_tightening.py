"""Tightening a_i, b_i, P_f, alpha_k, Assumption 5 interval, Theorem 3 rate bound."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st
from lstm_factories import random_delta_iss_lstm

from ltv_lstm_mpc import (
    CertificationSettings,
    ObserverGains,
    certify,
    delta_iss_certificate,
    incremental_lyapunov_certificate,
    load_model,
    observer_certificate,
    tightening_certificate,
)
from ltv_lstm_mpc.certificates.stability import matrix_inverse_sqrt


def build(seed: int, l_d: float = 0.01, N: int = 5):
    rng = np.random.default_rng(seed)
    model = random_delta_iss_lstm(rng, 3)
    d = delta_iss_certificate(model)
    ly = incremental_lyapunov_certificate(model, d, 1000.0)
    ob = observer_certificate(model, d, ObserverGains.disturbance_only(model, l_d))
    ti = tightening_certificate(model, d, ly, ob, N=N, Q=np.eye(6), y_min=-1.0, y_max=1.0)
    return model, d, ly, ob, ti


@given(seed=st.integers(0, 2**32 - 1), N=st.integers(1, 30), l_d=st.sampled_from([0.01, 0.1, 1.0]))
def test_tightening_recursion_and_terminal_weight(seed: int, N: int, l_d: float) -> None:
    _model, d, ly, ob, ti = build(seed, l_d, N)
    assert ti.a.shape == (N + 1, 1) and ti.b.shape == (N + 1, 1)
    np.testing.assert_allclose(ti.a[0], ob.c_o)
    np.testing.assert_array_equal(ti.b[0], 0.0)
    for i in range(N):  # eq. (recursion_a_ji) with paper notes 2.3, eq. (recursion_b_i)
        expected = ob.rho_o * ti.a[i] + ly.rho_s**i * ly.c_s_u * ob.L_max * ly.c_s
        np.testing.assert_allclose(ti.a[i + 1], expected, rtol=1e-14)
        np.testing.assert_allclose(ti.b[i + 1], ti.b[i] + ti.a[i] * ob.w_bar, rtol=1e-14)
    # paper notes 2.6: Lyapunov equation with (1 + eps) q I, P_f >= 0 entrywise
    residual = d.A_delta.T @ ti.P_f @ d.A_delta - ti.P_f + (1 + ti.epsilon) * ti.q * np.eye(2)
    np.testing.assert_allclose(residual, 0.0, atol=1e-9 * np.max(ti.P_f))
    assert np.all(ti.P_f >= 0)
    assert ti.q == pytest.approx(1.0)
    assert ti.e_inf == pytest.approx(ob.w_bar / (1 - ob.rho_o))


@given(seed=st.integers(0, 2**32 - 1))
def test_terminal_set_implies_tightened_output_bound(seed: int) -> None:
    """Part 2a of Theorem 3's proof: x in X_f(k) satisfies the i = N tightened constraint."""
    rng = np.random.default_rng(seed)
    model, _d, _ly, ob, ti = build(seed)
    low, high = ti.setpoint_interval()
    if not low[0] < high[0]:
        return
    y0 = rng.uniform(low, high)
    e_hat = ti.e_inf * rng.uniform(0.5, 3.0)
    alpha = ti.alpha(y0, e_hat)
    d_hat = rng.uniform(-ob.d_max, ob.d_max, size=1)
    from ltv_lstm_mpc import ReferenceCalculator, UnreachableSetpointError

    try:
        ref = ReferenceCalculator(model).solve(y0, d_hat)
    except UnreachableSetpointError:
        return
    if alpha <= 0:
        return
    P_inv_sqrt = matrix_inverse_sqrt(ti.P_f)
    n = model.n
    for _ in range(30):  # points on the boundary of X_f(k) in the (||dc||, ||dh||) plane
        t = np.abs(P_inv_sqrt @ rng.normal(size=2))
        t *= alpha / np.sqrt(t @ ti.P_f @ t)
        direction = rng.normal(size=n)
        h = ref.x_bar[n:] + t[1] * direction / np.linalg.norm(direction)
        y_model = model.W_y @ h + model.b_y
        e_tilde = ti.e_tilde(e_hat)
        assert np.all(y_model + ti.d_max <= ti.y_max - ti.a[ti.N] * e_tilde - ti.b[ti.N] + 1e-12)
        assert np.all(y_model - ti.d_max >= ti.y_min + ti.a[ti.N] * e_tilde + ti.b[ti.N] - 1e-12)


def test_alpha_formula_and_interval_and_output_bounds() -> None:
    model, _d, _ly, ob, ti = build(3)
    y0 = np.array([0.1])
    e_hat = 2.0  # above e_inf: e_tilde = e_hat
    kappa = np.linalg.norm(
        np.array([0.0, np.linalg.norm(model.W_y[0])]) @ matrix_inverse_sqrt(ti.P_f)
    )
    margin = 2 * ti.d_max + ti.a[ti.N, 0] * e_hat + ti.b[ti.N, 0]
    expected = min(1.0 - 0.1 - margin, 0.1 + 1.0 - margin) / kappa
    assert ti.alpha(y0, e_hat) == pytest.approx(expected, rel=1e-13)
    # below e_inf the max in eq. (e_ok_bar) uses e_inf
    assert ti.alpha(y0, 0.0) == pytest.approx(ti.alpha(y0, ti.e_inf), rel=1e-14)
    low, high = ti.setpoint_interval()
    assert ti.alpha(low, ti.e_inf) == pytest.approx(0.0, abs=1e-12)
    assert ti.alpha(high, ti.e_inf) == pytest.approx(0.0, abs=1e-12)
    lower, upper = ti.output_bounds(e_hat)
    assert lower.shape == (5, 1)
    np.testing.assert_allclose(upper[:, 0], 1.0 - ti.a[:5, 0] * e_hat - ti.b[:5, 0] - ti.d_max)
    assert ti.next_e_hat(e_hat) == pytest.approx(ob.rho_o * e_hat + ob.w_bar)


def test_rate_bound_sign_and_void_case() -> None:
    _model, _d, _ly, _ob, ti = build(4)
    bound = ti.setpoint_rate_bound(alpha=0.5, e_hat=ti.e_inf, K_bar=2.0, e_y_bar=0.03)
    assert bound.holds and bound.delta_y0_max > 0
    lhs = np.sqrt(np.max(np.linalg.eigvalsh(ti.P_f))) * (
        ti.c_s_ratio_term * ti.e_inf + ti.rho_f * 2.0 * ti.L_d_norm * 0.03
        + ti.rho_f * 2.0 * bound.delta_y0_max
    ) + ti.rho_f * np.max(1 / ti.kappa) * bound.delta_y0_max  # fmt: skip
    assert lhs == pytest.approx((1 - ti.rho_f) * 0.5, rel=1e-12)  # tight at the bound
    void = ti.setpoint_rate_bound(alpha=0.0, e_hat=ti.e_inf, K_bar=2.0, e_y_bar=0.03)
    assert not void.holds and void.delta_y0_max == 0.0


def test_paper_scaling_invariances() -> None:
    """paper notes 2.9: rho_s, rho_o, a_i e_hat invariant to scaling Q_s, Q_o; c_o scales 1/sqrt."""
    model = load_model("example_delta_iss_n3.npz")
    c1 = certify(model, CertificationSettings(Q_s=1000.0, Q_o=1000.0, w_bar=0.01))
    c2 = certify(model, CertificationSettings(Q_s=10.0, Q_o=10.0, w_bar=0.001))
    assert c1.lyapunov.rho_s == pytest.approx(c2.lyapunov.rho_s, rel=1e-10)
    assert c1.observer.rho_o == pytest.approx(c2.observer.rho_o, rel=1e-10)
    assert c2.observer.c_o[0] == pytest.approx(10 * c1.observer.c_o[0], rel=1e-10)
    np.testing.assert_allclose(
        c1.tightening.a * c1.tightening.e_inf, c2.tightening.a * c2.tightening.e_inf, rtol=1e-9
    )
    np.testing.assert_allclose(c1.y0_interval, c2.y0_interval, rtol=1e-9)


def test_alpha_min_and_rate_bound_over_a_range() -> None:
    *_, ti = build(6)
    low, high = ti.setpoint_interval()
    grid = np.linspace(low[0], high[0], 201)
    inner = (low[0] + 0.3 * (high[0] - low[0]), high[0] - 0.2 * (high[0] - low[0]))
    dense = [ti.alpha([y], ti.e_inf) for y in grid if inner[0] <= y <= inner[1]]
    assert ti.alpha_min([inner[0]], [inner[1]], ti.e_inf) == pytest.approx(min(dense), abs=1e-3)
    # The rate bound is monotone in alpha: a wider operating range can only shrink it.
    narrow = ti.setpoint_rate_bound(ti.alpha_min([-0.05], [0.05], ti.e_inf), ti.e_inf,
                                    K_bar=2.0, e_y_bar=0.03)  # fmt: skip
    wide = ti.setpoint_rate_bound(ti.alpha_min([inner[0]], [inner[1]], ti.e_inf), ti.e_inf,
                                  K_bar=2.0, e_y_bar=0.03)  # fmt: skip
    assert wide.delta_y0_max <= narrow.delta_y0_max


def test_empty_setpoint_interval_is_an_error_at_construction() -> None:
    """Assumption 5 with no admissible set-point: a specific error naming the numbers."""
    from ltv_lstm_mpc import EmptySetpointIntervalError, MPCConfig, OffsetFreeController, load_model

    model = load_model("ph_lstm_n5.npz")
    y_min, y_max = model.normalize_y([6.9])[0], model.normalize_y([7.1])[0]
    config = MPCConfig(solver="daqp", y_min=float(y_min), y_max=float(y_max))
    with pytest.raises(EmptySetpointIntervalError) as info:
        OffsetFreeController(model, config)
    message = str(info.value)
    for text in ("[6.9, 7.1] in physical units", "2 d_max = 0.2", "a_N e_tilde + b_N", "d_max"):
        assert text in message
    # a wide enough constraint constructs
    OffsetFreeController(model, MPCConfig(solver="daqp"))
