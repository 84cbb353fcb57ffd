"""One seam between the MPC and the solver layer: ``ltv_lstm_mpc/loop`` and
``ltv_lstm_mpc/mpc`` use the solver layer's public names only (no ``_``-prefixed module,
function or attribute of ``ltv_lstm_mpc.solvers``), and never test a solver's name to
decide what to compile or call: what a solver gives compiled callers comes from the
registry (``solvers.compiled_form``)."""

from __future__ import annotations

import ast
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("loop", "mpc")
SOLVERS = "ltv_lstm_mpc.solvers"
#: Names of the built-in backends with a compiled form: the MPC layer does not compare with them.
FORM_NAMES = frozenset({"daqp", "daqp:socp", "clarabel"})


def _private(dotted: str) -> bool:
    return any(part.startswith("_") for part in dotted.split("."))


def private_uses(source: str) -> list[str]:
    """What ``source`` uses of the solver layer that is private: an import of a module or
    name starting with ``_``, or an attribute starting with ``_`` of a solver-layer module
    (or name) it imported; and comparisons with the name of a backend that has a compiled
    form (``config.solver == "daqp:socp"``)."""
    found: list[str] = []
    bound: set[str] = set()  # local names of solver-layer modules and objects
    tree = ast.parse(source)
    for node in ast.walk(tree):
        if isinstance(node, ast.ImportFrom) and (node.module or "").startswith(SOLVERS):
            module = node.module or ""
            if _private(module[len(SOLVERS) :]):
                found.append(f"line {node.lineno}: from {module} import ...")
            for alias in node.names:
                if alias.name.startswith("_"):
                    found.append(f"line {node.lineno}: from {module} import {alias.name}")
                bound.add(alias.asname or alias.name)
        elif isinstance(node, ast.Import):
            for alias in node.names:
                if alias.name.startswith(SOLVERS):
                    if _private(alias.name[len(SOLVERS) :]):
                        found.append(f"line {node.lineno}: import {alias.name}")
                    bound.add(alias.asname or alias.name.split(".")[0])
    for node in ast.walk(tree):
        if isinstance(node, ast.Attribute) and node.attr.startswith("_"):
            base = node.value
            while isinstance(base, ast.Attribute):
                base = base.value
            text = ast.unparse(node)
            if isinstance(base, ast.Name) and (
                base.id in bound or text.startswith(SOLVERS + ".") or ".solvers." in text
            ):
                found.append(f"line {node.lineno}: {text}")
        elif isinstance(node, ast.Compare):
            operands = [node.left, *node.comparators]
            constants = [
                element.value
                for operand in operands
                for element in (
                    operand.elts
                    if isinstance(operand, (ast.Tuple, ast.List, ast.Set))
                    else [operand]
                )
                if isinstance(element, ast.Constant) and isinstance(element.value, str)
            ]
            named = sorted(FORM_NAMES.intersection(constants))
            if named:
                found.append(f"line {node.lineno}: compares with {named}: {ast.unparse(node)}")
    return found


def test_loop_and_mpc_use_the_solver_layers_public_names_only() -> None:
    found = []
    for package in PACKAGES:
        for path in sorted((ROOT / "ltv_lstm_mpc" / package).rglob("*.py")):
            for use in private_uses(path.read_text(encoding="utf-8")):
                found.append(f"{path.relative_to(ROOT)} {use}")
    assert found == []


def test_the_check_sees_private_uses() -> None:
    """The scan itself finds each kind of private use (so the test above can fail)."""
    source = (
        "from ltv_lstm_mpc.solvers import _compiled, daqp_native\n"
        "from ltv_lstm_mpc.solvers._base import Backend\n"
        "from ltv_lstm_mpc.solvers.daqp_socp import _new_socp_workspace\n"
        "import ltv_lstm_mpc.solvers._compiled\n"
        "import ltv_lstm_mpc.solvers.socp_sqp as sqp\n"
        "def f(config):\n"
        "    from ltv_lstm_mpc.solvers import socp_sqp\n"
        "    socp_sqp._new_socp_workspace\n"
        "    sqp._cone_value\n"
        "    ltv_lstm_mpc.solvers.socp_sqp._BIG\n"
        "    daqp_native.quadprog\n"
        "    if config.solver == 'daqp:socp' or config.solver in ('daqp', 'osqp'):\n"
        "        pass\n"
    )
    found = private_uses(source)
    assert len(found) == 9, found
    assert all("daqp_native.quadprog" not in use for use in found)
    clean = "from ltv_lstm_mpc.solvers import compiled_form\nform = compiled_form('osqp')\n"
    assert private_uses(clean) == []
