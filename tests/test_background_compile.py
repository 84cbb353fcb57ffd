"""Background compiles that never fail silently (ltv_lstm_mpc/loop/kernels.py, warmup.py).

Guards against this: a model file without ``Ts`` made the background compile crash (in its
log only); every later run started another one, ran the numpy kernels and left another
``ltv_lstm_mpc-compile-*`` folder in the temp folder. Now a failure is recorded (one
folder kept, marked with the fingerprint of the sources), reported once per process on the
next runs with the log's last line and the log file, and not retried until the sources
change.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import tempfile
import time
import warnings
from pathlib import Path

import pytest

from ltv_lstm_mpc import MPCConfig, load_model, numba_support
from ltv_lstm_mpc.loop import kernels, warmup

pytestmark = pytest.mark.skipif(not numba_support.AVAILABLE, reason="needs numba")

CONFIG = MPCConfig(solver="daqp", L_d=0.1)
MISSING = ["condense"]


@pytest.fixture
def temp(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Path:
    """A temp folder of its own (for this process and its children), and a fresh process
    as far as the once-per-process bookkeeping goes."""
    monkeypatch.setattr(tempfile, "tempdir", str(tmp_path))
    monkeypatch.setenv("TMPDIR", str(tmp_path))
    monkeypatch.setattr(kernels, "_started", set())
    monkeypatch.setattr(kernels, "_failure_reported", set(), raising=False)  # (older code)
    return tmp_path


def _folders(root: Path) -> list[Path]:
    return sorted(path for path in root.glob("ltv_lstm_mpc-compile-*") if path.is_dir())


def _run_job(job: Path, code: str = "") -> None:
    """Run compile_in_background on ``job`` the way start_background_compile does: a
    ``python -c`` child whose output goes to the job's log."""
    script = (
        f"{code}\nfrom ltv_lstm_mpc.loop.warmup import compile_in_background\n"
        f"compile_in_background({str(job)!r})\n"
    )
    with open(job / "log.txt", "wb") as log:
        subprocess.run(
            [sys.executable, "-c", script],
            stdout=log,
            stderr=subprocess.STDOUT,
            timeout=900,
            check=True,
            env={**os.environ, "LTV_LSTM_MPC_KERNEL": "numba"},
        )


def _failing_job(root: Path, name: str = "ltv_lstm_mpc-compile-test") -> Path:
    """A job folder whose configuration cannot be read: the background compile fails."""
    job = root / name
    job.mkdir()
    (job / "config.pickle").write_bytes(b"not a pickle")
    job_spec = {
        "missing": MISSING,
        "fingerprint": numba_support.SOURCES_FINGERPRINT,
        "installation": kernels.failure_folder().name,
    }
    (job / "job.json").write_text(json.dumps(job_spec))
    return job


def test_a_failure_is_kept_reported_once_and_not_retried(temp: Path, monkeypatch) -> None:
    _run_job(_failing_job(temp))
    kept = kernels.failure_folder()
    assert _folders(temp) == [kept]  # the job's folder became the one kept
    failure = kernels.compile_failure(MISSING)
    assert failure is not None and failure.log == kept / "log.txt"
    assert "UnpicklingError" in failure.last_line
    assert failure.last_line == failure.log.read_text().strip().splitlines()[-1]
    assert kernels.compile_failure(["another kernel"]) is None  # other kernels: not blocked

    def no_start(*args, **kwargs):
        raise AssertionError("a background compile started again")

    monkeypatch.setattr(kernels.subprocess, "Popen", no_start)
    model = load_model("ph_lstm_n5.npz")
    with pytest.warns(RuntimeWarning) as shown:
        assert not kernels.start_background_compile(model, CONFIG, MISSING)
    (warning,) = shown
    message = str(warning.message)
    assert "\n" not in message
    assert str(failure.log) in message and failure.last_line in message
    assert "kernels='compiled'" in message and f"delete {kept}" in message
    assert warning.filename == __file__  # at the caller's line

    monkeypatch.setattr(kernels, "_started", set())  # the next controller of this process
    with warnings.catch_warnings():  # said once per process
        warnings.simplefilter("error")
        assert not kernels.start_background_compile(model, CONFIG, MISSING)
    assert _folders(temp) == [kept]


def test_a_failing_background_compile_is_not_started_again(temp: Path, monkeypatch) -> None:
    """Through start_background_compile alone (the issue's symptom, as a user sees it):
    a background compile that fails (here: an unreadable model file, with an empty numba
    cache so that it reads it) is not started again by the next run, which warns once
    with the log's last line and the log file; one folder is left."""
    from ltv_lstm_mpc.lstm.model import LSTMModel

    monkeypatch.setenv("NUMBA_CACHE_DIR", str(temp / "empty-cache"))
    monkeypatch.setattr(LSTMModel, "save", lambda self, path: Path(path).write_bytes(b"no"))
    model = load_model("ph_lstm_n5.npz")
    assert kernels.start_background_compile(model, CONFIG, MISSING)
    deadline = time.monotonic() + 300
    while time.monotonic() < deadline:  # until its traceback's last line is in a log
        logs = [path / "log.txt" for path in _folders(temp)]
        if any("Error" in log.read_text().strip()[-300:] for log in logs if log.exists()):
            break
        time.sleep(0.5)
    time.sleep(1.0)  # its last writes
    (folder,) = _folders(temp)
    last = (folder / "log.txt").read_text().strip().splitlines()[-1]

    monkeypatch.setattr(kernels, "_started", set())  # the next run
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        started = kernels.start_background_compile(model, CONFIG, MISSING)
    assert not started
    assert [str(w.category.__name__) for w in caught] == ["RuntimeWarning"]
    assert last in str(caught[0].message)
    assert str(folder / "log.txt") in str(caught[0].message)
    assert _folders(temp) == [folder]


def test_edited_sources_retry_once_and_a_second_failure_replaces_the_first(
    temp: Path, monkeypatch
) -> None:
    _run_job(_failing_job(temp))
    kept = kernels.failure_folder()
    monkeypatch.setattr(numba_support, "SOURCES_FINGERPRINT", "edited sources")
    assert kernels.compile_failure(MISSING) is None

    class Started:
        pid = os.getpid()  # alive

    calls: list[list[str]] = []
    monkeypatch.setattr(
        kernels.subprocess, "Popen", lambda args, **kw: calls.append(args) or Started()
    )
    assert kernels.start_background_compile(load_model("ph_lstm_n5.npz"), CONFIG, MISSING)
    assert len(calls) == 1
    (job,) = [path for path in _folders(temp) if path != kept]
    assert json.loads((job / "job.json").read_text()) == {
        "missing": MISSING,
        "fingerprint": "edited sources",
        "installation": kept.name,
    }
    # that attempt fails too: it replaces the record, one folder kept, no more retries
    (job / "config.pickle").write_bytes(b"still not a pickle")
    (job / "log.txt").write_text("compiling\nValueError: the second failure\n")
    kernels.record_failure(job, MISSING, "edited sources", "ValueError: the second failure")
    assert _folders(temp) == [kept]
    failure = kernels.compile_failure(MISSING)
    assert failure is not None and failure.last_line == "ValueError: the second failure"


def test_success_removes_the_record(temp: Path) -> None:
    job = _failing_job(temp)
    (job / "log.txt").write_text("ValueError: x\n")
    kept = kernels.record_failure(job, MISSING, numba_support.SOURCES_FINGERPRINT, "x")
    other = _failing_job(temp, "ltv_lstm_mpc-compile-other")
    kernels.record_failure(other, ["osqp kernels"], numba_support.SOURCES_FINGERPRINT, "y")
    assert _folders(temp) == [kept]
    kernels.forget_failure(MISSING)  # compiled after all: the other set stays recorded
    assert kernels.compile_failure(MISSING) is None
    assert kernels.compile_failure(["osqp kernels"]) is not None
    kernels.forget_failure(["osqp kernels"])
    assert _folders(temp) == []


def test_a_killed_background_compile_is_recorded_not_piled_up(temp: Path, monkeypatch) -> None:
    """A job folder whose process ended without removing it or recording a failure
    (killed): the next start turns it into the failure record (one folder) and reports."""
    finished = subprocess.Popen([sys.executable, "-c", "pass"])
    finished.wait()
    for name in ("ltv_lstm_mpc-compile-a", "ltv_lstm_mpc-compile-b"):
        job = _failing_job(temp, name)
        (job / "pid").write_text(str(finished.pid))
        (job / "log.txt").write_text("compiling...\n")
    unknown = temp / "ltv_lstm_mpc-compile-not-ours"  # no pid file: left alone
    unknown.mkdir()
    other = _failing_job(temp, "ltv_lstm_mpc-compile-other-installation")
    (other / "pid").write_text(str(finished.pid))
    spec = json.loads((other / "job.json").read_text())
    (other / "job.json").write_text(json.dumps({**spec, "installation": "elsewhere"}))
    monkeypatch.setattr(kernels.subprocess, "Popen", None)  # must not start
    with pytest.warns(RuntimeWarning, match=r"ended without finishing \(killed\?\)"):
        assert not kernels.start_background_compile(load_model("ph_lstm_n5.npz"), CONFIG, MISSING)
    assert _folders(temp) == sorted([kernels.failure_folder(), unknown, other])


def test_the_background_compile_of_a_model_without_ts(temp: Path) -> None:
    """The issue's case: the background process (a ``python -c`` child) loads a model file
    without Ts, which warns; that crashed it (warn_at_caller in a ``__main__`` that no
    loader serves). Run with the kernels forced "missing" so that it loads the model and
    warms up (quick where numba's cache is warm); the folder is removed, nothing kept."""
    warmup.warm_up(load_model("ph_lstm_n5.npz"), CONFIG)  # warm cache: the child is quick
    job = temp / "ltv_lstm_mpc-compile-nots"
    job.mkdir()
    model = load_model("ph_lstm_n5.npz")
    model.Ts = None
    model.save(job / "model.npz")
    import pickle

    (job / "config.pickle").write_bytes(pickle.dumps(CONFIG))
    (job / "job.json").write_text(json.dumps({"missing": MISSING}))
    _run_job(
        job,
        "import ltv_lstm_mpc.loop.warmup as w\nw.uncached = lambda dispatchers: ['condense']",
    )
    left = {path.name: (path / "log.txt").read_text()[-2000:] for path in _folders(temp)}
    assert left == {}  # the job's folder removed, no failure kept


@pytest.mark.slow
def test_an_empty_cache_and_a_model_without_ts_end_compiled(tmp_path: Path) -> None:
    """End to end from an empty numba cache (about a minute on 2 cores): a controller on a
    model file without Ts starts the background compile, which fills the cache and
    removes its folder; the next controller runs compiled."""
    model = load_model("ph_lstm_n5.npz")
    model.Ts = None
    model.save(tmp_path / "nots.npz")
    environment = {
        **os.environ,
        "NUMBA_CACHE_DIR": str(tmp_path / "cache"),
        "TMPDIR": str(tmp_path),
    }
    environment.pop("LTV_LSTM_MPC_KERNEL", None)
    code = (
        "import sys, time, warnings\n"
        "warnings.simplefilter('ignore', UserWarning)\n"
        "from ltv_lstm_mpc import MPCConfig, OffsetFreeController, LSTMModel\n"
        "from ltv_lstm_mpc.loop.kernels import choose_kernels\n"
        f"model = LSTMModel.load({str(tmp_path / 'nots.npz')!r})\n"
        "config = MPCConfig(solver='daqp', L_d=0.1)\n"
        "print(OffsetFreeController(model, config).kernels)\n"
        "start = time.monotonic()\n"
        "while choose_kernels(config)[1] and time.monotonic() - start < 600:\n"
        "    time.sleep(0.5)\n"
        "print(OffsetFreeController(model, config).kernels)\n"
    )
    result = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, env=environment
    )
    assert result.returncode == 0, result.stderr
    deadline = time.monotonic() + 60
    while _folders(tmp_path) and time.monotonic() < deadline:  # the folder goes last
        time.sleep(0.5)
    logs = [(path / "log.txt").read_text() for path in _folders(tmp_path)]
    assert result.stdout.split() == ["numpy", "compiled"], (result.stderr, logs)
    assert logs == []
