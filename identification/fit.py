"""Fit factor of the seed paper (Sec. 3, Table 1)."""
from __future__ import annotations

import numpy as np

from .checks import as_signal, same_length

__all__ = ["fit_percent"]


def fit_percent(y, yhat):
    """Normalised fit ``100 * (1 - ||y - yhat|| / ||y - mean(y)||)`` per output.

    The paper's fit factor (Sec. 3): 100 % is a perfect fit, 0 % is no better
    than the mean of ``y``, and it is negative for worse fits.  Norms are
    Euclidean over time, computed for each column separately.

    Parameters
    ----------
    y : array_like, shape (n_samples,) or (n_samples, n_outputs)
        Measured output.
    yhat : array_like, same shape as ``y``
        Simulated (or predicted) model output.

    Returns
    -------
    float or numpy.ndarray of shape (n_outputs,)
        Fit in percent; a float for 1-D input.
    """
    one_d = np.ndim(y) == 1
    ys = as_signal("y", y)
    yh = as_signal("yhat", yhat)
    same_length("y", ys, "yhat", yh)
    if ys.shape != yh.shape:
        raise ValueError(f"yhat: expected shape {np.shape(y)} like y, got {np.shape(yhat)}")
    den = np.linalg.norm(ys - ys.mean(axis=0), axis=0)
    flat = np.flatnonzero(den == 0)
    if flat.size:
        raise ValueError(f"y: expected non-constant channels, got constant channel(s) {flat.tolist()}")
    fit = 100.0 * (1.0 - np.linalg.norm(ys - yh, axis=0) / den)
    return float(fit[0]) if one_d else fit
