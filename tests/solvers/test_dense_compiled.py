"""The compiled violation loops of the dense layer against their numpy expressions."""

from __future__ import annotations

import numpy as np
import pytest
from ltv_lstm_mpc.solvers import DenseCone, DenseQP


def numpy_violation(qp: DenseQP, x: np.ndarray) -> float:
    """The numpy reference of DenseQP.max_violation."""
    viol = max(0.0, float((qp.lb - x).max()), float((x - qp.ub).max()))
    if qp.A.shape[0]:
        Ax = qp.A @ x
        viol = max(viol, float((qp.lo - Ax).max()), float((Ax - qp.up).max()))
    for cone in qp.cones:
        viol = max(viol, cone.violation(x))
    return viol


@pytest.mark.parametrize("seed", range(8))
@pytest.mark.parametrize("rows", [0, 5])
@pytest.mark.parametrize("compiled", [True, False])
def test_max_violation_equals_the_numpy_expressions(
    seed: int, rows: int, compiled: bool, monkeypatch
) -> None:
    """Both of max_violation's paths: the compiled loops and the numpy fallback it takes
    where they are not compiled yet."""
    from ltv_lstm_mpc.solvers import dense

    for wrapper in (dense._bounds_rows_violation, dense._cone_violation):
        path = wrapper.dispatcher if compiled else wrapper.fallback
        assert wrapper.fallback is not wrapper.dispatcher  # a numpy twin, not the loops
        monkeypatch.setattr(wrapper, "_call", path)
    rng = np.random.default_rng(seed)
    n = 6
    G = rng.normal(size=(n, n))
    lb, ub = -rng.uniform(0, 1, n), rng.uniform(0, 1, n)
    lb[0], ub[1] = -np.inf, np.inf
    lo, up = -rng.uniform(0, 1, rows), rng.uniform(0, 1, rows)
    if rows:
        up[0] = np.inf
    cones = (
        DenseCone(rng.normal(size=(3, n)), rng.normal(size=3), rng.normal(size=n), 0.5),
        DenseCone(rng.normal(size=(2, n)), np.zeros(2), np.eye(n)[2], 0.1),
    )
    qp = DenseQP(G @ G.T, rng.normal(size=n), rng.normal(size=(rows, n)), lo, up, lb, ub,
                 cones=cones)  # fmt: skip
    for scale in (0.01, 1.0, 10.0):  # inside, near and far outside
        x = scale * rng.normal(size=n)
        assert qp.max_violation(x) == pytest.approx(numpy_violation(qp, x), rel=1e-13, abs=1e-13)
    assert qp.max_violation(np.full(n, np.nan)) == np.inf


@pytest.mark.parametrize("seed", range(8))
@pytest.mark.parametrize("rows", [0, 5])
def test_compiled_kkt_residuals_equal_the_numpy_reference(seed: int, rows: int) -> None:
    """acceptance.residuals on a cone-free DenseQP (compiled) == acceptance._residuals
    (numpy), multipliers of both signs at finite and infinite bounds included."""
    from ltv_lstm_mpc.solvers.acceptance import ProblemView, _residuals, residuals

    rng = np.random.default_rng(seed)
    n = 6
    G = rng.normal(size=(n, n))
    lb, ub = -rng.uniform(0, 1, n), rng.uniform(0, 1, n)
    lb[0], ub[1] = -np.inf, np.inf
    lo, up = -rng.uniform(0, 1, rows), rng.uniform(0, 1, rows)
    if rows:
        up[0], lo[1] = np.inf, -np.inf
        lo[2] = up[2]  # an equality row
    qp = DenseQP(G @ G.T, rng.normal(size=n), rng.normal(size=(rows, n)), lo, up, lb, ub)
    view = ProblemView.of_dense(qp)
    for scale in (0.01, 1.0, 10.0):
        x = scale * rng.normal(size=n)
        duals = {"ineq": rng.normal(size=rows), "bounds": rng.normal(size=n)}
        fast = residuals(view, x, duals)
        slow = _residuals(view, x, duals)
        for name in ("primal", "stationarity", "complementarity"):
            assert getattr(fast, name) == pytest.approx(getattr(slow, name), rel=1e-12, abs=1e-15)
        assert fast.unchecked == slow.unchecked == ""
