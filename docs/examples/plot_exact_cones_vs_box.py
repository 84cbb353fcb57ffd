r"""
Exact terminal cones or the conservative box
============================================

The terminal set of the FHOCP, eq. (optimization), is

.. math::

    \mathcal X_f(k) = \{x_N : \|[\,\|c_N - \bar c\|,\ \|h_N - \bar h\|\,]\|_{P_f}
    \le \alpha_k\},

an ellipse in the plane of the two distances :math:`t = (t_c, t_h) =
(\|c_N - \bar c\|, \|h_N - \bar h\|)`, posed exactly with second-order cones by a cone
solver (here the native ``clarabel`` on the condensed transcription). A QP-only solver
(here ``daqp``) gets the conservative reformulation of paper notes 4: a box on every
entry of :math:`c_N - \bar c` and :math:`h_N - \bar h` whose image in the t-plane is the
largest-area rectangle inside the ellipse, and a terminal cost that bounds
:math:`V_f` from above.

Both run the same pH scenario, with set-point steps rate-limited at 0.015 (normalized per
step), faster than Theorem 3 certifies (for :math:`L_d = 0.1` its inequality has no
solution at all, see the first line of output): the size of the terminal set then
decides whether the FHOCP stays feasible. Both transcriptions are condensed, so only the
terminal set and cost differ.
"""

# sphinx_gallery_thumbnail_number = 2

import matplotlib.pyplot as plt
import numpy as np

from ltv_lstm_mpc import (
    MPCConfig,
    OffsetFreeController,
    PHNeutralizationPlant,
    RobustMPC,
    certify,
    load_model,
    simulate,
)
from ltv_lstm_mpc.mpc.terminal import TerminalSet

model = load_model("ph_lstm_n5.npz")
certification = certify(model, MPCConfig(L_d=0.1).certification_settings(model))
bound = certification.rate_bound
print(f"Theorem 3's set-point rate bound for L_d = 0.1: holds = {bound.holds},")
print(f"  Delta y0_max = {bound.delta_y0_max:.2e} (normalized per step); here: 0.015")
setpoints = np.repeat([7.0, 8.0, 6.6], 100)  # pH
runs = {}
for solver in ("clarabel", "daqp"):
    config = MPCConfig(solver=solver, L_d=0.1)
    mpc = RobustMPC(model, config, certification=certification)
    controller = OffsetFreeController(model, config, setpoint_rate_limit=0.015, mpc=mpc)
    plant = PHNeutralizationPlant()
    plant.reset()
    result = simulate(plant, controller, setpoints, 0.55, progress=False)
    runs[solver] = (result, controller.records)

# %%
# Per step, the records give the terminal level :math:`\alpha_k`, the terminal-set norm
# of the applied plan (``residuals["terminal_residual"]`` is norm minus
# :math:`\alpha_k`), the plan's cost (eq. optimization_cost, with the exact
# :math:`V_f`) and whether the nominal FHOCP was feasible (otherwise the ``paper``
# fallback acts).
labels = {"clarabel": "exact cones (clarabel)", "daqp": "terminal box (daqp)"}
for solver, (result, records) in runs.items():
    reformulation = records[0].mpc.reformulation or "none (exact second-order cones)"
    tracking = np.mean((result.y_phi[:, 0] - setpoints) ** 2)
    print(f"{labels[solver]}: reformulation {reformulation}")
    print(
        f"  infeasible steps {np.sum(~result.feasible)} of {setpoints.size}, policies "
        f"{sorted(map(str, set(result.policy)))}"
    )
    print(
        f"  sum of plan costs {sum(r.mpc.cost for r in records):.2f}, "
        f"mean (pH - set-point)^2 {tracking:.4f}"
    )

# %%
# Output, input, the terminal-set norm of each applied plan against :math:`\alpha_k`, and
# the plan cost. Going down to 6.6 pH the terminal level shrinks; there the box leaves the
# FHOCP infeasible on some steps (crosses), the ``paper`` fallback acts, the input
# chatters, and the box plans re-simulated on the LSTM end outside the terminal set (norm
# above :math:`\alpha_k`: the linearization of one RTI step is poor on such jumps). The
# exact cones keep every step feasible.
t = np.arange(setpoints.size) * model.Ts / 60  # minutes
low, high = model.y_phi_constraint
u_low, u_high = OffsetFreeController(model, MPCConfig(solver="daqp", L_d=0.1)).input_bounds_phi
fig, (ax_y, ax_u, ax_t, ax_c) = plt.subplots(4, 1, sharex=True, figsize=(8, 9.5))
styles = {"clarabel": {"color": "C0", "lw": 1.2}, "daqp": {"color": "C1", "lw": 1.2, "ls": "--"}}
for solver, (result, records) in runs.items():
    style = styles[solver]
    ax_y.plot(t, result.y_phi[:, 0], label=f"pH, {labels[solver]}", **style)
    ax_u.plot(t, result.u_phi[:, 0], label=f"q3, {labels[solver]}", **style)
    norm = np.array([r.mpc.residuals["terminal_residual"] for r in records]) + result.alpha
    ax_t.plot(t, norm, label=f"||t_N||_Pf of the plan, {labels[solver]}", **style)
    ax_c.plot(t, [r.mpc.cost for r in records], label=labels[solver], **style)
    infeasible = ~result.feasible
    if infeasible.any():
        ax_t.plot(
            t[infeasible],
            np.zeros(infeasible.sum()),
            "x",
            color=style["color"],
            ms=4,
            label=f"infeasible FHOCP, {labels[solver]}",
        )
ax_y.plot(t, setpoints, ":", color="k", lw=0.8, label="requested set-point")
ax_y.axhline(float(low[0]), color="r", lw=0.8, label="output constraint")
ax_y.axhline(float(high[0]), color="r", lw=0.8)
ax_y.set_ylabel("pH")
ax_y.legend(loc="upper left", fontsize=7, ncol=2)
ax_u.axhline(u_low[0], color="k", lw=0.8, ls=":", label="input bounds")
ax_u.axhline(u_high[0], color="k", lw=0.8, ls=":")
ax_u.set_ylabel("q3 (mL/s)")
ax_u.legend(loc="lower left", fontsize=7)
ax_t.plot(t, runs["clarabel"][0].alpha, color="k", lw=0.8, label="terminal level alpha_k")
ax_t.set_ylabel("terminal-set norm")
ax_t.legend(loc="upper left", fontsize=7, ncol=2)
ax_c.set_yscale("log")
ax_c.set_ylabel("plan cost")
ax_c.set_xlabel("time (min)")
ax_c.legend(loc="lower left", fontsize=7)
fig.suptitle("pH plant, N = 5, L_d = 0.1, set-point rate 0.015: exact cones vs terminal box")
fig.tight_layout()

# %%
# The terminal set in the t-plane
# -------------------------------
# Left: the ellipse :math:`\|t\|_{P_f} \le \alpha_k` and the box at the step where the
# exact-cone plan ends closest to the boundary, with both plans' end points. Right: every
# step at once, scaled by :math:`\alpha_k` (the set is then the same for all steps);
# the box's corner lies on the ellipse, so the box is inside it. The points are the ends of
# the linearized predictions (``MPCSolution.x_linear``), on which the subproblem's terminal
# constraint acts; the plan re-simulated on the LSTM ends up to
# ``residuals["linearization_gap"]`` away from them.
terminal = TerminalSet(certification.tightening.P_f, model.n)
tau_c, tau_h = terminal.unit_tau  # box half-sizes in t for alpha_k = 1
print("P_f =", [[float(f"{v:.4g}") for v in row] for row in terminal.P_f])
print(
    f"box corner tau = ({tau_c:.4f}, {tau_h:.4f}) at alpha = 1; "
    f"||tau||_Pf = {np.sqrt(terminal.level(tau_c, tau_h)):.6f}"
)


def end_distances(records):
    """t = (||c_N - c_bar||, ||h_N - h_bar||) at the end of each step's linearized
    prediction (``x_linear``: the states the terminal constraint of the subproblem acts on)."""
    n = model.n
    ends = np.array([r.mpc.x_linear[-1] - r.x_bar for r in records])
    return np.linalg.norm(ends[:, :n], axis=1), np.linalg.norm(ends[:, n:], axis=1)


exact_result, exact_records = runs["clarabel"]
box_result, box_records = runs["daqp"]
exact_tc, exact_th = end_distances(exact_records)
box_tc, box_th = end_distances(box_records)
exact_ratio = np.array(
    [terminal.norm(r.mpc.x_linear[-1], r.x_bar) / r.mpc.alpha for r in exact_records]
)
k_star = int(np.argmax(np.where(exact_result.feasible, exact_ratio, -np.inf)))
alpha_star = exact_result.alpha[k_star]

fig, (ax_a, ax_b) = plt.subplots(1, 2, figsize=(10, 4.6))
for ax, scale in ((ax_a, alpha_star), (ax_b, 1.0)):
    grid_c = np.linspace(0, 1.15 * scale / np.sqrt(terminal.P_f[0, 0]), 300)
    grid_h = np.linspace(0, 1.15 * scale / np.sqrt(terminal.P_f[1, 1]), 300)
    level = np.sqrt(terminal.level(*np.meshgrid(grid_c, grid_h)))
    ax.contourf(grid_c, grid_h, level, levels=[0, scale], colors=["C0"], alpha=0.15)
    ax.contour(grid_c, grid_h, level, levels=[scale], colors=["C0"], linewidths=1.5)
    ax.add_patch(
        plt.Rectangle(
            (0, 0), scale * tau_c, scale * tau_h, fill=False, edgecolor="C1", lw=1.5, ls="--"
        )
    )
    ax.plot(scale * tau_c, scale * tau_h, "o", color="C1", ms=5)
    ax.set_xlim(0, grid_c[-1])
    ax.set_ylim(0, grid_h[-1])
both_feasible = exact_result.feasible & box_result.feasible
ax_a.plot(exact_tc[k_star], exact_th[k_star], "s", color="C0", label="end of the exact-cone plan")
if box_result.feasible[k_star]:
    ax_a.plot(box_tc[k_star], box_th[k_star], "^", color="C1", label="end of the box plan")
box_state = "feasible" if box_result.feasible[k_star] else "infeasible"
ax_a.set_title(f"step k = {k_star}, alpha_k = {alpha_star:.3f} (box FHOCP {box_state})")
ax_b.plot(
    exact_tc[both_feasible] / exact_result.alpha[both_feasible],
    exact_th[both_feasible] / exact_result.alpha[both_feasible],
    ".",
    color="C0",
    ms=4,
    label="plan ends, exact cones",
)
ax_b.plot(
    box_tc[both_feasible] / box_result.alpha[both_feasible],
    box_th[both_feasible] / box_result.alpha[both_feasible],
    ".",
    color="C1",
    ms=4,
    label="plan ends, terminal box",
)
ax_b.set_title("all steps with both FHOCPs feasible, scaled by alpha_k")
ax_a.set_xlabel("t_c = ||c_N - c_bar||")
ax_a.set_ylabel("t_h = ||h_N - h_bar||")
ax_b.set_xlabel("t_c / alpha_k")
ax_b.set_ylabel("t_h / alpha_k")
legend = [
    plt.Rectangle((0, 0), 1, 1, color="C0", alpha=0.3, label="terminal set ||t||_Pf <= alpha"),
    plt.Line2D([], [], color="C1", ls="--", label="box reformulation (its image in t)"),
]
ax_a.legend(handles=legend + ax_a.get_legend_handles_labels()[0], loc="upper right", fontsize=7)
ax_b.legend(handles=legend + ax_b.get_legend_handles_labels()[0], loc="upper right", fontsize=7)
fig.suptitle("Terminal set in the plane of (||c_N - c_bar||, ||h_N - h_bar||), normalized states")
fig.tight_layout()
plt.show()
