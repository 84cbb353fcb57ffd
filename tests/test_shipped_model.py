"""The model shipped in ltv_lstm_mpc/data/: certified, test FIT >= 94 %, rho_s <= 0.95."""

from __future__ import annotations

import json
from importlib import resources
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from ltv_lstm_mpc.certificates.stability import (
    delta_iss_certificate,
    incremental_lyapunov_certificate,
)
from ltv_lstm_mpc.lstm.model import LSTMModel
from ltv_lstm_mpc.training.datasets import generate_split
from ltv_lstm_mpc.training.train import fit_index, simulate_sequences

DATA = resources.files("ltv_lstm_mpc") / "data"


def _path(name: str) -> Path:
    return Path(str(DATA / name))


@pytest.fixture(scope="module")
def model() -> LSTMModel:
    return LSTMModel.load(_path("ph_lstm_n5.npz"))


@pytest.fixture(scope="module")
def report() -> dict[str, Any]:
    return json.loads(_path("ph_lstm_n5_report.json").read_text())


def test_shipped_files_exist_and_are_small() -> None:
    for name in ("ph_lstm_n5.npz", "ph_lstm_n5_report.json", "ph_lstm_n5_test_prediction.png"):
        path = _path(name)
        assert path.exists(), name
        assert path.stat().st_size < 500_000, name


def test_shipped_model_is_certified(model: LSTMModel, report: dict[str, Any]) -> None:
    assert (model.n, model.m, model.p) == (5, 1, 1)
    assert model.normalization is not None
    cert = delta_iss_certificate(model, 1.0, require=True)
    assert cert.rho_A_delta < 1.0 and cert.r1 < 0 and cert.r2 < 0
    lyap = incremental_lyapunov_certificate(model, cert, Q_s=1000.0)
    assert lyap.rho_s <= 0.95  # issue target (paper: 0.92)
    assert cert.rho_A_delta == pytest.approx(report["rho_A_delta"], abs=1e-12)
    assert cert.r1 == pytest.approx(report["r1"], abs=1e-12)
    assert cert.r2 == pytest.approx(report["r2"], abs=1e-12)
    assert lyap.rho_s == pytest.approx(report["rho_s"], abs=1e-12)


def test_shipped_normalization_is_the_training_range(model: LSTMModel) -> None:
    norm = model.normalization
    assert norm is not None
    assert 12.5 <= norm.u_phi_min[0] < 12.6 and 16.9 < norm.u_phi_max[0] <= 17.0
    assert 5.9 < norm.y_phi_min[0] < 6.1 and 8.5 < norm.y_phi_max[0] < 9.0


def test_shipped_model_reaches_reported_test_fit(model: LSTMModel, report: dict[str, Any]) -> None:
    meta = report["dataset"]
    u, y = generate_split(
        "test",
        seed=meta["seed"],
        sequences=meta["sequences"],
        steps=meta["steps"],
        split_sizes=tuple(meta["split_sizes"]),
    )
    assert u.shape == (2, 1500)
    pred = simulate_sequences(model, u, meta["q3_initial"])
    fit = fit_index(y, pred)
    assert fit == pytest.approx(report["fit"]["test"], abs=0.1)
    assert fit >= 94.0  # paper: 94.0 %
    assert np.all(np.isfinite(pred))
