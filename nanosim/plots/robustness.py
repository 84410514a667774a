"""Figures of the robustness analysis of a controller on the loop as it is run.

Every function returns a matplotlib ``Figure`` and writes no file;
:func:`nanosim.pipeline.design.run_design` saves them. Input: a mapping ``label ->``
:class:`~nanosim.design.robustness.ControllerRobustness` (one per plant, e.g. the
linear twin and the identified model, each with the loop's one-sample delay).
Frequencies in Hz, magnitudes in dB.
"""
from __future__ import annotations


from nanosim.design.lti import singular_values
from nanosim.design.robustness import DISK_MARGIN_TARGET, ROBUSTNESS_MAPS, ControllerRobustness
from nanosim.plots.style import magnitude_db, new_figure

__all__ = ["plot_loop_singular_values", "plot_disk_margins"]

_TITLES = {"S_o": "S_o = (I + G Kfb)^-1  (output sensitivity)", "S_i": "S_i = (I + Kfb G)^-1  (input sensitivity)",
           "T_o": "T_o = I - S_o", "T_i": "T_i = I - S_i", "KS": "KS = S_i K  (r -> u) [controller V / sensor V]",
           "SG": "SG = S_o G  (input disturbance -> y) [sensor V / controller V]"}
_COLORS = ("tab:blue", "tab:orange", "tab:green", "tab:red")


def _check(analyses) -> list[tuple[str, ControllerRobustness]]:
    items = list(dict(analyses).items())
    if not items or not all(isinstance(a, ControllerRobustness) for _, a in items):
        raise TypeError("analyses: expected a non-empty mapping label -> ControllerRobustness")
    return items


def plot_loop_singular_values(analyses, title: str = "Loop transfer matrices of the loop as run"):
    """Singular values of ``S_o, S_i, T_o, T_i, KS, SG`` (2 x 3 panels), every plant overlaid.

    Parameters
    ----------
    analyses : mapping of str to ControllerRobustness
    title : str

    Returns
    -------
    matplotlib.figure.Figure
        Largest singular value solid, the others thin; the refined peak of
        ``sigma_max`` is marked and written in the legend.
    """
    items = _check(analyses)
    fig, axs = new_figure(2, 3, size=(15, 8), sharex=True)
    for k, name in enumerate(ROBUSTNESS_MAPS):
        ax = axs.flat[k]
        for c, (label, a) in enumerate(items):
            r = a.response
            sv = singular_values(getattr(r, name))
            col = _COLORS[c % len(_COLORS)]
            key = "peak_" + name.replace("_", "")
            pk, fpk = a.summary.get(key), a.summary.get(key + "_freq_hz")
            lab = label + (f": peak {pk:.3g} at {fpk:.1f} Hz" if pk is not None and fpk is not None else "")
            ax.semilogx(r.freq_hz, magnitude_db(sv[:, 0]), color=col, lw=1.3, label=lab)
            for j in range(1, sv.shape[1]):
                ax.semilogx(r.freq_hz, magnitude_db(sv[:, j]), color=col, lw=0.6, alpha=0.6)
            if pk is not None and fpk is not None:
                ax.plot([fpk], [magnitude_db(pk)], "v", color=col, ms=6)
        ax.axhline(0.0, color="k", lw=0.6)
        if name.startswith("S"):
            ax.axhline(magnitude_db(2.0), color="0.4", ls=":", lw=0.8)
        ax.set_title(_TITLES[name], fontsize=10)
        ax.grid(True, which="both", alpha=0.3)
        ax.legend(fontsize=8, loc="lower left" if name.startswith("S_") else "upper right")
        if k >= 3:
            ax.set_xlabel("frequency [Hz]")
        if k % 3 == 0:
            ax.set_ylabel("singular values [dB]")
    delays = sorted({a.delay_samples for _, a in items})
    fig.suptitle(f"{title} (computation delay {', '.join(map(str, delays))} sample; dotted: 6 dB)")
    return fig


def plot_disk_margins(analyses, target_alpha: float = DISK_MARGIN_TARGET, title: str = "Disk margins per frequency"):
    """Multiloop disk margin ``alpha(f)`` at input, output and both, and the mu of the
    uncertainty set, every plant overlaid.

    Parameters
    ----------
    analyses : mapping of str to ControllerRobustness
    target_alpha : float
        Drawn as a dashed line (the bench specification: multiloop disk margin >= 0.4,
        :data:`~nanosim.design.robustness.DISK_MARGIN_TARGET`).
    title : str

    Returns
    -------
    matplotlib.figure.Figure
        Left: ``alpha(f) = 1 / mu(f)`` (a lower bound of the margin away from the peaks,
        see :func:`nanosim.design.mu.mu_upper_bound` ``peak_only``); right: the mixed mu
        upper bound over the parametric uncertainty set (robustly stable if below 1;
        :mod:`nanosim.design.parametric`), and dotted the unstructured complex covering.
    """
    items = _check(analyses)
    fig, axs = new_figure(1, 2, size=(14, 5))
    ax, axm = axs[0, 0], axs[0, 1]
    styles = (("alpha_input_f", "input", "-"), ("alpha_output_f", "output", "--"),
              ("alpha_input_output_f", "input + output", ":"))
    for c, (label, a) in enumerate(items):
        m = a.margins
        col = _COLORS[c % len(_COLORS)]
        for attr, where, ls in styles:
            ax.loglog(m.freq_hz, getattr(m, attr), color=col, ls=ls, lw=1.1,
                      label=f"{label}, {where}: min {getattr(m, where.replace(' + ', '_')).alpha:.3g}")
        mx = getattr(a, "mixed", None)
        if mx is not None:
            on_plant = ("" if a.uncertainty is None else " (gain x%.3g-%.3g of its own)"
                        % a.uncertainty.input_gain_range_about(a.input_gain_of_nominal))
            axm.loglog(mx.freq_hz, mx.mu_upper, color=col, lw=1.3,
                       label=f"{label}{on_plant}: mixed mu (real parameters) {mx.mu_peak:.3g} at "
                             f"{mx.mu_peak_freq_hz:.1f} Hz")
        if a.robust is not None:
            rb = a.robust
            axm.loglog(rb.freq_hz, rb.mu_upper, color=col, lw=0.8, ls=":",
                       label=f"{label}: complex covering, peak {rb.mu_peak:.3g}; sampled set "
                             + ("all stable" if rb.sampled_all_stable else "has unstable members"))
    ax.axhline(target_alpha, color="k", ls="--", lw=0.8, label=f"target {target_alpha:g}")
    ax.set_xlabel("frequency [Hz]")
    ax.set_ylabel("disk margin alpha [-]")
    ax.set_title("multiloop disk margins (1 / mu of S + (sigma-1)/2 I)", fontsize=10)
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=7, loc="lower left")
    axm.axhline(1.0, color="k", ls="--", lw=0.8)
    axm.set_xlabel("frequency [Hz]")
    axm.set_ylabel("mu upper bound [-]")
    unc = next((a.uncertainty for _, a in items if a.uncertainty is not None), None)
    axm.set_title("robust stability over the uncertainty set" + ("" if unc is None else
                  f": gain {unc.input_gain_range} of nominal, f x{unc.freq_scale_range}, "
                  f"zeta x{unc.damping_scale_range}, delay +{unc.extra_delay_samples_range} samples"), fontsize=9)
    axm.grid(True, which="both", alpha=0.3)
    if any(a.robust is not None for _, a in items):
        axm.legend(fontsize=7, loc="upper left")
    fig.suptitle(title)
    return fig
