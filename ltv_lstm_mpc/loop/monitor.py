r"""Run-time monitor of Theorem 3's hypotheses: on which steps did the guarantee hold?

Theorem 3 (recursive feasibility, constraint satisfaction, ISpS; with Theorem 4
offset-free tracking) holds for the closed loop when, at every step from a start where
the FHOCP of eq. (optimization) is feasible, the disturbance stays in
:math:`\mathcal D = \{\|d\|_\infty \le d_{max}\}` and varies slowly, the set-point is
admissible (Assumptions 4 and 5) and moves within the rate bound
:math:`\Delta y^0_{max}`, and the observer error stays within :math:`\hat e_{o,k}`.
The true disturbance and state are not measured; the monitor checks each hypothesis
through what the loop knows at step k (normalized units):

``d_in_bound``
    :math:`|\hat d_{k(j)}| < d_{max}` for every output j (the saturation of eq.
    d_lstm_observer is not active; with ``d_margin`` > 0: below
    :math:`(1 - d_{margin})\, d_{max}`).
``d_rate_in_bound``
    :math:`\|\hat d_k - \hat d_{k-1}\| \le w_{max}` (2-norm, as :math:`w` in the
    paper), the admissible disturbance variation of Theorem 2
    (:math:`w_{max} = \bar w / \sqrt{P_{o(3,3)}}`), checked on the estimate.
``setpoint_rate_in_bound``
    :math:`\|y^0_k - y^0_{k-1}\| \le \Delta y^0_{max}` (2-norm; paper notes 2.10c, the
    certification's ``rate_bound``), with :math:`y^0_k` inside the range the bound was
    computed for (``Certification.rate_bound_y0_range``: it uses the smallest
    :math:`\alpha` there) and :math:`\hat e_{o,k}` at most the :math:`\hat e_o` it used (a
    larger one shrinks it); fails on every step when the bound is void.
``output_error_in_bound``
    :math:`\|y_k - \hat y_k\| \le \bar e_y` (2-norm), the output-error bound the rate
    bound assumes, with :math:`\hat y_k = W_y \hat h_k + b_y + \hat d_k`.
``observer_error_consistent``
    :math:`|y_{k(j)} - \hat y_{k(j)}| \le c_{o(j)}\, \hat e_{o,k}` for every j: eq.
    (lyap_observer_constraint) bounds the output error by :math:`c_{o(j)} V_o`, so a
    larger error proves :math:`V_o(\hat\chi_k, \chi_k) > \hat e_{o,k}` (a necessary
    condition of :math:`\hat e_{o,k}` bounding the observer error).
``setpoint_admissible``
    the set-point used is in the admissible interval of Assumption 5 at
    :math:`\hat e_{o,k}` and has an equilibrium with :math:`\bar u \in \mathcal U`
    (Assumption 4): ``ControllerStep.setpoint_status`` is ``"ok"`` or
    ``"target_outside_admissible"``.

The verdict is **"held" at step k** when every check passed at every step since a step
j <= k at which they all passed and the FHOCP was solved with a plan that, re-simulated
on the LSTM, meets the nonlinear constraints (within :data:`PLAN_TOLERANCE`; the start of
Theorem 3's induction). Otherwise it is ``"voided by <names>"`` (the checks that failed
at this step) or ``"voided by infeasible_start"`` (they pass again, but no such start has
restarted the induction since).

**What "held" can and cannot say.** The true disturbance and observer error are not
measured, so each check tests an observable proxy or a necessary condition: a check that
fails proves (or, for ``d_rate_in_bound``, strongly indicates) that a hypothesis is
broken; "held" means that none was contradicted by what the loop observes, not that all
hold. In particular a step of the true disturbance reaches :math:`\hat d` only through
the observer gain (:math:`\Delta\hat d \approx L_d (y - \hat y)`), so a step larger than
:math:`w_{max}` but below about :math:`c_o \hat e_{o,k}` is not seen in the step it
happens; and :math:`V_o \le \hat e_o` at a restart is checked only through its
necessary condition. A step with verdict "held" on which the FHOCP was nevertheless
infeasible, or the plant violated its constraint, is therefore what to look at first:
either the theorem's conclusion failed or a hypothesis broke unseen.
:class:`~ltv_lstm_mpc.SimulationResult` counts those steps separately.
"""

from __future__ import annotations

import copy
import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from ltv_lstm_mpc.certificates.certify import Certification
from ltv_lstm_mpc.loop.statuses import SETPOINT_STATUSES_ADMISSIBLE
from ltv_lstm_mpc.lstm.model import LSTMModel, require_model
from ltv_lstm_mpc.validation import expect_instance, expect_real

__all__ = [
    "HYPOTHESES",
    "PLAN_TOLERANCE",
    "AssumptionCheck",
    "AssumptionLog",
    "AssumptionMonitor",
]

FloatArray = NDArray[np.float64]

#: The hypotheses checked per step, in the order of :class:`AssumptionCheck`.
HYPOTHESES = (
    "d_in_bound",
    "d_rate_in_bound",
    "setpoint_rate_in_bound",
    "output_error_in_bound",
    "observer_error_consistent",
    "setpoint_admissible",
)

#: Largest nonlinear residual (output rows, terminal level; normalized) of a plan that may
#: start the induction.
PLAN_TOLERANCE = 1e-8


@dataclass(slots=True)  # one per control step: not frozen (about 2 us less to build)
class AssumptionCheck:
    """The monitor's verdict at one step (see the module docstring for each field).

    Attributes
    ----------
    d_in_bound, d_rate_in_bound, setpoint_rate_in_bound, output_error_in_bound,
    observer_error_consistent, setpoint_admissible : bool
        Whether each hypothesis of Theorem 3 held at this step.
    fhocp_feasible : bool
        The nominal FHOCP was solved at this step.
    guarantee : str
        ``"held"``, ``"voided by <hypotheses>"`` or ``"voided by infeasible_start"``.
    """

    d_in_bound: bool
    d_rate_in_bound: bool
    setpoint_rate_in_bound: bool
    output_error_in_bound: bool
    observer_error_consistent: bool
    setpoint_admissible: bool
    fhocp_feasible: bool
    guarantee: str

    @property
    def held(self) -> bool:
        """Whether the guarantee of Theorem 3 held at this step."""
        return self.guarantee == "held"

    def failed(self) -> list[str]:
        """Names of the hypotheses that failed at this step."""
        return [name for name in HYPOTHESES if not getattr(self, name)]


class AssumptionLog:
    """The monitor's verdicts for one run's records, computed on first access.

    The controller's step stores only a reference to this log and its index in each
    :class:`~ltv_lstm_mpc.ControllerStep` (nothing on the timed path); reading
    ``ControllerStep.assumptions`` (or :meth:`verdicts`) checks every record up to that
    one in order, which is what the induction needs.

    Parameters
    ----------
    monitor : AssumptionMonitor
        Copied and reset here: each log owns its induction state (reading an earlier
        run's records after a reset cannot disturb the new run's verdicts).
    records : list of ControllerStep
        The run's records (the controller's list, appended to as the run goes).
    """

    def __init__(self, monitor: AssumptionMonitor, records: Sequence[Any]) -> None:
        monitor = copy.copy(monitor)  # its own induction state: logs never share one
        monitor.reset()
        self.monitor = monitor
        self.records = records
        self._verdicts: list[AssumptionCheck] = []

    def verdict(self, index: int) -> AssumptionCheck:
        """The verdict of record ``index`` (checking the records before it first)."""
        verdicts, check = self._verdicts, self.monitor.check
        while len(verdicts) <= index:
            r = self.records[len(verdicts)]
            mpc = r.mpc
            residuals = mpc.residuals
            start = (  # a solved FHOCP whose plan meets the nonlinear constraints
                mpc.feasible
                and residuals["output_violation"] <= PLAN_TOLERANCE
                and residuals["terminal_residual"] <= PLAN_TOLERANCE
            )
            verdicts.append(check(r.y, r.x_hat, r.d_hat, r.y0, r.e_hat, r.setpoint_status, start))
        return verdicts[index]

    def verdicts(self) -> list[AssumptionCheck]:
        """Verdicts of every record so far."""
        if self.records:
            self.verdict(len(self.records) - 1)
        return list(self._verdicts)


class AssumptionMonitor:
    r"""Checks Theorem 3's hypotheses step by step (see the module docstring).

    Parameters
    ----------
    model : LSTMModel
        Gives :math:`W_y, b_y` of :math:`\hat y_k = W_y \hat h_k + b_y + \hat d_k`.
    certification : Certification
        Gives :math:`d_{max}`, :math:`w_{max}`, :math:`c_o`, :math:`\Delta y^0_{max}` and
        :math:`\bar e_y`.
    d_margin : float
        Relative margin of ``d_in_bound`` in [0, 1): fails from
        :math:`(1 - d_{margin})\, d_{max}` on (0: at the saturation).
    """

    def __init__(
        self, model: LSTMModel, certification: Certification, *, d_margin: float = 0.0
    ) -> None:
        model = require_model(model)
        expect_instance(
            "certification",
            certification,
            Certification,
            "compute one with certify(model, config.certification_settings(model))",
            expected="a Certification",
        )
        expect_real("d_margin", d_margin, low=0.0, high=1.0, high_open=True)
        observer = certification.observer
        rate = certification.rate_bound
        self.n = model.n
        self.d_limit = observer.d_max * (1.0 - max(float(d_margin), 1e-12))
        self.w_max = float(observer.w_max) * (1.0 + 1e-9)
        #: :math:`\Delta y^0_{max}`, or -1 when the rate bound is void (fails every step).
        # (with 1e-9 relative room: a limiter at exactly the bound differs by an ulp)
        self.delta_y0_max = float(rate.delta_y0_max) * (1.0 + 1e-9) if rate.holds else -1.0
        #: The set-points and :math:`\hat e_o` the rate bound was certified for: its
        #: operating range (``Certification.rate_bound_y0_range``, the smallest
        #: :math:`\alpha` over it) and the :math:`\hat e_o` it used (a larger one shrinks it).
        p = model.p
        y0_range = certification.rate_bound_y0_range
        self.rate_low = [-math.inf] * p if y0_range is None else np.ravel(y0_range[0]).tolist()
        self.rate_high = [math.inf] * p if y0_range is None else np.ravel(y0_range[1]).tolist()
        self.rate_e_hat = float(rate.e_hat) * (1.0 + 1e-9)
        self.e_y_bar = float(rate.e_y_bar)
        self.c_o = [float(v) for v in np.atleast_1d(observer.c_o)]
        self._W_y = np.ascontiguousarray(model.W_y)
        self._b_y = np.asarray(model.b_y, dtype=np.float64)
        self.reset()

    def reset(self) -> None:
        """Forget the previous step (a new run starts unarmed)."""
        self._previous_d: list[float] | None = None
        self._previous_y0: list[float] | None = None
        self._armed = False

    def check(
        self,
        y: FloatArray,
        x_hat: FloatArray,
        d_hat: FloatArray,
        y0: FloatArray,
        e_hat: float,
        setpoint_status: str,
        feasible: bool,
    ) -> AssumptionCheck:
        """The hypotheses at this step and the guarantee's status (updates the induction).

        Parameters
        ----------
        y, y0 : (p,)
            Normalized measurement and the set-point used.
        x_hat, d_hat : (2n,), (p,)
            Estimates at this step (before the observer update).
        e_hat : float
            :math:`\\hat e_{o,k}`.
        setpoint_status : str
            ``ControllerStep.setpoint_status``.
        feasible : bool
            The FHOCP was solved and its plan, re-simulated on the LSTM, satisfies the
            nonlinear constraints (what may start the induction).

        Returns
        -------
        AssumptionCheck
        """
        # p is small (1-4): Python floats beat numpy's per-call overhead past the matvec
        d = d_hat.tolist()
        error = [abs(v) for v in (y - d_hat - self._b_y - self._W_y @ x_hat[self.n :]).tolist()]
        targets = y0.tolist()
        limit = self.d_limit
        d_in_bound = True
        for v in d:  # D is the inf-norm ball
            if not -limit < v < limit:
                d_in_bound = False
        previous_d, previous_y0 = self._previous_d, self._previous_y0
        d_rate = True
        # the rate bound holds for set-points in its range and e_hat up to the one it used
        setpoint_rate = self.delta_y0_max >= 0.0 and e_hat <= self.rate_e_hat
        for value, low, high in zip(targets, self.rate_low, self.rate_high, strict=True):
            if not low <= value <= high:
                setpoint_rate = False
        if previous_d is not None and previous_y0 is not None:  # 2-norms, as the paper's
            squares = 0.0
            for a, b in zip(d, previous_d, strict=True):
                squares += (a - b) * (a - b)
            d_rate = math.sqrt(squares) <= self.w_max
            squares = 0.0
            for a, b in zip(targets, previous_y0, strict=True):
                squares += (a - b) * (a - b)
            if not math.sqrt(squares) <= self.delta_y0_max:
                setpoint_rate = False
        consistent = e_hat < math.inf
        squares = 0.0
        for err, c in zip(error, self.c_o, strict=True):
            squares += err * err
            if not err <= c * e_hat:  # eq. (lyap_observer_constraint), per output
                consistent = False
        output_error = math.sqrt(squares) <= self.e_y_bar
        admissible = setpoint_status in SETPOINT_STATUSES_ADMISSIBLE
        self._previous_d, self._previous_y0 = d, targets
        flags = (d_in_bound, d_rate, setpoint_rate, output_error, consistent, admissible)
        if d_in_bound and d_rate and setpoint_rate and output_error and consistent and admissible:
            if self._armed or feasible:
                self._armed = True
                guarantee = "held"
            else:
                guarantee = "voided by infeasible_start"
        else:
            self._armed = False
            guarantee = "voided by " + ", ".join(
                name for name, flag in zip(HYPOTHESES, flags, strict=True) if not flag
            )
        return AssumptionCheck(
            d_in_bound, d_rate, setpoint_rate, output_error, consistent, admissible, feasible,
            guarantee,
        )  # fmt: skip
