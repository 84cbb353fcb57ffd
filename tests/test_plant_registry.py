"""The plant registry: registered names, ``module:Class`` plants through every entry point.

A plant defined only in the tests (``tests/user_plant.py``) runs through
``simulate --plant``, ``generate-data --plant`` and a campaign spec on 2 Dask workers; each
check replays the plant on the recorded inputs, so it fails unless that plant made the
outputs.
"""

from __future__ import annotations

import csv
import json
import math
import os
from pathlib import Path

import numpy as np
import pytest
import user_plant

from ltv_lstm_mpc import UnknownPlantError, register_plant, registered_plants, resolve_plant
from ltv_lstm_mpc.campaign.spec import load_spec
from ltv_lstm_mpc.campaign.task import run_task
from ltv_lstm_mpc.cli import main
from ltv_lstm_mpc.exceptions import ArgumentTypeError, CampaignSpecError
from ltv_lstm_mpc.plants.ph import PHNeutralizationPlant
from ltv_lstm_mpc.plants.quadtank import QuadrupleTankPlant
from ltv_lstm_mpc.plants.registry import plant_name_of
from ltv_lstm_mpc.training.datasets import IdentificationDataset

USER = "user_plant:HammersteinPH"
TESTS = Path(__file__).resolve().parent


def test_the_plants_that_ship_are_registered_with_their_defaults() -> None:
    assert {"ph", "lstm", "quadtank"} <= set(registered_plants())
    ph = resolve_plant("ph")
    assert isinstance(ph.build(), PHNeutralizationPlant)
    assert ph.Ts == 10.0 and ph.nominal_disturbance == (0.55,) and ph.model == "ph_lstm_n5.npz"
    quadtank = resolve_plant("quadtank")
    assert isinstance(quadtank.build(), QuadrupleTankPlant)
    assert quadtank.neurons == 8 and len(quadtank.output_labels) == 2
    assert plant_name_of("QuadrupleTankPlant") == "quadtank"
    assert plant_name_of("Nothing") is None


def test_the_ph_mismatch_option_changes_the_plant() -> None:
    nominal = resolve_plant("ph").build()
    scaled = resolve_plant("ph").build(mismatch={"W_a1": 1.1})
    assert scaled.params.W_a1 == pytest.approx(1.1 * nominal.params.W_a1, rel=1e-15)
    with pytest.raises(UnknownPlantError, match=r"takes no option y0_phi .*accepts: mismatch"):
        resolve_plant("ph").build(y0_phi=7.0)


def test_a_user_class_resolves_with_the_defaults_it_states() -> None:
    entry = resolve_plant(USER)
    assert entry.name == USER and entry.Ts == 10.0 and entry.model == "ph_lstm_n5.npz"
    assert entry.setpoints == ("7.3", "7.0") and entry.nominal_disturbance == (0.0,)
    assert entry.output_labels == ("pH",)
    before = user_plant.HammersteinPH.built
    plant = entry.build()
    assert isinstance(plant, user_plant.HammersteinPH)
    assert user_plant.HammersteinPH.built == before + 1
    assert plant.output()[0] == pytest.approx(7.026, abs=1e-12)


@pytest.mark.parametrize(
    ("name", "message"),
    [
        ("tank", "unknown plant 'tank': use one of lstm, ph, quadtank"),
        ("no_such_module:Plant", "module 'no_such_module' cannot be imported"),
        ("user_plant:Missing", "has no attribute 'Missing'"),
        ("user_plant:NotAPlant", r"class NotAPlant has no output\(\), step\(\)"),
        ("user_plant:", "write a user plant as 'package.module:Class'"),
    ],
)
def test_bad_plant_names_say_what_is_wrong(name: str, message: str) -> None:
    with pytest.raises(UnknownPlantError, match=message):
        resolve_plant(name)


def test_register_plant_adds_a_name_and_refuses_duplicates() -> None:
    from ltv_lstm_mpc.plants import registry

    try:
        register_plant("hammerstein_test", lambda model: user_plant.HammersteinPH(), Ts=10.0)
        assert "hammerstein_test" in registered_plants()
        assert resolve_plant("hammerstein_test").title == "plant hammerstein_test"
        with pytest.raises(UnknownPlantError, match="already registered"):
            register_plant("hammerstein_test", lambda model: user_plant.HammersteinPH())
        with pytest.raises(UnknownPlantError, match="without ':'"):
            register_plant("a:b", lambda model: None)
        register_plant("broken_test", lambda model: object())
        with pytest.raises(
            ArgumentTypeError, match=r"must be a plant \(with reset\(\), output\(\), step\(\)\)"
        ):
            resolve_plant("broken_test").build()
    finally:
        registry._REGISTRY.pop("hammerstein_test", None)
        registry._REGISTRY.pop("broken_test", None)


def _read_columns(path: Path, *names: str) -> list[np.ndarray]:
    with path.open(newline="") as handle:
        rows = list(csv.DictReader(handle))
    return [np.array([float(r[name]) for r in rows]) for name in names]


def test_simulate_runs_a_user_plant(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "sim"
    argv = ["simulate", "--plant", USER, "--solver", "daqp", "--segment", "80", "--L-d", "0.1",
            "--no-progress", "--out", str(out)]  # fmt: skip
    assert main(argv) == 0
    y, u, y0, d = _read_columns(out / "simulate.csv", "y_phi", "u_phi", "y0_phi", "disturbance")
    assert y.shape == (160,) and set(y0) == {7.3, 7.0} and set(d) == {0.0}  # its defaults
    np.testing.assert_allclose(y, user_plant.replay(u, d), rtol=0, atol=1e-12)
    assert np.all((u >= 12.5 - 1e-9) & (u <= 17.0 + 1e-9))
    summary = json.loads((out / "simulate.json").read_text())
    assert summary["final_offset"] < 1e-3  # offset-free on a plant the model only approximates
    assert "final offset" in capsys.readouterr().out


def test_simulate_refuses_a_plant_that_cannot_be_imported(capsys) -> None:
    with pytest.raises(SystemExit) as exit_info:  # an argparse usage error
        main(["simulate", "--plant", "nowhere.mod:Plant", "--no-progress"])
    assert exit_info.value.code == 2
    assert "module 'nowhere.mod' cannot be imported" in capsys.readouterr().err


def test_generate_data_runs_a_user_plant(tmp_path: Path) -> None:
    path = tmp_path / "data.npz"
    argv = ["generate-data", "--plant", USER, "--sequences", "3", "--steps", "150",
            "--out", str(path), "--no-progress"]  # fmt: skip
    assert main(argv) == 0
    data = IdentificationDataset.load(path)
    meta = data.metadata
    assert meta["plant"] == USER and meta["Ts"] == 10.0
    assert meta["u_phi_range"] == [12.5, 17.0] and meta["u_phi_initial"] == 15.6
    assert meta["y_phi_constraint"] == [6.0, 9.0] and meta["model_stem"] == "hammersteinph_lstm"
    for split in ("train", "val", "test"):
        u, y = data.split(split)
        assert u.shape == y.shape == (1, 150)
        assert u.min() >= 12.5 and u.max() <= 17.0 and np.ptp(u) > 1.0  # excited
        np.testing.assert_allclose(y[0], user_plant.replay(u[0]), rtol=0, atol=1e-12)


def test_campaign_runs_a_user_plant_on_two_dask_workers(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    pytest.importorskip("distributed")
    # the workers import the plant the same way: it must be on their path
    path = os.pathsep.join(p for p in (str(TESTS), os.environ.get("PYTHONPATH")) if p)
    monkeypatch.setenv("PYTHONPATH", path)
    spec = tmp_path / "spec.toml"
    spec.write_text(
        f'[campaign]\nplant = "{USER}"\nsteps = 60\nsetpoints = [7.3, 7.1]\n'
        'solver = "daqp"\n[factors]\nseed = [0, 1]\nnoise_std = [0.0, 0.01]\n'
    )
    out = tmp_path / "out"
    assert main(["campaign", str(spec), "--out", str(out), "--workers", "2", "--no-progress"]) == 0
    assert "4 tasks (4 run now, 0 already finished), 0 errors" in capsys.readouterr().out
    rows = {r["key"]: r for r in (json.loads(p.read_text()) for p in (out / "tasks").glob("*"))}
    assert len(rows) == 4
    assert all(r["status"] == "ok" and r["plant"] == USER for r in rows.values())
    # the same task in this process gives the same closed loop: the workers used this plant
    for task in load_spec(spec).tasks:
        local = run_task(task).row
        remote = rows[task.key]
        assert math.isfinite(remote["final_offset"])
        assert remote["final_offset"] == local["final_offset"]
        assert remote["segment_offsets"] == local["segment_offsets"]


def test_a_campaign_spec_refuses_options_the_user_plant_lacks(tmp_path: Path) -> None:
    spec = tmp_path / "spec.toml"
    spec.write_text(f'[campaign]\nplant = "{USER}"\nsteps = 60\nsetpoints = [7.3]\nq2 = [0.5]\n')
    with pytest.raises(CampaignSpecError, match="q2 is the pH plant's buffer flow"):
        load_spec(spec)
    spec.write_text('[campaign]\nplant = "nowhere:Plant"\nsteps = 60\nsetpoints = [7.3]\n')
    with pytest.raises(CampaignSpecError, match="module 'nowhere' cannot be imported"):
        load_spec(spec)
