"""The scripts in ``experiments/`` stay runnable: each answers ``--help`` at once (usage, what
it measures and the docs page its figures go to; no numerical library imported, nothing
run or written), and each benchmark runs end to end on a tiny size and prints its table.

The smoke runs are subprocesses started in ``tmp_path`` (anything a script writes lands
there); a script whose optional extra is missing is skipped. Runs that take long by nature
(a training, a Dask cluster, an empty numba cache, acados' generated C) are marked ``slow``.
"""

from __future__ import annotations

import json
import subprocess
import sys
from dataclasses import dataclass
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
EXPERIMENTS = ROOT / "experiments"
SCRIPTS = sorted(path.name for path in EXPERIMENTS.glob("*.py"))

#: Top-level modules that ``--help`` must not import (numba alone takes about a second).
HEAVY = {
    "numpy",
    "scipy",
    "numba",
    "ltv_lstm_mpc",
    "torch",
    "casadi",
    "cvxpy",
    "clarabel",
    "daqp",
    "dask",
    "distributed",
}


#: tests/training_factories.py's tiny data and training: a delta-ISS model within seconds.
TINY_DATA = json.dumps(dict(seed=1, sequences=4, steps=200, split_sizes=[2, 1, 1]))
TINY_TRAINING = json.dumps(
    dict(epochs=5, max_extra_epochs=300, lr=0.02, checkpoint_every=0, equilibrium_steps=100)
)


@dataclass(frozen=True)
class Smoke:
    """A tiny run of one benchmark: its arguments (``{tmp}``: the test's ``tmp_path``,
    ``{root}``: the checkout), what its output must hold, the files it must write, the
    optional modules it needs, and whether it is slow by nature."""

    args: tuple[str, ...]
    prints: tuple[str, ...]
    needs: tuple[str, ...] = ("daqp",)
    writes: tuple[str, ...] = ()
    slow: bool = False
    timeout: float = 300.0


SMOKE = {
    "acados_speed.py": Smoke(
        (
            "--N",
            "5",
            "--steps",
            "90",
            "--scenario",
            "paper3-dense",
            "--acados",
            "{root}/.acados",
            "--build",
            "{tmp}/build",
        ),
        (
            "N = 5 (microseconds",
            "ours: full step (one call)",
            "full step / solve() =",
            "fallback steps (",
            "failed steps (",
            "max/med",
        ),
        needs=("daqp", "casadi"),
        slow=True,
        timeout=600.0,
    ),
    "backend_overhead.py": Smoke(
        ("--N", "5", "--solvers", "daqp", "--states", "1", "--repeats", "5"),
        ("solve_point", "DAQP entry point", "daqp.solve"),
    ),
    "campaign_throughput.py": Smoke(
        (
            "--tasks",
            "2",
            "--steps",
            "30",
            "--workers",
            "1",
            "--repeat",
            "1",
            "--json",
            "{tmp}/throughput.json",
        ),
        ("throughput ratio", "scheduling overhead", "same results          True"),
        needs=("daqp", "distributed"),
        writes=("throughput.json",),
        slow=True,
    ),
    "cold_start.py": Smoke(
        ("--source", "{root}", "--steps", "20"),
        ("warm cache (auto): import", "the median step of the 20 after them", "(compiled)"),
    ),
    "condensing_speed.py": Smoke(
        ("--repeats", "3", "--n", "5", "--N", "5"),
        ("forward us", "diagonal   5  1   5", "    full   5  1   5"),
    ),
    "daqp_kept_workspace.py": Smoke(
        ("--N", "20", "--steps", "200", "--repeats", "2"), ("kept / fresh", "same bits")
    ),
    "dense_session_scaling.py": Smoke(
        ("--solvers", "daqp", "--n", "10", "--json", "{tmp}/rows.json"),
        ("first s", "OPTIMAL"),
        writes=("rows.json",),
    ),
    "equilibration_effect.py": Smoke(
        ("--solvers", "daqp", "--count", "2"),
        ("max point error", "scaled 1e6", "MPC"),
        needs=("daqp", "quadprog"),
    ),
    "exact_cones_speed.py": Smoke(
        ("--steps", "15", "--N", "5"),
        ("/daqp", "daqp:socp", "cvxpy:CLARABEL"),
        needs=("daqp", "clarabel", "cvxpy"),
    ),
    "export_pil.py": Smoke(
        ("--steps", "20", "--count", "3", "--step-runs", "ph5", "ph5c"),
        (
            "pH (n = 5)",
            "quadruple tank (n = 8)",
            "host - library",
            "pH scenario 3, N = 5",
            "N = 5, cones",
        ),
        needs=("daqp",),
    ),
    "export_speed.py": Smoke(
        ("--N", "5", "--steps", "30", "--repeats", "1", "--float"),
        ("C (gcc)", "C / Python", "C float", "float / double"),
        needs=("daqp",),
    ),
    "export_sil.py": Smoke(
        ("--N", "5", "--steps", "20", "--only", "3", "--solver", "daqp", "daqp:socp"),
        ("policy steps", "max |du|/|u|", "equal", "daqp:socp"),
        needs=("daqp",),
    ),
    "export_float.py": Smoke(
        ("--N", "5", "--steps", "20", "--only", "3"),
        ("w_bar share", "max |du|/|u|", "status diff"),
        needs=("daqp",),
    ),
    "gc_jitter.py": Smoke(
        ("--steps", "40", "--block", "20", "--N", "5"),
        ("collector on", "collector paused", "unreachable objects"),
    ),
    "growth_with_n.py": Smoke(
        ("--steps", "15", "--sizes", "5", "10", "--m", "1"),
        ("median us", "/ n=5", " 10    1 |"),
    ),
    "pipeline_speed.py": Smoke(
        ("--numpy-kernel", "--steps", "15", "--solvers", "daqp", "--N", "5"),
        ("step med", "new/old", "daqp   5 |"),
    ),
    "rti_quality.py": Smoke(
        ("--steps", "15", "--out", "{tmp}/rti.json"),
        ("first_input_difference_max", "closed_loop_cost_relative_difference"),
        writes=("rti.json",),
    ),
    "sparse_cones_crossover.py": Smoke(
        ("--steps", "15", "--N", "5"),
        ("sparse/condensed", "max |du0|"),
        needs=("daqp", "clarabel", "cvxpy"),
    ),
    "sqp_vs_exact_nmpc.py": Smoke(
        ("--states", "6"),
        ("default candidate: 6 states", "RTI infeasible: 6 states", "|u_0 SQP - u_0 IPOPT|"),
        needs=("daqp", "casadi"),
    ),
    "step_profile.py": Smoke(
        ("--steps", "15", "--N", "5", "--top", "5"),
        ("median step", "of which the solver call", "cProfile, per step"),
    ),
    "step_speed.py": Smoke(
        ("--steps", "15", "--N", "5"),
        ("daqp one-call", "cones daqp:socp", "socp prepared", "exact cones: clarabel / daqp"),
        needs=("daqp", "clarabel"),
    ),
    "worst_case.py": Smoke(
        ("--N", "5", "--steps", "80", "--solvers", "daqp", "daqp:socp", "--parts"),
        ("p99/", "daqp N=5 scenario 3", "daqp N=5 bench 1", "failed nominal SQP"),
    ),
    "train_fidelity.py": Smoke(
        (
            "--tag",
            "smoke",
            "--log",
            "{tmp}/log.md",
            "--out-root",
            "{tmp}/runs",
            "--data-options",
            TINY_DATA,
            "--config",
            TINY_TRAINING,
        ),
        ("| smoke | checkpoint_every=0, epochs=5",),
        needs=("torch",),
        writes=("log.md", "runs/smoke"),
        slow=True,
    ),
}

#: Scripts that are not benchmarks, each with a test of its own below.
NOT_BENCHMARKS = {"make_example_model.py"}


def run_script(
    script: str, args: list[str], cwd: Path, timeout: float, python_options: tuple[str, ...] = ()
) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, *python_options, str(EXPERIMENTS / script), *args],
        cwd=cwd, capture_output=True, text=True, timeout=timeout, check=False,
    )  # fmt: skip


@pytest.mark.parametrize("script", SCRIPTS)
def test_help_answers_at_once_without_running(script: str, tmp_path: Path) -> None:
    """``--help`` prints the usage, what the script measures and the docs page of its figures,
    exits 0, imports no numerical library (the script parses its arguments first) and writes
    nothing."""
    done = run_script(script, ["--help"], tmp_path, 60.0, ("-X", "importtime"))
    assert done.returncode == 0, done.stderr[-2000:]
    assert done.stdout.startswith("usage:"), done.stdout[:500]
    assert "docs/" in done.stdout, "the help names no docs page for the figures"
    imported = {
        line.rsplit("|", 1)[-1].strip().split(".")[0]
        for line in done.stderr.splitlines()
        if line.startswith("import time:")
    }
    assert not imported & HEAVY, f"--help imported {sorted(imported & HEAVY)}"
    assert list(tmp_path.iterdir()) == [], "--help wrote files"


def test_every_script_has_a_smoke_run() -> None:
    """A new script gets a tiny run here (or a test of its own); a removed one leaves none."""
    assert set(SMOKE) | NOT_BENCHMARKS == set(SCRIPTS)
    assert not set(SMOKE) & NOT_BENCHMARKS


@pytest.mark.parametrize(
    "script",
    [
        pytest.param(name, marks=pytest.mark.slow) if smoke.slow else name
        for name, smoke in SMOKE.items()
    ],
)
def test_benchmark_runs_on_a_tiny_size(script: str, tmp_path: Path) -> None:
    """The benchmark runs end to end on a tiny size, exits 0 and prints its table."""
    smoke = SMOKE[script]
    for module in smoke.needs:
        pytest.importorskip(module)
    if script == "acados_speed.py" and not (ROOT / ".acados" / "acados").is_dir():
        pytest.skip("acados is not installed into .acados (docs/benchmarks.md says how)")
    args = [arg.replace("{tmp}", str(tmp_path)).replace("{root}", str(ROOT)) for arg in smoke.args]
    done = run_script(script, args, tmp_path, smoke.timeout)
    output = f"stdout:\n{done.stdout[-3000:]}\nstderr:\n{done.stderr[-3000:]}"
    assert done.returncode == 0, output
    for text in smoke.prints:
        assert text in done.stdout, f"{text!r} not printed\n{output}"
    for name in smoke.writes:
        assert (tmp_path / name).exists(), f"{name} not written\n{output}"


@pytest.mark.slow
def test_cold_start_with_an_empty_cache(tmp_path: Path) -> None:
    """``cold_start.py``'s default row: a copy of the package with an empty numba cache runs
    the numpy kernels while they compile in the background, and waits for them (minutes)."""
    pytest.importorskip("daqp")
    done = run_script("cold_start.py", ["--steps", "20"], tmp_path, 900.0)
    output = f"stdout:\n{done.stdout[-3000:]}\nstderr:\n{done.stderr[-3000:]}"
    assert done.returncode == 0, output
    assert "empty cache (auto): import" in done.stdout and "(numpy)" in done.stdout, output
    assert "background compilation done" in done.stdout, output
    assert "warm cache (auto): import" in done.stdout and "(compiled)" in done.stdout, output


def test_example_model_script_rebuilds_the_shipped_file(tmp_path: Path) -> None:
    """``make_example_model.py`` writes the shipped ``example_delta_iss_n3.npz`` again: the
    same arrays (sampling time included) to rounding."""
    np = pytest.importorskip("numpy")
    done = run_script("make_example_model.py", [str(tmp_path / "example.npz")], tmp_path, 120.0)
    assert done.returncode == 0, done.stderr[-2000:]
    assert "rho(A_delta) = " in done.stdout and "wrote" in done.stdout
    with (
        np.load(tmp_path / "example.npz") as built,
        np.load(ROOT / "ltv_lstm_mpc" / "data" / "example_delta_iss_n3.npz") as shipped,
    ):
        assert sorted(built.files) == sorted(shipped.files)
        for name in shipped.files:
            np.testing.assert_allclose(built[name], shipped[name], rtol=1e-12, atol=1e-12)
