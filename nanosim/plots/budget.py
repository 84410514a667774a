"""Noise-budget figures: stacked PSDs and cumulative amplitude spectra per source (Fleming, Mechatronics 2014)."""
from __future__ import annotations

import numpy as np

from nanosim.plots.style import subplots

__all__ = ["figure_budget_psd", "figure_budget_cas"]


def _cas(f, s):
    inc = 0.5 * (s[1:] + s[:-1]) * np.diff(f)
    return np.sqrt(np.concatenate([[0.0], np.cumsum(inc)]))


def figure_budget_psd(freq_hz, psd: dict, title: str, f_min_hz: float = 0.1):
    """Stacked PSDs [nm^2/Hz]: each band is one source, the top edge the total (log-log)."""
    f = np.asarray(freq_hz)
    keep = f >= f_min_hz
    fig, ax = subplots(figsize=(8, 5))
    base = np.zeros(keep.sum())
    floor = 1e-12
    for name, s in psd.items():
        top = base + np.asarray(s)[keep]
        ax.fill_between(f[keep], np.maximum(base, floor), np.maximum(top, floor), alpha=0.6, lw=0.3, label=name)
        base = top
    ax.loglog(f[keep], np.maximum(base, floor), "k", lw=0.8, label="total")
    pos = base[base > 0]
    if pos.size:
        ax.set_ylim(max(pos.min(), pos.max() * 1e-9), pos.max() * 3)
    ax.set_xlabel("frequency (Hz)")
    ax.set_ylabel("PSD (nm$^2$/Hz), stacked")
    ax.set_title(title)
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=8)
    return fig


def figure_budget_cas(freq_hz, psd: dict, sigma: dict, title: str, simulated: dict | None = None,
                      f_min_hz: float = 0.1):
    """Cumulative amplitude spectrum [nm] per source and of the total; the top of each curve is its sigma.

    ``simulated``: the re-simulated sigma per source (and ``total``), drawn as markers at the right edge.
    """
    f = np.asarray(freq_hz)
    fig, ax = subplots(figsize=(8, 5))
    total = np.zeros_like(f)
    for k, (name, s) in enumerate(psd.items()):
        s = np.asarray(s)
        total = total + s
        line, = ax.semilogx(f, _cas(f, s), lw=1.0, label=f"{name}: {sigma[name]:.3g} nm")
        if simulated and name in simulated:
            ax.plot(f[-1] * 1.15, simulated[name], "o", color=line.get_color(), ms=5, clip_on=False)
    ax.semilogx(f, _cas(f, total), "k", lw=1.6, label=f"total: {sigma['total']:.3g} nm")
    if simulated and "total" in simulated:
        ax.plot(f[-1] * 1.15, simulated["total"], "ks", ms=6, clip_on=False, label="simulated (markers)")
    ax.set_xlim(f_min_hz, f[-1] * 1.3)
    ax.set_xlabel("frequency (Hz)")
    ax.set_ylabel("cumulative amplitude (nm rms)")
    ax.set_title(title)
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=8)
    return fig
