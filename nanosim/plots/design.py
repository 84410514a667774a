"""Figures of the design step (paper Figs. 8-12, 18, 21-22).

Every function returns a matplotlib ``Figure`` (no pyplot state) and writes no
file; :func:`nanosim.pipeline.design.run_design` saves them with
:func:`nanosim.fileio.save_figure`. Frequencies are in Hz, magnitudes in dB.
"""
from __future__ import annotations

import numpy as np

from nanosim.design.discretize import Discretization
from nanosim.design.hinf import Design
from nanosim.design.loops import loop_freqresp
from nanosim.design.lti import INV_SQRT2, analysis_grid_hz, freqresp
from nanosim.design.reduction import Reduction, multiplicative_uncertainty
from nanosim.design.weights import Weights
from nanosim.plots.style import ACTUATOR_NAMES, AXIS_NAMES, bode_grid, channel_names, magnitude_db, new_figure

__all__ = ["plot_hankel", "plot_reduction_bode", "plot_uncertainty", "plot_weights", "plot_sensitivity",
           "plot_T_KS", "plot_closed_loop_bode", "plot_controller_bode", "plot_exported_loops"]


def plot_hankel(red: Reduction):
    """Hankel singular values, kept vs removed (paper Fig. 8).

    Parameters
    ----------
    red : Reduction
        From :func:`nanosim.design.reduction.reduce_model`.

    Returns
    -------
    matplotlib.figure.Figure
    """
    fig, ax = new_figure(size=(8, 4.5))
    ax = ax[0, 0]
    h = red.hankel_sv
    k = len(red.hsv_kept)
    idx = np.arange(1, h.size + 1)
    hp = np.where(h > 0, h, np.nan)
    ax.bar(idx[:k], hp[:k], color="tab:blue", label=f"kept ({red.order} states)")
    ax.bar(idx[k:], hp[k:], color="tab:gray", label=f"removed ({h.size - k} states)")
    ax.set_yscale("log")
    ax.axvline(k + 0.5, color="k", ls="--", lw=1)
    ax.set_xlabel("state index of the balanced realization")
    ax.set_ylabel("Hankel singular value [sensor V / controller V]")
    ax.set_title(f"Hankel singular values of the {red.full_order}-state model (cf. paper Fig. 8)")
    pos = h[h > 0]
    if pos.size:
        ax.set_ylim(max(pos.min(), pos.max() * 1e-8) / 3, pos.max() * 3)
    ax.grid(True, which="both", alpha=0.3)
    txt = []
    if red.hsv_kept.size:
        txt.append(f"smallest kept: {red.hsv_kept.min():.3g}")
    if red.hsv_dropped.size:
        txt.append(f"largest removed: {red.hsv_dropped.max():.3g}")
    txt.append(f"H-inf error bound 2*sum(removed): {red.error_bound_hinf:.3g}")
    ax.text(0.98, 0.80, "\n".join(txt), transform=ax.transAxes, ha="right", va="top", fontsize=9,
            bbox=dict(boxstyle="round", fc="white", ec="0.7"))
    ax.legend(loc="upper right")
    return fig


def plot_reduction_bode(red: Reduction, f=None):
    """Full vs reduced model magnitude, ny x nu grid (paper Fig. 9).

    Parameters
    ----------
    red : Reduction
    f : ndarray, shape (F,), optional
        Frequencies [Hz]; default 1-2000 Hz densified at the full model's resonances.

    Returns
    -------
    matplotlib.figure.Figure
    """
    f = analysis_grid_hz([red.G_full], 1.0, 2000.0, 1200) if f is None else f
    return bode_grid(f"Full ({red.full_order} states, solid) vs reduced ({red.order} states, dashed) model; "
                      f"controller V -> sensor V (cf. paper Fig. 9)",
                      [("full", freqresp(red.G_full, f), dict(color="tab:blue", lw=1.2)),
                       ("reduced", freqresp(red.G_reduced, f), dict(color="tab:red", ls="--", lw=1.2))],
                      f, ylabel="|G| [dB, sensor V/controller V]")


def plot_uncertainty(red: Reduction, f=None):
    """sigma_max(E_o) of the reduction error (paper Fig. 10b).

    Parameters
    ----------
    red : Reduction
    f : ndarray, shape (F,), optional
        Frequencies [Hz]; default 1-2000 Hz densified at both models' resonances.

    Returns
    -------
    matplotlib.figure.Figure
    """
    f = analysis_grid_hz([red.G_full, red.G_reduced], 1.0, 2000.0, 1500) if f is None else f
    e = multiplicative_uncertainty(red.G_full, red.G_reduced, f)
    fig, ax = new_figure(size=(8, 4.5))
    ax = ax[0, 0]
    ax.semilogx(f, magnitude_db(e), color="tab:blue", label=r"$\bar\sigma(E_o)$, $E_o=(G_P-G)G^{-1}$")
    ax.axhline(-20, color="tab:green", ls="--", lw=1, label="-20 dB (paper: below this under 140 Hz)")
    ax.axhline(0, color="tab:red", ls="--", lw=1, label="0 dB (paper: above this over 600 Hz)")
    for v in (140, 600):
        ax.axvline(v, color="gray", ls=":", lw=0.8)
    ax.set_xlabel("frequency [Hz]")
    ax.set_ylabel("largest singular value [dB]")
    ax.set_title("Output multiplicative uncertainty from model reduction (cf. paper Fig. 10)")
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=8, loc="upper left")
    finite = e[np.isfinite(e) & (e > 0)]
    if finite.size:
        ax.set_ylim(max(magnitude_db(finite.min()) - 5, -120), magnitude_db(finite.max()) + 10)
    return fig


def plot_weights(W: Weights, f=None):
    """|Wp|, |Wt|, |Wu| and the bounds 1/|W| (paper Fig. 11b).

    Parameters
    ----------
    W : Weights
    f : ndarray, shape (F,), optional
        Frequencies [Hz]; default 1e-3 to 1e6 Hz.

    Returns
    -------
    matplotlib.figure.Figure
    """
    f = np.logspace(-3, 6, 900) if f is None else f
    fig, axs = new_figure(1, 2, size=(12, 4.5))
    cols = {"Wp": "tab:blue", "Wt": "tab:red", "Wu": "tab:green"}
    for nm in ("Wp", "Wt", "Wu"):
        if getattr(W, nm) is None:
            continue
        m = np.abs(getattr(W, nm).freqresp(f))
        axs[0, 0].semilogx(f, magnitude_db(m), color=cols[nm], label=f"|{nm}|")
        axs[0, 1].semilogx(f, -magnitude_db(m), color=cols[nm], label=f"1/|{nm}|")
    axs[0, 0].set_title("weights")
    axs[0, 1].set_title("inverse weights = bounds on S, T, KS (at gamma = 1)")
    for ax in axs[0]:
        ax.set_xlabel("frequency [Hz]")
        ax.set_ylabel("magnitude [dB]")
        ax.grid(True, which="both", alpha=0.3)
        ax.legend()
    fig.suptitle("Mixed-sensitivity weights (cf. paper Fig. 11b)")
    return fig


def _sv_panel(ax, f, sv, weight, gamma, label, bound_label, colors=("tab:blue", "tab:orange", "tab:green")):
    """Singular values (sigma_max thick) and, if ``weight`` is given, 1/|W| and gamma/|W|."""
    for k in range(sv.shape[1]):
        ax.semilogx(f, magnitude_db(sv[:, k]), color=colors[k % len(colors)], lw=2.2 if k == 0 else 1.0,
                    alpha=1.0 if k == 0 else 0.8, zorder=3 if k == 0 else 2,
                    label=(f"{label} sigma_{k + 1}" + (" (max)" if k == 0 else "")) if sv.shape[1] > 1 else label)
    if weight is not None:
        bound = 1.0 / np.abs(weight.freqresp(f))
        ax.semilogx(f, magnitude_db(bound), "k--", lw=1.2, label=f"1/|{bound_label}|")
        ax.semilogx(f, magnitude_db(gamma * bound), "k:", lw=1.2, label=f"gamma/|{bound_label}| (gamma = {gamma:.3g})")
    ax.set_xlabel("frequency [Hz]")
    ax.grid(True, which="both", alpha=0.3)


def plot_sensitivity(d: Design):
    """sigma(S) with nominal and full model vs the bound 1/|Wp| (paper Fig. 12).

    Parameters
    ----------
    d : Design
        From :func:`nanosim.design.hinf.design_hinf`; plotted on ``d.freq_hz``.

    Returns
    -------
    matplotlib.figure.Figure
    """
    n = 2 if d.full is not None else 1
    fig, axs = new_figure(1, n, size=(6.5 * n, 4.8), sharey=True)
    f = d.freq_hz
    panels = [("(a) nominal (reduced) model", d.nominal)]
    if d.full is not None:
        panels.append(("(b) full model", d.full))
    for ax, (ttl, la) in zip(axs[0], panels):
        _sv_panel(ax, f, la.sigma_S, d.weights.Wp, d.gamma, "S", "Wp")
        ax.axhline(magnitude_db(INV_SQRT2), color="gray", lw=0.8, ls="-.", label="-3 dB")
        ax.set_title(f"{ttl}: ||S||inf = {la.S_peak:.3f} ({magnitude_db(la.S_peak):.2f} dB) at {la.S_peak_hz:.0f} Hz",
                     fontsize=10)
        ax.set_ylim(-100, 20)
    axs[0, 0].set_ylabel("singular values of S [dB]")
    axs[0, 0].legend(fontsize=8, loc="lower right")
    fig.suptitle("Sensitivity S = (I + GK)^-1 (cf. paper Fig. 12)")
    return fig


def plot_T_KS(d: Design):
    """sigma(T) vs 1/|Wt| and sigma(KS) vs 1/|Wu| (paper Fig. 18a-b / 11b).

    Parameters
    ----------
    d : Design
        Plotted on ``d.freq_hz``.

    Returns
    -------
    matplotlib.figure.Figure
    """
    fig, axs = new_figure(1, 2, size=(13, 4.8))
    f = d.freq_hz
    _sv_panel(axs[0, 0], f, d.nominal.sigma_T, d.weights.Wt, d.gamma, "T nominal", "Wt")
    if d.full is not None:
        axs[0, 0].semilogx(f, magnitude_db(d.full.sigma_T[:, 0]), color="tab:purple", lw=1, alpha=0.8,
                           label="T full model sigma_max")
    axs[0, 0].set_ylim(-100, 30)
    axs[0, 0].set_ylabel("singular values of T [dB]")
    axs[0, 0].set_title("(a) complementary sensitivity T = GK(I+GK)^-1", fontsize=10)
    _sv_panel(axs[0, 1], f, d.nominal.sigma_KS, d.weights.Wu, d.gamma, "KS nominal", "Wu")
    axs[0, 1].set_ylabel("singular values of KS [dB, controller V / sensor V]")
    axs[0, 1].set_title("(b) control sensitivity KS = K(I+GK)^-1", fontsize=10)
    for ax in axs[0]:
        ax.legend(fontsize=8, loc="lower left")
    fig.suptitle("Closed-loop T and KS with their weight bounds (cf. paper Figs. 11b, 18)")
    return fig


def plot_closed_loop_bode(d: Design, f=None):
    """|T_ij| of the closed loop r -> y, ny x ny grid (paper Figs. 13, 21).

    Parameters
    ----------
    d : Design
    f : ndarray, shape (F,), optional
        Frequencies [Hz]; default 0.1-2000 Hz densified at the plants' and K's resonances.

    Returns
    -------
    matplotlib.figure.Figure
    """
    f = analysis_grid_hz([d.G_nominal, d.G_full, d.K], 0.1, 2000.0, 1200) if f is None else f
    curves = [("nominal model", loop_freqresp(freqresp(d.G_nominal, f), freqresp(d.K, f))[1],
               dict(color="tab:blue", lw=1.2))]
    if d.G_full is not None:
        curves.append(("full model", loop_freqresp(freqresp(d.G_full, f), freqresp(d.K, f))[1],
                       dict(color="tab:red", ls="--", lw=1.0)))
    on = channel_names(d.G_nominal.noutputs, AXIS_NAMES)
    return bode_grid("Closed loop T: reference -> output (cf. paper Figs. 13, 21)", curves, f,
                      ylabel="|T| [dB]", in_names=tuple(f"r{x}" for x in on), out_names=on, ylim=(-100, 10))


def plot_controller_bode(d: Design, disc: Discretization | None = None, f=None):
    """|K_ij| continuous (and discrete, and the damping loop Ky), nu x ny grid (paper Fig. 22).

    Parameters
    ----------
    d : Design
    disc : Discretization, optional
        Adds the discrete controller's error columns (up to 0.999 x Nyquist).
    f : ndarray, shape (F,), optional
        Frequencies [Hz]; default 0.01 Hz to 0.999 x Nyquist (2000 Hz without ``disc``).

    Returns
    -------
    matplotlib.figure.Figure
    """
    nyq = 0.5 / disc.dt if disc is not None else 2000.0
    f = analysis_grid_hz([d.K], 0.01, 0.999 * nyq, 1500) if f is None else f
    curves = [("continuous K", freqresp(d.K, f), dict(color="tab:blue", lw=1.2))]
    if disc is not None:
        ny = d.G_nominal.noutputs
        curves.append((f"discrete ({disc.method}, {1 / disc.dt:.0f} Hz)", freqresp(disc.Kd, f)[:, :, :ny],
                       dict(color="tab:orange", ls="--", lw=1.0)))
    if d.damping is not None:
        curves.append(("damping loop Ky (y -> u)", freqresp(d.damping.Ky, f), dict(color="tab:green", lw=1.0)))
    on = channel_names(d.G_nominal.noutputs, AXIS_NAMES)
    inn = channel_names(d.G_nominal.ninputs, ACTUATOR_NAMES)
    return bode_grid(f"Controller K ({d.controller_order} states): error -> command (cf. paper Fig. 22)", curves, f,
                      ylabel="|K| [dB, controller V/sensor V]", in_names=tuple(f"e{x}" for x in on),
                      out_names=tuple(f"u{x}" for x in inn), vlines=(500.0,))


def plot_exported_loops(name: str, Gd, Ke, Ky=None, *, delay_samples: int = 0, weights: Weights | None = None,
                        gamma: float | None = None, f=None) -> dict:
    """The design figures of a discrete exported controller on the identified model (paper Figs. 12, 18, 21, 22).

    Parameters
    ----------
    name : str
        Architecture (titles).
    Gd : control.StateSpace
        Identified discrete model (the loop as run, with ``delay_samples``).
    Ke, Ky : control.StateSpace
        Discrete error and measurement parts of ``u = Ke e + Ky y`` (``Ky`` None: one degree of freedom).
    delay_samples : int
        Loop delay beyond ``Gd``.
    weights : Weights or None
        Bounds ``1/|Wp|``, ``1/|Wt|``, ``1/|Wu|`` drawn with ``gamma`` (None: none, a design without them).
    gamma : float or None
    f : ndarray, optional
        Frequencies [Hz]; default 0.1 Hz to 0.999 x Nyquist, densified at the modes.

    Returns
    -------
    dict
        ``{"sensitivity", "T_KS", "closed_loop_bode", "controller_bode"}`` -> Figure.
    """
    from nanosim.design.architectures.common import distinct_modes_hz, freqresp_z, loop_response
    from nanosim.design.architectures.common import analysis_grid_hz as grid_z
    f = grid_z(float(Gd.dt), 900, distinct_modes_hz(Gd)) if f is None else np.asarray(f, float)
    r = loop_response(freqresp_z(Gd, f), f, Ke, Ky, delay_samples=delay_samples, dt=float(Gd.dt))
    g = 1.0 if gamma is None else float(gamma)

    def sv(H):
        return np.linalg.svd(H, compute_uv=False)

    w = weights if weights is not None else None
    S_pk = float(sv(r.S_o)[:, 0].max())
    fig_s, axs = new_figure(1, 1, size=(7, 4.8))
    _sv_panel(axs[0, 0], f, sv(r.S_o), None if w is None else w.Wp, g, "S", "Wp")
    axs[0, 0].axhline(magnitude_db(INV_SQRT2), color="gray", lw=0.8, ls="-.", label="-3 dB")
    axs[0, 0].set_ylim(-100, 20)
    axs[0, 0].set_ylabel("singular values of S [dB]")
    axs[0, 0].legend(fontsize=8, loc="lower right")
    axs[0, 0].set_title(f"identified model, loop as run: ||S||inf = {S_pk:.3f}", fontsize=10)
    fig_s.suptitle(f"Sensitivity S of the exported {name} controller (cf. paper Fig. 12)")
    fig_t, axt = new_figure(1, 2, size=(13, 4.8))
    _sv_panel(axt[0, 0], f, sv(r.T_ry), None if w is None else w.Wt, g, "T", "Wt")
    axt[0, 0].set_ylim(-100, 30)
    axt[0, 0].set_ylabel("singular values of T [dB]")
    _sv_panel(axt[0, 1], f, sv(r.KS), None if w is None else w.Wu, g, "KS", "Wu")
    axt[0, 1].set_ylabel("singular values of KS [dB, controller V / sensor V]")
    for ax in axt[0]:
        ax.legend(fontsize=8, loc="lower left")
    fig_t.suptitle(f"T (reference -> output) and KS of the exported {name} controller (cf. paper Figs. 11b, 18)")
    on = channel_names(Gd.noutputs, AXIS_NAMES)
    inn = channel_names(Gd.ninputs, ACTUATOR_NAMES)
    fig_cl = bode_grid(f"Closed loop T of the exported {name} controller: reference -> output (cf. paper Figs. 13, "
                       "21)", [("identified model", r.T_ry, dict(color="tab:blue", lw=1.2))], f, ylabel="|T| [dB]",
                       in_names=tuple(f"r{x}" for x in on), out_names=on, ylim=(-100, 10))
    curves = [("error part K (e -> u)", freqresp_z(Ke, f), dict(color="tab:blue", lw=1.2))]
    if Ky is not None:
        curves.append(("measurement part Ky (y -> u)", freqresp_z(Ky, f), dict(color="tab:green", lw=1.0)))
    order = Ke.nstates
    fig_k = bode_grid(f"Exported {name} controller ({order} states, {1 / float(Gd.dt):.0f} Hz): error -> command "
                      "(cf. paper Fig. 22)", curves, f, ylabel="|K| [dB, controller V/sensor V]",
                      in_names=tuple(f"e{x}" for x in on), out_names=tuple(f"u{x}" for x in inn), vlines=(500.0,))
    return {"sensitivity": fig_s, "T_KS": fig_t, "closed_loop_bode": fig_cl, "controller_bode": fig_k}
