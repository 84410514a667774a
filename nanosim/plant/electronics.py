"""Actuator and sensor signal chains, sampled at the controller rate (4 kHz).

Actuator side (per channel, vectorised over the 3 actuators)::

    u (controller V) -> computation delay (whole samples)
      -> DAC: quantisation (18 bits over +/-10 V), + DAC noise (white + flicker) + thermal drift of
         the leg + amplifier noise (input-referred)
      -> amplifier: clip to the command range [-1, 7.5] V (flag), x20, first-order small-signal
         bandwidth into the piezo capacitance -> v_piezo (V, mean over the sample period)
      -> piezo (nanosim.plant.piezo): PI hysteresis -> log creep -> v_free (V)

The mechanics applies the tendon force ``F = PIEZO_FORCE_PER_PIEZO_V * v_free``.

Sensor side (per capacitance probe)::

    displacement (um) -> gauge output filter (Butterworth, Tustin prewarped at 500 Hz) -> + gauge noise
      -> clip to +/-50 um (flag) -> 5 um/V -> 16-bit ADC over +/-10 V -> reading (sensor V)

Every default is a bench value with its source in :mod:`nanosim.constants`
(computation delay, amplifier bandwidth and noise, gauge bandwidth and noise,
DAC noise). Noise spectra, each with a physical basis:

- DAC: the standard electronic-noise spectrum, white with a flicker corner,
  one-sided PSD ``e_n**2 (1 + f_c / f)``: white ``dac_noise_V`` per sample
  (``e_n = dac_noise_V / sqrt(fs / 2)``) plus 1/f noise below
  ``dac_flicker_corner_Hz`` (realized by
  :class:`~nanosim.plant.filters.FlickerShaper` from 0.01 Hz up), at the
  datasheet level of the converter class (:data:`nanosim.constants.DAC_WHITE_NOISE_V`).
- Thermal drift: the chamber air's temperature near each leg is a first-order
  (Ornstein-Uhlenbeck) process of correlation time ``thermal_air_tau_s``,
  sampled exactly as ``x_k = a x_{k-1} + sqrt(1 - a^2) w_k``,
  ``a = exp(-dt / tau_air)``; the leg follows it through its heat diffusion, a
  first-order lag ``T_k = b T_{k-1} + (1 - b) x_k``, ``b = exp(-dt / tau_leg)``
  (``thermal_drift_tau_s``), scaled to the rms ``thermal_drift_K``
  (``var T / var x = (1 - b)^2 (1 + a b) / ((1 - b^2)(1 - a b))``). The
  spectrum is flat below both corners and falls as ``f^-4`` above them, so a
  loop of tens of Hz removes it. Both states start from their joint stationary
  distribution. The leg lengthens by ``d_alpha L T`` (differential expansion
  of the aluminium frame against the actuator over its mounted length), which
  acts like a free-strain change of the actuator: referred to controller volts
  by the free stroke per volt, ``thermal_drift_V``. Its level is the one noise
  level calibrated to the paper (the open-loop probe sigma at rest, 11.4 nm;
  ``tools/fit_drift_level.py``).
- Amplifier: white, referred to its input (``amplifier_noise_V`` per sample).
- Gauge: white ``0.3 nm / sqrt(1 kHz) = 9.5 pm/sqrt(Hz)`` (paper: 0.3 nm at
  1 kHz). The noise leaves the gauge through its output filter and the ADC
  samples it, so the per-sample variance is the density squared times the
  filter's equivalent noise bandwidth (aliased; white from sample to sample is
  exact for a filter above the Nyquist frequency). ``sensor_noise_band_Hz``
  overrides that band.
- ADC quantisation (1 LSB = 1.53 nm, 0.44 nm rms) follows from the converter.

Floor vibration is a mechanical input (:mod:`nanosim.plant.floor`).

Every effect is switchable; with everything off ``v_free_V == 20 * u`` and
``reading_um == displacement_um`` exactly.

Random streams: each noise draws from its own ``numpy.random.Generator``,
seeded from a child of ``numpy.random.SeedSequence(seed)`` (DAC white: child 0,
gauge: child 1, DAC flicker: child 2, amplifier: child 3; the floor uses 4;
thermal drift: child 5), so
giving both chains the same master seed yields independent streams. Normal
deviates are drawn in fixed blocks, so ``run`` and repeated ``step`` calls
produce bit-identical outputs, and ``reset`` replays the same noise.
"""
from __future__ import annotations

from dataclasses import dataclass
import math
from typing import NamedTuple

import numpy as np
from scipy.signal import lfilter

from nanosim import constants as C
from nanosim.validation import as_finite_array
from nanosim.plant.noise import NormalStream, child_seed
from nanosim.plant.filters import AmplifierLag, DelayLine, FlickerShaper, SampledFilter, butterworth_lowpass, enbw_hz
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

_ACTUATOR_STREAM = 0
_SENSOR_STREAM = 1
_FLICKER_STREAM = 2
_AMPLIFIER_STREAM = 3
_DRIFT_STREAM = 5
_FLICKER_F_MIN_HZ = 0.01          # lowest pole of the flicker shaper (records up to ~100 s)


@dataclass(frozen=True)
class ElectronicsConfig:
    """DAC, amplifier, gauge and ADC parameters and switches.

    Parameters
    ----------
    sample_rate_Hz : float
        Controller / acquisition sample rate (4 kHz).
    computation_delay_samples : int
        Whole samples between the controller's output ``u_k`` and the DAC
        update (0: ``u_k`` acts from the sample instant at which it is computed).
    dac_quantization : bool
        Quantise the command to ``dac_bits`` over ``dac_center_V +/- dac_full_scale_V``.
    dac_bits : int
        DAC resolution (:data:`nanosim.constants.DAC_BITS`).
    dac_full_scale_V : float
        DAC output half-range (controller volts; +/-10 V).
    dac_center_V : float
        Centre of the DAC output range (0 for a bipolar +/-10 V DAC).
    dac_noise : bool
        Add white Gaussian noise to the DAC output.
    dac_noise_V : float
        Standard deviation of the white DAC noise per sample, controller volts.
    dac_noise_corner_Hz : float or None
        ``None``: the white part is white. Otherwise it passes a two-pole
        low-pass ``b0 / (1 - a z^-1)^2``, ``a = exp(-2 pi fc / fs)``, scaled so
        its rms is still ``dac_noise_V`` (a low-passed DAC noise, e.g. 1.39 mV through 5 Hz).
    dac_flicker_corner_Hz : float or None
        1/f corner of the DAC noise: below it the flicker part exceeds the
        white part (``None`` or 0: white only).
    thermal_drift : bool
        Add the legs' thermal drift (see the module docstring).
    thermal_drift_K : float
        rms temperature fluctuation of each leg, K.
    thermal_drift_tau_s : float
        The leg's thermal lag, s.
    thermal_air_tau_s : float
        The correlation time of the air temperature the leg follows, s.
    amplifier_noise : bool
        Add the amplifier's white noise (input-referred).
    amplifier_noise_V : float
        Its standard deviation per sample, controller volts.
    amplifier_gain : float
        Piezo volts per controller volt (20).
    amplifier_bandwidth_Hz : float or None
        Small-signal -3 dB bandwidth of the amplifier driving the piezo
        capacitance (first order); ``None``: instantaneous.
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
        the gauge filter's (or, without one, the Nyquist band ``sample_rate_Hz / 2``).
    gauge_bandwidth_Hz : float or None
        -3 dB bandwidth of the gauge's output filter; ``None``: no filter.
    gauge_filter_order : int
        Butterworth order of that filter (1 or 2).
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
    computation_delay_samples: int = C.COMPUTATION_DELAY_SAMPLES
    dac_quantization: bool = True
    dac_bits: int = C.DAC_BITS
    dac_full_scale_V: float = C.DAC_FULL_SCALE_V
    dac_center_V: float = C.DAC_CENTER_V
    dac_noise: bool = True
    dac_noise_V: float = C.DAC_WHITE_NOISE_V
    dac_noise_corner_Hz: float | None = None
    dac_flicker_corner_Hz: float | None = C.DAC_FLICKER_CORNER_HZ
    thermal_drift: bool = True
    thermal_drift_K: float = C.THERMAL_DRIFT_K_RMS
    thermal_drift_tau_s: float = C.THERMAL_DRIFT_TAU_S
    thermal_air_tau_s: float = C.THERMAL_AIR_TAU_S
    amplifier_noise: bool = True
    amplifier_noise_V: float = C.AMPLIFIER_NOISE_V
    amplifier_gain: float = C.AMPLIFIER_GAIN
    amplifier_bandwidth_Hz: float | None = C.AMPLIFIER_BANDWIDTH_HZ
    saturation: bool = True
    command_range_V: tuple = C.COMMAND_RANGE_V
    sensor_noise: bool = True
    sensor_noise_nm_rms_1kHz: float = C.SENSOR_NOISE_NM_RMS_1KHZ
    sensor_noise_band_Hz: float | None = None
    gauge_bandwidth_Hz: float | None = C.GAUGE_BANDWIDTH_HZ
    gauge_filter_order: int = C.GAUGE_FILTER_ORDER
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
                     "sensor_um_per_V", "adc_full_scale_V", "thermal_drift_tau_s", "thermal_air_tau_s"):
            positive(name)
        fc = self.dac_flicker_corner_Hz
        if fc is not None and (not np.isfinite(float(fc)) or float(fc) < 0):
            raise ValueError(f"dac_flicker_corner_Hz: expected None or a finite value >= 0, got {fc!r}")
        for name in ("amplifier_bandwidth_Hz", "gauge_bandwidth_Hz"):
            if getattr(self, name) is not None:
                positive(name)
        d = self.computation_delay_samples
        if isinstance(d, bool) or not isinstance(d, (int, np.integer)) or not 0 <= d <= 100:
            raise ValueError(f"computation_delay_samples: expected an integer in 0..100, got {d!r}")
        object.__setattr__(self, "computation_delay_samples", int(d))
        if self.gauge_filter_order not in (1, 2):
            raise ValueError(f"gauge_filter_order: expected 1 or 2, got {self.gauge_filter_order!r}")
        for name in ("dac_noise_V", "sensor_noise_nm_rms_1kHz", "amplifier_noise_V", "thermal_drift_K"):
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
        kw = dict(dac_quantization=False, dac_noise=False, thermal_drift=False, saturation=False, amplifier_noise=False,
                  sensor_noise=False, sensor_clip=False, adc_quantization=False, computation_delay_samples=0,
                  amplifier_bandwidth_Hz=None, gauge_bandwidth_Hz=None)
        kw.update(overrides)
        return cls(**kw)

    @property
    def dt_s(self) -> float:
        """Sample period, seconds."""
        return 1.0 / self.sample_rate_Hz

    @property
    def dac_flicker_V_per_rtHz(self) -> float:
        """Flicker density of the DAC noise at 1 Hz, V/sqrt(Hz): ``e_n sqrt(f_c)`` (0 without flicker or noise)."""
        if not self.dac_noise or not self.dac_flicker_corner_Hz:
            return 0.0
        return self.dac_noise_V / math.sqrt(self.sample_rate_Hz / 2.0) * math.sqrt(self.dac_flicker_corner_Hz)

    @property
    def thermal_drift_V(self) -> float:
        """The rms of the thermal drift referred to the DAC output, controller volts (0 when off).

        ``d_alpha L sigma_T / (x_free / V_max) / gain``: the leg's elongation over the actuator's
        free stroke per piezo volt, over the amplifier gain.
        """
        if not self.thermal_drift:
            return 0.0
        um_per_piezo_V = C.PIEZO_FREE_STROKE_M / C.PIEZO_MAX_V
        return (C.THERMAL_EXPANSION_DIFF_PER_K * C.THERMAL_LOOP_LENGTH_M * self.thermal_drift_K
                / um_per_piezo_V / self.amplifier_gain)

    @property
    def dac_quantization_rms_V(self) -> float:
        """The rms of the DAC's quantisation error when dithered, ``LSB / sqrt(12)`` (0 when off)."""
        return self.dac_lsb_V / math.sqrt(12.0) if self.dac_quantization else 0.0

    @property
    def dac_lsb_V(self) -> float:
        """DAC step, controller volts (``2 dac_full_scale_V / 2**dac_bits``)."""
        return 2.0 * self.dac_full_scale_V / 2 ** self.dac_bits

    @property
    def adc_lsb_V(self) -> float:
        """ADC step, sensor volts (0.305 mV = 1.53 nm by default)."""
        return 2.0 * self.adc_full_scale_V / 2 ** self.adc_bits

    @property
    def sensor_noise_band_effective_Hz(self) -> float:
        """Band of the sampled gauge noise: the override, the gauge filter's ENBW, or Nyquist."""
        if self.sensor_noise_band_Hz is not None:
            return self.sensor_noise_band_Hz
        if self.gauge_bandwidth_Hz is not None:
            return enbw_hz(self.gauge_bandwidth_Hz, self.gauge_filter_order)
        return self.sample_rate_Hz / 2.0

    @property
    def sensor_noise_std_nm(self) -> float:
        """Per-sample gauge noise std, nm: ``rms_1kHz * sqrt(band / 1 kHz)``."""
        return self.sensor_noise_nm_rms_1kHz * float(np.sqrt(self.sensor_noise_band_effective_Hz / 1000.0))


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


def _fast_vector(name: str, value, n: int) -> np.ndarray:
    """``as_finite_array(name, value, shape=(n,))`` with a fast path for good input."""
    try:
        arr = np.asarray(value, dtype=float)
    except (TypeError, ValueError):
        arr = None
    if arr is None or arr.shape != (n,) or not math.isfinite(arr.sum()):
        arr = as_finite_array(name, value, shape=(n,))   # raises on bad input
    return arr


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
        self._noise = NormalStream(child_seed(seed, _ACTUATOR_STREAM), self.n_channels)
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
        flick = e.dac_flicker_V_per_rtHz
        self._flicker = (FlickerShaper(flick, _FLICKER_F_MIN_HZ, e.sample_rate_Hz, self.n_channels)
                         if flick > 0 else None)
        self._flicker_noise = (NormalStream(child_seed(seed, _FLICKER_STREAM), self.n_channels)
                               if self._flicker is not None else None)
        self._sigma_amp = e.amplifier_noise_V if e.amplifier_noise else 0.0
        self._amp_noise = (NormalStream(child_seed(seed, _AMPLIFIER_STREAM), self.n_channels)
                           if self._sigma_amp > 0 else None)
        self._drift_V = e.thermal_drift_V
        a = self._drift_a = math.exp(-self.dt_s / e.thermal_air_tau_s)
        b = self._drift_b = math.exp(-self.dt_s / e.thermal_drift_tau_s)
        self._drift_b0 = math.sqrt(1.0 - a * a)
        self._drift_c0 = 1.0 - b
        var_T = (1.0 - b) ** 2 * (1.0 + a * b) / ((1.0 - b * b) * (1.0 - a * b))     # var T / var x
        self._drift_cov = (1.0 - b) / (1.0 - a * b)                                   # cov(x, T) / var x
        self._drift_var = var_T
        self._drift_scale = self._drift_V / math.sqrt(var_T)
        self._drift_noise = (NormalStream(child_seed(seed, _DRIFT_STREAM), self.n_channels)
                             if self._drift_V > 0 else None)
        self._drift_start()
        self._delay = DelayLine(e.computation_delay_samples, self.n_channels)
        self._lag = AmplifierLag(e.amplifier_bandwidth_Hz, self.dt_s, self.n_channels)
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
        # flicker rms over 0.01 Hz ... fs/2 is sqrt(ln(2e5)) ~ 3.5 times its 1 Hz density
        margin = 20.0 * (self._sigma + self._sigma_amp + 3.5 * flick + self._drift_V)
        self._dac_clip_implied = (self._quant and self._center + self._code_lo * self._lsb + margin < self._lo
                                  and self._hi < self._center + self._code_hi * self._lsb - margin)

    def _drift_start(self) -> None:
        """The drift's filter states for a stationary start, from the stream's first two rows.

        ``x_{-1} = w_1`` and ``T_{-1} = cov x_{-1} + sqrt(var_T - cov^2) w_2`` (the joint
        stationary distribution of air and leg); the direct-form states are ``a x_{-1}``, ``b T_{-1}``.
        """
        if self._drift_noise is None:
            self._drift_z = self._drift_z2 = np.zeros(self.n_channels)
            return
        x = self._drift_noise.take1().copy()
        t = self._drift_cov * x + math.sqrt(self._drift_var - self._drift_cov ** 2) * self._drift_noise.take1()
        self._drift_z, self._drift_z2 = self._drift_a * x, self._drift_b * t

    def reset(self) -> None:
        """Virgin piezo state, no creep history, empty delay line, noise streams rewound."""
        self.piezo.reset()
        self._noise.reset()
        self._ar_state = np.zeros((2, self.n_channels))
        for part in (self._flicker, self._flicker_noise, self._amp_noise, self._delay, self._lag,
                     self._drift_noise):
            if part is not None:
                part.reset()
        self._drift_start()

    def _noise_step(self) -> np.ndarray | None:
        """The additive DAC noise of one sample (controller V), or None."""
        total = None
        if self._sigma > 0.0:
            noise = self._noise.take1()
            if self._ar:
                # DF-II transposed, as scipy.signal.lfilter: step == run bit for bit
                z = self._ar_state
                y = self._ar_b0 * noise + z[0]
                self._ar_state = np.stack([z[1] - self._ar_a1 * y, -self._ar_a2 * y])
                noise = y
            total = self._sigma * noise
        if self._flicker is not None:
            f = self._flicker.step(self._flicker_noise.take1())
            total = f if total is None else total + f
        if self._drift_noise is not None:
            # two first-order sections in direct form II transposed, as scipy.signal.lfilter: step == run
            x = self._drift_b0 * self._drift_noise.take1() + self._drift_z
            self._drift_z = self._drift_a * x
            t = self._drift_c0 * x + self._drift_z2
            self._drift_z2 = self._drift_b * t
            d = self._drift_scale * t
            total = d if total is None else total + d
        return total

    def _noise_run(self, n: int) -> np.ndarray | None:
        total = None
        if self._sigma > 0.0:
            noise = self._noise.take(n)
            if self._ar and n:
                noise, zf = lfilter([self._ar_b0, 0.0, 0.0], [1.0, self._ar_a1, self._ar_a2], noise, axis=0,
                                    zi=self._ar_state)
                self._ar_state = zf
            total = self._sigma * noise
        if self._flicker is not None:
            f = self._flicker.run(self._flicker_noise.take(n))
            total = f if total is None else total + f
        if self._drift_noise is not None and n:
            x, zf = lfilter([self._drift_b0, 0.0], [1.0, -self._drift_a], self._drift_noise.take(n), axis=0,
                            zi=self._drift_z[None])
            t, zf2 = lfilter([self._drift_c0, 0.0], [1.0, -self._drift_b], x, axis=0, zi=self._drift_z2[None])
            self._drift_z, self._drift_z2 = zf[0], zf2[0]
            d = self._drift_scale * t
            total = d if total is None else total + d
        return total

    def _electronics(self, u: np.ndarray, noise: np.ndarray | None, amp_noise: np.ndarray | None = None):
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
            u_dac = u_dac + noise
        u_in = u_dac if amp_noise is None else u_dac + amp_noise       # amplifier noise, input-referred
        if self._sat:
            u_cmd = minimum(maximum(u_in, self._lo), self._hi)
            sat = u_cmd != u_in
            if code is not None and not self._dac_clip_implied:
                sat |= code_c != code
        else:
            u_cmd = u_in
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
        u = self._delay.step(_fast_vector("u_V", u_V, self.n_channels))
        amp = self._sigma_amp * self._amp_noise.take1() if self._amp_noise is not None else None
        u_dac, v_amp, sat = self._electronics(u, self._noise_step(), amp)
        v_piezo = self._lag.step(v_amp)
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
        u = self._delay.run(as_finite_array("u_V", u_V, shape=(None, self.n_channels)))
        amp = self._sigma_amp * self._amp_noise.take(u.shape[0]) if self._amp_noise is not None else None
        u_dac, v_amp, sat = self._electronics(u, self._noise_run(u.shape[0]), amp)
        v_piezo = self._lag.run(v_amp)
        v_free = self.piezo._run(v_piezo)
        return ActuatorSample(u_dac, v_piezo, v_free, sat)


class SensorChain:
    """Gauge filter -> gauge noise -> ADC chain for ``n_channels`` probes.

    The gauge's output filter (if configured) starts at steady state with the
    first displacement it reads after construction or :meth:`reset`.

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
        self._noise = NormalStream(child_seed(seed, _SENSOR_STREAM), self.n_channels)
        self._sigma_um = e.sensor_noise_std_nm * 1e-3 if e.sensor_noise else 0.0
        self._filter = (SampledFilter(*butterworth_lowpass(e.gauge_bandwidth_Hz, e.gauge_filter_order), e.dt_s,
                                      self.n_channels) if e.gauge_bandwidth_Hz is not None else None)
        self._range = e.sensor_range_um
        self._um_per_V = e.sensor_um_per_V
        if e.adc_quantization:
            self._lsb = e.adc_lsb_V
            self._lsb_um = self._lsb * self._um_per_V
            self._code_lo = -float(2 ** (e.adc_bits - 1))
            self._code_hi = float(2 ** (e.adc_bits - 1) - 1)

    def reset(self) -> None:
        """Rewind the gauge noise stream; the gauge filter restarts at steady state."""
        self._noise.reset()
        if self._filter is not None:
            self._filter.reset()

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
        if self._filter is not None:
            d = self._filter.step(d)
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
        if self._filter is not None:
            d = self._filter.run(d)
        noise = self._noise.take(d.shape[0]) if self._sigma_um > 0.0 else None
        return self._convert(d, noise)
