"""Fault-injecting task functions, to exercise a campaign's fault handling.

Each wraps a task function (default :func:`~ltv_lstm_mpc.campaign.task.run_task`), is
picklable (it ships to Dask workers like the real one) and keeps its state in files of a
folder, so it works across processes: pass one as ``task_function`` to
:func:`~ltv_lstm_mpc.campaign.runner.run_campaign`.

* :class:`CountingTask` — records every call (:func:`executions` counts them per task).
* :class:`RaisingTask` — raises for the tasks whose settings match.
* :class:`CrashOnce` — kills its process (``os._exit``) the first time a matching task
  runs: on Dask the worker dies mid-task and the scheduler reschedules the task.
* :class:`ExitAfter` — kills its process when the n-th task starts: a campaign
  interrupted half way.
"""

from __future__ import annotations

import os
import uuid
from collections import Counter
from collections.abc import Mapping
from pathlib import Path
from typing import Any

from ltv_lstm_mpc.campaign.task import Task, TaskFunction, TaskOutcome, run_task

__all__ = ["CountingTask", "CrashOnce", "ExitAfter", "RaisingTask", "executions"]


def _matches(task: Task, match: Mapping[str, Any]) -> bool:
    return all(task.settings.get(name) == value for name, value in match.items())


class CountingTask:
    """Calls ``inner`` after writing one file ``<key>.<random>`` per call into ``folder``."""

    def __init__(self, folder: str | Path, inner: TaskFunction = run_task) -> None:
        self.folder = Path(folder)
        self.inner = inner

    def __call__(self, task: Task) -> TaskOutcome:
        self.folder.mkdir(parents=True, exist_ok=True)
        (self.folder / f"{task.key}.{uuid.uuid4().hex}").touch()
        return self.inner(task)


def executions(folder: str | Path) -> Counter[str]:
    """Calls recorded by :class:`CountingTask` in ``folder``, per task key."""
    path = Path(folder)
    if not path.is_dir():
        return Counter()
    return Counter(entry.name.split(".")[0] for entry in path.iterdir())


class RaisingTask:
    """Raises ``RuntimeError`` for tasks whose settings match ``match``; runs the others."""

    def __init__(self, match: Mapping[str, Any], inner: TaskFunction = run_task) -> None:
        self.match = dict(match)
        self.inner = inner

    def __call__(self, task: Task) -> TaskOutcome:
        if _matches(task, self.match):
            raise RuntimeError(f"injected failure for {self.match}")
        return self.inner(task)


class CrashOnce:
    """Exits the process (``os._exit(70)``) the first time a task matching ``match`` runs.

    The first call writes the marker ``folder/<key>.crashed`` and exits without running
    the task; later calls (the rescheduled task) run it normally.
    """

    def __init__(
        self, folder: str | Path, match: Mapping[str, Any], inner: TaskFunction = run_task
    ) -> None:
        self.folder = Path(folder)
        self.match = dict(match)
        self.inner = inner

    def __call__(self, task: Task) -> TaskOutcome:
        marker = self.folder / f"{task.key}.crashed"
        if _matches(task, self.match) and not marker.exists():
            self.folder.mkdir(parents=True, exist_ok=True)
            marker.touch()
            os._exit(70)
        return self.inner(task)


class ExitAfter:
    """Exits the process (``os._exit(71)``) when the ``count``-th call starts.

    Calls are counted by files in ``folder``, so the count spans processes.
    """

    def __init__(self, folder: str | Path, count: int, inner: TaskFunction = run_task) -> None:
        self.folder = Path(folder)
        self.count = int(count)
        self.inner = inner

    def __call__(self, task: Task) -> TaskOutcome:
        self.folder.mkdir(parents=True, exist_ok=True)
        (self.folder / f"{task.key}.{uuid.uuid4().hex}").touch()
        if sum(1 for _ in self.folder.iterdir()) >= self.count:
            os._exit(71)
        return self.inner(task)
