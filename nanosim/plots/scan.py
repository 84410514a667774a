"""Figures of a closed-loop scan: the path, the image beside the truth, the error maps, the line-rate sweep.

Each figure has a ``*_response`` function that computes what it shows from plain
arrays (testable, no matplotlib) and a ``*_plot`` function that draws it and
returns a Figure (nothing is written).
"""
from __future__ import annotations

import numpy as np

from nanosim.plots.style import new_figure

__all__ = ["zoom_window", "scan_path_response", "scan_path_plot", "scan_image_plot", "scan_error_response",
           "scan_error_plot", "line_rate_plot"]


def zoom_window(size_um: float) -> tuple:
    """The path figure's zoom: ``(x0, x1, y0, y1)`` um, a tenth of the field wide at ``(0.85, 0.5) size_um``."""
    w = size_um / 10
    return (0.85 * size_um - w / 2, 0.85 * size_um + w / 2, 0.5 * size_um - w / 2, 0.5 * size_um + w / 2)


def scan_path_response(ref_um: np.ndarray, table_um: np.ndarray, imaged: np.ndarray, size_um: float,
                       max_points: int = 20000):
    """The commanded and the true XY path of the imaged samples: decimated to at most ``max_points``, and
    whole inside :func:`zoom_window` (NaN elsewhere, so that the zoom draws no chords).

    Returns
    -------
    ref_xy, true_xy, ref_zoom, true_zoom : ndarray (M, 2), um
    """
    sel = np.flatnonzero(np.asarray(imaged, bool))
    ref, true = np.asarray(ref_um)[sel, :2], np.asarray(table_um)[sel, :2]
    step = max(1, int(np.ceil(len(sel) / max_points)))
    x0, x1, y0, y1 = zoom_window(size_um)
    pad = (x1 - x0) / 2
    def windowed(xy):
        out = xy.copy()
        out[~((xy[:, 0] > x0 - pad) & (xy[:, 0] < x1 + pad) & (xy[:, 1] > y0 - pad) & (xy[:, 1] < y1 + pad))] = np.nan
        return out

    return ref[::step], true[::step], windowed(ref), windowed(true)


def scan_path_plot(paths, size_um: float):
    """``paths``: list of ``(label, ref_xy, true_xy, ref_zoom, true_zoom)``; per pattern the whole path
    (the field's square dashed, the zoom's window solid) and below it the zoom.
    """
    n = len(paths)
    fig, ax = new_figure(2, n, size=(3.6 * n, 7.4))
    x0, x1, y0, y1 = zoom_window(size_um)
    for j, (label, ref, true, rz, tz) in enumerate(paths):
        a, z = ax[0, j], ax[1, j]
        a.plot(ref[:, 0], ref[:, 1], lw=0.3, color="0.6", label="command")
        a.plot(true[:, 0], true[:, 1], lw=0.3, color="tab:red", label="table (true)")
        a.plot([0, size_um, size_um, 0, 0], [0, 0, size_um, size_um, 0], "k--", lw=0.8)
        a.plot([x0, x1, x1, x0, x0], [y0, y0, y1, y1, y0], "k-", lw=1.0)
        a.set_aspect("equal")
        a.set_title(label, fontsize=9)
        z.plot(rz[:, 0], rz[:, 1], lw=0.8, color="0.5", label="command")
        z.plot(tz[:, 0], tz[:, 1], lw=0.8, color="tab:red", label="table (true)")
        z.set_xlim(x0, x1)
        z.set_ylim(y0, y1)
        z.set_aspect("equal")
        z.set_title("zoom (solid square above)", fontsize=8)
        z.set_xlabel("X (um)")
    ax[0, 0].set_ylabel("Y (um)")
    ax[1, 0].set_ylabel("Y (um)")
    ax[1, 0].legend(fontsize=7, loc="upper right")
    return fig


def scan_image_plot(images, truth_nm: np.ndarray, size_um: float):
    """The truth beside each pattern's image: ``images`` list of ``(label, image_nm, subtitle)``."""
    n = len(images) + 1
    fig, ax = new_figure(1, n, size=(3.4 * n, 3.6))
    ext = (0, size_um, 0, size_um)
    lo, hi = np.nanmin(truth_nm), np.nanmax(truth_nm)
    im = ax[0, 0].imshow(truth_nm, origin="lower", extent=ext, vmin=lo, vmax=hi, cmap="afmhot")
    ax[0, 0].set_title("sample (truth)", fontsize=9)
    for a, (label, img, sub) in zip(ax[0, 1:], images):
        a.imshow(img, origin="lower", extent=ext, vmin=lo, vmax=hi, cmap="afmhot")
        a.set_title(f"{label}\n{sub}", fontsize=9)
    for a in ax[0]:
        a.set_xlabel("X (um)")
    ax[0, 0].set_ylabel("Y (um)")
    fig.colorbar(im, ax=ax[0, -1], label="height (nm)", shrink=0.8)
    return fig


def scan_error_response(error_nm: np.ndarray, distortion_um: np.ndarray, mask: np.ndarray):
    """The image error and the distortion magnitude (nm) with the uncovered pixels blank (NaN)."""
    err = np.where(mask, error_nm, np.nan)
    dist = np.where(mask, 1e3 * np.hypot(distortion_um[..., 0], distortion_um[..., 1]), np.nan)
    return err, dist


def scan_error_plot(rows, size_um: float):
    """``rows``: list of ``(label, error_nm, distortion_nm)``; per pattern the image error and the distortion."""
    n = len(rows)
    fig, ax = new_figure(2, n, size=(3.5 * n, 6.6))
    ext = (0, size_um, 0, size_um)
    for j, (label, err, dist) in enumerate(rows):
        lim = np.nanpercentile(np.abs(err), 99.5) if np.isfinite(err).any() else 1.0
        im = ax[0, j].imshow(err, origin="lower", extent=ext, cmap="RdBu_r", vmin=-lim, vmax=lim)
        ax[0, j].set_title(f"{label}\nimage - truth (nm)", fontsize=9)
        fig.colorbar(im, ax=ax[0, j], shrink=0.75)
        im = ax[1, j].imshow(dist, origin="lower", extent=ext, cmap="viridis")
        ax[1, j].set_title("distortion |table - placed| (nm)", fontsize=9)
        fig.colorbar(im, ax=ax[1, j], shrink=0.75)
        ax[1, j].set_xlabel("X (um)")
    ax[0, 0].set_ylabel("Y (um)")
    ax[1, 0].set_ylabel("Y (um)")
    return fig


def line_rate_plot(curves, limit_fraction: float, plant: str):
    """Image error (fraction of the height range) against line rate: ``curves`` list of
    ``(label, rates_hz, fraction, rate_at_limit_hz)``.
    """
    fig, ax = new_figure(1, 1, size=(6.5, 4.2))
    a = ax[0, 0]
    for label, r, e, lim_hz in curves:
        line, = a.loglog(r, 100 * np.asarray(e), "o-", label=f"{label}: {lim_hz:.3g} Hz at the limit"
                         if np.isfinite(lim_hz) else label)
        if np.isfinite(lim_hz):
            a.axvline(lim_hz, color=line.get_color(), lw=0.7, ls=":")
    a.axhline(100 * limit_fraction, color="k", ls="--", lw=0.8, label=f"limit {100 * limit_fraction:g} %")
    a.set_xlabel("line rate (Hz)")
    a.set_ylabel("image error rms (% of height range)")
    a.set_title(f"image error vs line rate ({plant})", fontsize=10)
    a.grid(alpha=0.3, which="both")
    a.legend(fontsize=7)
    return fig
