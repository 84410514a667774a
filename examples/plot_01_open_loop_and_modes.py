"""
Open loop and modes
===================

The stage's vibration modes about its home pose (MuJoCo's own linearization of the MJCF), then the
open-loop response of the MuJoCo stage, with every electromechanical effect on, to a command step on
actuator A, and the frequency response of the linear twin.
"""
import matplotlib.pyplot as plt
import numpy as np

from nanosim import Stage, StageConfig, linearize, load_model, modal_analysis

# %%
# Modes below 1 kHz: frequency, damping ratio, the axis the probes see and the static gain.
model = load_model()
modes = modal_analysis(model)
for m in modes.below(1000.0):
    print(f"{m.freq_hz:7.1f} Hz  zeta {m.damping_ratio:.4f}  axis {m.axis}")
print("static gain [um per controller V], rows X Y Z, columns A B C:")
print(np.round(modes.static_gain_um_per_V, 2))

# %%
# A 0.5 V step on actuator A for 0.1 s (400 samples at 4 kHz), read by the capacitive probes.
stage = Stage(seed=0)
u = np.zeros((400, 3))
u[40:, 0] = 0.5
trace = stage.run(u)
fig, ax = plt.subplots(figsize=(7, 3.5))
for k, axis in enumerate("XYZ"):
    ax.plot(1e3 * trace.t_s, trace.sensor_um[:, k] - trace.sensor_um[0, k], label=axis)
ax.set_xlabel("time [ms]")
ax.set_ylabel("reading from home [um]")
ax.set_title("Open-loop step on actuator A (MuJoCo stage, every effect on)")
ax.legend()

# %%
# The linear twin: MuJoCo's linearization with the fast closure modes residualised
# (controller V -> sensor V).
twin = linearize(Stage(config=StageConfig.ideal(), model=model))
f_hz = np.logspace(1, 3.3, 600)
H = np.array([twin.sys_V(2j * np.pi * f) for f in f_hz])
fig, ax = plt.subplots(figsize=(7, 3.5))
for i, axis in enumerate("XYZ"):
    ax.loglog(f_hz, np.abs(H[:, i, 0]), label=f"A -> {axis}")
ax.set_xlabel("frequency [Hz]")
ax.set_ylabel("|G| [sensor V / controller V]")
ax.set_title(f"Linear twin, {twin.sys_V.nstates} states")
ax.legend()
