"""Identification data generator (paper Section V, paper notes 5)."""

from __future__ import annotations

import csv
from pathlib import Path

import numpy as np
import pytest

from ltv_lstm_mpc.exceptions import InvalidValueError
from ltv_lstm_mpc.lstm.model import Normalization
from ltv_lstm_mpc.training.datasets import (
    SPLITS,
    IdentificationDataset,
    generate_dataset,
    generate_split,
    multilevel_signal,
    sequence_rng,
    split_indices,
)


def _runs(signal: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(levels, lengths) of the constant runs of a piecewise-constant signal."""
    change = np.flatnonzero(np.diff(signal) != 0) + 1
    starts = np.concatenate([[0], change])
    lengths = np.diff(np.concatenate([starts, [signal.size]]))
    return signal[starts], lengths


def test_multilevel_signal_statistics() -> None:
    rng = np.random.default_rng(0)
    signal = multilevel_signal(rng, 20_000)
    levels, lengths = _runs(signal)
    assert signal.shape == (20_000,)
    assert np.all((signal >= 12.5) & (signal <= 17.0))
    # Every hold except the truncated last one lasts 10..100 samples.
    assert np.all((lengths[:-1] >= 10) & (lengths[:-1] <= 100))
    assert 1 <= lengths[-1] <= 100
    # Holds are roughly uniform on 10..100 (mean 55) and levels uniform on U_phi (mean 14.75).
    assert 50 < lengths[:-1].mean() < 60
    assert abs(levels.mean() - 14.75) < 0.2
    assert levels.min() < 12.8 and levels.max() > 16.7


def test_multilevel_signal_rejects_bad_arguments() -> None:
    rng = np.random.default_rng(0)
    with pytest.raises(InvalidValueError):
        multilevel_signal(rng, 0)
    with pytest.raises(InvalidValueError):
        multilevel_signal(rng, 10, min_hold=20, max_hold=10)
    with pytest.raises(InvalidValueError):
        multilevel_signal(rng, 10, low=17.0, high=12.5)


@pytest.fixture(scope="module")
def small_dataset() -> IdentificationDataset:
    return generate_dataset(seed=3, sequences=6, steps=300, split_sizes=(3, 2, 1))


def test_dataset_shapes_metadata_and_statistics(small_dataset: IdentificationDataset) -> None:
    ds = small_dataset
    assert [ds.u_phi[s].shape for s in SPLITS] == [(3, 300), (2, 300), (1, 300)]
    assert [ds.y_phi[s].shape for s in SPLITS] == [(3, 300), (2, 300), (1, 300)]
    for name in SPLITS:
        u, y = ds.split(name)
        assert np.all((u >= 12.5) & (u <= 17.0))
        assert np.all((y > 5.5) & (y < 9.5))
        # Every sequence starts at the nominal steady state (pH 7.026).
        np.testing.assert_allclose(y[:, 0], 7.0258, atol=1e-4)
        for row in u:
            _, lengths = _runs(row)
            assert np.all((lengths[:-1] >= 10) & (lengths[:-1] <= 100))
    meta = ds.metadata
    assert meta["seed"] == 3 and meta["Ts"] == 10.0 and meta["q2"] == 0.55
    assert meta["units"]["u_phi"].startswith("mL/s") and meta["units"]["y_phi"] == "pH"
    assert meta["sequence_indices"] == {"train": [0, 1, 2], "val": [3, 4], "test": [5]}


def test_default_split_is_10_3_2() -> None:
    assert split_indices() == {
        "train": list(range(10)),
        "val": [10, 11, 12],
        "test": [13, 14],
    }
    with pytest.raises(InvalidValueError):
        generate_dataset(sequences=15, split_sizes=(10, 3, 1))


def test_reproducible_and_split_regenerated_alone(small_dataset: IdentificationDataset) -> None:
    again = generate_dataset(seed=3, sequences=6, steps=300, split_sizes=(3, 2, 1))
    for name in SPLITS:
        np.testing.assert_array_equal(again.u_phi[name], small_dataset.u_phi[name])
        np.testing.assert_array_equal(again.y_phi[name], small_dataset.y_phi[name])
    u_test, y_test = generate_split("test", seed=3, sequences=6, steps=300, split_sizes=(3, 2, 1))
    np.testing.assert_array_equal(u_test, small_dataset.u_phi["test"])
    np.testing.assert_array_equal(y_test, small_dataset.y_phi["test"])
    other = generate_dataset(seed=4, sequences=6, steps=300, split_sizes=(3, 2, 1))
    assert not np.array_equal(other.u_phi["train"], small_dataset.u_phi["train"])
    # Per-sequence streams: sequence i does not depend on how many steps others have.
    rng_a = sequence_rng(3, 5, 6)
    np.testing.assert_array_equal(multilevel_signal(rng_a, 300), small_dataset.u_phi["test"][0])


def test_output_alignment_with_plant(small_dataset: IdentificationDataset) -> None:
    from ltv_lstm_mpc.plants import PHNeutralizationPlant

    u, y = small_dataset.split("val")
    plant = PHNeutralizationPlant()
    plant.reset()
    ys = [plant.output()[0]]
    for k in range(20):
        ys.append(plant.step(u[0, k])[0])
    # y[k] is measured before u[k] acts.
    np.testing.assert_allclose(y[0, :21], ys, atol=1e-11)


def test_normalization_from_training_split(small_dataset: IdentificationDataset) -> None:
    norm = small_dataset.normalization()
    assert isinstance(norm, Normalization)
    u, y = small_dataset.split("train")
    assert norm.u_phi_min[0] == u.min() and norm.u_phi_max[0] == u.max()
    assert norm.y_phi_min[0] == y.min() and norm.y_phi_max[0] == y.max()
    un = norm.normalize_u(u)
    assert un.min() == pytest.approx(-1.0) and un.max() == pytest.approx(1.0)


def test_save_load_and_csv(small_dataset: IdentificationDataset, tmp_path: Path) -> None:
    path = small_dataset.save(tmp_path / "data.npz")
    loaded = IdentificationDataset.load(path)
    for name in SPLITS:
        np.testing.assert_array_equal(loaded.u_phi[name], small_dataset.u_phi[name])
        np.testing.assert_array_equal(loaded.y_phi[name], small_dataset.y_phi[name])
    assert loaded.metadata == small_dataset.metadata
    csv_path = small_dataset.to_csv(tmp_path / "data.csv")
    with csv_path.open() as handle:
        rows = list(csv.reader(handle))
    assert rows[0] == ["split", "sequence", "k", "time_s", "u_phi_mL_s", "y_phi_pH"]
    assert len(rows) == 1 + 6 * 300
    assert rows[1][0] == "train" and float(rows[1][5]) == small_dataset.y_phi["train"][0, 0]
    with pytest.raises(FileNotFoundError):
        IdentificationDataset.load(tmp_path / "missing.npz")
