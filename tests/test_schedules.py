"""Piecewise-constant schedules (loop/schedules.py), shared by every experiment."""

from __future__ import annotations

import numpy as np
import pytest

from ltv_lstm_mpc.loop.schedules import equal_segments, piecewise_constant, segments


def test_scalar_and_vector_levels() -> None:
    np.testing.assert_array_equal(piecewise_constant([7.0, 8.0], [2, 3]), [7, 7, 8, 8, 8])
    vector = piecewise_constant([(1.0, 2.0), (3.0, 4.0)], [1, 2])
    np.testing.assert_array_equal(vector, [[1, 2], [3, 4], [3, 4]])
    assert piecewise_constant([1.0], [0]).shape == (0,)
    with pytest.raises(ValueError, match="2 levels for 3 lengths"):
        piecewise_constant([1.0, 2.0], [1, 1, 1])


def test_segments_and_equal_shares() -> None:
    assert segments([2, 3, 1]) == [(0, 2), (2, 5), (5, 6)]
    series, edges = equal_segments([7.0, 7.5, 8.0], 10)
    assert edges == [0, 3, 7, 10]
    np.testing.assert_array_equal(series, [7.0] * 3 + [7.5] * 4 + [8.0] * 3)
