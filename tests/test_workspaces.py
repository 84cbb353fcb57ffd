"""Typed workspaces across the compiled boundary: built by field name, in one order.

Every compiled kernel of the controller takes its buffers as one workspace (a numba
structref, see ``numba_support.workspace_type``) and a few per-call values; the workspaces
are built from keyword arguments, so no argument order can be swapped. These tests hold
the library to it: the compiled constructors' parameters are the fields in order, and no
function takes more than about a dozen positional parameters.
"""

from __future__ import annotations

import ast
import importlib
import inspect
from pathlib import Path

import numpy as np
import pytest

from ltv_lstm_mpc.numba_support import build_workspace

ROOT = Path(__file__).resolve().parents[1]

#: (module, fields constant, compiled constructor) of every workspace.
WORKSPACES = [
    ("ltv_lstm_mpc.loop.compiled_reference", "CHORD_FIELDS", "_new_chord_workspace"),
    ("ltv_lstm_mpc.loop.compiled_observer", "OBSERVER_FIELDS", "_new_observer_workspace"),
    ("ltv_lstm_mpc.mpc.compiled_condensing", "CONDENSING_FIELDS", "_new_condensing_workspace"),
    ("ltv_lstm_mpc.mpc.compiled_plan", "PLAN_FIELDS", "_new_plan_workspace"),
    ("ltv_lstm_mpc.mpc.compiled_prepare", "PREPARE_FIELDS", "_new_prepare_workspace"),
    ("ltv_lstm_mpc.mpc.native_feedback", "DAQP_FIELDS", "_new_daqp_workspace"),
    ("ltv_lstm_mpc.mpc.native_feedback", "FALLBACK_FIELDS", "_new_fallback_workspace"),
    ("ltv_lstm_mpc.loop.compiled_reference", "RESTART_FIELDS", "_new_restart_workspace"),
    ("ltv_lstm_mpc.loop.compiled_step", "STEP_FIELDS", "_new_step_workspace"),
    ("ltv_lstm_mpc.loop.compiled_step", "RECORD_FIELDS", "_new_record_arrays"),
    ("ltv_lstm_mpc.solvers.socp_sqp", "SOCP_FIELDS", "_new_socp_workspace"),
]

#: The most positional parameters a function of the library may take ("about a dozen").
MAX_POSITIONAL = 14


@pytest.mark.parametrize(("module", "fields", "constructor"), WORKSPACES)
def test_compiled_constructors_take_the_fields_in_order(
    module: str, fields: str, constructor: str
) -> None:
    loaded = importlib.import_module(module)
    function = getattr(loaded, constructor)
    python = getattr(function, "py_func", function)
    assert tuple(inspect.signature(python).parameters) == getattr(loaded, fields)


def test_build_workspace_names_missing_and_unknown_fields() -> None:
    def factory(a: float, b: float) -> tuple[float, float]:
        return (a, b)

    assert build_workspace(factory, ("a", "b"), {"b": 2.0, "a": 1.0}) == (1.0, 2.0)
    with pytest.raises(TypeError, match=r"missing \['b'\], unknown \['c'\]"):
        build_workspace(factory, ("a", "b"), {"a": 1.0, "c": 3.0})


def test_a_workspace_shares_its_arrays_with_their_owner() -> None:
    """A kernel writes into the owner's buffers (the observer's next state here)."""
    from ltv_lstm_mpc import load_model
    from ltv_lstm_mpc.loop.compiled_observer import new_observer_workspace, observer_update

    model = load_model("ph_lstm_n5.npz")
    n, m, p = model.n, model.m, model.p
    extra = np.full(4 * n, -7.0)
    workspace = new_observer_workspace(
        WU=model.kernel.WU, W_y=np.ascontiguousarray(model.W_y), b_y=model.b_y.copy(),
        L_gates=np.ones((4 * n, p)), L_d=np.eye(p), S=np.r_[np.zeros(2 * n + m), 1.0],
        T=np.zeros(4 * n), TC=np.zeros(n), extra=extra,
    )  # fmt: skip
    x_out, d_out = np.zeros(2 * n), np.zeros(p)
    x_hat, d_hat, y, u = np.zeros(2 * n), np.zeros(p), np.ones(p), np.zeros(m)
    observer_update(workspace, 1.0, x_hat, d_hat, y, u, x_out, d_out)
    innovation = 1.0 - float(model.b_y[0])
    np.testing.assert_allclose(extra, innovation, rtol=0, atol=1e-15)  # written in place
    assert d_out[0] == pytest.approx(innovation, abs=1e-15)


def _positional_counts() -> list[tuple[int, str]]:
    counts = []
    for folder in ("ltv_lstm_mpc", "solvers"):
        for path in sorted((ROOT / folder).rglob("*.py")):
            tree = ast.parse(path.read_text())
            for node in ast.walk(tree):
                if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
                    arguments = node.args.posonlyargs + node.args.args
                    names = [a.arg for a in arguments if a.arg not in ("self", "cls")]
                    where = f"{path.relative_to(ROOT)}:{node.lineno} {node.name}"
                    counts.append((len(names), where))
    return counts


def test_no_function_takes_more_than_about_a_dozen_positional_parameters() -> None:
    """The compiled constructors are the exception: build_workspace calls them with the
    fields in order (checked above), nothing else does."""
    constructors = {constructor for _, _, constructor in WORKSPACES}
    too_many = [
        (count, where)
        for count, where in _positional_counts()
        if count > MAX_POSITIONAL and where.rsplit(" ", 1)[1] not in constructors
    ]
    assert not too_many, too_many


def test_a_cold_compile_is_announced_once(monkeypatch, capsys) -> None:
    """An empty numba cache is said once, on stderr, before the compile; a warm one is not."""
    from ltv_lstm_mpc import numba_support
    from ltv_lstm_mpc.lstm.compiled import rollout

    if not numba_support.AVAILABLE:
        pytest.skip("needs numba")
    assert numba_support.uncached([object()]) == []  # unknown layout: counted as cached
    monkeypatch.setattr(numba_support, "_compile_announced", False)
    monkeypatch.setattr(numba_support, "uncached", lambda dispatchers: ["rollout"])
    assert numba_support.announce_compile([rollout], "the kernels", "5 s")
    assert not numba_support.announce_compile([rollout], "the kernels", "5 s")
    err = capsys.readouterr().err
    assert err.count("compiling the kernels (first run only, about 5 s on 2 cores") == 1
    monkeypatch.setattr(numba_support, "_compile_announced", False)
    monkeypatch.setattr(numba_support, "uncached", lambda dispatchers: [])
    assert not numba_support.announce_compile([rollout], "the kernels", "5 s")
    assert capsys.readouterr().err == ""
