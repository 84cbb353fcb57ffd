"""Training experiments for model fidelity: one run, one row of the training log.

Trains a delta-ISS LSTM with :func:`ltv_lstm_mpc.training.train.train` on identification
data (a saved ``.npz`` or generated with the given design), then appends one row to
``experiments/training_log.md``: the settings that differ from the defaults, the FIT per
split, :math:`\\rho(A_\\delta)`, :math:`\\rho_s` (Q_s = 1000 I), the d_max estimate on the
validation split, the admissible set-point interval for it and the wall time, and (so that
runs on other data compare) the test FIT and d_max estimate on the paper's own test and
validation splits.

Run one at a time on a shared machine, with one thread (the config's ``threads``)::

    nice -n 10 python experiments/train_fidelity.py --tag r02 --data ph_data.npz \\
        --config '{"lr": 3e-3, "delta_iss_margin": 0.1}'

``--from-report DIR`` only appends the row of a finished run (its report, model and data).
``--log`` writes the rows elsewhere; a run of some 20 s (tiny data, a few dozen epochs)::

    python experiments/train_fidelity.py --tag smoke --log /tmp/log.md --out-root /tmp/runs \\
        --data-options '{"seed": 1, "sequences": 4, "steps": 200, "split_sizes": [2, 1, 1]}' \\
        --config '{"epochs": 5, "lr": 0.02, "checkpoint_every": 0, "equilibrium_steps": 100}'

Needs torch (extra ``train``).
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

LOG = Path(__file__).with_name("training_log.md")


def build_parser() -> argparse.ArgumentParser:
    """The command line (``--help`` answers before the library and torch are imported)."""
    parser = argparse.ArgumentParser(
        description=__doc__.split("\n\n")[0],
        epilog="Rows: experiments/training_log.md, whose runs docs/user-guide/training.md and "
        'docs/benchmarks.md ("The paper\'s benchmark: model, certificates, closed loops") cite.',
    )
    parser.add_argument("--tag", required=True, help="the run's name (first column, folder)")
    parser.add_argument("--data", default=None, help="identification data .npz")
    parser.add_argument("--data-options", default="{}", help="generate_dataset kwargs (JSON)")
    parser.add_argument("--config", default="{}", help="TrainingConfig overrides (JSON)")
    parser.add_argument(
        "--out-root",
        default=str(Path(tempfile.gettempdir()) / "train_fidelity_runs"),
        help="the run goes to OUT_ROOT/TAG (default: %(default)s)",
    )
    parser.add_argument("--from-report", default=None, help="only log this finished run")
    parser.add_argument(
        "--log", type=Path, default=LOG, help="append the row here (default: %(default)s)"
    )
    return parser


if __name__ == "__main__":
    build_parser().parse_args()  # --help and bad options answer here, before the imports

from ltv_lstm_mpc.lstm.model import LSTMModel  # noqa: E402
from ltv_lstm_mpc.training.datasets import (  # noqa: E402
    IdentificationDataset,
    generate_dataset,
    generate_split,
)
from ltv_lstm_mpc.training.mismatch import estimate_d_max  # noqa: E402
from ltv_lstm_mpc.training.train import (  # noqa: E402
    TrainingConfig,
    evaluate_model,
    guarantee_numbers,
)

HEADER = (
    "| run | settings (differences from the defaults) | data | train / val / test FIT (%) "
    "| rho(A_delta) | rho_s | d_max estimate (val) | set-point interval, estimated d_max (pH) "
    "| best epoch / epochs run | wall time (s, 1 core) | test FIT on the paper's test split (%) "
    "| d_max estimate on the paper's val split |\n"
    "|---|---|---|---|---|---|---|---|---|---|---|---|\n"
)


def _settings(config: dict[str, Any]) -> str:
    defaults = TrainingConfig().to_dict()
    diff = {k: v for k, v in config.items() if defaults.get(k) != v}
    return ", ".join(f"{k}={v}" for k, v in sorted(diff.items())) or "defaults"


def _data_label(metadata: dict[str, Any]) -> str:
    label = (
        f"{metadata.get('sequences')}x{metadata.get('steps')} "
        f"split {'/'.join(str(s) for s in metadata.get('split_sizes', []))}, "
        f"hold {metadata.get('hold_range')}"
    )
    if metadata.get("levels"):
        label += f", {metadata['levels']} levels"
    return label + f", seed {metadata.get('seed')}"


def row(tag: str, run_dir: Path, dataset: IdentificationDataset) -> str:
    """One Markdown table row for a finished run in ``run_dir``."""
    report_path = next(run_dir.glob("*_report.json"))
    report = json.loads(report_path.read_text())
    model = LSTMModel.load(run_dir / report["model_file"])
    if "d_max_estimate" not in report:  # a report written before the field existed
        config = TrainingConfig.from_dict(
            {k: v for k, v in report["config"].items() if k in TrainingConfig().to_dict()}
        )
        report.update(guarantee_numbers(model, dataset, config))
    estimate = report["d_max_estimate"] or {"d_max": estimate_d_max(model, dataset).d_max}
    interval = report["setpoint_interval_phi"].get("estimated_d_max")
    interval_text = (
        "empty" if interval is None else f"[{interval['low'][0]:.2f}, {interval['high'][0]:.2f}]"
    )
    fit = report["fit"]
    # The paper's data (seed 0, 15 x 1500, 10/3/2): the same sequences for every run.
    paper_test, paper_val = generate_split("test"), generate_split("val")
    paper = IdentificationDataset(
        u_phi={"train": paper_test[0], "val": paper_val[0], "test": paper_test[0]},
        y_phi={"train": paper_test[1], "val": paper_val[1], "test": paper_test[1]},
        metadata={"q3_initial": 15.6},
    )
    fit_paper_test = evaluate_model(model, paper, ("test",))["test"]["fit"]
    d_max_paper_val = estimate_d_max(model, paper, splits=("val",)).d_max
    return (
        f"| {tag} | {_settings(report['config'])} | {_data_label(report['dataset'])} "
        f"| {fit['train']:.2f} / {fit['val']:.2f} / {fit['test']:.2f} "
        f"| {report['rho_A_delta']:.4f} | {report['rho_s']:.4f} | {estimate['d_max']:.3f} "
        f"| {interval_text} | {report['best_epoch']} / {report['epochs_run']} "
        f"| {report['wall_time_s']:.0f} | {fit_paper_test:.2f} | {d_max_paper_val:.3f} |\n"
    )


def append_row(text: str, log: Path = LOG) -> None:
    """Append ``text`` to the Markdown table in ``log`` (created with its header if absent)."""
    if not log.exists():
        log.write_text(
            "# Training experiments (model fidelity)\n\nEach row: one run of "
            "`experiments/train_fidelity.py` on one core (torch threads = 1, nice 10) of a "
            "2-core VM shared with another job; FIT as the training report defines it "
            "(physical pH, open-loop simulation from the equilibrium of the first input).\n\n"
            + HEADER
        )
    with log.open("a") as handle:
        handle.write(text)


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    if args.data is not None:
        dataset = IdentificationDataset.load(args.data)
    else:
        dataset = generate_dataset(**json.loads(args.data_options))
    if args.from_report is not None:
        append_row(row(args.tag, Path(args.from_report), dataset), args.log)
        return 0
    from ltv_lstm_mpc.training.train import train

    config = TrainingConfig.from_dict({**TrainingConfig().to_dict(), **json.loads(args.config)})
    out = Path(args.out_root) / args.tag
    start = time.perf_counter()
    result = train(dataset, config, out, progress=False, resume=False)
    print(f"{args.tag}: {time.perf_counter() - start:.0f} s", file=sys.stderr)
    text = row(args.tag, out, dataset)
    print(text, end="")
    append_row(text, args.log)
    del result
    return 0


if __name__ == "__main__":
    sys.exit(main())
