"""The bench electronics' parameters: :class:`ElectronicsConfig` (DAC, amplifier, gauge, ADC, noise, drift, delay).

One frozen value per stage; the chains that run it (:class:`~nanosim.plant.electronics.ActuatorChain`,
:class:`~nanosim.plant.electronics.SensorChain`) and the description of each effect are in
:mod:`nanosim.plant.electronics`, which re-exports this module's names.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from nanosim import constants as C
from nanosim.validation import as_finite_array
from nanosim.plant.charge_drive import DRIVES
from nanosim.plant.filters import enbw_hz

__all__ = ["ElectronicsConfig"]


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
    drive : {"voltage", "charge"}
        ``"voltage"``: the amplifier sets the piezo voltage. ``"charge"``: a charge
        amplifier sets its charge above ``charge_crossover_Hz`` (hysteresis and creep
        reduced to ``charge_residual``), a voltage below it (:mod:`nanosim.plant.charge_drive`).
    charge_crossover_Hz : float
        ``f_c = 1 / (2 pi R_p C_p)`` of the charge amplifier, Hz (> 0; 0.1 Hz).
    charge_residual : float
        Fraction of the voltage drive's hysteresis left above ``f_c`` (0 ... 1; 0.2).
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
    drive: str = "voltage"
    charge_crossover_Hz: float = C.CHARGE_CROSSOVER_HZ
    charge_residual: float = C.CHARGE_RESIDUAL_HYSTERESIS
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
                     "sensor_um_per_V", "adc_full_scale_V", "thermal_drift_tau_s", "thermal_air_tau_s",
                     "charge_crossover_Hz"):
            positive(name)
        if self.drive not in DRIVES:
            raise ValueError(f"drive: expected one of {', '.join(DRIVES)}, got {self.drive!r}")
        rho = self.charge_residual
        if isinstance(rho, bool) or not isinstance(rho, (int, float, np.floating, np.integer)) \
                or not 0.0 <= float(rho) <= 1.0:
            raise ValueError(f"charge_residual: expected a fraction in [0, 1], got {rho!r}")
        object.__setattr__(self, "charge_residual", float(rho))
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
