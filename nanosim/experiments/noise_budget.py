"""The closed-loop noise budget, analytic: each source's spectrum through the loop's transfer functions.

Fleming, "Measuring and predicting resolution in nanopositioning systems", Mechatronics 24 (2014)
605: at rest, the position noise is the sum of every source's PSD shaped by the closed loop, read as
stacked spectra and as the cumulative amplitude spectrum ``sqrt(int_0^f S(f') df')``, whose top is
the rms (sigma). No simulation: the loop as the bench runs it (:func:`nanosim.experiments.loop.run_closed_loop`:
``u_k`` from the reading ``y_k``, the reading ``y_{k+1}`` at the end of the period ``u_k`` acts in)
with the twin's linear model, every element of the chain linear:

* plant ``Gm(z) = C (zI - A)^-1 B + D / z``: the 4 kHz linear twin with the piezo's small-signal gain and
  creep filter (:func:`nanosim.plant.linearize.linearize` with ``include_piezo``), controller V -> sensor V;
  the ``D / z`` is the timing of :class:`~nanosim.plant.twin.TwinStage` (its reading ends the period);
* the computation delay ``z^-d``, the amplifier lag ``Ha(z)`` (period mean of a first-order lag,
  :class:`~nanosim.plant.filters.AmplifierLag`), the gauge's output filter ``Hg(z)`` (Butterworth,
  Tustin prewarped, :class:`~nanosim.plant.filters.SampledFilter`);
* the reading ``y = Hg (Gm Ha (z^-d u + n_a) + F a) + n_s``, ``u = -(Ke - Ky) y`` at ``r = 0``: actuator-side
  noise ``n_a`` [controller V] after the delay, floor acceleration ``a`` through the floor model ``F``
  (:class:`~nanosim.plant.floor.FloorModel`), sensor-side noise ``n_s`` [sensor V] after the filter.

So ``y = S_o (Pa n_a + Hg F a + n_s)`` with ``S_o = (I + P K)^-1``, ``P = Hg Gm Ha z^-d``,
``Pa = Hg Gm Ha``, and the table (the true position) ``t = Gm Ha (n_a - z^-d K y) + F a``.

The sources (:data:`SOURCES`; a new one is one entry there) are read from the stage's
configuration objects by name (:class:`~nanosim.plant.electronics.ElectronicsConfig`,
:class:`~nanosim.plant.floor.FloorConfig`), one-sided PSDs per channel, independent between channels:

* ``DAC``: ``(2 sigma^2 / fs)(1 + f_c / f)``, white ``dac_noise_V`` per sample plus its flicker below
  ``dac_flicker_corner_Hz`` (the electronics' own spectrum);
* ``amplifier``: white ``amplifier_noise_V`` per sample, input-referred;
* ``gauge``: white ``sensor_noise_std_nm`` per sample at the reading;
* ``floor vibration``: white table-top acceleration ``accel_psd_m2_s4_Hz`` per axis;
* ``DAC and ADC quantization``: the quantizers are nonlinear; each is treated as white noise of
  ``step^2 / 12`` per sample (uniform error, Widrow), ``dac_lsb_V`` at the actuator, ``adc_lsb_V`` at
  the reading. This holds when the signal moves over several steps between samples; at rest with
  noise below one ADC step it is an approximation.

``sigma`` of a source is ``sqrt(int S df)`` from ``f_min_hz`` to the Nyquist frequency; with
``record_s`` the spectrum is weighted by ``1 - sinc^2(f T)``, the share of a component of frequency
``f`` left in the variance of a record of length ``T`` about its own mean (what the std of a simulated
or measured record sees).
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Callable

import numpy as np
from scipy import signal

from nanosim import constants as C
from nanosim.design.lti import ss_response

__all__ = ["NoiseSource", "SOURCES", "LoopModel", "loop_model", "analytic_budget", "AnalyticBudget",
           "cumulative_amplitude", "F_MIN_HZ"]

F_MIN_HZ = 0.01         # the lowest frequency integrated (the DAC flicker shaper's lowest pole)


@dataclass(frozen=True)
class NoiseSource:
    """One noise source: where it enters the loop and its one-sided PSD per channel.

    Attributes
    ----------
    name : str
        The name (the simulated budget's, :func:`nanosim.experiments.resolution.noise_sources`).
    psd : callable
        ``psd(f_hz, stage_config) -> {entry: PSD array}``: entry ``"actuator"`` [controller V^2/Hz],
        ``"sensor"`` [sensor V^2/Hz] or ``"floor"`` [(m/s^2)^2/Hz], each of ``f_hz``'s shape; an empty
        dict when the source is off in the configuration.
    """

    name: str
    psd: Callable


def _white(sigma: float, fs: float, f):
    return np.full(np.shape(f), 2.0 * sigma * sigma / fs)


def _dac(f, cfg):
    e = cfg.electronics
    if not e.dac_noise or e.dac_noise_V <= 0:
        return {}
    white = _white(e.dac_noise_V, e.sample_rate_Hz, f)
    if e.dac_noise_corner_Hz is not None:       # the two-pole low-pass of the white part, rms kept
        a = math.exp(-2 * math.pi * e.dac_noise_corner_Hz / e.sample_rate_Hz)
        zi = np.exp(-2j * np.pi * np.asarray(f) / e.sample_rate_Hz)
        h = 1.0 / (1.0 - a * zi) ** 2
        white = white * np.abs(h) ** 2 * (1 - a * a) ** 3 / (1 + a * a)       # sum h_k^2 = (1 + a^2)/(1 - a^2)^3
    flick = e.dac_flicker_V_per_rtHz ** 2 / np.asarray(f) if e.dac_flicker_corner_Hz else 0.0
    return {"actuator": white + flick}


def _amplifier(f, cfg):
    e = cfg.electronics
    if not e.amplifier_noise or e.amplifier_noise_V <= 0:
        return {}
    return {"actuator": _white(e.amplifier_noise_V, e.sample_rate_Hz, f)}


def _gauge(f, cfg):
    e = cfg.electronics
    if not e.sensor_noise or e.sensor_noise_std_nm <= 0:
        return {}
    return {"sensor": _white(e.sensor_noise_std_nm * 1e-3 / e.sensor_um_per_V, e.sample_rate_Hz, f)}


def _floor(f, cfg):
    fl = cfg.floor
    if not fl.enabled or fl.accel_psd_m2_s4_Hz <= 0:
        return {}
    return {"floor": np.full(np.shape(f), fl.accel_psd_m2_s4_Hz)}


def _quantization(f, cfg):
    e = cfg.electronics
    out = {}
    if e.dac_quantization:
        out["actuator"] = _white(e.dac_lsb_V / math.sqrt(12.0), e.sample_rate_Hz, f)
    if e.adc_quantization:
        out["sensor"] = _white(e.adc_lsb_V / math.sqrt(12.0), e.sample_rate_Hz, f)
    return out


# every source of the budget, in the order of the stacked figure
SOURCES: tuple[NoiseSource, ...] = (
    NoiseSource("DAC", _dac),
    NoiseSource("amplifier", _amplifier),
    NoiseSource("gauge", _gauge),
    NoiseSource("floor vibration", _floor),
    NoiseSource("DAC and ADC quantization", _quantization),
)


@dataclass(frozen=True, eq=False)
class LoopModel:
    """The linear chain of the loop as run (module docstring), discrete at ``dt_s``.

    Attributes
    ----------
    Gm : control.StateSpace
        Twin with the piezo's small-signal model, controller V -> sensor V.
    floor : FloorModel or None
        Base acceleration [m/s^2] -> probe displacement [um].
    config : StageConfig
        The electronics and floor levels the sources read.
    dt_s : float
    """

    Gm: object
    floor: object
    config: object
    dt_s: float = C.CONTROL_PERIOD_S

    def responses(self, f_hz):
        """``(Gm, Ha, Hg, F, delay)`` on ``f_hz``: (F, 3, 3), (F,), (F,), (F, 3, 3) sensor V per m/s^2 or None,
        (F,) ``z^-d``.
        """
        e = self.config.electronics
        z = np.exp(2j * np.pi * np.asarray(f_hz) * self.dt_s)
        A, B, Cm, D = (np.asarray(m, float) for m in (self.Gm.A, self.Gm.B, self.Gm.C, self.Gm.D))
        Gm = _ss_response(A, B, Cm, np.zeros_like(D), z) + D[None] / z[:, None, None]
        if e.amplifier_bandwidth_Hz is not None:
            tau = 1.0 / (2 * math.pi * e.amplifier_bandwidth_Hz)
            a = math.exp(-self.dt_s / tau)
            m = (tau / self.dt_s) * (1 - a)
            Ha = (1 - m) + m * (1 - a) / (z - a)
        else:
            Ha = np.ones_like(z)
        if e.gauge_bandwidth_Hz is not None:
            from nanosim.plant.filters import PREWARP_HZ, butterworth_lowpass
            w = 2 * math.pi * PREWARP_HZ
            b, a_ = signal.bilinear(*butterworth_lowpass(e.gauge_bandwidth_Hz, e.gauge_filter_order),
                                    fs=w / (2 * math.tan(w * self.dt_s / 2)))
            Hg = np.polyval(np.atleast_1d(np.squeeze(b)), z) / np.polyval(a_, z)
            Hg = Hg * z ** (len(a_) - len(np.atleast_1d(np.squeeze(b))))
        else:
            Hg = np.ones_like(z)
        F = None
        if self.floor is not None:
            fm = self.floor
            F = _ss_response(fm.Ad, fm.Bd, fm.Cd, np.zeros((3, 3)), z) / e.sensor_um_per_V
        delay = z ** (-e.computation_delay_samples)
        return Gm, Ha, Hg, F, delay


def _ss_response(A, B, Cm, D, z):
    """``C (zI - A)^-1 B + D`` on the points ``z`` (F,), shape (F, ny, nu), by one eigendecomposition."""
    return ss_response(A, B, Cm, D, z, modal="always")


def loop_model(base) -> LoopModel:
    """The :class:`LoopModel` of the MuJoCo stage ``base`` (:class:`~nanosim.plant.stage.Stage`): its
    mechanics and piezo linearized, its electronics and floor levels.
    """
    from nanosim.plant.floor import floor_model
    from nanosim.plant.linearize import linearize
    cfg = base.config
    tw = linearize(base, include_piezo=True)
    fm = floor_model(base.model, base.dt_s) if (cfg.floor.enabled and cfg.floor.accel_psd_m2_s4_Hz > 0) else None
    return LoopModel(Gm=tw.sysd_V, floor=fm, config=cfg, dt_s=float(tw.dt_s))


@dataclass(frozen=True, eq=False)
class AnalyticBudget:
    """Per-source PSDs of the reading and the table on one axis, and their sigmas.

    Attributes
    ----------
    freq_hz : ndarray
    psd_sensor_nm2_hz, psd_table_nm2_hz : dict of ndarray
        One-sided PSD per source [nm^2/Hz] (the record weighting applied when ``record_s`` is given).
    sigma_sensor_nm, sigma_table_nm : dict of float
        Per source; ``"total"`` is the root of the sum of variances (the sources are independent).
    axis : int
    record_s : float or None
    """

    freq_hz: np.ndarray
    psd_sensor_nm2_hz: dict
    psd_table_nm2_hz: dict
    sigma_sensor_nm: dict
    sigma_table_nm: dict
    axis: int
    record_s: float | None = None
    notes: dict = field(default_factory=dict)


GRID_POINTS = 20000      # log-spaced: 0.06 % steps, a tenth of the half-power width of a resonance with zeta = 0.003


def _grid(dt_s: float, f_min: float) -> np.ndarray:
    return np.logspace(np.log10(f_min), np.log10(0.5 / dt_s), GRID_POINTS)


def analytic_budget(controller, loop: LoopModel, *, axis: int = 0, record_s: float | None = None,
                    f_min_hz: float = F_MIN_HZ, sources=SOURCES) -> AnalyticBudget:
    """Every source's PSD at the reading and the table of ``axis``, through the closed loop (module docstring).

    Parameters
    ----------
    controller : DiscreteController or ControllerConfig
        The linear controller, inputs ``[e]`` or ``[e; y]``.
    loop : LoopModel
    axis : int
        0, 1, 2 for X, Y, Z.
    record_s : float, optional
        Weight the spectra by ``1 - sinc^2(f T)`` (a record of ``T`` seconds about its mean).
    f_min_hz : float
        Lowest frequency integrated.
    sources : sequence of NoiseSource

    Returns
    -------
    AnalyticBudget
    """
    c = getattr(controller, "config", controller)
    f = _grid(loop.dt_s, f_min_hz)
    z = np.exp(2j * np.pi * f * c.dt)
    Kz = _ss_response(np.asarray(c.Akd, float), np.asarray(c.Bkd, float), np.asarray(c.Ckd, float),
                      np.asarray(c.Dkd, float), z)
    Ke, Ky = Kz[:, :, :c.n_error], Kz[:, :, c.n_error:]
    K = Ke - Ky if Ky.shape[2] else Ke                                  # u = -K y at r = 0
    Gm, Ha, Hg, F, delay = loop.responses(f)
    Pa = Hg[:, None, None] * Gm * Ha[:, None, None]                     # actuator noise -> reading
    P = Pa * delay[:, None, None]
    n = P.shape[1]
    So = np.linalg.inv(np.eye(n)[None] + P @ K)
    GmHa = Gm * Ha[:, None, None]
    # reading: y = So (Pa n_a + Hg F a + n_s); table: t = GmHa n_a - GmHa z^-d K y + F a
    Ty = GmHa * delay[:, None, None] @ K                                # y -> table (minus sign below)
    paths_y = {"actuator": So @ Pa, "sensor": So, "floor": None if F is None else So @ (Hg[:, None, None] * F)}
    paths_t = {"actuator": GmHa - Ty @ paths_y["actuator"], "sensor": -Ty @ So,
               "floor": None if F is None else F - Ty @ paths_y["floor"]}
    w = np.ones_like(f) if record_s is None else 1.0 - np.sinc(f * record_s) ** 2
    um = C.SENSOR_UM_PER_V * 1e3            # nm per sensor V
    psd_y, psd_t = {}, {}
    for src in sources:
        spectra = src.psd(f, loop.config)
        if not spectra:
            continue
        sy = np.zeros_like(f)
        stb = np.zeros_like(f)
        for entry, S in spectra.items():
            if paths_y[entry] is None:
                continue
            sy = sy + S * np.sum(np.abs(paths_y[entry][:, axis, :]) ** 2, axis=1)
            stb = stb + S * np.sum(np.abs(paths_t[entry][:, axis, :]) ** 2, axis=1)
        psd_y[src.name] = sy * um * um * w
        psd_t[src.name] = stb * um * um * w
    sig = lambda d: {k: float(np.sqrt(np.trapezoid(v, f))) for k, v in d.items()}
    sy, st = sig(psd_y), sig(psd_t)
    sy["total"] = float(np.sqrt(sum(v * v for v in sy.values())))
    st["total"] = float(np.sqrt(sum(v * v for v in st.values())))
    return AnalyticBudget(freq_hz=f, psd_sensor_nm2_hz=psd_y, psd_table_nm2_hz=psd_t, sigma_sensor_nm=sy,
                          sigma_table_nm=st, axis=axis, record_s=record_s,
                          notes={"quantization": "DAC and ADC quantizers as white noise of step^2/12 per sample",
                                 "stable": bool(np.all(np.isfinite(So)))})


def cumulative_amplitude(freq_hz, psd) -> np.ndarray:
    """Cumulative amplitude spectrum ``sqrt(int_{f_0}^{f} S df')`` (trapezoidal), same units as sqrt(S Hz)."""
    f = np.asarray(freq_hz, float)
    s = np.asarray(psd, float)
    inc = 0.5 * (s[1:] + s[:-1]) * np.diff(f)
    return np.sqrt(np.concatenate([[0.0], np.cumsum(inc)]))
