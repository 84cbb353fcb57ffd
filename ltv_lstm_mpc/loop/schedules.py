"""Piecewise-constant set-point and disturbance schedules of closed-loop experiments.

One implementation for every experiment of the library (the paper's scenarios, the
quadruple-tank benchmark, campaigns, ``ltv-lstm-mpc simulate``): a schedule holds each
level for a number of samples, and its segments are the ``[start, end)`` sample ranges of
the levels (the offsets are read at the end of each one).
"""

from __future__ import annotations

import itertools
from collections.abc import Sequence

import numpy as np
from numpy.typing import ArrayLike, NDArray

from ltv_lstm_mpc.exceptions import InvalidValueError

__all__ = ["equal_segments", "piecewise_constant", "segments"]

FloatArray = NDArray[np.float64]


def piecewise_constant(levels: Sequence[ArrayLike], lengths: Sequence[int]) -> FloatArray:
    """Each level held for its number of samples: shape ``(sum(lengths),)`` for scalar
    levels, ``(sum(lengths), p)`` for vectors of length p."""
    arrays = [np.asarray(level, dtype=np.float64) for level in levels]
    if len(arrays) != len(lengths):
        raise InvalidValueError(f"{len(arrays)} levels for {len(lengths)} lengths")
    return np.concatenate(
        [np.repeat(a[None, ...], n, axis=0) for a, n in zip(arrays, lengths, strict=True)]
    )


def segments(lengths: Sequence[int]) -> list[tuple[int, int]]:
    """``[start, end)`` sample range of each level of a schedule with these lengths."""
    edges = np.concatenate([[0], np.cumsum(lengths)])
    return [(int(a), int(b)) for a, b in itertools.pairwise(edges)]


def equal_segments(values: Sequence[float], steps: int) -> tuple[FloatArray, list[int]]:
    """``steps`` samples holding each value for an equal share (rounded); and the edges."""
    count = len(values)
    edges = [round(i * steps / count) for i in range(count + 1)]
    return piecewise_constant(list(values), list(np.diff(edges))), edges
