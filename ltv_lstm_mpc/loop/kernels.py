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
    A background compile that failed is not started again for the same sources and
    kernels: the next runs warn once (a ``RuntimeWarning`` naming the log's last line and
    the log file, kept in one folder, :func:`failure_folder`) and run the numpy reference;
    an edit of the package's sources allows one new attempt.
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

import contextlib
import copy
import hashlib
import json
import os
import pickle
import shutil
import subprocess
import sys
import tempfile
from collections.abc import Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import IO, TYPE_CHECKING, Any

from ltv_lstm_mpc import numba_support
from ltv_lstm_mpc.exceptions import InvalidValueError
from ltv_lstm_mpc.numba_support import AVAILABLE, load_cached, uncached

if TYPE_CHECKING:  # pragma: no cover
    from ltv_lstm_mpc.lstm.model import LSTMModel
    from ltv_lstm_mpc.mpc.config import MPCConfig

__all__ = [
    "KERNEL_MODES",
    "PREPARED_STEP_KERNELS",
    "CompileFailure",
    "choose_kernels",
    "compile_failure",
    "compile_lock",
    "controller_kernels",
    "failure_folder",
    "forget_failure",
    "load_kernels",
    "record_failure",
    "start_background_compile",
    "use_kernels",
]

#: The values of ``OffsetFreeController(..., kernels=...)``.
KERNEL_MODES = ("auto", "compiled", "numpy")

_ENVIRONMENT = "LTV_LSTM_MPC_KERNEL"


def controller_kernels(config: MPCConfig, *, native_feedback: bool = True) -> list[Any]:
    """The numba-compiled functions an ``OffsetFreeController`` with ``config`` calls on a
    compiled kernel: the MPC's (:func:`~ltv_lstm_mpc.mpc.kernels.compiled_kernels`), the
    observer update and the reference calculator's chord Newton and damped Newton with
    restarts, with the constructors of
    their workspaces; and the one-call step (:mod:`ltv_lstm_mpc.loop.compiled_step`) where
    the one-call feedback runs."""
    from ltv_lstm_mpc.loop import compiled_observer, compiled_reference
    from ltv_lstm_mpc.mpc.kernels import compiled_kernels

    kernels = [
        *compiled_kernels(config, native_feedback=native_feedback),
        compiled_observer.observer_update, *compiled_observer.CONSTRUCTORS,
        compiled_reference.chord_newton, compiled_reference.newton_restarts,
        *compiled_reference.CONSTRUCTORS,
    ]  # fmt: skip
    names = {getattr(kernel, "__name__", "") for kernel in kernels}
    if names & {"nominal_feedback", "cone_feedback"}:
        from ltv_lstm_mpc.loop import compiled_step  # the one-call step builds on them
        from ltv_lstm_mpc.mpc import native_feedback as one_call_feedback
        from ltv_lstm_mpc.solvers import socp_sqp

        kernels += [
            compiled_step.controller_step, compiled_step.controller_step_from_rows,
            compiled_step.controller_first_step,
            compiled_step.prepare_step, compiled_step.prepare_step_from_rows,
            compiled_step.feedback_step, compiled_step.feedback_step_from_rows,
            *compiled_step.CONSTRUCTORS,
        ]  # fmt: skip
        # the workspaces of the feedback it does not run are placeholders of their types
        placeholders = (
            one_call_feedback.CONSTRUCTORS  # DAQP's and the policy's
            if "cone_feedback" in names
            else (socp_sqp.new_socp_workspace_kernel,)
        )
        kernels += [kernel for kernel in placeholders if kernel not in kernels]
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


#: The one-call step's kernels for steps prepared between samples
#: (:meth:`~ltv_lstm_mpc.OffsetFreeController.prepare_next`): not loaded at construction.
PREPARED_STEP_KERNELS = (
    "prepare_step",
    "prepare_step_from_rows",
    "feedback_step",
    "feedback_step_from_rows",
)


def load_kernels(config: MPCConfig, *, one_call_step: bool = True) -> list[str]:
    """Load the compiled functions a controller with ``config`` calls in its steps
    (:func:`controller_kernels`; the one-call step's only with ``one_call_step``) from
    numba's on-disk cache now, at the controller's construction, rather than at each
    one's first call during the first steps
    (:func:`~ltv_lstm_mpc.numba_support.load_cached`). Returns the names of those the
    cache could not serve (they compile at their first call).

    Not loaded here: the kernels of prepared steps (:data:`PREPARED_STEP_KERNELS`), which
    only :meth:`~ltv_lstm_mpc.OffsetFreeController.prepare_next` calls; they are about a
    third of the loading time (1.9 of 6.2 s on 2 cores under a load of 9), and load at
    the first prepared step, as before.
    """
    step_module = "ltv_lstm_mpc.loop.compiled_step"
    used = [
        kernel
        for kernel in controller_kernels(config)
        if getattr(kernel, "__module__", "") != step_module
        or (one_call_step and kernel.__name__ not in PREPARED_STEP_KERNELS)
    ]
    return load_cached(used)


_started: set[tuple[str, ...]] = set()
_failure_reported: set[tuple[str, ...]] = set()

#: Folders of background compiles (``ltv_lstm_mpc-compile-XXXX``, removed when done) and the
#: one folder kept after a failure (``ltv_lstm_mpc-compile-failed-XXXX``), in the temp folder.
_JOB_PREFIX = "ltv_lstm_mpc-compile-"
_FAILED_PREFIX = "ltv_lstm_mpc-compile-failed-"
_MARKER = "failed.json"
_JOB = "job.json"
_LOG = "log.txt"


def _temp_root() -> Path:
    return Path(tempfile.gettempdir())


def _key(missing: Sequence[str]) -> str:
    return ",".join(sorted(missing))


def failure_folder() -> Path:
    """The one folder kept after a failed background compile of this installation (this
    package's folder, this Python, this ``NUMBA_CACHE_DIR``): the log of the last failure
    (``log.txt``), the model and configuration it compiled for, and the marker
    ``failed.json`` (the fingerprint of the sources it compiled,
    :data:`~ltv_lstm_mpc.numba_support.SOURCES_FINGERPRINT`, and the sets of kernels that
    failed)."""
    identity = "\0".join(
        [
            os.path.abspath(os.path.dirname(os.path.dirname(__file__))),
            sys.executable,
            os.environ.get("NUMBA_CACHE_DIR", ""),
        ]
    )
    return _temp_root() / (_FAILED_PREFIX + hashlib.sha1(identity.encode()).hexdigest()[:12])


@dataclass(frozen=True)
class CompileFailure:
    """A failed background compile of the current sources (:func:`compile_failure`).

    Attributes
    ----------
    folder : Path
        The folder kept (:func:`failure_folder`); deleting it allows a new attempt.
    log : Path
        Its log: the background process's output, the traceback last.
    last_line : str
        The log's last line (the error's), or what ended the process (killed).
    """

    folder: Path
    log: Path
    last_line: str

    def message(self) -> str:
        """The one-line warning of the next runs (:func:`start_background_compile`)."""
        return (
            "ltv_lstm_mpc: the background compilation of the controller kernels failed "
            f"({self.last_line}; log: {self.log}): this controller runs the numpy reference "
            "kernels (the same numbers, a few times slower per step) and no new attempt "
            "starts until the package's sources change. See the error itself with "
            "OffsetFreeController(..., kernels='compiled') or `ltv-lstm-mpc warmup`; "
            f"delete {self.folder} to let the background compilation try again"
        )


def _last_line(log: Path) -> str:
    """The last non-empty line of ``log`` (its last 4 kB), stripped; "" if none."""
    try:
        with open(log, "rb") as handle:
            handle.seek(0, os.SEEK_END)
            handle.seek(max(0, handle.tell() - 4096))
            tail = handle.read().decode("utf-8", "replace")
    except OSError:
        return ""
    lines = [line.strip() for line in tail.splitlines() if line.strip()]
    return lines[-1] if lines else ""


def _read_marker(folder: Path) -> dict[str, Any]:
    try:
        record = json.loads((folder / _MARKER).read_text())
    except (OSError, ValueError):
        return {}
    return record if isinstance(record, dict) else {}


def compile_failure(missing: Sequence[str]) -> CompileFailure | None:
    """The failed background compile recorded for the current sources and the kernels
    ``missing`` (:func:`record_failure`), or None: none, or one of other sources (edited
    or upgraded since: one new attempt) or of other kernels."""
    folder = failure_folder()
    record = _read_marker(folder)
    if record.get("fingerprint") != numba_support.SOURCES_FINGERPRINT:
        return None
    if _key(missing) not in record.get("missing", []):
        return None
    log = folder / _LOG
    return CompileFailure(folder, log, str(record.get("last_line") or _last_line(log)))


@contextlib.contextmanager
def compile_lock(*, wait: bool = True) -> Iterator[bool]:
    """The lock file that background compiles take turns on (and the records of failures
    are written under); yields whether it is held (``wait=False``: False where another
    process holds it; True without POSIX locks)."""
    with open(_temp_root() / "ltv_lstm_mpc-compile.lock", "a") as lock:
        try:
            import fcntl
        except ImportError:  # pragma: no cover - no POSIX locks: go ahead
            yield True
            return
        try:
            fcntl.flock(lock, fcntl.LOCK_EX if wait else fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            yield False
            return
        try:
            yield True
        finally:
            fcntl.flock(lock, fcntl.LOCK_UN)


def record_failure(job: Path, missing: Sequence[str], fingerprint: str, last_line: str) -> Path:
    """Keep the folder ``job`` of a failed background compile as the one
    :func:`failure_folder` (replacing an earlier one), with a marker: ``fingerprint`` (the
    sources it compiled) and the kernel set ``missing`` (added to those of earlier failures
    of the same sources). Call it holding :func:`compile_lock`. Returns the folder."""
    target = failure_folder()
    record = _read_marker(target)
    failed = list(record.get("missing", [])) if record.get("fingerprint") == fingerprint else []
    if _key(missing) not in failed:
        failed.append(_key(missing))
    if job != target:
        shutil.rmtree(target, ignore_errors=True)
        try:
            os.replace(job, target)
        except OSError:  # target not removable: keep at least the log there
            target.mkdir(exist_ok=True)
            with contextlib.suppress(OSError):
                shutil.copyfile(job / _LOG, target / _LOG)
            shutil.rmtree(job, ignore_errors=True)
    for leftover in (_JOB, "pid"):
        with contextlib.suppress(OSError):
            (target / leftover).unlink(missing_ok=True)
    record = {"fingerprint": fingerprint, "missing": failed, "last_line": last_line}
    (target / _MARKER).write_text(json.dumps(record, indent=1))
    return target


def forget_failure(missing: Sequence[str] | None = None) -> None:
    """The kernels ``missing`` compiled after all (None: every set): drop them from the
    failure record, and remove its folder when no failed set is left or the record is of
    other sources."""
    folder = failure_folder()
    if not folder.exists():
        return
    record = _read_marker(folder)
    failed = list(record.get("missing", []))
    if missing is not None and record.get("fingerprint") == numba_support.SOURCES_FINGERPRINT:
        failed = [key for key in failed if key != _key(missing)]
    else:
        failed = []
    if failed:
        record["missing"] = failed
        with contextlib.suppress(OSError):
            (folder / _MARKER).write_text(json.dumps(record, indent=1))
    else:
        shutil.rmtree(folder, ignore_errors=True)


def _alive(pid: int) -> bool:
    """Whether process ``pid`` runs (True where that cannot be told)."""
    if os.name != "posix":  # pragma: no cover - os.kill(pid, 0) would end it on Windows
        return True
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except OSError:  # another user's: alive
        return True
    return True


def _sweep_abandoned() -> None:
    """Background compiles that ended without removing their folder or recording a failure
    (killed): recorded as failures (their folder becomes the one kept), so that folders do
    not pile up and the kernels are not retried every run. Only while no background compile
    holds the lock; only folders this installation started (``pid`` and ``job.json``
    naming its :func:`failure_folder`: another installation's are its own to record)."""
    with compile_lock(wait=False) as held:
        if not held:
            return
        target = failure_folder()
        for job in sorted(_temp_root().glob(_JOB_PREFIX + "*")):
            if job.name.startswith(_FAILED_PREFIX) or not job.is_dir():
                continue
            try:
                pid = int((job / "pid").read_text())
                spec = json.loads((job / _JOB).read_text())
            except (OSError, ValueError):
                continue  # not started yet, or not ours
            if spec.get("installation") != target.name or _alive(pid):
                continue
            last = _last_line(job / _LOG)
            record_failure(
                job,
                spec.get("missing", []),
                spec.get("fingerprint", ""),
                f"the background process (pid {pid}) ended without finishing (killed?)"
                + (f"; its log's last line: {last}" if last else ""),
            )


def start_background_compile(model: LSTMModel, config: MPCConfig, missing: list[str]) -> bool:
    """Start a detached process that compiles ``config``'s kernels into numba's on-disk
    cache (:func:`~ltv_lstm_mpc.loop.warmup.warm_up` on a copy of ``model``), once per
    process and set of missing functions; concurrent ones (several processes, campaign
    workers) take turns on a lock file and skip what another has compiled. It outlives
    this process if need be. Its temporary folder is removed when it succeeds; on a
    failure it becomes the one folder kept (:func:`failure_folder`), and no process
    starts one for the same sources and kernels again: a ``RuntimeWarning`` says so, once
    per process, with the log's last line and the log file.

    Returns whether one was started."""
    key = tuple(missing)
    if key in _started:
        return False
    _started.add(key)
    with contextlib.suppress(OSError):
        _sweep_abandoned()
    failure = compile_failure(missing)
    if failure is not None:
        if key not in _failure_reported:
            _failure_reported.add(key)
            from ltv_lstm_mpc.caller_warnings import warn_at_caller

            warn_at_caller(failure.message(), RuntimeWarning)
        return False
    folder = Path(tempfile.mkdtemp(prefix=_JOB_PREFIX))
    try:
        model.save(folder / "model.npz")
        with open(folder / "config.pickle", "wb") as handle:
            pickle.dump(config, handle)
        job = {
            "missing": list(missing),
            "fingerprint": numba_support.SOURCES_FINGERPRINT,
            "installation": failure_folder().name,
        }
        (folder / _JOB).write_text(json.dumps(job))
        code = (
            f"import sys; sys.path[:0] = {[p for p in sys.path if p]!r}; "
            "from ltv_lstm_mpc.loop.warmup import compile_in_background; "
            f"compile_in_background({str(folder)!r})"
        )
        log: IO[bytes]
        with open(folder / _LOG, "wb") as log:
            process = subprocess.Popen(
                [sys.executable, "-c", code],
                stdin=subprocess.DEVNULL,
                stdout=log,
                stderr=subprocess.STDOUT,
                env={**os.environ, _ENVIRONMENT: "numba"},
                start_new_session=True,
            )
        with contextlib.suppress(OSError):
            (folder / "pid").write_text(str(process.pid))
    except Exception:  # nothing to start: the next run compiles (or runs numpy) again
        shutil.rmtree(folder, ignore_errors=True)
        return False
    return True


def use_kernels(
    model: LSTMModel, config: MPCConfig, kernels: str, *, one_call_step: bool = True
) -> LSTMModel:
    """The model a controller runs, with the kernel ``kernels`` asks for (a controller's
    ``kernels``): compiled or the numpy reference. ``model`` itself where its kernel is
    that one, else a copy of it with that kernel: the caller's model is never modified.
    Says once what happens (compiling now, or the numpy reference while a background
    process compiles). Compiled: loads now every kernel the cache holds (not at the first
    steps: :func:`~ltv_lstm_mpc.loop.kernels.load_kernels`)."""
    from ltv_lstm_mpc.lstm.kernel import LSTMKernel
    from ltv_lstm_mpc.numba_support import compile_notice, compile_on_demand, say_once

    compiled, missing = choose_kernels(config, kernels)
    if model.kernel.compiled != compiled and (kernels != "auto" or model.kernel.automatic):
        model = copy.copy(model)  # shares the weights; its own kernel
        model.kernel = LSTMKernel(model, compiled=compiled)
        model.kernel.automatic = kernels == "auto"
    if model.kernel.compiled:
        compile_on_demand()  # the solver layer's helpers compile too
        load_kernels(config, one_call_step=one_call_step)
    if not missing:
        return model
    if model.kernel.compiled:
        say_once(compile_notice("the controller kernels", "20-40 s"))
    elif start_background_compile(model, config, missing):
        from ltv_lstm_mpc.mpc.rti import NLP_SOLVERS
        from ltv_lstm_mpc.solvers import compiled_form

        form = None if config.solver in NLP_SOLVERS else compiled_form(config.solver)
        say_once(
            "ltv_lstm_mpc: the compiled controller kernels are not in numba's cache yet: "
            "this controller runs the numpy reference kernels (the same numbers to about "
            "1e-12, a few times slower per step) while a background process compiles them "
            "(once, about 20-40 s on 2 cores); later controllers and runs use them. "
            "OffsetFreeController(..., kernels='compiled') waits for the compilation "
            "instead; `ltv-lstm-mpc warmup` compiles ahead of time"
            + (
                f". The {config.solver} solver has no numpy twin: it compiles in this process "
                "at the first step (about 10 s on 2 cores, once)"
                if form is not None and form.compiled_only
                else ""
            )
        )
    return model
