"""Actuator and sensor signal chains, sampled at the controller rate (4 kHz).

Actuator side (per channel, vectorised over the 3 actuators)::

    u (controller V) -> computation delay (whole samples)
      -> DAC: quantisation (18 bits over +/-10 V), + DAC noise (white + flicker) + thermal drift of
         the leg + amplifier noise (input-referred)
      -> amplifier: clip to the command range [-1, 7.5] V (flag), x20, first-order small-signal
         bandwidth into the piezo capacitance -> v_piezo (V, mean over the sample period)
      -> piezo (nanosim.plant.piezo): PI hysteresis -> log creep -> v_free (V)
      -> drive="charge": the charge amplifier keeps a fraction of the hysteresis and creep above its
         crossover (nanosim.plant.charge_drive); v_piezo is then the charge command in piezo volts

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

import math
from typing import NamedTuple

import numpy as np
from scipy.signal import lfilter

from nanosim.validation import as_finite_array
from nanosim.plant.noise import NormalStream, child_seed
from nanosim.plant.charge_drive import ChargeDrive
from nanosim.plant.filters import AmplifierLag, DelayLine, FlickerShaper, SampledFilter, butterworth_lowpass
from nanosim.plant.piezo import PiezoConfig, PiezoModel
from nanosim.plant.electronics_config import ElectronicsConfig

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


class ActuatorSample(NamedTuple):
    """Actuator-chain output; fields are ``(3,)`` from ``step``, ``(N, 3)`` from ``run``.

    Attributes
    ----------
    u_dac_V : ndarray
        DAC output (after quantisation and noise), controller volts.
    v_piezo_V : ndarray
        Amplifier output (after saturation), piezo volts; with ``drive="charge"`` the charge
        command referred to piezo volts (``q / C_p``).
    v_free_V : ndarray
        Free-strain voltage after hysteresis and creep (and the charge drive), piezo volts.
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
        self._charge = (ChargeDrive(e.charge_crossover_Hz, e.charge_residual, self.dt_s, self.n_channels)
                        if e.drive == "charge" else None)
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
                     self._drift_noise, self._charge):
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
        if self._charge is not None:
            v_free = self._charge.step(v_piezo, v_free)
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
        if self._charge is not None:
            v_free = self._charge.run(v_piezo, v_free)
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
