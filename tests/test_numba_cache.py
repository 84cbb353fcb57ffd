"""numba's cache kept consistent across files (``numba_support.purge_stale_caches``).

numba checks a cached function against its own file only: a caller whose callee lives in
another, edited file loads its old machine code, callee included, and computes with it.
"""

from __future__ import annotations

import os
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

from ltv_lstm_mpc.numba_support import purge_stale_caches, sources_fingerprint


def _touch_later(path: Path, seconds: float = 10.0) -> None:
    """Move ``path``'s modification time forward (an edit within the same clock tick)."""
    stat = path.stat()
    os.utime(path, ns=(stat.st_atime_ns, stat.st_mtime_ns + int(seconds * 1e9)))


def _tree(root: Path) -> dict[str, Path]:
    """Two source files with cache files, a .pyc and a cache file of no source of ours."""
    (root / "pkg" / "sub" / "__pycache__").mkdir(parents=True)
    (root / "pkg" / "__pycache__").mkdir()
    (root / "pkg" / "a.py").write_text("x = 1\n")
    (root / "pkg" / "sub" / "b.py").write_text("y = 2\n")
    files = {
        "a_index": root / "pkg" / "__pycache__" / "a.f-1.py311.nbi",
        "a_data": root / "pkg" / "__pycache__" / "a.f-1.py311.1.nbc",
        "b_index": root / "pkg" / "sub" / "__pycache__" / "b.g-3.py311.nbi",
        "bytecode": root / "pkg" / "__pycache__" / "a.cpython-311.pyc",
        "foreign": root / "pkg" / "__pycache__" / "other.h-1.py311.nbi",
    }
    for path in files.values():
        path.write_bytes(b"cache")
    return files


def test_the_caches_of_every_file_go_when_any_file_changes(tmp_path: Path) -> None:
    files = _tree(tmp_path)
    roots, stamp = [tmp_path / "pkg"], tmp_path / "stamp"
    ours = ("a_index", "a_data", "b_index")
    assert purge_stale_caches(roots, stamp) == 3  # no stamp yet: nothing is trusted
    assert not any(files[name].exists() for name in ours)
    assert files["bytecode"].exists() and files["foreign"].exists()
    assert stamp.read_text() == sources_fingerprint(roots)
    for name in ours:
        files[name].write_bytes(b"cache")
    assert purge_stale_caches(roots, stamp) == 0  # nothing changed: the caches stay
    assert all(files[name].exists() for name in ours)
    _touch_later(tmp_path / "pkg" / "sub" / "b.py")  # one file changed: a's caches go too
    assert purge_stale_caches(roots, stamp) == 3
    assert not any(files[name].exists() for name in ours)
    (tmp_path / "pkg" / "c.py").write_text("z = 3\n")  # a new file changes the fingerprint
    assert stamp.read_text() != sources_fingerprint(roots)


def test_the_caches_under_numba_cache_dir_go_too(tmp_path: Path, monkeypatch) -> None:
    pytest.importorskip("numba")
    from numba.core import config
    from numba.core.caching import UserProvidedCacheLocator

    _tree(tmp_path)
    source = tmp_path / "pkg" / "a.py"
    monkeypatch.setattr(config, "CACHE_DIR", str(tmp_path / "cache"))
    folder = tmp_path / "cache" / UserProvidedCacheLocator.get_suitable_cache_subpath(str(source))
    folder.mkdir(parents=True)
    (folder / "a.f-1.py311.nbi").write_bytes(b"cache")
    assert purge_stale_caches([tmp_path / "pkg"], tmp_path / "stamp") == 4
    assert not (folder / "a.f-1.py311.nbi").exists()


def test_a_caller_in_another_file_compiles_against_the_edited_callee(tmp_path: Path) -> None:
    """The hazard itself, with numba: after the callee's file is edited, the cached caller
    still returns the old value; with the purge it returns the new one."""
    pytest.importorskip("numba")
    package = tmp_path / "pkgx"
    package.mkdir()
    (package / "__init__.py").write_text("")
    callee = package / "callee.py"
    callee.write_text("from numba import njit\n\n\n@njit(cache=True)\ndef f():\n    return 1\n")
    (package / "caller.py").write_text(
        "from numba import njit\n\nfrom .callee import f\n\n\n"
        "@njit(cache=True)\ndef g():\n    return f() + 10\n"
    )
    script = textwrap.dedent(
        f"""
        import sys
        from pathlib import Path
        sys.path.insert(0, {str(tmp_path)!r})
        from ltv_lstm_mpc.numba_support import purge_stale_caches
        if sys.argv[1] == "purge":
            purge_stale_caches([Path({str(package)!r})], Path({str(tmp_path / "stamp")!r}))
        from pkgx.caller import g
        print(g())
        """
    )

    def run(mode: str) -> str:
        result = subprocess.run(
            [sys.executable, "-c", script, mode], capture_output=True, text=True, check=True
        )
        return result.stdout.strip()

    assert run("purge") == "11"  # compiled and cached
    callee.write_text(callee.read_text().replace("return 1", "return 2"))
    _touch_later(callee)
    assert run("keep") == "11"  # numba alone: the caller's cache holds the old callee
    assert run("purge") == "12"
    assert run("keep") == "12"  # and the new caches are kept from then on
