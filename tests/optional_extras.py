"""Skips for the tests that need an optional extra (a solver backend or a package).

The suite passes on the core install (``pip install -e . daqp pytest hypothesis``): a test
that needs a backend or package of an extra skips where it is missing (counted in pytest's
summary, the reason listed by ``-ra``) and runs where it is installed. Only a missing
optional package skips: a backend name that no extra provides raises (a typo fails the
test instead of skipping it), and a backend whose package is installed but does not import
is not skipped (the test runs and fails, showing why).

A module of its own, not ``conftest.py``: ``tests/`` and ``tests/solvers/`` each have a
``conftest.py``, so ``from conftest import ...`` would not name one reliably.

- ``@requires_solver("cvxpy:CLARABEL")``: a ``skipif`` mark, on a test, a module
  (``pytestmark``) or a parameter (:func:`backend_params`).
- :func:`require_solver` / :func:`first_installed`: the same, called inside a test or a
  helper (a reference solution computed on demand).
- :func:`requires_package`: a ``skipif`` mark for a package (``pytest.importorskip`` inside
  a test).
"""

from __future__ import annotations

import importlib.util

import pytest
from ltv_lstm_mpc.solvers import available_solvers, registry

__all__ = [
    "backend_params",
    "first_installed",
    "missing_solver",
    "require_solver",
    "requires_daqp_binding",
    "requires_package",
    "requires_solver",
]

#: The extra that installs the solver backends (its install hint in the skip reasons).
SOLVERS_EXTRA = "solvers"


def _installed(package: str) -> bool:
    return importlib.util.find_spec(package) is not None


def missing_solver(name: str) -> str | None:
    """Why backend ``name`` cannot run here (a skip reason), None where it can.

    A reason only where an optional package is missing: ``cvxpy`` / ``qpsolvers`` or the
    solver it would call, a native backend's package, or DAQP's C entry point for
    ``daqp:socp`` (bound for DAQP 0.11 only). Raises ``ValueError`` for a name that is not
    a backend of the library's extras (a typo in a test).
    """
    if name in available_solvers():
        return None
    family, _, solver = name.partition(":")
    if family in ("cvxpy", "qpsolvers") and solver:
        if not _installed(family):
            return f"{name} needs {family} (extra {SOLVERS_EXTRA!r})"
        return f"{name} needs {solver}, not installed with {family}"
    packages = {entry: package for entry, package, _ in registry._native_entries()}
    if name not in packages:
        raise ValueError(f"{name!r} is not a backend of ltv_lstm_mpc's extras (a typo?)")
    if not _installed(packages[name]):
        return f"{name} needs the package {packages[name]!r} (extra {SOLVERS_EXTRA!r})"
    if name == "daqp:socp":
        from ltv_lstm_mpc.solvers import daqp_native

        return f"daqp:socp needs DAQP's C entry point ({daqp_native.unavailable_reason})"
    return None  # installed but not importable: the test runs and shows the error


def _reasons(names: tuple[str, ...]) -> list[str]:
    return [reason for reason in map(missing_solver, names) if reason is not None]


def requires_solver(*names: str) -> pytest.MarkDecorator:
    """A mark that skips the test (module, parameter) unless every backend in ``names`` is
    installed."""
    reasons = _reasons(names)
    return pytest.mark.skipif(bool(reasons), reason="; ".join(reasons) or "installed")


def require_solver(*names: str) -> None:
    """Skip the running test unless every backend in ``names`` is installed."""
    __tracebackhide__ = True  # the skip is reported at the caller's line
    reasons = _reasons(names)
    if reasons:
        pytest.skip("; ".join(reasons))


def first_installed(*names: str) -> str:
    """The first installed backend of ``names`` (a reference solver, in order of
    preference); skips the running test where none is."""
    __tracebackhide__ = True
    for name in names:
        if missing_solver(name) is None:
            return name
    pytest.skip("needs one of: " + "; ".join(_reasons(names)))


def backend_params(*names: str) -> list[object]:
    """``pytest.param(name, id=name)`` for each backend, skipped where it is missing: the
    parametrization of a test over named backends (over the installed ones:
    ``available_solvers()``)."""
    return [pytest.param(name, id=name, marks=requires_solver(name)) for name in names]


def requires_package(package: str, extra: str) -> pytest.MarkDecorator:
    """A mark that skips the test unless ``package`` (of the extra ``extra``) is installed."""
    return pytest.mark.skipif(not _installed(package), reason=f"needs {package} (extra {extra!r})")


def requires_daqp_binding() -> pytest.MarkDecorator:
    """A mark that skips the test unless DAQP's C entry point is bound natively
    (``solvers.daqp_native``; binding runs its self-test, which compiles on an empty numba
    cache: call this where the module is already known to import)."""
    from ltv_lstm_mpc.solvers import daqp_native

    return pytest.mark.skipif(
        daqp_native.native({}) is None,
        reason=f"DAQP not bound natively: {daqp_native.unavailable_reason}",
    )
