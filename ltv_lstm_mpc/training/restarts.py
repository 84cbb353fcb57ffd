"""Restarts of :func:`~ltv_lstm_mpc.training.train.train` over seeds, the best by validation FIT.

Each seed trains in its own folder ``<out_dir>/seed_<seed>`` (so each can be resumed from its
checkpoint), in a process pool of ``workers`` processes (``workers = 0``: one after the
other in this process). The restart kept is the one with the best validation FIT of its
selected (certified) model; the test split plays no part in the choice. Its model, report
and plots are copied to ``out_dir`` and ``restarts.json`` lists every seed's validation FIT
and certificate numbers.

Every process trains with ``config.threads`` torch threads: on a machine with C cores,
``workers * threads <= C`` avoids oversubscription (for n = 5 one thread per process is
fastest).
"""

from __future__ import annotations

import dataclasses
import json
import shutil
from collections.abc import Sequence
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from ltv_lstm_mpc.exceptions import InvalidValueError
from ltv_lstm_mpc.lstm.model import LSTMModel
from ltv_lstm_mpc.training.datasets import IdentificationDataset
from ltv_lstm_mpc.training.train import TrainingConfig, TrainingError

__all__ = ["RestartsResult", "train_restarts"]


@dataclass(frozen=True)
class RestartsResult:
    """What :func:`train_restarts` produced.

    Attributes
    ----------
    best_seed : int
        Seed of the restart kept (best validation FIT).
    model : LSTMModel
        Its model.
    report : dict
        Its training report (with ``restarts`` added: the summary below).
    model_path, report_path : Path
        The copies in ``out_dir``.
    runs : list of dict
        Per seed: ``seed``, ``fit_val``, ``rho_A_delta``, ``rho_s``, ``wall_time_s``,
        ``best_epoch``, ``folder``, or ``error`` for a seed that produced no certified model.
    """

    best_seed: int
    model: LSTMModel
    report: dict[str, Any]
    model_path: Path
    report_path: Path
    runs: list[dict[str, Any]]


def _train_one(
    dataset: IdentificationDataset, config: TrainingConfig, folder: str, name: str | None
) -> dict[str, Any]:
    """One restart (top level, so a process pool can pickle it)."""
    from ltv_lstm_mpc.training.train import train

    try:
        result = train(dataset, config, folder, progress=False, resume=True, name=name)
    except TrainingError as error:
        return {"seed": config.seed, "folder": folder, "error": str(error)}
    report = result.report
    return {
        "seed": config.seed,
        "folder": folder,
        "fit_val": report["fit"].get("val", report["fit"]["train"]),
        "rho_A_delta": report["rho_A_delta"],
        "rho_s": report["rho_s"],
        "best_epoch": report["best_epoch"],
        "wall_time_s": report["wall_time_s"],
        "model_file": report["model_file"],
        "report_file": result.report_path.name,
    }


def train_restarts(
    dataset: IdentificationDataset,
    config: TrainingConfig | None = None,
    seeds: Sequence[int] = (0, 1, 2, 3),
    out_dir: str | Path = "training_output",
    *,
    workers: int = 0,
    name: str | None = None,
) -> RestartsResult:
    """Train one model per seed and keep the one with the best validation FIT.

    Parameters
    ----------
    dataset : IdentificationDataset
        Identification data.
    config : TrainingConfig, optional
        Settings of every restart; its ``seed`` is replaced by each of ``seeds``.
    seeds : sequence of int
        Seeds of the restarts (distinct).
    out_dir : path
        Folder of the restarts (``seed_<seed>`` each) and of the copies of the best one.
    workers : int
        Size of the process pool (0: the restarts run one after the other in this process).
    name : str, optional
        File stem of the models (as :func:`~ltv_lstm_mpc.training.train.train`).

    Returns
    -------
    RestartsResult

    Raises
    ------
    TrainingError
        No restart produced a certified model.
    """
    config = config if config is not None else TrainingConfig()
    seeds = [int(s) for s in seeds]
    if not seeds or len(set(seeds)) != len(seeds):
        raise InvalidValueError(f"seeds must be distinct and at least one, got {seeds}")
    if not isinstance(workers, int) or workers < 0:
        raise InvalidValueError(f"workers must be a nonnegative integer, got {workers!r}")
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    jobs = [
        (dataset, dataclasses.replace(config, seed=seed), str(out / f"seed_{seed}"), name)
        for seed in seeds
    ]
    if workers == 0:
        runs = [_train_one(*job) for job in jobs]
    else:
        import multiprocessing

        # spawn: torch's threads and a fork do not mix
        context = multiprocessing.get_context("spawn")
        with ProcessPoolExecutor(max_workers=workers, mp_context=context) as pool:
            runs = list(pool.map(_train_one, *zip(*jobs, strict=True)))
    done = [run for run in runs if "error" not in run]
    if not done:
        raise TrainingError(
            "no restart produced a certified model: "
            + "; ".join(f"seed {run['seed']}: {run['error']}" for run in runs)
        )
    best = max(done, key=lambda run: run["fit_val"])
    folder = Path(best["folder"])
    for path in folder.iterdir():
        if path.is_file() and path.name != "checkpoint.pt":
            shutil.copy2(path, out / path.name)
    summary = {
        "selection": "best validation FIT of the restarts' selected models",
        "best_seed": best["seed"],
        "runs": runs,
    }
    (out / "restarts.json").write_text(json.dumps(summary, indent=2) + "\n")
    report_path = out / best["report_file"]
    report = json.loads(report_path.read_text())
    report["restarts"] = summary
    report_path.write_text(json.dumps(report, indent=2) + "\n")
    model_path = out / best["model_file"]
    return RestartsResult(
        best_seed=int(best["seed"]),
        model=LSTMModel.load(model_path),
        report=report,
        model_path=model_path,
        report_path=report_path,
        runs=runs,
    )
