"""``ltv-lstm-mpc export-c``: the controller as a C99 project (:mod:`ltv_lstm_mpc.export`).

Builds the controller the options describe (the options of ``simulate`` that the C export
covers), writes its C project (:func:`~ltv_lstm_mpc.export.package.export_controller_c`)
and, with ``--build``, compiles it with the host's ``make`` and runs the example.
"""

from __future__ import annotations

import argparse
import shutil
import subprocess
from typing import Any

__all__ = ["register"]


def register(subparsers: Any) -> None:
    """Add the ``export-c`` subcommand to the ``ltv-lstm-mpc`` parser."""
    from ltv_lstm_mpc.command_arguments import (
        add_d_max_option,
        add_l_d_option,
        add_n_option,
        add_policy_option,
        add_rate_limit_option,
        output_folder,
    )

    parser = subparsers.add_parser(
        "export-c",
        help="write the controller as a dependency-free C99 project (DAQP included)",
        description=(
            "Write the offset-free LSTM MPC for MODEL as C99: the header and source of the "
            "whole controller step (normalization, rate limiter, reference calculator, "
            "tightening, the condensed QP solved by DAQP with the infeasibility policy, exit "
            "gate, observer), DAQP's sources with its license, a Makefile, a CMakeLists.txt, "
            "an example and a README for integrators. The solver is daqp (the terminal box) "
            "or daqp:socp (the exact terminal cones by SQP on DAQP) on the condensed "
            "transcription, one SQP iteration per step (RTI)."
        ),
    )
    parser.add_argument(
        "model", nargs="?", default="ph_lstm_n5.npz", help="model .npz or shipped name"
    )
    parser.add_argument(
        "--out", type=output_folder, required=True, help="folder to write the project into"
    )
    parser.add_argument(
        "--prefix", default="controller", help="prefix of the files and C identifiers"
    )
    add_n_option(parser)
    add_l_d_option(parser)
    add_d_max_option(parser)
    add_rate_limit_option(parser)
    add_policy_option(parser)
    parser.add_argument(
        "--solver",
        choices=["daqp", "daqp:socp"],
        default="daqp",
        help="daqp: the terminal set as the conservative box (QP); daqp:socp: as the exact "
        "cones, by SQP on DAQP (double precision only)",
    )
    parser.add_argument(
        "--implausible-measurements",
        choices=["flag", "raise"],
        default="flag",
        help="flag: use and flag a measurement beyond one range width (the library's default); "
        "raise: refuse it (the C step holds the last input)",
    )
    parser.add_argument(
        "--float",
        action="store_true",
        help="single precision (float, for FPUs without double, e.g. a Cortex-M4F): refused "
        "where float's rounding takes more than half a margin of the certificates",
    )
    parser.add_argument(
        "--build",
        action="store_true",
        help="then build it with make (the host's C compiler) and run the example",
    )
    parser.set_defaults(func=_run_export)


def _run_export(args: argparse.Namespace) -> int:
    from ltv_lstm_mpc.exceptions import InvalidValueError
    from ltv_lstm_mpc.export.package import export_controller_c
    from ltv_lstm_mpc.loop.controller import OffsetFreeController
    from ltv_lstm_mpc.lstm.shipped import load_model
    from ltv_lstm_mpc.mpc.config import MPCConfig

    model = load_model(args.model)
    config = MPCConfig(
        N=args.N, L_d=args.L_d, d_max=args.d_max, solver=args.solver, transcription="condensed",
        infeasibility_policy=args.policy,
    )  # fmt: skip
    controller = OffsetFreeController(
        model, config, setpoint_rate_limit=args.rate_limit if args.rate_limit > 0 else None,
        implausible_measurements=args.implausible_measurements, one_call_step=False,
        kernels="numpy",  # (the export needs none compiled)
    )  # fmt: skip
    exported = export_controller_c(
        controller, args.out, prefix=args.prefix, precision="single" if args.float else "double"
    )
    files = sorted(p.name for p in args.out.iterdir() if p.is_file())
    print(f"wrote {args.out}: {', '.join(files)}, daqp/ (DAQP's sources and license)")
    print(
        f"{args.prefix}_controller: at most {exported.mpc_workspace_bytes} bytes; N = {config.N}, "
        f"solver {config.solver}, policy {config.infeasibility_policy}; "
        f"{exported.precision} precision; build: "
        f"make -C {args.out} (or cmake)"
    )
    if exported.single_precision_margins is not None:
        print(exported.single_precision_margins.summary())
    if not args.build:
        return 0
    if shutil.which("make") is None:
        raise InvalidValueError("--build needs make on the PATH (e.g. apt-get install make)")
    for command in (["make", "-C", str(args.out), "example"], ["./example"]):
        done = subprocess.run(command, cwd=args.out if command[0] != "make" else None,
                              capture_output=True, text=True)  # fmt: skip
        if done.returncode:
            print(done.stdout[-3000:] + done.stderr[-3000:])
            return 1
    print(done.stdout.rstrip())
    return 0
