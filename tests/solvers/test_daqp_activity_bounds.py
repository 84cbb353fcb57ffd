"""The row activity check before DAQP (``solvers.daqp_.activity_infeasible`` and its
compiled twin): a QP one of whose rows cannot hold anywhere in the box is infeasible
without a DAQP call; never a QP with a point, to within DAQP's tolerance."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from ltv_lstm_mpc.solvers import DenseQP, DenseSession, available_solvers
from optional_extras import requires_daqp_binding

pytestmark = pytest.mark.skipif("daqp" not in available_solvers(), reason="daqp not installed")
daqp_ = pytest.importorskip("ltv_lstm_mpc.solvers.daqp_")
daqp_native = pytest.importorskip("ltv_lstm_mpc.solvers.daqp_native")
needs_binding = requires_daqp_binding()
NO_BOUND = daqp_native.NO_BOUND
TOLERANCE = 1e-8


def random_rows(rng: np.random.Generator, n: int, rows: int) -> tuple[np.ndarray, ...]:
    """Rows with zeros, a box of mixed widths and scales, and a point x in it."""
    A = rng.normal(size=(rows, n)) * 10.0 ** rng.uniform(-3, 3, size=(rows, 1))
    A[rng.random((rows, n)) < 0.3] = 0.0
    width = 10.0 ** rng.uniform(-2, 2, n)
    centre = rng.normal(size=n) * width
    lb, ub = centre - width, centre + width
    x = rng.uniform(lb, ub)
    return A, lb, ub, x


def layout(lb: np.ndarray, ub: np.ndarray, lo: np.ndarray, up: np.ndarray) -> tuple:
    return np.concatenate([lb, lo]), np.concatenate([ub, up])


@pytest.mark.parametrize("seed", range(30))
def test_a_qp_with_a_point_is_never_called_infeasible(seed: int) -> None:
    """Rows through a point of the box, tight at it (equalities, one-sided, violated by
    less than the tolerance): no proof; nor with the point at a vertex of the box."""
    rng = np.random.default_rng(seed)
    for _ in range(50):
        n, rows = int(rng.integers(1, 30)), int(rng.integers(1, 12))
        A, lb, ub, x = random_rows(rng, n, rows)
        if rng.random() < 0.3:  # at a vertex
            x = np.where(rng.random(n) < 0.5, lb, ub)
        Ax = A @ x
        slack = 0.9 * TOLERANCE * rng.random(rows)  # violated within the tolerance
        lo = Ax + slack * (rng.random(rows) < 0.5)
        up = Ax - slack * (rng.random(rows) < 0.5)
        one_sided = rng.random(rows)
        lo[one_sided < 0.2] = -np.inf
        up[one_sided > 0.8] = np.inf
        lower, upper = layout(lb, ub, lo, up)
        assert not daqp_.activity_infeasible(A, lower, upper, TOLERANCE)
        assert not daqp_native.activity_infeasible(A, lower, upper, TOLERANCE)


@settings(max_examples=200, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), beyond=st.floats(1.01, 100.0))
def test_a_row_beyond_the_box_is_infeasible_as_daqp_says(seed: int, beyond: float) -> None:
    """A row asked for more than the box gives (by a factor ``beyond`` of its reach, on
    either side): proved, by both twins; and DAQP itself, run on the same QP, says
    infeasible (exit flag -1)."""
    rng = np.random.default_rng(seed)
    n, rows = int(rng.integers(1, 20)), int(rng.integers(1, 6))
    A, lb, ub, x = random_rows(rng, n, rows)
    if not np.any(A[0]):
        A[0, 0] = 1.0
    Ax = A @ x
    lo, up = Ax - 1.0, Ax + 1.0
    low_reach = float(np.minimum(A[0] * lb, A[0] * ub).sum())
    high_reach = float(np.maximum(A[0] * lb, A[0] * ub).sum())
    span = high_reach - low_reach + abs(high_reach) + 1.0
    if rng.random() < 0.5:
        lo[0], up[0] = high_reach + (beyond - 1.0) * span, np.inf
    else:
        lo[0], up[0] = -np.inf, low_reach - (beyond - 1.0) * span
    lower, upper = layout(lb, ub, lo, up)
    assert daqp_.activity_infeasible(A, lower, upper, TOLERANCE)
    assert daqp_native.activity_infeasible(A, lower, upper, TOLERANCE)
    import daqp

    H = np.eye(n)
    sense = np.zeros(n + rows, dtype=np.intc)
    bupper = np.minimum(upper, NO_BOUND)
    blower = np.maximum(lower, -NO_BOUND)
    _x, _fval, flag, _info = daqp.solve(H, np.zeros(n), A, bupper, blower, sense)
    assert flag == -1


def every_row(A: np.ndarray, lower: np.ndarray, upper: np.ndarray, tolerance: float) -> bool:
    """The definition, row by row, no row passed over (the twins pass over the rows the
    origin satisfies where the box holds it)."""
    n = A.shape[1]
    for i in range(A.shape[0]):
        used = A[i] != 0.0
        if np.any(used & ~((np.abs(lower[:n]) < NO_BOUND) & (np.abs(upper[:n]) < NO_BOUND))):
            continue
        with np.errstate(invalid="ignore", over="ignore"):
            p, q = (
                A[i][used] * (lower[:n][used] - tolerance),
                A[i][used] * (upper[:n][used] + tolerance),
            )
            smallest, largest = np.minimum(p, q).sum(), np.maximum(p, q).sum()
            size = np.maximum(np.abs(p), np.abs(q)).sum()
            margin = daqp_native.ACTIVITY_MARGIN
            lo, up = lower[n + i], upper[n + i]
            if up < NO_BOUND and smallest - up > tolerance + margin * (size + abs(up)):
                return True
            if lo > -NO_BOUND and lo - largest > tolerance + margin * (size + abs(lo)):
                return True
    return False


@pytest.mark.parametrize("seed", range(20))
def test_the_twins_agree(seed: int) -> None:
    """The same verdict from the numpy and the compiled twin, infinite and NaN bounds,
    NaN rows and rows near the margin included, and the definition's (every row, no row
    passed over: the origin's rows prove nothing)."""
    rng = np.random.default_rng(1000 + seed)
    for _ in range(200):
        n, rows = int(rng.integers(1, 15)), int(rng.integers(0, 6))
        A, lb, ub, x = random_rows(rng, n, rows)
        Ax = A @ x if rows else np.zeros(0)
        lo = Ax - rng.uniform(0, 1, rows)
        up = Ax + rng.uniform(0, 1, rows)
        if rows and rng.random() < 0.5:
            i = int(rng.integers(0, rows))
            shift = float(rng.normal() * 10.0 ** rng.uniform(-12, 3))
            lo[i] += shift
            up[i] += shift
        for values in (lb, ub, lo, up, A.ravel()):
            if values.size and rng.random() < 0.1:
                values[int(rng.integers(0, values.size))] = rng.choice(
                    [np.inf, -np.inf, np.nan, 2e30, -2e30]
                )
        if rng.random() < 0.5:  # the origin in the box, and in some rows
            lb, ub = np.minimum(lb, 0.0), np.maximum(ub, 0.0)
            lo[: rows // 2] = np.minimum(lo[: rows // 2], 0.0)
            up[: rows // 2] = np.maximum(up[: rows // 2], 0.0)
        lower, upper = layout(lb, ub, lo, up)
        tolerance = rng.choice([TOLERANCE, 0.0, 1e-6, -1e-6])  # (a negative one: no pass)
        verdict = daqp_.activity_infeasible(A, lower, upper, tolerance)
        assert verdict == daqp_native.activity_infeasible(A, lower, upper, tolerance)
        if not np.isnan(A).any():  # (the definition's sums in numpy's order)
            assert verdict == every_row(A, lower, upper, tolerance)


def test_rows_on_no_variable() -> None:
    """Empty rows (no variable): their activity is 0, proved where 0 is beyond a bound."""
    for up, expected in ((-1.0, True), (1.0, False)):
        lower, upper = np.array([-np.inf]), np.array([up])
        A = np.zeros((1, 0))
        assert daqp_.activity_infeasible(A, lower, upper, TOLERANCE) is expected
        assert daqp_native.activity_infeasible(A, lower, upper, TOLERANCE) == expected


def test_a_row_on_an_unbounded_variable_or_nan_proves_nothing() -> None:
    A = np.array([[1.0, 1.0]])
    for lb, ub in (([0.0, -np.inf], [1.0, 1.0]), ([0.0, 0.0], [1.0, NO_BOUND]),
                   ([0.0, np.nan], [1.0, 1.0])):  # fmt: skip
        lower, upper = layout(np.array(lb), np.array(ub), np.array([10.0]), np.array([np.inf]))
        assert not daqp_.activity_infeasible(A, lower, upper, TOLERANCE)
        assert not daqp_native.activity_infeasible(A, lower, upper, TOLERANCE)
    # a zero coefficient on the unbounded variable: the row is proved on the others
    A = np.array([[1.0, 0.0]])
    lower, upper = layout(np.zeros(2), np.array([1.0, np.inf]), np.array([10.0]), [np.inf])
    assert daqp_.activity_infeasible(A, lower, upper, TOLERANCE)
    assert daqp_native.activity_infeasible(A, lower, upper, TOLERANCE)


@needs_binding
@pytest.mark.parametrize("compiled", [False, True])
def test_the_backend_returns_infeasible_without_daqp(compiled: bool) -> None:
    """The dense backend (the reference engine's DAQP) ends such a QP infeasible with no
    DAQP iteration, compiled twin or numpy twin alike; a QP just inside the reach is
    DAQP's to solve."""
    n = 30
    qp = DenseQP(
        H=np.eye(n), f=np.zeros(n), A=np.ones((1, n)), lo=np.array([1.5 * n]),
        up=np.array([np.inf]), lb=-np.ones(n), ub=np.ones(n), hessian_floor=0.5,
    )  # fmt: skip
    session = DenseSession("daqp", tolerance=1e-8)
    session.solve_point(qp)  # (set up)
    backend = session._backend
    if not compiled:
        backend._native = None
    status, z, iterations, info = session.solve_point(qp)
    assert (status.value, z, iterations, info) == ("infeasible", None, 0, "exitflag -1")
    inside = DenseQP(**{**qp.__dict__, "lo": np.array([0.9 * n])})
    status, z, iterations, _ = session.solve_point(inside)
    assert status.value == "optimal" and iterations > 0
    assert float(np.sum(z)) >= 0.9 * n - 1e-8
