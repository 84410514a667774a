"""Figures of the Section 5 experiments (paper Figs. 14-20); each returns a Figure and writes nothing."""
from __future__ import annotations

import numpy as np

from nanosim import constants as C
from nanosim.plots.style import subplots

__all__ = ["fig_hysteresis", "fig_creep", "fig_resolution", "fig_small_steps", "fig_bandwidth", "fig_tracking",
           "fig_contouring"]


def fig_hysteresis(r):
    """Paper Fig. 14: open-loop hysteresis loop and closed-loop residual."""
    fig, ax = subplots(1, 2, figsize=(11, 4.4))
    for i, ax_name in enumerate("XYZ"):
        ax[0].plot(r.open_v, r.open_y_um[:, i], label=ax_name)
    ax[0].set_xlabel("actuator A command (controller V)")
    ax[0].set_ylabel("displacement (um)")
    ax[0].set_title(f"(a) open loop: output hysteresis {r.open_loop_percent:.1f} % of X travel")
    ax[0].legend()
    ax[0].grid(alpha=0.3)
    ref, y = r.closed.ref_um[:, 0], r.closed.y_um[:, 0]
    ax[1].plot(ref, (y - ref) * 1e3, lw=0.6, label="continuous triangle (tracking error)")
    ax[1].plot(r.closed_levels_um, (r.closed_up_um - r.closed_levels_um) * 1e3, "o-", label="settled, going up")
    ax[1].plot(r.closed_levels_um, (r.closed_down_um - r.closed_levels_um) * 1e3, "s--", label="settled, going down")
    ax[1].set_xlabel("X reference (um)")
    ax[1].set_ylabel("X output - reference (nm)")
    ax[1].set_title(f"(b) closed loop: settled hysteresis {r.closed_loop_nm:.1f} nm, "
                    f"ramp lag {r.closed_ramp_lag_nm:.0f} nm")
    ax[1].legend(fontsize=8, loc="center", bbox_to_anchor=(0.5, 0.7))   # in the empty band above the settled points
    ax[1].grid(alpha=0.3)
    return fig


def fig_creep(r):
    """Paper Fig. 15: creep in open and closed loop."""
    fig, ax = subplots(1, 2, figsize=(11, 4.2), sharey=False)
    for a, (y, title, d) in zip(ax, ((r.open_y_um, "open loop (inverse static gain)", r.open_drift_nm),
                                     (r.closed_y_um, "closed loop (H-infinity)", r.closed_drift_nm))):
        k0 = int(0.5 * C.CONTROL_RATE_HZ)
        for i, n in enumerate("XYZ"):
            a.plot(r.t_s, (y[:, i] - y[k0:k0 + 800, i].mean()) * 1e3, lw=0.6,
                   label=f"{n}: drift {d[i]:+.1f} nm")
        a.set_xlabel("time since reaching the origin (s)")
        a.set_ylabel("position - position at 0.5 s (nm)")
        a.set_title(f"{title}, hold {r.hold_s:.0f} s")
        a.legend(fontsize=8)
        a.grid(alpha=0.3)
    return fig


def _cumulative_sigma_nm(f, psd):
    """The square root of the PSD's integral from 0 to each frequency (trapezoids), nm."""
    df = np.diff(f)
    return np.sqrt(np.concatenate([[0.0], np.cumsum(0.5 * (psd[1:] + psd[:-1]) * df)]))


def fig_resolution(r):
    """Paper Fig. 16: readings at rest and their PSD, open and closed loop; the noise budget per source.

    With a noise budget a third row shows each source's PSD (nm^2/Hz, one source on at a
    time) over the total's, and the total's cumulative sigma (right axis, nm).
    """
    spectra = getattr(r, "budget_psd", None) or {}
    rows = 3 if spectra else 2
    fig, ax = subplots(rows, 2, figsize=(11, 3.5 * rows))
    t = np.arange(len(r.open_y_nm)) / C.CONTROL_RATE_HZ
    for j, (y, lab) in enumerate(((r.open_y_nm, "open_loop"), (r.closed_y_nm, "closed_loop"))):
        ax[0, j].plot(t, y - y.mean(), lw=0.4)
        s = r.sigma_nm[lab]
        ax[0, j].set_title(f"({'ab'[j]}) {lab.replace('_', ' ')}: sigma {s:.2f} nm, "
                           f"95.45 % {r.band2_nm[lab]:.1f} nm, 99.73 % {r.band3_nm[lab]:.1f} nm", fontsize=9)
        for k in (1, 2, 3):
            ax[0, j].axhline(k * s, color="0.5", lw=0.6, ls=":")
            ax[0, j].axhline(-k * s, color="0.5", lw=0.6, ls=":")
        ax[0, j].set_xlabel("time (s)")
        ax[0, j].set_ylabel("X probe (nm)")
        psd = r.psd_open if j == 0 else r.psd_closed
        ax[1, j].loglog(r.psd_freq_hz[1:], psd[1:])
        ax[1, j].set_xlabel("frequency (Hz)")
        ax[1, j].set_ylabel("PSD (nm^2/Hz)")
        ax[1, j].set_title(f"({'cd'[j]}) output PSD, no input")
        ax[1, j].grid(True, which="both", alpha=0.3)
        if not spectra:
            continue
        a = ax[2, j]
        rows_b = (r.budget or {}).get("sources", {})
        key = "open_loop_nm" if j == 0 else "sensor_nm"
        for name, (f, po, pc) in spectra.items():
            p = po if j == 0 else pc
            sig = rows_b.get(name, {}).get(key)
            if p is None or not np.any(p[1:] > 0) or (sig is not None and sig < 1e-6):
                continue                                  # a source that does not move this record
            a.loglog(f[1:], p[1:], lw=0.8, label=f"{name}: {sig:.2f} nm" if sig is not None else name)
        a.loglog(r.psd_freq_hz[1:], psd[1:], color="k", lw=1.0, label="all sources")
        a.set_ylim(bottom=psd[1:].min() * 1e-3)
        a.set_xlabel("frequency (Hz)")
        a.set_ylabel("PSD (nm^2/Hz)")
        a.set_title(f"({'ef'[j]}) {lab.replace('_', ' ')} per source (one on at a time)", fontsize=9)
        a.grid(True, which="both", alpha=0.3)
        a.legend(fontsize=6, loc="lower left")
        c = a.twinx()
        c.semilogx(r.psd_freq_hz[1:], _cumulative_sigma_nm(r.psd_freq_hz, psd)[1:], color="k", ls="--", lw=0.8)
        c.set_ylabel("cumulative sigma, all sources (nm, dashed)")
    return fig


def fig_small_steps(r):
    """Paper Fig. 17: the 10 nm staircase."""
    fig, ax = subplots(figsize=(8, 4))
    ax.plot(r.trace.t_s, r.trace.ref_um[:, 0] * 1e3, label="reference")
    ax.plot(r.trace.t_s, r.trace.y_um[:, 0] * 1e3, lw=0.6, label="X probe")
    ax.set_xlabel("time (s)")
    ax.set_ylabel("X (nm)")
    txt = ", ".join(f"{m:.1f}" for m in r.plateau_mean_nm)
    ax.set_title(f"10 nm steps, plateau means (nm): {txt}", fontsize=9)
    ax.legend()
    ax.grid(alpha=0.3)
    return fig


def fig_bandwidth(r, predicted=None):
    """Paper Fig. 18: measured sigma(S), sigma(T) (with the prediction) and the 2 um step.

    The measured S curve's legend names ``r.sensitivity_method.formula`` (``I - T`` or the feedback loop's
    ``(I + G K_fb)^-1``, :class:`nanosim.experiments.bandwidth.SensitivityMethod`).
    """
    fig, ax = subplots(1, 3, figsize=(14, 4.2))
    method = getattr(r, "sensitivity_method", None)      # a SensitivityMethod; absent: I - T
    formula = getattr(method, "formula", "I - T")
    ax[0].semilogx(r.freq_hz, 20 * np.log10(r.sigma_S), label=f"measured on the stage: {formula}")
    ax[1].semilogx(r.freq_hz, 20 * np.log10(r.sigma_T), label="measured on the stage (H1)")
    if predicted is not None:
        f, sS, sT = predicted
        ax[0].semilogx(f, 20 * np.log10(sS), "--", label="predicted (linear twin + K)")
        ax[1].semilogx(f, 20 * np.log10(sT), "--", label="predicted (linear twin + K)")
    for a, title, b in ((ax[0], "(a) largest singular value of S", r.bandwidth_S_hz),
                        (ax[1], "(b) largest singular value of T", r.bandwidth_T_hz)):
        a.axhline(-3.01, color="0.5", ls=":", lw=0.8)
        a.axvline(b, color="tab:red", lw=0.8)
        a.set_title(f"{title}: -3 dB at {b:.1f} Hz", fontsize=10)
        a.set_xlabel("frequency (Hz)")
        a.set_ylabel("dB")
        a.grid(True, which="both", alpha=0.3)
        a.legend(fontsize=8)
    k0 = int(0.01 * C.CONTROL_RATE_HZ)
    t = (r.step.t_s - r.step.t_s[k0]) * 1e3
    cases = getattr(r, "steps", ()) or ()
    if cases:
        for c in cases:
            tc = (c.trace.t_s - c.trace.t_s[k0]) * 1e3
            ax[2].plot(tc, c.sign * (c.trace.y_um[:, c.axis] - c.baseline_um) / abs(c.trace.ref_um[-1, c.axis]),
                       lw=0.8, label=f"{c.name}: {c.settling_ms:.1f} ms, {c.overshoot_percent:.1f} %")
        ax[2].plot(t, np.where(t >= 0, 1.0, 0.0), color="k", lw=0.8, ls="--", label="reference")
        for lim in (0.98, 1.02):
            ax[2].axhline(lim, color="0.5", ls=":", lw=0.8)
        ax[2].set_ylabel("step response / step")
    else:
        ax[2].plot(t, r.step.ref_um[:, 0], label="reference")
        ax[2].plot(t, r.step.y_um[:, 0], label="X probe")
        final = r.step.ref_um[-1, 0]
        y0 = r.step.y_um[:k0, 0].mean() if k0 else 0.0
        for lim in (y0 + 0.98 * (final - y0), y0 + 1.02 * (final - y0)):
            ax[2].axhline(lim, color="0.5", ls=":", lw=0.8)
        ax[2].set_ylabel("X (um)")
    slowest = max([c.settling_ms for c in cases] or [r.settling_ms])
    # the settling happens in the first tens of ms; the whole record is 300 ms
    ax[2].set_xlim(-5.0, min(t[-1], max(40.0, 2 * slowest if np.isfinite(slowest) else t[-1])))
    ax[2].set_xlabel("time (ms); dotted: the 2 % settling band")
    ax[2].set_title(f"(c) 2 um steps; +X after 1 s: rise {r.rise_ms:.1f} ms, settle {r.settling_ms:.1f} ms, "
                    f"overshoot {r.overshoot_percent:.1f} %", fontsize=9)
    ax[2].legend(fontsize=6)
    ax[2].grid(alpha=0.3)
    return fig


def fig_tracking(cases):
    """Paper Fig. 19: tracking of triangles and sines."""
    freqs = sorted({c.freq_hz for c in cases})
    fig, ax = subplots(2, len(freqs), figsize=(3.2 * len(freqs), 6))
    for c in cases:
        i = 0 if c.waveform == "triangle" else 1
        j = freqs.index(c.freq_hz)
        a = ax[i, j]
        a.plot(c.trace.t_s * 1e3, c.trace.ref_um[:, 0], ":", label="reference")
        a.plot(c.trace.t_s * 1e3, c.trace.y_um[:, 0], label="output")
        a.set_title(f"{c.waveform} {c.freq_hz:g} Hz\nrms err {c.rms_error_nm:.0f} nm, lag {c.phase_lag_deg:.0f} deg",
                     fontsize=9)
        a.set_xlabel("time (ms)")
        if j == 0:
            a.set_ylabel("X (um)")
        a.grid(alpha=0.3)
    ax[0, 0].legend(fontsize=8)
    return fig


def fig_contouring(cases):
    """Paper Fig. 20: contour error vs speed and the following errors at the fastest speed."""
    fig, ax = subplots(1, 2, figsize=(11, 4.2))
    v = [c.speed_um_s for c in cases]
    ax[0].loglog(v, [c.mean_error_nm for c in cases], "o-", label="mean contour error")
    ax[0].loglog(v, [c.max_error_nm for c in cases], "s--", label="max contour error")
    ax[0].set_xlabel("speed along the 45 degree line (um/s)")
    ax[0].set_ylabel("contour error (nm)")
    ax[0].set_title("(a) contour error vs speed")
    ax[0].legend()
    ax[0].grid(True, which="both", alpha=0.3)
    fast = max(cases, key=lambda c: c.speed_um_s)
    e = fast.trace.error_um
    ax[1].plot(fast.trace.t_s * 1e3, e[:, 0], label="X tracking error")
    ax[1].plot(fast.trace.t_s * 1e3, e[:, 1], "--", label="Y tracking error")
    contour_um = (fast.trace.y_um[:, 0] - fast.trace.y_um[:, 1]) / np.sqrt(2)
    ax[1].plot(fast.trace.t_s * 1e3, contour_um, label="contour error")
    ax[1].set_xlabel("time (ms)")
    ax[1].set_ylabel("error (um)")
    ax[1].set_title(f"(b) following errors at {fast.speed_um_s:g} um/s", fontsize=10)
    ax[1].legend()
    ax[1].grid(alpha=0.3)
    return fig
