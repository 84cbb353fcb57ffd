"""Which kernels a controller runs, compiled or numpy, and their compilation ahead of time.

Every loop of the controller has two implementations: the numpy reference and its numba
twin (``lstm/compiled.py``, ``loop/compiled_observer.py``, ``loop/compiled_reference.py``,
``mpc/compiled_*.py``; tested against each other to 1e-12). The twins run a step several
times faster, but compiling them takes 20-40 s on 2 cores the first time (numba keeps
them in its on-disk cache afterwards). A controller (``OffsetFreeController(...,
kernels=...)``) therefore chooses:

``"auto"`` (default)
    The compiled twins where numba's cache holds every one this configuration calls;
    otherwise the numpy reference for this controller (the first step is then immediate;
    0.4-0.5 ms per step against 0.09 ms compiled on the pH model with DAQP, N = 5, so
    that a numpy run of some 50 000 steps lasts about as long as the compilation) while a background
    process compiles them into the cache (:func:`start_background_compile`), so that the
    next controllers and the next runs are compiled. Said once per process, on stderr.
``"compiled"``
    The compiled twins, compiling now where the cache lacks them (the first step waits);
    what benchmarks use.
``"numpy"``
    The numpy reference.

The environment variable ``LTV_LSTM_MPC_KERNEL`` overrides ``"auto"``: ``numpy`` or
``numba``/``compiled``. ``ltv-lstm-mpc warmup``
(:func:`~ltv_lstm_mpc.loop.warmup.warm_up`) compiles a
configuration's kernels ahead of time, e.g. in a container image or a CI step.
"""

from __future__ import annotations

import os
import pickle
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path
from typing import TYPE_CHECKING, Any

from ltv_lstm_mpc.exceptions import InvalidValueError
from ltv_lstm_mpc.numba_support import AVAILABLE, uncached

if TYPE_CHECKING:  # pragma: no cover
    from ltv_lstm_mpc.lstm.model import LSTMModel
    from ltv_lstm_mpc.mpc.config import MPCConfig

__all__ = [
    "KERNEL_MODES",
    "choose_kernels",
    "controller_kernels",
    "start_background_compile",
]

#: The values of ``OffsetFreeController(..., kernels=...)``.
KERNEL_MODES = ("auto", "compiled", "numpy")

_ENVIRONMENT = "LTV_LSTM_MPC_KERNEL"


def controller_kernels(config: MPCConfig, *, native_feedback: bool = True) -> list[Any]:
    """The numba-compiled functions an ``OffsetFreeController`` with ``config`` calls on a
    compiled kernel: the MPC's (:func:`~ltv_lstm_mpc.mpc.rti.compiled_kernels`), the
    observer update and the reference calculator's chord Newton, with the constructors of
    their workspaces; and the one-call step (:mod:`ltv_lstm_mpc.loop.compiled_step`) where
    the one-call feedback runs."""
    from ltv_lstm_mpc.loop import compiled_observer, compiled_reference
    from ltv_lstm_mpc.mpc.rti import compiled_kernels

    kernels = [
        *compiled_kernels(config, native_feedback=native_feedback),
        compiled_observer.observer_update, compiled_observer._new_observer_workspace,
        compiled_reference.chord_newton, compiled_reference._new_chord_workspace,
    ]  # fmt: skip
    names = {getattr(kernel, "__name__", "") for kernel in kernels}
    if names & {"nominal_feedback", "cone_feedback"}:
        from ltv_lstm_mpc.loop import compiled_step  # the one-call step builds on them
        from ltv_lstm_mpc.mpc import native_feedback as one_call_feedback
        from ltv_lstm_mpc.solvers import daqp_socp

        kernels += [
            compiled_step.controller_step, compiled_step.controller_step_from_rows,
            compiled_step.prepare_step, compiled_step.prepare_step_from_rows,
            compiled_step.feedback_step, compiled_step.feedback_step_from_rows,
            compiled_step._new_step_workspace, compiled_step._new_record_arrays,
        ]  # fmt: skip
        # the workspace of the feedback it does not run is a placeholder of that type
        placeholder = (
            one_call_feedback._new_daqp_workspace
            if "cone_feedback" in names
            else daqp_socp._new_socp_workspace
        )
        if placeholder not in kernels:
            kernels.append(placeholder)
    return kernels


def choose_kernels(config: MPCConfig, kernels: str = "auto") -> tuple[bool, list[str]]:
    """Resolve ``kernels`` (one of :data:`KERNEL_MODES`) for a controller with ``config``.

    Returns
    -------
    compiled : bool
        Whether the controller runs the compiled twins.
    missing : list of str
        The compiled functions this configuration calls that numba's on-disk cache lacks
        (empty where everything is cached, or where the numpy reference is chosen on
        purpose): with ``compiled`` they compile at their first call; with
        ``"auto"`` they are why the numpy reference runs.

    Raises
    ------
    InvalidValueError
        ``kernels`` is not one of :data:`KERNEL_MODES`.
    """
    if kernels not in KERNEL_MODES:
        raise InvalidValueError(
            f"kernels must be one of {KERNEL_MODES}, got {kernels!r}: 'auto' (compiled where "
            "numba's cache has them, else numpy while they compile in the background), "
            "'compiled' (compile now if needed) or 'numpy' (the reference)"
        )
    if kernels == "auto":
        setting = os.environ.get(_ENVIRONMENT, "").strip().lower()
        if setting == "numpy":
            kernels = "numpy"
        elif setting in ("numba", "compiled"):
            kernels = "compiled"
    if kernels == "numpy" or not AVAILABLE:
        return False, []
    missing = uncached(controller_kernels(config))
    if kernels == "compiled":
        return True, missing
    return not missing, missing


_started: set[tuple[str, ...]] = set()


def start_background_compile(model: LSTMModel, config: MPCConfig, missing: list[str]) -> bool:
    """Start a detached process that compiles ``config``'s kernels into numba's on-disk
    cache (:func:`~ltv_lstm_mpc.loop.warmup.warm_up` on a copy of ``model``), once per
    process and set of missing functions; concurrent ones (several processes, campaign
    workers) take turns on a lock file and skip what another has compiled. It outlives
    this process if need be.
    Returns whether one was started."""
    key = tuple(missing)
    if key in _started:
        return False
    _started.add(key)
    folder = Path(tempfile.mkdtemp(prefix="ltv_lstm_mpc-compile-"))
    try:
        model.save(folder / "model.npz")
        with open(folder / "config.pickle", "wb") as handle:
            pickle.dump(config, handle)
        code = (
            f"import sys; sys.path[:0] = {[p for p in sys.path if p]!r}; "
            "from ltv_lstm_mpc.loop.warmup import compile_in_background; "
            f"compile_in_background({str(folder)!r})"
        )
        with open(folder / "log.txt", "wb") as log:
            subprocess.Popen(
                [sys.executable, "-c", code],
                stdin=subprocess.DEVNULL,
                stdout=log,
                stderr=subprocess.STDOUT,
                env={**os.environ, _ENVIRONMENT: "numba"},
                start_new_session=True,
            )
    except Exception:  # nothing to start: the next run compiles (or runs numpy) again
        shutil.rmtree(folder, ignore_errors=True)
        return False
    return True
