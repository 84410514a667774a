"""The linear twin wrapped in the same electromechanics as the MuJoCo :class:`~nanosim.plant.stage.Stage`."""
from __future__ import annotations

import numpy as np

from nanosim import constants as C
from nanosim.plant.electronics import ActuatorChain, SensorChain
from nanosim.plant.floor import FloorModel, FloorVibration
from nanosim.plant.stage import StageConfig, Trace

__all__ = ["TwinStage"]

UM_PER_V = C.SENSOR_UM_PER_V


class TwinStage:
    """The linear twin wrapped in the same electromechanics as :class:`Stage`.

    Same ``step``/``run``/``reset`` API: DAC, amplifier, piezo hysteresis and
    creep, gauge and ADC act exactly as on the MuJoCo stage; only the
    mechanics is the 4 kHz discrete linear twin. Floor vibration needs
    ``floor_model`` (:func:`nanosim.plant.floor.floor_model` of the MuJoCo
    model the twin came from); without it the twin has none.
    """

    def __init__(self, twin, seed: int = 0, config: StageConfig | None = None, home_um=None, home_qpos=None,
                 floor_model: FloorModel | None = None):
        self.config = config or StageConfig()
        self._floor_model = floor_model
        self._twin = twin
        self._home_qpos_arg = home_qpos
        self.seed = seed
        sysd = twin.sysd_V
        self._A, self._B, self._C, self._D = sysd.A, sysd.B, sysd.C, sysd.D
        self._qC, self._qD = getattr(twin, "qpos_C", None), getattr(twin, "qpos_D", None)
        self._q0 = None if home_qpos is None else np.asarray(home_qpos, float).copy()
        self._home_um = np.zeros(3) if home_um is None else np.asarray(home_um, float)
        self.dt_s = twin.dt_s
        self.reset()

    def variant(self, config: StageConfig, seed: int | None = None) -> "TwinStage":
        """A fresh twin stage on the same mechanics with other electromechanics (and seed)."""
        return TwinStage(self._twin, seed=self.seed if seed is None else seed, config=config,
                         home_um=self._home_um, home_qpos=self._home_qpos_arg, floor_model=self._floor_model)

    def reset(self) -> None:
        """Back to home with fresh electronics (same seed, same noise)."""
        self.actuators = ActuatorChain(self.config.electronics, self.config.piezo, seed=self.seed)
        self.sensors = SensorChain(self.config.electronics, seed=self.seed)
        self.floor = (FloorVibration(self._floor_model, self.config.floor, seed=self.seed)
                      if self._floor_model is not None else None)
        self._x = np.zeros(self._A.shape[0])
        self._v = np.zeros(3)
        self.time_s = 0.0
        self.table_um = self._home_um.copy()
        self.last_saturated = np.zeros(3, dtype=bool)
        self.last_piezo_V = np.zeros(3)

    def step(self, u_V) -> np.ndarray:
        """One 4 kHz period with command ``u_V`` (3,) controller volts; returns the sensor reading (3,) V."""
        act = self.actuators.step(u_V)
        v_eq = act.v_free_V / self.config.electronics.amplifier_gain      # equivalent controller volts
        self._v = v_eq
        self._x = self._A @ self._x + self._B @ v_eq
        self.table_um = self._home_um + UM_PER_V * (self._C @ self._x + self._D @ v_eq)
        if self.floor is not None and self.floor.active:
            self.table_um = self.table_um + self.floor.step()
        self.time_s += self.dt_s
        self.last_saturated = act.saturated
        self.last_piezo_V = act.v_piezo_V
        return self.sensors.step(self.table_um).reading_V

    @property
    def qpos(self) -> np.ndarray:
        """Joint positions of the linearized mechanism (needs a twin built ``with_qpos`` and ``home_qpos``)."""
        if self._qC is None or self._q0 is None:
            raise ValueError("qpos: build the twin with linearize(..., with_qpos=True) and pass home_qpos")
        return self._q0 + self._qC @ self._x + self._qD @ self._v

    def run(self, u_V) -> Trace:
        """Open-loop run with the same record layout as :meth:`Stage.run`."""
        u = np.asarray(u_V, float)
        rows = []
        for uk in u:
            y = self.step(uk)
            rows.append((self.last_piezo_V, self.last_saturated, self.table_um.copy(), y))
        pz, sat, tb, ys = (np.array(c) for c in zip(*rows))
        return Trace(t_s=self.dt_s * np.arange(1, len(u) + 1), u_V=u, piezo_V=pz, saturated=sat, table_um=tb,
                     sensor_V=ys, sensor_um=ys * UM_PER_V, clipped=np.zeros_like(sat))
