"""(c) pi-notch: static decoupling, per-axis PI with notch filters at the identified modes.

The industry baseline (Fleming & Leang, *Design, Modeling and Control of
Nanopositioning Systems*, Springer 2014, Ch. 7; Devasia, Eleftheriou & Moheimani,
IEEE TCST 15(5), 2007)::

    K(z) = G(1)^-1 diag(C, C, C),   C = k (s + wz)/(s + wl) * prod_m N_m(s)   (Tustin, 4 kHz)

* ``G(1)^-1``: inverse of the identified static gain (decoupling);
* ``N_m = (s^2 + w_m^2)/(s^2 + 2 zeta_n w_m s + w_m^2)``: one notch on every lightly
  damped identified mode ``w_m`` (prewarped, so it sits on the mode);
* PI ``k (s + wz)/(s + wl)`` (the integrator leaks below 0.01 Hz).

Tuning rule (MIGO, Astrom & Hagglund, *Advanced PID Control*, 2006: the largest
integral gain under a robustness constraint): over notch widths ``zeta_n`` and PI
corners ``f_z`` on a grid, the largest ``k`` (bisection) with a loop-at-a-time disk
margin of at least 0.5 at every plant input and output (identified model = the loop
as run, nominally stable); the pair with the largest integral gain
``k f_z`` [Hz] wins.
"""
from __future__ import annotations

import numpy as np

from nanosim.design.architectures.common import (
    DT_S,
    IDENTIFIED_DELAY_SAMPLES,
    BenchDesign,
    analysis_grid_hz,
    as_discrete,
    closed_loop_spectral_radius,
    dc_gain_z,
    diag_ss,
    disk_margin_summary,
    distinct_modes_hz,
    freqresp_z,
    loop_at_a_time_alpha,
    loop_response,
    max_gain,
    notch,
    pi_leaky,
    sensitivity_bandwidth_hz,
    series_siso,
    static_ss,
)

__all__ = ["design_pi_notch", "pi_notch_controller", "TUNING_RULE"]

TUNING_RULE = ("largest integral gain k*f_z over notch widths and PI corners with a loop-at-a-time disk margin "
               ">= 0.5 at every plant input and output (the identified model, the loop as run)")
NOTCH_ZETAS = (0.3, 0.5, 0.7)
PI_ZERO_HZ = (10.0, 20.0, 40.0, 70.0, 120.0, 200.0)


def pi_notch_controller(G0_inv, gain: float, pi_zero_hz: float, notch_hz, notch_zeta: float, dt: float = DT_S):
    """``G0_inv diag(C, C, C)`` with ``C = gain (s + wz)/(s + wl) prod N_m`` (discrete, ``dt``)."""
    import control as ct
    C = series_siso(pi_leaky(gain, pi_zero_hz, dt), *(notch(fm, notch_zeta, 0.0, dt) for fm in notch_hz))
    n = G0_inv.shape[0]
    return ct.ss(ct.series(diag_ss([C] * n), static_ss(G0_inv, dt)))


def design_pi_notch(G, *, dt: float = DT_S, delay_samples: int = IDENTIFIED_DELAY_SAMPLES, min_disk_margin: float = 0.5,
                    notch_zetas=NOTCH_ZETAS, pi_zeros_hz=PI_ZERO_HZ) -> BenchDesign:
    """PI with notches, tuned by the rule of the module docstring.

    Parameters
    ----------
    G : control.StateSpace
        Identified plant (discrete at ``dt``, or continuous: mapped by Tustin),
        controller V -> sensor V, square.
    dt : float
        Control period [s].
    delay_samples : int
        Loop delay the margins are checked with [samples].
    min_disk_margin : float
        Loop-at-a-time symmetric disk margin ``alpha`` required at every input and output.
    notch_zetas, pi_zeros_hz : sequences
        The tuning grid: notch pole damping ratios and PI corners [Hz].

    Returns
    -------
    BenchDesign
        Error-only controller (``n_error = 3``).
    """
    if not 0 < min_disk_margin < 2:
        raise ValueError(f"min_disk_margin: expected a disk margin alpha in (0, 2), got {min_disk_margin!r}")
    Gd = as_discrete(G, dt)
    G0_inv = np.linalg.inv(dc_gain_z(Gd))
    modes = distinct_modes_hz(Gd)
    f = analysis_grid_hz(dt, n=500, modes=modes)
    Gf = freqresp_z(Gd, f)
    best = None
    for zn in notch_zetas:
        for fz in pi_zeros_hz:
            # K is linear in k: one response at k = 1, then the margins are cheap in the bisection
            K1f = freqresp_z(pi_notch_controller(G0_inv, 1.0, fz, modes, zn, dt), f)
            def ok(k, K1f=K1f, zn=zn, fz=fz):
                if loop_at_a_time_alpha(Gf, k * K1f, delay_samples, dt, f) < min_disk_margin:
                    return False
                K = pi_notch_controller(G0_inv, k, fz, modes, zn, dt)
                return closed_loop_spectral_radius(Gd, K, delay_samples=delay_samples) < 1.0
            try:
                k = max_gain(ok, 1e-3, 20.0)
            except ValueError:
                continue
            if best is None or k * fz > best[0] * best[1]:
                best = (k, fz, zn)
    if best is None:
        raise ValueError(f"G: no PI-notch gain on the tuning grid reaches a disk margin of {min_disk_margin}")
    k, fz, zn = best
    K = pi_notch_controller(G0_inv, k, fz, modes, zn, dt)
    r = loop_response(Gf, f, K, delay_samples=delay_samples, dt=dt)
    dm = disk_margin_summary(r)
    params = {"proportional_gain": k, "pi_zero_hz": fz, "integral_gain_hz": k * fz, "notch_hz": modes,
              "notch_zeta": zn, "decoupling": "inverse identified static gain G(z=1)^-1",
              "predicted_bandwidth_S_hz": sensitivity_bandwidth_hz(r), "predicted_disk_margin": dm,
              "loop_delay_samples": delay_samples}
    return BenchDesign("pi-notch", K, G0_inv.shape[0], TUNING_RULE, params)
