"""(d) damping-tracking: positive position feedback on the identified modes plus integral tracking.

The damping-plus-tracking structure of Fleming & Leang (*Design, Modeling and Control of
Nanopositioning Systems*, Springer 2014, Ch. 8-9) in decoupled coordinates
(``v = G(1) u``)::

    u = G(1)^-1 [ diag(I_i) (r - y) + diag(PPF_i) y ]
    PPF_i = Gamma w_f^2 / (s^2 + 2 zeta_f w_f s + w_f^2) * s / (s + w_hp),  w_f = ratio * w_i
    I_i   = k_i / (s + w_l) * w_lp^2 / (s^2 + 1.4 w_lp s + w_lp^2)

``w_i`` is the identified mode with the largest peak in the decoupled axis ``i`` (X, Y:
the first XY pair, about 175 Hz; Z: the first Z mode, about 245 Hz). The PPF filter is
DC-blocked (``w_hp`` = 10 Hz) so that a constant reading does not leak into the command
(``Ky(z = 1) = 0``). The reference never passes through the damping loop.

Tuning rule: the largest integral gain ``k_i`` with a loop-at-a-time disk margin of at
least 0.5 for the whole loop (feedback operator ``I - PPF``, identified model with the
loop's delay, nominally stable), over a grid of PPF settings ``(zeta_f, ratio, Gamma)``
(each stable with a disk margin of at least 0.5 on its own) and tracking low-pass
corners ``f_lp``. The damping the chosen PPF gives is reported as the peak of
``sigma_max((I - Gd PPF)^-1 Gd G(1)^-1)`` between 100 and 600 Hz (``damped_peak_gain``, beside
``open_loop_peak_gain`` without the PPF loop; factors of the static gain, absolute, not dB; the band
is ``peak_band_hz``).
"""
from __future__ import annotations

import itertools

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
    lowpass2,
    max_gain,
    sensitivity_bandwidth_hz,
    series_siso,
    stack_2dof,
    static_ss,
    tf_to_ss,
)

__all__ = ["design_damping_tracking", "ppf_loop", "TUNING_RULE"]

TUNING_RULE = ("largest integral gain with a loop-at-a-time disk margin >= 0.5 for the whole loop, over a grid of "
               "PPF damping loops (decoupled coordinates, each stable with its own margin >= 0.5) and tracking "
               "low-pass corners")
PPF_ZETAS = (0.2, 0.3, 0.5)
PPF_RATIOS = (1.0, 1.2)
PPF_GAINS = (0.05, 0.1, 0.2, 0.3, 0.5)
LOWPASS_HZ = (150.0, 250.0)
HIGHPASS_HZ = 10.0
PEAK_BAND_HZ = (100.0, 600.0)     # where the damping is reported (open band)


def ppf_loop(G0_inv, modes_hz, gain: float, zeta: float, ratio: float, dt: float = DT_S,
             highpass_hz: float = HIGHPASS_HZ):
    """``G0_inv diag(PPF_i)`` (positive feedback ``u = Ky y``), one PPF per axis at ``ratio * modes_hz[i]``."""
    import control as ct
    filters = []
    for f1 in modes_hz:
        fo = ratio * f1
        w = 2 * np.pi * fo
        filters.append(series_siso(tf_to_ss([gain * w * w], [1, 2 * zeta * w, w * w], dt, prewarp_hz=fo),
                                   tf_to_ss([1, 0], [1, 2 * np.pi * highpass_hz], dt)))
    return ct.ss(ct.series(diag_ss(filters), static_ss(G0_inv, dt)))


def _tracking(G0_inv, ki_hz: float, lowpass_hz: float, dt: float):
    import control as ct
    C = series_siso(tf_to_ss([2 * np.pi * ki_hz], [1, 2 * np.pi * 0.01], dt), lowpass2(lowpass_hz, 0.7, dt))
    n = G0_inv.shape[0]
    return ct.ss(ct.series(diag_ss([C] * n), static_ss(G0_inv, dt)))


def design_damping_tracking(G, *, dt: float = DT_S, delay_samples: int = IDENTIFIED_DELAY_SAMPLES,
                            min_disk_margin: float = 0.5) -> BenchDesign:
    """PPF damping plus integral tracking, tuned by the rule of the module docstring.

    Parameters
    ----------
    G : control.StateSpace
        Identified plant (discrete at ``dt``, or continuous: Tustin), 3 x 3.
    dt : float
        Control period [s].
    delay_samples : int
        Loop delay [samples] of every check.
    min_disk_margin : float
        Loop-at-a-time disk margin of the damping loop alone and of the whole loop.

    Returns
    -------
    BenchDesign
        Two-degree-of-freedom controller, inputs ``[e; y]``.
    """
    Gd = as_discrete(G, dt)
    G0 = dc_gain_z(Gd)
    G0_inv = np.linalg.inv(G0)
    modes = distinct_modes_hz(Gd)
    if not modes:
        raise ValueError("G: no lightly damped mode to damp")
    f = analysis_grid_hz(dt, n=500, modes=modes)
    Gf = freqresp_z(Gd, f)
    fm = np.array(modes)
    P = freqresp_z(Gd, fm) @ G0_inv
    axis_modes = [float(fm[np.argmax(np.abs(P[:, i, i]))]) for i in range(G0.shape[0])]
    band = (f > PEAK_BAND_HZ[0]) & (f < PEAK_BAND_HZ[1])
    Gdel = Gf * np.exp(-2j * np.pi * f * delay_samples * dt)[:, None, None]
    best = None
    for z, ratio, g in itertools.product(PPF_ZETAS, PPF_RATIOS, PPF_GAINS):
        Ky = ppf_loop(G0_inv, axis_modes, g, z, ratio, dt)
        if closed_loop_spectral_radius(Gd, _zero_like(Ky), Ky, delay_samples) >= 1.0:
            continue
        Kyf = freqresp_z(Ky, f)
        if loop_at_a_time_alpha(Gf, -Kyf, delay_samples, dt, f) < min_disk_margin:
            continue
        for flp in LOWPASS_HZ:
            K1f = freqresp_z(_tracking(G0_inv, 1.0, flp, dt), f)

            def ok(ki, K1f=K1f, flp=flp, Ky=Ky, Kyf=Kyf):
                if loop_at_a_time_alpha(Gf, ki * K1f - Kyf, delay_samples, dt, f) < min_disk_margin:
                    return False
                return closed_loop_spectral_radius(Gd, *_stacked(_tracking(G0_inv, ki, flp, dt), Ky),
                                                   delay_samples) < 1.0
            try:
                ki = max_gain(ok, 0.1, 300.0, rel_tol=0.02)
            except ValueError:
                continue
            if best is None or ki > best[0]:
                best = (ki, flp, z, ratio, g)
    if best is None:
        raise ValueError(f"G: no PPF damping loop and integral gain on the grid keep a disk margin of "
                         f"{min_disk_margin}")
    ki, flp, z, ratio, g = best
    Ky = ppf_loop(G0_inv, axis_modes, g, z, ratio, dt)
    Kyf = freqresp_z(Ky, f)
    Gdamped = np.linalg.solve(np.eye(G0.shape[0]) - Gdel @ Kyf, Gdel) @ G0_inv
    peak = float(np.linalg.norm(Gdamped[band], 2, axis=(1, 2)).max())
    K2 = stack_2dof(_tracking(G0_inv, ki, flp, dt), Ky)
    Ke, Kyy = _stacked(_tracking(G0_inv, ki, flp, dt), Ky)
    r = loop_response(Gf, f, Ke, Kyy, delay_samples=delay_samples, dt=dt)
    params = {"ppf_axis_modes_hz": axis_modes, "ppf_gain": g, "ppf_zeta": z, "ppf_frequency_ratio": ratio,
              "ppf_highpass_hz": HIGHPASS_HZ, "peak_band_hz": list(PEAK_BAND_HZ), "damped_peak_gain": peak,
              "open_loop_peak_gain": float(np.linalg.norm((Gdel @ G0_inv)[band], 2, axis=(1, 2)).max()),
              "integral_gain_hz": ki, "tracking_lowpass_hz": flp,
              "predicted_bandwidth_S_hz": sensitivity_bandwidth_hz(r),
              "predicted_disk_margin": disk_margin_summary(r), "loop_delay_samples": delay_samples}
    return BenchDesign("damping-tracking", K2, G0.shape[0], TUNING_RULE, params)


def _zero_like(Ky):
    import control as ct
    return ct.ss(Ky.A, np.zeros_like(np.asarray(Ky.B)), Ky.C, np.zeros_like(np.asarray(Ky.D)), Ky.dt)


def _stacked(Ke, Ky):
    """``(Ke, Ky)`` on the shared state vector of the stacked controller ``[Ke, Ky]``."""
    from nanosim.design.architectures.common import split_2dof
    K2 = stack_2dof(Ke, Ky)
    return split_2dof(K2, Ke.ninputs)

