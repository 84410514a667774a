"""Design layer: the controller bench, its building blocks and the loop analysis (paper Sec. 4).

Front door: :func:`design` (``design(name, G, **kwargs) -> BenchDesign``) designs a named member of
:data:`REGISTRY` -- the bench's controllers, each with its tuning rule as a value (the LQG members:
:class:`LqgRule` presets) -- from the identified model ``G``; :mod:`~nanosim.design.architectures` lists them.

Below it (no file output here; :func:`nanosim.pipeline.design.run_design` writes the artifacts and
:mod:`nanosim.plots.design` draws the figures):

Building blocks

* :mod:`~nanosim.design.lti` -- LTI helpers, units, sign convention, BLAS threading, the one state-space
  response kernel (:func:`~nanosim.design.lti.ss_response`);
* :mod:`~nanosim.design.reduction` -- balanced truncation, multiplicative uncertainty;
* :mod:`~nanosim.design.weights` -- the weights Wp, Wt, Wu;
* :mod:`~nanosim.design.hinf` -- generalized plant, assumptions, synthesis (:class:`Design`);
* :mod:`~nanosim.design.damping` -- the inner active-damping loop (two degrees of freedom);
* :mod:`~nanosim.design.discretize` -- the discrete controller and its check;
* :mod:`~nanosim.design.feedforward` -- the inverse Prandtl-Ishlinskii operator;
* :mod:`~nanosim.design.controller` -- the real-time discrete controller; :mod:`~nanosim.design.sos` -- its
  second-order sections.

Analysis

* :mod:`~nanosim.design.loops` -- loop functions S, T, KS (the one sensitivity kernel,
  :func:`~nanosim.design.loops.sensitivities`) and their analysis;
* :mod:`~nanosim.design.robustness` -- robustness of any controller on the loop as run
  (facade of :mod:`~nanosim.design.loopplant` (the plant as the loop runs it and its delays),
  :mod:`~nanosim.design.loopresponse` (loop maps), :mod:`~nanosim.design.margins`,
  :mod:`~nanosim.design.mu` and :mod:`~nanosim.design.mixed_mu`, :mod:`~nanosim.design.uncertainty` and
  :mod:`~nanosim.design.parametric` (the stage's uncertainty set); argument checks in
  :mod:`~nanosim.design.loopargs`).

Plant ``G``: controller V -> sensor V; controller ``K``: error ``e = r - y``
[sensor V] -> controller V, ``u = +K e``; frequencies in Hz; frequency
responses ``(F, ny, nu)``.
"""
from __future__ import annotations

from nanosim.design.controller import ControllerConfig, DiscreteController
from nanosim.design.damping import DampingLoop, damped_plant, damping_loop
from nanosim.design.discretize import (
    DISCRETIZATION_METHODS,
    Discretization,
    dc_gain_discrete,
    discrete_closed_loop,
    discretization_error,
    discretize_controller,
    error_rel_to_peak,
)
from nanosim.design.hinf import AssumptionReport, Design, check_assumptions, design_hinf, generalized_plant
from nanosim.design.loops import (
    MODE_BAND_HZ,
    LoopAnalysis,
    analyse_loop,
    feedback_operator,
    loop_freqresp,
    loop_functions,
    min_damping,
    stack_inputs,
)
from nanosim.design.lti import (
    AXIS_RTOL,
    BANDWIDTH_DEFINITIONS,
    INV_SQRT2,
    SIGN_CONVENTION,
    UNITS,
    analysis_grid_hz,
    as_ss,
    crossing_hz,
    db,
    dc_gain,
    freqresp,
    load_state_space_npz,
    max_real_pole,
    refine_peak,
    sigma_max,
    single_threaded_blas,
    singular_values,
    static_gain,
)
from nanosim.design.reduction import Reduction, multiplicative_uncertainty, reduce_model
from nanosim.design.robustness import (
    IDENTIFIED_DELAY_SAMPLES,
    RECORD_ROW_DELAY_SAMPLES,
    ROBUSTNESS_MAPS,
    STAGE_UNCERTAINTY,
    ControllerRobustness,
    DiskMargin,
    DiskMarginReport,
    LeastDampedPole,
    LoopPlant,
    LoopResponse,
    LoopStateSpace,
    MuBounds,
    RobustStabilityResult,
    UncertaintySet,
    VISIBLE_PEAK,
    analyze_controller,
    closed_loop_poles,
    controller_systems,
    disk_gain_phase,
    disk_margins,
    electronics_ss,
    frequency_response,
    least_damped_pole,
    loop_transfer_response,
    loop_transfer_ss,
    mu_lower_bound,
    mu_upper_bound,
    perturbed_plant,
    pole_visibility,
    robust_stability_mu,
    robustness_summary,
    stage_grid_hz,
)
from nanosim.design.weights import PAPER_WEIGHTS, WEIGHT_NAMES, Weights, WeightSpec, paper_weights

# the front door (after the blocks it is built on)
from nanosim.design.architectures import BENCH, DESIGN_RULES, REGISTRY, BenchDesign, BenchMember, design  # noqa: E402
from nanosim.design.architectures.lqg_rules import LqgRule  # noqa: E402

__all__ = [
    # the front door
    "design", "REGISTRY", "BENCH", "DESIGN_RULES", "BenchMember", "BenchDesign", "LqgRule",
    # lti
    "SIGN_CONVENTION", "UNITS", "INV_SQRT2", "BANDWIDTH_DEFINITIONS", "AXIS_RTOL",
    "as_ss", "static_gain", "dc_gain", "freqresp", "sigma_max", "singular_values", "db",
    "max_real_pole", "crossing_hz", "analysis_grid_hz", "refine_peak", "load_state_space_npz",
    "single_threaded_blas",
    # weights
    "WeightSpec", "Weights", "PAPER_WEIGHTS", "paper_weights", "WEIGHT_NAMES",
    # reduction
    "Reduction", "reduce_model", "multiplicative_uncertainty",
    # hinf
    "AssumptionReport", "check_assumptions", "generalized_plant", "Design", "design_hinf",
    # damping
    "DampingLoop", "damping_loop", "damped_plant",
    # loops
    "loop_functions", "loop_freqresp", "LoopAnalysis", "analyse_loop", "min_damping", "MODE_BAND_HZ",
    "stack_inputs", "feedback_operator",
    # discretize
    "Discretization", "DISCRETIZATION_METHODS", "discretize_controller", "discretization_error",
    "discrete_closed_loop", "error_rel_to_peak", "dc_gain_discrete",
    # controller
    "ControllerConfig", "DiscreteController",
    # robustness
    "RECORD_ROW_DELAY_SAMPLES", "IDENTIFIED_DELAY_SAMPLES", "VISIBLE_PEAK", "electronics_ss", "pole_visibility",
    "ROBUSTNESS_MAPS", "STAGE_UNCERTAINTY", "UncertaintySet", "LoopPlant",
    "ControllerRobustness", "DiskMargin", "DiskMarginReport", "LeastDampedPole", "LoopResponse", "LoopStateSpace",
    "MuBounds", "RobustStabilityResult", "analyze_controller", "controller_systems", "closed_loop_poles",
    "disk_gain_phase", "disk_margins", "frequency_response", "least_damped_pole", "loop_transfer_response",
    "loop_transfer_ss", "mu_lower_bound", "mu_upper_bound", "perturbed_plant", "robust_stability_mu",
    "robustness_summary", "stage_grid_hz",
]
