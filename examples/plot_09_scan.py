"""
Scanning a sample
=================
What a scanning-probe user sees: the paper's H-infinity controller (the design example's procedure) scans a
synthetic sample (a calibration grating of square pillars and a rough surface) on the linear twin, in a
raster and a Lissajous pattern. The tip reads the height at the table's true position; the image puts it
at the sensor reading and is resampled onto the pixel grid, then compared with the truth. The raster's
trace and retrace images are shifted against each other by the loop's lag. ``nanosim scan --controller
runs/demo/controller.npz --out runs/scan`` runs the four patterns at 256 x 256 pixels on MuJoCo (or
``--twin``), with a sweep over the line rate for the fastest line rate under an image-error limit.
"""
import matplotlib.pyplot as plt
import numpy as np

from nanosim import (IdentifySettings, Stage, TwinStage, design_hinf, discretize_controller, identify_on_twin,
                     linearize, load_model, reduce_model)
from nanosim.design import DiscreteController
from nanosim.experiments import scan as S
from nanosim.plant.floor import floor_model

ident, _ = identify_on_twin(settings=IdentifySettings(seed=0))
Kd = discretize_controller(design_hinf(reduce_model(ident.sysc, order=10).G_reduced).K).Kd

model = load_model()
home_um = Stage(model=model).table_um


def twin_stage():
    """A fresh twin stage in the bench's electromechanics (every effect on), seed 0."""
    return TwinStage(linearize(Stage(model=model)), seed=0, home_um=home_um, floor_model=floor_model(model))


# %%
# A 10 x 10 um field at 128 x 128 pixels (78 nm pitch), 20 lines per second: a 6.4 s frame. Each scan starts
# from the bench's stated state (the controller reset at the home reading, a raised-cosine approach to the
# pattern's first point) and is led in by one line period that is not imaged. The raster's fast axis
# overscans the field by 2.5 um on each side: its trace image is built from the records taken while the
# reference moves forward, and the table trails the reference by the loop's lag (about 5 ms, 2-3 um at
# this line rate); with the default overscan, which only clears the command interpolation's turnaround, the last
# 2 um of every line would not be imaged (``imaged_fraction``).
sample = S.Sample(seed=0)
results = {}
for name in ("raster", "lissajous"):
    pattern = S.scan_pattern(name, 10.0, 128, 20.0, overscan_um=2.5 if name == "raster" else None)
    controller = DiscreteController.from_matrices(Kd.A, Kd.B, Kd.C, Kd.D, dt=Kd.dt)
    results[name] = res = S.run_scan(twin_stage(), controller, pattern, sample, placement="sensor")
    m = res.metrics()
    print(f"{m['label']:>18}: image error {m['image_error_rms_nm']:.2f} nm rms "
          f"({100 * m['image_error_fraction']:.2f} % of the {m['height_range_nm']:.0f} nm height range), "
          f"position error {m['position_error_rms_nm']:.1f} nm rms, imaged {100 * m['imaged_fraction']:.1f} % "
          f"of the covered pixels")
print(f"raster trace/retrace offset: {1e3 * results['raster'].trace_retrace_offset_um:.1f} nm")

# %%
# The truth beside the two images, and where the raster's image departs from the truth: the error is
# largest on the pillars' edges, where a position error of a few nanometres changes the height most.
truth = results["raster"].truth_nm
fig, axes = plt.subplots(1, 4, figsize=(13, 3.4), layout="constrained")
panels = [("truth", truth), ("raster image", results["raster"].image.image_nm),
          ("Lissajous image", results["lissajous"].image.image_nm)]
extent = (0, 10, 0, 10)
for ax, (title, img) in zip(axes, panels):
    im = ax.imshow(img, origin="lower", extent=extent, cmap="viridis", vmin=np.nanmin(truth), vmax=np.nanmax(truth))
    ax.set_title(title)
    ax.set_xlabel("x [um]")
fig.colorbar(im, ax=axes[:3], label="height [nm]", shrink=0.8)
err = results["raster"].image.error_nm
lim = np.nanmax(np.abs(err))
im = axes[3].imshow(err, origin="lower", extent=extent, cmap="RdBu_r", vmin=-lim, vmax=lim)
axes[3].set_title("raster image - truth")
axes[3].set_xlabel("x [um]")
fig.colorbar(im, ax=axes[3], label="[nm]", shrink=0.8)
axes[0].set_ylabel("y [um]")
