"""Scanning-probe imaging with the closed loop: scan patterns, a synthetic sample, images and their metrics.

A scanning probe microscope moves the sample under the tip along a pattern and
records the tip's signal (here the sample's height under the tip) together
with the position it assigns to it. The image is that record resampled onto
the pixel grid. Its errors come from where the tip really was (the table)
against where the image puts it: the commanded pattern (``placement =
"reference"``, the nominal raster of a conventional instrument) or the sensor
reading (``"sensor"``, an instrument that records its position sensors).

Patterns (Fleming & Leang, *Design, Modeling and Control of Nanopositioning
Systems*, Springer 2014, Ch. 1 and 10; Yong, Moheimani & Petersen, "High-speed
cycloid-scan atomic force microscopy", Nanotechnology 21, 2010; Mahmood &
Moheimani, "Spiral-scan atomic force microscopy", Nanotechnology 20, 2009;
Tuma et al., "High-speed multiresolution scanning probe microscopy based on
Lissajous scan trajectories", Nanotechnology 23, 2012; Bazaei, Yong &
Moheimani, "High-speed Lissajous-scan atomic force microscopy", RSI 83, 2012)
are sampled at the loop rate, over a square field of ``size_um`` with
``pixels`` x ``pixels`` pixels of pitch ``p = size_um / pixels``. Every
pattern takes the same frame time ``T = pixels / line_rate_hz`` (a raster's
``pixels`` lines, one trace and one retrace each), so patterns compare at
equal imaging speed:

- raster: triangle fast axis (X) at ``line_rate_hz``, overscanning the
  field so that the turnarounds fall outside it; slow axis (Y) a staircase
  (one pixel row per line) or a ramp of ``p`` per line;
- spiral (Archimedean, ring pitch ``p``, ``pixels / 2`` rings out to the
  radius ``size_um / 2``): constant angular velocity, ``r = R t / T``,
  ``theta = 2 pi (pixels / 2) t / T``; or constant linear velocity, the arc
  length ``s(theta) = (a / 2) (theta sqrt(1 + theta^2) + asinh theta)``,
  ``a = p / (2 pi)``, inverted at ``s = v t``;
- Lissajous: ``x = c + R sin(2 pi f_x t)``, ``y = c + R sin(2 pi f_y t)``
  with ``f_x = n / T``, ``f_y = (n - 1) / T`` (closed after ``T``); the line
  spacing at the centre, ``pi R / (2 n)``, equals ``p`` for ``n = pi pixels / 4``;
- rosette: ``x + i y = c + (R / 2) (exp(i 2 pi f_1 t) + exp(-i 2 pi f_2 t))``,
  a diameter ``R cos(pi (f_1 + f_2) t)`` turning at ``pi (f_1 - f_2)``;
  ``f_1 - f_2 = 1 / T`` (half a turn per frame) and ``f_1 + f_2 = m / T``,
  ``m`` the odd integer nearest ``pi pixels / 2`` (spacing ``p`` at the rim).

Each pattern is led in by one line period ``1 / line_rate_hz`` that is not
imaged (the raster's first line; the others grow from their start point under
a raised-cosine envelope), so the frame starts in the loop's steady motion.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from nanosim.experiments.loop import FS, LoopTrace, run_closed_loop  # noqa: F401 (FS: the patterns' rate, read as scan.FS)
from nanosim.experiments.scan_patterns import (  # noqa: F401 (_choice re-exported: nanosim.pipeline.scan)
    PATTERNS,
    PLACEMENTS,
    ScanPattern,
    _choice,
    _positive,
    lissajous,
    pattern_reference,
    raster,
    rosette,
    scan_pattern,
    spiral,
)

__all__ = ["PATTERNS", "PLACEMENTS", "ScanPattern", "Sample", "ScanImage", "ScanResult", "raster", "spiral",
           "lissajous", "rosette", "scan_pattern", "pattern_reference", "form_image", "raster_image", "analyse_scan",
           "trace_retrace_offset_um", "run_scan", "run_scan_batch", "line_rate_at_limit"]

# ------------------------------------------------------------------------------------------------ sample
@dataclass(frozen=True)
class Sample:
    """Synthetic sample: a calibration grating of square pillars plus a random rough surface.

    ``h(x, y) = H g(x) g(y) + rough(x, y)``, nm, with the smoothed square wave
    ``g(u) = (1 + tanh(beta sin(2 pi u / P)) / tanh(beta)) / 2`` (pillars of pitch ``P``, edges of
    width about ``P / (pi beta)``, the width a finite tip radius gives the edges of a real grating)
    and the rough surface a Gaussian random field of rms ``sigma`` and correlation length ``l``
    (autocorrelation ``sigma^2 exp(-r^2 / l^2)``, spectrum ``pi l^2 sigma^2 exp(-k^2 l^2 / 4)``),
    synthesised by filtering white noise from ``seed`` in the Fourier domain on a periodic grid of
    ``period_um`` with ``grid`` points per side (Shinozuka & Deodatis, Appl. Mech. Rev. 44, 1991),
    scaled to rms ``sigma`` exactly, and read between grid points by cubic splines
    (:func:`scipy.ndimage.map_coordinates`).

    The defaults put four grating periods in a 20 um field at a height in the range of commercial
    lateral calibration gratings (tens to hundreds of nm), with edges and roughness a few 78 nm
    pixels wide so that the image samples them; the grid spacing is an eighth of ``l``.
    """

    pitch_um: float = 5.0
    grating_height_nm: float = 100.0
    edge_sharpness: float = 3.0
    roughness_nm: float = 5.0
    correlation_um: float = 0.5
    period_um: float = 32.0
    grid: int = 512
    seed: int = 0
    _coef: np.ndarray = field(init=False, repr=False, compare=False)

    def __post_init__(self):
        for name in ("pitch_um", "correlation_um", "edge_sharpness", "period_um"):
            _positive(name, getattr(self, name))
        for name in ("grating_height_nm", "roughness_nm"):
            v = getattr(self, name)
            if not isinstance(v, (int, float, np.integer, np.floating)) or not np.isfinite(v) or v < 0:
                raise ValueError(f"{name}: expected a finite number >= 0, got {v!r}")
        _positive("grid", self.grid, integer=True)
        if not isinstance(self.seed, (int, np.integer)) or isinstance(self.seed, bool) or self.seed < 0:
            raise ValueError(f"seed: expected a non-negative int, got {self.seed!r}")
        from scipy import ndimage

        n, L, ell = int(self.grid), float(self.period_um), float(self.correlation_um)
        w = np.random.default_rng(int(self.seed)).standard_normal((n, n))
        k = 2 * np.pi * np.fft.fftfreq(n, L / n)
        k2 = k[:, None] ** 2 + k[None, :] ** 2
        rough = np.fft.ifft2(np.fft.fft2(w) * np.exp(-k2 * ell ** 2 / 8)).real
        rough *= self.roughness_nm / rough.std() if self.roughness_nm > 0 else 0.0
        object.__setattr__(self, "_coef", ndimage.spline_filter(rough, order=3, mode="grid-wrap"))

    def _g(self, u):
        b = self.edge_sharpness
        return 0.5 * (1.0 + np.tanh(b * np.sin(2 * np.pi * u / self.pitch_um)) / np.tanh(b))

    def height_nm(self, x_um, y_um) -> np.ndarray:
        """Height at ``(x_um, y_um)`` (arrays of one shape), nm."""
        from scipy import ndimage

        x, y = np.broadcast_arrays(np.asarray(x_um, float), np.asarray(y_um, float))
        h = self.grating_height_nm * self._g(x) * self._g(y)
        if self.roughness_nm > 0:
            d = self.period_um / self.grid                     # grid point (i, j) at (x, y) = (j d, i d)
            rough = ndimage.map_coordinates(self._coef, [y.ravel() / d, x.ravel() / d], order=3,
                                            mode="grid-wrap", prefilter=False)
            h = h + rough.reshape(x.shape)
        return h

    def truth(self, size_um: float, pixels: int) -> np.ndarray:
        """The ideal image: the height at the pixel centres, ``(pixels, pixels)`` (row = Y), nm."""
        c = (np.arange(pixels) + 0.5) * size_um / pixels
        return self.height_nm(c[None, :], c[:, None])


# ------------------------------------------------------------------------------------------------ images
def _pixel_centres(size_um: float, pixels: int):
    c = (np.arange(pixels) + 0.5) * size_um / pixels
    return np.meshgrid(c, c)


# The longest triangle edge (in pixel pitches) the image interpolates across. Every pattern spaces its
# lines one pitch apart, so within a covered region neighbouring cell means are at most two cells and a
# diagonal apart (2 sqrt 2 pitches); a longer edge bridges a gap the records do not cover (at the convex
# hull, between a Lissajous's or a rosette's turnarounds), where a linear interpolation over microns of a
# grating is no image of it.
MAX_EDGE_PIXELS = 3.0


def form_image(xy_um: np.ndarray, height_nm: np.ndarray, size_um: float, pixels: int,
               margin: int = 4, max_edge_pixels: float = MAX_EDGE_PIXELS) -> np.ndarray:
    """Resample heights recorded at ``xy_um`` (M, 2) onto the pixel centres (row = Y), nm.

    The records are first averaged per pixel cell (their mean position and mean height, cells
    ``margin`` pixels beyond the field included), then interpolated linearly on the Delaunay
    triangulation of those cell means (:class:`scipy.interpolate.LinearNDInterpolator`). A pixel is
    imaged only inside a triangle whose edges are at most ``max_edge_pixels`` pitches long: NaN outside
    the convex hull and where a longer triangle bridges a gap between the records. For a height linear
    across a cell the cell mean is exact; the averaging bounds the triangulation at one point per cell.
    Records in fewer than three cells, or all on one line, give an image of NaN.
    """
    from scipy.interpolate import LinearNDInterpolator
    from scipy.spatial import Delaunay, QhullError

    xy = np.asarray(xy_um, float)
    h = np.asarray(height_nm, float)
    if xy.ndim != 2 or xy.shape[1] != 2 or len(xy) != len(h):
        raise ValueError(f"xy_um: expected shape (M, 2) with M = len(height_nm) = {len(h)}, got {xy.shape}")
    if not np.isfinite(max_edge_pixels) or max_edge_pixels <= 0:
        raise ValueError(f"max_edge_pixels: expected a finite number > 0, got {max_edge_pixels!r}")
    p = size_um / pixels
    ij = np.floor(xy / p).astype(np.int64) + margin
    side = pixels + 2 * margin
    inside = np.all((ij >= 0) & (ij < side), axis=1) & np.isfinite(h)
    flat = ij[inside, 1] * side + ij[inside, 0]
    cnt = np.bincount(flat, minlength=side * side)
    occ = cnt > 0
    X, Y = _pixel_centres(size_um, pixels)
    means = [np.bincount(flat, v, side * side)[occ] / cnt[occ] for v in (xy[inside, 0], xy[inside, 1], h[inside])]
    pts = np.column_stack(means[:2])
    try:
        tri = Delaunay(pts)
    except (ValueError, QhullError):        # records in fewer than 3 cells, or on one line: nothing to image
        return np.full(X.shape, np.nan)
    q = np.column_stack([X.ravel(), Y.ravel()])
    img = LinearNDInterpolator(tri, means[2])(q)
    corners = pts[tri.simplices]                                          # (triangles, 3, 2)
    longest = np.linalg.norm(corners - np.roll(corners, 1, axis=1), axis=2).max(axis=1)
    simplex = tri.find_simplex(q)
    img[(simplex < 0) | (longest[simplex] > max_edge_pixels * p)] = np.nan
    return img.reshape(X.shape)


def coverage_mask(xy_um: np.ndarray, size_um: float, pixels: int) -> np.ndarray:
    """Pixels whose centre lies within one pitch of a position of the pattern ``xy_um`` (M, 2)."""
    from scipy.spatial import cKDTree

    X, Y = _pixel_centres(size_um, pixels)
    d, _ = cKDTree(np.asarray(xy_um, float)).query(np.column_stack([X.ravel(), Y.ravel()]))
    return (d <= size_um / pixels).reshape(X.shape)


def _fill_nearest(img: np.ndarray) -> np.ndarray:
    bad = ~np.isfinite(img)
    if not bad.any() or bad.all():
        return img
    from scipy import ndimage
    idx = ndimage.distance_transform_edt(bad, return_distances=False, return_indices=True)
    return img[tuple(idx)]


def trace_retrace_offset_um(trace_nm: np.ndarray, retrace_nm: np.ndarray, pitch_um: float,
                            upsample: int = 32) -> float:
    """Shift of the trace image against the retrace image along the fast axis (X), um.

    ``d`` such that ``trace(x) = retrace(x - d)`` (positive: features appear further along the
    trace direction in the trace image, the signature of a lag). Estimated from the peak of the
    rows' summed cross-correlation (mean removed, Hann-windowed, zero-padded), Fourier-interpolated by
    ``upsample`` and refined by a parabola through its top three points.
    """
    a = _fill_nearest(np.asarray(trace_nm, float))
    b = _fill_nearest(np.asarray(retrace_nm, float))
    if a.shape != b.shape or a.ndim != 2:
        raise ValueError(f"retrace_nm: expected the trace image's shape {a.shape}, got {b.shape}")
    n = a.shape[1]
    w = np.hanning(n)
    a = (a - a.mean(axis=1, keepdims=True)) * w
    b = (b - b.mean(axis=1, keepdims=True)) * w
    X = (np.fft.rfft(a, 2 * n, axis=1) * np.conj(np.fft.rfft(b, 2 * n, axis=1))).sum(axis=0)
    cc = np.fft.irfft(X, 2 * n * upsample) * upsample
    k = int(np.argmax(cc))
    y0, y1, y2 = cc[k - 1], cc[k], cc[(k + 1) % len(cc)]
    den = y0 - 2 * y1 + y2
    frac = 0.5 * (y0 - y2) / den if den != 0 else 0.0
    lag = (k + frac) / upsample
    if lag > n:
        lag -= 2 * n
    return float(lag * pitch_um)


@dataclass(frozen=True)
class ScanImage:
    """Image of one set of records: the image, its error against the truth and its summary (nm).

    ``imaged_fraction`` is the share of the covered pixels (the result's ``mask``) the image reaches;
    the error rms, max and fraction are over those.
    """

    image_nm: np.ndarray
    error_nm: np.ndarray
    rms_error_nm: float
    max_error_nm: float
    error_fraction: float
    imaged_fraction: float


@dataclass(frozen=True)
class ScanResult:
    """One closed-loop scan, imaged.

    Attributes
    ----------
    pattern : ScanPattern
    placement : {"reference", "sensor"}
        Where the image puts each record: the commanded (interpolated) position or the sensor reading.
    truth_nm : ndarray (pixels, pixels)
        The sample at the pixel centres.
    mask : ndarray of bool (pixels, pixels)
        Pixels the pattern covers (the image metrics are over these).
    image : ScanImage
        From every imaged record (:func:`form_image`); raster: the trace lines, row by row
        (:func:`raster_image`).
    retrace : ScanImage or None
        Raster: from the retrace lines.
    trace_retrace_offset_um : float
        Raster: :func:`trace_retrace_offset_um` of the two images (NaN for the other patterns).
    position_error_rms_nm, position_error_max_nm : ndarray (pixels, pixels)
        Per pixel, rms and max of ``|table - placed|`` over the records placed in it (NaN where none).
    distortion_um : ndarray (pixels, pixels, 2)
        Per pixel, the mean of ``table - placed`` (X, Y): where the tip was against where the image
        puts it.
    position_rms_nm, position_max_nm : float
        Over every imaged record.
    height_range_nm : float
        Peak to peak of the truth over the mask.
    upsample : int
        Records per loop sample (positions interpolated linearly in time) so that neighbouring records
        are at most half a pixel apart.
    trace : LoopTrace
        The closed-loop record.
    """

    pattern: ScanPattern
    placement: str
    truth_nm: np.ndarray
    mask: np.ndarray
    image: ScanImage
    retrace: ScanImage | None
    trace_retrace_offset_um: float
    position_error_rms_nm: np.ndarray
    position_error_max_nm: np.ndarray
    distortion_um: np.ndarray
    position_rms_nm: float
    position_max_nm: float
    height_range_nm: float
    upsample: int
    trace: LoopTrace

    def metrics(self) -> dict:
        """The scalar metrics, with units in the keys."""
        p = self.pattern
        d = {"pattern": p.name, "label": p.label, "placement": self.placement, "size_um": p.size_um,
             "pixels": p.pixels, "line_rate_hz": p.line_rate_hz, "frame_s": p.frame_s,
             "freqs_hz": list(p.freqs_hz), "coverage_fraction": float(self.mask.mean()),
             "height_range_nm": self.height_range_nm,
             "image_error_rms_nm": self.image.rms_error_nm, "image_error_max_nm": self.image.max_error_nm,
             "image_error_fraction": self.image.error_fraction, "imaged_fraction": self.image.imaged_fraction,
             "position_error_rms_nm": self.position_rms_nm, "position_error_max_nm": self.position_max_nm,
             "distortion_max_nm": float(1e3 * np.nanmax(np.hypot(self.distortion_um[..., 0],
                                                                  self.distortion_um[..., 1]))),
             "trace_retrace_offset_nm": 1e3 * self.trace_retrace_offset_um,
             "saturated_fraction": float(self.trace.saturated[self.pattern.imaged].any(axis=1).mean())}
        if self.retrace is not None:
            d["retrace_image_error_rms_nm"] = self.retrace.rms_error_nm
            d["retrace_image_error_fraction"] = self.retrace.error_fraction
        return d


def _upsampled(a: np.ndarray, k: int) -> np.ndarray:
    """Linear interpolation of the rows of ``a`` (M, d) at ``k`` points per interval (the last row kept)."""
    if k == 1:
        return a
    s = np.arange(k) / k
    out = a[:-1, None, :] * (1 - s)[None, :, None] + a[1:, None, :] * s[None, :, None]
    return np.concatenate([out.reshape(-1, a.shape[1]), a[-1:]])


def raster_image(x_um: np.ndarray, height_nm: np.ndarray, line: np.ndarray, keep: np.ndarray, size_um: float,
                 pixels: int) -> np.ndarray:
    """A raster's image as the instrument builds it: row ``j`` is line ``j``'s records (``keep``: trace or
    retrace) interpolated linearly in their X at the pixel centres; NaN beyond a line's records.

    Parameters
    ----------
    x_um : ndarray (M,)
        Placed X of every record, um.
    height_nm : ndarray (M,)
        Height seen by the tip, nm.
    line : ndarray of int (M,)
        Line of each record, ``0 .. pixels - 1``.
    keep : ndarray of bool (M,)
        Records of the image (the trace or the retrace).
    """
    c = (np.arange(pixels) + 0.5) * size_um / pixels
    img = np.full((pixels, pixels), np.nan)
    sel = keep & (line >= 0) & (line < pixels)
    x, h, ln = x_um[sel], height_nm[sel], line[sel]
    order = np.lexsort((x, ln))
    x, h, ln = x[order], h[order], ln[order]
    bounds = np.searchsorted(ln, np.arange(pixels + 1))
    for j in range(pixels):
        a, b = bounds[j], bounds[j + 1]
        if b - a >= 2:
            img[j] = np.interp(c, x[a:b], h[a:b], left=np.nan, right=np.nan)
    return img


def _summary(img, truth, mask, rng_nm) -> ScanImage:
    """The image's errors over the covered pixels it reaches; covered pixels it does not reach are
    missing (``imaged_fraction``), not in the rms.
    """
    err = img - truth
    reached = mask & np.isfinite(err)
    e = err[reached]
    rms = float(np.sqrt(np.mean(e ** 2))) if e.size else float("nan")
    mx = float(np.abs(e).max()) if e.size else float("nan")
    imaged = float(reached.sum() / mask.sum()) if mask.any() else float("nan")
    return ScanImage(img, err, rms, mx, rms / rng_nm if rng_nm > 0 else float("nan"), imaged)


def _image(xy, h, keep, truth, mask, size_um, pixels, rng_nm) -> ScanImage:
    return _summary(form_image(xy[keep], h[keep], size_um, pixels), truth, mask, rng_nm)


def _pixel_stats(xy, e_um, size_um, pixels):
    p = size_um / pixels
    ij = np.clip(np.floor(xy / p).astype(int), 0, pixels - 1)
    flat = ij[:, 1] * pixels + ij[:, 0]
    cnt = np.bincount(flat, minlength=pixels * pixels).astype(float)
    mag2 = (1e3 * np.hypot(e_um[:, 0], e_um[:, 1])) ** 2
    with np.errstate(invalid="ignore", divide="ignore"):
        rms = np.sqrt(np.bincount(flat, mag2, pixels * pixels) / cnt)
        mean = np.stack([np.bincount(flat, e_um[:, i], pixels * pixels) / cnt for i in range(2)], axis=-1)
    mx = np.full(pixels * pixels, -np.inf)
    np.maximum.at(mx, flat, np.sqrt(mag2))
    mx[cnt == 0] = np.nan
    shape = (pixels, pixels)
    return rms.reshape(shape), mx.reshape(shape), mean.reshape(shape + (2,))


def analyse_scan(pattern: ScanPattern, trace: LoopTrace, sample: Sample, placement: str = "reference") -> ScanResult:
    """Image ``sample`` from the closed-loop ``trace`` of ``pattern`` and measure the image.

    The tip sees the height at the table's true position; the image puts it at the commanded
    position (``placement = "reference"``) or the sensor reading (``"sensor"``). Records are
    interpolated linearly in time between loop samples (a detector sampled faster than the loop) so that
    neighbouring records are at most half a pixel apart, then resampled onto the pixel grid: a raster row
    by row (:func:`raster_image`: line ``j`` is row ``j``, its records placed by their X), the other
    patterns in two dimensions (:func:`form_image`).
    """
    _choice("placement", placement, PLACEMENTS)
    if len(trace.t_s) != len(pattern.t_s):
        raise ValueError(f"trace: expected {len(pattern.t_s)} samples (the pattern's), got {len(trace.t_s)}")
    size, px = pattern.size_um, pattern.pixels
    placed = (trace.ref_um if placement == "reference" else trace.y_um)[:, :2]
    true = trace.table_um[:, :2]
    step = np.hypot(*np.diff(trace.ref_um[pattern.imaged, :2], axis=0).T)
    k = int(np.clip(np.ceil(2.0 * (step.max() if step.size else 0.0) / pattern.pitch_um), 1, 64))
    sel = np.flatnonzero(pattern.imaged)
    placed_u, true_u = _upsampled(placed[sel], k), _upsampled(true[sel], k)
    ref_u = _upsampled(trace.ref_um[sel, :2], k)
    direction = np.repeat(pattern.direction[sel], k)[:len(placed_u)]
    h = sample.height_nm(true_u[:, 0], true_u[:, 1])
    truth = sample.truth(size, px)
    mask = coverage_mask(ref_u, size, px)
    rng_nm = float(np.ptp(truth[mask])) if mask.any() else 0.0
    retrace = None
    offset = float("nan")
    if pattern.name == "raster":
        line = np.repeat(np.floor(pattern.t_s[sel] * pattern.line_rate_hz).astype(int), k)[:len(placed_u)]
        image = _summary(raster_image(placed_u[:, 0], h, line, direction > 0, size, px), truth, mask, rng_nm)
        retrace = _summary(raster_image(placed_u[:, 0], h, line, direction < 0, size, px), truth, mask, rng_nm)
        offset = trace_retrace_offset_um(image.image_nm, retrace.image_nm, pattern.pitch_um)
    else:
        image = _image(placed_u, h, direction > 0, truth, mask, size, px, rng_nm)
    e = true_u - placed_u
    rms_map, max_map, dist = _pixel_stats(placed_u, e, size, px)
    mag = 1e3 * np.hypot(e[:, 0], e[:, 1])
    return ScanResult(pattern, placement, truth, mask, image, retrace, offset, rms_map, max_map, dist,
                      float(np.sqrt(np.mean(mag ** 2))), float(mag.max()), rng_nm, k, trace)


def run_scan(stage, controller, pattern: ScanPattern, sample: Sample, placement: str = "reference") -> ScanResult:
    """Run ``pattern`` in closed loop on ``stage`` (reset controller, settle at its first point), image it."""
    _choice("placement", placement, PLACEMENTS)
    controller.reset()
    cl = run_closed_loop(stage, controller, pattern_reference(pattern))
    return analyse_scan(pattern, cl, sample, placement)


def run_scan_batch(stage, bank, patterns, sample: Sample, placement: str = "reference") -> list:
    """Run ``patterns`` (all of one length) together, one per member of a batch stage and bank.

    ``stage`` a :class:`~nanosim.plant.batch.BatchTwinStage` or
    :class:`~nanosim.plant.batch.BatchMujocoStage` with one member per pattern; ``bank`` a
    :class:`~nanosim.experiments.batch_loop.BatchController` of as many members (reset here).
    Member ``b`` gives the numbers of :func:`run_scan` on its own stage.
    """
    from nanosim.experiments.batch_loop import run_closed_loop_batch

    _choice("placement", placement, PLACEMENTS)
    patterns = list(patterns)
    lengths = {len(p.t_s) for p in patterns}
    if len(lengths) != 1:
        raise ValueError(f"patterns: expected one length for a batch, got {sorted(lengths)}")
    if stage.n != len(patterns):
        raise ValueError(f"patterns: expected {stage.n} (one per batch member), got {len(patterns)}")
    bank.reset()
    refs = np.stack([pattern_reference(p) for p in patterns])
    traces = run_closed_loop_batch(stage, bank, refs)
    return [analyse_scan(p, tr, sample, placement) for p, tr in zip(patterns, traces)]


def line_rate_at_limit(line_rates_hz, error_fraction, limit: float) -> tuple[float, str]:
    """The highest line rate at which the image error stays under ``limit``.

    Scanning the rates upward, the first rate over the limit ends the range; between it and the
    rate before, ``log(error)`` is interpolated linearly in ``log(rate)`` to the limit.

    Returns
    -------
    rate_hz : float
        The crossing, Hz; the highest rate measured if none is over the limit; NaN if the lowest is over.
    status : {"crossed", "below_all", "above_all"}
        ``"below_all"``: every measured rate is under the limit (the crossing is above the highest);
        ``"above_all"``: the lowest measured rate is already over it.
    """
    r = np.asarray(line_rates_hz, float)
    e = np.asarray(error_fraction, float)
    order = np.argsort(r)
    r, e = r[order], e[order]
    over = np.flatnonzero(~(e < limit))
    if not len(over):
        return float(r[-1]), "below_all"
    i = int(over[0])
    if i == 0:
        return float("nan"), "above_all"
    r0, r1, e0, e1 = r[i - 1], r[i], e[i - 1], e[i]
    if not np.isfinite(e1) or e1 <= e0 or e0 <= 0:
        return float(r0), "crossed"
    s = (np.log(limit) - np.log(e0)) / (np.log(e1) - np.log(e0))
    return float(np.exp(np.log(r0) + s * (np.log(r1) - np.log(r0)))), "crossed"
