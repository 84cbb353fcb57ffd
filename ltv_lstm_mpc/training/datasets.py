r"""Identification data (paper Section V, "LSTM model identification"): pH and quadruple tank.

* :func:`multilevel_signal` — multilevel pseudo-random input: piecewise-constant levels drawn
  uniformly in :math:`\mathcal{U}_\phi = [12.5, 17]` mL/s, each held a random integer number of
  samples in [10, 100] (the last level is truncated at the end of the sequence).
* :func:`generate_dataset` — 15 sequences x 1500 steps (Ts = 10 s, q2 = 0.55 mL/s nominal), split
  10 train / 3 validation / 2 test, seeded and reproducible. Sequence ``i`` uses its own random
  stream ``numpy.random.SeedSequence(seed).spawn(sequences)[i]``, so one split (or one sequence)
  can be regenerated alone, bit for bit, with :func:`generate_split`.
* :class:`IdentificationDataset` — the arrays per split plus metadata with units;
  ``save``/``load`` (``.npz``), ``to_csv``; :meth:`IdentificationDataset.normalization` builds
  the [-1, 1] normalization from the training split's min/max (paper notes 1), reusing
  :class:`ltv_lstm_mpc.Normalization`.

Conventions
-----------
Every sequence starts with the plant at its **nominal steady state** (q3 = 15.6 mL/s,
q2 = 0.55 mL/s, pH 7.026). For a sequence of T steps, ``u_phi[k]`` (mL/s) is the base flow
applied on [k Ts, (k+1) Ts) and ``y_phi[k]`` (pH) is measured at the instant k Ts, before
``u_phi[k]`` acts: ``y_phi[0]`` is the initial steady-state pH and ``y_phi[k]`` depends on
``u_phi[0..k-1]`` only — the same alignment as the LSTM output :math:`\xi_k = W_y h_k + b_y`
(paper notes 1). Arrays have shape (sequences in the split, T).

Quadruple tank (two inputs, two outputs)
----------------------------------------
``generate_dataset(plant=QuadrupleTankPlant())`` runs the same design on Johansson's
quadruple-tank process: each pump voltage is its own multilevel pseudo-random signal in the
pump range (:data:`~ltv_lstm_mpc.plants.quadtank.QUADTANK_U_RANGE`, V), both drawn from the
sequence's random stream (pump 1 first), so the two pumps switch at different instants and
every direction of the input space is excited, the one that drives the levels apart (the
coupling) included. Every sequence starts at the steady state of the nominal voltages
(3, 3) V, without leak; Ts = 10 s. Arrays have shape (S, T, 2): ``u_phi[..., j]`` is
pump j + 1 (V), ``y_phi[..., j]`` the level h_{j+1} (cm). The metadata state the input of the
initial steady state (``u_phi_initial``), the level constraint of the benchmark
(``y_phi_constraint``, cm) and the file stem of the trained model (``model_stem``).
"""

from __future__ import annotations

import csv
import json
import re
import zipfile
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from ltv_lstm_mpc.exceptions import DimensionError, InvalidValueError
from ltv_lstm_mpc.lstm.model import LSTMModel, Normalization
from ltv_lstm_mpc.plants.ph import (
    PH_DATA_UNITS,
    PHNeutralizationPlant,
    ph_from_state,
    simulate_ph_batch,
)
from ltv_lstm_mpc.plants.protocol import Plant
from ltv_lstm_mpc.plants.quadtank import (
    QUADTANK_LEVEL_CONSTRAINT,
    QuadrupleTankPlant,
    simulate_quadtank_batch,
)
from ltv_lstm_mpc.validation import expect_path

__all__ = [
    "SPLITS",
    "IdentificationDataset",
    "generate_dataset",
    "generate_split",
    "hold_range_for",
    "initial_input",
    "input_coverage",
    "multilevel_signal",
    "sequence_rng",
    "simulate_sequences",
    "split_indices",
    "step_settling_times",
    "step_time_constants",
]

FloatArray = NDArray[np.float64]

#: Split names, in the order the sequences are assigned to them.
SPLITS: tuple[str, ...] = ("train", "val", "test")

#: Units of the stored signals of the pH data (held by the pH plant's module).
UNITS: dict[str, str] = PH_DATA_UNITS

#: Units of the stored signals of the quadruple-tank data.
QUADTANK_UNITS: dict[str, str] = {
    "u_phi": "V (pump voltages v1, v2)",
    "y_phi": "cm (lower levels h1, h2)",
    "d_phi": "cm^2 (leak areas of tanks 1, 2; 0 in the data)",
    "Ts": "s",
}

FORMAT_VERSION = 1

#: Plants :func:`generate_dataset` can simulate: the pH and quadruple-tank plants (batched,
#: compiled simulations) and any other plant with an input range (stepped one sample at a
#: time through its ``reset``/``output``/``step``, see :func:`_simulate_stepped`).
IdentificationPlant = PHNeutralizationPlant | QuadrupleTankPlant | Plant


def initial_input(metadata: Mapping[str, Any]) -> FloatArray:
    """Physical input of the steady state every sequence starts from, shape (m,).

    ``metadata["u_phi_initial"]`` (a list, any number of inputs) or the pH data's
    ``metadata["q3_initial"]`` (default 15.6 mL/s).
    """
    if "u_phi_initial" in metadata:
        return np.atleast_1d(np.asarray(metadata["u_phi_initial"], dtype=np.float64))
    return np.array([float(metadata.get("q3_initial", 15.6))])


def plant_label(plant: Any) -> str:
    """The name identification data record for ``plant``: the class name of the plants that
    ship (``"PHNeutralizationPlant"``), ``"package.module:Class"`` for any other."""
    cls = type(plant)
    if isinstance(plant, (PHNeutralizationPlant, QuadrupleTankPlant)):
        return cls.__name__
    return f"{cls.__module__}:{cls.__qualname__}"


def _input_range(plant: Any) -> tuple[FloatArray, FloatArray]:
    """(low, high) per input of a plant's ``u_phi_min`` / ``u_phi_max`` (any plant)."""
    low, high = getattr(plant, "u_phi_min", None), getattr(plant, "u_phi_max", None)
    if low is None or high is None:
        raise InvalidValueError(
            f"{type(plant).__name__} states no input range: give it attributes u_phi_min and "
            "u_phi_max (physical units, one value or one per input); the identification "
            "signal is drawn in that range"
        )
    size = max(np.size(low), np.size(high), len(getattr(plant, "input_labels", ())) or 1)
    low_v = np.broadcast_to(np.asarray(low, dtype=np.float64), (size,)).copy()
    high_v = np.broadcast_to(np.asarray(high, dtype=np.float64), (size,)).copy()
    return low_v, high_v


def _simulate_stepped(
    indices: list[int],
    *,
    seed: int,
    sequences: int,
    steps: int,
    plant: Any,
    min_hold: int,
    max_hold: int,
    progress: bool = False,
    levels: int = 0,
) -> tuple[FloatArray, FloatArray]:
    """(u_phi, y_phi) of any plant, one sample at a time: ``reset()``, then ``step(u)``.

    Each input is its own multilevel signal in the plant's range, drawn from the sequence's
    random stream (input 0 first, as for the quadruple tank). Shapes (S, T) for one
    input / output, (S, T, channels) for several.
    """
    from tqdm.auto import tqdm

    low, high = _input_range(plant)
    m = low.size
    u = np.empty((len(indices), steps, m))
    for row, index in enumerate(indices):
        rng = sequence_rng(seed, index, sequences)
        for j in range(m):
            u[row, :, j] = multilevel_signal(
                rng, steps, float(low[j]), float(high[j]), min_hold=min_hold, max_hold=max_hold,
                levels=levels,
            )  # fmt: skip
    outputs: list[FloatArray] = []
    for row in tqdm(range(len(indices)), disable=not progress, desc="sequences", leave=False):
        plant.reset()
        y = [np.atleast_1d(np.asarray(plant.output(), dtype=np.float64))]
        for k in range(steps - 1):
            y.append(np.atleast_1d(np.asarray(plant.step(u[row, k]), dtype=np.float64)))
        outputs.append(np.array(y))
    p = outputs[0].shape[1] if outputs else 1
    y_all = np.array(outputs) if outputs else np.empty((0, steps, p))
    return (u[..., 0] if m == 1 else u), (y_all[..., 0] if p == 1 else y_all)


def multilevel_signal(
    rng: np.random.Generator,
    steps: int,
    low: float = 12.5,
    high: float = 17.0,
    *,
    min_hold: int = 10,
    max_hold: int = 100,
    levels: int = 0,
) -> FloatArray:
    """Multilevel pseudo-random signal of ``steps`` samples.

    Levels are uniform in [low, high] (``levels = 0``, the paper) or drawn uniformly from
    ``levels`` equally spaced values ``low + (high - low) i / (levels - 1)``, the edges
    ``low`` and ``high`` included (``levels >= 2``: amplitude coverage of the whole input
    range; each level differs from the previous one, so about 1 / levels of the levels
    sit at each edge); each is held
    ``rng.integers(min_hold, max_hold + 1)`` samples (the last one is truncated at the end
    of the sequence).
    """
    if steps < 1:
        raise InvalidValueError(f"steps must be >= 1, got {steps}")
    if not 1 <= min_hold <= max_hold:
        raise InvalidValueError(f"need 1 <= min_hold <= max_hold, got {min_hold}, {max_hold}")
    if not high > low:
        raise InvalidValueError(f"need high > low, got low={low}, high={high}")
    if levels == 1 or levels < 0:
        raise InvalidValueError(f"levels must be 0 (uniform) or >= 2, got {levels}")
    out = np.empty(steps)
    k = 0
    previous = -1
    while k < steps:
        if levels:
            # a level different from the previous one, so the holds are as drawn
            index = int(rng.integers(0, levels if previous < 0 else levels - 1))
            if 0 <= previous <= index:
                index += 1
            previous = index
            level = low + (high - low) * index / (levels - 1)
        else:
            level = rng.uniform(low, high)
        hold = int(rng.integers(min_hold, max_hold + 1))
        out[k : k + hold] = level
        k += hold
    return out


def sequence_rng(seed: int, index: int, sequences: int) -> np.random.Generator:
    """Random generator of sequence ``index`` out of ``sequences`` for the master ``seed``."""
    if not 0 <= index < sequences:
        raise InvalidValueError(f"sequence index {index} outside [0, {sequences})")
    return np.random.default_rng(np.random.SeedSequence(seed).spawn(sequences)[index])


def split_indices(split_sizes: tuple[int, int, int] = (10, 3, 2)) -> dict[str, list[int]]:
    """Sequence indices per split: the first ``split_sizes[0]`` go to train, and so on."""
    if len(split_sizes) != 3 or any(int(s) != s or s < 0 for s in split_sizes):
        raise InvalidValueError(
            f"split_sizes must be three nonnegative integers, got {split_sizes}"
        )
    if split_sizes[0] < 1:
        raise InvalidValueError("the training split needs at least one sequence")
    start = 0
    out: dict[str, list[int]] = {}
    for name, size in zip(SPLITS, split_sizes, strict=True):
        out[name] = list(range(start, start + int(size)))
        start += int(size)
    return out


def _simulate_quadtank(
    indices: list[int],
    *,
    seed: int,
    sequences: int,
    steps: int,
    plant: QuadrupleTankPlant,
    min_hold: int,
    max_hold: int,
    levels: int = 0,
) -> tuple[FloatArray, FloatArray]:
    """(u_phi, y_phi) of shape (len(indices), steps, 2) for the quadruple tank."""
    u = np.empty((len(indices), steps, 2))
    for row, index in enumerate(indices):
        rng = sequence_rng(seed, index, sequences)
        for j in range(2):
            u[row, :, j] = multilevel_signal(
                rng, steps, plant.u_phi_min, plant.u_phi_max, min_hold=min_hold, max_hold=max_hold,
                levels=levels,
            )  # fmt: skip
    if not indices:
        return u, np.empty((0, steps, 2))
    h0 = np.tile(plant.steady_state(plant.v_nominal), (len(indices), 1))
    tank_levels = simulate_quadtank_batch(
        h0, plant.saturate(u[:, : steps - 1]), Ts=plant.Ts, substeps=plant.substeps,
        params=plant.params,
    )  # fmt: skip
    return u, np.ascontiguousarray(tank_levels[..., :2])


def _simulate(
    indices: list[int],
    *,
    seed: int,
    sequences: int,
    steps: int,
    plant: IdentificationPlant,
    min_hold: int,
    max_hold: int,
    progress: bool = False,
    levels: int = 0,
) -> tuple[FloatArray, FloatArray]:
    """(u_phi, y_phi) of shape (len(indices), steps) (pH) or (len(indices), steps, 2)
    (quadruple tank) for the given sequence indices."""
    if isinstance(plant, QuadrupleTankPlant):
        return _simulate_quadtank(
            indices, seed=seed, sequences=sequences, steps=steps, plant=plant,
            min_hold=min_hold, max_hold=max_hold, levels=levels,
        )  # fmt: skip
    if not isinstance(plant, PHNeutralizationPlant):
        return _simulate_stepped(
            indices, seed=seed, sequences=sequences, steps=steps, plant=plant,
            min_hold=min_hold, max_hold=max_hold, progress=progress, levels=levels,
        )  # fmt: skip
    u = np.empty((len(indices), steps))
    for row, index in enumerate(indices):
        rng = sequence_rng(seed, index, sequences)
        u[row] = multilevel_signal(
            rng, steps, plant.u_phi_min, plant.u_phi_max, min_hold=min_hold, max_hold=max_hold,
            levels=levels,
        )  # fmt: skip
    if not indices:
        return u, np.empty((0, steps))
    x0 = np.tile(plant.steady_state_state(plant.q3_nominal, plant.q2_nominal), (len(indices), 1))
    # Only y[0..T-1] are stored, so the last input need not be integrated.
    states = simulate_ph_batch(
        x0,
        plant.saturate(u[:, : steps - 1]),
        plant.q2_nominal,
        Ts=plant.Ts,
        substeps=plant.substeps,
        params=plant.params,
        progress=progress,
    )
    y = ph_from_state(states[..., 0], states[..., 1], pK1=plant.params.pK1, pK2=plant.params.pK2)
    return u, np.asarray(y, dtype=np.float64)


@dataclass(frozen=True)
class IdentificationDataset:
    """Input/output sequences of the identification experiment, per split.

    Attributes
    ----------
    u_phi : mapping str -> ndarray, shape (S, T) or (S, T, m)
        Inputs per split ``"train"``, ``"val"``, ``"test"`` (pH data: base flow q3, mL/s,
        (S, T); several inputs: one channel per last index).
    y_phi : mapping str -> ndarray, shape (S, T) or (S, T, p)
        Outputs per split; ``y_phi[s][:, k]`` is measured before ``u_phi[s][:, k]`` acts.
    metadata : mapping
        Units, seed, Ts, q1, q2, initial q3, hold range, sequence indices per split, ...
    """

    u_phi: Mapping[str, FloatArray]
    y_phi: Mapping[str, FloatArray]
    metadata: Mapping[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        u_fixed: dict[str, FloatArray] = {}
        y_fixed: dict[str, FloatArray] = {}
        for name in SPLITS:
            if name not in self.u_phi or name not in self.y_phi:
                raise DimensionError(f"dataset needs the splits {SPLITS}; missing {name!r}")
            u = np.array(self.u_phi[name], dtype=np.float64)
            y = np.array(self.y_phi[name], dtype=np.float64)
            if u.ndim not in (2, 3) or y.ndim not in (2, 3) or u.shape[:2] != y.shape[:2]:
                raise DimensionError(
                    f"split {name!r}: u_phi {u.shape} and y_phi {y.shape} must be (S, T) or "
                    "(S, T, channels) with the same S and T"
                )
            if not (np.all(np.isfinite(u)) and np.all(np.isfinite(y))):
                raise InvalidValueError(f"split {name!r} contains NaN or inf")
            u.setflags(write=False)
            y.setflags(write=False)
            u_fixed[name], y_fixed[name] = u, y
        object.__setattr__(self, "u_phi", u_fixed)
        object.__setattr__(self, "y_phi", y_fixed)
        object.__setattr__(self, "metadata", dict(self.metadata))

    def split(self, name: str) -> tuple[FloatArray, FloatArray]:
        """``(u_phi, y_phi)`` of one split (``"train"``, ``"val"`` or ``"test"``)."""
        if name not in SPLITS:
            raise InvalidValueError(f"unknown split {name!r}; allowed: {list(SPLITS)}")
        return self.u_phi[name], self.y_phi[name]

    @property
    def inputs(self) -> int:
        """Number of input channels m (1 for (S, T) arrays)."""
        u = self.u_phi["train"]
        return 1 if u.ndim == 2 else int(u.shape[2])

    @property
    def outputs(self) -> int:
        """Number of output channels p (1 for (S, T) arrays)."""
        y = self.y_phi["train"]
        return 1 if y.ndim == 2 else int(y.shape[2])

    def channels(self, name: str) -> tuple[FloatArray, FloatArray]:
        """``(u_phi, y_phi)`` of one split, always 3-D: (S, T, m) and (S, T, p)."""
        u, y = self.split(name)
        return (u if u.ndim == 3 else u[..., None]), (y if y.ndim == 3 else y[..., None])

    def normalization(self) -> Normalization:
        """[-1, 1] normalization from the training split's min/max per channel (paper notes 1)."""
        u, y = self.channels("train")
        return Normalization(
            u_phi_min=u.min(axis=(0, 1)),
            u_phi_max=u.max(axis=(0, 1)),
            y_phi_min=y.min(axis=(0, 1)),
            y_phi_max=y.max(axis=(0, 1)),
        )

    def save(self, path: str | Path) -> Path:
        """Save to ``.npz`` (arrays ``u_phi_<split>``, ``y_phi_<split>``, JSON ``metadata``)."""
        path = Path(path)
        if path.suffix != ".npz":
            path = path.with_suffix(".npz")
        path.parent.mkdir(parents=True, exist_ok=True)
        arrays: dict[str, Any] = {}
        for name in SPLITS:
            arrays[f"u_phi_{name}"] = self.u_phi[name]
            arrays[f"y_phi_{name}"] = self.y_phi[name]
        arrays["metadata"] = np.array(json.dumps(dict(self.metadata), sort_keys=True))
        np.savez_compressed(path, **arrays)
        return path

    @classmethod
    def load(cls, path: str | Path) -> IdentificationDataset:
        """Load a dataset written by :meth:`save`."""
        path = expect_path("path", path)
        if not path.exists():
            raise FileNotFoundError(f"dataset file {path} does not exist")
        if path.is_dir():
            raise InvalidValueError(f"{path} is a folder, not identification data (.npz)")
        not_data = (
            f"{path} is not identification data: expected the .npz written by "
            "`ltv-lstm-mpc generate-data` (arrays u_phi_train, y_phi_train, ...)"
        )
        try:
            archive = np.load(path, allow_pickle=False)
        except (ValueError, OSError, EOFError, zipfile.BadZipFile):
            raise InvalidValueError(not_data) from None
        if not isinstance(archive, np.lib.npyio.NpzFile):  # a bare .npy array
            raise InvalidValueError(not_data)
        with archive as data:
            missing = [
                f"{kind}_{name}"
                for name in SPLITS
                for kind in ("u_phi", "y_phi")
                if f"{kind}_{name}" not in data.files
            ]
            if missing:
                raise DimensionError(f"{path}: not an identification dataset, missing {missing}")
            u = {name: np.array(data[f"u_phi_{name}"]) for name in SPLITS}
            y = {name: np.array(data[f"y_phi_{name}"]) for name in SPLITS}
            meta = json.loads(str(data["metadata"])) if "metadata" in data.files else {}
        return cls(u_phi=u, y_phi=y, metadata=meta)

    def to_csv(self, path: str | Path) -> Path:
        """Write one tidy CSV: ``split, sequence, k, time_s, u_phi_<unit>, y_phi_<unit>``
        (one channel; the units of the data's metadata, e.g. ``u_phi_mL_s`` for the pH
        data's base flow, plain ``u_phi`` where none is stated) or ``..., u_phi_0, u_phi_1,
        y_phi_0, y_phi_1`` (several channels)."""
        path = Path(path)
        path.parent.mkdir(parents=True, exist_ok=True)
        Ts = float(self.metadata.get("Ts", 10.0))
        indices = self.metadata.get("sequence_indices", {})
        if self.u_phi["train"].ndim == 3 or self.y_phi["train"].ndim == 3:
            return self._to_csv_channels(path, Ts, indices)
        with path.open("w", newline="") as handle:
            writer = csv.writer(handle)
            units = self.metadata.get("units", {})
            writer.writerow(
                ["split", "sequence", "k", "time_s"]
                + [_unit_column(kind, units.get(kind)) for kind in ("u_phi", "y_phi")]
            )
            for name in SPLITS:
                u, y = self.split(name)
                seq_ids = indices.get(name, list(range(u.shape[0])))
                for row in range(u.shape[0]):
                    for k in range(u.shape[1]):
                        writer.writerow(
                            [
                                name,
                                seq_ids[row],
                                k,
                                f"{k * Ts:g}",
                                repr(float(u[row, k])),
                                repr(float(y[row, k])),
                            ]
                        )
        return path

    def _to_csv_channels(self, path: Path, Ts: float, indices: Mapping[str, Any]) -> Path:
        m, p = self.inputs, self.outputs
        with path.open("w", newline="") as handle:
            writer = csv.writer(handle)
            writer.writerow(
                ["split", "sequence", "k", "time_s"]
                + [f"u_phi_{j}" for j in range(m)]
                + [f"y_phi_{j}" for j in range(p)]
            )
            for name in SPLITS:
                u, y = self.channels(name)
                seq_ids = indices.get(name, list(range(u.shape[0])))
                for row in range(u.shape[0]):
                    for k in range(u.shape[1]):
                        writer.writerow(
                            [name, seq_ids[row], k, f"{k * Ts:g}"]
                            + [repr(float(v)) for v in u[row, k]]
                            + [repr(float(v)) for v in y[row, k]]
                        )
        return path

    def __repr__(self) -> str:
        shapes = ", ".join(f"{name}={self.u_phi[name].shape}" for name in SPLITS)
        return f"IdentificationDataset({shapes}, seed={self.metadata.get('seed')})"


def _metadata(
    seed: int,
    sequences: int,
    steps: int,
    split_sizes: tuple[int, int, int],
    plant: IdentificationPlant,
    min_hold: int,
    max_hold: int,
    levels: int = 0,
) -> dict[str, Any]:
    common: dict[str, Any] = {
        "format_version": FORMAT_VERSION,
        "seed": int(seed),
        "sequences": int(sequences),
        "steps": int(steps),
        "split_sizes": [int(s) for s in split_sizes],
        "sequence_indices": split_indices(split_sizes),
        "Ts": getattr(plant, "Ts", None),
        "substeps": getattr(plant, "substeps", None),
        "u_phi_range": [_plain(getattr(plant, name)) for name in ("u_phi_min", "u_phi_max")],
        "hold_range": [int(min_hold), int(max_hold)],
        "alignment": "y_phi[k] measured at k*Ts, before u_phi[k] acts",
    }
    if levels:  # the paper's uniform levels leave the metadata as they were
        common["levels"] = int(levels)
    if isinstance(plant, QuadrupleTankPlant):
        return {
            "plant": "QuadrupleTankPlant",
            "units": QUADTANK_UNITS,
            **common,
            "parameters": dict(plant.params.__dict__),
            "u_phi_initial": plant.v_nominal.tolist(),
            "y_phi_constraint": [list(QUADTANK_LEVEL_CONSTRAINT)] * 2,
            "model_stem": "quadtank_lstm",
            "initial_state": "steady state of u_phi_initial, no leak",
        }
    if not isinstance(plant, PHNeutralizationPlant):
        return _stepped_metadata(plant, common)
    return {
        "plant": "PHNeutralizationPlant",
        "units": UNITS,
        **common,
        "q1": plant.params.q1,
        "q2": plant.q2_nominal,
        "q3_initial": plant.q3_nominal,
        "initial_state": "nominal steady state (q3 = q3_initial, q2 = q2)",
    }


def _unit_column(kind: str, text: Any) -> str:
    """CSV column of a signal with its unit: ``("y_phi", "level h (cm)")`` ->
    ``"y_phi_cm"``, ``("u_phi", "mL/s (base flow q3)")`` -> ``"u_phi_mL_s"``; ``kind`` alone
    when no unit is stated."""
    if not isinstance(text, str) or not text.strip() or text.strip().endswith("units"):
        return kind
    text = text.strip()
    head, _, rest = text.partition(" (")
    inside = rest.rstrip(")") if rest.endswith(")") else ""
    unit = inside if inside and " " not in inside else head
    slug = re.sub(r"[^0-9A-Za-z]+", "_", unit).strip("_")
    return f"{kind}_{slug}" if slug else kind


def _plain(value: Any) -> Any:
    """A number or a list of numbers (JSON)."""
    array = np.asarray(value, dtype=np.float64)
    return float(array) if array.ndim == 0 else array.tolist()


def _stepped_metadata(plant: Any, common: dict[str, Any]) -> dict[str, Any]:
    """Metadata of a plant stepped by :func:`_simulate_stepped` (a user's plant)."""
    low, high = _input_range(plant)
    initial = getattr(plant, "u_phi_initial", None)
    inputs = ", ".join(getattr(plant, "input_labels", ())) or "input units"
    outputs = ", ".join(getattr(plant, "output_labels", ())) or "output units"
    meta: dict[str, Any] = {
        "plant": plant_label(plant),
        "units": {"u_phi": inputs, "y_phi": outputs, "Ts": "s"},
        **common,
        "u_phi_initial": _plain(initial if initial is not None else (low + high) / 2),
        "model_stem": f"{type(plant).__name__.lower()}_lstm",
        "initial_state": "the plant's reset()",
    }
    constraint = getattr(plant, "y_phi_constraint", None)
    if constraint is not None:
        meta["y_phi_constraint"] = _plain(constraint)
    return meta


def _check_sizes(sequences: int, steps: int, split_sizes: tuple[int, int, int]) -> None:
    if steps < 2:
        raise InvalidValueError(f"steps must be >= 2, got {steps}")
    if sum(split_sizes) != sequences:
        raise InvalidValueError(
            f"split sizes {tuple(split_sizes)} must add up to sequences = {sequences}"
        )


def generate_split(
    split: str,
    *,
    seed: int = 0,
    sequences: int = 15,
    steps: int = 1500,
    split_sizes: tuple[int, int, int] = (10, 3, 2),
    plant: IdentificationPlant | None = None,
    min_hold: int = 10,
    max_hold: int = 100,
    levels: int = 0,
) -> tuple[FloatArray, FloatArray]:
    """Regenerate one split alone; identical to the same split of :func:`generate_dataset`.

    Returns ``(u_phi, y_phi)``, each of shape (split size, steps) (pH) or
    (split size, steps, 2) (quadruple tank).
    """
    if split not in SPLITS:
        raise InvalidValueError(f"unknown split {split!r}; allowed: {list(SPLITS)}")
    _check_sizes(sequences, steps, split_sizes)
    plant = plant if plant is not None else PHNeutralizationPlant()
    return _simulate(
        split_indices(split_sizes)[split],
        seed=seed,
        sequences=sequences,
        steps=steps,
        plant=plant,
        min_hold=min_hold,
        max_hold=max_hold,
        levels=levels,
    )


def generate_dataset(
    seed: int = 0,
    sequences: int = 15,
    steps: int = 1500,
    split_sizes: tuple[int, int, int] = (10, 3, 2),
    *,
    plant: IdentificationPlant | None = None,
    min_hold: int = 10,
    max_hold: int = 100,
    levels: int = 0,
    progress: bool = False,
) -> IdentificationDataset:
    """Simulate the identification experiment of the paper (defaults reproduce it).

    Parameters
    ----------
    seed : int
        Master seed; sequence i uses ``SeedSequence(seed).spawn(sequences)[i]``.
    sequences, steps : int
        Number of sequences and samples per sequence (paper: 15 x 1500).
    split_sizes : (int, int, int)
        Train / validation / test sequence counts (paper: 10 / 3 / 2), assigned in order.
    plant : Plant, optional
        Plant to simulate (default: the pH plant of Table I, Ts = 10 s, q2 = 0.55 mL/s;
        a :class:`~ltv_lstm_mpc.QuadrupleTankPlant` gives two-input data,
        see the module docstring). Any other plant with ``u_phi_min`` / ``u_phi_max`` (the
        input range) is stepped one sample at a time from its ``reset()``; its metadata
        record ``"package.module:Class"``, its ``u_phi_initial`` (default: the middle of
        the range) and its ``y_phi_constraint`` where it states them.
    min_hold, max_hold : int
        Range of the number of samples each level is held (paper: 10..100;
        :func:`hold_range_for` matches it to the plant's time constants).
    levels : int
        0 (the paper): levels uniform in the input range; ``levels >= 2``: drawn from that
        many equally spaced values, the range's edges included (:func:`multilevel_signal`).
    progress : bool
        Show a tqdm progress bar over the simulated time steps.
    """
    split_sizes = tuple(int(s) for s in split_sizes)  # type: ignore[assignment]
    _check_sizes(sequences, steps, split_sizes)
    plant = plant if plant is not None else PHNeutralizationPlant()
    u_all, y_all = _simulate(
        list(range(sequences)),
        seed=seed,
        sequences=sequences,
        steps=steps,
        plant=plant,
        min_hold=min_hold,
        max_hold=max_hold,
        progress=progress,
        levels=levels,
    )
    idx = split_indices(split_sizes)
    return IdentificationDataset(
        u_phi={name: u_all[idx[name]] for name in SPLITS},
        y_phi={name: y_all[idx[name]] for name in SPLITS},
        metadata=_metadata(seed, sequences, steps, split_sizes, plant, min_hold, max_hold, levels),
    )


# ------------------------------------------------------------------ experiment design
def _step_responses(
    plant: PHNeutralizationPlant | QuadrupleTankPlant, targets: FloatArray, steps: int
) -> tuple[FloatArray, FloatArray]:
    """Outputs (S, steps, p) of steps from the nominal steady state to each constant input
    of ``targets`` (S, m), and the initial outputs (p,)."""
    if isinstance(plant, QuadrupleTankPlant):
        h0 = plant.steady_state(plant.v_nominal)
        u = np.repeat(targets[:, None, :], steps, axis=1)
        levels = simulate_quadtank_batch(
            np.tile(h0, (targets.shape[0], 1)), plant.saturate(u), Ts=plant.Ts,
            substeps=plant.substeps, params=plant.params,
        )  # fmt: skip
        return np.asarray(levels[..., :2]), np.asarray(h0[:2])
    x0 = plant.steady_state_state(plant.q3_nominal, plant.q2_nominal)
    u = np.repeat(targets[:, :1], steps, axis=1)
    states = simulate_ph_batch(
        np.tile(x0, (targets.shape[0], 1)), plant.saturate(u), plant.q2_nominal, Ts=plant.Ts,
        substeps=plant.substeps, params=plant.params,
    )  # fmt: skip
    y = ph_from_state(states[..., 0], states[..., 1], pK1=plant.params.pK1, pK2=plant.params.pK2)
    y0 = ph_from_state(x0[0], x0[1], pK1=plant.params.pK1, pK2=plant.params.pK2)
    return np.asarray(y, dtype=np.float64)[..., None], np.atleast_1d(np.asarray(y0, dtype=float))


def step_time_constants(
    plant: IdentificationPlant | None = None,
    *,
    amplitudes: int = 6,
    steps: int = 600,
) -> FloatArray:
    """Time constants (in samples) of the plant's step responses over its input range.

    From the nominal steady state the plant receives constant inputs at ``amplitudes``
    equally spaced values of its input range (all inputs together, the edges included);
    the time constant of each response and output is the first sample where the output
    has covered 63.2 % of its final change (responses that change by less than 1e-6 are
    skipped). The pH plant (six steps from q3 = 15.6 mL/s to 12.5 ... 17 mL/s): 8-12
    samples (80-120 s at Ts = 10 s); the quadruple tank: 5-13 samples.

    Parameters
    ----------
    plant : PHNeutralizationPlant or QuadrupleTankPlant, optional
        Default the pH plant of Table I.
    amplitudes : int
        Number of step sizes (>= 2).
    steps : int
        Length of each response (samples); long enough to settle.

    Returns
    -------
    ndarray
        The time constants found (samples), sorted.
    """
    plant = plant if plant is not None else PHNeutralizationPlant()
    return _step_times(plant, amplitudes, steps)[0]


def step_settling_times(
    plant: IdentificationPlant | None = None,
    *,
    amplitudes: int = 6,
    steps: int = 600,
    band: float = 0.02,
) -> FloatArray:
    """Settling times (in samples) of the same step responses as
    :func:`step_time_constants`: the first sample after which the output stays within
    ``band`` (relative) of its final change. Sorted."""
    plant = plant if plant is not None else PHNeutralizationPlant()
    return _step_times(plant, amplitudes, steps, band)[1]


def _step_times(
    plant: Any, amplitudes: int, steps: int, band: float = 0.02
) -> tuple[FloatArray, FloatArray]:
    if not isinstance(plant, (PHNeutralizationPlant, QuadrupleTankPlant)):
        raise InvalidValueError(
            "step responses are simulated for the shipped plants (ph, quadtank) only; for another "
            "plant choose min_hold / max_hold from its known time constants"
        )
    if amplitudes < 2 or steps < 10:
        raise InvalidValueError(f"need amplitudes >= 2 and steps >= 10, got {amplitudes}, {steps}")
    m = 2 if isinstance(plant, QuadrupleTankPlant) else 1
    low, high = (np.broadcast_to(v, (m,)) for v in _input_range(plant))
    targets = low + np.linspace(0.0, 1.0, amplitudes)[:, None] * (high - low)
    y, y0 = _step_responses(plant, targets, steps)
    tau: list[float] = []
    settle: list[float] = []
    for row in range(y.shape[0]):
        for j in range(y.shape[2]):
            change = y[row, :, j] - y0[j]
            final = change[-1]
            if abs(final) < 1e-6:
                continue
            relative = change / final
            reached = np.nonzero(relative >= 1.0 - np.exp(-1.0))[0]
            if reached.size:
                tau.append(float(reached[0]))
            outside = np.nonzero(np.abs(relative - 1.0) > band)[0]
            settle.append(float(outside[-1] + 1) if outside.size else 0.0)
    return np.sort(np.array(tau)), np.sort(np.array(settle))


def hold_range_for(
    plant: IdentificationPlant | None = None, *, settling: float = 2.0
) -> tuple[int, int]:
    """Hold-time range (samples) matched to the plant's time constants.

    The shortest hold is the fastest time constant of :func:`step_time_constants` (the
    fast dynamics are excited), the longest ``settling`` times the slowest 2 % settling
    time of :func:`step_settling_times` (the responses settle, so the static gain over the
    whole range is seen). The pH plant: (8, 76); the quadruple tank: (5, 96); the paper's
    pH design holds 10-100 samples.

    Parameters
    ----------
    plant : PHNeutralizationPlant or QuadrupleTankPlant, optional
        Default the pH plant.
    settling : float
        Longest hold in units of the slowest settling time (> 0).

    Returns
    -------
    (min_hold, max_hold) : (int, int)
    """
    plant = plant if plant is not None else PHNeutralizationPlant()
    if not settling > 0:
        raise InvalidValueError(f"settling must be > 0, got {settling}")
    tau, settle = _step_times(plant, 6, 600)
    if tau.size == 0:
        raise InvalidValueError("no step response of the plant changed its output")
    min_hold = max(1, int(np.floor(tau[0])))
    return min_hold, max(min_hold, int(np.ceil(settling * settle[-1])))


def input_coverage(
    dataset: IdentificationDataset, *, bins: int = 10, edge_fraction: float = 0.05
) -> dict[str, Any]:
    """How the identification inputs cover the input range, per split and input.

    Parameters
    ----------
    dataset : IdentificationDataset
    bins : int
        Equal-width amplitude bins over the input range of the data (``u_phi_range`` of the
        metadata, else the data's min/max).
    edge_fraction : float
        Width of the edge bands, as a fraction of the range.

    Returns
    -------
    dict
        ``{split: [per input: {"min", "max", "bin_fractions", "empty_bins",
        "low_edge_fraction", "high_edge_fraction", "holds": {"count", "min", "median",
        "max"}}]}``: the fraction of samples in each bin and in the bands within
        ``edge_fraction`` of the range's ends, and the hold times (samples) of the levels
        (the truncated first and last of each sequence included).
    """
    if bins < 1 or not 0.0 < edge_fraction < 0.5:
        raise InvalidValueError(
            f"need bins >= 1 and 0 < edge_fraction < 0.5, got {bins}, {edge_fraction}"
        )
    stated = dataset.metadata.get("u_phi_range")
    result: dict[str, Any] = {}
    for name in SPLITS:
        u, _ = dataset.channels(name)
        if u.shape[0] == 0:
            continue
        per_input: list[dict[str, Any]] = []
        for j in range(u.shape[2]):
            values = u[..., j]
            if stated is not None:
                lows = np.atleast_1d(np.asarray(stated[0], dtype=float))
                highs = np.atleast_1d(np.asarray(stated[1], dtype=float))
                low, high = float(lows[min(j, lows.size - 1)]), float(highs[min(j, highs.size - 1)])
            else:
                low, high = float(values.min()), float(values.max())
            width = max(high - low, 1e-12)
            counts, _ = np.histogram(np.clip(values, low, high), bins=bins, range=(low, high))
            fractions = counts / values.size
            holds: list[int] = []
            for row in values:
                changes = np.flatnonzero(np.diff(row) != 0.0) + 1
                edges = np.concatenate(([0], changes, [row.size]))
                holds.extend(np.diff(edges).tolist())
            per_input.append(
                {
                    "min": float(values.min()),
                    "max": float(values.max()),
                    "range": [low, high],
                    "bin_fractions": fractions.tolist(),
                    "empty_bins": int(np.sum(counts == 0)),
                    "low_edge_fraction": float(np.mean(values <= low + edge_fraction * width)),
                    "high_edge_fraction": float(np.mean(values >= high - edge_fraction * width)),
                    "holds": {
                        "count": len(holds),
                        "min": int(min(holds)),
                        "median": float(np.median(holds)),
                        "max": int(max(holds)),
                    },
                }
            )
        result[name] = per_input
    return result


def simulate_sequences(
    model: LSTMModel, u_phi: ArrayLike, q3_initial: float | ArrayLike
) -> FloatArray:
    """Physical outputs of ``model`` for each sequence of ``u_phi``, from the equilibrium of
    the constant physical input ``q3_initial`` (the data's initial steady state, one value
    per input); uses :meth:`LSTMModel.simulate`.

    ``u_phi`` of shape (S, T) (one input) gives (S, T) outputs (one output); (S, T, m) gives
    (S, T, p). Entry k is the output before ``u_phi[k]`` acts.
    """
    u_arr = np.asarray(u_phi, dtype=np.float64)
    channels = u_arr.ndim == 3
    u3 = u_arr if channels else np.atleast_2d(u_arr)[..., None]
    x0 = model.equilibrium(model.normalize_u(np.atleast_1d(np.asarray(q3_initial, dtype=float))))
    out = np.empty((u3.shape[0], u3.shape[1], model.p))
    for row in range(u3.shape[0]):
        u_norm = model.normalize_u(u3[row])
        _, y = model.simulate(x0, u_norm[:-1])
        out[row] = model.denormalize_y(y)
    return out if channels else out[..., 0]
