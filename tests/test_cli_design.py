"""The command line as one design: one default solver and L_d, the same option
names for the same things, defaults shown one way, every help text true, bad input exit 2
with one line, warnings as one clean line; and the messages of the library behind it."""

from __future__ import annotations

import argparse
import re
import textwrap
import warnings

import numpy as np
import pytest
from optional_extras import requires_solver

from ltv_lstm_mpc import (
    ArgumentTypeError,
    LtvMpcError,
    MPCConfig,
    OffsetFreeController,
    load_model,
)
from ltv_lstm_mpc.cli.main import build_parser, main

OPTION = re.compile(r"(?<![\w-])--[A-Za-z][\w-]*")


def _commands() -> dict[str, argparse.ArgumentParser]:
    parser = build_parser()
    action = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
    return dict(action.choices)


def _run(argv: list[str], capsys: pytest.CaptureFixture[str]) -> tuple[int, str, str]:
    try:
        code = main(argv)
    except SystemExit as stop:  # argparse's own errors
        code = int(stop.code or 0)
    captured = capsys.readouterr()
    return code, captured.out, captured.err


def test_every_help_names_only_options_of_its_own_command(monkeypatch) -> None:
    monkeypatch.setenv("COLUMNS", "10000")  # no option name broken at a line end
    commands = _commands()
    other = re.compile(rf"\b({'|'.join(map(re.escape, commands))})((?: [A-Z][\w.]*)*) (--[\w-]+)")
    for name, parser in commands.items():
        text = parser.format_help()
        for match in other.finditer(text):  # "bench --save-subproblems": bench's own option
            assert match.group(3) in commands[match.group(1)]._option_string_actions, match[0]
        own = set(parser._option_string_actions)
        named = set(OPTION.findall(other.sub("", text)))
        assert named <= own, f"`{name} --help` names {sorted(named - own)}"


def test_defaults_are_shown_one_way() -> None:
    for name, parser in _commands().items():
        formatter = parser._get_formatter()
        for action in parser._actions:
            if not action.help or action.help is argparse.SUPPRESS:
                continue
            text = formatter._expand_help(action)
            pattern = r"\(default [^:]|\(\d[\w.]*\)|default on\b|; default \d"
            assert not re.findall(pattern, text), f"`{name} --help`, {action.dest}: {text}"
            shown = action.default not in (None, argparse.SUPPRESS) and action.nargs != 0
            if shown and action.option_strings:
                assert "(default: " in text, (name, action.dest)


def test_help_texts_are_true_and_plant_neutral() -> None:
    commands = _commands()
    top = " ".join(build_parser().format_help().split())
    assert "pH plant, paper Section V; or the quadruple tank" not in top
    assert "on the pH (or --plant quadtank) data" not in top
    steps = commands["generate-data"]._option_string_actions["--steps"].help or ""
    assert "Ts = 10 s" not in steps and "plant's sampling time" in steps
    convert = " ".join(commands["convert"].format_help().split())
    assert "Read SOURCE" in convert and "write OUT" in convert and "Read IN " not in convert
    assert commands["replay"].description  # what replay does, not only its usage
    assert "--data" not in commands["generate-data"].format_help()


def test_one_default_solver_and_one_default_l_d() -> None:
    from ltv_lstm_mpc.solvers import default_solver

    from ltv_lstm_mpc.campaign.spec import DEFAULTS
    from ltv_lstm_mpc.mpc.config import DEFAULT_L_D

    commands = _commands()
    solver = default_solver()
    assert MPCConfig().solver == solver
    assert commands["simulate"].parse_args([]).solver == solver
    assert commands["warmup"].parse_args([]).solver == [solver]  # warms what simulate runs
    assert DEFAULTS["solver"] == solver
    assert MPCConfig().L_d == DEFAULT_L_D == DEFAULTS["L_d"]
    for name in ("certify", "simulate"):
        assert commands[name].parse_args([]).L_d == DEFAULT_L_D


def test_the_same_options_for_the_same_things() -> None:
    commands = _commands()
    for name, options in {
        "simulate": ("--solver", "--N", "--L-d", "--d-max", "--no-check-sampling-time"),
        "certify": ("--N", "--L-d", "--d-max"),
        "warmup": ("--solver", "--N"),
        "reproduce": ("--solver",),
    }.items():
        missing = set(options) - set(commands[name]._option_string_actions)
        assert not missing, f"{name} lacks {sorted(missing)}"
    args = commands["simulate"].parse_args(["--d-max", "0.2", "--no-check-sampling-time"])
    assert args.d_max == 0.2 and args.check_sampling_time is False


@pytest.mark.parametrize(
    ("argv", "text"),
    [
        (["simulate", "--solver", "DAQP"], "did you mean 'daqp'"),
        pytest.param(
            ["simulate", "--solver", "clarabel "],
            "did you mean 'clarabel'",
            marks=requires_solver("clarabel"),
        ),
        (["warmup", "--solver", "nope"], "solver 'nope' is not available"),
        (["reproduce", "--solver", "Daqp:SOCP"], "did you mean 'daqp:socp'"),
        (["simulate", "--segment", "0"], "--segment"),
        (["simulate", "--plant", "lstm", "--setpoints", "nan"], "'nan' (segment 1) is not finite"),
        (["simulate", "--plant", "lstm", "--setpoints", "7", "abc"], "'abc' (segment 2)"),
        (["simulate", "--plant", "lstm", "--disturbances", "x"], "--disturbances: 'x'"),
    ],
)
def test_bad_options_exit_2_with_one_line(argv, text, capsys) -> None:
    code, out, err = _run(argv, capsys)
    assert code == 2, err
    assert err.count("\n") == 1 and text in err, err
    assert "Traceback" not in err and not out


def test_setpoint_message_says_what_is_expected(capsys) -> None:
    code, _, err = _run(["simulate", "--plant", "lstm", "--setpoints", "abc"], capsys)
    assert code == 2
    assert "'abc'" in err and "is not a number; give one number per segment" in err
    assert "None" not in err and "['abc']" not in err


def test_a_plant_without_an_input_range_is_refused_before_simulating(
    tmp_path, monkeypatch, capsys
) -> None:
    (tmp_path / "rangeless_plant.py").write_text(
        textwrap.dedent(
            """
            from user_plant import HammersteinPH

            class Rangeless(HammersteinPH):
                u_phi_min = None
                u_phi_max = None
            """
        )
    )
    monkeypatch.syspath_prepend(str(tmp_path))
    argv = ["generate-data", "--plant", "rangeless_plant:Rangeless", "--out", str(tmp_path / "d")]
    code, _, err = _run([*argv, "--sequences", "3", "--steps", "20", "--no-progress"], capsys)
    assert code == 2
    assert err.count("\n") == 1 and "states no input range" in err and "u_phi_min" in err
    assert "simulating" not in err


def test_generate_data_checks_its_sizes_before_simulating(tmp_path, capsys) -> None:
    out = str(tmp_path / "d.npz")
    code, _, err = _run(["generate-data", "--out", out, "--split", "5", "5", "4"], capsys)
    assert code == 2 and "--split 5 5 4" in err and "simulating" not in err


def test_warnings_are_one_clean_line_with_the_command_option(capsys) -> None:
    argv = ["simulate", "--plant", "lstm", "--solver", "daqp", "--setpoints", "7.2",
            "--disturbances", "0.2", "--d-max", "0.001", "--segment", "15",
            "--no-progress"]  # fmt: skip
    code, _, err = _run(argv, capsys)
    assert code == 0, err
    lines = [line for line in err.splitlines() if "d_hat reached" in line]
    assert len(lines) == 1, err
    assert lines[0].startswith("ltv-lstm-mpc simulate: warning: d_hat reached")
    assert "--d-max" in lines[0] and "MPCConfig d_max" not in lines[0]
    assert "RuntimeWarning" not in err and "sys.exit" not in err
    assert not re.search(r"\d\.\d{8,}", err)  # numbers rounded (not 6.321881455615142)


def test_library_advice_becomes_the_option_of_the_command() -> None:
    from ltv_lstm_mpc.cli.main import _for_command

    commands = _commands()
    message = (
        "the model was identified at Ts = 5.0 s but the pH plant runs at Ts = 10.0 s: ... Run "
        "the pH plant at Ts = 5.0 s, or identify a model at 10.0 s; if the model's Ts is "
        "unknown and you accept the risk, pass check_sampling_time=False"
    )
    assert "pass --no-check-sampling-time" in _for_command(message, commands["simulate"])
    for name in ("reproduce", "campaign"):  # no such switch there: no such advice
        assert "check_sampling_time" not in _for_command(message, commands[name])
    rounded = _for_command("interval [[6.321881455615142], [8.678118544384857]] of", None)
    assert rounded == "interval [6.322, 8.678] of"


def test_sampling_time_error_names_the_switch_that_exists(tmp_path, capsys) -> None:
    model = load_model("ph_lstm_n5.npz")
    model.Ts = 5.0
    path = model.save(tmp_path / "ph_ts5.npz")
    argv = ["simulate", "--model", str(path), "--solver", "daqp", "--segment", "3",
            "--no-progress"]  # fmt: skip
    code, _, err = _run(argv, capsys)
    assert code == 1 and "Ts = 5.0 s" in err and "--no-check-sampling-time" in err
    assert "check_sampling_time=False" not in err
    code, _, err = _run([*argv, "--no-check-sampling-time"], capsys)
    assert code == 0, err


# ----------------------------------------------------------------------- library messages
@pytest.fixture(scope="module")
def ph_model():  # type: ignore[no-untyped-def]
    return load_model("ph_lstm_n5.npz")


def test_a_first_measurement_in_wrong_units_is_named_in_its_units(ph_model) -> None:
    controller = OffsetFreeController(ph_model, MPCConfig(solver="daqp"), setpoint_rate_limit=0.01)
    with pytest.raises(LtvMpcError) as info:
        controller.step(70.0, 7.0)
    message = str(info.value)
    assert "y_phi = 70 " in message and "5.96" in message and "units" in message
    assert "set-point" not in message.split(":")[0]  # about the measurement, not a set-point
    assert not controller.records
    controller.step(7.0, 7.0)  # the controller is still usable


def test_a_string_for_a_number_is_a_type_error(ph_model) -> None:
    controller = OffsetFreeController(ph_model, MPCConfig(solver="daqp"))
    for y, y0 in (("7.0", 7.0), (7.0, "7.2")):
        with pytest.raises(ArgumentTypeError) as info:
            controller.step(y, y0)
        assert isinstance(info.value, TypeError)
        assert isinstance(info.value, ValueError)  # as before: an InvalidValueError too
        assert "convert it first" in str(info.value)


def test_a_missing_model_file_is_a_library_error(tmp_path) -> None:
    from ltv_lstm_mpc import LSTMModel
    from ltv_lstm_mpc.exceptions import ModelFileNotFoundError
    from ltv_lstm_mpc.lstm.shipped import model_path

    missing = tmp_path / "mine.npz"
    for call in (lambda: load_model(missing), lambda: model_path(str(missing))):
        with pytest.raises(ModelFileNotFoundError) as info:
            call()
        assert isinstance(info.value, FileNotFoundError) and isinstance(info.value, LtvMpcError)
        assert str(missing) in str(info.value) and "ph_lstm_n5.npz" in str(info.value)
    with pytest.raises(ModelFileNotFoundError):
        LSTMModel.load(missing)


def test_default_solver_runs_the_paper_model(ph_model) -> None:
    from ltv_lstm_mpc.solvers import default_solver

    controller = OffsetFreeController(ph_model, setpoint_rate_limit=0.01)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        for _ in range(3):
            u = controller.step(7.0, 7.2)
    assert controller.config.solver == default_solver()
    assert np.all(np.isfinite(u))


def test_library_errors_of_train_name_the_command(tmp_path, capsys) -> None:
    """A library or file error of train is one line prefixed with the command, like every
    other command's (exit 1)."""
    code = main(["train", "--data", str(tmp_path / "missing.npz")])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 1
    assert len(err) == 1 and err[0].startswith("ltv-lstm-mpc train: error: "), err
