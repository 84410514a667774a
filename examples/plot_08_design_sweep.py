"""
A design sweep
==============

The flexure's design against its closed-loop performance: a grid over the table mass and the web
thickness of the first four-bar's notches (family fb1), the stage rebuilt from its geometry at every
point, its modes and travel, and an H-infinity controller with the paper's weights designed on each
point's linear twin, whose predicted sensitivity bandwidth gives the bandwidth axis. The Pareto front
keeps the points no other point beats in both bandwidth and travel (differences within
``PARETO_TIES`` are ties). ``nanosim sweep --param thickness.fb1=260:340:3 --param
target_mass_g=8:12:3 --out runs/sweep`` identifies and redesigns every point by the pipeline's rule
and measures bandwidth and resolution in the closed-loop experiments.
"""
import numpy as np

from nanosim import Stage, StageConfig, design_hinf, linearize, modal_analysis, reduce_model
from nanosim.constants import COMMAND_RANGE_V
from nanosim.pipeline.sweep import pareto_front, point_model
from nanosim.plots.montecarlo import fig_pareto

points = []
for mass_g in (8.0, 10.0, 12.0):
    for thickness_um in (260.0, 340.0):
        values = {"target_mass_g": mass_g, "thickness.fb1": thickness_um}
        model = point_model(values)
        modes = modal_analysis(model)
        travel = (COMMAND_RANGE_V[1] - COMMAND_RANGE_V[0]) * np.abs(modes.static_gain_um_per_V).sum(axis=1)
        twin = linearize(Stage(config=StageConfig.ideal(), model=model))
        d = design_hinf(reduce_model(twin.sys_V, order=10).G_reduced)
        points.append({"label": f"{mass_g:g} g, fb1 {thickness_um:g} um", "first_mode_hz": modes.physical[0].freq_hz,
                       "travel_um": float(travel.min()), "bandwidth_S_hz": d.nominal.bandwidth_S_hz})
        print(f"{points[-1]['label']:>18}: first mode {points[-1]['first_mode_hz']:6.1f} Hz, "
              f"travel {points[-1]['travel_um']:5.1f} um, S bandwidth {points[-1]['bandwidth_S_hz']:5.1f} Hz")

front = pareto_front(points, up=("bandwidth_S_hz", "travel_um"), down=())
print("Pareto front:", [points[i]["label"] for i in front])
pareto = fig_pareto(points, front, x="travel_um", y="bandwidth_S_hz", c="first_mode_hz",
                    labels={"travel_um": "travel [um]", "bandwidth_S_hz": "predicted S bandwidth [Hz]",
                            "first_mode_hz": "first mode [Hz]"})
