r"""
Training a delta-ISS LSTM on generated data
===========================================

The identification of the paper's Section V, cut down to run in seconds. A multilevel
pseudo-random experiment on the pH plant (levels of the base flow q3 held for 10 to 100
samples, Ts = 10 s, every sequence starting at the nominal steady state) gives the data;
:func:`~ltv_lstm_mpc.training.train.train` fits a single-layer LSTM in PyTorch with the
paper's loss, the mean squared error plus :math:`\lambda_1 \max\{r_i, 0\} + \lambda_2
\min\{r_i, 0\}` on the residuals :math:`r_1, r_2` of Remark 1, which pulls the weights into
the delta-ISS region; it stops only on weights certified delta-ISS (:math:`\rho(A_\delta)
< 1` on the exported float64 model). The model is then certified for the controller,
compared with test data it has not seen, and put in the loop.

The paper trains on 15 sequences of 1500 samples for 1000 epochs; the shipped
``ph_lstm_n5.npz`` comes from the same data and 1500 epochs of the fidelity preset
(``ltv-lstm-mpc train``, about 10 minutes); this example uses 6 sequences of 600 samples
and 80 epochs. The model, its JSON report and a plot are written to a temporary
folder.
"""

# sphinx_gallery_thumbnail_number = 2

import tempfile

import matplotlib.pyplot as plt
import numpy as np

from ltv_lstm_mpc import (
    MPCConfig,
    OffsetFreeController,
    PHNeutralizationPlant,
    certify,
    simulate,
)
from ltv_lstm_mpc.training.datasets import generate_dataset, initial_input
from ltv_lstm_mpc.training.train import TrainingConfig, train

dataset = generate_dataset(
    seed=0, sequences=6, steps=600, split_sizes=(4, 1, 1), plant=PHNeutralizationPlant()
)
for split in ("train", "val", "test"):
    u, y = dataset.split(split)
    print(
        f"{split:<5}: {u.shape[0]} sequences x {u.shape[1]} samples, q3 in "
        f"[{u.min():.2f}, {u.max():.2f}] mL/s, pH in [{y.min():.2f}, {y.max():.2f}]"
    )

config = TrainingConfig(n=5, epochs=80, lr=1e-2, checkpoint_every=0, eval_every=2)
with tempfile.TemporaryDirectory() as folder:
    result = train(dataset, config, folder, progress=False)
model, report = result.model, result.report
print(
    f"{report['epochs_run']} epochs in {report['wall_time_s']:.1f} s; best validation "
    f"FIT at epoch {report['best_epoch']}"
)
print("FIT (%):", ", ".join(f"{split} {fit:.1f}" for split, fit in report["fit"].items()))
print(
    f"rho(A_delta) = {report['rho_A_delta']:.4f} (r1 = {report['r1']:.4f}, "
    f"r2 = {report['r2']:.4f}), rho_s = {report['rho_s']:.4f}"
)
norm = model.normalization
print(f"{model}: normalization q3 in [{norm.u_phi_min[0]:.3f}, {norm.u_phi_max[0]:.3f}] mL/s,")
print(f"  pH in [{norm.y_phi_min[0]:.3f}, {norm.y_phi_max[0]:.3f}] (the training data's ranges)")

# %%
# Training history: the loss (its MSE part), the residuals of Remark 1 and the validation
# FIT, at every evaluation. The delta-ISS terms push :math:`r_1, r_2` below 0.
history = {key: np.array([record[key] for record in result.history]) for key in result.history[0]}
fig, (ax_l, ax_r, ax_f) = plt.subplots(1, 3, figsize=(11, 3.4))
ax_l.semilogy(history["epoch"], history["mse"], color="C0")
ax_l.set_title("training MSE (normalized)")
ax_r.plot(history["epoch"], history["r1"], color="C1", label="r1")
ax_r.plot(history["epoch"], history["r2"], color="C2", label="r2")
ax_r.axhline(0.0, color="r", lw=0.8, label="delta-ISS needs r1, r2 < 0")
ax_r.set_title("Remark 1 residuals")
ax_r.legend(fontsize=8)
ax_f.plot(history["epoch"], history["fit_val"], color="C3")
ax_f.set_title("validation FIT (%)")
for ax in (ax_l, ax_r, ax_f):
    ax.set_xlabel("epoch")
fig.tight_layout()

# %%
# The test sequence: the trained model simulated open loop from the equilibrium of the
# data's initial input (as the FIT is computed) against the plant's pH.
u_test, y_test = dataset.split("test")
x0 = model.equilibrium(model.normalize_u(initial_input(dataset.metadata)))
_, y_model = model.simulate(x0, model.normalize_u(u_test[0][:-1, None]))
prediction = model.denormalize_y(y_model)[:, 0]
t = np.arange(u_test.shape[1]) * model.Ts / 60  # minutes
low, high = model.y_phi_constraint
fig, (ax_y, ax_u) = plt.subplots(2, 1, sharex=True, figsize=(8, 5))
ax_y.plot(t, y_test[0], color="k", lw=1.0, label="pH plant (test data)")
ax_y.plot(t, prediction, color="C1", lw=1.0, label="trained LSTM, open loop")
ax_y.axhline(float(low[0]), color="r", lw=0.8, label="output constraint")
ax_y.axhline(float(high[0]), color="r", lw=0.8)
ax_y.set_ylabel("pH")
ax_y.legend(loc="upper left", bbox_to_anchor=(0, 0.94), fontsize=8, ncol=3)
ax_u.step(t, u_test[0], where="post", color="C0", label="q3 (base flow)")
ax_u.axhline(
    float(model.normalization.u_phi_min[0]), color="k", lw=0.8, ls=":", label="training input range"
)
ax_u.axhline(float(model.normalization.u_phi_max[0]), color="k", lw=0.8, ls=":")
ax_u.set_ylabel("q3 (mL/s)")
ax_u.set_xlabel("time (min)")
ax_u.legend(loc="lower left", fontsize=8)
fig.suptitle(
    f"Test sequence: FIT {report['fit']['test']:.1f} % (n = {model.n}, "
    f"{report['epochs_run']} epochs)"
)
fig.tight_layout()

# %%
# Certificates for the controller, then the trained model controls the pH plant: a
# set-point step and a step of the unmeasured buffer flow q2.
mpc_config = MPCConfig(solver="daqp", L_d=0.1)
cert = certify(model, mpc_config.certification_settings(model))
low_y0, high_y0 = cert.y0_interval_phi
print(
    f"rho_o = {cert.observer.rho_o:.4f}, e_inf = {cert.tightening.e_inf:.4f}, admissible "
    f"set-points [{low_y0[0]:.3f}, {high_y0[0]:.3f}] pH"
)
controller = OffsetFreeController(model, mpc_config, setpoint_rate_limit=0.01)
plant = PHNeutralizationPlant()
plant.reset()
setpoints = np.repeat([7.0, 7.5, 7.5], 150)
q2 = np.repeat([0.55, 0.55, 0.7], 150)  # mL/s
loop = simulate(plant, controller, setpoints, q2, progress=False)
for end in (149, 299, 449):
    print(f"k = {end}: |pH - set-point| = {abs(loop.y_phi[end, 0] - setpoints[end]):.1e}")

t = np.arange(setpoints.size) * model.Ts / 60
u_low, u_high = controller.input_bounds_phi
fig, (ax_y, ax_u) = plt.subplots(2, 1, sharex=True, figsize=(8, 5))
ax_y.plot(t, loop.y_phi[:, 0], label="pH")
ax_y.plot(t, setpoints, "--", color="k", lw=0.8, label="set-point")
ax_y.axhline(float(low[0]), color="r", lw=0.8, label="output constraint")
ax_y.axhline(float(high[0]), color="r", lw=0.8)
ax_y.set_ylabel("pH")
ax_y.legend(loc="lower right", fontsize=8)
ax_u.plot(t, loop.u_phi[:, 0], label="q3 (base flow)")
ax_u.axhline(u_low[0], color="k", lw=0.8, ls=":", label="input bounds")
ax_u.axhline(u_high[0], color="k", lw=0.8, ls=":")
ax_u.set_ylabel("q3 (mL/s)")
ax_u.set_xlabel("time (min)")
ax_u.legend(loc="lower right", fontsize=8)
fig.suptitle("The trained model in the loop: daqp, N = 5, L_d = 0.1; q2 0.55 -> 0.7 mL/s")
fig.tight_layout()
plt.show()
