"""nanosim: simulator, identification and robust control of a parallel-kinematic XYZ nanopositioner.

The public API, by layer (see README, "Architecture"):

- plant: :class:`Stage`, :class:`StageConfig`, :class:`Trace`, :func:`run_open_loop_batch`, :class:`TwinStage`,
  :func:`linearize`, :class:`LinearTwin`, :func:`load_model`, :func:`modal_analysis`
- design: :class:`Weights`, :func:`reduce_model`, :func:`damping_loop`, :func:`design_hinf`,
  :func:`discretize_controller`, :class:`DiscreteController`
- experiments: :func:`identify_stage`, :func:`identify_on_twin`, :class:`IdentifySettings`, :func:`run_closed_loop`
- pipeline: :class:`IdentifyConfig`, :class:`DesignConfig`, :class:`CharacterizeConfig`, :class:`PipelineConfig`,
  :func:`run_identify`, :func:`run_design`, :func:`run_characterize`, :func:`run_pipeline`, :func:`write_report`
"""
__version__ = "0.1.0"

from nanosim.design import (DiscreteController, Weights, damping_loop, design_hinf,  # noqa: E402
                            discretize_controller, reduce_model)
from nanosim.experiments.loop import run_closed_loop  # noqa: E402
from nanosim.experiments.sysid import IdentifySettings, identify_on_twin, identify_stage  # noqa: E402
from nanosim.pipeline import (CharacterizeConfig, DesignConfig, IdentifyConfig, PipelineConfig,  # noqa: E402
                              run_characterize, run_design, run_identify, run_pipeline, write_report)
from nanosim.plant.linearize import LinearTwin, linearize  # noqa: E402
from nanosim.plant.mjcf import load_model  # noqa: E402
from nanosim.plant.modes import modal_analysis  # noqa: E402
from nanosim.plant.stage import Stage, StageConfig, Trace, run_open_loop_batch  # noqa: E402
from nanosim.plant.twin import TwinStage  # noqa: E402

__all__ = ["Stage", "StageConfig", "Trace", "run_open_loop_batch", "TwinStage", "linearize", "LinearTwin",
           "load_model", "modal_analysis",
           "Weights", "reduce_model", "damping_loop", "design_hinf", "discretize_controller", "DiscreteController",
           "identify_stage", "identify_on_twin", "IdentifySettings", "run_closed_loop",
           "IdentifyConfig", "DesignConfig", "CharacterizeConfig", "PipelineConfig",
           "run_identify", "run_design", "run_characterize", "run_pipeline", "write_report", "__version__"]
