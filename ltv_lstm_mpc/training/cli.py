"""Sub-commands ``generate-data`` and ``train`` of the ``ltv-lstm-mpc`` command line.

:func:`register` adds them to an ``argparse`` sub-parser collection; each sets
``func(args) -> int`` (exit status). Defaults reproduce the paper (Section V): 15 sequences x
1500 steps split 10/3/2, n = 5, lambda1 = 0.03, lambda2 = 0.02, Adam lr 1e-3, 1000 epochs.
``--plant quadtank`` runs the same design on the quadruple-tank process (two pumps, two
levels; :mod:`ltv_lstm_mpc.training.datasets`); its default n is
:data:`QUADTANK_NEURONS`. torch is imported only when ``train`` runs.
"""

from __future__ import annotations

import argparse
import dataclasses
import sys
from pathlib import Path
from typing import Any

from ltv_lstm_mpc.command_arguments import (
    UsageError,
    nonnegative_float,
    plant_help,
    plant_name,
    positive_float,
    positive_int,
)
from ltv_lstm_mpc.exceptions import InvalidValueError, LtvMpcError
from ltv_lstm_mpc.plants.registry import plant_name_of, resolve_plant
from ltv_lstm_mpc.training.datasets import (
    IdentificationDataset,
    _input_range,
    generate_dataset,
    hold_range_for,
    input_coverage,
)

__all__ = ["coverage_summary", "generate_data_command", "register", "train_command"]

_DEFAULT_DATA = "ph_identification_data.npz"
#: Default LSTM size for ``--plant quadtank`` (the shipped ``quadtank_lstm_n8.npz``).
QUADTANK_NEURONS = resolve_plant("quadtank").neurons


def _add_data_options(parser: argparse.ArgumentParser, seed_flag: str) -> None:
    """The options of the identification data (``generate-data``, and ``train`` without
    ``--data``)."""
    from_data = ", or the plant of the --data file" if seed_flag == "--data-seed" else ""
    parser.add_argument(
        "--plant",
        type=plant_name,
        default=None,
        help=(
            f"plant to identify: {plant_help()}; ph: pH neutralization, one input; "
            "quadtank: quadruple tank, pump voltages v1, v2 in V -> levels h1, h2 in cm, "
            "Ts = 10 s; a class of yours needs u_phi_min and u_phi_max (its input range) "
            f"(default: ph{from_data})"
        ),
    )
    parser.add_argument(
        seed_flag, dest="data_seed", type=int, default=0, help="master seed of the data"
    )
    parser.add_argument(
        "--sequences",
        type=positive_int,
        default=15,
        help="number of sequences (15: the paper's)",
    )
    parser.add_argument(
        "--steps",
        type=positive_int,
        default=1500,
        help="samples per sequence, at the plant's sampling time",
    )
    parser.add_argument(
        "--split",
        type=int,
        nargs=3,
        metavar=("TRAIN", "VAL", "TEST"),
        default=None,
        help="sequences per split (default: 10 3 2, scaled to --sequences when it differs)",
    )
    parser.add_argument(
        "--min-hold",
        type=positive_int,
        default=None,
        help="shortest hold of a level, samples (default: 10, the paper's)",
    )
    parser.add_argument(
        "--max-hold",
        type=positive_int,
        default=None,
        help="longest hold of a level, samples (default: 100, the paper's)",
    )
    parser.add_argument(
        "--hold-from-plant",
        action="store_true",
        help=(
            "hold range matched to the plant's step responses: shortest = fastest time "
            "constant, longest = 2 x slowest settling time (overrides --min-hold/--max-hold)"
        ),
    )
    parser.add_argument(
        "--levels",
        type=int,
        default=0,
        help=(
            "amplitudes from this many equally spaced values of the input range, its edges "
            "included; 0: uniform in the range, the paper's"
        ),
    )


def _split_sizes(args: argparse.Namespace) -> tuple[int, int, int]:
    if args.split is not None:
        return (int(args.split[0]), int(args.split[1]), int(args.split[2]))
    if args.sequences == 15:
        return (10, 3, 2)
    test = max(1, round(args.sequences * 2 / 15)) if args.sequences >= 3 else 0
    val = max(1, round(args.sequences * 3 / 15)) if args.sequences >= 3 else 0
    return (args.sequences - val - test, val, test)


def _plant_name(args: argparse.Namespace) -> str:
    """``--plant`` (default ``"ph"``)."""
    return getattr(args, "plant", None) or "ph"


def _data_plant(dataset: IdentificationDataset) -> str:
    """The ``--plant`` name of a data file's plant (the data record its class, or
    ``"package.module:Class"`` for a user's plant)."""
    recorded = str(dataset.metadata.get("plant", "PHNeutralizationPlant"))
    return plant_name_of(recorded) or recorded


def _default_neurons(plant: str) -> int | None:
    """The plant's default LSTM size n (None: the training default, also for data of a
    plant class that is not importable here)."""
    try:
        return resolve_plant(plant).neurons
    except LtvMpcError:
        return None


def _generate(args: argparse.Namespace) -> IdentificationDataset:
    entry = resolve_plant(_plant_name(args))
    if entry.name == "lstm":
        raise UsageError(
            "the LSTM plant is a model, not a process to identify: choose the plant the "
            f"data come from ({plant_help()})"
        )
    plant = entry.build()
    try:  # everything checked before the long part
        _input_range(plant)
    except InvalidValueError as error:
        raise UsageError(f"--plant {entry.name}: {error}") from None
    if args.steps < 2:
        raise UsageError(f"--steps must be >= 2, got {args.steps}")
    split = _split_sizes(args)
    if sum(split) != args.sequences or min(split) < 0:
        raise UsageError(
            f"--split {' '.join(map(str, split))} must be >= 0 and add up to --sequences "
            f"{args.sequences}"
        )
    min_hold = args.min_hold if args.min_hold is not None else 10
    max_hold = args.max_hold if args.max_hold is not None else 100
    if args.hold_from_plant:
        min_hold, max_hold = hold_range_for(plant)
    if min_hold > max_hold:
        raise UsageError(f"--min-hold {min_hold} is longer than --max-hold {max_hold}")
    if args.levels == 1 or args.levels < 0:
        raise UsageError(f"--levels must be 0 (uniform) or >= 2, got {args.levels}")
    print(
        f"simulating {args.sequences} sequences x {args.steps} steps of the {entry.title} "
        f"(seed {args.data_seed})...",
        file=sys.stderr,
    )
    dataset = generate_dataset(
        seed=args.data_seed,
        sequences=args.sequences,
        steps=args.steps,
        split_sizes=_split_sizes(args),
        plant=plant,
        min_hold=min_hold,
        max_hold=max_hold,
        levels=args.levels,
        progress=not getattr(args, "no_progress", False),
    )
    print(coverage_summary(dataset), file=sys.stderr)
    return dataset


def coverage_summary(dataset: IdentificationDataset) -> str:
    """Lines describing the data's input coverage (:func:`input_coverage`) per split."""
    lines = [f"input coverage (hold range {dataset.metadata.get('hold_range')} samples):"]
    for split, per_input in input_coverage(dataset).items():
        for j, c in enumerate(per_input):
            lines.append(
                f"  {split} input {j}: reached [{c['min']:.4g}, {c['max']:.4g}] of "
                f"[{c['range'][0]:.4g}, {c['range'][1]:.4g}], {c['empty_bins']} of "
                f"{len(c['bin_fractions'])} amplitude bins empty, "
                f"{100 * c['low_edge_fraction']:.1f} % / {100 * c['high_edge_fraction']:.1f} % "
                f"of samples at the low / high edge (5 %), {c['holds']['count']} holds of "
                f"{c['holds']['min']}..{c['holds']['max']} samples"
            )
    return "\n".join(lines)


def generate_data_command(args: argparse.Namespace) -> int:
    """``ltv-lstm-mpc generate-data``: simulate the identification data and save it."""
    try:
        dataset = _generate(args)
        path = dataset.save(args.out)
        print(f"wrote {path} ({dataset!r})")
        if args.csv is not None:
            csv_path = dataset.to_csv(args.csv)
            print(f"wrote {csv_path}")
    except UsageError:
        raise
    except (LtvMpcError, OSError) as error:
        print(f"ltv-lstm-mpc generate-data: error: {error}", file=sys.stderr)
        return 1
    return 0


def train_command(args: argparse.Namespace) -> int:
    """``ltv-lstm-mpc train``: train a delta-ISS LSTM, write model, report and plot."""
    try:
        from ltv_lstm_mpc.training.train import TrainingConfig, TrainingError, preflight, train
    except ImportError as error:  # pragma: no cover - torch missing
        print(f"ltv-lstm-mpc train: error: {error}", file=sys.stderr)
        return 1
    dataset: IdentificationDataset | None = None
    plant_name = _plant_name(args)
    if args.data is not None:
        try:
            dataset = IdentificationDataset.load(args.data)
        except (LtvMpcError, OSError) as error:
            print(f"ltv-lstm-mpc train: error: {error}", file=sys.stderr)
            return 1
        plant_name = _data_plant(dataset)
        if args.plant is not None and args.plant != plant_name:
            print(
                f"ltv-lstm-mpc train: error: --plant {args.plant} but {args.data} holds data "
                f"of the {plant_name} plant ({dataset.metadata.get('plant')}); drop --plant or "
                "use matching data",
                file=sys.stderr,
            )
            return 2
    neurons = args.neurons
    if neurons is None:
        neurons = _default_neurons(plant_name)
    overrides: dict[str, Any] = {
        "n": neurons,
        "epochs": args.epochs,
        "max_extra_epochs": args.max_extra_epochs,
        "seed": args.seed,
        "threads": args.threads,
        "lambda1": args.lambda1,
        "lambda2": args.lambda2,
        "lr": args.lr,
        "truncation": args.truncation,
        "batch_size": args.batch_size,
        "washout": args.washout,
        "checkpoint_every": args.checkpoint_every,
        "dtype": args.dtype,
        "forget_bias_init": args.forget_bias_init,
        "lr_final_factor": args.lr_final_factor,
        "lr_warmup_epochs": args.lr_warmup_epochs,
        "delta_iss_margin": args.delta_iss_margin,
        "grad_clip_norm": args.grad_clip_norm,
        "selection_rho_s_max": args.selection_rho_s_max,
        "allow_empty_interval": True if args.allow_empty_interval else None,
    }
    try:
        config = dataclasses.replace(
            TrainingConfig.fidelity() if args.preset == "fidelity" else TrainingConfig(),
            **{k: v for k, v in overrides.items() if v is not None},
        )
        if dataset is None:
            dataset = _generate(args)
            out = Path(args.out)
            out.mkdir(parents=True, exist_ok=True)
            data_name = resolve_plant(plant_name).data_file
            print(f"wrote {dataset.save(out / data_name)}", file=sys.stderr)
        try:
            findings = preflight(dataset, config)
        except TrainingError as error:  # found before training: a bad input
            print(f"ltv-lstm-mpc train: error: {error}", file=sys.stderr)
            return 2
        for line in findings:
            print(f"data check: {line}", file=sys.stderr)
        if args.restarts > 1:
            from ltv_lstm_mpc.training.restarts import train_restarts

            restarts = train_restarts(
                dataset,
                config,
                seeds=range(config.seed, config.seed + args.restarts),
                out_dir=args.out,
                workers=args.workers,
            )
            for run in restarts.runs:
                outcome = (
                    f"FIT(val) {run['fit_val']:.2f} %"
                    if "error" not in run
                    else "no certified model"
                )
                print(f"seed {run['seed']}: {outcome}")
            print(f"kept seed {restarts.best_seed} (best validation FIT)")
            paths: tuple[Path | None, ...] = (restarts.model_path, restarts.report_path)
            report = restarts.report
        else:
            result = train(
                dataset,
                config,
                args.out,
                progress=not args.no_progress,
                resume=args.resume,
            )
            paths = (result.model_path, result.report_path, result.plot_path, result.curves_path)
            report = result.report
    except ImportError as error:  # pragma: no cover - torch missing
        print(f"ltv-lstm-mpc train: error: {error}", file=sys.stderr)
        return 1
    except UsageError:
        raise
    except (LtvMpcError, OSError) as error:
        print(f"ltv-lstm-mpc train: error: {error}", file=sys.stderr)
        return 1
    fit = report["fit"]
    per_output = report.get("fit_per_output", {})
    if any(len(v) > 1 for v in per_output.values()):
        print(
            "FIT per output "
            + "; ".join(
                f"{k} " + ", ".join(f"{v:.2f}" for v in values) + " %"
                for k, values in per_output.items()
            )
        )
    print(
        "FIT "
        + ", ".join(f"{k} {v:.2f} %" for k, v in fit.items())
        + f"; rho(A_delta) = {report['rho_A_delta']:.4f}, rho_s = {report['rho_s']:.4f}, "
        f"r1 = {report['r1']:.4f}, r2 = {report['r2']:.4f}; {report['epochs_run']} epochs in "
        f"{report['wall_time_s']:.0f} s"
    )
    for line in _interval_lines(report):
        print(line)
    outcome = report.get("selection_outcome", {})
    if outcome.get("pool") == "interval":
        print(
            f"warning: no checkpoint met the selection bound rho_s <= "
            f"{report['config'].get('selection_rho_s_max')} (the smallest rho_s seen was "
            f"{outcome.get('smallest_rho_s_seen', float('nan')):.4f}); kept the best validation "
            "FIT among the certified checkpoints with a non-empty set-point interval",
            file=sys.stderr,
        )
    elif outcome.get("pool") == "empty_interval":
        print(
            "warning: the model's admissible set-point interval (Assumption 5) is empty at "
            "d_max = 0.1 (written because of --allow-empty-interval): simulate refuses it "
            "there; run it with a smaller --d-max",
            file=sys.stderr,
        )
    for path in paths:
        if path is not None:
            print(f"wrote {path}")
    return 0


def _interval_lines(report: dict[str, Any]) -> list[str]:
    """The admissible set-point intervals of the training report, one line per d_max, in
    the data's output units."""
    unit = str(report.get("dataset", {}).get("units", {}).get("y_phi", "output units"))
    intervals = report.get("setpoint_interval_phi") or {}
    errors = report.get("setpoint_interval_errors") or {}
    lines = []
    for key, label in (("paper_d_max", "d_max = 0.1"), ("estimated_d_max", "estimated d_max")):
        if key not in intervals:
            continue
        value = intervals[key]
        if value is None:
            reason = str(errors.get(key, "empty"))
            lines.append(
                f"admissible set-point interval (Assumption 5, {label}): "
                + ("empty" if reason.startswith("empty") else f"none ({reason})")
            )
            continue
        if key == "estimated_d_max":
            label = f"estimated d_max = {value['d_max']:.3g}"
        bounds = ", ".join(
            f"[{lo:.4g}, {hi:.4g}]" for lo, hi in zip(value["low"], value["high"], strict=True)
        )
        lines.append(f"admissible set-point interval (Assumption 5, {label}): {bounds} {unit}")
    return lines


def register(subparsers: Any) -> None:
    """Add ``generate-data`` and ``train`` to ``subparsers`` (from ``add_subparsers()``)."""
    gen = subparsers.add_parser(
        "generate-data",
        help="simulate identification data of a plant (--plant: ph, quadtank or a class of yours)",
        description=(
            "Simulate the plant (--plant) under a multilevel pseudo-random signal per input, "
            "drawn in the plant's input range (u_phi_min..u_phi_max) with levels held "
            "--min-hold..--max-hold samples at the plant's sampling time, from its nominal "
            "steady state, and save the sequences split train/val/test as .npz (optionally "
            "CSV). ph (the default, the paper's Section V): base flow q3 in [12.5, 17] mL/s, "
            "Ts = 10 s; quadtank: pump voltages in [1.5, 4] V."
        ),
    )
    gen.add_argument(
        "--out",
        default=_DEFAULT_DATA,
        help="output .npz file",
    )
    _add_data_options(gen, "--seed")
    gen.add_argument("--csv", default=None, help="also write a tidy CSV to this file")
    gen.add_argument("--no-progress", action="store_true", help="hide the progress bar")
    gen.set_defaults(func=generate_data_command)

    tr = subparsers.add_parser(
        "train",
        help="train a delta-ISS LSTM on a plant's identification data (needs torch)",
        description=(
            "Train an LSTM with the paper's delta-ISS-penalized loss (MSE + lambda1 max(r1,0) "
            "+ lambda1 max(r2,0) + lambda2 min(r1,0) + lambda2 min(r2,0)), Adam, stopping after "
            "the planned epochs only once delta-ISS holds; by default with the fidelity preset, "
            "so that 'ltv-lstm-mpc train' on the default data retrains the shipped "
            "ph_lstm_n5.npz bit for bit (about 10 minutes). Writes <out>/ph_lstm_n<N>.npz "
            "(--plant quadtank: quadtank_lstm_n<N>.npz), a JSON "
            "report and a PNG of the test-set prediction; checkpoints allow --resume. "
            "Needs torch: pip install torch==2.13.0, then pip install -e '.[train]'."
        ),
    )
    tr.add_argument(
        "--data",
        default=None,
        help="dataset .npz from generate-data (default: generate it with --plant/--data-seed/"
        "--sequences/--steps and save it in --out)",
    )
    tr.add_argument("--out", default="training_output", help="output folder")
    _add_data_options(tr, "--data-seed")
    tr.add_argument(
        "--seed",
        type=int,
        default=None,
        help="training seed (initialization, shuffling; default: 0)",
    )
    tr.add_argument(
        "--neurons",
        type=positive_int,
        default=None,
        help=f"LSTM neurons n (default: 5; --plant quadtank: {QUADTANK_NEURONS})",
    )
    tr.add_argument(
        "--epochs",
        type=positive_int,
        default=None,
        help="planned epochs (default: 1500; --preset paper: 1000)",
    )
    tr.add_argument(
        "--max-extra-epochs",
        type=int,
        default=None,
        help="extra epochs allowed until delta-ISS holds (default: 500; --preset paper: 1000)",
    )
    tr.add_argument(
        "--lambda1", type=nonnegative_float, default=None, help="delta-ISS penalty (default: 0.03)"
    )
    tr.add_argument(
        "--lambda2",
        type=nonnegative_float,
        default=None,
        help="delta-ISS margin reward (default: 0.02)",
    )
    tr.add_argument(
        "--lr",
        type=positive_float,
        default=None,
        help="Adam learning rate (default: 3e-3; --preset paper: 1e-3)",
    )
    tr.add_argument(
        "--truncation",
        type=int,
        default=None,
        help="truncated-BPTT chunk length in samples, 0 = whole sequences (default: 100)",
    )
    tr.add_argument(
        "--batch-size", type=int, default=None, help="sequences per batch, 0 = all (default: 0)"
    )
    tr.add_argument(
        "--washout",
        type=int,
        default=None,
        help="initial samples excluded from the loss (default: 0)",
    )
    tr.add_argument(
        "--forget-bias-init",
        type=float,
        default=None,
        help="initial forget-gate bias, 2.0: slow memory (default: 2.0)",
    )
    tr.add_argument(
        "--lr-final-factor",
        type=float,
        default=None,
        help=(
            "cosine learning-rate decay to lr * factor over the epochs (default: 0.03; "
            "--preset paper: 1, constant)"
        ),
    )
    tr.add_argument(
        "--lr-warmup-epochs",
        type=int,
        default=None,
        help=(
            "linear learning-rate warm-up over these first epochs (default: 20; --preset paper: 0)"
        ),
    )
    tr.add_argument(
        "--delta-iss-margin",
        type=float,
        default=None,
        help=(
            "switch the lambda2 margin term off while rho(A_delta) <= 1 - margin, on again "
            "if the margin is lost (default: 0.12; --preset paper: always on)"
        ),
    )
    tr.add_argument(
        "--grad-clip-norm",
        type=nonnegative_float,
        default=None,
        help="clip the gradient norm of each step to this value, 0: no clipping (default: 0)",
    )
    tr.add_argument(
        "--selection-rho-s-max",
        type=float,
        default=None,
        help=(
            "select only checkpoints with rho_s (Lemma 2, Q_s = 1000 I) at most this "
            "(default: 0.92; --preset paper: any certified checkpoint)"
        ),
    )
    tr.add_argument(
        "--threads",
        type=int,
        default=None,
        help="torch.set_num_threads, 1: fastest for n = 5 (default: 1)",
    )
    tr.add_argument(
        "--checkpoint-every",
        type=int,
        default=None,
        help="epochs between checkpoints (default: 50)",
    )
    tr.add_argument(
        "--dtype",
        choices=("float64", "float32"),
        default=None,
        help="float type of the training (default: float64)",
    )
    tr.add_argument(
        "--resume",
        action=argparse.BooleanOptionalAction,
        default=True,
        help="continue from <out>/checkpoint.pt when present",
    )
    tr.add_argument(
        "--preset",
        choices=("fidelity", "paper"),
        default="fidelity",
        help=(
            "fidelity (with the default data it gives the shipped ph_lstm_n5.npz): "
            "1500 epochs, lr 3e-3 with warm-up and cosine decay, the lambda2 margin term off "
            "while rho(A_delta) <= 0.88, selection among checkpoints with rho_s <= 0.92 "
            "(TrainingConfig.fidelity()); paper: the paper's settings (TrainingConfig(): "
            "1000 epochs, lr 1e-3, the margin term always on); the other options override "
            "either"
        ),
    )
    tr.add_argument(
        "--allow-empty-interval",
        action="store_true",
        help=(
            "write the model even if no checkpoint has a non-empty admissible set-point "
            "interval (Assumption 5) at d_max = 0.1 (default: refuse, naming the cause)"
        ),
    )
    tr.add_argument(
        "--restarts",
        type=positive_int,
        default=1,
        help=(
            "train this many models, seeds --seed, --seed + 1, ..., each in <out>/seed_<s>, "
            "and keep the best validation FIT"
        ),
    )
    tr.add_argument(
        "--workers",
        type=int,
        default=0,
        help=(
            "processes for --restarts, 0: one after the other; keep --workers x "
            "--threads within the cores"
        ),
    )
    tr.add_argument("--no-progress", action="store_true", help="hide the progress bar")
    tr.set_defaults(func=train_command)
