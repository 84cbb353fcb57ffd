r"""All certificate numbers of the paper for one model and one tuning, in one call.

:func:`certify` chains :func:`~ltv_lstm_mpc.delta_iss_certificate`
(Assumption 2), :func:`~ltv_lstm_mpc.incremental_lyapunov_certificate`
(Lemma 2), :func:`~ltv_lstm_mpc.observer_certificate` (Theorem 2),
:func:`~ltv_lstm_mpc.tightening_certificate`
(eq. constraint_tightening_parameters,
terminal set), :func:`~ltv_lstm_mpc.estimate_K_bar` (Lemma 5) and the set-point
rate bound of Theorem 3 (paper notes 2.10c). :class:`CertificationSettings` defaults are the
paper's values (Section V).
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray

from ltv_lstm_mpc.certificates.reference_gain import KBarEstimate, estimate_K_bar
from ltv_lstm_mpc.certificates.stability import (
    DeltaISSCertificate,
    IncrementalLyapunovCertificate,
    ObserverCertificate,
    ObserverGains,
    delta_iss_certificate,
    design_observer_gains,
    incremental_lyapunov_certificate,
    observer_certificate,
)
from ltv_lstm_mpc.certificates.tightening import (
    SetpointRateBound,
    TighteningCertificate,
    tightening_certificate,
)
from ltv_lstm_mpc.exceptions import InvalidValueError
from ltv_lstm_mpc.lstm.model import LSTMModel, require_model
from ltv_lstm_mpc.validation import (
    expect_bool,
    expect_instance,
    expect_int,
    expect_output_bounds,
    expect_pair,
    expect_real,
)

__all__ = ["Certification", "CertificationSettings", "certify", "u_max_extrapolation"]

FloatArray = NDArray[np.float64]


def __getattr__(name: str) -> Any:
    """``PAPER_Y_PHI_BOUNDS``, the pH benchmark's output constraint, now held by the pH
    plant's module only (:data:`ltv_lstm_mpc.plants.ph.PH_OUTPUT_CONSTRAINT`); kept here
    for code that imported it from this module."""
    if name == "PAPER_Y_PHI_BOUNDS":
        from ltv_lstm_mpc.plants.ph import PH_OUTPUT_CONSTRAINT

        return PH_OUTPUT_CONSTRAINT
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


@dataclass(frozen=True)
class CertificationSettings:
    r"""Tuning that the certificates depend on; defaults are the paper's (Section V).

    Attributes
    ----------
    u_max : float
        :math:`u_{max}` (normalized input bound), 1.
    Q_s : float
        :math:`Q_s = q_s I_2`, 1000.
    Q_o : float
        :math:`Q_o = q_o I_3`, 1000.
    l_d : float
        :math:`L_d = l_d I_p`, 0.01 (0.1 in the paper's second plant simulation).
    L_f, L_i, L_o : float
        Scalar fill of the (n, p) gains :math:`L_f, L_i, L_o` (paper's example: chosen by
        optimization; default 0, the certified fallback of Remark 3). Ignored when
        ``design_gains`` is True.
    design_gains : bool
        Choose :math:`L_f, L_i, L_o` by
        :func:`~ltv_lstm_mpc.design_observer_gains`.
    d_max : float
        :math:`d_{max}`, 0.1.
    w_bar : float
        :math:`\bar w`, 0.01.
    Q : float
        :math:`Q = q I_{2n}`, 1.
    N : int
        Horizon, 5.
    y_min, y_max : float
        Output constraint in normalized units. ``None`` means: the constraint the model
        carries (``y_phi_constraint_min/max`` of its file, physical units, normalized
        through its normalization); a model without one needs explicit values.
    epsilon : float
        :math:`P_f` margin (paper notes 2.6), 0.01.
    e_y_bar : float
        :math:`\bar e_y` of Lemma 5 for the rate bound, 0.03.
    y0_operating_range : (float, float), optional
        Normalized set-point range over which Theorem 3's rate bound must hold; it uses the
        smallest :math:`\alpha_k` there. Default: the middle half of the admissible
        interval of Assumption 5 (the bound shrinks to 0 at its edges).
    K_bar_grid_points : int
        Grid size for :math:`\bar K`.
    """

    u_max: float = 1.0
    Q_s: float = 1000.0
    Q_o: float = 1000.0
    l_d: float = 0.01
    L_f: float = 0.0
    L_i: float = 0.0
    L_o: float = 0.0
    design_gains: bool = False
    d_max: float = 0.1
    w_bar: float = 0.01
    Q: float = 1.0
    N: int = 5
    y_min: float | None = None
    y_max: float | None = None
    epsilon: float = 0.01
    e_y_bar: float = 0.03
    K_bar_grid_points: int = 201
    y0_operating_range: tuple[float, float] | None = None

    def __post_init__(self) -> None:
        for name in ("u_max", "Q_s", "Q_o", "d_max", "w_bar", "Q", "epsilon", "e_y_bar"):
            expect_real(name, getattr(self, name), low=0.0, low_open=True)
        expect_real("l_d", self.l_d, low=0.0, high=2.0, low_open=True, high_open=True)
        for name in ("L_f", "L_i", "L_o"):
            expect_real(name, getattr(self, name))
        expect_bool("design_gains", self.design_gains)
        expect_int("N", self.N, minimum=1, hint="N is the prediction horizon, e.g. N=5")
        expect_int("K_bar_grid_points", self.K_bar_grid_points, minimum=2)
        expect_real("epsilon", self.epsilon, low=0.0, high=1.0, low_open=True, high_open=True)
        expect_output_bounds(self.y_min, self.y_max)
        if self.y0_operating_range is not None:
            expect_pair("y0_operating_range", self.y0_operating_range)

    def output_bounds(self, model: LSTMModel) -> tuple[FloatArray, FloatArray]:
        """Normalized output bounds (p,) resolved against the model's normalization."""
        p = model.p
        if self.y_min is not None and self.y_max is not None:
            return np.full(p, float(self.y_min)), np.full(p, float(self.y_max))
        if self.y_min is not None or self.y_max is not None:
            raise InvalidValueError("give both y_min and y_max, or neither")
        stored = model.output_constraint()
        if stored is None:
            raise InvalidValueError(
                "the model carries no output constraint (y_phi_constraint_min/max in its .npz) "
                "and none was given: pass y_min and y_max (normalized units) to MPCConfig / "
                "CertificationSettings (CLI: --y-min/--y-max), or store the constraint with "
                "LSTMModel(..., y_phi_constraint=(low, high)) in physical units and save it"
            )
        return stored

    def gains(self, model: LSTMModel) -> ObserverGains:
        """Observer gains filled from the scalar settings."""
        fill = np.ones((model.n, model.p))
        return ObserverGains(
            L_f=self.L_f * fill,
            L_i=self.L_i * fill,
            L_o=self.L_o * fill,
            L_d=self.l_d * np.eye(model.p),
        )


@dataclass(frozen=True)
class Certification:
    """Every certificate for one model and one :class:`CertificationSettings`."""

    settings: CertificationSettings
    delta_iss: DeltaISSCertificate
    lyapunov: IncrementalLyapunovCertificate
    observer: ObserverCertificate
    tightening: TighteningCertificate
    K_bar: KBarEstimate
    rate_bound: SetpointRateBound
    y0_interval: tuple[FloatArray, FloatArray]
    y0_interval_phi: tuple[FloatArray, FloatArray] | None
    rate_bound_y0_range: tuple[FloatArray, FloatArray] | None = None
    model_info: dict[str, Any] = field(default_factory=dict)

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready dict; keys are the paper's symbols, inputs echoed under ``inputs``."""
        d, ly, ob, ti = self.delta_iss, self.lyapunov, self.observer, self.tightening

        def lst(value: Any) -> Any:
            return np.asarray(value).tolist()

        result: dict[str, Any] = {
            "model": self.model_info,
            "rho_A_delta": d.rho_A_delta,
            "is_delta_iss": d.is_delta_iss,
            "A_delta": lst(d.A_delta),
            "B_delta": lst(d.B_delta),
            "r1": d.r1,
            "r2": d.r2,
            "sigma_f": d.sigma_f,
            "sigma_i": d.sigma_i,
            "sigma_o": d.sigma_o,
            "sigma_c": d.sigma_c,
            "sigma_x": d.sigma_x,
            "alpha": d.alpha,
            "beta": d.beta,
            "C_bound": d.c_bound,
            "H_bound": d.h_bound,
            "P_s": lst(ly.P_s),
            "rho_s": ly.rho_s,
            "c_s_l": ly.c_s_l,
            "c_s_u": ly.c_s_u,
            "c_s": lst(ly.c_s),
            "sigma_hat_f": ob.sigma_hat_f,
            "sigma_hat_i": ob.sigma_hat_i,
            "sigma_hat_o": ob.sigma_hat_o,
            "alpha_hat": ob.alpha_hat,
            "beta_hat": ob.beta_hat,
            "gamma_hat": ob.gamma_hat,
            "A_d": lst(ob.A_d),
            "rho_A_d": ob.rho_A_d,
            "C_hat_bound": ob.c_hat_bound,
            "P_o": lst(ob.P_o),
            "rho_o": ob.rho_o,
            "c_o_l": ob.c_o_l,
            "c_o_u": ob.c_o_u,
            "c_o": lst(ob.c_o),
            "L": lst(ob.L),
            "L_max": ob.L_max,
            "w_max": ob.w_max,
            "w_bar": ob.w_bar,
            "e_inf": ti.e_inf,
            "a": lst(ti.a),
            "b": lst(ti.b),
            "P_f": lst(ti.P_f),
            "rho_f": ti.rho_f,
            "kappa": lst(ti.kappa),
            "y0_interval": [lst(self.y0_interval[0]), lst(self.y0_interval[1])],
            "y0_interval_phi": (
                None
                if self.y0_interval_phi is None
                else [lst(self.y0_interval_phi[0]), lst(self.y0_interval_phi[1])]
            ),
            "K_bar": self.K_bar.K_bar,
            "delta_y0_max": self.rate_bound.delta_y0_max,
            "rate_bound_holds": self.rate_bound.holds,
            "rate_bound_alpha": self.rate_bound.alpha,
            "rate_bound_y0_range": None
            if self.rate_bound_y0_range is None
            else [lst(self.rate_bound_y0_range[0]), lst(self.rate_bound_y0_range[1])],
            "inputs": {
                **{k: v for k, v in asdict(self.settings).items() if k not in ("y_min", "y_max")},
                "L_f": lst(ob.gains.L_f),
                "L_i": lst(ob.gains.L_i),
                "L_o": lst(ob.gains.L_o),
                "L_d": lst(ob.gains.L_d),
                "y_min": lst(ti.y_min),
                "y_max": lst(ti.y_max),
            },
        }
        return result


def certify(
    model: LSTMModel,
    settings: CertificationSettings | None = None,
    *,
    model_info: dict[str, Any] | None = None,
) -> Certification:
    """Compute every certificate of the paper for ``model`` under ``settings``.

    Raises
    ------
    NotDeltaISSError
        If rho(A_delta) >= 1 (Assumption 2 is required for everything else).
    ObserverGainError
        If the observer gains violate Assumption 3.
    """
    model = require_model(model)
    settings = expect_instance(
        "settings",
        CertificationSettings() if settings is None else settings,
        CertificationSettings,
        "build them with CertificationSettings(u_max=1.0, ...), or pass None for the defaults",
        expected="a CertificationSettings or None",
    )
    if model_info is not None:
        expect_instance("model_info", model_info, dict, expected="a dict or None")
    model.require_square()
    delta_iss = delta_iss_certificate(model, settings.u_max, require=True)
    lyapunov = incremental_lyapunov_certificate(model, delta_iss, settings.Q_s)
    if settings.design_gains:
        _gains, observer = design_observer_gains(
            model,
            delta_iss,
            settings.l_d,
            d_max=settings.d_max,
            w_bar=settings.w_bar,
            Q_o=settings.Q_o,
        )
    else:
        observer = observer_certificate(
            model,
            delta_iss,
            settings.gains(model),
            d_max=settings.d_max,
            w_bar=settings.w_bar,
            Q_o=settings.Q_o,
        )
    y_min, y_max = settings.output_bounds(model)
    tightening = tightening_certificate(
        model,
        delta_iss,
        lyapunov,
        observer,
        N=settings.N,
        Q=settings.Q,
        y_min=y_min,
        y_max=y_max,
        epsilon=settings.epsilon,
    )
    interval = tightening.setpoint_interval()
    K_bar = estimate_K_bar(
        model,
        u_max=settings.u_max,
        y0_range=interval if np.all(interval[0] < interval[1]) else None,
        d_max=settings.d_max,
        grid_points=settings.K_bar_grid_points,
    )
    # Theorem 3's rate bound with the smallest alpha over the operating range.
    if settings.y0_operating_range is not None:
        operating = (
            np.full(model.p, float(settings.y0_operating_range[0])),
            np.full(model.p, float(settings.y0_operating_range[1])),
        )
    else:
        quarter = 0.25 * (interval[1] - interval[0])
        operating = (interval[0] + quarter, interval[1] - quarter)
    rate_bound = tightening.setpoint_rate_bound(
        tightening.alpha_min(operating[0], operating[1], tightening.e_inf),
        tightening.e_inf,
        K_bar=K_bar.K_bar,
        e_y_bar=settings.e_y_bar,
    )
    interval_phi = None
    if model.normalization is not None:
        interval_phi = (model.denormalize_y(interval[0]), model.denormalize_y(interval[1]))
    info = {"n": model.n, "m": model.m, "p": model.p, **(model_info or {})}
    return Certification(
        settings=settings,
        delta_iss=delta_iss,
        lyapunov=lyapunov,
        observer=observer,
        tightening=tightening,
        K_bar=K_bar,
        rate_bound=rate_bound,
        y0_interval=interval,
        y0_interval_phi=interval_phi,
        rate_bound_y0_range=operating,
        model_info=info,
    )


def u_max_extrapolation(model: LSTMModel, u_max: float) -> str | None:
    """Why ``u_max > 1`` is a risk for ``model``, or ``None`` (``u_max <= 1`` or no
    normalization): the normalization maps the training data's input range onto [-1, 1],
    so a larger bound lets the input leave the range the model was trained on. The
    controller warns with this text, and so does ``ltv-lstm-mpc certify``."""
    if model.normalization is None or not u_max > 1.0:
        return None
    low = model.denormalize_u(np.full(model.m, -u_max))
    high = model.denormalize_u(np.full(model.m, u_max))
    norm = model.normalization
    return (
        f"u_max = {u_max} (normalized) lets the input reach "
        f"[{low.tolist()}, {high.tolist()}] in physical units, beyond the range the "
        f"model was trained on [{norm.u_phi_min.tolist()}, {norm.u_phi_max.tolist()}]: "
        "its predictions there are extrapolations; keep u_max <= 1 or retrain on "
        "a wider input range"
    )
