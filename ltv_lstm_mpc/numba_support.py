"""numba's ``njit`` where numba is installed, else a stand-in that leaves a function as Python.

The one home of the guard used by every compiled kernel (the LSTM kernel, the dense solver
layer's loops, the DAQP binding): numba is a core dependency, but without it the package
still imports and runs its numpy reference code (``AVAILABLE`` is then ``False``).
"""

from __future__ import annotations

import hashlib
import importlib.util
import os
import pickle
from collections.abc import Sequence
from pathlib import Path
from typing import Any

__all__ = [
    "AVAILABLE",
    "REDUCTIONS",
    "SOURCES_FINGERPRINT",
    "announce_compile",
    "build_workspace",
    "compile_notice",
    "compile_on_demand",
    "entry_point",
    "load_cached",
    "make_njit",
    "njit",
    "prime_typeof",
    "ready",
    "say_once",
    "sources_fingerprint",
    "uncached",
    "workspace_type",
]


def _kernel_packages() -> tuple[Path, ...]:
    """The folders of the packages whose compiled kernels call one another across files:
    this one and its solver layer (``ltv_lstm_mpc.solvers``, the folder ``solvers/`` of the
    repository), as numba names their files (absolute, links not resolved)."""
    here = Path(os.path.abspath(__file__)).parent
    spec = importlib.util.find_spec("ltv_lstm_mpc.solvers")
    locations = list(spec.submodule_search_locations or []) if spec is not None else []
    return (here, *(Path(os.path.abspath(location)) for location in locations))


def sources_fingerprint(roots: Sequence[Path]) -> str:
    """A digest of the relative path, modification time and size of every Python file
    under ``roots`` (a file that vanishes while they are read is left out)."""
    digest = hashlib.sha1()
    for number, root in enumerate(roots):
        if not root.is_dir():
            continue
        for path in sorted(root.rglob("*.py")):
            try:
                stat = path.stat()
            except OSError:  # removed meanwhile, or a dangling link (an editor's lock file)
                continue
            relative = path.relative_to(root).as_posix()
            digest.update(f"{number}:{relative}\0{stat.st_mtime_ns}\0{stat.st_size}\n".encode())
    return digest.hexdigest()


def _tolerant_index(load_index: Any) -> Any:
    """numba's cache-index loader, reading an index it cannot unpickle as empty (a cache
    miss: the kernel compiles again and writes a new index).

    numba unpickles an index before it compares its stamp, and the index's keys hold the
    argument types of the cached kernels; an index written by an earlier version of this
    package names a type that has moved or gone since (a workspace type of a module that
    was split), which raises ``AttributeError`` or ``ImportError`` instead of a miss."""

    def load() -> Any:
        try:
            return load_index()
        except (AttributeError, ImportError, pickle.UnpicklingError, EOFError, TypeError):
            return {}

    return load


def make_njit(roots: Sequence[Path], fingerprint: str | None = None) -> Any:
    """numba's ``njit`` whose on-disk caches are valid only while no Python file under
    ``roots`` has changed (the fingerprint of :func:`sources_fingerprint`, taken now
    unless given as ``fingerprint``).

    numba checks a cached function against its own source file only, so a kernel that
    calls a kernel of another file (the one-call step calls the observer, the chord
    Newton, the condensing and the feedback; ``cone_feedback`` calls the SOCP solver)
    would load the callee's old machine code after only the callee's file was edited or
    upgraded, and compute with it. Here each cached kernel's index carries numba's stamp
    of its own file together with the fingerprint of all of them, so numba itself finds
    every such cache stale and compiles again from the current sources, in whatever
    folder it keeps its caches; a process that still runs old code (a background compile,
    a Dask worker, a notebook) writes caches with its old fingerprint, which the others do
    not take. Without numba: a stand-in that leaves a function as Python.
    """
    if not AVAILABLE:

        def stand_in(*args: Any, **kwargs: Any) -> Any:
            """Stand-in: returns the Python function unchanged."""
            if len(args) == 1 and callable(args[0]) and not kwargs:
                return args[0]

            def wrap(function: Any) -> Any:
                return function

            return wrap

        return stand_in
    if fingerprint is None:
        fingerprint = sources_fingerprint(roots)

    def stamped(dispatcher: Any) -> Any:
        cache_file = getattr(getattr(dispatcher, "_cache", None), "_cache_file", None)
        if cache_file is not None and hasattr(cache_file, "_source_stamp"):
            cache_file._source_stamp = (cache_file._source_stamp, fingerprint)
            cache_file._load_index = _tolerant_index(cache_file._load_index)
        return dispatcher

    def njit(*args: Any, **kwargs: Any) -> Any:
        """``numba.njit`` with the fingerprint of the sources in its cache's stamp."""
        result = _numba_njit(*args, **kwargs)
        if not callable(result) or hasattr(result, "py_func"):  # a dispatcher already
            return stamped(result)
        return lambda function: stamped(result(function))

    return njit


try:  # pragma: no cover - numba is a core dependency
    from numba import njit as _numba_njit

    AVAILABLE = True
except ImportError:  # pragma: no cover - exercised in a subprocess by the tests
    AVAILABLE = False

#: The fingerprint of every source file of this package and its solver layer, taken at
#: import (:func:`sources_fingerprint`): what the kernels' cache stamps carry, and what a
#: failed background compile's marker records (:mod:`ltv_lstm_mpc.loop.kernels`).
SOURCES_FINGERPRINT = sources_fingerprint(_kernel_packages()) if AVAILABLE else ""

#: The one ``njit`` of every compiled kernel of this package and its solver layer
#: (:func:`make_njit`: caches valid only while none of their source files has changed).
njit = make_njit(_kernel_packages(), SOURCES_FINGERPRINT)


#: LLVM flags of the compiled loops whose sums may run in any order (vectorized reductions,
#: fused multiply-adds): results within a few ulps of the sequential sums. No "fast" flags
#: that assume finite values: NaN and inf still propagate and are caught by the callers'
#: checks. One definition for every kernel that uses them.
REDUCTIONS = {"reassoc", "contract"}


#: The workspace classes made by :func:`workspace_type` (for :func:`prime_typeof`).
_WORKSPACE_TYPES: list[type] = []


def prime_typeof() -> None:
    """Resolve now how numba types an instance of each workspace class
    (:func:`workspace_type`): numba types such an argument through
    ``functools.singledispatch``, whose cache starts empty and is cleared by every new
    registration, and its first lookup for a class costs 0.2-0.8 ms on 2 cores (up to
    12 ms right after the kernels load), which the first compiled steps would pay. A
    controller calls it at the end of its construction."""
    if not AVAILABLE:
        return
    from numba.core.typing.typeof import typeof_impl

    for proxy in _WORKSPACE_TYPES:
        typeof_impl.dispatch(proxy)


def workspace_type(name: str, fields: Sequence[str], doc: str, module: str) -> Any:
    """A typed workspace class: named fields that travel into compiled kernels as one object.

    With numba: a ``numba.experimental.structref`` proxy (a mutable struct of the given
    fields, typed at construction; a kernel reads ``workspace.M`` by name, so no argument
    order can be swapped, and one object crosses the Python/compiled boundary instead of
    many arrays; dispatch costs what one argument costs). Without numba: a ``NamedTuple``
    with the same fields (the kernels are then plain Python).

    Why structref and not the alternatives (measured on this machine kind, 20 arrays):
    a ``namedtuple`` argument is typed by numba's Python fallback (3.5 us per call against
    1.3 us for 20 positional arrays); ``jitclass`` dispatches fastest (0.8 us) but functions
    taking one cannot be cached on disk, so every process would recompile the kernels;
    a structref dispatches in 1.4 us and its kernels are cached. Its cost is a one-off
    per process: about 0.6 s for the first workspace type constructed, 0.15 s for each
    further one.

    Arrays stored in a workspace are shared with their owners (the kernels write into the
    owners' buffers); scalars are copied, so values that change between calls stay
    arguments of the kernel.

    ``module`` is the defining module's ``__name__``: bind the result there as ``name``
    and its numba type as ``name + "Type"`` (``proxy.numba_type``), so that the on-disk
    cache of the kernels finds both by module and name.
    """
    import collections

    if not AVAILABLE:
        tuple_type = collections.namedtuple(name, list(fields), module=module)  # type: ignore[misc]
        tuple_type.__doc__ = doc
        return tuple_type
    from numba.core import types
    from numba.experimental import structref

    def preprocess_fields(self: Any, given: Any) -> Any:
        return tuple((field, types.unliteral(typ)) for field, typ in given)

    numba_type = type(
        f"{name}Type",
        (types.StructRef,),
        {"preprocess_fields": preprocess_fields, "__module__": module},
    )
    structref.register(numba_type)
    proxy = type(name, (structref.StructRefProxy,), {"__doc__": doc, "__module__": module})
    structref.define_proxy(proxy, numba_type, list(fields))
    proxy.numba_type = numba_type  # type: ignore[attr-defined]
    _WORKSPACE_TYPES.append(proxy)
    return proxy


def build_workspace(factory: Any, fields: Sequence[str], values: dict[str, Any]) -> Any:
    """A workspace from ``values`` given by field name: ``factory`` (a compiled constructor
    whose parameters are ``fields``, in that order; a test checks it) gets them in field
    order, so no caller passes them by position.

    Raises
    ------
    TypeError
        A field is missing or unknown (the message names them).
    """
    missing = [name for name in fields if name not in values]
    unknown = [name for name in values if name not in fields]
    if missing or unknown:
        raise TypeError(
            f"workspace fields: missing {missing}, unknown {unknown}; expected {list(fields)}"
        )
    return factory(*(values[name] for name in fields))


def entry_point(dispatcher: Any, args: Sequence[Any]) -> Any:
    """The compiled entry point of ``dispatcher`` for exactly the types of ``args``, or None
    (not compiled for them yet, not a numba dispatcher, or no numba).

    Calling it skips numba's type dispatch, which types each workspace argument through
    Python (about 2 us per workspace on this machine kind, 4 of the 6 us a call with two
    workspaces costs), but also skips its checks: the caller must pass arguments of the
    same types as ``args`` (the one-call step does so only while every argument is one it
    placed there itself; otherwise it calls the dispatcher).
    """
    overloads = getattr(dispatcher, "overloads", None)
    if not AVAILABLE or overloads is None:
        return None
    from numba import typeof

    compiled = overloads.get(tuple(typeof(value) for value in args))
    return None if compiled is None else compiled.entry_point


_compile_announced = False


_compile_on_demand = False


def compile_on_demand() -> None:
    """This process runs compiled kernels (a controller chose them): from now on
    :func:`ready` answers yes, so that the helpers with a Python fallback compile at their
    first call too (and land in the cache for the next runs)."""
    global _compile_on_demand
    _compile_on_demand = True


def ready(dispatchers: Sequence[Any]) -> bool:
    """Every one of ``dispatchers`` may run compiled: numba is installed and each is
    compiled in this process or held by the on-disk cache, or this process compiles on
    demand (:func:`compile_on_demand`). What the helpers with a numpy or Python fallback
    ask before their first call (no compile wait where a fallback exists).
    """
    if not AVAILABLE:
        return False
    if _compile_on_demand:
        return True
    if all(getattr(dispatcher, "signatures", None) for dispatcher in dispatchers):
        return True
    return not uncached(dispatchers)


def uncached(dispatchers: Sequence[Any]) -> list[str]:
    """Names of the compiled functions among ``dispatchers`` that the on-disk cache cannot
    serve (no entry for their current source): they compile at their first call.

    Reads numba's cache index; anything unexpected there counts as cached (say nothing
    rather than something wrong).
    """
    missing = []
    for dispatcher in dispatchers:
        try:
            index = dispatcher._cache._cache_file._load_index()
        except Exception:  # numba internals: an unknown layout counts as cached
            continue
        if not index:
            missing.append(getattr(dispatcher, "__name__", str(dispatcher)))
    return missing


def load_cached(dispatchers: Sequence[Any]) -> list[str]:
    """Load now, from numba's on-disk cache, every compiled version of ``dispatchers`` it
    holds for this machine and these sources that this process has not loaded yet.

    numba loads a cached kernel at its first call only: a controller built on a warm
    cache would spend its first steps reading and linking machine code (some 5 ms per
    step over the first 20 steps on 2 cores, before a step takes its 0.04 ms), which a
    controller's construction can do instead. Only versions whose index entry matches this
    machine and these sources and whose data file exists are asked for (numba's own
    ``Dispatcher.compile``, which reads them from the cache): nothing compiles here unless
    such a file cannot be read (then it compiles now instead of at its first call).

    A function that already has a compiled version in this process is skipped (the
    next controllers of a process read no cache index).

    Returns
    -------
    list of str
        Names of the functions among ``dispatchers`` that had nothing to load (no entry
        for this machine and these sources, or numba's internals not as expected).
    """
    if not AVAILABLE:
        return []
    nothing = []
    for dispatcher in dispatchers:
        name = getattr(dispatcher, "__name__", str(dispatcher))
        if getattr(dispatcher, "signatures", None):
            continue  # loaded or compiled in this process already (a later controller)
        try:
            cache = dispatcher._cache
            cache_file = cache._cache_file
            index = cache_file._load_index()
            codegen = dispatcher.targetctx.codegen()
            signatures = [
                key[0]
                for key, filename in index.items()
                if cache._index_key(key[0], codegen) == key
                and os.path.exists(cache_file._data_path(filename))
            ]
        except Exception:  # numba internals not as expected: loads at its first call
            nothing.append(name)
            continue
        if not signatures:
            nothing.append(name)
        for signature in signatures:
            if tuple(signature) not in dispatcher.overloads:
                dispatcher.compile(signature)  # numba's own path: from the cache
    return nothing


def say_once(message: str) -> bool:
    """Print ``message`` on stderr unless this process has already said one (the compile
    notice and the controller's kernel choice share it); returns whether it printed."""
    global _compile_announced
    if _compile_announced:
        return False
    _compile_announced = True
    import sys

    print(message, file=sys.stderr, flush=True)
    return True


def announce_compile(dispatchers: Sequence[Any], what: str, seconds: str) -> bool:
    """Say once per process, on stderr, that ``what`` compiles now (first run only) when
    any of ``dispatchers`` is not in the on-disk cache; returns whether it said so."""
    if _compile_announced or not AVAILABLE or not uncached(dispatchers):
        return False
    return say_once(compile_notice(what, seconds))


def compile_notice(what: str, seconds: str) -> str:
    """The one wording of the notice that ``what`` compiles now."""
    return (
        f"ltv_lstm_mpc: compiling {what} (first run only, about {seconds} on 2 cores; "
        "cached on disk for the next runs)..."
    )
