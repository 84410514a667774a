"""Every file a run folder holds: its name, kind, producing step and report caption (one place).

Writers (the pipeline steps) and readers (report, characterize, compare) use
these names; the report's figure list is :data:`FIGURES`, so a figure that is
produced but not registered fails ``tests/test_report.py``.
"""
from __future__ import annotations

from dataclasses import dataclass

__all__ = ["Artifact", "FIGURES", "figure", "MODES_JSON", "MODES_DIR", "MODEL_NPZ", "model_at_npz", "IDENTIFY_JSON",
           "TWIN_NPZ", "CONTROLLER_NPZ", "REDUCED_MODEL_NPZ", "DESIGN_JSON", "DESIGN_MAT", "METRICS_JSON",
           "PIPELINE_JSON", "REPORT_MD", "REPORT_HTML", "TWIN_DIR", "ROBUSTNESS_JSON", "SCORECARD_JSON", "SCORECARD_MD",
           "SCORECARD_HTML", "COMPARE_FIGURES"]


@dataclass(frozen=True)
class Artifact:
    """One file (or a family matched by ``pattern``) of a run folder.

    Attributes
    ----------
    name : str
        File name relative to the run folder (a glob pattern for a family, e.g. ``modes/mode_*.png``).
    step : str
        Pipeline step that writes it (``modes``, ``identify``, ``design``, ``characterize``, ``report``).
    caption : str
        Report caption (figures) or one-line description.
    """

    name: str
    step: str
    caption: str = ""

    @property
    def is_pattern(self) -> bool:
        """True if ``name`` is a glob pattern for a family of files."""
        return any(ch in self.name for ch in "*?[")


# --- data files -------------------------------------------------------------------------
MODES_JSON = "modes.json"
MODES_DIR = "modes"
MODEL_NPZ = "model.npz"
IDENTIFY_JSON = "identify.json"
TWIN_NPZ = "twin.npz"
CONTROLLER_NPZ = "controller.npz"
REDUCED_MODEL_NPZ = "reduced_model.npz"
DESIGN_JSON = "design.json"
ROBUSTNESS_JSON = "robustness.json"
DESIGN_MAT = "design.mat"
METRICS_JSON = "metrics.json"
PIPELINE_JSON = "pipeline.json"
REPORT_MD = "report.md"
REPORT_HTML = "report.html"
TWIN_DIR = "twin"
# nanosim compare (nanosim.pipeline.compare): the scorecard and its overlaid figures
SCORECARD_JSON = "scorecard.json"
SCORECARD_MD = "scorecard.md"
SCORECARD_HTML = "scorecard.html"
COMPARE_FIGURES: tuple[tuple[str, str], ...] = (
    ("compare_loops.png", "sigma_max of S_o and T_o, identified model (the loop as run)"),
    ("compare_step.png", "2 um step, first seed"),
    ("compare_contour.png", "Contour error at 1000 um/s, first seed"),
    ("compare_psd.png", "Closed-loop PSD of the X reading at rest, first seed"),
)


def model_at_npz(piezo_offset_V: float) -> str:
    """File name of the model identified at a piezo-volt operating point other than 0 V."""
    return f"model_{piezo_offset_V:g}V.npz"


# --- figures, in report order ---------------------------------------------------------------
FIGURES: tuple[Artifact, ...] = (
    Artifact("modes/mode_*.png", "modes", "Mode shapes"),
    Artifact("fig04_time_domain_fit.png", "identify", "Identification: time-domain fit (Fig. 4)"),
    Artifact("fig05_identified_frequency_response.png", "identify",
             "Identified frequency response vs linear twin (Fig. 5)"),
    Artifact("fig06_parametric_vs_h1.png", "identify", "Parametric vs non-parametric (Fig. 6)"),
    Artifact("fig07_operating_points.png", "identify", "Two operating points (Fig. 7)"),
    Artifact("singular_values.png", "identify", "Subspace singular values"),
    Artifact("fig08_hankel_sv.png", "design", "Hankel singular values (Fig. 8)"),
    Artifact("fig09_reduction_bode.png", "design", "Full vs reduced model (Fig. 9)"),
    Artifact("fig10_uncertainty.png", "design", "Multiplicative uncertainty (Fig. 10)"),
    Artifact("fig11b_weights.png", "design", "Weights (Fig. 11b)"),
    Artifact("fig12_sensitivity.png", "design", "Sensitivity with nominal and full models (Fig. 12)"),
    Artifact("fig18_T_KS.png", "design", "Closed-loop design singular values, T and KS (Fig. 18 a-b)"),
    Artifact("fig21_closed_loop_bode.png", "design", "Closed-loop Bode grid (Figs. 13, 21)"),
    Artifact("fig22_controller_bode.png", "design", "Controller Bode grid (Fig. 22)"),
    Artifact("fig23_robustness_sigma.png", "design",
             "Robustness: singular values of S_o, S_i, T_o, T_i, KS, SG on the loop as run"),
    Artifact("fig24_robustness_disk_margins.png", "design",
             "Robustness: multiloop disk margins and mu of the uncertainty set per frequency"),
    Artifact("fig14_hysteresis.png", "characterize", "Hysteresis, open and closed loop (Fig. 14)"),
    Artifact("fig15_creep.png", "characterize", "Creep (Fig. 15)"),
    Artifact("fig16_resolution.png", "characterize", "Resolution and PSD (Fig. 16)"),
    Artifact("fig17_small_steps.png", "characterize", "10 nm steps (Fig. 17)"),
    Artifact("fig18_bandwidth_step.png", "characterize", "Measured bandwidth and 2 um step (Fig. 18)"),
    Artifact("fig19_tracking.png", "characterize", "Tracking (Fig. 19)"),
    Artifact("fig20_contouring.png", "characterize", "Contouring (Fig. 20)"),
)


def figure(name: str) -> Artifact:
    """The registered figure called ``name`` (raises ``KeyError`` naming the known ones)."""
    for a in FIGURES:
        if a.name == name:
            return a
    raise KeyError(f"figure {name!r} is not registered in nanosim.pipeline.artifacts.FIGURES")
