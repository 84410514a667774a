"""Hysteresis measures of a single input/output loop (paper Fig. 14: output and input hysteresis in %)."""
from __future__ import annotations

import numpy as np

from nanosim.validation import as_finite_array

__all__ = ["loop_hysteresis_percent"]


def loop_hysteresis_percent(v_in, y_out, n_grid: int = 2001) -> tuple[float, float]:
    """Output and input hysteresis (%) of a single ``low -> high -> low`` loop.

    Parameters
    ----------
    v_in, y_out : array_like, shape (N,)
        Input and output samples of one loop; the input rises monotonically to
        its maximum, then falls monotonically. ``y_out`` must be monotonic
        on each branch (true for a PI model with positive weights).
    n_grid : int
        Number of interpolation points.

    Returns
    -------
    output_percent : float
        Max vertical gap between branches over the input span, divided by the
        output travel ``max(y) - min(y)``, in %.
    input_percent : float
        Max horizontal gap between branches over the output range both
        branches cover, divided by the input span ``max(v) - min(v)``, in %.
    """
    v = as_finite_array("v_in", v_in, ndim=1)
    y = as_finite_array("y_out", y_out, shape=(v.size,))
    k = int(np.argmax(v))
    if k == 0 or k == v.size - 1:
        raise ValueError("v_in: expected a rise to a maximum followed by a fall")
    vu, yu = v[:k + 1], y[:k + 1]
    vd, yd = v[k:][::-1], y[k:][::-1]
    lo_v, hi_v = max(vu.min(), vd.min()), v[k]
    vg = np.linspace(lo_v, hi_v, n_grid)
    gap_out = np.interp(vg, vd, yd) - np.interp(vg, vu, yu)
    lo_y, hi_y = max(yu.min(), yd.min()), min(yu.max(), yd.max())
    yg = np.linspace(lo_y, hi_y, n_grid)
    gap_in = np.interp(yg, yu, vu) - np.interp(yg, yd, vd)
    out_pct = 100.0 * float(np.max(np.abs(gap_out))) / float(y.max() - y.min())
    in_pct = 100.0 * float(np.max(np.abs(gap_in))) / float(v.max() - v.min())
    return out_pct, in_pct
