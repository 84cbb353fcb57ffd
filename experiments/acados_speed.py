"""Our whole controller step against acados' SQP-RTI solve of the same QP, in one run.

acados (generated C: the LSTM's discrete dynamics and their Jacobians from CasADi, full
condensing, a C QP solver) solves, at each step of bench's scenario 1 (short), the QP our
one-call daqp step solved: the same linearization trajectory (the previous plan's x_1
rolled out along the candidate: the previous inputs shifted, :math:`\\bar u` appended),
the same :math:`\\hat x_k` inserted as the first state, the same :math:`\\bar x, \\bar u`,
stage weights Q and R, the tightened output bounds of stages 1..N-1, the input box, and
the terminal box with its quadratic cost bound (the QP-only form of the terminal set,
:class:`~ltv_lstm_mpc.mpc.terminal.TerminalBoxReformulation`). Each step first runs our
controller (timed: observer, reference calculator and MPC, one compiled call), then
acados' ``solve()`` on that step's data (timed: one SQP-RTI iteration, linearization,
condensing and QP), alternately; the largest difference of the two first inputs says
that the two solved the same QP (on the steps where ours was optimal; with the count of
steps where they differ by more than 1e-6: on the nearly infeasible QPs of the paper's
scenario 3, acados' solvers can stop at points that differ from ours, and from each
other's, by up to a few 1e-2).

Printed per horizon: medians, p95, p99, max and their ratios to the median (the first 10
steps aside) of our full step (with the steps that took the infeasibility policy, their
count and their own median against the others'), of our MPC alone
(prepare + feedback, from the records), of DAQP's own time in it, and of each acados solve
(the Python call, with the steps whose QP it found infeasible and their median; acados'
own ``time_tot``, and that less its QP solver), the ratios of
ours to each acados solve, and an estimate of acados with DAQP (acados' time less its QP
solver, plus DAQP's time on the same QP). The jitter ratio (p95/median, ours / acados',
over the steps both timed) comes with a 95 % bootstrap interval that draws steps, each
with all its repeats and both times: one closed loop gives about 290 steps, whose p95
rests on the largest 15, so one run's ratio moves by about +-0.1; ``--repeats R`` pools R
closed loops (a new controller and plant each, the same acados solvers). With three
repeats or more it also prints the jitter of each step's smallest time over the repeats
(the loop is deterministic, so step k does the same work in every repeat, and the
machine's noise seldom hits the same step in all of them): the jitter of the work itself,
what an isolated core would show.

``--scenario`` picks the closed loop: bench's scenario 1 (the default; no infeasible step
at N = 20 and 50, a few at N = 5), the paper's scenario 3 (``paper3``), or the same with its
set-point levels cycled every 40 samples (``paper3-dense``: the worst case's denser run,
``experiments/worst_case.py``). acados solves every step's nominal QP from k = 1 on, also
where ours found it infeasible and applied the infeasibility policy: its solve fails there
(acados has no policy), and is timed all the same.

acados comes from the wheel ``comma-deps-acados`` on the package index (acados' Python
template, its shared libraries, headers and the template renderer); its vendored CasADi
is built for Python 3.12 and would replace ours, so install it into its own folder and
keep CasADi from the ``nmpc`` extra::

    python -m pip install --no-deps --target .acados comma-deps-acados==0.2.2.post92
    python experiments/acados_speed.py --N 5 20 50 --steps 300 [--repeats 5]

That build has acados' HPIPM and qpOASES but not DAQP (``FULL_CONDENSING_DAQP`` is
reported unavailable and skipped). For acados with DAQP, build it from source and pass the
source tree (``--acados DIR``: its ``lib/`` and ``interfaces/acados_template``; the
wheel's template renderer copied to ``DIR/bin/t_renderer``, as the newer templates need a
newer renderer than the wheel's, which the package index does not carry). Measured
with acados a66778d78 (the last commit whose templates that renderer renders; blasfeo
e33fe98, hpipm 945645e), DAQP dc13508 (the DAQP of the ``daqp`` module this library
uses: numba's loader puts that module's DAQP functions in the process' global symbol
table, where ``libacados.so`` finds its DAQP calls first, so the two DAQPs must have the
same structs), and acados' DAQP interface ``acados/dense_qp/dense_qp_daqp.[ch]`` taken
from 21376cb, whose DAQP that is (its statuses ``ACADOS_INFEASIBLE`` and
``ACADOS_UNKNOWN`` replaced by ``ACADOS_QP_FAILURE``, which a66778d78 has); the Python
template of that commit also needs ``pip install future-fstrings Deprecated``::

    cmake -DACADOS_WITH_DAQP=ON -DACADOS_WITH_QPOASES=OFF -DBLASFEO_TARGET=X64_AUTOMATIC \
        -DACADOS_SILENT=ON -DCMAKE_BUILD_TYPE=Release .. && make install -j2
    python experiments/acados_speed.py --acados DIR --N 5 20 50 --steps 300

The generated code goes to a temporary folder (``--build DIR`` to keep it); building takes
a few seconds per solver and horizon.
"""

from __future__ import annotations

import argparse
import ctypes
import gc
import os
import sys
import tempfile
import time
from dataclasses import replace
from pathlib import Path
from typing import Any

#: --scenario's choices (resolved in ``scenario_of``).
SCENARIOS = ("bench1", "paper3", "paper3-dense")


def build_parser() -> argparse.ArgumentParser:
    """The command line (``--help`` answers before numpy and the library are imported)."""
    parser = argparse.ArgumentParser(
        description=__doc__.split("\n\n")[0],
        epilog='Figures: docs/benchmarks.md, "Against acados\' SQP-RTI" and "The chord\'s '
        "refresh, and the jitter of the step's own work\" (--repeats). Smallest run: --N 5 "
        "--steps 20.",
    )
    parser.add_argument("--steps", type=int, default=300, help="closed-loop steps (300, >= 20)")
    parser.add_argument(
        "--repeats", type=int, default=1, help="closed loops per horizon, samples pooled"
    )
    parser.add_argument("--N", type=int, nargs="+", default=[5, 20, 50], help="horizons")
    parser.add_argument(
        "--scenario",
        choices=sorted(SCENARIOS),
        default="bench1",
        help="the closed loop: bench's scenario 1 (bench1, the default), the paper's scenario 3 "
        "(paper3) or the same with its set-point levels cycled every 40 samples (paper3-dense, "
        "more infeasible steps; experiments/worst_case.py)",
    )
    parser.add_argument("--acados", type=Path, default=Path(".acados"), help="the --target folder")
    parser.add_argument("--build", type=Path, default=None, help="keep the generated code here")
    return parser


if __name__ == "__main__":
    build_parser().parse_args()  # --help and bad options answer here, before the imports

for _name in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_name, "1")  # before numpy: small products, one thread

import numpy as np  # noqa: E402

from ltv_lstm_mpc import OffsetFreeController  # noqa: E402
from ltv_lstm_mpc.lstm.shipped import load_model  # noqa: E402
from ltv_lstm_mpc.mpc.nmpc import casadi_dynamics  # noqa: E402
from ltv_lstm_mpc.mpc.terminal import TerminalSet  # noqa: E402
from ltv_lstm_mpc.paper.scenarios import paper_scenarios  # noqa: E402
from ltv_lstm_mpc.solver_comparison.harness import bench_scenarios  # noqa: E402

#: acados QP solvers tried, in this order (a build without one is reported and skipped).
QP_SOLVERS = ("FULL_CONDENSING_DAQP", "FULL_CONDENSING_HPIPM", "FULL_CONDENSING_QPOASES")
#: HPIPM's mode and tolerances (acados' options ``hpipm_mode``, ``qp_solver_tol_*``).
HPIPM_MODE = os.environ.get("HPIPM_MODE", "SPEED_ABS")
HPIPM_TOLERANCE = float(os.environ.get("HPIPM_TOLERANCE", "1e-8"))
#: Bounds acados treats as absent (no output rows at stage 0, whose state is fixed).
NO_BOUND = 1e9


def load_acados(folder: Path) -> Any:
    """``acados_template`` from ``folder``: the wheel installed with ``--target folder``, or
    an acados source tree built with its libraries in ``folder/lib`` (module docstring)."""
    if (folder / "interfaces" / "acados_template").is_dir():
        return _load_source_build(folder)
    install = folder / "acados" / "install"
    if not install.is_dir():
        raise SystemExit(
            f"no acados under {folder}: python -m pip install --no-deps --target {folder} "
            "comma-deps-acados==0.2.2.post92 (or --acados an acados source tree built with "
            "DAQP: see this script's docstring)"
        )
    os.environ["ACADOS_SOURCE_DIR"] = str(install)
    os.environ["ACADOS_PYTHON_INTERFACE_PATH"] = str(folder / "acados" / "acados_template")
    renderer = install / "bin" / "t_renderer"
    renderer.chmod(renderer.stat().st_mode | 0o111)  # wheels lose the executable bit
    os.environ["TERA_PATH"] = str(renderer)
    for library in ("libblasfeo.so", "libhpipm.so", "libqpOASES_e.so.3.1", "libacados.so"):
        ctypes.CDLL(str(install / "lib" / library), mode=ctypes.RTLD_GLOBAL)
    _check_casadi()
    sys.path.append(str(folder))
    from acados import acados_template

    return acados_template


def _load_source_build(source: Path) -> Any:
    """``acados_template`` of an acados source tree built into ``source/lib``. Its
    libraries are loaded by path with ``RTLD_LOCAL`` (``libacados.so`` finds them by
    soname, and they do not enter the global symbol table: the daqp module's own DAQP
    functions stay its own); the generated solvers find them through their rpath."""
    lib = source / "lib"
    if not (lib / "libacados.so").is_file():
        raise SystemExit(f"no {lib / 'libacados.so'}: build acados first (module docstring)")
    renderer = source / "bin" / "t_renderer"
    if not renderer.is_file():
        raise SystemExit(f"no {renderer}: copy the wheel's acados/install/bin/t_renderer there")
    os.environ["ACADOS_SOURCE_DIR"] = str(source)
    os.environ["TERA_PATH"] = str(renderer)
    for library in ("libblasfeo.so", "libhpipm.so", "libdaqp.so", "libqpOASES_e.so"):
        if (lib / library).is_file():
            ctypes.CDLL(str(lib / library))  # RTLD_LOCAL
    _check_casadi()
    sys.path.insert(0, str(source / "interfaces" / "acados_template"))
    import acados_template

    return acados_template


def _check_casadi() -> None:
    """CasADi from the ``nmpc`` extra (imported before a vendored one is reachable)."""
    try:
        import casadi  # noqa: F401
    except ImportError as error:
        raise SystemExit(
            'acados_speed needs CasADi for the model functions: pip install -e ".[nmpc]"'
        ) from error


def build_solver(acados: Any, model: Any, controller: Any, qp_solver: str, folder: Path) -> Any:
    """An AcadosOcpSolver of the controller's QP-only FHOCP (module docstring)."""
    import casadi

    config = controller.mpc.config
    n2, m, p, N = 2 * model.n, model.m, model.p, config.N
    Q, R = config.weights(model)
    terminal = TerminalSet(np.asarray(controller.mpc.tightening.P_f), model.n)
    x = casadi.SX.sym("x", n2)
    u = casadi.SX.sym("u", m)
    ocp_model = acados.AcadosModel()
    ocp_model.name = f"lstm_{qp_solver.lower()}_{N}"
    ocp_model.x, ocp_model.u = x, u
    ocp_model.disc_dyn_expr = casadi_dynamics(model)(x, u)
    ocp = acados.AcadosOcp()
    ocp.model = ocp_model
    ocp.dims.N = N
    ocp.cost.cost_type = ocp.cost.cost_type_e = "LINEAR_LS"
    ocp.cost.W = np.block([[Q, np.zeros((n2, m))], [np.zeros((m, n2)), R]])
    ocp.cost.Vx = np.vstack([np.eye(n2), np.zeros((m, n2))])
    ocp.cost.Vu = np.vstack([np.zeros((n2, m)), np.eye(m)])
    ocp.cost.yref = np.zeros(n2 + m)
    ocp.cost.W_e = np.diag(terminal.box_weights)
    ocp.cost.Vx_e = np.eye(n2)
    ocp.cost.yref_e = np.zeros(n2)
    ocp.constraints.C = np.hstack([np.zeros((p, model.n)), model.W_y])
    ocp.constraints.D = np.zeros((p, m))
    ocp.constraints.lg = np.full(p, -NO_BOUND)
    ocp.constraints.ug = np.full(p, NO_BOUND)
    ocp.constraints.idxbu = np.arange(m)
    ocp.constraints.lbu = np.full(m, -config.u_max)
    ocp.constraints.ubu = np.full(m, config.u_max)
    ocp.constraints.idxbx_e = np.arange(n2)
    ocp.constraints.lbx_e = np.full(n2, -NO_BOUND)
    ocp.constraints.ubx_e = np.full(n2, NO_BOUND)
    ocp.constraints.x0 = np.zeros(n2)
    options = ocp.solver_options
    options.integrator_type = "DISCRETE"
    options.nlp_solver_type = "SQP_RTI"
    options.hessian_approx = "GAUSS_NEWTON"
    options.qp_solver = qp_solver
    options.qp_solver_iter_max = 200
    options.print_level = 0
    options.tf = float(N)
    if "HPIPM" in qp_solver:
        options.hpipm_mode = HPIPM_MODE
        for name in ("stat", "eq", "ineq", "comp"):
            setattr(options, f"qp_solver_tol_{name}", HPIPM_TOLERANCE)
    ocp.code_export_directory = str(folder / ocp_model.name)
    return acados.AcadosOcpSolver(
        ocp, json_file=str(folder / f"{ocp_model.name}.json"), verbose=False
    )


def feed(solver: Any, controller: Any, model: Any, dynamics: Any) -> None:
    """Write the data of the controller's last step into the acados solver (untimed)."""
    config = controller.mpc.config
    n2, N = 2 * model.n, config.N
    record, previous = controller.records[-1], controller.records[-2]
    terminal = TerminalSet(np.asarray(controller.mpc.tightening.P_f), model.n)
    x_hat = record.mpc.x[0]
    u_bar = np.clip(record.u_bar, -config.u_max, config.u_max)
    candidate = np.vstack([previous.mpc.u[1:], u_bar[None, :]])
    states = np.empty((N + 1, n2))
    states[0] = previous.mpc.x[1]  # the linearization starts at the previous plan's x_1
    for i in range(N):
        states[i + 1] = np.asarray(dynamics(states[i], candidate[i])).ravel()
    lower, upper = controller.mpc.tightening.output_bounds(record.e_hat)
    reference = np.concatenate([record.x_bar, record.u_bar])
    for i in range(N + 1):
        solver.set(i, "x", states[i])
    for i in range(N):
        solver.set(i, "u", candidate[i])
        solver.cost_set(i, "yref", reference)
    solver.cost_set(N, "yref", record.x_bar)
    solver.constraints_set(0, "lbx", x_hat)
    solver.constraints_set(0, "ubx", x_hat)
    for i in range(1, N):
        solver.constraints_set(i, "lg", lower[i] - model.b_y)
        solver.constraints_set(i, "ug", upper[i] - model.b_y)
    half = max(record.mpc.alpha, 0.0) * terminal.unit_half_widths
    solver.constraints_set(N, "lbx", record.x_bar - half)
    solver.constraints_set(N, "ubx", record.x_bar + half)


def scenario_of(name: str, model: Any) -> Any:
    """The closed loop named by ``--scenario`` (``SCENARIOS``)."""
    if name == "bench1":
        return bench_scenarios(model)[0]
    scenario3 = paper_scenarios(model)[2]
    return scenario3 if name == "paper3" else scenario3.cycled(40)


def run(
    acados: Any, N: int, steps: int, folder: Path, repeats: int = 1, scenario_name: str = "bench1"
) -> dict[str, dict[str, Any]]:
    """``repeats`` interleaved closed loops at horizon N (module docstring), each with a new
    controller and plant and the same acados solvers; the samples of all repeats pooled
    (the first 10 steps of each left out). acados solves the nominal QP of every step from
    k = 1 on, also where ours found it infeasible and took the infeasibility policy (its
    solve then fails: timed, and counted as failed)."""
    model = load_model("ph_lstm_n5.npz")
    scenario = scenario_of(scenario_name, model)
    steps = min(steps, len(scenario.setpoints))
    config = replace(scenario.config, N=N, solver="daqp")

    def new_controller() -> Any:
        controller = OffsetFreeController(
            model, config, setpoint_rate_limit=scenario.setpoint_rate_limit,
            kernels="compiled", one_call_step=True,
        )  # fmt: skip
        controller.records.reserve(steps + 1)
        return controller

    dynamics = casadi_dynamics(model)
    solvers = {}
    for qp_solver in QP_SOLVERS:
        try:
            solvers[qp_solver] = build_solver(acados, model, new_controller(), qp_solver, folder)
        except Exception as error:  # a build without this QP solver
            print(f"  N = {N}: acados {qp_solver} unavailable ({type(error).__name__})")
    skip = 10
    step_by_k = np.full((repeats, steps), np.nan)  # our step's time, per repeat and step
    solve_by_k = {name: np.full((repeats, steps), np.nan) for name in solvers}
    step_times: list[float] = []
    fallback: list[bool] = []
    mpc_times: list[float] = []
    daqp_times: list[float] = []
    pooled: dict[str, list[tuple[float, float, float, float, float]]] = {
        name: [] for name in solvers
    }
    for repeat in range(repeats):
        controller = new_controller()
        plant = scenario.make_plant(model)
        ours: list[float] = []
        theirs: dict[str, list[tuple[float, float, float, float, float]]] = {
            name: [] for name in solvers
        }
        y = plant.output()
        gc.collect()
        gc.disable()
        try:
            for k in range(steps):
                start = time.perf_counter()
                u = controller.step(y, scenario.setpoints[k])
                ours.append(time.perf_counter() - start)
                optimal = controller.records[-1].mpc.status == "optimal"
                if k >= 1:
                    ours_first = float(controller.records[-1].mpc.u[0, 0])
                    for name, solver in solvers.items():
                        feed(solver, controller, model, dynamics)
                        start = time.perf_counter()
                        status = solver.solve()
                        wall = time.perf_counter() - start
                        first = float(solver.get(0, "u")[0]) if status == 0 else np.nan
                        own, qp_call = (
                            float(np.ravel(solver.get_stats(field))[0])
                            for field in ("time_tot", "time_qp_solver_call")
                        )
                        gap = abs(first - ours_first) if optimal else np.nan
                        if k >= skip:
                            theirs[name].append((wall, own, gap, own - qp_call, float(status)))
                            solve_by_k[name][repeat, k] = wall
                d = scenario.disturbances[k]
                y = plant.step(u, None if np.isnan(d) else d)
        finally:
            gc.enable()
        records = controller.records[skip:]
        step_times.extend(ours[skip:])
        fallback.extend(not r.mpc.feasible for r in records)
        step_by_k[repeat] = ours
        mpc_times.extend(r.mpc.prepare_time + r.mpc.feedback_time for r in records)
        daqp_times.extend(r.mpc.solver_time for r in records)
        for name, rows in theirs.items():
            pooled[name].extend(rows)
    out: dict[str, dict[str, Any]] = {
        "ours": {
            "step": np.array(step_times), "mpc": np.array(mpc_times),
            "daqp": np.array(daqp_times), "by_step": step_by_k,
            "fallback": np.array(fallback, dtype=bool),
        }
    }  # fmt: skip
    for name, rows in pooled.items():
        table = np.array(rows)
        out[name] = {
            "solve": table[:, 0], "own": table[:, 1], "gap": table[:, 2], "around": table[:, 3],
            "failed": table[:, 4] != 0, "by_step": solve_by_k[name],
        }  # fmt: skip
    return out


def common_steps(ours: Any, theirs: Any) -> tuple[Any, Any]:
    """Our and acados' times (repeats x steps) on the steps that both timed in every repeat
    (every step from k = 10 on)."""
    both = np.all(np.isfinite(ours) & np.isfinite(theirs), axis=0)
    return ours[:, both], theirs[:, both]


def jitter(values: Any) -> float:
    """p95 / median of ``values``."""
    return float(np.percentile(values, 95) / np.median(values))


def jitter_ratio(ours: Any, theirs: Any) -> float:
    """``jitter`` of our times over that of acados', both over all repeats and steps."""
    return jitter(np.ravel(ours)) / jitter(np.ravel(theirs))


def jitter_ratio_interval(
    ours: Any, theirs: Any, resamples: int = 2000, seed: int = 0
) -> tuple[float, float]:
    """A 95 % bootstrap interval of :func:`jitter_ratio` over (repeats x steps) arrays of
    the same steps: the steps are drawn again with replacement, each with all its repeats
    and both solvers' times (the samples of one step are alike in every repeat, and ours
    and acados' of one step were measured side by side); percentile interval."""
    rng = np.random.default_rng(seed)
    count = ours.shape[1]
    ratios = np.empty(resamples)
    for i in range(resamples):
        steps = rng.integers(0, count, count)
        ratios[i] = jitter_ratio(ours[:, steps], theirs[:, steps])
    low, high = np.percentile(ratios, [2.5, 97.5])
    return float(low), float(high)


def quiet_jitter(ours: Any, theirs: Any) -> str:
    """With three repeats or more: the jitter of each step's smallest time over the repeats
    (the same work at step k in every repeat, as the loop is deterministic; the machine's
    noise seldom hits one step in all of them, so this is the work's own jitter, what an
    isolated core would show), ours / acados'."""
    if ours.shape[0] < 3:
        return ""
    mine, their = jitter(ours.min(axis=0)), jitter(theirs.min(axis=0))
    return f", per-step minimum over the repeats {mine:.3f} / {their:.3f} = {mine / their:.2f}"


def report(N: int, result: dict[str, dict[str, Any]]) -> None:
    """Print one horizon's table."""

    def stats(values: Any) -> str:
        us = values * 1e6
        median = float(np.median(us))
        p95, p99 = (float(v) for v in np.percentile(us, [95, 99]))
        largest = float(us.max())
        return (
            f"{median:8.1f} {p95:8.1f} {p99:8.1f} {largest:8.1f} {p95 / median:8.2f} "
            f"{p99 / median:8.2f} {largest / median:8.2f}"
        )

    def split(values: Any, mask: Any, what: str) -> str:
        """The median of ``values`` on the steps of ``mask`` against the others'."""
        if not mask.any():
            return f"no {what} steps"
        inside, outside = np.median(values[mask]) * 1e6, np.median(values[~mask]) * 1e6
        return (
            f"{int(mask.sum())} {what} steps ({100 * mask.mean():.1f} %): median {inside:.1f} "
            f"= {inside / outside:.2f}x the others' {outside:.1f}"
        )

    print(f"\nN = {N} (microseconds, the first 10 steps aside)")
    print(
        f"{'':>34} {'median':>8} {'p95':>8} {'p99':>8} {'max':>8} {'p95/med':>8} "
        f"{'p99/med':>8} {'max/med':>8}"
    )
    step, mpc = result["ours"]["step"], result["ours"]["mpc"]
    print(f"{'ours: full step (one call)':>34} {stats(step)}")
    print(f"{'':>34} {split(step, result['ours']['fallback'], 'fallback')}")
    print(f"{'ours: MPC (prepare + feedback)':>34} {stats(mpc)}")
    print(f"{'ours: DAQP in the MPC':>34} {stats(result['ours']['daqp'])}")
    for name, data in result.items():
        if name == "ours":
            continue
        label = name.replace("FULL_CONDENSING_", "acados ").lower()
        print(f"{label + ' solve()':>34} {stats(data['solve'])}")
        print(f"{'':>34} {split(data['solve'], data['failed'], 'failed')}")
        print(f"{label + ' time_tot':>34} {stats(data['own'])}")
        print(f"{label + ' time_tot less QP solver':>34} {stats(data['around'])}")
        solve = float(np.median(data["solve"]))
        ours_k, theirs_k = common_steps(result["ours"]["by_step"], data["by_step"])
        low, high = jitter_ratio_interval(ours_k, theirs_k)
        print(
            f"{'':>34} full step / solve() = {np.median(step) / solve:.2f}, "
            f"MPC / solve() = {np.median(mpc) / solve:.2f}, "
            f"jitter (p95/median) ours / theirs = {jitter_ratio(ours_k, theirs_k):.2f} "
            f"(95 % bootstrap interval {low:.2f}-{high:.2f}, {ours_k.shape[1]} steps x "
            f"{ours_k.shape[0]} repeats)" + quiet_jitter(ours_k, theirs_k) + "; "
            f"max |u_0 - ours| = {np.nanmax(data['gap']):.1e} "
            f"({int(np.isnan(data['gap']).sum())} failed or ours not optimal, "
            f"{int((np.nan_to_num(data['gap']) > 1e-6).sum())} beyond 1e-6)"
        )
    around = min(
        float(np.median(data["around"])) for name, data in result.items() if name != "ours"
    )
    estimate = (around + float(np.median(result["ours"]["daqp"]))) * 1e6
    print(
        f"{'acados + DAQP, estimated':>34} {estimate:8.1f}{'':>27}(acados' time_tot less its QP "
        f"solver, the smaller, + our DAQP time on the same QP): full step / estimate = "
        f"{np.median(step) * 1e6 / estimate:.2f}"
    )


def main() -> None:
    parser = build_parser()
    args = parser.parse_args()
    if args.repeats < 1 or args.steps < 20:
        parser.error("--repeats must be at least 1 and --steps at least 20")
    acados = load_acados(args.acados.resolve())
    with tempfile.TemporaryDirectory() as scratch:
        folder = (args.build or Path(scratch)).resolve()
        folder.mkdir(parents=True, exist_ok=True)
        cwd = os.getcwd()
        os.chdir(folder)  # acados writes some files next to the caller
        try:
            for N in args.N:
                report(N, run(acados, N, args.steps, folder, args.repeats, args.scenario))
        finally:
            os.chdir(cwd)


if __name__ == "__main__":
    main()
