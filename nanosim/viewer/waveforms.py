"""Reference generators in micrometres vs time (pure, no server).

Every generator maps time t (s, scalar or array) to an (..., 3) XYZ
reference in um: ``ref = wf(t)``.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["PRESETS", "Waveform", "step", "triangle", "contour", "contour_period_s"]

PRESETS = ("hold", "step", "sine", "triangle", "contour")


def _t(t):
    return np.asarray(t, dtype=float)


@dataclass(frozen=True)
class Waveform:
    """Reference ``offset + amplitude * direction * shape(t)``.

    Attributes
    ----------
    kind : one of :data:`PRESETS`.
    offset_um : (3,) XYZ hold position.
    amplitude_um : peak (sine/triangle/step) or contour corner distance per axis.
    freq_hz : sine/triangle frequency; step: toggle frequency of the square wave
        (0 = single step at t_step_s).
    direction : (3,) axis weights the amplitude is applied to.
    speed_um_s : contour speed along the path.
    """

    kind: str = "hold"
    offset_um: tuple[float, float, float] = (0.0, 0.0, 0.0)
    amplitude_um: float = 1.0
    freq_hz: float = 1.0
    direction: tuple[float, float, float] = (1.0, 0.0, 0.0)
    speed_um_s: float = 20.0
    t_step_s: float = 0.0

    def __post_init__(self):
        if self.kind not in PRESETS:
            raise ValueError(f"waveform: unknown kind {self.kind!r} (expected one of {PRESETS})")

    def __call__(self, t) -> np.ndarray:
        t = _t(t)
        off = np.asarray(self.offset_um, float)
        d = np.asarray(self.direction, float)
        if self.kind == "hold":
            s = np.zeros_like(t)
        elif self.kind == "step":
            s = step(t, self.freq_hz, self.t_step_s)
        elif self.kind == "sine":
            s = np.sin(2 * np.pi * self.freq_hz * t)
        elif self.kind == "triangle":
            s = triangle(t, self.freq_hz)
        else:
            return off + contour(t, corner_um=(self.amplitude_um, self.amplitude_um), speed_um_s=self.speed_um_s)
        return off + self.amplitude_um * s[..., None] * d


def step(t, freq_hz: float = 0.0, t_step_s: float = 0.0) -> np.ndarray:
    """Unit step at ``t_step_s``; with ``freq_hz > 0`` a 0/1 square wave of that frequency."""
    t = _t(t) - t_step_s
    if freq_hz <= 0:
        return (t >= 0).astype(float)
    return ((t >= 0) & (np.mod(t * freq_hz, 1.0) < 0.5)).astype(float)


def triangle(t, freq_hz: float) -> np.ndarray:
    """Zero-mean triangle of unit peak, starting at 0 and rising (same phase as sin)."""
    ph = np.mod(_t(t) * freq_hz + 0.25, 1.0)
    return 1.0 - 4.0 * np.abs(ph - 0.5)


def contour(t, corner_um=(20.0, 20.0), speed_um_s: float = 20.0, z_um: float = 0.0) -> np.ndarray:
    """The paper's 45-degree contour: (0,0) -> corner -> (0,0) at constant speed, repeating.

    Returns (..., 3) XYZ in um. Period = 2 |corner| / speed.
    """
    if speed_um_s <= 0:
        raise ValueError(f"contour: speed must be positive, got {speed_um_s!r} um/s")
    c = np.asarray(corner_um, float)
    length = float(np.hypot(*c))
    if length == 0:
        s = np.zeros_like(_t(t))
    else:
        period = 2 * length / speed_um_s
        ph = np.mod(_t(t), period) / period          # 0..1
        s = 1.0 - np.abs(2.0 * ph - 1.0)             # 0 -> 1 -> 0
    xy = s[..., None] * c
    return np.concatenate([xy, np.full(s.shape + (1,), float(z_um))], axis=-1)


def contour_period_s(corner_um=(20.0, 20.0), speed_um_s: float = 20.0) -> float:
    return 2 * float(np.hypot(*corner_um)) / speed_um_s
