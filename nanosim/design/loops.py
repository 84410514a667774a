"""Loop functions of the tracking loop and their closed-loop analysis.

Sign convention: negative feedback, ``e = r - y``, ``u = +K e``,
``S = (I + G K)^-1``, ``T = G K (I + G K)^-1``, ``KS = K (I + G K)^-1``
(:data:`nanosim.design.lti.SIGN_CONVENTION`). Two-degree-of-freedom
controllers ``u = K e + Ky y`` are stacked as ``[K, Ky]`` with inputs ``[e; y]``
(:func:`stack_inputs`); their feedback operator is ``K - Ky``
(:func:`feedback_operator`). Frequency responses are ``(F, rows, cols)`` arrays,
frequencies in Hz.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from nanosim.design.lti import (
    INV_SQRT2,
    crossing_hz,
    freqresp,
    max_real_pole,
    refine_peak,
    sigma_max,
    singular_values,
    static_gain,
)

__all__ = ["loop_functions", "loop_freqresp", "sensitivities", "LoopAnalysis", "analyse_loop", "min_damping",
           "MODE_BAND_HZ", "stack_inputs", "feedback_operator"]


def loop_functions(G, K):
    """State-space ``S, T, KS`` for ``u = +K e``, ``e = r - y`` (see module docstring).

    Parameters
    ----------
    G : control.StateSpace
        Plant, ``ny x nu`` (controller V -> sensor V).
    K : control.StateSpace
        Controller, ``nu x ny`` (error sensor V -> controller V).

    Returns
    -------
    S, T, KS : control.StateSpace
        ``(I + GK)^-1``, ``GK (I + GK)^-1`` (ny x ny) and ``K (I + GK)^-1`` (nu x ny).
        Each realization contains all plant and controller states, so its poles are
        the closed-loop poles.
    """
    import control as ct
    I = static_gain(np.eye(G.noutputs))
    L = ct.series(K, G)                     # L = G K
    S = ct.feedback(I, L, sign=-1)          # (I + L)^-1
    T = ct.feedback(L, I, sign=-1)          # L (I + L)^-1
    KS = ct.feedback(K, G, sign=-1)         # K (I + G K)^-1
    return S, T, KS


def loop_freqresp(Gf, Kf):
    """Frequency-domain S, T, KS from frequency-response stacks.

    Parameters
    ----------
    Gf : ndarray, complex, shape (F, ny, nu)
        ``G(j 2 pi f)`` [sensor V / controller V].
    Kf : ndarray, complex, shape (F, nu, ny)
        ``K(j 2 pi f)`` [controller V / sensor V].

    Returns
    -------
    S, T : ndarray, complex, shape (F, ny, ny)
        ``(I + G K)^-1`` and ``I - S`` [dimensionless].
    KS : ndarray, complex, shape (F, nu, ny)
        ``K S`` [controller V / sensor V].
    """
    S = sensitivities(Gf, Kf)[2]
    return S, np.eye(Gf.shape[1]) - S, Kf @ S


def sensitivities(Gf, Kf):
    """The loop transfers and sensitivities at plant output and input, frequency by frequency: the one
    kernel of the frequency-domain loop maps (:func:`loop_freqresp`,
    :func:`~nanosim.design.loopresponse.loop_transfer_response`, the bench's fast checks).

    Parameters
    ----------
    Gf : ndarray, complex, shape (F, ny, nu)
        Plant response (with any loop delay) [sensor V / controller V].
    Kf : ndarray, complex, shape (F, nu, ny)
        Feedback operator ``u = +K e`` [controller V / sensor V].

    Returns
    -------
    Lo, Li, S_o, S_i : ndarray, complex
        ``G K`` and ``K G``; ``(I + G K)^-1`` (F, ny, ny) and ``(I + K G)^-1`` (F, nu, nu).
    """
    ny, nu = Gf.shape[1], Gf.shape[2]
    Lo = Gf @ Kf
    Li = Kf @ Gf
    return Lo, Li, np.linalg.inv(np.eye(ny) + Lo), np.linalg.inv(np.eye(nu) + Li)


@dataclass(frozen=True, eq=False)
class LoopAnalysis:
    """Closed-loop figures of one plant with the designed controller.

    Attributes
    ----------
    stable : bool
        All closed-loop poles have ``Re < 0``.
    max_real_pole : float
        Largest closed-loop pole real part [rad/s].
    S_peak : float
        ``max_f sigma_max(S)`` on the refined grid [dimensionless].
    S_peak_hz : float
        Where it occurs [Hz].
    bandwidth_S_hz, bandwidth_T_hz, bandwidth_T_last_hz : float
        See ``BANDWIDTH_DEFINITIONS``.
    sigma_S, sigma_T, sigma_KS : ndarray, shape (F, ny)
        All singular values on ``Design.freq_hz``.
    T_f : ndarray, complex, shape (F, ny, ny)
        ``T(j 2 pi f)`` on the grid (for Bode plots).
    min_damping, min_damping_hz : float
        Smallest damping ratio ``-Re p / |p|`` of the closed-loop poles between
        ``MODE_BAND_HZ`` and its frequency [Hz] (how long a disturbance rings).
    """

    stable: bool
    max_real_pole: float
    S_peak: float
    S_peak_hz: float
    bandwidth_S_hz: float
    bandwidth_T_hz: float
    bandwidth_T_last_hz: float
    sigma_S: np.ndarray
    sigma_T: np.ndarray
    sigma_KS: np.ndarray
    T_f: np.ndarray
    min_damping: float = float("nan")
    min_damping_hz: float = float("nan")


MODE_BAND_HZ = (50.0, 1000.0)


def min_damping(A, band_hz=MODE_BAND_HZ) -> tuple[float, float]:
    """Smallest damping ratio of the poles of ``A`` in a frequency band.

    Parameters
    ----------
    A : array_like, shape (n, n)
        State matrix (continuous, rad/s).
    band_hz : (float, float), default MODE_BAND_HZ
        Band of pole frequencies ``|p| / 2 pi`` [Hz]; only poles with ``Im p > 0`` count.

    Returns
    -------
    zeta : float
        ``min -Re p / |p|`` [dimensionless]; NaN without a pole in the band.
    freq_hz : float
        Its ``|p| / 2 pi`` [Hz]; NaN without a pole in the band.
    """
    p = np.linalg.eigvals(np.asarray(A, float)) if np.size(A) else np.array([])
    f = np.abs(p) / (2 * np.pi)
    sel = (p.imag > 0) & (f >= band_hz[0]) & (f <= band_hz[1])
    if not np.any(sel):
        return float("nan"), float("nan")
    z = -p.real[sel] / np.abs(p[sel])
    i = int(np.argmin(z))
    return float(z[i]), float(f[sel][i])


def analyse_loop(G, K, f, S_ss=None) -> LoopAnalysis:
    """Closed-loop stability, ||S|| peak, bandwidths and singular values of ``G`` with ``K``.

    Parameters
    ----------
    G : control.StateSpace
        Plant, ``ny x nu`` (controller V -> sensor V).
    K : control.StateSpace
        Controller, ``nu x ny`` (error sensor V -> controller V).
    f : ndarray, shape (F,)
        Analysis grid [Hz]; the S peak is refined between its points.
    S_ss : control.StateSpace, optional
        ``loop_functions(G, K)[0]`` if already computed (its poles are the closed-loop poles).

    Returns
    -------
    LoopAnalysis
    """
    if S_ss is None:
        S_ss = loop_functions(G, K)[0]
    mrp = max_real_pole(S_ss.A)
    zmin, zmin_hz = min_damping(S_ss.A)
    Gf, Kf = freqresp(G, f), freqresp(K, f)
    Sf, Tf, KSf = loop_freqresp(Gf, Kf)
    sS, sT, sKS = singular_values(Sf), singular_values(Tf), singular_values(KSf)

    def smax_S(ff):
        return sigma_max(loop_freqresp(freqresp(G, ff), freqresp(K, ff))[0])

    peak, fpk = refine_peak(smax_S, f, sS[:, 0])
    return LoopAnalysis(stable=bool(mrp < 0), max_real_pole=mrp, S_peak=peak, S_peak_hz=fpk,
                        bandwidth_S_hz=crossing_hz(f, sS[:, 0], INV_SQRT2, rising=True),
                        bandwidth_T_hz=crossing_hz(f, sT[:, 0], INV_SQRT2, rising=False),
                        bandwidth_T_last_hz=crossing_hz(f, sT[:, 0], INV_SQRT2, rising=False, first=False),
                        sigma_S=sS, sigma_T=sT, sigma_KS=sKS, T_f=Tf, min_damping=zmin, min_damping_hz=zmin_hz)


def stack_inputs(K, Ky):
    """``[K, Ky]`` with inputs ``[e; y]`` and summed outputs (block-diagonal states).

    Parameters
    ----------
    K, Ky : control.StateSpace
        ``nu x ny`` each (sensor V -> controller V), both continuous or both with
        the sample time ``K.dt``.

    Returns
    -------
    control.StateSpace
        ``nu x 2 ny``: ``u = K e + Ky y``; states of ``K`` then of ``Ky``.
    """
    import control as ct
    from scipy.linalg import block_diag
    A = block_diag(np.asarray(K.A), np.asarray(Ky.A))
    B = block_diag(np.asarray(K.B), np.asarray(Ky.B))
    C = np.hstack([np.asarray(K.C), np.asarray(Ky.C)])
    D = np.hstack([np.asarray(K.D), np.asarray(Ky.D)])
    return ct.ss(A, B, C, D, K.dt)


def feedback_operator(K2, n_error: int):
    """Error-sign feedback operator ``K - Ky`` of a stacked ``[K, Ky]`` (``u = K r - (K - Ky) y``).

    Parameters
    ----------
    K2 : control.StateSpace
        ``[K, Ky]`` from :func:`stack_inputs` (``nu x 2 ny``), or a plain ``K`` (``nu x ny``).
    n_error : int
        Number of error inputs ``ny``.

    Returns
    -------
    control.StateSpace
        ``nu x ny`` (sensor V -> controller V), same sample time; ``K2`` itself if it
        has no measurement inputs.
    """
    import control as ct
    if K2.ninputs == n_error:
        return K2
    B, D = np.asarray(K2.B), np.asarray(K2.D)
    return ct.ss(K2.A, B[:, :n_error] - B[:, n_error:], K2.C, D[:, :n_error] - D[:, n_error:], K2.dt)
