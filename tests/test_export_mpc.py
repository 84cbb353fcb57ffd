"""The C99 export of the MPC's subproblem (ltv_lstm_mpc/export: ``mpc=``): the linearized,
condensed QP of eq. (optimization), DAQP (vendored, on the caller's workspace), the
acceptance tests, the infeasibility policies and the plan's re-simulation equal
``RobustMPC.prepare``/``feedback`` step by step over closed loops with infeasible instants;
the build is warning-free under the strict flags, allocation-free (``nm``), and clean under
AddressSanitizer and UndefinedBehaviorSanitizer. Skipped where no C compiler is installed."""

from __future__ import annotations

import ctypes
import shutil
import subprocess
from dataclasses import replace
from pathlib import Path
from types import SimpleNamespace
from typing import Any

import numpy as np
import pytest

from ltv_lstm_mpc import MPCConfig, OffsetFreeController, simulate
from ltv_lstm_mpc.benchmarks.quadtank import quadtank_scenarios
from ltv_lstm_mpc.exceptions import InvalidValueError
from ltv_lstm_mpc.export import export_model_c
from ltv_lstm_mpc.export.sil import CONE_FAILED, CONE_MAX_ITER, FeedbackResult, compile_controller
from ltv_lstm_mpc.export.sil import MPC_STATUS_NAMES as STATUS_NAMES
from ltv_lstm_mpc.export.sil import POLICY_NAMES as POLICIES
from ltv_lstm_mpc.lstm.shipped import load_model
from ltv_lstm_mpc.paper.scenarios import paper_scenarios

pytest.importorskip("daqp")

COMPILERS = [name for name in ("gcc", "clang") if shutil.which(name)]
STRICT = ["-std=c99", "-O2", "-Wall", "-Wextra", "-Wpedantic", "-Werror"]
needs_compiler = pytest.mark.skipif(not COMPILERS, reason="no C compiler (gcc or clang)")


def build(folder: Path, prefix: str, compiler: str) -> Path:
    """The export in ``folder`` (``<prefix>.c`` and DAQP's sources) as a shared library."""
    exported = SimpleNamespace(source=folder / f"{prefix}.c", prefix=prefix, single=False)
    return compile_controller(exported, compiler)


class CMPC:
    """The exported subproblem through ctypes."""

    def __init__(self, library: Path, prefix: str, exported: Any, N: int) -> None:
        lib = ctypes.CDLL(str(library))
        self.lib, self.N, self.n, self.m, self.p = lib, N, exported.n, exported.m, exported.p
        self.workspace = ctypes.create_string_buffer(exported.mpc_workspace_bytes)
        pointer = np.ctypeslib.ndpointer(dtype=np.float64, flags="C_CONTIGUOUS")
        ws = ctypes.c_void_p
        self.linearize = getattr(lib, f"{prefix}_linearize")
        self.linearize.argtypes, self.linearize.restype = [ws, pointer, pointer], None
        self.condense = getattr(lib, f"{prefix}_condense")
        self.condense.argtypes = [ws, pointer, pointer, pointer, pointer, ctypes.c_double]
        self.condense.restype = ctypes.c_double
        self.feedback = getattr(lib, f"{prefix}_feedback")
        self.feedback.argtypes = [ws, *[pointer] * 5, ctypes.c_double, ctypes.c_double,
                                  ctypes.POINTER(FeedbackResult)]  # fmt: skip
        self.feedback.restype = None

    def solve(self, entry: dict[str, Any]) -> tuple[FeedbackResult, np.ndarray]:
        """Linearize, condense and feed back one captured step; (result, plan inputs)."""
        n2, m, N = 2 * self.n, self.m, self.N
        S = entry["S"]
        c = np.ascontiguousarray
        self.linearize(self.workspace, c(S[0, :n2]), c(S[:N, n2 : n2 + m]))
        scale = self.condense(
            self.workspace, c(entry["x_bar"]), c(entry["u_bar"]), c(entry["lower"]),
            c(entry["upper"]), entry["alpha"],
        )  # fmt: skip
        result = FeedbackResult()
        self.feedback(
            self.workspace, c(entry["x_hat"]), c(entry["x_bar"]), c(entry["u_bar"]),
            c(entry["lower"]), c(entry["upper"]), entry["alpha"], scale, ctypes.byref(result),
        )  # fmt: skip
        return result, self.plan_inputs()

    def plan_inputs(self) -> np.ndarray:
        """``w->u`` (its offset: the fields before it, from the exported layout)."""
        return self._u_view.copy()

    def bind_u(self, offset: int) -> None:
        """Where ``u`` lies in the workspace (from ``<prefix>_mpc_u_offset``)."""
        count = self.N * self.m
        self._u_view = np.frombuffer(self.workspace, dtype=np.float64, count=count,
                                     offset=offset).reshape(self.N, self.m)  # fmt: skip


def capture(controller: OffsetFreeController) -> list[dict[str, Any]]:
    """Record every ``controller.mpc.feedback`` call: the linearization trajectory, the
    estimate, set-points, tightened bounds and alpha_k it runs on, and its solution."""
    mpc = controller.mpc
    original = mpc.feedback
    rows: list[dict[str, Any]] = []

    def feedback(x_hat: Any, *args: Any, **kwargs: Any) -> Any:
        entry = {
            "S": mpc._traj.S.copy(),
            "x_hat": np.array(x_hat, dtype=np.float64),
            "x_bar": np.array(mpc._x_bar, dtype=np.float64),
            "u_bar": np.array(mpc._u_bar, dtype=np.float64),
            "lower": np.array(mpc._lower, dtype=np.float64),
            "upper": np.array(mpc._upper, dtype=np.float64),
            "alpha": float(mpc._alpha),
        }
        entry["solution"] = original(x_hat, *args, **kwargs)
        rows.append(entry)
        return entry["solution"]

    mpc.feedback = feedback  # type: ignore[method-assign]
    return rows


def closed_loop(
    plant_name: str, policy: str, N: int, steps: int, solver: str = "daqp", period: int = 0
) -> tuple[OffsetFreeController, list[dict[str, Any]]]:
    """A closed loop with infeasible instants on the reference engine (every step through
    ``RobustMPC.feedback``) with ``policy``: the paper's scenario 3 on the pH plant (its
    set-point levels cycled every ``period`` samples where given), or the quadruple tank's
    set-point changes."""
    if plant_name == "ph":
        model = load_model("ph_lstm_n5.npz")
        scenario: Any = paper_scenarios(model)[2]
        if period:
            scenario = scenario.cycled(period)
        plant = None
    else:
        model = load_model("quadtank_lstm_n8.npz")
        scenario = quadtank_scenarios(short=True)[0]
        plant = scenario.make_plant(model)
    config = replace(scenario.config, solver=solver, N=N, infeasibility_policy=policy)
    controller = OffsetFreeController(
        model, config, setpoint_rate_limit=scenario.setpoint_rate_limit, one_call_step=False
    )
    rows = capture(controller)
    if plant is None:
        plant = scenario.make_plant(model, controller.certification)
    disturbances = scenario.disturbances if plant_name == "ph" else scenario.leaks
    simulate(plant, controller, scenario.setpoints, disturbances, steps, progress=False)
    return controller, rows


def export(controller: OffsetFreeController, folder: Path, prefix: str = "ctl") -> Any:
    return export_model_c(
        controller.model, folder, observer=controller.observer, reference=controller.reference,
        tightening=controller.mpc.tightening, mpc=controller.mpc, prefix=prefix,
    )  # fmt: skip


def u_offset(folder: Path, prefix: str, compiler: str) -> tuple[int, int, int]:
    """``offsetof(<prefix>_mpc_workspace, u)``, its ``sizeof`` and that of the model's
    workspace inside it (``<prefix>_workspace``), from a compiled probe."""
    probe = folder / "probe.c"
    probe.write_text(
        f'#include <stddef.h>\n#include <stdio.h>\n#include "{prefix}.h"\n'
        f'int main(void) {{ printf("%zu %zu %zu\\n", offsetof({prefix}_mpc_workspace, u), '
        f"sizeof({prefix}_mpc_workspace), sizeof({prefix}_workspace)); return 0; }}\n"
    )
    binary = folder / "probe"
    subprocess.run([compiler, "-std=c99", "-o", str(binary), str(probe)], check=True)
    found = subprocess.run([str(binary)], capture_output=True, text=True).stdout.split()
    offset, size, model_size = (int(value) for value in found)
    return offset, size, model_size


def compare(cmpc: CMPC, rows: list[dict[str, Any]]) -> dict[str, Any]:
    """Every captured step through the C subproblem: statuses, policies and inputs."""
    worst_u = worst_cost = 0.0
    policies: dict[str, int] = {}
    for k, entry in enumerate(rows):
        solution = entry["solution"]
        result, u = cmpc.solve(entry)
        name = STATUS_NAMES.get(result.status, f"code {result.status}")
        assert name == solution.status, (k, name, solution.status, solution.reason)
        assert POLICIES[result.policy] == solution.policy, (k, result.policy, solution.policy)
        assert result.iterations == solution.iterations, k
        assert result.qp_iterations == solution.solver_iterations, k  # (DAQP's, all QPs)
        scale = max(1.0, float(np.abs(solution.u).max()))
        worst_u = max(worst_u, float(np.abs(u - solution.u).max()) / scale)
        worst_cost = max(worst_cost, abs(result.cost - solution.cost) / max(1.0, solution.cost))
        policies[solution.policy] = policies.get(solution.policy, 0) + 1
    return {"u": worst_u, "cost": worst_cost, "policies": policies}


@needs_compiler
@pytest.mark.parametrize("policy", ["paper", "soft", "shift"])
def test_the_c_subproblem_equals_robust_mpc_feedback(policy: str, tmp_path: Path) -> None:
    """Scenario 3 (set-point jumps with infeasible instants), 300 steps, N = 5: on every
    step the C subproblem gives RobustMPC.feedback's status, policy and SQP iterations
    exactly, its plan's inputs to 1e-9 (relative) and its cost to 1e-9."""
    controller, rows = closed_loop("ph", policy, 5, 300)
    exported = export(controller, tmp_path)
    compiler = COMPILERS[0]
    offset, size, model_size = u_offset(tmp_path, "ctl", compiler)
    assert size <= exported.mpc_workspace_bytes
    assert model_size == exported.workspace_bytes  # (the Newton/condensing union included)
    cmpc = CMPC(build(tmp_path, "ctl", compiler), "ctl", exported, 5)
    cmpc.bind_u(offset)
    found = compare(cmpc, rows)
    assert found["u"] <= 1e-9 and found["cost"] <= 1e-9, found
    assert set(found["policies"]) - {"nominal"}, found  # the policy ran somewhere


@needs_compiler
@pytest.mark.parametrize(("N", "backward"), [(5, "0"), (40, "1")])
def test_the_c_picks_the_librarys_condensing_form(N: int, backward: str, tmp_path: Path) -> None:
    """H and g0 as the library forms them (CondensedTranscription.backward_condensing):
    rank updates on the causal columns for N m <= 3.5 (2n) with diagonal weights (pH,
    2n = 10: N = 5), the backward recursion beyond (N = 40); either equals
    RobustMPC.feedback to 1e-9 over 80 steps of scenario 3."""
    controller, rows = closed_loop("ph", "paper", N, 80)
    assert controller.mpc._problem.backward_condensing == (backward == "1")
    exported = export(controller, tmp_path)
    assert f"#define BACKWARD_CONDENSING {backward}\n" in exported.source.read_text()
    compiler = COMPILERS[0]
    offset, _, _ = u_offset(tmp_path, "ctl", compiler)
    cmpc = CMPC(build(tmp_path, "ctl", compiler), "ctl", exported, N)
    cmpc.bind_u(offset)
    found = compare(cmpc, rows)
    assert found["u"] <= 1e-9 and found["cost"] <= 1e-9, found


@needs_compiler
@pytest.mark.parametrize("N", [15, 20])
def test_the_c_paper_qp_keeps_daqps_workspace_from_keep_from(N: int, tmp_path: Path) -> None:
    """Where DAQP proves the nominal QP infeasible the C's paper QP runs on its set-up
    (qp_solve_box_from, the library's box_quadprog_from) from KEEP_FROM variables on
    (counted in a -DCTL_TEST_HOOKS build), not below; every step as RobustMPC.feedback
    gives it (statuses, policies, the DAQP iterations of both QPs), and bit for bit as the
    same C with nothing kept (scenario 3, set-points cycled every 40 samples: 2400 steps,
    in which some box QPs' unconstrained optimum holds: one iteration, redone fresh)."""
    from ltv_lstm_mpc.solvers.daqp_native import KEEP_FROM

    controller, rows = closed_loop("ph", "paper", N, 2400 if N >= KEEP_FROM else 200, period=40)
    exported = export(controller, tmp_path)
    compiler = COMPILERS[0]
    offset, _, _ = u_offset(tmp_path, "ctl", compiler)
    library = compile_controller(exported, compiler, extra_flags=("-DCTL_TEST_HOOKS",))
    cmpc = CMPC(library, "ctl", exported, N)
    cmpc.bind_u(offset)
    found = compare(cmpc, rows)
    assert found["u"] <= 1e-9 and found["cost"] <= 1e-9, found
    assert found["policies"].get("paper", 0) >= 10, found
    if N < KEEP_FROM:  # (not compiled in below KEEP_FROM)
        with pytest.raises(ValueError):
            ctypes.c_long.in_dll(cmpc.lib, "ctl_test_kept_solves")
        return
    assert ctypes.c_long.in_dll(cmpc.lib, "ctl_test_kept_solves").value >= 100
    kept = [cmpc.solve(entry) for entry in rows]  # (the plan's inputs copied)
    ctypes.c_int.in_dll(cmpc.lib, "ctl_test_keep_off").value = 1
    solved = ctypes.c_long.in_dll(cmpc.lib, "ctl_test_kept_solves").value
    for entry, (result, u) in zip(rows, kept, strict=True):
        fresh, fresh_u = cmpc.solve(entry)
        np.testing.assert_array_equal(u, fresh_u)
        assert bytes(result) == bytes(fresh)  # every field, to the last bit
    assert ctypes.c_long.in_dll(cmpc.lib, "ctl_test_kept_solves").value == solved
    # an output row with equal bounds (DAQP makes it an immutable active row, which leaves
    # the bounds' LDP terms formed otherwise): never kept, the same bits as nothing kept
    ctypes.c_int.in_dll(cmpc.lib, "ctl_test_keep_off").value = 0
    equal = []
    for entry, (result, _) in zip(rows, kept, strict=True):
        if POLICIES[result.policy] != "paper":
            continue
        entry = dict(entry, lower=entry["lower"].copy(), upper=entry["upper"].copy())
        entry["lower"][-1] = entry["upper"][-1] = 0.5 * (entry["lower"][-1] + entry["upper"][-1])
        equal.append((entry, cmpc.solve(entry)))
    assert ctypes.c_long.in_dll(cmpc.lib, "ctl_test_kept_solves").value == solved
    assert sum(POLICIES[result.policy] == "paper" for _, (result, _) in equal) >= 10
    ctypes.c_int.in_dll(cmpc.lib, "ctl_test_keep_off").value = 1
    for entry, (result, u) in equal:
        fresh, fresh_u = cmpc.solve(entry)
        np.testing.assert_array_equal(u, fresh_u)
        assert bytes(result) == bytes(fresh)


@needs_compiler
def test_the_c_subproblem_equals_feedback_on_the_quadruple_tank(tmp_path: Path) -> None:
    """The quadruple tank (n = 8, two pumps, two levels), 240 steps at N = 5 and N = 20:
    statuses, policies exactly, inputs and cost to 1e-9."""
    for N in (5, 20):
        controller, rows = closed_loop("quadtank", "paper", N, 240)
        folder = tmp_path / f"N{N}"
        exported = export(controller, folder)
        compiler = COMPILERS[-1]
        offset, _, _ = u_offset(folder, "ctl", compiler)
        cmpc = CMPC(build(folder, "ctl", compiler), "ctl", exported, N)
        cmpc.bind_u(offset)
        found = compare(cmpc, rows)
        assert found["u"] <= 1e-9 and found["cost"] <= 1e-9, found


@needs_compiler
def test_the_c_prechecks_equal_feedback(tmp_path: Path) -> None:
    """The pre-checks no solver can fix, as RobustMPC.feedback words them: an estimate whose
    first output leaves its tightened bounds (infeasible_initial) and a set-point outside
    the admissible interval (alpha_nonpositive), each followed by the policy."""
    controller, rows = closed_loop("ph", "paper", 5, 40)
    mpc = controller.mpc
    n2 = 2 * controller.model.n
    entry = rows[-1]
    y0, e_hat = controller.records[-1].y0, controller.records[-1].e_hat
    checks = []
    for shift, setpoint in ((3.0, y0), (0.0, y0 + 50.0)):
        mpc.prepare(
            entry["x_bar"], entry["u_bar"], setpoint, e_hat, x_pred=entry["S"][0, :n2],
            warm=entry["S"][:-1, n2 : n2 + controller.model.m],
        )  # fmt: skip
        x_hat = entry["x_hat"].copy()
        x_hat[n2 // 2 :] += shift
        mpc.feedback(x_hat)
        checks.append(rows[-1])
    assert [c["solution"].status for c in checks] == ["infeasible_initial", "alpha_nonpositive"]
    exported = export(controller, tmp_path)
    offset, _, _ = u_offset(tmp_path, "ctl", COMPILERS[0])
    cmpc = CMPC(build(tmp_path, "ctl", COMPILERS[0]), "ctl", exported, 5)
    cmpc.bind_u(offset)
    found = compare(cmpc, checks)
    assert found["u"] <= 1e-9 and found["cost"] <= 1e-9, found


def test_the_export_refuses_what_it_cannot_run(tmp_path: Path) -> None:
    """An MPC on another solver or with globalized SQP, or not a RobustMPC: refused, naming
    the value and the fix."""
    model = load_model("ph_lstm_n5.npz")
    for config, match in (
        (MPCConfig(solver="osqp", N=5), "solver='osqp'"),
        (MPCConfig(solver="daqp", N=5, sqp_iterations=3), "sqp_iterations=1"),
    ):
        if config.solver == "osqp":
            pytest.importorskip("osqp")
        controller = OffsetFreeController(model, config)
        with pytest.raises(InvalidValueError, match=match):
            export_model_c(model, tmp_path, mpc=controller.mpc)
    with pytest.raises(InvalidValueError, match=r"controller\.mpc"):
        export_model_c(model, tmp_path, mpc=object())


DRIVER = r"""
#include <stdio.h>
#include <string.h>
#include "ctl.h"

#define NX CTL_NX
#define HN CTL_MPC_N
static ctl_mpc_workspace work[2]; /* two controllers in one program */

int main(int argc, char **argv)
{
    double S0[NX], cand[HN * CTL_M], x_hat[NX], x_bar[NX], u_bar[CTL_M];
    double lower[HN][CTL_P], upper[HN][CTL_P], alpha;
    FILE *in = fopen(argv[1], "rb");
    int i, k;
    (void)argc;
    for (k = 0;; ++k) {
        ctl_feedback_result result[2];
        if (fread(S0, sizeof S0, 1, in) != 1) {
            break;
        }
        if (fread(cand, sizeof cand, 1, in) != 1 || fread(x_hat, sizeof x_hat, 1, in) != 1 ||
            fread(x_bar, sizeof x_bar, 1, in) != 1 || fread(u_bar, sizeof u_bar, 1, in) != 1 ||
            fread(lower, sizeof lower, 1, in) != 1 || fread(upper, sizeof upper, 1, in) != 1 ||
            fread(&alpha, sizeof alpha, 1, in) != 1) {
            return 2;
        }
        for (i = 0; i < 2; ++i) {
            double scale;
            ctl_linearize(&work[i], S0, cand);
            scale = ctl_condense(&work[i], x_bar, u_bar, (const double (*)[CTL_P])lower,
                                 (const double (*)[CTL_P])upper, alpha);
            ctl_feedback(&work[i], x_hat, x_bar, u_bar, (const double (*)[CTL_P])lower,
                         (const double (*)[CTL_P])upper, alpha, scale, &result[i]);
        }
        if (memcmp(work[0].u, work[1].u, sizeof work[0].u) != 0 ||
            result[0].status != result[1].status) {
            return 3;
        }
        printf("%d %d %.17g", result[0].status, result[0].policy, result[0].cost);
        for (i = 0; i < HN * CTL_M; ++i) {
            printf(" %.17g", work[0].u[i / CTL_M][i % CTL_M]);
        }
        printf("\n");
    }
    fclose(in);
    return 0;
}
"""


def write_steps(rows: list[dict[str, Any]], path: Path, N: int, n2: int, m: int) -> None:
    """The captured steps as the driver reads them (float64, native order)."""
    parts = []
    for entry in rows:
        S = entry["S"]
        parts += [S[0, :n2], S[:N, n2 : n2 + m].ravel(), entry["x_hat"], entry["x_bar"]]
        parts += [entry["u_bar"], entry["lower"].ravel(), entry["upper"].ravel()]
        parts.append(np.array([entry["alpha"]]))
    np.concatenate(parts).astype(np.float64).tofile(path)


@needs_compiler
@pytest.mark.parametrize("solver", ["daqp", "daqp:socp"])
def test_the_c_subproblem_runs_clean_under_the_sanitizers(solver: str, tmp_path: Path) -> None:
    """A C driver replays 120 steps of scenario 3 (the policy included) on two workspaces
    in one program under AddressSanitizer and UndefinedBehaviorSanitizer, with the terminal
    box and with the exact cones: no report, both workspaces give the same plan, equal to
    RobustMPC.feedback's (statuses, policies exactly; a failed cone SQP where the library
    names the step infeasible or failed; inputs to 1e-9)."""
    controller, rows = closed_loop("ph", "soft", 5, 120, solver)
    export(controller, tmp_path)
    model = controller.model
    write_steps(rows, tmp_path / "steps.bin", 5, 2 * model.n, model.m)
    (tmp_path / "driver.c").write_text(DRIVER)
    compiler = COMPILERS[0]  # (gcc first: clang's sanitizer runtimes are a separate package)
    binary = tmp_path / "driver"
    daqp = sorted(str(p) for p in (tmp_path / "daqp" / "src").glob("*.c"))
    command = [
        compiler, *STRICT, "-g", "-fsanitize=address,undefined", "-fno-sanitize-recover=all",
        "-include", str(tmp_path / "daqp" / "no_heap.h"), "-I", str(tmp_path),
        "-I", str(tmp_path / "daqp" / "include"), "-o", str(binary), str(tmp_path / "driver.c"),
        str(tmp_path / "ctl.c"), *daqp, "-lm",
    ]  # fmt: skip
    done = subprocess.run(command, capture_output=True, text=True)
    if done.returncode and ("asan" in done.stderr or "ubsan" in done.stderr):
        pytest.skip(f"{compiler} has no sanitizer runtime here: {done.stderr[-300:]}")
    assert done.returncode == 0, done.stderr
    run = subprocess.run(
        [str(binary), str(tmp_path / "steps.bin")], capture_output=True, text=True, timeout=300
    )
    assert run.returncode == 0 and not run.stderr, run.stderr[-3000:]
    lines = run.stdout.split("\n")[:-1]
    assert len(lines) == len(rows)
    assert any(r["solution"].policy != "nominal" for r in rows)
    for k, (line, entry) in enumerate(zip(lines, rows, strict=True)):
        values = line.split()
        solution = entry["solution"]
        if int(values[0]) in (CONE_FAILED, CONE_MAX_ITER):  # (the certificates: Python's)
            assert not solution.feasible, k
        else:
            assert STATUS_NAMES[int(values[0])] == solution.status, k
        assert POLICIES[int(values[1])] == solution.policy, k
        u = np.array([float(v) for v in values[3:]]).reshape(solution.u.shape)
        assert np.abs(u - solution.u).max() <= 1e-9 * max(1.0, np.abs(solution.u).max()), k


@needs_compiler
@pytest.mark.parametrize("solver", ["daqp", "daqp:socp"])
def test_the_exported_objects_reference_no_heap_and_no_io(solver: str, tmp_path: Path) -> None:
    """``nm -u`` on every object of the export (the controller and DAQP, built as the
    user guide says: DAQP with ``no_heap.h``; the terminal box and the exact cones): no
    malloc, calloc, realloc, free, and no stdio; only libm and the C library's memory
    moves."""
    if solver == "daqp":
        controller, _ = closed_loop("ph", "paper", 5, 2)
    else:
        model = load_model("ph_lstm_n5.npz")
        config = MPCConfig(solver=solver, N=5, infeasibility_policy="soft")
        controller = OffsetFreeController(model, config, kernels="numpy")
    export(controller, tmp_path)
    sources = [tmp_path / "ctl.c", *sorted((tmp_path / "daqp" / "src").glob("*.c"))]
    undefined: set[str] = set()
    defined: set[str] = set()
    for source in sources:
        obj = tmp_path / (source.stem + ".o")
        command = [
            COMPILERS[0], *STRICT, "-c", "-include", str(tmp_path / "daqp" / "no_heap.h"),
            "-I", str(tmp_path / "daqp" / "include"), "-o", str(obj), str(source),
        ]  # fmt: skip
        subprocess.run(command, check=True)
        for flag, names in (("-u", undefined), ("--defined-only", defined)):
            listing = subprocess.run(["nm", flag, str(obj)], capture_output=True, text=True)
            names |= {line.split()[-1] for line in listing.stdout.splitlines() if line.strip()}
    external = undefined - defined
    assert not external & {"malloc", "calloc", "realloc", "free", "printf", "fprintf", "puts"}
    allowed = {"memcpy", "memmove", "memset", "sqrt", "fmax", "floor", "fabs", "copysign"}
    assert {name for name in external if not name.startswith("_")} <= allowed, external
