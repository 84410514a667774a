"""Pipeline layer: the only layer that writes run folders (steps, config, artifact names, report)."""
from nanosim.pipeline.characterize import run_characterize
from nanosim.pipeline.config import CharacterizeConfig, DesignConfig, IdentifyConfig, PipelineConfig
from nanosim.pipeline.design import run_design
from nanosim.pipeline.identify import run_identify
from nanosim.pipeline.report import write_report
from nanosim.pipeline.run import run_pipeline

__all__ = ["run_characterize", "run_design", "run_identify", "run_pipeline", "write_report",
           "CharacterizeConfig", "DesignConfig", "IdentifyConfig", "PipelineConfig"]
