"""Discrete-to-continuous conversion by the inverse Tustin (bilinear) map.

The seed paper converts its identified discrete model to continuous time with
``z = e^(s T) ~ (1 + s T/2) / (1 - s T/2)``.  python-control provides
``c2d(sys, T, 'tustin')`` but no inverse; :func:`d2c_tustin` is its exact
inverse (to rounding), including the optional frequency prewarping.

With ``T_w = T`` (no prewarp) or ``T_w = 2 tan(w_p T / 2) / w_p`` (prewarp at
``w_p = 2 pi prewarp_hz`` rad/s, as in python-control), the forward map is

    Ad = (I - A T_w/2)^-1 (I + A T_w/2),   Bd = (I - A T_w/2)^-1 B T_w,
    Cd = C (I - A T_w/2)^-1,               Dd = D + C Bd / 2

and its inverse, implemented here, is

    A = (2/T_w) (Ad + I)^-1 (Ad - I),      B = (2/T_w) (Ad + I)^-1 Bd,
    C = 2 Cd (Ad + I)^-1,                  D = Dd - Cd (Ad + I)^-1 Bd.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .checks import frozen_array, positive_float, state_space

__all__ = ["ContinuousModel", "d2c_tustin", "d2c_zoh", "d2c"]


@dataclass(frozen=True, eq=False)
class ContinuousModel:
    """Continuous-time state-space matrices ``dx/dt = A x + B u``, ``y = C x + D u``.

    Attributes
    ----------
    A : numpy.ndarray, shape (n, n)
        In 1/s.
    B : numpy.ndarray, shape (n, n_inputs)
    C : numpy.ndarray, shape (n_outputs, n)
    D : numpy.ndarray, shape (n_outputs, n_inputs)
    """

    A: np.ndarray
    B: np.ndarray
    C: np.ndarray
    D: np.ndarray


def _warped_period(dt: float, prewarp_hz: float | None) -> float:
    if prewarp_hz is None:
        return dt
    prewarp_hz = positive_float("prewarp_hz", prewarp_hz)
    if prewarp_hz >= 0.5 / dt:
        raise ValueError(f"prewarp_hz: expected a frequency below Nyquist {0.5 / dt:g} Hz, got {prewarp_hz:g}")
    w = 2.0 * np.pi * prewarp_hz
    return 2.0 * np.tan(w * dt / 2.0) / w


def d2c_tustin(A, B, C, D, dt: float, *, prewarp_hz: float | None = None) -> ContinuousModel:
    """Inverse Tustin transform of discrete state-space matrices.

    Exact inverse of ``control.c2d(sys, dt, 'tustin')`` (and of
    ``control.c2d(sys, dt, 'tustin', prewarp_frequency=2*pi*prewarp_hz)``).

    Parameters
    ----------
    A : array_like, shape (n, n)
    B : array_like, shape (n, n_inputs)
    C : array_like, shape (n_outputs, n)
    D : array_like, shape (n_outputs, n_inputs)
        Discrete-time matrices.
    dt : float
        Sample time in s.
    prewarp_hz : float, optional
        Frequency (Hz) at which the continuous and discrete responses are
        made to agree exactly; default none (plain Tustin).

    Returns
    -------
    ContinuousModel

    Raises
    ------
    ValueError
        If ``A`` has an eigenvalue at ``z = -1`` (it maps to ``s = inf``).
    """
    A, B, C, D = state_space(A, B, C, D)
    n = A.shape[0]
    dt = positive_float("dt", dt)
    tw = _warped_period(dt, prewarp_hz)
    M = A + np.eye(n)
    if n and np.linalg.cond(M) > 1e12:
        raise ValueError("A: expected no eigenvalue at z = -1 (Nyquist), got I + A (near) singular")
    MinvB = np.linalg.solve(M, B)
    Ac = (2.0 / tw) * np.linalg.solve(M, A - np.eye(n))
    Bc = (2.0 / tw) * MinvB
    Cc = 2.0 * np.linalg.solve(M.T, C.T).T
    Dc = D - C @ MinvB
    return ContinuousModel(A=frozen_array(Ac), B=frozen_array(Bc), C=frozen_array(Cc), D=frozen_array(Dc))


def d2c_zoh(A, B, C, D, dt: float) -> ContinuousModel:
    """Inverse zero-order-hold discretisation (matrix logarithm).

    Exact inverse of ``control.c2d(sys, dt, 'zoh')``: with
    ``expm([[Ac, Bc], [0, 0]] dt) = [[A, B], [0, I]]``, returns
    ``Ac, Bc`` from the principal matrix logarithm, and ``C, D`` unchanged.
    Poles map exactly, ``s = log(z) / dt``.

    Parameters
    ----------
    A : array_like, shape (n, n)
    B : array_like, shape (n, n_inputs)
    C : array_like, shape (n_outputs, n)
    D : array_like, shape (n_outputs, n_inputs)
        Discrete-time matrices.
    dt : float
        Sample time in s.

    Returns
    -------
    ContinuousModel

    Raises
    ------
    ValueError
        If ``A`` has an eigenvalue on the closed negative real axis (no real
        logarithm).
    """
    import scipy.linalg as la

    A, B, C, D = state_space(A, B, C, D)
    n = A.shape[0]
    dt = positive_float("dt", dt)
    lam = np.linalg.eigvals(A)
    bad = (np.abs(lam.imag) <= 1e-12 * np.maximum(np.abs(lam), 1e-300)) & (lam.real <= 0)
    if bad.any():
        raise ValueError(
            f"A: expected no eigenvalue on the negative real axis or at 0 (no real logarithm), "
            f"got {lam[bad].real.tolist()}"
        )
    m = B.shape[1]
    M = np.zeros((n + m, n + m))
    M[:n, :n] = A
    M[:n, n:] = B
    M[n:, n:] = np.eye(m)
    Lm = la.logm(M)
    if np.iscomplexobj(Lm):
        Lm = Lm.real
    Lm = Lm / dt
    return ContinuousModel(A=frozen_array(Lm[:n, :n]), B=frozen_array(Lm[:n, n:]), C=frozen_array(C), D=frozen_array(D))


def d2c(sys, *, method: str = "tustin", prewarp_hz: float | None = None):
    """Convert a discrete model to a continuous ``control.StateSpace``.

    Parameters
    ----------
    sys : IdentifiedModel or control.StateSpace
        Discrete-time model (``dt_s`` attribute, or ``dt > 0`` for
        python-control).  Signal names of a ``StateSpace`` are kept; the
        labels of an ``IdentifiedModel`` become input/output names.
    method : {"tustin", "zoh"}, default "tustin"
        ``"tustin"``: :func:`d2c_tustin` (the paper's choice);
        ``"zoh"``: :func:`d2c_zoh` (no frequency warping).
    prewarp_hz : float, optional
        Prewarp frequency in Hz, see :func:`d2c_tustin` (Tustin only).

    Returns
    -------
    control.StateSpace
        Continuous-time system (``dt = 0``).
    """
    import control

    if method not in ("tustin", "zoh"):
        raise ValueError(f"method: expected 'tustin' or 'zoh', got {method!r}")
    if method == "zoh" and prewarp_hz is not None:
        raise ValueError(f"prewarp_hz: expected None with method='zoh', got {prewarp_hz!r}")

    def convert(A, B, C, D, dt):
        if method == "zoh":
            return d2c_zoh(A, B, C, D, dt)
        return d2c_tustin(A, B, C, D, dt, prewarp_hz=prewarp_hz)

    if isinstance(sys, control.StateSpace):
        if sys.dt is None or sys.dt is True or not sys.dt or sys.dt <= 0:
            raise ValueError(f"sys: expected a discrete StateSpace with numeric dt > 0, got dt={sys.dt!r}")
        cm = convert(sys.A, sys.B, sys.C, sys.D, float(sys.dt))
        return control.ss(cm.A, cm.B, cm.C, cm.D, inputs=sys.input_labels, outputs=sys.output_labels)
    if hasattr(sys, "dt_s") and hasattr(sys, "A"):
        cm = convert(sys.A, sys.B, sys.C, sys.D, sys.dt_s)
        kw = {}
        if getattr(sys, "input_names", None):
            kw["inputs"] = list(sys.input_names)
        if getattr(sys, "output_names", None):
            kw["outputs"] = list(sys.output_names)
        return control.ss(cm.A, cm.B, cm.C, cm.D, **kw)
    raise ValueError(f"sys: expected an IdentifiedModel or discrete control.StateSpace, got {type(sys).__name__}")
