"""Smooth command ramps used to move the stage without exciting its resonances."""
from __future__ import annotations

import numpy as np

__all__ = ["raised_cosine"]


def raised_cosine(n: int, rise_fraction: float = 1.0) -> np.ndarray:
    """(n,) ramp 0 -> 1 as half a cosine over the first ``rise_fraction * n`` samples, then 1."""
    return 0.5 * (1 - np.cos(np.pi * np.minimum(np.arange(n) / (rise_fraction * n), 1.0)))
