"""Run a campaign: in this process, or on Dask (a LocalCluster or an existing scheduler).

Both runners hand the same picklable tasks to the same function
(:func:`ltv_lstm_mpc.campaign.task.execute`) and write each outcome the moment it comes
back (:class:`~ltv_lstm_mpc.campaign.store.ResultStore`); only where the tasks run differs.
On Dask every task is one future: a worker that dies mid-task has its task rescheduled
by the scheduler (up to ``distributed.scheduler.allowed-failures`` times, then the task is
recorded as an error), and everything already finished is on disk. The client writes
the files, so remote workers need no access to the output folder.

Ctrl-C stops a run quietly: the worker processes of the LocalCluster never see the
interrupt (it is blocked in the threads that start them, so only this process gets it);
:func:`run_campaign` closes the cluster and raises :class:`CampaignInterrupted`, which
says how many tasks are stored and how to resume.
"""

from __future__ import annotations

import contextlib
import logging
import math
import multiprocessing
import os
import signal
import threading
import time
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

from tqdm.auto import tqdm

from ltv_lstm_mpc import __version__
from ltv_lstm_mpc.campaign.spec import CampaignSpec
from ltv_lstm_mpc.campaign.store import ResultStore, ordered_columns
from ltv_lstm_mpc.campaign.task import (
    Task,
    TaskFunction,
    TaskOutcome,
    error_outcome,
    execute,
    run_task,
)
from ltv_lstm_mpc.exceptions import LtvMpcError

__all__ = [
    "CampaignError",
    "CampaignInterrupted",
    "CampaignRun",
    "Estimate",
    "dask_client",
    "estimate_campaign",
    "pending_tasks",
    "run_campaign",
]

INSTALL_HINT = "install the extra: python -m pip install 'ltv_lstm_mpc[campaign]'"
#: Why a LocalCluster started from a script's top level fails, and the fix.
MAIN_GUARD_HINT = (
    "the LocalCluster's worker processes start a fresh Python that imports your script "
    'again, so a script must call run_campaign under `if __name__ == "__main__":` '
    "(or run serial=True, or on a scheduler=...)"
)


class CampaignError(LtvMpcError, RuntimeError):
    """A campaign cannot run (Dask missing, workers on another library version, ...)."""


class CampaignInterrupted(KeyboardInterrupt):
    """A campaign stopped by Ctrl-C; everything finished before it is stored.

    A :class:`KeyboardInterrupt` (so ``except Exception`` does not swallow it). Running the
    same spec into the same folder resumes: the stored tasks are skipped.

    Attributes
    ----------
    stored, total : int
        Tasks stored in the output folder (the ones a resume skips); tasks of the spec.
    out : Path
        The output folder.
    """

    def __init__(self, stored: int, total: int, out: Path) -> None:
        super().__init__(
            f"interrupted; {stored} of {total} tasks stored in {out}; run the same spec "
            "into the same folder to resume"
        )
        self.stored, self.total, self.out = stored, total, out


@contextlib.contextmanager
def _interrupt_only_this_thread() -> Iterator[None]:
    """Block SIGINT in the threads (and so the processes) started inside the block.

    Ctrl-C in a terminal sends SIGINT to every process of the foreground group, the Dask
    worker processes included, each of which would print its own KeyboardInterrupt
    traceback. A thread inherits the signal mask of the thread that starts it, and a
    process that of the thread that spawns it, so with SIGINT blocked here while the
    cluster starts, its threads (which later restart dead workers too) and its worker
    processes never receive it. This thread unblocks it at the end: a Ctrl-C during the
    start is delivered then, not lost. A Python handler of SIGTERM (the command line's,
    which stops a campaign as Ctrl-C does) is deferred the same way: a SIGTERM during the
    start runs it at the end, once the cluster can be closed whole (SIGTERM itself is not
    blocked: the worker processes would inherit the mask, and their nannies stop them
    with SIGTERM). No-op where threads cannot mask signals.
    """
    if not hasattr(signal, "pthread_sigmask") or (
        threading.current_thread() is not threading.main_thread()
    ):
        yield
        return
    # multiprocessing starts its resource tracker on first use, blocking and then
    # *unblocking* SIGINT in the calling thread: start it now, before the mask is set
    from multiprocessing import resource_tracker

    resource_tracker.ensure_running()
    terminate = signal.getsignal(signal.SIGTERM)
    deferred: list[int] = []
    if callable(terminate):
        signal.signal(signal.SIGTERM, lambda signum, frame: deferred.append(signum))
    previous = signal.pthread_sigmask(signal.SIG_BLOCK, {signal.SIGINT})
    try:
        yield
    finally:
        signal.pthread_sigmask(signal.SIG_SETMASK, previous)
        if callable(terminate):
            signal.signal(signal.SIGTERM, terminate)
    if deferred and callable(terminate):
        terminate(signal.SIGTERM, None)


@dataclass(frozen=True)
class CampaignRun:
    """The outcome of :func:`run_campaign`.

    Attributes
    ----------
    rows : list of dict
        One row per task of the spec, in task order (stored and new), every row with
        every column (None where a failed task has no value).
    executed, skipped : int
        Tasks run by this call; tasks found finished in the output folder.
    errors : int
        Rows with ``status`` ``"error"`` (the task raised) or ``"lost"`` (the cluster lost
        it; run again by the next call).
    wall_s : float
        Wall time of this call, s.
    files : list of Path
        Results (Parquet, CSV) and report files written.
    """

    rows: list[dict[str, Any]]
    executed: int
    skipped: int
    errors: int
    wall_s: float
    files: list[Path] = field(default_factory=list)


def pending_tasks(
    spec: CampaignSpec, store: ResultStore, *, retry_errors: bool = False
) -> tuple[list[Task], dict[str, dict[str, Any]]]:
    """Tasks still to run and the rows already stored (``retry_errors``: rerun error rows)."""
    finished = store.finished(task.key for task in spec.tasks)
    # "lost" (the cluster lost the task, not the task's own error) always runs again
    finished = {k: row for k, row in finished.items() if row.get("status") != "lost"}
    if retry_errors:
        finished = {k: row for k, row in finished.items() if row.get("status") != "error"}
    return [task for task in spec.tasks if task.key not in finished], finished


@contextlib.contextmanager
def dask_client(scheduler: str | None = None, workers: int | None = None) -> Iterator[Any]:
    """A ``distributed.Client``: to ``scheduler``, or to a new LocalCluster (closed after).

    The LocalCluster has ``workers`` worker processes (default: one per core) with one
    thread each (a closed loop is single-threaded; its BLAS runs on one thread).
    """
    try:
        from distributed import Client, LocalCluster
    except ImportError:
        raise CampaignError(f"running on Dask needs dask[distributed]: {INSTALL_HINT}") from None
    if scheduler is not None:
        client = Client(scheduler)
        try:
            _check_worker_versions(client)
            yield client
        finally:
            client.close()
        return
    if getattr(multiprocessing.current_process(), "_inheriting", False):
        # a new worker process importing its parent's script (multiprocessing's own test)
        raise CampaignError(
            f"run_campaign was called while a worker process imported the script: {MAIN_GUARD_HINT}"
        )
    count = workers if workers is not None else (os.cpu_count() or 1)
    with contextlib.ExitStack() as stack:
        # the cluster's threads and worker processes never see Ctrl-C (this thread does)
        with _interrupt_only_this_thread():
            try:
                cluster = stack.enter_context(
                    LocalCluster(
                        n_workers=count,
                        threads_per_worker=1,
                        processes=True,
                        dashboard_address=":0",  # a free port: several clusters at once
                        silence_logs=logging.ERROR,
                    )
                )
            except RuntimeError as error:  # "Nanny failed to start": a worker process died
                raise CampaignError(
                    f"the LocalCluster's worker processes did not start ({error}); a likely "
                    f"cause: {MAIN_GUARD_HINT}"
                ) from error
            client = stack.enter_context(Client(cluster))
        yield client


def _library_version() -> str:
    import ltv_lstm_mpc

    return ltv_lstm_mpc.__version__


def _check_worker_versions(client: Any) -> None:
    versions = client.run(_library_version)
    other = {worker: v for worker, v in versions.items() if v != __version__}
    if other:
        raise CampaignError(
            f"workers run another ltv_lstm_mpc version than this client ({__version__}): "
            f"{other}; task keys include the version, install the same one everywhere"
        )


def _run_serial(tasks: Sequence[Task], function: TaskFunction) -> Iterator[TaskOutcome]:
    for task in tasks:
        yield execute(task, function)


def _execute_on_worker(task: Task, function: TaskFunction) -> TaskOutcome:
    """:func:`execute` on a Dask worker, whose tqdm bars (the closed loop's, disabled) take
    a thread lock instead of a multiprocessing one: a worker killed mid-task (the cluster
    closed on Ctrl-C) then leaves no semaphore for the resource tracker to warn about."""
    import threading

    from tqdm.auto import tqdm as auto_tqdm

    if not isinstance(getattr(auto_tqdm, "_lock", None), type(threading.RLock())):
        auto_tqdm.set_lock(threading.RLock())
    return execute(task, function)


def _run_dask(client: Any, tasks: Sequence[Task], function: TaskFunction) -> Iterator[TaskOutcome]:
    from distributed import as_completed

    futures = {
        client.submit(
            _execute_on_worker, task, function, key=f"ltv-campaign-{task.key}", pure=False
        ): task
        for task in tasks
    }
    for future in as_completed(futures):
        task = futures[future]
        try:
            outcome = future.result()
        except Exception as error:  # KilledWorker (died too often), cancelled, ...
            outcome = error_outcome(
                task, f"{type(error).__name__}: {error}", attempts=0, wall_s=math.nan, status="lost"
            )
        future.release()
        yield outcome


def run_campaign(
    spec: CampaignSpec,
    out: str | Path,
    *,
    scheduler: str | None = None,
    workers: int | None = None,
    serial: bool = False,
    retry_errors: bool = False,
    progress: bool = True,
    report: bool = True,
    task_function: TaskFunction = run_task,
    log: Callable[[str], None] | None = None,
    beta: float = 0.05,
    offset_tolerance: float | None = None,
) -> CampaignRun:
    """Run every unfinished task of ``spec``, store each at once, then the tables and report.

    Parameters
    ----------
    spec : CampaignSpec
    out : path
        Output folder (see :mod:`ltv_lstm_mpc.campaign.store`); finished tasks found there
        are skipped.
    scheduler : str, optional
        Address of a running Dask scheduler (``tcp://host:8786``); default: a new
        LocalCluster with ``workers`` processes (one per core by default).
    serial : bool
        Run in this process, without Dask.
    retry_errors : bool
        Rerun the tasks stored with ``status = "error"``.
    progress : bool
        Progress bar over the tasks.
    report : bool
        Write ``report.md``, the plots and ``statements.csv``.
    beta : float
        1 - confidence of the report's statistical statements
        (:mod:`~ltv_lstm_mpc.campaign.statements`).
    offset_tolerance : float, optional
        Tolerance of their ``offset`` outcome (output units); default the spec's
        ``[campaign].offset_tolerance`` (1e-3 when it sets none).
    task_function : callable
        What runs one task (default :func:`~ltv_lstm_mpc.campaign.task.run_task`); it
        must be picklable for Dask (see :mod:`ltv_lstm_mpc.campaign.testing`).
    log : callable, optional
        Receives one-line progress messages.

    Raises
    ------
    CampaignInterrupted
        On Ctrl-C (a :class:`KeyboardInterrupt`), after closing the cluster; the tasks
        finished before it are stored and a rerun skips them.
    """
    if serial and scheduler is not None:
        raise CampaignError("serial runs in this process: give serial=True or a scheduler")
    start = time.perf_counter()
    store = ResultStore(out)
    store.prepare(spec.name, [task.key for task in spec.tasks], spec.text)
    pending, finished = pending_tasks(spec, store, retry_errors=retry_errors)
    where = (
        "this process"
        if serial
        else (scheduler or f"a LocalCluster of {workers or os.cpu_count()} workers")
    )
    if log is not None:
        log(
            f"{spec.name}: {len(spec.tasks)} tasks, {len(finished)} finished, "
            f"{len(pending)} to run in {where}"
        )
    executed = 0
    try:
        with contextlib.ExitStack() as stack:
            if not pending:
                outcomes: Iterator[TaskOutcome] = iter(())
            elif serial:
                outcomes = _run_serial(pending, task_function)
            else:
                client = stack.enter_context(dask_client(scheduler, workers))
                outcomes = _run_dask(client, pending, task_function)
            bar = stack.enter_context(
                tqdm(total=len(pending), desc=spec.name, unit="task", disable=not progress)
            )
            for outcome in outcomes:
                store.write(outcome)
                executed += 1
                bar.update(1)
                if outcome.row.get("status") in ("error", "lost"):
                    bar.set_postfix_str(f"last error: {outcome.row['key']}", refresh=False)
    except KeyboardInterrupt:
        # the cluster is closed; what finished is on disk (each row written atomically)
        left, _ = pending_tasks(spec, store)
        raise CampaignInterrupted(
            len(spec.tasks) - len(left), len(spec.tasks), store.root
        ) from None
    stored = store.finished(task.key for task in spec.tasks)
    rows = [stored[task.key] for task in spec.tasks if task.key in stored]
    columns = ordered_columns(rows)
    rows = [{column: row.get(column) for column in columns} for row in rows]
    files = store.write_results(rows) if rows else []
    if report and rows:
        from ltv_lstm_mpc.campaign.report import write_report

        files.extend(
            write_report(
                rows,
                spec.varying,
                store.root,
                title=spec.name,
                strata=spec.strata,
                beta=beta,
                offset_tolerance=(
                    spec.offset_tolerance if offset_tolerance is None else offset_tolerance
                ),
                replications=[n for n in spec.replications if n in spec.varying],
                offset_window=_offset_window(spec),
            )
        )
    errors = sum(1 for row in rows if row.get("status") in ("error", "lost"))
    return CampaignRun(
        rows=rows,
        executed=executed,
        skipped=len(finished),
        errors=errors,
        wall_s=time.perf_counter() - start,
        files=files,
    )


@dataclass(frozen=True)
class Estimate:
    """The dry-run's numbers (:func:`estimate_campaign`).

    Attributes
    ----------
    tasks, finished, pending : int
        Tasks of the spec; already in the output folder; still to run.
    workers : int
        Parallel workers assumed.
    seconds : float
        Estimated wall time of the pending tasks, s (without starting the cluster).
    calibration : list of (label, setup_s, step_s)
        Measured per (solver, N, transcription) group: setup and per-step time.
    """

    tasks: int
    finished: int
    pending: int
    workers: int
    seconds: float
    calibration: list[tuple[str, float, float]]


def _scenario_steps(task: Task) -> int:
    if "scenario" not in task.settings:
        return int(task.settings["steps"])
    from ltv_lstm_mpc.campaign.task import load_task_model
    from ltv_lstm_mpc.paper.scenarios import paper_scenarios

    model = load_task_model(task)
    short = bool(task.settings["short"])
    return next(
        sc.steps
        for sc in paper_scenarios(model, short=short)
        if sc.name == task.settings["scenario"]
    )


def estimate_campaign(
    spec: CampaignSpec,
    out: str | Path | None = None,
    *,
    workers: int = 1,
    retry_errors: bool = False,
    calibration_steps: int = 10,
    calibration_budget_s: float = 20.0,
) -> Estimate:
    """Count the tasks and estimate the wall time from short calibration runs.

    Tasks are grouped by (solver, N, transcription). One task per group runs
    ``calibration_steps`` samples in this process (the slowest step, the first, counts as
    setup; each solver at its largest N first,
    then the other groups, until ``calibration_budget_s`` is spent); a group not measured
    takes its solver's measurement at the nearest N, else the slowest measured. A task
    then costs its setup plus its steps times the step time (capped by ``max_seconds``),
    and the pending tasks are spread over ``workers`` (never below the longest task).
    """
    store = ResultStore(out) if out is not None else None
    if store is not None:
        pending, finished = pending_tasks(spec, store, retry_errors=retry_errors)
    else:
        pending, finished = list(spec.tasks), {}

    def group(task: Task) -> tuple[str, int, str]:
        s = task.settings
        return (s["solver"], s["N"], s["transcription"])

    groups: dict[tuple[str, int, str], Task] = {}
    for task in pending:
        groups.setdefault(group(task), task)
    largest: dict[tuple[str, str], tuple[str, int, str]] = {}
    for solver, N, transcription in groups:
        best = largest.get((solver, transcription))
        if best is None or N > best[1]:
            largest[(solver, transcription)] = (solver, N, transcription)
    order = list(largest.values()) + [g for g in groups if g not in largest.values()]
    calibration: dict[tuple[str, int, str], tuple[float, float]] = {}
    started = time.perf_counter()
    if pending:  # warm-up: imports, compiled kernels
        run_task(replace(pending[0], trace=False), steps_limit=2)
    for name in order:
        if calibration and time.perf_counter() - started > calibration_budget_s:
            break
        row = run_task(replace(groups[name], trace=False), steps_limit=calibration_steps).row
        # The first (slowest) step builds the solver's problem: count it as setup.
        setup = float(row["setup_s"]) + float(row["max_step_s"])
        steps = max(int(row["steps_done"]) - 1, 1)
        calibration[name] = (setup, max(float(row["wall_s"]) - setup, 0.0) / steps)
    slowest = max(calibration.values(), key=lambda c: c[0] + 1000 * c[1], default=(0.0, 0.0))

    def figures(name: tuple[str, int, str]) -> tuple[float, float]:
        if name in calibration:
            return calibration[name]
        same = [g for g in calibration if (g[0], g[2]) == (name[0], name[2])]
        if same:
            return calibration[min(same, key=lambda g: abs(g[1] - name[1]))]
        return slowest

    total = longest = 0.0
    steps_of: dict[tuple[str, str, bool], int] = {}
    for task in pending:
        setup, step = figures(group(task))
        if "scenario" in task.settings:
            scenario_id = (
                task.model_location,
                str(task.settings["scenario"]),
                bool(task.settings["short"]),
            )
            if scenario_id not in steps_of:
                steps_of[scenario_id] = _scenario_steps(task)
            steps = steps_of[scenario_id]
        else:
            steps = int(task.settings["steps"])
        seconds = setup + step * steps
        cap = task.settings.get("max_seconds")
        seconds = min(seconds, setup + cap) if cap is not None else seconds
        total += seconds
        longest = max(longest, seconds)
    return Estimate(
        tasks=len(spec.tasks),
        finished=len(finished),
        pending=len(pending),
        workers=workers,
        seconds=max(total / max(workers, 1), longest),
        calibration=[
            (f"{solver}, N = {N}, {transcription}", *values)
            for (solver, N, transcription), values in calibration.items()
        ],
    )


def _offset_window(spec: CampaignSpec) -> int | None:
    """The spec's offset window when every task uses the same (None: they differ)."""
    from ltv_lstm_mpc.campaign.task import DEFAULT_OFFSET_WINDOW

    windows = {t.settings.get("offset_window", DEFAULT_OFFSET_WINDOW) for t in spec.tasks}
    return windows.pop() if len(windows) == 1 else None
