r"""The LSTM prediction model, its observer and the reference calculator as dependency-free
C99 (the first parts of the C export of the controller).

:func:`export_model_c` renders the templates of ``export/templates`` with a model's
weights and, optionally, an :class:`~ltv_lstm_mpc.Observer`'s gains and a
:class:`~ltv_lstm_mpc.ReferenceCalculator`'s settings and equilibrium grid: a header and
a source file with every constant as ``static const`` data named after the paper's
symbols (the gates' weights ``WU``, the output map ``W_y``, ``b_y``, the observer's
``L_gates`` and ``L_d``, the grid), and functions on one caller-owned workspace struct:
eq. (lstm) one step and a rollout, its Jacobians (eq. jacobian), the output map, eq.
(lstm_observer), eq. (reference_calculation) (its state in a second caller-owned
struct), and with a :class:`~ltv_lstm_mpc.certificates.tightening.TighteningCertificate`
the per-step formulas of the tightening (the output bounds, :math:`\alpha_k`, the
set-point interval, the :math:`\hat e_o` recursion), the rate limiter and the exit gate.
No
allocation, no global mutable state, no I/O, only libm; C99 that compiles with
``-std=c99 -Wall -Wextra -Wpedantic -Werror`` (``tests/test_export_c.py`` builds it,
compares it with the compiled kernels and runs it under AddressSanitizer and
UndefinedBehaviorSanitizer).

The C code performs the compiled kernels' operations in their order
(:func:`~ltv_lstm_mpc.lstm.compiled.lstm_cell` with its polynomial activations,
:func:`~ltv_lstm_mpc.lstm.compiled.jacobians`,
:func:`~ltv_lstm_mpc.loop.compiled_observer.observer_update`,
:func:`~ltv_lstm_mpc.loop.compiled_reference.chord_newton` and
:func:`~ltv_lstm_mpc.loop.compiled_reference.newton_restarts` with the admissibility and
stale rules of the one-call step): the two agree to rounding (the kernels sum with
reassociation allowed), whatever the target's libm.

With ``mpc=`` (a :class:`~ltv_lstm_mpc.mpc.rti.RobustMPC` on the condensed
transcription with DAQP), the MPC's subproblem follows: the linearization along a
candidate, the condensed QP (:mod:`~ltv_lstm_mpc.mpc.compiled_condensing`), DAQP
(vendored, on the caller's workspace), the acceptance tests, the infeasibility policies
and the plan's re-simulation (:mod:`~ltv_lstm_mpc.mpc.native_feedback`,
:mod:`~ltv_lstm_mpc.mpc.compiled_plan`), equal to ``RobustMPC.feedback``
(``tests/test_export_mpc.py``). With ``controller=`` (an
:class:`~ltv_lstm_mpc.OffsetFreeController`), the whole step of Fig. 1 in physical units,
``<prefix>_controller_step`` (``tests/test_export_step.py``; on the host through
:mod:`ltv_lstm_mpc.export.sil`). Not exported yet: the exact cones of ``daqp:socp``
(``docs/user-guide/export-c.md``).
"""

from __future__ import annotations

import ctypes
import math
import re
from dataclasses import dataclass
from importlib import resources
from pathlib import Path
from string import Template
from typing import Any

import numpy as np

from ltv_lstm_mpc.exceptions import InvalidValueError
from ltv_lstm_mpc.export.socp_struct import (
    SOCP_PROBLEMS,
    SOCP_SIZE_KEYS,
    SOCP_STRUCT,
    socp_declaration,
    socp_length,
    socp_sizes,
)
from ltv_lstm_mpc.lstm.model import LSTMModel, require_model

__all__ = [
    "EXPORTED_SOLVERS",
    "PRECISIONS",
    "SINGLE_PRECISION_FLOORS",
    "ExportedC",
    "daqp_refusal",
    "export_model_c",
    "export_refusal",
    "mpc_refusal",
]


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
        ``sizeof(<prefix>_workspace)`` on a target whose doubles are 8 bytes, 8-aligned,
        floats and ints 4 bytes (x86-64, Arm; an upper bound where doubles are 4-aligned, as
        on i386).
    reference_state_bytes : int
        ``sizeof(<prefix>_reference_state)`` (0: no reference calculator exported).
    horizon : int
        The exported MPC's horizon N (0: no MPC exported).
    mpc_workspace_bytes : int
        An upper bound of ``sizeof(<prefix>_mpc_workspace)`` (0: no MPC exported; DAQP's
        structs counted with 8-byte pointers).
    n, m, p : int
        The model's units, inputs and outputs.
    precision : str
        ``"double"`` or ``"single"`` (``<prefix>_real`` is ``double`` or ``float``).
    single_precision_margins : SinglePrecisionMargins or None
        In single precision with a controller: its rounding against the certificates'
        margins (:func:`~ltv_lstm_mpc.export.precision.single_precision_margins`).
    socp_sizes : tuple of int
        With the exact cones of ``daqp:socp``: the sizes of ``<prefix>_socp``'s arrays
        (:func:`socp_sizes`); empty otherwise.
    """

    header: Path
    source: Path
    prefix: str
    workspace_bytes: int
    reference_state_bytes: int = 0
    mpc_workspace_bytes: int = 0
    horizon: int = 0
    n: int = 0
    m: int = 0
    p: int = 0
    precision: str = "double"
    single_precision_margins: Any = None
    socp_sizes: tuple[int, ...] = ()

    @property
    def single(self) -> bool:
        """Whether ``<prefix>_real`` is ``float`` (``precision="single"``)."""
        return self.precision == "single"


def _literal(value: float) -> str:
    """A C double literal that reads back as ``value`` exactly (shortest round trip)."""
    value = float(value)
    if not math.isfinite(value):
        raise InvalidValueError(f"cannot export the non-finite value {value!r} as C data")
    text = repr(value)
    return text if any(ch in text for ch in ".en") else text + ".0"


#: The precisions of :func:`export_model_c`: C's ``double`` or ``float``.
PRECISIONS = ("double", "single")

# A floating literal of C (decimal), or a comment, string or character literal to leave
# as it is; a hexadecimal floating literal is refused (the templates write none).
_C_FLOAT_LITERAL = re.compile(
    r'(/\*.*?\*/|//[^\n]*|"(?:\\.|[^"\\])*"|\'(?:\\.|[^\'\\])+\')'
    r"|(?<![\w.])((?:\d+\.\d*|\.\d+)(?:[eE][-+]?\d+)?|\d+[eE][-+]?\d+)(?![\w.])"
    r"|(?<![\w.])(0[xX][0-9a-fA-F]*\.?[0-9a-fA-F]*[pP][-+]?\d+)",
    re.DOTALL,
)


def _float_literal(text: str) -> str:
    """The float literal (``f`` suffix, shortest round trip) of the double literal ``text``."""
    with np.errstate(over="ignore"):
        value = np.float32(float(text))
    if not np.isfinite(value):
        raise InvalidValueError(
            f"the constant {text} is beyond the range of a float (FLT_MAX = 3.4e38): this "
            "controller cannot be exported in single precision; export it in double"
        )
    if value == 0.0 and float(text) != 0.0:
        raise InvalidValueError(
            f"the constant {text} is below the range of a float (it would become 0): this "
            "controller cannot be exported in single precision; export it in double"
        )
    out = str(value)
    return (out if any(ch in out for ch in ".e") else out + ".0") + "f"


def _float_token(match: Any) -> str:
    if match.group(1):
        return str(match.group(1))
    if match.group(3):
        raise InvalidValueError(
            f"the hexadecimal floating constant {match.group(3)} has no float form here: "
            "write it in decimal"
        )
    return _float_literal(match.group(2))


def _single_precision(source: str) -> str:
    """``source`` (rendered C) with every floating literal of its code a float literal
    (comments and strings as they are): no computation is promoted to double."""
    return _C_FLOAT_LITERAL.sub(_float_token, source)


#: The tolerances of a single-precision export (``precision="single"``): the library's
#: (double's unit roundoff 1.1e-16) below these floors are raised to them, a few to some
#: hundred units of float's roundoff (6e-8) at the normalized units' scale of 1; larger
#: ones are kept. ``huge_entry``: a float's range ends at 3.4e38.
SINGLE_PRECISION_FLOORS: dict[str, float] = {
    "precheck_tol": 1e-6,  # the pre-check of the i = 0 output row (1e-12)
    "huge_entry": 1e30,  # larger entries of a solution reject it (1e100; replaced)
    "u_margin": 1e-6,  # an equilibrium's input within U's bound times 1 + it (1e-12)
    "reference_tol": 1e-5,  # the reference calculator's Newton residual (1e-10)
    "reuse_tol": 1e-5,  # the estimate within it of the plan's x_1 reuses the plan (1e-9)
    "tolerance": 1e-4,  # the acceptance tests' feasibility tolerance (DAQP: 1e-6)
    "primal_tol": 1e-5,  # DAQP's settings (daqp.solve's in the library)
    "dual_tol": 1e-5,
    "zero_tol": 1e-6,
    "pivot_tol": 1e-5,
    "progress_tol": 1e-6,
    "sing_tol": 1e-6,
    "refactor_tol": 1e-5,
}


def _float_below(value: float) -> float:
    """The largest float (single precision) <= ``value``: a bound the float code must not
    exceed, rounded towards it."""
    rounded = np.float32(value)
    if float(rounded) > value:
        rounded = np.nextafter(rounded, np.float32(-np.inf))
    return float(rounded)


def _precision_value(name: str, value: float, single: bool) -> float:
    """``value`` of the tolerance ``name``, raised to its floor in single precision
    (:data:`SINGLE_PRECISION_FLOORS`; ``huge_entry`` replaced)."""
    if not single:
        return float(value)
    floor = SINGLE_PRECISION_FLOORS[name]
    return floor if name == "huge_entry" else max(float(value), floor)


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
        and prefix.isascii()
        and prefix[0].isalpha()
        and all(ch.isalnum() or ch == "_" for ch in prefix)
    ):
        raise InvalidValueError(
            f"prefix={prefix!r} is not a C identifier that starts with a letter: use letters, "
            "digits and underscores (e.g. prefix='lstm'; a leading underscore is reserved in "
            "C). Two exports in one program need prefixes that differ in more than case "
            "(their header guards are the upper-case prefix)"
        )
    return prefix


def export_model_c(
    model: LSTMModel,
    out_dir: str | Path,
    *,
    observer: Any = None,
    reference: Any = None,
    tightening: Any = None,
    mpc: Any = None,
    controller: Any = None,
    prefix: str = "lstm_model",
    precision: str = "double",
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
    reference : ReferenceCalculator, optional
        Its settings (``tol``, ``max_iter``, ``jump``, ``restarts``, the bound of U) and
        equilibrium grid become ``<prefix>_reference``: eq. (reference_calculation) by the
        warm chord Newton, the damped Newton with restarts where that finds no admissible
        equilibrium, and the last admissible one kept where none is (an unreachable
        set-point); it must belong to ``model``.
    tightening : TighteningCertificate, optional
        Its :math:`a_i, b_i`, bounds, :math:`\kappa`, :math:`d_{max}`, :math:`\bar w`,
        :math:`\rho_o`, :math:`\bar e_\infty` become the per-step formulas (the tightened
        output bounds, :math:`\alpha_k`, the set-point interval, the :math:`\hat e_o`
        recursion) with the rate limiter and the exit gate (``controller.mpc.tightening``).
    mpc : RobustMPC, optional
        The controller's MPC (``controller.mpc``; the condensed transcription on DAQP):
        its horizon, weights, terminal set, input bound, acceptance tolerance, DAQP
        settings and infeasibility policy become ``<prefix>_linearize``,
        ``<prefix>_condense`` and ``<prefix>_feedback`` (eq. optimization as one convex
        subproblem, with the policies), on a second caller-owned struct,
        ``<prefix>_mpc_workspace``; DAQP's C sources (the release the library calls) are
        copied into ``out_dir/daqp`` with its license.
    controller : OffsetFreeController, optional
        The whole controller: its observer, reference calculator, tightening certificate
        and MPC (the arguments above, taken from it where not given) and its step,
        ``<prefix>_controller_step`` on a caller-owned ``<prefix>_controller``: the
        normalization, rate limiter, reference calculator with the stale rule,
        tightening and :math:`\alpha_k`, candidate, subproblem, exit gate, observer and
        :math:`\hat e_o` recursion of ``OffsetFreeController.step`` (physical units in
        and out).
    prefix : str
        Prefix of the files and of every C identifier (a C identifier).
    precision : {"double", "single"}
        The C type of every value, ``<prefix>_real``: ``double`` (the library's arithmetic;
        the code then equals the compiled kernels to rounding), or ``float`` for FPUs
        without double precision (e.g. a Cortex-M4F): every constant rounded to float,
        float arithmetic (the activations' own exponential in float), DAQP built with
        ``DAQP_SINGLE_PRECISION`` and the tolerances raised to
        :data:`SINGLE_PRECISION_FLOORS`. With ``controller``, refused where float's
        rounding takes more than half a margin of the certificates
        (:func:`~ltv_lstm_mpc.export.precision.single_precision_margins`); its deviation
        from double: ``docs/user-guide/export-c.md``, "Single precision".

    Returns
    -------
    ExportedC
    """
    from ltv_lstm_mpc import __version__
    from ltv_lstm_mpc.certificates.tightening import TighteningCertificate
    from ltv_lstm_mpc.loop.observer import Observer
    from ltv_lstm_mpc.loop.reference import ReferenceCalculator

    model = require_model(model)
    prefix = _check_prefix(prefix)
    if precision not in PRECISIONS:
        raise InvalidValueError(
            f"precision={precision!r} is not one of {PRECISIONS}: 'double' for C's double, "
            "'single' for float (FPUs without double precision)"
        )
    single = precision == "single"
    real_bytes = 4 if single else 8
    if controller is not None:
        # (by its parts, not its class: the C engine of the controller's package calls this)
        if not all(hasattr(controller, a) for a in ("mpc", "observer", "reference", "scaling")):
            raise InvalidValueError(
                f"controller must be an OffsetFreeController, got {type(controller).__name__}"
            )
        observer = controller.observer if observer is None else observer
        reference = controller.reference if reference is None else reference
        tightening = controller.mpc.tightening if tightening is None else tightening
        mpc = controller.mpc if mpc is None else mpc
    if reference is not None and not isinstance(reference, ReferenceCalculator):
        raise InvalidValueError(
            f"reference must be an ltv_lstm_mpc.ReferenceCalculator, got "
            f"{type(reference).__name__}; pass controller.reference"
        )
    if tightening is not None and not isinstance(tightening, TighteningCertificate):
        raise InvalidValueError(
            f"tightening must be a TighteningCertificate, got {type(tightening).__name__}; "
            "pass controller.mpc.tightening"
        )
    if tightening is not None and np.shape(tightening.y_min) != (model.p,):
        raise InvalidValueError(
            f"tightening has {np.size(tightening.y_min)} outputs, the model {model.p}: pass "
            "the certificate of this model's controller (controller.mpc.tightening)"
        )
    if reference is not None and not _same_weights(reference.model, model):
        raise InvalidValueError(
            "reference belongs to another model than the one exported (other weights); "
            "pass the model the reference calculator was built with (reference.model)"
        )
    if observer is not None:
        if not isinstance(observer, Observer):
            raise InvalidValueError(
                f"observer must be an ltv_lstm_mpc.Observer, got {type(observer).__name__}; "
                "build one with Observer(model, gains, d_max=...) or pass "
                "controller.observer"
            )
        if not _same_weights(observer.model, model):
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
        "real_type": "float" if single else "double",
        "real_name": precision,
        "single": "1" if single else "0",
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
            "static const real_t L_gates[4 * N][P] = {  /* rows f, i, o, g (g: none) */\n"
            + _matrix(L_gates)
            + "\n};\n"
            if injected
            else "/* L_f = L_i = L_o = 0: no injection into the gates (Remark 3). */\n"
        )
        observer_fields["injection"] = (
            "    for (a = 0; a < 4 * N; ++a) {\n"
            "        real_t acc = 0.0;\n"
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
    fields["has_reference"] = "0"
    fields["grid_points"] = "1"
    fields["reference_code"] = ""
    doubles, ints = (n + m + 1) + 4 * n + n + 4 * n + p, 0
    newton_bytes = 0
    state_bytes = 0
    if reference is not None:
        nz = 2 * n + m
        grid_u = np.asarray(reference._grid_u, dtype=np.float64)
        grid_x = np.asarray(reference._grid_x, dtype=np.float64)
        grid_y = np.asarray(reference._grid_y, dtype=np.float64)
        reference_fields = dict(fields)
        from ltv_lstm_mpc.loop.compiled_reference import (
            BACKTRACKING_STEPS,
            CHORD_REFRESH_CONTRACTION,
            U_MARGIN,
        )

        reference_fields.update(
            refresh=_literal(CHORD_REFRESH_CONTRACTION),
            halvings=str(int(BACKTRACKING_STEPS)),
            u_margin=_literal(_precision_value("u_margin", U_MARGIN, single)),
            grid_points=str(grid_u.shape[0]),
            tol=_literal(_precision_value("reference_tol", reference.tol, single)),
            max_iter=str(int(reference.max_iter)),
            jump=_literal(reference.jump),
            u_max=_literal(reference.u_max),
            restarts=str(int(reference.restarts)),
            grid_u=_matrix(grid_u),
            grid_x=_matrix(grid_x),
            grid_y=_matrix(grid_y),
        )
        fields["has_reference"] = "1"
        fields["grid_points"] = str(grid_u.shape[0])
        fields["reference_code"] = _template("reference.c.in").substitute(reference_fields)
        newton_bytes = real_bytes * (6 * nz + 2 * n + 4 * n * n + 2 * n * m + (2 * n + p) + nz * nz)
        newton_bytes += real_bytes * grid_u.shape[0] + 4 * (grid_u.shape[0] + nz)
        newton_bytes += (-newton_bytes) % real_bytes
        state_bytes = real_bytes * (nz + p + nz * nz + 1)  # (the int, padded)
    fields["has_tightening"] = "0"
    fields["horizon"] = "1"
    fields["tightening_code"] = ""
    if tightening is not None:
        N = int(tightening.N)
        tightening_fields = dict(fields)
        tightening_fields.update(
            horizon=str(N),
            a=_matrix(np.asarray(tightening.a, dtype=np.float64)[: N + 1]),
            b=_matrix(np.asarray(tightening.b, dtype=np.float64)[: N + 1]),
            y_min=", ".join(_literal(v) for v in np.ravel(tightening.y_min)),
            y_max=", ".join(_literal(v) for v in np.ravel(tightening.y_max)),
            kappa=", ".join(_literal(v) for v in np.ravel(tightening.kappa)),
            d_max_tightening=_literal(tightening.d_max),
            w_bar=_literal(tightening.w_bar),
            rho_o=_literal(tightening.rho_o),
            e_inf=_literal(tightening.e_inf),
            e_inf_below=_literal(_float_below(tightening.e_inf)),
        )
        fields["has_tightening"] = "1"
        fields["horizon"] = str(N)
        fields["tightening_code"] = _template("tightening.c.in").substitute(tightening_fields)
    if reference is not None:
        for name in ("max_iter", "restarts"):
            value = int(getattr(reference, name))
            if not 0 < value < 2**31:
                raise InvalidValueError(
                    f"reference.{name} = {value} does not fit a C int: use 1..2**31 - 1"
                )
    if mpc is not None:
        reason = mpc_refusal(mpc, precision)
        if reason is not None:
            raise InvalidValueError(reason)
    margins = None
    if single and controller is not None:
        margins = _single_margins(controller)
        reason = margins.refusal()
        if reason is not None:
            raise InvalidValueError(reason)
    # The Newton iterations' and the condensing's scratch share a union (model.h.in).
    condense_bytes = 0
    fields["mpc_horizon"] = "1"
    if mpc is not None:
        fields["mpc_horizon"] = str(int(mpc.N))
        condense_bytes = real_bytes * (
            2 * (2 * n) ** 2 + m * 2 * n + 3 * 2 * n + (int(mpc.N) + 1) * 2 * n
        )
    workspace_bytes = real_bytes * doubles + 4 * ints
    workspace_bytes += (-workspace_bytes) % real_bytes  # the struct's alignment
    workspace_bytes += max(newton_bytes, condense_bytes)
    fields["workspace_bytes"] = str(workspace_bytes)
    fields["mpc_declarations"] = ""
    fields["mpc_code"] = ""
    fields["has_mpc"] = "0" if mpc is None else "1"
    fields["mpc_includes"] = ""
    mpc_bytes = 0
    if mpc is not None:
        mpc_fields, mpc_bytes = _mpc_fields(mpc, model, fields, workspace_bytes, real_bytes)
        fields["mpc_declarations"] = _template("mpc.h.in").substitute(mpc_fields)
        fields["mpc_code"] = _template("mpc.c.in").substitute(mpc_fields)
        fields["mpc_includes"] = _template("daqp_wiring.c.in").substitute(mpc_fields)
    fields["has_controller"] = "0" if controller is None else "1"
    if controller is not None:
        if tightening is None or int(tightening.N) != int(mpc.N):
            raise InvalidValueError(
                "the controller step needs the tightening certificate of its MPC's horizon "
                "(controller.mpc.tightening)"
            )
        step_fields = _controller_fields(controller, mpc_fields)
        fields["mpc_declarations"] += _template("controller.h.in").substitute(step_fields)
        fields["mpc_code"] += _template("controller.c.in").substitute(step_fields)
        mpc_bytes += (
            real_bytes * (2 * (2 * n) + 2 * p + 2 * m + 4 * n + 2 * m) + 8 * 5 + state_bytes
        )
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    header = out / f"{prefix}.h"
    source = out / f"{prefix}.c"
    header_text = _template("model.h.in").substitute(fields)
    source_text = _template("model.c.in").substitute(fields)
    if single:
        header_text, source_text = _single_precision(header_text), _single_precision(source_text)
    header.write_text(header_text)
    source.write_text(source_text)
    if mpc is not None:
        _copy_daqp(out / "daqp", single=single)
    return ExportedC(
        header=header,
        source=source,
        prefix=prefix,
        workspace_bytes=workspace_bytes,
        reference_state_bytes=state_bytes,
        mpc_workspace_bytes=mpc_bytes,
        horizon=0 if mpc is None else int(mpc.N),
        n=n,
        m=m,
        p=p,
        precision=precision,
        single_precision_margins=margins,
        socp_sizes=_exported_socp_sizes(mpc, model),
    )


def _exported_socp_sizes(mpc: Any, model: LSTMModel) -> tuple[int, ...]:
    """:attr:`ExportedC.socp_sizes` of an export of ``mpc`` (:data:`SOCP_SIZE_KEYS`)."""
    if mpc is None or not mpc._problem.exact_cones:
        return ()
    sizes = socp_sizes(int(mpc.N), model.n, model.m, model.p, mpc.config.infeasibility_policy)
    return tuple(sizes[key] for key in SOCP_SIZE_KEYS)


#: The DAQP release whose C sources are vendored in ``export/vendor/daqp``.
DAQP_VENDORED = "0.11.0"


def _copy_daqp(target: Path, *, single: bool = False) -> None:
    """DAQP's vendored C sources, its license and ``no_heap.h`` into ``target``."""
    vendor = resources.files("ltv_lstm_mpc.export").joinpath("vendor", "daqp")
    for folder in ("include", "src"):
        (target / folder).mkdir(parents=True, exist_ok=True)
        for entry in vendor.joinpath(folder).iterdir():
            if entry.name.endswith((".h", ".c")):
                (target / folder / entry.name).write_bytes(entry.read_bytes())
    for name in ("LICENSE", "README.md"):
        (target / name).write_bytes(vendor.joinpath(name).read_bytes())
    no_heap = _template("no_heap.h.in").substitute(
        single_precision=(
            "#define DAQP_SINGLE_PRECISION /* c_float is float */\n"
            "/* sqrt, fabs of a float are float's (math.h's would compute in double) */\n"
            "#include <tgmath.h>\n"
        )
        if single
        else ""
    )
    (target / "no_heap.h").write_text(no_heap)


def _daqp_settings(config: Any, single: bool = False) -> str:
    """The ``DAQPSettings`` the library's DAQP calls use (``daqp.solve``'s keywords from the
    solver options) as C designated initializers, equality elimination off."""
    from ltv_lstm_mpc.solvers import daqp_native
    from ltv_lstm_mpc.solvers.tolerances import solver_options

    reason = daqp_refusal()
    if reason is not None:
        raise InvalidValueError(reason)
    options = solver_options("daqp", config.tolerance, dict(config.solver_settings))
    native = daqp_native.native(options)
    if native is None:
        raise InvalidValueError(
            f"DAQP's settings cannot be read from the installed release "
            f"({daqp_native.unavailable_reason()}); reinstall daqp=={DAQP_VENDORED}"
        )
    settings = daqp_native._Settings.from_buffer_copy(bytes(native.settings))
    lines = []
    for name, kind in settings._fields_:
        value = getattr(settings, name)
        if name == "eq_reduction":
            value = -1  # DAQP_EQ_REDUCTION_OFF (daqp_wiring.c.in says why)
        if name in SINGLE_PRECISION_FLOORS:
            value = _precision_value(name, value, single)
        text = str(int(value)) if kind is ctypes.c_int else _literal(value)
        lines.append(f"    .{name} = {text},")
    return "\n".join(lines)


def _mpc_fields(
    mpc: Any, model: LSTMModel, fields: dict[str, str], model_bytes: int, real_bytes: int = 8
) -> tuple[dict[str, str], int]:
    """The template fields of ``mpc.h.in`` and ``mpc.c.in`` and the workspace's size bound."""
    from ltv_lstm_mpc.mpc.fhocp import PRECHECK_TOL
    from ltv_lstm_mpc.mpc.native_feedback import HUGE_ENTRY
    from ltv_lstm_mpc.solvers import daqp_native
    from ltv_lstm_mpc.solvers.tolerances import feasibility_tolerance

    config = mpc.config
    single = real_bytes == 4
    if not _same_weights(mpc.model, model):
        raise InvalidValueError(
            "mpc predicts with another model than the one exported (other weights); pass "
            "the model the controller was built with (controller.model)"
        )
    policies = ("nominal", "paper", "soft", "shift")
    policy = config.infeasibility_policy
    problem: Any = mpc._problem
    N, n, m, p = int(mpc.N), model.n, model.m, model.p
    nx, nu = 2 * n, N * m
    n_out = (N - 1) * p
    rows = n_out + nx
    cones = bool(problem.exact_cones)
    soft = policy == "soft" and not cones  # (with cones: the soft problem is a socp's)
    soft_n = nu + n_out + 1 if soft else 1
    soft_rows = 2 * n_out + 2 * nx if soft else 1
    qp_n = max(nu, soft_n if soft else 0)
    qp_rows = max(rows, soft_rows if soft else 0)
    qp_m = max(nu + rows, soft_n + soft_rows if soft else 0)
    sizes = socp_sizes(N, n, m, p, policy) if cones else {}
    if cones and sizes["R"] < 1:  # (the C ring's modulus; numba's has a guard)
        raise InvalidValueError(
            f"socp_sqp.CUT_ROUNDS is {sizes['R']}; the C export needs at least 1 (the "
            "infeasibility check's kept iterates)"
        )
    if cones:  # DAQP's buffers also hold the SQP's subproblems
        qp_n = max(qp_n, sizes["n"])
        qp_rows = max(qp_rows, sizes["m"] + sizes["c"] + sizes["r"])
        qp_m = max(qp_m, sizes["k"] + sizes["r"])
    Qs = problem.stage_weights()[1]
    diagonal_weights = all(np.array_equal(W, np.diag(np.diag(W))) for W in Qs)
    # the library's form of H and g0 (its Gram matrix for full weights at short horizons is
    # the backward recursion in C)
    from ltv_lstm_mpc.mpc.condensed import backward_condensing

    backward = backward_condensing(N, m, nx, diagonal_weights)
    Q = np.asarray(mpc._Q, dtype=np.float64)
    Q_diagonal = bool(np.array_equal(Q, np.diag(np.diag(Q))))
    values = dict(fields)
    values.update(
        mpc_N=str(N),
        nx=str(nx),
        nu=str(nu),
        rows=str(rows),
        gamma_size=str(nx * m * N * (N + 1) // 2),
        plan_cell_rows=str(max(N - 1, 1)),
        soft_n=str(soft_n),
        soft_rows=str(soft_rows),
        qp_n=str(qp_n),
        qp_m=str(qp_m),
        qp_rows=str(qp_rows),
        policy_name=policy,
        policy_code=str(policies.index(policy)),
        u_max=_literal(config.u_max),
        weights_diagonal="1" if diagonal_weights else "0",
        backward_condensing="1" if backward or not diagonal_weights else "0",
        Qs=(
            _matrix(np.array([np.diag(W) for W in Qs]))
            if diagonal_weights
            else "\n".join("    {\n" + _matrix(W, "        ") + "\n    }," for W in Qs)
        ),
        Q_diagonal="1" if Q_diagonal else "0",
        R=_matrix(np.asarray(mpc._R, dtype=np.float64)),
        Q=", ".join(_literal(v) for v in np.diag(Q)) if Q_diagonal else _matrix(Q),
        P_terms=", ".join(_literal(v) for v in mpc._P_terms),
        unit_half=", ".join(_literal(v) for v in problem._unit_half),
        tolerance=_literal(
            _precision_value("tolerance", feasibility_tolerance("daqp", config.tolerance), single)
        ),
        precheck_tol=_literal(_precision_value("precheck_tol", PRECHECK_TOL, single)),
        hessian_floor=_literal(problem.hessian_floor),
        rounding_margin=_literal(daqp_native.ROUNDING_MARGIN),
        condition_limit=_literal(daqp_native.CONDITION_LIMIT),
        activity_margin=_literal(daqp_native.ACTIVITY_MARGIN),
        keep_from=str(daqp_native.KEEP_FROM),
        huge_entry=_literal(_precision_value("huge_entry", HUGE_ENTRY, single)),
        slack_regularization=_literal(problem.slack_regularization),
        soft_penalty=_literal(config.soft_penalty),
        daqp_settings=_daqp_settings(config, single),
        exact_cones="1" if cones else "0",
        sqp_max_iterations="0",
        socp_declarations="",
        socp_members="",
        cone_feedback_code="",
    )
    if cones:
        from ltv_lstm_mpc.solvers import socp_sqp

        constants = {
            f"sqp_{name.lower()}": (
                str(value) if isinstance(value, int) else _literal(float(value))
            )
            for name, value in (
                ("SMOOTHING", socp_sqp.SMOOTHING), ("STEP_TOLERANCE", socp_sqp.STEP_TOLERANCE),
                ("CONE_TOLERANCE", socp_sqp.CONE_TOLERANCE),
                ("MAX_ITERATIONS", socp_sqp.MAX_ITERATIONS),
                ("FULL_STEPS", socp_sqp.FULL_STEPS), ("PROXIMAL", socp_sqp.PROXIMAL),
                ("PROXIMAL_DECREASE", socp_sqp.PROXIMAL_DECREASE),
                ("PROXIMAL_FLOOR", socp_sqp.PROXIMAL_FLOOR), ("ARMIJO", socp_sqp.ARMIJO),
                ("DEFINITE_PIVOT", socp_sqp.DEFINITE_PIVOT),
                ("BACKTRACKS", socp_sqp.BACKTRACKS),
                ("SCREENING_MARGIN", socp_sqp.SCREENING_MARGIN),
                ("CUT_ROUNDS", socp_sqp.CUT_ROUNDS), ("CUT_FROM", socp_sqp.CUT_FROM),
                ("CUT_GROWTH", socp_sqp.CUT_GROWTH), ("CUT_TOLERANCE", socp_sqp.CUT_TOLERANCE),
                ("CUT_MARGIN", socp_sqp.CUT_MARGIN),
                ("REDUCTION_SCALE", socp_sqp.REDUCTION_SCALE),
                ("REDUCED_HESSIAN_LIMIT", socp_sqp.REDUCED_HESSIAN_LIMIT),
            )
        }  # fmt: skip
        values.update(constants)
        cone_values = dict(values)
        cone_values.update(
            P_f=_matrix(np.asarray(problem.terminal.P_f, dtype=np.float64)),
            P_root=_matrix(np.asarray(problem.terminal.square_root, dtype=np.float64)),
        )
        values["socp_declarations"] = socp_declaration(fields["prefix"], sizes)
        values["socp_members"] = (
            f"    {fields['prefix']}_socp socp[{len(SOCP_PROBLEMS)}];"
            "   /* the exact-cone problems: the nominal one, the policy's */\n"
        )
        values["cone_feedback_code"] = _template("socp.c.in").substitute(cone_values) + _template(
            "cone_feedback.c.in"
        ).substitute(cone_values)
    doubles = (N + 1) * (nx + m) + N * (2 * n + nx * (n + m)) + nx * m * N * (N + 1) // 2
    doubles += nu * nu + 2 * nu
    doubles += rows * nu + 2 * rows + 2 * (nu + rows)
    doubles += qp_n + qp_m + soft_n * soft_n + soft_n
    doubles += soft_rows * soft_n + 2 * (soft_n + soft_rows) + 5 * (qp_n + 1)
    doubles += (qp_n + 1) * (qp_n + 2) // 2 + 2 * qp_n + qp_m + qp_n * qp_rows + qp_rows
    doubles += 2 * qp_m + (qp_n + 1) * qp_n // 2 + qp_n + N * m + 2 * (N + 1) * nx
    doubles += max(N - 1, 1) * 5 * n
    ints = qp_m + (qp_n + 1) + qp_n + qp_m
    for _name, kind, length in SOCP_STRUCT if cones else ():
        count = socp_length(length, sizes) * len(SOCP_PROBLEMS)
        doubles += count if kind == "real" else 0
        ints += count if kind == "int" else 0
    bound = real_bytes * doubles + 4 * ints + model_bytes + 1024
    values["mpc_workspace_bytes"] = f"at most {bound}"
    return values, bound


def _controller_fields(controller: Any, fields: dict[str, str]) -> dict[str, str]:
    """The template fields of ``controller.h.in`` and ``controller.c.in``."""
    from ltv_lstm_mpc.loop.compiled_reference import U_MARGIN
    from ltv_lstm_mpc.loop.statuses import IMPLAUSIBLE_MEASUREMENT_LIMIT

    scaling = controller.scaling
    limit = controller.setpoint_rate_limit
    values = dict(fields)
    single = fields["single"] == "1"

    def row(name: str) -> str:
        return ", ".join(_literal(v) for v in np.ravel(getattr(scaling, name)))

    values.update(
        y_min=row("y_min"),
        y_scale=row("y_scale"),
        u_min=row("u_min"),
        u_scale=row("u_scale"),
        u_phi_low=row("u_phi_low"),
        u_phi_high=row("u_phi_high"),
        has_limiter="0" if limit is None else "1",
        rate_limit=_literal(_rate_limit(limit, single)),
        e_hat0=_literal(_float_below(_e_hat0(controller)) if single else _e_hat0(controller)),
        reuse_tol=_literal(_precision_value("reuse_tol", controller.mpc.reuse_tol, single)),
        implausible=_literal(IMPLAUSIBLE_MEASUREMENT_LIMIT),
        flag_implausible="1" if controller.implausible_measurements == "flag" else "0",
        u_margin=_literal(_precision_value("u_margin", U_MARGIN, single)),
    )
    return values


def _rate_limit(limit: float | None, single: bool) -> float:
    """The set-point rate limit as rendered (0: none); in single precision rounded down
    (the float limiter then steps back where its sum rounds past it: tightening.c.in)."""
    if limit is None:
        return 0.0
    return _float_below(float(limit)) if single else float(limit)


def _e_hat0(controller: Any) -> float:
    r""":math:`\hat e_{o,0}` of ``controller`` (``OffsetFreeController.reset``)."""
    e_hat0 = controller.config.e_hat0
    return float(controller.mpc.tightening.e_inf if e_hat0 is None else e_hat0)


#: The solvers of the MPCs the C export covers: DAQP on the terminal box, and the SQP of
#: ``daqp:socp`` on the exact cones.
EXPORTED_SOLVERS = ("daqp", "daqp:socp")


def mpc_refusal(mpc: Any, precision: str = "double") -> str | None:
    """Why the C export does not cover ``mpc`` (None: it does): the condensed problem on
    DAQP (:data:`EXPORTED_SOLVERS`; the exact cones in double precision only), one SQP
    iteration per step, the policy ``"paper"``, ``"soft"`` or ``"shift"``."""
    from ltv_lstm_mpc.mpc.rti import RobustMPC

    if not isinstance(mpc, RobustMPC):
        return f"mpc must be a RobustMPC, got {type(mpc).__name__}; pass controller.mpc"
    config = mpc.config
    if config.solver not in EXPORTED_SOLVERS or mpc.transcription != "condensed":
        return (
            f"the C export solves the condensed problem with DAQP ('daqp': the terminal box; "
            f"'daqp:socp': the exact cones); this MPC uses solver={config.solver!r} on the "
            f"{mpc.transcription} transcription: build the controller with "
            "MPCConfig(solver='daqp' or 'daqp:socp', transcription='condensed')"
        )
    if config.sqp_iterations != 1:
        return (
            f"the C export runs one convex subproblem per step (RTI); this MPC runs up to "
            f"{config.sqp_iterations} SQP iterations: use MPCConfig(sqp_iterations=1)"
        )
    if config.infeasibility_policy not in ("paper", "soft", "shift"):
        return (
            f"infeasibility_policy={config.infeasibility_policy!r} is not exported: use "
            "'paper', 'soft' or 'shift'"
        )
    if precision == "single" and config.solver == "daqp:socp":
        return (
            "the exact cones (solver='daqp:socp') are exported in double precision only: "
            "their SQP stops at steps of 1e-7 relative and cone violations of 1e-9, below "
            "float's resolution; export them with precision='double', or the terminal box "
            "(solver='daqp') in single precision"
        )
    return None


def daqp_refusal() -> str | None:
    """Why the installed DAQP is not the vendored release (None: it is): the exported
    controller would solve its QPs with other code than the library."""
    import importlib.metadata

    try:
        installed: str | None = importlib.metadata.version("daqp")
    except importlib.metadata.PackageNotFoundError:
        installed = None
    if installed == DAQP_VENDORED:
        return None
    return (
        f"the C export vendors DAQP {DAQP_VENDORED}, and the library runs DAQP "
        f"{installed or '(not installed)'}: the exported controller would solve its QPs with "
        f"other code than the Python one. Install it with pip install daqp=={DAQP_VENDORED}"
    )


def _single_margins(controller: Any) -> Any:
    """:func:`~ltv_lstm_mpc.export.precision.single_precision_margins` of ``controller``
    at the acceptance tolerance of its single-precision export."""
    from ltv_lstm_mpc.export.precision import single_precision_margins
    from ltv_lstm_mpc.solvers.tolerances import feasibility_tolerance

    tolerance = feasibility_tolerance("daqp", controller.mpc.config.tolerance)
    return single_precision_margins(controller, _precision_value("tolerance", tolerance, True))


def export_refusal(controller: Any, precision: str = "double") -> str | None:
    """Why ``controller`` cannot run as exported C on this machine (None: it can): the
    export's coverage (:func:`mpc_refusal`; the controller's own MPC), the DAQP release
    (:func:`daqp_refusal`), in single precision the certificates' margins
    (:mod:`~ltv_lstm_mpc.export.precision`), a C compiler on the PATH."""
    from ltv_lstm_mpc.export.sil import find_c_compiler

    if controller.custom_mpc:
        return "the controller runs an MPC given by the caller (mpc=...): not exported"
    reason = mpc_refusal(controller.mpc, precision) or daqp_refusal()
    if reason is None and precision == "single":
        reason = _single_margins(controller).refusal()
    if reason is not None:
        return reason
    if find_c_compiler() is None:
        return "no C compiler on the PATH (cc, gcc or clang): install one, e.g. gcc"
    return None


def _same_weights(other: LSTMModel, model: LSTMModel) -> bool:
    """``other`` is ``model`` or has its weights (a component built on it)."""
    return other is model or (
        np.array_equal(other.kernel.WU, model.kernel.WU)
        and np.array_equal(other.W_y, model.W_y)
        and np.array_equal(other.b_y, model.b_y)
    )
