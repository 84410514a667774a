"""The bench electronics of B stages at once: DAC, amplifier, piezo operators and creep, gauge, ADC.

Each member has three channels; the state is held as ``3 B`` channels and
every effect is one numpy operation over all of them, in the order and with
the formulas of the single-stage chains
(:class:`~nanosim.plant.electronics.ActuatorChain`,
:class:`~nanosim.plant.electronics.SensorChain`,
:class:`~nanosim.plant.piezo.PiezoModel`), from the same
:class:`~nanosim.plant.electronics.ElectronicsConfig` and
:class:`~nanosim.plant.piezo.PiezoConfig`. Member ``b`` therefore gives
bit-for-bit the numbers of a single stage with seed ``seeds[b]``
(``tests/test_batch.py`` holds that contract: a change to the single-stage
chains that is not mirrored here fails it).

The chain (``ActuatorChain.step``, ``SensorChain.step``): computation delay
(:class:`~nanosim.plant.filters.DelayLine`), DAC quantiser, DAC noise (white and
flicker), input-referred amplifier noise, saturation, gain, amplifier lag
(:class:`~nanosim.plant.filters.AmplifierLag`), piezo operators (the compiled
:func:`~nanosim.plant.piezo.play_channel` of the single stage), linear creep; gauge filter
(:class:`~nanosim.plant.filters.SampledFilter`), gauge noise, clip, ADC. The
filters are the single-stage classes on ``3 B`` channels.

Noise: each member's DAC noise (white, flicker and the legs' thermal drift),
amplifier noise and gauge noise are drawn by
single-stage chains built from that member's seed with every other effect off
(amplifier gain 1 for the amplifier noise), so their outputs are exactly the
noise terms the single stage adds (same generators, same block draws, same
shaping filters); they are added where the single stage adds them.
"""
from __future__ import annotations

from dataclasses import replace
from typing import Sequence

import numpy as np

from scipy.signal import lfilter

from nanosim.plant import batch_kernel
from nanosim.plant.electronics import ActuatorChain, ElectronicsConfig, SensorChain
from nanosim.plant.filters import AmplifierLag, DelayLine, SampledFilter, butterworth_lowpass
from nanosim.plant.piezo import PiezoConfig, play_run

__all__ = ["BatchElectronics", "BatchReading"]

_NOISE_CHUNK = 4096          # noise samples drawn per member at a time


class _NoiseTerms:
    """Per-member additive noise terms, drawn in chunks from the members' own single-stage chains."""

    def __init__(self, make_chain, extract, seeds):
        self._make, self._extract, self._seeds = make_chain, extract, list(seeds)
        self.reset()

    def reset(self) -> None:
        self._chains = [self._make(s) for s in self._seeds]
        self._buf = np.empty((0, 3 * len(self._seeds)))
        self._i = 0

    def _refill(self) -> None:
        zeros = np.zeros((_NOISE_CHUNK, 3))
        self._buf = np.concatenate([self._extract(ch.run(zeros)) for ch in self._chains], axis=1)
        self._i = 0

    def take(self, n: int) -> np.ndarray:
        """The next ``n`` rows, shape ``(n, 3 B)``: the numbers ``n`` calls of :meth:`take1` give."""
        out = np.empty((n, 3 * len(self._seeds)))
        filled = 0
        while filled < n:
            if self._i == len(self._buf):
                self._refill()
            k = min(n - filled, len(self._buf) - self._i)
            out[filled:filled + k] = self._buf[self._i:self._i + k]
            self._i += k
            filled += k
        return out

    def rows_left(self) -> int:
        """Rows left in the drawn chunk (a new chunk is drawn if none is)."""
        if self._i == len(self._buf):
            self._refill()
        return len(self._buf) - self._i

    def rows(self, n: int) -> np.ndarray:
        """The next ``n <= rows_left()`` rows as a view of the chunk (the numbers of :meth:`take`, no copy);
        valid until the next chunk is drawn.
        """
        if n > len(self._buf) - self._i:
            raise ValueError(f"n: expected at most {len(self._buf) - self._i} rows (rows_left), got {n}")
        out = self._buf[self._i:self._i + n]
        self._i += n
        return out

    def take1(self) -> np.ndarray:
        """Next noise term of every channel, shape ``(3 B,)``."""
        if self._i == len(self._buf):
            self._refill()
        row = self._buf[self._i]
        self._i += 1
        return row


class _StackedNoise(_NoiseTerms):
    """The same terms as :class:`_NoiseTerms`, drawn from the members' streams and shaped for all
    channels at once (the chains' arithmetic: ``0 + sigma w (+ flicker)``, flicker through
    :func:`~nanosim.plant.batch_kernel.flicker_cascade`), instead of running each member's chain.
    """

    def __init__(self, make_chain, kind: str, seeds):
        self._kind = kind
        super().__init__(make_chain, None, seeds)

    def reset(self) -> None:
        super().reset()
        ch0 = self._chains[0]
        if self._kind == "gauge":
            self._sigma = ch0._sigma_um
        elif self._kind == "amp":
            self._sigma = ch0._sigma_amp
        else:
            self._sigma = ch0._sigma
            fl = ch0._flicker
            if fl is not None:
                self._fl_gain = fl._gain
                self._fl_bz = np.array([bz for bz, _ in fl._sec])
                self._fl_ap = np.array([ap for _, ap in fl._sec])
                self._fl_z = np.zeros((len(fl._sec), 3 * len(self._seeds)))
            if ch0._drift_noise is not None:            # each chain's stationary start, members side by side
                self._drift_z = np.concatenate([ch._drift_z for ch in self._chains])
                self._drift_z2 = np.concatenate([ch._drift_z2 for ch in self._chains])

    def _gather(self, stream: str, k: int) -> np.ndarray:
        """``(k, 3 B)``: ``k`` rows of every member's ``stream``, members side by side (``np.concatenate``'s)."""
        out = np.empty((k, 3 * len(self._chains)))
        for b, ch in enumerate(self._chains):
            getattr(ch, stream).take_into(out[:, 3 * b:3 * b + 3])
        return out

    def _refill(self) -> None:
        # the arithmetic of the chains, 0 + sigma w (+ flicker), in place: no new chunk-sized arrays
        k = _NOISE_CHUNK
        ch0 = self._chains[0]
        if self._kind in ("gauge", "amp"):
            total = self._gather("_noise" if self._kind == "gauge" else "_amp_noise", k)
            np.multiply(self._sigma, total, out=total)
        else:
            total = None
            if self._sigma > 0.0:
                total = self._gather("_noise", k)
                np.multiply(self._sigma, total, out=total)
            if ch0._flicker is not None:
                e = self._gather("_flicker_noise", k)
                f = batch_kernel.flicker_cascade(e, self._fl_gain, self._fl_bz, self._fl_ap, self._fl_z)
                if total is None:
                    total = f
                else:
                    np.add(total, f, out=total)
            if ch0._drift_noise is not None:            # ActuatorChain._noise_run's two sections, every channel
                w = self._gather("_drift_noise", k)
                x, zf = lfilter([ch0._drift_b0, 0.0], [1.0, -ch0._drift_a], w, axis=0, zi=self._drift_z[None])
                t, zf2 = lfilter([ch0._drift_c0, 0.0], [1.0, -ch0._drift_b], x, axis=0, zi=self._drift_z2[None])
                self._drift_z, self._drift_z2 = zf[0], zf2[0]
                d = np.multiply(ch0._drift_scale, t, out=t)
                if total is None:
                    total = d
                else:
                    np.add(total, d, out=total)
        np.add(0.0, total, out=total)
        self._buf = total
        self._i = 0


def _noise_terms(make_chain, extract, kind: str, seeds) -> _NoiseTerms:
    """Stacked noise when numba is there and the chain has no AR-shaped white noise, else per chain."""
    if batch_kernel.AVAILABLE:
        ch = make_chain(0)
        if getattr(ch, "_ar", 0.0) == 0.0:
            return _StackedNoise(make_chain, kind, seeds)
    return _NoiseTerms(make_chain, extract, seeds)


class _StepElectronics:
    """:meth:`BatchElectronics.actuate` and :meth:`~BatchElectronics.read`, one period per compiled call.

    For stages whose mechanics is stepped outside the compiled loop (the MuJoCo batch): the same
    arithmetic as the compiled loop on the electronics' own state arrays and noise streams, so the
    numpy methods and these can be mixed in any order.
    """

    def __init__(self, el):
        self.el = el
        self.ip, self.fp = batch_kernel.electronics_params(el)
        nch = 3 * el.n
        self._hcr = np.empty(nch)
        self._none1 = np.zeros((1, 0))
        if el._hyst:
            self._pr, self._pw, self._pom, self._pp = el._r, el._w, el._om, el._pp
        else:
            self._pr = self._pw = self._pom = np.zeros(0)
            self._pp = np.zeros(2)
        if el._creep:
            self._csc, self._ca, self._cb = (np.ascontiguousarray(c[:, 0]) for c in (el._sc_col, el._a_col, el._b_col))
        else:
            self._csc = self._ca = self._cb = np.zeros(0)
        gf = el._gauge_filter
        self._gb, self._ga = ((np.ascontiguousarray(gf._b), np.ascontiguousarray(gf._a)) if gf is not None
                              else (np.zeros(1), np.zeros(1)))

    def _row(self, src):
        return src.take1()[None, :] if src is not None else self._none1

    def actuate(self, u_V: np.ndarray):
        """Controller volts ``(B, 3)`` -> ``(None, v_piezo_V, v_free_V, saturated)`` (no ``u_dac_V``)."""
        el = self.el
        shape = u_V.shape
        uu = np.array(u_V, dtype=float).reshape(-1)
        nch = uu.shape[0]
        v_pz, v_free, sat = np.empty(nch), np.empty(nch), np.empty(nch, dtype=bool)
        dbuf = el._delay._buf if el._delay.n else np.zeros((0, nch))
        z = el._z if el._hyst else np.zeros((nch, 0))
        cx = el._x if el._creep else np.zeros((0, nch))
        batch_kernel.actuate_period(uu, 0, self.ip, self.fp, dbuf, self._row(el._dac_noise), self._row(el._amp_noise),
                                    el._lag._v, self._pr, self._pw, self._pom, self._pp, z, self._hcr, self._csc,
                                    self._ca, self._cb, cx, v_pz, v_free, sat)
        return None, v_pz.reshape(shape), v_free.reshape(shape), sat.reshape(shape)

    def read(self, displacement_um: np.ndarray):
        """True displacements ``(B, 3)`` um -> ``(reading_V, reading_um, clipped)``, or None if the gauge
        filter has not started (the numpy method starts it).
        """
        el = self.el
        gf = el._gauge_filter
        if gf is not None and gf._z is None:
            return None
        shape = displacement_um.shape
        dd = np.array(displacement_um, dtype=float).reshape(-1)
        nch = dd.shape[0]
        yv, yu, cl = np.empty(nch), np.empty(nch), np.empty(nch, dtype=bool)
        gz = gf._z if gf is not None else np.zeros((0, nch))
        batch_kernel.sense_period(dd, 0, self.ip, self.fp, self._gb, self._ga, gz, self._row(el._gauge_noise),
                                  yv, yu, cl)
        return yv.reshape(shape), yu.reshape(shape), cl.reshape(shape)


class BatchReading:
    """Gauge/ADC output of a batch: ``reading_V``, ``reading_um``, ``clipped``, each ``(B, 3)``."""

    __slots__ = ("reading_V", "reading_um", "clipped")

    def __init__(self, reading_V, reading_um, clipped):
        self.reading_V, self.reading_um, self.clipped = reading_V, reading_um, clipped


class BatchElectronics:
    """Actuator and sensor chains of B stages (3 channels each), vectorized over the batch.

    Parameters
    ----------
    electronics : ElectronicsConfig
    piezo : PiezoConfig
    seeds : sequence of int
        Master seed of each member (DAC noise: child stream 0, gauge noise: child 1,
        as in the single-stage chains).
    """

    def __init__(self, electronics: ElectronicsConfig, piezo: PiezoConfig, seeds: Sequence[int]):
        if electronics.drive != "voltage":
            raise ValueError(f"electronics.drive: the batch electronics runs the voltage drive only; expected "
                             f"'voltage', got {electronics.drive!r} (run the charge drive on single stages: "
                             f"Stage, TwinStage)")
        self.electronics, self.piezo_config = electronics, piezo
        self.seeds = list(seeds)
        if not self.seeds:
            raise ValueError("seeds: expected at least one seed (one per batch member), got none")
        self.n = len(self.seeds)
        self._steps = None
        e, p = electronics, piezo
        nch = 3 * self.n
        # DAC and amplifier (ActuatorChain._electronics)
        self._quant = e.dac_quantization
        self._lsb = e.dac_lsb_V
        self._code_lo = -float(2 ** (e.dac_bits - 1))
        self._code_hi = float(2 ** (e.dac_bits - 1) - 1)
        self._center = e.dac_center_V
        self._sat = e.saturation
        self._lo, self._hi = e.command_range_V
        self._gain = e.amplifier_gain
        sigma = e.dac_noise_V if e.dac_noise else 0.0
        flick = e.dac_flicker_V_per_rtHz
        sigma_amp = e.amplifier_noise_V if e.amplifier_noise else 0.0
        drift = e.thermal_drift_V
        margin = 20.0 * (sigma + sigma_amp + 3.5 * flick + drift)
        self._delay = DelayLine(e.computation_delay_samples, nch)
        self._lag = AmplifierLag(e.amplifier_bandwidth_Hz, e.dt_s, nch)
        self._dac_clip_implied = (self._quant and self._center + self._code_lo * self._lsb + margin < self._lo
                                  and self._hi < self._center + self._code_hi * self._lsb - margin)
        # piezo (PlayOperators through the compiled play_run, KelvinVoigtCreep)
        self._hyst = p.hysteresis
        if self._hyst:
            w0, w = p.hysteresis_weights()
            self._w0, self._w = float(w0), np.ascontiguousarray(w, dtype=float).copy()
            self._r = np.ascontiguousarray(p.pi_thresholds_V, dtype=float).copy()
            self._om, self._pp = p.kernel_arrays(e.dt_s)
            self._z0 = np.zeros((nch, self._r.size))
            self._h1 = np.empty((1, nch))
        self._creep = p.linear_creep
        if self._creep:
            c = np.asarray(p.creep_gains, dtype=float)
            tau = np.asarray(p.creep_time_constants_s, dtype=float)
            a = np.exp(-e.dt_s / tau)
            self._a_col, self._b_col = a[:, None], (1.0 - a)[:, None]
            self._scale = 1.0 / (1.0 + float(c.sum())) if p.normalize_creep_dc else 1.0
            self._sc_col = np.array([self._scale * float(ck) for ck in c])[:, None]
            self._x0 = np.zeros((c.size, nch))
            self._terms = np.empty((c.size + 1, nch))
        # gauge filter, gauge and ADC (SensorChain.step)
        self._gauge_filter = (SampledFilter(*butterworth_lowpass(e.gauge_bandwidth_Hz, e.gauge_filter_order),
                                            e.dt_s, nch) if e.gauge_bandwidth_Hz is not None else None)
        self._clip = e.sensor_clip
        self._range = e.sensor_range_um
        self._um_per_V = e.sensor_um_per_V
        self._adc = e.adc_quantization
        if self._adc:
            self._adc_lsb = e.adc_lsb_V
            self._adc_lsb_um = self._adc_lsb * self._um_per_V
            self._adc_lo = -float(2 ** (e.adc_bits - 1))
            self._adc_hi = float(2 ** (e.adc_bits - 1) - 1)
        quiet = dict(dac_quantization=False, saturation=False, sensor_clip=False, adc_quantization=False,
                     computation_delay_samples=0, amplifier_bandwidth_Hz=None)
        self._dac_noise = self._amp_noise = self._gauge_noise = None
        if sigma > 0.0 or flick > 0.0 or drift > 0.0:          # u_dac = 0 + (white + flicker + drift)
            dac_cfg = replace(e, sensor_noise=False, amplifier_noise=False, **quiet)
            self._dac_noise = _noise_terms(lambda s: ActuatorChain(dac_cfg, PiezoConfig.linear(), seed=s),
                                           lambda smp: smp.u_dac_V, "dac", self.seeds)
        if sigma_amp > 0.0:                     # v_piezo = 1 x (0 + amplifier noise)
            amp_cfg = replace(e, sensor_noise=False, dac_noise=False, thermal_drift=False,
                              amplifier_gain=1.0, **quiet)
            self._amp_noise = _noise_terms(lambda s: ActuatorChain(amp_cfg, PiezoConfig.linear(), seed=s),
                                           lambda smp: smp.v_piezo_V, "amp", self.seeds)
        if e.sensor_noise and e.sensor_noise_std_nm > 0:
            gauge_cfg = replace(e, dac_noise=False, thermal_drift=False, **quiet)
            self._gauge_noise = _noise_terms(lambda s: SensorChain(gauge_cfg, seed=s), lambda smp: smp.reading_um,
                                             "gauge", self.seeds)
        self.reset()

    def use_compiled_steps(self) -> None:
        """Make :meth:`actuate` and :meth:`read` compiled calls (numba; the same numbers), if numba is there."""
        if batch_kernel.AVAILABLE:
            self._steps = _StepElectronics(self)

    def reset(self) -> None:
        """Virgin piezos, no creep history, every noise stream rewound to its seed."""
        if self._hyst:
            self._z = self._z0.copy()
        if self._creep:
            self._x = self._x0.copy()
        for part in (self._dac_noise, self._amp_noise, self._gauge_noise, self._delay, self._lag,
                     self._gauge_filter):
            if part is not None:
                part.reset()

    @property
    def hysteresis_state(self) -> np.ndarray | None:
        """Copy of the operator outputs, ``(3 B, n_operators)`` (None without hysteresis)."""
        return self._z.copy() if self._hyst else None

    def actuate(self, u_V: np.ndarray):
        """Controller volts ``(B, 3)`` -> ``(u_dac_V, v_piezo_V, v_free_V, saturated)``, each ``(B, 3)``.

        The operations are those of ``ActuatorChain.step`` (in place where that changes
        nothing); the creep sum ``s h + sum_k s c_k x_k`` is one reduction along the
        stage axis, which numpy evaluates left to right like the single chain's loop.
        """
        if self._steps is not None:
            return self._steps.actuate(u_V)
        shape = u_V.shape
        u = self._delay.step(u_V.reshape(-1))
        maximum, minimum = np.maximum, np.minimum
        if self._quant:
            code = np.subtract(u, self._center)
            np.divide(code, self._lsb, out=code)
            np.rint(code, out=code)
            code_c = maximum(code, self._code_lo)
            minimum(code_c, self._code_hi, out=code_c)
            u_dac = np.multiply(code_c, self._lsb)
            np.add(self._center, u_dac, out=u_dac)
        else:
            code = code_c = None
            u_dac = u.copy()
        if self._dac_noise is not None:
            np.add(u_dac, self._dac_noise.take1(), out=u_dac)
        u_in = u_dac if self._amp_noise is None else u_dac + self._amp_noise.take1()
        if self._sat:
            u_cmd = maximum(u_in, self._lo)
            minimum(u_cmd, self._hi, out=u_cmd)
            sat = u_cmd != u_in
            if code is not None and not self._dac_clip_implied:
                sat |= code_c != code
        else:
            u_cmd = u_in
            sat = (code_c != code) if code is not None else np.zeros(u.shape, dtype=bool)
        v = self._lag.step(np.multiply(self._gain, u_cmd))
        h = v
        if self._hyst:                                          # the single stage's compiled operators
            play_run(v.reshape(1, -1), self._z, self._r, self._w, self._om, self._pp, self._h1)
            h = self._h1[0].copy()
        if self._creep:
            terms = self._terms
            np.multiply(self._scale, h, out=terms[0])
            np.multiply(self._sc_col, self._x, out=terms[1:])
            hc = np.add.reduce(terms, axis=0)
            x = self._x
            np.multiply(self._a_col, x, out=x)
            x += self._b_col * h
            h = hc
        return u_dac.reshape(shape), v.reshape(shape), h.reshape(shape), sat.reshape(shape)

    def read(self, displacement_um: np.ndarray) -> BatchReading:
        """True probe displacements ``(B, 3)`` um -> gauge noise, clip, ADC (one sample per member)."""
        if self._steps is not None:
            out = self._steps.read(displacement_um)
            if out is not None:
                return BatchReading(*out)
        shape = displacement_um.shape
        d = displacement_um.reshape(-1)
        if self._gauge_filter is not None:
            d = self._gauge_filter.step(d)
        if self._gauge_noise is not None:
            d = d + self._gauge_noise.take1()
        if self._clip:
            dc = np.minimum(np.maximum(d, -self._range), self._range)
            clipped = dc != d
            d = dc
        else:
            clipped = np.zeros(d.shape, dtype=bool)
        if self._adc:
            code = np.rint(d / self._um_per_V / self._adc_lsb)
            code_c = np.minimum(np.maximum(code, self._adc_lo), self._adc_hi)
            clipped |= code_c != code
            return BatchReading((code_c * self._adc_lsb).reshape(shape), (code_c * self._adc_lsb_um).reshape(shape),
                                clipped.reshape(shape))
        return BatchReading((d / self._um_per_V).reshape(shape), d.reshape(shape).copy(), clipped.reshape(shape))
