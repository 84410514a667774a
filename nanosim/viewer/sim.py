"""Live closed/open-loop simulation used by the viewer's physics thread.

The mechanics is the MuJoCo :class:`~nanosim.plant.stage.Stage` or the linear
:class:`~nanosim.plant.twin.TwinStage`, with the same electronics around both.
"""
from __future__ import annotations


import mujoco
import numpy as np

from nanosim import constants as C
from nanosim.plant.mechanics import home_data
from nanosim.plant.mjcf import load_model
from nanosim.plant.mjcf import probe_readings_um
from nanosim.plant.modes import modal_analysis

from nanosim.design.controller import DiscreteController
from nanosim.plant.linearize import linearize
from nanosim.plant.stage import Stage, StageConfig
from nanosim.plant.twin import TwinStage

__all__ = ["load_controller", "PHYSICS", "LiveSim"]


def load_controller(path):
    """DiscreteController from a controller file (``.npz``/``.mat``, read by
    :func:`nanosim.design.architectures.protocol.read_controller_file`) at the loop's 4 kHz; one-line
    errors naming ``--controller``.

    Raises
    ------
    FileNotFoundError
        No such file.
    ValueError
        A directory, not a controller ``.npz``, or a sample time other than the loop's.
    """
    from nanosim.design.architectures.protocol import read_controller_file

    return DiscreteController(read_controller_file(path, dt=C.CONTROL_PERIOD_S, name="--controller"))


PHYSICS = ("mujoco", "linear")


class LiveSim:
    """Stage + reference + (optional) H-infinity controller, one 4 kHz step at a time.

    Not thread-safe by itself: the viewer calls it from the physics thread only
    and reads the published snapshot (``snapshot()``) under its lock.
    """

    def __init__(self, model: mujoco.MjModel | None = None, mjcf=None, controller=None,
                 realistic: bool = False, seed: int = 0, physics: str = "mujoco"):
        if physics not in PHYSICS:
            raise ValueError(f"physics: expected one of {PHYSICS}, got {physics!r}")
        self.mjcf = mjcf
        self.model = model if model is not None else load_model(mjcf)
        self.controller = controller
        self.controller_on = controller is not None
        self.seed = seed
        self.G0 = modal_analysis(self.model).static_gain_um_per_V
        self.G0inv = np.linalg.inv(self.G0)
        self.realistic = realistic
        self.physics = physics
        self._twin = None
        self._make_stage()

    def set_physics(self, physics: str) -> None:
        """``"mujoco"`` (nonlinear integrator, 20 substeps per period) or ``"linear"``
        (MuJoCo's own linearization about home, one 12-state step per period); resets.
        """
        if physics not in PHYSICS:
            raise ValueError(f"physics: expected one of {PHYSICS}, got {physics!r}")
        if physics != self.physics:
            self.physics = physics
            self._make_stage()

    def _linear_twin(self):
        if self._twin is None:
            self._twin = linearize(Stage(config=StageConfig.ideal(), model=self.model), with_qpos=True)
        return self._twin

    def _make_stage(self):
        if self.physics == "linear":
            cfg = StageConfig() if self.realistic else StageConfig.ideal()
            home = home_data(self.model)
            self.stage = TwinStage(self._linear_twin(), seed=self.seed, config=cfg,
                                   home_um=probe_readings_um(self.model, home), home_qpos=home.qpos)
        else:
            cfg = StageConfig() if self.realistic else StageConfig.ideal()
            self.stage = Stage(seed=self.seed, config=cfg, model=self.model)
        # probe reading at home (e.g. the Z probe's zero offset): the viewer's
        # references and readouts are displacements from home
        self.y_home_V = self._home_reading_V()
        self.y_V = self.y_home_V.copy()
        self.u_V = np.zeros(3)
        self.ref_um = np.zeros(3)
        self.reset_controller()

    def reset_controller(self) -> None:
        """Start the controller at the current reading and command (no kick, ``reset_at``)."""
        if self.controller is not None:
            if isinstance(self.controller, DiscreteController):
                self.controller.reset_at(self.y_V, command_V=self.u_V)
            else:
                self.controller.reset_at(self.y_V)

    def _home_reading_V(self) -> np.ndarray:
        d = home_data(self.model)
        return probe_readings_um(self.model, d) / C.SENSOR_UM_PER_V

    def set_realistic(self, on: bool):
        if bool(on) != self.realistic:
            self.realistic = bool(on)
            self._make_stage()

    def reset(self):
        self._make_stage()

    @property
    def time_s(self) -> float:
        return float(self.stage.time_s)

    @property
    def dt_s(self) -> float:
        return C.CONTROL_PERIOD_S

    def step(self, ref_um) -> np.ndarray:
        """One control period toward ``ref_um`` (3,, from home); returns measured um from home (3,)."""
        self.ref_um = np.asarray(ref_um, float)
        if self.controller_on and self.controller is not None:
            r_V = self.ref_um / C.SENSOR_UM_PER_V + self.y_home_V
            self.u_V = np.asarray(self.controller.feedback(r_V, self.y_V), float)
        else:
            self.u_V = self.G0inv @ self.ref_um
        self.y_V = np.asarray(self.stage.step(self.u_V), float)
        return (self.y_V - self.y_home_V) * C.SENSOR_UM_PER_V

    @property
    def table_from_home_um(self) -> np.ndarray:
        """The table's true (noise-free) position, um from home (the reading at home is its zero)."""
        return np.asarray(self.stage.table_um, float) - self.y_home_V * C.SENSOR_UM_PER_V

    @property
    def qpos(self) -> np.ndarray:
        if self.physics == "linear":
            return self.stage.qpos
        return self.stage.data.qpos.copy()

    def snapshot(self) -> dict:
        st = self.stage
        return {"t": self.time_s, "qpos": self.qpos, "ref_um": self.ref_um.copy(),
                "meas_um": (self.y_V - self.y_home_V) * C.SENSOR_UM_PER_V, "u_V": self.u_V.copy(),
                "piezo_V": np.asarray(st.last_piezo_V, float).copy(),
                "saturated": np.asarray(st.last_saturated, bool).copy(),
                "table_um": np.asarray(st.table_um, float).copy()}
