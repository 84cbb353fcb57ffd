r"""An LSTM model read from an ONNX graph: one ``LSTM`` operator and its output layer.

PyTorch, Keras/TensorFlow and MATLAB export ONNX. This module reads a graph holding one
ONNX ``LSTM`` operator (forward, one layer, default activations) followed by the output
layer (``Gemm``, or ``MatMul`` + ``Add``, with the ``Squeeze`` / ``Transpose`` /
``Reshape`` glue exporters emit) and checks that it is the network of eq. (lstm):

.. math::

    c^+ = \sigma(W_f u + U_f h + b_f) \odot c
          + \sigma(W_i u + U_i h + b_i) \odot \tanh(W_c u + U_c h + b_c), \quad
    h^+ = \sigma(W_o u + U_o h + b_o) \odot \tanh(c^+), \quad y = W_y h + b_y.

ONNX stacks the gates in the order (i, o, f, c) and splits each bias into an input part
``Wb`` and a recurrent part ``Rb``; eq. (lstm)'s :math:`b` is their sum. Anything the
equation does not have is refused with an error that names the operator or attribute:
peepholes (input ``P``), cell clipping (``clip``), other activations, ``input_forget``,
reverse or bidirectional direction, several LSTM layers, an activation after the output
layer. The initial-state inputs are ignored (the observer estimates the state).

The weights keep the values the file stores (float32 in most exports, widened to float64).
The normalization, the output constraint and the sampling time are taken from the
arguments, else from the model's ``metadata_props`` (keys :data:`METADATA_KEYS`, values
JSON numbers or lists), never guessed.
"""

from __future__ import annotations

import json
from collections.abc import Mapping
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from ltv_lstm_mpc.exceptions import ModelFormatError

if TYPE_CHECKING:  # pragma: no cover
    from ltv_lstm_mpc.lstm.model import Normalization

__all__ = ["METADATA_KEYS", "onnx_metadata", "read_onnx"]

FloatArray = NDArray[np.float64]

#: ``metadata_props`` keys read when the arguments do not give them (JSON values): the
#: names of the library's file format (``LSTMModel.to_arrays``).
METADATA_KEYS = (
    "u_phi_min",
    "u_phi_max",
    "y_phi_min",
    "y_phi_max",
    "y_phi_constraint_min",
    "y_phi_constraint_max",
    "Ts",
)

#: Operators between the LSTM and the output layer (and after it) that only move axes.
_GLUE = ("Squeeze", "Unsqueeze", "Transpose", "Reshape", "Identity", "Flatten")

#: The LSTM operator's default activations (f, g, h in ONNX's notation).
_DEFAULT_ACTIVATIONS = ["Sigmoid", "Tanh", "Tanh"]


def _onnx() -> Any:
    try:
        import onnx
    except ImportError as error:  # pragma: no cover - depends on the installation
        raise ModelFormatError(
            "reading an ONNX model needs the onnx package: pip install 'ltv_lstm_mpc[onnx]'"
        ) from error
    return onnx


def onnx_metadata(
    normalization: Normalization | None = None,
    y_phi_constraint: tuple[ArrayLike, ArrayLike] | None = None,
    Ts: float | None = None,
) -> dict[str, str]:
    """The ``metadata_props`` entries (key -> JSON text) that :func:`model_from_onnx` reads:
    attach them to an exported graph (``onnx.helper.set_model_props(model, ...)``) so the
    file carries its normalization, output constraint and sampling time."""
    entries: dict[str, Any] = {}
    if normalization is not None:
        for name in METADATA_KEYS[:4]:
            entries[name] = np.asarray(getattr(normalization, name), dtype=float).tolist()
    if y_phi_constraint is not None:
        low, high = y_phi_constraint
        entries["y_phi_constraint_min"] = np.atleast_1d(np.asarray(low, dtype=float)).tolist()
        entries["y_phi_constraint_max"] = np.atleast_1d(np.asarray(high, dtype=float)).tolist()
    if Ts is not None:
        entries["Ts"] = float(Ts)
    return {key: json.dumps(value) for key, value in entries.items()}


def _constants(graph: Any) -> dict[str, FloatArray]:
    from onnx import numpy_helper

    values = {init.name: numpy_helper.to_array(init) for init in graph.initializer}
    for node in graph.node:
        if node.op_type == "Constant":
            for attribute in node.attribute:
                if attribute.name == "value":
                    values[node.output[0]] = numpy_helper.to_array(attribute.t)
    return values


def _attributes(node: Any) -> dict[str, Any]:
    from onnx import helper

    return {attribute.name: helper.get_attribute_value(attribute) for attribute in node.attribute}


def _check_lstm(node: Any) -> int:
    """The refusals of the LSTM operator's attributes; returns hidden_size (or 0)."""
    attributes = _attributes(node)
    direction = attributes.get("direction", b"forward")
    direction = direction.decode() if isinstance(direction, bytes) else str(direction)
    if direction != "forward":
        raise ModelFormatError(
            f"ONNX LSTM node {node.name!r} has direction={direction!r}; eq. (lstm) is one "
            "forward recurrence: export a unidirectional LSTM (bidirectional=False)"
        )
    activations = [
        a.decode() if isinstance(a, bytes) else str(a)
        for a in attributes.get("activations", _DEFAULT_ACTIVATIONS)
    ]
    if activations != _DEFAULT_ACTIVATIONS:
        raise ModelFormatError(
            f"ONNX LSTM node {node.name!r} has activations={activations}; eq. (lstm) needs "
            f"the defaults {_DEFAULT_ACTIVATIONS} (sigmoid gates, tanh cell and output): "
            "e.g. Keras' recurrent_activation='hard_sigmoid' changes the dynamics"
        )
    for name in ("activation_alpha", "activation_beta"):
        if name in attributes:
            raise ModelFormatError(
                f"ONNX LSTM node {node.name!r} sets {name}={list(attributes[name])}; eq. (lstm) "
                "has the standard sigmoid and tanh without parameters"
            )
    if "clip" in attributes:
        raise ModelFormatError(
            f"ONNX LSTM node {node.name!r} clips the cell input (clip={attributes['clip']}); "
            "eq. (lstm) has no cell clipping: export without it"
        )
    if int(attributes.get("input_forget", 0)) != 0:
        raise ModelFormatError(
            f"ONNX LSTM node {node.name!r} couples the input and forget gates "
            "(input_forget=1); eq. (lstm) has independent gates"
        )
    return int(attributes.get("hidden_size", 0))


def _consumers(graph: Any, name: str) -> list[Any]:
    return [node for node in graph.node if name in node.input]


def _output_layer(
    graph: Any, lstm: Any, constants: Mapping[str, FloatArray], n: int
) -> tuple[FloatArray, FloatArray]:
    """W_y (p, n) and b_y (p,) from the Gemm or MatMul + Add reading the LSTM's Y."""
    outputs = {value.name for value in graph.output}
    name = lstm.output[0] if lstm.output else ""
    for other in lstm.output[1:]:
        if other and other in outputs:
            raise ModelFormatError(
                f"the graph outputs the LSTM's final state {other!r}; eq. (lstm)'s output is "
                "y = W_y h + b_y at every step: export the sequence output through the "
                "output layer"
            )
    while True:
        readers = _consumers(graph, name) if name else []
        if len(readers) != 1:
            raise ModelFormatError(
                f"the LSTM's sequence output Y must feed one output layer (Gemm, or MatMul + "
                f"Add); {name!r} is read by {[node.op_type for node in readers] or 'nothing'}"
            )
        node = readers[0]
        if node.op_type in _GLUE:
            name = node.output[0]
            continue
        break
    if node.op_type == "Gemm":
        attributes = _attributes(node)
        if int(attributes.get("transA", 0)):
            raise ModelFormatError(f"Gemm node {node.name!r} with transA=1 is not supported")
        if node.input[1] not in constants:
            raise ModelFormatError(f"Gemm node {node.name!r}: its weight is not a constant")
        B = np.asarray(constants[node.input[1]], dtype=np.float64)
        W_y = float(attributes.get("alpha", 1.0)) * (B if attributes.get("transB", 0) else B.T)
        if len(node.input) > 2 and node.input[2]:
            C = np.asarray(constants[node.input[2]], dtype=np.float64).reshape(-1)
            b_y = float(attributes.get("beta", 1.0)) * C
        else:
            b_y = np.zeros(W_y.shape[0])
        last = node.output[0]
    elif node.op_type == "MatMul":
        weight = next((i for i in node.input if i in constants), None)
        if weight is None or node.input[0] != name:
            raise ModelFormatError(
                f"MatMul node {node.name!r} must multiply the LSTM output by a constant weight"
            )
        W_y = np.asarray(constants[weight], dtype=np.float64).T
        last = node.output[0]
        b_y = np.zeros(W_y.shape[0])
        readers = _consumers(graph, last)
        if len(readers) == 1 and readers[0].op_type == "Add":
            add = readers[0]
            bias = next((i for i in add.input if i in constants), None)
            if bias is None:
                raise ModelFormatError(f"Add node {add.name!r} after the MatMul adds no constant")
            b_y = np.asarray(constants[bias], dtype=np.float64).reshape(-1)
            last = add.output[0]
    else:
        raise ModelFormatError(
            f"the LSTM's output feeds a {node.op_type} node ({node.name!r}); eq. (lstm)'s "
            "output layer is linear, y = W_y h + b_y: Gemm, or MatMul + Add"
        )
    while last not in outputs:  # only glue may follow the output layer
        readers = _consumers(graph, last)
        if len(readers) != 1 or readers[0].op_type not in _GLUE:
            found = [node.op_type for node in readers] or ["nothing"]
            raise ModelFormatError(
                f"after the output layer the graph applies {found}; eq. (lstm)'s output is "
                "the linear y = W_y h + b_y (an output activation is not part of the model)"
            )
        last = readers[0].output[0]
    if W_y.ndim != 2 or W_y.shape[1] != n or b_y.shape != (W_y.shape[0],):
        raise ModelFormatError(
            f"output layer weights of shape {W_y.shape} and bias {b_y.shape} do not fit "
            f"n = {n} hidden units"
        )
    return W_y, b_y


def _from_metadata(model: Any, key: str) -> Any:
    for entry in model.metadata_props:
        if entry.key == key:
            try:
                return json.loads(entry.value)
            except json.JSONDecodeError as error:
                raise ModelFormatError(
                    f"metadata_props[{key!r}] = {entry.value!r} is not JSON (a number or a "
                    "list of numbers)"
                ) from error
    return None


def read_onnx(source: str | Path | Any) -> dict[str, Any]:
    """The arrays of an ONNX file or ``onnx.ModelProto`` by the library's file-format names
    (see the module documentation for what the graph may hold): ``W_f`` ... ``b_y`` as
    float64 arrays, and the :data:`METADATA_KEYS` that ``metadata_props`` states;
    :meth:`~ltv_lstm_mpc.LSTMModel.from_onnx` builds the model with
    :meth:`~ltv_lstm_mpc.LSTMModel.from_arrays` (which checks that the normalization and
    the output constraint are complete).

    Raises
    ------
    ModelFormatError
        No or several LSTM operators, an attribute or input that eq. (lstm) does not have,
        an output layer that is not linear, metadata that is not JSON; the message names it.
    """
    onnx = _onnx()
    model = source if hasattr(source, "graph") else onnx.load(str(source))
    graph = model.graph
    lstms = [node for node in graph.node if node.op_type == "LSTM"]
    if len(lstms) != 1:
        kinds = sorted({node.op_type for node in graph.node})
        raise ModelFormatError(
            f"the ONNX graph holds {len(lstms)} LSTM operators (operators: {kinds}); "
            "eq. (lstm) is one single-layer LSTM followed by a linear output layer"
            + (": export one layer (num_layers=1)" if len(lstms) > 1 else "")
        )
    lstm = lstms[0]
    hidden = _check_lstm(lstm)
    constants = _constants(graph)
    inputs = list(lstm.input) + [""] * (8 - len(lstm.input))
    names = ("X", "W", "R", "B", "sequence_lens", "initial_h", "initial_c", "P")
    for label in ("W", "R", "B"):
        given = inputs[names.index(label)]
        if given and given not in constants:
            raise ModelFormatError(
                f"the LSTM's input {label} ({given!r}) is not a constant of the graph"
            )
    peephole = inputs[7]
    if peephole and (peephole not in constants or np.any(constants[peephole])):
        raise ModelFormatError(
            f"the LSTM node {lstm.name!r} has peephole weights (input P, {peephole!r}); "
            "eq. (lstm) has no peephole connections"
        )
    W = np.asarray(constants[inputs[1]], dtype=np.float64)
    R = np.asarray(constants[inputs[2]], dtype=np.float64)
    if W.ndim != 3 or W.shape[0] != 1 or W.shape[1] % 4:
        raise ModelFormatError(f"LSTM input W has shape {W.shape}, expected (1, 4n, m)")
    W, R = W[0], R[0]
    n = W.shape[0] // 4
    if hidden and hidden != n:
        raise ModelFormatError(f"hidden_size={hidden} but W has {W.shape[0]} = 4 x {n} rows")
    if R.shape != (4 * n, n):
        raise ModelFormatError(f"LSTM input R has shape {R.shape}, expected ({4 * n}, {n})")
    if inputs[3]:
        B = np.asarray(constants[inputs[3]], dtype=np.float64).reshape(-1)
        if B.shape != (8 * n,):
            raise ModelFormatError(f"LSTM input B has shape {B.shape}, expected ({8 * n},)")
        bias = B[: 4 * n] + B[4 * n :]  # Wb + Rb
    else:
        bias = np.zeros(4 * n)
    W_y, b_y = _output_layer(graph, lstm, constants, n)
    arrays: dict[str, FloatArray] = {"W_y": W_y, "b_y": b_y}
    for k, gate in enumerate("iofc"):  # ONNX's gate order
        rows = slice(k * n, (k + 1) * n)
        arrays[f"W_{gate}"] = W[rows]
        arrays[f"U_{gate}"] = R[rows]
        arrays[f"b_{gate}"] = bias[rows]
    result: dict[str, Any] = dict(arrays)
    for key in METADATA_KEYS:  # the file format's names: LSTMModel.from_arrays checks them
        value = _from_metadata(model, key)
        if value is not None:
            result[key] = value
    return result
