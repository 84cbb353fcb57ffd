"""The ``ltv-lstm-mpc`` command line."""

from __future__ import annotations

import json
import subprocess
import sys

import numpy as np
import pytest

from ltv_lstm_mpc import CertificationSettings, certify, load_model
from ltv_lstm_mpc.cli.main import main

REQUIRED_KEYS = {
    "rho_A_delta", "A_delta", "B_delta", "r1", "r2", "P_s", "rho_s", "c_s_l", "c_s_u", "c_s",
    "A_d", "P_o", "rho_o", "c_o", "L_max", "w_max", "a", "b", "e_inf", "P_f", "y0_interval",
    "K_bar", "inputs",
}  # fmt: skip


def test_certify_json_has_every_symbol_and_echoes_inputs(capsys) -> None:
    assert main(["certify", "example_delta_iss_n3.npz", "--json", "--L-d", "0.1", "--N", "7"]) == 0
    data = json.loads(capsys.readouterr().out)
    assert REQUIRED_KEYS <= set(data)
    inputs = data["inputs"]
    for key in ("u_max", "Q_s", "Q_o", "L_f", "L_i", "L_o", "L_d", "d_max", "w_bar", "Q", "N",
                "y_min", "y_max"):  # fmt: skip
        assert key in inputs
    assert inputs["L_d"] == [[0.1]] and inputs["N"] == 7
    assert len(data["a"]) == 8
    # The same numbers as the library call with the echoed inputs.
    model = load_model("example_delta_iss_n3.npz")
    direct = certify(model, CertificationSettings(l_d=0.1, N=7))
    assert data["rho_o"] == pytest.approx(direct.observer.rho_o, rel=1e-15)
    np.testing.assert_allclose(data["a"], direct.tightening.a, rtol=1e-15)


def test_certify_table_and_help(capsys) -> None:
    assert main(["certify"]) == 0
    out = capsys.readouterr().out
    assert "rho_A_delta" in out and "y0_interval_phi" in out
    with pytest.raises(SystemExit):
        main(["certify", "--help"])
    assert "--L-d" in capsys.readouterr().out


def test_certify_errors_are_clean(capsys, tmp_path) -> None:
    assert main(["certify", str(tmp_path / "missing.npz")]) == 1
    err = capsys.readouterr().err  # the path and the shipped models, one line
    assert str(tmp_path / "missing.npz") in err and "ph_lstm_n5.npz" in err
    assert err.count("\n") == 1
    with pytest.raises(SystemExit) as stop:  # now a usage error, found by the parser
        main(["certify", "--L-d", "3.0"])
    assert stop.value.code == 2
    assert "'3.0' must lie in (0, 2)" in capsys.readouterr().err


def test_console_script_runs() -> None:
    result = subprocess.run(
        [sys.executable, "-m", "ltv_lstm_mpc.cli.main", "certify", "--json"],
        capture_output=True, text=True, check=True,
    )  # fmt: skip
    assert json.loads(result.stdout)["is_delta_iss"] is True


def test_simulate_with_daqp_runs_the_condensed_path(capsys) -> None:
    argv = ["simulate", "--plant", "lstm", "--setpoints", "7.0", "7.3", "--segment", "20"]
    code = main([*argv, "--solver", "daqp", "--no-progress"])
    assert code == 0
    out = capsys.readouterr().out
    assert "transcription condensed" in out
    code = main([*argv, "--solver", "daqp", "--transcription", "sparse", "--no-progress"])
    assert code == 0
    assert "transcription sparse" in capsys.readouterr().out


def test_every_subcommand_is_registered() -> None:
    """The README's commands exist (train, bench and replay live in their own modules)."""
    from ltv_lstm_mpc.cli.main import build_parser

    parser = build_parser()
    commands = next(a for a in parser._actions if a.dest == "command").choices
    expected = {"certify", "reproduce", "simulate", "generate-data", "train", "bench", "replay"}
    assert expected <= set(commands)


def test_bench_smoke_through_the_entry_point(tmp_path) -> None:
    result = subprocess.run(
        [sys.executable, "-m", "ltv_lstm_mpc.cli.main", "bench", "--smoke", "--out", str(tmp_path)],
        capture_output=True,
        text=True,
        timeout=600,
    )
    assert result.returncode == 0, result.stderr[-2000:]
    assert any(tmp_path.iterdir())


# ------------------------------------------------------------------- bad invocations
def _run_main(argv: list[str], capsys) -> tuple[int, str]:  # type: ignore[no-untyped-def]
    try:
        code = main(argv)
    except SystemExit as stop:  # argparse usage errors
        code = int(stop.code or 0)
    err = capsys.readouterr().err
    assert "Traceback" not in err
    return code, err


USAGE_ERRORS = [
    (["simulate", "--segment", "0"], "argument --segment: '0' must be an integer >= 1"),
    (["simulate", "--segment", "-3"], "--segment"),
    (["simulate", "--rate-limit", "-1"], "--rate-limit"),
    (["simulate", "--N", "0"], "--N"),
    (["simulate", "--L-d", "2.5"], "must lie in (0, 2)"),
    (["simulate", "--max-offset", "nan"], "--max-offset"),
    (["certify", "--u-max", "-1"], "--u-max"),
    (["certify", "--d-max", "inf"], "--d-max"),
    (["bench", "--backends", "nope", "--smoke"], "matches no installed backend"),
    (["bench", "--steps", "0", "--smoke"], "--steps"),
]


@pytest.mark.parametrize(("argv", "text"), USAGE_ERRORS)
def test_usage_errors_exit_2_without_traceback(argv, text, capsys) -> None:
    code, err = _run_main(argv, capsys)
    assert code == 2
    assert text in err


def test_out_pointing_at_a_file_is_refused_before_any_work(tmp_path, capsys) -> None:
    target = tmp_path / "results.txt"
    target.write_text("keep me")
    for argv in (["simulate", "--out", str(target)], ["reproduce", "--out", str(target)]):
        code, err = _run_main(argv, capsys)
        assert code == 2 and "exists and is not a folder" in err
    assert target.read_text() == "keep me"


def test_bad_model_files_are_one_line_errors(tmp_path, capsys) -> None:
    bad = tmp_path / "truncated.npz"
    bad.write_bytes(b"PK\x03\x04 truncated")
    folder = tmp_path / "folder.npz"
    folder.mkdir()
    for path, text in ((bad, "damaged or truncated"), (folder, "is a folder")):
        code, err = _run_main(["certify", str(path)], capsys)
        assert code == 1
        assert err.count("\n") == 1 and text in err and str(path) in err


def test_max_offset_sets_the_exit_status(capsys) -> None:
    argv = ["simulate", "--solver", "daqp", "--setpoints", "7.2", "--segment", "60",
            "--no-progress"]  # fmt: skip
    code, _ = _run_main([*argv, "--max-offset", "1e-9"], capsys)
    assert code == 3
    out_code, _ = _run_main([*argv, "--max-offset", "5"], capsys)
    assert out_code == 0


def _mimo_model_file(tmp_path):  # type: ignore[no-untyped-def]
    from lstm_factories import random_delta_iss_lstm

    from ltv_lstm_mpc import LSTMModel, Normalization

    base = random_delta_iss_lstm(np.random.default_rng(3), 4, 2, 2)
    normalization = Normalization(
        u_phi_min=np.zeros(2), u_phi_max=np.ones(2), y_phi_min=np.zeros(2), y_phi_max=np.ones(2)
    )
    model = LSTMModel(
        **base.weights(), normalization=normalization, y_phi_constraint=(np.zeros(2), np.ones(2))
    )
    return model, model.save(tmp_path / "mimo.npz")


def test_simulate_accepts_a_mimo_model(tmp_path, capsys) -> None:
    model, path = _mimo_model_file(tmp_path)
    targets = []
    for u in ([0.4, 0.6], [0.6, 0.45]):  # set-points with an equilibrium inside U
        x = model.equilibrium(model.normalize_u(np.array(u)))
        targets.append(",".join(f"{v:.6f}" for v in model.denormalize_y(model.output(x))))
    out = tmp_path / "out"
    argv = ["simulate", "--model", str(path), "--plant", "lstm", "--solver", "daqp",
            "--setpoints", *targets, "--disturbances", "0", "0.005,-0.005",
            "--segment", "300", "--no-progress", "--out", str(out), "--L-d", "0.1",
            "--max-offset", "1e-6"]  # fmt: skip
    code, _ = _run_main(argv, capsys)
    assert code == 0
    summary = json.loads((out / "simulate.json").read_text())
    assert summary["outputs"] == 2 and summary["constraint_violation_steps"] == 0
    assert np.max(summary["segment_offsets"]) < 1e-6  # offset-free on both outputs
    assert summary["setpoint_ok_steps"] == 600
    assert (out / "simulate.csv").exists() and (out / "simulate.png").exists()
    for bad, text in (
        (["--plant", "ph", "--setpoints", "0.5,0.4"], "use --plant lstm"),
        (["--plant", "lstm", "--setpoints", "1,2,3"], "needs 2 finite values"),
        (["--plant", "lstm", "--y0-initial", "0.5"], "--y0-initial"),
    ):
        code, err = _run_main(["simulate", "--model", str(path), *bad], capsys)
        assert code == 2 and text in err
    # no set-points given: the model's admissible interval gives them, and says so
    argv = ["simulate", "--model", str(path), "--plant", "lstm", "--solver", "daqp",
            "--segment", "5", "--no-progress"]  # fmt: skip
    assert main(argv) == 0
    assert "of its admissible set-point interval" in capsys.readouterr().out
