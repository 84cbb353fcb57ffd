r"""The offset-free control loop of the paper's Fig. 1, one ``step`` per sample.

normalization -> :class:`~ltv_lstm_mpc.Observer` (eq. lstm_observer) ->
:class:`~ltv_lstm_mpc.ReferenceCalculator` (eq. reference_calculation) ->
:class:`~ltv_lstm_mpc.RobustMPC` (eq. optimization; ``prepare`` then ``feedback``,
whatever the transcription) -> de-normalization. This is the only controller: the
configuration chooses the solver and the transcription (condensed dense QP, sparse with
exact cones, or the exact NMPC), with the same checks, fallbacks and records.

Timing convention: at sample k the controller holds :math:`(\hat x_k, \hat d_k)` and
:math:`\hat e_{o,k}`. ``step(y_phi_k, y0_phi_k)`` computes :math:`u_k` from them, then
feeds :math:`(y_k, u_k)` to the observer, which yields :math:`(\hat x_{k+1}, \hat d_{k+1})`,
and advances :math:`\hat e_{o,k+1} = \rho_o \hat e_{o,k} + \bar w` (eq. eo_evolution).
At the first call the observer starts at the LSTM equilibrium matching :math:`y_0`
with :math:`\hat d_0 = 0` (paper notes 2.10b).
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass
from types import SimpleNamespace
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from ltv_lstm_mpc.caller_warnings import RunWarnings
from ltv_lstm_mpc.certificates.certify import Certification
from ltv_lstm_mpc.deferred_state import Deferred, DeferredState, defer, settle
from ltv_lstm_mpc.exceptions import (
    ArgumentTypeError,
    InvalidValueError,
    UnreachableSetpointError,
)
from ltv_lstm_mpc.loop import compiled_step as one_call
from ltv_lstm_mpc.loop.monitor import AssumptionCheck, AssumptionLog, AssumptionMonitor
from ltv_lstm_mpc.loop.observer import Observer
from ltv_lstm_mpc.loop.records import ControllerRecords
from ltv_lstm_mpc.loop.reference import ReferenceCalculator, ReferenceSolution
from ltv_lstm_mpc.loop.statuses import IMPLAUSIBLE_MEASUREMENT_LIMIT
from ltv_lstm_mpc.lstm.model import LSTMModel, require_model
from ltv_lstm_mpc.mpc.config import MPCConfig, require_config
from ltv_lstm_mpc.mpc.fhocp import MPCSolution, MPCSolver
from ltv_lstm_mpc.mpc.rti import RobustMPC
from ltv_lstm_mpc.numba_support import entry_point, prime_typeof
from ltv_lstm_mpc.validation import (
    expect_bool,
    expect_instance,
    expect_methods,
    expect_real,
    real_vector,
)

__all__ = ["ControllerStep", "OffsetFreeController"]

FloatArray = NDArray[np.float64]

#: ``_last_reference`` kept by a one-call step: built from its record row when needed.
_RECORDED = object()
#: An empty vector: "none" for the one-call step's optional vector arguments.
_NO_VALUES = np.zeros(0)
_FLOAT64 = np.dtype(np.float64)  # numpy's one native float64 dtype (compared by identity)
#: The one-call step's rate limit without a limiter.
_NO_LIMIT = math.nan


def _same_state(now: tuple[Any, ...] | None, prepared: tuple[Any, ...]) -> bool:
    """Whether the one-call state arguments ``now`` are those a preparation used: the same
    arrays (not copies: views of the record rows), the same scalars."""
    if now is None:
        return False
    for index in (0, 1, 2, 3, 4, 6):
        if now[index] is not prepared[index]:
            return False
    limit, prepared_limit = now[8], prepared[8]
    same_limit = limit == prepared_limit or (math.isnan(limit) and math.isnan(prepared_limit))
    return bool(now[5] == prepared[5] and now[7] == prepared[7] and same_limit)


def _same_arguments(now: tuple[int, float, float], prepared: tuple[int, float, float]) -> bool:
    """Whether the ``*_from_rows`` arguments ``(jinv_valid, e_hat, rate_limit)`` are those
    a preparation used (NaN, no limiter, equal to NaN)."""
    limit, prepared_limit = now[2], prepared[2]
    same_limit = limit == prepared_limit or (math.isnan(limit) and math.isnan(prepared_limit))
    return now[0] == prepared[0] and now[1] == prepared[1] and same_limit


def _choose_kernels(
    model: LSTMModel, config: MPCConfig, kernels: str, *, one_call_step: bool = True
) -> None:
    """Give ``model`` the kernel ``kernels`` asks for (:mod:`ltv_lstm_mpc.loop.kernels`):
    compiled or the numpy reference; say once what happens (compiling now, or the numpy
    reference while a background process compiles). Compiled: load now every kernel the
    cache holds (not at the first steps: :func:`~ltv_lstm_mpc.loop.kernels.load_kernels`)."""
    from ltv_lstm_mpc.loop.kernels import (
        choose_kernels,
        load_kernels,
        start_background_compile,
    )
    from ltv_lstm_mpc.lstm.kernel import LSTMKernel
    from ltv_lstm_mpc.numba_support import compile_notice, compile_on_demand, say_once

    compiled, missing = choose_kernels(config, kernels)
    if model.kernel.compiled != compiled and (kernels != "auto" or model.kernel.automatic):
        model.kernel = LSTMKernel(model, compiled=compiled)
        model.kernel.automatic = kernels == "auto"
    if model.kernel.compiled:
        compile_on_demand()  # the solver layer's helpers compile too
        load_kernels(config, one_call_step=one_call_step)
    if not missing:
        return
    if model.kernel.compiled:
        say_once(compile_notice("the controller kernels", "20-40 s"))
    elif start_background_compile(model, config, missing):
        from ltv_lstm_mpc.mpc.rti import NLP_SOLVERS
        from ltv_lstm_mpc.solvers import compiled_form

        form = None if config.solver in NLP_SOLVERS else compiled_form(config.solver)
        say_once(
            "ltv_lstm_mpc: the compiled controller kernels are not in numba's cache yet: "
            "this controller runs the numpy reference kernels (the same numbers to about "
            "1e-12, a few times slower per step) while a background process compiles them "
            "(once, about 20-40 s on 2 cores); later controllers and runs use them. "
            "OffsetFreeController(..., kernels='compiled') waits for the compilation "
            "instead; `ltv-lstm-mpc warmup` compiles ahead of time"
            + (
                f". The {config.solver} solver has no numpy twin: it compiles in this process "
                "at the first step (about 10 s on 2 cores, once)"
                if form is not None and form.compiled_only
                else ""
            )
        )


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


class OffsetFreeController(DeferredState):
    r"""Robust offset-free LSTM MPC (paper Fig. 1) with physical inputs and outputs.

    Parameters
    ----------
    model : LSTMModel
        Needs a normalization (physical <-> normalized signals) and m = p.
    config : MPCConfig, optional
    setpoint_rate_limit : float, optional
        Largest change of the normalized set-point per step (Theorem 3's
        :math:`\Delta y^0_{max}`; see ``certification.rate_bound``). None: no limiter.
    mpc : RobustMPC-like, optional
        The MPC to use (default ``RobustMPC(model, config)``, which follows
        ``config.solver`` and ``config.transcription``). Anything with ``prepare`` /
        ``feedback`` (or only ``solve(x_hat, x_bar, u_bar, y0, e_hat) -> MPCSolution``),
        ``reset()`` and ``certification`` fits.
    implausible_measurements : {"flag", "raise"}
        What :meth:`step` does with a measurement more than one range width outside the
        model's normalization range (``measurement_status == "implausible"``): ``"flag"``
        (default) records it, warns once per run and uses it; ``"raise"`` refuses it with
        :class:`~ltv_lstm_mpc.InvalidValueError` before anything is updated.
    kernels : {"auto", "compiled", "numpy"}
        Compiled (numba) or numpy reference kernels (:mod:`ltv_lstm_mpc.loop.kernels`):
        ``"auto"`` (default) runs the compiled ones where numba's on-disk cache holds them
        and otherwise the numpy reference while a background process compiles them for
        the next controllers and runs (no silent 20-40 s wait on a fresh install);
        ``"compiled"`` compiles now if needed (benchmarks); ``"numpy"`` the reference.
        Ignored with ``mpc`` (the model's kernel is used as it is). The choice made is
        :attr:`kernels` (``"compiled"`` or ``"numpy"``).
    monitor : AssumptionMonitor, optional
        Checks Theorem 3's hypotheses on every record (:mod:`ltv_lstm_mpc.loop.monitor`);
        default: one on this controller's certification. Give one built on a certification
        whose rate bound covers your set-point range (``y0_operating_range`` of
        :class:`~ltv_lstm_mpc.CertificationSettings`) when the limiter uses that bound.
    one_call_step : bool
        Run each step after the first as one compiled call where the configuration allows
        it (default True; the condensed transcription with DAQP bound natively, compiled
        kernels, one SQP iteration, no ``mpc`` given: :mod:`ltv_lstm_mpc.loop.compiled_step`),
        falling back to the general path on any step that call does not accept. False:
        the general path on every step (the tested reference; same numbers to 1e-12).
        :attr:`one_call` says whether it applies.

    Notes
    -----
    Whatever produced it (the nominal plan, a policy, the ``+shift`` fallback, an SQP
    iterate, a custom ``mpc``), the input :meth:`step` returns lies in
    :math:`\mathcal U`: an input outside it is projected onto it (a non-finite one is
    replaced by the last applied input) and the step records the amount in
    ``input_clipped``. Warnings about the run (input clipped, implausible measurement,
    set-point status, :math:`\hat d` saturation) point at the caller's line, are shown once
    per run and counted in ``warning_counts``.
    """

    # The limiter's last set-point (normalized) and the state the last one-call step left,
    # as written into the owners (a one-call step leaves them deferred in its record row:
    # ltv_lstm_mpc.deferred_state).
    _y0 = Deferred[FloatArray | None]()
    _installed = Deferred[tuple[Any, ...] | None]()

    def __init__(
        self,
        model: LSTMModel,
        config: MPCConfig | None = None,
        *,
        setpoint_rate_limit: float | None = None,
        mpc: MPCSolver | None = None,
        implausible_measurements: str = "flag",
        kernels: str = "auto",
        monitor: AssumptionMonitor | None = None,
        one_call_step: bool = True,
    ) -> None:
        model, config = require_model(model), require_config(config)
        expect_bool("one_call_step", one_call_step)
        if mpc is not None:
            _check_mpc(mpc)
        if setpoint_rate_limit is not None:
            expect_real("setpoint_rate_limit", setpoint_rate_limit, hint="or None: no limiter")
        if model.normalization is None:
            raise InvalidValueError(
                "OffsetFreeController works with physical signals and needs a model with a "
                "normalization (u_phi_min, u_phi_max, y_phi_min, y_phi_max)"
            )
        if setpoint_rate_limit is not None and not setpoint_rate_limit > 0:
            raise InvalidValueError(
                f"setpoint_rate_limit must be positive, got {setpoint_rate_limit}"
            )
        if implausible_measurements not in ("flag", "raise"):
            raise InvalidValueError(
                f"implausible_measurements must be 'flag' or 'raise', got "
                f"{implausible_measurements!r}"
            )
        self.implausible_measurements = implausible_measurements
        self.model = model
        self.config = config = config or MPCConfig()
        if mpc is None:
            _choose_kernels(model, config, kernels, one_call_step=one_call_step)
        #: ``"compiled"`` or ``"numpy"``: the kernels this controller runs (see ``kernels``).
        self.kernels = "compiled" if model.kernel.compiled else "numpy"
        self.mpc: MPCSolver = mpc if mpc is not None else RobustMPC(model, config)
        self.certification = self.mpc.certification
        self.observer = Observer(model, self.certification.observer.gains, d_max=config.d_max)
        # tol 1e-10 (not 1e-12): the warm chord path then ends in one residual check at steady
        # state; the equilibrium error it leaves is far below the offsets measured.
        self.reference = ReferenceCalculator(model, u_max=config.u_max, strict=False, tol=1e-10)
        self.setpoint_rate_limit = setpoint_rate_limit
        self._phases = hasattr(self.mpc, "prepare") and hasattr(self.mpc, "feedback")
        norm = model.normalization
        assert norm is not None  # checked above
        self._y_min, self._y_scale = norm.y_phi_min, norm.y_scale
        self._u_min, self._u_scale = norm.u_phi_min, norm.u_scale
        # U in physical units: the de-normalized [-u_max, u_max], never beyond the stored
        # range where u_max = 1 (the de-normalization of 1 may round one ulp above it).
        u_max = self._u_max = float(config.u_max)
        self._u_phi_low = self._denormalize_u(np.full(model.m, -u_max))
        self._u_phi_high = self._denormalize_u(np.full(model.m, u_max))
        if u_max <= 1.0:
            np.maximum(self._u_phi_low, norm.u_phi_min, out=self._u_phi_low)
            np.minimum(self._u_phi_high, norm.u_phi_max, out=self._u_phi_high)
        #: Watches Theorem 3's hypotheses per step (:mod:`ltv_lstm_mpc.loop.monitor`).
        # (None when a custom mpc brings a certification of its own kind: nothing to check)
        if monitor is not None:
            expect_instance(
                "monitor", monitor, AssumptionMonitor, "or None", expected="an AssumptionMonitor"
            )
        elif isinstance(self.certification, Certification):
            monitor = AssumptionMonitor(model, self.certification)
        self.monitor: AssumptionMonitor | None = monitor
        self.warnings = RunWarnings()
        self._entries: dict[str, Any] = {}  # compiled entry points (_compiled)
        #: (record rows, k, inverse Jacobian valid): the state one-call step k left deferred
        #: in its row (_defer_state; None: written into the owners).
        self._deferred: tuple[SimpleNamespace, int, int] | None = None
        self._prepared: tuple[Any, ...] | None = None  # what prepare_next prepared
        #: The one-call step's constants and buffers (None: the general path only).
        self._one_call: Any = self._one_call_workspace() if mpc is None and one_call_step else None
        if self.kernels == "compiled":
            prime_typeof()  # the first compiled steps then type their workspaces at once
        #: This run's records (a read-only sequence of :class:`ControllerStep`).
        self.records: ControllerRecords = ControllerRecords(self._recorded_step)
        self.reset()

    @property
    def warning_counts(self) -> dict[str, int]:
        """Steps of this run on which each warned condition held (shown once per run):
        ``"input_clipped"``, ``"measurement_implausible"``, ``"setpoint"``,
        ``"d_hat_saturated"``."""
        return dict(self.warnings.counts)

    @property
    def one_call(self) -> bool:
        """Whether steps after the first run as one compiled call (``one_call_step``)."""
        return self._one_call is not None

    @property
    def input_bounds_phi(self) -> tuple[FloatArray, FloatArray]:
        """U in physical units: (low, high), each (m,)."""
        return self._u_phi_low.copy(), self._u_phi_high.copy()

    def reset(self) -> None:
        """Back to the uninitialized state (the next step initializes the observer)."""
        self._settle()
        self._initialized = False
        self._y0 = None
        self._last_reference: Any = None  # the last admissible one (or _RECORDED)
        self._last_converged: ReferenceSolution | None = None  # before any admissible one
        tightening = self.certification.tightening
        self.e_hat = tightening.e_inf if self.config.e_hat0 is None else float(self.config.e_hat0)
        self.mpc.reset()
        self.reference.reset()
        model = self.model
        self.records = ControllerRecords(
            self._recorded_step,
            None if self._one_call is None else (model.p, model.m, 2 * model.n, self.config.N),
        )
        self._last_reference_row = -1  # the record row of _last_reference, when it is _RECORDED
        self._assumption_log = (
            None if self.monitor is None else AssumptionLog(self.monitor, self.records)
        )
        self.records.log = self._assumption_log
        self.warnings.reset()
        self._interval: tuple[float, list[float], list[float]] = (math.nan, [], [])
        self._prepared = None
        self._installed = None
        self._requested_phi: FloatArray | None = None  # the set-point the last step requested

    def _limit(self, y0_target: FloatArray) -> FloatArray:
        if self._y0 is None or self.setpoint_rate_limit is None:
            return y0_target
        limit = self.setpoint_rate_limit
        change = np.minimum(np.maximum(y0_target - self._y0, -limit), limit)  # np.clip, faster
        change += self._y0
        return change

    def _reference(
        self, reference: ReferenceSolution, y0: FloatArray, d_hat: FloatArray
    ) -> tuple[ReferenceSolution, FloatArray, bool]:
        """Use ``reference``, or the last one if Newton failed; returns (ref, y0 for MPC, stale).

        With a stale reference the MPC gets :math:`y^0 = g(\\bar x) + \\hat d`, the set-point
        the reused equilibrium encodes, keeping eq. (reference_calculation_output) true for
        the terminal set (Theorem 3, Part 2a).
        """
        if reference.ok:
            self._last_reference = reference
            return reference, y0, False
        last = self._last_reference
        if last is _RECORDED:  # kept by a one-call step: its record's reference
            last = self._recorded_reference(self._last_reference_row)
        if last is None:  # no admissible equilibrium yet
            if reference.converged:  # nothing better to keep
                self._last_converged = reference
                return reference, y0, False
            last = self._last_converged  # Newton failed: keep the last equilibrium found
        if last is None:
            raise UnreachableSetpointError(
                f"the reference calculator found no equilibrium for the set-point "
                f"{self._physical_y(y0)} (physical; {y0.tolist()} normalized), d_hat = "
                f"{d_hat.tolist()} at step {len(self.records)}, nor any before (residual "
                f"{reference.residual:.2e}): "
                "start from a set-point the model can reach (certify's y0_interval), or "
                "let setpoint_rate_limit move it there from the measured output"
            )
        return last, np.asarray(self.model.output(last.x_bar) + d_hat, dtype=np.float64), True

    def _physical_y(self, y: FloatArray) -> list[float]:
        return [float(v) for v in self.model.denormalize_y(y)]

    def _diagnose(
        self,
        y0: FloatArray,
        y0_target: FloatArray,
        d_hat: FloatArray,
        reference: ReferenceSolution,
        stale: bool,
    ) -> tuple[str, NDArray[np.bool_]]:
        """Set-point status and saturated outputs of this step; warns once per run."""
        ti = self.certification.tightening
        limit = self.config.d_max * (1.0 - 1e-12)
        flags = [abs(d) >= limit for d in d_hat.tolist()]  # p scalars: lists beat numpy here
        saturated = np.array(flags)
        if stale or not reference.u_admissible:
            status = "unreachable_stale" if stale else "unreachable"
        else:
            if self._interval[0] != self.e_hat:
                low, high = ti.setpoint_interval(self.e_hat)
                self._interval = (self.e_hat, low.tolist(), high.tolist())
            _, lows, highs = self._interval
            inside = all(a < y < b for a, y, b in zip(lows, y0.tolist(), highs, strict=True))
            status = "ok" if inside else "outside_admissible"
            if inside and y0_target is not y0:  # the rate limiter is moving the set-point
                target = y0_target.tolist()
                if not all(a < y < b for a, y, b in zip(lows, target, highs, strict=True)):
                    status = "target_outside_admissible"
        self._warn_diagnosis(status, saturated, y0, y0_target, stale)
        return status, saturated

    def _warn_diagnosis(
        self,
        status: str,
        saturated: NDArray[np.bool_],
        y0: FloatArray,
        y0_target: FloatArray,
        stale: bool,
    ) -> None:
        """Count (and show once per run) the saturation of d_hat and a set-point status
        other than ``"ok"`` (both paths of :meth:`step`)."""
        ti = self.certification.tightening
        k = len(self.records)
        if saturated.any() and self.warnings.first("d_hat_saturated"):
            j = int(np.flatnonzero(saturated)[0])
            scale = float(self._y_scale[j])
            self.warnings.warn(
                f"d_hat reached its bound d_max = {self.config.d_max} (normalized; "
                f"{self.config.d_max * scale:.4g} in physical output units) on output {j} at "
                f"step {k}: the plant-model mismatch exceeds the disturbance bound the "
                "guarantees assume (|d| <= d_max), and offsets may remain. Raise d_max "
                "(MPCConfig d_max; estimate_d_max(model, data) measures the mismatch), which "
                "shrinks the admissible set-point interval, or use a model that fits this "
                "operating point better"
            )
        if status != "ok" and self.warnings.first("setpoint"):
            low, high = ti.setpoint_interval(self.e_hat)
            interval = (
                f"the admissible interval [{self._physical_y(low)}, "
                f"{self._physical_y(high)}] of Assumption 5"
            )
            if status == "outside_admissible":
                where = (
                    f"outside {interval} (no terminal set: the MPC is infeasible and its "
                    "policy applies)"
                )
            elif status == "target_outside_admissible":
                where = (
                    f"outside {interval}; the rate-limited set-point "
                    f"{self._physical_y(y0)} is still inside and will leave it"
                )
            else:
                where = "not reachable: no equilibrium with the input inside its bounds" + (
                    " (the previous target is kept)" if stale else ""
                )
            requested = y0_target if status == "target_outside_admissible" else y0
            self.warnings.warn(
                f"set-point {self._physical_y(requested)} (physical units) at step {k} is {where}"
            )

    def _check_first_measurement(self, y: FloatArray, y_phi: ArrayLike) -> None:
        """Refuse a first measurement more than one range width outside the model's
        normalization range (in the measurement's own units), before any reference
        calculation: the observer (and the set-point rate limiter) start from it, so the
        controller would fail later naming a set-point the caller never gave."""
        if max(abs(v) for v in y.tolist()) <= IMPLAUSIBLE_MEASUREMENT_LIMIT:
            return
        norm = self.model.normalization
        assert norm is not None  # checked at construction

        def physical(values: Any) -> str:
            numbers = [f"{float(v):.4g}" for v in np.ravel(values)]
            return numbers[0] if len(numbers) == 1 else "[" + ", ".join(numbers) + "]"

        raise InvalidValueError(
            f"the first measurement y_phi = {physical(y_phi)} lies far outside the model's "
            f"output range {physical(norm.y_phi_min)} .. {physical(norm.y_phi_max)} (the "
            "physical units of its normalization; more than one range width outside): "
            "wrong units or a sensor fault? The controller starts its observer and the "
            "set-point rate limiter from the first measurement, so it cannot start from this "
            "one; give the measurement in the model's units"
        )

    def _measurement_status(self, y: FloatArray, y_phi: ArrayLike) -> str:
        """``"ok"``, ``"outside_training_range"`` or ``"implausible"`` (see
        :class:`ControllerStep`); warns once per run, or raises, on an implausible one."""
        largest = max(abs(v) for v in y.tolist())
        if largest <= 1.0:
            return "ok"
        if largest <= IMPLAUSIBLE_MEASUREMENT_LIMIT:
            return "outside_training_range"
        norm = self.model.normalization
        assert norm is not None  # checked at construction
        message = (
            f"measurement y_phi = {np.asarray(y_phi, dtype=np.float64).tolist()} at step "
            f"{len(self.records)} lies more than one range width outside the model's "
            f"normalization range [{norm.y_phi_min.tolist()}, {norm.y_phi_max.tolist()}] "
            f"(normalized {y.tolist()}, limit +-{IMPLAUSIBLE_MEASUREMENT_LIMIT}): a sensor "
            "fault or wrong units?"
        )
        if self.implausible_measurements == "raise":
            raise InvalidValueError(
                message + " Refused (implausible_measurements='raise'); pass "
                "implausible_measurements='flag' to record it and use it anyway"
            )
        if self.warnings.first("measurement_implausible"):
            self.warnings.warn(message + " It is used as it is and flagged per step.")
        return "implausible"

    def _gate_input(self, u: FloatArray, u_bar: FloatArray) -> tuple[FloatArray, float]:
        """The exit gate: ``u`` projected onto U, and how far it moved (inf-norm; inf when
        it was not finite and the last applied input, or the projection of u_bar at the
        first step, replaces it)."""
        u_max = self._u_max
        if all(-u_max <= v <= u_max for v in u.tolist()):  # NaN fails the test
            return u, 0.0
        if np.isfinite(u).all():
            gated = np.clip(u, -u_max, u_max)
            moved = float(np.abs(gated - u).max())
        else:
            if self.records:
                gated = self.records[-1].u.copy()
            else:
                gated = np.clip(u_bar, -u_max, u_max)
            moved = math.inf
        if self.warnings.first("input_clipped"):
            self._warn_clipped(u, moved)
        return gated, moved

    def _warn_clipped(self, u: FloatArray, moved: float) -> None:
        """Show that the MPC's input ``u`` was moved onto U (once per run)."""
        what = (
            f"was projected onto U (moved by {moved:.3e}, normalized)"
            if math.isfinite(moved)
            else "was not finite and was replaced by "
            + ("the last applied input" if self.records else "u_bar projected onto U")
        )
        self.warnings.warn(
            f"the MPC's input {u.tolist()} (normalized) at step {len(self.records)} "
            f"{what}: U = [{self._u_phi_low.tolist()}, {self._u_phi_high.tolist()}] in "
            "physical units. Every such step is recorded in ControllerStep.input_clipped"
        )

    # Parts of one step; a faster controller overrides these, not the loop in ``step``.
    def _normalize(self, y_phi: ArrayLike, y0_phi: ArrayLike) -> tuple[FloatArray, FloatArray]:
        """Normalized measurement and set-point, checked (paper notes 1)."""
        p = self.model.p
        y_arr = real_vector("y_phi", y_phi, p)
        y0_arr = real_vector("y0_phi", y0_phi, p)
        self._requested_phi = y0_arr
        y = (y_arr - self._y_min) / self._y_scale - 1.0
        y0_target = (y0_arr - self._y_min) / self._y_scale - 1.0
        return y, y0_target

    def _solve_reference(
        self,
        y0: FloatArray,
        d_hat: FloatArray,
        chord: tuple[FloatArray, float, int, bool] | None = None,
    ) -> ReferenceSolution:
        """eq. (reference_calculation) at this step (``chord``: see :meth:`_step_general`)."""
        if chord is None:
            return self.reference.solve_arrays(y0, d_hat)  # checked float64 (p,) arrays
        return self.reference.solve_arrays(y0, d_hat, chord=chord)

    def _solve_mpc(
        self,
        x_hat: FloatArray,
        reference: ReferenceSolution,
        y0: FloatArray,
        skip_native: bool = False,
    ) -> MPCSolution:
        """The FHOCP eq. (optimization): ``prepare`` (candidate, linearization, build) then
        ``feedback`` (insert x_hat, solve, validate)."""
        mpc = self.mpc
        if self._phases:
            mpc.prepare(reference.x_bar, reference.u_bar, y0, self.e_hat, x_pred=x_hat)
            if skip_native:  # the one-call step's feedback declined this point already
                assert isinstance(mpc, RobustMPC)
                return mpc._feedback(x_hat, native=False)
            return mpc.feedback(x_hat)
        return mpc.solve(x_hat, reference.x_bar, reference.u_bar, y0, self.e_hat)

    def _update_observer(self, y: FloatArray, u: FloatArray) -> None:
        """eq. (lstm_observer): (y_k, u_k) -> (x_hat_{k+1}, d_hat_{k+1})."""
        self.observer.update(y, u)

    def _denormalize_u(self, u: FloatArray) -> FloatArray:
        """Physical input from the normalized one."""
        return np.asarray((u + 1.0) * self._u_scale + self._u_min, dtype=np.float64)

    def step(self, y_phi: ArrayLike, y0_phi: ArrayLike) -> FloatArray:
        """One sample: measured physical output and set-point in, physical input out.

        On the condensed transcription with DAQP bound natively (compiled kernels, one SQP
        iteration, this controller's own MPC) a step after the first runs as one compiled
        call (:mod:`ltv_lstm_mpc.loop.compiled_step`) whenever every test of that call
        passes; otherwise, and for every other configuration, the general path below runs,
        with the same numbers (tested to 1e-12). After :meth:`prepare_next` (called between
        samples) the step runs only the feedback of the prepared subproblem and the
        observer update.
        """
        u = self._step_from_deferred_rows(y_phi, y0_phi)  # the common one-call step
        if u is not None:
            return u
        chord = None
        skip_native = False
        if self._one_call is not None and self._initialized:
            answer = self._step_one_call(y_phi, y0_phi)
            if not isinstance(answer, tuple):
                return answer
            chord, skip_native = answer
        return self._step_general(y_phi, y0_phi, chord, skip_native)

    # ------------------------------------------------------------------ one-call step
    def _one_call_workspace(self) -> Any:
        """The :data:`~ltv_lstm_mpc.loop.compiled_step.StepWorkspace` of this controller, or
        None where the one-call step does not apply (another transcription or solver, DAQP
        not bound natively, the numpy kernels, a globalized SQP)."""
        mpc, reference, observer = self.mpc, self.reference, self.observer
        if not isinstance(mpc, RobustMPC) or mpc._native_feedback is None:
            return None
        problem = mpc._problem
        daqp, socp = problem.daqp_workspace, problem.socp_workspace
        if (
            (daqp is None and socp is None)
            or mpc._prepare_workspace is None
            or reference._chord_workspace is None
            or getattr(observer, "_workspace", None) is None
        ):
            return None
        ti, model = self.certification.tightening, self.model
        N, p = mpc.N, model.p

        def vector(values: Any) -> FloatArray:
            return np.array(values, dtype=np.float64)  # an owned, C-contiguous copy

        self._one_call_requested = np.zeros(p)  # the workspace's ``requested``
        if getattr(self, "_jinv_backup", None) is None:  # kept when the workspace is rebuilt
            self._jinv_backup = np.zeros_like(reference._Jinv_buffer)
        self._y_buffer, self._y0_buffer = np.zeros(p), np.zeros(p)
        self._one_call_settings = self._one_call_settings_now()
        return one_call.new_step_workspace(
            y_min=vector(self._y_min), y_scale=vector(self._y_scale),
            u_min=vector(self._u_min), u_scale=vector(self._u_scale),
            u_phi_low=vector(self._u_phi_low), u_phi_high=vector(self._u_phi_high),
            a=vector(ti.a), b=vector(ti.b), bound_min=vector(ti.y_min),
            bound_max=vector(ti.y_max), kappa=vector(ti.kappa), lower=np.zeros((N, p)),
            upper=np.zeros((N, p)), requested=self._one_call_requested,
            clock=np.zeros(2, dtype=np.int64),
            u_max=self._u_max, implausible=float(IMPLAUSIBLE_MEASUREMENT_LIMIT),
            tol=float(reference.tol), max_iter=int(reference.max_iter),
            jump=float(reference.jump), reuse_tol=float(mpc.reuse_tol),
            d_max=float(observer.d_max), tightening_d_max=float(ti.d_max),
            rho_o=float(ti.rho_o), w_bar=float(ti.w_bar), e_inf=float(ti.e_inf),
            backward=bool(getattr(problem, "backward_condensing", False)),
            chord=reference._chord_workspace,
            trajectories=mpc._prepare_workspace, condensing=mpc._condensing_workspace,
            daqp=daqp if daqp is not None else one_call.placeholder_daqp(),
            plan=mpc._plan_workspace, observer=observer._workspace, cand=mpc._cand,
            cones=socp is not None,
            socp=socp if socp is not None else one_call.placeholder_socp(),
            tolerance=float(problem.tolerance), jinv_backup=self._jinv_backup,
        )  # fmt: skip

    def _one_call_settings_now(self) -> tuple[float, int, float, float]:
        """The settings the one-call workspace holds: the reference calculator's tolerance,
        iterations and jump bound, the MPC's reuse tolerance."""
        reference, mpc = self.reference, self.mpc
        return (reference.tol, reference.max_iter, reference.jump, mpc.reuse_tol)  # type: ignore[attr-defined]

    def _one_call_state(self) -> tuple[Any, ...] | None:
        """The state arguments of the compiled step, ``(y0_previous, x_hat, d_hat, last_z,
        last_target, jinv_valid, previous_u, e_hat, rate_limit)``, or None where the
        one-call step cannot run now (no plan or reference yet, or a limiter without its
        last set-point: the general path then runs). Reading them writes a deferred state
        into its owners (:mod:`ltv_lstm_mpc.deferred_state`)."""
        mpc: Any = self.mpc
        reference, observer = self.reference, self.observer
        previous_u, last_z = mpc._previous_u, reference._last_z
        y0_previous = self._y0
        rate_limit = self.setpoint_rate_limit
        if previous_u is None or last_z is None or not mpc._plan_valid:
            return None
        if rate_limit is None:
            rate_limit = math.nan
        elif y0_previous is None:
            return None
        self._check_settings()
        last_target = reference._last_target
        return (
            _NO_VALUES if y0_previous is None else y0_previous, observer.x_hat,
            observer.d_hat, last_z, _NO_VALUES if last_target is None else last_target,
            1 if reference._Jinv is not None else 0, previous_u, self.e_hat, float(rate_limit),
        )  # fmt: skip

    def _check_settings(self) -> None:
        """A new workspace where the user changed one of the settings it holds."""
        if self._one_call_settings_now() != self._one_call_settings:
            self._one_call = self._one_call_workspace()
            self._entries.clear()

    def _rows_arguments(self, k: int) -> tuple[int, float, float] | None:
        """``(jinv_valid, e_hat, rate_limit)`` for the ``*_from_rows`` calls of one-call step
        ``k`` when the state it starts from is the one one-call step ``k - 1`` left in its
        record row (still deferred and untouched, or written into the owners and unchanged
        since: :meth:`_installed_state`), so that the compiled entry points apply; None
        otherwise (the state is passed as arguments, through numba's dispatcher), and then
        no state is left deferred: a step that runs from a deferred state ran from rows."""
        e_hat = self.e_hat
        deferred = self._deferred
        if type(e_hat) is not float or not self.mpc._plan_valid:  # type: ignore[attr-defined]
            self._settle()
            return None
        if deferred is not None:
            if deferred[1] != k - 1:
                self._settle()
                return None
            jinv_valid = deferred[2]
        elif self._installed_state(k):
            jinv_valid = 0 if self.reference._Jinv is None else 1
            self._check_settings()  # (deferred: a setting assigned since would have settled)
        else:
            return None
        rate_limit = self.setpoint_rate_limit
        return jinv_valid, e_hat, _NO_LIMIT if rate_limit is None else float(rate_limit)

    def _installed_state(self, k: int) -> bool:
        """Whether every state argument is the one one-call step ``k - 1`` left, written
        into the owners (views of its record row, of the types the compiled entry points
        were resolved for)."""
        installed = self._installed
        if installed is None or installed[6] != k - 1:
            return False
        reference, observer, mpc = self.reference, self.observer, self.mpc
        return (
            observer.x_hat is installed[0]
            and observer.d_hat is installed[1]
            and reference._last_z is installed[2]
            and reference._last_target is installed[3]
            and mpc._previous_u is installed[4]  # type: ignore[attr-defined]
            and self._y0 is installed[5]
        )

    def _defer_state(self) -> None:
        """Leave the state of the last one-call step in its record row: the owners go
        without it until it is first read (:mod:`ltv_lstm_mpc.deferred_state`;
        :meth:`_settle` writes it)."""
        settle_state = self._settle
        defer(self.observer, settle_state)
        defer(self.reference, settle_state)
        defer(self.mpc, settle_state)  # type: ignore[arg-type]
        defer(self, settle_state)
        problem = self.mpc._problem  # type: ignore[attr-defined]
        problem.scale = math.nan  # prepare sets it again before any general feedback
        problem._last.clear()

    def _settle(self) -> None:
        """Write the state the last one-call step k left in its record row into the
        observer (estimates of row k + 1), the reference calculator (last solution and
        target, inverse Jacobian), the MPC (plan, times) and this controller (set-point),
        as views of the row (never written again); a value assigned since is kept."""
        deferred = self._deferred
        if deferred is None:
            return
        self._deferred = None
        rows, k, inverse_valid = deferred
        x_hat, d_hat = rows.x_hat[k + 1], rows.d_hat[k + 1]
        last_z, last_target, previous_u, y0 = rows.z[k], rows.target[k], rows.u_plan[k], rows.y0[k]
        reference = self.reference
        jinv = reference._Jinv_buffer if inverse_valid == 1 else None
        solver_time, prepare_time, feedback_time = rows.real[
            k, one_call.SOLVER_TIME : one_call.FEEDBACK_TIME + 1
        ].tolist()
        settle(self.observer, {"x_hat": x_hat, "d_hat": d_hat})
        settle(reference, {"_last_z": last_z, "_last_target": last_target, "_Jinv": jinv})
        times = {"solver_time": solver_time, "prepare_time": prepare_time}
        times["feedback_time"] = feedback_time
        iterations = int(rows.integer[k, one_call.SOLVER_ITERATIONS])
        settle(self.mpc, {"_previous_u": previous_u, **times, "qp_iterations": iterations})  # type: ignore[arg-type]
        installed = (x_hat, d_hat, last_z, last_target, previous_u, y0, k)
        settle(self, {"_y0": y0, "_installed": installed})

    def _compiled(self, name: str, fast: bool, arguments: tuple[Any, ...]) -> Any:
        """Call ``compiled_step.<name>``: through its entry point when ``fast`` (all
        arguments of the types it was resolved for: :meth:`_rows_arguments`), otherwise
        through numba's dispatcher (which checks the types), resolving the entry point."""
        entry = self._entries.get(name) if fast else None
        if entry:
            return entry(*arguments)
        function = getattr(one_call, name)
        result = function(*arguments)
        if fast and entry is None:  # False: no entry point (not a compiled dispatcher)
            self._entries[name] = entry_point(function, arguments) or False
        return result

    def _signals(self, y_phi: ArrayLike, y0_phi: ArrayLike) -> tuple[FloatArray, FloatArray]:
        """Measurement and set-point as C-contiguous float64 vectors of p values for the
        compiled call. The common inputs (such arrays, or one float where p = 1) pass as
        they are, or through the controller's buffers, with their finiteness left to the
        compiled call (which hands a non-finite value to the general path: its error);
        anything else is checked (:func:`~ltv_lstm_mpc.validation.real_vector`)."""
        return (
            self._vector("y_phi", y_phi, self._y_buffer),
            self._vector("y0_phi", y0_phi, self._y0_buffer),
        )

    @staticmethod
    def _vector(name: str, value: Any, buffer: FloatArray) -> FloatArray:
        ready = OffsetFreeController._ready_vector(value, buffer)
        if ready is not None:
            return ready
        checked = real_vector(name, value, buffer.shape[0])
        return checked if checked.flags.carray else np.array(checked)

    @staticmethod
    def _ready_vector(value: Any, buffer: FloatArray) -> FloatArray | None:
        """``value`` as the step's signal without a check or a copy: a C-contiguous float64
        vector of the buffer's shape itself, a float (numpy float64 included, p = 1) in
        ``buffer``; None for anything else (:meth:`_vector` checks it)."""
        if type(value) is np.ndarray:
            if value.dtype is _FLOAT64 and value.shape == buffer.shape and value.flags.carray:
                return value
        elif isinstance(value, float) and buffer.shape[0] == 1:  # float and numpy.float64
            buffer[0] = value
            return buffer
        return None

    def prepare_next(self, y0_phi: ArrayLike | None = None) -> bool:
        r"""Prepare the next step now, between samples (after this step's input is applied).

        Everything the next :meth:`step` computes before its feedback does not use its
        measurement: the set-point and its limiter, the reference eq.
        (reference_calculation), the tightened bounds and :math:`\alpha_k`, and the
        linearized, condensed subproblem (Theorem 3's candidate) all follow from the
        estimates :math:`\hat x_{k+1}, \hat d_{k+1}` this step left
        (:func:`~ltv_lstm_mpc.loop.compiled_step.prepare_step`). Prepared, the next step
        runs only the feedback, the exit gate and the observer update
        (:func:`~ltv_lstm_mpc.loop.compiled_step.feedback_step`): the time from the
        measurement to the input is the feedback's. Its numbers are those of an
        unprepared step (tested bit for bit).

        The next step uses the preparation only if it requests the same set-point (equal
        values) and nothing the step depends on changed in between (:meth:`reset`, a new
        estimate, plan or limiter assigned); otherwise it puts the preparation aside and
        runs as usual, with the same numbers.

        Parameters
        ----------
        y0_phi : array_like, optional
            The set-point the next step will request (physical units, p values; a schedule
            knows it); default: the one the last step requested.

        Returns
        -------
        bool
            True when the next step is prepared; False where the one-call step does not
            apply (:attr:`one_call` False: the general path prepares inside the step),
            before the first step, or where the preparation did not pass the one-call
            step's tests (the next step then runs as usual).

        Raises
        ------
        InvalidValueError, DimensionError
            ``y0_phi`` not p finite real numbers.
        """
        self._discard_preparation()
        if y0_phi is None:
            requested = self._requested_phi
        else:
            requested = real_vector("y0_phi", y0_phi, self.model.p)
        if self._one_call is None or not self._initialized or requested is None:
            return False
        y0_arr = np.array(requested, dtype=np.float64)  # an owned, C-contiguous copy
        records = self.records
        k = len(records)
        if k + 2 > records.capacity:
            records.reserve(k + 2)
        from_rows = self._rows_arguments(k)
        state = None
        if from_rows is not None:
            code, inverse_valid, factorizations = self._compiled(
                "prepare_step_from_rows",
                True,
                (self._one_call, records.compiled, k, y0_arr, *from_rows),
            )
        else:
            state = self._one_call_state()
            if state is None:
                return False
            code, inverse_valid, factorizations = self._compiled(
                "prepare_step", False, (self._one_call, records.compiled, k, y0_arr, *state)
            )
        if code != one_call.STEP_DONE:
            self._restore_chord()
            return False
        self._prepared = (
            k, y0_arr.tolist(), from_rows, state, self._one_call, inverse_valid, factorizations,
        )  # fmt: skip
        return True

    def _discard_preparation(self) -> None:
        """Put a preparation of :meth:`prepare_next` aside (the chord as it was before)."""
        if self._prepared is not None:
            self._prepared = None
            self._restore_chord()

    def _restore_chord(self) -> None:
        """The reference calculator's inverse Jacobian as before the last preparation."""
        np.copyto(self.reference._Jinv_buffer, self._jinv_backup)

    def _step_prepared(
        self, y_phi: ArrayLike, y0_phi: ArrayLike
    ) -> FloatArray | tuple[tuple[FloatArray, float, int, bool] | None, bool] | None:
        """:meth:`step` on the preparation of :meth:`prepare_next`: the physical input, or
        what :meth:`_step_one_call` returns for the general path, or None where the
        preparation does not apply (put aside)."""
        prepared = self._prepared
        assert prepared is not None
        self._prepared = None
        k, y0_prepared, from_rows, state, workspace, inverse_valid, factorizations = prepared
        y_arr, y0_arr = self._signals(y_phi, y0_phi)
        records = self.records
        usable = k == len(records)
        if usable and from_rows is not None:
            now = self._rows_arguments(k)
            usable = now is not None and _same_arguments(now, from_rows)
        elif usable:
            usable = _same_state(self._one_call_state(), state)
        # (after the state checks: they build a new workspace where a setting changed)
        if not usable or self._one_call is not workspace or y0_arr.tolist() != y0_prepared:
            self._restore_chord()
            return None
        if from_rows is not None:
            code, warnings, e_hat_next = self._compiled(
                "feedback_step_from_rows",
                True,
                (workspace, records.compiled, k, y_arr, from_rows[1]),
            )
        else:
            assert state is not None
            code, warnings, e_hat_next = self._compiled(
                "feedback_step",
                False,
                (workspace, records.compiled, k, y_arr, state[1], state[2], state[7]),
            )
        if code == one_call.STEP_GENERAL:
            self._restore_chord()
            return None
        return self._finish_one_call(
            k, code, warnings, inverse_valid, factorizations, e_hat_next, y0_arr
        )

    def _step_from_deferred_rows(self, y_phi: ArrayLike, y0_phi: ArrayLike) -> FloatArray | None:
        """The common one-call step, with as little Python as possible: the last step was a
        one-call step whose state is still deferred in its record row, nothing is prepared,
        the signals are floats or numpy float64 scalars (p = 1) or C-contiguous float64
        vectors, and the entry point is resolved. The same call and bookkeeping as
        :meth:`_step_one_call` and :meth:`_finish_one_call` in that case (the same numbers,
        the same path after a compiled call that did not finish); None where any of it does
        not hold (nothing changed: :meth:`step` goes on as without it)."""
        deferred = self._deferred
        if deferred is None:
            return None
        rows, last, inverse_valid_before = deferred
        workspace = self._one_call
        records = self.records
        items = records._items
        k = len(items)
        e_hat = self.e_hat
        entry = self._entries.get("controller_step_from_rows")
        if (
            last != k - 1
            or rows is not records.rows
            or type(e_hat) is not float
            or not entry
            or workspace is None
            or self._prepared is not None
            or k + 2 > records.capacity
            or not self.mpc._plan_valid  # type: ignore[attr-defined]
        ):
            return None
        y_arr = self._ready_vector(y_phi, self._y_buffer)
        y0_arr = self._ready_vector(y0_phi, self._y0_buffer)
        if y_arr is None or y0_arr is None:
            return None
        rate_limit = self.setpoint_rate_limit
        code, warnings, inverse_valid, factorizations, e_hat_next = entry(
            workspace, records.compiled, k, y_arr, y0_arr, inverse_valid_before, e_hat,
            _NO_LIMIT if rate_limit is None else float(rate_limit),
        )  # fmt: skip
        if code == one_call.STEP_GENERAL:
            return self._step_general(y_phi, y0_phi, None, False)
        if code != one_call.STEP_DONE:
            answer = self._finish_one_call(
                k, code, warnings, inverse_valid, factorizations, e_hat_next, y0_arr
            )
            if not isinstance(answer, tuple):
                return answer
            chord, skip_native = answer
            return self._step_general(y_phi, y0_phi, chord, skip_native)
        if factorizations:
            self.reference.counts["factorizations"] += factorizations
        self._deferred = (rows, k, inverse_valid)
        self._requested_phi = y0_arr
        self._last_reference = _RECORDED
        self._last_reference_row = k
        if warnings:
            self._warn_one_call(rows, k, warnings)
        self.e_hat = e_hat_next
        items.append(None)  # records.append_recorded()
        return rows.u_phi[k]

    def _step_one_call(
        self, y_phi: ArrayLike, y0_phi: ArrayLike
    ) -> FloatArray | tuple[tuple[FloatArray, float, int, bool] | None, bool]:
        """:meth:`step` as one compiled call; returns the physical input, or
        ``(chord outcome or None, skip_native)`` for the general path to go on with."""
        if self._prepared is not None:
            answer = self._step_prepared(y_phi, y0_phi)
            if answer is not None:
                return answer
        records = self.records
        k = len(records)
        from_rows = self._rows_arguments(k)
        state = None if from_rows is not None else self._one_call_state()
        if from_rows is None and state is None:
            return None, False
        y_arr, y0_arr = self._signals(y_phi, y0_phi)
        if k + 2 > records.capacity:
            records.reserve(k + 2)
        workspace = self._one_call
        if from_rows is not None:
            code, warnings, inverse_valid, factorizations, e_hat_next = self._compiled(
                "controller_step_from_rows",
                True,
                (workspace, records.compiled, k, y_arr, y0_arr, *from_rows),
            )
        else:
            code, warnings, inverse_valid, factorizations, e_hat_next = self._compiled(
                "controller_step",
                False,
                (workspace, records.compiled, k, y_arr, y0_arr, *state),  # type: ignore[misc]
            )
        if code == one_call.STEP_GENERAL:
            return None, False
        return self._finish_one_call(
            k, code, warnings, inverse_valid, factorizations, e_hat_next, y0_arr
        )

    def _finish_one_call(
        self,
        k: int,
        code: int,
        warnings: int,
        inverse_valid: int,
        factorizations: int,
        e_hat_next: float,
        y0_arr: FloatArray,
    ) -> FloatArray | tuple[tuple[FloatArray, float, int, bool] | None, bool]:
        """After a compiled step or feedback: the input, with the state the step left
        deferred in its record row k (:meth:`_defer_state`); or, when the compiled call
        did not accept, the chord's outcome for the general path."""
        records = self.records
        rows = records.rows
        assert rows is not None
        if code != one_call.STEP_DONE:
            self.reference.adopt_chord_state(inverse_valid, factorizations)
            chord_row = rows.integer[k]
            chord = (
                rows.z[k].copy(),
                float(rows.real[k, one_call.REFERENCE_RESIDUAL]),
                int(chord_row[one_call.REFERENCE_ITERATIONS]),
                bool(chord_row[one_call.CHORD_OK]),
            )
            return chord, code == one_call.STEP_FEEDBACK
        if factorizations:
            self.reference.counts["factorizations"] += factorizations
        if self._deferred is None:  # else deferred since step k - 1 and untouched: kept so
            self._defer_state()
        self._deferred = (rows, k, inverse_valid)
        self._requested_phi = y0_arr
        self._last_reference = _RECORDED
        self._last_reference_row = k
        if warnings:
            self._warn_one_call(rows, k, warnings)
        self.e_hat = e_hat_next
        records.append_recorded()
        return rows.u_phi[k]

    def _warn_one_call(self, rows: SimpleNamespace, k: int, warnings: int) -> None:
        """The warnings of :meth:`_diagnose` and :meth:`_gate_input` for one-call step k."""
        status = one_call.SETPOINT_STATUSES[int(rows.integer[k, one_call.SETPOINT_STATUS])]
        y0 = rows.y0[k]
        y0_target = rows.y0[k]
        if status == "target_outside_admissible":
            y0_target = self._one_call_requested.copy()
        self._warn_diagnosis(status, rows.saturated[k].astype(bool), y0, y0_target, False)
        if warnings & 4 and self.warnings.first("input_clipped"):
            self._warn_clipped(rows.u_plan[k, 0], float(rows.real[k, one_call.INPUT_CLIPPED]))

    def _recorded_reference(self, k: int) -> ReferenceSolution:
        """The reference solution of one-call step k, from its record row."""
        rows = self.records.rows
        assert rows is not None
        return ReferenceSolution(
            x_bar=rows.x_bar[k].copy(),
            u_bar=rows.u_bar[k].copy(),
            residual=float(rows.real[k, one_call.REFERENCE_RESIDUAL]),
            jacobian_condition=math.nan,
            u_admissible=True,
            converged=True,
            iterations=int(rows.integer[k, one_call.REFERENCE_ITERATIONS]),
        )

    def _recorded_step(self, records: ControllerRecords, k: int) -> ControllerStep:
        """The :class:`ControllerStep` of one-call step k of the run ``records``, built
        from its row (when the record is first read)."""
        rows = records.rows
        assert rows is not None
        real = rows.real[k].tolist()
        integer = rows.integer[k].tolist()
        mpc: Any = self.mpc
        prepare_time, feedback_time = real[one_call.PREPARE_TIME], real[one_call.FEEDBACK_TIME]
        solution = MPCSolution(
            u=rows.u_plan[k],
            x=rows.x_plan[k],
            x_linear=rows.x_linear[k],
            status="optimal" if integer[one_call.STATUS] == 1 else "optimal_inaccurate",
            feasible=True,
            policy="nominal",
            solve_time=prepare_time + feedback_time,
            solver_time=real[one_call.SOLVER_TIME],
            iterations=1,
            sqp_step=real[one_call.SQP_STEP],
            alpha=real[one_call.ALPHA],
            cost=real[one_call.COST],
            residuals={
                "output_violation": real[one_call.OUTPUT_VIOLATION],
                "terminal_residual": real[one_call.TERMINAL_RESIDUAL],
                "linearization_gap": real[one_call.LINEARIZATION_GAP],
            },
            reformulation=mpc.reformulation,
            solver_iterations=integer[one_call.SOLVER_ITERATIONS],
            transcription=mpc.transcription,
            prepare_time=prepare_time,
            feedback_time=feedback_time,
            reason="",
        )
        return ControllerStep(
            y=rows.y[k],
            y0=rows.y0[k],
            u=rows.u[k],
            u_phi=rows.u_phi[k],
            x_hat=rows.x_hat[k],
            d_hat=rows.d_hat[k],
            e_hat=real[one_call.E_HAT],
            x_bar=rows.x_bar[k],
            u_bar=rows.u_bar[k],
            reference_ok=True,
            mpc=solution,
            time_observer=real[one_call.TIME_OBSERVER],
            time_reference=real[one_call.TIME_REFERENCE],
            time_mpc=real[one_call.TIME_MPC],
            stale_reference=False,
            setpoint_status=one_call.SETPOINT_STATUSES[integer[one_call.SETPOINT_STATUS]],
            d_hat_saturated=rows.saturated[k].astype(bool),
            input_clipped=real[one_call.INPUT_CLIPPED],
            measurement_status=one_call.MEASUREMENT_STATUSES[integer[one_call.MEASUREMENT_STATUS]],
            monitor_log=records.log,
            index=k,
        )

    def _step_general(
        self,
        y_phi: ArrayLike,
        y0_phi: ArrayLike,
        chord: tuple[FloatArray, float, int, bool] | None = None,
        skip_native: bool = False,
    ) -> FloatArray:
        """:meth:`step` in Python, calling each stage's compiled kernel (or numpy
        reference) in turn. ``chord``: the warm chord's outcome, when the one-call step ran
        it and did not accept it (the reference calculator goes on from it);
        ``skip_native``: the one-call feedback already declined this step's point."""
        y, y0_target = self._normalize(y_phi, y0_phi)
        if not self._initialized:
            self._check_first_measurement(y, y_phi)
        measurement_status = self._measurement_status(y, y_phi)
        t0 = time.perf_counter()
        if not self._initialized:
            self.observer.initialize(y, reference=self.reference)
            self.reference.reset()
            self._initialized = True
            if self.setpoint_rate_limit is not None:
                self._y0 = y.copy()  # the limited set-point starts from the measured output
        y0 = self._limit(y0_target)
        self._y0 = y0
        # No copies: the observer update rebinds x_hat and d_hat, it never mutates them.
        x_hat, d_hat = self.observer.x_hat, self.observer.d_hat
        t1 = time.perf_counter()
        if chord is None:
            solved = self._solve_reference(y0, d_hat)
        else:
            solved = self._solve_reference(y0, d_hat, chord)
        reference, y0_mpc, stale = self._reference(solved, y0, d_hat)
        setpoint_status, saturated = self._diagnose(y0, y0_target, d_hat, reference, stale)
        t2 = time.perf_counter()
        solution = self._solve_mpc(x_hat, reference, y0_mpc, skip_native)
        u = solution.u[0].copy()
        u_max = self._u_max
        inside = all(-u_max < v < u_max for v in u.tolist())  # strictly; NaN fails
        input_clipped = 0.0
        if not inside:  # outside U, non-finite, or on its boundary
            u, input_clipped = self._gate_input(u, reference.u_bar)
        t3 = time.perf_counter()
        self._update_observer(y, u)
        e_hat_used = self.e_hat
        self.e_hat = self.certification.tightening.next_e_hat(self.e_hat)
        t4 = time.perf_counter()
        u_phi = self._denormalize_u(u)
        if not inside:  # never beyond the physical bounds (rounding of the de-normalization)
            np.clip(u_phi, self._u_phi_low, self._u_phi_high, out=u_phi)
        self.records.append(
            ControllerStep(
                y=y,
                y0=y0,
                u=u,
                u_phi=u_phi,
                x_hat=x_hat,
                d_hat=d_hat,
                e_hat=e_hat_used,
                x_bar=reference.x_bar,
                u_bar=reference.u_bar,
                reference_ok=reference.ok and not stale,
                mpc=solution,
                time_observer=(t1 - t0) + (t4 - t3),
                time_reference=t2 - t1,
                time_mpc=t3 - t2,
                stale_reference=stale,
                setpoint_status=setpoint_status,
                d_hat_saturated=saturated,
                input_clipped=input_clipped,
                measurement_status=measurement_status,
                monitor_log=self._assumption_log,
                index=len(self.records),
            )
        )
        return u_phi


def _check_mpc(mpc: object) -> None:
    """An MPC given to the controller fills the role of :class:`RobustMPC`."""
    phases = ("prepare", "feedback") if hasattr(mpc, "prepare") else ("solve",)
    hint = "or None for RobustMPC(model, config)"
    expect_methods("mpc", mpc, (*phases, "reset"), "an MPC like RobustMPC", hint)
    if not hasattr(mpc, "certification"):
        raise ArgumentTypeError(
            f"mpc must be an MPC like RobustMPC, with a certification attribute; got "
            f"{type(mpc).__name__}; {hint}"
        )
