"""Registry of installed backends: names, capabilities, factories and compiled forms.

Sessions over it (:class:`~ltv_lstm_mpc.solvers.Session`, :func:`~ltv_lstm_mpc.solvers.solve`)
live in :mod:`~ltv_lstm_mpc.solvers.session`, which imports this module (not the other way:
no import cycle).
"""

from __future__ import annotations

import difflib
import functools
import importlib
import importlib.util
import re
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from ltv_lstm_mpc.exceptions import InvalidValueError, SolverNotFound

from ._adapters import convex_from_dense, dense_from_convex
from ._base import BackendFactory
from .compiled_forms import CompiledForm, dense_check_form
from .dense import DenseBackendFactory
from .tolerances import FIRST_ORDER, note_registered

__all__ = [
    "DEFAULT_SOLVER",
    "CompiledForm",
    "SolverInfo",
    "available_solvers",
    "compiled_form",
    "cone_solvers",
    "default_solver",
    "get_backend",
    "get_dense_backend",
    "register_backend",
    "solver_info",
    "unregister_backend",
]

#: Solver of :class:`Session` and :func:`solve` when none is named: any
#: :class:`ConvexProblem` (every cone, sparse data), interior point, high accuracy. The MPC's
#: default is :func:`default_solver` (the fastest exact one installed).
DEFAULT_SOLVER = "cvxpy:CLARABEL"
_EXTRA_HINT = 'pip install "ltv_lstm_mpc[solvers]"'
#: The MPC's solvers that solve its second-order cones exactly, fastest first (median
#: step on the paper's scenarios at N = 5: 0.03-0.05 ms, about 0.3 ms, 2.5-7 ms):
#: :func:`default_solver` takes the first one installed.
EXACT_SOLVERS_BY_SPEED = ("daqp:socp", "clarabel", "cvxpy:CLARABEL", "cvxpy:ECOS")
#: Accepted registry names: letters, digits and ``_ . : @ , + -`` (no spaces).
_NAME_RE = re.compile(r"[A-Za-z0-9_][A-Za-z0-9_.:@,+\-]*")
#: Native backends that solve second-order cones exactly.
NATIVE_CONE_SOLVERS = frozenset({"clarabel", "daqp:socp"})


@dataclass(frozen=True)
class SolverInfo:
    """What a registered solver can do.

    Attributes
    ----------
    name : str
        Registry name.
    family : str
        ``"cvxpy"``, ``"qpsolvers"``, ``"osqp"``, ``"piqp"``, ``"daqp"``,
        ``"quadprog"``, ``"proxqp"``, ``"clarabel"`` or ``"user"`` (:func:`register_backend`).
    supports_cones : bool
        Solves second-order cones exactly.
    native_dense : bool
        Has a dedicated :class:`~ltv_lstm_mpc.solvers.DenseBackend` (no
        conversion to a ConvexProblem), i.e. is meant for condensed MPC QPs.
    first_order : bool
        A first-order method (OSQP, SCS, ProxQP): accurate to about ``1e3 *
        tolerance``, see :func:`~ltv_lstm_mpc.solvers.feasibility_tolerance`.
    """

    name: str
    family: str
    supports_cones: bool
    native_dense: bool
    first_order: bool


#: What builds a backend's :class:`~ltv_lstm_mpc.solvers.compiled_forms.CompiledForm` from
#: the registry name.
CompiledFormFactory = Callable[[str], CompiledForm]


@dataclass(frozen=True)
class _Entry:
    info: SolverInfo
    factory: BackendFactory | None
    dense_factory: DenseBackendFactory | None
    compiled: CompiledFormFactory | None = None


def _installed(module: str) -> bool:
    return importlib.util.find_spec(module) is not None


def _module(name: str) -> Any:
    return importlib.import_module(f"{__package__}.{name}")


def _native_entries() -> list[tuple[str, str, Callable[[], tuple[Any, Any]]]]:
    """(name, module to find, loader of (factory, dense_factory)) of the native backends."""
    return [
        ("osqp", "osqp", lambda: (_module("osqp_").make, _module("osqp_").make_dense)),
        ("piqp", "piqp", lambda: (_module("piqp_").make_auto, _module("piqp_").make_dense_qp)),
        ("piqp:sparse", "piqp", lambda: (_module("piqp_").make_sparse, None)),
        (
            "piqp:dense",
            "piqp",
            lambda: (_module("piqp_").make_dense, _module("piqp_").make_dense_qp),
        ),
        ("daqp", "daqp", lambda: (_module("daqp_").make, _module("daqp_").make_dense)),
        ("daqp:socp", "daqp", _daqp_socp),
        ("quadprog", "quadprog", lambda: (None, _module("quadprog_").make_dense)),
        ("clarabel", "clarabel", lambda: (None, _module("clarabel_").make_dense)),
        ("proxqp", "proxsuite", lambda: (None, _module("proxqp_").make_dense)),
    ]


#: Native backends that advertise a compiled form: name -> module whose ``compiled_form``
#: builds it (the other cone solvers get :func:`~.compiled_forms.dense_check_form`).
_COMPILED_FORMS = {"daqp": "daqp_", "daqp:socp": "daqp_socp", "clarabel": "clarabel_"}


def _compiled_factory(name: str, cones: bool) -> CompiledFormFactory | None:
    """The compiled form factory of the installed backend ``name`` (one that solves cones
    exactly when ``cones``), or None: it has none."""
    if name in _COMPILED_FORMS:
        factory: CompiledFormFactory = _module(_COMPILED_FORMS[name]).compiled_form
        return factory
    return dense_check_form if cones else None


def _daqp_socp() -> tuple[Any, Any]:
    """The exact-cone SQP on DAQP: only where DAQP's C entry point is bound natively."""
    from . import daqp_native

    if not daqp_native.bound():
        raise ImportError(daqp_native.unavailable_reason or "DAQP is not bound natively")
    return None, _module("daqp_socp").make_dense


@functools.cache
def _registry() -> dict[str, _Entry]:
    """Name -> entry for every backend that imports (guarded imports, computed once)."""
    reg: dict[str, _Entry] = {}
    try:
        import cvxpy as cp

        from . import cvxpy_

        for s in cvxpy_.supported_solvers(cp.installed_solvers()):
            name = f"cvxpy:{s}"
            cones = s in cvxpy_.CONE_SOLVERS
            info = SolverInfo(name, "cvxpy", cones, True, s.lower() in FIRST_ORDER)
            compiled = _compiled_factory(name, cones)
            reg[name] = _Entry(info, cvxpy_.factory(s), cvxpy_.dense_factory(s), compiled)
    except ImportError:
        pass
    try:
        import qpsolvers

        from . import qpsolvers_

        for s in sorted(qpsolvers.available_solvers):
            name = f"qpsolvers:{s}"
            info = SolverInfo(name, "qpsolvers", False, True, s.lower() in FIRST_ORDER)
            reg[name] = _Entry(info, qpsolvers_.factory(s), qpsolvers_.dense_factory(s))
    except ImportError:
        pass
    for name, _module, _loader in _native_entries():
        entry = _native_entry(name)
        if entry is not None:
            reg[name] = entry
    return reg


def available_solvers() -> list[str]:
    """Names of the installed solvers, each once, e.g. ``["cvxpy:CLARABEL", ..., "daqp"]``.

    ``cvxpy:<SOLVER>`` for the cvxpy solvers this layer supports (CLARABEL, ECOS,
    SCS for cones; OSQP, PIQP, PROXQP, DAQP, HIGHS for QPs), ``qpsolvers:<name>``
    for every solver in ``qpsolvers.available_solvers``, the native ``osqp``,
    ``piqp`` (``piqp:sparse``, ``piqp:dense``), ``daqp``, ``daqp:socp`` (dense, exact
    cones by SQP on DAQP), ``quadprog``, ``proxqp`` and ``clarabel`` (dense, exact cones),
    then the solvers added with
    :func:`register_backend`.
    """
    return list(_registry())


def cone_solvers() -> list[str]:
    """Installed solvers that solve second-order cones exactly."""
    return [name for name, entry in _registry().items() if entry.info.supports_cones]


@functools.cache
def _native_entry(name: str) -> _Entry | None:
    """The entry of the native backend ``name`` alone (None: not a native name, or not
    installed): what :func:`_entry` answers before the full registry is built, so that
    asking for ``daqp`` does not import cvxpy and qpsolvers (about 1 s)."""
    for entry_name, module, loader in _native_entries():
        if entry_name != name:
            continue
        if not _installed(module):
            return None
        try:
            factory, dense = loader()
        except ImportError:
            return None
        family = name.split(":")[0]
        cones = name in NATIVE_CONE_SOLVERS
        return _Entry(
            SolverInfo(name, family, cones, dense is not None, family in FIRST_ORDER),
            factory,
            dense,
            _compiled_factory(name, cones),
        )
    return None


def _entry(name: str) -> _Entry:
    if isinstance(name, str) and _registry.cache_info().currsize == 0:
        # the full registry is not built: no backend was registered, replaced or removed
        native = _native_entry(name)
        if native is not None:
            return native
    reg = _registry()
    entry = reg.get(name) if isinstance(name, str) else None
    if entry is not None:
        return entry
    raise SolverNotFound(_not_found_message(name, list(reg)))


def _suggestions(name: str, installed: list[str]) -> list[str]:
    """Installed names ``name`` may have meant: the same name up to case and surrounding
    spaces (also after a ``family:`` prefix, ``'DAQP'`` -> ``'daqp'``, ``'cvxpy:DAQP'``),
    else the close matches of :func:`difflib.get_close_matches`."""
    key = name.strip().lower()
    same = [s for s in installed if key in (s.lower(), s.lower().rpartition(":")[2])]
    if same:
        return sorted(same, key=lambda s: (s.lower() != key, ":" in s, s))[:3]
    lowered = {s.lower(): s for s in installed}
    return [lowered[s] for s in difflib.get_close_matches(key, list(lowered), n=3, cutoff=0.8)]


def _why_missing(name: str) -> str:
    """Why ``name`` is not in the registry, said truthfully: the package it needs is not
    installed (install advice), or it is installed but this build cannot use it, or the
    name is not one of the library's at all (no install advice)."""
    family, _, solver = name.strip().partition(":")
    native = {entry: module for entry, module, _ in _native_entries()}
    if name in native:
        if not _installed(native[name]):
            return f"its package {native[name]!r} is not installed: {_EXTRA_HINT}"
        if name == "daqp:socp":
            from . import daqp_native

            reason = daqp_native.unavailable_reason or "DAQP is not bound natively"
            return f"daqp is installed but its C entry point is not bound here ({reason})"
        return f"its package {native[name]!r} is installed but failed to import"
    if family in ("cvxpy", "qpsolvers") and solver:
        if not _installed(family):
            return f"{family} is not installed: {_EXTRA_HINT}"
        return (
            f"{family} is installed but has no solver {solver!r} installed; that solver's own "
            "package (and licence, for a commercial one) is not part of ltv_lstm_mpc[solvers]"
        )
    if name.strip().upper() in _CVXPY_KNOWN:
        installed_cvxpy = _installed("cvxpy")
        return (
            f"it is not a name of this library; {name.strip().upper()} is a solver cvxpy "
            f"knows, used as 'cvxpy:{name.strip().upper()}' once its own package (and "
            "licence, for a commercial one) is installed"
            + ("" if installed_cvxpy else f", with cvxpy: {_EXTRA_HINT}")
        )
    return (
        "names are 'cvxpy:<SOLVER>', 'qpsolvers:<solver>', 'osqp', 'piqp', 'daqp', "
        "'daqp:socp', 'quadprog', 'proxqp', 'clarabel' or one added with register_backend()"
    )


#: Solvers cvxpy can call once their package is installed (cvxpy's own list, abridged).
_CVXPY_KNOWN = frozenset(
    {"GUROBI", "MOSEK", "CPLEX", "XPRESS", "COPT", "CVXOPT", "GLPK", "GLOP", "SCIP", "KNITRO"}
)


def _not_found_message(name: object, installed: list[str]) -> str:
    """The message of :class:`SolverNotFound` for ``name``: did you mean, why it is missing
    (install advice only when the package is missing) and the installed names."""
    if not isinstance(name, str):
        return f"a solver name must be a string, got {type(name).__name__} {name!r}"
    suggestions = _suggestions(name, installed)
    exact = name.strip().lower() in map(str.lower, suggestions)
    why = "" if exact else f" ({_why_missing(name)})"
    mean = f"; did you mean {' or '.join(repr(s) for s in suggestions)}?" if suggestions else "."
    listed = ", ".join(installed) or f"none ({_EXTRA_HINT})"
    return f"solver {name!r} is not available{why}{mean} Installed: {listed}"


def default_solver() -> str:
    """The MPC's default solver: the fastest installed one that solves the terminal
    second-order cones exactly (:data:`EXACT_SOLVERS_BY_SPEED`): ``"daqp:socp"`` where DAQP
    is installed and bound natively, else the native ``"clarabel"``, else
    ``"cvxpy:CLARABEL"``, else ``"cvxpy:ECOS"``. With none installed, ``"cvxpy:CLARABEL"``
    (using it raises :class:`SolverNotFound` with the install command).

    ``MPCConfig().solver`` and every command line's ``--solver`` default to it. Asking does
    not import cvxpy where a native solver answers.
    """
    for name in EXACT_SOLVERS_BY_SPEED:
        if _registry.cache_info().currsize:  # built: registered or removed names count
            if name in _registry():
                return name
        elif _native_entry(name) is not None:
            return name
        elif name.startswith("cvxpy:") and _installed("cvxpy") and name in _registry():
            return name
    return DEFAULT_SOLVER


def solver_info(name: str) -> SolverInfo:
    """Capabilities of the solver ``name``.

    Raises
    ------
    SolverNotFound
        If ``name`` is not installed (or unknown); the message lists the
        installed solvers and the extra to install.
    """
    return _entry(name).info


def compiled_form(name: str) -> CompiledForm | None:
    """What the solver ``name`` gives compiled (numba) callers, or None: it has nothing
    compiled (:mod:`~ltv_lstm_mpc.solvers.compiled_forms` lists the forms).

    The MPC layer reads its solver's form where it builds its compiled kernels (the
    functions to compile ahead, the one-call feedback's solve and workspace), never per
    step. A backend added with :func:`register_backend` has the dense layer's form where it
    solves cones (:func:`~ltv_lstm_mpc.solvers.compiled_forms.dense_check_form`), else none;
    replacing a built-in name replaces its form too.

    Raises
    ------
    SolverNotFound
        As :func:`solver_info`.
    """
    entry = _entry(name)
    return None if entry.compiled is None else entry.compiled(name)


def get_backend(name: str) -> BackendFactory:
    """ConvexProblem factory of the backend ``name`` (a dense-only one through an adapter).

    Raises
    ------
    SolverNotFound
        If ``name`` is not installed (or unknown); the message lists the
        installed solvers and the extra to install.
    """
    entry = _entry(name)
    if entry.factory is not None:
        return entry.factory
    assert entry.dense_factory is not None  # an entry has at least one factory
    return convex_from_dense(entry.dense_factory)


def get_dense_backend(name: str) -> DenseBackendFactory:
    """Dense factory of the backend ``name`` (a ConvexProblem-only one through an adapter).

    Raises
    ------
    SolverNotFound
        As :func:`get_backend`.
    """
    entry = _entry(name)
    if entry.dense_factory is not None:
        return entry.dense_factory
    assert entry.factory is not None
    return dense_from_convex(entry.factory)


def _check_name(name: object) -> str:
    if not isinstance(name, str) or not _NAME_RE.fullmatch(name):
        raise InvalidValueError(
            f"solver name must be a non-empty string of letters, digits and '_.:@,+-' "
            f"(no spaces), got {name!r}"
        )
    return name


def _add(name: str, entry: _Entry, replace: bool) -> str:
    reg = _registry()
    if name in reg and not replace:
        raise InvalidValueError(
            f"solver {name!r} is already registered; pass replace=True to replace it"
        )
    reg[name] = entry
    note_registered(name, entry.info.first_order)
    return name


def register_backend(
    name: str,
    factory: BackendFactory | None = None,
    *,
    dense_factory: DenseBackendFactory | None = None,
    supports_cones: bool = False,
    first_order: bool = False,
    replace: bool = False,
) -> str:
    """Add a solver of your own to the registry (the public extension point).

    Parameters
    ----------
    name : str
        Registry name: letters, digits and ``_ . : @ , + -``, no spaces.
    factory : callable, optional
        ``factory(name, tolerance, settings) -> Backend`` (a subclass of
        :class:`~ltv_lstm_mpc.solvers.Backend`) for ConvexProblems
        (:class:`Session`, :func:`solve`).
    dense_factory : callable, optional
        ``dense_factory(name, tolerance, settings) -> DenseBackend`` for
        :class:`~ltv_lstm_mpc.solvers.DenseSession`. At least one of the two
        factories is needed; the missing one is served by a generic adapter
        (dense QPs converted to ConvexProblems, or cone-free ConvexProblems
        converted to dense QPs).
    supports_cones : bool
        Whether ``factory``'s backend solves second-order cones exactly
        (listed by :func:`cone_solvers`; its ``Backend.supports_cones`` decides
        what a session does).
    first_order : bool
        Whether it is a first-order method (:func:`feasibility_tolerance`).
    replace : bool
        Replace an existing entry of that name (else that is an error).

    Returns
    -------
    str
        ``name``, now listed by :func:`available_solvers`.

    Raises
    ------
    InvalidValueError
        Bad name, no factory, a factory that is not callable, or an existing
        name without ``replace=True``.
    """
    _check_name(name)
    if factory is None and dense_factory is None:
        raise InvalidValueError(
            f"register_backend({name!r}): give factory=..., dense_factory=... or both"
        )
    for label, f in (("factory", factory), ("dense_factory", dense_factory)):
        if f is not None and not callable(f):
            raise InvalidValueError(
                f"register_backend({name!r}): {label} must be callable, got {type(f).__name__}"
            )
    info = SolverInfo(name, "user", bool(supports_cones), dense_factory is not None, first_order)
    compiled = dense_check_form if supports_cones else None
    return _add(name, _Entry(info, factory, dense_factory, compiled), replace)


def unregister_backend(name: str) -> None:
    """Remove ``name`` from the registry (any entry, built-in ones included).

    Raises
    ------
    SolverNotFound
        If ``name`` is not registered.
    """
    _entry(name)
    del _registry()[name]
    note_registered(name, None)
