"""``ltv-lstm-mpc export-c`` and :func:`ltv_lstm_mpc.export.package.export_controller_c`:
the C project (sources, DAQP, Makefile, CMakeLists.txt, example, README) builds with make
and with CMake under the strict flags, and its example, the controller in closed loop on
its own LSTM model, reaches the set-point without offset. Skipped without make or a C
compiler."""

from __future__ import annotations

import shutil
import subprocess
from pathlib import Path

import pytest

from ltv_lstm_mpc import MPCConfig, OffsetFreeController
from ltv_lstm_mpc.cli.main import main
from ltv_lstm_mpc.export.package import export_controller_c
from ltv_lstm_mpc.lstm.shipped import load_model

pytest.importorskip("daqp")
needs_make = pytest.mark.skipif(
    shutil.which("make") is None or not any(shutil.which(c) for c in ("cc", "gcc", "clang")),
    reason="no make or C compiler",
)


def final_offset(output: str) -> float:
    """The example's last line: ``final offset X (physical units), steps refused 0``."""
    line = [row for row in output.splitlines() if row.startswith("final offset")][-1]
    assert line.endswith("steps refused 0"), line
    return float(line.split()[2])


@needs_make
def test_export_c_writes_a_project_that_builds_and_tracks(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """The command on the pH model with --build: the files, the strict build by make, the
    example's final offset below 1e-6 pH."""
    out = tmp_path / "ph_c"
    assert main(["export-c", "--out", str(out), "--prefix", "ph", "--N", "5", "--build"]) == 0
    printed = capsys.readouterr().out
    for name in ("ph.h", "ph.c", "Makefile", "CMakeLists.txt", "README.md", "example.c"):
        assert (out / name).is_file(), name
    assert (out / "daqp" / "LICENSE").is_file() and (out / "daqp" / "no_heap.h").is_file()
    readme = (out / "README.md").read_text()
    for text in ("ph_controller_step", "PH_STEP_BAD_MEASUREMENT", "DAQP 0.11.0", "N = 5"):
        assert text in readme, text
    assert final_offset(printed) < 1e-6


@needs_make
def test_a_mimo_project_builds_with_cmake(tmp_path: Path) -> None:
    """The quadruple tank's controller (two pumps, two levels, the soft policy) through the
    Python API, built by CMake with -Werror: the example tracks without offset."""
    if shutil.which("cmake") is None:
        pytest.skip("no cmake")
    model = load_model("quadtank_lstm_n8.npz")
    config = MPCConfig(solver="daqp", N=5, infeasibility_policy="soft")
    controller = OffsetFreeController(model, config, kernels="numpy")
    export_controller_c(controller, tmp_path, prefix="tank")
    build = tmp_path / "build"
    strict = "-Wall -Wextra -Wpedantic -Werror"
    for command in (
        ["cmake", "-S", str(tmp_path), "-B", str(build), f"-DCMAKE_C_FLAGS={strict}"],
        ["cmake", "--build", str(build)],
    ):
        done = subprocess.run(command, capture_output=True, text=True)
        assert done.returncode == 0, done.stdout[-2000:] + done.stderr[-2000:]
    run = subprocess.run([str(build / "tank_example")], capture_output=True, text=True)
    assert run.returncode == 0, run.stdout + run.stderr
    assert final_offset(run.stdout) < 1e-6


@needs_make
def test_export_c_writes_the_exact_cones_for_another_model(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """--solver daqp:socp on a model that is not the pH plant's (the delta-ISS example,
    n = 3): the project builds under the strict flags, its example tracks without offset,
    its README names the cone statuses and no pH figure; --float with the cones is
    refused with the reason."""
    out = tmp_path / "own"
    arguments = ["export-c", "example_delta_iss_n3.npz", "--out", str(out), "--prefix", "own"]
    assert main([*arguments, "--N", "7", "--solver", "daqp:socp", "--build"]) == 0
    printed = capsys.readouterr().out
    assert "solver daqp:socp" in printed
    assert final_offset(printed) < 1e-6
    readme = (out / "README.md").read_text()
    for text in ("OWN_STATUS_CONE_FAILED", "own_controller_socp", "exact second-order cones"):
        assert text in readme, text
    assert "pH" not in readme
    assert main([*arguments, "--solver", "daqp:socp", "--float"]) != 0
    assert "double precision only" in capsys.readouterr().err
