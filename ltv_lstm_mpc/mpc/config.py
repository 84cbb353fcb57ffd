r"""Tuning of the robust offset-free MPC, :class:`MPCConfig` (defaults: the paper's Section V).

Every field is honoured by every transcription, or rejected with an error naming the field
(:func:`~ltv_lstm_mpc.resolve_transcription`).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any, Literal

import numpy as np
from numpy.typing import NDArray

from ltv_lstm_mpc.certificates.certify import CertificationSettings
from ltv_lstm_mpc.exceptions import ArgumentTypeError, DimensionError, InvalidValueError
from ltv_lstm_mpc.lstm.model import LSTMModel
from ltv_lstm_mpc.validation import (
    expect_bool,
    expect_int,
    expect_output_bounds,
    expect_real,
    finite_array,
)

__all__ = [
    "DEFAULT_L_D",
    "TRANSCRIPTIONS",
    "InfeasibilityPolicy",
    "MPCConfig",
    "Transcription",
    "default_solver",
    "require_config",
]

FloatArray = NDArray[np.float64]
InfeasibilityPolicy = Literal["paper", "soft", "shift"]
Transcription = Literal["auto", "condensed", "sparse", "nonlinear"]
_POLICIES = ("paper", "soft", "shift")
#: The transcriptions of the FHOCP (see :attr:`MPCConfig.transcription`).
TRANSCRIPTIONS: tuple[str, ...] = ("auto", "condensed", "sparse", "nonlinear")
#: The one default observer gain :math:`L_d = l_d I_p` of the library and every command
#: (``MPCConfig``, ``certify``, ``simulate``, ``campaign``): the paper's first choice, with
#: which Theorem 3's set-point rate bound holds on the shipped model (0.1, the paper's
#: second pH simulation, rejects disturbances faster but makes that bound void).
DEFAULT_L_D = 0.01


def default_solver() -> str:
    """The fastest installed solver with exact terminal cones
    (:func:`ltv_lstm_mpc.solvers.default_solver`): ``MPCConfig``'s default solver."""
    from ltv_lstm_mpc.solvers import default_solver as registry_default

    return registry_default()


@dataclass(frozen=True)
class MPCConfig:
    r"""Tuning of the robust offset-free MPC; defaults are the paper's (Section V).

    Attributes
    ----------
    N : int
        Prediction horizon (5).
    Q : float or ndarray
        Stage state weight, scalar q meaning :math:`q I_{2n}` (1).
    R : float or ndarray
        Stage input weight, scalar r meaning :math:`r I_m` (1).
    u_max : float
        :math:`u_{max}` (1, normalized).
    y_min, y_max : float, optional
        Output constraint (normalized); ``None``: the constraint the model carries
        (``y_phi_constraint_min/max`` of its file; the shipped pH models state the
        paper's [6, 9] pH); a model without one needs explicit values.
    d_max, w_bar : float
        :math:`d_{max}` (0.1) and :math:`\bar w` (0.01).
    Q_s, Q_o : float
        Lyapunov weights :math:`Q_s = q_s I_2`, :math:`Q_o = q_o I_3` (1000).
    L_d : float
        :math:`L_d = l_d I_p` (:data:`DEFAULT_L_D`, 0.01).
    L_f, L_i, L_o : float
        Fill values of the observer gains (0: the certified fallback of Remark 3).
    design_gains : bool
        Choose :math:`L_f, L_i, L_o` by paper notes 2.11 instead.
    solver : str
        Backend name; default :func:`default_solver`, the fastest installed one with exact
        terminal cones (``"daqp:socp"`` where DAQP is installed, else ``"clarabel"``, else
        ``"cvxpy:CLARABEL"``). E.g. ``"cvxpy:CLARABEL"`` (cones, exact), ``"osqp"``, ``"daqp"``,
        ``"qpsolvers:piqp"`` (QP-only: the terminal cones get the conservative
        :class:`~ltv_lstm_mpc.mpc.terminal.TerminalBoxReformulation`, recorded per step).
    tolerance : float
        Solver tolerance (mapped per solver).
    sqp_iterations : int
        Linearizations per step (1 = plain RTI).
    sqp_tolerance : float
        Stop the SQP iterations when :math:`\|u^{j+1} - u^j\|_\infty` falls below it.
    infeasibility_policy : {"paper", "soft", "shift"}
        What to apply when the FHOCP is infeasible (see the module docstring).
    soft_penalty : float
        Exact-penalty weight of the ``"soft"`` policy.
    e_hat0 : float, optional
        Initial observer-error bound :math:`\hat e_{o,0}` (paper notes 2.10b: default
        :math:`\bar e_\infty`).
    epsilon : float
        :math:`P_f` margin (paper notes 2.6).
    """

    N: int = 5
    Q: float | FloatArray = 1.0
    R: float | FloatArray = 1.0
    u_max: float = 1.0
    y_min: float | None = None
    y_max: float | None = None
    d_max: float = 0.1
    w_bar: float = 0.01
    Q_s: float = 1000.0
    Q_o: float = 1000.0
    L_d: float = DEFAULT_L_D
    L_f: float = 0.0
    L_i: float = 0.0
    L_o: float = 0.0
    design_gains: bool = False
    solver: str = field(default_factory=default_solver)
    transcription: Transcription = "auto"
    tolerance: float = 1e-8
    sqp_iterations: int = 1
    sqp_tolerance: float = 1e-8
    infeasibility_policy: InfeasibilityPolicy = "paper"
    soft_penalty: float = 1e3
    e_hat0: float | None = None
    epsilon: float = 0.01
    solver_settings: dict[str, object] = field(default_factory=dict)

    def __post_init__(self) -> None:
        # Types and ranges of every field, once, here: a bad value never reaches a solver.
        expect_int("N", self.N, minimum=1, hint="N is the prediction horizon, e.g. N=5")
        for name in ("Q", "R"):
            weight = finite_array(name, getattr(self, name))
            if weight.ndim not in (0, 2):
                raise DimensionError(
                    f"{name} must be a number or a square matrix, got shape {weight.shape}"
                )
        for name in ("u_max", "d_max", "w_bar", "Q_s", "Q_o", "tolerance", "soft_penalty"):
            expect_real(name, getattr(self, name), low=0.0, low_open=True)
        expect_real("L_d", self.L_d, low=0.0, high=2.0, low_open=True, high_open=True)
        for name in ("L_f", "L_i", "L_o"):
            expect_real(name, getattr(self, name))
        expect_real("sqp_tolerance", self.sqp_tolerance, low=0.0)
        expect_real(
            "epsilon",
            self.epsilon,
            low=0.0,
            high=1.0,
            low_open=True,
            high_open=True,
            hint="epsilon is the P_f margin, e.g. 0.01",
        )
        expect_output_bounds(self.y_min, self.y_max)
        expect_bool("design_gains", self.design_gains)
        if not isinstance(self.solver_settings, Mapping):
            raise ArgumentTypeError(
                f"solver_settings must be a dict of solver options, got "
                f"{type(self.solver_settings).__name__} {self.solver_settings!r}"
            )
        if not isinstance(self.infeasibility_policy, str) or (
            self.infeasibility_policy not in _POLICIES
        ):
            raise InvalidValueError(
                f"infeasibility_policy must be one of {_POLICIES}, "
                f"got {self.infeasibility_policy!r}"
            )
        expect_int("sqp_iterations", self.sqp_iterations, minimum=1)
        if not isinstance(self.transcription, str) or self.transcription not in TRANSCRIPTIONS:
            raise InvalidValueError(
                f"transcription must be one of {TRANSCRIPTIONS}, got {self.transcription!r}"
            )
        if not isinstance(self.solver, str) or not self.solver:
            raise InvalidValueError(f"solver must be a solver name, got {self.solver!r}")
        if self.e_hat0 is not None:
            expect_real(
                "e_hat0",
                self.e_hat0,
                low=0.0,
                hint="the initial observer-error bound of eq. eo_evolution; None uses e_inf",
            )

    def weights(self, model: LSTMModel) -> tuple[FloatArray, FloatArray]:
        """Q (2n, 2n) and R (m, m) as matrices, validated."""
        n2, m = 2 * model.n, model.m
        Q = np.asarray(self.Q, dtype=np.float64)
        R = np.asarray(self.R, dtype=np.float64)
        Q = Q * np.eye(n2) if Q.ndim == 0 else Q
        R = R * np.eye(m) if R.ndim == 0 else R
        for name, W, size in (("Q", Q, n2), ("R", R, m)):
            if W.shape != (size, size):
                raise DimensionError(f"{name} has shape {W.shape}, expected ({size}, {size})")
            if not np.allclose(W, W.T) or np.min(np.linalg.eigvalsh(W)) <= 0:
                raise InvalidValueError(f"{name} must be symmetric positive definite")
        return Q, R

    def certification_settings(self, model: LSTMModel) -> CertificationSettings:
        """The certificate inputs implied by this configuration."""
        Q, _ = self.weights(model)
        return CertificationSettings(
            u_max=self.u_max,
            Q_s=self.Q_s,
            Q_o=self.Q_o,
            l_d=self.L_d,
            L_f=self.L_f,
            L_i=self.L_i,
            L_o=self.L_o,
            design_gains=self.design_gains,
            d_max=self.d_max,
            w_bar=self.w_bar,
            Q=float(np.max(np.linalg.eigvalsh(Q))),
            N=self.N,
            y_min=self.y_min,
            y_max=self.y_max,
            epsilon=self.epsilon,
        )


def require_config(value: Any, name: str = "config") -> MPCConfig:
    """``value`` when it is an :class:`MPCConfig` (``None``: the defaults), else
    :class:`~ltv_lstm_mpc.ArgumentTypeError` (a dict of settings is the usual
    slip: the message says to write ``MPCConfig(**settings)``)."""
    if value is None:
        return MPCConfig()
    if isinstance(value, MPCConfig):
        return value
    hint = "build one with MPCConfig(solver='daqp', N=5, ...)"
    if isinstance(value, Mapping):
        hint = f"write MPCConfig(**{_short(value)}) instead of the dict"
    raise ArgumentTypeError(
        f"{name} must be an MPCConfig or None, got {type(value).__name__} {_short(value)}; {hint}"
    )


def _short(value: Any) -> str:
    text = repr(value)
    return text if len(text) <= 80 else text[:77] + "..."
