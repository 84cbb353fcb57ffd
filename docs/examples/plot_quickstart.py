"""
Quick start: the offset-free controller on the pH plant
=======================================================

The shipped delta-ISS LSTM of the pH-neutralization benchmark (paper Section V) controls the
pH plant itself (Fig. 1): a set-point step, then a step of the unmeasured buffer flow q2.
The disturbance estimate removes the offset the model-plant mismatch and the disturbance
would leave.
"""

import matplotlib.pyplot as plt
import numpy as np

from ltv_lstm_mpc import (
    MPCConfig,
    OffsetFreeController,
    PHNeutralizationPlant,
    load_model,
    simulate,
)

model = load_model("ph_lstm_n5.npz")
controller = OffsetFreeController(
    model, MPCConfig(solver="daqp", L_d=0.1), setpoint_rate_limit=0.01
)
plant = PHNeutralizationPlant()
plant.reset()
setpoints = np.repeat([7.5, 6.8, 6.8], 300)
q2 = np.repeat([0.55, 0.55, 0.7], 300)  # buffer flow, mL/s
result = simulate(plant, controller, setpoints, q2, progress=False)

# %%
# The offset at the end of each segment (pH):
for end in (299, 599, 899):
    print(f"k = {end}: |y - y0| = {abs(result.y_phi[end, 0] - setpoints[end]):.1e} pH")

# %%
# Output, set-point and the output constraint; the input and its bounds.
t = np.arange(setpoints.size) * 10 / 60  # minutes (Ts = 10 s)
low, high = model.y_phi_constraint
fig, (ax_y, ax_u) = plt.subplots(2, 1, sharex=True, figsize=(8, 5))
ax_y.plot(t, result.y_phi[:, 0], label="pH")
ax_y.plot(t, setpoints, "--", label="set-point")
ax_y.axhline(float(low[0]), color="r", lw=0.8, label="output constraint")
ax_y.axhline(float(high[0]), color="r", lw=0.8)
ax_y.set_ylabel("pH")
ax_y.legend(loc="upper right")
ax_u.plot(t, result.u_phi[:, 0], label="q3 (base flow)")
u_low, u_high = (bound[0] for bound in controller.input_bounds_phi)  # U, physical
ax_u.axhline(u_low, color="k", lw=0.8, ls=":", label="input bounds")
ax_u.axhline(u_high, color="k", lw=0.8, ls=":")
ax_u.set_ylabel("q3 (mL/s)")
ax_u.set_xlabel("time (min)")
ax_u.legend(loc="upper right")
fig.suptitle("pH plant, daqp, N = 5, L_d = 0.1: set-point step, then q2 0.55 -> 0.7 mL/s")
fig.tight_layout()
plt.show()
