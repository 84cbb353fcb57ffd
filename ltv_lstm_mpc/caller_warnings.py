"""Warnings that point at the caller's line and are shown once per closed-loop run.

Python's ``stacklevel`` counts frames, so a warning raised inside the controller points at
whichever library line happened to call it (``simulate``'s loop, a campaign task, ...).
:func:`warn_at_caller` attributes the warning to the first frame outside
:mod:`ltv_lstm_mpc` instead: the user's own call of ``simulate`` or ``controller.step``.

Python's warning registry shows a warning once per location for the whole process, so a
second run with the same problem would stay silent. :class:`RunWarnings` keeps a registry
of its own that :meth:`RunWarnings.reset` clears (the controller resets it with every run),
and counts every occurrence of each kind, shown or not.
"""

from __future__ import annotations

import linecache
import sys
import warnings
from types import FrameType
from typing import Any

__all__ = ["RunWarnings", "warn_at_caller"]

_LIBRARY = "ltv_lstm_mpc"


def _caller_frame() -> FrameType | None:
    """The innermost frame whose module is not part of the library (None: none found)."""
    frame: FrameType | None = sys._getframe(1)
    while frame is not None:
        name = frame.f_globals.get("__name__", "")
        if name != _LIBRARY and not name.startswith(_LIBRARY + "."):
            return frame
        frame = frame.f_back
    return None


def warn_at_caller(
    message: str,
    category: type[Warning] = RuntimeWarning,
    *,
    registry: dict[Any, Any] | None = None,
) -> None:
    """Issue ``message`` attributed to the first caller outside the library.

    Parameters
    ----------
    message : str
    category : Warning subclass
    registry : dict, optional
        Warning registry deciding "already shown" for the ``"default"`` action (a fresh one
        per call when None: the warning filters alone decide). The filters set with
        :func:`warnings.simplefilter` / ``-W`` apply as for :func:`warnings.warn`.
    """
    frame = _caller_frame()
    if frame is None:  # pragma: no cover - the library is always called from somewhere
        warnings.warn(message, category, stacklevel=2)
        return
    filename = frame.f_code.co_filename
    _prime_source_lines(filename, frame.f_globals)
    warnings.warn_explicit(
        message,
        category,
        filename,
        frame.f_lineno,
        module=frame.f_globals.get("__name__"),
        registry={} if registry is None else registry,
    )


def _prime_source_lines(filename: str, module_globals: dict[str, Any]) -> None:
    """Let :mod:`linecache` find the source of ``filename`` through its module's loader
    (a zip import, a notebook cell), so the warning shows the caller's line.

    What ``warnings.warn_explicit(..., module_globals=...)`` would do, minus its failure:
    CPython's implementation asks the loader ``get_source(module_globals["__name__"])``
    itself and lets its error escape, and the module named ``__main__`` is one no loader
    serves under that name (``python -c``, ``python -`` and a frozen ``__main__``: the
    built-in or frozen importer raises ``ImportError: '__main__' is not a built-in
    module``; ``python -m pkg.mod``: its file loader refuses the name ``__main__``).
    :func:`linecache.getlines` tolerates that; any other error of a loader costs only
    the source line.
    """
    try:
        linecache.getlines(filename, module_globals)
    except Exception:  # a loader's own failure: the warning goes out without the line
        pass


class RunWarnings:
    """Per-run warning bookkeeping of the closed loop: counts, and one display per kind.

    Attributes
    ----------
    counts : dict of str to int
        Occurrences of each kind in this run (steps on which the condition held), whether
        or not the warning was shown.
    """

    def __init__(self) -> None:
        self.counts: dict[str, int] = {}
        self._registry: dict[Any, Any] = {}

    def reset(self) -> None:
        """A new run: counts to zero, every kind may be shown again."""
        self.counts = {}
        self._registry = {}

    def first(self, kind: str) -> bool:
        """Count one occurrence of ``kind``; True if it is the first of this run."""
        count = self.counts.get(kind, 0)
        self.counts[kind] = count + 1
        return count == 0

    def warn(self, message: str, category: type[Warning] = RuntimeWarning) -> None:
        """Show ``message`` at the caller's line (this run's registry)."""
        warn_at_caller(message, category, registry=self._registry)
