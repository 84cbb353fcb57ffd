"""The compiled functions of the MPC layer a configuration runs (what compiles, and when).

:func:`compiled_kernels` decides, from an :class:`~ltv_lstm_mpc.mpc.config.MPCConfig`
alone, which numba kernels a :class:`~ltv_lstm_mpc.mpc.rti.RobustMPC` calls;
:func:`ltv_lstm_mpc.loop.kernels.controller_kernels` adds the loop's. The one place where
the MPC layer branches on which compiled code exists, so that the transcriptions and the
RTI core do not.
"""

from __future__ import annotations

from typing import Any

from ltv_lstm_mpc.mpc.config import MPCConfig
from ltv_lstm_mpc.mpc.transcription import resolve_transcription

__all__ = ["compiled_kernels"]


def compiled_kernels(config: MPCConfig, *, native_feedback: bool = True) -> list[Any]:
    """The numba-compiled functions a :class:`~ltv_lstm_mpc.mpc.rti.RobustMPC` with ``config``
    calls when its model's kernel is compiled (workspace constructors included): what
    compiles on an empty cache. Decided from ``config`` before anything is built, by the
    rules the constructor follows (a test builds each configuration and compares the
    functions that did compile with this list).

    The LSTM loops (``lstm/compiled.py``) and the plan checks (``mpc/compiled_plan.py``)
    for every transcription; the condensing and the one-call preparation for the
    condensed one; the kernels of the solver's compiled form
    (:func:`~ltv_lstm_mpc.solvers.compiled_form`: DAQP's entry point, the SQP of
    ``daqp:socp``, the dense layer's loops of a cone solver); where its compiled solve is
    bound, the one-call feedback's workspace and the feedback where it runs (one SQP
    iteration).
    """
    from ltv_lstm_mpc.lstm import compiled as lstm_compiled
    from ltv_lstm_mpc.mpc import compiled_condensing, compiled_plan, compiled_prepare

    kernels: list[Any] = [
        lstm_compiled.rollout, lstm_compiled.pairs, lstm_compiled.jacobians,
        compiled_plan.plan_metrics, *compiled_plan.CONSTRUCTORS,
    ]  # fmt: skip
    if resolve_transcription(config) != "condensed":
        return kernels
    kernels += [
        compiled_condensing.condense, compiled_condensing.insert_state,
        compiled_condensing.expand_point, *compiled_condensing.CONSTRUCTORS,
        compiled_prepare.prepare_condensed, *compiled_prepare.CONSTRUCTORS,
    ]  # fmt: skip
    from ltv_lstm_mpc.solvers import compiled_form

    form = compiled_form(config.solver)  # what the solver gives compiled callers, if any
    if form is None:
        return kernels
    kernels += form.kernels  # its solve, workspace and loops
    if not form.bound or form.quadprog is None:  # no compiled solve here
        return kernels
    from ltv_lstm_mpc.mpc import native_feedback as native

    if form.socp_solve is not None:  # exact cones by SQP on DAQP (solvers/socp_sqp.py)
        kernels.append(native.new_fallback_workspace_kernel)  # the one-call policy's buffers
        if config.sqp_iterations == 1 and native_feedback:
            kernels.append(native.cone_feedback)
        return kernels
    kernels += native.CONSTRUCTORS
    if config.sqp_iterations == 1 and native_feedback:
        kernels.append(native.nominal_feedback)
    return kernels
