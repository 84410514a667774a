"""Linear least-squares regressors shared by subspace identification and initial-state estimation.

For ``x(k+1) = A x(k) + B u(k)``, ``y(k) = C x(k) + D u(k)`` the output is
linear in ``x(0)``, ``B`` and ``D``; these helpers build that regression and
solve it with column scaling.
"""
from __future__ import annotations

import numpy as np
import scipy.linalg as _la
from scipy import fft as _fft

__all__ = ["observability_powers", "fill_forced_regressors", "lstsq_scaled", "fit_x0_B_D"]


def observability_powers(A: np.ndarray, C: np.ndarray, n_samples: int) -> np.ndarray:
    """``O[k] = C A^k`` for ``k = 0 .. n_samples-1``, shape (n_samples, l, n)."""
    l, n = C.shape
    blk = min(n_samples, 64)
    O = np.empty((n_samples, l, n))
    M = C.copy()
    for k in range(blk):
        O[k] = M
        M = M @ A
    if n_samples > blk:
        Ab = np.linalg.matrix_power(A, blk)
        for start in range(blk, n_samples, blk):
            stop = min(start + blk, n_samples)
            O[start:stop] = O[start - blk : stop - blk] @ Ab
    return O


def fill_forced_regressors(O: np.ndarray, u: np.ndarray, out: np.ndarray) -> None:
    """Output response to each entry of B, zero initial state, written into ``out``.

    ``out[k, :, p * m + q] = sum_{t<k} C A^(k-1-t) e_p u_q(t)`` (row-major
    ``vec(B)``), computed by FFT convolution; ``out`` has shape (N, l, n m).
    """
    N, l, n = O.shape
    m = u.shape[1]
    nfft = _fft.next_fast_len(2 * N - 1, real=True)
    g = np.zeros((N, l * n))
    g[1:] = O[:-1].reshape(N - 1, l * n)
    G = _fft.rfft(g, n=nfft, axis=0)
    del g
    Uf = _fft.rfft(u, n=nfft, axis=0)
    for q in range(m):
        out[:, :, q::m] = _fft.irfft(G * Uf[:, q : q + 1], n=nfft, axis=0)[:N].reshape(N, l, n)


def lstsq_scaled(Phi: np.ndarray, target: np.ndarray) -> np.ndarray:
    """Column-normalised least squares; ``Phi`` is overwritten."""
    norms = np.linalg.norm(Phi, axis=0)
    norms[norms == 0] = 1.0
    Phi /= norms
    theta = _la.lstsq(Phi, target, lapack_driver="gelsy", overwrite_a=True, check_finite=False)[0]
    return theta / norms


def fit_x0_B_D(A, C, u, y, feedthrough):
    N, l = y.shape
    n = A.shape[0]
    m = u.shape[1]
    p = n + n * m + (l * m if feedthrough else 0)
    Phi = np.empty((N, l, p))
    O = observability_powers(A, C, N)
    Phi[:, :, :n] = O
    fill_forced_regressors(O, u, Phi[:, :, n : n + n * m])
    del O
    if feedthrough:
        Dreg = Phi[:, :, n + n * m :]
        Dreg[...] = 0.0
        for r in range(l):
            Dreg[:, r, r * m : (r + 1) * m] = u
    theta = lstsq_scaled(Phi.reshape(N * l, p), y.reshape(N * l))
    x0 = theta[:n]
    B = theta[n : n + n * m].reshape(n, m)
    D = theta[n + n * m :].reshape(l, m) if feedthrough else np.zeros((l, m))
    return x0, B, D
