r"""One campaign task: one closed loop of the one controller, a plain function of its settings.

:func:`run_task` builds the plant (with measurement noise and pH-plant parameter mismatch
when asked), the :class:`~ltv_lstm_mpc.OffsetFreeController`, runs
:func:`~ltv_lstm_mpc.simulate` and returns one row of the results table
(:data:`METRIC_COLUMNS`) and, for the traced subset, the per-step trace. It reads nothing
but its :class:`Task` and the model file and keeps no state between calls, so it runs the
same in this process or on any Dask worker. :func:`execute` is what the runners call: it
retries a raising task once and records the error instead of raising.

Metrics (physical units; the true plant output, not the noisy measurement):

* ``final_offset``: largest :math:`|y_k - y^0_k|` at the last sample of the constant
  segments (set-point and disturbance both constant); ``segment_offsets`` lists them.
* ``final_offset_mean``: largest :math:`|\mathrm{mean}(y_k - y^0_k)|` over the last
  ``offset_window`` samples of each constant segment (the setting; default
  :data:`DEFAULT_OFFSET_WINDOW`, at most the segment),
  recorded in ``offset_window``. Under measurement noise the loop moves the plant with
  the noise, so one sample of even the noise-free output scatters; the window mean is
  the offset the statements test (``offset`` outcome).
* ``violations``: samples of the true plant output outside the model's output
  constraint (the plant's ``y_phi_constraint``, else the model's stored one; the row's
  ``output_constraint``, JSON [low, high], and ``output_unit``, from the plant registry);
  ``max_violation`` and ``violation_sum`` their size.
* ``closed_loop_cost``: mean of :math:`\|y_k - y^0_k\|^2` over the run (requested set-point).
* ``infeasible_steps`` (nominal FHOCP not solved), ``fallback_steps`` and
  ``fallback_<policy>_steps``, ``d_hat_saturated_steps``, the set-point status counts,
  ``optimal_steps``, ``failed_steps``, ``solver_error_steps`` and every FHOCP status in
  ``status_counts`` (JSON).
* ``guarantee_held_steps`` (steps where Theorem 3's guarantee held,
  :mod:`ltv_lstm_mpc.loop.monitor`), ``violations_guarantee_held`` /
  ``violations_guarantee_voided`` (the violation samples split by it: Theorem 3
  excludes them where its hypotheses hold; the monitor sees those through the
  estimates) and ``infeasible_steps_guarantee_held``.
* ``median_step_s``, ``p95_step_s``, ``max_step_s``, ``median_mpc_s``: controller step
  times (``kernels``: ``"compiled"`` or ``"numpy"``, the kernels that ran: a worker with an
  empty numba cache runs numpy until the background compilation is done); ``setup_s``
  (model, certificates, controller) and ``wall_s`` (the whole task);
  ``transcription_used`` (what ``transcription = "auto"`` chose).
* ``started_at``, ``finished_at`` (Unix times) and ``worker`` (``host:pid``), set by
  :func:`execute`.
"""

from __future__ import annotations

import hashlib
import io
import itertools
import json
import os
import socket
import time
import traceback
import typing
import warnings
from collections import Counter
from collections.abc import Callable, Mapping
from dataclasses import dataclass, replace
from typing import Any

import numpy as np
from numpy.typing import NDArray

from ltv_lstm_mpc import __version__
from ltv_lstm_mpc.exceptions import LtvMpcError
from ltv_lstm_mpc.loop.schedules import equal_segments
from ltv_lstm_mpc.loop.statuses import MEASUREMENT_STATUSES, SETPOINT_STATUSES
from ltv_lstm_mpc.mpc.config import InfeasibilityPolicy
from ltv_lstm_mpc.plants.measurement import NoisyMeasurement

__all__ = [
    "DEFAULT_OFFSET_WINDOW",
    "METRIC_COLUMNS",
    "Task",
    "TaskFunction",
    "TaskOutcome",
    "execute",
    "load_task_model",
    "run_task",
    "setting_column",
    "task_key",
]

FloatArray = NDArray[np.float64]

_POLICIES: tuple[str, ...] = typing.get_args(InfeasibilityPolicy)

#: Default window (samples) of the measured offset: the mean of the noise-free plant
#: output's error over the last ``offset_window`` samples of each constant segment.
DEFAULT_OFFSET_WINDOW = 50

#: Metric columns of a row, in order (after the key and the settings).
METRIC_COLUMNS: tuple[str, ...] = (
    "status",
    "error",
    "attempts",
    "steps_done",
    "final_offset",
    "segment_offsets",
    "final_offset_mean",
    "violations",
    "max_violation",
    "violation_sum",
    "output_constraint",
    "output_unit",
    "closed_loop_cost",
    "infeasible_steps",
    "fallback_steps",
    *(f"fallback_{policy}_steps" for policy in _POLICIES),
    *(f"fallback_{policy}+shift_steps" for policy in _POLICIES if policy != "shift"),
    "truncated",
    "d_hat_saturated_steps",
    *(f"setpoint_{name}_steps" for name in SETPOINT_STATUSES),
    "input_clipped_steps",
    *(f"measurement_{name}_steps" for name in MEASUREMENT_STATUSES[1:]),
    "guarantee_held_steps",
    "violations_guarantee_held",
    "violations_guarantee_voided",
    "infeasible_steps_guarantee_held",
    "optimal_steps",
    "failed_steps",
    "solver_error_steps",
    "status_counts",
    "median_step_s",
    "p95_step_s",
    "max_step_s",
    "median_mpc_s",
    "transcription_used",
    "kernels",
    "warnings",
    "warning_messages",
    "setup_s",
    "wall_s",
    "started_at",
    "finished_at",
    "worker",
    "library_version",
    "model_sha256",
)


@dataclass(frozen=True)
class Task:
    """One closed loop of a campaign.

    Attributes
    ----------
    key : str
        Hash of the settings and the library version (:func:`task_key`): the name of its
        result file.
    settings : dict
        Every setting of the task (canonical values, see
        :data:`ltv_lstm_mpc.campaign.spec.SETTINGS`).
    model_location : str
        Absolute model path on the submitting machine, or the name of a shipped model.
    trace : bool
        Also return the per-step trace.
    model_sha256 : str
        SHA-256 of the model file (part of the key: a retrained model is a new task).
    model_bytes : bytes, optional
        The model file itself (for a path; None for a shipped model): workers of a remote
        cluster need no access to the submitting machine's files.
    """

    key: str
    settings: dict[str, Any]
    model_location: str
    trace: bool = False
    model_sha256: str = ""
    model_bytes: bytes | None = None


def load_task_model(task: Task) -> Any:
    """The task's :class:`~ltv_lstm_mpc.LSTMModel` (from its bytes when it has them)."""
    if task.model_bytes is None:
        from ltv_lstm_mpc.lstm.shipped import load_model

        return load_model(task.model_location)
    from ltv_lstm_mpc.lstm.model import LSTMModel

    with np.load(io.BytesIO(task.model_bytes), allow_pickle=False) as data:
        arrays = {name: data[name] for name in data.files}
    return LSTMModel.from_arrays(arrays)


@dataclass(frozen=True)
class TaskOutcome:
    """What a task returns: its row and, for the traced subset, its per-step trace."""

    row: dict[str, Any]
    trace: dict[str, list[Any]] | None = None


#: A task function: a task in, its outcome out (:func:`run_task` or a wrapper of it).
TaskFunction = Callable[[Task], TaskOutcome]


def task_key(
    settings: Mapping[str, Any], version: str = __version__, model_sha256: str = ""
) -> str:
    """Hash (20 hex digits) of the canonical settings, the library version and the model
    file's SHA-256 (so that a model retrained in place, or another file of the same name,
    makes new tasks)."""
    text = json.dumps(
        {"settings": dict(settings), "library_version": version, "model_sha256": model_sha256},
        sort_keys=True,
        separators=(",", ":"),
    )
    return hashlib.sha256(text.encode("utf-8")).hexdigest()[:20]


def setting_column(name: str, value: Any) -> Any:
    """A setting as a table cell: lists as JSON text, a mismatch as ``"W_a1*1.1"``."""
    if name == "mismatch":
        if not value:
            return "nominal"
        return ",".join(f"{k}*{v!r}" for k, v in sorted(value.items()))
    if isinstance(value, (list, dict)):
        return json.dumps(value)
    return value


@dataclass(frozen=True)
class _Loop:
    """Everything one closed loop needs, built from a task's settings."""

    plant: Any
    controller: Any
    setpoints: FloatArray
    disturbances: FloatArray | None
    segments: list[tuple[int, int]]
    facts: dict[str, Any]
    offset_window: int = 50


def _build_loop(task: Task, model: Any, steps_limit: int | None) -> _Loop:
    from ltv_lstm_mpc.loop.controller import OffsetFreeController
    from ltv_lstm_mpc.mpc.config import MPCConfig
    from ltv_lstm_mpc.plants.registry import resolve_plant

    s = task.settings
    if model.p != 1:
        raise LtvMpcError(
            f"campaigns run single-output models (this one has p = {model.p} outputs)"
        )
    overrides: dict[str, Any] = {
        "N": s["N"],
        "solver": s["solver"],
        "transcription": s["transcription"],
        "infeasibility_policy": s["policy"],
        "sqp_iterations": s["sqp_iterations"],
        "d_max": s["d_max"],
    }
    if "scenario" in s:
        from ltv_lstm_mpc.paper.scenarios import paper_scenarios

        (scenario,) = [
            sc for sc in paper_scenarios(model, short=s["short"]) if sc.name == s["scenario"]
        ]
        if "L_d" in s:
            overrides["L_d"] = s["L_d"]
        config = replace(scenario.config, **overrides)
        plant_kind, rate_limit = scenario.plant, scenario.setpoint_rate_limit
        setpoints = scenario.setpoints
        disturbances: FloatArray | None = scenario.disturbances
        segments = list(scenario.segments)
        y0_initial: float | None = scenario.y0_phi_initial
    else:
        config = MPCConfig(L_d=s["L_d"], **overrides)
        plant_kind = s["plant"]
        rate_limit = s["rate_limit"] if s["rate_limit"] > 0 else None
        steps = s["steps"]
        setpoints, sp_edges = equal_segments(s["setpoints"], steps)
        given = s.get("q2", s.get("disturbances"))
        disturbances, d_edges = (None, []) if given is None else equal_segments(given, steps)
        edges = sorted(set(sp_edges) | set(d_edges))
        segments = list(itertools.pairwise(edges))
        y0_initial = s.get("y0_initial")
    if steps_limit is not None:
        setpoints = setpoints[:steps_limit]
        disturbances = None if disturbances is None else disturbances[:steps_limit]
        segments = [(a, min(b, steps_limit)) for a, b in segments if a < steps_limit]
    entry = resolve_plant(plant_kind)
    options: dict[str, Any] = {}
    if "mismatch" in entry.options:
        options["mismatch"] = s["mismatch"]
    controller = OffsetFreeController(model, config, setpoint_rate_limit=rate_limit)
    if "y0_phi" in entry.options and y0_initial is None and model.p == 1:
        # as simulate: the middle of the controller's admissible set-point interval
        from ltv_lstm_mpc.paper.scenarios import initial_output

        y0_initial = initial_output(model, controller.certification)
    if "y0_phi" in entry.options and y0_initial is not None:
        options["y0_phi"] = y0_initial
    inner = entry.build(model, **options)
    facts = {
        "plant": plant_kind,
        "steps": int(setpoints.shape[0]),
        "L_d": config.L_d,
        "rate_limit": 0.0 if rate_limit is None else float(rate_limit),
    }
    return _Loop(
        plant=NoisyMeasurement(inner, s["noise_std"], s["seed"]),
        controller=controller,
        setpoints=setpoints,
        disturbances=disturbances,
        segments=segments,
        facts=facts,
        offset_window=int(s.get("offset_window", DEFAULT_OFFSET_WINDOW)),
    )


def _base_row(task: Task) -> dict[str, Any]:
    row: dict[str, Any] = {"key": task.key}
    for name, value in task.settings.items():
        row[name] = setting_column(name, value)
    row["model_sha256"] = task.model_sha256
    return row


def _metrics(loop: _Loop, sim: Any, model: Any) -> tuple[dict[str, Any], FloatArray]:
    from ltv_lstm_mpc.loop.simulation import output_constraint
    from ltv_lstm_mpc.plotting import signal_labels

    done = int(sim.y_phi.shape[0])
    y_true = sim.y_phi_true.reshape(done, -1)  # without the measurement noise
    y0 = np.asarray(sim.y0_phi, dtype=np.float64).reshape(done, -1)
    error = np.abs(y_true - y0).max(axis=1) if done else np.zeros(0)
    offsets = [float(error[end - 1]) for _, end in loop.segments if 0 < end <= done]
    window = int(loop.offset_window)
    signed = (y_true - y0) if done else np.zeros((0, 1))
    means = [
        float(np.max(np.abs(signed[max(start, end - window) : end].mean(axis=0))))
        for start, end in loop.segments
        if 0 < end <= done and end > start
    ]
    # the plant's output constraint, else the model's: the one sim.plant_violation measured
    constraint = output_constraint(loop.plant, model)
    violation = sim.plant_violation  # of the true plant output (simulate)
    statuses = Counter(str(v) for v in sim.status)
    counts = sim.summary_counts()
    times = np.asarray(sim.time_total, dtype=np.float64)
    row: dict[str, Any] = {
        "steps_done": done,
        "final_offset": max(offsets) if offsets else None,
        "segment_offsets": json.dumps(offsets),
        "final_offset_mean": max(means) if means else None,
        "offset_window": window,
        "violations": int(np.sum(violation > 1e-9)) if constraint is not None else None,
        "max_violation": float(np.max(violation, initial=0.0)) if constraint is not None else None,
        "violation_sum": float(np.sum(violation)) if constraint is not None else None,
        "output_constraint": None
        if constraint is None
        else json.dumps([constraint[0].tolist(), constraint[1].tolist()]),
        "output_unit": signal_labels(loop.facts["plant"], model).output_unit,
        "closed_loop_cost": float(np.mean(np.sum((y_true - y0) ** 2, axis=1))) if done else None,
        "infeasible_steps": int(np.sum(~sim.feasible)),
        "fallback_steps": int(np.sum(sim.policy != "nominal")),
        **{f"fallback_{p}_steps": int(np.sum(sim.policy == p)) for p in _POLICIES},
        # the policy itself failed and the shifted plan was applied (RobustMPC)
        **{
            f"fallback_{p}+shift_steps": int(np.sum(sim.policy == f"{p}+shift"))
            for p in _POLICIES
            if p != "shift"
        },
        "truncated": done < int(loop.setpoints.shape[0]),  # stopped by max_seconds
        "d_hat_saturated_steps": counts.get("d_hat_saturated_steps", 0),
        **{
            f"setpoint_{name}_steps": counts.get(f"setpoint_{name}_steps", 0)
            for name in SETPOINT_STATUSES
        },
        "input_clipped_steps": counts.get("input_clipped_steps", 0),
        **{
            f"measurement_{name}_steps": counts.get(f"measurement_{name}_steps", 0)
            for name in MEASUREMENT_STATUSES[1:]
        },
        # Theorem 3's monitor (loop/monitor.py): where the guarantee held, the theorem
        # excludes violations and infeasible steps
        "guarantee_held_steps": counts.get("guarantee_held_steps"),
        "violations_guarantee_held": counts.get("plant_violation_steps_guarantee_held"),
        "violations_guarantee_voided": counts.get("plant_violation_steps_guarantee_voided"),
        "infeasible_steps_guarantee_held": counts.get("infeasible_steps_guarantee_held"),
        "optimal_steps": sum(n for k, n in statuses.items() if k.startswith("optimal")),
        "failed_steps": statuses.get("failed", 0),
        "solver_error_steps": statuses.get("solver_error", 0),
        "status_counts": json.dumps(dict(sorted(statuses.items()))),
        "median_step_s": float(np.median(times)) if done else None,
        "p95_step_s": float(np.quantile(times, 0.95)) if done else None,
        "max_step_s": float(np.max(times)) if done else None,
        "median_mpc_s": float(np.median(sim.time_mpc)) if done else None,
        "transcription_used": sim.transcription,
        "kernels": loop.controller.kernels,
    }
    return row, violation


def _trace(loop: _Loop, sim: Any, model: Any, violation: FloatArray) -> dict[str, list[Any]]:
    done = int(sim.y_phi.shape[0])
    y_true = sim.y_phi_true.reshape(done, -1)
    y0_used = model.denormalize_y(np.asarray(sim.y0).reshape(done, -1)) if done else sim.y0
    columns: dict[str, Any] = {
        "k": np.arange(done),
        "y_phi": y_true[:, 0],
        "y_measured_phi": sim.y_phi[:, 0],
        "y0_phi": sim.y0_phi[:, 0],
        "y0_used_phi": np.asarray(y0_used).reshape(done, -1)[:, 0],
        "u_phi": sim.u_phi[:, 0],
        "d_phi": sim.d_phi[:, 0],
        "d_hat": sim.d_hat[:, 0],
        "violation": violation,
        "feasible": sim.feasible,
        "policy": sim.policy,
        "status": sim.status,
        "setpoint_status": sim.setpoint_status,
        "d_hat_saturated": sim.d_hat_saturated.any(axis=1),
        "guarantee": sim.guarantee if sim.guarantee is not None else np.full(done, ""),
        "time_total_s": sim.time_total,
        "time_mpc_s": sim.time_mpc,
    }
    return {name: np.asarray(values).tolist() for name, values in columns.items()}


def run_task(task: Task, *, steps_limit: int | None = None) -> TaskOutcome:
    """Run one closed loop and return its row (and trace when ``task.trace``).

    Parameters
    ----------
    task : Task
    steps_limit : int, optional
        Run at most this many samples (the dry-run's calibration).

    Raises
    ------
    Exception
        Whatever the closed loop raises (:func:`execute` records it).
    """
    from ltv_lstm_mpc.loop.simulation import simulate

    start = time.perf_counter()
    model = load_task_model(task)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        loop = _build_loop(task, model, steps_limit)
        setup = time.perf_counter() - start
        sim = simulate(
            loop.plant,
            loop.controller,
            loop.setpoints,
            loop.disturbances,
            int(loop.setpoints.shape[0]),
            progress=False,
            max_seconds=task.settings.get("max_seconds"),
        )
    metrics, violation = _metrics(loop, sim, model)
    messages = list(dict.fromkeys(str(w.message) for w in caught))
    row = _base_row(task)
    row.update(loop.facts)  # plant, steps, L_d, rate_limit actually used
    row.update(
        {
            "status": "ok",
            "error": "",
            "attempts": 1,
            **metrics,
            "warnings": len(caught),
            "warning_messages": " | ".join(m[:200] for m in messages[:3]),
            "setup_s": setup,
            "wall_s": time.perf_counter() - start,
            "library_version": __version__,
        }
    )
    trace = _trace(loop, sim, model, violation) if task.trace else None
    return TaskOutcome(row=row, trace=trace)


def error_outcome(
    task: Task, error: str, *, attempts: int, wall_s: float, status: str = "error"
) -> TaskOutcome:
    """The row of a task that failed: its settings, ``status`` (``"error"``: the task
    raised; ``"lost"``: the cluster lost it, e.g. its workers kept dying) and the error."""
    row = _base_row(task)
    row.update(
        {
            "status": status,
            "error": error,
            "attempts": attempts,
            "wall_s": wall_s,
            "library_version": __version__,
        }
    )
    return TaskOutcome(row=row)


def _describe(error: BaseException) -> str:
    frames = traceback.extract_tb(error.__traceback__)
    where = f" (at {os.path.basename(frames[-1].filename)}:{frames[-1].lineno})" if frames else ""
    return f"{type(error).__name__}: {error}{where}"


def execute(task: Task, function: TaskFunction = run_task, attempts: int = 2) -> TaskOutcome:
    """Run ``function(task)``, retrying once; a task that still raises becomes an error row.

    Parameters
    ----------
    task : Task
    function : callable
        The task function (default :func:`run_task`).
    attempts : int
        Tries before the error is recorded (2: retried once).

    Returns
    -------
    TaskOutcome
        The function's outcome, or the error row; ``attempts``, ``started_at`` and
        ``finished_at`` (Unix times, s) and ``worker`` (``host:pid``) set.
    """
    start, started_at = time.perf_counter(), time.time()
    message = ""
    outcome = None
    for attempt in range(1, attempts + 1):
        try:
            outcome = function(task)
        except Exception as error:
            message = _describe(error)
            continue
        outcome.row["attempts"] = attempt
        break
    if outcome is None:
        outcome = error_outcome(
            task, message, attempts=attempts, wall_s=time.perf_counter() - start
        )
    outcome.row.update(
        started_at=started_at,
        finished_at=time.time(),
        worker=f"{socket.gethostname()}:{os.getpid()}",
    )
    return outcome
