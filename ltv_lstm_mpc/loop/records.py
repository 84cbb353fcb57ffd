"""The controller's per-step records: preallocated rows, records built when they are read.

:attr:`OffsetFreeController.records <ltv_lstm_mpc.OffsetFreeController.records>` is a
:class:`ControllerRecords`: a read-only sequence of
:class:`~ltv_lstm_mpc.loop.step_record.ControllerStep`. A step that ran as one compiled call
(:mod:`ltv_lstm_mpc.loop.compiled_step`) writes its numbers into the preallocated rows of a
:data:`~ltv_lstm_mpc.loop.compiled_step.RecordArrays` and appends a placeholder; its
:class:`~ltv_lstm_mpc.loop.step_record.ControllerStep` is built from those rows the first
time it is read (then kept), so neither allocation nor record-building is part of the
timed step. A step of the reference engine appends its record as it is.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator, Sequence
from types import SimpleNamespace
from typing import Any, overload

from ltv_lstm_mpc.loop.compiled_step import RECORD_FIELDS, new_record_arrays

__all__ = ["ControllerRecords"]


class ControllerRecords(Sequence[Any]):
    """The records of one run of a controller (a read-only sequence, like a list).

    Parameters
    ----------
    build : callable
        ``build(records, k)``: the record of step ``k`` from ``records.rows`` (a namespace
        of the :data:`~ltv_lstm_mpc.loop.compiled_step.RecordArrays` fields as numpy
        arrays) and ``records.log``.
    shape : (p, m, 2n, N), optional
        Row sizes; None: no rows (every step appends its record: the reference engine).
    """

    def __init__(
        self,
        build: Callable[[ControllerRecords, int], Any],
        shape: tuple[int, int, int, int] | None = None,
    ) -> None:
        #: The list behind the sequence: a record, or None for a step an engine wrote into
        #: the rows (its record is built when first read). What an engine appends to.
        self.slots: list[Any] = []
        self._build = build
        self._shape = shape
        #: The rows as numpy arrays (None until :meth:`reserve`), and the same arrays as the
        #: compiled step's :data:`~ltv_lstm_mpc.loop.compiled_step.RecordArrays`.
        self.rows: SimpleNamespace | None = None
        self.compiled: Any = None
        self.capacity = 0
        #: The run's assumption log (the records' ``monitor_log``), set by the controller.
        self.log: Any = None
        #: What an engine keeps beside a step's row to build its record from (by step; the
        #: one-call engine: a failed exact-cone solve's arrays, whose status and reason are
        #: read when the record is built).
        self.extras: dict[int, Any] = {}

    # ------------------------------------------------------------------ writing
    def append(self, record: Any) -> None:
        """Append a finished record (the reference engine)."""
        self.slots.append(record)

    def append_recorded(self) -> None:
        """Append the step written into row ``len(self)`` (built when first read)."""
        self.slots.append(None)

    def reserve(self, steps: int) -> None:
        """Rows for at least ``steps`` steps (``simulate`` reserves its run's length, so
        that no step grows the arrays); existing rows are copied. A no-op without rows."""
        if self._shape is None or steps <= self.capacity:
            return
        capacity = max(int(steps), 2 * self.capacity, 64)
        compiled, arrays = new_record_arrays(capacity, *self._shape)
        rows = SimpleNamespace(**arrays)
        if self.rows is not None:
            for name in RECORD_FIELDS:
                old = getattr(self.rows, name)
                getattr(rows, name)[: old.shape[0]] = old
        self.rows, self.compiled, self.capacity = rows, compiled, capacity

    # ------------------------------------------------------------------ reading
    def __len__(self) -> int:
        return len(self.slots)

    @overload
    def __getitem__(self, index: int) -> Any: ...

    @overload
    def __getitem__(self, index: slice) -> list[Any]: ...

    def __getitem__(self, index: int | slice) -> Any:
        if isinstance(index, slice):
            return [self[k] for k in range(*index.indices(len(self.slots)))]
        item = self.slots[index]
        if item is None:
            k = index if index >= 0 else index + len(self.slots)
            assert self.rows is not None
            item = self.slots[k] = self._build(self, k)
        return item

    def __iter__(self) -> Iterator[Any]:
        for k in range(len(self.slots)):
            yield self[k]

    def __eq__(self, other: object) -> bool:
        if isinstance(other, ControllerRecords | list):
            return list(self) == list(other)
        return NotImplemented

    def __hash__(self) -> int:
        raise TypeError("unhashable type: 'ControllerRecords' (a mutable sequence)")

    def __repr__(self) -> str:
        return f"ControllerRecords({len(self)} steps)"
