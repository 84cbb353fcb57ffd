"""numba's cache kept consistent across files (``numba_support.make_njit``).

numba checks a cached function against its own file only: a caller whose callee lives in
another, edited file would load its old machine code, callee included, and compute with it.
The package's ``njit`` puts a fingerprint of all its source files into every cache's stamp.
"""

from __future__ import annotations

import os
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

from ltv_lstm_mpc.numba_support import make_njit, sources_fingerprint


def _touch_later(path: Path, seconds: float = 10.0) -> None:
    """Move ``path``'s modification time forward (an edit within the same clock tick)."""
    stat = path.stat()
    os.utime(path, ns=(stat.st_atime_ns, stat.st_mtime_ns + int(seconds * 1e9)))


def test_the_fingerprint_follows_every_source_file(tmp_path: Path) -> None:
    (tmp_path / "pkg" / "sub").mkdir(parents=True)
    (tmp_path / "pkg" / "a.py").write_text("x = 1\n")
    (tmp_path / "pkg" / "sub" / "b.py").write_text("y = 2\n")
    (tmp_path / "pkg" / "notes.txt").write_text("not a source")
    roots = [tmp_path / "pkg", tmp_path / "missing"]
    first = sources_fingerprint(roots)
    assert sources_fingerprint(roots) == first  # nothing changed
    (tmp_path / "pkg" / "notes.txt").write_text("still not a source")
    assert sources_fingerprint(roots) == first
    os.symlink(tmp_path / "nowhere.py", tmp_path / "pkg" / ".#a.py")  # an editor's lock
    assert sources_fingerprint(roots) == first  # a dangling link is left out
    _touch_later(tmp_path / "pkg" / "sub" / "b.py")
    second = sources_fingerprint(roots)
    assert second != first
    (tmp_path / "pkg" / "c.py").write_text("z = 3\n")
    assert sources_fingerprint(roots) not in (first, second)


def test_cached_kernels_carry_the_fingerprint_in_their_stamp(tmp_path: Path) -> None:
    pytest.importorskip("numba")
    (tmp_path / "a.py").write_text("x = 1\n")
    njit = make_njit([tmp_path])
    fingerprint = sources_fingerprint([tmp_path])

    def add_one(x):  # type: ignore[no-untyped-def]
        return x + 1

    cached = njit(cache=True)(add_one)
    stamp = cached._cache._cache_file._source_stamp
    assert isinstance(stamp, tuple) and stamp[1] == fingerprint
    assert cached(2) == 3
    bare = njit(add_one)  # no cache: nothing to stamp, still compiled
    assert not hasattr(bare._cache, "_cache_file") and bare(2) == 3


def test_an_index_naming_a_type_that_has_moved_is_a_cache_miss(tmp_path: Path) -> None:
    """An index written by an earlier layout (its keys name a workspace type that has moved
    since) is read as empty and the kernel compiles, instead of failing to unpickle."""
    pytest.importorskip("numba")
    import pickle
    import types

    (tmp_path / "a.py").write_text("x = 1\n")
    njit = make_njit([tmp_path])

    def add_two(x):  # type: ignore[no-untyped-def]
        return x + 2

    cached = njit(cache=True)(add_two)
    cache_file = cached._cache._cache_file
    gone = types.ModuleType("ltv_test_moved_types")

    class MovedType:
        pass

    MovedType.__module__, MovedType.__qualname__ = gone.__name__, "MovedType"
    gone.MovedType = MovedType  # type: ignore[attr-defined]
    sys.modules[gone.__name__] = gone
    try:
        index = pickle.dumps((cache_file._source_stamp, {(MovedType(),): "x.nbc"}))
    finally:
        del sys.modules[gone.__name__]
    index_path = Path(cache_file._index_path)
    index_path.parent.mkdir(parents=True, exist_ok=True)
    with open(index_path, "wb") as f:
        pickle.dump(cache_file._version, f, protocol=-1)
        f.write(index)
    assert cache_file._load_index() == {}
    assert cached(1) == 3


PACKAGE_FILES = {
    "__init__.py": "",
    "_jit.py": (
        "import os\nfrom pathlib import Path\n\nimport numba\n\n"
        "from ltv_lstm_mpc.numba_support import make_njit\n\n"
        "njit = numba.njit if os.environ.get('PLAIN_NUMBA') else "
        "make_njit([Path(__file__).parent])\n"
    ),
    "callee.py": "from ._jit import njit\n\n\n@njit(cache=True)\ndef f():\n    return 1\n",
    "caller.py": (
        "from ._jit import njit\nfrom .callee import f\n\n\n"
        "@njit(cache=True)\ndef g():\n    return f() + 10\n"
    ),
}


@pytest.mark.parametrize("plain", [True, False], ids=["numba alone", "make_njit"])
def test_a_cached_caller_sees_its_edited_callee(tmp_path: Path, plain: bool) -> None:
    """The hazard itself: after the callee's file is edited, numba alone loads the cached
    caller with the old callee; with make_njit the caller compiles again."""
    pytest.importorskip("numba")
    package = tmp_path / "pkgx"
    package.mkdir()
    for name, text in PACKAGE_FILES.items():
        (package / name).write_text(text)
    script = textwrap.dedent(
        f"""
        import sys
        sys.path.insert(0, {str(tmp_path)!r})
        from pkgx.caller import g
        print(g())
        """
    )
    environment = dict(os.environ, PLAIN_NUMBA="1" if plain else "")

    def run() -> str:
        result = subprocess.run(
            [sys.executable, "-c", script], capture_output=True, text=True, check=True,
            env=environment,
        )  # fmt: skip
        return result.stdout.strip()

    assert run() == "11"  # compiled and cached
    assert list((package / "__pycache__").glob("caller.g-*.nbi"))
    callee = package / "callee.py"
    callee.write_text(callee.read_text().replace("return 1", "return 2"))
    _touch_later(callee)
    assert run() == ("11" if plain else "12")


LOADER_FILES = {
    "__init__.py": "",
    "kernels.py": (
        "from pathlib import Path\n\nfrom ltv_lstm_mpc.numba_support import make_njit\n\n"
        "njit = make_njit([Path(__file__).parent])\n\n\n"
        "@njit(cache=True)\ndef used(x):\n    return x + 1\n\n\n"
        "@njit(cache=True)\ndef never_called(x):\n    return x - 1\n"
    ),
}


def test_load_cached_loads_what_the_cache_holds_and_compiles_nothing(tmp_path: Path) -> None:
    """numba loads a cached kernel at its first call; load_cached loads it now (the
    controller's construction), and leaves a kernel the cache lacks uncompiled."""
    pytest.importorskip("numba")
    package = tmp_path / "pkgl"
    package.mkdir()
    for name, text in LOADER_FILES.items():
        (package / name).write_text(text)
    prelude = f"import sys\nsys.path.insert(0, {str(tmp_path)!r})\nfrom pkgl import kernels\n"

    def run(code: str) -> str:
        result = subprocess.run(
            [sys.executable, "-c", prelude + code], capture_output=True, text=True, check=True
        )
        return result.stdout.strip()

    assert run("print(kernels.used(1))") == "2"  # compiled and cached
    loaded = run(
        "from ltv_lstm_mpc.numba_support import load_cached\n"
        "nothing = load_cached([kernels.used, kernels.never_called])\n"
        "print(nothing, len(kernels.used.signatures), len(kernels.never_called.signatures),"
        " sum(kernels.used.stats.cache_hits.values()),"
        " sum(kernels.used.stats.cache_misses.values()))\n"
        "print(kernels.used(1))\n"
    )
    assert loaded.splitlines() == ["['never_called'] 1 0 1 0", "2"]
