"""Controller step time against the network size n (N = 20, DAQP, condensed path).

Random delta-ISS LSTMs with n = 5 / 10 / 20 / 40 neurons (``--sizes``), SISO and (2,2)
(``--m``), each in closed loop with its own LSTM plant (a slow set-point sine inside the
admissible interval). Prints the median and p95 of the full step and the ratio to n = 5
(the first size); the loops of the four sizes run interleaved step by step (order
alternating), so that the ratios are measured side by side. With ``--load`` a busy process
runs on the other core during the measurement (the tail latency must not depend on it: the loop runs
on one BLAS thread, see ``simulate``). Compare the compiled and the numpy kernel with
``LTV_LSTM_MPC_KERNEL=numpy``.

    python experiments/growth_with_n.py
    python experiments/growth_with_n.py --load
    python experiments/growth_with_n.py --steps 15 --sizes 5 10 --m 1
"""

from __future__ import annotations

import argparse
import multiprocessing
import time
from typing import Any

SKIP = 10  # first steps left out of the figures


def build_parser() -> argparse.ArgumentParser:
    """The command line (``--help`` answers before numpy and the library are imported)."""
    parser = argparse.ArgumentParser(
        description=__doc__.split("\n\n")[0],
        epilog='Figures: docs/benchmarks.md, "The compiled step" (growth with n), and '
        'docs/user-guide/compiled.md, "How to measure".',
    )
    parser.add_argument(
        "--steps", type=int, default=300, help=f"closed-loop steps (300; more than {SKIP})"
    )
    parser.add_argument("--load", action="store_true", help="busy process on the other core")
    parser.add_argument(
        "--sizes", type=int, nargs="+", default=[5, 10, 20, 40], help="neurons n (5 10 20 40)"
    )
    parser.add_argument(
        "--m", type=int, nargs="+", default=[1, 2], help="inputs = outputs m = p (1 2)"
    )
    return parser


if __name__ == "__main__":
    build_parser().parse_args()  # --help and bad options answer here, before the imports

import numpy as np  # noqa: E402

from ltv_lstm_mpc import LSTMModel, MPCConfig, Normalization, OffsetFreeController  # noqa: E402
from ltv_lstm_mpc.certificates.stability import delta_iss_certificate  # noqa: E402
from ltv_lstm_mpc.loop.simulation import single_threaded_blas  # noqa: E402
from ltv_lstm_mpc.plants import LSTMPlant  # noqa: E402


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


def _loop(n: int, m: int) -> tuple[OffsetFreeController, LSTMPlant, Any]:
    """Controller, plant and set-point schedule of the closed loop of one model size."""
    model = random_model(n, m)
    controller = OffsetFreeController(model, MPCConfig(solver="daqp", N=20), kernels="compiled")
    plant = LSTMPlant(model)
    y_start = plant.output()
    low, high = controller.reference.reachable_output_range
    amplitude = 0.1 * (high - low) * np.linspace(1.0, 0.5, m)  # inside the reachable range

    def setpoint(k: int) -> np.ndarray:
        return np.asarray(y_start + amplitude * np.sin(0.02 * k), dtype=np.float64)

    return controller, plant, setpoint


def measure(sizes: tuple[int, ...], m: int, steps: int) -> list[tuple[float, float]]:
    """Median and p95 step time (us) of each size, the loops interleaved step by step
    (order alternating) so that the machine's drift hits every size alike."""
    loops = [_loop(n, m) for n in sizes]
    outputs = [plant.output() for _, plant, _ in loops]
    times: list[list[float]] = [[] for _ in loops]
    with single_threaded_blas():
        for k in range(steps):
            order = range(len(loops)) if k % 2 == 0 else reversed(range(len(loops)))
            for j in order:
                controller, plant, setpoint = loops[j]
                start = time.perf_counter()
                u = controller.step(outputs[j], setpoint(k))
                times[j].append(time.perf_counter() - start)
                outputs[j] = plant.step(u, None)
    return [
        (1e6 * float(np.median(t[SKIP:])), 1e6 * float(np.percentile(t[SKIP:], 95))) for t in times
    ]


def main() -> None:
    parser = build_parser()
    args = parser.parse_args()
    if args.steps <= SKIP:
        parser.error(f"--steps must be more than {SKIP} (the first {SKIP} are left out)")
    worker = None
    if args.load:
        worker = multiprocessing.Process(target=_busy, args=(time.time() + 3600,), daemon=True)
        worker.start()
    try:
        print(
            f"{'n':>3} {'m=p':>4} | {'median us':>9} {'p95 us':>7} {'p95/median':>10} "
            f"{f'/ n={args.sizes[0]}':>6}"
        )
        sizes = tuple(args.sizes)
        for m in args.m:
            results = measure(sizes, m, args.steps)
            for n, (median, p95) in zip(sizes, results, strict=True):
                ratio = median / results[0][0]
                print(
                    f"{n:>3} {m:>4} | {median:9.0f} {p95:7.0f} {p95 / median:10.2f} {ratio:6.2f}",
                    flush=True,
                )
    finally:
        if worker is not None:
            worker.terminate()


if __name__ == "__main__":
    main()
