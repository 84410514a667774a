"""A scan run live in the viewer: the pattern's references step by step, the image binned as it forms.

The viewer's references are displacements from home, so the pattern's field
``[0, size]^2`` is centred on home. The scan first moves from the current
reference to the pattern's first point (a raised cosine of
the approach time of
:data:`~nanosim.experiments.loop.LOOP_PROTOCOL`), then runs the pattern through the
bench's command interpolation (:func:`nanosim.experiments.scan.pattern_reference`).
Each imaged sample adds the sample's height at the table's true position to the
pixel of the sensor reading (raster: trace lines only); a pixel shows the mean of
its records. The viewer shows the image at the GUI rate (:meth:`LiveScan.image_rgb`).
"""
from __future__ import annotations

import numpy as np

from nanosim.experiments import scan as S
from nanosim.experiments.loop import LOOP_PROTOCOL
from nanosim.ramps import raised_cosine

__all__ = ["LiveScan", "height_rgb"]


def height_rgb(h_nm: np.ndarray, lo: float, hi: float, empty=None) -> np.ndarray:
    """Heights (nm) as an ``(H, W, 3)`` uint8 image in an AFM-style black-red-yellow-white scale.

    ``empty`` (bool mask, optional): pixels drawn dark blue-grey (no record yet).
    """
    v = np.clip((np.nan_to_num(h_nm, nan=lo) - lo) / max(hi - lo, 1e-12), 0.0, 1.0)
    rgb = np.stack([np.clip(2 * v, 0, 1), np.clip(2 * v - 0.5, 0, 1), np.clip(2 * v - 1, 0, 1)], axis=-1)
    out = (255 * rgb).astype(np.uint8)
    if empty is not None:
        out[empty] = (40, 44, 60)
    return out


class LiveScan:
    """One scan pattern run sample by sample (not thread-safe: the physics thread steps it).

    Parameters
    ----------
    pattern : str
        One of :data:`nanosim.experiments.scan.PATTERNS`.
    size_um, pixels, line_rate_hz
        As :func:`nanosim.experiments.scan.scan_pattern`.
    start_um : array_like (3,)
        The reference when the scan starts (um from home).
    fs : float
        Loop rate, Hz.
    """

    def __init__(self, pattern: str, size_um: float, pixels: int, line_rate_hz: float, start_um=(0.0, 0.0, 0.0),
                 fs: float = S.FS, sample: S.Sample | None = None):
        self.pattern = S.scan_pattern(pattern, size_um, pixels, line_rate_hz, fs=fs)
        self.sample = sample or S.Sample()
        ref = S.pattern_reference(self.pattern)
        ref[:, :2] -= size_um / 2
        start = np.asarray(start_um, float)
        w = raised_cosine(int(LOOP_PROTOCOL.approach_s * fs), 0.6)
        pre = start + w[:, None] * (ref[0] - start)
        self.ref_um = np.concatenate([pre, ref])
        imaged = self.pattern.imaged & (self.pattern.direction > 0)
        self.imaged = np.concatenate([np.zeros(len(pre), bool), imaged])
        self.k = 0
        self.size_um, self.pixels = float(size_um), int(pixels)
        self._sum = np.zeros(pixels * pixels)
        self._cnt = np.zeros(pixels * pixels)
        truth = self.sample.truth(size_um, pixels)
        self.truth_nm = truth
        self.lo, self.hi = float(truth.min()), float(truth.max())

    @property
    def done(self) -> bool:
        return self.k >= len(self.ref_um)

    @property
    def progress(self) -> float:
        """Fraction of the samples run, 0..1."""
        return min(1.0, self.k / len(self.ref_um))

    @property
    def filled(self) -> float:
        """Fraction of the pixels with at least one record."""
        return float(np.count_nonzero(self._cnt) / self._cnt.size)

    def next_reference(self) -> np.ndarray:
        """The reference of the next sample (um from home); the last one once done."""
        return self.ref_um[min(self.k, len(self.ref_um) - 1)]

    def record(self, meas_um, table_um) -> None:
        """Account the samples just run, ``(n, 3)`` sensor readings and true table positions (um from home)."""
        meas = np.atleast_2d(np.asarray(meas_um, float))
        table = np.atleast_2d(np.asarray(table_um, float))
        n = min(len(meas), len(self.ref_um) - self.k)
        if n <= 0:
            return
        keep = self.imaged[self.k:self.k + n]
        self.k += n
        if not keep.any():
            return
        c = self.size_um / 2
        m, t = meas[:n][keep, :2] + c, table[:n][keep, :2] + c
        h = self.sample.height_nm(t[:, 0], t[:, 1])
        ij = np.floor(m / (self.size_um / self.pixels)).astype(int)
        ok = np.all((ij >= 0) & (ij < self.pixels), axis=1)
        flat = ij[ok, 1] * self.pixels + ij[ok, 0]
        np.add.at(self._sum, flat, h[ok])
        np.add.at(self._cnt, flat, 1.0)

    def image_nm(self) -> np.ndarray:
        """The image so far, ``(pixels, pixels)`` (row = Y), NaN where no record fell yet."""
        with np.errstate(invalid="ignore", divide="ignore"):
            return (self._sum / self._cnt).reshape(self.pixels, self.pixels)

    def image_rgb(self) -> np.ndarray:
        """The image so far as uint8 RGB, top row = largest Y (as a micrograph is shown)."""
        img = self.image_nm()
        return height_rgb(img, self.lo, self.hi, empty=~np.isfinite(img))[::-1]
