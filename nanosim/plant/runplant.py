"""The plant of one command: a MuJoCo model's ideal stage and its linear twin, built once and passed down.

Every command that needs the linear twin of the stage (``nanosim characterize --twin``, ``scan``,
``montecarlo``, ``sweep``, the identification on the twin, ``twin.npz``) linearizes the same thing: the
ideal stage (:meth:`~nanosim.plant.stage.StageConfig.ideal`, every electromechanical effect off) of the
command's MuJoCo model. :class:`RunPlant` is that plant: built from the model (or the ``mjcf``) once,
its :attr:`~RunPlant.twin` computed on first use and then shared by everything the command passes it to.
"""
from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

from nanosim.plant.linearize import LinearTwin, linearize
from nanosim.plant.stage import Stage, StageConfig

__all__ = ["RunPlant"]


@dataclass(frozen=True, eq=False)
class RunPlant:
    """The ideal stage of one MuJoCo model and its linear twin (the mechanics, the piezo linear).

    Attributes
    ----------
    ideal_stage : Stage
        The model's stage with :meth:`StageConfig.ideal` (seed 0).
    """

    ideal_stage: Stage

    @classmethod
    def of_model(cls, model) -> "RunPlant":
        """The plant of a compiled ``mujoco.MjModel``."""
        return cls(Stage(config=StageConfig.ideal(), model=model))

    @classmethod
    def load(cls, mjcf=None) -> "RunPlant":
        """The plant of an MJCF file (None: the bundled stage)."""
        return cls(Stage(config=StageConfig.ideal(), mjcf=mjcf))

    @property
    def model(self):
        """The ``mujoco.MjModel``."""
        return self.ideal_stage.model

    @cached_property
    def twin(self) -> LinearTwin:
        """:func:`~nanosim.plant.linearize.linearize` of :attr:`ideal_stage` (computed once)."""
        return linearize(self.ideal_stage)
