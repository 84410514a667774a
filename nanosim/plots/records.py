"""Figures of a model identified from a user's record (``nanosim identify --data``); each returns a Figure.

Any number of inputs and outputs, any sample time; the signals are in the record's own units.
"""
from __future__ import annotations

import numpy as np

import identification as ident
from nanosim.plots.style import subplots

__all__ = ["figure_record_time_fit", "figure_record_bode", "figure_record_singular_values"]


def figure_record_time_fit(u, y, yhat, dt_s: float, fit_percent, output_names, input_names):
    """Validation record: inputs, and per output the measurement beside the model's simulation."""
    ny = y.shape[1]
    t = np.arange(len(y)) * dt_s
    fig, ax = subplots(ny + 1, 1, figsize=(8, 2.0 * (ny + 1)), sharex=True)
    for j in range(u.shape[1]):
        ax[0].plot(t, u[:, j], lw=0.5, label=input_names[j])
    ax[0].set_ylabel("input")
    ax[0].set_title("Validation record (not used for the estimation)")
    ax[0].legend(fontsize=7, ncol=min(6, u.shape[1]))
    for i in range(ny):
        ax[i + 1].plot(t, y[:, i], lw=0.6, label="measured")
        ax[i + 1].plot(t, yhat[:, i], "--", lw=0.6, label="model")
        ax[i + 1].set_ylabel(output_names[i])
        ax[i + 1].set_title(f"{output_names[i]}: fit {fit_percent[i]:.1f} %", fontsize=9)
    ax[1].legend(fontsize=7)
    ax[-1].set_xlabel("time (s)")
    return fig


def figure_record_bode(model, u, y, dt_s: float, output_names, input_names):
    """Magnitude of every channel: the identified model beside the non-parametric H1 estimate."""
    fs = 1.0 / dt_s
    nper = int(min(len(u) // 8, 4096))
    h1 = ident.h1_estimate(u, y, fs=fs, nperseg=max(nper, 64))
    f = h1.freq_hz[1:]
    H = ident.frequency_response(model, f)
    ny, nu = H.shape[1], H.shape[2]
    fig, ax = subplots(ny, nu, figsize=(3.4 * nu + 1, 2.4 * ny + 1), sharex=True, squeeze=False)
    for i in range(ny):
        for j in range(nu):
            a = ax[i, j]
            a.semilogx(f, 20 * np.log10(np.abs(h1.H[1:, i, j]) + 1e-30), ":", lw=0.8, label="H1 estimate")
            a.semilogx(f, 20 * np.log10(np.abs(H[:, i, j]) + 1e-30), lw=0.9, label="subspace model")
            a.grid(True, which="both", alpha=0.3)
            if i == 0:
                a.set_title(f"from {input_names[j]}", fontsize=9)
            if j == 0:
                a.set_ylabel(f"to {output_names[i]} (dB)")
            if i == ny - 1:
                a.set_xlabel("frequency (Hz)")
    ax[0, 0].legend(fontsize=7)
    fig.suptitle("Identified model against the H1 estimate of the record")
    return fig


def figure_record_singular_values(model):
    """Subspace singular values, for the order."""
    fig, ax = subplots(figsize=(7, 4))
    sv = model.singular_values[:40]
    ax.semilogy(np.arange(1, len(sv) + 1), sv, "o-", ms=3, label=f"order {model.order}")
    ax.axvline(model.order + 0.5, color="0.5", ls="--", lw=0.8)
    ax.set_xlabel("index")
    ax.set_ylabel("singular value (scaled data)")
    ax.set_title("Subspace singular values for order selection")
    ax.legend()
    ax.grid(True, which="both", alpha=0.3)
    return fig
