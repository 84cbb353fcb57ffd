"""Two-input identification data (quadruple tank) and two-output training/export."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from ltv_lstm_mpc.cli import main
from ltv_lstm_mpc.lstm.model import LSTMModel
from ltv_lstm_mpc.plants import QuadrupleTankPlant
from ltv_lstm_mpc.plants.quadtank import QUADTANK_LEVEL_CONSTRAINT, QUADTANK_U_RANGE
from ltv_lstm_mpc.training.datasets import (
    SPLITS,
    IdentificationDataset,
    generate_dataset,
    generate_split,
    initial_input,
)
from ltv_lstm_mpc.training.train import TrainingConfig, evaluate_model, simulate_sequences

SIZES = {"sequences": 4, "steps": 250, "split_sizes": (2, 1, 1)}


@pytest.fixture(scope="module")
def quad_data() -> IdentificationDataset:
    return generate_dataset(seed=5, plant=QuadrupleTankPlant(), **SIZES)  # type: ignore[arg-type]


def _switches(signal: np.ndarray) -> set[int]:
    return set(np.flatnonzero(np.diff(signal) != 0).tolist())


def test_two_input_data_shapes_ranges_and_metadata(quad_data: IdentificationDataset) -> None:
    ds = quad_data
    assert (ds.inputs, ds.outputs) == (2, 2)
    assert [ds.u_phi[s].shape for s in SPLITS] == [(2, 250, 2), (1, 250, 2), (1, 250, 2)]
    start = QuadrupleTankPlant().steady_state([3.0, 3.0])[:2]
    for name in SPLITS:
        u, y = ds.split(name)
        assert np.all((u >= QUADTANK_U_RANGE[0]) & (u <= QUADTANK_U_RANGE[1]))
        assert np.all((y > 2.0) & (y < 23.0))
        np.testing.assert_allclose(y[:, 0], np.tile(start, (u.shape[0], 1)), atol=1e-12)
        for row in u:
            # Each pump is its own multilevel signal: levels held 10..100 samples, and the
            # two pumps switch at different instants (every input direction is excited).
            for j in range(2):
                edges = np.concatenate([[0], np.flatnonzero(np.diff(row[:, j])) + 1, [250]])
                assert np.all(np.diff(edges)[:-1] >= 10) and np.all(np.diff(edges)[:-1] <= 100)
            assert _switches(row[:, 0]) != _switches(row[:, 1])
    meta = ds.metadata
    assert meta["plant"] == "QuadrupleTankPlant" and meta["Ts"] == 10.0
    assert meta["u_phi_initial"] == [3.0, 3.0] and meta["model_stem"] == "quadtank_lstm"
    assert meta["y_phi_constraint"] == [list(QUADTANK_LEVEL_CONSTRAINT)] * 2
    np.testing.assert_array_equal(initial_input(meta), [3.0, 3.0])
    assert initial_input({"q3_initial": 15.6}).tolist() == [15.6]


def test_alignment_with_the_plant_and_split_regenerated_alone(
    quad_data: IdentificationDataset,
) -> None:
    u, y = quad_data.split("val")
    plant = QuadrupleTankPlant()
    ys = [plant.output()]
    for k in range(40):
        ys.append(plant.step(u[0, k]))
    np.testing.assert_allclose(y[0, :41], np.array(ys), atol=1e-11)  # y[k] before u[k] acts
    u_test, y_test = generate_split("test", seed=5, plant=QuadrupleTankPlant(), **SIZES)  # type: ignore[arg-type]
    np.testing.assert_array_equal(u_test, quad_data.u_phi["test"])
    np.testing.assert_array_equal(y_test, quad_data.y_phi["test"])


def test_normalization_per_channel_save_load_csv(
    quad_data: IdentificationDataset, tmp_path: Path
) -> None:
    norm = quad_data.normalization()
    u, y = quad_data.split("train")
    np.testing.assert_array_equal(norm.u_phi_min, u.min(axis=(0, 1)))
    np.testing.assert_array_equal(norm.y_phi_max, y.max(axis=(0, 1)))
    assert norm.u_phi_min.shape == (2,) and norm.y_phi_min.shape == (2,)
    loaded = IdentificationDataset.load(quad_data.save(tmp_path / "qt.npz"))
    np.testing.assert_array_equal(loaded.y_phi["test"], quad_data.y_phi["test"])
    assert loaded.metadata == quad_data.metadata
    lines = quad_data.to_csv(tmp_path / "qt.csv").read_text().splitlines()
    assert lines[0] == "split,sequence,k,time_s,u_phi_0,u_phi_1,y_phi_0,y_phi_1"
    assert len(lines) == 1 + 4 * 250


def test_cli_generate_data_quadtank(tmp_path: Path) -> None:
    out = tmp_path / "qt_data.npz"
    code = main(
        ["generate-data", "--plant", "quadtank", "--out", str(out), "--sequences", "3",
         "--steps", "40", "--split", "1", "1", "1", "--no-progress"]
    )  # fmt: skip
    assert code == 0
    ds = IdentificationDataset.load(out)
    assert ds.u_phi["train"].shape == (1, 40, 2) and ds.metadata["plant"] == "QuadrupleTankPlant"
    # train --data takes the plant of the file; a contradicting --plant is a usage error
    code = main(["train", "--data", str(out), "--plant", "ph", "--out", str(tmp_path / "m")])
    assert code == 2


@pytest.mark.torch
def test_two_output_training_exports_ts_constraint_and_fit_per_output(
    quad_data: IdentificationDataset, tmp_path: Path
) -> None:
    pytest.importorskip("torch")
    from ltv_lstm_mpc.training.train import train

    config = TrainingConfig(
        n=3, epochs=5, lambda1=0.3, lr=1e-2, forget_bias_init=0.0, max_extra_epochs=200,
        checkpoint_every=0, equilibrium_steps=100,
    )  # fmt: skip
    result = train(quad_data, config, tmp_path, progress=False, resume=False)
    assert result.model_path.name == "quadtank_lstm_n3.npz"
    model = LSTMModel.load(result.model_path)
    assert (model.n, model.m, model.p) == (3, 2, 2) and model.Ts == 10.0
    np.testing.assert_array_equal(model.y_phi_constraint[0], [4.0, 4.0])  # type: ignore[index]
    np.testing.assert_array_equal(model.y_phi_constraint[1], [20.0, 20.0])  # type: ignore[index]
    report = json.loads(result.report_path.read_text())
    assert report["delta_iss"] and report["Ts"] == 10.0
    per_output = report["fit_per_output"]["test"]
    assert len(per_output) == 2 and report["fit"]["test"] == pytest.approx(min(per_output))
    again = evaluate_model(model, quad_data)["test"]["fit_per_output"]
    np.testing.assert_allclose(again, per_output, atol=1e-9)
    # The numpy simulation of the exported model is what the FIT was computed on.
    pred = simulate_sequences(model, quad_data.u_phi["test"], [3.0, 3.0])
    assert pred.shape == (1, 250, 2)
    x0 = model.equilibrium(model.normalize_u([3.0, 3.0]))
    np.testing.assert_allclose(pred[0, 0], model.denormalize_y(model.output(x0)), atol=1e-12)
    assert result.plot_path is not None and result.plot_path.stat().st_size > 1000


@pytest.mark.torch
def test_cli_train_quadtank_tiny(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    pytest.importorskip("torch")
    code = main(
        ["train", "--plant", "quadtank", "--out", str(tmp_path), "--sequences", "3", "--steps",
         "120", "--split", "1", "1", "1", "--neurons", "3", "--epochs", "3", "--lr", "0.01",
         "--lambda1", "0.3", "--forget-bias-init", "0", "--checkpoint-every", "0",
         "--preset", "paper", "--no-progress"]
    )  # fmt: skip
    assert code == 0
    out = capsys.readouterr().out
    assert "FIT per output" in out and "quadtank_lstm_n3.npz" in out
    assert (tmp_path / "quadtank_identification_data.npz").exists()
