"""ConvexProblem / SecondOrderCone validation, structure keys, save/load, reformulation."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import scipy.sparse as sp
from hypothesis import given, settings
from hypothesis import strategies as st
from ltv_lstm_mpc.solvers import ConvexProblem, PolyhedralInnerApproximation, SecondOrderCone
from ltv_lstm_mpc.solvers.testing import random_mpc_problem, random_qp, random_socp

from ltv_lstm_mpc.exceptions import DimensionError, InvalidValueError


def _equal(a: ConvexProblem, b: ConvexProblem) -> None:
    for name in ("P", "A_eq", "G"):
        ma, mb = getattr(a, name), getattr(b, name)
        assert (ma is None) == (mb is None)
        if ma is not None:
            np.testing.assert_array_equal(ma.indptr, mb.indptr)
            np.testing.assert_array_equal(ma.indices, mb.indices)
            np.testing.assert_array_equal(ma.data, mb.data)
    for name in ("q", "b_eq", "l", "u", "lb", "ub"):
        va, vb = getattr(a, name), getattr(b, name)
        assert (va is None) == (vb is None)
        if va is not None:
            np.testing.assert_array_equal(va, vb)
    assert len(a.cones) == len(b.cones)
    for ca, cb in zip(a.cones, b.cones, strict=True):
        np.testing.assert_array_equal(ca.F.toarray(), cb.F.toarray())
        np.testing.assert_array_equal(ca.g, cb.g)
        np.testing.assert_array_equal(ca.e, cb.e)
        assert ca.f == cb.f


@pytest.mark.parametrize(
    "make",
    [
        pytest.param(lambda: random_qp(seed=1), id="qp"),
        pytest.param(lambda: random_qp(5, 3, 0, seed=2, bounds=False), id="qp-no-eq-no-bounds"),
        pytest.param(lambda: random_socp(seed=3), id="socp"),
        pytest.param(lambda: random_mpc_problem(5, seed=4), id="mpc5"),
        pytest.param(lambda: ConvexProblem(P=np.eye(2), q=np.ones(2)), id="unconstrained"),
    ],
)
def test_save_load_round_trip(tmp_path: Path, make: object) -> None:
    p = make()  # type: ignore[operator]
    path = p.save(tmp_path / "sub")
    assert path.suffix == ".npz"
    loaded = ConvexProblem.load(path)
    _equal(p, loaded)
    assert loaded.structure_key() == p.structure_key()


def test_load_rejects_other_format(tmp_path: Path) -> None:
    np.savez(tmp_path / "x.npz", format_version=np.asarray(99))
    with pytest.raises(InvalidValueError, match="format_version 99"):
        ConvexProblem.load(tmp_path / "x.npz")


def test_shape_errors_name_the_array() -> None:
    with pytest.raises(DimensionError, match=r"P must have shape \(3, 3\)"):
        ConvexProblem(P=np.eye(2), q=np.zeros(3))
    with pytest.raises(DimensionError, match=r"A_eq must have shape \(p, 2\)"):
        ConvexProblem(P=np.eye(2), q=np.zeros(2), A_eq=np.ones((1, 3)), b_eq=[1.0])
    with pytest.raises(DimensionError, match=r"b_eq must have shape \(1,\)"):
        ConvexProblem(P=np.eye(2), q=np.zeros(2), A_eq=np.ones((1, 2)), b_eq=[1.0, 2.0])
    with pytest.raises(DimensionError, match=r"u must have shape \(2,\)"):
        ConvexProblem(P=np.eye(2), q=np.zeros(2), G=np.eye(2), u=np.ones(3))
    with pytest.raises(DimensionError, match=r"cones\[0\]\.F must have shape \(k, 2\)"):
        ConvexProblem(
            P=np.eye(2),
            q=np.zeros(2),
            cones=(SecondOrderCone(np.eye(3), np.zeros(3), np.zeros(3), 1.0),),
        )
    with pytest.raises(DimensionError, match=r"cone e must have shape \(2,\)"):
        SecondOrderCone(F=np.eye(2), g=np.zeros(2), e=np.zeros(3), f=1.0)


def test_value_errors() -> None:
    with pytest.raises(InvalidValueError, match="symmetric"):
        ConvexProblem(P=np.array([[1.0, 1.0], [0.0, 1.0]]), q=np.zeros(2))
    with pytest.raises(InvalidValueError, match="q has NaN"):
        ConvexProblem(P=np.eye(2), q=np.array([0.0, np.nan]))
    with pytest.raises(InvalidValueError, match="P has non-finite"):
        ConvexProblem(P=np.array([[np.inf, 0.0], [0.0, 1.0]]), q=np.zeros(2))
    with pytest.raises(InvalidValueError, match="l > u"):
        ConvexProblem(P=np.eye(2), q=np.zeros(2), G=np.eye(2), l=[1.0, 0.0], u=[0.0, 0.0])
    with pytest.raises(InvalidValueError, match=r"lb has \+inf"):
        ConvexProblem(P=np.eye(2), q=np.zeros(2), lb=[np.inf, 0.0])
    with pytest.raises(InvalidValueError, match="given together"):
        ConvexProblem(P=np.eye(2), q=np.zeros(2), A_eq=np.ones((1, 2)))
    with pytest.raises(InvalidValueError, match="without l or u"):
        ConvexProblem(P=np.eye(2), q=np.zeros(2), G=np.eye(2))
    with pytest.raises(InvalidValueError, match="must be a SecondOrderCone"):
        ConvexProblem(P=np.eye(2), q=np.zeros(2), cones=("x",))  # type: ignore[arg-type]


def test_one_sided_rows_and_readonly_data() -> None:
    p = ConvexProblem(P=sp.eye(2), q=np.zeros(2), G=np.eye(2), u=[1.0, 2.0])
    assert p.l is not None and np.all(np.isneginf(p.l))
    assert p.n_variables == 2 and p.n_ineq == 2 and p.n_eq == 0 and not p.has_cones
    with pytest.raises(ValueError, match="read-only"):
        p.q[0] = 1.0  # type: ignore[index]


def test_structure_key_tracks_pattern_not_values() -> None:
    p = random_mpc_problem(5, seed=0)
    same = p.with_values(q=np.asarray(p.q) + 1.0, P=np.asarray(p.P.data) * 2.0)
    assert same.structure_key() == p.structure_key()
    np.testing.assert_allclose(same.P.toarray(), 2.0 * p.P.toarray())
    lb = np.array(p.lb)
    lb[0] = -5.0  # an infinite bound becomes finite: new structure
    assert p.with_values(lb=lb).structure_key() != p.structure_key()
    assert random_mpc_problem(6, seed=0).structure_key() != p.structure_key()
    with pytest.raises(DimensionError, match="new nonzero values of P"):
        p.with_values(P=np.ones(3))
    with pytest.raises(InvalidValueError, match="unknown field"):
        p.with_values(R=np.ones(3))


def test_explicit_zeros_keep_the_pattern() -> None:
    P = sp.csc_matrix((np.array([1.0, 0.0, 0.0, 1.0]), np.array([0, 1, 0, 1]), np.array([0, 2, 4])))
    p = ConvexProblem(P=P, q=np.zeros(2))
    assert p.P.nnz == 4
    assert p.with_values(P=np.array([1.0, 0.5, 0.5, 1.0])).structure_key() == p.structure_key()


def test_objective_and_violation() -> None:
    p = ConvexProblem(
        P=2 * np.eye(2),
        q=np.array([1.0, 0.0]),
        G=np.eye(2),
        l=[-1.0, -1.0],
        u=[1.0, 1.0],
        cones=(SecondOrderCone(F=np.eye(2), g=np.zeros(2), e=np.zeros(2), f=1.0),),
    )
    assert p.objective([1.0, 2.0]) == pytest.approx(0.5 * (2 + 8) + 1.0)
    assert p.max_violation([0.5, 0.5]) == 0.0
    assert p.max_violation([1.0, 1.0]) == pytest.approx(np.sqrt(2) - 1)
    assert p.max_violation([0.0, 3.0]) == pytest.approx(2.0)


def test_reformulation_is_cone_free_and_keeps_the_rest() -> None:
    p = random_socp(seed=8)
    r = PolyhedralInnerApproximation().apply(p)
    assert not r.has_cones
    assert r.n_variables == p.n_variables
    assert r.n_ineq == p.n_ineq + sum(2 * c.dim for c in p.cones)
    np.testing.assert_array_equal(r.q, p.q)
    # the pattern of the new rows depends on patterns only (values with zeros sums keep it)
    assert (
        PolyhedralInnerApproximation().apply(random_socp(seed=8)).structure_key()
        == r.structure_key()
    )


@settings(max_examples=60, deadline=None)
@given(
    seed=st.integers(0, 10_000),
    k=st.integers(1, 5),
    scale=st.floats(0.1, 10.0),
)
def test_polyhedral_inner_approximation_is_conservative(seed: int, k: int, scale: float) -> None:
    """Every point the reformulation admits satisfies the original cone."""
    rng = np.random.default_rng(seed)
    n = 4
    cone = SecondOrderCone(
        F=rng.standard_normal((k, n)), g=rng.standard_normal(k), e=rng.standard_normal(n), f=1.0
    )
    p = ConvexProblem(P=np.eye(n), q=np.zeros(n), cones=(cone,))
    r = PolyhedralInnerApproximation().apply(p)
    Z = scale * rng.standard_normal((200, n))
    assert r.G is not None and r.u is not None
    inside = np.all(Z @ r.G.T.toarray() <= r.u, axis=1)
    for z in Z[inside]:
        assert cone.residual(z) <= 1e-9


def test_frozen_matrices_are_reused_without_copy_and_still_checked() -> None:
    import scipy.sparse as sp
    from ltv_lstm_mpc.solvers import ConvexProblem, frozen_csc

    from ltv_lstm_mpc.exceptions import InvalidValueError

    P = frozen_csc(sp.csc_matrix(np.diag([2.0, 1.0])), "P")
    assert not P.data.flags.writeable
    first = ConvexProblem(P=P, q=np.zeros(2))
    second = ConvexProblem(P=P, q=np.ones(2))
    assert first.P is P and second.P is P  # validated once, no copy per problem
    with pytest.raises(InvalidValueError, match="symmetric"):
        ConvexProblem(
            P=frozen_csc(sp.csc_matrix(np.array([[1.0, 1.0], [0.0, 1.0]]))), q=np.zeros(2)
        )
    with pytest.raises(InvalidValueError, match="non-finite"):
        frozen_csc(sp.csc_matrix(np.array([[np.nan, 0.0], [0.0, 1.0]])))
