"""
Compensating the piezo's hysteresis
===================================
The open-loop loop of the paper's Fig. 14 (actuator A, 0 -> 1.65 -> 0 controller volts in 2 s, X read by
the gauge) on the linear twin with the bench electromechanics, with the voltage drive and with an inverse
Prandtl-Ishlinskii feedforward. The feedforward's operator is identified on the stage first, from nested
minor loops run open loop on each actuator, and inverted in closed form; the command passes the inverse
before the amplifier. ``nanosim characterize --feedforward inverse-pi`` runs every experiment that way, and
``nanosim pipeline`` compares the voltage drive, the feedforward, the charge drive and both, closed loop
too, in the report's "Hysteresis compensation" section.
"""
import matplotlib.pyplot as plt
import numpy as np

from nanosim.constants import CONTROL_RATE_HZ
from nanosim.design.feedforward import InversePI
from nanosim.experiments.loop import fit_feedforward
from nanosim.pipeline.characterize import make_plant_factory
from nanosim.plant.loopmetrics import loop_hysteresis_percent

factory = make_plant_factory(True)[0]          # the linear twin, every effect on; factory(seed) -> a fresh stage
model = fit_feedforward(factory, seed=0)
print(f"fitted operator: linear weight {model.linear_weight:.3f}, {np.count_nonzero(model.weights)} of "
      f"{len(model.thresholds_V)} play operators weighted, thresholds up to {model.thresholds_V.max():.2f} "
      f"controller V, residual {100 * model.residual_rms / model.output_rms:.2f} % rms of the record")

# %%
# The Fig. 14 command from rest, then the same command through the inverse (a fresh inverse: its
# operators start from rest with the stage's).
t = np.arange(int(2.0 * CONTROL_RATE_HZ)) / CONTROL_RATE_HZ
v = 1.65 * np.where(t < 1.0, t, 2.0 - t)
u = np.zeros((v.size, 3))
u[:, 0] = v
loops = {}
for label, command in (("voltage drive", u), ("inverse-PI feedforward", InversePI(model, n_channels=3).run(u))):
    x_um = factory(1).run(command).sensor_um[:, 0]
    x_um = x_um - x_um[0]
    out_pct, in_pct = loop_hysteresis_percent(v, -x_um)     # X moves negative for actuator A
    loops[label] = x_um
    print(f"{label:>24}: X travel {x_um.min():.2f} um, hysteresis {out_pct:.1f} % of the output, "
          f"{in_pct:.1f} % of the input")

fig, ax = plt.subplots(figsize=(6, 4.5), layout="constrained")
for label, x_um in loops.items():
    ax.plot(v, x_um, label=label)
ax.set_xlabel("command, actuator A [controller V]")
ax.set_ylabel("X reading [um]")
ax.set_title("Fig. 14 open-loop loop on the twin")
ax.legend()
