"""The user guide's "The whole path for a new process" code (docs/user-guide/extending.md,
linked from the README) runs exactly as printed and does what it says; then the README's
"Your own plant and model" code on the model it trained."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest

from ltv_lstm_mpc.lstm.model import LSTMModel

PAGE = Path(__file__).resolve().parents[1] / "docs" / "user-guide" / "extending.md"


def page_block(marker: str) -> str:
    """The fenced code between ``<!-- marker -->`` and ``<!-- /marker -->`` on the page."""
    text = PAGE.read_text()
    match = re.search(
        rf"<!-- {marker} -->\s*```python\n(.*?)```\s*<!-- /{marker} -->", text, flags=re.S
    )
    assert match is not None, f"{PAGE.name} has no python block between <!-- {marker} --> markers"
    return match.group(1)


@pytest.mark.torch
def test_bring_your_own_process_code_runs(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    pytest.importorskip("torch")
    monkeypatch.chdir(tmp_path)
    namespace: dict[str, object] = {"__name__": "readme_byop"}
    exec(compile(page_block("byop-code"), "extending.md (byop-code)", "exec"), namespace)
    printed = capsys.readouterr().out
    assert "rho(A_delta) =" in printed and "final offsets" in printed
    cert, sim, setpoints = namespace["cert"], namespace["sim"], namespace["setpoints"]
    assert cert.delta_iss.is_delta_iss  # type: ignore[attr-defined]
    # Offset-free at the end of every segment (set-point steps, then the leak), within
    # 1e-3 of the output constraint's range (5..15), and the true plant never left it.
    ends = [299, 599, 899]
    offsets = np.abs(sim.y_phi[ends, 0] - setpoints[ends])  # type: ignore[attr-defined, index]
    assert np.all(offsets < 1e-3 * (15.0 - 5.0)), offsets
    assert float(np.max(sim.plant_violation)) == 0.0  # type: ignore[attr-defined]
    assert sim.feasible.all()  # type: ignore[attr-defined]
    # The leak was an unmeasured disturbance the estimate had to absorb.
    assert abs(sim.d_hat[-1, 0] - sim.d_hat[599, 0]) > 1e-3  # type: ignore[attr-defined]
    model = LSTMModel.load(tmp_path / "tank_model" / "tank_lstm_n3.npz")
    assert model.Ts == 10.0 and model.y_phi_constraint is not None
    np.testing.assert_array_equal(model.y_phi_constraint[0], [5.0])

    # The README's "Your own plant and model" code runs on that model, as printed.
    readme = Path(__file__).resolve().parents[1] / "README.md"
    match = re.search(
        r"<!-- own-plant-code -->\s*```python\n(.*?)```\s*<!-- /own-plant-code -->",
        readme.read_text(),
        flags=re.S,
    )
    assert match is not None, "README has no own-plant-code block"
    own: dict[str, object] = {"__name__": "readme_own_plant"}
    exec(compile(match.group(1), "README.md (own-plant-code)", "exec"), own)
    assert "final offset" in capsys.readouterr().out
    own_sim = own["sim"]
    assert abs(own_sim.y_phi[-1, 0] - 10.6) < 1e-2  # type: ignore[attr-defined]
    assert own_sim.feasible.all()  # type: ignore[attr-defined]
