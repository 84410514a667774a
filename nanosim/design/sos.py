"""Second-order sections of a discrete MIMO state space, one SISO channel at a time.

Fixed-point and DSP implementations run a controller as cascaded biquads, not as a dense
state space. Each channel ``K_ij(z)`` (output ``i``, input ``j``) of ``x[k+1] = A x[k] + B v[k]``,
``u[k] = C x[k] + D v[k]`` is reduced to a minimal realization (the other channels' states are
uncontrollable or unobservable from it), written as zeros, poles and gain (poles: eigenvalues;
zeros: the Rosenbrock pencil; no polynomials) and paired into sections
(:func:`scipy.signal.zpk2sos`, ``pairing="nearest"``), so that::

    K_ij(z) = prod_s (b0_s + b1_s z^-1 + b2_s z^-2) / (1 + a1_s z^-1 + a2_s z^-2)

with the channel gain in the first section (scipy.signal's ``sos`` layout ``[b0, b1, b2, a0, a1, a2]``,
``a0 = 1``). Channels are padded to the same number of sections with the identity section
``[1, 0, 0, 1, 0, 0]``; a channel that is identically zero is the section ``[0, 0, 0, 1, 0, 0]``.
The command is ``u_i[k] = sum_j K_ij(z) v_j[k]``.
"""
from __future__ import annotations

import numpy as np

__all__ = ["state_space_sos", "sos_frequency_response", "IDENTITY_SECTION"]

IDENTITY_SECTION = np.array([1.0, 0.0, 0.0, 1.0, 0.0, 0.0])


def _minimal_siso(A, b, c, d, tol):
    """A minimal realization of one SISO channel (python-control's ``minreal``)."""
    import control as ct
    if A.shape[0] == 0:
        return A, b, c, d
    s = ct.ss(A, b, c, d, True)
    m = ct.minreal(s, tol=tol, verbose=False)
    return np.asarray(m.A), np.asarray(m.B), np.asarray(m.C), np.asarray(m.D)


def _delayed(sos, r: int) -> np.ndarray:
    """Sections of ``z^-r H(z)`` from those of ``H(z)``, which :func:`scipy.signal.zpk2sos` builds with ``r``
    zeros at the origin for a strictly proper channel (``r`` more poles than zeros): each such zero leaves a
    trailing zero coefficient, and shifting a numerator right by one multiplies its section by ``z^-1``.
    """
    sos = np.array(sos, float)
    for sec in sos[::-1]:
        while r > 0 and sec[2] == 0.0:
            sec[0:3] = [0.0, sec[0], sec[1]]
            r -= 1
    if r:
        raise ValueError(f"sos: {r} sample(s) of delay left over: the sections have no trailing zero coefficient")
    return sos


def _zpk(a, b, c, d):
    """Zeros, poles and gain of a SISO state space without forming polynomials.

    Poles: the eigenvalues of ``a``; zeros: the finite generalized eigenvalues of the Rosenbrock
    pencil ``([[a, b], [c, d]], [[I, 0], [0, 0]])``; gain: the ratio of the response to the
    zero-pole product at a point on the unit circle away from both (exact for a minimal channel).
    """
    import scipy.linalg as sla
    n = a.shape[0]
    p = np.linalg.eigvals(a)
    M = np.block([[a, b], [c, d]])
    N = np.zeros_like(M)
    N[:n, :n] = np.eye(n)
    w = sla.eigvals(M, N)
    z = w[np.isfinite(w) & (np.abs(w) < 1e12)]
    best = None
    for theta in np.linspace(0.1, 3.0, 13):          # the point farthest from every pole and zero
        z0 = np.exp(1j * theta)
        dist = np.min(np.abs(np.concatenate([p, z]) - z0)) if len(z) + len(p) else 1.0
        if best is None or dist > best[0]:
            best = (dist, z0)
    z0 = best[1]
    h = (c @ np.linalg.solve(z0 * np.eye(n) - a, b) + d)[0, 0]
    k = h * np.prod(z0 - p) / np.prod(z0 - z)
    return z, p, float(np.real(k))


def state_space_sos(A, B, C, D, *, minreal_tol: float = 1e-9) -> np.ndarray:
    """Second-order sections of every SISO channel of a discrete state space (module docstring).

    Parameters
    ----------
    A, B, C, D : array_like
        Discrete state space, ``n_out x n_in`` channels.
    minreal_tol : float
        Tolerance of the pole-zero cancellations of the per-channel minimal realization.

    Returns
    -------
    numpy.ndarray, shape (n_out, n_in, n_sections, 6)
        ``sos[i, j]`` is channel ``K_ij`` in scipy.signal's layout.
    """
    from scipy import signal
    A, B, C, D = (np.atleast_2d(np.asarray(M, float)) for M in (A, B, C, D))
    n_out, n_in = D.shape
    chans = {}
    for i in range(n_out):
        for j in range(n_in):
            a, b, c, d = _minimal_siso(A, B[:, j:j + 1], C[i:i + 1], D[i:i + 1, j:j + 1], minreal_tol)
            if a.shape[0] == 0 or not np.any(c) or not np.any(b):
                g = float(d[0, 0])
                chans[i, j] = np.array([[g, 0.0, 0.0, 1.0, 0.0, 0.0]])
                continue
            z, p, k = _zpk(a, b, c, d)
            if k == 0 or not np.isfinite(k):
                chans[i, j] = np.array([[0.0, 0.0, 0.0, 1.0, 0.0, 0.0]])
                continue
            chans[i, j] = _delayed(signal.zpk2sos(z, p, k, pairing="nearest"), len(p) - len(z))
    n_sec = max(s.shape[0] for s in chans.values())
    out = np.tile(IDENTITY_SECTION, (n_out, n_in, n_sec, 1))
    for (i, j), s in chans.items():
        out[i, j, :s.shape[0]] = s
    return out


def sos_frequency_response(sos, freq_hz, dt: float) -> np.ndarray:
    """Frequency response of every channel, shape ``(len(freq_hz), n_out, n_in)``."""
    from scipy import signal
    sos = np.asarray(sos, float)
    f = np.asarray(freq_hz, float)
    H = np.empty((len(f), sos.shape[0], sos.shape[1]), complex)
    for i in range(sos.shape[0]):
        for j in range(sos.shape[1]):
            H[:, i, j] = signal.sosfreqz(sos[i, j], worN=f, fs=1.0 / dt)[1]
    return H
