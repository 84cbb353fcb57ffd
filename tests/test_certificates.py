"""Certificates: Theorem 1, Lemma 2, Theorem 2, Lemma 4 as properties; hand-computed values."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st
from lstm_factories import random_delta_iss_lstm, random_lstm

from ltv_lstm_mpc import (
    InvalidValueError,
    LSTMModel,
    NotDeltaISSError,
    Observer,
    ObserverGainError,
    ObserverGains,
    delta_iss_certificate,
    design_observer_gains,
    incremental_lyapunov_certificate,
    observer_certificate,
)

TOL = 1e-12


def sample_state(rng: np.random.Generator, model: LSTMModel, c_bound: float) -> np.ndarray:
    """A state in X = C x H of Theorem 1 (sometimes on the boundary)."""
    c = rng.uniform(-c_bound, c_bound, size=model.n)
    h = rng.uniform(-1, 1, size=model.n)
    if rng.random() < 0.2:
        c = np.sign(c) * c_bound
    return np.concatenate([c, h])


def error_pair(model: LSTMModel, x_a: np.ndarray, x_b: np.ndarray) -> np.ndarray:
    n = model.n
    return np.array([np.linalg.norm(x_a[:n] - x_b[:n]), np.linalg.norm(x_a[n:] - x_b[n:])])


@given(seed=st.integers(0, 2**32 - 1), n=st.integers(1, 5), near=st.booleans())
def test_theorem1_bound_and_lemma2_decrease(seed: int, n: int, near: bool) -> None:
    rng = np.random.default_rng(seed)
    model = random_delta_iss_lstm(rng, n)
    cert = delta_iss_certificate(model, require=True)
    lyap = incremental_lyapunov_certificate(model, cert, 1000.0)
    for _ in range(20):
        x_a = sample_state(rng, model, cert.c_bound)
        x_b = sample_state(rng, model, cert.c_bound)
        if near:  # nearby pairs probe the linear regime, where bounds are tightest
            x_b = np.clip(x_a + 1e-3 * rng.normal(size=2 * n), -cert.c_bound, cert.c_bound)
            x_b[n:] = np.clip(x_b[n:], -1, 1)
        u_a = rng.uniform(-1, 1, size=1)
        u_b = rng.uniform(-1, 1, size=1)
        # eq. (bound_lstm_trajectory)
        lhs = error_pair(model, model.step(x_a, u_a), model.step(x_b, u_b))
        rhs = cert.A_delta @ error_pair(model, x_a, x_b) + cert.B_delta * np.linalg.norm(u_a - u_b)
        assert np.all(lhs <= rhs + TOL), (lhs, rhs)
        # eq. (incremental_lyap_neg_def): same input
        v_now = lyap.V_s(model, x_a, x_b)
        v_next = lyap.V_s(model, model.step(x_a, u_a), model.step(x_b, u_a))
        assert v_next <= lyap.rho_s * v_now + TOL
        # eq. (incremental_lyap_pos_def) and (incremental_lyap_constraints)
        dist = np.linalg.norm(x_a - x_b)
        assert lyap.c_s_l * dist - TOL <= v_now <= lyap.c_s_u * dist + TOL
        y_gap = np.abs(model.W_y @ (x_a[n:] - x_b[n:]))
        assert np.all(y_gap <= lyap.c_s * v_now + TOL)


@given(seed=st.integers(0, 2**32 - 1))
def test_invariant_set_of_theorem1(seed: int) -> None:
    rng = np.random.default_rng(seed)
    model = random_delta_iss_lstm(rng, 4)
    cert = delta_iss_certificate(model)
    x = sample_state(rng, model, cert.c_bound)
    for u in rng.uniform(-1, 1, size=(50, 1)):
        x = model.step(x, u)
        assert np.max(np.abs(x[:4])) <= cert.c_bound + TOL
        assert np.max(np.abs(x[4:])) <= 1.0


def literal_typo_model() -> LSTMModel:
    """n = 1: U_f = U_c = 0 and U_i = 1, so the literal alpha (with ||U_c||) is 0."""
    one = np.ones((1, 1))
    zero = np.zeros((1, 1))
    return LSTMModel(
        W_f=0.1 * one, U_f=zero, b_f=np.zeros(1),
        W_i=0.1 * one, U_i=one, b_i=np.zeros(1),
        W_o=0.1 * one, U_o=zero, b_o=np.zeros(1),
        W_c=0.1 * one, U_c=zero, b_c=np.ones(1),
        W_y=one, b_y=np.zeros(1),
    )  # fmt: skip


def test_literal_alpha_typo_violates_theorem1_but_corrected_holds() -> None:
    model = literal_typo_model()
    corrected = delta_iss_certificate(model, require=True)
    literal = delta_iss_certificate(model, alpha_variant="literal")
    assert literal.alpha == pytest.approx(0.0, abs=1e-15)
    assert corrected.alpha > 0.19
    # Same c and u, different h: c+ differs only through the input gate.
    x_a = np.array([0.0, 1.0])
    x_b = np.array([0.0, -1.0])
    u = np.array([0.0])
    lhs = error_pair(model, model.step(x_a, u), model.step(x_b, u))
    gap = error_pair(model, x_a, x_b)
    assert lhs[0] > 0.1  # the cell states really do separate
    assert lhs[0] > (literal.A_delta @ gap)[0] + 0.1  # literal paper bound violated
    assert np.all(lhs <= corrected.A_delta @ gap + TOL)  # paper notes 2.2 bound holds


def test_certificates_by_hand_for_a_one_neuron_model() -> None:
    """n = m = p = 1 with round numbers; every value computed here with scalar formulas."""
    w = {"f": (0.2, 0.4, -0.1), "i": (0.3, -0.2, 0.1), "o": (-0.1, 0.5, 0.2), "c": (0.6, 0.3, -0.2)}
    args = {}
    for gate, (W, U, b) in w.items():
        args[f"W_{gate}"], args[f"U_{gate}"], args[f"b_{gate}"] = [[W]], [[U]], [b]
    model = LSTMModel(**args, W_y=[[2.0]], b_y=[0.5])
    sig = lambda z: 1 / (1 + math.exp(-z))  # noqa: E731
    s_f = sig(0.2 + 0.4 + 0.1)  # |W| u_max + |U| + |b| with u_max = 1
    s_i = sig(0.3 + 0.2 + 0.1)
    s_o = sig(0.1 + 0.5 + 0.2)
    s_c = math.tanh(0.6 + 0.3 + 0.2)
    c_bound = s_i * s_c / (1 - s_f)
    s_x = math.tanh(c_bound)
    alpha = 0.25 * 0.4 * c_bound + s_i * 0.3 + 0.25 * 0.2 * s_c  # paper notes 2.2: ||U_i|| last
    beta = 0.25 * 0.2 * c_bound + s_i * 0.6 + 0.25 * 0.3 * s_c
    A = np.array([[s_f, alpha], [s_o * s_f, alpha * s_o + 0.25 * s_x * 0.5]])
    cert = delta_iss_certificate(model)
    for got, want in [(cert.sigma_f, s_f), (cert.sigma_i, s_i), (cert.sigma_o, s_o),
                      (cert.sigma_c, s_c), (cert.sigma_x, s_x), (cert.alpha, alpha),
                      (cert.beta, beta), (cert.c_bound, c_bound)]:  # fmt: skip
        assert got == pytest.approx(want, rel=1e-14)
    np.testing.assert_allclose(cert.A_delta, A, rtol=1e-14)
    np.testing.assert_allclose(cert.B_delta, [beta, beta * s_o + 0.25 * s_x * 0.1], rtol=1e-14)
    trace, det = A[0, 0] + A[1, 1], A[0, 0] * A[1, 1] - A[0, 1] * A[1, 0]
    assert cert.r1 == pytest.approx(trace - 1 - det, abs=1e-14)  # Jury: trace < 1 + det
    assert cert.r2 == pytest.approx(det - 1, abs=1e-14)  # Jury: det < 1
    rho = max(abs(np.roots([1, -trace, det])))
    assert cert.rho_A_delta == pytest.approx(rho, rel=1e-12)
    # Lemma 2 with Q_s = 1000 I: P_s as the series sum (A')^k Q A^k.
    P = sum(np.linalg.matrix_power(A.T, k) @ (1000 * np.eye(2)) @ np.linalg.matrix_power(A, k)
            for k in range(3000))  # fmt: skip
    lyap = incremental_lyapunov_certificate(model, cert, 1000.0)
    np.testing.assert_allclose(lyap.P_s, P, rtol=1e-10)
    lam = np.linalg.eigvalsh(P)
    assert lyap.rho_s == pytest.approx(math.sqrt(1 - 1000 / lam[1]), rel=1e-10)
    assert lyap.c_s_l == pytest.approx(math.sqrt(lam[0]), rel=1e-10)
    P_inv = np.linalg.inv(P)  # ||[0, 2] P^{-1/2}|| = sqrt([0,2] P^{-1} [0,2]')
    assert lyap.c_s[0] == pytest.approx(math.sqrt(4 * P_inv[1, 1]), rel=1e-10)
    # Observer with L_f = L_i = L_o = 0, L_d = 0.1 (Remark 3): A_d = [[A, 0], [0, 0.2, 0.9]].
    gains = ObserverGains.disturbance_only(model, 0.1)
    obs = observer_certificate(model, cert, gains, d_max=0.1, w_bar=0.01, Q_o=1000.0)
    A_d = np.zeros((3, 3))
    A_d[:2, :2] = A
    A_d[2, 1:] = [0.1 * 2.0, 0.9]
    np.testing.assert_allclose(obs.A_d, A_d, rtol=1e-14)
    P_o = sum(np.linalg.matrix_power(A_d.T, k) @ (1000 * np.eye(3)) @ np.linalg.matrix_power(A_d, k)
              for k in range(5000))  # fmt: skip
    np.testing.assert_allclose(obs.P_o, P_o, rtol=1e-9)
    assert obs.w_max == pytest.approx(0.01 / math.sqrt(P_o[2, 2]), rel=1e-9)
    assert obs.e_inf == pytest.approx(0.01 / (1 - obs.rho_o), rel=1e-12)
    # L of Theorem 2's proof: only the disturbance row is nonzero for these gains.
    np.testing.assert_allclose(obs.L, [[0, 0, 0], [0, 0, 0], [0, 0.2, 0.1]], atol=1e-15)
    assert obs.L_max == pytest.approx(
        np.linalg.norm(obs.L @ np.linalg.inv(np.linalg.cholesky(P_o)).T, 2), rel=1e-9
    )


def test_not_delta_iss_raises_with_numbers() -> None:
    model = random_lstm(np.random.default_rng(0), 4, scale=2.0)
    cert = delta_iss_certificate(model)
    assert cert.rho_A_delta >= 1
    with pytest.raises(NotDeltaISSError) as info:
        delta_iss_certificate(model, require=True)
    assert info.value.rho_A_delta == pytest.approx(cert.rho_A_delta)
    assert info.value.r1 == pytest.approx(cert.r1)
    assert "rho(A_delta)" in str(info.value)
    with pytest.raises(NotDeltaISSError):
        incremental_lyapunov_certificate(model, cert)


def test_bad_observer_gains_raise() -> None:
    model = random_delta_iss_lstm(np.random.default_rng(1), 3)
    cert = delta_iss_certificate(model)
    with pytest.raises(ObserverGainError, match=r"rho\(A_d\) = 1.5"):
        observer_certificate(model, cert, ObserverGains.disturbance_only(model, 2.5))


def observer_gain_cases(model: LSTMModel, rng: np.random.Generator) -> list[ObserverGains]:
    small = lambda: 0.05 * rng.normal(size=(model.n, model.p))  # noqa: E731
    return [
        ObserverGains.disturbance_only(model, 0.01),
        ObserverGains.disturbance_only(model, 0.5),
        ObserverGains(L_f=small(), L_i=small(), L_o=small(), L_d=0.1 * np.eye(model.p)),
    ]


@given(seed=st.integers(0, 2**32 - 1), case=st.integers(0, 2))
def test_theorem2_and_lemma4_on_random_observer_trajectories(seed: int, case: int) -> None:
    rng = np.random.default_rng(seed)
    model = random_delta_iss_lstm(rng, 3)
    cert = delta_iss_certificate(model)
    gains = observer_gain_cases(model, rng)[case]
    d_max, w_bar = 0.1, 0.01
    try:
        obs_cert = observer_certificate(model, cert, gains, d_max=d_max, w_bar=w_bar, Q_o=1000.0)
    except ObserverGainError:
        return  # random gains may violate Assumption 3; that is tested elsewhere
    w_max = obs_cert.w_max
    n = model.n
    x = sample_state(rng, model, cert.c_bound)
    d = rng.uniform(-d_max, d_max, size=1)
    observer = Observer(model, gains, d_max=d_max,
                        x_hat0=sample_state(rng, model, obs_cert.c_hat_bound),
                        d_hat0=rng.uniform(-d_max, d_max, size=1))  # fmt: skip
    for _ in range(40):
        u = rng.uniform(-1, 1, size=1)
        w = rng.choice([-1.0, 1.0]) * w_max * rng.uniform(0.5, 1.0, size=1)
        if abs(d[0] + w[0]) > d_max:
            w = -w  # keep d in D
        y = model.output(x) + d
        x_hat, d_hat = observer.x_hat.copy(), observer.d_hat.copy()
        V_now = obs_cert.V_o(model, x_hat, d_hat, x, d)
        # eq. (lyap_observer_constraint) (paper notes 2.4: V_o)
        gap = np.abs(model.W_y @ (x[n:] - x_hat[n:]) + (d - d_hat))
        assert np.all(gap <= obs_cert.c_o * V_now + TOL)
        x_hat_next, d_hat_next = observer.step(y, u)
        x_next, d_next = model.step(x, u), d + w
        # eq. (lyap_observer_neg_def)
        V_next = obs_cert.V_o(model, x_hat_next, d_hat_next, x_next, d_next)
        assert V_next <= obs_cert.rho_o * V_now + w_bar + TOL
        # eq. (lyap_observer_max_gain): distance from the open-loop model prediction
        prediction = np.concatenate([model.step(x_hat, u), d_hat])
        jump = np.linalg.norm(np.concatenate([x_hat_next, d_hat_next]) - prediction)
        assert jump <= obs_cert.L_max * V_now + TOL
        # Lemma 4: the observer state stays in C_hat x H x D
        assert np.max(np.abs(x_hat_next[:n])) <= obs_cert.c_hat_bound + TOL
        assert np.max(np.abs(x_hat_next[n:])) <= 1.0
        assert np.max(np.abs(d_hat_next)) <= d_max
        x, d = x_next, d_next


def test_observer_converges_without_disturbance_variation() -> None:
    """Theorem 2, last claim: w -> 0 implies the estimate converges."""
    rng = np.random.default_rng(11)
    model = random_delta_iss_lstm(rng, 3)
    gains = ObserverGains.disturbance_only(model, 0.5)
    observer = Observer(model, gains, d_max=0.1)
    x, d = np.zeros(6), np.array([0.05])
    for _ in range(400):
        u = rng.uniform(-1, 1, size=1)
        observer.step(model.output(x) + d, u)
        x = model.step(x, u)
    np.testing.assert_allclose(observer.x_hat, x, atol=1e-8)
    np.testing.assert_allclose(observer.d_hat, d, atol=1e-8)


def test_design_observer_gains_never_worse_than_fallback() -> None:
    rng = np.random.default_rng(2)
    model = random_delta_iss_lstm(rng, 2)
    cert = delta_iss_certificate(model)
    fallback = observer_certificate(model, cert, ObserverGains.disturbance_only(model, 1.0))
    gains, designed = design_observer_gains(model, cert, 1.0, max_evaluations=300)
    assert designed.rho_A_d < 1
    assert designed.rho_A_d + designed.L_max <= fallback.rho_A_d + fallback.L_max + 1e-12
    np.testing.assert_allclose(gains.L_d, np.eye(1))


def test_non_monotone_lyapunov_weights_are_rejected() -> None:
    """A Q_s with a negative off-diagonal gives P_s < 0 somewhere; Lemma 2's proof (and the
    bound, by counterexample in review) then fails, so the certificate refuses it."""
    model = random_delta_iss_lstm(np.random.default_rng(5), 3)
    cert = delta_iss_certificate(model)
    with pytest.raises(InvalidValueError, match=r"(?s)P_s = .* has negative entries"):
        incremental_lyapunov_certificate(
            model, cert, 1000.0 * np.array([[1.0, -0.99], [-0.99, 1.0]])
        )
    with pytest.raises(InvalidValueError, match=r"(?s)P_o = .* has negative entries"):
        Q_o = 1000.0 * np.array([[1.0, 0.0, -0.9], [0.0, 1.0, 0.0], [-0.9, 0.0, 1.0]])
        observer_certificate(model, cert, ObserverGains.disturbance_only(model, 0.1), Q_o=Q_o)


@pytest.mark.parametrize("shift", [40.0, 20.0])
def test_saturated_forget_gate_is_not_delta_iss_never_an_arithmetic_error(shift: float) -> None:
    """b_f = 40 makes sigma_f exactly 1.0 in floating point: no bound on the cell state."""
    from ltv_lstm_mpc import certify, load_model

    base = load_model("ph_lstm_n5.npz")
    weights = base.weights()
    weights["b_f"] = weights["b_f"] + shift
    model = LSTMModel(**weights, normalization=base.normalization)
    certificate = delta_iss_certificate(model)
    assert certificate.rho_A_delta >= 1.0 and not certificate.is_delta_iss
    with pytest.raises(NotDeltaISSError, match=r"rho\(A_delta\) = ") as info:
        certify(model)
    if shift == 40.0:
        assert certificate.sigma_f == 1.0 and math.isinf(certificate.rho_A_delta)
        assert "forget gate saturates (sigma_f = 1.0)" in str(info.value)
