r"""
Fault injection: what the step records say
==========================================

Four things that go wrong in a real loop, on the pH plant with the shipped model, and
what the controller does about each. Every :class:`~ltv_lstm_mpc.ControllerStep` (and the
arrays of a :class:`~ltv_lstm_mpc.SimulationResult`) records

* the FHOCP ``status`` (``optimal``, or why it failed: ``failed``, ``solver_error``,
  ``infeasible``, ``alpha_nonpositive``, ``infeasible_initial``, ...) and ``reason``;
* the ``policy`` applied: ``nominal``, a fallback (``paper``, ``soft``, ``shift``), or
  ``<policy>+shift`` when the fallback failed too;
* the ``setpoint_status`` (``ok``, ``outside_admissible``, ``unreachable_stale``, ...)
  and the ``measurement_status`` (``ok``, ``outside_training_range``, ``implausible``);
* ``input_clipped``: how far the exit gate had to move the input into U.

Whatever happens, the input handed to the plant lies in U (checked below for each run).
Solver faults come from :func:`ltv_lstm_mpc.solvers.testing.faulty`, which wraps any
installed backend so that chosen solve calls misbehave.
"""

import textwrap
import warnings

import matplotlib.pyplot as plt
import numpy as np
from ltv_lstm_mpc.solvers.testing import faulty

from ltv_lstm_mpc import (
    InvalidValueError,
    MPCConfig,
    OffsetFreeController,
    PHNeutralizationPlant,
    load_model,
    simulate,
)

model = load_model("ph_lstm_n5.npz")
STEPS = 120
t = np.arange(STEPS) * model.Ts / 60  # minutes
low_y, high_y = model.y_phi_constraint
LANES = ("status", "policy", "setpoint_status", "measurement_status")


def say(text, indent=""):
    """Print wrapped to 88 columns (the library's messages are long)."""
    print(textwrap.fill(str(text), 88, initial_indent=indent, subsequent_indent=indent + "    "))


def closed_loop(solver, setpoints, *, rate=0.01):
    """One run of ``simulate``; the library's warnings are printed, as a user sees them."""
    config = MPCConfig(solver=solver, L_d=0.1)
    controller = OffsetFreeController(model, config, setpoint_rate_limit=rate)
    plant = PHNeutralizationPlant()
    plant.reset()
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        result = simulate(plant, controller, setpoints, 0.55, progress=False)
    for warning in caught:
        say(f"{warning.category.__name__}: {warning.message}")
    lanes = {name: getattr(result, name).astype(str) for name in LANES}
    return result.y_phi[:, 0], result.u_phi[:, 0], lanes, controller


def report(name, u, lanes, controller):
    """The statuses met, the first reason given, and the check that u stayed in U."""
    u_low, u_high = controller.input_bounds_phi
    inside = bool(np.all((u >= u_low[0]) & (u <= u_high[0])))
    say(f"{name}: input in U = [{u_low[0]:.2f}, {u_high[0]:.2f}] mL/s on every step: {inside}")
    for lane in LANES:
        values, counts = np.unique(lanes[lane], return_counts=True)
        print(
            f"  {lane:<19} " + ", ".join(f"{v} x{c}" for v, c in zip(values, counts, strict=True))
        )
    reasons = [r.mpc.reason for r in controller.records if r.mpc.reason]
    if reasons:
        say(f"first reason: {reasons[0]}", "  ")


def figure(title, runs, setpoints, spans=(), lanes_shown=LANES):
    """pH, q3 with its bounds, and one row per status value met (a mark per step)."""
    fig, (ax_y, ax_u, ax_s) = plt.subplots(
        3, 1, sharex=True, figsize=(8, 7.5), gridspec_kw={"height_ratios": [2, 2, 2.2]}
    )
    rows = []
    for j, (label, y, u, lanes, _) in enumerate(runs):
        tag = f" ({label})" if label else ""
        ax_y.plot(t, y, color=f"C{j}", label=f"pH{tag}")
        ax_u.plot(t, u, color=f"C{j}", label=f"q3{tag}")
        for lane in lanes_shown:
            for value in dict.fromkeys(lanes[lane]):
                rows.append((f"{lane}: {value}{tag}", lanes[lane] == value, f"C{j}"))
    ax_y.plot(t, setpoints, "--", color="k", lw=0.8, label="set-point")
    ax_y.axhline(float(low_y[0]), color="r", lw=0.8, label="output constraint")
    ax_y.axhline(float(high_y[0]), color="r", lw=0.8)
    ax_y.set_ylim(float(low_y[0]) - 0.5, float(high_y[0]) + 1.3)
    u_low, u_high = runs[0][4].input_bounds_phi
    ax_u.axhline(u_low[0], color="k", lw=0.8, ls=":", label="input bounds")
    ax_u.axhline(u_high[0], color="k", lw=0.8, ls=":")
    for start, stop, text, colour in spans:
        for ax in (ax_y, ax_u, ax_s):
            ax.axvspan(
                t[start],
                t[stop - 1],
                color=colour,
                alpha=0.15,
                lw=0,
                label=text if ax is ax_y else None,
            )
    for i, (_, mask, colour) in enumerate(rows):
        ax_s.plot(t[mask], np.full(mask.sum(), i), "|", color=colour, ms=6)
    ax_s.set_yticks(range(len(rows)), [name for name, _, _ in rows], fontsize=7)
    ax_s.set_ylim(len(rows) - 0.5, -0.5)
    ax_y.set_ylabel("pH")
    ax_y.legend(loc="upper left", fontsize=7, ncol=3)
    ax_u.set_ylabel("q3 (mL/s)")
    ax_u.legend(loc="lower left", fontsize=7, ncol=2)
    ax_s.set_xlabel("time (min)")
    ax_s.set_title("step records", fontsize=9)
    fig.suptitle(title)
    fig.tight_layout()


# %%
# A solver that lies
# ------------------
# DAQP wrapped so that 20 solve calls return the point ``1e6`` reported *optimal*. The MPC
# core checks every point before using it: this one is ``failed`` (the reason says why),
# the ``paper`` fallback is tried (its solve is faulted too) and the previous plan,
# shifted, is applied (``paper+shift``).
setpoints = np.repeat([7.0, 7.5], [30, STEPS - 30])
solver = faulty("daqp", "garbage", calls=range(40, 60))
y, u, lanes, controller = closed_loop(solver, setpoints)
say(f"registered as {solver!r}")
report("daqp with injected faults", u, lanes, controller)
faulted = np.flatnonzero(lanes["status"] != "optimal")
figure(
    "Injected solver fault: 'garbage' points reported optimal",
    [("", y, u, lanes, controller)],
    setpoints,
    [(faulted[0], faulted[-1] + 1, "faulted solves", "C3")],
)

# %%
# A set-point outside the admissible interval
# -------------------------------------------
# 8.8 pH lies inside the output constraint [6, 9] pH but outside the admissible interval of
# Assumption 5 (the constraint shrunk by the tightening and 2 d_max): no terminal set
# exists (``alpha_nonpositive``), and once the output gets close to the tightened bound
# the first output row fails too (``infeasible_initial``). The ``paper`` policy applies.
# Without a rate limit the set-point jumps there at once.
setpoints = np.repeat([7.0, 8.8], [40, STEPS - 40])
y, u, lanes, controller = closed_loop("daqp", setpoints, rate=None)
report("set-point 8.8 pH", u, lanes, controller)
low_a, high_a = controller.certification.y0_interval_phi
print(f"admissible set-points: [{low_a[0]:.3f}, {high_a[0]:.3f}] pH")
figure(
    "Set-point 8.8 pH, outside the admissible interval (no rate limit)",
    [("", y, u, lanes, controller)],
    setpoints,
)

# %%
# An unreachable set-point
# ------------------------
# 10 pH needs more base than q3 can deliver: the reference calculator finds no equilibrium
# with the input in U, the controller keeps the previous target (``unreachable_stale``)
# and says so once per run.
setpoints = np.repeat([7.0, 10.0], [40, STEPS - 40])
y, u, lanes, controller = closed_loop("daqp", setpoints, rate=None)
report("set-point 10 pH", u, lanes, controller)
figure("Set-point 10 pH: no equilibrium with q3 in U", [("", y, u, lanes, controller)], setpoints)

# %%
# Sensor faults
# -------------
# The pH sensor drops out (NaN) for five samples, later reads 0 pH for three (a fault or
# wrong units). A non-finite measurement is always refused
# (:class:`~ltv_lstm_mpc.InvalidValueError`, before anything is updated); a finite one
# far outside the training range is ``implausible``: with the default
# ``implausible_measurements="flag"`` it is used (and the observer, the disturbance
# estimate and the input react to it), with ``"raise"`` it is refused too. Here the loop
# is written out, and the caller holds the last input while the controller refuses. (The
# step numbers in the controller's messages count the steps it recorded: the refused
# samples are not among them.)
DROPOUT, SPIKE = (40, 45), (80, 83)


def sensor_loop(implausible):
    controller = OffsetFreeController(
        model,
        MPCConfig(solver="daqp", L_d=0.1),
        setpoint_rate_limit=0.01,
        implausible_measurements=implausible,
    )
    plant = PHNeutralizationPlant()
    plant.reset()
    y_true, u_applied, lanes = [], [], {lane: [] for lane in LANES}
    first_refusal = {}
    u = None
    for k in range(STEPS):
        y = plant.output()
        if DROPOUT[0] <= k < DROPOUT[1]:
            y = np.array([np.nan])
        elif SPIKE[0] <= k < SPIKE[1]:
            y = np.array([0.0])
        try:
            u = controller.step(y, 7.3)
            record = controller.records[-1]
            values = (
                record.mpc.status,
                record.mpc.policy,
                record.setpoint_status,
                record.measurement_status,
            )
        except InvalidValueError as error:  # nothing was updated: hold the last input
            first_refusal.setdefault(np.isnan(y).any(), str(error))
            values = ("refused (last input held)",) * 3 + ("refused",)
        for lane, value in zip(LANES, values, strict=True):
            lanes[lane].append(value)
        y_true.append(plant.output()[0])
        u_applied.append(u[0])
        plant.step(u, 0.55)
    for message in first_refusal.values():
        say(f"refused: {message}", "  ")
    lanes = {lane: np.array(values) for lane, values in lanes.items()}
    return np.array(y_true), np.array(u_applied), lanes, controller


runs = []
for implausible in ("flag", "raise"):
    print(f'implausible_measurements="{implausible}":')
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        y, u, lanes, controller = sensor_loop(implausible)
    for warning in caught:
        say(f"{warning.category.__name__}: {warning.message}", "  ")
    report(f'  "{implausible}"', u, lanes, controller)
    runs.append((implausible, y, u, lanes, controller))
figure(
    "Sensor faults: NaN dropout, then a reading of 0 pH (true pH plotted)",
    runs,
    np.full(STEPS, 7.3),
    [(*DROPOUT, "sensor reads NaN", "C3"), (*SPIKE, "sensor reads 0 pH", "C4")],
    lanes_shown=("status", "measurement_status"),
)
plt.show()
