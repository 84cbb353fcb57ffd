"""Models and data files shipped inside the package (``ltv_lstm_mpc/data``)."""

from __future__ import annotations

from importlib import resources
from pathlib import Path

from ltv_lstm_mpc.exceptions import ModelFileNotFoundError
from ltv_lstm_mpc.lstm.model import LSTMModel, missing_model, shipped_model_names
from ltv_lstm_mpc.validation import expect_instance, expect_path

__all__ = ["load_model", "missing_model", "model_path", "shipped_models", "shipped_path"]


def shipped_models() -> list[str]:
    """Names of the ``.npz`` models shipped in ``ltv_lstm_mpc/data``."""
    return shipped_model_names()


def shipped_path(name: str) -> Path:
    """Path of a file shipped in ``ltv_lstm_mpc/data`` (e.g. ``"example_delta_iss_n3.npz"``).

    Raises
    ------
    ModelFileNotFoundError
        No shipped file of that name (a ``FileNotFoundError``; the message lists them).
    """
    expect_instance("name", name, str, f"one of {shipped_models()}", expected="a file name")
    candidate = resources.files("ltv_lstm_mpc") / "data" / name
    if not candidate.is_file():
        raise ModelFileNotFoundError(
            f"no shipped file {name!r}; shipped models: {', '.join(shipped_models())}"
        )
    return Path(str(candidate))


def model_path(name: str) -> Path:
    """``name`` as a path where that file exists, else the shipped file of that name.

    Raises
    ------
    ModelFileNotFoundError
        Neither exists (a ``FileNotFoundError`` and an ``LtvMpcError``; the message names
        the path and lists the shipped models).
    """
    path = Path(name)
    if path.exists():
        return path
    if not (resources.files("ltv_lstm_mpc") / "data" / str(name)).is_file():
        raise missing_model(name)
    return shipped_path(str(name))


def load_model(name_or_path: str | Path) -> LSTMModel:
    """Load a model from a path (the library's ``.npz``, an ``.onnx`` graph read by
    :meth:`LSTMModel.from_onnx`, a saved ``.keras`` model read by
    :meth:`LSTMModel.from_keras`), or by the name of a shipped model.

    Raises
    ------
    ArgumentTypeError
        ``name_or_path`` is not a ``str`` or ``os.PathLike``.
    ModelFileNotFoundError
        No such file and no shipped model of that name (a ``FileNotFoundError``; the
        message names the path and lists the shipped models).
    """
    path = expect_path(
        "name_or_path", name_or_path, f"a .npz, .onnx or .keras file or one of {shipped_models()}"
    )
    if path.exists():
        if path.suffix.lower() == ".onnx":
            return LSTMModel.from_onnx(path)
        if path.suffix.lower() == ".keras":
            return LSTMModel.from_keras(path)
        return LSTMModel.load(path)
    candidate = resources.files("ltv_lstm_mpc") / "data" / str(name_or_path)
    if not candidate.is_file():
        raise missing_model(path)
    return LSTMModel.load(Path(str(candidate)))
