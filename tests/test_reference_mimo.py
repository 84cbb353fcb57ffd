"""MIMO reference calculator: admissible equilibria on a (3,3) model with folds."""

from __future__ import annotations

import numpy as np
import pytest
from lstm_factories import random_delta_iss_lstm

from ltv_lstm_mpc import UnreachableSetpointError
from ltv_lstm_mpc.loop.reference import ReferenceCalculator


@pytest.fixture(scope="module")
def folded():
    """A (3,3) model, a target y with an admissible equilibrium and an inadmissible one."""
    rng = np.random.default_rng(0)
    model = random_delta_iss_lstm(rng, 4, 3, 3, scale=0.6)
    probe = ReferenceCalculator(model, strict=False)
    n2 = 2 * model.n
    for _ in range(50):
        u_in = rng.uniform(-0.9, 0.9, 3)
        y = model.output(model.equilibrium(u_in))
        for _ in range(10):
            u_out = rng.uniform(-3.0, 3.0, 3)
            z0 = np.concatenate([model.equilibrium(u_out), u_out])
            z, _, _, converged, _, _ = probe._newton(z0, y)
            if converged and np.max(np.abs(z[n2:])) > 1.0 + 1e-6:
                return model, y, z[:n2], z[n2:]
    raise AssertionError("no fold found")  # pragma: no cover


@pytest.mark.parametrize("strict", [False, True])
def test_inadmissible_warm_start_still_gives_the_admissible_equilibrium(folded, strict) -> None:
    model, y, x_out, u_out = folded
    assert np.max(np.abs(u_out)) > 1.0  # the warm start's own equilibrium is outside U
    np.testing.assert_allclose(model.output(x_out), y, atol=1e-10)
    calculator = ReferenceCalculator(model, strict=strict)
    solution = calculator.solve(y, np.zeros(3), warm=(x_out, u_out))
    assert solution.ok and np.max(np.abs(solution.u_bar)) <= 1.0 + 1e-12
    assert solution.residual < 1e-10
    np.testing.assert_allclose(model.output(solution.x_bar), y, atol=1e-10)
    x_next = model.step(solution.x_bar, solution.u_bar)
    np.testing.assert_allclose(x_next, solution.x_bar, atol=1e-10)


def test_warm_path_follows_the_equilibrium_branch(folded) -> None:
    """Targets moving along the outputs of an admissible equilibrium path from the middle of
    U: every solution is admissible and is that path's equilibrium (no branch jump)."""
    model, _, _, _ = folded
    calculator = ReferenceCalculator(model, strict=True)
    direction = np.array([1.0, -0.5, 0.25])
    for k in range(30):
        u_path = 0.02 * k * direction
        target = model.output(model.equilibrium(u_path))
        solution = calculator.solve(target, np.zeros(3))
        assert solution.ok
        np.testing.assert_allclose(solution.u_bar, u_path, atol=1e-8)


def test_strict_raises_only_without_any_admissible_equilibrium(folded) -> None:
    model, y, _, _ = folded
    _, high = ReferenceCalculator(model, strict=False).reachable_output_range
    with pytest.raises(UnreachableSetpointError, match="not reachable"):
        ReferenceCalculator(model, strict=True).solve(high + 1.0, np.zeros(3))
    assert ReferenceCalculator(model, strict=True).solve(y, np.zeros(3)).ok
