r"""The quadruple-tank process (Johansson, IEEE TCST 8(3), 2000): a MIMO benchmark plant.

Four tanks, two pumps. Pump 1 (voltage :math:`v_1`) feeds tank 1 (fraction
:math:`\gamma_1` of its flow) and tank 4 (fraction :math:`1 - \gamma_1`); pump 2 feeds tank 2
(:math:`\gamma_2`) and tank 3 (:math:`1 - \gamma_2`). Tanks 3 and 4 drain into tanks 1 and 2.
The two lower levels :math:`h_1, h_2` are measured. Johansson's equations (his eq. (1)):

.. math::

    \dot h_1 &= -\frac{a_1}{A_1}\sqrt{2 g h_1} + \frac{a_3}{A_1}\sqrt{2 g h_3}
               + \frac{\gamma_1 k_1}{A_1} v_1 \\
    \dot h_2 &= -\frac{a_2}{A_2}\sqrt{2 g h_2} + \frac{a_4}{A_2}\sqrt{2 g h_4}
               + \frac{\gamma_2 k_2}{A_2} v_2 \\
    \dot h_3 &= -\frac{a_3}{A_3}\sqrt{2 g h_3} + \frac{(1 - \gamma_2) k_2}{A_3} v_2 \\
    \dot h_4 &= -\frac{a_4}{A_4}\sqrt{2 g h_4} + \frac{(1 - \gamma_1) k_1}{A_4} v_1

With :math:`\gamma_1 + \gamma_2 > 1` the linearization has two left-half-plane zeros
(minimum phase, Johansson's operating point :math:`P_-`); with :math:`\gamma_1 + \gamma_2 < 1`
one zero is in the right half plane (:math:`P_+`).

Signals (suffix ``_phi``, paper notes 1)
----------------------------------------
* input :math:`u_\phi = (v_1, v_2)` in V, saturated to :math:`[u_{\phi,min}, u_{\phi,max}]`
  per pump before it is applied (default [1.5, 4.0] V, the benchmark's operating range: lower
  levels from about 3 cm to 22 cm at steady state);
* output :math:`y_\phi = (h_1, h_2)` in cm (Johansson measures :math:`k_c h_i` in V; the
  sensor gain :math:`k_c` is kept in the parameters for reference only);
* unmeasured disturbance :math:`d_\phi = (a_{L1}, a_{L2})` in cm^2: the cross-sections of a
  leak (an extra outlet orifice) in tanks 1 and 2, draining :math:`a_{Li}\sqrt{2 g h_i}`.
  Nominal 0 (no leak). A leak lowers the levels for the same pump voltages, the offset an
  offset-free controller has to remove.

*Levels never negative.* Every outflow is :math:`a\sqrt{2 g \max(h, 0)}` (the leak as well),
so a level at 0 cannot drain further; after each integration step the levels are clipped at
0 as a guard against a Runge-Kutta overshoot (it does not happen in the operating range).

*Integrator.* Classical Runge-Kutta 4, ``substeps = 20`` per sampling period
(dt = 0.5 s against the fastest time constant, about 10 s for an upper tank at the
smallest levels of the operating range), input and leak held constant over the period
(zero-order hold). Against scipy ``solve_ivp`` (DOP853, rtol = 1e-13) the one-step level
error is about 3e-9 cm (max 2.6e-9 over 10 random steps with and without leaks; tested
< 1e-8). One :meth:`QuadrupleTankPlant.step` (plain Python floats) takes about 0.1 ms on
the 2-core development VM.

*Measurement noise*: wrap the plant, ``NoisyMeasurement(QuadrupleTankPlant(), noise_std,
seed)`` (:class:`~ltv_lstm_mpc.plants.measurement.NoisyMeasurement`, cm; the state is never
affected and ``simulate`` judges the constraint on the true levels).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from ltv_lstm_mpc.exceptions import DimensionError, InvalidValueError
from ltv_lstm_mpc.validation import expect_instance, expect_int, expect_real, real_vector

__all__ = [
    "QUADTANK_LEVEL_CONSTRAINT",
    "QUADTANK_TS",
    "QUADTANK_U_RANGE",
    "QuadrupleTankParameters",
    "QuadrupleTankPlant",
    "simulate_quadtank_batch",
]

FloatArray = NDArray[np.float64]

#: Sampling time of the benchmark, s (stored in the shipped model file as ``Ts``).
QUADTANK_TS: float = 10.0
#: Pump-voltage range of the benchmark (saturation and identification range), V.
QUADTANK_U_RANGE: tuple[float, float] = (1.5, 4.0)
#: Constraint on the lower levels (h1, h2) of the closed loop, cm (both outputs).
QUADTANK_LEVEL_CONSTRAINT: tuple[float, float] = (4.0, 20.0)


@dataclass(frozen=True)
class QuadrupleTankParameters:
    r"""Physical parameters of the quadruple-tank process (Johansson 2000, Tables I and II).

    Source: K. H. Johansson, "The quadruple-tank process: a multivariable laboratory
    process with an adjustable zero", IEEE Trans. Control Syst. Technol. 8(3):456-465, 2000.
    Table I (process parameters) and Table II (operating points); the defaults are the
    minimum-phase operating point :math:`P_-`.

    ==========================  ===============================  ==============
    parameter                   value                            unit
    ==========================  ===============================  ==============
    A1, A3 (tank areas)         28                               cm^2
    A2, A4                      32                               cm^2
    a1, a3 (outlet areas)       0.071                            cm^2
    a2, a4                      0.057                            cm^2
    kc (level sensor gain)      0.50                             V/cm
    g                           981                              cm/s^2
    k1, k2 (pump gains, P-)     3.33, 3.35                       cm^3/(V s)
    gamma1, gamma2 (P-)         0.70, 0.60                       -
    operating point (P-)        h = (12.4, 12.7, 1.8, 1.4)       cm, at v = (3.00, 3.00) V
    ==========================  ===============================  ==============

    With these parameters the equations give the steady state (12.26, 12.78, 1.63, 1.41) cm
    at v = (3, 3) V (Table II lists measured, rounded levels).

    :meth:`non_minimum_phase` gives :math:`P_+` (k = 3.14, 3.29; gamma = 0.43, 0.34).
    """

    A1: float = 28.0
    A2: float = 32.0
    A3: float = 28.0
    A4: float = 32.0
    a1: float = 0.071
    a2: float = 0.057
    a3: float = 0.071
    a4: float = 0.057
    kc: float = 0.50
    g: float = 981.0
    k1: float = 3.33
    k2: float = 3.35
    gamma1: float = 0.70
    gamma2: float = 0.60

    def __post_init__(self) -> None:
        for name in ("A1", "A2", "A3", "A4", "a1", "a2", "a3", "a4", "kc", "g", "k1", "k2"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value > 0):
                raise InvalidValueError(f"{name} must be positive and finite, got {value!r}")
        for name in ("gamma1", "gamma2"):
            value = getattr(self, name)
            if not 0.0 <= value <= 1.0:
                raise InvalidValueError(
                    f"{name} is a valve split and must lie in [0, 1], got {value}"
                )

    @classmethod
    def minimum_phase(cls) -> QuadrupleTankParameters:
        """Johansson's operating point :math:`P_-` (the default)."""
        return cls()

    @classmethod
    def non_minimum_phase(cls) -> QuadrupleTankParameters:
        """Johansson's operating point :math:`P_+` (gamma1 + gamma2 < 1, an RHP zero)."""
        return cls(k1=3.14, k2=3.29, gamma1=0.43, gamma2=0.34)


def _rhs(h: FloatArray, v: FloatArray, leak: FloatArray, p: QuadrupleTankParameters) -> FloatArray:
    """dh/dt for a batch of levels h (..., 4), voltages v (..., 2), leak areas (..., 2)."""
    s = np.sqrt(2.0 * p.g * np.maximum(h, 0.0))
    q1 = p.gamma1 * p.k1 * v[..., 0]
    q2 = p.gamma2 * p.k2 * v[..., 1]
    q3 = (1.0 - p.gamma2) * p.k2 * v[..., 1]
    q4 = (1.0 - p.gamma1) * p.k1 * v[..., 0]
    dh1 = (-(p.a1 + leak[..., 0]) * s[..., 0] + p.a3 * s[..., 2] + q1) / p.A1
    dh2 = (-(p.a2 + leak[..., 1]) * s[..., 1] + p.a4 * s[..., 3] + q2) / p.A2
    dh3 = (-p.a3 * s[..., 2] + q3) / p.A3
    dh4 = (-p.a4 * s[..., 3] + q4) / p.A4
    return np.stack([dh1, dh2, dh3, dh4], axis=-1)


def simulate_quadtank_batch(
    h0: ArrayLike,
    v: ArrayLike,
    leak: ArrayLike | None = None,
    *,
    Ts: float = QUADTANK_TS,
    substeps: int = 20,
    params: QuadrupleTankParameters | None = None,
) -> FloatArray:
    """Integrate a batch of quadruple-tank processes over T periods (RK4, zero-order hold).

    Parameters
    ----------
    h0 : array_like, shape (B, 4) or (4,)
        Initial levels (h1, h2, h3, h4), cm.
    v : array_like, shape (B, T, 2) or (T, 2)
        Pump voltages per period, V (used as given: saturate before calling).
    leak : array_like broadcastable to v, optional
        Leak areas (a_L1, a_L2) per period, cm^2 (default 0).

    Returns
    -------
    ndarray, shape (B, T + 1, 4) (or (T + 1, 4) for unbatched input)
        Levels at the sampling instants 0..T.
    """
    par = params if params is not None else QuadrupleTankParameters()
    h = np.array(h0, dtype=np.float64)
    v_arr = np.asarray(v, dtype=np.float64)
    single = h.ndim == 1
    if single:
        h = h[None]
        v_arr = v_arr[None]
    if h.ndim != 2 or h.shape[1] != 4 or v_arr.ndim != 3 or v_arr.shape[2] != 2:
        raise DimensionError(
            f"h0 must be (B, 4) and v (B, T, 2) (or (4,) and (T, 2)); got {h.shape}, {v_arr.shape}"
        )
    if v_arr.shape[0] != h.shape[0]:
        raise DimensionError(f"h0 has {h.shape[0]} rows but v has {v_arr.shape[0]}")
    leak_arr = np.broadcast_to(
        np.zeros(2) if leak is None else np.asarray(leak, dtype=np.float64), v_arr.shape
    )
    B, T, _ = v_arr.shape
    out = np.empty((B, T + 1, 4))
    out[:, 0] = h
    dt = Ts / substeps
    for k in range(T):
        u, d = v_arr[:, k], leak_arr[:, k]
        for _ in range(substeps):
            k1 = _rhs(h, u, d, par)
            k2 = _rhs(h + 0.5 * dt * k1, u, d, par)
            k3 = _rhs(h + 0.5 * dt * k2, u, d, par)
            k4 = _rhs(h + dt * k3, u, d, par)
            h = np.maximum(h + (dt / 6.0) * (k1 + 2.0 * k2 + 2.0 * k3 + k4), 0.0)
        out[:, k + 1] = h
    return out[0] if single else out


class QuadrupleTankPlant:
    r"""Johansson's quadruple-tank process as a closed-loop plant (two pumps, two levels).

    Follows the :class:`~ltv_lstm_mpc.Plant` protocol with physical signals:
    ``step(u_phi, d_phi)`` takes the pump voltages (V, saturated per pump) and the leak areas
    of tanks 1 and 2 (cm^2, ``None``: no leak) and returns the measured lower levels (cm).
    See the module docstring for the equations, the integrator and the noise model.

    Parameters
    ----------
    Ts : float
        Sampling period, s (default :data:`QUADTANK_TS`).
    substeps : int
        RK4 steps per period.
    params : QuadrupleTankParameters, optional
        Default: Johansson's minimum-phase point.
    u_phi_min, u_phi_max : float
        Pump saturation, V (default :data:`QUADTANK_U_RANGE`).
    v_nominal : (float, float)
        Pump voltages of the initial steady state, V (Johansson's 3.0, 3.0).
    """

    #: Entries of ``d_phi`` in :meth:`step` (the leak areas of tanks 1 and 2, cm^2).
    disturbance_size: int = 2

    def __init__(
        self,
        Ts: float = QUADTANK_TS,
        substeps: int = 20,
        params: QuadrupleTankParameters | None = None,
        *,
        u_phi_min: float = QUADTANK_U_RANGE[0],
        u_phi_max: float = QUADTANK_U_RANGE[1],
        v_nominal: tuple[float, float] = (3.0, 3.0),
    ) -> None:
        Ts = expect_real("Ts", Ts, low=0.0, low_open=True, hint="the sampling time, s")
        substeps = expect_int("substeps", substeps, minimum=1)
        expect_real("u_phi_min", u_phi_min, hint="a pump voltage in V")
        expect_real("u_phi_max", u_phi_max, hint="a pump voltage in V")
        if params is not None:
            expect_instance(
                "params",
                params,
                QuadrupleTankParameters,
                expected="QuadrupleTankParameters or None",
            )

        if not (
            math.isfinite(u_phi_min) and math.isfinite(u_phi_max) and 0 <= u_phi_min < u_phi_max
        ):
            raise InvalidValueError(
                f"need 0 <= u_phi_min < u_phi_max (pump voltages, V), got {u_phi_min}, {u_phi_max}"
            )
        self.params = params if params is not None else QuadrupleTankParameters()
        self.Ts = float(Ts)
        self.substeps = int(substeps)
        self.u_phi_min = float(u_phi_min)
        self.u_phi_max = float(u_phi_max)
        self.v_nominal = real_vector("v_nominal (V)", v_nominal, 2)
        self.h: FloatArray = self.steady_state(self.v_nominal)

    # ------------------------------------------------------------- steady state
    def steady_state(self, v_phi: ArrayLike, leak: ArrayLike | None = None) -> FloatArray:
        """Steady levels (h1, h2, h3, h4) in cm for constant pump voltages (V) and leaks."""
        p = self.params
        v = real_vector("v_phi (V)", v_phi, 2)
        a_l = np.zeros(2) if leak is None else real_vector("leak (cm^2)", leak, 2)
        if np.any(v < 0) or np.any(a_l < 0):
            raise InvalidValueError(f"voltages and leak areas must be >= 0, got {v}, {a_l}")
        q3 = (1.0 - p.gamma2) * p.k2 * v[1]
        q4 = (1.0 - p.gamma1) * p.k1 * v[0]
        into1 = p.gamma1 * p.k1 * v[0] + q3
        into2 = p.gamma2 * p.k2 * v[1] + q4
        two_g = 2.0 * p.g
        return np.array(
            [
                (into1 / (p.a1 + a_l[0])) ** 2 / two_g,
                (into2 / (p.a2 + a_l[1])) ** 2 / two_g,
                (q3 / p.a3) ** 2 / two_g,
                (q4 / p.a4) ** 2 / two_g,
            ]
        )

    def steady_state_input(self, h_phi: ArrayLike) -> FloatArray:
        """Pump voltages (V) whose steady state (no leak) has the lower levels ``h_phi`` (cm).

        Solves the linear balance :math:`\\Gamma v = (a_1\\sqrt{2 g h_1}, a_2\\sqrt{2 g h_2})`;
        the result may lie outside the pump range (then the levels are not reachable).
        """
        p = self.params
        h = real_vector("h_phi (cm)", h_phi, 2)
        if np.any(h < 0):
            raise InvalidValueError(f"levels must be >= 0 cm, got {h}")
        gamma = np.array(
            [[p.gamma1 * p.k1, (1.0 - p.gamma2) * p.k2], [(1.0 - p.gamma1) * p.k1, p.gamma2 * p.k2]]
        )
        outflow = np.array([p.a1, p.a2]) * np.sqrt(2.0 * p.g * h)
        return np.asarray(np.linalg.solve(gamma, outflow), dtype=np.float64)

    # ------------------------------------------------------------------ protocol
    def saturate(self, u_phi: ArrayLike) -> FloatArray:
        """Clip the pump voltages to [u_phi_min, u_phi_max] V."""
        return np.clip(np.asarray(u_phi, dtype=np.float64), self.u_phi_min, self.u_phi_max)

    def reset(self, v_phi: ArrayLike | None = None) -> FloatArray:
        """Put the plant at the steady state of ``v_phi`` (default ``v_nominal``), no leak;
        returns the levels (h1, h2, h3, h4) in cm."""
        v = self.v_nominal if v_phi is None else real_vector("v_phi (V)", v_phi, 2)
        self.h = self.steady_state(v)
        return self.h.copy()

    def output(self) -> FloatArray:
        """Measured lower levels (h1, h2) in cm; shape (2,)."""
        return self.h[:2].copy()

    def step(self, u_phi: ArrayLike, d_phi: ArrayLike | None = None) -> FloatArray:
        """Apply the pump voltages ``u_phi`` (V, saturated) with the leak areas ``d_phi``
        (cm^2, default none) for one Ts; return the measured levels (h1, h2) in cm."""
        v = self.saturate(real_vector("u_phi (pump voltages, V)", u_phi, 2))
        if d_phi is None:
            leak = (0.0, 0.0)
        else:
            leak_arr = real_vector("d_phi (leak areas of tanks 1 and 2, cm^2)", d_phi, 2)
            if np.any(leak_arr < 0):
                raise InvalidValueError(
                    f"d_phi holds leak areas and must be >= 0 cm^2, got {leak_arr.tolist()}"
                )
            leak = (float(leak_arr[0]), float(leak_arr[1]))
        self.h = _rk4_scalar(self.h, (float(v[0]), float(v[1])), leak, self.Ts, self.substeps,
                             self.params)  # fmt: skip
        return self.output()


def _rk4_scalar(
    h: FloatArray,
    v: tuple[float, float],
    leak: tuple[float, float],
    Ts: float,
    substeps: int,
    p: QuadrupleTankParameters,
) -> FloatArray:
    """The RK4 of :func:`simulate_quadtank_batch` for one plant in plain Python floats."""
    two_g = 2.0 * p.g
    q1 = p.gamma1 * p.k1 * v[0]
    q2 = p.gamma2 * p.k2 * v[1]
    q3 = (1.0 - p.gamma2) * p.k2 * v[1]
    q4 = (1.0 - p.gamma1) * p.k1 * v[0]
    o1, o2 = p.a1 + leak[0], p.a2 + leak[1]
    sqrt = math.sqrt

    def rhs(x1: float, x2: float, x3: float, x4: float) -> tuple[float, float, float, float]:
        s1 = sqrt(two_g * x1) if x1 > 0 else 0.0
        s2 = sqrt(two_g * x2) if x2 > 0 else 0.0
        s3 = sqrt(two_g * x3) if x3 > 0 else 0.0
        s4 = sqrt(two_g * x4) if x4 > 0 else 0.0
        return (
            (-o1 * s1 + p.a3 * s3 + q1) / p.A1,
            (-o2 * s2 + p.a4 * s4 + q2) / p.A2,
            (-p.a3 * s3 + q3) / p.A3,
            (-p.a4 * s4 + q4) / p.A4,
        )

    x1, x2, x3, x4 = (float(value) for value in h)
    dt = Ts / substeps
    half = 0.5 * dt
    for _ in range(substeps):
        a1, a2, a3, a4 = rhs(x1, x2, x3, x4)
        b1, b2, b3, b4 = rhs(x1 + half * a1, x2 + half * a2, x3 + half * a3, x4 + half * a4)
        c1, c2, c3, c4 = rhs(x1 + half * b1, x2 + half * b2, x3 + half * b3, x4 + half * b4)
        e1, e2, e3, e4 = rhs(x1 + dt * c1, x2 + dt * c2, x3 + dt * c3, x4 + dt * c4)
        x1 = max(x1 + dt / 6.0 * (a1 + 2.0 * b1 + 2.0 * c1 + e1), 0.0)
        x2 = max(x2 + dt / 6.0 * (a2 + 2.0 * b2 + 2.0 * c2 + e2), 0.0)
        x3 = max(x3 + dt / 6.0 * (a3 + 2.0 * b3 + 2.0 * c3 + e3), 0.0)
        x4 = max(x4 + dt / 6.0 * (a4 + 2.0 * b4 + 2.0 * c4 + e4), 0.0)
    return np.array([x1, x2, x3, x4])
