"""Small identification data and training settings shared by the training tests."""

from __future__ import annotations

from ltv_lstm_mpc.training.datasets import IdentificationDataset, generate_dataset
from ltv_lstm_mpc.training.train import TrainingConfig


def tiny_dataset() -> IdentificationDataset:
    """Four 200-sample pH sequences (2 train, 1 val, 1 test)."""
    return generate_dataset(seed=1, sequences=4, steps=200, split_sizes=(2, 1, 1))


def tiny_config(**overrides: object) -> TrainingConfig:
    """A few quick epochs on :func:`tiny_dataset` (``overrides`` set fields on top)."""
    values: dict[str, object] = dict(
        epochs=5, max_extra_epochs=300, lr=0.02, checkpoint_every=0, equilibrium_steps=100
    )
    values.update(overrides)
    return TrainingConfig(**values)  # type: ignore[arg-type]
