"""Build the example delta-ISS model shipped as ``ltv_lstm_mpc/data/example_delta_iss_n3.npz``.

The example is hand-shaped, not trained: n = 3 neurons, m = p = 1, random small recurrent
weights and biases (sigma_f stays near 1/2, so rho(A_delta) < 1), a strong
input path through the cell candidate (so the equilibrium output spans a useful range),
and W_y, b_y scaled so that the equilibrium output over u in [-1, 1] spans about
[-0.9, 0.9]. Its normalization pretends the pH plant's units (q3 in [12.5, 17] mL/s,
pH in [5.9, 9.1]) so the paper's output constraint [6, 9] pH applies; its sampling time is
the pH plant's, 10 s.

Run: ``python experiments/make_example_model.py [OUT.npz]`` (default: the shipped file).
"""

from __future__ import annotations

import argparse
from pathlib import Path

SHIPPED = Path(__file__).resolve().parents[1] / "ltv_lstm_mpc" / "data" / "example_delta_iss_n3.npz"


def build_parser() -> argparse.ArgumentParser:
    """The command line (``--help`` answers before numpy and the library are imported)."""
    parser = argparse.ArgumentParser(
        description=__doc__.split("\n\n")[0],
        epilog="Prints the model's rho(A_delta), rho_s and admissible set-point interval; the "
        "shipped models are listed in docs/user-guide/certificates.md.",
    )
    parser.add_argument(
        "out",
        nargs="?",
        type=Path,
        default=SHIPPED,
        help="where to write the model (default: ltv_lstm_mpc/data/example_delta_iss_n3.npz)",
    )
    return parser


if __name__ == "__main__":
    build_parser().parse_args()  # --help and bad options answer here, before the imports

import numpy as np  # noqa: E402

from ltv_lstm_mpc import LSTMModel, Normalization, certify  # noqa: E402


def build(seed: int = 7) -> LSTMModel:
    """The example model (deterministic for a given seed)."""
    rng = np.random.default_rng(seed)
    n = 3
    weights: dict[str, np.ndarray] = {}
    for gate in "fioc":
        weights[f"W_{gate}"] = rng.normal(scale=0.15, size=(n, 1))
        weights[f"U_{gate}"] = rng.normal(scale=0.08, size=(n, n))
        weights[f"b_{gate}"] = rng.normal(scale=0.1, size=n)
    weights["W_c"] = np.array([[1.2], [-0.9], [0.7]])
    weights["W_y"] = np.ones((1, n))
    weights["b_y"] = np.zeros(1)
    model = LSTMModel(**weights)
    # Rescale the output so the equilibrium output over U spans [-0.9, 0.9].
    outputs_grid = np.array(
        [model.output(model.equilibrium(np.array([u])))[0] for u in np.linspace(-1, 1, 41)]
    )
    low, high = outputs_grid.min(), outputs_grid.max()
    gain = 1.8 / (high - low)
    weights["W_y"] = weights["W_y"] * gain
    weights["b_y"] = np.array([-0.9 - gain * low])
    normalization = Normalization(
        u_phi_min=np.array([12.5]),
        u_phi_max=np.array([17.0]),
        y_phi_min=np.array([5.9]),
        y_phi_max=np.array([9.1]),
    )
    # the paper's output constraint Y_phi = [6, 9] pH and sampling time travel with the model
    return LSTMModel(
        **weights, normalization=normalization, y_phi_constraint=([6.0], [9.0]), Ts=10.0
    )


def main() -> None:
    out = build_parser().parse_args().out
    model = build()
    certification = certify(model)
    print(
        f"rho(A_delta) = {certification.delta_iss.rho_A_delta:.4f}, "
        f"rho_s = {certification.lyapunov.rho_s:.4f}, "
        f"y0 interval (pH) = {certification.y0_interval_phi}"
    )
    print("wrote", model.save(out))


if __name__ == "__main__":
    main()
