r"""
Your own model: units, output constraint, certificates and a closed loop
========================================================================

An LSTM of eq. (lstm) works on normalized signals in [-1, 1]; what makes it *your* model
is the physical side: the normalization (the ranges of the identification data), the
output constraint :math:`\mathcal Y_\phi` and the sampling time. This example takes the
weights of the small delta-ISS network the library ships (``example_delta_iss_n3.npz``,
n = 3 neurons, one input, one output) and gives them the units of a heating process:
heater power P in [0, 10] kW in, outlet temperature T in [20, 80] °C out, the constraint
25 °C <= T <= 75 °C, Ts = 10 s.

:func:`~ltv_lstm_mpc.certify` then computes every number the guarantees of the paper
rest on (Assumption 2 to Theorem 3), and the controller runs against the model itself
with an unmeasured output disturbance (the nominal setting of the paper's Fig. 2,
:class:`~ltv_lstm_mpc.LSTMPlant`).

Weights trained in PyTorch come in the same way:
``LSTMModel.from_torch_state_dict(state_dict, normalization=..., y_phi_constraint=(low,
high), Ts=...)`` takes the state dict of one ``nn.LSTM`` layer and one ``nn.Linear``.
"""

import tempfile
import textwrap
from pathlib import Path

import matplotlib.pyplot as plt
import numpy as np

from ltv_lstm_mpc import (
    LSTMModel,
    LSTMPlant,
    MPCConfig,
    Normalization,
    OffsetFreeController,
    certify,
    load_model,
    simulate,
)

weights = load_model("example_delta_iss_n3.npz").weights()  # W_f, U_f, b_f, ..., W_y, b_y
print(textwrap.fill("weights: " + ", ".join(f"{k} {v.shape}" for k, v in weights.items()), 88))

# The identification data's ranges: heater power P in kW, outlet temperature T in °C.
normalization = Normalization(u_phi_min=[0.0], u_phi_max=[10.0], y_phi_min=[20.0], y_phi_max=[80.0])
model = LSTMModel(
    **weights, normalization=normalization, y_phi_constraint=([25.0], [75.0]), Ts=10.0
)

# %%
# The model file carries all of it: weights, normalization, constraint and Ts (the
# example saves it in a temporary folder and loads it back).
with tempfile.TemporaryDirectory() as folder:
    path = model.save(Path(folder) / "heater_lstm_n3.npz")
    model = load_model(path)
low_c, high_c = model.y_phi_constraint
print(model, f"Ts = {model.Ts} s, constraint T in [{low_c[0]}, {high_c[0]}] °C")

# %%
# Certificates
# ------------
# One call for one tuning (here the defaults of the paper's Section V with
# :math:`L_d = 0.1`): the constructor of the controller runs the same call and refuses a
# model that is not delta-ISS or a constraint that leaves no admissible set-point.
config = MPCConfig(solver="daqp", L_d=0.1)
cert = certify(model, config.certification_settings(model))
d, ly, ob, ti = cert.delta_iss, cert.lyapunov, cert.observer, cert.tightening
y_scale = float(model.normalization.y_scale[0])  # °C per normalized unit


def number(value: object) -> str:
    """4 significant digits; arrays as nested lists on one line."""
    array = np.asarray(value)
    if array.ndim == 0:
        return f"{float(array):.4g}"
    return "[" + ", ".join(number(item) for item in array) + "]"


def show(symbol: str, value: object, meaning: str) -> None:
    """``symbol  value  meaning``; the meaning on its own line after a long value."""
    text = number(value)
    if len(text) <= 18:
        print(f"  {symbol:<18} {text:<18} {meaning}")
    else:
        print(f"  {symbol:<18} {text}\n  {'':<18} {'':<18} {meaning}")


print("delta-ISS (Assumption 2, Theorem 1, Remark 1)")
show("rho(A_delta)", d.rho_A_delta, "< 1: the LSTM is delta-ISS")
show("r1, r2", [d.r1, d.r2], "Remark 1 residuals: both < 0 iff delta-ISS")
show("sigma_f", d.sigma_f, "bound of the forget gate over U")
print("incremental Lyapunov function V_s (Lemma 2)")
show("rho_s", ly.rho_s, "contraction of V_s per step")
show("c_s_l, c_s_u", [ly.c_s_l, ly.c_s_u], "bounds of V_s by the state difference")
show("c_s", ly.c_s, "output change per unit of V_s")
print("observer (Assumption 3, Theorem 2)")
show("rho(A_d)", ob.rho_A_d, "< 1: Assumption 3 holds")
show("rho_o", ob.rho_o, "contraction of the observer error V_o per step")
show("c_o", ob.c_o, "output error per unit of V_o")
show("L_max", ob.L_max, "observer correction per unit of V_o")
show("w_max", ob.w_max, "admissible disturbance change per step")
show("w_bar", ob.w_bar, "V_o increase caused by a change w_max")
show("d_max", ob.d_max, f"|d_hat| <= d_max: {ob.d_max * y_scale:.3g} °C of disturbance")
print("observer error bound and constraint tightening (eq. constraint_tightening_parameters)")
show("e_inf", ti.e_inf, "steady bound w_bar / (1 - rho_o) on V_o")
show("a_i (i = 0..N)", ti.a[:, 0], "tightening per unit of e_hat_o,k")
show("b_i (i = 0..N)", ti.b[:, 0], "tightening from the disturbance drift")
show("P_f", ti.P_f, "terminal weight (paper notes 2.6)")
low_y0, high_y0 = cert.y0_interval_phi
show(
    "admissible y0 (°C)", [low_y0[0], high_y0[0]], "Assumption 5: alpha_k > 0 for these set-points"
)
show("K_bar", cert.K_bar.K_bar, "Lemma 5: gain from set-point to equilibrium")
rate = cert.rate_bound.delta_y0_max
show("Delta y0_max", rate, f"Theorem 3: set-point rate, {rate * y_scale:.3g} °C per step")

# %%
# What the tightening leaves: the predicted output i steps ahead must stay within
# :math:`\mathcal Y` shrunk by :math:`a_i \hat e_{o,k} + b_i + d_{max}`
# (eq. optimization_constraint_yub/ylb), here at :math:`\hat e_{o,k} = \bar e_\infty`; at
# the end of the horizon the terminal set needs room for :math:`2 d_{max}` more, which
# gives the admissible set-point interval.
lower, upper = ti.output_bounds(ti.e_inf)  # (N, p), normalized
lower_c, upper_c = model.denormalize_y(lower)[:, 0], model.denormalize_y(upper)[:, 0]
steps_ahead = np.arange(ti.N)
fig, ax = plt.subplots(figsize=(7, 3.8))
ax.bar(
    steps_ahead,
    upper_c - lower_c,
    bottom=lower_c,
    width=0.6,
    color="C0",
    alpha=0.6,
    label="tightened output band, i = 0..N-1",
)
ax.bar(
    ti.N,
    high_y0[0] - low_y0[0],
    bottom=low_y0[0],
    width=0.6,
    color="C2",
    alpha=0.6,
    label="admissible set-points (Assumption 5)",
)
ax.axhline(low_c[0], color="r", lw=0.8, label="output constraint")
ax.axhline(high_c[0], color="r", lw=0.8)
ax.set_xticks([*steps_ahead, ti.N], [*map(str, steps_ahead), "set-point"])
ax.set_xlabel("prediction step i")
ax.set_ylabel("T (°C)")
ax.set_title(f"Constraint tightening at e_hat = e_inf, N = {ti.N}, L_d = {config.L_d}")
fig.legend(loc="lower center", ncol=3, fontsize=8)
fig.tight_layout(rect=(0, 0.07, 1, 1))

# %%
# Closed loop
# -----------
# The model is its own plant here, started at its equilibrium at 42 °C; the set-point
# moves to 58 °C, limited to Theorem 3's rate (computed for the middle half of the
# admissible interval, where both set-points lie), then a 2 °C output disturbance acts
# (within :math:`d_{max}`): the disturbance estimate removes its offset.
low_op, high_op = (model.denormalize_y(v)[0] for v in cert.rate_bound_y0_range)
print(f"rate bound holds for set-points in [{low_op:.2f}, {high_op:.2f}] °C")
controller = OffsetFreeController(model, config, setpoint_rate_limit=rate)
plant = LSTMPlant(model, y0_phi=42.0)
setpoints = np.repeat([42.0, 58.0, 58.0], 300)  # °C
disturbance = np.repeat([0.0, 0.0, 2.0], 300)  # °C, added to the output
result = simulate(plant, controller, setpoints, disturbance, progress=False)
for end in (299, 599, 899):
    print(f"k = {end}: |T - T0| = {abs(result.y_phi[end, 0] - setpoints[end]):.1e} °C")
counts = result.summary_counts()
print("steps per condition:", {name: n for name, n in counts.items() if n}, "(all others 0)")

# %%
t = np.arange(setpoints.size) * model.Ts / 60  # minutes
u_low, u_high = controller.input_bounds_phi
fig, (ax_y, ax_u, ax_d) = plt.subplots(3, 1, sharex=True, figsize=(8, 7))
ax_y.plot(t, result.y_phi[:, 0], label="T")
ax_y.plot(t, setpoints, "--", color="k", lw=0.8, label="requested set-point")
ax_y.plot(t, model.denormalize_y(result.y0)[:, 0], ":", color="C1", label="rate-limited set-point")
ax_y.axhspan(low_y0[0], high_y0[0], color="C2", alpha=0.12, label="admissible set-points")
ax_y.axhline(low_c[0], color="r", lw=0.8, label="output constraint")
ax_y.axhline(high_c[0], color="r", lw=0.8)
ax_y.set_ylabel("T (°C)")
ax_y.legend(loc="lower right", fontsize=8, ncol=2)
ax_u.plot(t, result.u_phi[:, 0], label="P (heater power)")
ax_u.axhline(u_low[0], color="k", lw=0.8, ls=":", label="input bounds")
ax_u.axhline(u_high[0], color="k", lw=0.8, ls=":")
ax_u.set_ylabel("P (kW)")
ax_u.legend(loc="upper right", fontsize=8)
ax_d.plot(t, result.d_phi[:, 0], label="output disturbance d")
ax_d.plot(t, result.d_hat[:, 0] * y_scale, label="estimate d_hat")
ax_d.axhline(config.d_max * y_scale, color="r", lw=0.8, label="±d_max")
ax_d.axhline(-config.d_max * y_scale, color="r", lw=0.8)
ax_d.set_ylabel("disturbance (°C)")
ax_d.set_xlabel("time (min)")
ax_d.legend(loc="upper left", fontsize=8)
fig.suptitle("Your own model: heater LSTM (n = 3), daqp, N = 5, L_d = 0.1")
fig.tight_layout()
plt.show()
