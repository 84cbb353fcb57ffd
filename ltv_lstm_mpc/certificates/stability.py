r"""Stability certificates of the LSTM model and of its observer.

Pure functions returning frozen dataclasses; every field carries the paper's symbol.

* :func:`delta_iss_certificate` — Assumption 2, Theorem 1 and Remark 1: gate bounds
  :math:`\bar\sigma`, :math:`\alpha`, :math:`\beta`, :math:`A_\delta`, :math:`B_\delta`,
  :math:`\rho(A_\delta)`, the Jury residuals :math:`r_1, r_2` and the invariant set
  :math:`\mathcal{X} = \mathcal{C} \times \mathcal{H}`.
* :func:`incremental_lyapunov_certificate` — Lemma 2: :math:`P_s, c_{s,l}, c_{s,u},
  \rho_s, c_s`.
* :func:`observer_certificate` — Assumption 3, Lemma 4 and Theorem 2: hat sigmas,
  :math:`\hat\alpha, \hat\beta, \hat\gamma, A_d, P_o, \rho_o, c_{o,l}, c_{o,u}, c_o,
  w_{max}`, the matrix :math:`L` and :math:`L_{max}`.
* :func:`design_observer_gains` — paper notes 2.11.

Norms follow paper notes 2.7: :math:`\|\cdot\|` is the vector 2-norm / induced 2-norm,
except inside the :math:`\bar\sigma` and :math:`\hat{\bar\sigma}` definitions, which
use the induced inf-norm of the concatenated block row.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Literal

import numpy as np
import scipy.linalg
import scipy.optimize
from numpy.typing import ArrayLike, NDArray

from ltv_lstm_mpc.exceptions import (
    DimensionError,
    InvalidValueError,
    NotDeltaISSError,
    ObserverGainError,
)
from ltv_lstm_mpc.lstm.model import LSTMModel, require_model
from ltv_lstm_mpc.validation import (
    expect_bool,
    expect_instance,
    expect_int,
    expect_real,
    finite_array,
)

__all__ = [
    "DeltaISSCertificate",
    "IncrementalLyapunovCertificate",
    "ObserverCertificate",
    "ObserverGains",
    "delta_iss_certificate",
    "design_observer_gains",
    "incremental_lyapunov_certificate",
    "matrix_inverse_sqrt",
    "observer_certificate",
    "solve_lyapunov",
]

FloatArray = NDArray[np.float64]
AlphaVariant = Literal["corrected", "literal"]


def _sigmoid(z: float) -> float:
    return float(0.5 * (1.0 + np.tanh(0.5 * z)))


def _spectral_norm(matrix: FloatArray) -> float:
    """Induced 2-norm (largest singular value)."""
    return float(np.linalg.norm(matrix, 2))


def _block_row_inf_norm(*blocks: FloatArray) -> float:
    """Induced inf-norm (max absolute row sum) of the block row ``[B_1, B_2, ...]``."""
    rows = np.hstack([np.atleast_2d(b.reshape(b.shape[0], -1)) for b in blocks])
    return float(np.max(np.sum(np.abs(rows), axis=1)))


def solve_lyapunov(A: FloatArray, Q: FloatArray) -> FloatArray:
    r"""Solve the discrete Lyapunov equation :math:`A^\top P A - P = -Q` for P.

    Uses :func:`scipy.linalg.solve_discrete_lyapunov`, which solves
    :math:`a X a^H - X + q = 0`; here ``a = A.T``. The result is symmetrized.
    """
    P = scipy.linalg.solve_discrete_lyapunov(A.T, Q)
    return np.asarray(0.5 * (P + P.T), dtype=np.float64)


def matrix_inverse_sqrt(P: FloatArray) -> FloatArray:
    r""":math:`P^{-1/2}` of a symmetric positive definite matrix (eigendecomposition)."""
    eigenvalues, eigenvectors = np.linalg.eigh(P)
    if np.min(eigenvalues) <= 0:
        raise InvalidValueError(f"matrix is not positive definite (eigenvalues {eigenvalues})")
    return np.asarray((eigenvectors / np.sqrt(eigenvalues)) @ eigenvectors.T, dtype=np.float64)


def _as_spd(name: str, Q: ArrayLike, size: int) -> FloatArray:
    Q_arr = np.asarray(Q, dtype=np.float64)
    if Q_arr.ndim == 0:
        Q_arr = float(Q_arr) * np.eye(size)
    if Q_arr.shape != (size, size):
        raise DimensionError(f"{name} has shape {Q_arr.shape}, expected ({size}, {size}) or scalar")
    if not np.all(np.isfinite(Q_arr)):
        raise InvalidValueError(f"{name} contains NaN or inf")
    if not np.allclose(Q_arr, Q_arr.T):
        raise InvalidValueError(f"{name} must be symmetric")
    if np.min(np.linalg.eigvalsh(Q_arr)) <= 0:
        raise InvalidValueError(
            f"{name} must be positive definite, eigenvalues {np.linalg.eigvalsh(Q_arr)}"
        )
    return Q_arr


def _require_nonnegative(name: str, P: FloatArray, weight: str) -> None:
    """The proofs of Lemma 2 / Theorem 2 need ||.||_P monotone on the nonnegative orthant."""
    if np.any(P < -1e-12 * float(np.max(np.abs(P)))):
        raise InvalidValueError(
            f"{name} = {np.array2string(P, precision=4)} has negative entries: the proof needs "
            f"{name} >= 0 entrywise so that its norm is monotone on the nonnegative orthant "
            f"(otherwise the bound can fail). Use a diagonal or entrywise nonnegative {weight}."
        )


def _positive(name: str, value: float) -> float:
    return expect_real(name, value, low=0.0, low_open=True)


# --------------------------------------------------------------------------- delta-ISS
@dataclass(frozen=True)
class DeltaISSCertificate:
    r"""delta-ISS certificate of an LSTM model (Assumption 2, Theorem 1, Remark 1).

    Attributes
    ----------
    u_max : float
        Input bound :math:`u_{max}` of :math:`\mathcal{U} = \{\|u\|_\infty \le u_{max}\}`.
    sigma_f, sigma_i, sigma_o : float
        Gate bounds :math:`\bar\sigma^f, \bar\sigma^i, \bar\sigma^o`
        = :math:`\sigma(\|[W u_{max}\; U\; b]\|_\infty)`.
    sigma_c : float
        Cell-candidate bound :math:`\bar\sigma^c = \tanh(\|[W_c u_{max}\; U_c\; b_c]\|_\infty)`.
    sigma_x : float
        :math:`\bar\sigma^x = \tanh(\bar\sigma^i \bar\sigma^c / (1 - \bar\sigma^f))`.
    alpha : float
        :math:`\alpha` of Assumption 2 (with the paper notes 2.2 correction unless
        ``alpha_variant == "literal"``).
    beta : float
        :math:`\beta` of Theorem 1.
    A_delta : ndarray, shape (2, 2)
        :math:`A_\delta`, eq. (delta_iss_matrix); entrywise nonnegative.
    B_delta : ndarray, shape (2,)
        :math:`B_\delta` of Theorem 1.
    rho_A_delta : float
        Spectral radius :math:`\rho(A_\delta)`; delta-ISS iff < 1.
    r1, r2 : float
        Residuals of Remark 1 (Jury criterion); delta-ISS iff both < 0.
    c_bound : float
        :math:`\bar\sigma^i \bar\sigma^c / (1 - \bar\sigma^f)`: the invariant set
        :math:`\mathcal{C} = \{\|c\|_\infty \le c_{bound}\}`.
    h_bound : float
        1: the invariant set :math:`\mathcal{H} = \{\|h\|_\infty \le 1\}`.
    alpha_variant : str
        ``"corrected"`` (paper notes 2.2: last term :math:`\frac14\|U_i\|\bar\sigma^c`) or
        ``"literal"`` (the paper's printed :math:`\frac14\|U_c\|\bar\sigma^c`, for
        comparison only; it is not a valid bound).
    """

    u_max: float
    sigma_f: float
    sigma_i: float
    sigma_o: float
    sigma_c: float
    sigma_x: float
    alpha: float
    beta: float
    A_delta: FloatArray
    B_delta: FloatArray
    rho_A_delta: float
    r1: float
    r2: float
    c_bound: float
    h_bound: float
    alpha_variant: str

    @property
    def is_delta_iss(self) -> bool:
        r"""True iff :math:`\rho(A_\delta) < 1` (Assumption 2)."""
        return self.rho_A_delta < 1.0

    def require(self) -> DeltaISSCertificate:
        """Return self, or raise :class:`NotDeltaISSError` if rho(A_delta) >= 1."""
        if not self.is_delta_iss:
            raise NotDeltaISSError(
                f"the LSTM model is not certified delta-ISS (Assumption 2): "
                f"rho(A_delta) = {self.rho_A_delta:.6f} >= 1 (Remark 1 residuals "
                f"r1 = {self.r1:.4g}, "
                f"r2 = {self.r2:.4g}, both must be < 0)"
                + (
                    f"; the forget gate saturates (sigma_f = {self.sigma_f!r}), so the cell "
                    "state has no bound"
                    if not self.sigma_f < 1.0
                    else ""
                )
                + ". Retrain with the delta-ISS penalty (ltv-lstm-mpc train) or reduce u_max.",
                rho_A_delta=self.rho_A_delta,
                r1=self.r1,
                r2=self.r2,
            )
        return self


def _model_and_delta_iss(
    model: LSTMModel, delta_iss: DeltaISSCertificate
) -> tuple[LSTMModel, DeltaISSCertificate]:
    """The model and its delta-ISS certificate, type-checked (the certificates' inputs)."""
    hint = "compute it with delta_iss_certificate(model, u_max)"
    expected = "a DeltaISSCertificate"
    delta_iss = expect_instance(
        "delta_iss", delta_iss, DeltaISSCertificate, hint, expected=expected
    )
    return require_model(model), delta_iss


def delta_iss_certificate(
    model: LSTMModel,
    u_max: float = 1.0,
    *,
    alpha_variant: AlphaVariant = "corrected",
    require: bool = False,
) -> DeltaISSCertificate:
    r"""Compute the delta-ISS certificate of Assumption 2 / Theorem 1 / Remark 1.

    .. math::

        A_\delta = \begin{bmatrix} \bar\sigma^f & \alpha \\
        \bar\sigma^o \bar\sigma^f & \alpha \bar\sigma^o + \frac14 \bar\sigma^x \|U_o\|
        \end{bmatrix}, \quad
        B_\delta = \begin{bmatrix} \beta \\ \beta \bar\sigma^o + \frac14 \bar\sigma^x \|W_o\|
        \end{bmatrix}

        \alpha = \tfrac14 \|U_f\| \frac{\bar\sigma^i\bar\sigma^c}{1-\bar\sigma^f}
        + \bar\sigma^i \|U_c\| + \tfrac14 \|U_i\| \bar\sigma^c \quad (\text{paper notes 2.2})

    Parameters
    ----------
    model : LSTMModel
    u_max : float
        Input bound of :math:`\mathcal{U}` (normalized units), default 1.
    alpha_variant : {"corrected", "literal"}
        ``"literal"`` reproduces the paper's printed :math:`\frac14\|U_c\|\bar\sigma^c`
        typo (paper notes 2.2) for comparison; never use it for a certificate.
    require : bool
        Raise :class:`NotDeltaISSError` when :math:`\rho(A_\delta) \ge 1`.
    """
    model = require_model(model)
    expect_bool("require", require)
    u_max = _positive("u_max", u_max)
    if alpha_variant not in ("corrected", "literal"):
        raise InvalidValueError(
            f"alpha_variant must be 'corrected' or 'literal', got {alpha_variant!r}"
        )
    sigma_f = _sigmoid(_block_row_inf_norm(model.W_f * u_max, model.U_f, model.b_f[:, None]))
    sigma_i = _sigmoid(_block_row_inf_norm(model.W_i * u_max, model.U_i, model.b_i[:, None]))
    sigma_o = _sigmoid(_block_row_inf_norm(model.W_o * u_max, model.U_o, model.b_o[:, None]))
    sigma_c = float(np.tanh(_block_row_inf_norm(model.W_c * u_max, model.U_c, model.b_c[:, None])))
    # A saturated forget gate (sigma_f = 1 in floating point, e.g. b_f = 40) bounds no cell
    # state: c_bound is infinite and so is rho(A_delta) (its (1,1) entry is already 1).
    saturated = not sigma_f < 1.0
    c_bound = math.inf if saturated else sigma_i * sigma_c / (1.0 - sigma_f)
    sigma_x = float(np.tanh(c_bound))
    norm_U_o = _spectral_norm(model.U_o)
    last_U = model.U_i if alpha_variant == "corrected" else model.U_c
    alpha = (
        0.25 * _spectral_norm(model.U_f) * c_bound
        + sigma_i * _spectral_norm(model.U_c)
        + 0.25 * _spectral_norm(last_U) * sigma_c
    )
    beta = (
        0.25 * _spectral_norm(model.W_f) * c_bound
        + sigma_i * _spectral_norm(model.W_c)
        + 0.25 * _spectral_norm(model.W_i) * sigma_c
    )
    A_delta = np.array(
        [
            [sigma_f, alpha],
            [sigma_o * sigma_f, alpha * sigma_o + 0.25 * sigma_x * norm_U_o],
        ]
    )
    B_delta = np.array([beta, beta * sigma_o + 0.25 * sigma_x * _spectral_norm(model.W_o)])
    r1 = (
        -1.0
        + sigma_f
        + alpha * sigma_o
        + 0.25 * sigma_x * norm_U_o
        - 0.25 * sigma_f * sigma_x * norm_U_o
    )
    r2 = 0.25 * sigma_f * sigma_x * norm_U_o - 1.0
    A_delta.setflags(write=False)
    B_delta.setflags(write=False)
    certificate = DeltaISSCertificate(
        u_max=u_max,
        sigma_f=sigma_f,
        sigma_i=sigma_i,
        sigma_o=sigma_o,
        sigma_c=sigma_c,
        sigma_x=sigma_x,
        alpha=alpha,
        beta=beta,
        A_delta=A_delta,
        B_delta=B_delta,
        rho_A_delta=(
            float(np.max(np.abs(np.linalg.eigvals(A_delta))))
            if np.all(np.isfinite(A_delta))
            else math.inf
        ),
        r1=r1,
        r2=r2,
        c_bound=c_bound,
        h_bound=1.0,
        alpha_variant=alpha_variant,
    )
    return certificate.require() if require else certificate


# ---------------------------------------------------------------- incremental Lyapunov
@dataclass(frozen=True)
class IncrementalLyapunovCertificate:
    r"""Incremental Lyapunov function :math:`V_s` of Lemma 2.

    :math:`V_s(x_a, x_b) = \| [\|c_a - c_b\|, \|h_a - h_b\|] \|_{P_s}`.

    Attributes
    ----------
    Q_s : ndarray, shape (2, 2)
        Weight of the Lyapunov equation :math:`A_\delta^\top P_s A_\delta - P_s = -Q_s`.
    P_s : ndarray, shape (2, 2)
        Its solution.
    c_s_l, c_s_u : float
        :math:`c_{s,l} = \sqrt{\lambda_{min}(P_s)}`, :math:`c_{s,u} = \sqrt{\lambda_{max}(P_s)}`,
        eq. (incremental_lyap_pos_def).
    rho_s : float
        :math:`\rho_s = \sqrt{1 - \lambda_{min}(Q_s)/\lambda_{max}(P_s)}`,
        eq. (incremental_lyap_neg_def).
    c_s : ndarray, shape (p,)
        :math:`c_{s(j)} = \|[0\; \|W_{y(j*)}\|] P_s^{-1/2}\|`, eq. (incremental_lyap_constraints).
    """

    Q_s: FloatArray
    P_s: FloatArray
    c_s_l: float
    c_s_u: float
    rho_s: float
    c_s: FloatArray

    def V_s(self, model: LSTMModel, x_a: ArrayLike, x_b: ArrayLike) -> float:
        """Evaluate :math:`V_s(x_a, x_b)` of Lemma 2."""
        c_a, h_a = model.split_state(x_a)
        c_b, h_b = model.split_state(x_b)
        e = np.array([np.linalg.norm(c_a - c_b), np.linalg.norm(h_a - h_b)])
        return float(np.sqrt(e @ self.P_s @ e))


def incremental_lyapunov_certificate(
    model: LSTMModel,
    delta_iss: DeltaISSCertificate,
    Q_s: ArrayLike = 1000.0,
) -> IncrementalLyapunovCertificate:
    r"""Lemma 2: incremental Lyapunov function of a delta-ISS LSTM for a given :math:`Q_s`.

    Parameters
    ----------
    model : LSTMModel
    delta_iss : DeltaISSCertificate
        Must certify delta-ISS (raises :class:`NotDeltaISSError` otherwise).
    Q_s : float or array_like, shape (2, 2)
        Symmetric positive definite weight; a scalar q means q I_2 (paper: 1000 I).
    """
    model, delta_iss = _model_and_delta_iss(model, delta_iss)
    delta_iss.require()
    Q = _as_spd("Q_s", Q_s, 2)
    P_s = solve_lyapunov(delta_iss.A_delta, Q)
    _require_nonnegative("P_s", P_s, "Q_s")
    eig_P = np.linalg.eigvalsh(P_s)
    P_inv_sqrt = matrix_inverse_sqrt(P_s)
    row_norms = np.linalg.norm(model.W_y, axis=1)
    c_s = np.array([np.linalg.norm(np.array([0.0, r]) @ P_inv_sqrt) for r in row_norms])
    for array in (Q, P_s, c_s):
        array.setflags(write=False)
    return IncrementalLyapunovCertificate(
        Q_s=Q,
        P_s=P_s,
        c_s_l=float(np.sqrt(eig_P[0])),
        c_s_u=float(np.sqrt(eig_P[-1])),
        rho_s=float(np.sqrt(1.0 - np.min(np.linalg.eigvalsh(Q)) / eig_P[-1])),
        c_s=c_s,
    )


# ---------------------------------------------------------------------------- observer
@dataclass(frozen=True)
class ObserverGains:
    r"""Gains of the observer eq. (lstm_observer).

    Attributes
    ----------
    L_f, L_i, L_o : ndarray, shape (n, p)
        Output-injection gains in the forget, input and output gates.
    L_d : ndarray, shape (p, p)
        Disturbance-estimate gain (paper: 0.01 or 0.1 times identity).
    """

    L_f: FloatArray
    L_i: FloatArray
    L_o: FloatArray
    L_d: FloatArray

    def __post_init__(self) -> None:
        for name in ("L_f", "L_i", "L_o", "L_d"):
            value = np.array(finite_array(name, getattr(self, name)))
            if value.ndim == 0:
                value = value.reshape(1, 1)
            if value.ndim != 2:
                raise DimensionError(f"{name} must be a matrix, got shape {value.shape}")
            if not np.all(np.isfinite(value)):
                raise InvalidValueError(f"{name} contains NaN or inf")
            value.setflags(write=False)
            object.__setattr__(self, name, value)
        n, p = self.L_f.shape
        for name in ("L_i", "L_o"):
            if getattr(self, name).shape != (n, p):
                raise DimensionError(
                    f"{name} has shape {getattr(self, name).shape}, expected ({n}, {p}) like L_f"
                )
        if self.L_d.shape != (p, p):
            raise DimensionError(f"L_d has shape {self.L_d.shape}, expected ({p}, {p})")

    @classmethod
    def disturbance_only(cls, model: LSTMModel, l_d: float) -> ObserverGains:
        r"""The always-valid choice :math:`L_f = L_i = L_o = 0`, :math:`L_d = l_d I_p` (Remark 3).

        Certified (:math:`\rho(A_d) < 1`) for :math:`0 < l_d < 2` on a delta-ISS model.
        """
        zeros = np.zeros((model.n, model.p))
        return cls(L_f=zeros, L_i=zeros, L_o=zeros, L_d=float(l_d) * np.eye(model.p))

    def check_model(self, model: LSTMModel) -> None:
        """Raise :class:`DimensionError` unless the gains fit ``model`` (n, p)."""
        if self.L_f.shape != (model.n, model.p):
            raise DimensionError(
                f"observer gains L_f/L_i/L_o have shape {self.L_f.shape}, expected "
                f"({model.n}, {model.p}) for this model"
            )


@dataclass(frozen=True)
class ObserverCertificate:
    r"""Observer certificate (Assumption 3, Lemma 4, Theorem 2).

    Attributes
    ----------
    gains : ObserverGains
        :math:`L_f, L_i, L_o, L_d`.
    d_max : float
        Disturbance bound of :math:`\mathcal{D} = \{\|d\|_\infty \le d_{max}\}`.
    w_bar : float
        :math:`\bar w` of eq. (lyap_observer_neg_def); the paper fixes it and derives w_max.
    sigma_hat_f, sigma_hat_i, sigma_hat_o : float
        :math:`\hat{\bar\sigma}^f, \hat{\bar\sigma}^i, \hat{\bar\sigma}^o` of Assumption 3.
    alpha_hat, beta_hat, gamma_hat : float
        :math:`\hat\alpha, \hat\beta, \hat\gamma` of Assumption 3.
    A_d : ndarray, shape (3, 3)
        Error-bound dynamics, eq. (Ad_observer).
    rho_A_d : float
        :math:`\rho(A_d)`; Assumption 3 requires < 1.
    c_hat_bound : float
        :math:`\hat{\bar\sigma}^i \bar\sigma^c / (1 - \hat{\bar\sigma}^f)`: invariant set
        :math:`\hat{\mathcal{C}}` of Lemma 4.
    Q_o, P_o : ndarray, shape (3, 3)
        :math:`A_d^\top P_o A_d - P_o = -Q_o`.
    c_o_l, c_o_u : float
        :math:`\sqrt{\lambda_{min}(P_o)}, \sqrt{\lambda_{max}(P_o)}`, eq. (lyap_observer_pos_def).
    rho_o : float
        :math:`\sqrt{1 - \lambda_{min}(Q_o)/\lambda_{max}(P_o)}`, eq. (lyap_observer_neg_def).
    c_o : ndarray, shape (p,)
        :math:`c_{o(j)} = \|[0\; \|W_{y(j*)}\|\; 1] P_o^{-1/2}\|`, eq. (lyap_observer_constraint).
    w_max : float
        :math:`w_{max} = \bar w / \sqrt{P_{o(3,3)}}`: the admissible disturbance variation.
    L : ndarray, shape (3, 3)
        The matrix L of the proof of Theorem 2 (eq. inequality_L_bar).
    alpha_bar, beta_bar, gamma_bar : float
        Entries of L (with paper notes 2.5: :math:`\hat{\bar\sigma}^i` in the h row).
    L_max : float
        :math:`L_{max} = \|L P_o^{-1/2}\|`, eq. (lyap_observer_max_gain).
    e_inf : float
        :math:`\bar e_\infty = \bar w / (1 - \rho_o)`, eq. (eo-limit).
    """

    gains: ObserverGains
    d_max: float
    w_bar: float
    sigma_hat_f: float
    sigma_hat_i: float
    sigma_hat_o: float
    alpha_hat: float
    beta_hat: float
    gamma_hat: float
    A_d: FloatArray
    rho_A_d: float
    c_hat_bound: float
    Q_o: FloatArray
    P_o: FloatArray
    c_o_l: float
    c_o_u: float
    rho_o: float
    c_o: FloatArray
    w_max: float
    L: FloatArray
    alpha_bar: float
    beta_bar: float
    gamma_bar: float
    L_max: float
    e_inf: float = field(default=0.0)

    def V_o(
        self,
        model: LSTMModel,
        x_hat: ArrayLike,
        d_hat: ArrayLike,
        x: ArrayLike,
        d: ArrayLike,
    ) -> float:
        r"""Evaluate :math:`V_o(\hat\chi, \chi)` of Theorem 2."""
        c_hat, h_hat = model.split_state(x_hat)
        c, h = model.split_state(x)
        e = np.array(
            [
                np.linalg.norm(c_hat - c),
                np.linalg.norm(h_hat - h),
                np.linalg.norm(
                    np.asarray(d_hat, dtype=np.float64) - np.asarray(d, dtype=np.float64)
                ),
            ]
        )
        return float(np.sqrt(e @ self.P_o @ e))


def _observer_matrix(
    model: LSTMModel,
    delta_iss: DeltaISSCertificate,
    gains: ObserverGains,
    d_max: float,
) -> tuple[FloatArray, dict[str, float]]:
    """A_d of eq. (Ad_observer) and its scalar ingredients."""
    u_max = delta_iss.u_max
    W_y = model.W_y

    def sigma_hat(W: FloatArray, U: FloatArray, b: FloatArray, L: FloatArray) -> float:
        LW = L @ W_y
        return _sigmoid(_block_row_inf_norm(W * u_max, U - LW, b[:, None], LW, 2.0 * d_max * L))

    s_hat_f = sigma_hat(model.W_f, model.U_f, model.b_f, gains.L_f)
    s_hat_i = sigma_hat(model.W_i, model.U_i, model.b_i, gains.L_i)
    s_hat_o = sigma_hat(model.W_o, model.U_o, model.b_o, gains.L_o)
    c_bound = delta_iss.c_bound
    sigma_c, sigma_i, sigma_x = delta_iss.sigma_c, delta_iss.sigma_i, delta_iss.sigma_x
    alpha_hat = (
        0.25 * c_bound * _spectral_norm(model.U_f - gains.L_f @ W_y)
        + sigma_i * _spectral_norm(model.U_c)
        + 0.25 * sigma_c * _spectral_norm(model.U_i - gains.L_i @ W_y)
    )
    beta_hat = 0.25 * c_bound * _spectral_norm(gains.L_f) + 0.25 * sigma_c * _spectral_norm(
        gains.L_i
    )
    gamma_hat = s_hat_o * alpha_hat + 0.25 * sigma_x * _spectral_norm(model.U_o - gains.L_o @ W_y)
    A_d = np.array(
        [
            [s_hat_f, alpha_hat, beta_hat],
            [
                s_hat_o * s_hat_f,
                gamma_hat,
                s_hat_o * beta_hat + 0.25 * sigma_x * _spectral_norm(gains.L_o),
            ],
            [0.0, _spectral_norm(gains.L_d @ W_y), _spectral_norm(np.eye(model.p) - gains.L_d)],
        ]
    )
    scalars = dict(
        sigma_hat_f=s_hat_f,
        sigma_hat_i=s_hat_i,
        sigma_hat_o=s_hat_o,
        alpha_hat=alpha_hat,
        beta_hat=beta_hat,
        gamma_hat=gamma_hat,
    )
    return A_d, scalars


def observer_certificate(
    model: LSTMModel,
    delta_iss: DeltaISSCertificate,
    gains: ObserverGains,
    *,
    d_max: float = 0.1,
    w_bar: float = 0.01,
    Q_o: ArrayLike = 1000.0,
) -> ObserverCertificate:
    r"""Certificate of the observer eq. (lstm_observer) (Assumption 3, Lemma 4, Theorem 2).

    Parameters
    ----------
    model : LSTMModel
    delta_iss : DeltaISSCertificate
        Must certify delta-ISS.
    gains : ObserverGains
    d_max : float
        :math:`d_{max}` (paper: 0.1).
    w_bar : float
        :math:`\bar w` (paper: 0.01 with :math:`Q_o = 1000 I`, paper notes 2.9).
    Q_o : float or array_like, shape (3, 3)
        Lyapunov weight; a scalar q means q I_3.

    Raises
    ------
    ObserverGainError
        If :math:`\rho(A_d) \ge 1` (Assumption 3 violated).
    """
    model, delta_iss = _model_and_delta_iss(model, delta_iss)
    expect_instance("gains", gains, ObserverGains, expected="ObserverGains")
    delta_iss.require()
    gains.check_model(model)
    d_max = _positive("d_max", d_max)
    w_bar = _positive("w_bar", w_bar)
    Q = _as_spd("Q_o", Q_o, 3)
    A_d, scalars = _observer_matrix(model, delta_iss, gains, d_max)
    rho_A_d = float(np.max(np.abs(np.linalg.eigvals(A_d))))
    if rho_A_d >= 1.0:
        raise ObserverGainError(
            f"observer gains violate Assumption 3: rho(A_d) = {rho_A_d:.6f} >= 1. Use "
            "ObserverGains.disturbance_only(model, l_d) with 0 < l_d < 2, or "
            "design_observer_gains().",
            rho_A_d=rho_A_d,
        )
    P_o = solve_lyapunov(A_d, Q)
    _require_nonnegative("P_o", P_o, "Q_o")
    eig_P = np.linalg.eigvalsh(P_o)
    P_inv_sqrt = matrix_inverse_sqrt(P_o)
    row_norms = np.linalg.norm(model.W_y, axis=1)
    c_o = np.array([np.linalg.norm(np.array([0.0, r, 1.0]) @ P_inv_sqrt) for r in row_norms])
    rho_o = float(np.sqrt(1.0 - np.min(np.linalg.eigvalsh(Q)) / eig_P[-1]))
    # Matrix L of eq. (inequality_L_bar); c_hat_bound is Lemma 4's invariant bound.
    c_hat_bound = scalars["sigma_hat_i"] * delta_iss.sigma_c / (1.0 - scalars["sigma_hat_f"])
    W_y = model.W_y
    sigma_c, sigma_o = delta_iss.sigma_c, delta_iss.sigma_o
    alpha_bar = 0.25 * c_hat_bound * _spectral_norm(
        gains.L_f @ W_y
    ) + 0.25 * sigma_c * _spectral_norm(gains.L_i @ W_y)
    beta_bar = 0.25 * c_hat_bound * _spectral_norm(gains.L_f) + 0.25 * sigma_c * _spectral_norm(
        gains.L_i
    )
    gamma_bar = 0.25 * float(np.tanh(c_hat_bound))
    L = np.array(
        [
            [0.0, alpha_bar, beta_bar],
            [
                0.0,
                gamma_bar * _spectral_norm(gains.L_o @ W_y) + sigma_o * alpha_bar,
                gamma_bar * _spectral_norm(gains.L_o) + sigma_o * beta_bar,
            ],
            [0.0, _spectral_norm(gains.L_d @ W_y), _spectral_norm(gains.L_d)],
        ]
    )
    L_max = _spectral_norm(L @ P_inv_sqrt)
    for array in (A_d, Q, P_o, c_o, L):
        array.setflags(write=False)
    return ObserverCertificate(
        gains=gains,
        d_max=d_max,
        w_bar=w_bar,
        A_d=A_d,
        rho_A_d=rho_A_d,
        c_hat_bound=c_hat_bound,
        Q_o=Q,
        P_o=P_o,
        c_o_l=float(np.sqrt(eig_P[0])),
        c_o_u=float(np.sqrt(eig_P[-1])),
        rho_o=rho_o,
        c_o=c_o,
        w_max=w_bar / float(np.sqrt(P_o[2, 2])),
        L=L,
        alpha_bar=alpha_bar,
        beta_bar=beta_bar,
        gamma_bar=gamma_bar,
        L_max=L_max,
        e_inf=w_bar / (1.0 - rho_o),
        **scalars,
    )


def design_observer_gains(
    model: LSTMModel,
    delta_iss: DeltaISSCertificate,
    l_d: float = 0.01,
    *,
    d_max: float = 0.1,
    w_bar: float = 0.01,
    Q_o: ArrayLike = 1000.0,
    L_max_weight: float = 1.0,
    max_evaluations: int = 2000,
) -> tuple[ObserverGains, ObserverCertificate]:
    r"""Choose :math:`L_f, L_i, L_o` to minimize :math:`\rho(A_d)` (paper notes 2.11).

    Derivative-free (Nelder-Mead) search started from zero gains, on the objective
    :math:`\rho(A_d) + w \cdot L_{max}` (``w = L_max_weight``; keeps :math:`L_{max}`
    small, which shrinks the tightening :math:`a_i`), with :math:`L_d = l_d I_p` fixed.
    The zero-gain fallback of Remark 3 (always valid for :math:`0 < l_d < 2`) is kept
    unless the search finds a strictly better certified objective.

    Returns
    -------
    gains : ObserverGains
    certificate : ObserverCertificate
    """
    if not 0.0 < l_d < 2.0:
        raise InvalidValueError(f"l_d must lie in (0, 2) for the certified fallback, got {l_d}")
    model, delta_iss = _model_and_delta_iss(model, delta_iss)
    expect_real("l_d", l_d, low=0.0, high=2.0, low_open=True, high_open=True)
    expect_int("max_evaluations", max_evaluations, minimum=1)
    delta_iss.require()
    fallback = ObserverGains.disturbance_only(model, l_d)
    best_gains = fallback
    best_certificate = observer_certificate(
        model, delta_iss, fallback, d_max=d_max, w_bar=w_bar, Q_o=Q_o
    )
    best_value = best_certificate.rho_A_d + L_max_weight * best_certificate.L_max
    n, p = model.n, model.p
    size = n * p

    def unpack(theta: FloatArray) -> ObserverGains:
        L_f, L_i, L_o = (theta[k * size : (k + 1) * size].reshape(n, p) for k in range(3))
        return ObserverGains(L_f=L_f, L_i=L_i, L_o=L_o, L_d=l_d * np.eye(p))

    def objective(theta: FloatArray) -> float:
        gains = unpack(theta)
        A_d, _ = _observer_matrix(model, delta_iss, gains, d_max)
        rho = float(np.max(np.abs(np.linalg.eigvals(A_d))))
        if rho >= 1.0:
            return 10.0 + rho
        try:
            certificate = observer_certificate(
                model, delta_iss, gains, d_max=d_max, w_bar=w_bar, Q_o=Q_o
            )
        except (ObserverGainError, InvalidValueError, np.linalg.LinAlgError):
            return 10.0 + rho
        return certificate.rho_A_d + L_max_weight * certificate.L_max

    # Start at zero gains with a simplex of 0.05 steps (the default 0.00025 step for a
    # zero start is too small to leave the fallback's neighbourhood).
    start = np.zeros(3 * size)
    simplex = np.vstack([start, start + 0.05 * np.eye(3 * size)])
    result = scipy.optimize.minimize(
        objective,
        start,
        method="Nelder-Mead",
        options={
            "maxfev": max_evaluations,
            "xatol": 1e-6,
            "fatol": 1e-9,
            "initial_simplex": simplex,
        },
    )
    if result.fun < best_value - 1e-12:
        gains = unpack(np.asarray(result.x))
        try:
            certificate = observer_certificate(
                model, delta_iss, gains, d_max=d_max, w_bar=w_bar, Q_o=Q_o
            )
            best_gains, best_certificate = gains, certificate
        except ObserverGainError:
            pass
    return best_gains, best_certificate
