"""Controller step time against the network size n (N = 20, DAQP, condensed path).

Random delta-ISS LSTMs with n = 5 / 10 / 20 / 40 neurons, SISO and (2,2), each in closed
loop with its own LSTM plant (a slow set-point sine inside the admissible interval).
Prints the median and p95 of the full step. With ``--load`` a busy process runs on the
other core during the measurement (the tail latency must not depend on it: the loop runs
on one BLAS thread, see ``simulate``). Compare the compiled and the numpy kernel with
``LTV_LSTM_MPC_KERNEL=numpy``.

    python experiments/growth_with_n.py
    python experiments/growth_with_n.py --load
"""

from __future__ import annotations

import argparse
import multiprocessing
import time

import numpy as np

from ltv_lstm_mpc import LSTMModel, MPCConfig, Normalization, OffsetFreeController, simulate
from ltv_lstm_mpc.certificates.stability import delta_iss_certificate
from ltv_lstm_mpc.plants import LSTMPlant


def random_model(n: int, m: int, seed: int = 0) -> LSTMModel:
    """A random LSTM shrunk until rho(A_delta) < 0.97, physical units = normalized ones."""
    rng = np.random.default_rng(seed)
    scale = 0.3
    for _ in range(100):
        weights = {}
        for gate in "fioc":
            weights[f"W_{gate}"] = rng.normal(scale=scale, size=(n, m))
            weights[f"U_{gate}"] = rng.normal(scale=scale / np.sqrt(n), size=(n, n))
            weights[f"b_{gate}"] = rng.normal(scale=scale, size=n)
        weights["W_y"] = rng.normal(size=(m, n)) / np.sqrt(n)
        weights["b_y"] = np.zeros(m)
        model = LSTMModel(**weights)
        if delta_iss_certificate(model).rho_A_delta < 0.97:
            break
        scale *= 0.9
    normalization = Normalization(
        u_phi_min=-np.ones(m), u_phi_max=np.ones(m), y_phi_min=-np.ones(m), y_phi_max=np.ones(m)
    )
    return LSTMModel(
        **model.weights(),
        normalization=normalization,
        y_phi_constraint=(-3 * np.ones(m), 3 * np.ones(m)),
    )


def _busy(stop: float) -> None:
    while time.time() < stop:
        sum(i * i for i in range(1000))


def measure(n: int, m: int, steps: int) -> tuple[float, float]:
    model = random_model(n, m)
    controller = OffsetFreeController(model, MPCConfig(solver="daqp", N=20))
    plant = LSTMPlant(model)
    y_start = plant.output()
    low, high = controller.reference.reachable_output_range
    amplitude = 0.1 * (high - low) * np.linspace(1.0, 0.5, m)  # inside the reachable range

    def setpoint(k: int) -> np.ndarray:
        return np.asarray(y_start + amplitude * np.sin(0.02 * k), dtype=np.float64)

    result = simulate(plant, controller, setpoint, steps=steps, progress=False)
    times = result.time_total[10:]
    return 1e6 * float(np.median(times)), 1e6 * float(np.percentile(times, 95))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--steps", type=int, default=300)
    parser.add_argument("--load", action="store_true", help="busy process on the other core")
    args = parser.parse_args()
    worker = None
    if args.load:
        worker = multiprocessing.Process(target=_busy, args=(time.time() + 3600,), daemon=True)
        worker.start()
    try:
        print(f"{'n':>3} {'m=p':>4} | {'median us':>9} {'p95 us':>7} {'p95/median':>10}")
        for m in (1, 2):
            for n in (5, 10, 20, 40):
                median, p95 = measure(n, m, args.steps)
                print(f"{n:>3} {m:>4} | {median:9.0f} {p95:7.0f} {p95 / median:10.2f}", flush=True)
    finally:
        if worker is not None:
            worker.terminate()


if __name__ == "__main__":
    main()
