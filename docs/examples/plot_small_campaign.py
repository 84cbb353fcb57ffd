r"""
A small robustness campaign and its report
==========================================

A campaign runs many closed loops over the product of a few factors and tabulates each
one: offsets, true-plant constraint violations, infeasible steps, fallbacks,
:math:`\hat d` saturation, step times. Here 24 short loops on the pH plant with the
shipped model: measurement noise (0 or 0.02 pH) x observer gain :math:`L_d` (0.01 or
0.1) x plant-model mismatch (none; 20 % more carbonate in the base stream, ``W_b3``;
acid 1 % stronger, ``W_a1``) x two noise seeds.

The spec is the dict form of the TOML file that ``ltv-lstm-mpc campaign SPEC.toml --out
DIR`` reads (:func:`~ltv_lstm_mpc.campaign.spec.load_spec`); every entry is checked when
it is read. The tasks run in this process (``serial=True``); ``workers=2`` runs them on a local
Dask cluster instead (from a script, under ``if __name__ == "__main__":``, or with the
command line), and a remote scheduler works by its address. Results, per-task files,
traces and the report go to a temporary folder here.
"""

# sphinx_gallery_thumbnail_number = 3

import tempfile
import textwrap
from pathlib import Path

import matplotlib.pyplot as plt
import numpy as np
import pyarrow.parquet as pq

from ltv_lstm_mpc import load_model
from ltv_lstm_mpc.campaign import parse_spec, run_campaign

spec = parse_spec(
    {
        "campaign": {
            "name": "gallery_robustness",
            "plant": "ph",
            "model": "ph_lstm_n5.npz",
            "steps": 900,  # Ts = 10 s: 2.5 hours of plant time per loop
            "setpoints": [7.5, 6.8, 7.2],  # pH, 300 samples each
            "q2": [0.55, 0.55, 0.7],  # buffer flow, mL/s
            "solver": "daqp",
            "rate_limit": 0.01,
            "trace": {"seed": [0], "noise_std": [0.02]},  # per-step traces of 6 tasks
        },
        "factors": {
            "noise_std": [0.0, 0.02],  # pH
            "L_d": [0.01, 0.1],
            "mismatch": [{}, {"W_b3": 1.2}, {"W_a1": 1.01}],
            "seed": [0, 1],
        },
    }
)
print(f"{len(spec.tasks)} tasks; varying: {spec.varying}")

with tempfile.TemporaryDirectory() as folder:
    run = run_campaign(spec, folder, serial=True, progress=False)
    out = Path(folder)
    print(f"{run.executed} tasks run, {run.errors} errors, {run.wall_s:.1f} s")
    written = ", ".join(str(path.relative_to(out)) for path in run.files)
    print(textwrap.fill(f"written: {written}", 88, subsequent_indent="    "))
    report = (out / "report.md").read_text()
    plots = [path for path in run.files if path.suffix == ".png"]
    report_plot_path = next((p for p in plots if "mismatch" in p.name), plots[0])
    report_plot = plt.imread(report_plot_path)
    traces = {
        row["key"]: pq.read_table(out / "traces" / f"{row['key']}.parquet").to_pydict()
        for row in run.rows
        if row["seed"] == 0 and row["noise_std"] == 0.02
    }

# %%
# The report
# ----------
# ``report.md``: the overall figures, then a break-down by each factor (and the errors, if
# any task failed).
print(report)

# %%
# One of the report's plots (``plots/`` holds one per factor): the distributions per
# mismatch. The 1 % stronger acid leaves
# an offset: the mismatch is larger than the disturbance bound :math:`d_{max}` the
# controller is tuned for, so :math:`\hat d` saturates (its steps are counted in
# ``d_hat_saturated_steps``).
fig, ax = plt.subplots(figsize=(10, 3.4))
ax.imshow(report_plot)
ax.set_axis_off()
fig.tight_layout()

# %%
# The rows, task by task
# ----------------------
# Every row holds the task's settings and its metrics; here the offset at the end of each
# set-point segment (largest of the three) and the steps with :math:`\hat d` at its bound,
# for each combination (two seeds each).
mismatches = list(dict.fromkeys(row["mismatch"] for row in run.rows))  # "nominal", ...
combinations = [(L_d, noise) for L_d in spec.factors["L_d"] for noise in spec.factors["noise_std"]]


def rows_of(mismatch, L_d, noise):
    """The rows of one combination of the factors (both seeds)."""
    wanted = (mismatch, L_d, noise)
    return [r for r in run.rows if (r["mismatch"], r["L_d"], r["noise_std"]) == wanted]


fig, (ax_o, ax_s) = plt.subplots(1, 2, figsize=(10, 4))
for i, mismatch in enumerate(mismatches):
    for j, (L_d, noise) in enumerate(combinations):
        rows = rows_of(mismatch, L_d, noise)
        x = [i + (j - 1.5) * 0.18] * len(rows)
        label = f"L_d = {L_d}, noise {noise} pH" if i == 0 else None
        style = {"marker": "o" if noise == 0.0 else "^", "ls": "", "color": f"C{j // 2}"}
        ax_o.plot(x, [r["final_offset"] for r in rows], label=label, **style)
        ax_s.plot(x, [r["d_hat_saturated_steps"] for r in rows], label=label, **style)
for ax in (ax_o, ax_s):
    ax.set_xticks(range(len(mismatches)), mismatches)
    ax.set_xlabel("plant-model mismatch")
ax_o.set_yscale("log")
ax_o.set_ylabel("final offset |pH - set-point| (pH)")
ax_o.set_title("largest offset at the end of a segment")
ax_s.set_ylabel("steps")
ax_s.set_title(f"steps with |d_hat| = d_max (of {spec.fixed['steps']})")
ax_s.legend(loc="upper left", fontsize=8)
fig.suptitle(f"{len(run.rows)} closed loops on the pH plant (true plant output)")
fig.tight_layout()

# %%
# Traces
# ------
# The six traced tasks (noise 0.02 pH, seed 0): true pH, set-point, base flow and the
# normalized disturbance estimate with its bound. With the stronger acid, :math:`\hat d`
# runs into :math:`-d_{max}` at the first set-point and the pH stays below it there: that
# segment gives the task's final offset. The larger :math:`L_d` estimates faster and
# passes more measurement noise to q3.
model = load_model(spec.fixed["model"])
t = np.arange(spec.fixed["steps"]) * model.Ts / 3600  # hours
low, high = model.y_phi_constraint
norm = model.normalization
fig, axes = plt.subplots(3, 2, sharex=True, sharey="row", figsize=(10, 7.5))
for column, L_d in enumerate((0.01, 0.1)):
    ax_y, ax_u, ax_d = axes[:, column]
    for row in run.rows:
        if row["key"] not in traces or row["L_d"] != L_d:
            continue
        trace = traces[row["key"]]
        colour = f"C{mismatches.index(row['mismatch'])}"
        label = row["mismatch"]
        ax_y.plot(t, trace["y_phi"], color=colour, lw=1, label=label)
        ax_u.plot(t, trace["u_phi"], color=colour, lw=1, label=label)
        ax_d.plot(t, trace["d_hat"], color=colour, lw=1, label=label)
        y0 = trace["y0_phi"]
    ax_y.plot(t, y0, "--", color="k", lw=0.8, label="set-point")
    ax_y.axhline(float(low[0]), color="r", lw=0.8, label="output constraint")
    ax_y.axhline(float(high[0]), color="r", lw=0.8)
    # U = the normalization range of the input (u_max = 1)
    ax_u.axhline(float(norm.u_phi_min[0]), color="k", lw=0.8, ls=":", label="input bounds")
    ax_u.axhline(float(norm.u_phi_max[0]), color="k", lw=0.8, ls=":")
    d_max = spec.tasks[0].settings["d_max"]
    ax_d.axhline(d_max, color="r", lw=0.8, label="±d_max")
    ax_d.axhline(-d_max, color="r", lw=0.8)
    ax_y.set_title(f"L_d = {L_d}, noise 0.02 pH, seed 0")
    ax_d.set_xlabel("time (h)")
axes[0, 0].set_ylabel("pH (true)")
axes[1, 0].set_ylabel("q3 (mL/s)")
axes[2, 0].set_ylabel("d_hat (normalized)")
axes[0, 1].legend(loc="upper right", fontsize=7, ncol=2)
axes[1, 1].legend(loc="lower right", fontsize=7, ncol=2)
axes[2, 1].legend(loc="lower right", fontsize=7, ncol=2)
setpoints, q2 = spec.fixed["setpoints"], spec.fixed["q2"]
fig.suptitle(f"Traced tasks: set-points {setpoints} pH, q2 {q2} mL/s (equal segments)")
fig.tight_layout()
plt.show()
