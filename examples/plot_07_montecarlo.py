"""
A small Monte Carlo
===================

A controller on a few fabricated stages: every notch's thickness and radius, the link widths, the target
mass and each actuator's piezo gain are drawn from their tolerances (:mod:`nanosim.plant.tolerances`
states each distribution and its source), and each sample gets its modes, closed-loop stability, disk
margin and the Section 5 experiments on its linear twin. ``nanosim montecarlo --n 200 --controller
runs/demo/controller.npz --out runs/mc`` is the same run at size; here four samples, and
the paper's H-infinity controller designed as in the design example.
"""
import json
import tempfile
from pathlib import Path

import numpy as np

from nanosim import IdentifySettings, design_hinf, discretize_controller, identify_on_twin, reduce_model
from nanosim.fileio import write_npz
from nanosim.pipeline.config import MonteCarloConfig
from nanosim.pipeline.mc_stats import default_spec
from nanosim.pipeline.montecarlo import load_sample_flats, run_montecarlo
from nanosim.plant.tolerances import default_tolerances
from nanosim.plots.montecarlo import fig_histograms

ident, twin = identify_on_twin(settings=IdentifySettings(seed=0))      # the bundled stage, on its linear twin
Kd = discretize_controller(design_hinf(reduce_model(ident.sysc, order=10).G_reduced).K).Kd

for t in list(default_tolerances().tolerances)[:6]:
    print(t)

# %%
# The run folder holds one record per sample, the yield against the spec (the paper's bands by default)
# with its 95 % Wilson interval, histograms and the tolerances that matter.
out = Path(tempfile.mkdtemp(prefix="nanosim-mc-")) / "mc"
controller = out.parent / "controller.npz"
write_npz(controller, Akd=Kd.A, Bkd=Kd.B, Ckd=Kd.C, Dkd=Kd.D, dt=np.float64(Kd.dt))
run_montecarlo(controller, out, MonteCarloConfig(n=4, crosscheck=0, workers=1),
               progress=False)
summary = json.loads((out / "summary.json").read_text())
for row in summary["yield"]:
    lo, hi = row["ci95_percent"]
    print(f"{row['label']:>36}: {row['pass']}/{row['n']} pass (95 % interval {lo:.0f}-{hi:.0f} %)")

# %%
# Each metric over the samples against its limit (the run folder's ``fig_mc_histograms.png``).
histograms = fig_histograms(load_sample_flats(out, 4), default_spec())
