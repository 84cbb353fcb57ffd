"""Compile a controller configuration's kernels ahead of time (see
:mod:`ltv_lstm_mpc.loop.kernels`): :func:`warm_up` (``ltv-lstm-mpc warmup``) and the
background process that ``kernels="auto"`` starts on an empty numba cache."""

from __future__ import annotations

import copy
import json
import pickle
import shutil
import warnings
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from ltv_lstm_mpc.loop.controller import OffsetFreeController
from ltv_lstm_mpc.loop.kernels import (
    compile_lock,
    controller_kernels,
    forget_failure,
    record_failure,
)
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
    in seconds. ``ltv-lstm-mpc warmup`` calls it. A failed background compile recorded
    for these kernels (:func:`~ltv_lstm_mpc.loop.kernels.compile_failure`) is forgotten
    once they compiled."""
    import time

    start = time.perf_counter()
    missing = uncached(controller_kernels(config))
    twin = copy.copy(model)  # the same weights, its own compiled kernel
    twin.kernel = LSTMKernel(twin, compiled=True)
    controller = OffsetFreeController(twin, config, kernels="compiled")
    x_bar = twin.equilibrium(np.zeros(twin.m))
    y = np.asarray(twin.denormalize_y(twin.output(x_bar)), dtype=np.float64)
    for _ in range(steps):  # the first step (compiled too where it can be), then the others
        controller.step(y, y)
    controller.reset()
    controller.step(y, y)
    for _ in range(2):  # prepared steps: after a first step, then after a one-call one
        controller.prepare_next()
        controller.step(y, y)
    # the general path's compiled feedback, which a one-call step hands over to (and the
    # reference engine's first step where the one-call one declines)
    general = OffsetFreeController(twin, config, kernels="compiled", one_call_step=False)
    for _ in range(2):
        general.step(y, y)
    from ltv_lstm_mpc.mpc.rti import NLP_SOLVERS
    from ltv_lstm_mpc.solvers import compiled_form

    form = None if config.solver in NLP_SOLVERS else compiled_form(config.solver)
    listed = controller_kernels(config)
    if form is not None and form.warm_up is not None and any(k in listed for k in form.kernels):
        form.warm_up()  # its Python entry: the general path's, where the one-call one falls back
    if missing:
        forget_failure(missing)
    return time.perf_counter() - start


def compile_in_background(folder: str) -> None:
    """The background process of
    :func:`~ltv_lstm_mpc.loop.kernels.start_background_compile`: one at a time (a lock
    file in the temporary folder), skip if another has compiled everything meanwhile.
    Removes ``folder`` when done (and the record of an earlier failure of the same
    kernels); on a failure, prints the traceback into ``log.txt`` and keeps the folder as
    the one :func:`~ltv_lstm_mpc.loop.kernels.failure_folder`, marked with the fingerprint
    of the sources, so that the next runs report it instead of trying again."""
    import sys
    import traceback

    from ltv_lstm_mpc.numba_support import SOURCES_FINGERPRINT

    path = Path(folder)
    try:
        missing = list(json.loads((path / "job.json").read_text())["missing"])
    except (OSError, ValueError, KeyError, TypeError):  # started by an older version
        missing = []
    with compile_lock():
        try:
            with open(path / "config.pickle", "rb") as handle:
                config = pickle.load(handle)
            if uncached(controller_kernels(config)):
                with warnings.catch_warnings():  # e.g. a model file without Ts: not news
                    warnings.simplefilter("ignore", UserWarning)
                    model = LSTMModel.load(path / "model.npz")
                warm_up(model, config)
        except Exception:
            traceback.print_exc()  # into log.txt
            sys.stdout.flush()
            sys.stderr.flush()
            last = traceback.format_exc().strip().splitlines()[-1]
            record_failure(path, missing, SOURCES_FINGERPRINT, last)
            return
        forget_failure(missing)
    shutil.rmtree(path, ignore_errors=True)
