"""Wrong types and bad values at the public entry points: one library error each, naming
the argument, the value given and what is expected (never a foreign traceback)."""

from __future__ import annotations

import time

import numpy as np
import pytest

from ltv_lstm_mpc import (
    ArgumentTypeError,
    CertificationSettings,
    DimensionError,
    InvalidValueError,
    LtvMpcError,
    MPCConfig,
    OffsetFreeController,
    PHNeutralizationPlant,
    certify,
    load_model,
    simulate,
)
from ltv_lstm_mpc.campaign.spec import parse_spec
from ltv_lstm_mpc.cli.main import main
from ltv_lstm_mpc.exceptions import CampaignSpecError
from ltv_lstm_mpc.training.datasets import IdentificationDataset


@pytest.fixture(scope="module")
def ph_model():
    return load_model("ph_lstm_n5.npz")


@pytest.fixture(scope="module")
def controller(ph_model):
    return OffsetFreeController(ph_model, MPCConfig(solver="daqp"))


def _run_main(argv: list[str], capsys) -> tuple[int, str]:
    try:
        code = main(argv)
    except SystemExit as stop:  # usage errors found by argparse
        code = int(stop.code or 0)
    return code, capsys.readouterr().err


def test_argument_type_error_is_a_library_error_and_a_type_error() -> None:
    assert issubclass(ArgumentTypeError, LtvMpcError)
    assert issubclass(ArgumentTypeError, TypeError)


# ------------------------------------------------------------------ wrong types


def test_controller_given_a_file_name_says_how_to_load_the_model() -> None:
    with pytest.raises(ArgumentTypeError, match=r"model must be an LSTMModel, got str") as info:
        OffsetFreeController("ph_lstm_n5.npz")
    assert "load_model" in str(info.value)


def test_controller_given_a_dict_config_says_to_build_an_mpc_config(ph_model) -> None:
    with pytest.raises(ArgumentTypeError, match=r"config must be an MPCConfig") as info:
        OffsetFreeController(ph_model, {"solver": "daqp"})
    assert "MPCConfig(**{'solver': 'daqp'})" in str(info.value)


def test_controller_refuses_an_mpc_that_fills_no_role(ph_model) -> None:
    with pytest.raises(ArgumentTypeError, match=r"mpc must be an MPC like RobustMPC"):
        OffsetFreeController(ph_model, mpc=object())
    with pytest.raises(ArgumentTypeError, match="setpoint_rate_limit"):
        OffsetFreeController(ph_model, setpoint_rate_limit="fast")


def test_certify_given_a_file_name() -> None:
    with pytest.raises(ArgumentTypeError, match=r"model must be an LSTMModel, got str"):
        certify("ph_lstm_n5.npz")
    model = load_model("example_delta_iss_n3.npz")
    with pytest.raises(ArgumentTypeError, match=r"settings must be a CertificationSettings"):
        certify(model, {"u_max": 1.0})


def test_simulate_names_the_argument_of_the_wrong_type(controller) -> None:
    with pytest.raises(ArgumentTypeError, match=r"plant must be a plant"):
        simulate(None, controller, 7.5, steps=2, progress=False)
    with pytest.raises(ArgumentTypeError, match=r"controller must be an OffsetFreeController"):
        simulate(PHNeutralizationPlant(), "controller", 7.5, steps=2, progress=False)
    with pytest.raises(ArgumentTypeError, match="progress"):
        simulate(PHNeutralizationPlant(), controller, 7.5, steps=2, progress="no")


def test_load_model_of_none() -> None:
    with pytest.raises(ArgumentTypeError, match=r"name_or_path must be a file path") as info:
        load_model(None)
    assert "ph_lstm_n5.npz" in str(info.value)  # the shipped names


def test_model_methods_check_shapes_and_values(ph_model) -> None:
    x = np.zeros(2 * ph_model.n)
    with pytest.raises(DimensionError, match="do not broadcast"):
        ph_model.jacobians(np.zeros((3, 2 * ph_model.n)), np.zeros((2, 1)))
    with pytest.raises(DimensionError, match="x has shape"):
        ph_model.jacobians(np.zeros(3), np.zeros(1))
    with pytest.raises(InvalidValueError, match=r"u contains NaN or inf"):
        ph_model.step(x, [np.nan])
    with pytest.raises(InvalidValueError, match=r"x contains NaN or inf"):
        ph_model.step(np.full(2 * ph_model.n, np.inf), [0.0])
    with pytest.raises(InvalidValueError, match="real numbers"):
        ph_model.step(x, "0.5")
    with pytest.raises(InvalidValueError, match="u_seq"):
        ph_model.simulate(x, [[0.1], [np.nan]])


def test_equilibrium_of_nan_is_refused_at_once(ph_model) -> None:
    start = time.perf_counter()
    with pytest.raises(InvalidValueError, match=r"u contains NaN or inf"):
        ph_model.equilibrium([np.nan])
    assert time.perf_counter() - start < 0.5  # not 10,000 iterations
    with pytest.raises(ArgumentTypeError, match="max_iter"):
        ph_model.equilibrium([0.0], max_iter=10.5)


def test_valid_model_calls_are_unchanged(ph_model) -> None:
    x = ph_model.equilibrium(np.array([0.2]))
    np.testing.assert_array_equal(ph_model.step(x, [0.2]), ph_model.kernel.step(x, np.array([0.2])))
    _, A, B = ph_model.step_and_jacobians(x, np.array([0.2]))
    A2, B2 = ph_model.jacobians(x, [0.2])
    np.testing.assert_array_equal(A, A2)
    np.testing.assert_array_equal(B, B2)


# ------------------------------------------------------------------ bad values


def test_certify_cli_refuses_a_reversed_y0_range(capsys) -> None:
    code, err = _run_main(["certify", "--y0-range", "2", "1"], capsys)
    assert code == 2
    assert "LOW must be below HIGH" in err and "swap" in err
    code, err = _run_main(["certify", "--y0-range", "0.1", "nan"], capsys)
    assert code == 2 and "not a finite number" in err


def test_certify_cli_checks_the_y_min_y_max_pair(capsys) -> None:
    code, err = _run_main(["certify", "--y-min", "0.5", "--y-max", "0.2"], capsys)
    assert code == 2 and "--y-min/--y-max" in err
    code, err = _run_main(["certify", "--y-min", "nan"], capsys)
    assert code == 2 and "not a finite number" in err
    code, err = _run_main(["certify", "--y-min", "-0.5"], capsys)
    assert code == 2 and "give both --y-min and --y-max" in err


def test_y0_operating_range_in_the_library_must_be_ordered() -> None:
    with pytest.raises(InvalidValueError, match="low < high"):
        CertificationSettings(y0_operating_range=(0.5, -0.5))


def test_simulate_refuses_a_negative_time_limit(controller) -> None:
    for bad in (-1, 0.0, float("nan")):
        with pytest.raises(InvalidValueError, match="max_seconds"):
            simulate(PHNeutralizationPlant(), controller, 7.5, steps=3, max_seconds=bad)
    with pytest.raises(InvalidValueError, match="blas_threads"):
        simulate(PHNeutralizationPlant(), controller, 7.5, steps=3, blas_threads=0)


@pytest.mark.parametrize("epsilon", [5, 1.0, 0.0, -0.01, float("nan")])
def test_mpc_config_epsilon_lies_in_the_open_unit_interval(epsilon) -> None:
    with pytest.raises(InvalidValueError, match="epsilon"):
        MPCConfig(epsilon=epsilon)
    with pytest.raises(InvalidValueError, match="epsilon"):
        CertificationSettings(epsilon=epsilon)


def test_mpc_config_horizon_names_the_type() -> None:
    with pytest.raises(ArgumentTypeError, match=r"N must be an integer, got str '5'"):
        MPCConfig(N="5")
    with pytest.raises(ArgumentTypeError, match=r"got float 5.0"):
        MPCConfig(N=5.0)
    with pytest.raises(InvalidValueError, match=r"N must be an integer >= 1, got 0"):
        MPCConfig(N=0)
    with pytest.raises(ArgumentTypeError, match=r"N must be an integer, got str"):
        CertificationSettings(N="5")
    assert MPCConfig(N=np.int64(7)).N == 7  # numpy integers are integers


def test_mpc_config_fields_are_checked_where_they_are_read() -> None:
    with pytest.raises(ArgumentTypeError, match=r"u_max must be a real number, got str"):
        MPCConfig(u_max="1")
    with pytest.raises(InvalidValueError, match=r"L_d must lie in \(0, 2\)"):
        MPCConfig(L_d=2.5)
    with pytest.raises(ArgumentTypeError, match="design_gains"):
        MPCConfig(design_gains="yes")
    with pytest.raises(ArgumentTypeError, match="solver_settings"):
        MPCConfig(solver_settings=["verbose"])
    with pytest.raises(InvalidValueError, match="y_min must be below y_max"):
        MPCConfig(y_min=0.5, y_max=0.5)


def test_nan_output_bound_is_named_not_taken_for_a_missing_one() -> None:
    for make in (MPCConfig, CertificationSettings):
        with pytest.raises(InvalidValueError, match=r"y_min must be a finite number, got nan"):
            make(y_min=float("nan"))
        with pytest.raises(InvalidValueError, match=r"y_max must be a finite number"):
            make(y_min=-0.5, y_max=float("inf"))


def test_certify_cli_warns_about_u_max_above_one_like_the_controller(capsys, ph_model) -> None:
    code, err = _run_main(["certify", "--u-max", "1.2"], capsys)
    assert code == 0
    assert "warning: u_max = 1.2 (normalized)" in err and "extrapolations" in err
    with pytest.warns(RuntimeWarning, match=r"u_max = 1.2 \(normalized\)"):
        OffsetFreeController(ph_model, MPCConfig(solver="daqp", u_max=1.2))
    code, err = _run_main(["certify"], capsys)
    assert code == 0 and "warning" not in err


def test_campaign_factor_listed_twice_is_an_error_naming_it() -> None:
    spec = {"campaign": {"model": "ph_lstm_n5.npz", "steps": 5, "setpoints": [7.0]}}
    with pytest.raises(CampaignSpecError, match=r"listed twice") as info:
        parse_spec({**spec, "factors": {"seed": [0, 0]}})
    assert info.value.field == "[factors].seed[1]"
    with pytest.raises(CampaignSpecError, match=r"\[factors\].L_d\[2\]"):
        parse_spec({**spec, "factors": {"L_d": [0.1, 0.2, 0.10]}})
    assert len(parse_spec({**spec, "factors": {"seed": [0, 1]}}).tasks) == 2


def test_missing_model_error_lists_each_place_once(tmp_path, monkeypatch) -> None:
    monkeypatch.chdir(tmp_path)
    spec = {"campaign": {"model": "nope.npz", "steps": 5, "setpoints": [7.0]}}
    with pytest.raises(CampaignSpecError) as info:
        parse_spec(spec)
    message = str(info.value)
    assert message.count("nope.npz") == 2  # the name given, then the one place looked in
    assert str((tmp_path / "nope.npz").resolve()) in message


def test_quadtank_simulate_needs_one_set_point_per_output(capsys) -> None:
    for plant in ("quadtank", "lstm"):
        argv = ["simulate", "--plant", plant, "--model", "quadtank_lstm_n8.npz",
                "--setpoints", "14", "--segment", "3", "--no-progress"]  # fmt: skip
        code, err = _run_main(argv, capsys)
        assert code == 2, plant
        assert "'14' needs 2 finite values (one per output), got 1" in err


def test_replay_of_a_folder_that_is_not_a_bench_output(tmp_path, capsys) -> None:
    code, err = _run_main(["replay", str(tmp_path)], capsys)
    assert code == 1
    assert "not a folder of saved subproblems" in err and "--save-subproblems" in err
    assert "Errno" not in err
    code, err = _run_main(["replay", str(tmp_path / "absent")], capsys)
    assert code == 1 and "is not a folder" in err and "Errno" not in err


def test_data_file_that_is_not_identification_data(tmp_path, capsys) -> None:
    text = tmp_path / "passwd"
    text.write_text("root:x:0:0:root:/root:/bin/bash\n")
    array = tmp_path / "array.npy"
    np.save(array, np.zeros(3))
    for path in (text, array, tmp_path):
        with pytest.raises(InvalidValueError, match="identification data") as info:
            IdentificationDataset.load(path)
        assert "allow_pickle" not in str(info.value)
    code, err = _run_main(["certify", "--d-max-from", str(text)], capsys)
    assert code == 1 and "is not identification data" in err and "allow_pickle" not in err
