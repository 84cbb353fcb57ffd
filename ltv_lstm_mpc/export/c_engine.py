r"""The C engine: the controller's step as the exported C99 code, on the host.

:class:`CEngine` exports the controller (:func:`~ltv_lstm_mpc.export.c_model.export_model_c`
with ``controller=``), builds it with the host's C compiler and runs each step through
``<prefix>_controller_step`` (:mod:`ltv_lstm_mpc.export.sil`): software in the loop, with
the records, warnings and errors of the reference engine, so that ``simulate``, the paper's
scenarios (``reproduce --engine c``) and campaigns run the C code. It checks the signals
as the reference engine does before the call (it raises where that one raises); what the
C code computes (the observer's estimates, the reference, the plan, the input, the
statuses) goes into the records as it is. Chosen only when asked for
(``OffsetFreeController(..., engine="c")``), for the configurations the export covers.

Its timings: the C call as a whole is the record's ``time_mpc`` (``time_observer`` and
``time_reference`` are 0: the C step is not split), and the MPC's ``solver_time`` is NaN
(DAQP is built without its timer).
"""

from __future__ import annotations

import shutil
import tempfile
import time
import weakref
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from ltv_lstm_mpc.exceptions import LtvMpcError, UnreachableSetpointError
from ltv_lstm_mpc.loop.diagnostics import (
    check_first_measurement,
    measurement_status,
    warn_clipped,
    warn_diagnosis,
)
from ltv_lstm_mpc.loop.statuses import SETPOINT_STATUSES
from ltv_lstm_mpc.loop.step_record import ControllerStep
from ltv_lstm_mpc.mpc.fhocp import MPCSolution
from ltv_lstm_mpc.validation import real_vector

if TYPE_CHECKING:
    from ltv_lstm_mpc.loop.controller import OffsetFreeController

__all__ = ["CEngine", "SingleCEngine"]

FloatArray = NDArray[np.float64]

#: The prefix of the C identifiers of the engine's export.
PREFIX = "ltv_c"


class CEngine:
    """The exported C step on the host (module docstring).

    Parameters
    ----------
    controller : OffsetFreeController
        The loop it runs.
    """

    name = "c"
    #: The export's precision (``export_model_c(..., precision=)``).
    precision = "double"
    record_shape: tuple[int, int, int, int] | None = None

    @classmethod
    def refusal(cls, controller: OffsetFreeController) -> str | None:
        """Why the C export does not cover this controller (None: it does)."""
        from ltv_lstm_mpc.export.c_model import export_refusal

        return export_refusal(controller, precision=cls.precision)

    def __init__(self, controller: OffsetFreeController) -> None:
        from ltv_lstm_mpc.export.c_model import export_model_c
        from ltv_lstm_mpc.export.sil import CController, compile_controller

        self.controller = controller
        folder = Path(tempfile.mkdtemp(prefix="ltv_lstm_mpc_c_"))
        weakref.finalize(self, shutil.rmtree, folder, True)
        #: What the export wrote (a temporary folder, removed with the engine).
        self.exported = export_model_c(
            controller.model, folder, controller=controller, prefix=PREFIX,
            precision=self.precision,
        )  # fmt: skip
        self.c = CController(compile_controller(self.exported), self.exported)
        self.reset()

    def reset(self) -> None:
        """Back to before the first step (the C controller too)."""
        self.c.reset()

    def settle(self) -> None:
        """Nothing kept aside."""

    def prepare(self, y0_phi: FloatArray | None) -> bool:
        """Not between samples: the C step runs whole."""
        return False

    def step(self, y_phi: ArrayLike, y0_phi: ArrayLike) -> FloatArray:
        """One sample through the C step; the record as the reference engine's."""
        controller = self.controller
        p, scaling = controller.model.p, controller.scaling
        y_arr = real_vector("y_phi", y_phi, p)
        y0_arr = real_vector("y0_phi", y0_phi, p)
        controller.requested_phi = y0_arr
        y, y0_target = scaling.normalize_y(y_arr), scaling.normalize_y(y0_arr)
        if not controller.initialized:
            check_first_measurement(controller, y, y_arr)
        status_y = measurement_status(controller, y, y_arr)
        start = time.perf_counter()
        code, u_phi, r = self.c.step(y_arr, y0_arr)
        elapsed = time.perf_counter() - start
        if code == 3:
            raise UnreachableSetpointError(
                f"the reference calculator found no equilibrium for the set-point "
                f"{y0_arr.tolist()} (physical) at step {len(controller.records)}, nor any "
                "before: start from a set-point the model can reach (certify's y0_interval), "
                "or let setpoint_rate_limit move it there from the measured output"
            )
        if code != 0:  # (the checks above refuse what the C step refuses)
            raise LtvMpcError(f"the C step refused the step (code {code}) the checks passed")
        controller.initialized = True
        x_hat_next, d_hat_next, e_hat_next = self.c.state()
        controller.observer.reset(x_hat_next, d_hat_next)
        e_hat_used = controller.e_hat
        controller.e_hat = e_hat_next
        y0 = np.array(r.y0[:], dtype=np.float64)
        if controller.setpoint_rate_limit is not None:
            controller.y0_last = y0
        d_hat = np.array(r.d_hat[:], dtype=np.float64)
        stale = r.setpoint_status == SETPOINT_STATUSES.index("unreachable_stale")
        status_y0 = SETPOINT_STATUSES[r.setpoint_status]
        limit = controller.config.d_max * (1.0 - 1e-12)
        saturated = np.array([abs(d) >= limit for d in d_hat.tolist()])
        warn_diagnosis(controller, status_y0, saturated, y0, y0_target, stale)
        u = np.array(r.u[:], dtype=np.float64)
        if r.input_clipped > 0.0 and controller.warnings.first("input_clipped"):
            warn_clipped(controller, np.array(self.c.plan()[0][0]), r.input_clipped)
        solution = self._solution(r, elapsed)
        controller.records.append(
            ControllerStep(
                y=np.array(r.y[:]), y0=y0, u=u, u_phi=u_phi.copy(),
                x_hat=np.array(r.x_hat[:]), d_hat=d_hat, e_hat=e_hat_used,
                x_bar=np.array(r.x_bar[:]), u_bar=np.array(r.u_bar[:]),
                reference_ok=status_y0 not in ("unreachable", "unreachable_stale"),
                mpc=solution, time_observer=0.0, time_reference=0.0, time_mpc=elapsed,
                stale_reference=stale, setpoint_status=status_y0, d_hat_saturated=saturated,
                input_clipped=float(r.input_clipped), measurement_status=status_y,
                monitor_log=controller.assumption_log, index=len(controller.records),
                engine=self.name,
            )
        )  # fmt: skip
        return u_phi

    def _solution(self, r: Any, elapsed: float) -> MPCSolution:
        """The MPC's outcome of the C record (and the plan the C controller holds)."""
        from ltv_lstm_mpc.export.sil import (
            CONE_FAILED,
            CONE_MAX_ITER,
            MPC_STATUS_NAMES,
            POLICY_NAMES,
        )

        mpc = self.controller.mpc
        feedback = r.mpc
        status = MPC_STATUS_NAMES.get(feedback.status, "failed")
        feasible = status in ("optimal", "optimal_inaccurate")
        reason = ""
        if not feasible:
            reason = status if feedback.status <= -100 else f"exitflag {feedback.status}"
            if feedback.status == -102:
                reason = "the QP's point failed the acceptance tests (C step)"
            if feedback.status in (CONE_FAILED, CONE_MAX_ITER):
                status, reason = self.c.cone_outcome(feedback, self.controller.config)
        u, x_plan, x_linear = self.c.plan()
        return MPCSolution(
            u=u, x=x_plan, x_linear=x_linear, status=status, feasible=feasible,
            policy=POLICY_NAMES[feedback.policy], solve_time=elapsed,
            solver_time=float("nan"), iterations=int(feedback.iterations),
            sqp_step=float(feedback.sqp_step), alpha=float(r.alpha), cost=float(feedback.cost),
            residuals={
                "output_violation": float(feedback.output_violation),
                "terminal_residual": float(feedback.terminal_norm) - float(r.alpha),
                "linearization_gap": float(feedback.linearization_gap),
            },
            reformulation=getattr(mpc, "reformulation", None),
            solver_iterations=int(feedback.qp_iterations), transcription="condensed",
            feedback_time=elapsed, reason=reason,
        )  # fmt: skip


class SingleCEngine(CEngine):
    """The exported C step in single precision (``float``) on the host:
    ``OffsetFreeController(..., engine="c-single")`` (refused where float's rounding takes
    more than half a margin of the certificates, :mod:`ltv_lstm_mpc.export.precision`)."""

    name = "c-single"
    precision = "single"
