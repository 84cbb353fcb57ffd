r"""The record of one controller step (:class:`ControllerStep`), whichever engine ran it.

A step engine that writes its numbers into the preallocated record rows
(:data:`~ltv_lstm_mpc.loop.compiled_step.RecordArrays`; the one-call engine) leaves its
records to be built from those rows when first read: :func:`recorded_step` and
:func:`recorded_reference` do that, here, once for every engine that writes rows.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from ltv_lstm_mpc.loop import compiled_step as rows_layout
from ltv_lstm_mpc.loop.monitor import AssumptionCheck, AssumptionLog
from ltv_lstm_mpc.loop.records import ControllerRecords
from ltv_lstm_mpc.loop.reference import ReferenceSolution
from ltv_lstm_mpc.loop.statuses import MEASUREMENT_STATUSES, SETPOINT_STATUSES
from ltv_lstm_mpc.mpc.fhocp import MPCSolution
from ltv_lstm_mpc.mpc.native_feedback import POLICIES, STATUS_CONE_FAILURE, feedback_outcome
from ltv_lstm_mpc.solvers.socp_sqp import snapshot_views

__all__ = ["ControllerStep", "recorded_reference", "recorded_step"]

FloatArray = NDArray[np.float64]


@dataclass(slots=True)  # one per control step: not frozen (2 us less to build)
class ControllerStep:
    """Everything one :meth:`OffsetFreeController.step` computed (normalized unless ``_phi``).

    Attributes
    ----------
    y, y0 : ndarray (p,)
        Measured output and the (rate-limited) set-point used.
    u : ndarray (m,)
        Applied input; ``u_phi`` is its physical value.
    x_hat, d_hat : ndarray
        Estimates used at this step (before the observer update).
    e_hat : float
        :math:`\\hat e_{o,k}` used.
    x_bar, u_bar : ndarray
        Reference-calculator set-points.
    reference_ok : bool
        The reference converged at this step with :math:`\\bar u \\in \\mathcal{U}`.
    stale_reference : bool
        Newton failed at this step: the previous :math:`(\\bar x, \\bar u)` was reused and
        the MPC got the set-point it actually encodes, :math:`g(\\bar x) + \\hat d`, so that
        the terminal set still implies the output constraints (Part 2a of Theorem 3's proof).
    mpc : MPCSolution
        The robust MPC result (status, policy, residuals, ...).
    time_observer, time_reference, time_mpc : float
        Wall time of each part, s.
    setpoint_status : str
        ``"ok"``; ``"outside_admissible"`` (the set-point lies outside the admissible
        interval of Assumption 5 at this :math:`\\hat e_{o,k}`: no terminal set);
        ``"unreachable_stale"`` (no equilibrium with :math:`\\bar u \\in \\mathcal U` for it:
        the previous target is kept, see ``stale_reference``); ``"unreachable"`` (the same
        at the first step: the inadmissible equilibrium found is used);
        ``"target_outside_admissible"`` (the rate-limited set-point used is admissible, but
        the requested one it moves towards is not: the limiter will carry it outside).
    d_hat_saturated : ndarray of bool (p,)
        :math:`|\\hat d_k| = d_{max}` per output (the saturation of eq. d_lstm_observer is
        active): the plant-model mismatch has reached the bound of
        :math:`\\mathcal D = \\{\\|d\\|_\\infty \\le d_{max}\\}` the guarantees assume.
    input_clipped : float
        How far (normalized, inf-norm) the MPC's first input had to be moved to lie in
        :math:`\\mathcal U = \\{\\|u\\|_\\infty \\le u_{max}\\}` at the controller's exit gate;
        0 when it was inside, ``inf`` when it was not finite and was replaced by the last
        applied input (the projection of :math:`\\bar u` onto U at the first step).
    measurement_status : str
        ``"ok"`` (the normalized measurement lies in [-1, 1], the training range);
        ``"outside_training_range"`` (up to one range width beyond it: the model
        extrapolates); ``"implausible"`` (further: ``|y|`` > ``IMPLAUSIBLE_MEASUREMENT_LIMIT``,
        most likely a sensor fault or wrong units).
    assumptions : AssumptionCheck
        (property) Theorem 3's hypotheses at this step and whether its guarantee held
        (``assumptions.guarantee``: ``"held"`` or ``"voided by ..."``; see
        :mod:`ltv_lstm_mpc.loop.monitor`), computed when first read (off the timed step).
    monitor_log, index : AssumptionLog, int
        Where ``assumptions`` comes from: the run's log and this step's index in it.
    engine : str
        The step engine that ran this step (:mod:`ltv_lstm_mpc.loop.engines`):
        ``"one-call"`` (one compiled call) or ``"reference"`` (stage by stage: every step
        of a controller whose configuration the one-call engine refuses, its first step,
        and the steps the one-call engine hands over).
    """

    y: FloatArray
    y0: FloatArray
    u: FloatArray
    u_phi: FloatArray
    x_hat: FloatArray
    d_hat: FloatArray
    e_hat: float
    x_bar: FloatArray
    u_bar: FloatArray
    reference_ok: bool
    mpc: MPCSolution
    time_observer: float
    time_reference: float
    time_mpc: float
    stale_reference: bool = False
    setpoint_status: str = "ok"
    d_hat_saturated: NDArray[np.bool_] | None = None
    input_clipped: float = 0.0
    measurement_status: str = "ok"
    monitor_log: AssumptionLog | None = None
    index: int = -1
    engine: str = "reference"

    @property
    def assumptions(self) -> AssumptionCheck | None:
        """Theorem 3's hypotheses at this step and whether its guarantee held (computed
        on first access, in step order; :mod:`ltv_lstm_mpc.loop.monitor`); None for a
        record built outside a controller."""
        if self.monitor_log is None:
            return None
        return self.monitor_log.verdict(self.index)

    @property
    def time_total(self) -> float:
        """Observer + reference + MPC wall time, s."""
        return self.time_observer + self.time_reference + self.time_mpc


def recorded_reference(records: ControllerRecords, k: int) -> ReferenceSolution:
    """The reference solution of step ``k``, from its record row."""
    rows = records.rows
    assert rows is not None
    return ReferenceSolution(
        x_bar=rows.x_bar[k].copy(),
        u_bar=rows.u_bar[k].copy(),
        residual=float(rows.real[k, rows_layout.REFERENCE_RESIDUAL]),
        jacobian_condition=math.nan,
        u_admissible=True,
        converged=True,
        iterations=int(rows.integer[k, rows_layout.REFERENCE_ITERATIONS]),
    )


def recorded_step(records: ControllerRecords, k: int, mpc: Any) -> ControllerStep:
    """The :class:`ControllerStep` of step ``k`` of the run ``records``, built from its row
    (when the record is first read); ``mpc``: the controller's MPC (its ``reformulation``
    and ``transcription`` name the subproblem)."""
    rows = records.rows
    assert rows is not None
    c = rows_layout
    real = rows.real[k].tolist()
    integer = rows.integer[k].tolist()
    prepare_time, feedback_time = real[c.PREPARE_TIME], real[c.FEEDBACK_TIME]
    parts = mpc.one_call_parts()
    if integer[c.STATUS] == STATUS_CONE_FAILURE:  # the certificate checks, on the copy
        real_copy, integer_copy = records.extras[k]
        snapshot = snapshot_views(real_copy, integer_copy, parts.socp_arrays)
        outcome, reason = parts.failure_outcome(
            snapshot, integer[c.FAILURE_FLAG_COLUMN], integer[c.FAILURE_SQP_COLUMN]
        )
        status = outcome.name.lower()
    else:
        status, reason = feedback_outcome(integer[c.STATUS], parts.flag_outcome)
    policy = POLICIES[integer[c.POLICY]]
    if policy.endswith("shift") and integer[c.U_BAR_PROJECTED]:  # (RobustMPC.feedback)
        reason += "; the candidate applied appends u_bar projected onto U"
    solution = MPCSolution(
        u=rows.u_plan[k],
        x=rows.x_plan[k],
        x_linear=rows.x_linear[k],
        status=status,
        feasible=policy == "nominal",
        policy=policy,
        solve_time=prepare_time + feedback_time,
        solver_time=real[c.SOLVER_TIME],
        iterations=integer[c.SQP_ITERATIONS],
        sqp_step=real[c.SQP_STEP],
        alpha=real[c.ALPHA],
        cost=real[c.COST],
        residuals={
            "output_violation": real[c.OUTPUT_VIOLATION],
            "terminal_residual": real[c.TERMINAL_RESIDUAL],
            "linearization_gap": real[c.LINEARIZATION_GAP],
        },
        reformulation=mpc.reformulation,
        solver_iterations=integer[c.SOLVER_ITERATIONS],
        transcription=mpc.transcription,
        prepare_time=prepare_time,
        feedback_time=feedback_time,
        reason=reason,
    )
    return ControllerStep(
        y=rows.y[k],
        y0=rows.y0[k],
        u=rows.u[k],
        u_phi=rows.u_phi[k],
        x_hat=rows.x_hat[k],
        d_hat=rows.d_hat[k],
        e_hat=real[c.E_HAT],
        x_bar=rows.x_bar[k],
        u_bar=rows.u_bar[k],
        reference_ok=not integer[c.STALE_REFERENCE],
        mpc=solution,
        time_observer=real[c.TIME_OBSERVER],
        time_reference=real[c.TIME_REFERENCE],
        time_mpc=real[c.TIME_MPC],
        stale_reference=bool(integer[c.STALE_REFERENCE]),
        setpoint_status=SETPOINT_STATUSES[integer[c.SETPOINT_STATUS]],
        d_hat_saturated=rows.saturated[k].astype(bool),
        input_clipped=real[c.INPUT_CLIPPED],
        measurement_status=MEASUREMENT_STATUSES[integer[c.MEASUREMENT_STATUS]],
        monitor_log=records.log,
        index=k,
        engine="one-call",
    )
