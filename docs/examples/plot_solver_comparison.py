r"""
Solver comparison: one closed loop, several backends
====================================================

The controller is the same for every backend; the solver name only chooses how each
convex subproblem of the RTI step is posed and solved (:func:`~ltv_lstm_mpc.resolve_transcription`):

* QP-only solvers (``daqp``, ``quadprog``, ``osqp``, ...) get the *condensed* dense QP,
  with the terminal cones replaced by the conservative box reformulation (paper notes 4);
* the native cone solver ``clarabel`` gets the condensed problem with the exact
  second-order-cone terminal set;
* cvxpy's solvers (``cvxpy:CLARABEL``, ``cvxpy:ECOS``, ...) get the *sparse* transcription
  with exact cones;
* ``ipopt`` (CasADi) solves the nonlinear FHOCP exactly: the accuracy reference.

Each runs the same pH scenario (set-point step, then a step of the unmeasured buffer
flow q2). Backends that are not installed here are skipped.
"""

import textwrap

import matplotlib.pyplot as plt
import numpy as np
from ltv_lstm_mpc.solvers import available_solvers

from ltv_lstm_mpc import (
    MPCConfig,
    OffsetFreeController,
    PHNeutralizationPlant,
    RobustMPC,
    SolverNotFound,
    certify,
    load_model,
    simulate,
)

QP_ONLY = ["daqp", "quadprog", "osqp", "piqp", "proxqp", "qpsolvers:quadprog"]
CONES_AND_NLP = ["clarabel", "cvxpy:CLARABEL", "cvxpy:ECOS", "ipopt"]
installed = available_solvers()
print(textwrap.fill(f"{len(installed)} backends installed: " + ", ".join(installed), 88))

model = load_model("ph_lstm_n5.npz")
base = MPCConfig(L_d=0.1)
certification = certify(model, base.certification_settings(model))  # shared by all runs
setpoints = np.repeat([7.0, 7.5, 7.5], 100)  # pH
q2 = np.repeat([0.55, 0.55, 0.7], 100)  # buffer flow, mL/s

results = {}
for solver in QP_ONLY + CONES_AND_NLP:
    config = MPCConfig(L_d=0.1, solver=solver)
    try:
        mpc = RobustMPC(model, config, certification=certification)
    except (SolverNotFound, ImportError) as error:
        print(f"{solver}: skipped ({type(error).__name__})")
        continue
    controller = OffsetFreeController(model, config, setpoint_rate_limit=0.01, mpc=mpc)
    plant = PHNeutralizationPlant()
    plant.reset()
    results[solver] = (simulate(plant, controller, setpoints, q2, progress=False), controller)

# %%
# What each backend did. The step time is the whole controller step (observer, reference
# calculator, RTI preparation and feedback); the first step is left out of the medians
# because it carries one-off set-up costs (cvxpy compiles its problem, CasADi builds the
# NLP), printed separately. The input difference is against ``daqp``.
reference = results["daqp"][0].u_phi[:, 0]
box = results["daqp"][1].records[0].mpc.reformulation
print("set: the terminal set, 'exact' = second-order cones,")
print(f"     'box' = {box} (paper notes 4)")
print(f"{'':<36}{'step time (ms)':^24}")
print(
    f"{'backend':<20}{'path':<10}{'set':<6}{'median':>8}{'p95':>8}{'first':>8}"
    f"{'max |dq3|':>11}  statuses"
)
for solver, (result, controller) in results.items():
    step_ms = 1e3 * result.time_total
    terminal = "box" if controller.records[0].mpc.reformulation else "exact"
    values, counts = np.unique(result.status, return_counts=True)
    statuses = ", ".join(f"{v} {c}" for v, c in zip(values, counts, strict=True))
    difference = np.max(np.abs(result.u_phi[:, 0] - reference))
    print(
        f"{solver:<20}{result.transcription:<10}{terminal:<6}{np.median(step_ms[1:]):8.3f}"
        f"{np.quantile(step_ms[1:], 0.95):8.3f}{step_ms[0]:8.1f}{difference:11.1e}  {statuses}"
    )
print("(max |dq3|: largest difference of the applied q3 to daqp's, mL/s)")

# %%
# The closed loops on top of each other: pH with its set-point and constraint, the base
# flow q3 with its bounds. At this scale they coincide.
t = np.arange(setpoints.size) * model.Ts / 60  # minutes
low, high = model.y_phi_constraint
u_low, u_high = results["daqp"][1].input_bounds_phi
fig, (ax_y, ax_u) = plt.subplots(2, 1, sharex=True, figsize=(8, 5))
for j, (solver, (result, _)) in enumerate(results.items()):
    ax_y.plot(t, result.y_phi[:, 0], color=f"C{j}", lw=1.0, label=solver)
    ax_u.plot(t, result.u_phi[:, 0], color=f"C{j}", lw=1.0)
ax_y.plot(t, setpoints, "--", color="k", lw=0.8, label="set-point")
ax_y.axhline(float(low[0]), color="r", lw=0.8, label="output constraint")
ax_y.axhline(float(high[0]), color="r", lw=0.8)
ax_y.set_ylabel("pH")
ax_y.legend(loc="lower right", fontsize=7, ncol=3)
ax_u.axhline(u_low[0], color="k", lw=0.8, ls=":", label="input bounds")
ax_u.axhline(u_high[0], color="k", lw=0.8, ls=":")
ax_u.set_ylabel("q3 (mL/s)")
ax_u.set_xlabel("time (min)")
ax_u.legend(loc="center right", fontsize=8)
fig.suptitle("pH plant, N = 5, L_d = 0.1: set-point 7.0 -> 7.5, then q2 0.55 -> 0.7 mL/s")
fig.tight_layout()

# %%
# Per-step controller time by backend: one dot per step (log scale; colour =
# transcription), the median and the 5-95 % range. On the condensed path a whole step
# takes well under a millisecond; cvxpy's sparse path and the exact NMPC take milliseconds.
# Isolated slow steps are mostly the machine's own jitter (other processes).
colours = {"condensed": "C0", "sparse": "C1", "nonlinear": "C3"}
names = list(results)


def style(name: str) -> dict[str, object]:
    """Colour by transcription; pale for the terminal box of the QP-only backends."""
    result, controller = results[name]
    exact = controller.records[0].mpc.reformulation is None
    return {"color": colours[result.transcription], "alpha": 0.9 if exact else 0.45}


legend_handles = [
    plt.Rectangle((0, 0), 1, 1, color="C0", alpha=0.45, label="condensed, terminal box (QP)"),
    plt.Rectangle((0, 0), 1, 1, color="C0", alpha=0.9, label="condensed, exact cones"),
    plt.Rectangle((0, 0), 1, 1, color="C1", alpha=0.9, label="sparse, exact cones (cvxpy)"),
    plt.Rectangle((0, 0), 1, 1, color="C3", alpha=0.9, label="nonlinear (exact NMPC)"),
]
fig, ax = plt.subplots(figsize=(8, 4.5))
jitter = np.random.default_rng(0)  # only spreads the dots sideways
for x, name in enumerate(names, start=1):
    step_ms = 1e3 * results[name][0].time_total[1:]
    low, median, high = np.quantile(step_ms, [0.05, 0.5, 0.95])
    colour = style(name)
    ax.plot(x + jitter.uniform(-0.25, 0.25, step_ms.size), step_ms, ".", ms=2, **colour)
    ax.errorbar(x, median, yerr=[[median - low], [high - median]], fmt="_", ms=18, mew=2,
                color="k", capsize=5, elinewidth=1)  # fmt: skip
ax.set_xticks(range(1, len(names) + 1), names, rotation=30, ha="right")
ax.set_yscale("log")
ax.set_ylabel("controller step time (ms)")
ax.set_title(f"Step times over {setpoints.size - 1} steps (first step excluded)")
whisker = plt.Line2D([], [], color="k", marker="_", ms=12, label="median, 5-95 % of steps")
ax.legend(handles=[*legend_handles, whisker], loc="upper left", fontsize=8)
fig.tight_layout()

# %%
# Do the backends agree? The largest difference of the applied q3 to ``daqp``'s over the
# run. The QP backends solve the same QP: they agree to their tolerances. The exact-cone
# backends differ from it by the conservatism of the terminal box, and the exact NMPC by
# what one RTI linearization per step leaves out.
others = [name for name in names if name != "daqp"]
differences = [np.max(np.abs(results[name][0].u_phi[:, 0] - reference)) for name in others]
resolution = np.finfo(float).eps * np.max(np.abs(reference))
fig, ax = plt.subplots(figsize=(8, 4))
bars = ax.bar(others, np.maximum(differences, resolution))
for bar, name in zip(bars, others, strict=True):
    bar.set(facecolor=style(name)["color"], alpha=style(name)["alpha"])
line = ax.axhline(resolution, color="k", lw=0.8, ls=":", label="float64 resolution of q3")
ax.set_yscale("log")
ax.set_ylabel("max |q3 - q3(daqp)| (mL/s)")
ax.set_title("Largest difference of the applied input to daqp's, same scenario")
ax.tick_params(axis="x", rotation=30)
for label in ax.get_xticklabels():
    label.set_horizontalalignment("right")
ax.legend(handles=[*legend_handles, line], loc="upper left", fontsize=8)
fig.tight_layout()
plt.show()
