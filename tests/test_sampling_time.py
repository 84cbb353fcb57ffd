"""The sampling time is part of the model-plant contract."""

from __future__ import annotations

import warnings

import numpy as np
import pytest

from ltv_lstm_mpc import (
    LSTMModel,
    MPCConfig,
    OffsetFreeController,
    PHNeutralizationPlant,
    QuadrupleTankPlant,
    SamplingTimeError,
    load_model,
    shipped_path,
    simulate,
)
from ltv_lstm_mpc.campaign.spec import parse_spec
from ltv_lstm_mpc.exceptions import CampaignSpecError
from ltv_lstm_mpc.lstm.model import ModelFormatError
from ltv_lstm_mpc.plants import LSTMPlant, NoisyMeasurement
from ltv_lstm_mpc.plants.protocol import check_sampling_time


@pytest.mark.parametrize(
    "name", ["ph_lstm_n5.npz", "quadtank_lstm_n8.npz", "example_delta_iss_n3.npz"]
)
def test_every_shipped_model_states_its_sampling_time(name) -> None:
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # no "states no sampling time" warning
        assert load_model(name).Ts == 10.0


def test_quadtank_model_on_a_plant_at_another_sampling_time_is_refused() -> None:
    """Before: 400 steps all 'ok' with an 8.7e-3 cm offset and no word."""
    model = load_model("quadtank_lstm_n8.npz")
    controller = OffsetFreeController(model, MPCConfig(solver="daqp"))
    with pytest.raises(SamplingTimeError, match=r"Ts = 10.0 s .* Ts = 1.0 s"):
        simulate(QuadrupleTankPlant(Ts=1.0), controller, np.full((5, 2), 13.0), progress=False)
    assert not controller.records


def test_ph_plant_at_a_microsecond_is_refused_unless_asked() -> None:
    model = load_model("ph_lstm_n5.npz")
    controller = OffsetFreeController(model, MPCConfig(solver="daqp"))
    with pytest.raises(SamplingTimeError, match="check_sampling_time=False"):
        simulate(PHNeutralizationPlant(Ts=1e-6), controller, np.full(5, 7.0), progress=False)
    result = simulate(
        PHNeutralizationPlant(Ts=1e-6),
        controller,
        np.full(5, 7.0),
        progress=False,
        check_sampling_time=False,
    )
    assert result.u_phi.shape == (5, 1)


def test_wrapped_and_lstm_plants_state_their_sampling_time() -> None:
    model = load_model("ph_lstm_n5.npz")
    assert LSTMPlant(model, y0_phi=7.0).Ts == 10.0
    assert NoisyMeasurement(PHNeutralizationPlant(Ts=5.0), 0.01).Ts == 5.0
    controller = OffsetFreeController(model, MPCConfig(solver="daqp"))
    with pytest.raises(SamplingTimeError):
        simulate(
            NoisyMeasurement(PHNeutralizationPlant(Ts=5.0), 0.01),
            controller,
            np.full(3, 7.0),
            progress=False,
        )


def test_the_comparison() -> None:
    check_sampling_time(10.0, 10.0 * (1 + 1e-12))  # rounding is not a mismatch
    check_sampling_time(10.0, None)  # a user plant without Ts: not checked
    with pytest.raises(SamplingTimeError):
        check_sampling_time(10.0, 10.001)
    with pytest.warns(UserWarning, match="states no sampling time") as caught:
        check_sampling_time(None, 10.0)
    assert caught[0].filename == __file__


def _without_ts(tmp_path):
    arrays = load_model("ph_lstm_n5.npz").to_arrays()
    del arrays["Ts"]
    path = tmp_path / "old.npz"
    np.savez(path, **arrays)
    return path


def test_old_file_without_ts_loads_with_a_warning_that_says_how_to_add_it(tmp_path) -> None:
    path = _without_ts(tmp_path)
    with pytest.warns(UserWarning, match=r"states no sampling time Ts.*Ts=<seconds>") as caught:
        model = LSTMModel.load(path)
    assert model.Ts is None
    assert caught[0].filename == __file__
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        fixed = LSTMModel.load(path, Ts=10.0)
    assert fixed.Ts == 10.0
    resaved = fixed.save(tmp_path / "new.npz")
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert LSTMModel.load(resaved).Ts == 10.0


def test_a_contradicting_ts_argument_is_refused(tmp_path) -> None:
    with pytest.raises(ModelFormatError, match=r"states Ts = 10\.0 s"):
        LSTMModel.load(shipped_path("ph_lstm_n5.npz"), Ts=1.0)


def test_model_without_ts_on_a_plant_with_one_warns_and_runs(tmp_path) -> None:
    with pytest.warns(UserWarning):
        model = LSTMModel.load(_without_ts(tmp_path))
    controller = OffsetFreeController(model, MPCConfig(solver="daqp"))
    with pytest.warns(UserWarning, match="cannot be compared"):
        result = simulate(PHNeutralizationPlant(), controller, np.full(3, 7.0), progress=False)
    assert result.u_phi.shape == (3, 1)


def test_campaign_on_the_ph_plant_refuses_a_model_at_another_sampling_time(tmp_path) -> None:
    model = load_model("ph_lstm_n5.npz")
    model.Ts = 2.0
    path = model.save(tmp_path / "fast.npz")
    spec = {"campaign": {"model": str(path), "plant": "ph", "steps": 10, "setpoints": [7.0]}}
    with pytest.raises(CampaignSpecError, match=r"model.*Ts = 2.0 s.*Ts = 10.0 s"):
        parse_spec(spec)
    spec["campaign"]["plant"] = "lstm"  # the LSTM plant runs at the model's own Ts
    assert parse_spec(spec).tasks
