"""Command-line interface ``ltv-lstm-mpc``.

Subcommands
-----------
certify
    Print every certificate number of the paper for a model (``--json`` for one JSON object).
reproduce
    The paper's five closed-loop simulations (``--benchmark quadtank``: the quadruple-tank
    benchmark, :mod:`ltv_lstm_mpc.benchmarks.quadtank`).
simulate
    One configurable closed loop (``--plant ph``, ``lstm`` or ``quadtank``).
generate-data, train
    Identification data and delta-ISS LSTM training (see ``ltv_lstm_mpc.training.cli``).
campaign
    Many closed loops over a product of factors, on Dask (see ``ltv_lstm_mpc.campaign.cli``).
convert
    An ONNX model into the library's ``.npz`` with its metadata
    (``ltv_lstm_mpc.cli.convert``).
warmup
    Compile the controller kernels into numba's cache ahead of time
    (``ltv_lstm_mpc.cli.warmup``).
"""

from __future__ import annotations

import argparse
import json
import re
import sys
import warnings
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from ltv_lstm_mpc import __version__
from ltv_lstm_mpc.benchmarks.quadtank import QUADTANK_MODEL
from ltv_lstm_mpc.certificates.certify import (
    Certification,
    CertificationSettings,
    certify,
    u_max_extrapolation,
)
from ltv_lstm_mpc.command_arguments import (
    OrderedPair,
    Parser,
    UsageError,
    add_check_sampling_time_option,
    add_d_max_option,
    add_l_d_option,
    add_n_option,
    add_policy_option,
    add_rate_limit_option,
    add_solver_option,
    check_order,
    nonnegative_float,
    output_folder,
    plant_help,
    plant_name,
    positive_float,
    positive_int,
    real,
    solver_name,
)
from ltv_lstm_mpc.exceptions import LtvMpcError
from ltv_lstm_mpc.loop.schedules import segments as schedule_segments
from ltv_lstm_mpc.loop.statuses import SETPOINT_STATUSES
from ltv_lstm_mpc.lstm.model import LSTMModel
from ltv_lstm_mpc.lstm.shipped import load_model, model_path

__all__ = ["build_parser", "main"]

EXAMPLE_MODEL = "example_delta_iss_n3.npz"
PH_MODEL = "ph_lstm_n5.npz"


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
        default=PH_MODEL,
        help=(
            f"model .npz file or the name of a shipped model (also shipped: {QUADTANK_MODEL}, "
            f"{EXAMPLE_MODEL})"
        ),
    )
    parser.add_argument("--json", action="store_true", help="print one JSON object")
    parser.add_argument("--u-max", type=positive_float, default=1.0, help="input bound u_max")
    parser.add_argument("--Q-s", type=positive_float, default=1000.0, help="Q_s = q I_2")
    parser.add_argument("--Q-o", type=positive_float, default=1000.0, help="Q_o = q I_3")
    add_l_d_option(parser)
    parser.add_argument("--L-f", type=real, default=0.0, help="fill value of L_f")
    parser.add_argument("--L-i", type=real, default=0.0, help="fill value of L_i")
    parser.add_argument("--L-o", type=real, default=0.0, help="fill value of L_o")
    parser.add_argument(
        "--design-gains",
        action="store_true",
        help=(
            "choose L_f, L_i, L_o minimizing rho(A_d) (paper notes 2.11) instead of the fill values"
        ),
    )
    add_d_max_option(parser)
    parser.add_argument(
        "--d-max-from",
        type=Path,
        default=None,
        metavar="DATA.npz",
        help=(
            "estimate d_max from identification data (ltv-lstm-mpc generate-data): the largest "
            "open-loop output mismatch of the model plus 10 %%; overrides --d-max"
        ),
    )
    parser.add_argument("--w-bar", type=nonnegative_float, default=0.01, help="w_bar")
    parser.add_argument("--Q", type=positive_float, default=1.0, help="stage weight Q = q I_2n")
    add_n_option(parser)
    parser.add_argument(
        "--y-min",
        type=real,
        default=None,
        help="normalized output lower bound (default: the model's stored output constraint)",
    )
    parser.add_argument(
        "--y-max",
        type=real,
        default=None,
        help="normalized output upper bound (default: the model's stored output constraint)",
    )
    parser.add_argument("--e-y-bar", type=positive_float, default=0.03, help="e_y_bar of Lemma 5")
    parser.add_argument(
        "--y0-range",
        action=OrderedPair,
        default=None,
        help=(
            "normalized set-point range for Theorem 3's rate bound (default: the middle half "
            "of the admissible interval)"
        ),
    )
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
    check_order("--y-min/--y-max", args.y_min, args.y_max)
    if (args.y_min is None) != (args.y_max is None):
        raise UsageError("give both --y-min and --y-max, or neither (the model's constraint)")
    path = model_path(args.model)
    model = load_model(path)  # .npz or .onnx
    extrapolation = u_max_extrapolation(model, args.u_max)
    if extrapolation is not None:
        print(f"ltv-lstm-mpc certify: warning: {extrapolation}", file=sys.stderr)
    if args.d_max_from is not None:
        from ltv_lstm_mpc.training.mismatch import estimate_d_max

        estimate = estimate_d_max(model, args.d_max_from)
        args.d_max = estimate.d_max
        split, sequence, sample = estimate.worst
        print(
            f"d_max = {estimate.d_max:.6g} estimated from {args.d_max_from}: largest open-loop "
            f"mismatch {estimate.mismatch:.6g} (normalized; {estimate.mismatch_phi:.4g} in "
            f"physical units, {split} sequence {sequence} sample {sample}) + "
            f"{100 * estimate.margin:.0f} %; a larger d_max shrinks the admissible set-point "
            "interval by 2 d_max",
            file=sys.stderr,
        )
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
        y0_operating_range=None if args.y0_range is None else tuple(args.y0_range),
    )
    certification = certify(model, settings, model_info={"path": str(path)})
    if args.json:
        print(json.dumps(certification.to_dict(), indent=2))
    else:
        print(_format_table(certification))
    return 0


def _add_reproduce(subparsers: Any) -> None:
    parser = subparsers.add_parser(
        "reproduce",
        help="run the paper's five closed-loop simulations (or --benchmark quadtank)",
        description=(
            "Reproduce the five simulations of the paper's Section V on the shipped pH model: "
            "(1) LSTM plant under Theorem 3's conditions, (2) larger changes, (3) set-point "
            "steps with infeasible instants, (4) pH plant with L_d = 0.01, (5) pH plant with "
            "L_d = 0.1. Prints steady-state offsets, constraint violations, infeasible steps, "
            "step times and the certificate numbers next to the paper's. With --out DIR, writes "
            "a PNG, CSV and JSON per scenario and DIR/summary.json. --benchmark quadtank: the "
            "quadruple-tank process with the shipped (2, 2) model, set-point changes on both "
            "levels and a leak, on the daqp and clarabel paths (offsets per output in cm)."
        ),
    )
    parser.add_argument(
        "--benchmark",
        choices=["paper", "quadtank"],
        default="paper",
        help="paper: the pH scenarios of Section V; quadtank: the quadruple tank",
    )
    parser.add_argument(
        "--out", type=output_folder, default=None, help="output folder (PNG/CSV/JSON)"
    )
    parser.add_argument(
        "--model",
        default=None,
        help=f"model file or shipped name (default: {PH_MODEL}; --benchmark quadtank: "
        f"{QUADTANK_MODEL})",
    )
    parser.add_argument(
        "--only", nargs="*", default=None, help="run only scenarios whose name contains these"
    )
    parser.add_argument(
        "--solver",
        type=solver_name(nonlinear=True),
        default=None,
        metavar="NAME",
        help=(
            "solver backend (default: the library's, the fastest installed one with exact "
            "terminal cones, for the paper's scenarios; --benchmark quadtank: daqp and clarabel)"
        ),
    )
    parser.add_argument(
        "--engine",
        choices=["auto", "reference", "one-call", "c", "c-single"],
        default="auto",
        help=(
            "the controllers' step engine: auto (the fastest that runs the configuration), "
            "reference, one-call, or c: the exported C99 step built with the host's C "
            "compiler (software in the loop; its solver: daqp, the default with --engine c), "
            "c-single: the same in single precision (float)"
        ),
    )
    parser.add_argument("--short", action="store_true", help="quarter-length schedules (smoke)")
    parser.add_argument("--no-plots", action="store_true", help="skip the PNG files")
    parser.add_argument("--no-progress", action="store_true", help="no progress bars")
    _add_max_offset(parser)
    parser.set_defaults(func=_run_reproduce)


def _benchmarks() -> dict[str, Any]:
    """The benchmarks of ``reproduce --benchmark``, by name."""
    from ltv_lstm_mpc.benchmarks.quadtank import QUADTANK_BENCHMARK
    from ltv_lstm_mpc.paper.reproduce import PAPER_BENCHMARK

    return {"paper": PAPER_BENCHMARK, "quadtank": QUADTANK_BENCHMARK}


def _run_reproduce(args: argparse.Namespace) -> int:
    benchmark = _benchmarks()[args.benchmark]
    path = model_path(args.model or benchmark.model)
    model = load_model(path)  # .npz or .onnx
    solver = args.solver
    if args.engine in ("c", "c-single") and solver is None:  # the C export's one solver
        solver = "daqp"
    report = benchmark.reproduce(
        model,
        args.out,
        only=args.only,
        engine=args.engine,
        solvers=None if solver is None else (solver,),
        short=args.short,
        progress=not args.no_progress,
        plot=not args.no_plots,
        model_info={"path": str(path)},
    )
    print(benchmark.format_report(report))
    print(
        f"\nwall time {report['wall_time_s']:.1f} s"
        + (f"; results in {args.out}" if args.out else "")
    )
    return _offset_status([s["final_offset"] for s in report["scenarios"]], args.max_offset)


def _add_max_offset(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--max-offset",
        type=positive_float,
        default=None,
        help="exit with status 3 when a final offset exceeds this (physical output units)",
    )


def _offset_status(offsets: Sequence[float | None], max_offset: float | None) -> int:
    """0, or 3 (with a message) when a final offset exceeds ``--max-offset``."""
    worst = max((o for o in offsets if o is not None), default=0.0)
    if max_offset is not None and worst > max_offset:
        print(
            f"final offset {worst:.3g} exceeds --max-offset {max_offset:g}: exit status 3",
            file=sys.stderr,
        )
        return 3
    return 0


def _add_simulate(subparsers: Any) -> None:
    parser = subparsers.add_parser(
        "simulate",
        help="run one configurable closed-loop scenario",
        description=(
            "Closed loop of the offset-free LSTM MPC on the pH plant, the LSTM plant or the "
            "quadruple-tank process: a piecewise-constant set-point and disturbance schedule, "
            "any solver, horizon and observer gain. Writes PNG/CSV/JSON with --out."
        ),
    )
    parser.add_argument(
        "--model",
        default=None,
        help=f"model (default: the plant's: {PH_MODEL} for ph, {QUADTANK_MODEL} for quadtank)",
    )
    parser.add_argument(
        "--plant",
        type=plant_name,
        default="ph",
        help=(
            f"plant: {plant_help()}; quadtank: the quadruple-tank process (pump "
            "voltages in V, levels in cm, disturbances = leak areas of tanks 1 and 2 in cm^2)"
        ),
    )
    parser.add_argument(
        "--setpoints",
        nargs="+",
        default=None,
        help=(
            "set-point per segment, physical units (default: the plant's own, where it states "
            "them; otherwise 1/4, 3/4 and 1/2 of the model's admissible set-point interval, "
            "printed); for a model with p > 1 outputs one comma-separated value per output, "
            "e.g. 0.2,0.1 0.3,0.0"
        ),
    )
    parser.add_argument(
        "--disturbances",
        nargs="+",
        default=None,
        help=(
            "disturbance per segment (q2 in mL/s for ph, output offset for lstm, leak areas "
            "of tanks 1 and 2 in cm^2 for quadtank; default: the plant's nominal one; "
            "comma-separated per output for p > 1)"
        ),
    )
    parser.add_argument("--segment", type=positive_int, default=400, help="samples per segment")
    add_solver_option(parser, nonlinear=True)
    parser.add_argument(
        "--transcription",
        choices=["auto", "condensed", "sparse", "nonlinear"],
        default="auto",
        help=(
            "FHOCP transcription (auto: sparse for cvxpy's solvers, nonlinear for ipopt, "
            "condensed for every other solver, the native clarabel with exact cones included)"
        ),
    )
    add_n_option(parser)
    parser.add_argument(
        "--y0-initial",
        type=real,
        default=None,
        help=(
            "initial output of the LSTM plant, physical units (default: the middle of the "
            "model's admissible set-point interval); other plants start from their own reset"
        ),
    )
    add_l_d_option(parser)
    add_d_max_option(parser)
    add_rate_limit_option(parser)
    add_policy_option(parser)
    parser.add_argument(
        "--sqp-iterations", type=positive_int, default=1, help="SQP iterations (1 = RTI)"
    )
    parser.add_argument(
        "--out", type=output_folder, default=None, help="output folder (PNG/CSV/JSON)"
    )
    parser.add_argument("--no-progress", action="store_true", help="no progress bar")
    add_check_sampling_time_option(parser)
    _add_max_offset(parser)
    parser.set_defaults(func=_run_simulate)


def _run_simulate(args: argparse.Namespace) -> int:
    import numpy as np

    from ltv_lstm_mpc.cli.simulate_mimo import parse_vectors
    from ltv_lstm_mpc.mpc.config import MPCConfig
    from ltv_lstm_mpc.paper.reproduce import format_table, write_scenario_outputs
    from ltv_lstm_mpc.paper.scenarios import Scenario, run_scenario
    from ltv_lstm_mpc.plants.registry import resolve_plant
    from ltv_lstm_mpc.plotting import name_of, signal_labels

    entry = resolve_plant(args.plant)
    model_name = args.model or entry.model
    if model_name is None:
        raise UsageError(f"the plant {entry.name} names no default model: give --model")
    model = load_model(model_path(model_name))  # .npz or .onnx
    _check_plant_size(entry, model)
    config = MPCConfig(
        N=args.N,
        L_d=args.L_d,
        d_max=args.d_max,
        solver=args.solver,
        transcription=args.transcription,
        infeasibility_policy=args.policy,
        sqp_iterations=args.sqp_iterations,
    )
    rate_limit = args.rate_limit if args.rate_limit > 0 else None
    y0_initial = getattr(args, "y0_initial", None)
    if y0_initial is not None and ("y0_phi" not in entry.options or model.p != 1):
        raise UsageError(
            f"--y0-initial {y0_initial:g}: the {entry.name} plant starts from its own reset "
            "state; --y0-initial sets the initial output of the single-output LSTM plant "
            "(--plant lstm) only"
        )
    default_setpoints = list(entry.setpoints_for(model))
    if not args.setpoints and not default_setpoints:
        from ltv_lstm_mpc.certificates.certify import certify
        from ltv_lstm_mpc.paper.scenarios import (
            ADMISSIBLE_SETPOINT_FRACTIONS,
            admissible_setpoints,
        )

        certification = certify(model, config.certification_settings(model))
        default_setpoints = admissible_setpoints(model, certification)
        low, high = (np.ravel(v) for v in certification.y0_interval_phi or ((), ()))
        interval = ", ".join(f"[{a:.4g}, {b:.4g}]" for a, b in zip(low, high, strict=True))
        print(
            f"set-points {' '.join(default_setpoints)} "
            f"{signal_labels(entry.name, model).output_unit}: {entry.name} names none for this "
            f"model, so they lie at {', '.join(f'{f:g}' for f in ADMISSIBLE_SETPOINT_FRACTIONS)} "
            f"of its admissible set-point interval {interval} (within the equilibrium outputs "
            "of its input range; give --setpoints to choose)"
        )
    if model.p > 1:
        from ltv_lstm_mpc.cli.simulate_mimo import run_mimo

        setpoint_tokens = args.setpoints or default_setpoints or None
        if setpoint_tokens is None:
            raise UsageError(
                f"give --setpoints, one comma-separated value per output (p = {model.p})"
            )
        plant = entry.build(model)
        mimo, sim = run_mimo(
            model,
            config,
            setpoint_tokens,
            args.disturbances,
            args.segment,
            rate_limit,
            args.out,
            not args.no_progress,
            plant=plant,
            labels=_plot_labels(entry, model),
            title=_plot_title(entry, model, setpoint_tokens, args),
            check_sampling_time=args.check_sampling_time,
        )
        offsets = mimo["segment_offsets"]
        outputs = _plot_labels(entry, model)[1]
        print(
            f"{'segment':>7}  "
            + "  ".join(f"{'offset ' + name_of(label):<14}" for label in outputs)
            + f"  ({signal_labels(entry.name, model).output_unit})"
        )
        for number, row in enumerate(offsets):
            print(f"{number:>7}  " + "  ".join(f"{v:<14.3e}" for v in row))
        counts = sim.summary_counts()
        largest = mimo.get("max_constraint_violation")
        print(
            f"constraint violations {mimo.get('constraint_violation_steps', '-')} steps"
            + ("" if largest is None else f" (largest {largest:.3g})")
            + "; "
            f"set-points ok {counts['setpoint_ok_steps']} / {mimo['steps']}; d_hat saturated "
            f"{counts['d_hat_saturated_steps']}; infeasible {counts['infeasible_steps']}; median "
            f"step {1e6 * mimo['median_step_time_s']:.0f} us ({sim.transcription})"
        )
        print(_guarantee_line(counts, mimo["steps"]))
        return _offset_status([mimo["final_offset"]], args.max_offset)
    tokens = args.setpoints or default_setpoints
    if not tokens:
        raise UsageError(f"the plant {entry.name} names no default set-points: give --setpoints")
    setpoints = [float(v) for v in parse_vectors("--setpoints", tokens, 1)[:, 0]]
    given = None
    if args.disturbances is not None:
        given = [float(v) for v in parse_vectors("--disturbances", args.disturbances, 1)[:, 0]]
    segments = len(setpoints)
    nominal = entry.nominal_disturbance[0] if entry.nominal_disturbance else float("nan")
    disturbances = given or [nominal] * segments
    if len(disturbances) != segments:
        raise UsageError(
            f"give one disturbance per set-point: {segments} set-points, {len(disturbances)} "
            "disturbances"
        )
    lengths = [args.segment] * segments
    scenario = Scenario(
        name="simulate",
        title=_plot_title(entry, model, tokens, args),
        plant=entry.name,
        setpoints=np.repeat(np.asarray(setpoints, dtype=float), args.segment),
        disturbances=np.repeat(np.asarray(disturbances, dtype=float), args.segment),
        config=config,
        setpoint_rate_limit=rate_limit,
        segments=schedule_segments(lengths),
        y0_phi_initial=y0_initial,
    )
    result = run_scenario(
        scenario, model, progress=not args.no_progress, check_sampling_time=args.check_sampling_time
    )
    if "y0_phi" in entry.options:
        print(
            f"initial output {result.simulation.y_phi[0, 0]:.4g} "
            f"{signal_labels(entry.name, model).output_unit}"
            + (
                " (--y0-initial)"
                if y0_initial is not None
                else " (the middle of the model's admissible set-point interval; --y0-initial "
                "to choose)"
            )
        )
    summary = write_scenario_outputs(result, args.out) if args.out is not None else result.summary()
    print(format_table([summary]))
    sim = result.simulation
    print(
        f"transcription {sim.transcription}; median step "
        f"{1e6 * float(np.median(sim.time_total)):.0f} us (prepare "
        f"{1e6 * float(np.median(sim.time_prepare)):.0f} us, feedback "
        f"{1e6 * float(np.median(sim.time_feedback)):.0f} us)"
    )
    counts = sim.summary_counts()
    print(
        "set-points: "
        + ", ".join(f"{name} {counts[f'setpoint_{name}_steps']}" for name in SETPOINT_STATUSES)
        + f" steps; d_hat saturated {counts['d_hat_saturated_steps']} steps; infeasible "
        f"{counts['infeasible_steps']} steps; plant outside the output constraint "
        f"{counts.get('plant_violation_steps', '-')} steps; input clipped into U "
        f"{counts['input_clipped_steps']} steps; implausible measurements "
        f"{counts['measurement_implausible_steps']} steps"
    )
    print(_guarantee_line(counts, len(sim.feasible)))
    return _offset_status([summary["final_offset"]], args.max_offset)


def _guarantee_line(counts: dict[str, int], steps: int) -> str:
    """The run-time monitor's counts in one line (:mod:`ltv_lstm_mpc.loop.monitor`)."""
    if "guarantee_held_steps" not in counts:
        return "Theorem 3's guarantee: not monitored"
    failed = ", ".join(
        f"{name.removesuffix('_failed_steps')} {value}"
        for name, value in counts.items()
        if name.endswith("_failed_steps") and value
    )
    return (
        f"Theorem 3's guarantee held on {counts['guarantee_held_steps']} of {steps} steps "
        f"(hypotheses failed: {failed or 'none'}); where it held: plant outside the output "
        f"constraint {counts.get('plant_violation_steps_guarantee_held', '-')} steps, "
        f"infeasible {counts['infeasible_steps_guarantee_held']} steps"
    )


def _plot_labels(entry: Any, model: LSTMModel) -> tuple[tuple[str, ...], tuple[str, ...]]:
    """(input labels, output labels) with units for the ``simulate`` plot: the plant's, or
    those of the plant whose shipped model this is (the LSTM plant)."""
    from ltv_lstm_mpc.plotting import signal_labels

    labels = signal_labels(entry.name, model)
    return labels.inputs, labels.outputs


def _plot_title(
    entry: Any, model: LSTMModel, setpoints: Sequence[str], args: argparse.Namespace
) -> str:
    """Title of the ``simulate`` plot: the plant, the set-point schedule with its unit and
    the controller settings ("pH plant: set-points 7.5 -> 8 pH; daqp, N = 5, L_d = 0.1")."""
    from ltv_lstm_mpc.plotting import signal_labels

    unit = f" {signal_labels(entry.name, model).output_unit}"
    shown = [f"({', '.join(t.split(','))})" if "," in str(t) else str(t) for t in setpoints]
    return (
        f"{entry.title}: set-points {' -> '.join(shown)}{unit}; {args.solver}, N = {args.N}, "
        f"L_d = {args.L_d}"
    )


def _check_plant_size(entry: Any, model: LSTMModel) -> None:
    """The plant's inputs and outputs (where its entry names them) against the model's."""
    if not entry.output_labels:  # the LSTM plant (the model itself) or a class without labels
        return
    inputs, outputs = len(entry.input_labels), len(entry.output_labels)
    if (inputs, outputs) == (model.m, model.p):
        return
    hint = "use --plant lstm"
    if entry.model is not None:
        hint += f", or --model {entry.model} (or a model from `ltv-lstm-mpc train --plant "
        hint += f"{entry.name}`)"
    raise UsageError(
        f"the {entry.name} plant has {inputs} input(s) and {outputs} output(s) "
        f"({', '.join(entry.input_labels)} -> {', '.join(entry.output_labels)}); this model "
        f"has m = {model.m}, p = {model.p}: {hint}"
    )


def build_parser() -> argparse.ArgumentParser:
    """The ``ltv-lstm-mpc`` argument parser with every subcommand."""
    parser = Parser(
        prog="ltv-lstm-mpc",
        description=(
            "Robust offset-free constrained MPC with LSTM models (Schimperna & Magni), "
            "solved by RTI-style convex subproblems."
        ),
    )
    parser.add_argument("--version", action="version", version=f"%(prog)s {__version__}")
    subparsers = parser.add_subparsers(dest="command", metavar="COMMAND")
    _add_certify(subparsers)
    _add_reproduce(subparsers)
    _add_simulate(subparsers)
    _register_optional_commands(subparsers)
    return parser


#: Modules whose ``register(subparsers)`` adds subcommands (train, bench, replay, campaign,
#: warmup).
OPTIONAL_COMMAND_MODULES = (
    "ltv_lstm_mpc.training.cli",
    "ltv_lstm_mpc.solver_comparison.harness",
    "ltv_lstm_mpc.campaign.cli",
    "ltv_lstm_mpc.cli.warmup",
    "ltv_lstm_mpc.cli.convert",
    "ltv_lstm_mpc.cli.export_c",
)


def _register_optional_commands(subparsers: Any) -> None:
    """Subcommands that live in their own modules (training, experiments)."""
    import importlib
    import importlib.util

    for name in OPTIONAL_COMMAND_MODULES:
        if importlib.util.find_spec(name) is not None:
            importlib.import_module(name).register(subparsers)


#: Library advice rewritten for the command line: (phrase, the option that replaces it, the
#: text where the command has no such option).
_CLI_ADVICE = (
    (
        "; if the model's Ts is unknown and you accept the risk, pass check_sampling_time=False",
        "--no-check-sampling-time",
        "; if the model's Ts is unknown and you accept the risk, pass --no-check-sampling-time",
    ),
    (
        " (MPCConfig d_max; estimate_d_max(model, data) measures the mismatch)",
        "--d-max",
        " with --d-max (`ltv-lstm-mpc certify MODEL --d-max-from DATA.npz` estimates it)",
    ),
)
_LONG_FLOAT = re.compile(r"(?<![\w.])-?\d+\.\d{5,}(?:e[-+]?\d+)?(?![\w.])")
_SINGLETON = re.compile(r"\[(-?[\d.]+(?:e[-+]?\d+)?)\]")


def _for_command(message: str, parser: argparse.ArgumentParser | None) -> str:
    """``message`` as the command line says it: library advice (``pass
    check_sampling_time=False``, ``MPCConfig d_max``) replaced by the command's option where
    it has one, left out where it has none; floats rounded to 4 significant digits and
    one-element lists unwrapped (``[[6.321881455615142], [8.67811...]]`` -> ``[6.322,
    8.678]``); one line."""
    options = set() if parser is None else set(parser._option_string_actions)
    for phrase, option, replacement in _CLI_ADVICE:
        if phrase in message:
            message = message.replace(phrase, replacement if option in options else "")
    message = _LONG_FLOAT.sub(lambda m: f"{float(m.group()):.4g}", message)
    message = _SINGLETON.sub(r"\1", message)
    return " ".join(message.split())


def _command_parser(parser: argparse.ArgumentParser, command: str) -> Any:
    """The sub-parser of ``command`` (None if there is none)."""
    for action in parser._subparsers._group_actions if parser._subparsers else ():
        choices = getattr(action, "choices", None) or {}
        if command in choices:
            return choices[command]
    return None


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of ``ltv-lstm-mpc``; returns the exit status.

    Exit codes: 0 success; 1 a library or file error (a model file that does not exist
    or cannot be read, ...); 2 a bad option or input found before the work starts (an
    unknown solver, a set-point that is not a finite number, a plant without an input
    range, ...: one line on stderr, ``ltv-lstm-mpc COMMAND: error: ...``); 3 a final
    offset above ``--max-offset``; 130 interrupted. Warnings print as one line each,
    ``ltv-lstm-mpc COMMAND: warning: ...``.
    """
    parser = build_parser()
    args = parser.parse_args(argv)
    if not getattr(args, "func", None):
        parser.print_help()
        return 2
    prog = f"ltv-lstm-mpc {args.command}"
    command = _command_parser(parser, args.command)

    def show(message: Any, category: Any, *_: Any, **__: Any) -> None:
        print(f"{prog}: warning: {_for_command(str(message), command)}", file=sys.stderr)

    try:
        with warnings.catch_warnings():
            warnings.showwarning = show
            return int(args.func(args))
    except UsageError as error:
        print(f"{prog}: error: {_for_command(str(error), command)}", file=sys.stderr)
        return 2
    except (LtvMpcError, OSError, ValueError) as error:
        print(f"{prog}: error: {_for_command(str(error), command)}", file=sys.stderr)
        return 1
    except KeyboardInterrupt as interrupt:
        # one line; a command may say what was kept and how to resume (campaign)
        print(f"{prog}: {interrupt or 'interrupted'}", file=sys.stderr)
        return 130


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
