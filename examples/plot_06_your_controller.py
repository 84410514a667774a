"""
Your own controller on the bench
================================

Any object with ``step(error_V, measurement_V) -> u_V`` and ``reset(measurement_V=None)`` can run the
bench's closed loop: readings and errors in sensor volts (X, Y, Z), commands in controller volts
(actuators A, B, C), once per 250 us sample. Here a decoupled PI controller runs a 2 um step on the linear
twin with the bench electronics. Saved in a file ``my_pid.py`` with a ``make()`` function returning a fresh
object, the same controller goes through the whole bench::

    nanosim compare --controllers my_pid.py:make lqg --model runs/demo/model.npz --twin --out runs/pid
"""
import matplotlib.pyplot as plt
import numpy as np

from nanosim import Stage, StageConfig, TwinStage, linearize, load_model, run_closed_loop
from nanosim.constants import CONTROL_PERIOD_S, JACOBIAN_J, SENSOR_UM_PER_V, STATIC_GAIN_SCALE_UM_PER_V
from nanosim.design.architectures.protocol import ObjectController
from nanosim.plant.floor import floor_model


class PI:
    """Integral action through the inverse of the nominal static gain (no notch: slow, below the 174 Hz first mode)."""

    M = np.linalg.inv(JACOBIAN_J * STATIC_GAIN_SCALE_UM_PER_V / SENSOR_UM_PER_V)   # sensor V -> controller V

    def __init__(self, kp=0.002, ki=5.0):
        self.kp, self.ki = kp, ki
        self.reset()

    def reset(self, measurement_V=None):
        """Zero the integrator (the loop starts at zero error)."""
        self.integral = np.zeros(3)

    def step(self, error_V, measurement_V):
        """One sample: error and reading [sensor V] in, command [controller V] out."""
        self.integral += self.ki * CONTROL_PERIOD_S * error_V
        return self.M @ (self.kp * error_V + self.integral)


def make():
    """A fresh controller (what ``--controllers my_pid.py:make`` calls)."""
    return PI()


# %%
# The twin stage: the same step/run/reset interface as the MuJoCo ``Stage``, with the 4 kHz linear
# mechanics inside the same DAC, amplifier, piezo, gauge and ADC.
model = load_model()
stage = TwinStage(linearize(Stage(config=StageConfig.ideal(), model=model)), seed=0,
                  home_um=Stage(model=model).table_um, floor_model=floor_model(model))

# %%
# Hold the origin for 20 ms, then step 2 um in X. The loop first moves from home to the origin on a
# raised-cosine reference, starting from zero error (``reset_at``), so the record starts settled. Without a
# notch the integral gain must keep the loop gain below 1 at the lightly damped first mode, so the step
# takes a large fraction of a second: the bench's designs are two orders of magnitude faster.
ref_um = np.zeros((int(1.0 / CONTROL_PERIOD_S), 3))
ref_um[80:, 0] = 2.0
trace = run_closed_loop(stage, ObjectController(make()), ref_um)
x = trace.y_um[:, 0]
inside = np.abs(x - 2.0) <= 0.02 * 2.0
last_outside = np.flatnonzero(~inside)[-1]
settling = ("not inside by the end of the record" if last_outside + 1 == len(x)
            else f"{1e3 * (trace.t_s[last_outside + 1] - trace.t_s[80]):.1f} ms")
print(f"X at the end {x[-100:].mean():.3f} um; inside 2 % of the step: {settling}")

fig, ax = plt.subplots(figsize=(7, 3.5))
ax.plot(1e3 * trace.t_s, trace.ref_um[:, 0], "k--", lw=1, label="reference")
ax.plot(1e3 * trace.t_s, trace.y_um[:, 0], label="X reading")
ax.plot(1e3 * trace.t_s, trace.y_um[:, 1], label="Y reading")
ax.set_xlabel("time [ms]")
ax.set_ylabel("[um]")
ax.set_title("A PI controller on the twin stage: 2 um step in X")
ax.legend()
