"""
Mode-shape exploration
======================

How the modes move with the stiffness of a hinge family, the mass of the table and the thickness of a
notch, and what the first mode looks like. Every variant is a new MjModel of the same MJCF:
``load_model(stiffness_scale=..., body_mass_kg=...)`` scales the joints of a hinge family (``fourbar1``,
``fourbar2``, ``swing``) or sets a body's mass; a notch thickness rebuilds the stage from its geometry
(every stiffness and mass follows), as ``nanosim sweep`` does.
"""
import matplotlib.pyplot as plt
import numpy as np

from nanosim import load_model, modal_analysis
from nanosim.pipeline.sweep import point_model
from nanosim.plots.modes import mode_shape_figures


def first_modes(model, n=6):
    """Frequencies [Hz] of the first ``n`` physical modes."""
    return [m.freq_hz for m in modal_analysis(model).physical[:n]]


scales = [0.8, 0.9, 1.0, 1.1, 1.25]
variants = {f"stiffness of the {family} hinges, factor": (
    scales, lambda s, family=family: load_model(stiffness_scale={family: s}))
    for family in ("fourbar1", "fourbar2", "swing")}
variants["table mass [g]"] = ([6.0, 8.0, 10.0, 12.0, 14.0], lambda g: load_model(body_mass_kg={"table": g * 1e-3}))
variants["fb2 notch thickness [um]"] = ([60.0, 70.0, 80.0], lambda t: point_model({"thickness.fb2": t}))

fig, axes = plt.subplots(2, 3, figsize=(11, 6.5), sharey=True)
for ax, (label, (values, build)) in zip(axes.flat, variants.items()):
    freqs = np.array([first_modes(build(v)) for v in values])
    ax.plot(values, freqs, "o-", ms=3)
    ax.set_xlabel(label, fontsize=9)
    ax.grid(alpha=0.3)
    print(f"{label}: first mode {freqs[0, 0]:.1f} -> {freqs[-1, 0]:.1f} Hz, "
          f"sixth {freqs[0, 5]:.1f} -> {freqs[-1, 5]:.1f} Hz")
axes[0, 0].set_ylabel("mode frequency [Hz]")
axes[1, 0].set_ylabel("mode frequency [Hz]")
axes[1, 2].axis("off")
fig.suptitle("The first six modes of the stage")
fig.tight_layout()

# %%
# The shape of the first mode of the bundled stage (grey: home; red: the exaggerated shape).
# ``nanosim modes --plot DIR`` writes one such figure per mode.
model = load_model()
shapes = mode_shape_figures(model, modal_analysis(model), fmax_hz=200.0)
first_mode_name, first_mode_figure = shapes[0]
print(first_mode_name)
