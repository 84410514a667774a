"""The scan patterns of :mod:`nanosim.experiments.scan`: raster, spiral, Lissajous and rosette paths.

Each pattern (:class:`ScanPattern`, :func:`scan_pattern`) is the reference path of one frame, led in by
one line period that is not imaged; the geometry of each is described in :mod:`nanosim.experiments.scan`,
which re-exports these names.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from nanosim.experiments.loop import FS, INTERPOLATION_S, interpolate
from nanosim.ramps import raised_cosine

__all__ = ["PATTERNS", "PLACEMENTS", "SLOW_AXES", "SPIRAL_VELOCITIES", "ScanPattern", "raster", "spiral", "lissajous",
           "rosette", "scan_pattern", "pattern_reference"]


PATTERNS = ("raster", "spiral", "lissajous", "rosette")
PLACEMENTS = ("reference", "sensor")
SLOW_AXES = ("staircase", "ramp")
SPIRAL_VELOCITIES = ("linear", "angular")


def _positive(name: str, value, integer: bool = False):
    ok = isinstance(value, (int, np.integer)) and not isinstance(value, bool) if integer else \
        isinstance(value, (int, float, np.integer, np.floating)) and not isinstance(value, bool)
    if not ok or not np.isfinite(value) or value <= 0:
        kind = "a positive integer" if integer else "a positive finite number"
        raise ValueError(f"{name}: expected {kind}, got {value!r}")
    return int(value) if integer else float(value)


def _choice(name: str, value, choices) -> str:
    if value not in choices:
        raise ValueError(f"{name}: expected one of {', '.join(choices)}, got {value!r}")
    return value


@dataclass(frozen=True)
class ScanPattern:
    """A scan pattern sampled at ``fs`` (before the command interpolation).

    Attributes
    ----------
    name : str
        One of :data:`PATTERNS` (with its variant, e.g. ``"spiral (linear)"`` in ``label``).
    label : str
        Name and variant for figures and tables.
    t_s : ndarray, shape (N,)
        Time from the start of the frame, s (negative during the lead-in).
    xy_um : ndarray, shape (N, 2)
        Commanded X, Y in um from the probe origin (the field is ``[0, size_um]^2``).
    imaged : ndarray of bool, shape (N,)
        Samples of the frame (False during the lead-in).
    direction : ndarray of int8, shape (N,)
        Raster: +1 trace (X rising), -1 retrace; other patterns: +1 on every imaged sample.
    size_um, pixels, line_rate_hz
        The field, its pixels per side and the line rate (frame time ``pixels / line_rate_hz``).
    freqs_hz : tuple of float
        The pattern's frequencies (raster: fast axis; spiral: revolutions at the rim; Lissajous: f_x, f_y;
        rosette: f_1, f_2), Hz.
    fs : float
        Sample rate, Hz.
    """

    name: str
    label: str
    t_s: np.ndarray
    xy_um: np.ndarray
    imaged: np.ndarray
    direction: np.ndarray
    size_um: float
    pixels: int
    line_rate_hz: float
    freqs_hz: tuple
    fs: float = FS

    @property
    def pitch_um(self) -> float:
        """Pixel pitch ``size_um / pixels``, um."""
        return self.size_um / self.pixels

    @property
    def frame_s(self) -> float:
        """Frame time ``pixels / line_rate_hz``, s."""
        return self.pixels / self.line_rate_hz


def _time(pixels: int, line_rate_hz: float, fs: float):
    lead = int(round(fs / line_rate_hz))
    n = int(round(pixels / line_rate_hz * fs))
    if n < 4:
        raise ValueError(f"line_rate_hz: a frame of {pixels} lines at {line_rate_hz:g} Hz is {n} samples at "
                         f"{fs:g} Hz; expected at least 4")
    t = (np.arange(lead + n) - lead) / fs
    return t, t >= 0


def _envelope(t_s: np.ndarray, lead_s: float) -> np.ndarray:
    """0 -> 1 over the lead-in (raised cosine), 1 in the frame."""
    env = np.ones_like(t_s)
    k = t_s < 0
    if k.any():
        env[k] = raised_cosine(int(k.sum()), 1.0)
    return env


def _common(size_um, pixels, line_rate_hz, fs):
    return (_positive("size_um", size_um), _positive("pixels", pixels, integer=True),
            _positive("line_rate_hz", line_rate_hz), _positive("fs", fs))


def raster(size_um: float, pixels: int, line_rate_hz: float, slow_axis: str = "staircase",
           overscan_um: float | None = None, fs: float = FS) -> ScanPattern:
    """Raster: triangle fast axis X at ``line_rate_hz``, slow axis Y a staircase or a ramp.

    Parameters
    ----------
    size_um : float
        Side of the square field, um.
    pixels : int
        Pixels per side (and lines per frame).
    line_rate_hz : float
        Lines per second (one trace and one retrace each), Hz.
    slow_axis : {"staircase", "ramp"}
        Staircase: line ``j`` at the pixel row ``y = (j + 1/2) p``; ramp: ``y = p (t f + 1/4)``
        (the row centre at the middle of each trace), clipped to the field.
    overscan_um : float, optional
        The fast axis runs from ``-overscan_um`` to ``size_um + overscan_um`` so that its turnarounds,
        rounded by the command interpolation, fall outside the field; default ``v t_i / 2`` with
        ``v = 2 size_um line_rate_hz`` the nominal trace speed and ``t_i`` the interpolation time
        (:data:`~nanosim.experiments.loop.INTERPOLATION_S`): the two moving averages of ``t_i``
        cut a triangle's apex by ``v t_i / 3``.
    fs : float
        Sample rate, Hz.

    Returns
    -------
    ScanPattern
        Trace: X rising across the field in the first half of each line period.
    """
    size_um, pixels, f, fs = _common(size_um, pixels, line_rate_hz, fs)
    _choice("slow_axis", slow_axis, SLOW_AXES)
    if overscan_um is None:
        overscan_um = 2 * size_um * f * INTERPOLATION_S / 2
    elif not isinstance(overscan_um, (int, float, np.integer, np.floating)) or not np.isfinite(overscan_um) \
            or overscan_um < 0:
        raise ValueError(f"overscan_um: expected a finite number >= 0, got {overscan_um!r}")
    o = float(overscan_um)
    t, imaged = _time(pixels, f, fs)
    ph = t * f
    frac = ph - np.floor(ph)
    x = -o + (size_um + 2 * o) * (1.0 - np.abs(1.0 - 2.0 * frac))
    p = size_um / pixels
    if slow_axis == "staircase":
        y = (np.clip(np.floor(ph), 0, pixels - 1) + 0.5) * p
    else:
        y = np.clip(p * (np.maximum(ph, 0.0) + 0.25), 0.0, size_um)
    direction = np.where(frac < 0.5, 1, -1).astype(np.int8)
    return ScanPattern("raster", f"raster ({slow_axis})", t, np.column_stack([x, y]), imaged, direction,
                       size_um, pixels, f, (f,), fs)


def _clv_theta(s: np.ndarray, a: float, theta_max: float) -> np.ndarray:
    """Angle at arc length ``s`` of the spiral ``r = a theta`` (exact arc length, inverted by interpolation)."""
    th = np.linspace(0.0, theta_max, max(4096, int(theta_max * 64)))
    arc = 0.5 * a * (th * np.sqrt(1.0 + th ** 2) + np.arcsinh(th))
    return np.interp(s, arc, th)


def spiral(size_um: float, pixels: int, line_rate_hz: float, velocity: str = "linear",
           fs: float = FS) -> ScanPattern:
    """Archimedean spiral from the field's centre out to the radius ``size_um / 2``.

    Parameters
    ----------
    size_um, pixels, line_rate_hz, fs
        As :func:`raster`; the spiral has ``pixels / 2`` rings of pitch ``p`` in the frame time
        ``pixels / line_rate_hz``.
    velocity : {"linear", "angular"}
        Constant linear velocity (speed ``v = s_end / T``, ``s_end`` the spiral's arc length) or constant
        angular velocity (``line_rate_hz / 2`` revolutions per second).

    Returns
    -------
    ScanPattern
        ``freqs_hz``: the revolution rate at the rim, Hz.
    """
    size_um, pixels, f, fs = _common(size_um, pixels, line_rate_hz, fs)
    _choice("velocity", velocity, SPIRAL_VELOCITIES)
    t, imaged = _time(pixels, f, fs)
    T = pixels / f
    R = size_um / 2
    p = size_um / pixels
    a = p / (2 * np.pi)
    theta_max = R / a
    tt = np.clip(t, 0.0, None)
    if velocity == "angular":
        theta = theta_max * tt / T
        rim_hz = theta_max / (2 * np.pi * T)
    else:
        s_end = 0.5 * a * (theta_max * np.sqrt(1 + theta_max ** 2) + np.arcsinh(theta_max))
        theta = _clv_theta(s_end * tt / T, a, theta_max)
        rim_hz = (s_end / T) / (2 * np.pi * R)
    r = a * theta
    xy = size_um / 2 + np.column_stack([r * np.cos(theta), r * np.sin(theta)])
    return ScanPattern("spiral", f"spiral ({velocity} velocity)", t, xy, imaged, np.ones(len(t), np.int8),
                       size_um, pixels, f, (float(rim_hz),), fs)


def _frequencies(name: str, freqs_hz, default):
    if freqs_hz is None:
        return default
    f = tuple(freqs_hz)
    if len(f) != 2:
        raise ValueError(f"freqs_hz: expected two frequencies for the {name} pattern, got {len(f)}")
    return tuple(_positive("freqs_hz", v) for v in f)


def lissajous(size_um: float, pixels: int, line_rate_hz: float, freqs_hz=None, fs: float = FS) -> ScanPattern:
    """Lissajous ``x = c + R sin(2 pi f_x t)``, ``y = c + R sin(2 pi f_y t)`` over the square field.

    Parameters
    ----------
    size_um, pixels, line_rate_hz, fs
        As :func:`raster`.
    freqs_hz : (float, float), optional
        ``(f_x, f_y)``, Hz; default ``(n / T, (n - 1) / T)`` with ``n = round(pi pixels / 4)``
        and ``T = pixels / line_rate_hz``: the pattern closes after ``T`` with line spacing ``p``
        at the centre.
    """
    size_um, pixels, f, fs = _common(size_um, pixels, line_rate_hz, fs)
    T = pixels / f
    n = max(2, int(round(np.pi * pixels / 4)))
    fx, fy = _frequencies("lissajous", freqs_hz, (n / T, (n - 1) / T))
    t, imaged = _time(pixels, f, fs)
    R = size_um / 2
    env = _envelope(t, 1 / f)
    xy = R + env[:, None] * R * np.column_stack([np.sin(2 * np.pi * fx * t), np.sin(2 * np.pi * fy * t)])
    return ScanPattern("lissajous", "Lissajous", t, xy, imaged, np.ones(len(t), np.int8), size_um, pixels, f,
                       (float(fx), float(fy)), fs)


def rosette(size_um: float, pixels: int, line_rate_hz: float, freqs_hz=None, fs: float = FS) -> ScanPattern:
    """Rosette ``x + i y = c + (R / 2) (exp(i 2 pi f_1 t) + exp(-i 2 pi f_2 t))`` over the disc of radius R.

    Parameters
    ----------
    size_um, pixels, line_rate_hz, fs
        As :func:`raster`.
    freqs_hz : (float, float), optional
        ``(f_1, f_2)``, Hz; default ``((m + 1) / (2 T), (m - 1) / (2 T))``, ``m`` the odd integer
        nearest ``pi pixels / 2``: half a turn of the petals per frame, spacing ``p`` at the rim.
    """
    size_um, pixels, f, fs = _common(size_um, pixels, line_rate_hz, fs)
    T = pixels / f
    m = int(round(np.pi * pixels / 2))
    m += 1 - m % 2
    f1, f2 = _frequencies("rosette", freqs_hz, ((m + 1) / (2 * T), (m - 1) / (2 * T)))
    t, imaged = _time(pixels, f, fs)
    R = size_um / 2
    env = _envelope(t, 1 / f)
    z = 0.5 * R * env * (np.exp(2j * np.pi * f1 * t) + np.exp(-2j * np.pi * f2 * t))
    xy = R + np.column_stack([z.real, z.imag])
    return ScanPattern("rosette", "rosette", t, xy, imaged, np.ones(len(t), np.int8), size_um, pixels, f,
                       (float(f1), float(f2)), fs)


def scan_pattern(name: str, size_um: float, pixels: int, line_rate_hz: float, *, slow_axis: str = "staircase",
                 spiral_velocity: str = "linear", freqs_hz=None, overscan_um: float | None = None,
                 fs: float = FS) -> ScanPattern:
    """The pattern ``name`` (one of :data:`PATTERNS`) with its options; see each generator."""
    _choice("pattern", name, PATTERNS)
    if freqs_hz is not None and name not in ("lissajous", "rosette"):
        raise ValueError(f"freqs_hz: expected None for the {name} pattern (set by line_rate_hz; frequencies "
                         f"apply to lissajous and rosette), got {freqs_hz!r}")
    if name == "raster":
        return raster(size_um, pixels, line_rate_hz, slow_axis, overscan_um, fs)
    if name == "spiral":
        return spiral(size_um, pixels, line_rate_hz, spiral_velocity, fs)
    if name == "lissajous":
        return lissajous(size_um, pixels, line_rate_hz, freqs_hz, fs)
    return rosette(size_um, pixels, line_rate_hz, freqs_hz, fs)


def pattern_reference(pattern: ScanPattern, smoothing: bool = True) -> np.ndarray:
    """The loop's reference ``(N, 3)`` um: the pattern's X, Y, Z held at 0, through the bench's
    command interpolation (:func:`nanosim.experiments.loop.interpolate`) unless ``smoothing`` is False.
    """
    ref = np.zeros((len(pattern.t_s), 3))
    ref[:, :2] = pattern.xy_um
    return interpolate(ref, fs=pattern.fs) if smoothing else ref
