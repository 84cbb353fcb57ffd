r"""The exported C controller on the host, through ctypes (software in the loop).

:func:`compile_controller` builds an export of
:func:`~ltv_lstm_mpc.export.c_model.export_model_c` with ``controller=`` (``<prefix>.c`` and
DAQP's vendored sources, DAQP with ``no_heap.h``) into a shared library with the host's C
compiler; :class:`CController` calls its ``<prefix>_controller_step`` on one
``<prefix>_controller``, in physical units, with the step's record
(``<prefix>_step_record``) read into Python. ``experiments/export_sil.py`` replays the
library's closed loops through it; ``tests/test_export_step.py`` checks it.
"""

from __future__ import annotations

import ctypes
import functools
import shutil
import subprocess
import sys
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from ltv_lstm_mpc.exceptions import InvalidValueError

__all__ = [
    "MPC_STATUS_NAMES",
    "POLICY_NAMES",
    "STEP_CODES",
    "CController",
    "FeedbackResult",
    "compile_controller",
    "find_c_compiler",
    "host_compiler",
]

#: ``<prefix>_feedback_result.status`` codes and ``MPCSolution.status`` names.
MPC_STATUS_NAMES = {
    1: "optimal",
    2: "optimal_inaccurate",
    -1: "infeasible",
    -2: "failed",
    -3: "unbounded",
    -4: "max_iter",
    -5: "failed",
    -6: "failed",
    -100: "infeasible_initial",
    -101: "alpha_nonpositive",
    -102: "failed",
}
#: ``<prefix>_feedback_result.policy`` codes (``MPCSolution.policy``).
POLICY_NAMES = ("nominal", "paper", "soft", "shift", "paper+shift", "soft+shift")
#: ``<prefix>_controller_step``'s return codes.
STEP_CODES = ("ok", "bad_measurement", "bad_setpoint", "unreachable")

#: The flags the library builds with: strict C99, and no fused multiply-add (the library's
#: kernels round each product, docs/user-guide/export-c.md).
BUILD_FLAGS = ("-std=c99", "-O2", "-Wall", "-Wextra", "-Wpedantic", "-Werror")


def find_c_compiler() -> str | None:
    """The first of ``cc``, ``gcc``, ``clang`` on the PATH (None: none)."""
    return next((name for name in ("cc", "gcc", "clang") if shutil.which(name)), None)


def host_compiler() -> str:
    """:func:`find_c_compiler`, or an error that says what to install."""
    found = find_c_compiler()
    if found is not None:
        return found
    raise InvalidValueError(
        "no C compiler on the PATH (cc, gcc or clang): install one, e.g. "
        "`apt-get install gcc`, to run the exported controller on the host"
    )


def daqp_flags(folder: Path) -> list[str]:
    """The compiler flags of DAQP's sources in an export's ``folder``: ``no_heap.h`` forced
    in, its headers on the include path."""
    daqp = folder / "daqp"
    return ["-include", str(daqp / "no_heap.h"), "-I", str(daqp / "include")]


def daqp_sources(folder: Path) -> list[str]:
    """DAQP's C sources in an export's ``folder``, sorted."""
    return sorted(str(path) for path in (folder / "daqp" / "src").glob("*.c"))


@functools.cache
def _is_gcc(compiler: str) -> bool:
    """Whether ``compiler`` is gcc (``cc`` may be): it takes gcc's own flags."""
    done = subprocess.run([compiler, "--version"], capture_output=True, text=True)
    return done.returncode == 0 and "Free Software Foundation" in done.stdout


def precision_flags(exported: Any, compiler: str) -> list[str]:
    """The flags of a single-precision export's build with ``compiler``: with gcc,
    ``-fsingle-precision-constant`` (DAQP's double literals as float, as on the target,
    :data:`~ltv_lstm_mpc.export.pil.CORTEX_M4F_FLAGS`); none otherwise."""
    return ["-fsingle-precision-constant"] if exported.single and _is_gcc(compiler) else []


def _own_symbols() -> list[str]:
    """On ELF hosts, the library's calls bound to its own definitions: the process already
    holds DAQP (the ``daqp`` package's build, in double precision), whose exported
    functions would otherwise take the calls of the vendored copy (``-Bsymbolic``)."""
    return ["-Wl,-Bsymbolic"] if sys.platform.startswith(("linux", "freebsd")) else []


def compile_controller(exported: Any, compiler: str | None = None) -> Path:
    """Build ``exported`` (an :class:`~ltv_lstm_mpc.export.c_model.ExportedC` with the
    controller step) into ``lib<prefix>.so`` next to its sources; returns its path."""
    folder = exported.source.parent
    compiler = compiler or host_compiler()
    library = folder / f"lib{exported.prefix}_{Path(compiler).name}.so"
    command = [
        compiler, *BUILD_FLAGS, *precision_flags(exported, compiler), "-fPIC", "-shared",
        *_own_symbols(), *daqp_flags(folder),
        "-o", str(library), str(exported.source), *daqp_sources(folder), "-lm",
    ]  # fmt: skip
    done = subprocess.run(command, capture_output=True, text=True)
    if done.returncode:
        raise InvalidValueError(f"{' '.join(command)} failed:\n{done.stderr[-3000:]}")
    return library


def _real(precision: str) -> Any:
    """The ctypes type of ``<prefix>_real``."""
    return ctypes.c_float if precision == "single" else ctypes.c_double


def _feedback_type(precision: str = "double") -> type[ctypes.Structure]:
    """``<prefix>_feedback_result``: the MPC's outcome of a step."""
    d, i = _real(precision), ctypes.c_int
    fields = [
        ("status", i), ("policy", i), ("iterations", i), ("qp_iterations", i),
        ("sqp_step", d), ("cost", d), ("terminal_norm", d), ("output_violation", d),
        ("linearization_gap", d),
    ]  # fmt: skip
    return type("FeedbackResult", (ctypes.Structure,), {"_fields_": fields})


#: ``<prefix>_feedback_result`` of a double-precision export.
FeedbackResult = _feedback_type()


def _record_type(n: int, m: int, p: int, precision: str = "double") -> type[ctypes.Structure]:
    """``<prefix>_step_record`` for a model of n units, m inputs and p outputs."""
    d, i = _real(precision), ctypes.c_int
    FeedbackResult = _feedback_type(precision)
    fields = [
        ("y", d * p), ("y0", d * p), ("u", d * m), ("x_hat", d * (2 * n)), ("d_hat", d * p),
        ("e_hat", d), ("x_bar", d * (2 * n)), ("u_bar", d * m), ("alpha", d),
        ("input_clipped", d), ("measurement_status", i), ("setpoint_status", i),
        ("reference_status", i), ("u_bar_projected", i), ("mpc", FeedbackResult),
    ]  # fmt: skip
    return type("StepRecord", (ctypes.Structure,), {"_fields_": fields})


class CController:
    """One exported controller (``<prefix>_controller``) in a library of
    :func:`compile_controller`.

    Parameters
    ----------
    library : Path
        The shared library.
    exported : ExportedC
        What the export wrote (prefix, sizes, n, m, p).
    """

    def __init__(self, library: Path, exported: Any) -> None:
        lib = ctypes.CDLL(str(library))
        prefix = exported.prefix
        self.m, self.p = exported.m, exported.p
        precision = exported.precision
        #: The numpy type of ``<prefix>_real``.
        self.dtype = np.float32 if exported.single else np.float64
        real = _real(precision)
        self.Record = _record_type(exported.n, exported.m, exported.p, precision)
        size = getattr(lib, f"{prefix}_controller_size")
        size.argtypes, size.restype = [], ctypes.c_size_t
        self.state_buffer = ctypes.create_string_buffer(int(size()))
        self._init = getattr(lib, f"{prefix}_controller_init")
        self._init.argtypes, self._init.restype = [ctypes.c_void_p], None
        pointer = np.ctypeslib.ndpointer(dtype=self.dtype, flags="C_CONTIGUOUS")
        self._step = getattr(lib, f"{prefix}_controller_step")
        self._step.argtypes = [
            ctypes.c_void_p, pointer, pointer, pointer, ctypes.POINTER(self.Record),
        ]  # fmt: skip
        self._step.restype = ctypes.c_int
        self._state = getattr(lib, f"{prefix}_controller_state")
        self._state.argtypes = [ctypes.c_void_p, pointer, pointer, ctypes.POINTER(real)]
        self._state.restype = None
        self._plan = getattr(lib, f"{prefix}_controller_plan")
        self._plan.argtypes = [ctypes.c_void_p, pointer, pointer, pointer]
        self._plan.restype = None
        self.N, self.nx = exported.horizon, 2 * exported.n
        self.library = lib
        self.reset()

    def reset(self) -> None:
        """Back to before the first step."""
        self._init(self.state_buffer)

    def step(self, y_phi: ArrayLike, y0_phi: ArrayLike) -> tuple[int, NDArray[np.float64], Any]:
        """One sample: ``(code, u_phi, record)`` (code: an index of :data:`STEP_CODES`;
        ``y_phi``, ``y0_phi`` rounded to ``<prefix>_real``, ``u_phi`` as float64)."""
        u_phi = np.zeros(self.m, dtype=self.dtype)
        record = self.Record()
        code = self._step(
            self.state_buffer,
            np.ascontiguousarray(y_phi, dtype=self.dtype).reshape(self.p),
            np.ascontiguousarray(y0_phi, dtype=self.dtype).reshape(self.p),
            u_phi,
            ctypes.byref(record),
        )
        return int(code), u_phi.astype(np.float64, copy=False), record

    def state(self) -> tuple[NDArray[np.float64], NDArray[np.float64], float]:
        r"""The estimates the next step starts from and its :math:`\hat e_o`."""
        x_hat, d_hat = np.zeros(self.nx, self.dtype), np.zeros(self.p, self.dtype)
        e_hat = self._state.argtypes[3]._type_()
        self._state(self.state_buffer, x_hat, d_hat, ctypes.byref(e_hat))
        return (
            x_hat.astype(np.float64, copy=False),
            d_hat.astype(np.float64, copy=False),
            float(e_hat.value),
        )

    def plan(self) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
        """The last plan: inputs (N, m), re-simulated and linearized states (N + 1, 2n)."""
        u = np.zeros((self.N, self.m), self.dtype)
        x_plan = np.zeros((self.N + 1, self.nx), self.dtype)
        x_linear = np.zeros((self.N + 1, self.nx), self.dtype)
        self._plan(self.state_buffer, u, x_plan, x_linear)
        f64 = np.float64
        return (
            u.astype(f64, copy=False),
            x_plan.astype(f64, copy=False),
            x_linear.astype(f64, copy=False),
        )
