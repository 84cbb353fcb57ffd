"""``ltv-lstm-mpc warmup``: compile a controller configuration's kernels ahead of time.

A fresh install has an empty numba cache: the first controller then runs the numpy
reference while a background process compiles (``kernels="auto"``, see
:mod:`ltv_lstm_mpc.loop.kernels`). This command does the compilation now and waits for
it, e.g. as a step of a container build or a CI job, so that every later run starts
compiled.
"""

from __future__ import annotations

import argparse
from typing import Any

__all__ = ["register"]


def register(subparsers: Any) -> None:
    """Add the ``warmup`` subcommand to the ``ltv-lstm-mpc`` parser."""
    from ltv_lstm_mpc.command_arguments import add_n_option, add_solver_option

    parser = subparsers.add_parser(
        "warmup",
        help="compile the controller kernels into numba's cache now (first run only)",
        description=(
            "Compile (or load from numba's on-disk cache) every kernel a controller with the "
            "given solver, transcription and horizon calls, by running a few steps of it on "
            "the model; prints the kernels that were missing and the time taken. The default "
            "solver is simulate's, so that warming up with the defaults warms what simulate "
            "runs."
        ),
    )
    parser.add_argument(
        "model", nargs="?", default="ph_lstm_n5.npz", help="model .npz or shipped name"
    )
    add_solver_option(parser, repeat=True)
    parser.add_argument(
        "--transcription",
        choices=("auto", "condensed", "sparse"),
        default="auto",
        help="FHOCP transcription",
    )
    add_n_option(parser)
    parser.set_defaults(func=_run_warmup)


def _run_warmup(args: argparse.Namespace) -> int:
    from ltv_lstm_mpc.loop.kernels import choose_kernels
    from ltv_lstm_mpc.loop.warmup import warm_up
    from ltv_lstm_mpc.lstm.shipped import load_model
    from ltv_lstm_mpc.mpc.config import MPCConfig

    model = load_model(args.model)
    for solver in args.solver:
        config = MPCConfig(solver=solver, transcription=args.transcription, N=args.N)
        missing = choose_kernels(config, "compiled")[1]
        print(
            f"{solver}: {len(missing)} kernel(s) not in the cache"
            + (f" ({', '.join(missing)})" if missing else ""),
            flush=True,
        )
        seconds = warm_up(model, config)
        left = choose_kernels(config, "compiled")[1]
        print(f"{solver}: ready in {seconds:.1f} s" + (f"; still missing {left}" if left else ""))
    return 0
