r"""The offset-free control loop of the paper's Fig. 1, one ``step`` per sample.

normalization -> :class:`~ltv_lstm_mpc.Observer` (eq. lstm_observer) ->
:class:`~ltv_lstm_mpc.ReferenceCalculator` (eq. reference_calculation) ->
:class:`~ltv_lstm_mpc.RobustMPC` (eq. optimization; ``prepare`` then ``feedback``,
whatever the transcription) -> exit gate onto :math:`\mathcal U` -> de-normalization.
:class:`OffsetFreeController` describes the loop (its components, configuration,
certification, records and warnings); a step engine runs it
(:mod:`ltv_lstm_mpc.loop.engines`): the reference engine stage by stage
(:mod:`~ltv_lstm_mpc.loop.engines.reference_engine`, every configuration), or the one-call
engine as one compiled call (:mod:`~ltv_lstm_mpc.loop.engines.one_call_engine`), chosen
once at construction. The configuration chooses the solver and the transcription
(condensed dense QP, sparse with exact cones, or the exact NMPC), with the same checks,
fallbacks and records.

Timing convention: at sample k the controller holds :math:`(\hat x_k, \hat d_k)` and
:math:`\hat e_{o,k}`. ``step(y_phi_k, y0_phi_k)`` computes :math:`u_k` from them, then
feeds :math:`(y_k, u_k)` to the observer, which yields :math:`(\hat x_{k+1}, \hat d_{k+1})`,
and advances :math:`\hat e_{o,k+1} = \rho_o \hat e_{o,k} + \bar w` (eq. eo_evolution).
At the first call the observer starts at the LSTM equilibrium matching :math:`y_0`
with :math:`\hat d_0 = 0` (paper notes 2.10b).
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

from ltv_lstm_mpc.caller_warnings import RunWarnings
from ltv_lstm_mpc.certificates.certify import Certification
from ltv_lstm_mpc.deferred_state import Deferred, DeferredState
from ltv_lstm_mpc.exceptions import ArgumentTypeError, InvalidValueError
from ltv_lstm_mpc.loop.engines import choose_engine
from ltv_lstm_mpc.loop.engines.base import StepEngine
from ltv_lstm_mpc.loop.kernels import use_kernels
from ltv_lstm_mpc.loop.monitor import AssumptionLog, AssumptionMonitor
from ltv_lstm_mpc.loop.observer import Observer
from ltv_lstm_mpc.loop.records import ControllerRecords
from ltv_lstm_mpc.loop.reference import ReferenceCalculator
from ltv_lstm_mpc.loop.signals import SignalScaling
from ltv_lstm_mpc.loop.step_record import ControllerStep, recorded_step
from ltv_lstm_mpc.lstm.model import LSTMModel, require_model
from ltv_lstm_mpc.mpc.config import MPCConfig, require_config
from ltv_lstm_mpc.mpc.fhocp import MPCSolver
from ltv_lstm_mpc.mpc.rti import RobustMPC
from ltv_lstm_mpc.numba_support import prime_typeof
from ltv_lstm_mpc.validation import (
    expect_bool,
    expect_instance,
    expect_methods,
    expect_real,
    real_vector,
)

__all__ = ["ControllerStep", "OffsetFreeController"]

FloatArray = NDArray[np.float64]


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
        :attr:`kernels` (``"compiled"`` or ``"numpy"``). The caller's model is never
        modified: where the choice is not the model's kernel, the controller runs a copy
        of the model with its own kernel (:attr:`model`).
    monitor : AssumptionMonitor, optional
        Checks Theorem 3's hypotheses on every record (:mod:`ltv_lstm_mpc.loop.monitor`);
        default: one on this controller's certification. Give one built on a certification
        whose rate bound covers your set-point range (``y0_operating_range`` of
        :class:`~ltv_lstm_mpc.CertificationSettings`) when the limiter uses that bound.
    one_call_step : bool
        Allow the one-call engine (default True): each step, the first one included, as one
        compiled call where the configuration allows it (the condensed transcription with
        DAQP bound natively, compiled kernels, one SQP iteration, no ``mpc`` given:
        :mod:`ltv_lstm_mpc.loop.engines.one_call_engine`), handing any step that call does
        not accept to the reference engine. False: the reference engine on every step
        (the readable specification; same numbers to 1e-12).
    engine : {"auto", "reference", "one-call", "c", "c-single"}
        The step engine (:mod:`ltv_lstm_mpc.loop.engines`): ``"auto"`` (default) the
        fastest that supports the configuration; ``"c"`` the exported C99 step built
        with the host's C compiler (:mod:`~ltv_lstm_mpc.export.c_engine`, software
        in the loop: the configurations the C export covers), ``"c-single"`` the same in
        single precision (float); a named engine that does not support the configuration
        raises, with its reason.

    Attributes
    ----------
    engine : StepEngine
        What runs :meth:`step` (:mod:`ltv_lstm_mpc.loop.engines`), chosen once, here: the
        fastest engine that supports this configuration; ``engine.name`` says which
        (``"one-call"`` or ``"reference"``), :attr:`engine_refusals` why the faster ones
        did not take it.
    e_hat : float
        :math:`\hat e_{o,k}`, the observer-error bound the next step uses.
    y0_last : ndarray or None
        The limiter's last set-point (normalized; None before the first step or without
        a limiter).

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

    #: The limiter's last set-point (normalized): deferred while a one-call step's record
    #: row holds it (:mod:`ltv_lstm_mpc.deferred_state`).
    y0_last = Deferred[FloatArray | None]()

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
        engine: str = "auto",
    ) -> None:
        model, config = require_model(model), require_config(config)
        expect_bool("one_call_step", one_call_step)
        if not isinstance(engine, str):
            raise InvalidValueError(
                f"engine must be a string ('auto', 'reference', 'one-call', 'c' or "
                f"'c-single'), got "
                f"{type(engine).__name__}"
            )
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
        self.config = config = config or MPCConfig()
        self.one_call_step = one_call_step
        #: Whether the caller gave the MPC (``mpc``): its kernels are used as they are.
        self.custom_mpc = mpc is not None
        if mpc is None:  # (the caller's model, or a copy with the kernel chosen)
            model = use_kernels(model, config, kernels, one_call_step=one_call_step)
        #: The model this controller runs: the caller's, or a copy of it with its own kernel.
        self.model = model
        #: ``"compiled"`` or ``"numpy"``: the kernels this controller runs (see ``kernels``).
        self.kernels = "compiled" if model.kernel.compiled else "numpy"
        self.mpc: MPCSolver = mpc if mpc is not None else RobustMPC(model, config)
        self.certification = self.mpc.certification
        self.observer = Observer(model, self.certification.observer.gains, d_max=config.d_max)
        # tol 1e-10 (not 1e-12): the warm chord path then ends in one residual check at steady
        # state; the equilibrium error it leaves is far below the offsets measured.
        self.reference = ReferenceCalculator(model, u_max=config.u_max, strict=False, tol=1e-10)
        self.setpoint_rate_limit = setpoint_rate_limit
        #: The normalization and U (physical and normalized; paper notes 1).
        self.scaling = SignalScaling.of(model, config.u_max)
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
        self.initialized = False
        self.y0_last = None
        self.requested_phi: FloatArray | None = None  # the set-point the last step requested
        #: This run's records (a read-only sequence of :class:`ControllerStep`).
        self.records: ControllerRecords = ControllerRecords(self._recorded_step)
        self.engine: StepEngine
        #: Why each engine faster than :attr:`engine` refused this configuration.
        self.engine_refusals: dict[str, str]
        self.engine, self.engine_refusals = choose_engine(self, engine)
        if self.kernels == "compiled":
            prime_typeof()  # the first compiled steps then type their workspaces at once
        self.reset()

    @property
    def warning_counts(self) -> dict[str, int]:
        """Steps of this run on which each warned condition held (shown once per run):
        ``"input_clipped"``, ``"measurement_implausible"``, ``"setpoint"``,
        ``"d_hat_saturated"``."""
        return dict(self.warnings.counts)

    @property
    def one_call(self) -> bool:
        """Whether the steps run as one compiled call each (the one-call engine)."""
        return self.engine.name == "one-call"

    @property
    def input_bounds_phi(self) -> tuple[FloatArray, FloatArray]:
        """U in physical units: (low, high), each (m,)."""
        return self.scaling.u_phi_low.copy(), self.scaling.u_phi_high.copy()

    def reset(self) -> None:
        """Back to the uninitialized state (the next step initializes the observer)."""
        self.engine.settle()
        self.initialized = False
        self.y0_last = None
        tightening = self.certification.tightening
        self.e_hat = tightening.e_inf if self.config.e_hat0 is None else float(self.config.e_hat0)
        self.mpc.reset()
        self.reference.reset()
        self.records = ControllerRecords(self._recorded_step, self.engine.record_shape)
        #: The run's assumption log (the records' ``monitor_log``).
        self.assumption_log = (
            None if self.monitor is None else AssumptionLog(self.monitor, self.records)
        )
        self.records.log = self.assumption_log
        self.warnings.reset()
        self.requested_phi = None
        self.engine.reset()

    def step(self, y_phi: ArrayLike, y0_phi: ArrayLike) -> FloatArray:
        r"""One sample: measured physical output and set-point in, physical input out.

        The stages of Fig. 1, whichever engine runs them (:attr:`engine`):

        1. normalization of :math:`y_{\phi,k}` and :math:`y^0_{\phi,k}` (paper notes 1) and
           the measurement status; at the first step the observer starts at the
           equilibrium matching :math:`y_0`;
        2. the set-point rate limiter (Theorem 3's :math:`\Delta y^0_{max}`);
        3. the reference calculator, eq. (reference_calculation), and the set-point
           status of Assumption 5 at :math:`\hat e_{o,k}`;
        4. the robust MPC, eq. (optimization), with the tightened output bounds
           (eq. optimization_constraint_yub/ylb) and :math:`\alpha_k` (eq. def_alpha):
           ``prepare`` then ``feedback``;
        5. the exit gate onto :math:`\mathcal U`;
        6. the observer update, eq. (lstm_observer), and eq. (eo_evolution);
        7. de-normalization of :math:`u_k`, and the step's record (:attr:`records`).

        After :meth:`prepare_next` (called between samples) a one-call step runs only the
        feedback of the prepared subproblem and stages 5-7.
        """
        return self.engine.step(y_phi, y0_phi)

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
            True when the next step is prepared; False where the engine does not prepare
            between samples (the reference engine prepares inside the step), before the
            first step, or where the preparation did not pass the one-call step's tests
            (the next step then runs as usual).

        Raises
        ------
        InvalidValueError, DimensionError
            ``y0_phi`` not p finite real numbers.
        """
        if y0_phi is None:
            requested = self.requested_phi
        else:
            requested = real_vector("y0_phi", y0_phi, self.model.p)
        return self.engine.prepare(requested)

    def _recorded_step(self, records: ControllerRecords, k: int) -> ControllerStep:
        """The record of step ``k`` of the run ``records``, built from its row when first
        read (an engine that writes rows: :mod:`ltv_lstm_mpc.loop.step_record`)."""
        return recorded_step(records, k, self.mpc)


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
