"""The C SQP of the exact cones (``export/templates/socp.c.in``, ``<prefix>_socp_solve``)
against the library's :func:`~ltv_lstm_mpc.solvers.socp_sqp.socp_solve`, problem by
problem, on random SOCPs of the controller's shape (feasible, infeasible and unbounded by
construction, the terminal cost quadratic or linear in ``t``:
:func:`~ltv_lstm_mpc.solvers.testing.controller_socp`). These reach the SQP's rare paths,
which the closed loops of ``tests/test_export_step.py`` seldom take: the proximal re-solve
of unbounded and infeasible subproblems, the line search after the full steps, failed
solves and runs out of iterations. Skipped without a C compiler."""

from __future__ import annotations

import ctypes
import shutil
from typing import Any

import numpy as np
import pytest
from ltv_lstm_mpc.solvers.daqp_native import native
from ltv_lstm_mpc.solvers.daqp_socp import problem_workspace
from ltv_lstm_mpc.solvers.socp_sqp import (
    FULL_STEPS,
    MAX_ITERATIONS,
    socp_solve,
)
from ltv_lstm_mpc.solvers.testing import (
    PREDICTED_EPIGRAPH_KINDS,
    REDUCTION_SCALE_CASES,
    SOCP_KINDS,
    controller_socp,
    write_reduction_case,
)
from ltv_lstm_mpc.solvers.tolerances import solver_options

from ltv_lstm_mpc import MPCConfig, OffsetFreeController
from ltv_lstm_mpc.export import export_model_c
from ltv_lstm_mpc.export.sil import CController, compile_controller
from ltv_lstm_mpc.lstm.shipped import load_model

pytest.importorskip("daqp")
pytestmark = pytest.mark.skipif(
    not any(shutil.which(c) for c in ("gcc", "clang")), reason="no C compiler (gcc or clang)"
)


def _c_sqp(folder: Any, cones: int = 3) -> tuple[CController, Any, Any]:
    """A cone controller's C library (pH, N = 5, the soft policy: the largest problem,
    12 variables, 8 rows, 12 cone rows), its ``<prefix>_socp_solve``, and the DAQP
    buffers of the library's SQP with the same settings. ``cones``: the cones its
    ``<prefix>_socp`` has room for (the controller's problems have 3; more, for test
    problems with more, by sizing the export's buffers as
    :func:`~ltv_lstm_mpc.export.socp_struct.socp_sizes` would for that many)."""
    from ltv_lstm_mpc.export import c_model
    from ltv_lstm_mpc.export.socp_struct import socp_sizes

    def sizes(*args: Any) -> dict[str, int]:
        room = socp_sizes(*args)
        room["k"] += cones - room["c"]
        room["r"] = room["R"] * cones
        room["c"] = cones
        return room

    model = load_model("ph_lstm_n5.npz")
    config = MPCConfig(N=5, solver="daqp:socp", infeasibility_policy="soft")
    controller = OffsetFreeController(model, config, kernels="numpy", one_call_step=False)
    with pytest.MonkeyPatch.context() as patch:
        patch.setattr(c_model, "socp_sizes", sizes)
        exported = export_model_c(model, folder, controller=controller, prefix="ctl")
    assert exported.socp_sizes[:4] == (12, 8, 12, cones)
    # (-DCTL_TEST_HOOKS: the C guards' test entry points beside the exported code)
    c = CController(compile_controller(exported, extra_flags=("-DCTL_TEST_HOOKS",)), exported)
    solve = c.library.ctl_socp_solve
    solve.argtypes = [ctypes.c_void_p, ctypes.c_void_p] + [ctypes.c_void_p] * 3
    solve.restype = ctypes.c_int
    buffers = native(solver_options("daqp", config.tolerance, dict(config.solver_settings)))
    return c, solve, buffers


@pytest.fixture(scope="module")
def c_sqp(tmp_path_factory: pytest.TempPathFactory) -> tuple[CController, Any, Any]:
    """:func:`_c_sqp`: the controller's C SQP, room for its 3 cones."""
    return _c_sqp(tmp_path_factory.mktemp("cones"))


@pytest.fixture(scope="module")
def c_sqp_four_cones(tmp_path_factory: pytest.TempPathFactory) -> tuple[CController, Any, Any]:
    """:func:`_c_sqp` with room for 4 cones (``badly_scaled_epigraph_socp(0)``'s)."""
    return _c_sqp(tmp_path_factory.mktemp("four_cones"), cones=4)


def write_c(c: CController, qp: Any) -> Any:
    """``qp`` into the controller's second ``<prefix>_socp`` (the policy's); its pointer."""
    pointer = c._socp(c.state_buffer, 1)
    s = pointer.contents
    n, m = qp.H.shape[0], qp.A.shape[0]
    sizes = [cone.F.shape[0] for cone in qp.cones]
    s.n, s.m, s.cones = n, m, len(sizes)
    rows = np.cumsum([0, *sizes])
    for j, value in enumerate(rows):
        s.cone_rows[j] = int(value)
    s.first_active[:] = [0] * len(s.first_active)

    def put(name: str, values: Any) -> None:
        flat = np.ravel(values)
        np.ctypeslib.as_array(getattr(s, name))[: flat.size] = flat

    for name in ("H", "f", "A", "lb", "ub", "lo", "up"):
        put(name, getattr(qp, name))
    put("F", np.vstack([cone.F for cone in qp.cones]))
    put("g", np.concatenate([cone.g for cone in qp.cones]))
    put("e", np.vstack([cone.e for cone in qp.cones]))
    put("offsets", [cone.f for cone in qp.cones])
    return pointer


def c_solve(solve: Any, c: CController, pointer: Any) -> tuple[int, int, int, float]:
    """One cold ``<prefix>_socp_solve`` on the controller's buffers."""
    sqp, total, violation = ctypes.c_int(), ctypes.c_int(), ctypes.c_double()
    address = ctypes.addressof(pointer.contents)
    flag = solve(c.state_buffer, address, ctypes.byref(sqp), ctypes.byref(total),
                 ctypes.byref(violation))  # fmt: skip
    return int(flag), sqp.value, total.value, violation.value


CASES = [(seed, kind, linear) for seed in range(12) for kind in SOCP_KINDS for linear in (0, 1)]


def test_the_c_sqp_equals_the_librarys_on_random_socps(c_sqp: Any) -> None:
    """72 random SOCPs, each solved twice (the second solve starts from the first's
        epigraph prediction). On every solve: DAQP's last exit flag, whether the SQP
        converged, the proximal iterations and the epigraph prediction equal the library's;
        a converged iterate within 1e-6 (relative) of the library's. Where the SQP ends within
        its full steps (no line search), also the SQP iterations, and a converged iterate to
    1e-9. The
        line search's later iterates amplify the ulps by which the two DAQP builds differ
        (the library calls the daqp package's, with equality elimination on automatic), so the
        SQP iterations may differ there: they must on at most 1 in 10 solves. The set covers
        converged, infeasible (DAQP's -1) and unbounded problems (the proximal re-solves, DAQP's
        iteration limit -4, runs out of SQP iterations) and line searches (all counted)."""
    c, solve, buffers = c_sqp
    seen: dict[str, int] = {}
    differing = 0
    for seed, kind, linear in CASES:
        qp = controller_socp(seed, kind, bool(linear))
        pointer = write_c(c, qp)
        ws, arrays = problem_workspace(qp, buffers)
        s = pointer.contents
        n, cones = qp.H.shape[0], len(qp.cones)
        for solve_index in range(2):
            flag, sqp, _total, _violation, _seconds = socp_solve(ws, False, MAX_ITERATIONS)
            c_flag, c_iterations, _c_total, _c_violation = c_solve(solve, c, pointer)
            where = (seed, kind, linear, solve_index, flag, sqp, c_flag, c_iterations)
            converged = flag in (1, 2) and sqp <= MAX_ITERATIONS
            assert c_flag == flag, where
            assert (c_flag in (1, 2) and c_iterations <= MAX_ITERATIONS) == converged, where
            assert list(s.regularized) == list(arrays["regularized"]), where
            assert list(s.first_active)[:cones] == list(arrays["first_active"]), where
            z = np.ctypeslib.as_array(s.z)[:n]
            gap = np.abs(z - arrays["z"]).max() / (1.0 + np.abs(arrays["z"]).max())
            if converged:
                assert gap <= 1e-6, where
            if flag > 0 and arrays["regularized"][1]:  # (the last step a proximal one)
                direction = np.ctypeslib.as_array(s.direction)[:n]
                scale = 1.0 + np.abs(arrays["direction"]).max()
                assert np.abs(direction - arrays["direction"]).max() <= 1e-6 * scale, where
            if sqp <= FULL_STEPS:  # (a failed solve's iterate may hold an unbounded
                # subproblem's huge entries, whose size depends on DAQP's rounding)
                assert c_iterations == sqp, where
                assert gap <= 1e-9 or not converged, (where, gap)
            differing += c_iterations != sqp
        label = "converged" if converged else ("max_iter" if flag > 0 else f"flag {flag}")
        seen[label] = seen.get(label, 0) + 1
        if arrays["regularized"][0]:
            seen["proximal"] = seen.get("proximal", 0) + 1
        if sqp > FULL_STEPS:
            seen["line search"] = seen.get("line search", 0) + 1
    assert differing <= 0.1 * 2 * len(CASES), (differing, seen)
    for label in ("converged", "flag -1", "flag -4", "max_iter", "proximal", "line search"):
        assert seen.get(label, 0) > 0, (label, seen)


def test_the_c_sqp_ends_the_mpcs_infeasible_problems_where_the_library_does(c_sqp: Any) -> None:
    """The infeasibility check with the earlier iterates' cutting planes: the nominal
    problems of the paper's scenario 3 at N = 5 that fail (steps 590-618; the SQP circles
    on most of them without the check), solved by the C SQP and the library's: the same
    exit flag, SQP iteration and kept iterates (``cut_state``), and the same kept points,
    the check ending at least half of them."""
    from dataclasses import replace
    from itertools import pairwise

    from ltv_lstm_mpc.solvers import DenseCone, DenseQP

    from ltv_lstm_mpc.paper.scenarios import paper_scenarios

    c, solve, buffers = c_sqp
    model = load_model("ph_lstm_n5.npz")
    scenario = paper_scenarios(model)[2]
    config = replace(scenario.config, N=5, solver="daqp:socp")
    controller = OffsetFreeController(
        model, config, setpoint_rate_limit=scenario.setpoint_rate_limit, kernels="compiled"
    )
    arrays = controller.mpc._problem.socp_arrays
    plant = scenario.make_plant(model)
    y = plant.output()
    failed = by_check = 0
    for k in range(620):
        u = controller.step(y, scenario.setpoints[k])
        if not controller.records[-1].mpc.feasible:
            rows = arrays["cone_rows"]
            cones = tuple(
                DenseCone(arrays["F"][a:b].copy(), arrays["g"][a:b].copy(),
                          arrays["e"][j].copy(), float(arrays["offsets"][j]))
                for j, (a, b) in enumerate(pairwise(rows))
            )  # fmt: skip
            qp = DenseQP(
                H=arrays["H"].copy(), f=arrays["f"].copy(), A=arrays["A"].copy(),
                lo=arrays["lo"].copy(), up=arrays["up"].copy(), lb=arrays["lb"].copy(),
                ub=arrays["ub"].copy(), cones=cones,
            )  # fmt: skip
            pointer = write_c(c, qp)
            ws, library = problem_workspace(qp, buffers)
            flag, sqp, *_ = socp_solve(ws, False, MAX_ITERATIONS)
            c_flag, c_sqp_iterations, *_ = c_solve(solve, c, pointer)
            s = pointer.contents
            state = list(s.cut_state)
            assert (c_flag, c_sqp_iterations) == (flag, sqp) == (-1, sqp), k
            assert state == list(library["cut_state"]), k
            n = qp.H.shape[0]
            points = np.ctypeslib.as_array(s.cut_points)[: state[0] * n].reshape(state[0], n)
            np.testing.assert_allclose(points, library["cut_points"][: state[0]], atol=1e-9)
            failed += 1
            by_check += state[2] > 0
        d = scenario.disturbances[k]
        y = plant.step(u, None if np.isnan(d) else d)
    assert failed >= 25
    assert by_check >= failed // 2


@pytest.mark.parametrize(
    ("seed", "kind", "linear"),
    [(6, "feasible", 0), (43, "feasible", 0), (84, "feasible", 0), (93, "feasible", 0),
     (138, "feasible", 0), (34, "infeasible", 1), (171, "infeasible", 1),
     (94, "infeasible", 0)],
)  # fmt: skip
def test_the_c_sqp_runs_the_check_as_the_library(
    c_sqp: Any, seed: int, kind: str, linear: int
) -> None:
    """The random SOCPs on which the library's infeasibility check runs without ending the
    solve (tests/test_daqp_socp.py's CHECKED_NOT_ENDED), and one it ends (94): the C SQP
    takes the same exit flag, SQP iterations, DAQP iterations (the check's solves among
    them) and kept iterates, the same point to 1e-9 where it converges (1e-6 relative
    where it fails, as the random SOCPs above)."""
    c, solve, buffers = c_sqp
    qp = controller_socp(seed, kind, bool(linear))
    pointer = write_c(c, qp)
    ws, arrays = problem_workspace(qp, buffers)
    flag, sqp, total, _violation, _seconds = socp_solve(ws, False, MAX_ITERATIONS)
    c_flag, c_iterations, c_total, _c_violation = c_solve(solve, c, pointer)
    s = pointer.contents
    assert (c_flag, c_iterations, c_total) == (flag, sqp, total)
    assert list(s.cut_state) == list(arrays["cut_state"])
    n = qp.H.shape[0]
    z = np.ctypeslib.as_array(s.z)[:n]
    tolerance = 1e-9 if flag in (1, 2) else 1e-6  # (a failed solve's last iterate: 1e-6)
    np.testing.assert_allclose(z, arrays["z"], rtol=0, atol=tolerance * (1 + np.abs(z).max()))


@pytest.mark.parametrize("seed", [18, 59])
def test_the_c_check_keeps_a_feasible_problem_at_a_cones_apex_feasible(
    c_sqp: Any, seed: int
) -> None:
    """apex_socp (tests/test_daqp_socp.py): the C check shifts and loosens its planes as
    the library's, so it ends no solve there (cut_state[2] = 0; without the shift it ended
    seed 18 at SQP iteration 19). (Its exit flag and last iterates may differ from the
    library's on this problem, which stalls at the apex: the two DAQP builds' ulps, with
    or without the check.)"""
    from ltv_lstm_mpc.solvers.testing import apex_socp

    c, solve, buffers = c_sqp
    qp = apex_socp(seed)
    pointer = write_c(c, qp)
    ws, arrays = problem_workspace(qp, buffers)
    socp_solve(ws, False, MAX_ITERATIONS)
    c_solve(solve, c, pointer)
    s = pointer.contents
    assert s.cut_state[2] == 0 and arrays["cut_state"][2] == 0


@pytest.mark.parametrize("kind", PREDICTED_EPIGRAPH_KINDS)
def test_the_c_sqp_ends_on_a_reduced_subproblems_verdict_as_the_library(
    c_sqp: Any, kind: str
) -> None:
    """solvers.testing.predicted_epigraph_socp, its first cone predicted active: the C SQP
    ends the infeasible one on its reduced subproblem's verdict, and solves the feasible
    ones' whole subproblems, as the library: the same exit flag, SQP and DAQP iterations,
    and point where it converges."""
    from ltv_lstm_mpc.solvers.testing import predicted_epigraph_socp

    c, solve, buffers = c_sqp
    qp = predicted_epigraph_socp(kind)
    pointer = write_c(c, qp)
    pointer.contents.first_active[0] = 1
    ws, arrays = problem_workspace(qp, buffers)
    arrays["first_active"][0] = 1
    flag, sqp, total, _violation, _seconds = socp_solve(ws, False, MAX_ITERATIONS)
    c_flag, c_iterations, c_total, _c_violation = c_solve(solve, c, pointer)
    assert (c_flag, c_iterations, c_total) == (flag, sqp, total)
    feasible = kind != "infeasible"
    assert (flag > 0) == feasible and (feasible or sqp == 2)
    if feasible:
        z = np.ctypeslib.as_array(pointer.contents.z)[:2]
        np.testing.assert_allclose(z, arrays["z"], rtol=0, atol=1e-12)


@pytest.mark.parametrize("which", [0, 1])
def test_the_c_sqp_solves_badly_scaled_reduced_subproblems_whole(
    request: pytest.FixtureRequest, which: int
) -> None:
    """solvers.testing.badly_scaled_epigraph_socp (0: 4 cones, in the fixture with room for
    them, a reduced Hessian of order 1e12 against 1; 1: 3 cones, 1.7e12, 100 times W's
    largest entry): the C SQP declines its reduced subproblems' verdicts beyond
    SQP_REDUCED_HESSIAN_LIMIT and SQP_REDUCTION_SCALE as the library does, and converges
    with it: the same exit flag and SQP iterations, the point within 1e-6 (relative; DAQP's
    iterations on such a problem differ between the daqp package's build the library calls
    and the C's). On 0 the row's test and the Hessian's both decline, each enough alone
    (the C with both off fails here); on 1 the Hessian's absolute limit. Each test alone:
    test_the_c_reduction_takes_a_verdict_only_within_scale_as_the_library."""
    from ltv_lstm_mpc.solvers.testing import badly_scaled_epigraph_socp

    c, solve, buffers = request.getfixturevalue("c_sqp_four_cones" if which == 0 else "c_sqp")
    qp = badly_scaled_epigraph_socp(which)
    pointer = write_c(c, qp)
    ws, arrays = problem_workspace(qp, buffers)
    flag, sqp, _total, _violation, _seconds = socp_solve(ws, False, MAX_ITERATIONS)
    c_flag, c_iterations, _c_total, _c_violation = c_solve(solve, c, pointer)
    assert (c_flag, c_iterations) == (flag, sqp)
    assert flag > 0 and sqp <= MAX_ITERATIONS
    n = qp.H.shape[0]
    z = np.ctypeslib.as_array(pointer.contents.z)[:n]
    np.testing.assert_allclose(z, arrays["z"], rtol=0, atol=1e-6 * (1 + np.abs(z).max()))


@pytest.mark.parametrize(
    ("epsilon", "cost_x", "cost_t", "proves"),
    [case[1:] for case in REDUCTION_SCALE_CASES],
    ids=[case[0] for case in REDUCTION_SCALE_CASES],
)
def test_the_c_reduction_takes_a_verdict_only_within_scale_as_the_library(
    c_sqp: Any, epsilon: float, cost_x: float, cost_t: float, proves: bool
) -> None:
    """sqp_reduction_proves (through the test build's ctl_test_reduction_proves) on the
    state of solvers.testing.REDUCTION_SCALE_CASES, written into the controller's
    <prefix>_socp: each of its three scale tests declines alone where the library's
    _reduction_proves does (the row's entries, the reduced Hessian against W's largest
    entry and against SQP_REDUCED_HESSIAN_LIMIT), and the verdict is taken within scale."""
    c, _solve, _buffers = c_sqp
    s = c._socp(c.state_buffer, 1).contents
    s.n, s.m, s.cones = 2, 0, 1
    s.cone_rows[0], s.cone_rows[1] = 0, 1
    views = {
        "hessian": np.ctypeslib.as_array(s.hessian)[:4].reshape(2, 2),
        "A_k": np.ctypeslib.as_array(s.A_k)[:2].reshape(1, 2),
        "bupper": np.ctypeslib.as_array(s.bupper),
        "blower": np.ctypeslib.as_array(s.blower),
        "epigraph": np.ctypeslib.as_array(s.epigraph),
        "eliminated": np.ctypeslib.as_array(s.eliminated),
        "reduced_index": np.ctypeslib.as_array(s.reduced_index),
        "tau": np.ctypeslib.as_array(s.tau)[:2].reshape(1, 2),
    }
    write_reduction_case(views, epsilon, cost_x, cost_t)
    proves_c = c.library.ctl_test_reduction_proves
    proves_c.argtypes = [ctypes.c_void_p, ctypes.c_int]
    proves_c.restype = ctypes.c_int
    assert bool(proves_c(ctypes.addressof(s), 1)) is proves
