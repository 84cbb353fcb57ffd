"""LSTMModel: dynamics, analytic Jacobians, equilibrium, file format, torch import, errors."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st
from lstm_factories import random_delta_iss_lstm, random_lstm

from ltv_lstm_mpc import (
    DimensionError,
    InvalidValueError,
    LSTMModel,
    LtvMpcError,
    ModelFormatError,
    Normalization,
)
from ltv_lstm_mpc.lstm.model import WEIGHT_NAMES


def _sigmoid(z: np.ndarray) -> np.ndarray:
    return 1.0 / (1.0 + np.exp(-z))


def reference_step(model: LSTMModel, x: np.ndarray, u: np.ndarray) -> np.ndarray:
    """eq. (lstm) written out gate by gate, independent of the model's stacked matmul."""
    c, h = x[: model.n], x[model.n :]
    f = _sigmoid(model.W_f @ u + model.U_f @ h + model.b_f)
    i = _sigmoid(model.W_i @ u + model.U_i @ h + model.b_i)
    o = _sigmoid(model.W_o @ u + model.U_o @ h + model.b_o)
    g = np.tanh(model.W_c @ u + model.U_c @ h + model.b_c)
    c_next = f * c + i * g
    return np.concatenate([c_next, o * np.tanh(c_next)])


dims = st.tuples(st.integers(1, 5), st.integers(1, 3), st.integers(1, 3))


@given(dims=dims, seed=st.integers(0, 2**32 - 1), scale=st.floats(0.1, 2.0))
def test_step_matches_equations(dims: tuple[int, int, int], seed: int, scale: float) -> None:
    n, m, p = dims
    rng = np.random.default_rng(seed)
    model = random_lstm(rng, n, m, p, scale=scale)
    x = rng.normal(size=2 * n)
    u = rng.normal(size=m)
    np.testing.assert_allclose(
        model.step(x, u), reference_step(model, x, u), rtol=1e-13, atol=1e-14
    )
    np.testing.assert_allclose(model.output(x), model.W_y @ x[n:] + model.b_y, rtol=1e-13)


@given(dims=dims, seed=st.integers(0, 2**32 - 1), scale=st.floats(0.1, 2.0))
def test_jacobians_match_central_differences(
    dims: tuple[int, int, int], seed: int, scale: float
) -> None:
    n, m, p = dims
    rng = np.random.default_rng(seed)
    model = random_lstm(rng, n, m, p, scale=scale)
    x = rng.normal(size=2 * n)
    u = rng.normal(size=m)
    A, B = model.jacobians(x, u)
    eps = 1e-6
    A_fd = np.column_stack(
        [
            (model.step(x + eps * e, u) - model.step(x - eps * e, u)) / (2 * eps)
            for e in np.eye(2 * n)
        ]
    )
    B_fd = np.column_stack(
        [(model.step(x, u + eps * e) - model.step(x, u - eps * e)) / (2 * eps) for e in np.eye(m)]
    )
    assert A.shape == (2 * n, 2 * n) and B.shape == (2 * n, m)
    np.testing.assert_allclose(A, A_fd, atol=1e-8)
    np.testing.assert_allclose(B, B_fd, atol=1e-8)


def test_batched_jacobians_equal_pointwise() -> None:
    rng = np.random.default_rng(3)
    model = random_lstm(rng, 4, 2, 2)
    X = rng.normal(size=(6, 8))
    U = rng.normal(size=(6, 2))
    X_next, A, B = model.step_and_jacobians(X, U)
    for k in range(6):
        A_k, B_k = model.jacobians(X[k], U[k])
        np.testing.assert_allclose(A[k], A_k, rtol=1e-14, atol=1e-15)
        np.testing.assert_allclose(B[k], B_k, rtol=1e-14, atol=1e-15)
        np.testing.assert_allclose(X_next[k], model.step(X[k], U[k]), rtol=1e-14)


def test_simulate_alignment_and_shapes() -> None:
    rng = np.random.default_rng(4)
    model = random_lstm(rng, 3, 1, 1)
    x0 = rng.normal(size=6) * 0.1
    u_seq = rng.uniform(-1, 1, size=10)
    states, outputs = model.simulate(x0, u_seq)
    assert states.shape == (11, 6) and outputs.shape == (11, 1)
    np.testing.assert_array_equal(states[0], x0)
    np.testing.assert_allclose(states[5], model.step(states[4], u_seq[4:5]))
    # No feed-through: outputs[k] depends on h_k only.
    np.testing.assert_allclose(outputs[3], model.W_y @ states[3, 3:] + model.b_y)


@given(seed=st.integers(0, 2**32 - 1), u=st.floats(-1, 1))
def test_equilibrium_is_fixed_point_and_attractive(seed: int, u: float) -> None:
    rng = np.random.default_rng(seed)
    model = random_delta_iss_lstm(rng, 3)
    x_eq = model.equilibrium(np.array([u]))
    np.testing.assert_allclose(model.step(x_eq, [u]), x_eq, atol=1e-12)
    # Lemma 3: trajectories under constant u converge to the unique equilibrium.
    states, _ = model.simulate(rng.uniform(-0.5, 0.5, size=6), np.full(400, u))
    np.testing.assert_allclose(states[-1], x_eq, atol=1e-9)


def test_save_load_roundtrip(tmp_path) -> None:
    rng = np.random.default_rng(5)
    model = random_delta_iss_lstm(rng, 3, normalization=True)
    path = model.save(tmp_path / "model.npz")
    loaded = LSTMModel.load(path)
    for name in WEIGHT_NAMES:
        np.testing.assert_array_equal(getattr(loaded, name), getattr(model, name))
    assert loaded.normalization is not None
    np.testing.assert_array_equal(loaded.normalization.y_phi_max, [9.1])
    with np.load(path) as data:
        assert set(data.files) == set(WEIGHT_NAMES) | {
            "u_phi_min",
            "u_phi_max",
            "y_phi_min",
            "y_phi_max",
        }


def test_normalization_maps_are_inverse_and_hit_bounds() -> None:
    norm = Normalization(np.array([12.5]), np.array([17.0]), np.array([5.9]), np.array([9.1]))
    np.testing.assert_allclose(norm.normalize_u([12.5, 17.0]), [-1.0, 1.0])
    np.testing.assert_allclose(norm.normalize_y(7.5), 0.0)
    values = np.linspace(5, 10, 7)
    np.testing.assert_allclose(norm.denormalize_y(norm.normalize_y(values)), values)
    with pytest.raises(InvalidValueError, match="y_phi_max must be strictly greater"):
        Normalization(np.array([0.0]), np.array([1.0]), np.array([2.0]), np.array([1.0]))


def test_missing_key_and_bad_shape_and_nan_errors(tmp_path) -> None:
    rng = np.random.default_rng(6)
    arrays = random_lstm(rng, 3).weights()
    partial = {k: v for k, v in arrays.items() if k != "U_c"}
    np.savez(tmp_path / "partial.npz", **partial)
    with pytest.raises(ModelFormatError, match=r"missing weight array\(s\) \['U_c'\]"):
        LSTMModel.load(tmp_path / "partial.npz")
    bad = dict(arrays, U_o=np.zeros((3, 2)))
    with pytest.raises(DimensionError, match=r"U_o has shape \(3, 2\), expected \(3, 3\)"):
        LSTMModel(**bad)
    bad = dict(arrays, b_i=np.array([0.0, np.nan, 0.0]))
    with pytest.raises(InvalidValueError, match="b_i contains NaN"):
        LSTMModel(**bad)
    bad = dict(arrays, extra=np.zeros(2))
    with pytest.raises(ModelFormatError, match="unexpected array"):
        LSTMModel.from_arrays(bad)
    model = LSTMModel(**arrays)
    with pytest.raises(DimensionError, match=r"x has shape \(5,\), expected \(\.\.\., 6\)"):
        model.step(np.zeros(5), [0.0])
    with pytest.raises(LtvMpcError, match="no normalization"):
        model.normalize_y(7.0)


def test_require_square_names_m_and_p() -> None:
    model = random_lstm(np.random.default_rng(7), 3, 2, 1)
    with pytest.raises(DimensionError, match="m=2 inputs and p=1 outputs"):
        model.require_square()


@pytest.mark.torch
def test_from_torch_state_dict_matches_torch_lstm() -> None:
    torch = pytest.importorskip("torch")
    torch.manual_seed(0)
    n, m, p, T = 4, 2, 1, 12
    lstm = torch.nn.LSTM(m, n, batch_first=True).double()
    linear = torch.nn.Linear(n, p).double()
    state = {f"lstm.{k}": v for k, v in lstm.state_dict().items()}
    state.update({f"head.{k}": v for k, v in linear.state_dict().items()})
    model = LSTMModel.from_torch_state_dict(state)
    u = torch.randn(1, T, m, dtype=torch.float64)
    with torch.no_grad():
        h_seq, _ = lstm(u)
        y_torch = linear(h_seq)[0].numpy()
    _, outputs = model.simulate(np.zeros(2 * n), u[0].numpy())
    # torch's output after reading u_k is h_{k+1}: the model's outputs shifted by one
    # (paper notes 1).
    np.testing.assert_allclose(outputs[1:], y_torch, rtol=1e-12, atol=1e-12)


def test_from_state_dict_rejects_multilayer() -> None:
    rng = np.random.default_rng(8)
    fake = {
        "weight_ih_l0": rng.normal(size=(8, 1)),
        "weight_hh_l0": rng.normal(size=(8, 2)),
        "bias_ih_l0": np.zeros(8),
        "bias_hh_l0": np.zeros(8),
        "weight_ih_l1": rng.normal(size=(8, 2)),
        "weight": rng.normal(size=(1, 2)),
        "bias": np.zeros(1),
    }
    with pytest.raises(ModelFormatError, match="single-layer"):
        LSTMModel.from_torch_state_dict(fake)


# ------------------------------------------------------------------ bad model files
def _bad_files(tmp_path):  # type: ignore[no-untyped-def]
    from ltv_lstm_mpc.lstm.shipped import shipped_path

    source = shipped_path("ph_lstm_n5.npz")
    data = source.read_bytes()
    files = {}
    files["truncated"] = tmp_path / "truncated.npz"
    files["truncated"].write_bytes(data[: len(data) // 2])
    files["npy"] = tmp_path / "single.npy"
    np.save(files["npy"], np.zeros(3))
    files["npy_named_npz"] = tmp_path / "single_npy.npz"
    files["npy_named_npz"].write_bytes(files["npy"].read_bytes())
    files["text"] = tmp_path / "text.npz"
    files["text"].write_text("not a model\n")
    files["folder"] = tmp_path / "folder.npz"
    files["folder"].mkdir()
    with np.load(source) as stored:
        arrays = dict(stored)
    files["strings"] = tmp_path / "strings.npz"
    np.savez(files["strings"], **{**arrays, "W_f": arrays["W_f"].astype(str)})
    files["complex"] = tmp_path / "complex.npz"
    np.savez(files["complex"], **{**arrays, "U_o": arrays["U_o"] + 1e-3j})
    return files


EXPECTED_MODEL_FILE_MESSAGES = {
    "truncated": "damaged or truncated .npz",
    "npy": "single-array .npy file",
    "npy_named_npz": "single-array .npy file",
    "text": "not an .npz archive",
    "folder": "is a folder",
    "strings": "W_f must be real numbers, got string values",
    "complex": "U_o must be real numbers, got complex values",
}


@pytest.mark.parametrize("kind", list(EXPECTED_MODEL_FILE_MESSAGES))
def test_every_bad_model_file_is_a_model_format_error(tmp_path, kind: str) -> None:
    path = _bad_files(tmp_path)[kind]
    with pytest.raises(ModelFormatError) as info:
        LSTMModel.load(path)
    message = str(info.value)
    assert str(path) in message
    assert EXPECTED_MODEL_FILE_MESSAGES[kind] in message


def test_non_real_weights_are_rejected_by_name() -> None:
    arrays = random_lstm(np.random.default_rng(0), 3).weights()
    for name, bad in (("b_c", arrays["b_c"] + 1j), ("W_y", arrays["W_y"].astype(str))):
        with pytest.raises(InvalidValueError, match=f"{name} must be real numbers"):
            LSTMModel(**{**arrays, name: bad})


# ------------------------------------------------------------ output constraint in the file
def test_output_constraint_travels_with_the_model(tmp_path) -> None:
    from ltv_lstm_mpc import load_model

    shipped = load_model("ph_lstm_n5.npz")
    assert shipped.y_phi_constraint is not None
    assert [float(v[0]) for v in shipped.y_phi_constraint] == [6.0, 9.0]
    low, high = shipped.output_constraint()  # type: ignore[misc]
    np.testing.assert_allclose(shipped.denormalize_y(low), [6.0])
    np.testing.assert_allclose(shipped.denormalize_y(high), [9.0])
    model = LSTMModel(
        **shipped.weights(), normalization=shipped.normalization, y_phi_constraint=([20.0], [80.0])
    )
    path = model.save(tmp_path / "temperature.npz")
    loaded = LSTMModel.load(path)
    assert loaded.y_phi_constraint is not None
    assert [float(v[0]) for v in loaded.y_phi_constraint] == [20.0, 80.0]
    with pytest.raises(InvalidValueError, match="must be below"):
        LSTMModel(**shipped.weights(), y_phi_constraint=([9.0], [6.0]))
    with np.load(path) as stored:
        arrays = dict(stored)
    del arrays["y_phi_constraint_max"]
    np.savez(tmp_path / "half.npz", **arrays)
    with pytest.raises(ModelFormatError, match="output constraint is incomplete"):
        LSTMModel.load(tmp_path / "half.npz")


def test_a_model_without_output_constraint_needs_explicit_bounds() -> None:
    from ltv_lstm_mpc import MPCConfig, OffsetFreeController, load_model

    shipped = load_model("ph_lstm_n5.npz")
    bare = LSTMModel(**shipped.weights(), normalization=shipped.normalization)
    with pytest.raises(InvalidValueError, match="carries no output constraint") as info:
        OffsetFreeController(bare, MPCConfig(solver="daqp"))
    assert "y_min and y_max" in str(info.value)
    # explicit bounds work, and equal the shipped model's stored ones
    low, high = shipped.output_constraint()  # type: ignore[misc]
    config = MPCConfig(solver="daqp", y_min=float(low[0]), y_max=float(high[0]))
    a = OffsetFreeController(bare, config).certification.tightening
    b = OffsetFreeController(shipped, MPCConfig(solver="daqp")).certification.tightening
    np.testing.assert_allclose(a.y_min, b.y_min, rtol=0, atol=1e-15)
    np.testing.assert_allclose(a.y_max, b.y_max, rtol=0, atol=1e-15)


def test_u_max_beyond_the_training_range_warns() -> None:
    from ltv_lstm_mpc import MPCConfig, OffsetFreeController, load_model

    model = load_model("ph_lstm_n5.npz")
    with pytest.warns(RuntimeWarning, match=r"beyond the range the model was trained on") as record:
        OffsetFreeController(model, MPCConfig(solver="daqp", u_max=1.5))
    assert "u_max = 1.5" in str(record[0].message)
    import warnings

    with warnings.catch_warnings():
        warnings.simplefilter("error")
        OffsetFreeController(model, MPCConfig(solver="daqp", u_max=1.0))
