"""nanosim: simulator, identification and robust control of a parallel-kinematic XYZ nanopositioner."""
from nanosim.plant.linearize import LinearTwin, linearize
from nanosim.plant.stage import Stage, StageConfig, Trace, run_open_loop_batch

__all__ = ["Stage", "StageConfig", "Trace", "run_open_loop_batch", "linearize", "LinearTwin"]
__version__ = "0.1.0"
