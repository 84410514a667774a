"""The sampled stage: MuJoCo mechanics + piezo + electronics at 4 kHz.

``Stage.step(u_V)`` applies three controller volts with zero-order hold for
one 250 us control period (MuJoCo substeps evenly inside it) and returns the
three probe readings in sensor volts (5 um/V) at the end of the period.
``Stage.run`` and :func:`run_open_loop_batch` do the same for whole command
arrays; the batch runner uses ``mujoco.rollout`` threads.
"""
from __future__ import annotations

import os
from dataclasses import dataclass, field

import mujoco
import numpy as np
from mujoco import rollout

from nanosim import constants as C
from nanosim.validation import as_finite_array
from nanosim.plant.electronics import ActuatorChain, ElectronicsConfig, SensorChain
from nanosim.plant.floor import FloorConfig, FloorVibration, floor_model
from nanosim.plant.mechanics import home_data
from nanosim.plant.mjcf import custom_numeric, load_model, probe_layout, update_position_sensors
from nanosim.plant.piezo import PiezoConfig

__all__ = ["StageConfig", "Trace", "Stage", "rollout_probes_um", "run_open_loop_batch", "STAGE_ELECTRONICS",
           "STAGE_ELECTRONICS_V1"]

# The bench electronics: every default of ElectronicsConfig (sourced values in
# nanosim.constants: the DAC's resolution and range, every broadband noise at its
# datasheet level). The legs' thermal-drift level is the one noise level calibrated
# to the paper (open-loop probe sigma at rest 11.4 nm, Sec. 5): tools/fit_drift_level.py.
STAGE_ELECTRONICS = ElectronicsConfig()
_DAC_SPAN = dict(dac_bits=16, dac_full_scale_V=(C.COMMAND_RANGE_V[1] - C.COMMAND_RANGE_V[0]) / 2,
                 dac_center_V=(C.COMMAND_RANGE_V[1] + C.COMMAND_RANGE_V[0]) / 2, thermal_drift=False)
# Stage v1 (the first stage model, kept for comparison): no computation delay, amplifier or gauge
# bandwidth, no amplifier
# noise; DAC noise 1.39 mV low-passed by two poles at 5 Hz (a level and corner calibrated to
# the open- and closed-loop sigma). For comparisons and ablations.
STAGE_ELECTRONICS_V1 = ElectronicsConfig(**_DAC_SPAN, computation_delay_samples=0, dac_noise_V=1.39e-3,
                                         dac_noise_corner_Hz=5.0, dac_flicker_corner_Hz=None,
                                         amplifier_noise=False, amplifier_bandwidth_Hz=None,
                                         gauge_bandwidth_Hz=None)


@dataclass(frozen=True)
class StageConfig:
    """Electromechanics switches; ``StageConfig()`` has every effect on."""

    electronics: ElectronicsConfig = field(default_factory=lambda: STAGE_ELECTRONICS)
    piezo: PiezoConfig = field(default_factory=PiezoConfig)
    floor: FloorConfig = field(default_factory=FloorConfig)

    @classmethod
    def ideal(cls) -> "StageConfig":
        """Linear plant: no noise, quantization, saturation, delay, filters, hysteresis, creep or floor."""
        return cls(electronics=ElectronicsConfig.ideal(), piezo=PiezoConfig.linear(), floor=FloorConfig.off())

    @classmethod
    def v1(cls) -> "StageConfig":
        """The stage-v1 electromechanics (the first stage model, kept for comparison).

        v1 electronics, v1 creep, no floor vibration.
        """
        return cls(electronics=STAGE_ELECTRONICS_V1, piezo=PiezoConfig.calibrated_v1(), floor=FloorConfig.off())




@dataclass(frozen=True)
class Trace:
    """A sampled record; row k holds the command applied over [t_k, t_k + T)
    and the reading at t_k + T.

    t_s (N,) time at the end of each period, s; u_V (N, 3) controller command
    (it reaches the DAC ``computation_delay_samples`` periods later);
    piezo_V (N, 3) amplifier output; saturated (N, 3) command clipped;
    table_um (N, 3) true probe-axis displacement, floor vibration included
    (no gauge noise or filter); sensor_V (N, 3)
    ADC reading in sensor volts; sensor_um (N, 3) the same in um;
    clipped (N, 3) gauge out of range.
    """

    t_s: np.ndarray
    u_V: np.ndarray
    piezo_V: np.ndarray
    saturated: np.ndarray
    table_um: np.ndarray
    sensor_V: np.ndarray
    sensor_um: np.ndarray
    clipped: np.ndarray

    def as_arrays(self) -> dict[str, np.ndarray]:
        """The fields as a name -> array dict."""
        return {k: getattr(self, k) for k in self.__dataclass_fields__}


class Stage:
    """Bundled stage with every effect on (``Stage()``), or as configured.

    Parameters
    ----------
    seed : master seed for DAC and gauge noise.
    config : :class:`StageConfig`.
    mjcf : path to another stage MJCF; ``model`` : an already-loaded MjModel.
    """

    def __init__(self, seed: int = 0, config: StageConfig | None = None, mjcf=None,
                 model: mujoco.MjModel | None = None):
        self.config = config or StageConfig()
        self.seed = seed
        self.model = model if model is not None else load_model(mjcf)
        self.dt_s = 1.0 / self.config.electronics.sample_rate_Hz
        ratio = self.dt_s / self.model.opt.timestep
        self.substeps = int(round(ratio))
        if abs(ratio - self.substeps) > 1e-9 * ratio:
            raise ValueError(f"mjcf: timestep {self.model.opt.timestep} s must divide the control period "
                             f"{self.dt_s} s evenly")
        self._probe_adr, self._probe_bias_m = probe_layout(self.model)
        self._force_per_V = float(custom_numeric(self.model, "piezo_force_per_volt_N",
                                                 C.PIEZO_FORCE_PER_PIEZO_V)[0])
        self.reset()

    def variant(self, config: StageConfig, seed: int | None = None) -> "Stage":
        """A fresh stage on the same mechanics with other electromechanics (and seed)."""
        return Stage(seed=self.seed if seed is None else seed, config=config, model=self.model)

    # -- state -------------------------------------------------------------
    def reset(self) -> None:
        """Home keyframe, virgin piezo, noise streams rewound to the seed."""
        self.data = home_data(self.model)
        self.actuators = ActuatorChain(self.config.electronics, self.config.piezo, seed=self.seed)
        self.sensors = SensorChain(self.config.electronics, seed=self.seed)
        self.floor = FloorVibration(floor_model(self.model, self.dt_s), self.config.floor, seed=self.seed)
        self.time_s = 0.0
        self.last_piezo_V = np.zeros(3)
        self.last_saturated = np.zeros(3, dtype=bool)
        self.last_clipped = np.zeros(3, dtype=bool)
        self.table_um = self._probe_um()

    def _probe_um(self) -> np.ndarray:
        return (self.data.sensordata[self._probe_adr] + self._probe_bias_m) * 1e6

    # -- stepping ------------------------------------------------------------
    def step(self, u_V) -> np.ndarray:
        """Apply controller volts (3,) for one period; return sensor volts (3,)."""
        u = as_finite_array("u_V", u_V, shape=(3,))
        act = self.actuators.step(u)
        self.data.ctrl[:] = self._force_per_V * act.v_free_V
        mujoco.mj_step(self.model, self.data, self.substeps)
        update_position_sensors(self.model, self.data)   # the reading at the end of the period
        self.time_s += self.dt_s
        self.table_um = self._probe_um()
        if self.floor.active:
            self.table_um = self.table_um + self.floor.step()
        sens = self.sensors.step(self.table_um)
        self.last_piezo_V = act.v_piezo_V
        self.last_saturated = act.saturated
        self.last_clipped = sens.clipped
        return sens.reading_V

    def run(self, u_V) -> Trace:
        """Open-loop run of an (N, 3) command array from the current state."""
        u = as_finite_array("u_V", u_V, shape=(None, 3))
        act = self.actuators.run(u)
        table = _rollout(self.model, [self.data], self.data, self._force_per_V * act.v_free_V[None],
                         self.substeps, self._probe_adr, self._probe_bias_m)[0]
        n = len(u)
        if self.floor.active:
            table = table + self.floor.run(n)
        t = self.time_s + self.dt_s * np.arange(1, n + 1)
        self.time_s = float(t[-1]) if n else self.time_s
        if n:
            self.table_um = table[-1]
            self.last_piezo_V = act.v_piezo_V[-1]
        return _trace(t, u, act, table, self.sensors)


#: Control periods per rollout call: bounds memory (states are per substep) and the time a call
#: holds the main thread (a signal is handled between calls), a fraction of a second for a batch.
_CHUNK = 250


def rollout_probes_um(model, datas, start: mujoco.MjData, forces: np.ndarray, substeps: int,
                      probe_adr: np.ndarray, bias_m: np.ndarray) -> np.ndarray:
    """Probe readings (um) of ``(B, N, 3)`` tendon forces held over ``substeps`` (what :meth:`Stage.run` rolls out).

    ``start`` is the initial state and is advanced to the final state of trajectory 0; ``datas``
    are the rollout's thread-local MjData.
    """
    return _rollout(model, datas, start, forces, substeps, probe_adr, bias_m)


def _rollout(model, datas, start: mujoco.MjData, forces: np.ndarray, substeps: int,
             probe_adr: np.ndarray, bias_m: np.ndarray) -> np.ndarray:
    """Roll out (B, N, 3) tendon forces held over ``substeps``; return (B, N, 3) probe um.

    ``start`` is advanced to the final state of trajectory 0 (single-trajectory use).
    """
    nb, n, _ = forces.shape
    spec = mujoco.mjtState.mjSTATE_FULLPHYSICS
    size = mujoco.mj_stateSize(model, spec)
    state0 = np.empty(size)
    mujoco.mj_getState(model, start, state0, spec)
    states = np.tile(state0, (nb, 1))
    out = np.empty((nb, n, 3))
    scratch = mujoco.MjData(model)
    for k0 in range(0, n, _CHUNK):
        k1 = min(n, k0 + _CHUNK)
        ctrl = np.repeat(forces[:, k0:k1], substeps, axis=1)
        st, sd = rollout.rollout(model, datas, states, ctrl, skip_checks=False)
        # mj_step records sensors before it integrates: the reading at the end of period p is the
        # one recorded by the first substep of period p + 1; the chunk's last comes from its final state
        out[:, k0:k1 - 1] = (sd[:, substeps::substeps, :][:, :, probe_adr] + bias_m) * 1e6
        states = st[:, -1, :].copy()
        for b in range(nb):
            mujoco.mj_setState(model, scratch, states[b], spec)
            update_position_sensors(model, scratch)
            out[b, k1 - 1] = (scratch.sensordata[probe_adr] + bias_m) * 1e6
    if nb:
        mujoco.mj_setState(model, start, states[0], spec)
        mujoco.mj_forward(model, start)
    return out


def run_open_loop_batch(u_batch, *, seeds, config: StageConfig | None = None, mjcf=None,
                        model: mujoco.MjModel | None = None, nthread: int | None = None) -> list[Trace]:
    """Run B independent open-loop experiments in parallel with ``mujoco.rollout``.

    Parameters
    ----------
    u_batch : (B, N, 3) controller volts, each experiment from the home state.
    seeds : B seeds, one Stage seed per experiment.
    """
    u = as_finite_array("u_batch", u_batch, shape=(None, None, 3))
    seeds = list(seeds)
    if len(seeds) != u.shape[0]:
        raise ValueError(f"seeds: expected {u.shape[0]} seeds (one per experiment), got {len(seeds)}")
    stages = [Stage(seed=s, config=config, mjcf=mjcf, model=model) for s in seeds]
    acts = [st.actuators.run(ui) for st, ui in zip(stages, u)]
    forces = np.stack([st._force_per_V * a.v_free_V for st, a in zip(stages, acts)])
    st0 = stages[0]
    nthread = nthread or max(1, min(len(seeds), os.cpu_count() or 1))
    datas = [mujoco.MjData(st0.model) for _ in range(nthread)]
    table = _rollout(st0.model, datas, home_data(st0.model), forces, st0.substeps, st0._probe_adr,
                     st0._probe_bias_m)
    traces = []
    t = st0.dt_s * np.arange(1, u.shape[1] + 1)
    for st, ui, a, tb in zip(stages, u, acts, table):
        if st.floor.active:
            tb = tb + st.floor.run(len(ui))
        traces.append(_trace(t, ui, a, tb, st.sensors))
    return traces


def _trace(t, u, act, table_um, sensors: SensorChain) -> Trace:
    """Record of an open-loop run: actuator-chain output, table motion, and the sensor chain's readings."""
    sens = sensors.run(table_um)
    return Trace(t_s=t, u_V=u, piezo_V=act.v_piezo_V, saturated=act.saturated, table_um=table_um,
                 sensor_V=sens.reading_V, sensor_um=sens.reading_um, clipped=sens.clipped)
