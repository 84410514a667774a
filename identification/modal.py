"""Modal parameters (natural frequencies, damping ratios) of a state-space model."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .checks import frozen_array, positive_float, square_matrix

__all__ = ["Modes", "modes_from_model", "continuous_poles", "split_poles"]


@dataclass(frozen=True, eq=False)
class Modes:
    """Modal parameters sorted by increasing natural frequency.

    Attributes
    ----------
    freq_hz : numpy.ndarray, shape (n_pairs,)
        Undamped natural frequency ``|s| / (2 pi)`` of each complex-conjugate
        pole pair, in Hz.
    damping : numpy.ndarray, shape (n_pairs,)
        Damping ratio ``-Re(s) / |s|`` (negative for unstable pairs).
    poles_s : numpy.ndarray of complex, shape (n_pairs,)
        Continuous-time pole of each pair with positive imaginary part, rad/s.
    real_poles_s : numpy.ndarray, shape (n_real,)
        Real continuous-time poles in rad/s, sorted by magnitude (e.g. the
        piezo creep pole).  A discrete pole on the negative real axis has no
        real continuous equivalent and is reported as ``log|z| / dt``.
    """

    freq_hz: np.ndarray
    damping: np.ndarray
    poles_s: np.ndarray
    real_poles_s: np.ndarray


def continuous_poles(A, dt: float | None = None) -> np.ndarray:
    """Continuous-time poles: ``eig(A)`` or ``log(eig(A)) / dt`` if ``dt`` is given.

    Parameters
    ----------
    A : array_like, shape (n, n), or IdentifiedModel
        State matrix; for an :class:`IdentifiedModel`, its ``A`` and ``dt_s``
        are used.
    dt : float, optional
        Sample time in s of a discrete ``A``.

    Returns
    -------
    numpy.ndarray of complex, shape (n,)
        Poles in rad/s (the exact ``z = exp(s dt)`` map, not Tustin).
    """
    A, dt = _unpack(A, dt)
    lam = np.linalg.eigvals(A).astype(complex)
    if dt is None:
        return lam
    if np.any(lam == 0):
        raise ValueError("A: expected no eigenvalue at z = 0 (no continuous equivalent), got one")
    return np.log(lam) / dt


def split_poles(lam, imag_tol: float = 1e-9):
    """Complex poles (upper half plane) and real poles of the eigenvalues ``lam``.

    A pole is complex when ``|Im| > imag_tol * |pole|``; returns ``(upper, real)``, complex and
    real arrays in the order of ``lam``.
    """
    lam = np.asarray(lam, complex)
    is_cplx = np.abs(lam.imag) > imag_tol * np.abs(lam)
    return lam[is_cplx & (lam.imag > 0)], lam[~is_cplx].real


def _unpack(A, dt):
    if hasattr(A, "A") and hasattr(A, "dt_s"):
        if dt is None:
            dt = A.dt_s
        A = A.A
    A = square_matrix("A", A)
    if dt is not None:
        dt = positive_float("dt", dt)
    return A, dt


def modes_from_model(A, dt: float | None = None, *, imag_tol: float = 1e-9) -> Modes:
    """Natural frequencies and damping ratios of the complex poles.

    Parameters
    ----------
    A : array_like, shape (n, n), or IdentifiedModel
        State matrix.  An :class:`IdentifiedModel` supplies its own
        ``dt_s``.
    dt : float, optional
        Sample time in s for a discrete ``A`` (poles mapped by
        ``s = log(z) / dt``); None means ``A`` is continuous.
    imag_tol : float, default 1e-9
        A pole is complex when ``|Im| > imag_tol * |pole|`` (tested on ``z``
        for discrete models, on ``s`` for continuous ones).

    Returns
    -------
    Modes
    """
    A, dt = _unpack(A, dt)
    lam = np.linalg.eigvals(A).astype(complex)
    upper, real = split_poles(lam, imag_tol)
    if dt is None:
        s_pairs = upper
        s_real = real
    else:
        if np.any(np.abs(lam) == 0):
            raise ValueError("A: expected no eigenvalue at z = 0 (no continuous equivalent), got one")
        s_pairs = np.log(upper) / dt
        s_real = np.log(np.abs(real)) / dt
    wn = np.abs(s_pairs)
    order = np.argsort(wn)
    s_pairs, wn = s_pairs[order], wn[order]
    s_real = s_real[np.argsort(np.abs(s_real))]
    return Modes(
        freq_hz=frozen_array(wn / (2 * np.pi)),
        damping=frozen_array(-s_pairs.real / wn),
        poles_s=frozen_array(s_pairs),
        real_poles_s=frozen_array(s_real),
    )
