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
    "CONE_FAILED",
    "CONE_MAX_ITER",
    "MPC_STATUS_NAMES",
    "POLICY_NAMES",
    "STEP_CODES",
    "CController",
    "FeedbackResult",
    "compile_controller",
    "find_c_compiler",
    "host_compiler",
    "socp_type",
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
#: ``<prefix>_STATUS_CONE_FAILED`` and ``<prefix>_STATUS_CONE_MAX_ITER`` (exact cones): the
#: nominal problem's SQP ended with a negative DAQP flag or ran out of iterations; the
#: library's status then comes from the certificate checks (:meth:`CController.cone_outcome`).
CONE_FAILED, CONE_MAX_ITER = -103, -104
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


def compile_controller(
    exported: Any, compiler: str | None = None, extra_flags: tuple[str, ...] = ()
) -> Path:
    """Build ``exported`` (an :class:`~ltv_lstm_mpc.export.c_model.ExportedC` with the
    controller step) into ``lib<prefix>.so`` next to its sources; returns its path.
    ``extra_flags`` follow the library's (e.g. ``-D<PREFIX>_TEST_FAULTS`` for the
    fault-injection tests)."""
    folder = exported.source.parent
    compiler = compiler or host_compiler()
    library = folder / f"lib{exported.prefix}_{Path(compiler).name}.so"
    command = [
        compiler, *BUILD_FLAGS, *precision_flags(exported, compiler), *extra_flags,
        "-fPIC", "-shared",
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
        ("linearization_gap", d), ("cone_flag", i), ("cone_sqp", i), ("cone_violation", d),
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


def socp_type(sizes: tuple[int, ...], precision: str = "double") -> type[ctypes.Structure]:
    """``<prefix>_socp`` of an export whose ``ExportedC.socp_sizes`` are ``sizes`` (from
    :data:`~ltv_lstm_mpc.export.socp_struct.SOCP_STRUCT`, as the C declaration)."""
    from ltv_lstm_mpc.export.socp_struct import SOCP_SIZE_KEYS, SOCP_STRUCT, socp_length

    named = dict(zip(SOCP_SIZE_KEYS, sizes, strict=True))
    fields = []
    for name, kind, length in SOCP_STRUCT:
        ctype = _real(precision) if kind == "real" else ctypes.c_int
        count = socp_length(length, named)
        fields.append((name, ctype if length == "1" else ctype * count))
    return type("Socp", (ctypes.Structure,), {"_fields_": fields})


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
        self._socp: Any = None
        self._cut_rounds = int(exported.socp_sizes[-1]) if exported.socp_sizes else 0
        if exported.socp_sizes:
            Socp = socp_type(exported.socp_sizes, precision)
            self._socp = getattr(lib, f"{prefix}_controller_socp")
            self._socp.argtypes = [ctypes.c_void_p, ctypes.c_int]
            self._socp.restype = ctypes.POINTER(Socp)
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

    def socp_arrays(self, which: int = 0) -> dict[str, Any]:
        """The exact-cone problem ``which`` (0: nominal, 1: the policy's;
        :data:`~ltv_lstm_mpc.export.socp_struct.SOCP_PROBLEMS`) as the C SQP left
        it: copies of its arrays at the problem's own sizes, shaped and named as the
        library's :func:`~ltv_lstm_mpc.solvers.socp_sqp.socp_arrays` (what
        :func:`~ltv_lstm_mpc.solvers.daqp_socp.failure_outcome` and the certificate checks
        read). Only for an export with the exact cones."""
        if self._socp is None:
            raise InvalidValueError("this export has no exact cones (solver='daqp:socp')")
        s = self._socp(self.state_buffer, which).contents
        n, m, cones = int(s.n), int(s.m), int(s.cones)
        rows = list(s.cone_rows)[: cones + 1]
        k = n + m + cones

        def take(name: str, *shape: int) -> NDArray[Any]:
            flat = np.ctypeslib.as_array(getattr(s, name))
            size = int(np.prod(shape))
            dtype = np.float64 if flat.dtype.kind == "f" else np.int64
            return np.array(flat[:size], dtype=dtype).reshape(shape)

        return {
            "H": take("H", n, n), "f": take("f", n), "A": take("A", m, n), "lb": take("lb", n),
            "ub": take("ub", n), "lo": take("lo", m), "up": take("up", m),
            "F": take("F", rows[-1], n), "g": take("g", rows[-1]),
            "cone_rows": np.array(rows, dtype=np.int64), "e": take("e", cones, n),
            "offsets": take("offsets", cones), "z": take("z", n), "mu": take("mu", cones),
            "lam": take("lam", k), "regularized": take("regularized", 2),
            "direction": take("direction", n), "first_active": take("first_active", cones),
            "cut_points": take("cut_points", self._cut_rounds, n),
            "cut_state": take("cut_state", 3),
        }  # fmt: skip

    def cone_outcome(self, feedback: Any, config: Any) -> tuple[str, str]:
        """The library's status and reason of a step whose nominal exact-cone SQP did not
        converge (``feedback.status`` :data:`CONE_FAILED` or :data:`CONE_MAX_ITER`): the
        certificate checks of :mod:`~ltv_lstm_mpc.solvers.socp_certificates` on the C
        SQP's problem and last iterate (:meth:`socp_arrays`), as the one-call engine reads
        its own when a record is read; ``config``: the controller's ``MPCConfig``."""
        from ltv_lstm_mpc.solvers.acceptance import ProblemView
        from ltv_lstm_mpc.solvers.daqp_socp import failure_outcome, snapshot_qp
        from ltv_lstm_mpc.solvers.socp_certificates import max_iter_status

        arrays = self.socp_arrays(0)
        if feedback.status == CONE_FAILED:
            outcome, reason = failure_outcome(
                arrays, int(feedback.cone_flag), int(feedback.cone_sqp), config.tolerance,
                dict(config.solver_settings),
            )  # fmt: skip
            return outcome.name.lower(), reason
        view = ProblemView.of_dense(snapshot_qp(arrays))
        outcome, reason, _certificate = max_iter_status(
            arrays, float(feedback.cone_violation), view
        )
        return outcome.name.lower(), reason

    def mpc_status(self, feedback: Any, config: Any) -> str:
        """The library's MPC status name of a step's ``feedback`` (``<prefix>_feedback_
        result``): :data:`MPC_STATUS_NAMES`, or :meth:`cone_outcome`'s."""
        if feedback.status in (CONE_FAILED, CONE_MAX_ITER):
            return self.cone_outcome(feedback, config)[0]
        return MPC_STATUS_NAMES[feedback.status]

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
