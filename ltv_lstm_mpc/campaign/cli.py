"""Sub-command ``campaign`` of the ``ltv-lstm-mpc`` command line.

``ltv-lstm-mpc campaign SPEC.toml --out DIR [--scheduler ADDRESS] [--workers N] [--serial]
[--dry-run] [--retry-errors] [--beta BETA] [--offset-tolerance TOL]``, or
``ltv-lstm-mpc campaign [SPEC.toml] --plan-epsilon EPS [--beta BETA]`` to size a campaign
(:func:`~ltv_lstm_mpc.campaign.statements.loops_needed`) without running it. A bad spec
is a usage error (exit code 2, the message names the entry); a library error is exit
code 1; tasks that fail are recorded, not fatal (exit code 0, their count on stderr).
Dask is imported only when the tasks run on it. Ctrl-C, or SIGTERM (``kill PID``), prints
one line (``interrupted; N of M tasks stored in DIR; resume with: ...``, exit code 130)
and no worker traceback.
"""

from __future__ import annotations

import argparse
import contextlib
import os
import shlex
import signal
import sys
import threading
from collections.abc import Iterator
from pathlib import Path
from typing import Any

from ltv_lstm_mpc.command_arguments import (
    RawDescriptionHelpFormatter,
    UsageError,
    fraction_open,
    nonnegative_float,
    output_folder,
    positive_int,
)
from ltv_lstm_mpc.exceptions import CampaignSpecError

__all__ = ["campaign_command", "register"]


def register(subparsers: Any) -> None:
    """Add the ``campaign`` subcommand to the ``ltv-lstm-mpc`` parser."""
    from ltv_lstm_mpc.campaign.spec import describe_settings

    settings = "\n".join(f"  {name:<15} {doc}" for name, doc in describe_settings())
    parser = subparsers.add_parser(
        "campaign",
        formatter_class=RawDescriptionHelpFormatter,
        epilog=(
            "settings ([campaign] fixed values, [factors] lists, [[cases]] overrides):\n"
            f"{settings}\n"
            "  (also in [campaign]: name, trace = true | {setting = [values]})"
        ),
        help="run many closed loops (a product of factors) on Dask, resumable",
        description=(
            "Run every task of a campaign spec (TOML: [campaign] fixed settings, [factors] "
            "lists whose product is the task list, optional [[cases]]), one closed loop each, "
            "on a Dask LocalCluster (one worker process per core), an existing scheduler "
            "(--scheduler) or this process (--serial). Each finished task is stored at once "
            "under --out; rerunning skips finished tasks. Writes results.parquet/.csv, traces "
            "for the spec's trace subset, report.md and plots."
        ),
    )
    parser.add_argument(
        "spec", type=Path, nargs="?", help="campaign spec (.toml); optional with --plan-epsilon"
    )
    parser.add_argument("--out", type=output_folder, default=None, help="output folder")
    parser.add_argument(
        "--scheduler", default=None, metavar="ADDRESS", help="address of a running Dask scheduler"
    )
    parser.add_argument(
        "--workers",
        type=positive_int,
        default=None,
        help=f"worker processes of the LocalCluster (default: one per core, {os.cpu_count()})",
    )
    parser.add_argument("--serial", action="store_true", help="run in this process, no Dask")
    parser.add_argument(
        "--dry-run",
        action="store_true",
        help="print the task count and a time estimate from short calibration runs",
    )
    parser.add_argument(
        "--retry-errors", action="store_true", help="rerun the tasks stored with an error"
    )
    parser.add_argument(
        "--plan-epsilon",
        type=fraction_open(0.0, 1.0),
        default=None,
        metavar="EPS",
        help="print how many i.i.d. closed loops without a failure state P(failure) <= EPS "
        "at confidence 1 - BETA (and how many the spec draws per stratum), run nothing",
    )
    parser.add_argument(
        "--beta",
        type=fraction_open(0.0, 1.0),
        default=0.05,
        help="1 - confidence of the report's statistical statements",
    )
    parser.add_argument(
        "--offset-tolerance",
        type=nonnegative_float,
        default=None,
        metavar="TOL",
        help=(
            "offset (output units) above which a loop counts as failed (default: the spec's "
            "[campaign].offset_tolerance, else 1e-3)"
        ),
    )
    parser.add_argument("--no-report", action="store_true", help="skip report.md and the plots")
    parser.add_argument("--no-progress", action="store_true", help="no progress bar")
    parser.set_defaults(func=campaign_command)


def _plan(args: argparse.Namespace) -> int:
    """``--plan-epsilon``: the loops needed for the statement, and what the spec draws."""
    from ltv_lstm_mpc.campaign.statements import clopper_pearson_upper, loops_needed

    needed = loops_needed(args.plan_epsilon, args.beta)
    print(
        f"{needed} i.i.d. closed loops without a failure state P(failure) <= "
        f"{args.plan_epsilon:g} with confidence {1 - args.beta:.4g} (one-sided "
        f"Clopper-Pearson; one failure among them gives "
        f"{clopper_pearson_upper(1, needed, args.beta):.3g})"
    )
    if args.spec is None:
        return 0
    spec = _load(args.spec)
    strata = len({repr([t.settings.get(n) for n in spec.strata]) for t in spec.tasks})
    per_stratum = len(spec.tasks) // max(strata, 1)
    if not spec.random.active and not spec.replications:
        print(
            f"{args.spec}: no [random] table and no replications, so its {len(spec.tasks)} "
            f"tasks are not i.i.d. draws; add [random] with samples = {needed} (and the "
            "distributions of the settings to sample), or a seed factor with that many seeds"
        )
        return 0
    if spec.replications:
        enough = "enough" if per_stratum >= needed else f"{needed} needed"
        pooled = ", ".join(spec.replications)
        print(
            f"{args.spec}: {per_stratum} loops per stratum (replications {pooled} pooled), "
            f"{strata} strata, {len(spec.tasks)} tasks: {enough}"
        )
        return 0
    enough = "enough" if spec.random.samples >= needed else f"set samples = {needed}"
    print(
        f"{args.spec}: {spec.random.samples} draws per stratum, {strata} strata, "
        f"{len(spec.tasks)} tasks: {enough}"
    )
    return 0


def _load(path: Path) -> Any:
    from ltv_lstm_mpc.campaign.spec import load_spec

    if not path.is_file():
        raise UsageError(f"no campaign spec file {str(path)!r}")
    try:
        return load_spec(path)
    except CampaignSpecError as error:
        raise UsageError(f"{path}: {error}") from None


def _duration(seconds: float) -> str:
    if seconds < 120:
        return f"{seconds:.0f} s"
    if seconds < 7200:
        return f"{seconds / 60:.1f} min"
    return f"{seconds / 3600:.1f} h"


def _scheduler_workers(address: str) -> int:
    from ltv_lstm_mpc.campaign.runner import dask_client

    with dask_client(address) as client:
        workers = client.scheduler_info().get("workers", {})
        return max(sum(int(w.get("nthreads", 1)) for w in workers.values()), 1)


def _resume_command(args: argparse.Namespace) -> str:
    """The command line that resumes this run (the same spec, folder and cluster options)."""
    words = ["ltv-lstm-mpc", "campaign", str(args.spec), "--out", str(args.out)]
    if args.scheduler is not None:
        words += ["--scheduler", args.scheduler]
    if args.workers is not None:
        words += ["--workers", str(args.workers)]
    flags = ("serial", "retry_errors", "no_report", "no_progress")
    words += [f"--{flag.replace('_', '-')}" for flag in flags if getattr(args, flag)]
    return shlex.join(words)


@contextlib.contextmanager
def _terminate_as_interrupt() -> Iterator[None]:
    """SIGTERM (``kill PID``) stops the campaign as Ctrl-C does.

    The cluster is closed and the one line says what is stored and how to resume, instead
    of the process dying with its workers' semaphores leaked (a SIGTERM while the
    LocalCluster starts is deferred until it can be closed whole:
    :func:`~ltv_lstm_mpc.campaign.runner.dask_client`). A campaign started with ``&``
    from a script ignores SIGINT (the shell sets it so), and SIGTERM is how it is
    stopped. POSIX: on Windows the handler is set but ``kill`` ends a process without
    running it. No-op outside the main thread, where Python cannot set handlers.
    """
    if threading.current_thread() is not threading.main_thread():
        yield
        return

    def interrupt(signum: int, frame: Any) -> None:
        raise KeyboardInterrupt

    previous = signal.signal(signal.SIGTERM, interrupt)
    try:
        yield
    finally:
        if previous is not None:  # (None: a handler set outside Python, not restorable)
            signal.signal(signal.SIGTERM, previous)


def campaign_command(args: argparse.Namespace) -> int:
    """``ltv-lstm-mpc campaign``: run (or estimate) a campaign; returns the exit status."""
    from ltv_lstm_mpc.campaign.runner import CampaignInterrupted, estimate_campaign, run_campaign

    if args.plan_epsilon is not None:
        return _plan(args)
    if args.spec is None:
        raise UsageError("give a campaign spec (.toml), or --plan-epsilon EPS to size one")
    if args.out is None:
        raise UsageError("--out is required to run a campaign (or --dry-run estimate it)")
    if args.serial and (args.scheduler is not None or args.workers is not None):
        raise UsageError("--serial runs in this process: drop --scheduler / --workers")
    if args.scheduler is not None and args.workers is not None:
        raise UsageError("--workers sizes the LocalCluster; an existing --scheduler has its own")
    spec = _load(args.spec)
    if args.dry_run:
        if args.serial:
            workers = 1
        elif args.scheduler is not None:
            workers = _scheduler_workers(args.scheduler)
        else:
            workers = args.workers or os.cpu_count() or 1
        estimate = estimate_campaign(spec, args.out, workers=workers)
        print(
            f"campaign {spec.name}: {estimate.tasks} tasks ({estimate.finished} finished in "
            f"{args.out}, {estimate.pending} to run)"
        )
        for label, setup, step in estimate.calibration:
            print(f"  calibration {label}: setup {setup:.2f} s, {1e3 * step:.3g} ms per step")
        print(
            f"estimated time: {_duration(estimate.seconds)} on {workers} worker"
            f"{'s' if workers != 1 else ''} (plus starting the cluster)"
        )
        return 0
    try:
        with _terminate_as_interrupt():
            run = run_campaign(
                spec,
                args.out,
                scheduler=args.scheduler,
                workers=args.workers,
                serial=args.serial,
                retry_errors=args.retry_errors,
                progress=not args.no_progress,
                report=not args.no_report,
                log=lambda message: print(message, file=sys.stderr),
                beta=args.beta,
                offset_tolerance=args.offset_tolerance,
            )
    except CampaignInterrupted as interrupted:
        # one line, printed by the command line's KeyboardInterrupt handler
        raise KeyboardInterrupt(
            f"interrupted; {interrupted.stored} of {interrupted.total} tasks stored in "
            f"{args.out}; resume with: {_resume_command(args)}"
        ) from None
    print(
        f"campaign {spec.name}: {len(run.rows)} tasks ({run.executed} run now, {run.skipped} "
        f"already finished), {run.errors} errors; {run.wall_s:.1f} s"
    )
    for path in run.files:
        if path.name.startswith(("results", "report")):
            print(f"  {path}")
    if run.errors:
        print(
            f"{run.errors} tasks failed (recorded with their errors in the results and "
            "report.md; --retry-errors reruns them)",
            file=sys.stderr,
        )
    return 0
