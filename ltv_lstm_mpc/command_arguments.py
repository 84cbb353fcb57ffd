"""Argument types of the command line: every numeric option is checked before any work.

Each function is an ``argparse`` ``type=``: a bad value is a usage error (exit code 2, one
line naming the option's value and the allowed range), never a traceback and never a
silent fallback. :class:`UsageError` is raised by commands for usage errors found after
parsing (e.g. an unknown bench backend); ``main`` turns it into exit code 2.

A module of its own, below the ``cli`` package: the commands that live with their own
packages (``train``/``generate-data`` in ``training``, ``bench``/``replay`` in ``bench``,
``campaign``) use these types without importing the ``cli`` package that registers them.
"""

from __future__ import annotations

import argparse
import math
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

from ltv_lstm_mpc.exceptions import InvalidValueError, LtvMpcError

__all__ = [
    "OrderedPair",
    "UsageError",
    "check_order",
    "fraction_open",
    "nonnegative_float",
    "output_folder",
    "plant_name",
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


def plant_name(text: str) -> str:
    """A registered plant name or an importable ``package.module:Class`` (the plant
    registry, :func:`ltv_lstm_mpc.resolve_plant`)."""
    from ltv_lstm_mpc.plants.registry import resolve_plant

    try:
        return resolve_plant(text).name
    except LtvMpcError as error:
        raise argparse.ArgumentTypeError(str(error)) from None


def plant_help() -> str:
    """The ``--plant`` choices for help texts: the registered names and the user form."""
    from ltv_lstm_mpc.plants.registry import registered_plants

    return ", ".join(registered_plants()) + ", or package.module:Class (a plant class of yours)"


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


def check_order(option: str, low: float | None, high: float | None) -> None:
    """The one check of every (low, high) pair of the command line: ``low < high``.

    ``option`` names the pair in the message (``"--y0-range"`` or ``"--y-min/--y-max"``);
    a pair with a missing side (``None``) is left to the command. Raises
    :class:`UsageError` (exit code 2) showing both values.
    """
    if low is None or high is None or low < high:
        return
    swap = f"; swap them ({option} {high:g} {low:g})" if low > high else ""
    raise UsageError(f"{option}: LOW must be below HIGH, got LOW = {low:g}, HIGH = {high:g}{swap}")


class OrderedPair(argparse.Action):
    """``nargs=2`` action for a ``LOW HIGH`` option: each a finite number (:func:`real`)
    and ``LOW < HIGH`` (:func:`check_order`), else a usage error naming the option."""

    def __init__(self, option_strings: Sequence[str], dest: str, **kwargs: Any) -> None:
        kwargs.setdefault("nargs", 2)
        kwargs.setdefault("type", real)
        kwargs.setdefault("metavar", ("LOW", "HIGH"))
        if kwargs["nargs"] != 2:
            raise InvalidValueError("OrderedPair takes exactly two values (nargs=2)")
        super().__init__(option_strings, dest, **kwargs)

    def __call__(
        self,
        parser: argparse.ArgumentParser,
        namespace: argparse.Namespace,
        values: Any,
        option_string: str | None = None,
    ) -> None:
        low, high = values
        try:
            check_order(option_string or self.dest, low, high)
        except UsageError as error:
            parser.error(str(error))
        setattr(namespace, self.dest, [low, high])
