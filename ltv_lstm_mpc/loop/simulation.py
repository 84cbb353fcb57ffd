"""Closed-loop simulation: plant -> controller -> plant, with a record of everything."""

from __future__ import annotations

import contextlib
import gc
import time
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray
from tqdm.auto import tqdm

from ltv_lstm_mpc.exceptions import DimensionError, InvalidValueError
from ltv_lstm_mpc.loop.controller import OffsetFreeController
from ltv_lstm_mpc.loop.monitor import HYPOTHESES
from ltv_lstm_mpc.loop.statuses import MEASUREMENT_STATUSES, SETPOINT_STATUSES
from ltv_lstm_mpc.plants.protocol import Plant
from ltv_lstm_mpc.plants.protocol import check_sampling_time as sampling_time_contract
from ltv_lstm_mpc.validation import (
    expect_bool,
    expect_instance,
    expect_int,
    expect_methods,
    expect_real,
    real_vector,
)

__all__ = [
    "SimulationResult",
    "garbage_collection_paused",
    "output_constraint",
    "simulate",
    "single_threaded_blas",
]

FloatArray = NDArray[np.float64]


@dataclass(frozen=True)
class SimulationResult:
    r"""Arrays of one closed-loop run (index k = sample k; physical units where ``_phi``).

    Attributes
    ----------
    y_phi : (steps, p)
        Measured plant output at sample k (before u_k is applied).
    u_phi : (steps, m)
        Applied input.
    y0_phi : (steps, p)
        Requested set-point; ``y0`` is the normalized set-point used (rate-limited).
    d_phi : (steps, q)
        Disturbance applied to the plant during step k (NaN where the plant default
        was used).
    d_hat : (steps, p)
        Disturbance estimate (normalized).
    x_hat : (steps, 2n)
        State estimate.
    e_hat, alpha : (steps,)
        Observer-error bound and terminal level.
    feasible : (steps,) bool
        Nominal FHOCP solved.
    policy : (steps,) str
        Policy used (``"nominal"`` or the fallback).
    status : (steps,) str
        FHOCP status.
    output_violation : (steps,)
        Nonlinear violation of the tightened output rows by the applied plan (>= 0).
    time_observer, time_reference, time_mpc, time_total : (steps,)
        Per-step wall times, s.
    time_prepare, time_feedback : (steps,)
        The MPC's two RTI phases (``time_mpc`` is about their sum), s.
    transcription : str
        The MPC's transcription (``"condensed"``, ``"sparse"``, ``"nonlinear"``).
    setpoint_status : (steps,) str
        One of :data:`~ltv_lstm_mpc.loop.statuses.SETPOINT_STATUSES`
        (see :class:`~ltv_lstm_mpc.ControllerStep`).
    d_hat_saturated : (steps, p) bool
        :math:`|\hat d_k| = d_{max}` per output.
    plant_violation : (steps,)
        Violation (>= 0, physical units) of the output constraint of
        :func:`output_constraint` (the plant's ``y_phi_constraint``, else the model's
        stored one) by the true plant output ``y_phi_true``; NaN when neither states one.
        Unlike ``output_violation`` (the plan on the model) this is the true plant.
    y_phi_true : (steps, p)
        True plant output at sample k: ``y_phi`` without the measurement noise of a
        :class:`~ltv_lstm_mpc.plants.measurement.NoisyMeasurement` (equal to ``y_phi``
        for a plant measured exactly).
    input_clipped : (steps,)
        How far the controller's exit gate moved the MPC's input into U (normalized
        inf-norm; 0 inside, inf where a non-finite input was replaced).
    measurement_status : (steps,) str
        ``"ok"``, ``"outside_training_range"`` or ``"implausible"`` (see
        :class:`~ltv_lstm_mpc.ControllerStep`).
    warning_counts : dict of str to int
        The controller's :attr:`~ltv_lstm_mpc.OffsetFreeController.warning_counts`
        for this run: steps on which each warned condition held (each warning is shown once
        per run).
    guarantee : (steps,) str
        Theorem 3's guarantee per step: ``"held"`` or ``"voided by ..."``
        (:mod:`ltv_lstm_mpc.loop.monitor`).
    hypotheses : dict of str to (steps,) bool
        Each monitored hypothesis per step (names: :data:`~ltv_lstm_mpc.loop.monitor.HYPOTHESES`).
    """

    y_phi: FloatArray
    u_phi: FloatArray
    y0_phi: FloatArray
    y0: FloatArray
    d_phi: FloatArray
    d_hat: FloatArray
    x_hat: FloatArray
    e_hat: FloatArray
    alpha: FloatArray
    feasible: NDArray[np.bool_]
    policy: NDArray[np.str_]
    status: NDArray[np.str_]
    output_violation: FloatArray
    time_observer: FloatArray
    time_reference: FloatArray
    time_mpc: FloatArray
    time_total: FloatArray
    time_prepare: FloatArray
    time_feedback: FloatArray
    transcription: str = ""
    setpoint_status: NDArray[np.str_] | None = None
    d_hat_saturated: NDArray[np.bool_] | None = None
    plant_violation: FloatArray | None = None
    y_phi_true: FloatArray | None = None
    input_clipped: FloatArray | None = None
    measurement_status: NDArray[np.str_] | None = None
    warning_counts: dict[str, int] | None = None
    guarantee: NDArray[np.str_] | None = None
    hypotheses: dict[str, NDArray[np.bool_]] | None = None

    @property
    def guarantee_held(self) -> NDArray[np.bool_]:
        """Per step: whether Theorem 3's guarantee held (all False without a monitor)."""
        if self.guarantee is None:
            return np.zeros(len(self.feasible), dtype=bool)
        return np.asarray(self.guarantee == "held", dtype=bool)

    def summary_counts(self) -> dict[str, int]:
        """Steps per set-point status, d_hat-saturated steps, infeasible steps, steps with
        the input clipped, steps per measurement status; with the monitor, steps where
        Theorem 3's guarantee held, steps where each hypothesis failed, and the infeasible
        and plant-violation steps split by whether the guarantee held (the theorem
        excludes them where it held)."""
        counts: dict[str, int] = {}
        if self.setpoint_status is not None:
            for name in SETPOINT_STATUSES:
                counts[f"setpoint_{name}_steps"] = int(np.sum(self.setpoint_status == name))
        if self.d_hat_saturated is not None:
            counts["d_hat_saturated_steps"] = int(np.sum(self.d_hat_saturated.any(axis=1)))
        counts["infeasible_steps"] = int(np.sum(~self.feasible))
        if self.plant_violation is not None and not np.all(np.isnan(self.plant_violation)):
            counts["plant_violation_steps"] = int(np.sum(self.plant_violation > 1e-9))
        if self.input_clipped is not None:
            counts["input_clipped_steps"] = int(np.sum(self.input_clipped > 0.0))
        if self.measurement_status is not None:
            for name in MEASUREMENT_STATUSES[1:]:
                counts[f"measurement_{name}_steps"] = int(np.sum(self.measurement_status == name))
        if self.guarantee is not None:
            held = self.guarantee_held
            counts["guarantee_held_steps"] = int(np.sum(held))
            for name, flags in (self.hypotheses or {}).items():
                counts[f"{name}_failed_steps"] = int(np.sum(~flags))
            counts["infeasible_steps_guarantee_held"] = int(np.sum(~self.feasible & held))
            if "plant_violation_steps" in counts:
                assert self.plant_violation is not None
                violated = self.plant_violation > 1e-9
                counts["plant_violation_steps_guarantee_held"] = int(np.sum(violated & held))
                counts["plant_violation_steps_guarantee_voided"] = int(np.sum(violated & ~held))
        return counts


@contextlib.contextmanager
def single_threaded_blas(threads: int | None = 1) -> Iterator[None]:
    """Limit the BLAS to ``threads`` threads inside the block (threadpoolctl).

    The controller step hands only small matrices to the BLAS; a multi-threaded BLAS then
    adds scheduling latency and makes the step's tail depend on the load of the other
    cores. Wrap a control loop in it (``simulate`` does). ``None``: no change.
    """
    if threads is None:
        yield
        return
    from threadpoolctl import threadpool_limits

    with threadpool_limits(limits=int(threads), user_api="blas"):
        yield


@contextlib.contextmanager
def garbage_collection_paused(pause: bool = True) -> Iterator[None]:
    """Python's cyclic garbage collector off inside the block, as it was after it.

    The collector runs when allocations pile up, at whatever step that happens, and a
    collection of the older generations walks every object the loop has recorded: single
    steps of 3-6 ms in a loop whose steps take 0.1 ms (measured by
    ``experiments/gc_jitter.py``). A controller step creates no reference cycles (a
    4200-step loop leaves 12 unreachable objects), so memory stays bounded without the
    collector; reference counting still frees everything at once. Wrap a control loop in
    it (``simulate`` does); ``pause=False``: no change.
    """
    if not pause or not gc.isenabled():
        yield
        return
    gc.disable()
    try:
        yield
    finally:
        gc.enable()


def _as_schedule(
    name: str,
    value: ArrayLike | Callable[[int], ArrayLike] | None,
    steps: int,
    width: int | None,
) -> list[FloatArray | None]:
    """Per-step vectors of a schedule: None, a callable, a constant, or one row per step.

    A scalar, or a vector of shape ``(width,)``, is a constant; an array of shape
    ``(steps', width)`` (or ``(steps',)`` when ``width == 1``) with ``steps' >= steps`` is a
    time series. ``width=None`` (a plant whose disturbance size is unknown) accepts a
    scalar, a 1-D series or a 2-D series.
    """
    if value is None:
        return [None] * steps
    if callable(value):
        values = [value(k) for k in range(steps)]
        return [
            real_vector(f"{name}({k})", v, width if width is not None else np.size(v))
            for k, v in enumerate(values)
        ]
    if isinstance(value, (bool, str, bytes)):
        real_vector(name, value, 1)  # raises with the standard message
    array = np.asarray(value)
    if array.ndim == 0 or (width is not None and width > 1 and array.shape == (width,)):
        constant = real_vector(name, array.reshape(-1), array.size)
        if width is not None and constant.shape != (width,):
            raise DimensionError(f"{name} has {constant.size} entries, expected {width}")
        return [constant] * steps
    if array.ndim == 1:
        if width is not None and width != 1:
            raise DimensionError(
                f"{name} has shape {array.shape}: give one row of {width} entries per step, "
                f"shape (steps, {width}), or one constant vector of shape ({width},)"
            )
        rows = array.reshape(-1, 1)
    elif array.ndim == 2 and (width is None or array.shape[1] == width):
        rows = array
    else:
        expected = f"(steps, {width})" if width is not None else "(steps, width)"
        raise DimensionError(f"{name} has shape {array.shape}, expected {expected}")
    if rows.shape[0] < steps:
        raise DimensionError(f"{name} has {rows.shape[0]} samples, need at least steps={steps}")
    checked = real_vector(name, rows[:steps].reshape(-1), steps * rows.shape[1])
    series = checked.reshape(steps, rows.shape[1])
    return [series[k] for k in range(steps)]


def output_constraint(plant: Any, model: Any) -> tuple[FloatArray, FloatArray] | None:
    """The output constraint (low, high) the plant's output is judged against, physical units.

    The plant's own ``y_phi_constraint`` where it states one (a user plant class, see
    :mod:`ltv_lstm_mpc.plants.registry`), else the model's stored constraint
    (``y_phi_constraint_min/max`` of its file); None when neither states one. Every
    violation the library reports (``plant_violation`` here, the summaries of ``simulate``,
    ``reproduce`` and campaigns) is measured against this one pair.

    Parameters
    ----------
    plant : Plant
        The plant (a wrapper such as :class:`~ltv_lstm_mpc.plants.measurement.NoisyMeasurement`
        forwards the attribute).
    model : LSTMModel
        The controller's model.

    Returns
    -------
    (low, high) of shape (p,), or None
    """
    p = int(model.p)
    stated = getattr(plant, "y_phi_constraint", None)
    if stated is None:
        stated = model.y_phi_constraint
    if stated is None:
        return None
    try:
        low, high = (np.broadcast_to(np.asarray(v, dtype=np.float64), (p,)).copy() for v in stated)
    except (TypeError, ValueError):
        raise InvalidValueError(
            f"the plant's y_phi_constraint must be (low, high) with one value or {p} values "
            f"each (physical output units), got {stated!r}"
        ) from None
    if not (np.all(np.isfinite(low)) and np.all(np.isfinite(high)) and np.all(low < high)):
        raise InvalidValueError(
            f"the output constraint must be finite with low < high on every output, got "
            f"low {low.tolist()}, high {high.tolist()} (the plant's y_phi_constraint or the "
            "model's y_phi_constraint_min/max)"
        )
    return low, high


def simulate(
    plant: Plant,
    controller: OffsetFreeController,
    setpoints: ArrayLike | Callable[[int], ArrayLike],
    disturbances: ArrayLike | Callable[[int], ArrayLike] | None = None,
    steps: int | None = None,
    *,
    progress: bool = True,
    description: str = "closed loop",
    max_seconds: float | None = None,
    blas_threads: int | None = 1,
    check_sampling_time: bool = True,
    pause_garbage_collection: bool = True,
    prepare_between_samples: bool = False,
) -> SimulationResult:
    """Run plant and controller in closed loop.

    Parameters
    ----------
    plant : Plant
        Anything with ``output()`` and ``step(u_phi, d_phi)`` (pH plant, LSTM plant).
        It is used as it is (call ``plant.reset()`` first if needed).
    controller : OffsetFreeController
        Reset before the run.
    setpoints : array (steps, p) or (steps,), scalar, or callable k -> y0_phi
        Physical set-point per sample.
    disturbances : array, scalar, callable or None
        Physical disturbance passed to ``plant.step`` at each sample (None: the plant's
        default).
    steps : int, optional
        Number of samples (default: the length of ``setpoints``).
    progress : bool
        Show a tqdm progress bar.
    max_seconds : float, optional
        Stop after this wall time (the result then has fewer samples than ``steps``).
    blas_threads : int or None
        BLAS threads during the loop (default 1, see :func:`single_threaded_blas`;
        None leaves the BLAS as it is).
    check_sampling_time : bool
        Refuse a plant whose ``Ts`` differs from the model's
        (:class:`~ltv_lstm_mpc.SamplingTimeError`; a model without ``Ts`` warns,
        a plant without ``Ts`` is not checked). ``False``: the model's Ts is unknown or
        knowingly ignored.
    pause_garbage_collection : bool
        Python's cyclic garbage collector off during the loop (default; see
        :func:`garbage_collection_paused`): no collection pauses between steps.
    prepare_between_samples : bool
        After each sample, prepare the next step with the schedule's next set-point
        (:meth:`~ltv_lstm_mpc.OffsetFreeController.prepare_next`), as a real-time loop does
        while the plant evolves: each step then runs only its feedback and observer update.
        Same numbers either way (tested bit for bit); the records' times split accordingly.
    """
    _check_arguments(plant, controller, progress, description, max_seconds, blas_threads)
    expect_bool("pause_garbage_collection", pause_garbage_collection)
    expect_bool("prepare_between_samples", prepare_between_samples)
    if check_sampling_time:
        plant_Ts = getattr(plant, "Ts", None)
        sampling_time_contract(
            controller.model.Ts,
            None if plant_Ts is None else float(plant_Ts),
            type(plant).__name__,
        )
    p = controller.model.p
    if steps is None:
        if callable(setpoints) or (
            np.ndim(setpoints) == 0 or (p > 1 and np.shape(setpoints) == (p,))
        ):
            raise DimensionError(
                "steps is required when setpoints is a constant (scalar or (p,) vector) or a "
                "callable"
            )
        steps = int(np.shape(setpoints)[0])
    if isinstance(steps, bool) or int(steps) != steps or steps <= 0:
        raise InvalidValueError(f"steps must be a positive integer, got {steps!r}")
    steps = int(steps)
    y0_schedule = _as_schedule("setpoints", setpoints, steps, p)
    d_schedule = _as_schedule(
        "disturbances", disturbances, steps, getattr(plant, "disturbance_size", None)
    )
    controller.reset()
    reserve = getattr(getattr(controller, "records", None), "reserve", None)
    if reserve is not None:  # the one-call step's record rows, allocated before the loop
        reserve(steps + 1)
    y_phi = np.atleast_1d(np.asarray(plant.output(), dtype=np.float64))
    true_output = getattr(plant, "true_output", None)  # noisy measurements: the truth
    ys, ys_true, us, y0s, ds = [], [], [], [], []
    start = time.perf_counter()
    # The step's small matrix products on one BLAS thread: a threaded BLAS makes their
    # tail latency depend on whatever else runs on the machine; no collector pauses.
    with (
        single_threaded_blas(blas_threads),
        garbage_collection_paused(pause_garbage_collection),
    ):
        for k in tqdm(range(steps), disable=not progress, desc=description, leave=False):
            u_phi = controller.step(y_phi, y0_schedule[k])
            ys.append(y_phi)
            ys_true.append(y_phi if true_output is None else true_output())
            us.append(u_phi)
            y0s.append(y0_schedule[k])
            d = d_schedule[k]
            ds.append(np.full(1, np.nan) if d is None else d)
            y_phi = np.atleast_1d(np.asarray(plant.step(u_phi, d), dtype=np.float64))
            if prepare_between_samples and k + 1 < steps:
                controller.prepare_next(y0_schedule[k + 1])
            if max_seconds is not None and time.perf_counter() - start > max_seconds:
                break
    records = controller.records
    y_array = np.array(ys_true)
    constraint = output_constraint(plant, controller.model)
    if constraint is None or not len(ys):
        plant_violation = np.full(len(ys), np.nan)
    else:
        low, high = constraint
        plant_violation = np.maximum(np.maximum(low - y_array, y_array - high).max(axis=1), 0.0)
    return SimulationResult(
        y_phi=np.array(ys),
        u_phi=np.array(us),
        y0_phi=np.array(y0s),
        y0=np.array([r.y0 for r in records]),
        d_phi=np.array(ds),
        d_hat=np.array([r.d_hat for r in records]),
        x_hat=np.array([r.x_hat for r in records]),
        e_hat=np.array([r.e_hat for r in records]),
        alpha=np.array([r.mpc.alpha for r in records]),
        feasible=np.array([r.mpc.feasible for r in records]),
        policy=np.array([r.mpc.policy for r in records]),
        status=np.array([r.mpc.status for r in records]),
        output_violation=np.array([r.mpc.residuals["output_violation"] for r in records]),
        time_observer=np.array([r.time_observer for r in records]),
        time_reference=np.array([r.time_reference for r in records]),
        time_mpc=np.array([r.time_mpc for r in records]),
        time_total=np.array([r.time_total for r in records]),
        time_prepare=np.array([r.mpc.prepare_time for r in records]),
        time_feedback=np.array([r.mpc.feedback_time for r in records]),
        transcription=records[0].mpc.transcription if records else "",
        setpoint_status=np.array([r.setpoint_status for r in records]),
        d_hat_saturated=np.array(
            [
                np.zeros(controller.model.p, dtype=bool)
                if r.d_hat_saturated is None
                else r.d_hat_saturated
                for r in records
            ],
            dtype=bool,
        ).reshape(len(records), controller.model.p),
        plant_violation=plant_violation,
        y_phi_true=y_array,
        input_clipped=np.array([r.input_clipped for r in records], dtype=np.float64),
        measurement_status=np.array([r.measurement_status for r in records], dtype=str),
        warning_counts=controller.warning_counts,
        **_monitor_arrays(records),
    )


def _monitor_arrays(records: Sequence[Any]) -> dict[str, Any]:
    """``guarantee`` and ``hypotheses`` of :class:`SimulationResult` from the records
    (None where the steps carry no monitor verdict)."""
    checks = [r.assumptions for r in records]
    if not checks or any(c is None for c in checks):
        return {"guarantee": None, "hypotheses": None}
    return {
        "guarantee": np.array([c.guarantee for c in checks], dtype=str),
        "hypotheses": {
            name: np.array([getattr(c, name) for c in checks], dtype=bool) for name in HYPOTHESES
        },
    }


def _check_arguments(
    plant: object,
    controller: object,
    progress: object,
    description: object,
    max_seconds: object,
    blas_threads: object,
) -> None:
    """The types and ranges of :func:`simulate`'s arguments (signals are checked per step)."""
    expect_methods("plant", plant, ("output", "step"), "a plant", "e.g. PHNeutralizationPlant()")
    expect_instance(
        "controller",
        controller,
        OffsetFreeController,
        "build one with OffsetFreeController(model, MPCConfig(...))",
        expected="an OffsetFreeController",
    )
    expect_bool("progress", progress)
    expect_instance("description", description, str, expected="a string")
    if max_seconds is not None:
        expect_real("max_seconds", max_seconds, low=0.0, low_open=True, hint="or None: no limit")
    if blas_threads is not None:
        expect_int("blas_threads", blas_threads, minimum=1, hint="or None: leave the BLAS as it is")
