"""Identification figures (paper Figs. 4-7 and the subspace singular values); each returns a Figure."""
from __future__ import annotations

import numpy as np

import identification as ident
from nanosim import constants as C
from nanosim.plots.style import subplots

__all__ = ["figure_time_fit", "figure_bode_grid", "figure_singular_values", "figure_parametric_vs_h1"]

AXES, ACTS = C.AXES, C.ACTUATORS


def figure_time_fit(result, col: int = 0, row: int = 0):
    """Paper Fig. 4: input signal, measured output, model output, close-up."""
    u, y = result.validation[col]
    model = result.columns[col]
    yhat = ident.simulate(model, u[:, None], ident.estimate_x0(model, y, u[:, None]))
    t = np.arange(len(u)) / C.CONTROL_RATE_HZ
    fig, ax = subplots(4, 1, figsize=(8, 8.5), sharex=False)
    ax[0].plot(t, u, lw=0.6)
    ax[0].set_ylabel("command (V)")
    ax[0].set_title(f"(a) input to actuator {ACTS[col]}")
    ax[1].plot(t, y[:, row] * C.SENSOR_UM_PER_V, lw=0.6)
    ax[1].set_ylabel(f"{AXES[row]} (um)")
    ax[1].set_title("(b) measured output (simulated stage, validation record)")
    ax[2].plot(t, yhat[:, row] * C.SENSOR_UM_PER_V, lw=0.6, color="tab:orange")
    ax[2].set_ylabel(f"{AXES[row]} (um)")
    ax[2].set_title(f"(c) identified model output, fit {result.fit_percent[row, col]:.1f} %")
    sl = slice(int(1.9 * C.CONTROL_RATE_HZ), int(2.0 * C.CONTROL_RATE_HZ))
    ax[3].plot(t[sl], y[sl, row] * 5, label="measured")
    ax[3].plot(t[sl], yhat[sl, row] * 5, "--", label="model")
    ax[3].set_ylabel(f"{AXES[row]} (um)")
    ax[3].set_xlabel("time (s)")
    ax[3].set_title("(d) close-up")
    ax[3].legend()
    return fig


def figure_bode_grid(models, labels, title, fmin=1.0, fmax=1000.0, styles=None):
    """3x3 magnitude grid of discrete models (or (f, H) tuples), H of shape (F, ny, nu)."""
    f = np.logspace(np.log10(fmin), np.log10(fmax), 800)
    fig, ax = subplots(3, 3, figsize=(11, 8), sharex=True)
    for m, lab, sty in zip(models, labels, styles or [{}] * len(models)):
        H = ident.frequency_response(m, f) if not isinstance(m, tuple) else m[1]
        fr = f if not isinstance(m, tuple) else m[0]
        for i in range(3):
            for j in range(3):
                ax[i, j].semilogx(fr, 20 * np.log10(np.abs(H[:, i, j]) + 1e-20), label=lab, **sty)
    for i in range(3):
        ax[i, 0].set_ylabel(f"to {AXES[i]} (dB, sensor V/V)")
        for j in range(3):
            ax[i, j].grid(True, which="both", alpha=0.3)
            if i == 0:
                ax[i, j].set_title(f"from actuator {ACTS[j]}")
            if i == 2:
                ax[i, j].set_xlabel("frequency (Hz)")
    ax[0, 0].legend(fontsize=8)
    fig.suptitle(title)
    return fig


def figure_singular_values(result):
    """Subspace singular values per column, for order selection."""
    fig, ax = subplots(figsize=(7, 4))
    for j, c in enumerate(result.columns):
        sv = c.singular_values[:30]
        ax.semilogy(np.arange(1, len(sv) + 1), sv, "o-", ms=3, label=f"column {ACTS[j]} (order {c.order})")
    ax.axvline(13.5, color="0.5", ls="--", lw=0.8)
    ax.set_xlabel("index")
    ax.set_ylabel("singular value (scaled data)")
    ax.set_title("Subspace singular values for order selection")
    ax.legend()
    ax.grid(True, which="both", alpha=0.3)
    return fig


def figure_parametric_vs_h1(result, col: int = 0, row: int = 0):
    """Paper Fig. 6: parametric model vs non-parametric H1 estimate, with coherence."""
    u, y = result.estimation[col]
    h1 = ident.h1_estimate(u, y, fs=C.CONTROL_RATE_HZ, nperseg=2048)
    f = h1.freq_hz
    Hm = ident.frequency_response(result.columns[col], f)
    band = (f >= 2) & (f <= 1000)
    fig, ax = subplots(2, 1, figsize=(8, 6), sharex=True, gridspec_kw={"height_ratios": [3, 1]})
    ax[0].semilogx(f[band], 20 * np.log10(np.abs(h1.H[band, row, 0])), ":", label="H1 estimate (non-parametric)")
    ax[0].semilogx(f[band], 20 * np.log10(np.abs(Hm[band, row, 0])), label="subspace model")
    ax[0].set_ylabel("magnitude (dB, sensor V/V)")
    ax[0].set_title(f"Actuator {ACTS[col]} to {AXES[row]}: time-domain model vs frequency-domain estimate")
    ax[0].legend()
    ax[0].grid(True, which="both", alpha=0.3)
    ax[1].semilogx(f[band], h1.coherence[band, row, 0])
    ax[1].set_ylabel("coherence")
    ax[1].set_xlabel("frequency (Hz)")
    ax[1].set_ylim(0, 1.05)
    ax[1].grid(True, which="both", alpha=0.3)
    return fig
