r"""The paper's five closed-loop simulations (Section V, Figs. 3-7) on the shipped model.

1. ``lstm_theorem3`` — LSTM plant (Fig. 2), slow set-point and disturbance changes that
   satisfy Theorem 3's conditions: the set-point passes through the rate limiter
   :math:`\Delta y^0_{max}` of paper notes 2.10c and the disturbance ramps with
   :math:`|w| \le w_{max}`. Expected: zero violations, every step feasible, zero
   steady-state error (Fig. 3).
2. ``lstm_larger`` — larger set-point rate and disturbance steps that violate the
   sufficient conditions; feasibility is kept in practice (Fig. 4).
3. ``lstm_steps`` — still larger set-point steps: infeasible instants (shaded), where the
   paper's fallback (no output/terminal constraints) is applied (Fig. 5).
4. ``ph_small_Ld`` — the pH plant with :math:`L_d = 0.01`: offset-free, slowly (Fig. 6).
5. ``ph_large_Ld`` — the pH plant with :math:`L_d = 0.1`: offset-free, faster, constraints
   respected (Fig. 7).

The paper gives no numeric schedules for its figures; these are ours, chosen to show each
figure's point, and fixed here so every run (and the solver comparison) uses the same ones.
Physical units: pH for outputs and the LSTM plant's output disturbance, mL/s for q2.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np
from numpy.typing import NDArray

from ltv_lstm_mpc.certificates.certify import Certification, certify
from ltv_lstm_mpc.exceptions import InvalidValueError
from ltv_lstm_mpc.loop.controller import OffsetFreeController
from ltv_lstm_mpc.loop.monitor import AssumptionMonitor
from ltv_lstm_mpc.loop.schedules import piecewise_constant
from ltv_lstm_mpc.loop.schedules import segments as schedule_segments
from ltv_lstm_mpc.loop.simulation import SimulationResult, simulate
from ltv_lstm_mpc.lstm.model import LSTMModel
from ltv_lstm_mpc.mpc.config import MPCConfig
from ltv_lstm_mpc.mpc.fhocp import MPCSolver
from ltv_lstm_mpc.plants.protocol import Plant
from ltv_lstm_mpc.plants.registry import resolve_plant

__all__ = [
    "SETTLE_SAMPLES",
    "Scenario",
    "ScenarioResult",
    "paper_scenarios",
    "run_scenario",
]

FloatArray = NDArray[np.float64]

#: Output constraint of the paper, pH.
Y_PHI_MIN, Y_PHI_MAX = 6.0, 9.0


def _ramped(
    levels: Sequence[float], lengths: Sequence[int], slope: float, start: float
) -> FloatArray:
    """Piecewise-constant targets reached by ramps of at most ``slope`` per step."""
    target = piecewise_constant(levels, lengths)
    out = np.empty_like(target)
    value = start
    for k, goal in enumerate(target):
        value += float(np.clip(goal - value, -slope, slope))
        out[k] = value
    return out


@dataclass(frozen=True)
class Scenario:
    """One closed-loop experiment.

    Attributes
    ----------
    name, title : str
        Identifier and plot title.
    plant : str
        A plant name of the registry (:mod:`ltv_lstm_mpc.plants.registry`): ``"lstm"``,
        LSTM + output disturbance (Fig. 2), ``"ph"``, the pH process (Fig. 1), or another
        registered name or ``"package.module:Class"``.
    setpoints : ndarray (steps,)
        Requested set-point :math:`y^0_\\phi` (pH) per sample, before the rate limiter.
    disturbances : ndarray (steps,)
        LSTM plant: output disturbance in pH; pH plant: buffer flow q2 in mL/s; NaN
        everywhere: the plant's own default disturbance.
    config : MPCConfig
        Controller tuning.
    setpoint_rate_limit : float or None
        Normalized :math:`\\Delta y^0_{max}` per step (None: no limiter).
    segments : list of (start, end)
        Constant set-point/disturbance segments [start, end) long enough to settle;
        ``final_offset`` is evaluated at their last sample.
    y0_phi_initial : float
        Initial plant output (pH); the plant starts at the equilibrium giving it.
    notes : str
        What the scenario's numbers come from, in words.
    rate_certification : Certification, optional
        The certification whose rate bound the limiter uses (its own set-point range);
        the controller's assumption monitor checks against it
        (:mod:`ltv_lstm_mpc.loop.monitor`). None: the controller's own.
    """

    name: str
    title: str
    plant: str
    setpoints: FloatArray
    disturbances: FloatArray
    config: MPCConfig
    setpoint_rate_limit: float | None
    segments: list[tuple[int, int]] = field(default_factory=list)
    y0_phi_initial: float = 7.0
    notes: str = ""
    rate_certification: Certification | None = None

    @property
    def steps(self) -> int:
        """Number of samples."""
        return int(self.setpoints.shape[0])

    def make_plant(self, model: LSTMModel) -> Plant:
        """A fresh plant at its initial condition (through the plant registry)."""
        entry = resolve_plant(self.plant)
        options = {"y0_phi": self.y0_phi_initial} if "y0_phi" in entry.options else {}
        return entry.build(model, **options)

    def make_controller(
        self,
        model: LSTMModel,
        *,
        mpc: MPCSolver | None = None,
        solver: str | None = None,
        N: int | None = None,
    ) -> OffsetFreeController:
        """The controller of this scenario (optionally another solver, horizon or MPC)."""
        config = self.config
        if solver is not None:
            config = replace(config, solver=solver)
        if N is not None:
            config = replace(config, N=N)
        monitor = None
        if self.rate_certification is not None:
            monitor = AssumptionMonitor(model, self.rate_certification)
        return OffsetFreeController(
            model, config, setpoint_rate_limit=self.setpoint_rate_limit, mpc=mpc, monitor=monitor
        )


@dataclass(frozen=True)
class ScenarioResult:
    """A scenario's simulation and its summary numbers (see :meth:`summary`)."""

    scenario: Scenario
    simulation: SimulationResult
    controller: OffsetFreeController

    def summary(self) -> dict[str, Any]:
        """Numbers of ``summary.json``: violations, infeasible steps, offsets, timings."""
        sim, sc = self.simulation, self.scenario
        y = sim.y_phi[:, 0]
        violation = float(max(0.0, np.max(Y_PHI_MIN - y), np.max(y - Y_PHI_MAX)))
        offsets = [abs(float(y[end - 1] - sc.setpoints[end - 1])) for _, end in sc.segments]
        cert = self.controller.certification
        return {
            "name": sc.name,
            "title": sc.title,
            "plant": sc.plant,
            "steps": sc.steps,
            "solver": self.controller.config.solver,
            "N": self.controller.config.N,
            "L_d": self.controller.config.L_d,
            "setpoint_rate_limit": sc.setpoint_rate_limit,
            "max_output_violation": violation,
            "max_predicted_violation": float(np.max(sim.output_violation)),
            "infeasible_steps": int(np.sum(~sim.feasible)),
            "fallback_steps": int(np.sum(sim.policy != "nominal")),
            **{k: v for k, v in sim.summary_counts().items() if k != "infeasible_steps"},
            "final_offset": max(offsets) if offsets else None,
            "segment_offsets": offsets,
            "median_step_time_s": float(np.median(sim.time_total)),
            "max_step_time_s": float(np.max(sim.time_total)),
            "median_mpc_time_s": float(np.median(sim.time_mpc)),
            "rho_o": cert.observer.rho_o,
            "L_max": cert.observer.L_max,
            "e_inf": cert.tightening.e_inf,
            "y0_interval_phi": [float(v[0]) for v in cert.y0_interval_phi]
            if cert.y0_interval_phi is not None
            else None,
        }


#: Samples scenario 1 leaves after the rate-limited set-point has arrived (to settle).
SETTLE_SAMPLES = 200


def paper_scenarios(model: LSTMModel, *, short: bool = False) -> list[Scenario]:
    """The five scenarios of the paper's Section V for ``model`` (the shipped pH model).

    Parameters
    ----------
    model : LSTMModel
        Used for Theorem 3's rate bound and the disturbance-variation bound.
    short : bool
        Shorter schedules (about a quarter of the samples) for smoke tests; the segments
        may then be too short to settle.
    """
    scale = 1 if not short else 4
    base = MPCConfig()
    levels1 = [7.5, 6.9, 7.6, 7.2]
    range1 = (min(*levels1, 7.0), max(*levels1, 7.0))  # with the initial output 7.0 pH
    # Theorem 3's rate bound with the smallest alpha over scenario 1's set-point range.
    operating = model.normalize_y(np.array(range1))
    settings = replace(
        base.certification_settings(model),
        y0_operating_range=(float(operating[0]), float(operating[1])),
    )
    slow_cert = certify(model, settings)
    if not slow_cert.rate_bound.holds:
        raise InvalidValueError("Theorem 3's rate condition cannot hold for this model and range")
    rate = slow_cert.rate_bound.delta_y0_max
    y_scale = float(model.normalization.y_scale[0]) if model.normalization is not None else 1.0
    w_max_phi = slow_cert.observer.w_max * y_scale  # pH per step
    scenarios: list[Scenario] = []

    # 1: Theorem 3's conditions (rate-limited set-point, |w| <= w_max). Each segment is
    # long enough for the limited set-point to arrive and settle: a model with a smaller
    # rate bound (larger K_bar, Lemma 5) gets longer segments, the shipped one 900/600.
    L = [900 // scale, 900 // scale, 900 // scale, 600 // scale]
    if not short:
        steps_normalized = np.abs(np.diff(model.normalize_y(np.array([7.0, *levels1]))))
        ramps = np.ceil(steps_normalized.ravel() / rate).astype(int)
        L = [max(length, int(ramp) + SETTLE_SAMPLES) for length, ramp in zip(L, ramps, strict=True)]
    d_ramp = np.clip(np.arange(sum(L)) - 50 // scale, 0, None) * 0.8 * w_max_phi
    d_ramp = np.minimum(d_ramp, 0.02)
    scenarios.append(
        Scenario(
            name="1_lstm_theorem3",
            title="LSTM plant, slow changes satisfying Theorem 3",
            plant="lstm",
            setpoints=piecewise_constant(levels1, L),
            disturbances=d_ramp,
            config=base,
            setpoint_rate_limit=rate,
            segments=schedule_segments(L),
            notes=(
                f"rate limit {rate:.4g} (normalized/step, paper notes 2.10c, valid over "
                f"[{range1[0]}, {range1[1]}] pH); |w| <= 0.8 w_max"
            ),
            rate_certification=slow_cert,
        )
    )
    # 2: larger changes: 10x faster set-point, disturbance steps.
    L2 = [600 // scale] * 4
    scenarios.append(
        Scenario(
            name="2_lstm_larger",
            title="LSTM plant, larger set-point and disturbance changes",
            plant="lstm",
            setpoints=piecewise_constant([7.8, 6.7, 8.2, 7.0], L2),
            disturbances=piecewise_constant([0.0, 0.08, -0.06, 0.04], L2),
            config=base,
            setpoint_rate_limit=10 * rate,
            segments=schedule_segments(L2),
            notes="10x Theorem 3's rate, output-disturbance steps of 0.06-0.14 pH",
        )
    )
    # 3: set-point steps, no limiter: infeasible instants.
    scenarios.append(
        Scenario(
            name="3_lstm_steps",
            title="LSTM plant, large set-point steps (infeasible instants shaded)",
            plant="lstm",
            setpoints=piecewise_constant([8.3, 6.6, 8.4, 7.0], L2),
            disturbances=piecewise_constant([0.0, 0.1, -0.1, 0.0], L2),
            config=base,
            setpoint_rate_limit=None,
            segments=schedule_segments(L2),
            notes="set-point steps without rate limiter",
        )
    )
    # 4 and 5: the pH plant with a q2 step.
    L4 = [1500 // scale, 1500 // scale, 1500 // scale]
    q2 = piecewise_constant([0.55, 0.7], [L4[0], L4[1] + L4[2]])  # q2 step with the 2nd set-point
    for name, title, l_d, lengths, disturbance in (
        ("4_ph_small_Ld", "pH plant, L_d = 0.01 (offset-free, slow)", 0.01, L4, q2),
        (
            "5_ph_large_Ld",
            "pH plant, L_d = 0.1 (offset-free, faster)",
            0.1,
            [500 // scale] * 4,
            piecewise_constant([0.55, 0.7, 0.45, 0.55], [500 // scale] * 4),
        ),
    ):
        levels = [7.5, 6.8, 8.0, 7.0][: len(lengths)]
        scenarios.append(
            Scenario(
                name=name,
                title=title,
                plant="ph",
                setpoints=piecewise_constant(levels, lengths),
                disturbances=disturbance[: sum(lengths)],
                config=replace(base, L_d=l_d),
                setpoint_rate_limit=0.01,
                segments=schedule_segments(lengths),
                notes="q2 steps; set-point rate limit 0.01 normalized/step",
            )
        )
    return scenarios


def run_scenario(
    scenario: Scenario,
    model: LSTMModel,
    *,
    mpc: MPCSolver | None = None,
    solver: str | None = None,
    N: int | None = None,
    progress: bool = False,
    check_sampling_time: bool = True,
) -> ScenarioResult:
    """Simulate one scenario in closed loop and return it with its summary
    (``check_sampling_time``: as :func:`~ltv_lstm_mpc.simulate`'s)."""
    controller = scenario.make_controller(model, mpc=mpc, solver=solver, N=N)
    plant = scenario.make_plant(model)
    disturbances = scenario.disturbances
    result = simulate(
        plant,
        controller,
        scenario.setpoints,
        None if np.all(np.isnan(disturbances)) else disturbances,
        scenario.steps,
        progress=progress,
        description=scenario.name,
        check_sampling_time=check_sampling_time,
    )
    return ScenarioResult(scenario=scenario, simulation=result, controller=controller)
