r"""The one-call step engine: each step as one compiled call, the first one included.

On the condensed transcription with DAQP bound natively (QP, or exact cones by SQP on
DAQP), compiled kernels, one SQP iteration and the controller's own MPC, a step runs as
:func:`~ltv_lstm_mpc.loop.compiled_step.controller_step`: the same stages as the
:class:`~ltv_lstm_mpc.loop.engines.reference_engine.ReferenceEngine`, on the same shared
formulas and compiled kernels, in one call. It writes everything into the preallocated
record rows; the records are built from them when read
(:mod:`ltv_lstm_mpc.loop.step_record`), and the state the next step starts from stays in
the rows (:mod:`ltv_lstm_mpc.deferred_state`) until something reads it. The first step
after construction or a reset runs as
:func:`~ltv_lstm_mpc.loop.compiled_step.controller_first_step` (the observer's start at an
equilibrium, then the same stages).

A step the compiled call does not accept (a measurement the checks flag, a first step
the reference engine would raise or warn on, a warm chord that does not give an
admissible equilibrium, a point the one-call feedback declines) is handed to the
reference engine with what already ran
(:class:`~ltv_lstm_mpc.loop.engines.reference_engine.Handover`): the same numbers to 1e-12
(``tests/test_one_call_step.py``). :meth:`OneCallEngine.prepare` runs the stages that do
not use the measurement between samples (``OffsetFreeController.prepare_next``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from types import SimpleNamespace
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from ltv_lstm_mpc.deferred_state import Deferred, DeferredState, defer, settle
from ltv_lstm_mpc.loop import compiled_step as one_call
from ltv_lstm_mpc.loop.diagnostics import flag_implausible, warn_clipped, warn_diagnosis
from ltv_lstm_mpc.loop.engines.reference_engine import Handover, ReferenceEngine
from ltv_lstm_mpc.loop.statuses import IMPLAUSIBLE_MEASUREMENT_LIMIT, SETPOINT_STATUSES
from ltv_lstm_mpc.mpc.rti import RobustMPC
from ltv_lstm_mpc.numba_support import entry_point
from ltv_lstm_mpc.validation import real_vector

if TYPE_CHECKING:
    from ltv_lstm_mpc.loop.controller import OffsetFreeController

__all__ = ["OneCallEngine"]

FloatArray = NDArray[np.float64]

#: An empty vector: "none" for the compiled step's optional vector arguments.
_NO_VALUES = np.zeros(0)
_FLOAT64 = np.dtype(np.float64)  # numpy's one native float64 dtype (compared by identity)
#: The compiled step's rate limit without a limiter.
_NO_LIMIT = math.nan


def _same_limit(a: float, b: float) -> bool:
    return a == b or (math.isnan(a) and math.isnan(b))


@dataclass(slots=True)
class StepState:
    """The state arguments of :func:`~ltv_lstm_mpc.loop.compiled_step.controller_step`
    (see there), read from their owners."""

    y0_previous: FloatArray
    x_hat: FloatArray
    d_hat: FloatArray
    last_z: FloatArray
    last_target: FloatArray
    jinv_valid: int
    previous_u: FloatArray
    e_hat: float
    rate_limit: float

    def arguments(self) -> tuple[Any, ...]:
        """In the compiled call's order."""
        return (
            self.y0_previous, self.x_hat, self.d_hat, self.last_z, self.last_target,
            self.jinv_valid, self.previous_u, self.e_hat, self.rate_limit,
        )  # fmt: skip

    def same_as(self, other: StepState | None) -> bool:
        """The same arrays (not copies: views of the record rows), the same scalars."""
        return (
            other is not None
            and self.y0_previous is other.y0_previous
            and self.x_hat is other.x_hat
            and self.d_hat is other.d_hat
            and self.last_z is other.last_z
            and self.last_target is other.last_target
            and self.previous_u is other.previous_u
            and self.jinv_valid == other.jinv_valid
            and self.e_hat == other.e_hat
            and _same_limit(self.rate_limit, other.rate_limit)
        )


@dataclass(slots=True)
class RowsArguments:
    """The scalar arguments of the ``*_from_rows`` calls (the state is in row k - 1)."""

    jinv_valid: int
    e_hat: float
    rate_limit: float

    def same_as(self, other: RowsArguments | None) -> bool:
        return (
            other is not None
            and self.jinv_valid == other.jinv_valid
            and self.e_hat == other.e_hat
            and _same_limit(self.rate_limit, other.rate_limit)
        )


@dataclass(slots=True)
class DeferredRows:
    """The state one-call step ``k`` left in its record row, not yet written into the
    owners (:meth:`OneCallEngine.settle` writes it)."""

    rows: SimpleNamespace
    k: int
    inverse_valid: int


@dataclass(slots=True)
class Installed:
    """The state one-call step ``k`` left, as written into the owners (views of its row)."""

    x_hat: FloatArray
    d_hat: FloatArray
    last_z: FloatArray
    last_target: FloatArray
    previous_u: FloatArray
    y0: FloatArray
    k: int


@dataclass(slots=True)
class Preparation:
    """What :meth:`OneCallEngine.prepare` prepared for step ``k``."""

    k: int
    y0_values: list[float]
    from_rows: RowsArguments | None
    state: StepState | None
    workspace: Any
    inverse_valid: int
    factorizations: int


class OneCallEngine(DeferredState):
    """Each step as one compiled call, the first one included (module docstring).

    Parameters
    ----------
    controller : OffsetFreeController
        A configuration :meth:`refusal` accepts.
    """

    name = "one-call"
    # The state the last step left, as written into the owners (deferred while it waits
    # in its record row).
    installed = Deferred[Installed | None]()

    @staticmethod
    def refusal(controller: OffsetFreeController) -> str | None:
        """Why this engine does not run ``controller`` (None: it does)."""
        config = controller.config
        if not controller.one_call_step:
            return "one_call_step=False"
        if not isinstance(controller.mpc, RobustMPC) or controller.custom_mpc:
            return "a custom mpc was given"
        if controller.kernels != "compiled":
            return "the numpy kernels run (kernels='numpy', or not compiled yet)"
        if controller.mpc.one_call_parts() is None:
            return (
                f"no one-call feedback for solver={config.solver!r}, transcription="
                f"{controller.mpc.transcription!r}, sqp_iterations={config.sqp_iterations} "
                "(it needs the condensed transcription with DAQP bound natively, daqp or "
                "daqp:socp, and one SQP iteration)"
            )
        if (
            controller.reference.chord_state() is None
            or controller.observer.step_workspace() is None
        ):
            return "the reference calculator or the observer runs the numpy kernels"
        return None

    def __init__(self, controller: OffsetFreeController) -> None:
        self.controller = controller
        mpc = controller.mpc
        assert isinstance(mpc, RobustMPC)  # refusal checked it
        #: The controller's MPC (its compiled parts: :meth:`RobustMPC.one_call_parts`).
        self.mpc = mpc
        #: The engine of the steps this one hands over.
        self.general = ReferenceEngine(controller)
        model = controller.model
        self.record_shape = (model.p, model.m, 2 * model.n, controller.config.N)
        self.chord = controller.reference.chord_state()
        assert self.chord is not None  # refusal checked it
        self.jinv_backup = np.zeros_like(self.chord.jinv)
        p = model.p
        #: The workspace's ``requested``: the set-point requested before the limiter.
        self.requested = np.zeros(p)
        self.y_buffer, self.y0_buffer = np.zeros(p), np.zeros(p)
        self.entries: dict[str, Any] = {}  # compiled entry points (_compiled)
        self.deferred: DeferredRows | None = None
        self.prepared: Preparation | None = None
        self.settings = self._settings_now()
        self.workspace = self._new_workspace()
        self.installed = None

    # ------------------------------------------------------------------ workspace
    def _new_workspace(self) -> Any:
        """The :data:`~ltv_lstm_mpc.loop.compiled_step.StepWorkspace`, from the components'
        public workspaces and the certificate's arrays."""
        controller = self.controller
        mpc, reference = self.mpc, controller.reference
        parts, chord = mpc.one_call_parts(), reference.chord_state()
        assert parts is not None and chord is not None
        ti, scaling, N = controller.certification.tightening, controller.scaling, mpc.N
        p = controller.model.p

        def vector(values: Any) -> FloatArray:
            return np.array(values, dtype=np.float64)  # an owned, C-contiguous copy

        self.settings = self._settings_now()
        return one_call.new_step_workspace(
            y_min=vector(scaling.y_min), y_scale=vector(scaling.y_scale),
            u_min=vector(scaling.u_min), u_scale=vector(scaling.u_scale),
            u_phi_low=vector(scaling.u_phi_low), u_phi_high=vector(scaling.u_phi_high),
            a=vector(ti.a), b=vector(ti.b), bound_min=vector(ti.y_min),
            bound_max=vector(ti.y_max), kappa=vector(ti.kappa), lower=np.zeros((N, p)),
            upper=np.zeros((N, p)), requested=self.requested,
            clock=np.zeros(2, dtype=np.int64),
            u_max=scaling.u_max, implausible=float(IMPLAUSIBLE_MEASUREMENT_LIMIT),
            tol=float(reference.tol), max_iter=int(reference.max_iter),
            jump=float(reference.jump), reuse_tol=float(mpc.reuse_tol),
            d_max=float(controller.observer.d_max), tightening_d_max=float(ti.d_max),
            rho_o=float(ti.rho_o), w_bar=float(ti.w_bar), e_inf=float(ti.e_inf),
            backward=parts.backward, chord=chord.workspace,
            trajectories=parts.trajectories, condensing=parts.condensing,
            daqp=parts.daqp if parts.daqp is not None else one_call.placeholder_daqp(),
            plan=parts.plan, observer=controller.observer.step_workspace(),
            cand=parts.candidate, cones=parts.socp is not None,
            socp=parts.socp if parts.socp is not None else one_call.placeholder_socp(),
            tolerance=parts.tolerance, jinv_backup=self.jinv_backup,
            fallback=(
                parts.fallback if parts.fallback is not None else one_call.placeholder_fallback()
            ),
            restart=chord.restart,
            flag_implausible=controller.implausible_measurements == "flag",
        )  # fmt: skip

    def _settings_now(self) -> tuple[float, int, float, float, str]:
        """The settings the workspace holds: the reference calculator's tolerance,
        iterations and jump bound, the MPC's reuse tolerance, the controller's
        ``implausible_measurements``."""
        controller = self.controller
        reference, mpc = controller.reference, self.mpc
        return (
            reference.tol, reference.max_iter, reference.jump, mpc.reuse_tol,
            controller.implausible_measurements,
        )  # fmt: skip

    def _check_settings(self) -> None:
        """A new workspace where the user changed one of the settings it holds."""
        if self._settings_now() != self.settings:
            self.workspace = self._new_workspace()
            self.entries.clear()

    # ------------------------------------------------------------------ run state
    def reset(self) -> None:
        """Forget the run (the controller has settled the deferred state first), and make
        the first steps of the next one ready (:meth:`_ready`)."""
        self.prepared = None
        self.installed = None
        self.general.reset()
        self._ready()

    def _ready(self) -> None:
        """The record rows of the first steps, and the entry points of the first step and
        of the common step (``controller_first_step``, ``controller_step_from_rows``, from
        the versions the controller loaded from numba's cache at construction), now rather
        than in the first steps: those then take the time of any other step
        (``experiments/cold_start.py``)."""
        records = self.controller.records
        records.reserve(2)  # (the first rows: 64)
        y, y0 = self.y_buffer, self.y0_buffer
        for name, arguments in (
            ("controller_first_step", (self.workspace, records.compiled, 0, y, y0, 0.0, _NO_LIMIT)),
            ("controller_step_from_rows",
             (self.workspace, records.compiled, 1, y, y0, 0, 0.0, _NO_LIMIT)),
        ):  # fmt: skip
            if self.entries.get(name):
                continue
            entry = entry_point(getattr(one_call, name), arguments)
            if entry is not None:
                self.entries[name] = entry

    def _step_state(self) -> StepState | None:
        """The state arguments of the compiled step, or None where it cannot run now (no
        plan or reference yet, or a limiter without its last set-point: the reference
        engine then runs). Reading them writes a deferred state into its owners."""
        controller = self.controller
        mpc, reference, observer = self.mpc, controller.reference, controller.observer
        previous_u, warm = mpc.previous_plan, reference.warm_start()
        y0_previous = controller.y0_last
        rate_limit = controller.setpoint_rate_limit
        if previous_u is None or warm is None or not mpc.plan_valid:
            return None
        if rate_limit is None:
            rate_limit = math.nan
        elif y0_previous is None:
            return None
        self._check_settings()
        return StepState(
            y0_previous=_NO_VALUES if y0_previous is None else y0_previous,
            x_hat=observer.x_hat, d_hat=observer.d_hat, last_z=warm.last_z,
            last_target=_NO_VALUES if warm.last_target is None else warm.last_target,
            jinv_valid=warm.jinv_valid, previous_u=previous_u, e_hat=controller.e_hat,
            rate_limit=float(rate_limit),
        )  # fmt: skip

    def _rows_arguments(self, k: int) -> RowsArguments | None:
        """The arguments of the ``*_from_rows`` calls of step ``k`` when the state it starts
        from is the one step ``k - 1`` left in its record row (still deferred and untouched,
        or written into the owners and unchanged since: :meth:`_installed_state`), so that
        the compiled entry points apply; None otherwise (the state is passed as arguments,
        through numba's dispatcher), and then no state is left deferred."""
        controller = self.controller
        e_hat, deferred = controller.e_hat, self.deferred
        if type(e_hat) is not float or not self.mpc.plan_valid:
            self.settle()
            return None
        if deferred is not None:
            if deferred.k != k - 1:
                self.settle()
                return None
            jinv_valid = deferred.inverse_valid
        elif self._installed_state(k):
            jinv_valid = controller.reference.jinv_valid
            self._check_settings()  # (deferred: a setting assigned since would have settled)
        else:
            return None
        rate_limit = controller.setpoint_rate_limit
        return RowsArguments(
            jinv_valid, e_hat, _NO_LIMIT if rate_limit is None else float(rate_limit)
        )

    def _installed_state(self, k: int) -> bool:
        """Whether every state argument is the one step ``k - 1`` left, written into the
        owners (views of its record row, of the types the entry points were resolved for)."""
        installed = self.installed
        if installed is None or installed.k != k - 1:
            return False
        controller = self.controller
        reference, observer, mpc = controller.reference, controller.observer, self.mpc
        return (
            observer.x_hat is installed.x_hat
            and observer.d_hat is installed.d_hat
            and reference.last_z is installed.last_z
            and reference.last_target is installed.last_target
            and mpc.previous_plan is installed.previous_u
            and controller.y0_last is installed.y0
        )

    def _defer_state(self) -> None:
        """Leave the state of the last step in its record row: the owners go without it
        until it is first read (:mod:`ltv_lstm_mpc.deferred_state`; :meth:`settle`)."""
        controller, mpc = self.controller, self.mpc
        for owner in (controller.observer, controller.reference, mpc, controller, self):
            defer(owner, self.settle)
        mpc.forget_preparation()

    def settle(self) -> None:
        """Write the state the last step k left in its record row into the observer
        (estimates of row k + 1), the reference calculator (last solution and target,
        inverse Jacobian), the MPC (plan, times), the controller (set-point) and this
        engine, as views of the row (never written again); a value assigned since is kept."""
        deferred = self.deferred
        if deferred is None:
            return
        self.deferred = None
        rows, k = deferred.rows, deferred.k
        self.general.remember_recorded(k)  # the last admissible reference: row k's
        controller, mpc = self.controller, self.mpc
        x_hat, d_hat = rows.x_hat[k + 1], rows.d_hat[k + 1]
        last_z, last_target, previous_u, y0 = rows.z[k], rows.target[k], rows.u_plan[k], rows.y0[k]
        solver_time, prepare_time, feedback_time = rows.real[
            k, one_call.SOLVER_TIME : one_call.FEEDBACK_TIME + 1
        ].tolist()
        controller.observer.settle_estimates(x_hat, d_hat)
        controller.reference.settle_warm_start(last_z, last_target, deferred.inverse_valid)
        iterations = int(rows.integer[k, one_call.SOLVER_ITERATIONS])
        mpc.settle_plan(previous_u, (solver_time, prepare_time, feedback_time), iterations)
        settle(controller, {"y0_last": y0})
        installed = Installed(x_hat, d_hat, last_z, last_target, previous_u, y0, k)
        settle(self, {"installed": installed})

    # ------------------------------------------------------------------ compiled calls
    def _compiled(self, name: str, fast: bool, arguments: tuple[Any, ...]) -> Any:
        """Call ``compiled_step.<name>``: through its entry point when ``fast`` (all
        arguments of the types it was resolved for: :meth:`_rows_arguments`), otherwise
        through numba's dispatcher (which checks the types), resolving the entry point."""
        entry = self.entries.get(name) if fast else None
        if entry:
            return entry(*arguments)
        function = getattr(one_call, name)
        result = function(*arguments)
        if fast and entry is None:  # False: no entry point (not a compiled dispatcher)
            self.entries[name] = entry_point(function, arguments) or False
        return result

    def _signals(self, y_phi: ArrayLike, y0_phi: ArrayLike) -> tuple[FloatArray, FloatArray]:
        """Measurement and set-point as C-contiguous float64 vectors of p values for the
        compiled call. The common inputs (such arrays, or one float where p = 1) pass as
        they are, or through the buffers, with their finiteness left to the compiled call
        (which hands a non-finite value to the reference engine: its error); anything else
        is checked (:func:`~ltv_lstm_mpc.validation.real_vector`)."""
        return (
            _vector("y_phi", y_phi, self.y_buffer),
            _vector("y0_phi", y0_phi, self.y0_buffer),
        )

    # ------------------------------------------------------------------ the step
    def step(self, y_phi: ArrayLike, y0_phi: ArrayLike) -> FloatArray:
        """One sample: one compiled call where it accepts, else the reference engine.

        The common step first, with as little Python as possible: the last step was a
        one-call step whose state is still deferred in its record row, nothing is
        prepared, the signals are floats or numpy float64 scalars (p = 1) or C-contiguous
        float64 vectors, and the entry point is resolved. The same call and bookkeeping as
        :meth:`_step_one_call` and :meth:`_finish` in that case; otherwise
        :meth:`_step_any` (nothing has changed)."""
        deferred = self.deferred
        if deferred is None:
            return self._step_any(y_phi, y0_phi)
        controller = self.controller
        records = controller.records
        slots = records.slots  # (len and append of the list itself: 0.15 us a step less)
        k = len(slots)
        e_hat = controller.e_hat
        entry = self.entries.get("controller_step_from_rows")
        if (
            deferred.k != k - 1
            or deferred.rows is not records.rows
            or type(e_hat) is not float
            or not entry
            or self.prepared is not None
            or k + 2 > records.capacity
            or not self.mpc.plan_valid
        ):
            return self._step_any(y_phi, y0_phi)
        y_arr = _ready_vector(y_phi, self.y_buffer)
        y0_arr = _ready_vector(y0_phi, self.y0_buffer)
        if y_arr is None or y0_arr is None:
            return self._step_any(y_phi, y0_phi)
        rate_limit = controller.setpoint_rate_limit
        code, warnings, inverse_valid, factorizations, e_hat_next = entry(
            self.workspace, records.compiled, k, y_arr, y0_arr, deferred.inverse_valid, e_hat,
            _NO_LIMIT if rate_limit is None else float(rate_limit),
        )  # fmt: skip
        if code == one_call.STEP_GENERAL:
            return self.general.step(y_phi, y0_phi)
        if code != one_call.STEP_DONE:
            answer = self._finish(
                k, code, warnings, inverse_valid, factorizations, e_hat_next, y0_arr, y_phi
            )
            assert isinstance(answer, Handover)
            return self.general.step(y_phi, y0_phi, answer)
        # :meth:`_finish` of a done step, inline (the state stays deferred since step k - 1)
        if factorizations:
            controller.reference.counts["factorizations"] += factorizations
        rows = deferred.rows
        deferred.k, deferred.inverse_valid = k, inverse_valid  # (in place: a step's less)
        controller.requested_phi = y0_arr  # (the reference engine learns k at settle())
        if warnings:
            self._warn(rows, k, warnings, y_phi)
        controller.e_hat = e_hat_next
        slots.append(None)  # records.append_recorded()
        return rows.u_phi[k]

    def _step_any(self, y_phi: ArrayLike, y0_phi: ArrayLike) -> FloatArray:
        """:meth:`step` where the common step does not apply."""
        handover = None
        if self.controller.initialized:
            answer = self._step_one_call(y_phi, y0_phi)
            if not isinstance(answer, Handover):
                return answer
            handover = answer
        else:
            first = self._first_step(y_phi, y0_phi)
            if not isinstance(first, Handover):
                return first
            handover = first
        return self.general.step(y_phi, y0_phi, handover)

    def _first_step(self, y_phi: ArrayLike, y0_phi: ArrayLike) -> FloatArray | Handover:
        """The first step after construction or a reset as one compiled call
        (:func:`~ltv_lstm_mpc.loop.compiled_step.controller_first_step`: the observer's
        start at the equilibrium whose output is the measurement, then the step); where it
        does not accept, what the reference engine needs to run the whole first step
        (``ReferenceEngine._start`` included, with its errors and warnings): no chord
        (the reference is solved again, cold), and whether the one-call feedback already
        declined this step's subproblem (then not run again)."""
        controller = self.controller
        self.settle()
        self._check_settings()
        records = controller.records
        k = len(records)
        y_arr, y0_arr = self._signals(y_phi, y0_phi)
        if k + 2 > records.capacity:
            records.reserve(k + 2)
        rate_limit = controller.setpoint_rate_limit
        e_hat = float(controller.e_hat)
        code, warnings, inverse_valid, factorizations, e_hat_next = self._compiled(
            "controller_first_step", True,
            (self.workspace, records.compiled, k, y_arr, y0_arr, e_hat,
             _NO_LIMIT if rate_limit is None else float(rate_limit)),
        )  # fmt: skip
        if code != one_call.STEP_DONE:
            return Handover(None, code == one_call.STEP_FEEDBACK)
        controller.initialized = True
        self.mpc.plan_valid = True  # the plan the call left in row k (settled from there)
        answer = self._finish(
            k, code, warnings, inverse_valid, factorizations, e_hat_next, y0_arr, y_phi
        )
        assert not isinstance(answer, Handover)
        return answer

    def _step_one_call(self, y_phi: ArrayLike, y0_phi: ArrayLike) -> FloatArray | Handover:
        """:meth:`step` as one compiled call; returns the physical input, or what ran for
        the reference engine to go on with."""
        if self.prepared is not None:
            answer = self._step_prepared(y_phi, y0_phi)
            if answer is not None:
                return answer
        records = self.controller.records
        k = len(records)
        from_rows = self._rows_arguments(k)
        state = None if from_rows is not None else self._step_state()
        if from_rows is None and state is None:
            return Handover(None, False)
        y_arr, y0_arr = self._signals(y_phi, y0_phi)
        if k + 2 > records.capacity:
            records.reserve(k + 2)
        if from_rows is not None:
            code, warnings, inverse_valid, factorizations, e_hat_next = self._compiled(
                "controller_step_from_rows", True,
                (self.workspace, records.compiled, k, y_arr, y0_arr, from_rows.jinv_valid,
                 from_rows.e_hat, from_rows.rate_limit),
            )  # fmt: skip
        else:
            assert state is not None
            code, warnings, inverse_valid, factorizations, e_hat_next = self._compiled(
                "controller_step", False,
                (self.workspace, records.compiled, k, y_arr, y0_arr, *state.arguments()),
            )  # fmt: skip
        if code == one_call.STEP_GENERAL:
            return Handover(None, False)
        return self._finish(
            k, code, warnings, inverse_valid, factorizations, e_hat_next, y0_arr, y_phi
        )

    def _finish(
        self,
        k: int,
        code: int,
        warnings: int,
        inverse_valid: int,
        factorizations: int,
        e_hat_next: float,
        y0_arr: FloatArray,
        y_phi: ArrayLike,
    ) -> FloatArray | Handover:
        """After a compiled step or feedback: the input, with the state the step left
        deferred in its record row k (:meth:`_defer_state`); or, when the compiled call
        did not accept, the chord's outcome for the reference engine (``y_phi``: the
        measurement as given, for a warning's message)."""
        controller = self.controller
        records = controller.records
        rows = records.rows
        assert rows is not None
        if code != one_call.STEP_DONE:
            controller.reference.adopt_chord_state(inverse_valid, factorizations)
            chord_row = rows.integer[k]
            chord = (
                rows.z[k].copy(),
                float(rows.real[k, one_call.REFERENCE_RESIDUAL]),
                int(chord_row[one_call.REFERENCE_ITERATIONS]),
                bool(chord_row[one_call.CHORD_OK]),
            )
            return Handover(chord, code == one_call.STEP_FEEDBACK)
        if factorizations:
            controller.reference.counts["factorizations"] += factorizations
        if self.deferred is None:  # else deferred since step k - 1 and untouched: kept so
            self._defer_state()
        self.deferred = DeferredRows(rows, k, inverse_valid)
        controller.requested_phi = y0_arr
        self.general.remember_recorded(k)
        if warnings:
            self._warn(rows, k, warnings, y_phi)
        controller.e_hat = e_hat_next
        records.append_recorded()
        return rows.u_phi[k]

    def _warn(self, rows: SimpleNamespace, k: int, warnings: int, y_phi: ArrayLike) -> None:
        """The run warnings of compiled step k (:mod:`ltv_lstm_mpc.loop.diagnostics`; its
        measurement ``y_phi``), and the reference calculator's count of its damped Newton
        (bit 3)."""
        if warnings & 32:  # the failed cone solve's arrays, for its status and reason: the
            # step copied them into the flat snapshot (socp_sqp.snapshot_into), kept here
            parts = self.mpc.one_call_parts()
            assert parts is not None  # (the one-call engine runs on them)
            real, integer = parts.failure_snapshot
            self.controller.records.extras[k] = (real.copy(), integer.copy())
        if warnings & 16:
            flag_implausible(self.controller, rows.y[k], y_phi)
        if warnings & 8:
            self.controller.reference.counts["fallbacks"] += 1
        if not warnings & 7:
            return
        status = SETPOINT_STATUSES[int(rows.integer[k, one_call.SETPOINT_STATUS])]
        y0 = y0_target = rows.y0[k]
        controller = self.controller
        if status == "target_outside_admissible" or (
            status == "unreachable_stale" and controller.setpoint_rate_limit is not None
        ):
            y0_target = self.requested.copy()
        stale = bool(rows.integer[k, one_call.STALE_REFERENCE])
        warn_diagnosis(controller, status, rows.saturated[k].astype(bool), y0, y0_target, stale)
        if warnings & 4 and controller.warnings.first("input_clipped"):
            warn_clipped(controller, rows.u_plan[k, 0], float(rows.real[k, one_call.INPUT_CLIPPED]))

    # ------------------------------------------------------------------ between samples
    def prepare(self, y0_phi: FloatArray | None) -> bool:
        """Run the stages before the feedback for the next step now
        (:func:`~ltv_lstm_mpc.loop.compiled_step.prepare_step`); False before the first
        step, without a set-point (None), or where the preparation did not pass the
        compiled step's tests (the next step runs as usual)."""
        self.discard_preparation()
        if not self.controller.initialized or y0_phi is None:
            return False
        y0_arr = np.array(y0_phi, dtype=np.float64)  # an owned, C-contiguous copy
        records = self.controller.records
        k = len(records)
        if k + 2 > records.capacity:
            records.reserve(k + 2)
        from_rows = self._rows_arguments(k)
        state = None
        if from_rows is not None:
            code, inverse_valid, factorizations = self._compiled(
                "prepare_step_from_rows", True,
                (self.workspace, records.compiled, k, y0_arr, from_rows.jinv_valid,
                 from_rows.e_hat, from_rows.rate_limit),
            )  # fmt: skip
        else:
            state = self._step_state()
            if state is None:
                return False
            code, inverse_valid, factorizations = self._compiled(
                "prepare_step", False,
                (self.workspace, records.compiled, k, y0_arr, *state.arguments()),
            )  # fmt: skip
        if code != one_call.STEP_DONE:
            self._restore_chord()
            return False
        self.prepared = Preparation(
            k, y0_arr.tolist(), from_rows, state, self.workspace, inverse_valid, factorizations
        )
        return True

    def discard_preparation(self) -> None:
        """Put a preparation aside (the chord as it was before)."""
        if self.prepared is not None:
            self.prepared = None
            self._restore_chord()

    def _restore_chord(self) -> None:
        """The reference calculator's inverse Jacobian as before the last preparation."""
        assert self.chord is not None
        np.copyto(self.chord.jinv, self.jinv_backup)

    def _step_prepared(self, y_phi: ArrayLike, y0_phi: ArrayLike) -> FloatArray | Handover | None:
        """:meth:`step` on the preparation: the physical input, or what
        :meth:`_step_one_call` returns for the reference engine, or None where the
        preparation does not apply (put aside)."""
        prepared = self.prepared
        assert prepared is not None
        self.prepared = None
        k = prepared.k
        y_arr, y0_arr = self._signals(y_phi, y0_phi)
        records = self.controller.records
        usable = k == len(records)
        if usable and prepared.from_rows is not None:
            usable = prepared.from_rows.same_as(self._rows_arguments(k))
        elif usable:
            state = self._step_state()
            usable = state is not None and state.same_as(prepared.state)
        # (after the state checks: they build a new workspace where a setting changed)
        if (
            not usable
            or self.workspace is not prepared.workspace
            or y0_arr.tolist() != prepared.y0_values
        ):
            self._restore_chord()
            return None
        if prepared.from_rows is not None:
            code, warnings, e_hat_next = self._compiled(
                "feedback_step_from_rows", True,
                (self.workspace, records.compiled, k, y_arr, prepared.from_rows.e_hat),
            )  # fmt: skip
        else:
            state = prepared.state
            assert state is not None
            code, warnings, e_hat_next = self._compiled(
                "feedback_step", False,
                (self.workspace, records.compiled, k, y_arr, state.x_hat, state.d_hat,
                 state.e_hat),
            )  # fmt: skip
        if code == one_call.STEP_GENERAL:
            self._restore_chord()
            return None
        return self._finish(
            k, code, warnings, prepared.inverse_valid, prepared.factorizations, e_hat_next,
            y0_arr, y_phi,
        )  # fmt: skip


def _vector(name: str, value: Any, buffer: FloatArray) -> FloatArray:
    ready = _ready_vector(value, buffer)
    if ready is not None:
        return ready
    checked = real_vector(name, value, buffer.shape[0])
    return checked if checked.flags.carray else np.array(checked)


def _ready_vector(value: Any, buffer: FloatArray) -> FloatArray | None:
    """``value`` as the step's signal without a check or a copy: a C-contiguous float64
    vector of the buffer's shape itself, a float (numpy float64 included, p = 1) in
    ``buffer``; None for anything else (:func:`_vector` checks it)."""
    if type(value) is np.ndarray:
        if value.dtype is _FLOAT64 and value.shape == buffer.shape and value.flags.carray:
            return value
    elif isinstance(value, float) and buffer.shape[0] == 1:  # float and numpy.float64
        buffer[0] = value
        return buffer
    return None
