"""No import cycles between the library's packages or modules (lazy imports count; imports
only for type checking do not)."""

from __future__ import annotations

import ast
import sys
from collections import defaultdict
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


def _modules() -> dict[str, Path]:
    """Module name -> file, with ``solvers/`` installed as ``ltv_lstm_mpc.solvers``."""
    found: dict[str, Path] = {}
    for path in sorted((ROOT / "ltv_lstm_mpc").rglob("*.py")):
        parts = list(path.relative_to(ROOT).with_suffix("").parts)
        if parts[-1] == "__init__":
            parts = parts[:-1]
        found[".".join(parts)] = path
    for path in sorted((ROOT / "solvers").glob("*.py")):
        suffix = "" if path.stem == "__init__" else "." + path.stem
        found["ltv_lstm_mpc.solvers" + suffix] = path
    return found


def _graph(modules: dict[str, Path]) -> dict[str, set[str]]:
    """Module -> the library modules it imports anywhere in its code."""
    graph: dict[str, set[str]] = defaultdict(set)
    for name, path in modules.items():
        tree = ast.parse(path.read_text(encoding="utf-8"))
        typing_only = {
            id(node)
            for block in ast.walk(tree)
            if isinstance(block, ast.If) and "TYPE_CHECKING" in ast.unparse(block.test)
            for node in ast.walk(block)
        }
        package = name if path.name == "__init__.py" else name.rsplit(".", 1)[0]
        for node in ast.walk(tree):
            if id(node) in typing_only:
                continue
            if isinstance(node, ast.ImportFrom):
                if node.level:
                    base = package.split(".")[: len(package.split(".")) - (node.level - 1)]
                    target = ".".join(base + ([node.module] if node.module else []))
                else:
                    target = node.module or ""
                if not target.startswith("ltv_lstm_mpc"):
                    continue
                for alias in node.names:
                    child = f"{target}.{alias.name}"
                    graph[name].add(child if child in modules else target)
            elif isinstance(node, ast.Import):
                graph[name].update(a.name for a in node.names if a.name.startswith("ltv_lstm_mpc"))
    return graph


def _cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """Strongly connected components with more than one node (Tarjan)."""
    sys.setrecursionlimit(max(sys.getrecursionlimit(), 10_000))
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    found: list[list[str]] = []

    def visit(node: str) -> None:
        index[node] = low[node] = len(index)
        stack.append(node)
        on_stack.add(node)
        for other in graph.get(node, ()):
            if other not in index:
                visit(other)
                low[node] = min(low[node], low[other])
            elif other in on_stack:
                low[node] = min(low[node], index[other])
        if low[node] == index[node]:
            component = []
            while True:
                other = stack.pop()
                on_stack.discard(other)
                component.append(other)
                if other == node:
                    break
            if len(component) > 1:
                found.append(sorted(component))

    for node in sorted(set(graph) | {b for targets in graph.values() for b in targets}):
        if node not in index:
            visit(node)
    return found


def test_no_module_import_cycles() -> None:
    assert _cycles(_graph(_modules())) == []


def test_no_package_import_cycles() -> None:
    """Packages: ``ltv_lstm_mpc.<package>``; the top-level modules (exceptions, validation,
    the package's ``__init__``) are below every package and not counted."""
    modules = _modules()
    graph = _graph(modules)
    packages: dict[str, set[str]] = defaultdict(set)

    def package(module: str) -> str | None:
        parts = module.split(".")
        if len(parts) > 2:
            return ".".join(parts[:2])
        path = modules.get(module)
        is_package = len(parts) == 2 and path is not None and path.name == "__init__.py"
        return module if is_package else None

    for source, targets in graph.items():
        for target in targets:
            a, b = package(source), package(target)
            if a and b and a != b:
                packages[a].add(b)
    assert _cycles(packages) == []


def test_the_check_sees_a_cycle() -> None:
    """The detector itself finds a cycle (so the two tests above can fail)."""
    assert _cycles({"a": {"b"}, "b": {"c"}, "c": {"a"}}) == [["a", "b", "c"]]


def test_importing_the_package_loads_no_numerical_library() -> None:
    """``import ltv_lstm_mpc`` is cheap (PEP 562 lazy names): numba, scipy, cvxpy, torch and
    dask load only when a name that needs them is first used."""
    import subprocess
    import sys

    code = (
        "import sys, ltv_lstm_mpc\n"
        "heavy = ('numba', 'scipy', 'cvxpy', 'torch', 'distributed', 'matplotlib')\n"
        "print(sorted(m for m in heavy if m in sys.modules))\n"
        "ltv_lstm_mpc.MPCConfig\n"
        "names = ltv_lstm_mpc.__all__\n"
        "print('numba' in sys.modules, len(names) == len(set(names)))\n"
    )
    result = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert result.returncode == 0, result.stderr[-2000:]
    lines = result.stdout.splitlines()
    assert lines[0] == "[]"
    assert lines[1].split()[1] == "True"


def test_every_public_name_resolves() -> None:
    import ltv_lstm_mpc

    # the lazy table and __all__ name the same public names (the two lists cannot drift)
    assert sorted(ltv_lstm_mpc._LAZY) == sorted(set(ltv_lstm_mpc.__all__) - {"__version__"})
    for name in ltv_lstm_mpc.__all__:
        assert getattr(ltv_lstm_mpc, name) is not None, name
    with pytest.raises(AttributeError, match="has no attribute 'nothing_here'"):
        ltv_lstm_mpc.nothing_here  # noqa: B018


def test_no_docstring_holds_a_control_character() -> None:
    """A LaTeX command in a docstring that is not raw loses its backslash to an escape
    (``\\tilde`` becomes a tab and "ilde", ``\\bar`` a backspace and "ar") and renders
    wrongly in the API pages: every docstring of the library is free of tab, backspace,
    bell, form feed and vertical tab characters."""
    found = []
    for name, path in _modules().items():
        tree = ast.parse(path.read_text(), filename=str(path))
        for node in ast.walk(tree):
            if isinstance(node, (ast.Module, ast.ClassDef, ast.FunctionDef, ast.AsyncFunctionDef)):
                text = ast.get_docstring(node, clean=False) or ""
                if any(character in text for character in "\t\b\a\f\v"):
                    found.append(f"{name}.{getattr(node, 'name', '')}")
    assert found == []
