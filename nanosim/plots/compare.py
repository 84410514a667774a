"""Overlaid figures of ``nanosim compare``: loop singular values, 2 um step, contour error, closed-loop PSD.

Each function takes one entry per controller and returns a Figure (never writes);
:func:`compare_figures` maps the registered file names
(:data:`nanosim.pipeline.artifacts.COMPARE_FIGURES`) to their figures.
"""
from __future__ import annotations

import numpy as np

from nanosim import artifact_names as N
from nanosim.paper import PAPER, PAPER_STEP_UM
from nanosim.plots.style import new_figure

__all__ = ["fig_compare_loops", "fig_compare_step", "fig_compare_contour", "fig_compare_psd", "compare_figures"]


def _color(i: int):
    import matplotlib

    return matplotlib.colormaps["tab10"](i % 10)


def fig_compare_loops(responses: dict):
    """``sigma_max(S_o)`` and ``sigma_max(T_o)`` per controller.

    Parameters
    ----------
    responses : dict of str to LoopResponse
        :func:`nanosim.design.robustness.loop_transfer_response` results (identified model, delay).
    """
    fig, axs = new_figure(1, 2, size=(12, 4.5))
    for i, (name, r) in enumerate(responses.items()):
        f = r.freq_hz
        for ax, key in zip(axs[0], ("S_o", "T_o")):
            ax.semilogx(f, 20 * np.log10(np.maximum(r.sigma_max(key), 1e-12)), color=_color(i), label=name)
    for ax, title in zip(axs[0], ("sigma_max(S_o), output sensitivity", "sigma_max(T_o)")):
        ax.axhline(-3.01, color="0.5", ls=":", lw=0.8)
        ax.set(xlabel="frequency [Hz]", ylabel="[dB]", title=title, xlim=(1, 2000))
        ax.grid(True, which="both", alpha=0.3)
    axs[0, 0].set_ylim(-60, 15)
    axs[0, 1].set_ylim(-60, 15)
    axs[0, 0].legend(fontsize=8)
    fig.suptitle("Feedback loops on the identified model (the loop as run)")
    return fig


def fig_compare_step(steps: dict, step_um: float = PAPER_STEP_UM):
    """X reading after a 2 um step per controller: ``{name: (t_s, y_um)}`` (step at t = 0)."""
    fig, axs = new_figure(1, 1, size=(9, 4.5))
    ax = axs[0, 0]
    for i, (name, (t, y)) in enumerate(steps.items()):
        ax.plot(1e3 * t, y, color=_color(i), label=name, lw=1.2)
    ax.axhspan(step_um * 0.98, step_um * 1.02, color="0.85", zorder=0, label="2 % band")
    ax.axvline(PAPER["settle"], color="0.4", ls="--", lw=0.8, label=f"{PAPER['settle']:g} ms (paper)")
    ax.set(xlabel="time after the step [ms]", ylabel="X reading [um]", title="2 um step", xlim=(-2, 60))
    ax.grid(True, alpha=0.3)
    ax.legend(fontsize=8)
    return fig


def fig_compare_contour(contours: dict):
    """Contour error along the 45 degree line at 1000 um/s: ``{name: contour_error_nm}`` (moving part)."""
    fig, axs = new_figure(1, 1, size=(9, 4.5))
    ax = axs[0, 0]
    for i, (name, e) in enumerate(contours.items()):
        t = np.arange(len(e)) / 4.0
        ax.plot(t, e, color=_color(i), lw=1.0, label=f"{name} (mean {np.mean(e):.0f} nm)")
    ax.axhline(PAPER["contour_mean"], color="0.4", ls="--", lw=0.8,
               label=f"{PAPER['contour_mean']:g} nm (paper's mean)")
    ax.set(xlabel="time while moving [ms]", ylabel="contour error [nm]", title="Contouring at 1000 um/s")
    ax.grid(True, alpha=0.3)
    ax.legend(fontsize=8)
    return fig


def fig_compare_psd(psds: dict):
    """Closed-loop PSD of the X reading at rest: ``{name: (freq_hz, psd_nm2_per_hz)}``."""
    fig, axs = new_figure(1, 1, size=(9, 4.5))
    ax = axs[0, 0]
    for i, (name, (f, p)) in enumerate(psds.items()):
        ax.loglog(f[1:], p[1:], color=_color(i), lw=1.0, label=name)
    ax.set(xlabel="frequency [Hz]", ylabel="PSD [nm^2/Hz]", title="Closed-loop reading at rest (X)")
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=8)
    return fig


def compare_figures(results: dict, responses: dict) -> dict:
    """``{file name: Figure}`` for the compare run folder.

    Parameters
    ----------
    results : dict
        ``{controller: {experiment name: result}}`` of the first seed (missing experiments are
        left out of their figure).
    responses : dict
        ``{controller: LoopResponse}`` of the linear controllers.
    """
    steps, contours, psds = {}, {}, {}
    for name, res in results.items():
        bw = res.get("bandwidth")
        if bw is not None:
            tr = bw.step
            k0 = int(round(0.01 / (tr.t_s[1] - tr.t_s[0])))
            steps[name] = (tr.t_s[k0:] - tr.t_s[k0], tr.y_um[k0:, 0] - tr.y_um[:k0, 0].mean())
        cases = res.get("contouring")
        if cases:
            fast = max(cases, key=lambda c: c.speed_um_s)
            contours[name] = fast.contour_error_nm
        rr = res.get("resolution")
        if rr is not None:
            psds[name] = (rr.psd_freq_hz, rr.psd_closed)
    figs = {}
    if responses:
        figs[N.COMPARE_LOOPS_PNG] = fig_compare_loops(responses)
    if steps:
        figs[N.COMPARE_STEP_PNG] = fig_compare_step(steps)
    if contours:
        figs[N.COMPARE_CONTOUR_PNG] = fig_compare_contour(contours)
    if psds:
        figs[N.COMPARE_PSD_PNG] = fig_compare_psd(psds)
    return figs
