"""Figures of a population of stages (``nanosim montecarlo``) and of a design sweep (``nanosim sweep``).

Each function returns a matplotlib Figure and writes nothing.
"""
from __future__ import annotations

import math

import numpy as np

from nanosim.plots.style import subplots

__all__ = ["fig_histograms", "fig_sensitivity", "fig_crosscheck", "fig_pareto", "fig_bench"]


def fig_histograms(flats: list, spec: dict):
    """One histogram per spec limit (and the first mode, XY split, disk margin) with the limits drawn."""
    items = [(lim["metric"], lim.get("label", lim["metric"]), lim.get("min"), lim.get("max"), lim["unit"])
             for lim in spec["limits"] if lim["metric"] != "closed_loop_stable"]
    items += [("mode_1_hz", "first mode", None, None, "Hz"), ("xy_split_percent", "XY split, first pair", None,
                                                              None, "%"),
              ("disk_margin_alpha", "disk margin alpha (worst location and piezo end, twin)", None, None, "-")]
    ncol = 4
    nrow = math.ceil(len(items) / ncol)
    fig, axs = subplots(nrow, ncol, figsize=(3.3 * ncol, 2.6 * nrow), squeeze=False)
    for ax, (m, label, lo, hi, unit) in zip(axs.ravel(), items):
        v = np.array([f.get(m, math.nan) for f in flats], float)
        v = v[np.isfinite(v)]
        if v.size:
            ax.hist(v, bins=min(30, max(5, v.size // 5)), color="tab:blue", alpha=0.75)
        span = float(np.ptp(v)) if v.size else 0.0
        for x, side in ((lo, "left"), (hi, "right")):
            if x is None:
                continue
            far = v.size and abs(x - (v.min() if side == "left" else v.max())) > 5.0 * max(span, 1e-12)
            if far:         # a limit far from every sample: name it at the edge, keep the bars readable
                text = f"<- limit {x:g} {unit}" if side == "left" else f"limit {x:g} {unit} ->"
                ax.text(0.02 if side == "left" else 0.98, 0.92, text, transform=ax.transAxes, ha=side,
                        color="tab:red", fontsize=7)
            else:
                ax.axvline(x, color="tab:red", lw=1.5)
        ax.set_title(label, fontsize=9)
        ax.set_xlabel(f"{m} [{unit}]", fontsize=7)
        ax.tick_params(labelsize=7)
        ax.grid(alpha=0.3)
    for ax in axs.ravel()[len(items):]:
        ax.set_visible(False)
    fig.suptitle(f"{len(flats)} fabricated stages: metric distributions (red: spec limits)")
    return fig


def fig_sensitivity(sens: dict, top_groups: int = 9):
    """Adjusted R^2 of each tolerance group alone, per metric (a heat map)."""
    metrics = list(sens)
    groups = []
    for m in metrics:
        for g in sens[m]["groups"]:
            if g["group"] not in groups:
                groups.append(g["group"])
    groups = groups[:top_groups]
    M = np.full((len(metrics), len(groups)), np.nan)
    for i, m in enumerate(metrics):
        for g in sens[m]["groups"]:
            if g["group"] in groups:
                M[i, groups.index(g["group"])] = g["adjusted_r2"]
    fig, ax = subplots(1, 1, figsize=(1.1 * len(groups) + 4, 0.42 * len(metrics) + 2))
    im = ax.imshow(np.clip(M, 0, 1), vmin=0, vmax=1, cmap="viridis", aspect="auto")
    ax.set_xticks(range(len(groups)), groups, rotation=35, ha="right", fontsize=8)
    ax.set_yticks(range(len(metrics)), metrics, fontsize=8)
    for i in range(len(metrics)):
        for j in range(len(groups)):
            if np.isfinite(M[i, j]):
                ax.text(j, i, f"{M[i, j]:.2f}", ha="center", va="center", fontsize=7,
                        color="white" if M[i, j] < 0.5 else "black")
    fig.colorbar(im, ax=ax, label="adjusted R^2 (group alone)")
    ax.set_title("Which tolerances matter: variance of each metric explained by one tolerance group")
    return fig


def fig_crosscheck(cross: list, tol_percent: float):
    """Twin vs MuJoCo, relative difference of every cross-checked metric per sample, with the ``tol_percent`` band."""
    metrics = sorted({m for c in cross for m in c["metrics"]})
    fig, ax = subplots(1, 1, figsize=(9, 0.35 * len(metrics) + 2))
    for k, c in enumerate(cross):
        y = np.array([metrics.index(m) + 0.6 * (k / max(1, len(cross) - 1) - 0.5) for m in c["metrics"]])
        x = np.array([100 * (r["twin"] - r["mujoco"]) / max(abs(r["mujoco"]), 1e-12) for r in c["metrics"].values()])
        # open marker: within the metric's reading resolution (two ADC counts or two periods), whatever the %;
        # square: only within the resolution of the twin's reading range at indistinguishable physics
        rows = list(c["metrics"].values())
        res = np.array([r.get("within_resolution", False) for r in rows], bool)
        spr = np.array([r["ok"] and not r["ok_without_spread"] for r in rows], bool)
        plain = ~res & ~spr
        line, = ax.plot(x[plain], y[plain], "o", ms=3, label=f"#{c['sample']}")
        ax.plot(x[res], y[res], "o", ms=4, mfc="none", color=line.get_color())
        ax.plot(x[spr], y[spr], "s", ms=5, mfc="none", color=line.get_color())
    ax.axvspan(-tol_percent, tol_percent, color="tab:green", alpha=0.12, label=f"within {tol_percent:g} %")
    ax.plot([], [], "o", ms=4, mfc="none", color="0.4", label="within the reading resolution")
    ax.plot([], [], "s", ms=5, mfc="none", color="0.4", label="within the resolution of the twin's spread")
    ax.set_yticks(range(len(metrics)), metrics, fontsize=8)
    ax.set_xlabel("(twin - MuJoCo) / MuJoCo [%]")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=7, ncol=2, loc="best")
    ax.set_title("Cross-check: linear twin vs MuJoCo on the same fabricated stages")
    return fig


def fig_pareto(points: list, front: list, x: str, y: str, c: str, labels: dict | None = None):
    """Design sweep: ``x`` vs ``y`` coloured by ``c``; the Pareto-optimal points circled and labelled."""
    labels = labels or {}
    fig, ax = subplots(1, 1, figsize=(8, 5.5))
    xv = np.array([p.get(x, math.nan) for p in points], float)
    yv = np.array([p.get(y, math.nan) for p in points], float)
    cv = np.array([p.get(c, math.nan) for p in points], float)
    sc = ax.scatter(xv, yv, c=cv, cmap="viridis", s=40, zorder=3)
    fig.colorbar(sc, ax=ax, label=labels.get(c, c))
    for i in front:
        ax.scatter(xv[i], yv[i], s=140, facecolors="none", edgecolors="tab:red", lw=1.5, zorder=4)
        ax.annotate(points[i].get("label", str(i)), (xv[i], yv[i]), fontsize=7, xytext=(4, 4),
                    textcoords="offset points")
    ax.set_xlabel(labels.get(x, x))
    ax.set_ylabel(labels.get(y, y))
    ax.ticklabel_format(useOffset=False)      # the values themselves, however close (no "+7.4e1" offset)
    for v, set_lim in ((xv, ax.set_xlim), (yv, ax.set_ylim)):
        lim = _flat_limits(v)
        if lim is not None:
            set_lim(*lim)
    ax.grid(alpha=0.3)
    ax.set_title("Design sweep: bandwidth vs travel vs resolution (red: Pareto-optimal, ties counted)")
    return fig


def _flat_limits(v: np.ndarray, rel: float = 1e-3, half_width: float = 5e-3):
    """Axis limits ``centre * (1 -+ half_width)`` for values that spread by less than ``rel`` of their size (a
    parameter that does not move a figure: readable ticks, the points on one line), else None.
    """
    v = v[np.isfinite(v)]
    if not v.size:
        return None
    c = float(np.mean(v))
    if c == 0.0 or float(np.ptp(v)) > rel * abs(c):
        return None
    return c - half_width * abs(c), c + half_width * abs(c)


def fig_bench(rows: list, alphas: dict):
    """Controllers on the same stages: yield over every limit (with its 95 % interval) and the distribution of
    the twin's disk margin alpha (``alphas``: ``{controller: [alpha per sample]}``).
    """
    names = [r["controller"] for r in rows]
    fig, (ax1, ax2) = subplots(1, 2, figsize=(12, 0.45 * len(names) + 2.5), sharey=True)
    y = np.arange(len(names))
    yl = np.array([r["yield_percent"] for r in rows], float)
    ci = np.array([r["ci95_percent"] for r in rows], float)
    ax1.barh(y, yl, color="tab:blue", alpha=0.7)
    err = np.clip([yl - ci[:, 0], ci[:, 1] - yl], 0.0, None)       # an interval's end may round past its yield
    ax1.errorbar(yl, y, xerr=err, fmt="none", ecolor="k", capsize=3)
    ax1.set_xlim(0, 100)
    ax1.set_xlabel("yield, every limit [%] (bar: 95 % interval)")
    ax1.set_yticks(y, names)
    ax1.grid(alpha=0.3, axis="x")
    data = [np.asarray(alphas.get(n, []), float) for n in names]
    data = [d[np.isfinite(d)] for d in data]
    for k, d in enumerate(data):               # drawn by hand: boxplot's orientation keyword moved in 3.10
        if not d.size:
            continue
        p5, q1, med, q3, p95 = np.percentile(d, [5, 25, 50, 75, 95])
        ax2.plot([p5, p95], [k, k], color="k", lw=1)
        ax2.plot([q1, q3], [k, k], color="tab:blue", lw=8, solid_capstyle="butt", alpha=0.7)
        ax2.plot([med], [k], "|", color="k", ms=14, mew=2)
        out = d[(d < p5) | (d > p95)]
        ax2.plot(out, np.full(out.size, k), ".", color="0.4", ms=3)
    ax2.set_xlabel("disk margin alpha, twin (bar: quartiles and median; line: 5-95 %; dots: the rest)")
    ax2.grid(alpha=0.3, axis="x")
    ax2.invert_yaxis()
    n = rows[0]["n"] if rows else 0
    fig.suptitle(f"{len(names)} controllers on the same {n} fabricated stages")
    return fig
