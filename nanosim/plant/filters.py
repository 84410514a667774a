"""Sampled models of the bench's continuous-time signal-chain elements (4 kHz, per channel).

Every element has ``step`` (one sample, shape ``(n_channels,)``) and ``run``
(``(N, n_channels)``), and ``run`` gives bit for bit the numbers of repeated
``step`` calls: the recursions are written in the direct-form-II-transposed
order of :func:`scipy.signal.lfilter`, which ``run`` uses.

- :class:`DelayLine` -- the controller's computation delay in whole samples.
- :class:`AmplifierLag` -- a first-order amplifier (small-signal bandwidth
  ``f_a``) driven by the zero-order-held command; its output is reported as the
  exact average over each sample period, which the mechanics holds.
- :class:`SampledFilter` -- a continuous low-pass (the capacitive gauge's output
  filter) sampled by the ADC: bilinear (Tustin) discretization prewarped at
  500 Hz, the middle of the stage's modal band. For a 5 kHz 2-pole filter the
  discrete response is within 0.1 % and 0.9 degrees of the continuous one up
  to 740 Hz; for 1 kHz within 3.5 % and 5 degrees (exact at 500 Hz). (A
  first-order hold would treat the displacement as piecewise linear, which
  itself attenuates a 740 Hz motion sampled at 4 kHz by 10 %.)
- :class:`FlickerShaper` -- white noise to ``1/f`` (flicker) noise by a cascade
  of first-order pole-zero sections, one pole per decade with the zero half a
  decade above it (the classic pole-zero-interlacing approximation: PSD slope
  -10 dB/decade within +/-0.3 dB between the first zero and the last pole).
"""
from __future__ import annotations

import math

import numpy as np
from scipy import signal

__all__ = ["DelayLine", "AmplifierLag", "PREWARP_HZ", "SampledFilter", "butterworth_lowpass", "enbw_hz",
           "FlickerShaper"]


class DelayLine:
    """Delay of ``n`` whole samples; the line holds ``initial`` (default 0) at reset.

    Parameters
    ----------
    n_samples : int
        Delay (>= 0).
    n_channels : int
        Channels.
    """

    def __init__(self, n_samples: int, n_channels: int):
        if isinstance(n_samples, bool) or int(n_samples) != n_samples or n_samples < 0:
            raise ValueError(f"n_samples: expected an integer >= 0, got {n_samples!r}")
        self.n = int(n_samples)
        self.n_channels = int(n_channels)
        self.reset()

    def reset(self, initial=0.0) -> None:
        """Fill the line with ``initial`` (scalar or ``(n_channels,)``)."""
        self._buf = np.zeros((self.n, self.n_channels)) + initial

    def step(self, x: np.ndarray) -> np.ndarray:
        """Push one sample ``(n_channels,)``; return the one ``n`` samples old."""
        if self.n == 0:
            return x
        out = self._buf[0].copy()
        self._buf = np.vstack([self._buf[1:], x[None, :]])
        return out

    def run(self, x: np.ndarray) -> np.ndarray:
        """Delay a sequence ``(N, n_channels)``."""
        if self.n == 0:
            return x
        full = np.vstack([self._buf, x])
        self._buf = full[len(x):].copy()
        return full[:len(x)].copy()


class AmplifierLag:
    """First-order amplifier ``tau v' = v_in - v`` driven by a zero-order-held input.

    With ``a = exp(-T / tau)`` and ``v_k`` the output at the start of period k::

        mean over period k = v_in + (v_k - v_in) * (tau / T) (1 - a)
        v_{k+1}           = v_in + (v_k - v_in) * a

    ``step``/``run`` return the period means (a lag of about ``tau`` for slow
    signals). ``bandwidth_Hz = None`` passes the input through.
    """

    def __init__(self, bandwidth_Hz: float | None, dt_s: float, n_channels: int):
        self.n_channels = int(n_channels)
        self.active = bandwidth_Hz is not None
        if self.active:
            tau = 1.0 / (2.0 * math.pi * float(bandwidth_Hz))
            self._a = math.exp(-dt_s / tau)
            self._m = (tau / dt_s) * (1.0 - self._a)
        self.reset()

    def reset(self) -> None:
        """Output 0 V."""
        self._v = np.zeros(self.n_channels)

    def step(self, v_in: np.ndarray) -> np.ndarray:
        """Period mean of the output for one held input ``(n_channels,)``."""
        if not self.active:
            return v_in
        vk = self._v
        # the arithmetic of lfilter([0, 1 - a], [1, -a]) in direct form II transposed
        self._v = v_in * (1.0 - self._a) - vk * (-self._a)
        return v_in + (vk - v_in) * self._m

    def run(self, v_in: np.ndarray) -> np.ndarray:
        """Period means for a sequence ``(N, n_channels)``."""
        if not self.active or not len(v_in):
            return v_in
        vk, zf = signal.lfilter([0.0, 1.0 - self._a], [1.0, -self._a], v_in, axis=0, zi=self._v[None, :])
        self._v = zf[0]
        return v_in + (vk - v_in) * self._m


def butterworth_lowpass(bandwidth_Hz: float, order: int):
    """Continuous Butterworth low-pass ``(num, den)`` with -3 dB at ``bandwidth_Hz`` (order 1 or 2)."""
    if order not in (1, 2):
        raise ValueError(f"order: expected 1 or 2, got {order!r}")
    return signal.butter(order, 2.0 * math.pi * float(bandwidth_Hz), analog=True)


def enbw_hz(bandwidth_Hz: float, order: int) -> float:
    """Equivalent noise bandwidth of a Butterworth low-pass: ``f_c (pi / 2n) / sin(pi / 2n)``."""
    x = math.pi / (2 * order)
    return float(bandwidth_Hz) * x / math.sin(x)


PREWARP_HZ = 500.0


class SampledFilter:
    """A continuous SISO filter per channel, discretized by Tustin prewarped at ``prewarp_Hz``.

    The state is set to steady state with the first input the filter sees after a reset.
    """

    def __init__(self, num, den, dt_s: float, n_channels: int, prewarp_Hz: float = PREWARP_HZ):
        w = 2.0 * math.pi * float(prewarp_Hz)
        b, a = signal.bilinear(num, den, fs=w / (2.0 * math.tan(w * dt_s / 2.0)))
        b = np.atleast_1d(np.squeeze(b))
        self._b = b / a[0]
        self._a = np.asarray(a, float) / a[0]
        self.n_channels = int(n_channels)
        self._order = len(self._a) - 1
        self.reset()

    def reset(self) -> None:
        """Forget the state (the next input sets the steady state)."""
        self._z = None

    def _init(self, x0: np.ndarray) -> None:
        zi = signal.lfilter_zi(self._b, self._a)                   # unit-step steady state
        self._z = zi[:, None] * x0[None, :]

    def step(self, x: np.ndarray) -> np.ndarray:
        """Filter one sample ``(n_channels,)``."""
        if self._z is None:
            self._init(x)
        b, a, z = self._b, self._a, self._z
        y = z[0] + x * b[0]                     # lfilter's direct form II transposed, term by term
        n = self._order
        self._z = np.stack([z[i + 1] + x * b[i + 1] - y * a[i + 1] for i in range(n - 1)]
                           + [x * b[n] - y * a[n]])
        return y

    def run(self, x: np.ndarray) -> np.ndarray:
        """Filter a sequence ``(N, n_channels)``."""
        if not len(x):
            return x.copy()
        if self._z is None:
            self._init(x[0])
        y, self._z = signal.lfilter(self._b, self._a, x, axis=0, zi=self._z)
        return y


class FlickerShaper:
    """Unit white noise -> flicker noise with one-sided PSD ``density_1Hz**2 / f``.

    Parameters
    ----------
    density_1Hz : float
        Amplitude spectral density at 1 Hz (units per sqrt(Hz)).
    f_min_Hz : float
        Lowest pole (the 1/f law holds from about ``3 f_min`` up).
    fs_Hz : float
        Sample rate; the last pole sits at or below ``fs / 20`` and the spectrum
        above the last zero is white at the level of the 1/f line there.
    n_channels : int
    """

    def __init__(self, density_1Hz: float, f_min_Hz: float, fs_Hz: float, n_channels: int):
        self.n_channels = int(n_channels)
        poles = f_min_Hz * 10.0 ** np.arange(0, int(math.floor(math.log10(fs_Hz / 20.0 / f_min_Hz))) + 1)
        zeros = poles * math.sqrt(10.0)
        self._sec = [(math.exp(-2 * math.pi * fz / fs_Hz), math.exp(-2 * math.pi * fp / fs_Hz))
                     for fp, fz in zip(poles, zeros)]
        w = 2 * math.pi * 1.0 / fs_Hz
        zinv = np.exp(-1j * w)
        h1 = abs(np.prod([(1 - bz * zinv) / (1 - ap * zinv) for bz, ap in self._sec]))
        # unit-variance white input: one-sided density sqrt(2 / fs)
        self._gain = float(density_1Hz) / (h1 * math.sqrt(2.0 / fs_Hz))
        self.reset()

    def reset(self) -> None:
        """Zero state."""
        self._z = np.zeros((len(self._sec), self.n_channels))

    def step(self, e: np.ndarray) -> np.ndarray:
        """Shape one white sample ``(n_channels,)``."""
        y = self._gain * e
        z = self._z.copy()
        for k, (bz, ap) in enumerate(self._sec):
            out = z[k] + y                      # lfilter([1, -bz], [1, -ap]) in direct form II transposed
            z[k] = y * (-bz) - out * (-ap)
            y = out
        self._z = z
        return y

    def run(self, e: np.ndarray) -> np.ndarray:
        """Shape a white sequence ``(N, n_channels)``."""
        y = self._gain * e
        z = self._z.copy()
        for k, (bz, ap) in enumerate(self._sec):
            y, zf = signal.lfilter([1.0, -bz], [1.0, -ap], y, axis=0, zi=z[k][None, :])
            z[k] = zf[0]
        self._z = z
        return y
