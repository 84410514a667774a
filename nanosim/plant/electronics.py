"""Actuator and sensor signal chains, sampled at the controller rate (4 kHz).

Actuator side (per channel, vectorised over the 3 actuators)::

    u (controller V) -> DAC: 16-bit quantisation over +/-10 V, + white Gaussian noise
      -> amplifier: clip to the command range [-1, 7.5] V (flag), x20 -> v_piezo (V)
      -> piezo (nanosim.piezo): PI hysteresis -> Kelvin-Voigt creep -> v_free (V)

The mechanics applies the tendon force ``F = PIEZO_FORCE_PER_PIEZO_V * v_free``.

Sensor side (per capacitance probe)::

    displacement (um) -> + gauge noise -> clip to +/-50 um (flag)
      -> 5 um/V -> 16-bit ADC over +/-10 V -> reading (sensor V)

Gauge noise. The datasheet gives 0.3 nm rms in a 1 kHz bandwidth. It is
modelled as white noise with the matching one-sided density
``0.3 nm / sqrt(1000 Hz) = 9.5 pm/sqrt(Hz)``, integrated over the band
``sensor_noise_band_Hz``; the per-sample standard deviation is
``0.3 nm * sqrt(band / 1000 Hz)``. The default band is the Nyquist band of the
4 kHz loop (2 kHz), i.e. 0.424 nm per sample: the gauge is assumed to have an
analogue bandwidth above 2 kHz, so its noise aliases into the full sampled
band. Set ``sensor_noise_band_Hz=1000`` to get 0.3 nm per sample (a gauge
limited to 1 kHz). Either way it is below the ADC's quantisation noise
(1 LSB = 1.53 nm, 0.44 nm rms).

Every effect is switchable; with everything off ``v_free_V == 20 * u`` and
``reading_um == displacement_um`` exactly.

Random streams: each chain draws from its own ``numpy.random.Generator``,
seeded from a child of ``numpy.random.SeedSequence(seed)`` (actuator: child 0,
sensor: child 1), so giving both chains the same master seed yields
independent streams. Normal deviates are drawn in fixed blocks, so ``run`` and
repeated ``step`` calls produce bit-identical outputs, and ``reset`` replays
the same noise.
"""
from __future__ import annotations

from dataclasses import dataclass
import math
from typing import NamedTuple

import numpy as np
from scipy.signal import lfilter

from nanosim import constants as C
from nanosim.validation import as_finite_array
from nanosim.plant.piezo import PiezoConfig, PiezoModel

__all__ = [
    "ElectronicsConfig",
    "ActuatorSample",
    "SensorSample",
    "ActuatorChain",
    "SensorChain",
    "quantize",
    "child_seed",
]

_NOISE_BLOCK = 4096
_ACTUATOR_STREAM = 0
_SENSOR_STREAM = 1


@dataclass(frozen=True)
class ElectronicsConfig:
    """DAC, amplifier, gauge and ADC parameters and switches.

    Parameters
    ----------
    sample_rate_Hz : float
        Controller / acquisition sample rate (4 kHz).
    dac_quantization : bool
        Quantise the command to ``dac_bits`` over ``dac_center_V +/- dac_full_scale_V``.
    dac_bits : int
        DAC resolution.
    dac_full_scale_V : float
        DAC output half-range (controller volts).
    dac_center_V : float
        Centre of the DAC output range (0 for a bipolar +/-10 V DAC; 3.25 V with
        4.25 V half-range spans exactly the [-1, 7.5] V command range).
    dac_noise : bool
        Add white Gaussian noise to the DAC output.
    dac_noise_V : float
        Standard deviation of the DAC noise per sample, controller volts.
        Default 1 mV; calibrate so the open-loop probe std at rest is 11.4 nm.
    dac_noise_corner_Hz : float or None
        ``None``: white noise. Otherwise the noise passes a two-pole low-pass
        ``b0 / (1 - a z^-1)^2``, ``a = exp(-2 pi fc / fs)``, scaled so its rms is
        still ``dac_noise_V``: DAC and voltage-reference noise is dominated by
        low-frequency (1/f, drift) components, and the amplifier rolls off.
    amplifier_gain : float
        Piezo volts per controller volt (20).
    saturation : bool
        Clip the command to ``command_range_V`` before the gain.
    command_range_V : tuple of float
        Allowed command range in controller volts ([-1, 7.5] V = -20..150 piezo V).
    sensor_noise : bool
        Add capacitance-gauge noise.
    sensor_noise_nm_rms_1kHz : float
        Gauge noise, nm rms in a 1 kHz bandwidth (0.3 nm).
    sensor_noise_band_Hz : float or None
        Equivalent noise bandwidth of the sampled gauge noise; ``None`` means
        the Nyquist band ``sample_rate_Hz / 2``.
    sensor_clip : bool
        Clip the displacement to ``+/-sensor_range_um``.
    sensor_range_um : float
        Gauge range (+/-50 um).
    sensor_um_per_V : float
        Gauge sensitivity (5 um/V).
    adc_quantization : bool
        Quantise the gauge voltage with the ADC.
    adc_bits : int
        ADC resolution (16).
    adc_full_scale_V : float
        ADC input range ``+/-adc_full_scale_V`` (10 V).
    """

    sample_rate_Hz: float = C.CONTROL_RATE_HZ
    dac_quantization: bool = True
    dac_bits: int = 16
    dac_full_scale_V: float = 10.0
    dac_center_V: float = 0.0
    dac_noise: bool = True
    dac_noise_V: float = 1e-3
    dac_noise_corner_Hz: float | None = None
    amplifier_gain: float = C.AMPLIFIER_GAIN
    saturation: bool = True
    command_range_V: tuple = C.COMMAND_RANGE_V
    sensor_noise: bool = True
    sensor_noise_nm_rms_1kHz: float = C.SENSOR_NOISE_NM_RMS_1KHZ
    sensor_noise_band_Hz: float | None = None
    sensor_clip: bool = True
    sensor_range_um: float = C.SENSOR_RANGE_UM
    sensor_um_per_V: float = C.SENSOR_UM_PER_V
    adc_quantization: bool = True
    adc_bits: int = C.ADC_BITS
    adc_full_scale_V: float = C.ADC_FULL_SCALE_V

    def __post_init__(self):
        def positive(name):
            x = float(getattr(self, name))
            if not np.isfinite(x) or x <= 0:
                raise ValueError(f"{name}: expected a finite value > 0, got {getattr(self, name)}")
            object.__setattr__(self, name, x)

        for name in ("sample_rate_Hz", "dac_full_scale_V", "amplifier_gain", "sensor_range_um",
                     "sensor_um_per_V", "adc_full_scale_V"):
            positive(name)
        for name in ("dac_noise_V", "sensor_noise_nm_rms_1kHz"):
            x = float(getattr(self, name))
            if not np.isfinite(x) or x < 0:
                raise ValueError(f"{name}: expected a finite value >= 0, got {getattr(self, name)}")
            object.__setattr__(self, name, x)
        if self.sensor_noise_band_Hz is not None:
            positive("sensor_noise_band_Hz")
        for name in ("dac_bits", "adc_bits"):
            b = getattr(self, name)
            if int(b) != b or not 1 <= int(b) <= 32:
                raise ValueError(f"{name}: expected an integer in 1..32, got {b}")
            object.__setattr__(self, name, int(b))
        rng = as_finite_array("command_range_V", self.command_range_V, shape=(2,))
        if not rng[0] < rng[1]:
            raise ValueError(f"command_range_V: expected (low, high) with low < high, got {tuple(rng)}")
        object.__setattr__(self, "command_range_V", (float(rng[0]), float(rng[1])))

    @classmethod
    def ideal(cls, **overrides) -> "ElectronicsConfig":
        """All effects off (exact gain-only chain); keyword overrides allowed."""
        kw = dict(dac_quantization=False, dac_noise=False, saturation=False,
                  sensor_noise=False, sensor_clip=False, adc_quantization=False)
        kw.update(overrides)
        return cls(**kw)

    @property
    def dt_s(self) -> float:
        """Sample period, seconds."""
        return 1.0 / self.sample_rate_Hz

    @property
    def dac_lsb_V(self) -> float:
        """DAC step, controller volts (20 V / 2**16 = 0.305 mV by default)."""
        return 2.0 * self.dac_full_scale_V / 2 ** self.dac_bits

    @property
    def adc_lsb_V(self) -> float:
        """ADC step, sensor volts (0.305 mV = 1.53 nm by default)."""
        return 2.0 * self.adc_full_scale_V / 2 ** self.adc_bits

    @property
    def sensor_noise_std_nm(self) -> float:
        """Per-sample gauge noise std, nm: ``rms_1kHz * sqrt(band / 1 kHz)``."""
        band = self.sample_rate_Hz / 2.0 if self.sensor_noise_band_Hz is None else self.sensor_noise_band_Hz
        return self.sensor_noise_nm_rms_1kHz * float(np.sqrt(band / 1000.0))


class ActuatorSample(NamedTuple):
    """Actuator-chain output; fields are ``(3,)`` from ``step``, ``(N, 3)`` from ``run``.

    Attributes
    ----------
    u_dac_V : ndarray
        DAC output (after quantisation and noise), controller volts.
    v_piezo_V : ndarray
        Amplifier output (after saturation), piezo volts.
    v_free_V : ndarray
        Free-strain voltage after hysteresis and creep, piezo volts.
    saturated : ndarray of bool
        Command outside the amplifier command range or the DAC range.
    """

    u_dac_V: np.ndarray
    v_piezo_V: np.ndarray
    v_free_V: np.ndarray
    saturated: np.ndarray


class SensorSample(NamedTuple):
    """Sensor-chain output; fields are ``(3,)`` from ``step``, ``(N, 3)`` from ``run``.

    Attributes
    ----------
    reading_V : ndarray
        ADC reading, sensor volts (multiple of the ADC LSB when quantised).
    reading_um : ndarray
        The same reading in micrometres (``reading_V * sensor_um_per_V``).
    clipped : ndarray of bool
        Gauge out of range or ADC over range.
    """

    reading_V: np.ndarray
    reading_um: np.ndarray
    clipped: np.ndarray


def quantize(x: np.ndarray, bits: int, full_scale: float) -> tuple[np.ndarray, np.ndarray]:
    """Mid-tread two's-complement quantiser over ``+/-full_scale``.

    Returns ``(values, overflow)``: values ``code * lsb`` with integer codes
    clipped to ``[-2**(bits-1), 2**(bits-1) - 1]``, ``lsb = 2 full_scale / 2**bits``,
    and a boolean array marking clipped codes.
    """
    lsb = 2.0 * full_scale / 2 ** bits
    lo, hi = -float(2 ** (bits - 1)), float(2 ** (bits - 1) - 1)
    code = np.rint(x / lsb)
    overflow = (code < lo) | (code > hi)
    np.clip(code, lo, hi, out=code)
    return code * lsb, overflow


def child_seed(seed, stream: int) -> np.random.SeedSequence:
    """Seed sequence for one stochastic element derived from a master seed.

    ``seed`` may be an int, ``None`` (fresh OS entropy) or a
    ``numpy.random.SeedSequence`` (used as is, ignoring ``stream``).
    """
    if isinstance(seed, np.random.SeedSequence):
        return seed
    if seed is not None and (not isinstance(seed, (int, np.integer)) or seed < 0):
        raise ValueError(f"seed: expected a non-negative int, None or SeedSequence, got {seed!r}")
    return np.random.SeedSequence(seed).spawn(stream + 1)[stream]


def _fast_vector(name: str, value, n: int) -> np.ndarray:
    """``as_finite_array(name, value, shape=(n,))`` with a fast path for good input."""
    try:
        arr = np.asarray(value, dtype=float)
    except (TypeError, ValueError):
        arr = None
    if arr is None or arr.shape != (n,) or not math.isfinite(arr.sum()):
        arr = as_finite_array(name, value, shape=(n,))   # raises on bad input
    return arr


class _NormalStream:
    """Standard normal deviates of width ``n`` drawn in fixed blocks (step == run)."""

    def __init__(self, seedseq: np.random.SeedSequence, width: int, block: int = _NOISE_BLOCK):
        self._seedseq = seedseq
        self._width = width
        self._block = block
        self.reset()

    def reset(self) -> None:
        self._rng = np.random.default_rng(self._seedseq)
        self._buf = self._rng.standard_normal((self._block, self._width))
        self._i = 0

    def take1(self) -> np.ndarray:
        if self._i == self._block:
            self._buf = self._rng.standard_normal((self._block, self._width))
            self._i = 0
        row = self._buf[self._i]
        self._i += 1
        return row

    def take(self, n: int) -> np.ndarray:
        out = np.empty((n, self._width))
        filled = 0
        while filled < n:
            if self._i == self._block:
                self._buf = self._rng.standard_normal((self._block, self._width))
                self._i = 0
            m = min(n - filled, self._block - self._i)
            out[filled:filled + m] = self._buf[self._i:self._i + m]
            self._i += m
            filled += m
        return out


class ActuatorChain:
    """Stateful DAC -> amplifier -> piezo chain for ``n_channels`` actuators.

    Parameters
    ----------
    electronics : ElectronicsConfig, optional
        DAC / amplifier settings (default: all on).
    piezo : PiezoConfig, optional
        Hysteresis / creep settings (default: all on).
    seed : int, None or numpy.random.SeedSequence
        Master seed; the DAC noise uses child stream 0 (see :func:`child_seed`).
    n_channels : int
        Number of actuators (3).

    Examples
    --------
    >>> chain = ActuatorChain(seed=1)
    >>> s = chain.step([0.5, 0.0, 0.0])
    >>> force_N = PIEZO_FORCE_PER_PIEZO_V * s.v_free_V   # doctest: +SKIP
    """

    def __init__(self, electronics: ElectronicsConfig | None = None, piezo: PiezoConfig | None = None,
                 seed=0, n_channels: int = 3):
        self.electronics = ElectronicsConfig() if electronics is None else electronics
        self.piezo_config = PiezoConfig() if piezo is None else piezo
        self.n_channels = int(n_channels)
        e = self.electronics
        self.dt_s = e.dt_s
        self.piezo = PiezoModel(self.piezo_config, self.dt_s, self.n_channels)
        self._noise = _NormalStream(child_seed(seed, _ACTUATOR_STREAM), self.n_channels)
        self._gain = e.amplifier_gain
        self._lo, self._hi = e.command_range_V
        self._sigma = e.dac_noise_V if e.dac_noise else 0.0
        fc = e.dac_noise_corner_Hz
        a = math.exp(-2 * math.pi * fc / e.sample_rate_Hz) if (fc and self._sigma > 0) else 0.0
        self._ar = a
        # two equal poles (1 - a z^-1)^2, scaled to unit variance: var = (1 + a^2) / (1 - a^2)^3
        self._ar_b0 = (1.0 - a * a) * math.sqrt((1.0 - a * a) / (1.0 + a * a)) if a else 1.0
        self._ar_a1, self._ar_a2 = -2.0 * a, a * a
        self._ar_state = np.zeros((2, self.n_channels))
        self._quant = e.dac_quantization
        if self._quant:
            self._lsb = e.dac_lsb_V
            self._code_lo = -float(2 ** (e.dac_bits - 1))
            self._code_hi = float(2 ** (e.dac_bits - 1) - 1)
        self._center = e.dac_center_V
        self._sat = e.saturation
        # With saturation on and the command range well inside the DAC range, a
        # clipped DAC code always lands outside the command range (noise cannot
        # bring it back) and is flagged there: skip the separate DAC check.
        margin = 20.0 * self._sigma
        self._dac_clip_implied = (self._quant and self._center + self._code_lo * self._lsb + margin < self._lo
                                  and self._hi < self._center + self._code_hi * self._lsb - margin)

    def reset(self) -> None:
        """Virgin piezo state, no creep history, DAC noise stream rewound."""
        self.piezo.reset()
        self._noise.reset()
        self._ar_state = np.zeros((2, self.n_channels))

    def _electronics(self, u: np.ndarray, noise: np.ndarray | None):
        # Same ufunc sequence for (3,) and (N, 3) inputs: step and run agree bit for bit.
        maximum, minimum = np.maximum, np.minimum
        if self._quant:
            code = np.rint((u - self._center) / self._lsb)
            code_c = minimum(maximum(code, self._code_lo), self._code_hi)
            u_dac = self._center + code_c * self._lsb
        else:
            code = code_c = None
            u_dac = u.copy()
        if noise is not None:
            u_dac = u_dac + self._sigma * noise
        if self._sat:
            u_cmd = minimum(maximum(u_dac, self._lo), self._hi)
            sat = u_cmd != u_dac
            if code is not None and not self._dac_clip_implied:
                sat |= code_c != code
        else:
            u_cmd = u_dac
            sat = (code_c != code) if code is not None else np.zeros(u.shape, dtype=bool)
        return u_dac, self._gain * u_cmd, sat

    def step(self, u_V) -> ActuatorSample:
        """Advance one controller sample.

        Parameters
        ----------
        u_V : array_like, shape (n_channels,)
            Controller command, volts (before the x20 amplifier).

        Returns
        -------
        ActuatorSample
            ``u_dac_V``, ``v_piezo_V``, ``v_free_V`` (shape ``(n_channels,)``) and
            ``saturated`` flags.
        """
        u = _fast_vector("u_V", u_V, self.n_channels)
        noise = self._noise.take1() if self._sigma > 0.0 else None
        if noise is not None and self._ar:
            # DF-II transposed, as scipy.signal.lfilter: step == run bit for bit
            z = self._ar_state
            y = self._ar_b0 * noise + z[0]
            self._ar_state = np.stack([z[1] - self._ar_a1 * y, -self._ar_a2 * y])
            noise = y
        u_dac, v_piezo, sat = self._electronics(u, noise)
        v_free = self.piezo._step(v_piezo)
        return ActuatorSample(u_dac, v_piezo, v_free, sat)

    def run(self, u_V) -> ActuatorSample:
        """Advance over ``N`` samples; identical to ``N`` calls of :meth:`step`.

        Parameters
        ----------
        u_V : array_like, shape (N, n_channels)
            Controller commands, volts.

        Returns
        -------
        ActuatorSample
            Fields of shape ``(N, n_channels)``.
        """
        u = as_finite_array("u_V", u_V, shape=(None, self.n_channels))
        noise = self._noise.take(u.shape[0]) if self._sigma > 0.0 else None
        if noise is not None and self._ar and len(noise):
            noise, zf = lfilter([self._ar_b0, 0.0, 0.0], [1.0, self._ar_a1, self._ar_a2], noise, axis=0,
                                zi=self._ar_state)
            self._ar_state = zf
        u_dac, v_piezo, sat = self._electronics(u, noise)
        v_free = self.piezo._run(v_piezo)
        return ActuatorSample(u_dac, v_piezo, v_free, sat)


class SensorChain:
    """Stateless-but-seeded gauge -> ADC chain for ``n_channels`` probes.

    Parameters
    ----------
    electronics : ElectronicsConfig, optional
        Gauge / ADC settings (default: all on).
    seed : int, None or numpy.random.SeedSequence
        Master seed; gauge noise uses child stream 1 (see :func:`child_seed`).
    n_channels : int
        Number of probes (3).
    """

    def __init__(self, electronics: ElectronicsConfig | None = None, seed=0, n_channels: int = 3):
        self.electronics = ElectronicsConfig() if electronics is None else electronics
        self.n_channels = int(n_channels)
        e = self.electronics
        self._noise = _NormalStream(child_seed(seed, _SENSOR_STREAM), self.n_channels)
        self._sigma_um = e.sensor_noise_std_nm * 1e-3 if e.sensor_noise else 0.0
        self._range = e.sensor_range_um
        self._um_per_V = e.sensor_um_per_V
        if e.adc_quantization:
            self._lsb = e.adc_lsb_V
            self._lsb_um = self._lsb * self._um_per_V
            self._code_lo = -float(2 ** (e.adc_bits - 1))
            self._code_hi = float(2 ** (e.adc_bits - 1) - 1)

    def reset(self) -> None:
        """Rewind the gauge noise stream."""
        self._noise.reset()

    def _convert(self, d: np.ndarray, noise: np.ndarray | None) -> SensorSample:
        if noise is not None:
            d = d + self._sigma_um * noise
        if self.electronics.sensor_clip:
            dc = np.minimum(np.maximum(d, -self._range), self._range)
            clipped = dc != d
            d = dc
        else:
            clipped = np.zeros(d.shape, dtype=bool)
        if self.electronics.adc_quantization:
            code = np.rint(d / self._um_per_V / self._lsb)
            code_c = np.minimum(np.maximum(code, self._code_lo), self._code_hi)
            clipped |= code_c != code
            return SensorSample(code_c * self._lsb, code_c * self._lsb_um, clipped)
        return SensorSample(d / self._um_per_V, d.copy(), clipped)

    def step(self, displacement_um) -> SensorSample:
        """Read one sample of the true probe displacements.

        Parameters
        ----------
        displacement_um : array_like, shape (n_channels,)
            True displacement at each probe, micrometres.

        Returns
        -------
        SensorSample
            ``reading_V``, ``reading_um`` and ``clipped`` flags.
        """
        d = _fast_vector("displacement_um", displacement_um, self.n_channels)
        noise = self._noise.take1() if self._sigma_um > 0.0 else None
        return self._convert(d, noise)

    def run(self, displacement_um) -> SensorSample:
        """Read ``N`` samples; identical to ``N`` calls of :meth:`step`.

        Parameters
        ----------
        displacement_um : array_like, shape (N, n_channels)
            True probe displacements, micrometres.
        """
        d = as_finite_array("displacement_um", displacement_um, shape=(None, self.n_channels))
        noise = self._noise.take(d.shape[0]) if self._sigma_um > 0.0 else None
        return self._convert(d, noise)
