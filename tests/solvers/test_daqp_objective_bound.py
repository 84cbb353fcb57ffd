"""DAQP's objective bound (``solvers.daqp_.objective_bound`` and its compiled twin): the
inequality it rests on, solves that find a point unchanged, infeasible ones ended sooner,
and the MPC's ``hessian_floor``."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from ltv_lstm_mpc.solvers import DenseQP, DenseSession, available_solvers
from optional_extras import requires_daqp_binding

from ltv_lstm_mpc import OffsetFreeController, load_model
from ltv_lstm_mpc.exceptions import InvalidValueError

pytestmark = pytest.mark.skipif("daqp" not in available_solvers(), reason="needs daqp")

daqp_ = pytest.importorskip("ltv_lstm_mpc.solvers.daqp_")
daqp_native = pytest.importorskip("ltv_lstm_mpc.solvers.daqp_native")
needs_binding = requires_daqp_binding()
NO_BOUND = daqp_native.NO_BOUND


def box_qp(seed: int, n: int = 8, rows: int = 6, infeasible: bool = False) -> DenseQP:
    """H = G'G + R (R = r I, r known: the floor), a box on every variable, rows; where
    ``infeasible``, one row asks for more than the box can give."""
    rng = np.random.default_rng(seed)
    r = 10.0 ** rng.uniform(-2, 1)  # (tr H / r below 1e8: DAQP factors H as it is)
    G = rng.normal(size=(n + 2, n)) * 10.0 ** rng.uniform(-1, 1.5)
    H = G.T @ G + r * np.eye(n)
    f = rng.normal(size=n) * 10.0 ** rng.uniform(-1, 3)
    A = rng.normal(size=(rows, n))
    width = rng.uniform(0.2, 2.0, n)
    lb, ub = -width, width
    lo, up = -rng.uniform(0.1, 1.0, rows), rng.uniform(0.1, 1.0, rows)
    if infeasible:  # row 0 beyond its largest value over the box
        reach = float(np.abs(A[0]) @ width)
        lo[0], up[0] = reach * rng.uniform(1.01, 3.0), np.inf
    return DenseQP(H=H, f=f, A=A, lo=lo, up=up, lb=lb, ub=ub, hessian_floor=0.5 * r)


@settings(max_examples=60, deadline=None)
@given(seed=st.integers(0, 10_000), tolerance=st.sampled_from([0.0, 1e-8, 1e-6]))
def test_the_bound_exceeds_daqps_objective_at_every_point_of_the_box(
    seed: int, tolerance: float
) -> None:
    """Half the bound is above 1/2 |R x + v|^2 = J(x) + 1/2 f'H^-1 f at every point of the
    box widened by the tolerance (its vertices, where the convex J is largest, included)."""
    qp = box_qp(seed)
    bound = daqp_.objective_bound(qp.H, qp.f, qp.lb, qp.ub, qp.hessian_floor, tolerance)
    assert bound < NO_BOUND
    rng = np.random.default_rng(seed)
    offset = 0.5 * float(qp.f @ np.linalg.solve(qp.H, qp.f))
    wide_lb, wide_ub = qp.lb - tolerance, qp.ub + tolerance
    points = [rng.uniform(wide_lb, wide_ub) for _ in range(50)]
    points += [np.where(rng.random(qp.f.shape[0]) < 0.5, wide_lb, wide_ub) for _ in range(50)]
    largest = max(qp.objective(x) + offset for x in points)
    assert largest <= 0.5 * bound, (largest, bound)


@needs_binding
@settings(max_examples=40, deadline=None)
@given(seed=st.integers(0, 10_000))
def test_the_compiled_twin_gives_the_same_bound(seed: int) -> None:
    qp = box_qp(seed)
    for floor in (qp.hessian_floor, 0.0):
        for lb in (qp.lb, np.where(np.arange(qp.lb.shape[0]) == 2, -np.inf, qp.lb)):
            expected = daqp_.objective_bound(qp.H, qp.f, lb, qp.ub, floor, 1e-8)
            found = daqp_native.objective_bound(qp.H, qp.f, lb, qp.ub, floor, 1e-8, 1e-11)
            assert found == pytest.approx(expected, rel=1e-13), (floor, lb)


@needs_binding
@pytest.mark.parametrize("seed", range(20))
def test_the_twins_agree_on_the_gate_at_its_limits(seed: int) -> None:
    """A diagonal H whose trace is the floor times CONDITION_LIMIT, to the last bits on
    either side: the numpy and the compiled twin give a bound at the same QPs (the trace
    summed in the same order)."""
    rng = np.random.default_rng(seed)
    n = int(rng.integers(5, 60))
    H = np.diag(10.0 ** rng.uniform(0, 1, n))
    f, lb, ub = np.ones(n), -np.ones(n), np.ones(n)
    limit = float(np.add.accumulate(np.diagonal(H))[-1]) / daqp_native.CONDITION_LIMIT
    given = []
    floors = [limit * (1.0 - 1e-9)]
    floors += [np.nextafter(limit, 0.0), limit, np.nextafter(limit, 1.0)]
    floors += [limit * (1.0 + 1e-9)]
    for floor in floors:
        expected = daqp_.objective_bound(H, f, lb, ub, floor, 1e-8, 1e-14)
        found = daqp_native.objective_bound(H, f, lb, ub, floor, 1e-8, 1e-14)
        assert (expected < NO_BOUND) == (found < NO_BOUND), (floor, expected, found)
        given.append(found < NO_BOUND)
    assert not given[0] and given[-1]


@needs_binding
@pytest.mark.parametrize("side", ["lower", "upper"])
def test_the_twins_give_no_bound_at_a_nan_bound_on_either_side(side: str) -> None:
    qp = box_qp(5)
    lb, ub = qp.lb.copy(), qp.ub.copy()
    (lb if side == "lower" else ub)[2] = np.nan
    assert daqp_.objective_bound(qp.H, qp.f, lb, ub, qp.hessian_floor, 1e-8) == NO_BOUND
    found = daqp_native.objective_bound(qp.H, qp.f, lb, ub, qp.hessian_floor, 1e-8, 1e-11)
    assert found == NO_BOUND


def test_no_bound_where_a_bound_is_infinite_the_floor_zero_or_h_not_semidefinite() -> None:
    qp = box_qp(1)
    args = (qp.H, qp.f, qp.lb, qp.ub, qp.hessian_floor, 1e-8)
    assert daqp_.objective_bound(*args) < NO_BOUND
    unbounded = qp.ub.copy()
    unbounded[3] = np.inf
    assert daqp_.objective_bound(qp.H, qp.f, qp.lb, unbounded, qp.hessian_floor, 1e-8) == NO_BOUND
    assert daqp_.objective_bound(qp.H, qp.f, qp.lb, qp.ub, 0.0, 1e-8) == NO_BOUND
    assert daqp_.objective_bound(-qp.H, qp.f, qp.lb, qp.ub, qp.hessian_floor, 1e-8) == NO_BOUND
    huge = qp.ub * 1e20
    assert daqp_.objective_bound(qp.H, qp.f, -huge, huge, qp.hessian_floor, 1e-8) == NO_BOUND


def solve(qp: DenseQP, backend: str = "daqp") -> tuple[str, np.ndarray | None, int, str]:
    session = DenseSession(backend, tolerance=1e-8)
    status, z, iterations, info = session.solve_point(qp)
    return status.value, z, iterations, info


@pytest.mark.parametrize("seed", range(40))
def test_a_solve_that_finds_a_point_is_unchanged(seed: int) -> None:
    """The same status, point (bit for bit) and DAQP iterations as without the floor."""
    qp = box_qp(seed)
    with_floor = solve(qp)
    without = solve(dataclasses.replace(qp, hessian_floor=0.0))
    assert with_floor[0] == without[0] == "optimal"
    np.testing.assert_array_equal(with_floor[1], without[1])
    assert with_floor[2] == without[2]


@pytest.fixture
def daqps_own_proof(monkeypatch: pytest.MonkeyPatch) -> None:
    """DAQP proves an infeasible QP itself: the row activity check that would prove these
    one-row QPs infeasible before DAQP runs (``activity_infeasible``, both twins) is
    switched off, so that the tests below see DAQP's iterations under the bound."""
    monkeypatch.setattr(daqp_, "activity_infeasible", lambda *args: False)
    monkeypatch.setattr(daqp_native, "activity_infeasible", lambda *args: False)


@pytest.mark.usefixtures("daqps_own_proof")
@pytest.mark.parametrize("seed", range(40))
def test_an_infeasible_qp_ends_infeasible_and_never_later(seed: int) -> None:
    qp = box_qp(seed, n=30, rows=4, infeasible=True)
    with_floor = solve(qp)
    without = solve(dataclasses.replace(qp, hessian_floor=0.0))
    assert with_floor[0] == without[0] == "infeasible", (with_floor, without)
    assert with_floor[2] <= without[2]


@pytest.mark.usefixtures("daqps_own_proof")
def test_an_infeasible_qp_ends_sooner_on_the_bound() -> None:
    """A row ten times beyond what the box can give: DAQP adds bound after bound (its
    proof) where the bound ends it at the first points. (Just beyond the box, the bound,
    loose by a trace and a factor 2, ends nothing sooner: 1.01 n gives 42 and 42.)"""
    n = 40
    H = np.eye(n) + 0.1 * np.ones((n, n))
    A = np.ones((1, n))
    qp = DenseQP(
        H=H, f=np.zeros(n), A=A, lo=np.array([10.0 * n]), up=np.array([np.inf]),
        lb=-np.ones(n), ub=np.ones(n), hessian_floor=0.5,
    )  # fmt: skip
    with_floor = solve(qp)
    without = solve(dataclasses.replace(qp, hessian_floor=0.0))
    assert with_floor[0] == without[0] == "infeasible"
    assert with_floor[2] <= 5 < n <= without[2], (with_floor[2], without[2])


def test_the_settings_own_bound_is_kept_where_smaller_and_with_proximal_iterations() -> None:
    qp = box_qp(3)
    computed = daqp_.objective_bound(qp.H, qp.f, qp.lb, qp.ub, qp.hessian_floor, 1e-8)
    assert computed < NO_BOUND
    for own, expected in ((0.5 * computed, 0.5 * computed), (2.0 * computed, computed)):
        backend = daqp_.DaqpDense("daqp", 1e-8, {"fval_bound": own})
        backend.setup(qp)
        assert backend._objective_bound(None) == pytest.approx(expected, rel=1e-13)
    backend = daqp_.DaqpDense("daqp", 1e-8, {"eps_prox": 1e-6})
    backend.setup(qp)
    assert backend._objective_bound(backend.native) == NO_BOUND


@needs_binding
def test_the_compiled_writer_keeps_the_settings_own_bound_where_smaller_or_proximal() -> None:
    qp = box_qp(4)
    computed = daqp_native.objective_bound(
        qp.H, qp.f, qp.lb, qp.ub, qp.hessian_floor, 1e-8, daqp_.DAQP_ZERO_TOL
    )
    for options, own, expected in (
        ({"primal_tol": 1e-8}, NO_BOUND, computed),
        ({"primal_tol": 1e-8}, 0.5 * computed, 0.5 * computed),
        ({"primal_tol": 1e-8, "eps_prox": 1e-6}, 7.0, 7.0),
        ({"primal_tol": 1e-8, "zero_tol": 10.0 * qp.hessian_floor}, NO_BOUND, NO_BOUND),
    ):
        settings = daqp_native.native(options).settings
        daqp_native.set_objective_bound(settings, qp.H, qp.f, qp.lb, qp.ub, qp.hessian_floor, own)
        written = settings.view(np.float64)[daqp_native._S_FVAL]
        assert written == pytest.approx(expected, rel=1e-15), options


def box(H, f, lb, ub, floor: float) -> DenseQP:
    n = len(f)
    return DenseQP(
        H=np.asarray(H, float), f=np.asarray(f, float), A=np.zeros((0, n)), lo=np.zeros(0),
        up=np.zeros(0), lb=np.asarray(lb, float), ub=np.asarray(ub, float), hessian_floor=floor,
    )  # fmt: skip


def proximal_cases() -> list[tuple[DenseQP, dict]]:
    """A review's feasible QPs, each with an honest floor, on which DAQP regularizes H (its
    proximal mode): a small-scale H with a near-null direction; a near-zero diagonal entry
    beside one of 621 and a fixed variable; a user's automatic eps_prox of -10; a dense H
    of scale 1e-8 and condition 1e15 with one row."""
    rng = np.random.default_rng(0)
    n = 6
    Q, _ = np.linalg.qr(rng.normal(size=(n, n)))
    H = (Q * (1e-8 * np.logspace(0, -15, n))) @ Q.T
    H = 0.5 * (H + H.T)
    dense = DenseQP(
        H=H, f=np.zeros(n), A=np.ones((1, n)), lo=np.array([2.0]), up=np.array([np.inf]),
        lb=-np.ones(n), ub=np.ones(n), hessian_floor=0.5 * float(np.linalg.eigvalsh(H).min()),
    )  # fmt: skip
    fixed = -0.3628015076815992
    return [
        (box(np.diag([1e-7, 1e-19]), [0, 0], [-1, 0.9], [1, 1], 1e-19), {}),
        (
            box(
                np.diag([2.069492757894325e-10, 621.128007551889]),
                [9.112158450462133e-08, -3.755717485415513e-08],
                [fixed, -0.9816247179629607],
                [fixed, 0.10381701842065905],
                1e-10,
            ),
            {},
        ),
        (box(np.diag([1.0, 1e-12]), [0, 0], [-1, 0.9], [1, 1], 1e-12), {"eps_prox": -10.0}),
        (dense, {}),
    ]


@pytest.mark.parametrize("case", range(4))
def test_no_bound_where_daqp_could_regularize_the_hessian(case: int) -> None:
    """On each (feasible) QP DAQP works on H + eps I, whose objective the bound does not
    bound: none is given, and the solve is the one without the floor (it was "infeasible"
    with the bound)."""
    qp, settings = proximal_cases()[case]
    assert float(np.linalg.eigvalsh(qp.H).min()) >= qp.hessian_floor
    tolerance = float(settings.get("zero_tol", daqp_.DAQP_ZERO_TOL))
    assert daqp_.objective_bound(qp.H, qp.f, qp.lb, qp.ub, qp.hessian_floor, 1e-8, tolerance) == (
        NO_BOUND
    )
    runs = []
    for floor in (qp.hessian_floor, 0.0):
        session = DenseSession("daqp", tolerance=1e-8, **settings)
        status, z, iterations, _info = session.solve_point(
            dataclasses.replace(qp, hessian_floor=floor)
        )
        runs.append((status.value, iterations, None if z is None else z.tolist()))
    assert runs[0] == runs[1]
    assert runs[0][0] == "optimal", runs


@pytest.mark.parametrize("floor", [-1.0, np.inf, np.nan])
def test_a_bad_floor_is_refused_with_its_value(floor: float) -> None:
    qp = dataclasses.replace(box_qp(0), hessian_floor=floor)
    with pytest.raises(InvalidValueError, match="hessian_floor must be a finite number >= 0"):
        qp.check()


def test_the_floor_survives_copy_save_and_load(tmp_path) -> None:
    qp = box_qp(2)
    assert qp.copy().hessian_floor == qp.hessian_floor
    assert DenseQP.load(qp.save(tmp_path / "qp.npz")).hessian_floor == qp.hessian_floor


@pytest.mark.parametrize("N", [5, 20])
def test_the_mpcs_floor_is_below_the_condensed_hessians_eigenvalues(N: int) -> None:
    """CondensedTranscription.hessian_floor (half R's smallest eigenvalue) is a floor of
    the condensed H of every QP it solves, over 150 steps of the paper's scenario 3."""
    from ltv_lstm_mpc.paper.scenarios import paper_scenarios

    model = load_model("ph_lstm_n5.npz")
    scenario = paper_scenarios(model)[2]
    config = dataclasses.replace(scenario.config, solver="daqp", N=N, R=0.3)
    controller = OffsetFreeController(
        model, config, setpoint_rate_limit=scenario.setpoint_rate_limit, engine="reference"
    )
    problem = controller.mpc._problem
    assert problem.hessian_floor == pytest.approx(0.15)
    ratios, kinds = [], set()
    original = problem.solve

    def watch(kind: str, x_hat: np.ndarray):  # type: ignore[no-untyped-def]
        result = original(kind, x_hat)
        qp = problem._last[kind]
        kinds.add(kind)
        assert 0.0 < qp.hessian_floor <= problem.hessian_floor
        ratios.append(float(np.linalg.eigvalsh(qp.H).min()) / qp.hessian_floor)
        return result

    problem.solve = watch
    plant = scenario.make_plant(model)
    y = plant.output()
    for k in range(150):
        u = controller.step(y, scenario.setpoints[k])
        y = plant.step(u)
    assert kinds == {"nominal", "paper"}, kinds  # (the policy's QP too)
    assert min(ratios) >= 2.0, min(ratios)  # (half R's, and H >= I (x) R)
