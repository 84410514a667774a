"""One figure style: matplotlib ``Figure`` objects without pyplot state (thread-safe, no backend switch).

Every plotting function in :mod:`nanosim.plots` returns a Figure and never
writes a file; :func:`nanosim.fileio.save_figure` writes it.
Frequency responses are ``(F, ny, nu)`` arrays (frequency first) everywhere.
"""
from __future__ import annotations

import numpy as np

__all__ = ["new_figure", "subplots", "magnitude_db", "bode_grid", "channel_names", "ACTUATOR_NAMES",
           "AXIS_NAMES"]

ACTUATOR_NAMES = ("A", "B", "C")
AXIS_NAMES = ("X", "Y", "Z")


def new_figure(nrows: int = 1, ncols: int = 1, size=(8, 5), **subplot_kw):
    """A constrained-layout Figure and its (nrows, ncols) axes array."""
    from matplotlib.figure import Figure

    fig = Figure(figsize=size, layout="constrained")
    axs = fig.subplots(nrows, ncols, squeeze=False, **subplot_kw)
    return fig, axs


def magnitude_db(x) -> np.ndarray:
    """20 log10 |x| with a floor at 1e-300 (no -inf)."""
    return 20.0 * np.log10(np.maximum(np.abs(x), 1e-300))


def _names(n, base):
    return base if n == len(base) else tuple(f"{i + 1}" for i in range(n))


def channel_names(n: int, base: tuple[str, ...]) -> tuple[str, ...]:
    """Channel labels: ``base`` (e.g. :data:`AXIS_NAMES`) if it has ``n`` names, else ``("1", ..., "n")``."""
    return _names(n, base)


def bode_grid(title, curves, freq_hz, ylabel="magnitude [dB]", in_names=None, out_names=None, ylim=None,
              vlines=()):
    """Ny x nu magnitude grid.

    Parameters
    ----------
    curves : list of (label, H, style)
        ``H`` complex, shape (F, ny, nu); ``style`` keyword arguments for ``semilogx``.
    freq_hz : (F,) array
    """
    ny, nu = curves[0][1].shape[1:]
    fig, axs = new_figure(ny, nu, size=(3.6 * nu + 1, 2.7 * ny + 0.8), sharex=True)
    in_names = in_names or _names(nu, ACTUATOR_NAMES)
    out_names = out_names or _names(ny, AXIS_NAMES)
    for i in range(ny):
        for j in range(nu):
            ax = axs[i, j]
            for label, H, st in curves:
                f = st.pop("freq_hz", freq_hz) if isinstance(st, dict) else freq_hz
                ax.semilogx(f, magnitude_db(H[:, i, j]), label=label, **st)
            for v in vlines:
                ax.axvline(v, color="gray", ls=":", lw=0.8)
            ax.set_title(f"{in_names[j]} -> {out_names[i]}", fontsize=10)
            ax.grid(True, which="both", alpha=0.3)
            if ylim is not None:
                ax.set_ylim(*ylim)
            if j == 0:
                ax.set_ylabel(ylabel)
            if i == ny - 1:
                ax.set_xlabel("frequency [Hz]")
    axs[0, 0].legend(fontsize=8, loc="best")
    fig.suptitle(title)
    return fig


def subplots(nrows: int = 1, ncols: int = 1, figsize=(8, 5), **subplot_kw):
    """Like ``pyplot.subplots`` (squeezed axes) but a pyplot-free constrained-layout Figure."""
    from matplotlib.figure import Figure

    fig = Figure(figsize=figsize, layout="constrained")
    return fig, fig.subplots(nrows, ncols, **subplot_kw)
