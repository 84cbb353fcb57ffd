"""Compile a controller configuration's kernels ahead of time (see
:mod:`ltv_lstm_mpc.loop.kernels`): :func:`warm_up` (``ltv-lstm-mpc warmup``) and the
background process that ``kernels="auto"`` starts on an empty numba cache."""

from __future__ import annotations

import copy
import pickle
import shutil
import tempfile
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from ltv_lstm_mpc.loop.controller import OffsetFreeController
from ltv_lstm_mpc.loop.kernels import controller_kernels
from ltv_lstm_mpc.lstm.kernel import LSTMKernel
from ltv_lstm_mpc.lstm.model import LSTMModel
from ltv_lstm_mpc.numba_support import uncached

if TYPE_CHECKING:  # pragma: no cover
    from ltv_lstm_mpc.mpc.config import MPCConfig

__all__ = ["compile_in_background", "warm_up"]


def warm_up(model: LSTMModel, config: MPCConfig, *, steps: int = 3) -> float:
    """Compile (or load from numba's cache) every kernel a controller with ``config`` on
    ``model`` calls, by building one on a compiled kernel and running ``steps`` steps at
    the equilibrium of ``u = 0`` with the model as its own plant (and a few steps
    prepared between samples, :meth:`OffsetFreeController.prepare_next
    <ltv_lstm_mpc.OffsetFreeController.prepare_next>`). Returns the wall time
    in seconds. ``ltv-lstm-mpc warmup`` calls it."""
    import time

    start = time.perf_counter()
    twin = copy.copy(model)  # the same weights, its own compiled kernel
    twin.kernel = LSTMKernel(twin, compiled=True)
    controller = OffsetFreeController(twin, config, kernels="compiled")
    x_bar = twin.equilibrium(np.zeros(twin.m))
    y = np.asarray(twin.denormalize_y(twin.output(x_bar)), dtype=np.float64)
    for _ in range(steps):  # the first step general, then one-call steps
        controller.step(y, y)
    controller.reset()
    controller.step(y, y)
    for _ in range(2):  # prepared steps: after a general step, then after a one-call one
        controller.prepare_next()
        controller.step(y, y)
    from ltv_lstm_mpc.solvers import daqp_socp

    if daqp_socp.socp_solve in controller_kernels(config):  # its Python entry: the
        daqp_socp.warm_up()  # general path's, where the one-call feedback falls back
    return time.perf_counter() - start


def compile_in_background(folder: str) -> None:
    """The background process of
    :func:`~ltv_lstm_mpc.loop.kernels.start_background_compile`: one at a time (a lock
    file in the temporary folder), skip if another has compiled everything meanwhile;
    remove ``folder`` when done, keep it with the traceback in ``log.txt`` on a failure."""
    import traceback

    path = Path(folder)
    lock_path = Path(tempfile.gettempdir()) / "ltv_lstm_mpc-compile.lock"
    try:
        with open(lock_path, "a") as lock:
            try:
                import fcntl

                fcntl.flock(lock, fcntl.LOCK_EX)
            except ImportError:  # pragma: no cover - no POSIX locks: compile anyway
                pass
            with open(path / "config.pickle", "rb") as handle:
                config = pickle.load(handle)
            if uncached(controller_kernels(config)):
                warm_up(LSTMModel.load(path / "model.npz"), config)
    except Exception:
        traceback.print_exc()  # into log.txt (the folder stays for a look)
        return
    shutil.rmtree(path, ignore_errors=True)
