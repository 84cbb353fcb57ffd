"""Argument types of the command line: every numeric option is checked before any work.

Each function is an ``argparse`` ``type=``: a bad value is a usage error (exit code 2, one
line naming the option's value and the allowed range), never a traceback and never a
silent fallback. :class:`UsageError` is raised by commands for usage errors found after
parsing (e.g. an unknown bench backend); ``main`` turns it into exit code 2.
"""

from __future__ import annotations

import argparse
import math
from collections.abc import Callable
from pathlib import Path

from ltv_lstm_mpc.exceptions import LtvMpcError

__all__ = [
    "UsageError",
    "fraction_open",
    "nonnegative_float",
    "output_folder",
    "positive_float",
    "positive_int",
    "real",
]


class UsageError(LtvMpcError, ValueError):
    """A command-line usage error found after parsing (exit code 2)."""


def real(text: str) -> float:
    """A finite real number."""
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a number") from None
    if not math.isfinite(value):
        raise argparse.ArgumentTypeError(f"{text!r} is not a finite number")
    return value


def positive_float(text: str) -> float:
    """A finite number > 0."""
    value = real(text)
    if not value > 0:
        raise argparse.ArgumentTypeError(f"{text!r} must be > 0")
    return value


def nonnegative_float(text: str) -> float:
    """A finite number >= 0."""
    value = real(text)
    if value < 0:
        raise argparse.ArgumentTypeError(f"{text!r} must be >= 0")
    return value


def positive_int(text: str) -> int:
    """An integer >= 1."""
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not an integer") from None
    if value < 1:
        raise argparse.ArgumentTypeError(f"{text!r} must be an integer >= 1")
    return value


def fraction_open(low: float, high: float) -> Callable[[str], float]:
    """A number in the open interval (low, high)."""

    def check(text: str) -> float:
        value = real(text)
        if not low < value < high:
            raise argparse.ArgumentTypeError(f"{text!r} must lie in ({low:g}, {high:g})")
        return value

    check.__name__ = f"number in ({low:g}, {high:g})"
    return check


def output_folder(text: str) -> Path:
    """A folder to write into: absent (created later) or an existing folder, not a file."""
    path = Path(text)
    if path.exists() and not path.is_dir():
        raise argparse.ArgumentTypeError(f"{text!r} exists and is not a folder")
    parent = path if path.exists() else next((p for p in path.parents if p.exists()), Path("."))
    if not parent.is_dir():
        raise argparse.ArgumentTypeError(f"{text!r}: {parent} is not a folder")
    return path
