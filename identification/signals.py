"""Excitation signals for time-domain identification.

Implements the "modified pseudorandom binary signal" of the seed paper
(Section 3): a step plus pseudorandom binary sequences (PRBS) in three
frequency bands (50, 100 and 200 Hz), each 1 s long, peak 0.5 V, sampled at
4 kHz.

The PRBS are maximum-length sequences (MLS, ``scipy.signal.max_len_seq``)
held for ``P`` samples per chip (zero-order hold at a *clock* rate
``f_clk = fs / P``).  A held binary random sequence has the power spectral
density ``amplitude**2 * P / fs * sinc(f / f_clk)**2``, which is flat at low
frequency, 3.9 dB down at ``f_clk / 2`` and zero at ``f_clk`` and its
multiples.  This module uses ``f_clk = 2 * band_hz`` (``P = round(fs / (2 *
band_hz))``), so the spectrum of ``prbs(..., band_hz=B)`` is within 3.9 dB of
its DC level up to ``B`` and has its first null at ``2 B``.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import signal as _sig

from .checks import as_signal, frozen_array, nonneg_float, positive_float, positive_int, welch_segment_length

__all__ = ["prbs", "prbs_channels", "prbs_hold_samples", "paper_excitation", "Excitation", "signal_spectrum",
           "Spectrum"]


def prbs_hold_samples(band_hz: float, *, fs: float) -> int:
    """Number of samples each PRBS chip is held for a given band.

    Parameters
    ----------
    band_hz : float
        Band edge in Hz, ``0 < band_hz <= fs / 2``.
    fs : float
        Sampling frequency in Hz.

    Returns
    -------
    int
        ``P = max(1, round(fs / (2 * band_hz)))``; the chip clock is ``fs / P``
        (about ``2 * band_hz``).
    """
    fs = positive_float("fs", fs)
    band_hz = positive_float("band_hz", band_hz)
    if band_hz > fs / 2 * (1 + 1e-12):
        raise ValueError(f"band_hz: expected a value <= fs/2 = {fs / 2:g} Hz, got {band_hz:g} Hz")
    hold = fs / (2.0 * band_hz)
    if not hold < 2.0**62:        # a band so narrow that one chip would outlast any record (or overflow)
        raise ValueError(f"band_hz: expected at least fs/2**63 = {fs / 2.0**63:.3g} Hz, got {band_hz:g} Hz")
    return max(1, int(round(hold)))


def prbs(n_samples: int, band_hz: float, *, fs: float, amplitude: float = 1.0, seed=0) -> np.ndarray:
    """Pseudorandom binary sequence built from a maximum-length sequence.

    Parameters
    ----------
    n_samples : int
        Number of output samples.
    band_hz : float
        Band edge in Hz (``0 < band_hz <= fs/2``).  Each chip of the MLS is
        held for ``P = max(1, round(fs / (2 band_hz)))`` samples, so the power
        spectrum ``~ sinc(f P / fs)**2`` is within 3.9 dB of its DC value up to
        ``band_hz`` and has its first null at ``fs / P ~ 2 band_hz``.  With
        ``band_hz = fs/2`` the sequence is not held (white binary sequence).
    fs : float
        Sampling frequency in Hz.
    amplitude : float, default 1.0
        Output levels are ``+amplitude`` and ``-amplitude`` (signal units,
        e.g. V).
    seed : int, numpy.random.SeedSequence or numpy.random.Generator, default 0
        Selects the (nonzero) initial shift-register state, i.e. the cyclic
        shift of the MLS.  Same seed -> same sequence.

    Returns
    -------
    numpy.ndarray, shape (n_samples,)
        Values in ``{-amplitude, +amplitude}``.

    Notes
    -----
    The register length is the smallest ``nbits >= 2`` with
    ``2**nbits - 1 >= ceil(n_samples / P)``, so the chips never repeat within
    the returned signal.  When ``n_samples == P * (2**nbits - 1)`` the signal is
    exactly one period and has the two-valued periodic autocorrelation of an
    MLS (``N`` at lag 0, ``-1`` elsewhere, in chip units).
    """
    return prbs_channels(n_samples, band_hz, fs=fs, n_channels=1, amplitude=amplitude, seed=seed)[:, 0]


def prbs_channels(n_samples: int, band_hz: float, *, fs: float, n_channels: int, amplitude: float = 1.0,
                  seed=0) -> np.ndarray:
    """``n_channels`` simultaneous PRBS for a MIMO experiment: disjoint stretches of one MLS.

    Independent calls of :func:`prbs` give cyclic shifts of the *same* MLS, so two channels whose
    shifts happen to be close are one signal delayed: at frequencies below about one over that delay
    their cross-spectrum is nearly the auto-spectrum, the input spectral matrix of a MIMO H1 estimate
    is nearly singular and the estimate is biased there. Here the channels are consecutive,
    non-overlapping stretches of one sequence (the register is long enough for all of them), so no
    channel repeats another at any lag within the record.

    Parameters
    ----------
    n_samples, band_hz, fs, amplitude : as :func:`prbs`.
    n_channels : int
        Number of channels (>= 1).
    seed : int, numpy.random.SeedSequence or numpy.random.Generator, default 0
        Selects the initial register state. Same seed -> same signals.

    Returns
    -------
    numpy.ndarray, shape (n_samples, n_channels)
        Values in ``{-amplitude, +amplitude}``.
    """
    n_samples = positive_int("n_samples", n_samples)
    n_channels = positive_int("n_channels", n_channels)
    amplitude = positive_float("amplitude", amplitude)
    hold = prbs_hold_samples(band_hz, fs=fs)
    n_chips = -(-n_samples // hold)
    nbits = max(2, int(np.ceil(np.log2(n_channels * n_chips + 1))))
    if nbits > 32:
        channels = f" and {n_channels} channels" if n_channels > 1 else ""
        raise ValueError(f"n_samples: expected at most {hold * ((2**32 - 1) // n_channels)} samples for this band"
                         f"{channels}, got {n_samples}")
    rng = np.random.default_rng(_seed_sequence(seed))
    state = rng.integers(0, 2, size=nbits)
    if not state.any():
        state[rng.integers(nbits)] = 1
    chips = _sig.max_len_seq(nbits, state=state, length=n_channels * n_chips)[0].reshape(n_channels, n_chips).T
    u = amplitude * (2.0 * chips.astype(float) - 1.0)
    return u[np.arange(n_samples) // hold]            # each chip held ``hold`` samples (never more than needed)


def _seed_sequence(seed) -> np.random.SeedSequence:
    if isinstance(seed, np.random.SeedSequence):
        return seed
    if isinstance(seed, np.random.Generator):
        return np.random.SeedSequence(int(seed.integers(2**63)))
    try:
        return np.random.SeedSequence(seed)
    except (TypeError, ValueError):
        raise ValueError(f"seed: expected a non-negative int, SeedSequence or Generator, got {seed!r}") from None


@dataclass(frozen=True, eq=False)
class Excitation:
    """Identification input signal with its segment layout.

    Attributes
    ----------
    t_s : numpy.ndarray, shape (n_samples,)
        Time in s, ``t_s[k] = k / fs``.
    u : numpy.ndarray, shape (n_samples,)
        Input signal (controller volts); ``max|u| == amplitude``.
    fs : float
        Sampling frequency in Hz.
    amplitude : float
        Peak input magnitude (V).
    step_level : float
        Level of the step segment (V), ``amplitude / 2``.
    segment_names : tuple of str
        ``("lead_in", "step", "prbs_50Hz", ...)`` (``lead_in`` only if its
        duration is > 0).
    segment_bounds : numpy.ndarray of int, shape (n_segments, 2)
        ``[start, stop)`` sample indices of each segment.
    bands_hz : tuple of float
        PRBS band edges in Hz, in segment order.
    """

    t_s: np.ndarray
    u: np.ndarray
    fs: float
    amplitude: float
    step_level: float
    segment_names: tuple
    segment_bounds: np.ndarray
    bands_hz: tuple

    def segment(self, name: str) -> slice:
        """Sample slice of the segment called ``name``."""
        if name not in self.segment_names:
            raise ValueError(f"name: expected one of {self.segment_names}, got {name!r}")
        start, stop = self.segment_bounds[self.segment_names.index(name)]
        return slice(int(start), int(stop))


def paper_excitation(
    fs: float = 4000.0,
    amplitude: float = 0.5,
    bands_hz=(50.0, 100.0, 200.0),
    band_duration_s: float = 1.0,
    step_duration_s: float = 1.0,
    *,
    lead_in_s: float = 0.0,
    ride_on_step: bool = True,
    seed=0,
) -> Excitation:
    """Step plus multi-band PRBS excitation of the seed paper (Sec. 3, Fig. 4a).

    Layout (all segments back to back, system assumed at rest before ``t=0``):

    1. ``lead_in`` (optional, ``lead_in_s`` long): ``u = 0``.
    2. ``step``: ``u = amplitude / 2`` for ``step_duration_s``.  Holding the
       step for many time constants of the slowest (creep) pole gives a
       settled plateau from which the DC gain is identified accurately.
    3. One PRBS segment per entry of ``bands_hz`` (``band_duration_s`` each),
       see :func:`prbs` for the band definition.  With ``ride_on_step=True``
       (default) the PRBS of amplitude ``amplitude / 2`` rides on the step
       level, so ``u`` switches between ``0`` and ``amplitude``: the input
       keeps the DC level of the step (more low-frequency information) and
       stays unipolar, as preferred by piezo drivers.  With
       ``ride_on_step=False`` the PRBS switches between ``+-amplitude``
       around zero (4x more power at the resonances, DC information from the
       step segment only).

    In both cases ``max|u| == amplitude``.

    Parameters
    ----------
    fs : float, default 4000.0
        Sampling frequency in Hz.
    amplitude : float, default 0.5
        Peak input magnitude (V).
    bands_hz : sequence of float, default (50, 100, 200)
        PRBS band edges in Hz, each ``<= fs / 2``.
    band_duration_s : float, default 1.0
        Duration of each PRBS segment in s.
    step_duration_s : float, default 1.0
        Duration of the step plateau in s.
    lead_in_s : float, default 0.0
        Zero-input lead-in before the step, in s.
    ride_on_step : bool, default True
        See above.
    seed : int or numpy.random.SeedSequence, default 0
        Seed; each band gets an independent child seed.

    Returns
    -------
    Excitation
        Frozen dataclass with ``t_s``, ``u`` and the segment layout.  The
        defaults give 4 s = 16000 samples.
    """
    fs = positive_float("fs", fs)
    amplitude = positive_float("amplitude", amplitude)
    band_duration_s = positive_float("band_duration_s", band_duration_s)
    step_duration_s = positive_float("step_duration_s", step_duration_s)
    lead_in_s = nonneg_float("lead_in_s", lead_in_s)
    try:
        bands = tuple(float(b) for b in bands_hz)
    except TypeError:
        raise ValueError(f"bands_hz: expected a sequence of frequencies in Hz, got {bands_hz!r}") from None
    if not bands:
        raise ValueError("bands_hz: expected at least one band, got an empty sequence")
    for b in bands:
        prbs_hold_samples(b, fs=fs)  # validates each band
    n_lead = int(round(lead_in_s * fs))
    n_step = int(round(step_duration_s * fs))
    n_band = int(round(band_duration_s * fs))
    if n_step < 1 or n_band < 1:
        raise ValueError(
            f"step_duration_s, band_duration_s: expected at least one sample each at fs={fs:g} Hz, "
            f"got {n_step} and {n_band} samples"
        )
    step_level = amplitude / 2.0
    names, pieces = [], []
    if n_lead:
        names.append("lead_in")
        pieces.append(np.zeros(n_lead))
    names.append("step")
    pieces.append(np.full(n_step, step_level))
    children = _seed_sequence(seed).spawn(len(bands))
    for b, child in zip(bands, children):
        names.append(f"prbs_{b:g}Hz")
        if ride_on_step:
            pieces.append(step_level + prbs(n_band, b, fs=fs, amplitude=amplitude / 2.0, seed=child))
        else:
            pieces.append(prbs(n_band, b, fs=fs, amplitude=amplitude, seed=child))
    lengths = np.array([len(p) for p in pieces])
    stops = np.cumsum(lengths)
    bounds = np.stack([stops - lengths, stops], axis=1)
    u = np.concatenate(pieces)
    t = np.arange(u.size) / fs
    return Excitation(
        t_s=frozen_array(t),
        u=frozen_array(u),
        fs=fs,
        amplitude=amplitude,
        step_level=step_level,
        segment_names=tuple(names),
        segment_bounds=frozen_array(bounds),
        bands_hz=bands,
    )


@dataclass(frozen=True, eq=False)
class Spectrum:
    """Welch power spectral density.

    Attributes
    ----------
    freq_hz : numpy.ndarray, shape (n_freq,)
        Frequencies in Hz.
    psd : numpy.ndarray, shape (n_freq,) or (n_channels, n_freq)
        One-sided PSD in (signal unit)**2 / Hz; 1-D for a 1-D input.
    fs : float
        Sampling frequency in Hz.
    nperseg : int
        Welch segment length in samples (resolution ``fs / nperseg`` Hz).
    """

    freq_hz: np.ndarray
    psd: np.ndarray
    fs: float
    nperseg: int


def signal_spectrum(u, *, fs: float, nperseg: int | None = None, window: str = "hann") -> Spectrum:
    """One-sided Welch PSD of a signal, for reporting excitation content.

    Parameters
    ----------
    u : array_like, shape (n_samples,) or (n_samples, n_channels)
        Signal; columns are channels.
    fs : float
        Sampling frequency in Hz.
    nperseg : int, optional
        Segment length; default ``min(n_samples, max(256, round(fs)))``
        (about 1 Hz resolution when enough data is available).
    window : str, default "hann"
        Window passed to :func:`scipy.signal.welch`.

    Returns
    -------
    Spectrum
    """
    one_d = np.ndim(u) == 1
    x = as_signal("u", u)
    fs = positive_float("fs", fs)
    n = x.shape[0]
    nperseg = welch_segment_length(nperseg, n, fs)
    f, p = _sig.welch(x, fs=fs, window=window, nperseg=nperseg, axis=0)
    p = p.T
    return Spectrum(freq_hz=frozen_array(f), psd=frozen_array(p[0] if one_d else p), fs=fs, nperseg=nperseg)
