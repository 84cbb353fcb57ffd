r"""Software and processor in the loop for the C export: recorded closed loops replayed
through the exported observer (eq. (lstm_observer)) and through the whole controller step,
on the host and on a Cortex-M7.

:func:`write_observer_replay` renders a ``pil_main.c`` that feeds the loop's measurements
and inputs through ``<prefix>_observer_update`` and prints the estimates (each double's
bits), a start-up file and a linker script for QEMU's ``mps2-an500`` board (a Cortex-M7
with a double-precision FPU). :func:`run_host` builds and runs it with the host's C
compiler (software in the loop); :func:`run_pil` cross-compiles it with
``arm-none-eabi-gcc -mcpu=cortex-m7 -mfpu=fpv5-d16 -mfloat-abi=hard`` and runs it on
``qemu-system-arm -M mps2-an500 -semihosting`` (processor in the loop), which also reports
the stack the updates used (measured: a painted region) and the sizes of the exported
code's sections (``arm-none-eabi-size``).

:func:`write_step_replay`, :func:`run_step_host` and :func:`run_step_pil` do the same for
``<prefix>_controller_step`` (an export with ``controller=``; DAQP's sources built with
``no_heap.h``): the measurements and set-points of a loop in, the inputs (bits), return
codes, MPC statuses and policies out; on the target also the flash of the export's own
symbols in the linked program, ``sizeof(<prefix>_controller)``, the stack, and with
``count_instructions`` the instructions of each step. They are counted from QEMU's
instruction trace: with ``-singlestep`` each translation block is one instruction and
``-d exec,nochain`` logs each one executed, with its function's name; the replay calls
``pil_mark(k)`` (through a volatile pointer, never inlined) before step k, and the lines
between marks are the step's instructions (deterministic; QEMU's virtual clock under
``-icount``, read with semihosting's ``SYS_ELAPSED``, varied up to 1.8x between runs on
this machine). Instructions are not cycles: a time from them is an estimate.

The toolchain: Debian's ``gcc-arm-none-eabi``, ``libnewlib-arm-none-eabi`` and
``qemu-system-arm`` (:func:`find_toolchain` says what is missing). The facts this rests on
(booting the board, enabling the FPU before the first floating-point instruction, linking
``.data`` straight into RAM) are in ``docs/user-guide/export-c.md``.
"""

from __future__ import annotations

import shutil
import subprocess
from dataclasses import dataclass
from importlib import resources
from pathlib import Path
from string import Template
from typing import Any

import numpy as np

from ltv_lstm_mpc.exceptions import InvalidValueError
from ltv_lstm_mpc.export.c_model import ExportedC, _literal, _matrix, _single_precision
from ltv_lstm_mpc.export.sil import daqp_flags, daqp_sources, precision_flags

__all__ = [
    "CORTEX_M4F_FLAGS",
    "CORTEX_M7_FLAGS",
    "TARGETS",
    "ReplayResult",
    "StepReplayResult",
    "Target",
    "Toolchain",
    "find_toolchain",
    "run_host",
    "run_pil",
    "run_step_host",
    "run_step_pil",
    "target_of",
    "write_observer_replay",
    "write_step_replay",
]

#: The Cortex-M7 build: double-precision FPU, hard-float calling convention, Thumb.
CORTEX_M7_FLAGS = ("-mcpu=cortex-m7", "-mfpu=fpv5-d16", "-mfloat-abi=hard", "-mthumb")
#: The Cortex-M4F build (an export in single precision): single-precision FPU, hard-float
#: calling convention, Thumb; DAQP's double literals as float (gcc's
#: ``-fsingle-precision-constant``, which the host build of the comparison takes too).
CORTEX_M4F_FLAGS = (
    "-mcpu=cortex-m4", "-mfpu=fpv4-sp-d16", "-mfloat-abi=hard", "-mthumb",
    "-fsingle-precision-constant",
)  # fmt: skip


@dataclass(frozen=True)
class Target:
    """A processor of the PIL check: its name, compiler flags, QEMU board and the clock of
    a typical part (for a time estimate from instructions: one per cycle)."""

    name: str
    flags: tuple[str, ...]
    board: str
    clock_mhz: float


#: The targets: a Cortex-M7 (double precision) on QEMU's ``mps2-an500``, a Cortex-M4F
#: (single precision) on ``mps2-an386``.
TARGETS = {
    "double": Target("Cortex-M7", CORTEX_M7_FLAGS, "mps2-an500", 600.0),
    "single": Target("Cortex-M4F", CORTEX_M4F_FLAGS, "mps2-an386", 168.0),
}


def target_of(exported: ExportedC) -> Target:
    """The PIL target of ``exported``'s precision: a Cortex-M7 for double, a Cortex-M4F (no
    double-precision FPU) for single."""
    return TARGETS[exported.precision]


#: The C dialect and warnings of every build of the exported code.
STRICT_FLAGS = ("-std=c99", "-O2", "-Wall", "-Wextra", "-Wpedantic", "-Werror")


@dataclass(frozen=True)
class Toolchain:
    """The cross compiler, its ``size`` and QEMU (absolute paths)."""

    gcc: str
    size: str
    qemu: str


def find_toolchain() -> Toolchain | None:
    """The Cortex-M7 toolchain on PATH, or None when a part is missing (install Debian's
    ``gcc-arm-none-eabi libnewlib-arm-none-eabi qemu-system-arm``)."""
    parts = [shutil.which(name) for name in ("arm-none-eabi-gcc", "arm-none-eabi-size")]
    qemu = shutil.which("qemu-system-arm")
    if parts[0] is None or parts[1] is None or qemu is None:
        return None
    return Toolchain(gcc=parts[0], size=parts[1], qemu=qemu)


@dataclass(frozen=True)
class ReplayResult:
    """The estimates of a replay and, on the target, what it cost.

    Attributes
    ----------
    estimates : ndarray, shape (K, 2n + p)
        :math:`(\\hat x_k, \\hat d_k)` after each of the K updates.
    stack_bytes : int or None
        Stack the updates used (measured on the target; None on the host).
    sections : dict or None
        ``text``, ``rodata``, ``data``, ``bss`` bytes of the exported ``<prefix>.c``
        compiled for the target (``-O2``); None on the host.
    """

    estimates: Any
    stack_bytes: int | None = None
    sections: dict[str, int] | None = None


def _render(name: str, fields: dict[str, str]) -> str:
    text = resources.files("ltv_lstm_mpc.export").joinpath("templates", name).read_text()
    return Template(text).substitute(fields)


def write_observer_replay(
    exported: ExportedC,
    x_hat0: Any,
    d_hat0: Any,
    y: Any,
    u: Any,
) -> Path:
    r"""Render the replay of ``K`` observer updates next to ``exported``'s files.

    Parameters
    ----------
    exported : ExportedC
        From :func:`~ltv_lstm_mpc.export.c_model.export_model_c` with an observer.
    x_hat0 : array_like, shape (2n,)
    d_hat0 : array_like, shape (p,)
        The estimate before the first update.
    y : array_like, shape (K, p)
    u : array_like, shape (K, m)
        Measurements :math:`y_k` and applied inputs :math:`u_k`, normalized.

    Returns
    -------
    Path
        ``pil_main.c`` (with ``pil_startup.c`` and ``pil.ld`` beside it; one replay per
        folder: a second one replaces them).
    """
    source = exported.source.read_text()
    if "_observer_update(" not in source:
        raise InvalidValueError(
            f"{exported.source} has no observer update: export with "
            "export_model_c(model, out_dir, observer=controller.observer)"
        )
    if exported.single:
        raise InvalidValueError(
            "the observer replay runs double-precision exports: replay the whole step of a "
            "single-precision one (write_step_replay, run_step_pil)"
        )
    n, m, p = exported.n, exported.m, exported.p
    Y = np.asarray(y, dtype=np.float64)
    U = np.asarray(u, dtype=np.float64)
    Y = Y.reshape(-1, p) if Y.ndim == 1 and p == 1 else Y
    U = U.reshape(-1, m) if U.ndim == 1 and m == 1 else U
    if Y.ndim != 2 or U.ndim != 2 or Y.shape[1] != p or U.shape[1] != m:
        raise InvalidValueError(
            f"y has shape {Y.shape} and u {U.shape}: pass y as (K, {p}) and u as (K, {m}) "
            "(one row per step)"
        )
    if Y.shape[0] != U.shape[0] or Y.shape[0] < 1:
        raise InvalidValueError(
            f"y has {Y.shape[0]} rows and u {U.shape[0]}: pass one row of each per step (K >= 1)"
        )
    x_first = np.ravel(np.asarray(x_hat0, dtype=np.float64))
    d_first = np.ravel(np.asarray(d_hat0, dtype=np.float64))
    if x_first.shape != (2 * n,) or d_first.shape != (p,):
        raise InvalidValueError(
            f"x_hat0 has {x_first.size} values and d_hat0 {d_first.size}: pass {2 * n} and "
            f"{p} (the state [c; h] and the disturbance estimate)"
        )
    if not (np.all(np.isfinite(Y)) and np.all(np.isfinite(U))):
        raise InvalidValueError("y and u must be finite: replay a recorded loop's signals")
    fields = {
        "x_hat0": ", ".join(_literal(v) for v in x_first),
        "d_hat0": ", ".join(_literal(v) for v in d_first),
        "Y": _matrix(Y),
        "U": _matrix(U),
    }
    return _write_replay(exported, "pil_observer_main.c.in", "pil_main.c", Y.shape[0], fields)


def _write_replay(
    exported: ExportedC, template: str, name: str, steps: int, fields: dict[str, str]
) -> Path:
    """Render ``template`` as ``name`` next to ``exported``'s files with ``fields`` and the
    common ones, and the target's start-up code and linker script beside it."""
    from ltv_lstm_mpc import __version__

    fields = {
        "prefix": exported.prefix,
        "PREFIX": exported.prefix.upper(),
        "version": __version__,
        "steps": str(steps),
        **fields,
    }
    folder = exported.source.parent
    main = folder / name
    main.write_text(_render(template, fields))
    (folder / "pil_startup.c").write_text(_render("pil_startup.c.in", fields))
    (folder / "pil.ld").write_text(_render("pil.ld.in", fields))
    return main


def _run(command: list[str], timeout: float, what: str, output: Path | None = None) -> str:
    """Run ``command``; its standard output (through the file ``output`` where given: QEMU
    writes the replay's lines there, a regular file, which never refuses a write as a full
    pipe can)."""
    if output is None:
        done = subprocess.run(command, capture_output=True, text=True, timeout=timeout)
        stdout = done.stdout
    else:
        with output.open("w") as handle:
            done = subprocess.run(command, stdout=handle, stderr=subprocess.PIPE, text=True,
                                  timeout=timeout)  # fmt: skip
        stdout = output.read_text()
    if done.returncode != 0:
        raise RuntimeError(
            f"{what} failed (exit {done.returncode}): {' '.join(command)}\n"
            f"{stdout[-2000:]}{done.stderr[-2000:]}"
        )
    return stdout


def _estimates(output: str) -> Any:
    rows = [line.split()[1:] for line in output.splitlines() if line.startswith("x ")]
    bits = np.array([[int(word, 16) for word in row] for row in rows], dtype=np.uint64)
    return bits.view(np.float64)


def run_host(
    main: Path, exported: ExportedC, compiler: str = "gcc", timeout: float = 120.0
) -> ReplayResult:
    """Build the replay with the host's ``compiler`` (the strict flags) and run it."""
    folder = main.parent
    binary = folder / "pil_host"
    _run(
        [compiler, *STRICT_FLAGS, "-o", str(binary), str(main), str(exported.source), "-lm"],
        timeout,
        f"building the replay with {compiler}",
    )
    return ReplayResult(estimates=_estimates(_run([str(binary)], timeout, "the host replay")))


def run_pil(
    main: Path, exported: ExportedC, toolchain: Toolchain, timeout: float = 300.0
) -> ReplayResult:
    """Cross-compile the replay for the Cortex-M7 and run it on QEMU (module docstring)."""
    folder = main.parent
    elf = folder / "pil.elf"
    _run(
        [
            toolchain.gcc, *STRICT_FLAGS, *CORTEX_M7_FLAGS, "--specs=rdimon.specs",
            "-T", str(folder / "pil.ld"), "-o", str(elf), str(folder / "pil_startup.c"),
            str(main), str(exported.source), "-lm",
        ],
        timeout,
        "cross-compiling the replay (arm-none-eabi-gcc)",
    )  # fmt: skip
    output = _run(_qemu(toolchain, elf), timeout,
                  "running the replay on QEMU (mps2-an500, Cortex-M7)",
                  folder / "pil_output.txt")  # fmt: skip
    obj = folder / f"{exported.prefix}_m7.o"
    _run(
        [toolchain.gcc, *STRICT_FLAGS, *CORTEX_M7_FLAGS, "-c", "-o", str(obj),
         str(exported.source)],
        timeout,
        "compiling the exported code for the Cortex-M7",
    )  # fmt: skip
    sections = {"text": 0, "rodata": 0, "data": 0, "bss": 0}
    for line in _run([toolchain.size, "-A", str(obj)], timeout, "arm-none-eabi-size").splitlines():
        parts = line.split()
        if len(parts) >= 2 and parts[0].startswith("."):
            kind = parts[0][1:].split(".")[0]
            if kind in sections:
                sections[kind] += int(parts[1])
    return ReplayResult(
        estimates=_estimates(output),
        stack_bytes=_stack(output),
        sections=sections,
    )


@dataclass(frozen=True)
class StepReplayResult:
    """What a replay of the controller step printed.

    Attributes
    ----------
    u_phi : ndarray (K, m)
        The inputs, bit for bit.
    codes : ndarray (K, 3)
        Per step: the return code, the MPC's status and policy.
    stack_bytes : int or None
        The stack the steps used (target only).
    instructions : ndarray (K,) or None
        Instructions executed per step (target only, when counted).
    sections : dict or None
        Flash and RAM of the controller's code and data in the linked target program,
        bytes: ``text``, ``rodata``, ``data``, ``bss`` (the harness's own excluded; the
        controller struct the harness declares is ``controller_bytes``).
    controller_bytes : int or None
        ``sizeof(<prefix>_controller)`` on the target.
    seconds : ndarray (K,) or None
        Each step's wall time on the host (the best of the replays timed).
    """

    u_phi: Any
    codes: Any
    stack_bytes: int | None = None
    instructions: Any = None
    sections: dict[str, int] | None = None
    controller_bytes: int | None = None
    seconds: Any = None


def write_step_replay(exported: ExportedC, y_phi: Any, y0_phi: Any) -> Path:
    r"""Render the replay of ``K`` controller steps next to ``exported``'s files.

    Parameters
    ----------
    exported : ExportedC
        From :func:`~ltv_lstm_mpc.export.c_model.export_model_c` with ``controller=``.
    y_phi, y0_phi : array_like, shape (K, p)
        The measurements and requested set-points, physical units (a recorded loop's).

    Returns
    -------
    Path
        ``pil_step_main.c`` (with ``pil_startup.c`` and ``pil.ld`` beside it).
    """
    if "_controller_step(" not in exported.source.read_text():
        raise InvalidValueError(
            f"{exported.source} has no controller step: export with "
            "export_model_c(model, out_dir, controller=controller)"
        )
    p = exported.p
    Y = np.asarray(y_phi, dtype=np.float64).reshape(-1, p)
    Y0 = np.asarray(y0_phi, dtype=np.float64).reshape(-1, p)
    if Y.shape != Y0.shape or Y.shape[0] < 1:
        raise InvalidValueError(
            f"y_phi has {Y.shape[0]} rows and y0_phi {Y0.shape[0]}: pass one row of each "
            f"per step, {p} values each"
        )
    fields = {"Y": _matrix(Y), "Y0": _matrix(Y0)}
    if exported.single:  # (the data as float literals)
        fields = {name: _single_precision(value) for name, value in fields.items()}
    return _write_replay(exported, "pil_step_main.c.in", "pil_step_main.c", Y.shape[0], fields)


def _step_sources(main: Path, exported: ExportedC) -> list[str]:
    return [str(main), str(exported.source), *daqp_sources(exported.source.parent)]


def _daqp_flags(exported: ExportedC) -> list[str]:
    return daqp_flags(exported.source.parent)


def _qemu(toolchain: Toolchain, elf: Path, board: str = "mps2-an500") -> list[str]:
    """QEMU's MPS2 ``board`` (default: the Cortex-M7's) running ``elf`` with semihosting."""
    return [toolchain.qemu, "-M", board, "-nographic", "-semihosting", "-kernel", str(elf)]


def _stack(output: str) -> int | None:
    """The stack a replay reported (its ``stack`` line; None: none)."""
    found = [int(line.split()[1]) for line in output.splitlines() if line.startswith("stack ")]
    return found[0] if found else None


def _step_outcome(output: str, m: int, single: bool = False) -> tuple[Any, Any]:
    """The inputs (float64; from a float's bits in single precision) and codes printed."""
    rows = [line.split()[1:] for line in output.splitlines() if line.startswith("u ")]
    kind = np.uint32 if single else np.uint64
    bits = np.array([[int(word, 16) for word in row[:m]] for row in rows], dtype=kind)
    codes = np.array([[int(word) for word in row[m:]] for row in rows], dtype=np.int64)
    values = bits.view(np.float32 if single else np.float64)
    return values.astype(np.float64), codes


def run_step_host(
    main: Path,
    exported: ExportedC,
    compiler: str = "gcc",
    timeout: float = 300.0,
    *,
    timing_repeats: int = 0,
    cflags: tuple[str, ...] = (),
) -> StepReplayResult:
    """Build the step replay with the host's ``compiler`` (the strict flags, then
    ``cflags``, e.g. ``("-O3",)``) and run it; with ``timing_repeats`` > 0 (a POSIX host),
    also each step's wall time, the best of that many replays (``seconds``)."""
    binary = main.parent / "pil_step_host"
    cflags = (*precision_flags(exported, compiler), *cflags)  # (the target's constants)
    timing = (
        [f"-DPIL_TIMING={int(timing_repeats)}", "-D_POSIX_C_SOURCE=199309L"]
        if timing_repeats > 0
        else []
    )
    _run(
        [compiler, *STRICT_FLAGS, *cflags, *timing, *_daqp_flags(exported), "-o", str(binary),
         *_step_sources(main, exported), "-lm"],
        timeout,
        f"building the step replay with {compiler}",
    )  # fmt: skip
    output = _run([str(binary)], timeout, "the host replay")
    u_phi, codes = _step_outcome(output, exported.m, exported.single)
    seconds = None
    if timing_repeats > 0:
        seconds = np.array([float(line.split()[1]) for line in output.splitlines()
                            if line.startswith("t ")])  # fmt: skip
    return StepReplayResult(u_phi=u_phi, codes=codes, seconds=seconds)


def _count_instructions(command: list[str], steps: int, timeout: float) -> Any:
    """Instructions between the replay's ``pil_mark`` calls: QEMU with ``-singlestep``
    (one instruction per translation block) and ``-d exec,nochain`` logs one line per
    instruction executed, named by its function; the lines are counted as they stream."""
    process = subprocess.Popen(
        [*command, "-singlestep", "-d", "exec,nochain", "-D", "/dev/stderr"],
        stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True,
    )  # fmt: skip
    assert process.stderr is not None
    marks: list[int] = []
    count, previous = 0, ""
    try:
        for line in process.stderr:
            if not line.startswith("Trace"):
                continue
            count += 1
            name = line.rstrip().rsplit(" ", 1)[-1]
            if name == "pil_mark" and previous != "pil_mark":
                marks.append(count)
            previous = name
        process.wait(timeout=timeout)
    finally:
        if process.poll() is None:
            process.kill()
    if len(marks) != steps + 1:
        raise RuntimeError(f"the instruction trace has {len(marks)} marks, expected {steps + 1}")
    return np.diff(np.array(marks, dtype=np.int64))


def run_step_pil(
    main: Path,
    exported: ExportedC,
    toolchain: Toolchain,
    *,
    count_instructions: bool = False,
    timeout: float = 600.0,
) -> StepReplayResult:
    """Cross-compile the step replay for its target (:func:`target_of`: a Cortex-M7 for
    double, a Cortex-M4F for single precision) and run it on QEMU; with
    ``count_instructions``, run it a second time under QEMU's instruction trace and count
    the instructions of each step (module docstring; about 1 s per million instructions
    here, so replay a few dozen steps for it)."""
    folder = main.parent
    target = target_of(exported)
    flags = [*STRICT_FLAGS, *target.flags, "-ffunction-sections", "-fdata-sections"]
    elf = folder / "pil_step.elf"
    link = [toolchain.gcc, *flags, *_daqp_flags(exported), "--specs=rdimon.specs",
            "-Wl,--gc-sections", "-T", str(folder / "pil.ld")]  # fmt: skip
    _run(
        [*link, "-o", str(elf), str(folder / "pil_startup.c"), *_step_sources(main, exported),
         "-lm"],
        timeout,
        "cross-compiling the step replay (arm-none-eabi-gcc)",
    )  # fmt: skip
    qemu = _qemu(toolchain, elf, target.board)
    output = _run(qemu, timeout, f"running the step replay on QEMU ({target.board})",
                  folder / "pil_step_output.txt")  # fmt: skip
    u_phi, codes = _step_outcome(output, exported.m, exported.single)
    instructions = None
    if count_instructions:
        instructions = _count_instructions(qemu, u_phi.shape[0], timeout)
    sections, controller = _controller_sections(elf, exported, toolchain, timeout)
    return StepReplayResult(
        u_phi=u_phi, codes=codes, stack_bytes=_stack(output),
        instructions=instructions, sections=sections, controller_bytes=controller,
    )  # fmt: skip


def _controller_sections(
    elf: Path, exported: ExportedC, toolchain: Toolchain, timeout: float
) -> tuple[dict[str, int], int | None]:
    """The linked program's symbols that come from the export (the controller's source and
    DAQP's), summed by section kind; and the size of the harness's controller struct."""
    nm = str(Path(toolchain.size).with_name(Path(toolchain.size).name.replace("size", "nm")))
    listing = _run([nm, "-S", "--size-sort", str(elf)], timeout, "arm-none-eabi-nm")
    harness = {"main", "pil_mark", "print_bits", "stack_pointer", "pil_reset", "Y_PHI",
               "Y0_PHI", "controller", "record", "inputs", "outcome", "marked", "mark"}  # fmt: skip
    kinds = {"t": "text", "r": "rodata", "d": "data", "b": "bss"}
    sections = {"text": 0, "rodata": 0, "data": 0, "bss": 0}
    exported_symbols = set()
    folder = exported.source.parent
    for source in [exported.source, *map(Path, daqp_sources(folder))]:
        obj = folder / (source.stem + "_m7_symbols.o")
        _run([toolchain.gcc, *STRICT_FLAGS, *target_of(exported).flags, *_daqp_flags(exported),
              "-c", "-o", str(obj), str(source)], timeout,
             "compiling for the symbol list")  # fmt: skip
        names = _run([nm, "--defined-only", str(obj)], timeout, "arm-none-eabi-nm")
        exported_symbols |= {line.split()[-1] for line in names.splitlines() if line.strip()}
    controller = None
    for line in listing.splitlines():
        parts = line.split()
        if len(parts) != 4:
            continue
        size, kind, name = int(parts[1], 16), parts[2].lower(), parts[3]
        if name == "controller":
            controller = size
        if name in harness or kind not in kinds:
            continue
        base = name.split(".")[0]
        if name in exported_symbols or base in exported_symbols:
            sections[kinds[kind]] += size
    return sections, controller
