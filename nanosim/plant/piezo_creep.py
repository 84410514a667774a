"""The operators' thermal creep: the closed-form step response and the activation voltage of a creep rate.

:func:`activation_voltage_for_creep` finds the activation voltage ``V_a`` of the thermally activated
play operators (:mod:`~nanosim.plant.piezo_operators`) whose open-loop creep after a step follows PI's
law at a given rate per decade over :data:`CREEP_WINDOW_S`; :class:`~nanosim.plant.piezo.PiezoConfig`
calibrates with it (and re-exports these names).
"""
from __future__ import annotations

from functools import lru_cache

import numpy as np
from scipy.optimize import brentq

from nanosim import constants as C
from nanosim.plant.piezo_operators import play_run, relaxation_rates

__all__ = ["CREEP_WINDOW_S", "activation_voltage_for_creep"]


# Creep-rate window of PI's law (t0 = 0.1 s) over which the activation voltage is derived.
CREEP_WINDOW_S = (0.1, 10.0)


def _step_response(t, step_V, r, w0, w, va, nu):
    """Continuous-time output at ``t`` after a step ``step_V > 0`` from the virgin state (see PiezoConfig)."""
    t = np.maximum(np.asarray(t, dtype=float), 0.0)[..., None]
    e0 = np.minimum(step_V, r)                                   # z_0 = max(H - r, 0), e_0 = H - z_0
    if va > 0.0:
        p0 = np.exp(-e0 / va)
        om = -np.expm1(-relaxation_rates(r, va, nu) * t)
        omt = om + (1.0 - om) * (2.0 * p0 / (1.0 + p0))
        with np.errstate(divide="ignore"):
            e = np.where(omt > 0.0, -va * np.log(omt / (2.0 - omt)), e0)       # omt = 0: no motion (as the kernel)
    else:
        e = np.broadcast_to(e0, t.shape[:-1] + r.shape)
    return w0 * step_V + ((step_V - e) * w).sum(-1)


def _creep_rate(step_V, r, w0, w, va, nu, window_s=CREEP_WINDOW_S, n=41):
    t = np.logspace(np.log10(window_s[0]), np.log10(window_s[1]), n)
    x = _step_response(t, step_V, r, w0, w, va, nu)
    return float(np.polyfit(np.log10(t / t[0]), x / x[0], 1)[0])


@lru_cache(maxsize=64)
def _activation_cached(per_decade, step_V, r, w0, w, tau_min_s):
    ra, wa = np.asarray(r), np.asarray(w)

    def excess(va):
        return _creep_rate(step_V, ra, w0, wa, va, va / tau_min_s) - per_decade

    grid = np.logspace(-4.0, np.log10(float(step_V)), 49)         # the first crossing from below
    ex = np.array([excess(va) for va in grid])
    above = np.flatnonzero(ex > 0.0)
    if ex[0] >= 0.0 or above.size == 0:
        raise ValueError(f"creep_per_decade: {per_decade} per decade is out of this operator set's reach after a "
                         f"{step_V} V step (at most {ex.max() + per_decade:.4g})")
    k = int(above[0])
    return float(brentq(excess, grid[k - 1], grid[k], xtol=1e-12, rtol=1e-12))


@lru_cache(maxsize=64)
def _ramp_outputs_cached(r, va, nu, peak, rise_s, dt_s):
    """Operator outputs at the last sample of a linear 0 -> peak ramp of rise_s from rest (clamped, as output)."""
    ra = np.ascontiguousarray(r, dtype=float)
    n = max(1, int(round(rise_s / dt_s)))
    v = np.linspace(0.0, peak, n + 1)
    z = np.zeros((1, ra.size))
    om = np.ascontiguousarray(-np.expm1(-relaxation_rates(ra, va, nu) * dt_s))
    play_run(v[:n, None].copy(), z, ra, np.zeros(ra.size), om, np.array([0.0, va]), np.empty((n, 1)))
    return tuple(float(x) for x in np.minimum(np.maximum(z[0], peak - ra), peak + ra))


def activation_voltage_for_creep(per_decade: float, step_V: float, thresholds_V, linear_weight: float, weights,
                                 tau_min_s: float = C.CREEP_TAU_MIN_S) -> float:
    """Activation voltage ``V_a`` whose open-loop creep after a step is ``per_decade`` (PI's law, 0.1-10 s).

    Parameters
    ----------
    per_decade : float
        Target ``gamma``: the least-squares slope of ``x(t) / x(0.1 s)``
        against ``log10 t`` over 0.1-10 s (PI: 0.01-0.02).
    step_V : float
        Step from the virgin state, piezo volts (> 0).
    thresholds_V, weights : sequence of float
        Operator thresholds and weights.
    linear_weight : float
        ``w0``.
    tau_min_s : float
        Creep onset; the attempt rate is ``nu = V_a / tau_min_s``.

    Returns
    -------
    float
        ``V_a`` in volts: the smallest root of the closed-form relation
        (:meth:`PiezoConfig.thermal_step_response`), bracketed on a log grid.
    """
    g, h, tm = float(per_decade), float(step_V), float(tau_min_s)
    if not np.isfinite(g) or g <= 0:
        raise ValueError(f"per_decade: expected a finite value > 0, got {per_decade}")
    if not np.isfinite(h) or h <= 0:
        raise ValueError(f"step_V: expected a finite value > 0, got {step_V}")
    if not np.isfinite(tm) or tm <= 0:
        raise ValueError(f"tau_min_s: expected a finite value > 0, got {tau_min_s}")
    return _activation_cached(g, h, tuple(float(x) for x in thresholds_V), float(linear_weight),
                              tuple(float(x) for x in weights), tm)
