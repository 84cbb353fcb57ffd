"""The output folder of a campaign: one file per finished task, written at once, atomically.

Layout of ``OUT``::

    campaign.toml            the spec (copied)
    campaign.json            name, library version, task keys in order
    tasks/<key>.json         one row per finished task (written when the task finishes)
    traces/<key>.parquet     per-step traces of the traced subset (.csv without pyarrow)
    results.parquet, .csv    every task of the spec, in task order (written at the end)
    report.md, plots/        :func:`ltv_lstm_mpc.campaign.report.write_report`

Every file is written to a temporary name in the same folder and renamed into place
(``os.replace``), so a process killed at any moment leaves either the whole file or none.
A task's row is written after its trace: a row file means the task is finished. The key
hashes the settings and the library version, so rerunning a campaign (or another one
that shares tasks) into the same folder skips the finished tasks, and a new library
version recomputes everything.
"""

from __future__ import annotations

import csv
import io
import json
import os
import uuid
from collections.abc import Iterable, Mapping, Sequence
from pathlib import Path
from typing import Any

from ltv_lstm_mpc import __version__
from ltv_lstm_mpc.campaign.task import METRIC_COLUMNS, TaskOutcome

__all__ = ["ResultStore", "atomic_write", "ordered_columns", "write_table"]


def atomic_write(path: Path, data: bytes) -> None:
    """Write ``data`` to ``path`` through a temporary file and a rename (all or nothing)."""
    path.parent.mkdir(parents=True, exist_ok=True)
    temporary = path.with_name(f".{path.name}.{os.getpid()}.{uuid.uuid4().hex[:8]}.tmp")
    try:
        with open(temporary, "wb") as handle:
            handle.write(data)
            handle.flush()
            os.fsync(handle.fileno())
        os.replace(temporary, path)
    finally:
        if temporary.exists():
            temporary.unlink()


def ordered_columns(rows: Iterable[Mapping[str, Any]]) -> list[str]:
    """Columns of ``rows``: the key, the settings, the metrics, then anything else."""
    from ltv_lstm_mpc.campaign.spec import SETTINGS

    seen: dict[str, None] = {}
    for row in rows:
        seen.update(dict.fromkeys(row))
    preferred = ["key", *SETTINGS, *METRIC_COLUMNS]
    return [c for c in preferred if c in seen] + [c for c in seen if c not in preferred]


def _have_pyarrow() -> bool:
    import importlib.util

    return importlib.util.find_spec("pyarrow") is not None


def write_table(
    rows: Sequence[Mapping[str, Any]],
    stem: Path,
    *,
    csv_file: bool = True,
    columns: Sequence[str] | None = None,
) -> list[Path]:
    """Write ``rows`` as ``stem.parquet`` (with pyarrow) and ``stem.csv``; missing cells empty.

    ``columns`` default: :func:`ordered_columns`. Returns the paths written.
    """
    columns = list(columns) if columns is not None else ordered_columns(rows)
    written: list[Path] = []
    if _have_pyarrow():
        import pyarrow as pa
        import pyarrow.parquet as pq

        table = pa.Table.from_pydict({c: [row.get(c) for row in rows] for c in columns})
        buffer = io.BytesIO()
        pq.write_table(table, buffer)
        path = stem.with_suffix(".parquet")
        atomic_write(path, buffer.getvalue())
        written.append(path)
    if csv_file or not written:
        text = io.StringIO()
        writer = csv.DictWriter(text, fieldnames=columns, extrasaction="ignore")
        writer.writeheader()
        for row in rows:
            writer.writerow({c: "" if row.get(c) is None else row.get(c) for c in columns})
        path = stem.with_suffix(".csv")
        atomic_write(path, text.getvalue().encode("utf-8"))
        written.append(path)
    return written


class ResultStore:
    """One campaign output folder (see the module docstring).

    Parameters
    ----------
    root : path
        The output folder (created when needed).
    """

    def __init__(self, root: str | Path) -> None:
        self.root = Path(root)
        self.tasks_dir = self.root / "tasks"
        self.traces_dir = self.root / "traces"

    def prepare(self, name: str, keys: Sequence[str], spec_text: str = "") -> None:
        """Create the folders; write the spec copy and the manifest of this campaign."""
        self.tasks_dir.mkdir(parents=True, exist_ok=True)
        self.traces_dir.mkdir(parents=True, exist_ok=True)
        if spec_text:
            atomic_write(self.root / "campaign.toml", spec_text.encode("utf-8"))
        manifest = {"name": name, "library_version": __version__, "tasks": list(keys)}
        atomic_write(self.root / "campaign.json", json.dumps(manifest, indent=1).encode())

    def row_path(self, key: str) -> Path:
        """File of a task's row."""
        return self.tasks_dir / f"{key}.json"

    def load(self, key: str) -> dict[str, Any] | None:
        """The stored row of a task, or None (not finished, or an unreadable file)."""
        try:
            row = json.loads(self.row_path(key).read_text(encoding="utf-8"))
        except (OSError, ValueError):
            return None
        return row if isinstance(row, dict) and row.get("key") == key else None

    def finished(self, keys: Iterable[str]) -> dict[str, dict[str, Any]]:
        """Rows already stored for these keys."""
        rows = {}
        for key in keys:
            row = self.load(key)
            if row is not None:
                rows[key] = row
        return rows

    def write(self, outcome: TaskOutcome) -> Path:
        """Store a finished task: its trace (if any) first, then its row. Returns the row file."""
        key = outcome.row["key"]
        if outcome.trace is not None:
            names = list(outcome.trace)
            rows = [
                dict(zip(names, values, strict=True))
                for values in zip(*outcome.trace.values(), strict=True)
            ]
            write_table(rows, self.traces_dir / key, csv_file=not _have_pyarrow(), columns=names)
        path = self.row_path(key)
        atomic_write(path, json.dumps(outcome.row, indent=1).encode("utf-8"))
        return path

    def write_results(self, rows: Sequence[Mapping[str, Any]]) -> list[Path]:
        """``results.parquet`` (with pyarrow) and ``results.csv`` of ``rows``."""
        return write_table(rows, self.root / "results")
