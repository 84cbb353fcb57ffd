"""d_max from data: estimate_d_max and certify --d-max-from."""

from __future__ import annotations

import numpy as np
import pytest

from ltv_lstm_mpc import InvalidValueError, estimate_d_max, load_model
from ltv_lstm_mpc.cli.main import main
from ltv_lstm_mpc.training.datasets import generate_dataset
from ltv_lstm_mpc.training.train import simulate_sequences


@pytest.fixture(scope="module")
def data():
    return generate_dataset(seed=3, sequences=3, steps=300, split_sizes=(1, 1, 1))


def test_estimate_is_the_largest_open_loop_mismatch_plus_margin(data) -> None:
    model = load_model("ph_lstm_n5.npz")
    estimate = estimate_d_max(model, data, margin=0.25)
    scale = float(model.normalization.y_scale[0])  # type: ignore[union-attr]
    worst = 0.0
    for split in ("train", "val", "test"):
        u, y = data.split(split)
        pred = simulate_sequences(model, u, float(data.metadata.get("q3_initial", 15.6)))
        worst = max(worst, float(np.max(np.abs(pred - y))) / scale)
    assert estimate.mismatch == pytest.approx(worst, rel=1e-12)
    assert estimate.d_max == pytest.approx(1.25 * worst, rel=1e-12)
    assert estimate.mismatch_phi == pytest.approx(worst * scale, rel=1e-12)
    assert estimate.splits == ("train", "val", "test")
    split, sequence, sample = estimate.worst
    u, y = data.split(split)
    pred = simulate_sequences(model, u, float(data.metadata.get("q3_initial", 15.6)))
    assert abs(pred[sequence, sample] - y[sequence, sample]) / scale == pytest.approx(worst)
    with pytest.raises(InvalidValueError, match="margin must be"):
        estimate_d_max(model, data, margin=-0.1)


def test_certify_d_max_from_data(tmp_path, data, capsys) -> None:
    path = data.save(tmp_path / "data.npz")
    model = load_model("ph_lstm_n5.npz")
    expected = estimate_d_max(model, path).d_max
    assert main(["certify", "ph_lstm_n5.npz", "--json", "--d-max-from", str(path)]) == 0
    captured = capsys.readouterr()
    import json

    assert json.loads(captured.out)["inputs"]["d_max"] == pytest.approx(expected, rel=1e-12)
    assert "estimated from" in captured.err and "shrinks the admissible" in captured.err
