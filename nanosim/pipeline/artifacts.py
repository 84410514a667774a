"""Every file a run folder holds: its name, kind, producing step and report caption (one place).

Writers (the pipeline steps) and readers (report, characterize, compare) use
these names; the report's figure list is :data:`FIGURES`, so a figure that is
produced but not registered fails ``tests/test_report.py``. The names that the
experiments, plots and viewer need are defined in :mod:`nanosim.artifact_names` (a
lower layer) and re-exported here.
"""
from __future__ import annotations

from dataclasses import dataclass

from nanosim.artifact_names import (COMPARE_CONTOUR_PNG, COMPARE_LOOPS_PNG, COMPARE_PSD_PNG, COMPARE_STEP_PNG,
                                    CONTROLLER_NPZ, FIG14_HYSTERESIS, FIG15_CREEP, FIG16_RESOLUTION,
                                    FIG17_SMALL_STEPS, FIG18_BANDWIDTH_STEP, FIG19_TRACKING, FIG20_CONTOURING,
                                    MODE_SHAPE_GLOB, SCORECARD_JSON, mode_shape_png)

__all__ = ["Artifact", "FIGURES", "figure", "MODES_JSON", "MODES_DIR", "MODEL_NPZ", "model_at_npz", "IDENTIFY_JSON",
           "TWIN_NPZ", "CONTROLLER_NPZ", "REDUCED_MODEL_NPZ", "DESIGN_JSON", "DESIGN_MAT", "METRICS_JSON",
           "PIPELINE_JSON", "REPORT_MD", "REPORT_HTML", "TWIN_DIR", "ROBUSTNESS_JSON", "SCORECARD_JSON", "SCORECARD_MD",
           "SCORECARD_HTML", "COMPARE_FIGURES", "MANIFEST_JSON", "mode_shape_png", "MODE_SHAPE_GLOB",
           "FIG04_TIME_DOMAIN_FIT", "FIG05_IDENTIFIED_FREQUENCY_RESPONSE", "FIG06_PARAMETRIC_VS_H1",
           "FIG07_OPERATING_POINTS", "FIG_SINGULAR_VALUES", "FIG08_HANKEL_SV", "FIG09_REDUCTION_BODE",
           "FIG10_UNCERTAINTY", "FIG11B_WEIGHTS", "FIG12_SENSITIVITY", "FIG18_T_KS", "FIG21_CLOSED_LOOP_BODE",
           "FIG22_CONTROLLER_BODE", "FIG23_ROBUSTNESS_SIGMA", "FIG24_ROBUSTNESS_DISK_MARGINS", "FIG14_HYSTERESIS",
           "FIG15_CREEP", "FIG16_RESOLUTION", "FIG17_SMALL_STEPS", "FIG18_BANDWIDTH_STEP", "FIG19_TRACKING",
           "FIG20_CONTOURING", "COMPARE_LOOPS_PNG", "COMPARE_STEP_PNG", "COMPARE_CONTOUR_PNG", "COMPARE_PSD_PNG",
           "compare_seed_dir", "pipeline_seed_dir", "SEEDS_JSON", "PAPER_DESIGN_SEEDS_JSON", "ABLATION_JSON",
           "ABLATION_MD", "ABLATION_PARTIAL_JSON", "MONTECARLO_JSON", "TOLERANCES_JSON", "SPEC_JSON", "SUMMARY_JSON",
           "MC_SAMPLES_DIR", "MC_CROSSCHECK_DIR", "MC_SPREAD_DIR", "mc_sample_json", "FIG_MC_HISTOGRAMS",
           "FIG_MC_SENSITIVITY", "FIG_MC_CROSSCHECK", "MC_BENCH_JSON", "FIG_MC_BENCH", "SWEEP_JSON",
           "SWEEP_POINTS_DIR", "sweep_point_json", "FIG_SWEEP_PARETO", "TIMINGS_JSON", "BUDGET_JSON", "BUDGET_NPZ",
           "FIG_BUDGET_PSD", "FIG_BUDGET_CAS", "MODEL_MAT", "CONTROLLER_MAT", "COMPENSATION_JSON",
           "FIG_COMPENSATION"]


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
# CONTROLLER_NPZ (and SCORECARD_JSON below): defined in nanosim.artifact_names (the viewer reads them)
REDUCED_MODEL_NPZ = "reduced_model.npz"
DESIGN_JSON = "design.json"
ROBUSTNESS_JSON = "robustness.json"
DESIGN_MAT = "design.mat"
METRICS_JSON = "metrics.json"
PIPELINE_JSON = "pipeline.json"
REPORT_MD = "report.md"                 # also the report of a montecarlo, sweep and pipeline --seeds folder
REPORT_HTML = "report.html"
TWIN_DIR = "twin"
MANIFEST_JSON = "manifest.json"         # written last: seals a run folder (nanosim.pipeline.runfolder)
# the wall-clock times of a run folder's commands (nanosim.pipeline.timings), kept out of the result files so
# that those are byte-identical between two runs with the same seed; a plain output, listed in the manifest
TIMINGS_JSON = "timings.json"
# nanosim compare (nanosim.pipeline.compare): the scorecard (SCORECARD_JSON, .md, .html) and its overlaid figures
SCORECARD_MD = "scorecard.md"
SCORECARD_HTML = "scorecard.html"
COMPARE_FIGURES: tuple[tuple[str, str], ...] = (
    (COMPARE_LOOPS_PNG, "sigma_max of S_o and T_o, identified model (the loop as run)"),
    (COMPARE_STEP_PNG, "2 um step, first seed"),
    (COMPARE_CONTOUR_PNG, "Contour error at 1000 um/s, first seed"),
    (COMPARE_PSD_PNG, "Closed-loop PSD of the X reading at rest, first seed"),
)
# nanosim ablation (nanosim.pipeline.ablation) and tools/paper_design_seeds.py, read by the report
ABLATION_JSON = "ablation.json"
ABLATION_MD = "ablation.md"
ABLATION_PARTIAL_JSON = "ablation.partial.json"     # the rows so far, rewritten after each row
PAPER_DESIGN_SEEDS_JSON = "paper_design_seeds.json"
# nanosim pipeline --seeds (nanosim.pipeline.seeds): the summary of the seeds' run folders
SEEDS_JSON = "seeds.json"
# nanosim montecarlo (nanosim.pipeline.montecarlo)
MONTECARLO_JSON = "montecarlo.json"     # the plan
TOLERANCES_JSON = "tolerances.json"
SPEC_JSON = "spec.json"
SUMMARY_JSON = "summary.json"
MC_SAMPLES_DIR = "samples"
MC_CROSSCHECK_DIR = "crosscheck"
MC_SPREAD_DIR = "crosscheck_spread"     # the twin's reading spread of each cross-checked sample
FIG_MC_HISTOGRAMS = "fig_mc_histograms.png"
FIG_MC_SENSITIVITY = "fig_mc_sensitivity.png"
FIG_MC_CROSSCHECK = "fig_mc_crosscheck.png"
# nanosim montecarlo with several controllers (nanosim.pipeline.mc_bench)
MC_BENCH_JSON = "montecarlo_bench.json"     # the plan
FIG_MC_BENCH = "fig_mc_bench.png"
# nanosim sweep (nanosim.pipeline.sweep)
SWEEP_JSON = "sweep.json"
# nanosim budget (nanosim.pipeline.budget)
BUDGET_JSON = "budget.json"
BUDGET_NPZ = "budget.npz"
FIG_BUDGET_PSD = "fig_budget_psd.png"
FIG_BUDGET_CAS = "fig_budget_cas.png"
# nanosim pipeline's hysteresis compensation on the linear twin (nanosim.pipeline.compensation)
COMPENSATION_JSON = "compensation.json"
FIG_COMPENSATION = "fig_compensation.png"
# beside model.npz and controller.npz (nanosim.pipeline.export)
MODEL_MAT = "model.mat"
CONTROLLER_MAT = "controller.mat"
SWEEP_POINTS_DIR = "points"
FIG_SWEEP_PARETO = "fig_sweep_pareto.png"


def model_at_npz(piezo_offset_V: float) -> str:
    """File name of the model identified at a piezo-volt operating point other than 0 V."""
    return f"model_{piezo_offset_V:g}V.npz"


# The per-seed sub-folders of the two commands that write them are named differently (existing run
# folders and the docs use both names): nanosim compare writes <controller>/seed<s>/metrics.json,
# nanosim pipeline --seeds a complete run folder seed_<s>/ per seed.
def compare_seed_dir(seed: int) -> str:
    """Sub-folder of one seed in a ``nanosim compare`` controller folder: ``seed0``."""
    return f"seed{seed}"


def pipeline_seed_dir(seed: int) -> str:
    """Run folder of one seed in a ``nanosim pipeline --seeds`` folder: ``seed_0``."""
    return f"seed_{seed}"


def mc_sample_json(index: int) -> str:
    """One Monte Carlo sample's record in :data:`MC_SAMPLES_DIR`, :data:`MC_CROSSCHECK_DIR` or :data:`MC_SPREAD_DIR`."""
    return f"sample_{index:05d}.json"


def sweep_point_json(index: int) -> str:
    """One sweep point's record in :data:`SWEEP_POINTS_DIR`."""
    return f"point_{index:03d}.json"


# --- figures of the identify and design steps (those of the experiments: nanosim.artifact_names) ---
FIG04_TIME_DOMAIN_FIT = "fig04_time_domain_fit.png"
FIG05_IDENTIFIED_FREQUENCY_RESPONSE = "fig05_identified_frequency_response.png"
FIG06_PARAMETRIC_VS_H1 = "fig06_parametric_vs_h1.png"
FIG07_OPERATING_POINTS = "fig07_operating_points.png"
FIG_SINGULAR_VALUES = "singular_values.png"
FIG08_HANKEL_SV = "fig08_hankel_sv.png"
FIG09_REDUCTION_BODE = "fig09_reduction_bode.png"
FIG10_UNCERTAINTY = "fig10_uncertainty.png"
FIG11B_WEIGHTS = "fig11b_weights.png"
FIG12_SENSITIVITY = "fig12_sensitivity.png"
FIG18_T_KS = "fig18_T_KS.png"
FIG21_CLOSED_LOOP_BODE = "fig21_closed_loop_bode.png"
FIG22_CONTROLLER_BODE = "fig22_controller_bode.png"
FIG23_ROBUSTNESS_SIGMA = "fig23_robustness_sigma.png"
FIG24_ROBUSTNESS_DISK_MARGINS = "fig24_robustness_disk_margins.png"


# --- figures, in report order ---------------------------------------------------------------
FIGURES: tuple[Artifact, ...] = (
    Artifact(f"{MODES_DIR}/{MODE_SHAPE_GLOB}", "modes", "Mode shapes"),
    Artifact(FIG04_TIME_DOMAIN_FIT, "identify", "Identification: time-domain fit (Fig. 4)"),
    Artifact(FIG05_IDENTIFIED_FREQUENCY_RESPONSE, "identify",
             "Identified frequency response vs linear twin (Fig. 5)"),
    Artifact(FIG06_PARAMETRIC_VS_H1, "identify", "Parametric vs non-parametric (Fig. 6)"),
    Artifact(FIG07_OPERATING_POINTS, "identify", "Two operating points (Fig. 7)"),
    Artifact(FIG_SINGULAR_VALUES, "identify", "Subspace singular values"),
    Artifact(FIG08_HANKEL_SV, "design", "Hankel singular values (Fig. 8)"),
    Artifact(FIG09_REDUCTION_BODE, "design", "Full vs reduced model (Fig. 9)"),
    Artifact(FIG10_UNCERTAINTY, "design", "Multiplicative uncertainty (Fig. 10)"),
    Artifact(FIG11B_WEIGHTS, "design", "Weights (Fig. 11b)"),
    Artifact(FIG12_SENSITIVITY, "design", "Sensitivity with nominal and full models (Fig. 12)"),
    Artifact(FIG18_T_KS, "design", "Closed-loop design singular values, T and KS (Fig. 18 a-b)"),
    Artifact(FIG21_CLOSED_LOOP_BODE, "design", "Closed-loop Bode grid (Figs. 13, 21)"),
    Artifact(FIG22_CONTROLLER_BODE, "design", "Controller Bode grid (Fig. 22)"),
    Artifact("reference_fig*.png", "design",
             "The mixed-sensitivity reference design of the settings (--architecture mixsyn), not exported"),
    Artifact(FIG23_ROBUSTNESS_SIGMA, "design",
             "Robustness: singular values of S_o, S_i, T_o, T_i, KS, SG on the loop as run"),
    Artifact(FIG24_ROBUSTNESS_DISK_MARGINS, "design",
             "Robustness: multiloop disk margins and mu of the uncertainty set per frequency"),
    Artifact(FIG14_HYSTERESIS, "characterize", "Hysteresis, open and closed loop (Fig. 14)"),
    Artifact(FIG15_CREEP, "characterize", "Creep (Fig. 15)"),
    Artifact(FIG16_RESOLUTION, "characterize", "Resolution and PSD (Fig. 16)"),
    Artifact(FIG17_SMALL_STEPS, "characterize", "10 nm steps (Fig. 17)"),
    Artifact(FIG18_BANDWIDTH_STEP, "characterize", "Measured bandwidth and 2 um step (Fig. 18)"),
    Artifact(FIG19_TRACKING, "characterize", "Tracking (Fig. 19)"),
    Artifact(FIG20_CONTOURING, "characterize", "Contouring (Fig. 20)"),
    Artifact(FIG_COMPENSATION, "compensation",
             "Hysteresis compensation on the linear twin: Fig. 14 open-loop loops and errors per drive"),
    Artifact(FIG_BUDGET_PSD, "budget", "Noise budget: stacked PSD of the table position per source (analytic)"),
    Artifact(FIG_BUDGET_CAS, "budget", "Noise budget: cumulative amplitude spectrum per source"),
)


def figure(name: str) -> Artifact:
    """The registered figure called ``name`` (raises ``KeyError`` naming the known ones)."""
    for a in FIGURES:
        if a.name == name:
            return a
    raise KeyError(f"figure {name!r} is not registered in nanosim.pipeline.artifacts.FIGURES")
