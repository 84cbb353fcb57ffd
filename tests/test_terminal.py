"""The terminal set of eq. (optimization) in its forms (mpc/terminal.py): they agree, and the
QP box reformulation (paper notes 4) is inside the set and over-bounds the cost."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from ltv_lstm_mpc.exceptions import DimensionError, InvalidValueError
from ltv_lstm_mpc.mpc.terminal import TerminalSet, terminal_norm_of_squares


@st.composite
def terminal_sets(draw: st.DrawFn) -> TerminalSet:
    """An entrywise nonnegative, positive definite P_f and a state size n."""
    p11 = draw(st.floats(0.05, 50.0))
    p22 = draw(st.floats(0.05, 50.0))
    p12 = draw(st.floats(0.0, 0.95)) * math.sqrt(p11 * p22)
    n = draw(st.integers(1, 8))
    return TerminalSet(np.array([[p11, p12], [p12, p22]]), n)


def _point(terminal: TerminalSet, data: st.DataObject, scale: float) -> np.ndarray:
    entries = st.floats(-scale, scale, allow_nan=False)
    return np.array(data.draw(st.lists(entries, min_size=2 * terminal.n, max_size=2 * terminal.n)))


@given(terminal_sets(), st.data())
def test_every_form_of_the_norm_agrees(terminal: TerminalSet, data: st.DataObject) -> None:
    x_bar = _point(terminal, data, 1.0)
    x_N = x_bar + _point(terminal, data, 2.0)
    n = terminal.n
    t_c, t_h = np.linalg.norm(x_N[:n] - x_bar[:n]), np.linalg.norm(x_N[n:] - x_bar[n:])
    t = np.array([t_c, t_h])
    exact = math.sqrt(t @ terminal.P_f @ t)  # ||[t_c, t_h]||_{P_f}
    norm = terminal.norm(x_N, x_bar)
    assert norm == pytest.approx(exact, rel=1e-12, abs=1e-14)
    assert math.sqrt(terminal.level(t_c, t_h)) == pytest.approx(exact, rel=1e-12, abs=1e-14)
    compiled = terminal_norm_of_squares(t_c**2, t_h**2, np.array(terminal.terms))
    assert compiled == pytest.approx(norm, rel=1e-12, abs=1e-14)
    assert np.linalg.norm(terminal.square_root @ t) == pytest.approx(exact, rel=1e-12, abs=1e-14)


@given(terminal_sets(), st.floats(0.0, 5.0), st.data())
def test_the_box_lies_inside_the_terminal_set(
    terminal: TerminalSet, alpha: float, data: st.DataObject
) -> None:
    """paper notes 4: |x_N - x_bar| <= alpha * unit_half_widths entrywise implies
    x_N in X_f(k); the box's corner reaches the ellipse's boundary (largest such box)."""
    x_bar = _point(terminal, data, 1.0)
    half = alpha * terminal.unit_half_widths
    fractions = np.array(
        data.draw(st.lists(st.floats(-1.0, 1.0), min_size=half.size, max_size=half.size))
    )
    x_N = x_bar + fractions * half
    assert terminal.norm(x_N, x_bar) <= alpha * (1 + 1e-12) + 1e-15
    corner = x_bar + half
    assert terminal.norm(corner, x_bar) == pytest.approx(alpha, rel=1e-12, abs=1e-15)


@given(terminal_sets(), st.data())
def test_the_box_cost_bounds_the_terminal_cost(terminal: TerminalSet, data: st.DataObject) -> None:
    """paper notes 4: t'P_f t <= sum_j w_j (x_N,j - x_bar_j)^2 (the QP minimizes more)."""
    x_bar = _point(terminal, data, 1.0)
    x_N = x_bar + _point(terminal, data, 2.0)
    exact_cost = terminal.norm(x_N, x_bar) ** 2
    box_cost = float(terminal.box_weights @ (x_N - x_bar) ** 2)
    assert exact_cost <= box_cost * (1 + 1e-12) + 1e-15


def test_contains_and_bad_weights() -> None:
    terminal = TerminalSet(np.array([[2.0, 0.5], [0.5, 1.0]]), 2)
    x_bar = np.zeros(4)
    inside = np.array([0.1, 0.0, 0.1, 0.0])
    assert terminal.contains(inside, x_bar, 1.0)
    assert not terminal.contains(10 * inside, x_bar, 1.0)
    with pytest.raises(DimensionError, match=r"shape \(3, 3\)"):
        TerminalSet(np.eye(3), 2)
    with pytest.raises(InvalidValueError, match="entrywise nonnegative"):
        TerminalSet(np.array([[1.0, -0.1], [-0.1, 1.0]]), 2)
