"""
Robustness: disk margins and mu
===============================

The paper's H-infinity controller (the design example's procedure) analysed on the loop as it runs: on
the identified model, which holds the loop's delay, and on the linear twin with the bench electronics.
For each plant :func:`nanosim.design.analyze_controller` gives the loop transfer matrices at the plant input
and output, loop-at-a-time and multiloop disk margins, the least damped closed-loop pole, and a mixed
real/complex mu upper bound over the stage's uncertainty set (piezo gain per channel, each mode's frequency
and damping, an extra sample of delay). ``mu_peak < 1`` proves stability of every plant in the set.
"""
from nanosim import IdentifySettings, Stage, design_hinf, discretize_controller, identify_on_twin, reduce_model
from nanosim.design import STAGE_UNCERTAINTY, LoopPlant, analyze_controller
from nanosim.plots.robustness import plot_disk_margins, plot_loop_singular_values

ident, twin = identify_on_twin(settings=IdentifySettings(seed=0))      # the bundled stage, on its linear twin
d = design_hinf(reduce_model(ident.sysc, order=10).G_reduced)
Kd = discretize_controller(d.K).Kd
print(STAGE_UNCERTAINTY)

# %%
# The analysis on both plants.
plants = [LoopPlant.identified(ident.sysd), LoopPlant.twin(twin.sysd_V, Stage().config.electronics)]
analyses = {p.label: analyze_controller(Kd, p) for p in plants}
for a in analyses.values():
    s = a.summary
    mu = "none (a centre loop is unstable)" if s["mu_peak"] is None else f"{s['mu_peak']:.3f}"
    print(f"{a.label}: multiloop input disk margin {s['dm_input_alpha']:.3f}, "
          f"mu peak {mu}, least damped pole zeta {s['least_damped_zeta']:.4f} "
          f"at {s['least_damped_freq_hz']:.0f} Hz")
singular_values = plot_loop_singular_values(analyses)
disk_margins = plot_disk_margins(analyses)
