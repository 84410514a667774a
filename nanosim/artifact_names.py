"""The artifact names that layers below :mod:`nanosim.pipeline` use (one place; re-exported by the registry).

:mod:`nanosim.pipeline.artifacts` is the registry of every file a run folder holds and
re-exports these names. They are defined here, at the lowest layer, because the modules
that use them may not import the pipeline (importlinter layers, ``pyproject.toml``): the
experiments (their figures), the plots (``nanosim compare``'s figures, the mode-shape
files) and the viewer (a ``nanosim compare`` folder's controllers and scorecard). Every
other name lives in :mod:`nanosim.pipeline.artifacts`.
"""
from __future__ import annotations

__all__ = ["CONTROLLER_NPZ", "SCORECARD_JSON", "FIG14_HYSTERESIS", "FIG15_CREEP", "FIG16_RESOLUTION",
           "FIG17_SMALL_STEPS", "FIG18_BANDWIDTH_STEP", "FIG19_TRACKING", "FIG20_CONTOURING", "COMPARE_LOOPS_PNG",
           "COMPARE_STEP_PNG", "COMPARE_CONTOUR_PNG", "COMPARE_PSD_PNG", "MODE_SHAPE_GLOB", "mode_shape_png"]

CONTROLLER_NPZ = "controller.npz"
SCORECARD_JSON = "scorecard.json"

# figures of the registered experiments (nanosim characterize)
FIG14_HYSTERESIS = "fig14_hysteresis.png"
FIG15_CREEP = "fig15_creep.png"
FIG16_RESOLUTION = "fig16_resolution.png"
FIG17_SMALL_STEPS = "fig17_small_steps.png"
FIG18_BANDWIDTH_STEP = "fig18_bandwidth_step.png"
FIG19_TRACKING = "fig19_tracking.png"
FIG20_CONTOURING = "fig20_contouring.png"

# nanosim compare's overlaid figures (nanosim.plots.compare)
COMPARE_LOOPS_PNG = "compare_loops.png"
COMPARE_STEP_PNG = "compare_step.png"
COMPARE_CONTOUR_PNG = "compare_contour.png"
COMPARE_PSD_PNG = "compare_psd.png"

# one figure per mode shape (nanosim.plots.modes), in the run folder's modes/ folder
MODE_SHAPE_GLOB = "mode_*.png"


def mode_shape_png(index: int, freq_hz: float) -> str:
    """``mode_01_176Hz.png`` for the first mode (index 0) at 176 Hz; matches :data:`MODE_SHAPE_GLOB`."""
    return f"mode_{index + 1:02d}_{freq_hz:.0f}Hz.png"
