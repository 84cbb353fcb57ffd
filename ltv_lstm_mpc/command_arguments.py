"""Argument types of the command line: every numeric option is checked before any work.

Each function is an ``argparse`` ``type=``: a bad value is a usage error (exit code 2, one
line naming the option's value and the allowed range), never a traceback and never a
silent fallback. :class:`UsageError` is raised by commands for usage errors found after
parsing (e.g. an unknown bench backend); ``main`` turns it into exit code 2.

A module of its own, below the ``cli`` package: the commands that live with their own
packages (``train``/``generate-data`` in ``training``, ``bench``/``replay`` in ``bench``,
``campaign``) use these types without importing the ``cli`` package that registers them.
"""

from __future__ import annotations

import argparse
import math
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

from ltv_lstm_mpc.exceptions import InvalidValueError, LtvMpcError

__all__ = [
    "HelpFormatter",
    "OrderedPair",
    "Parser",
    "RawDescriptionHelpFormatter",
    "UsageError",
    "add_check_sampling_time_option",
    "add_d_max_option",
    "add_l_d_option",
    "add_n_option",
    "add_solver_option",
    "check_order",
    "fraction_open",
    "nonnegative_float",
    "output_folder",
    "plant_name",
    "positive_float",
    "positive_int",
    "real",
    "solver_name",
]


class UsageError(LtvMpcError, ValueError):
    """A command-line usage error found after parsing (exit code 2)."""


class HelpFormatter(argparse.ArgumentDefaultsHelpFormatter):
    """The one way every command shows its defaults: argparse's ``(default: X)`` after
    each option's help, left out where there is nothing to show (a switch, a default of
    ``None`` whose help says in words what applies)."""

    def _get_help_string(self, action: argparse.Action) -> str:
        text = action.help or ""
        default = action.default
        hidden = default is None or default is argparse.SUPPRESS or action.nargs == 0  # a switch
        if "%(default)" in text or hidden or default == []:
            return text
        if not action.option_strings and action.nargs not in (argparse.OPTIONAL, "*"):
            return text
        return text + " (default: %(default)s)"


class RawDescriptionHelpFormatter(HelpFormatter, argparse.RawDescriptionHelpFormatter):
    """:class:`HelpFormatter` that keeps the description's and epilog's line breaks."""


class Parser(argparse.ArgumentParser):
    """The parser of ``ltv-lstm-mpc`` and of each command (``add_subparsers`` makes its
    sub-parsers of this class): :class:`HelpFormatter` by default, and a usage error is one
    line on stderr, ``PROG: error: MESSAGE (see PROG --help)``, with exit code 2."""

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        kwargs.setdefault("formatter_class", HelpFormatter)
        super().__init__(*args, **kwargs)

    def error(self, message: str) -> Any:
        """Print one line and exit with code 2 (argparse prints the usage block first)."""
        self.exit(2, f"{self.prog}: error: {message} (see {self.prog} --help)\n")


def real(text: str) -> float:
    """A finite real number."""
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a number") from None
    if not math.isfinite(value):
        raise argparse.ArgumentTypeError(f"{text!r} is not a finite number")
    return value


def plant_name(text: str) -> str:
    """A registered plant name or an importable ``package.module:Class`` (the plant
    registry, :func:`ltv_lstm_mpc.resolve_plant`)."""
    from ltv_lstm_mpc.plants.registry import resolve_plant

    try:
        return resolve_plant(text).name
    except LtvMpcError as error:
        raise argparse.ArgumentTypeError(str(error)) from None


def plant_help() -> str:
    """The ``--plant`` choices for help texts: the registered names and the user form."""
    from ltv_lstm_mpc.plants.registry import registered_plants

    return ", ".join(registered_plants()) + ", or package.module:Class (a plant class of yours)"


def positive_float(text: str) -> float:
    """A finite number > 0."""
    value = real(text)
    if not value > 0:
        raise argparse.ArgumentTypeError(f"{text!r} must be > 0")
    return value


def nonnegative_float(text: str) -> float:
    """A finite number >= 0."""
    value = real(text)
    if value < 0:
        raise argparse.ArgumentTypeError(f"{text!r} must be >= 0")
    return value


def positive_int(text: str) -> int:
    """An integer >= 1."""
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not an integer") from None
    if value < 1:
        raise argparse.ArgumentTypeError(f"{text!r} must be an integer >= 1")
    return value


def fraction_open(low: float, high: float) -> Callable[[str], float]:
    """A number in the open interval (low, high)."""

    def check(text: str) -> float:
        value = real(text)
        if not low < value < high:
            raise argparse.ArgumentTypeError(f"{text!r} must lie in ({low:g}, {high:g})")
        return value

    check.__name__ = f"number in ({low:g}, {high:g})"
    return check


def output_folder(text: str) -> Path:
    """A folder to write into: absent (created later) or an existing folder, not a file."""
    path = Path(text)
    if path.exists() and not path.is_dir():
        raise argparse.ArgumentTypeError(f"{text!r} exists and is not a folder")
    parent = path if path.exists() else next((p for p in path.parents if p.exists()), Path("."))
    if not parent.is_dir():
        raise argparse.ArgumentTypeError(f"{text!r}: {parent} is not a folder")
    return path


def check_order(option: str, low: float | None, high: float | None) -> None:
    """The one check of every (low, high) pair of the command line: ``low < high``.

    ``option`` names the pair in the message (``"--y0-range"`` or ``"--y-min/--y-max"``);
    a pair with a missing side (``None``) is left to the command. Raises
    :class:`UsageError` (exit code 2) showing both values.
    """
    if low is None or high is None or low < high:
        return
    swap = f"; swap them ({option} {high:g} {low:g})" if low > high else ""
    raise UsageError(f"{option}: LOW must be below HIGH, got LOW = {low:g}, HIGH = {high:g}{swap}")


class OrderedPair(argparse.Action):
    """``nargs=2`` action for a ``LOW HIGH`` option: each a finite number (:func:`real`)
    and ``LOW < HIGH`` (:func:`check_order`), else a usage error naming the option."""

    def __init__(self, option_strings: Sequence[str], dest: str, **kwargs: Any) -> None:
        kwargs.setdefault("nargs", 2)
        kwargs.setdefault("type", real)
        kwargs.setdefault("metavar", ("LOW", "HIGH"))
        if kwargs["nargs"] != 2:
            raise InvalidValueError("OrderedPair takes exactly two values (nargs=2)")
        super().__init__(option_strings, dest, **kwargs)

    def __call__(
        self,
        parser: argparse.ArgumentParser,
        namespace: argparse.Namespace,
        values: Any,
        option_string: str | None = None,
    ) -> None:
        low, high = values
        try:
            check_order(option_string or self.dest, low, high)
        except UsageError as error:
            parser.error(str(error))
        setattr(namespace, self.dest, [low, high])


def solver_name(nonlinear: bool = False) -> Callable[[str], str]:
    """``--solver``'s type: an installed solver (``SolverNotFound``'s message: did you mean,
    what to install); ``nonlinear``: also ``ipopt`` (the nonlinear transcription)."""

    def check(text: str) -> str:
        from ltv_lstm_mpc.exceptions import SolverNotFound
        from ltv_lstm_mpc.mpc.rti import NLP_SOLVERS
        from ltv_lstm_mpc.solvers import solver_info

        if text in NLP_SOLVERS:
            if nonlinear:
                return text
            raise argparse.ArgumentTypeError(
                f"{text!r} solves the nonlinear transcription, which this command does not run; "
                "give a QP or cone solver"
            )
        try:
            solver_info(text)
        except SolverNotFound as error:
            raise argparse.ArgumentTypeError(str(error)) from None
        return text

    check.__name__ = "solver name"
    return check


def add_solver_option(
    parser: argparse.ArgumentParser, *, nonlinear: bool = False, repeat: bool = False
) -> None:
    """``--solver NAME`` (default: :func:`~ltv_lstm_mpc.solvers.default_solver`, the fastest
    installed solver with exact terminal cones, the library's ``MPCConfig`` default)."""
    from ltv_lstm_mpc.solvers import default_solver

    names = "ltv_lstm_mpc.solvers.available_solvers()" + (", or ipopt" if nonlinear else "")
    help_text = (
        f"solver backend: a name of {names}; the default is the fastest installed one "
        "with exact terminal cones"
    )
    if repeat:  # "append" adds to a list default: the default is filled in after parsing
        parser.add_argument(
            "--solver",
            type=solver_name(nonlinear),
            action=_AppendOrDefault,
            default=[default_solver()],
            metavar="NAME",
            help=help_text + "; repeat for several",
        )
        return
    parser.add_argument(
        "--solver",
        type=solver_name(nonlinear),
        default=default_solver(),
        metavar="NAME",
        help=help_text,
    )


class _AppendOrDefault(argparse.Action):
    """``action="append"`` whose values replace the default list instead of extending it."""

    def __call__(
        self,
        parser: argparse.ArgumentParser,
        namespace: argparse.Namespace,
        values: Any,
        option_string: str | None = None,
    ) -> None:
        current = getattr(namespace, self.dest, None)
        items = [] if current is None or current is self.default else list(current)
        setattr(namespace, self.dest, [*items, values])


def add_n_option(parser: argparse.ArgumentParser) -> None:
    """``--N``: the prediction horizon (``MPCConfig.N``)."""
    from ltv_lstm_mpc.mpc.config import MPCConfig

    parser.add_argument("--N", type=positive_int, default=MPCConfig.N, help="prediction horizon N")


def add_l_d_option(parser: argparse.ArgumentParser) -> None:
    """``--L-d``: the observer gain l_d of L_d = l_d I_p (:data:`DEFAULT_L_D`)."""
    from ltv_lstm_mpc.mpc.config import DEFAULT_L_D

    parser.add_argument(
        "--L-d",
        type=fraction_open(0.0, 2.0),
        default=DEFAULT_L_D,
        help="observer gain L_d = l_d I_p (0.1: faster disturbance rejection, the rate "
        "bound of Theorem 3 void on the shipped model)",
    )


def add_d_max_option(parser: argparse.ArgumentParser) -> None:
    """``--d-max``: the disturbance bound d_max (``MPCConfig.d_max``, normalized)."""
    from ltv_lstm_mpc.mpc.config import MPCConfig

    parser.add_argument(
        "--d-max",
        type=positive_float,
        default=MPCConfig.d_max,
        help="disturbance bound d_max (normalized): raise it where d_hat saturates; "
        "it shrinks the admissible set-point interval by 2 d_max",
    )


def add_check_sampling_time_option(parser: argparse.ArgumentParser) -> None:
    """``--no-check-sampling-time``: run a model identified at another sampling time."""
    parser.add_argument(
        "--no-check-sampling-time",
        dest="check_sampling_time",
        action="store_false",
        help="run even where the model's sampling time differs from the plant's or is "
        "unknown (at your risk)",
    )


def add_rate_limit_option(parser: argparse.ArgumentParser) -> None:
    """``--rate-limit``: the set-point rate limiter's bound per step (0: none)."""
    parser.add_argument(
        "--rate-limit",
        type=nonnegative_float,
        default=0.01,
        help="largest normalized set-point change per step (0 = no limiter)",
    )


def add_policy_option(parser: argparse.ArgumentParser) -> None:
    """``--policy``: the infeasibility policy (``MPCConfig.infeasibility_policy``)."""
    parser.add_argument(
        "--policy", choices=["paper", "soft", "shift"], default="paper", help="infeasibility policy"
    )
