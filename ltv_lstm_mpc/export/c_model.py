r"""The LSTM prediction model and its observer as dependency-free C99 (the first part of the
C export of the controller).

:func:`export_model_c` renders the templates of ``export/templates`` with a model's
weights and, optionally, an :class:`~ltv_lstm_mpc.Observer`'s gains: a header and a
source file with every constant as ``static const`` data named after the paper's symbols
(the gates' weights ``WU``, the output map ``W_y``, ``b_y``, the observer's ``L_gates``
and ``L_d``), and functions on one caller-owned workspace struct: eq. (lstm) one step and
a rollout, its Jacobians (eq. jacobian), the output map and eq. (lstm_observer). No
allocation, no global mutable state, no I/O, only libm; C99 that compiles with
``-std=c99 -Wall -Wextra -Wpedantic -Werror`` (``tests/test_export_c.py`` builds it,
compares it with the compiled kernels and runs it under AddressSanitizer and
UndefinedBehaviorSanitizer).

The C code performs the compiled kernels' operations in their order
(:func:`~ltv_lstm_mpc.lstm.compiled.lstm_cell` with its polynomial activations,
:func:`~ltv_lstm_mpc.lstm.compiled.jacobians`,
:func:`~ltv_lstm_mpc.loop.compiled_observer.observer_update`): the two agree to rounding
(the kernels sum with reassociation allowed), whatever the target's libm.

What is not exported yet: the reference calculator, the tightening and
:math:`\alpha_k`, the condensed FHOCP with DAQP, the infeasibility policies, the input
gate and the normalization; the whole controller step follows in later parts of the
export (``docs/user-guide/export-c.md``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from importlib import resources
from pathlib import Path
from string import Template
from typing import Any

import numpy as np

from ltv_lstm_mpc.exceptions import InvalidValueError
from ltv_lstm_mpc.lstm.model import LSTMModel, require_model

__all__ = ["ExportedC", "export_model_c"]


@dataclass(frozen=True)
class ExportedC:
    """What :func:`export_model_c` wrote.

    Attributes
    ----------
    header, source : Path
        ``<prefix>.h`` and ``<prefix>.c``.
    prefix : str
        The C identifiers' prefix.
    workspace_bytes : int
        ``sizeof(<prefix>_workspace)`` on a target with 8-byte doubles.
    """

    header: Path
    source: Path
    prefix: str
    workspace_bytes: int


def _literal(value: float) -> str:
    """A C double literal that reads back as ``value`` exactly (shortest round trip)."""
    value = float(value)
    if not math.isfinite(value):
        raise InvalidValueError(f"cannot export the non-finite value {value!r} as C data")
    text = repr(value)
    return text if any(ch in text for ch in ".en") else text + ".0"


def _matrix(rows: Any, indent: str = "    ") -> str:
    """The rows of a 2-D array as C initializer lines ``{a, b, ...},``."""
    lines = []
    for row in np.atleast_2d(rows):
        lines.append(indent + "{" + ", ".join(_literal(v) for v in row) + "},")
    return "\n".join(lines)


def _template(name: str) -> Template:
    text = resources.files("ltv_lstm_mpc.export").joinpath("templates", name).read_text()
    return Template(text)


def _check_prefix(prefix: str) -> str:
    if not (
        isinstance(prefix, str)
        and prefix
        and (prefix[0].isalpha() or prefix[0] == "_")
        and all(ch.isalnum() or ch == "_" for ch in prefix)
        and prefix.isascii()
    ):
        raise InvalidValueError(
            f"prefix={prefix!r} is not a C identifier: use letters, digits and underscores, "
            "not starting with a digit (e.g. prefix='lstm')"
        )
    return prefix


def export_model_c(
    model: LSTMModel,
    out_dir: str | Path,
    *,
    observer: Any = None,
    prefix: str = "lstm_model",
) -> ExportedC:
    r"""Write ``<prefix>.h`` and ``<prefix>.c``: the model of eq. (lstm) and, with
    ``observer``, eq. (lstm_observer), as C99 (module docstring).

    Parameters
    ----------
    model : LSTMModel
        The prediction model (its normalized units: the C functions take and return them).
    out_dir : str or Path
        Folder to write into (created if missing); existing files of the same names are
        replaced.
    observer : Observer, optional
        Its gains :math:`L_f, L_i, L_o, L_d` and bound :math:`d_{max}` become
        ``<prefix>_observer_update``; it must observe ``model``.
    prefix : str
        Prefix of the files and of every C identifier (a C identifier).

    Returns
    -------
    ExportedC
    """
    from ltv_lstm_mpc import __version__
    from ltv_lstm_mpc.loop.observer import Observer

    model = require_model(model)
    prefix = _check_prefix(prefix)
    if observer is not None:
        if not isinstance(observer, Observer):
            raise InvalidValueError(
                f"observer must be an ltv_lstm_mpc.Observer, got {type(observer).__name__}; "
                "build one with Observer(model, gains, d_max=...) or pass "
                "controller.observer"
            )
        other = observer.model
        if other is not model and not (
            np.array_equal(other.kernel.WU, model.kernel.WU)
            and np.array_equal(other.W_y, model.W_y)
            and np.array_equal(other.b_y, model.b_y)
        ):
            raise InvalidValueError(
                "observer observes another model than the one exported (other weights); "
                "pass the model the observer was built with (observer.model)"
            )
    n, m, p = model.n, model.m, model.p
    WU = np.asarray(model.kernel.WU, dtype=np.float64)
    fields: dict[str, str] = {
        "prefix": prefix,
        "PREFIX": prefix.upper(),
        "version": __version__,
        "source": f"an LSTM model (n = {n}, m = {m}, p = {p})",
        "n": str(n),
        "m": str(m),
        "p": str(p),
        "has_observer": "1" if observer is not None else "0",
        "d_max": _literal(observer.d_max) if observer is not None else "0.0",
        "WU": _matrix(WU),
        "W_y": _matrix(np.asarray(model.W_y, dtype=np.float64)),
        "b_y": ", ".join(_literal(v) for v in np.asarray(model.b_y, dtype=np.float64)),
    }
    for j in range(2, 14):
        fields[f"taylor{j}"] = _literal(1.0 / math.factorial(j))
    fields["observer_data"] = ""
    fields["observer_code"] = ""
    if observer is not None:
        gains = observer.gains
        L_gates = np.vstack([gains.L_f, gains.L_i, gains.L_o, np.zeros((n, p))])
        injected = bool(np.any(L_gates))
        observer_fields = dict(fields)
        observer_fields["L_d"] = _matrix(np.asarray(gains.L_d, dtype=np.float64))
        observer_fields["L_gates"] = (
            "static const double L_gates[4 * N][P] = {  /* rows f, i, o, g (g: none) */\n"
            + _matrix(L_gates)
            + "\n};\n"
            if injected
            else "/* L_f = L_i = L_o = 0: no injection into the gates (Remark 3). */\n"
        )
        observer_fields["injection"] = (
            "    for (a = 0; a < 4 * N; ++a) {\n"
            "        double acc = 0.0;\n"
            "        for (l = 0; l < P; ++l) {\n"
            "            acc += L_gates[a][l] * w->innovation[l];\n"
            "        }\n"
            "        w->injection[a] = acc;\n"
            "    }\n"
            "    cell(w, x_hat, w->injection, x_out, x_out + N);"
            if injected
            else "    cell(w, x_hat, 0, x_out, x_out + N);"
        )
        fields["observer_code"] = _template("observer.c.in").substitute(observer_fields)
    workspace_bytes = 8 * ((n + m + 1) + 4 * n + n + 4 * n + p)
    fields["workspace_bytes"] = str(workspace_bytes)
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    header = out / f"{prefix}.h"
    source = out / f"{prefix}.c"
    header.write_text(_template("model.h.in").substitute(fields))
    source.write_text(_template("model.c.in").substitute(fields))
    return ExportedC(header=header, source=source, prefix=prefix, workspace_bytes=workspace_bytes)
