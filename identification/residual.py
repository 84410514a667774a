"""What a model leaves unexplained, referred to its input.

A controller with a disturbance observer assumes a spectrum for the disturbance at the plant input
(the piezo's hysteresis and creep, on this stage). :func:`input_referred_residual` measures that
spectrum on an identification record: the residual ``r = y - G u`` of the identified single-input
model ``G``, referred to the input by least squares over the outputs at each frequency,

    S_dd(f) = g^H S_rr(f) g / |g|^4,   g = G(e^{j 2 pi f dt}),

from the Welch cross-spectral matrix ``S_rr`` of the residual. For a residual that is ``G d`` plus
nothing else this is the power spectral density of ``d``. Output noise appears in it as
``|g|^-2`` times its density, so trust it below the first resonance, where ``|g|`` is large.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import signal as _sig

from .checks import as_signal, frozen_array, positive_float, same_length, welch_segment_length
from .freq import frequency_response
from .simulation import _model_matrices, estimate_x0, simulate

__all__ = ["ResidualSpectrum", "input_referred_residual"]


@dataclass(frozen=True, eq=False)
class ResidualSpectrum:
    """Residual of a single-input model on a record, as an amplitude spectral density.

    Attributes
    ----------
    freq_hz : numpy.ndarray, shape (n_freq,)
        Frequencies [Hz], 0 .. fs/2.
    input_asd : numpy.ndarray, shape (n_freq,)
        Input-referred residual [input units / sqrt(Hz)], one-sided.
    output_asd : numpy.ndarray, shape (n_freq, n_outputs)
        Residual of each output [output units / sqrt(Hz)], one-sided.
    residual_rms : numpy.ndarray, shape (n_outputs,)
        Root-mean-square residual of each output [output units].
    fs : float
        Sampling frequency [Hz].
    nperseg : int
        Welch segment length (resolution ``fs / nperseg`` Hz).
    """

    freq_hz: np.ndarray
    input_asd: np.ndarray
    output_asd: np.ndarray
    residual_rms: np.ndarray
    fs: float
    nperseg: int

    def band_asd(self, f_lo_hz: float, f_hi_hz: float) -> float:
        """Input-referred ASD averaged as power over ``f_lo_hz <= f < f_hi_hz`` [input units / sqrt(Hz)]."""
        sel = (self.freq_hz >= f_lo_hz) & (self.freq_hz < f_hi_hz)
        if not sel.any():
            raise ValueError(f"f_lo_hz, f_hi_hz: expected a band holding at least one of the "
                             f"{self.freq_hz.size} frequencies (resolution {self.fs / self.nperseg:g} Hz), "
                             f"got [{f_lo_hz!r}, {f_hi_hz!r})")
        return float(np.sqrt(np.mean(self.input_asd[sel] ** 2)))


def input_referred_residual(model, u, y, *, fs: float, nperseg: int | None = None,
                            estimate_initial_state: bool = True) -> ResidualSpectrum:
    """Spectrum of the residual ``y - G u`` of a discrete single-input model, referred to its input.

    Parameters
    ----------
    model : IdentifiedModel
        Or any object with discrete-time ``A, B, C, D`` of one input, sampled at ``1 / fs``.
    u : array_like, shape (n_samples,) or (n_samples, 1)
        Input record [input units].
    y : array_like, shape (n_samples, n_outputs)
        Output record [output units].
    fs : float
        Sampling frequency [Hz].
    nperseg : int, optional
        Welch segment length; default about 1 Hz resolution, as :func:`~identification.h1_estimate`.
    estimate_initial_state : bool
        Simulate from the least-squares initial state (:func:`~identification.estimate_x0`), else from zero.

    Returns
    -------
    ResidualSpectrum
    """
    A, B, C, D = _model_matrices(model)
    if B.shape[1] != 1:
        raise ValueError(f"model: expected one input, got {B.shape[1]}")
    us = as_signal("u", u)
    ys = as_signal("y", y)
    same_length("u", us, "y", ys)
    if us.shape[1] != 1:
        raise ValueError(f"u: expected one input column, got {us.shape[1]}")
    if ys.shape[1] != C.shape[0]:
        raise ValueError(f"y: expected {C.shape[0]} output columns (the model's), got {ys.shape[1]}")
    fs = positive_float("fs", fs)
    nperseg = welch_segment_length(nperseg, us.shape[0], fs)
    x0 = estimate_x0(model, ys, us) if estimate_initial_state else None
    r = (ys - simulate(model, us, x0)).T                                   # (p, N)
    f, S = _sig.csd(r[:, None, :], r[None, :, :], fs=fs, nperseg=nperseg, axis=-1)   # [a, b] = E[conj(r_a) r_b]
    g = frequency_response((A, B, C, D), f, dt_s=1.0 / fs)[:, :, 0]     # (nf, p)
    S_f = np.moveaxis(S, -1, 0)                                           # (nf, p, p)
    g2 = np.sum(np.abs(g) ** 2, axis=1)
    with np.errstate(divide="ignore", invalid="ignore"):
        sdd = np.real(np.einsum("fa,fab,fb->f", g, S_f, np.conj(g))) / g2 ** 2
    sdd = np.where(g2 > 0, np.clip(sdd, 0.0, None), np.nan)
    out = np.sqrt(np.clip(np.real(np.diagonal(S_f, axis1=1, axis2=2)), 0.0, None))
    return ResidualSpectrum(freq_hz=frozen_array(f), input_asd=frozen_array(np.sqrt(sdd)),
                            output_asd=frozen_array(out), residual_rms=frozen_array(np.sqrt(np.mean(r ** 2, axis=1))),
                            fs=fs, nperseg=nperseg)
