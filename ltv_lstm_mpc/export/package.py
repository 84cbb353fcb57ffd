r"""The exported controller as a C project for integrators (``ltv-lstm-mpc export-c``).

:func:`export_controller_c` writes what :func:`~ltv_lstm_mpc.export.c_model.export_model_c`
writes for a whole controller (``<prefix>.h``, ``<prefix>.c``, DAQP's sources) and the
files to build and check it: a ``Makefile``, a ``CMakeLists.txt``, ``example.c`` (the
controller in closed loop with its own LSTM model as the plant) and a ``README.md`` for
integrators (files, use, units, return codes and statuses, memory, how to verify), from
the templates in ``export/templates``.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from ltv_lstm_mpc.export.c_model import (
    DAQP_VENDORED,
    ExportedC,
    _template,
    export_model_c,
)

__all__ = ["export_controller_c"]


def _values(values: Any, unit: str) -> str:
    return ", ".join(f"{float(v):.6g}" for v in np.ravel(values)) + (f" {unit}" if unit else "")


def export_controller_c(
    controller: Any, out_dir: str | Path, *, prefix: str = "controller", precision: str = "double"
) -> ExportedC:
    """Write the controller's C project into ``out_dir`` (module docstring).

    Parameters
    ----------
    controller : OffsetFreeController
        The controller (DAQP on the condensed transcription, one SQP iteration per step;
        :func:`~ltv_lstm_mpc.export.c_model.mpc_refusal` says what is covered).
    out_dir : str or Path
        Folder to write into (created if missing; files of the same names are replaced).
    prefix : str
        Prefix of the files and of every C identifier.
    precision : {"double", "single"}
        C's ``double`` or ``float`` (:func:`~ltv_lstm_mpc.export.c_model.export_model_c`).

    Returns
    -------
    ExportedC
    """
    from ltv_lstm_mpc import __version__
    from ltv_lstm_mpc.plotting import signal_labels

    exported = export_model_c(
        controller.model, out_dir, controller=controller, prefix=prefix, precision=precision
    )
    out = Path(out_dir)
    model, config = controller.model, controller.config
    labels = signal_labels(None, model)
    units = f"outputs {', '.join(labels.outputs)}; inputs {', '.join(labels.inputs)}"
    low, high = controller.input_bounds_phi
    limit = controller.setpoint_rate_limit
    fields = {
        "prefix": prefix,
        "PREFIX": prefix.upper(),
        "version": __version__,
        "source": f"an LSTM model (n = {model.n}, m = {model.m}, p = {model.p})",
        "daqp_version": DAQP_VENDORED,
        "controller_bytes": f"at most {exported.mpc_workspace_bytes} bytes",
        "sample_time": f"T_s = {model.Ts:g} s"
        if model.Ts is not None
        else "the model's sampling time",
        "units": units,
        "u_bounds": f"[{_values(low, '')}] .. [{_values(high, '')}]",
        "implausible_note": (
            "" if controller.implausible_measurements == "flag" else ", or at any step"
        ),
        "terminal_note": (
            "the terminal set as exact second-order cones, by the SQP of the library's "
            "daqp:socp (a few QPs a step)"
            if exported.socp_sizes
            else "the terminal set as the conservative box of the library's daqp"
        ),
        "cone_status_note": (
            f" With the exact cones, `{prefix.upper()}_STATUS_CONE_FAILED` (the SQP ended "
            "on a subproblem DAQP could not solve: its exit flag and SQP iteration in "
            "`cone_flag`, `cone_sqp`) and `_STATUS_CONE_MAX_ITER` (it ran out of "
            "iterations) precede the infeasibility policy; the library tells infeasible "
            f"from failed there by its certificate checks on `{prefix}_controller_socp(c, 0)` "
            "(the SIL does)."
            if exported.socp_sizes
            else ""
        ),
        "N": str(config.N),
        "policy": config.infeasibility_policy,
        "L_d": f"{config.L_d:g}",
        "d_max": f"{config.d_max:g}",
        "rate_limit": "none" if limit is None else f"{limit:g} per step (normalized)",
    }
    fields["precision_note"] = _precision_note(exported)
    for name in ("Makefile", "CMakeLists.txt", "README.md", "example.c"):
        (out / name).write_text(_template(name + ".in").substitute(fields))
    return exported


def _precision_note(exported: ExportedC) -> str:
    """The README's paragraph on the export's precision."""
    prefix, upper = exported.prefix, exported.prefix.upper()
    if exported.precision == "double":
        return (
            f"Every value is `{prefix}_real`, here `double` (`{upper}_SINGLE` 0): the\n"
            "library's arithmetic. `ltv-lstm-mpc export-c --float` writes the controller in\n"
            "`float` for FPUs without double precision (e.g. a Cortex-M4F)."
        )
    margins = exported.single_precision_margins
    return (
        f"Every value is `{prefix}_real`, here `float` (`{upper}_SINGLE` 1), for FPUs without\n"
        "double precision; DAQP is built with `DAQP_SINGLE_PRECISION` (defined in\n"
        "`daqp/no_heap.h`), and the tolerances are raised to float's (the library's\n"
        "`SINGLE_PRECISION_FLOORS`). Float's rounding, bounded at export (the library's\n"
        f"`ltv_lstm_mpc.export.precision`): {margins.summary()}. The observer's error\n"
        "bound and the tightened outputs hold for plants whose disturbances stay within the\n"
        "rest of those margins (the terminal set, the reference's tolerance and the\n"
        "constants' own rounding are not bounded; the library measures the closed-loop\n"
        "deviation from double in experiments/export_float.py).\n\n"
        "DAQP's sources write some constants as double literals: with gcc, add\n"
        "`-fsingle-precision-constant` to `CFLAGS` so that they do not turn its float\n"
        "arithmetic into (software) double (`daqp/no_heap.h` includes `<tgmath.h>` for its\n"
        "`sqrt` and `fabs` of floats). On a Cortex-M4F the objects then call no\n"
        "double-precision helper (`arm-none-eabi-nm -u`: no `__aeabi_d*`)."
    )
