"""The model shipped in ltv_lstm_mpc/data/: certified, test FIT >= 97 %, rho_s <= 0.92, the
estimated plant-model mismatch d_max <= 0.15 with the paper's set-points still admissible."""

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
    assert lyap.rho_s <= 0.92  # the paper's 0.92
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
        min_hold=meta["hold_range"][0],
        max_hold=meta["hold_range"][1],
        levels=meta.get("levels", 0),
    )
    assert u.shape == (2, 1500)
    pred = simulate_sequences(model, u, meta["q3_initial"])
    fit = fit_index(y, pred)
    assert fit == pytest.approx(report["fit"]["test"], abs=0.1)
    assert fit >= 97.0  # paper: 94.0 %
    assert np.all(np.isfinite(pred))


def test_shipped_model_mismatch_leaves_the_papers_setpoints_admissible(
    model: LSTMModel, report: dict[str, Any]
) -> None:
    """estimate_d_max on the validation split (the report's number, recomputed) is at most
    0.15, and the admissible set-point interval for it still holds 7-8 pH."""
    from ltv_lstm_mpc.training.datasets import generate_dataset
    from ltv_lstm_mpc.training.mismatch import estimate_d_max

    meta = report["dataset"]
    low_hold, high_hold = meta["hold_range"]
    dataset = generate_dataset(
        seed=meta["seed"], min_hold=low_hold, max_hold=high_hold, levels=meta.get("levels", 0)
    )
    found = estimate_d_max(model, dataset, splits=("val",))
    assert found.d_max == pytest.approx(report["d_max_estimate"]["d_max"], rel=1e-9)
    assert found.d_max <= 0.15
    from ltv_lstm_mpc.certificates.certify import CertificationSettings, certify

    certification = certify(model, CertificationSettings(d_max=found.d_max))
    assert certification.y0_interval_phi is not None
    low, high = certification.y0_interval_phi
    assert low[0] < 7.0 and high[0] > 8.0
    interval = report["setpoint_interval_phi"]["estimated_d_max"]
    assert (interval["low"][0], interval["high"][0]) == pytest.approx((low[0], high[0]), abs=1e-9)
