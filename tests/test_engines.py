"""The step engines and the seam between the controller and them.

- the shared formulas: each compiled twin gives its numpy reference's numbers, bit for bit
  (both engines call one of the two: ``loop/signals.py``, ``certificates/tightening.py``);
- the engine choice: once, at construction, named, with the reasons of the refusals;
- the layout the engines redesign promises (``README.md``, "Where to change what"): a short
  controller, no private reads or positional state tuples in ``loop/``, few branches on
  the compiled/numpy choice outside the engine and kernel files.
"""

from __future__ import annotations

import ast
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from ltv_lstm_mpc import MPCConfig, OffsetFreeController, RobustMPC
from ltv_lstm_mpc.certificates import compiled_tightening as twin
from ltv_lstm_mpc.loop import compiled_signals, signals
from ltv_lstm_mpc.lstm.shipped import load_model

PACKAGE = Path(__file__).resolve().parents[1] / "ltv_lstm_mpc"
LOOP = PACKAGE / "loop"


@pytest.fixture(scope="module")
def model():  # type: ignore[no-untyped-def]
    return load_model("ph_lstm_n5.npz")


@pytest.fixture(scope="module")
def tightening(model):  # type: ignore[no-untyped-def]
    return RobustMPC(model, MPCConfig(solver="daqp", N=7)).certification.tightening


# ---------------------------------------------------------------- shared formulas
@settings(max_examples=60, deadline=None)
@given(e_hat=st.floats(0.0, 0.5), y0=st.floats(-1.2, 1.2))
def test_tightening_twins_give_the_certificate_numbers(tightening, e_hat, y0) -> None:  # type: ignore[no-untyped-def]
    """Bounds (eq. optimization_constraint_yub/ylb), alpha_k (eq. def_alpha), the
    admissible interval (Assumption 5) and eq. eo_evolution: compiled == numpy, exactly."""
    ti = tightening
    N, p = ti.N, ti.y_min.shape[0]
    lower, upper = np.zeros((N, p)), np.zeros((N, p))
    twin.output_bounds_into(ti.a, ti.b, ti.d_max, ti.y_min, ti.y_max, e_hat, lower, upper)
    expected_lower, expected_upper = ti.output_bounds(e_hat)
    np.testing.assert_array_equal(lower, expected_lower)
    np.testing.assert_array_equal(upper, expected_upper)
    y0_arr = np.full(p, y0)
    e_tilde = max(e_hat, ti.e_inf)
    a_N, b_N = np.ascontiguousarray(ti.a[N]), np.ascontiguousarray(ti.b[N])
    two_d = 2.0 * ti.d_max
    kappa = np.asarray(ti.kappa, dtype=np.float64)
    alpha = twin.terminal_alpha(y0_arr, ti.y_min, ti.y_max, kappa, two_d, a_N, b_N, e_tilde)
    assert alpha == ti.alpha(y0_arr, e_hat)
    low, high = ti.setpoint_interval(e_hat)
    inside = bool(np.all((low < y0_arr) & (y0_arr < high)))
    assert (
        twin.inside_setpoint_interval(y0_arr, ti.y_min, ti.y_max, two_d, a_N, b_N, e_tilde)
        is inside
    )
    assert twin.next_e_hat(ti.rho_o, ti.w_bar, e_hat) == ti.next_e_hat(e_hat)


@settings(max_examples=60, deadline=None)
@given(
    target=st.lists(st.floats(-3, 3), min_size=2, max_size=2),
    previous=st.lists(st.floats(-3, 3), min_size=2, max_size=2),
    limit=st.floats(1e-4, 1.0),
    u=st.lists(st.floats(-2, 2), min_size=3, max_size=3),
    largest=st.floats(0.0, 5.0),
)
def test_signal_twins_give_the_reference_numbers(target, previous, limit, u, largest) -> None:  # type: ignore[no-untyped-def]
    """Rate limiter, exit-gate projection and measurement status: compiled == numpy."""
    y0, y0_previous = np.array(target), np.array(previous)
    expected = signals.limit_rate(y0, y0_previous, limit)
    limited, requested = y0.copy(), np.zeros(2)
    compiled_signals.limit_rate_into(limited, y0_previous, limit, requested)
    np.testing.assert_array_equal(limited, expected)
    np.testing.assert_array_equal(requested, y0)
    rounding = 4 * np.finfo(float).eps * np.maximum(1.0, np.abs(y0_previous))
    assert np.all(np.abs(limited - y0_previous) <= limit + rounding)
    u_arr = np.array(u)
    gated, moved = signals.project_onto_box(u_arr, 1.0)
    projected = u_arr.copy()
    assert compiled_signals.project_into(projected, 1.0) == moved
    np.testing.assert_array_equal(projected, gated)
    assert compiled_signals.measurement_code(largest, 3.0) == signals.measurement_code(largest, 3.0)
    for used in (False, True):
        for limited in (False, True):
            for target in (False, True):
                code = signals.setpoint_code(used, limited, target)
                assert compiled_signals.setpoint_code(used, limited, target) == code


# ---------------------------------------------------------------- engine choice
def test_the_engine_is_chosen_once_and_named(model) -> None:  # type: ignore[no-untyped-def]
    """The fastest engine that runs the configuration; the refusals say why."""
    fast = OffsetFreeController(model, MPCConfig(solver="daqp", N=5), kernels="compiled")
    assert fast.engine.name == "one-call" and fast.engine_refusals == {} and fast.one_call
    plain = OffsetFreeController(
        model, MPCConfig(solver="daqp", N=5), kernels="compiled", one_call_step=False
    )
    assert plain.engine.name == "reference"
    assert plain.engine_refusals == {"one-call": "one_call_step=False"}
    numpy = OffsetFreeController(model, MPCConfig(solver="daqp", N=5), kernels="numpy")
    assert "numpy kernels" in numpy.engine_refusals["one-call"]
    sqp = OffsetFreeController(
        model, MPCConfig(solver="daqp", N=5, sqp_iterations=3), kernels="compiled"
    )
    assert sqp.engine.name == "reference"
    assert "sqp_iterations=3" in sqp.engine_refusals["one-call"]
    given = OffsetFreeController(model, mpc=RobustMPC(model, MPCConfig(solver="daqp", N=5)))
    assert given.engine_refusals == {"one-call": "a custom mpc was given"}


def test_the_records_say_which_engine_ran_each_step(model) -> None:  # type: ignore[no-untyped-def]
    """Every step of a refused configuration: the reference engine; every step of a
    one-call controller, the first one included: the one-call engine."""
    for one_call_step, engine in ((True, "one-call"), (False, "reference")):
        controller = OffsetFreeController(
            model, MPCConfig(solver="daqp", N=5), kernels="compiled", one_call_step=one_call_step
        )
        for _ in range(4):
            controller.step(7.0, 7.1)
        assert [r.engine for r in controller.records] == [engine] * 4


# ---------------------------------------------------------------- the layout
def _function(path: Path, cls: str, name: str) -> ast.FunctionDef:
    tree = ast.parse(path.read_text())
    for node in ast.walk(tree):
        if isinstance(node, ast.ClassDef) and node.name == cls:
            for item in node.body:
                if isinstance(item, ast.FunctionDef) and item.name == name:
                    return item
    raise AssertionError(f"{cls}.{name} not found in {path}")


def test_the_controller_is_short() -> None:
    """controller.py <= 500 lines; OffsetFreeController.step <= 80 lines."""
    path = LOOP / "controller.py"
    assert len(path.read_text().splitlines()) <= 500
    step = _function(path, "OffsetFreeController", "step")
    assert step.end_lineno is not None and step.end_lineno - step.lineno + 1 <= 80


def private_reads(folder: Path) -> list[str]:
    """``x._name`` where x is not ``self`` / ``cls`` (another object's private name)."""
    found = []
    for path in sorted(folder.rglob("*.py")):
        for node in ast.walk(ast.parse(path.read_text())):
            if (
                isinstance(node, ast.Attribute)
                and node.attr.startswith("_")
                and not node.attr.startswith("__")
                and not (isinstance(node.value, ast.Name) and node.value.id in ("self", "cls"))
            ):
                found.append(f"{path.relative_to(PACKAGE)}:{node.lineno}: {ast.unparse(node)}")
    return found


def test_loop_reads_no_private_name_of_another_object() -> None:
    assert private_reads(LOOP) == []


def test_loop_has_no_type_ignore() -> None:
    hits = [
        f"{path.name}:{number}"
        for path in sorted(LOOP.rglob("*.py"))
        for number, line in enumerate(path.read_text().splitlines(), 1)
        if "type: ignore" in line
    ]
    assert hits == []


#: Names whose test in an ``if`` is a branch on how a step runs (compiled or numpy, native
#: feedback or not, workspace or not, one call or not, deferred or not).
_CHOICE = ("compiled", "native", "workspace", "one_call", "deferred")


def choice_branches() -> dict[str, int]:
    """``if``/``elif``/conditional-expression tests naming a choice word, per file, in
    ``loop/``, ``mpc/`` and ``lstm/`` outside the engine and kernel files."""
    counts: dict[str, int] = {}
    for folder in ("loop", "mpc", "lstm"):
        for path in sorted((PACKAGE / folder).rglob("*.py")):
            name = path.name
            if name.startswith("compiled") or name in ("kernel.py", "kernels.py"):
                continue
            if "engines" in path.parts or name == "native_feedback.py":
                continue
            for node in ast.walk(ast.parse(path.read_text())):
                if isinstance(node, ast.If | ast.IfExp):
                    text = ast.unparse(node.test)
                    if any(word in text for word in _CHOICE):
                        key = str(path.relative_to(PACKAGE))
                        counts[key] = counts.get(key, 0) + 1
    return counts


def test_few_branches_on_the_compiled_choice_outside_engines_and_kernels() -> None:
    counts = choice_branches()
    assert sum(counts.values()) <= 20, counts
