"""Training on a plant the defaults were not tuned for.

The selection of the exported checkpoint (a rho_s bound tuned on the pH data, then a
non-empty admissible set-point interval of Assumption 5), the message that names the
selection constraint that failed first, the refusal to write a model whose interval is
empty, the checks of the data before training, and the escalated delta-ISS weights of the
extra epochs. A gravity-drained tank (``tests/gravity_tank.py``, level in cm, Ts = 5 s) is
the user's plant.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
from pathlib import Path

import gravity_tank
import numpy as np
import pytest
import training_factories

from ltv_lstm_mpc.training.datasets import IdentificationDataset, generate_dataset
from ltv_lstm_mpc.training.train import TrainingConfig, TrainingError


@pytest.fixture(scope="module")
def tiny_dataset() -> IdentificationDataset:
    return training_factories.tiny_dataset()


@pytest.fixture(scope="module")
def tank_dataset() -> IdentificationDataset:
    """Four 300-sample sequences of the gravity-drained tank (2 train, 1 val, 1 test)."""
    return generate_dataset(
        seed=0, sequences=4, steps=300, split_sizes=(2, 1, 1), plant=gravity_tank.GravityTank()
    )


def _with_constraint(
    dataset: IdentificationDataset, low: float, high: float
) -> IdentificationDataset:
    """The same data with another output constraint (what the plant states)."""
    return dataclasses.replace(
        dataset, metadata={**dataset.metadata, "y_phi_constraint": [low, high]}
    )


# ------------------------------------------------------------------- no torch needed
def test_tank_plant_is_no_ph_plant(tank_dataset: IdentificationDataset) -> None:
    meta = tank_dataset.metadata
    assert meta["Ts"] == 5.0 and meta["y_phi_constraint"] == [10.0, 45.0]
    assert meta["units"]["y_phi"] == "h (cm)"
    y = np.concatenate([tank_dataset.y_phi[s].ravel() for s in ("train", "val", "test")])
    assert 5.0 < y.min() < 20.0 and 30.0 < y.max() < 55.0


def test_preflight_states_range_constraint_and_time_constant_in_the_plants_units(
    tank_dataset: IdentificationDataset,
) -> None:
    from ltv_lstm_mpc.training.train import preflight

    lines = preflight(tank_dataset, TrainingConfig.fidelity())
    text = "\n".join(lines)
    assert "h (cm)" in text and "[10, 45]" in text
    assert "Ts = 5 s" in text and "time constant" in text
    assert "pH" not in text


def test_preflight_refuses_a_constraint_that_leaves_no_setpoint_before_training(
    tiny_dataset: IdentificationDataset,
) -> None:
    from ltv_lstm_mpc.training.train import preflight

    narrow = _with_constraint(tiny_dataset, 7.0, 7.2)
    with pytest.raises(TrainingError, match=r"before training: .* 4 d_max = 0\.4") as info:
        preflight(narrow, TrainingConfig.fidelity())
    assert "[7, 7.2]" in str(info.value) and "--allow-empty-interval" in str(info.value)
    outside = _with_constraint(tiny_dataset, 20.0, 30.0)
    with pytest.raises(TrainingError, match="does not overlap"):
        preflight(outside, TrainingConfig.fidelity())
    # asked for: a warning line instead
    lines = preflight(narrow, TrainingConfig.fidelity(allow_empty_interval=True))
    assert any(line.startswith("warning: ") for line in lines)


def test_escalation_only_in_the_extra_epochs() -> None:
    from ltv_lstm_mpc.training.train import escalation_factor

    config = TrainingConfig(epochs=80, escalate_every=50)
    assert [escalation_factor(e, config) for e in (0, 79, 80, 129, 130, 180)] == [
        1.0,
        1.0,
        2.0,
        2.0,
        4.0,
        8.0,
    ]
    assert escalation_factor(500, dataclasses.replace(config, escalate_every=0)) == 1.0
    with pytest.raises(Exception, match="escalate_every"):
        TrainingConfig(escalate_every=-1)
    with pytest.raises(Exception, match="allow_empty_interval"):
        TrainingConfig(allow_empty_interval=1)  # type: ignore[arg-type]


# ------------------------------------------------------------------------- torch
@pytest.mark.torch
def test_unreachable_rho_s_bound_is_named_not_the_residuals(
    tiny_dataset: IdentificationDataset, tmp_path: Path
) -> None:
    """The old message said 'no delta-ISS certified weights ... both must be < 0' with r1,
    r2 < 0 when only the selection bound rho_s <= 0.92 failed."""
    pytest.importorskip("torch")
    from ltv_lstm_mpc.training.train import train

    config = training_factories.tiny_config(
        epochs=5, max_extra_epochs=25, selection_rho_s_max=0.05, selection_fallback=False
    )
    with pytest.raises(TrainingError) as info:
        train(tiny_dataset, config, tmp_path, progress=False, resume=False)
    message = str(info.value)
    assert "none met the selection bound rho_s <= 0.05" in message
    assert "smallest rho_s was" in message and "--selection-rho-s-max" in message
    assert "no delta-ISS certified weights" not in message


@pytest.mark.torch
def test_unreachable_rho_s_bound_falls_back_to_a_nonempty_interval(
    tiny_dataset: IdentificationDataset, tmp_path: Path
) -> None:
    pytest.importorskip("torch")
    from ltv_lstm_mpc.training.train import train

    config = training_factories.tiny_config(epochs=5, max_extra_epochs=25, selection_rho_s_max=0.05)
    result = train(tiny_dataset, config, tmp_path, progress=False, resume=False)
    report = json.loads(result.report_path.read_text())
    assert report["selection_outcome"]["pool"] == "interval"
    assert report["selection_outcome"]["rho_s_bound_met"] is False
    assert report["rho_s"] > 0.05 and "was dropped" in report["selection"]
    interval = report["setpoint_interval_phi"]["paper_d_max"]
    assert interval is not None and interval["low"][0] < interval["high"][0]
    assert report["preflight"] and report["preflight"][0].startswith("output 0")


@pytest.mark.torch
def test_model_with_an_empty_interval_is_refused_unless_asked(
    tiny_dataset: IdentificationDataset, tmp_path: Path
) -> None:
    """The paper preset gave a model (rho_s = 0.999) whose interval was empty, found only
    at simulate; train now refuses to write it, and names Assumption 5."""
    pytest.importorskip("torch")
    from ltv_lstm_mpc.training.train import train

    # 6.6..6.9 pH: wide enough for the preflight (normalized width 0.58 > 0.4 on the data's
    # 6.22..7.25 pH), too narrow for the tightening of the first certified checkpoint
    # (epoch 27: 2 d_max + a_N e_inf + b_N = 0.48, above the half-width 0.29; the next one
    # has 0.25 and would be selected)
    data = _with_constraint(tiny_dataset, 6.6, 6.9)
    config = training_factories.tiny_config(epochs=5, max_extra_epochs=22)
    with pytest.raises(TrainingError) as info:
        train(data, config, tmp_path / "refused", progress=False, resume=False)
    message = str(info.value)
    assert "admissible set-point interval of Assumption 5" in message
    assert "--allow-empty-interval" in message
    assert not list((tmp_path / "refused").glob("*.npz"))
    allowed = dataclasses.replace(config, allow_empty_interval=True)
    result = train(data, allowed, tmp_path / "allowed", progress=False, resume=False)
    report = result.report
    assert result.model_path.exists()
    assert report["selection_outcome"]["interval_empty"] is True
    assert report["setpoint_interval_phi"]["paper_d_max"] is None


@pytest.mark.torch
def test_the_planned_epochs_are_unchanged_by_the_escalation(
    tiny_dataset: IdentificationDataset, tmp_path: Path
) -> None:
    """Runs that stop at the planned epochs (the shipped models') train exactly as before;
    only the extra epochs, which run while no checkpoint qualifies, escalate."""
    pytest.importorskip("torch")
    from ltv_lstm_mpc.training.train import train

    config = training_factories.tiny_config(epochs=6, max_extra_epochs=6)
    histories: dict[int, list[dict[str, float]]] = {50: [], 0: []}
    for every, history in histories.items():
        try:
            train(
                tiny_dataset,
                dataclasses.replace(config, escalate_every=every),
                tmp_path / str(every),
                progress=False,
                resume=False,
                callback=history.append,
            )
        except TrainingError:
            pass  # 12 epochs may not certify: the histories are what is compared
    escalated, paper = histories[50], histories[0]
    assert escalated[:6] == paper[:6]
    assert escalated[6]["loss"] != paper[6]["loss"]


@pytest.mark.torch
def test_cli_train_reports_the_interval_and_has_the_switch(
    tiny_dataset: IdentificationDataset, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    pytest.importorskip("torch")
    from ltv_lstm_mpc.training.cli import register

    parser = argparse.ArgumentParser()
    register(parser.add_subparsers())
    data = tiny_dataset.save(tmp_path / "tiny.npz")
    args = parser.parse_args(
        [
            *("train", "--data", str(data), "--out", str(tmp_path / "run"), "--epochs", "5"),
            *("--preset", "paper", "--lr", "0.02", "--no-progress", "--checkpoint-every", "0"),
            *("--max-extra-epochs", "25", "--selection-rho-s-max", "0.05"),
        ]
    )
    assert args.allow_empty_interval is False
    assert args.func(args) == 0
    captured = capsys.readouterr()
    assert "admissible set-point interval (Assumption 5, d_max = 0.1):" in captured.out
    assert "pH" in captured.out.split("admissible set-point interval")[1].splitlines()[0]
    assert "rho_s <= 0.05" in captured.err  # the fallback is said
    assert "time constant" in captured.err  # the preflight, before training


@pytest.mark.slow
@pytest.mark.torch
def test_default_preset_gives_the_tank_a_certified_model_with_an_interval(
    tmp_path: Path,
) -> None:
    """Guards against ``train --epochs 80`` with the default preset on a gravity-drained
    tank ending with no model. Measured on 8 sequences x 600 samples: 277 epochs (80 planned,
    then escalated extra ones), rho_s = 0.9987, interval [22.6, 32.4] cm, test FIT 86.3 %;
    140 s (410 s while other jobs loaded the 2-core VM)."""
    pytest.importorskip("torch")
    from ltv_lstm_mpc.training.train import train

    data = generate_dataset(
        seed=0, sequences=8, steps=600, split_sizes=(5, 2, 1), plant=gravity_tank.GravityTank()
    )
    config = dataclasses.replace(TrainingConfig.fidelity(), epochs=80, checkpoint_every=0)
    result = train(data, config, tmp_path, progress=False, resume=False)
    interval = result.report["setpoint_interval_phi"]["paper_d_max"]
    assert interval is not None and 10.0 < interval["low"][0] < interval["high"][0] < 45.0
