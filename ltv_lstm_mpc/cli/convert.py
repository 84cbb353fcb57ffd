"""``ltv-lstm-mpc convert``: a model from another format into the library's ``.npz``.

Reads an ONNX graph (:meth:`~ltv_lstm_mpc.LSTMModel.from_onnx`), a Keras model
(:meth:`~ltv_lstm_mpc.LSTMModel.from_keras`) or the library's own ``.npz``, adds the
normalization, output constraint and sampling time given on the command line (else those
the file carries), and writes ``OUT.npz``.
"""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any

__all__ = ["register"]


def register(subparsers: Any) -> None:
    """Add the ``convert`` subcommand to the ``ltv-lstm-mpc`` parser."""
    from ltv_lstm_mpc.command_arguments import positive_float, real

    parser = subparsers.add_parser(
        "convert",
        help="convert an ONNX or Keras model (one LSTM + a linear output layer) into .npz",
        description=(
            "Read SOURCE (.onnx: one LSTM operator and a linear output layer, checked against "
            "eq. (lstm); .keras; or .npz), add the metadata given here (one --u-phi per input, "
            "one --y-phi and --y-phi-constraint per output, in physical units), write OUT "
            "(.npz)."
        ),
    )
    parser.add_argument(
        "source", type=Path, metavar="SOURCE", help="model file (.onnx, .keras or .npz)"
    )
    parser.add_argument("out", type=Path, metavar="OUT", help="output .npz file")
    for flag, what in (
        ("--u-phi", "physical input range used for normalization"),
        ("--y-phi", "physical output range used for normalization"),
        ("--y-phi-constraint", "physical output constraint"),
    ):
        parser.add_argument(
            flag,
            nargs=2,
            type=real,
            action="append",
            metavar=("LOW", "HIGH"),
            default=None,
            help=f"{what} (repeat once per channel)",
        )
    parser.add_argument(
        "--Ts",
        type=positive_float,
        default=None,
        help="sampling time in s (default: the one SOURCE carries)",
    )
    parser.set_defaults(func=_run_convert)


def _run_convert(args: argparse.Namespace) -> int:
    import numpy as np

    from ltv_lstm_mpc.command_arguments import UsageError
    from ltv_lstm_mpc.lstm.model import LSTMModel, Normalization, metadata_arrays
    from ltv_lstm_mpc.lstm.shipped import load_model

    if (args.u_phi is None) != (args.y_phi is None):
        raise UsageError("give both --u-phi and --y-phi (the normalization), or neither")
    normalization = None
    if args.u_phi is not None:
        u, y = np.array(args.u_phi, dtype=float).T, np.array(args.y_phi, dtype=float).T
        normalization = Normalization(u[0], u[1], y[0], y[1])
    constraint = None
    if args.y_phi_constraint is not None:
        low, high = np.array(args.y_phi_constraint, dtype=float).T
        constraint = (low, high)
    arrays = load_model(args.source).to_arrays()  # .onnx, .keras or .npz, with its metadata
    arrays.update(metadata_arrays(normalization, constraint, args.Ts))
    model = LSTMModel.from_arrays(arrays)
    path = model.save(args.out)
    norm = "with" if model.normalization is not None else "WITHOUT"
    print(
        f"wrote {path}: n = {model.n}, m = {model.m}, p = {model.p}, {norm} normalization, "
        f"output constraint {model.y_phi_constraint}, Ts = {model.Ts}"
    )
    if model.normalization is None:
        print("  (the controller needs a normalization: give --u-phi and --y-phi)")
    return 0
