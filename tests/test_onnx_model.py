"""LSTM models read from ONNX (ltv_lstm_mpc/lstm/onnx_model.py), checked against the
framework that made them: torch exports, onnxruntime runs the graph (float32)."""

from __future__ import annotations

import warnings

import numpy as np
import pytest

onnx = pytest.importorskip("onnx")
torch = pytest.importorskip("torch")
onnxruntime = pytest.importorskip("onnxruntime")

from onnx import helper, numpy_helper  # noqa: E402

from ltv_lstm_mpc import LSTMModel, ModelFormatError, certify, load_model  # noqa: E402
from ltv_lstm_mpc.lstm.model import Normalization  # noqa: E402
from ltv_lstm_mpc.lstm.onnx_model import onnx_metadata  # noqa: E402


class Net(torch.nn.Module):
    """nn.LSTM + nn.Linear (+ an optional output activation), batch first."""

    def __init__(self, m=2, n=5, p=2, *, layers=1, bidirectional=False, activation=None):
        super().__init__()
        self.lstm = torch.nn.LSTM(
            m, n, num_layers=layers, batch_first=True, bidirectional=bidirectional
        )
        self.out = torch.nn.Linear(n * (2 if bidirectional else 1), p)
        self.activation = activation

    def forward(self, u):
        h, _ = self.lstm(u)
        y = self.out(h)
        return y if self.activation is None else self.activation(y)


def _export(net, path, *, dynamo=False, m=2):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        torch.onnx.export(
            net, (torch.zeros(1, 7, m),), str(path), dynamo=dynamo,
            input_names=["u"], output_names=["y"],
            dynamic_axes=None if dynamo else {"u": {1: "T"}, "y": {1: "T"}},
        )  # fmt: skip
    return path


def _delta_iss_net(seed=0, **kwargs):
    torch.manual_seed(seed)
    net = Net(**kwargs)
    n = net.lstm.hidden_size
    with torch.no_grad():  # small recurrent weights, forget gates mostly shut: delta-ISS
        for name, parameter in net.lstm.named_parameters():
            if name.startswith("weight_hh"):
                parameter.mul_(0.1)
            elif name.startswith("weight_ih"):
                parameter.mul_(0.5)
            elif name.startswith("bias_ih"):
                parameter[n : 2 * n] = -2.0
    return net.eval()


@pytest.mark.parametrize("dynamo", [False, True])
def test_a_torch_export_reads_back_as_eq_lstm(tmp_path, dynamo) -> None:
    """Open loop over 300 steps equal to onnxruntime's run of the file (float32 there),
    the weights equal to the torch state-dict route's."""
    net = _delta_iss_net()
    path = _export(net, tmp_path / "net.onnx", dynamo=dynamo)
    model = load_model(path)
    direct = LSTMModel.from_torch_state_dict(net.state_dict())
    for name in ("W_f", "U_i", "b_o", "W_c", "W_y", "b_y"):
        np.testing.assert_allclose(getattr(model, name), getattr(direct, name), atol=1e-7)
    u = np.random.default_rng(1).uniform(-1, 1, (300, 2))
    session = onnxruntime.InferenceSession(str(path))
    if dynamo:  # the dynamo export has the traced sequence length
        reference = np.concatenate([
            session.run(None, {"u": u[None, k : k + 7].astype(np.float32)})[0][0]
            for k in range(0, 294, 7)
        ])  # fmt: skip
        u = u[:294]
        # restart from zero every 7 steps, as the export does
        ours = np.concatenate([
            model.simulate(np.zeros(10), u[k : k + 7])[1][1:] for k in range(0, 294, 7)
        ])  # fmt: skip
    else:
        reference = session.run(None, {"u": u[None].astype(np.float32)})[0][0]
        # torch's output after reading u_k is y(h_{k+1}): this model's output shifted by one
        ours = model.simulate(np.zeros(10), u)[1][1:]
    assert np.max(np.abs(ours - reference)) < 2e-5


def test_metadata_carries_normalization_constraint_and_Ts(tmp_path) -> None:
    path = _export(_delta_iss_net(), tmp_path / "net.onnx")
    graph = onnx.load(str(path))
    norm = Normalization([0.0, 1.0], [10.0, 5.0], [2.0, 3.0], [12.0, 9.0])
    helper.set_model_props(graph, onnx_metadata(norm, ([4.0, 4.0], [10.0, 8.0]), Ts=15.0))
    model = LSTMModel.from_onnx(graph)
    np.testing.assert_array_equal(model.normalization.u_phi_max, [10.0, 5.0])
    np.testing.assert_array_equal(model.y_phi_constraint[1], [10.0, 8.0])
    assert model.Ts == 15.0
    assert LSTMModel.from_onnx(path).normalization is None  # never guessed
    helper.set_model_props(graph, {"u_phi_min": "[0, 1]"})
    with pytest.raises(
        ModelFormatError, match=r"normalization is incomplete: \[.*'u_phi_max'.*\] missing"
    ):
        LSTMModel.from_onnx(graph)
    helper.set_model_props(graph, {"Ts": "ten"})
    with pytest.raises(ModelFormatError, match=r"metadata_props\['Ts'\].*not JSON"):
        LSTMModel.from_onnx(graph)


def _lstm_node(graph):
    return next(node for node in graph.node if node.op_type == "LSTM")


def test_refusals_name_what_eq_lstm_lacks(tmp_path) -> None:
    base = onnx.load(str(_export(_delta_iss_net(), tmp_path / "net.onnx")))

    def variant(change):
        graph = onnx.ModelProto()
        graph.CopyFrom(base)
        change(graph.graph)
        return graph

    cases = {
        "clip": (lambda g: _lstm_node(g).attribute.append(helper.make_attribute("clip", 3.0))),
        r"activations=\['HardSigmoid'": (
            lambda g: _lstm_node(g).attribute.append(
                helper.make_attribute("activations", ["HardSigmoid", "Tanh", "Tanh"])
            )
        ),
        "input_forget": (
            lambda g: _lstm_node(g).attribute.append(helper.make_attribute("input_forget", 1))
        ),
        "direction='reverse'": (
            lambda g: _lstm_node(g).attribute.append(helper.make_attribute("direction", "reverse"))
        ),
    }

    def add_peephole(g):
        node = _lstm_node(g)
        g.initializer.append(numpy_helper.from_array(np.ones((1, 15), np.float32), "peep"))
        while len(node.input) < 7:
            node.input.append("")
        node.input.append("peep")

    cases["peephole"] = add_peephole
    for message, change in cases.items():
        with pytest.raises(ModelFormatError, match=message):
            LSTMModel.from_onnx(variant(change))


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        ({"layers": 2}, "holds 2 LSTM operators.*num_layers=1"),
        ({"bidirectional": True}, "direction='bidirectional'"),
        ({"activation": torch.tanh}, r"after the output layer the graph applies \['Tanh'\]"),
    ],
)
def test_torch_networks_that_are_not_eq_lstm_are_refused(tmp_path, kwargs, message) -> None:
    net = _delta_iss_net(**kwargs)
    with pytest.raises(ModelFormatError, match=message):
        LSTMModel.from_onnx(_export(net, tmp_path / "net.onnx"))


def test_a_graph_without_an_lstm_is_refused(tmp_path) -> None:
    linear = torch.nn.Linear(2, 2)
    path = tmp_path / "linear.onnx"
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        torch.onnx.export(linear, (torch.zeros(1, 2),), str(path), dynamo=False)
    with pytest.raises(ModelFormatError, match=r"holds 0 LSTM operators \(operators: \['Gemm'\]"):
        load_model(path)


def _net_from(model):
    """A torch network holding ``model``'s weights (torch's gate order i, f, g, o)."""
    net = Net(m=model.m, n=model.n, p=model.p)
    order = ("i", "f", "c", "o")

    def stack(kind):
        return torch.tensor(np.vstack([getattr(model, f"{kind}_{g}") for g in order]))

    with torch.no_grad():
        net.lstm.weight_ih_l0.copy_(stack("W"))
        net.lstm.weight_hh_l0.copy_(stack("U"))
        net.lstm.bias_ih_l0.copy_(
            torch.tensor(np.concatenate([getattr(model, f"b_{g}") for g in order]))
        )
        net.lstm.bias_hh_l0.zero_()
        net.out.weight.copy_(torch.tensor(model.W_y))
        net.out.bias.copy_(torch.tensor(model.b_y))
    return net.eval()


def test_the_shipped_ph_model_round_trips_through_onnx(tmp_path) -> None:
    """The shipped model as a torch network, exported with its metadata and read back:
    the same weights to float32 precision, normalization, constraint and Ts exactly, the
    certificates equal to the torch state-dict route's (the same float32 weights) and
    to the shipped model's within float32 rounding."""
    shipped = load_model("ph_lstm_n5.npz")
    net = _net_from(shipped)
    path = _export(net, tmp_path / "ph.onnx", m=1)
    graph = onnx.load(str(path))
    helper.set_model_props(
        graph, onnx_metadata(shipped.normalization, shipped.y_phi_constraint, shipped.Ts)
    )
    model = LSTMModel.from_onnx(graph)
    for name in ("W_f", "U_f", "b_f", "W_i", "U_o", "b_c", "W_y", "b_y"):
        np.testing.assert_allclose(getattr(model, name), getattr(shipped, name), atol=1e-6)
    assert model.Ts == shipped.Ts
    np.testing.assert_array_equal(model.y_phi_constraint[0], shipped.y_phi_constraint[0])
    np.testing.assert_array_equal(model.normalization.y_phi_max, shipped.normalization.y_phi_max)
    torch_route = LSTMModel.from_torch_state_dict(
        net.state_dict(),
        normalization=shipped.normalization,
        y_phi_constraint=shipped.y_phi_constraint,
        Ts=shipped.Ts,
    )
    ours, theirs, original = (certify(m).to_dict() for m in (model, torch_route, shipped))
    for key in ("rho_A_delta", "rho_s", "rho_o", "L_max", "c_o", "e_inf"):
        assert ours[key] == pytest.approx(theirs[key], rel=1e-9, abs=1e-12), key
        assert ours[key] == pytest.approx(original[key], rel=1e-4), key


def test_the_cli_takes_an_onnx_model(tmp_path, capsys) -> None:
    """`certify` (and every command reading a model) accepts an .onnx file."""
    import json

    from ltv_lstm_mpc.cli import main

    shipped = load_model("ph_lstm_n5.npz")
    graph = onnx.load(str(_export(_net_from(shipped), tmp_path / "ph.onnx", m=1)))
    helper.set_model_props(
        graph, onnx_metadata(shipped.normalization, shipped.y_phi_constraint, shipped.Ts)
    )
    onnx.save(graph, str(tmp_path / "ph.onnx"))
    assert main(["certify", str(tmp_path / "ph.onnx"), "--json"]) == 0
    found = json.loads(capsys.readouterr().out)
    expected = certify(shipped).to_dict()
    assert found["rho_A_delta"] == pytest.approx(expected["rho_A_delta"], rel=1e-4)


def test_convert_writes_the_npz_with_the_metadata_given(tmp_path, capsys) -> None:
    from ltv_lstm_mpc.cli import main

    shipped = load_model("ph_lstm_n5.npz")
    source = _export(_net_from(shipped), tmp_path / "ph.onnx", m=1)
    norm = shipped.normalization
    argv = [
        "convert", str(source), str(tmp_path / "ph.npz"),
        "--u-phi", str(norm.u_phi_min[0]), str(norm.u_phi_max[0]),
        "--y-phi", str(norm.y_phi_min[0]), str(norm.y_phi_max[0]),
        "--y-phi-constraint", "6", "9", "--Ts", str(shipped.Ts),
    ]  # fmt: skip
    assert main(argv) == 0
    assert "with normalization" in capsys.readouterr().out
    model = load_model(tmp_path / "ph.npz")
    np.testing.assert_allclose(model.W_f, shipped.W_f, atol=1e-6)
    np.testing.assert_array_equal(model.normalization.u_phi_max, norm.u_phi_max)
    np.testing.assert_array_equal(model.y_phi_constraint[1], [9.0])
    assert model.Ts == shipped.Ts
    assert main(["convert", str(source), str(tmp_path / "bare.npz")]) == 0
    assert "WITHOUT normalization" in capsys.readouterr().out
    assert main(["convert", str(source), str(tmp_path / "x.npz"), "--u-phi", "0", "1"]) == 2
