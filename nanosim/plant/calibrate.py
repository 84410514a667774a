"""Fit hinge-family stiffnesses and masses to the paper's modes and static gain.

Least squares (``scipy.optimize.least_squares``) on the exact constrained
linearization (:mod:`nanosim.mechanics`), in log-parameters. Targets: the six
identified modes (paper Sec. 3: 175/179 XY, 245 Z, 460/474 XY, 740 Hz Z), the
static gain 3.0 um/V * J (rows X, Y; row Z 3.2 um/V so that Z travel reaches
80 um, see ``mjcf/README.md``) and 0.005 modal damping.
"""
from __future__ import annotations

from dataclasses import dataclass

import mujoco
import numpy as np
from scipy.optimize import least_squares

from nanosim import constants as C
from nanosim.plant.build import DEFAULT_PARAMS, StageParams, stage_xml
from nanosim.plant.mechanics import mechanical_matrices, reduced_modes, static_compliance
from nanosim.plant.modes import modal_analysis

TARGET_XY_HZ = (175.0, 179.0, 460.0, 474.0)
TARGET_Z_HZ = (245.0, 740.0)
TARGET_GAIN_SCALE_XY = C.STATIC_GAIN_SCALE_UM_PER_V
TARGET_GAIN_Z_UM_PER_V = 3.45
TARGET_ZETA = 0.005

FIT_NAMES = ("k_fourbar1", "k_fourbar2", "k_swing", "k_lever", "k_crank_bend", "link_density_scale", "table_extra_mass",
             "lever_block_mass", "chain_a_stiffness_factor", "piezo_arm")
DAMPING_NAMES = ("beta_hinge", "beta_piezo")
# keep the fit physical: aluminium links within 0.3-3x the drawn volume, grams not kilograms
PHYSICAL_BOUNDS = {
    "chain_a_stiffness_factor": (1.0, 1.15),
    "link_density_scale": (0.3, 3.0),
    "table_extra_mass": (0.2e-3, 20e-3),
    "lever_block_mass": (0.5e-3, 20e-3),
    "piezo_arm": (1.5e-3, 6e-3),
}


@dataclass(frozen=True)
class StageLinearSummary:
    """Modes split by axis and the static gain of one parameter set."""

    xy_hz: np.ndarray          # XY-mode frequencies, ascending
    z_hz: np.ndarray           # Z-mode frequencies, ascending
    xy_zeta: np.ndarray
    z_zeta: np.ndarray
    gain_um_per_V: np.ndarray  # (3, 3) rows XYZ, cols ABC


def model_from_params(p: StageParams) -> mujoco.MjModel:
    return mujoco.MjModel.from_xml_string(stage_xml(p))


def summarize(p: StageParams, exact: bool = False) -> StageLinearSummary:
    """Modes and static gain of MuJoCo's own linearization (``exact=True``: rigid closures)."""
    model = model_from_params(p)
    if exact:
        mm = mechanical_matrices(model)
        f, zeta, shapes = reduced_modes(mm)
        part = np.abs(mm.probe @ shapes)
        is_z = part[2] > np.hypot(part[0], part[1])
        gain = static_compliance(mm) * C.PIEZO_FORCE_PER_PIEZO_V * C.AMPLIFIER_GAIN * 1e6
    else:
        res = modal_analysis(model)
        phys = [m for m in res.physical if m.freq_hz < 2000.0]
        f = np.array([m.freq_hz for m in phys])
        zeta = np.array([m.damping_ratio for m in phys])
        is_z = np.array([m.axis == "Z" for m in phys], dtype=bool)
        gain = res.static_gain_um_per_V
    return StageLinearSummary(xy_hz=f[~is_z], z_hz=f[is_z], xy_zeta=zeta[~is_z], z_zeta=zeta[is_z],
                              gain_um_per_V=gain)


def _gain_target() -> np.ndarray:
    target = TARGET_GAIN_SCALE_XY * C.JACOBIAN_J.copy()
    target[2] = TARGET_GAIN_Z_UM_PER_V
    return target


def _residuals(s: StageLinearSummary) -> np.ndarray:
    if len(s.xy_hz) != 4 or len(s.z_hz) != 2:
        return np.full(12, 10.0)
    r_f = np.log(np.concatenate([s.xy_hz, s.z_hz]) / np.array(TARGET_XY_HZ + TARGET_Z_HZ))
    target = _gain_target()
    r_g = (s.gain_um_per_V - target).ravel() / np.abs(target).max()
    return np.concatenate([3.0 * r_f, r_g])


def calibrate(p0: StageParams = DEFAULT_PARAMS, max_nfev: int = 200, verbose: int = 0):
    """Return (params, summary, residual_vector) fitted to the paper's targets."""
    x0 = np.log([getattr(p0, n) for n in FIT_NAMES])

    def fun(x):
        p = p0.with_(**dict(zip(FIT_NAMES, np.exp(x))))
        return _residuals(summarize(p))

    lo = x0 - np.log(1e3)
    hi = x0 + np.log(1e3)
    for name, (a, b) in PHYSICAL_BOUNDS.items():
        lo[FIT_NAMES.index(name)], hi[FIT_NAMES.index(name)] = np.log(a), np.log(b)
    x0 = np.clip(x0, lo + 1e-9, hi - 1e-9)
    sol = least_squares(fun, x0, bounds=(lo, hi), x_scale=1.0, max_nfev=max_nfev, verbose=verbose)
    p = p0.with_(**dict(zip(FIT_NAMES, np.exp(sol.x))))
    p = calibrate_damping(p)
    s = summarize(p)
    return p, s, _residuals(s)


def calibrate_damping(p: StageParams) -> StageParams:
    """Choose stiffness-proportional damping so the modes sit near zeta = 0.005."""
    x0 = np.log([getattr(p, n) for n in DAMPING_NAMES])

    def fun(x):
        s = summarize(p.with_(**dict(zip(DAMPING_NAMES, np.exp(x)))))
        return np.log(np.concatenate([s.xy_zeta, s.z_zeta]) / TARGET_ZETA)

    sol = least_squares(fun, x0, max_nfev=60)
    return p.with_(**dict(zip(DAMPING_NAMES, np.exp(sol.x))))
