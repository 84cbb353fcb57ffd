r"""The pH-neutralization benchmark plant (paper Section V).

Every plant follows the :class:`Plant` protocol (the "Plant" block of the paper's Fig. 1/Fig. 2):
``reset()`` puts it at its initial condition, ``output()`` returns the current measurement and
``step(u_phi, d_phi)`` applies an input for one sampling period and returns the new measurement.
All signals are **physical** (suffix ``_phi``, paper notes 1).

pH neutralization (paper Section V, Henson & Seborg 1994)
---------------------------------------------------------
States :math:`x = [W_{a4}, W_{b4}, h_1]` (M, M, cm), input :math:`u_\phi = q_3` (mL/s, base flow),
disturbance :math:`d_\phi = q_2` (mL/s, buffer flow), output :math:`y_\phi` = pH:

.. math::

    \dot x = f(x) + g(x) u_\phi + p(x) d_\phi, \qquad c(x, y_\phi) = 0,

    f(x) = \begin{bmatrix} \frac{q_1}{A_1 x_3}(W_{a1} - x_1) \\
    \frac{q_1}{A_1 x_3}(W_{b1} - x_2) \\ \frac{1}{A_1}(q_1 - C_{v4}(x_3 + z)^{n}) \end{bmatrix},
    \quad g(x) = \begin{bmatrix} \frac{1}{A_1 x_3}(W_{a3} - x_1) \\
    \frac{1}{A_1 x_3}(W_{b3} - x_2) \\ \frac{1}{A_1} \end{bmatrix},
    \quad p(x) = \begin{bmatrix} \frac{1}{A_1 x_3}(W_{a2} - x_1) \\
    \frac{1}{A_1 x_3}(W_{b2} - x_2) \\ \frac{1}{A_1} \end{bmatrix},

    c(x, y_\phi) = x_1 + 10^{y_\phi - 14} - 10^{-y_\phi}
    + x_2 \frac{1 + 2 \cdot 10^{y_\phi - pK_2}}{1 + 10^{pK_1 - y_\phi} + 10^{y_\phi - pK_2}}.

Parameters are those of Table I with :math:`W_{a3} = -3.05 \cdot 10^{-3}` M (paper notes 2.1:
the paper prints +3.05e-3, which gives pH 2.6 instead of 7.0 at the nominal point). Flows in
mL/s = cm^3/s, area in cm^2, level in cm, time in s, concentrations in mol/L.

*Input saturation.* :math:`q_3` is clipped to :math:`\mathcal{U}_\phi = [12.5, 17]` mL/s
(``u_phi_min``, ``u_phi_max``) before it is applied, as in the paper ("the alkaline flow is
considered saturated"); :math:`q_2` must be nonnegative.

*Output equation.* The charge-balance residual :math:`c(x, \cdot)` is strictly increasing in pH
(every term is nondecreasing and :math:`10^{y-14} - 10^{-y}` is strictly increasing, with
:math:`W_{b4} \ge 0`), so the pH is its unique root in the bracket [-2, 16]. It is found by a
vectorized safeguarded Newton iteration: a Newton step is taken only if it stays inside the
current bracket, otherwise the bracket is bisected; the bracket shrinks every iteration, so it
always converges (never an unguarded Newton). Tolerance 1e-13 pH.

*Integrator.* The process is not stiff (time constants about 90-260 s against Ts = 10 s), so a
fixed-step classical Runge-Kutta 4 with ``substeps = 10`` per sampling period (dt = 1 s) is used;
the input is held constant over the period (zero-order hold). Against scipy ``solve_ivp`` Radau
with rtol = 1e-12 the one-step pH error is about 1e-10 (max 1.1e-10 over 20 random steps; tested
< 1e-6; paper notes 5 measured ~5e-10).
Measured cost on the 2-core development VM (Python 3.11, numpy 2.4): about 0.04 ms per step for
one plant (:meth:`PHNeutralizationPlant.step` runs the same RK4 in plain Python floats, 40
right-hand-side evaluations, plus a scalar pH solve), and about 0.7 ms per step for a batch of 15
plants in :func:`simulate_ph_batch` (numpy, vectorized over the batch; the whole 15 x 1500
identification experiment takes about 1.1 s).
"""

from __future__ import annotations

import math
from collections.abc import Iterable
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from ltv_lstm_mpc.exceptions import DimensionError, InvalidValueError, LtvMpcError
from ltv_lstm_mpc.validation import expect_instance, expect_int, expect_real, real_vector

__all__ = [
    "PH_DATA_UNITS",
    "PH_INITIAL_OUTPUT",
    "PH_OUTPUT_CONSTRAINT",
    "PH_REGISTRY_DEFAULTS",
    "PHNeutralizationPlant",
    "PHParameters",
    "ph_from_state",
    "simulate_ph_batch",
]

#: The paper's output constraint :math:`\mathcal{Y}_\phi = [6, 9]` pH (Section V), stored in
#: the shipped pH models (``y_phi_constraint_min/max``). The only place the library holds it:
#: every other module takes the constraint from the plant or the model.
PH_OUTPUT_CONSTRAINT: tuple[float, float] = (6.0, 9.0)

#: Units of the stored signals of the pH identification data
#: (:mod:`ltv_lstm_mpc.training.datasets`).
PH_DATA_UNITS: dict[str, str] = {
    "u_phi": "mL/s (base flow q3)",
    "y_phi": "pH",
    "d_phi": "mL/s (buffer flow q2)",
    "Ts": "s",
}

#: pH of the paper's initial condition (the LSTM-plant scenarios of Section V start there).
PH_INITIAL_OUTPUT = 7.0

#: The pH plant's entry in the plant registry (:func:`~ltv_lstm_mpc.register_plant`):
#: its title, units, default model, set-points (pH) and nominal buffer flow q2 (mL/s).
PH_REGISTRY_DEFAULTS: dict[str, Any] = {
    "title": "pH plant",
    "description": "pH neutralization (paper Section V): base flow q3 (mL/s) -> pH; "
    "disturbance: buffer flow q2 (mL/s)",
    "model": "ph_lstm_n5.npz",
    "setpoints": ("7.5", "6.8", "8.0"),
    "nominal_disturbance": (0.55,),
    "disturbance": "buffer flow q2 in mL/s",
    "Ts": 10.0,
    "input_labels": ("q3 (mL/s)",),
    "output_labels": ("pH",),
    "y_phi_constraint": PH_OUTPUT_CONSTRAINT,
    "data_file": "ph_identification_data.npz",
    "neurons": 5,
    "options": ("mismatch",),
    "class_name": "PHNeutralizationPlant",
}

FloatArray = NDArray[np.float64]


@dataclass(frozen=True)
class PHParameters:
    """Parameters of the pH process, Table I of the paper (with paper notes 2.1's sign of W_a3).

    Attributes
    ----------
    z : float
        Vertical offset of the outlet, cm.
    C_v4 : float
        Outlet valve coefficient, mL/s per cm^n_valve.
    n_valve : float
        Valve exponent (the paper's n = 0.607).
    pK1, pK2 : float
        Dissociation constants of the buffer (H2CO3).
    A1 : float
        Tank cross-section, cm^2.
    W_a1, W_a2, W_a3 : float
        Charge-related reaction invariants of the acid, buffer and base streams, M.
    W_b1, W_b2, W_b3 : float
        Carbonate-ion reaction invariants of the acid, buffer and base streams, M.
    q1 : float
        Acid flow, mL/s (constant parameter).
    """

    z: float = 11.5
    C_v4: float = 4.59
    n_valve: float = 0.607
    pK1: float = 6.35
    pK2: float = 10.25
    A1: float = 207.0
    W_a1: float = 3.00e-3
    W_a2: float = -0.03
    W_a3: float = -3.05e-3
    W_b1: float = 0.0
    W_b2: float = 0.03
    W_b3: float = 5.00e-5
    q1: float = 16.6


def _charge_balance(
    W_a4: FloatArray, W_b4: FloatArray, pH: FloatArray, pK1: float, pK2: float
) -> tuple[FloatArray, FloatArray]:
    """Residual c(x, pH) and its derivative with respect to pH."""
    ln10 = np.log(10.0)
    a = 10.0 ** (pH - 14.0)
    b = 10.0 ** (-pH)
    e1 = 10.0 ** (pK1 - pH)
    e2 = 10.0 ** (pH - pK2)
    num = 1.0 + 2.0 * e2
    den = 1.0 + e1 + e2
    frac = num / den
    residual = W_a4 + a - b + W_b4 * frac
    # d frac / d pH = ln10 [2 e2 den - num (e2 - e1)] / den^2
    dfrac = ln10 * (2.0 * e2 * den - num * (e2 - e1)) / (den * den)
    derivative = ln10 * (a + b) + W_b4 * dfrac
    return residual, derivative


def ph_from_state(
    W_a4: ArrayLike,
    W_b4: ArrayLike,
    *,
    pK1: float = 6.35,
    pK2: float = 10.25,
    tol: float = 1e-13,
    max_iter: int = 200,
) -> FloatArray:
    r"""Solve the charge balance :math:`c(x, pH) = 0` for the pH (vectorized, bracketed).

    Parameters
    ----------
    W_a4, W_b4 : array_like
        Reaction invariants of the outlet stream (M); broadcast together. ``W_b4 >= 0``.
    pK1, pK2 : float
        Dissociation constants.
    tol : float
        Width of the final bracket (pH units).
    max_iter : int
        Iteration cap (bisection alone needs about 50 iterations for ``tol = 1e-13``).

    Returns
    -------
    ndarray
        pH with the broadcast shape of the inputs.

    Notes
    -----
    The residual is strictly increasing in pH, so the root is unique. The bracket
    [-2, 16] always contains it for physical invariants (``|W_a4|`` < 1 M). Each iteration takes
    the Newton step from the bracket end with the smaller residual if it falls strictly inside
    the bracket, else the midpoint, and then shrinks the bracket with the sign of the residual.
    """
    Wa, Wb = np.broadcast_arrays(
        np.asarray(W_a4, dtype=np.float64), np.asarray(W_b4, dtype=np.float64)
    )
    if np.any(Wb < 0) or not (np.all(np.isfinite(Wa)) and np.all(np.isfinite(Wb))):
        raise InvalidValueError("W_b4 must be nonnegative and both invariants finite")
    lo = np.full(Wa.shape, -2.0)
    hi = np.full(Wa.shape, 16.0)
    r_lo, _ = _charge_balance(Wa, Wb, lo, pK1, pK2)
    r_hi, _ = _charge_balance(Wa, Wb, hi, pK1, pK2)
    if np.any(r_lo > 0) or np.any(r_hi < 0):
        raise InvalidValueError("charge balance has no root in pH [-2, 16]; check W_a4, W_b4")
    x = np.full(Wa.shape, 7.0)
    done = np.zeros(Wa.shape, dtype=bool)
    for _ in range(max_iter):
        # Converged entries are frozen, so each result is independent of the batch it is in.
        r, dr = _charge_balance(Wa, Wb, x, pK1, pK2)
        positive = r > 0
        hi = np.where(positive, x, hi)
        lo = np.where(positive, lo, x)
        with np.errstate(divide="ignore", invalid="ignore"):
            newton = x - r / dr
        inside = (newton > lo) & (newton < hi) & np.isfinite(newton)
        x_new = np.where(inside, newton, 0.5 * (lo + hi))
        converged = (np.abs(x_new - x) < tol) | (hi - lo < tol) | (r == 0)
        x_new = np.where(r == 0, x, x_new)
        x = np.where(done, x, x_new)
        done |= converged
        if np.all(done):
            return x
    raise LtvMpcError(f"pH solve did not converge in {max_iter} iterations")


def _ph_rhs(x: FloatArray, q3: FloatArray, q2: FloatArray, par: PHParameters) -> FloatArray:
    """dx/dt = f(x) + g(x) q3 + p(x) q2 for a batch of states x (..., 3)."""
    Wa, Wb, h = x[..., 0], x[..., 1], x[..., 2]
    inv = 1.0 / (par.A1 * h)
    q4 = par.C_v4 * np.maximum(h + par.z, 0.0) ** par.n_valve
    dWa = inv * (par.q1 * (par.W_a1 - Wa) + q3 * (par.W_a3 - Wa) + q2 * (par.W_a2 - Wa))
    dWb = inv * (par.q1 * (par.W_b1 - Wb) + q3 * (par.W_b3 - Wb) + q2 * (par.W_b2 - Wb))
    dh = (par.q1 + q3 + q2 - q4) / par.A1
    return np.stack([dWa, dWb, dh], axis=-1)


def simulate_ph_batch(
    x0: ArrayLike,
    q3: ArrayLike,
    q2: ArrayLike | float = 0.55,
    *,
    Ts: float = 10.0,
    substeps: int = 10,
    params: PHParameters | None = None,
    progress: bool = False,
) -> FloatArray:
    """Integrate a batch of pH plants over T sampling periods (RK4, zero-order hold).

    Parameters
    ----------
    x0 : array_like, shape (B, 3) or (3,)
        Initial states [W_a4 (M), W_b4 (M), h1 (cm)].
    q3 : array_like, shape (B, T) or (T,)
        Base flow per period, mL/s (used as given: saturate before calling).
    q2 : float or array_like broadcastable to q3
        Buffer flow per period, mL/s.
    progress : bool
        Show a tqdm progress bar over the periods.

    Returns
    -------
    ndarray, shape (B, T + 1, 3) (or (T + 1, 3) for unbatched input)
        States at the sampling instants 0..T.
    """
    par = params if params is not None else PHParameters()
    x0_arr = np.asarray(x0, dtype=np.float64)
    q3_arr = np.asarray(q3, dtype=np.float64)
    single = x0_arr.ndim == 1
    if single:
        x0_arr = x0_arr[None]
        q3_arr = q3_arr.reshape(1, -1)
    if x0_arr.ndim != 2 or x0_arr.shape[1] != 3 or q3_arr.ndim != 2:
        raise DimensionError(f"x0 must be (B, 3) and q3 (B, T); got {x0_arr.shape}, {q3_arr.shape}")
    q2_arr = np.broadcast_to(np.asarray(q2, dtype=np.float64), q3_arr.shape)
    B, T = q3_arr.shape
    states = np.empty((B, T + 1, 3))
    states[:, 0] = x0_arr
    dt = Ts / substeps
    x = x0_arr.copy()
    steps: Iterable[int] = range(T)
    if progress:
        from tqdm.auto import tqdm

        steps = tqdm(steps, desc="simulate", unit="step", leave=False)
    for k in steps:
        u, d = q3_arr[:, k], q2_arr[:, k]
        for _ in range(substeps):
            k1 = _ph_rhs(x, u, d, par)
            k2 = _ph_rhs(x + 0.5 * dt * k1, u, d, par)
            k3 = _ph_rhs(x + 0.5 * dt * k2, u, d, par)
            k4 = _ph_rhs(x + dt * k3, u, d, par)
            x = x + (dt / 6.0) * (k1 + 2.0 * k2 + 2.0 * k3 + k4)
        states[:, k + 1] = x
    return states[0] if single else states


def _rk4_scalar(
    x: tuple[float, float, float], q3: float, q2: float, Ts: float, substeps: int, par: PHParameters
) -> tuple[float, float, float]:
    """Same RK4 as :func:`simulate_ph_batch` for one plant in plain Python floats (faster)."""
    A1, z, Cv, nv = par.A1, par.z, par.C_v4, par.n_valve
    qa = par.q1 * par.W_a1 + q3 * par.W_a3 + q2 * par.W_a2
    qb = par.q1 * par.W_b1 + q3 * par.W_b3 + q2 * par.W_b2
    qin = par.q1 + q3 + q2

    def rhs(Wa: float, Wb: float, h: float) -> tuple[float, float, float]:
        inv = 1.0 / (A1 * h)
        q4 = Cv * max(h + z, 0.0) ** nv
        return inv * (qa - qin * Wa), inv * (qb - qin * Wb), (qin - q4) / A1

    Wa, Wb, h = x
    dt = Ts / substeps
    for _ in range(substeps):
        a1, b1, c1 = rhs(Wa, Wb, h)
        a2, b2, c2 = rhs(Wa + 0.5 * dt * a1, Wb + 0.5 * dt * b1, h + 0.5 * dt * c1)
        a3, b3, c3 = rhs(Wa + 0.5 * dt * a2, Wb + 0.5 * dt * b2, h + 0.5 * dt * c2)
        a4, b4, c4 = rhs(Wa + dt * a3, Wb + dt * b3, h + dt * c3)
        Wa += dt / 6.0 * (a1 + 2.0 * a2 + 2.0 * a3 + a4)
        Wb += dt / 6.0 * (b1 + 2.0 * b2 + 2.0 * b3 + b4)
        h += dt / 6.0 * (c1 + 2.0 * c2 + 2.0 * c3 + c4)
    return Wa, Wb, h


def _ph_scalar(Wa: float, Wb: float, pK1: float, pK2: float, tol: float = 1e-13) -> float:
    """Scalar version of :func:`ph_from_state` (same safeguarded Newton in the bracket)."""
    ln10 = math.log(10.0)

    def residual(y: float) -> tuple[float, float]:
        a, b = 10.0 ** (y - 14.0), 10.0 ** (-y)
        e1, e2 = 10.0 ** (pK1 - y), 10.0 ** (y - pK2)
        num, den = 1.0 + 2.0 * e2, 1.0 + e1 + e2
        dfrac = ln10 * (2.0 * e2 * den - num * (e2 - e1)) / (den * den)
        return Wa + a - b + Wb * num / den, ln10 * (a + b) + Wb * dfrac

    lo, hi = -2.0, 16.0
    if residual(lo)[0] > 0 or residual(hi)[0] < 0 or Wb < 0:
        raise InvalidValueError("charge balance has no root in pH [-2, 16]; check W_a4, W_b4")
    y = 7.0
    for _ in range(200):
        r, dr = residual(y)
        if r == 0.0:
            return y
        if r > 0:
            hi = y
        else:
            lo = y
        newton = y - r / dr if dr > 0 else math.nan
        y_new = newton if lo < newton < hi else 0.5 * (lo + hi)
        if abs(y_new - y) < tol or hi - lo < tol:
            return y_new
        y = y_new
    raise LtvMpcError("pH solve did not converge in 200 iterations")


class PHNeutralizationPlant:
    r"""pH-neutralization process of the paper's Section V (Henson & Seborg 1994).

    State :math:`x = [W_{a4}, W_{b4}, h_1]` (M, M, cm); input :math:`u_\phi = q_3` (mL/s),
    saturated to :math:`[12.5, 17]`; disturbance :math:`d_\phi = q_2` (mL/s, nominal 0.55);
    output pH. See the module docstring for the equations, the integrator and its cost.

    Parameters
    ----------
    Ts : float
        Sampling period, s.
    substeps : int
        RK4 steps per sampling period.
    q1 : float
        Acid flow, mL/s.
    q2_nominal : float
        Nominal buffer flow, mL/s (used when ``step`` gets ``d_phi=None`` and by ``reset``).
    q3_nominal : float
        Base flow of the initial steady state, mL/s.
    params : PHParameters, optional
        Other Table I parameters (``q1`` above overrides ``params.q1``).
    """

    #: Input saturation bounds of :math:`\mathcal{U}_\phi`, mL/s.
    u_phi_min: float = 12.5
    u_phi_max: float = 17.0
    #: Entries of ``d_phi`` in :meth:`step` (the buffer flow q2).
    disturbance_size: int = 1

    def __init__(
        self,
        Ts: float = 10.0,
        substeps: int = 10,
        q1: float = 16.6,
        q2_nominal: float = 0.55,
        q3_nominal: float = 15.6,
        params: PHParameters | None = None,
    ) -> None:
        Ts = expect_real("Ts", Ts, low=0.0, low_open=True, hint="the sampling time, s")
        substeps = expect_int("substeps", substeps, minimum=1)
        for name, flow in (("q1", q1), ("q2_nominal", q2_nominal), ("q3_nominal", q3_nominal)):
            expect_real(name, flow, low=0.0, hint="a flow in mL/s")
        if params is not None:
            expect_instance("params", params, PHParameters, expected="PHParameters or None")

        base = params if params is not None else PHParameters()
        self.params = PHParameters(**{**base.__dict__, "q1": float(q1)})
        self.Ts = float(Ts)
        self.substeps = int(substeps)
        self.q2_nominal = float(q2_nominal)
        self.q3_nominal = float(q3_nominal)
        self.x: FloatArray = self.steady_state_state(self.q3_nominal, self.q2_nominal)

    # ------------------------------------------------------------- steady state
    def steady_state_state(self, q3: float, q2: float = 0.55) -> FloatArray:
        """Steady state [W_a4, W_b4, h1] for constant q3, q2 (mL/s); analytic."""
        par = self.params
        q4 = par.q1 + q2 + q3
        h = (q4 / par.C_v4) ** (1.0 / par.n_valve) - par.z
        W_a4 = (par.q1 * par.W_a1 + q2 * par.W_a2 + q3 * par.W_a3) / q4
        W_b4 = (par.q1 * par.W_b1 + q2 * par.W_b2 + q3 * par.W_b3) / q4
        return np.array([W_a4, W_b4, h])

    def steady_state(self, q3: float, q2: float = 0.55) -> tuple[FloatArray, float]:
        """Steady state and its pH for constant q3, q2 (mL/s): ``(x_ss, pH_ss)``."""
        x = self.steady_state_state(q3, q2)
        return x, float(self._ph(x))

    def titration_curve(self, q3_values: ArrayLike, q2: float = 0.55) -> FloatArray:
        """Steady-state pH for each q3 (mL/s) in ``q3_values`` at buffer flow q2."""
        q3_arr = np.asarray(q3_values, dtype=np.float64)
        states = np.array([self.steady_state_state(float(q), q2) for q in q3_arr.ravel()])
        return self._ph(states).reshape(q3_arr.shape)

    # ------------------------------------------------------------------ protocol
    def _ph(self, x: FloatArray) -> FloatArray:
        if x.shape == (3,):
            return np.asarray(
                _ph_scalar(float(x[0]), float(x[1]), self.params.pK1, self.params.pK2)
            )
        return ph_from_state(x[..., 0], x[..., 1], pK1=self.params.pK1, pK2=self.params.pK2)

    def saturate(self, u_phi: ArrayLike) -> FloatArray:
        """Clip q3 to [u_phi_min, u_phi_max] mL/s."""
        return np.clip(np.asarray(u_phi, dtype=np.float64), self.u_phi_min, self.u_phi_max)

    def reset(self, q3: float | None = None, q2: float | None = None) -> FloatArray:
        """Put the plant at the steady state of (q3, q2) (default nominal 15.6, 0.55 mL/s).

        Returns the state [W_a4, W_b4, h1].
        """
        q3_val = self.q3_nominal if q3 is None else float(q3)
        q2_val = self.q2_nominal if q2 is None else float(q2)
        self.x = self.steady_state_state(q3_val, q2_val)
        return self.x.copy()

    def output(self) -> FloatArray:
        """Current pH, shape (1,)."""
        return np.atleast_1d(self._ph(self.x))

    def step(self, u_phi: ArrayLike, d_phi: ArrayLike | None = None) -> FloatArray:
        """Apply q3 = ``u_phi`` (mL/s, saturated) and q2 = ``d_phi`` (mL/s, default nominal)
        for one Ts and return the new pH, shape (1,)."""
        u = float(real_vector("u_phi (q3, mL/s)", u_phi, 1)[0])
        d = (
            self.q2_nominal
            if d_phi is None
            else float(real_vector("d_phi (q2, mL/s)", d_phi, 1)[0])
        )
        if d < 0:
            raise InvalidValueError(f"the buffer flow q2 = d_phi must be nonnegative, got {d}")
        u = float(self.saturate(u))
        Wa, Wb, h = (float(v) for v in self.x)
        self.x = np.array(_rk4_scalar((Wa, Wb, h), u, d, self.Ts, self.substeps, self.params))
        return self.output()
