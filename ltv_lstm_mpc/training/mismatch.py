r"""The disturbance bound :math:`d_{max}` estimated from the plant-model mismatch on data.

The guarantees of the paper assume the plant-model mismatch, seen by the observer as the
output disturbance :math:`d`, lies in :math:`\mathcal D = \{\|d\|_\infty \le d_{max}\}`
(Section III); the tightening uses :math:`\pm d_{max}` (paper notes 2.8). The disturbance
estimate is saturated at :math:`d_{max}` (eq. d_lstm_observer); when the real mismatch is larger,
:math:`\hat d` sits at the bound and offsets remain (the controller warns and records
``d_hat_saturated``). :func:`estimate_d_max` measures the mismatch of the model's
open-loop prediction on identification or validation data and adds a stated margin.

The trade-off: a larger :math:`d_{max}` shrinks the admissible set-point interval of
Assumption 5 by :math:`2 d_{max}` (and the tightened output bounds by :math:`d_{max}`),
so the estimate is a starting point to weigh against the set-points the process needs.
It lives with the identification data and the model's simulation (this package), and the
certificates take its result as the number ``d_max``. This is an estimate from finite
data, not a bound proved for the plant, and a
conservative one: the open-loop mismatch also contains the drift of the model's state,
which the observer corrects in closed loop. On the shipped pH model and the paper's
identification data (``generate_dataset(seed=0)``) it gives a mismatch of 0.17
(normalized; 0.25 pH), d_max = 0.19 with the 10 % margin on all three splits, and
d_max = 0.128 on the validation split alone (the training report's number), against the
paper's 0.1.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from ltv_lstm_mpc.exceptions import InvalidValueError
from ltv_lstm_mpc.lstm.model import LSTMModel, require_model

if TYPE_CHECKING:  # pragma: no cover
    from ltv_lstm_mpc.training.datasets import IdentificationDataset

__all__ = ["DMaxEstimate", "estimate_d_max"]


@dataclass(frozen=True)
class DMaxEstimate:
    """Result of :func:`estimate_d_max` (normalized units unless ``_phi``).

    Attributes
    ----------
    d_max : float
        ``mismatch * (1 + margin)``: the value to use as ``MPCConfig(d_max=...)``.
    mismatch : float
        Largest :math:`|y - \\hat y|` of the open-loop prediction over the splits used.
    mismatch_phi : float
        The same in physical output units (e.g. pH).
    margin : float
        Relative margin added.
    splits : tuple of str
        Data splits used.
    worst : tuple of (str, int, int)
        Split, sequence and sample of the largest mismatch.
    """

    d_max: float
    mismatch: float
    mismatch_phi: float
    margin: float
    splits: tuple[str, ...]
    worst: tuple[str, int, int]


def estimate_d_max(
    model: LSTMModel,
    data: IdentificationDataset | str | Path,
    *,
    splits: tuple[str, ...] = ("train", "val", "test"),
    margin: float = 0.1,
) -> DMaxEstimate:
    """Largest output mismatch of the open-loop prediction on ``data``, plus ``margin``.

    Each sequence is simulated open loop with :meth:`LSTMModel.simulate` from the
    equilibrium of the data's initial input (as the FIT of the training report), and the
    mismatch is measured in normalized output units, the units of :math:`d_{max}`.

    Parameters
    ----------
    model : LSTMModel
        Needs a normalization (the data are physical signals).
    data : IdentificationDataset or path
        Identification data (``ltv-lstm-mpc generate-data``), e.g. its validation split.
    splits : tuple of str
        Splits to use (those that are empty are skipped).
    margin : float
        Relative margin, >= 0 (default 10 %).

    Returns
    -------
    DMaxEstimate
    """
    model = require_model(model)
    from ltv_lstm_mpc.training.datasets import IdentificationDataset, simulate_sequences

    if model.normalization is None:
        raise InvalidValueError("estimate_d_max needs a model with a normalization")
    if not (np.isfinite(margin) and margin >= 0):
        raise InvalidValueError(f"margin must be a finite number >= 0, got {margin}")
    if model.m != 1 or model.p != 1:
        raise InvalidValueError(
            f"estimate_d_max reads single-input single-output identification data; the model "
            f"has m = {model.m}, p = {model.p}"
        )
    dataset = data if isinstance(data, IdentificationDataset) else IdentificationDataset.load(data)
    q3_initial = float(dataset.metadata.get("q3_initial", 15.6))
    scale = float(model.normalization.y_scale[0])
    worst_value, worst = -1.0, ("", 0, 0)
    used: list[str] = []
    for name in splits:
        u, y = dataset.split(name)
        if u.shape[0] == 0:
            continue
        used.append(name)
        error = np.abs(simulate_sequences(model, u, q3_initial) - y) / scale
        index = np.unravel_index(int(np.argmax(error)), error.shape)
        if float(error[index]) > worst_value:
            worst_value = float(error[index])
            worst = (name, int(index[0]), int(index[1]))
    if not used:
        raise InvalidValueError(f"no data in the splits {splits} of the dataset")
    return DMaxEstimate(
        d_max=worst_value * (1.0 + margin),
        mismatch=worst_value,
        mismatch_phi=worst_value * scale,
        margin=float(margin),
        splits=tuple(used),
        worst=worst,
    )
