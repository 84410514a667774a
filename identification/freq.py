"""Frequency-domain tools: non-parametric H1 estimate and model responses.

The seed paper verifies its time-domain model against a frequency-domain
identification (Sec. 3, Fig. 6).  :func:`h1_estimate` is the standard H1
estimator (Bendat & Piersol), ``H1 = S_yu S_uu^-1`` per frequency, from
Welch cross spectra; :func:`frequency_response` evaluates a parametric model
on the same frequency grid for comparison.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import signal as _sig

from .checks import (
    as_signal,
    frozen_array,
    not_degenerate,
    positive_float,
    same_length,
    state_space,
    welch_segment_length,
)

__all__ = ["H1Estimate", "h1_estimate", "frequency_response"]


@dataclass(frozen=True, eq=False)
class H1Estimate:
    """Non-parametric frequency-response estimate.

    Attributes
    ----------
    freq_hz : numpy.ndarray, shape (n_freq,)
        Frequencies in Hz (0 .. fs/2).
    H : numpy.ndarray of complex, shape (n_freq, n_outputs, n_inputs)
        ``H[k, i, j]`` is the response from input ``j`` to output ``i`` at
        ``freq_hz[k]`` in output units / input units.  NaN where the input
        cross-spectral matrix is singular (e.g. DC after detrending, nulls of
        a held PRBS).
    coherence : numpy.ndarray, shape (n_freq, n_outputs, n_inputs)
        Ordinary coherence ``|S_yu|^2 / (S_uu S_yy)`` of each pair, in [0, 1].
    multiple_coherence : numpy.ndarray, shape (n_freq, n_outputs)
        Fraction of each output's power explained linearly by all inputs
        together, in [0, 1]; equals ``coherence[:, 0]`` for one input.
    fs : float
        Sampling frequency in Hz.
    nperseg : int
        Welch segment length (resolution ``fs / nperseg`` Hz).
    """

    freq_hz: np.ndarray
    H: np.ndarray
    coherence: np.ndarray
    multiple_coherence: np.ndarray
    fs: float
    nperseg: int


def h1_estimate(
    u,
    y,
    *,
    fs: float,
    nperseg: int | None = None,
    window: str = "hann",
    noverlap: int | None = None,
    detrend: str | bool = "constant",
) -> H1Estimate:
    """H1 frequency-response estimate ``H = S_yu S_uu^-1`` from Welch spectra.

    Parameters
    ----------
    u : array_like, shape (n_samples,) or (n_samples, n_inputs)
        Input(s).  With several inputs they must not be fully correlated
        (e.g. independent PRBS).
    y : array_like, shape (n_samples,) or (n_samples, n_outputs)
        Output(s), same number of samples.
    fs : float
        Sampling frequency in Hz.
    nperseg : int, optional
        Welch segment length; default ``min(n_samples, max(256, round(fs)))``
        (about 1 Hz resolution).
    window, noverlap, detrend
        Passed to :func:`scipy.signal.csd`.

    Returns
    -------
    H1Estimate

    Notes
    -----
    H1 is unbiased for noise on the output and biased low by input noise.
    Trust it where ``coherence`` (SISO) or ``multiple_coherence`` (MIMO) is
    close to 1.  Windowing bias is significant at lightly damped resonances
    whose half-power bandwidth ``2 zeta f_n`` is below a few ``fs / nperseg``.
    """
    us = as_signal("u", u)
    ys = as_signal("y", y)
    same_length("u", us, "y", ys)
    fs = positive_float("fs", fs)
    not_degenerate("u", us)
    n = us.shape[0]
    nperseg = welch_segment_length(nperseg, n, fs)
    kw = dict(fs=fs, window=window, nperseg=nperseg, noverlap=noverlap, detrend=detrend, axis=-1)
    U = us.T
    Y = ys.T
    f, Puu = _sig.csd(U[:, None, :], U[None, :, :], **kw)  # [a, b] = E[conj(U_a) U_b]
    _, Puy = _sig.csd(U[:, None, :], Y[None, :, :], **kw)  # [a, i] = E[conj(U_a) Y_i]
    _, Pyy = _sig.welch(Y, **kw)  # (l, nf)
    Puu_f = np.moveaxis(Puu, -1, 0)  # (nf, m, m), Hermitian
    Puy_f = np.moveaxis(Puy, -1, 0)  # (nf, m, l)
    m = us.shape[1]
    lam = np.linalg.eigvalsh(Puu_f)  # ascending
    ok = lam[:, 0] > 1e-12 * max(lam[:, -1].max(), np.finfo(float).tiny)
    HT = np.full(Puy_f.shape, np.nan, dtype=complex)
    if ok.any():
        HT[ok] = np.linalg.solve(Puu_f[ok], Puy_f[ok])  # (nf, m, l) = H^T
    H = np.transpose(HT, (0, 2, 1))  # (nf, l, m)
    syu = np.transpose(Puy_f, (0, 2, 1))  # (nf, l, m): E[Y_i conj(U_j)] conj-sym. |.| same
    suu = np.real(np.diagonal(Puu_f, axis1=1, axis2=2))  # (nf, m)
    pyy = Pyy.T  # (nf, l)
    with np.errstate(divide="ignore", invalid="ignore"):
        coh = np.abs(syu) ** 2 / (suu[:, None, :] * pyy[:, :, None])
        mult = np.real(np.sum(H * np.conj(syu), axis=2)) / pyy
    coh = np.clip(np.nan_to_num(coh, nan=0.0, posinf=0.0), 0.0, 1.0)
    mult = np.clip(np.nan_to_num(mult, nan=0.0, posinf=0.0), 0.0, 1.0)
    if m == 1:
        mult = coh[:, :, 0].copy()
    return H1Estimate(
        freq_hz=frozen_array(f),
        H=frozen_array(H),
        coherence=frozen_array(coh),
        multiple_coherence=frozen_array(mult),
        fs=fs,
        nperseg=nperseg,
    )


def _system_matrices(system, dt_s):
    """Return (A, B, C, D, dt or None) from the accepted system types."""
    if isinstance(system, (tuple, list)):
        if len(system) != 4:
            raise ValueError(f"system: expected a tuple (A, B, C, D), got a sequence of length {len(system)}")
        A, B, C, D = system
        dt = None if dt_s is None else positive_float("dt_s", dt_s)
    elif hasattr(system, "A") and hasattr(system, "dt_s"):  # IdentifiedModel
        A, B, C, D = system.A, system.B, system.C, system.D
        dt = float(system.dt_s)
    elif hasattr(system, "A") and hasattr(system, "dt"):  # control.StateSpace
        A, B, C, D = system.A, system.B, system.C, system.D
        if system.dt is True:
            raise ValueError("system: expected a numeric dt, got dt=True (unspecified sampling time)")
        dt = float(system.dt) if system.dt else None
    elif hasattr(system, "A"):  # ContinuousModel
        A, B, C, D = system.A, system.B, system.C, system.D
        dt = None if dt_s is None else positive_float("dt_s", dt_s)
    else:
        raise ValueError(
            "system: expected an IdentifiedModel, ContinuousModel, control.StateSpace or "
            f"tuple (A, B, C, D), got {type(system).__name__}"
        )
    A, B, C, D = state_space(A, B, C, D)
    return A, B, C, D, dt


def frequency_response(system, freq_hz, *, dt_s: float | None = None) -> np.ndarray:
    """Frequency response of a state-space model.

    Evaluates ``C (lambda I - A)^-1 B + D`` at ``lambda = exp(2j pi f dt)``
    (discrete) or ``lambda = 2j pi f`` (continuous) by one linear solve per
    frequency (no eigen-decomposition, so it is accurate at lightly damped
    resonances).

    Parameters
    ----------
    system : IdentifiedModel, ContinuousModel, control.StateSpace or tuple
        An :class:`IdentifiedModel` is discrete with its ``dt_s``; a
        ``control.StateSpace`` uses its ``dt`` (0 = continuous); a
        ``ContinuousModel`` or a tuple ``(A, B, C, D)`` is continuous unless
        ``dt_s`` is given.
    freq_hz : array_like, shape (n_freq,)
        Frequencies in Hz (>= 0).
    dt_s : float, optional
        Sample time in s for tuple input (makes it discrete).

    Returns
    -------
    numpy.ndarray of complex, shape (n_freq, n_outputs, n_inputs)
    """
    A, B, C, D, dt = _system_matrices(system, dt_s)
    f = np.asarray(freq_hz, dtype=float)
    if f.ndim != 1 or f.size == 0:
        raise ValueError(f"freq_hz: expected a non-empty 1-D array, got shape {f.shape}")
    if not np.all(np.isfinite(f)):
        raise ValueError("freq_hz: expected finite frequencies, got NaN/inf")
    w = 2j * np.pi * f
    lam = np.exp(w * dt) if dt is not None else w
    n = A.shape[0]
    M = lam[:, None, None] * np.eye(n) - A  # (nf, n, n)
    X = np.linalg.solve(M, np.broadcast_to(B, (f.size,) + B.shape))  # (nf, n, m)
    G = C @ X + D  # (nf, l, m)
    return G
