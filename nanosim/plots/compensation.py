"""The hysteresis-compensation figure of a run folder: the Fig. 14 open-loop loops per drive and the errors."""
from __future__ import annotations

import numpy as np

from nanosim.plots.style import subplots

__all__ = ["compensation_plot"]


def compensation_plot(loops: dict, doc: dict):
    """Fig. 14's open-loop loops overlaid per case, the loop widths and the closed-loop errors as bars.

    Parameters
    ----------
    loops : dict
        ``{label: (command_V, x_um)}``: actuator A's command (controller V) and the X reading from the
        loop's start (um), one entry per case.
    doc : dict
        ``compensation.json``'s content (:func:`nanosim.pipeline.compensation.compensation_doc`).
    """
    cases = list((doc.get("cases") or {}).values())
    labels = [c["label"] for c in cases]
    fig, ax = subplots(2, 2, figsize=(12, 8.5))
    a = ax[0, 0]
    for label, (v, x) in loops.items():
        a.plot(v, x, lw=1.0, label=label)
    a.set_xlabel("actuator A command (controller V)")
    a.set_ylabel("X displacement along its travel (um)")
    a.set_title("(a) open loop, Fig. 14: 0 -> 1.65 -> 0 V in 2 s", fontsize=10)
    a.legend(fontsize=8)
    a.grid(alpha=0.3)

    def bars(a, groups, unit, title, fmt="%.3g"):
        x = np.arange(len(groups))
        w = 0.8 / max(1, len(cases))
        for k, c in enumerate(cases):
            vals = [np.nan if v is None else v for v in (g[1](c) for g in groups)]
            rect = a.bar(x + (k - (len(cases) - 1) / 2) * w, vals, w, label=c["label"])
            a.bar_label(rect, fmt=fmt, fontsize=7)
        a.set_xticks(x, [g[0] for g in groups], fontsize=8)
        a.set_ylabel(unit)
        a.set_title(title, fontsize=10)
        a.grid(alpha=0.3, axis="y")

    bars(ax[0, 1], [("output hysteresis", lambda c: c.get("open_loop_output_percent")),
                    ("input hysteresis", lambda c: c.get("open_loop_input_percent"))],
         "% of travel / of command span", "(b) open-loop loop width (Fig. 14); colours as in (a)")
    bars(ax[1, 0], [("contour mean", lambda c: c.get("contour_mean_error_nm")),
                    ("contour max", lambda c: c.get("contour_max_error_nm")),
                    ("closed-loop hysteresis", lambda c: c.get("closed_loop_hysteresis_nm"))],
         "nm", "(c) closed loop: contour error at 1000 um/s, settled hysteresis (20 um)")
    track = [(t["waveform"], t["freq_hz"]) for t in (cases[0].get("tracking") or [])] if cases else []

    def rms(c, key):
        return next((t["rms_error_nm"] for t in c.get("tracking") or [] if (t["waveform"], t["freq_hz"]) == key), None)

    bars(ax[1, 1], [(f"{w} {f:g} Hz", lambda c, key=(w, f): rms(c, key)) for w, f in track],
         "nm rms", "(d) closed loop: tracking error, X, 10 um (Fig. 19)", fmt="%.0f")
    fig.suptitle(f"Hysteresis compensation, linear twin with every effect on, seed {doc.get('seed')}: "
                 + ", ".join(labels), fontsize=10)
    return fig
