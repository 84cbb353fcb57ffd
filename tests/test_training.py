"""delta-ISS LSTM training (paper Section V): residuals, loss, short training, CLI, resume."""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np
import pytest
import training_factories

from ltv_lstm_mpc.certificates.stability import delta_iss_certificate
from ltv_lstm_mpc.exceptions import InvalidValueError
from ltv_lstm_mpc.lstm.model import LSTMModel
from ltv_lstm_mpc.training.datasets import IdentificationDataset, generate_dataset

# Torch-free imports must work without torch installed.
from ltv_lstm_mpc.training.train import TrainingConfig, fit_index


# ------------------------------------------------------------------- no torch needed
def test_fit_index_definition() -> None:
    y_real = np.array([[1.0, 2.0, 3.0], [4.0, 5.0, 6.0]])
    assert fit_index(y_real, y_real) == 100.0
    assert fit_index(y_real, np.full_like(y_real, y_real.mean())) == pytest.approx(0.0)
    y = y_real + 0.1
    expected = 100 * (1 - np.linalg.norm(0.1 * np.ones(6)) / np.linalg.norm(y_real - 3.5))
    assert fit_index(y_real, y) == pytest.approx(expected)
    with pytest.raises(InvalidValueError):
        fit_index(np.ones(3), np.ones(3))


def test_config_defaults_follow_the_paper_and_validate() -> None:
    cfg = TrainingConfig()
    assert (cfg.n, cfg.lambda1, cfg.lambda2, cfg.lr, cfg.epochs) == (5, 0.03, 0.02, 1e-3, 1000)
    assert cfg.Q_s == 1000.0 and cfg.u_max == 1.0
    assert TrainingConfig.from_dict(cfg.to_dict()) == cfg
    with pytest.raises(InvalidValueError):
        TrainingConfig(n=0)
    with pytest.raises(InvalidValueError):
        TrainingConfig(dtype="float16")
    with pytest.raises(InvalidValueError):
        TrainingConfig.from_dict({"neurons": 5})


def test_missing_torch_gives_install_hint(monkeypatch: pytest.MonkeyPatch) -> None:
    from ltv_lstm_mpc.training import train as training

    monkeypatch.setitem(sys.modules, "torch", None)
    with pytest.raises(ImportError, match=r"pip install torch==2\.13\.0"):
        training._import_torch()


def _parser() -> argparse.ArgumentParser:
    from ltv_lstm_mpc.training.cli import register

    parser = argparse.ArgumentParser(prog="ltv-lstm-mpc")
    register(parser.add_subparsers(dest="command", required=True))
    return parser


def test_cli_generate_data_and_help(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    parser = _parser()
    out = tmp_path / "d.npz"
    args = parser.parse_args(
        [
            *("generate-data", "--out", str(out), "--sequences", "3", "--steps", "60"),
            *("--seed", "7", "--csv", str(tmp_path / "d.csv")),
        ]
    )
    assert args.func(args) == 0
    ds = IdentificationDataset.load(out)
    assert ds.metadata["seed"] == 7 and ds.u_phi["train"].shape == (1, 60)
    assert (tmp_path / "d.csv").exists()
    for command in ("generate-data", "train"):
        with pytest.raises(SystemExit) as excinfo:
            parser.parse_args([command, "--help"])
        assert excinfo.value.code == 0
    help_text = capsys.readouterr().out
    assert "--lambda1" in help_text and "--resume" in help_text
    defaults = parser.parse_args(["train"])
    assert defaults.neurons is None and defaults.resume is True  # None -> the preset's value
    assert defaults.preset == "fidelity"  # the shipped model's settings


# ------------------------------------------------------------------------ torch tests
def _random_weights(rng: np.random.Generator, n: int, scale: float) -> dict[str, np.ndarray]:
    w: dict[str, np.ndarray] = {}
    for g in "fioc":
        w[f"W_{g}"] = scale * rng.standard_normal((n, 1))
        w[f"U_{g}"] = scale * rng.standard_normal((n, n))
        w[f"b_{g}"] = scale * rng.standard_normal(n)
    w["W_y"] = rng.standard_normal((1, n))
    w["b_y"] = rng.standard_normal(1)
    return w


@pytest.mark.torch
@pytest.mark.parametrize("seed", range(20))
def test_torch_residuals_equal_numpy_certificate(seed: int) -> None:
    torch = pytest.importorskip("torch")
    from ltv_lstm_mpc.training.train import torch_residuals

    rng = np.random.default_rng(seed)
    n = int(rng.integers(1, 8))
    # Realistic weight scales (trained models have |r1|, |r2| of order 1). For huge weights
    # sigma_f rounds to ~1 and 1/(1 - sigma_f) amplifies ulp differences of any two
    # implementations; the certificate is meaningless there anyway.
    scale = float(rng.choice([0.05, 0.2, 0.5, 1.0]))
    u_max = float(rng.choice([0.5, 1.0, 2.0]))
    w = _random_weights(rng, n, scale)
    cert = delta_iss_certificate(LSTMModel(**w), u_max)
    blocks = {
        g: tuple(torch.tensor(w[f"{k}_{g}"], dtype=torch.float64) for k in "WUb") for g in "fioc"
    }
    r1, r2 = torch_residuals(blocks, u_max)
    # 1e-10 absolute where |r| <= 1 (the regime where the sign matters), relative beyond.
    assert abs(float(r1) - cert.r1) <= 1e-10 * max(1.0, abs(cert.r1))
    assert abs(float(r2) - cert.r2) <= 1e-10 * max(1.0, abs(cert.r2))


@pytest.mark.torch
def test_torch_residuals_from_nn_lstm_are_differentiable_and_match_export() -> None:
    torch = pytest.importorskip("torch")
    from ltv_lstm_mpc.training.train import _export, _gate_blocks, _state_dict, torch_residuals

    torch.manual_seed(0)
    lstm = torch.nn.LSTM(1, 4, batch_first=True).double()
    linear = torch.nn.Linear(4, 1).double()
    r1, r2 = torch_residuals(_gate_blocks(lstm), 1.0)
    (r1 + r2).backward()
    assert lstm.weight_hh_l0.grad is not None and torch.all(torch.isfinite(lstm.weight_hh_l0.grad))
    dataset = generate_dataset(seed=0, sequences=3, steps=40, split_sizes=(1, 1, 1))
    model = _export(_state_dict(lstm, linear), dataset.normalization(), (6.0, 9.0))
    cert = delta_iss_certificate(model)
    assert abs(float(r1.detach()) - cert.r1) <= 1e-10
    assert abs(float(r2.detach()) - cert.r2) <= 1e-10
    # Output alignment (paper notes 1): torch's shifted outputs equal LSTMModel.simulate.
    from ltv_lstm_mpc.training.train import _predict

    u = np.linspace(-1, 1, 30)
    x0 = np.zeros(8)
    with torch.no_grad():
        state = (
            torch.zeros(1, 1, 4, dtype=torch.float64),
            torch.zeros(1, 1, 4, dtype=torch.float64),
        )
        pred, _ = _predict(lstm, linear, torch.tensor(u, dtype=torch.float64)[None, :, None], state)
    _, y = model.simulate(x0, u[:, None])
    np.testing.assert_allclose(pred.numpy()[0, :, 0], y[:-1, 0], atol=1e-12)


@pytest.fixture(scope="module")
def tiny_dataset() -> IdentificationDataset:
    return training_factories.tiny_dataset()


_tiny_config = training_factories.tiny_config


@pytest.mark.torch
def test_short_training_decreases_loss_and_exports(
    tiny_dataset: IdentificationDataset, tmp_path: Path
) -> None:
    pytest.importorskip("torch")
    from ltv_lstm_mpc.training.train import train

    result = train(tiny_dataset, _tiny_config(), tmp_path, progress=False, resume=False)
    history = result.history
    assert history[-1]["loss"] < history[0]["loss"]
    assert history[-1]["mse"] < history[0]["mse"]
    # Stopping rule: at least the planned epochs, and stopped once delta-ISS holds.
    assert result.report["epochs_run"] >= 5 and history[-1]["certified"] == 1.0
    loaded = LSTMModel.load(result.model_path)
    assert loaded.n == 5 and loaded.normalization is not None
    cert = delta_iss_certificate(loaded)
    assert cert.is_delta_iss
    report = json.loads(result.report_path.read_text())
    assert report["rho_A_delta"] == pytest.approx(cert.rho_A_delta)
    assert set(report["fit"]) == {"train", "val", "test"}
    for key in ("r1", "r2", "rho_s", "wall_time_s", "seed", "config", "library_version"):
        assert key in report
    assert result.plot_path is not None and result.plot_path.stat().st_size > 1000
    from ltv_lstm_mpc.training.train import evaluate_model

    assert evaluate_model(loaded, tiny_dataset)["test"]["fit"] == pytest.approx(
        report["fit"]["test"], abs=1e-9
    )


@pytest.mark.torch
def test_checkpoint_resume_is_deterministic(
    tiny_dataset: IdentificationDataset, tmp_path: Path
) -> None:
    pytest.importorskip("torch")
    from ltv_lstm_mpc.training.train import TrainingError, train

    config = _tiny_config(epochs=20, checkpoint_every=5, max_extra_epochs=200, lr=0.03)
    straight = tmp_path / "straight"
    resumed = tmp_path / "resumed"

    class Stop(Exception):
        pass

    def interrupt(record: dict[str, float]) -> None:
        if record["epoch"] == 12:
            raise Stop

    result_a = train(tiny_dataset, config, straight, progress=False, resume=False)
    with pytest.raises(Stop):
        train(tiny_dataset, config, resumed, progress=False, callback=interrupt)
    assert (resumed / "checkpoint.pt").exists()  # written at epoch 10
    result_b = train(tiny_dataset, config, resumed, progress=False, resume=True)
    for name, value in result_a.model.weights().items():
        np.testing.assert_array_equal(value, result_b.model.weights()[name], err_msg=name)
    assert result_a.report["epochs_run"] == result_b.report["epochs_run"]
    assert result_a.history == result_b.history
    # Resuming a finished run trains no further.
    result_c = train(tiny_dataset, config, resumed, progress=False, resume=True)
    assert result_c.report["epochs_run"] == result_b.report["epochs_run"]
    # A checkpoint written with another configuration is refused.
    with pytest.raises(TrainingError, match="different configuration"):
        train(tiny_dataset, _tiny_config(lr=0.01), resumed, progress=False, resume=True)


@pytest.mark.torch
def test_uncertified_training_fails_with_clear_message(
    tiny_dataset: IdentificationDataset, tmp_path: Path
) -> None:
    pytest.importorskip("torch")
    from ltv_lstm_mpc.training.train import TrainingError, train

    # forget-gate bias 2 starts far from delta-ISS (r1 > 0): one epoch cannot certify it.
    config = _tiny_config(epochs=1, max_extra_epochs=1, lr=1e-4)
    with pytest.raises(TrainingError, match=r"no delta-ISS certified weights after 2 epochs"):
        train(tiny_dataset, config, tmp_path, progress=False, resume=False)


@pytest.mark.torch
def test_cli_train_tiny(tiny_dataset: IdentificationDataset, tmp_path: Path) -> None:
    pytest.importorskip("torch")
    data = tiny_dataset.save(tmp_path / "tiny.npz")
    parser = _parser()
    args = parser.parse_args(
        [
            *("train", "--data", str(data), "--out", str(tmp_path / "run"), "--epochs", "3"),
            *("--preset", "paper"),
            *("--lr", "0.02", "--neurons", "3", "--no-progress", "--checkpoint-every", "2"),
        ]
    )
    assert args.func(args) == 0
    assert (tmp_path / "run" / "ph_lstm_n3.npz").exists()
    assert (tmp_path / "run" / "ph_lstm_n3_report.json").exists()
    assert (tmp_path / "run" / "ph_lstm_n3_test_prediction.png").exists()
    assert (tmp_path / "run" / "checkpoint.pt").exists()


@pytest.mark.slow
@pytest.mark.torch
def test_paper_training_reaches_the_papers_numbers(tmp_path: Path) -> None:
    """The paper's configuration (about 4-5 min on 2 cores) reaches about the paper's
    numbers: test FIT >= 94 %, rho_s <= 0.95."""
    pytest.importorskip("torch")
    from ltv_lstm_mpc.training.train import train

    dataset = generate_dataset()
    result = train(dataset, TrainingConfig(), tmp_path, progress=False, resume=False)
    report = result.report
    assert report["delta_iss"] and report["rho_A_delta"] < 1.0
    assert report["fit"]["test"] >= 94.0
    assert report["rho_s"] <= 0.95
    assert report["wall_time_s"] < 20 * 60
