"""``warn_at_caller`` (ltv_lstm_mpc/caller_warnings.py) in every kind of process.

CPython's ``warnings.warn_explicit(..., module_globals=...)`` asks the module's loader for
the source of ``__name__`` and lets its error escape; no loader serves a module named
``__main__`` (``python -c``, ``python -``, ``python -m``, a frozen ``__main__``), so every
library warning raised from such a process crashed it instead (the background
compile of a model file without ``Ts`` died of it).
"""

from __future__ import annotations

import subprocess
import sys
import textwrap
import warnings
from pathlib import Path

import pytest

from ltv_lstm_mpc.caller_warnings import warn_at_caller

SCRIPT = (
    "from ltv_lstm_mpc.caller_warnings import warn_at_caller\n"
    "warn_at_caller('hello from the library')\n"
    "print('still running')\n"
)


def _check(result: subprocess.CompletedProcess[str]) -> None:
    assert result.returncode == 0, result.stderr
    assert "still running" in result.stdout
    assert "RuntimeWarning: hello from the library" in result.stderr


def test_a_python_c_child_process() -> None:
    _check(subprocess.run([sys.executable, "-c", SCRIPT], capture_output=True, text=True))


def test_a_script_read_from_stdin() -> None:
    _check(subprocess.run([sys.executable, "-"], input=SCRIPT, capture_output=True, text=True))


def test_a_module_run_with_dash_m(tmp_path: Path) -> None:
    (tmp_path / "user_script.py").write_text(SCRIPT)
    result = subprocess.run(
        [sys.executable, "-m", "user_script"], capture_output=True, text=True, cwd=tmp_path
    )
    _check(result)
    assert "warn_at_caller('hello from the library')" in result.stderr  # the caller's line


@pytest.mark.parametrize("loader", ["frozen", "builtin", "broken"])
def test_a_main_module_whose_loader_has_no_source(loader: str) -> None:
    """A frozen ``__main__`` (PyInstaller and the like), the built-in importer's (an
    interactive session) and a loader that fails: the warning is shown, without a line."""
    import importlib.machinery

    class Broken:
        @staticmethod
        def get_source(name: str) -> str:
            raise RuntimeError("no source here")

    loaders = {
        "frozen": importlib.machinery.FrozenImporter,
        "builtin": importlib.machinery.BuiltinImporter,
        "broken": Broken,
    }
    namespace = {"__name__": "__main__", "__loader__": loaders[loader]}
    code = compile("warn_at_caller('from a frozen main')\n", "<frozen main>", "exec")
    namespace["warn_at_caller"] = warn_at_caller
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        exec(code, namespace)
    assert [str(w.message) for w in caught] == ["from a frozen main"]
    assert caught[0].filename == "<frozen main>"


def test_a_loader_that_serves_the_source_still_gives_the_line() -> None:
    """Where the caller's file is not on disk but its loader has the source (a zip
    import), the warning still shows the caller's line."""

    class ZipLike:
        @staticmethod
        def get_source(name: str) -> str:
            return "x = 1\nwarn_at_caller('zipped')  # the caller's line\n"

    filename = "/nowhere/zipped_module.py"
    namespace = {"__name__": "zipped_module", "__loader__": ZipLike}
    namespace["warn_at_caller"] = warn_at_caller
    code = compile("x = 1\nwarn_at_caller('zipped')\n", filename, "exec")
    shown: list[str] = []
    with warnings.catch_warnings():
        warnings.simplefilter("always")
        warnings.showwarning = lambda message, category, file, line, *rest: shown.append(
            warnings.formatwarning(message, category, file, line)
        )
        exec(code, namespace)
    assert len(shown) == 1 and "# the caller's line" in shown[0]


def test_an_error_filter_still_raises() -> None:
    """``-W error`` (a filter) turns the warning into the exception, as warnings.warn does."""
    code = textwrap.dedent(
        """
        import warnings
        warnings.simplefilter("error")
        from ltv_lstm_mpc.caller_warnings import warn_at_caller
        try:
            warn_at_caller("boom")
        except RuntimeWarning as error:
            print("raised", error)
        """
    )
    result = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert result.returncode == 0, result.stderr
    assert result.stdout.strip() == "raised boom"
