r"""The reference step engine: the paper's loop (Fig. 1), one component after the other.

The readable specification of a controller step, and the engine of every configuration
(any transcription, solver, policy, SQP, a custom ``mpc``, the numpy kernels). Each stage
is its component's method, with that component's compiled kernel or numpy reference:

1. normalization (paper notes 1) and the measurement status;
2. the set-point rate limiter (Theorem 3's :math:`\Delta y^0_{max}`);
3. the reference calculator, eq. (reference_calculation), with the stale-reference rule
   (Theorem 3, Part 2a) and the set-point status of Assumption 5;
4. the robust MPC, eq. (optimization): ``prepare`` (candidate, linearization, tightened
   bounds, :math:`\alpha_k`) then ``feedback`` (insert :math:`\hat x_k`, solve, validate,
   policies);
5. the exit gate onto :math:`\mathcal U`;
6. the observer, eq. (lstm_observer), and eq. (eo_evolution);
7. de-normalization, and the step's record.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import ArrayLike, NDArray

from ltv_lstm_mpc.exceptions import UnreachableSetpointError
from ltv_lstm_mpc.loop.diagnostics import (
    check_first_measurement,
    measurement_status,
    setpoint_status,
    warn_clipped,
    warn_diagnosis,
)
from ltv_lstm_mpc.loop.reference import ReferenceSolution
from ltv_lstm_mpc.loop.signals import limit_rate, project_onto_box
from ltv_lstm_mpc.loop.step_record import ControllerStep, recorded_reference
from ltv_lstm_mpc.mpc.fhocp import MPCSolution
from ltv_lstm_mpc.mpc.rti import RobustMPC
from ltv_lstm_mpc.validation import real_vector

if TYPE_CHECKING:
    from ltv_lstm_mpc.loop.controller import OffsetFreeController

__all__ = ["Handover", "ReferenceEngine"]

FloatArray = NDArray[np.float64]


@dataclass(frozen=True, slots=True)
class Handover:
    """What another engine already ran of a step it hands over to this one.

    Attributes
    ----------
    chord : (z, residual, iterations, converged) or None
        The warm chord Newton's outcome (the reference calculator goes on from it).
    feedback_declined : bool
        That engine's feedback declined this step's point (the general feedback runs).
    """

    chord: tuple[FloatArray, float, int, bool] | None
    feedback_declined: bool


class ReferenceEngine:
    """The paper's loop, stage by stage (module docstring); supports every configuration.

    Parameters
    ----------
    controller : OffsetFreeController
        The loop it runs (components, configuration, records, warnings).
    """

    name = "reference"
    record_shape: tuple[int, int, int, int] | None = None

    @staticmethod
    def refusal(controller: OffsetFreeController) -> str | None:
        """None: every configuration runs here."""
        return None

    def __init__(self, controller: OffsetFreeController) -> None:
        self.controller = controller
        mpc = controller.mpc
        #: The MPC has ``prepare`` / ``feedback`` (else only ``solve``).
        self.phases = hasattr(mpc, "prepare") and hasattr(mpc, "feedback")
        self.reset()

    def reset(self) -> None:
        """Forget the run's references."""
        #: The last admissible reference (None: none, or the one of ``recorded_row``).
        self.last_reference: ReferenceSolution | None = None
        #: The record row holding the last admissible reference (-1: none there).
        self.recorded_row = -1
        #: The last converged one, before any admissible one.
        self.last_converged: ReferenceSolution | None = None
        #: (e_hat, lows, highs): the admissible set-point interval at that e_hat.
        self.interval: tuple[float, tuple[list[float], list[float]]] = (math.nan, ([], []))

    def remember_recorded(self, k: int) -> None:
        """The last admissible reference is the one of record row ``k`` (built on demand)."""
        self.last_reference = None
        self.recorded_row = k

    def settle(self) -> None:
        """Nothing kept aside."""

    def prepare(self, y0_phi: FloatArray | None) -> bool:
        """Not between samples: the MPC prepares inside the step."""
        return False

    # ----------------------------------------------------------------------- the step
    def step(
        self, y_phi: ArrayLike, y0_phi: ArrayLike, handover: Handover | None = None
    ) -> FloatArray:
        """One sample of Fig. 1 (module docstring); ``handover``: what another engine ran
        of this step already."""
        controller = self.controller
        observer, records = controller.observer, controller.records
        y, y0_target = self._normalize(y_phi, y0_phi)
        if not controller.initialized:
            check_first_measurement(controller, y, y_phi)
        status_y = measurement_status(controller, y, y_phi)
        t0 = time.perf_counter()
        if not controller.initialized:
            self._start(y)
        y0 = self._limit(y0_target)
        # No copies: the observer update rebinds x_hat and d_hat, it never mutates them.
        x_hat, d_hat = observer.x_hat, observer.d_hat
        t1 = time.perf_counter()
        if handover is None or handover.chord is None:
            solved = controller.reference.solve_arrays(y0, d_hat)  # checked (p,) float64
        else:
            solved = controller.reference.solve_arrays(y0, d_hat, chord=handover.chord)
        reference, y0_mpc, stale = self._reference(solved, y0, d_hat)
        status_y0, saturated = self._diagnose(y0, y0_target, d_hat, reference, stale)
        t2 = time.perf_counter()
        declined = handover is not None and handover.feedback_declined
        solution = self._solve_mpc(x_hat, reference, y0_mpc, declined)
        u = solution.u[0].copy()
        inside = _strictly_inside(u, controller.scaling.u_max)
        input_clipped = 0.0
        if not inside:  # outside U, non-finite, or on its boundary
            u, input_clipped = self._gate(u, reference.u_bar)
        t3 = time.perf_counter()
        observer.update(y, u)
        e_hat_used = controller.e_hat
        controller.e_hat = controller.certification.tightening.next_e_hat(e_hat_used)
        t4 = time.perf_counter()
        u_phi = controller.scaling.denormalize_u(u)
        if not inside:  # never beyond the physical bounds (rounding of the de-normalization)
            np.clip(u_phi, controller.scaling.u_phi_low, controller.scaling.u_phi_high, out=u_phi)
        records.append(
            ControllerStep(
                y=y, y0=y0, u=u, u_phi=u_phi, x_hat=x_hat, d_hat=d_hat, e_hat=e_hat_used,
                x_bar=reference.x_bar, u_bar=reference.u_bar,
                reference_ok=reference.ok and not stale, mpc=solution,
                time_observer=(t1 - t0) + (t4 - t3), time_reference=t2 - t1,
                time_mpc=t3 - t2, stale_reference=stale, setpoint_status=status_y0,
                d_hat_saturated=saturated, input_clipped=input_clipped,
                measurement_status=status_y, monitor_log=controller.assumption_log,
                index=len(records), engine=self.name,
            )
        )  # fmt: skip
        return u_phi

    # ----------------------------------------------------------------------- stages
    def _normalize(self, y_phi: ArrayLike, y0_phi: ArrayLike) -> tuple[FloatArray, FloatArray]:
        """Normalized measurement and set-point, checked (paper notes 1)."""
        controller = self.controller
        p = controller.model.p
        y_arr = real_vector("y_phi", y_phi, p)
        y0_arr = real_vector("y0_phi", y0_phi, p)
        controller.requested_phi = y0_arr
        scaling = controller.scaling
        return scaling.normalize_y(y_arr), scaling.normalize_y(y0_arr)

    def _start(self, y: FloatArray) -> None:
        """The first step: the observer at the LSTM equilibrium matching :math:`y_0` with
        :math:`\\hat d_0 = 0` (paper notes 2.10b); the limiter starts from :math:`y_0`."""
        controller = self.controller
        controller.observer.initialize(y, reference=controller.reference)
        controller.reference.reset()
        controller.initialized = True
        if controller.setpoint_rate_limit is not None:
            controller.y0_last = y.copy()

    def _limit(self, y0_target: FloatArray) -> FloatArray:
        """The rate-limited set-point (:func:`~ltv_lstm_mpc.loop.signals.limit_rate`)."""
        controller = self.controller
        previous, limit = controller.y0_last, controller.setpoint_rate_limit
        y0 = (
            y0_target
            if previous is None or limit is None
            else limit_rate(y0_target, previous, limit)
        )
        controller.y0_last = y0
        return y0

    def _reference(
        self, reference: ReferenceSolution, y0: FloatArray, d_hat: FloatArray
    ) -> tuple[ReferenceSolution, FloatArray, bool]:
        """Use ``reference``, or the last one if Newton failed; returns (ref, y0 for MPC,
        stale).

        With a stale reference the MPC gets :math:`y^0 = g(\\bar x) + \\hat d`, the
        set-point the reused equilibrium encodes, keeping eq.
        (reference_calculation_output) true for the terminal set (Theorem 3, Part 2a).
        """
        controller = self.controller
        if reference.ok:
            self.last_reference, self.recorded_row = reference, -1
            return reference, y0, False
        last = self.last_reference
        if last is None and self.recorded_row >= 0:
            last = recorded_reference(controller.records, self.recorded_row)
        if last is None:  # no admissible equilibrium yet
            if reference.converged:  # nothing better to keep
                self.last_converged = reference
                return reference, y0, False
            last = self.last_converged  # Newton failed: keep the last equilibrium found
        if last is None:
            raise UnreachableSetpointError(
                f"the reference calculator found no equilibrium for the set-point "
                f"{controller.scaling.physical_y(y0)} (physical; {y0.tolist()} normalized), "
                f"d_hat = {d_hat.tolist()} at step {len(controller.records)}, nor any "
                f"before (residual {reference.residual:.2e}): start from a set-point the "
                "model can reach (certify's y0_interval), or let setpoint_rate_limit move "
                "it there from the measured output"
            )
        y0_stale = controller.model.output(last.x_bar) + d_hat
        return last, np.asarray(y0_stale, dtype=np.float64), True

    def _diagnose(
        self,
        y0: FloatArray,
        y0_target: FloatArray,
        d_hat: FloatArray,
        reference: ReferenceSolution,
        stale: bool,
    ) -> tuple[str, NDArray[np.bool_]]:
        """Set-point status and saturated outputs of this step; warns once per run."""
        controller = self.controller
        limit = controller.config.d_max * (1.0 - 1e-12)
        saturated = np.array([abs(d) >= limit for d in d_hat.tolist()])  # p scalars: lists
        e_hat = controller.e_hat
        if self.interval[0] != e_hat:
            low, high = controller.certification.tightening.setpoint_interval(e_hat)
            self.interval = (e_hat, (low.tolist(), high.tolist()))
        status = setpoint_status(self.interval[1], y0, y0_target, stale, reference.u_admissible)
        warn_diagnosis(controller, status, saturated, y0, y0_target, stale)
        return status, saturated

    def _solve_mpc(
        self, x_hat: FloatArray, reference: ReferenceSolution, y0: FloatArray, declined: bool
    ) -> MPCSolution:
        """The FHOCP eq. (optimization): ``prepare`` (candidate, linearization, build) then
        ``feedback`` (insert x_hat, solve, validate); ``declined``: the one-call feedback
        already declined this point."""
        controller = self.controller
        mpc, e_hat = controller.mpc, controller.e_hat
        if not self.phases:
            return mpc.solve(x_hat, reference.x_bar, reference.u_bar, y0, e_hat)
        mpc.prepare(reference.x_bar, reference.u_bar, y0, e_hat, x_pred=x_hat)
        if declined:  # (only the one-call engine hands over, on a RobustMPC)
            assert isinstance(mpc, RobustMPC)
            return mpc.feedback(x_hat, native=False)
        return mpc.feedback(x_hat)

    def _gate(self, u: FloatArray, u_bar: FloatArray) -> tuple[FloatArray, float]:
        """The exit gate: ``u`` projected onto U, and how far it moved (inf-norm; inf when
        it was not finite and the last applied input, or the projection of u_bar at the
        first step, replaces it)."""
        controller = self.controller
        u_max = controller.scaling.u_max
        if all(-u_max <= v <= u_max for v in u.tolist()):  # NaN fails the test
            return u, 0.0
        if np.isfinite(u).all():
            gated, moved = project_onto_box(u, u_max)
        else:
            records = controller.records
            gated = records[-1].u.copy() if records else np.clip(u_bar, -u_max, u_max)
            moved = math.inf
        if controller.warnings.first("input_clipped"):
            warn_clipped(controller, u, moved)
        return gated, moved


def _strictly_inside(u: FloatArray, u_max: float) -> bool:
    """Every entry strictly inside (-u_max, u_max) (NaN fails)."""
    return all(-u_max < v < u_max for v in u.tolist())
