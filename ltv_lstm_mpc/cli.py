"""Command-line interface ``ltv-lstm-mpc``.

Subcommands
-----------
certify
    Print every certificate number of the paper for a model (``--json`` for one JSON object).
generate-data, train
    Identification data and delta-ISS LSTM training (see ``ltv_lstm_mpc.training_cli``).
"""

from __future__ import annotations

import argparse
import json
import sys
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from . import __version__
from .certify import PAPER_Y_PHI_BOUNDS, Certification, CertificationSettings, certify
from .exceptions import LtvMpcError
from .model import LSTMModel
from .shipped import shipped_path

__all__ = ["build_parser", "main"]

EXAMPLE_MODEL = "example_delta_iss_n3.npz"


def _resolve_model_path(name: str) -> Path:
    """A path, or the name of a model shipped in ``ltv_lstm_mpc/data``."""
    path = Path(name)
    return path if path.exists() else shipped_path(name)


def _add_certify(subparsers: Any) -> None:
    parser = subparsers.add_parser(
        "certify",
        help="print every certificate number (delta-ISS, Lyapunov, observer, tightening)",
        description=(
            "Compute the certificates of Schimperna & Magni for an LSTM model: delta-ISS "
            "(Assumption 2: rho_A_delta, r1, r2), Lemma 2 (P_s, rho_s, c_s), Theorem 2 (A_d, "
            "P_o, rho_o, c_o, L_max, w_max), tightening (a, b, e_inf, P_f, alpha), Assumption 5 "
            "(y0_interval), Lemma 5 (K_bar) and Theorem 3's set-point rate bound. Defaults are "
            "the paper's values. All numbers are in normalized units unless suffixed _phi."
        ),
    )
    parser.add_argument(
        "model",
        nargs="?",
        default=EXAMPLE_MODEL,
        help=f"model .npz file or the name of a shipped model (default: {EXAMPLE_MODEL})",
    )
    parser.add_argument("--json", action="store_true", help="print one JSON object")
    parser.add_argument("--u-max", type=float, default=1.0, help="input bound u_max (default 1)")
    parser.add_argument("--Q-s", type=float, default=1000.0, help="Q_s = q I_2 (default 1000)")
    parser.add_argument("--Q-o", type=float, default=1000.0, help="Q_o = q I_3 (default 1000)")
    parser.add_argument("--L-d", type=float, default=0.01, help="L_d = l_d I_p (default 0.01)")
    parser.add_argument("--L-f", type=float, default=0.0, help="fill value of L_f (default 0)")
    parser.add_argument("--L-i", type=float, default=0.0, help="fill value of L_i (default 0)")
    parser.add_argument("--L-o", type=float, default=0.0, help="fill value of L_o (default 0)")
    parser.add_argument(
        "--design-gains",
        action="store_true",
        help="choose L_f, L_i, L_o minimizing rho(A_d) (SPEC 2.11) instead of the fill values",
    )
    parser.add_argument("--d-max", type=float, default=0.1, help="d_max (default 0.1)")
    parser.add_argument("--w-bar", type=float, default=0.01, help="w_bar (default 0.01)")
    parser.add_argument("--Q", type=float, default=1.0, help="stage weight Q = q I_2n (default 1)")
    parser.add_argument("--N", type=int, default=5, help="prediction horizon (default 5)")
    parser.add_argument(
        "--y-min",
        type=float,
        default=None,
        help=(
            "normalized output lower bound (default: the paper's "
            f"{PAPER_Y_PHI_BOUNDS[0]} pH through the model's normalization, else -1)"
        ),
    )
    parser.add_argument(
        "--y-max",
        type=float,
        default=None,
        help=(
            "normalized output upper bound (default: the paper's "
            f"{PAPER_Y_PHI_BOUNDS[1]} pH through the model's normalization, else 1)"
        ),
    )
    parser.add_argument("--e-y-bar", type=float, default=0.03, help="e_y_bar of Lemma 5 (0.03)")
    parser.set_defaults(func=_run_certify)


def _format_table(certification: Certification) -> str:
    data = certification.to_dict()
    lines = ["Certificates (normalized units unless marked _phi)", ""]
    groups = [
        (
            "delta-ISS (Assumption 2, Theorem 1, Remark 1)",
            ["rho_A_delta", "A_delta", "B_delta", "r1", "r2", "alpha", "beta"],
        ),
        ("Incremental Lyapunov (Lemma 2)", ["P_s", "rho_s", "c_s_l", "c_s_u", "c_s"]),
        (
            "Observer (Assumption 3, Theorem 2)",
            ["A_d", "rho_A_d", "P_o", "rho_o", "c_o", "L_max", "w_max", "w_bar", "e_inf"],
        ),
        ("Tightening and terminal set", ["a", "b", "P_f", "rho_f", "kappa"]),
        (
            "Set-points (Assumption 5, Lemma 5, Theorem 3)",
            ["y0_interval", "y0_interval_phi", "K_bar", "delta_y0_max", "rate_bound_holds"],
        ),
    ]

    def fmt(value: Any) -> str:
        if isinstance(value, float):
            return f"{value:.6g}"
        if isinstance(value, list):
            return "[" + ", ".join(fmt(v) for v in value) + "]"
        return str(value)

    for title, keys in groups:
        lines.append(title)
        for key in keys:
            lines.append(f"  {key:<18} {fmt(data[key])}")
        lines.append("")
    lines.append("Inputs: " + ", ".join(f"{k}={fmt(v)}" for k, v in data["inputs"].items()))
    return "\n".join(lines)


def _run_certify(args: argparse.Namespace) -> int:
    path = _resolve_model_path(args.model)
    model = LSTMModel.load(path)
    settings = CertificationSettings(
        u_max=args.u_max,
        Q_s=args.Q_s,
        Q_o=args.Q_o,
        l_d=args.L_d,
        L_f=args.L_f,
        L_i=args.L_i,
        L_o=args.L_o,
        design_gains=args.design_gains,
        d_max=args.d_max,
        w_bar=args.w_bar,
        Q=args.Q,
        N=args.N,
        y_min=args.y_min,
        y_max=args.y_max,
        e_y_bar=args.e_y_bar,
    )
    certification = certify(model, settings, model_info={"path": str(path)})
    if args.json:
        print(json.dumps(certification.to_dict(), indent=2))
    else:
        print(_format_table(certification))
    return 0


def build_parser() -> argparse.ArgumentParser:
    """The ``ltv-lstm-mpc`` argument parser with every subcommand."""
    parser = argparse.ArgumentParser(
        prog="ltv-lstm-mpc",
        description=(
            "Robust offset-free constrained MPC with LSTM models (Schimperna & Magni), "
            "solved by RTI-style convex subproblems."
        ),
    )
    parser.add_argument("--version", action="version", version=f"%(prog)s {__version__}")
    subparsers = parser.add_subparsers(dest="command", metavar="COMMAND")
    _add_certify(subparsers)
    _register_optional_commands(subparsers)
    return parser


def _register_optional_commands(subparsers: Any) -> None:
    """Subcommands that live in their own modules (training, experiments)."""
    import importlib
    import importlib.util

    for name in ("training_cli",):
        if importlib.util.find_spec(f"{__package__}.{name}") is not None:
            importlib.import_module(f"{__package__}.{name}").register(subparsers)


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of ``ltv-lstm-mpc``; returns the exit status."""
    parser = build_parser()
    args = parser.parse_args(argv)
    if not getattr(args, "func", None):
        parser.print_help()
        return 2
    try:
        return int(args.func(args))
    except (LtvMpcError, FileNotFoundError) as error:
        print(f"ltv-lstm-mpc {args.command}: error: {error}", file=sys.stderr)
        return 1


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
