"""Floor vibration: base acceleration seen by the gauges as relative table motion.

The gauges and the actuators are fixed to the same base, so floor (or table)
vibration reaches the reading only through the stage's own dynamics. In the
base frame each body ``i`` carries the inertial force ``-m_i a_b`` at its
centre of mass, i.e. the generalized force ``Q = -sum_i m_i J_com,i^T a_b``
(``J_com`` from ``mujoco.mj_jacBodyCom``). On the loop-closure manifold of
:func:`nanosim.plant.mechanics.mechanical_matrices` (``q = N z``)::

    Mr z'' + Cr z' + Kr z = N^T Q a_b,      probe displacement = Pr z

a linear map from the three base-acceleration components to the three probe
displacements. The mechanics is linear at these amplitudes, so the reading of
a vibrating stage is the reading of a quiet one plus this relative motion
(exact by superposition, in open and closed loop); :class:`FloorVibration`
generates it sample by sample and the stage adds it to the probe displacement.

Spectrum: white table-top acceleration, one-sided PSD ``S_a`` per axis up to
the Nyquist frequency, held over each sample period (zero-order hold). Level:
:data:`nanosim.constants.FLOOR_ACCEL_PSD_M2_S4_HZ` (a VC-C floor through an
isolated optical table; the paper's stage sat on one, in a sealed chamber).
"""
from __future__ import annotations

from dataclasses import dataclass

import mujoco
import numpy as np
import scipy.linalg as sla

from nanosim import constants as C
from nanosim.plant.mechanics import home_data, mechanical_matrices
from nanosim.plant.noise import NormalStream, child_seed

__all__ = ["FloorConfig", "FloorModel", "floor_model", "FloorVibration", "vc_accel_psd"]

_FLOOR_STREAM = 4
_CACHE: dict = {}


def vc_accel_psd(f_Hz: float, velocity_um_s: float = C.FLOOR_VC_C_VELOCITY_UM_S,
                 transmissibility: float = C.FLOOR_TABLE_PLATEAU) -> float:
    """Table-top acceleration PSD, (m/s^2)^2/Hz, of a vibration-criterion floor at ``f_Hz``.

    A VC curve gives the rms velocity ``v`` in each 1/3-octave band (bandwidth 0.2316 f); its
    acceleration ``2 pi f v`` spread over the band, through the table's ``transmissibility``:
    ``S_a(f) = (2 pi f v T)^2 / (0.2316 f)``. VC-C through a 0.01 plateau: 4.66e-10 at 175 Hz.
    """
    for name, x in (("f_Hz", f_Hz), ("velocity_um_s", velocity_um_s), ("transmissibility", transmissibility)):
        if not np.isfinite(x) or x <= 0:
            raise ValueError(f"{name}: expected a finite value > 0, got {x!r}")
    bandwidth_Hz = (2.0 ** (1.0 / 6.0) - 2.0 ** (-1.0 / 6.0)) * f_Hz
    return float((2.0 * np.pi * f_Hz * velocity_um_s * 1e-6 * transmissibility) ** 2 / bandwidth_Hz)


@dataclass(frozen=True)
class FloorConfig:
    """Floor-vibration input.

    Parameters
    ----------
    enabled : bool
        Add the relative motion from base acceleration.
    accel_psd_m2_s4_Hz : float
        One-sided PSD of the table-top acceleration per axis, (m/s^2)^2/Hz (>= 0).
    """

    enabled: bool = True
    accel_psd_m2_s4_Hz: float = C.FLOOR_ACCEL_PSD_M2_S4_HZ

    def __post_init__(self):
        x = float(self.accel_psd_m2_s4_Hz)
        if not np.isfinite(x) or x < 0:
            raise ValueError(f"accel_psd_m2_s4_Hz: expected a finite value >= 0, got {self.accel_psd_m2_s4_Hz}")
        object.__setattr__(self, "accel_psd_m2_s4_Hz", x)

    @classmethod
    def off(cls) -> "FloorConfig":
        """No floor vibration."""
        return cls(enabled=False)


@dataclass(frozen=True)
class FloorModel:
    """Discrete (ZOH) map from base acceleration (m/s^2, world X, Y, Z) to probe displacement (um).

    ``x[k+1] = Ad x[k] + Bd a[k]``, ``d[k+1] = Cd x[k+1]`` (the displacement at
    the end of the period over which ``a[k]`` is held, like the stage's reading).
    """

    Ad: np.ndarray
    Bd: np.ndarray
    Cd: np.ndarray
    dt_s: float
    static_um_per_m_s2: np.ndarray      # (3, 3) quasi-static probe displacement per unit base acceleration


def floor_model(model: mujoco.MjModel, dt_s: float = C.CONTROL_PERIOD_S) -> FloorModel:
    """Build (once per model object) the base-acceleration -> probe-displacement model."""
    key = (id(model), float(dt_s))
    hit = _CACHE.get(key)
    if hit is not None and hit[0] is model:
        return hit[1]
    mm = mechanical_matrices(model)
    data = home_data(model)
    Q = np.zeros((model.nv, 3))
    jacp = np.zeros((3, model.nv))
    for b in range(1, model.nbody):
        m = float(model.body_mass[b])
        if m == 0.0:
            continue
        mujoco.mj_jacBodyCom(model, data, jacp, None, b)
        Q -= m * jacp.T
    Mr, Cr, Kr, _, Pr, _ = mm.reduced
    Qr = mm.N.T @ Q
    nz = Mr.shape[0]
    Minv = np.linalg.inv(Mr)
    A = np.block([[np.zeros((nz, nz)), np.eye(nz)], [-Minv @ Kr, -Minv @ Cr]])
    B = np.vstack([np.zeros((nz, 3)), Minv @ Qr])
    Cm = np.hstack([Pr, np.zeros((3, nz))]) * 1e6
    # exact ZOH: expm of the augmented matrix
    n = 2 * nz
    E = sla.expm(np.block([[A, B], [np.zeros((3, n + 3))]]) * dt_s)
    fm = FloorModel(Ad=E[:n, :n], Bd=E[:n, n:], Cd=Cm, dt_s=float(dt_s),
                    static_um_per_m_s2=Pr @ np.linalg.solve(Kr, Qr) * 1e6)
    _CACHE[key] = (model, fm)
    return fm


class FloorVibration:
    """Relative probe motion (um) from white base acceleration, sample by sample.

    Parameters
    ----------
    fm : FloorModel
    config : FloorConfig
    seed : int, None or SeedSequence
        Master seed (child stream 4).
    """

    def __init__(self, fm: FloorModel, config: FloorConfig, seed=0):
        self.model, self.config = fm, config
        self.active = config.enabled and config.accel_psd_m2_s4_Hz > 0
        # white one-sided PSD S up to fs/2: per-sample variance S fs / 2
        self._sigma = float(np.sqrt(config.accel_psd_m2_s4_Hz / (2.0 * fm.dt_s))) if self.active else 0.0
        self._noise = NormalStream(child_seed(seed, _FLOOR_STREAM), 3) if self.active else None
        self.reset()

    def reset(self) -> None:
        """Quiet state, noise stream rewound."""
        self._x = np.zeros(self.model.Ad.shape[0])
        if self._noise is not None:
            self._noise.reset()

    def step(self) -> np.ndarray:
        """Displacement (3,) um at the end of the next sample period."""
        if not self.active:
            return np.zeros(3)
        a = self._sigma * self._noise.take1()
        self._x = self.model.Ad @ self._x + self.model.Bd @ a
        return self.model.Cd @ self._x

    def run(self, n: int) -> np.ndarray:
        """Displacements (n, 3) um; identical to ``n`` calls of :meth:`step`."""
        if not self.active:
            return np.zeros((n, 3))
        a = self._sigma * self._noise.take(n)
        out = np.empty((n, 3))
        Ad, Bd, Cd, x = self.model.Ad, self.model.Bd, self.model.Cd, self._x
        for k in range(n):
            x = Ad @ x + Bd @ a[k]
            out[k] = Cd @ x
        self._x = x
        return out
