"""Small LTI helpers shared by the design layer: conversion, frequency responses, gains, grids.

Units and signals
-----------------
Plant ``G``: inputs = controller volts for actuators A, B, C (before the x20
amplifier); outputs = sensor volts X, Y, Z (5 um/V). Controller ``K``: input =
tracking error in sensor volts, output = controller volts. Frequencies are in
Hz in every public argument and result (``*_hz``); state-space models use
``s`` in rad/s. Frequency responses are complex arrays of shape
``(F, ny, nu)``, frequency first (the project-wide order).

Sign convention (pinned, tested)
--------------------------------
Negative feedback: ``e = r - y``, ``u = +K e``, ``L = G K``,
``S = (I + G K)^-1`` (r -> e), ``T = G K (I + G K)^-1`` (r -> y),
``KS = K (I + G K)^-1`` (r -> u). The controller returned by
``control.hinfsyn``/``mixsyn`` for the ``augw`` plant is used with exactly this
sign (its measured signal is ``v = r - G u = e``).

BLAS threading
--------------
The matrices here are tiny (<= 60 states); on a loaded 2-core machine
OpenBLAS's default threading made slycot ``sb10ad`` 3-40x slower (0.45 s with
one thread vs 1.3-17 s with two, measured on the 19-state paper problem). The
design layer's public entry points therefore run under
:func:`single_threaded_blas` (``threadpoolctl``), which limits every loaded BLAS
(the OpenBLAS copies of the slycot, numpy and scipy wheels) to one thread and
restores the previous setting afterwards.
"""
from __future__ import annotations

import contextlib
import functools
import math
import warnings

import numpy as np

from nanosim import fileio

__all__ = [
    "SIGN_CONVENTION", "UNITS", "INV_SQRT2", "BANDWIDTH_DEFINITIONS", "AXIS_RTOL",
    "as_ss", "static_gain", "dc_gain", "freqresp", "ss_response", "MODAL_COND_MAX", "sigma_max", "singular_values",
    "db",
    "max_real_pole", "crossing_hz", "analysis_grid_hz", "refine_peak", "load_state_space_npz",
    "single_threaded_blas",
]

SIGN_CONVENTION = ("negative feedback: e = r - y [sensor V]; u = +K e [controller V]; L = G K; "
                   "S = (I + G K)^-1 (r -> e); T = G K (I + G K)^-1 (r -> y); KS = K (I + G K)^-1 (r -> u)")
UNITS = {
    "plant_G": "input controller V (actuators A,B,C, before the x20 amplifier) -> output sensor V (X,Y,Z; 5 um/V)",
    "controller_K": "input tracking error e = r - y in sensor V -> output controller V",
    "state_space_time": "continuous models: s in rad/s, time in s; discrete models: sample time dt in s",
    "frequencies": "Hz (keys ending in _hz)",
    "magnitudes": "singular values are dimensionless ratios for S and T, controller V / sensor V for K and KS",
}
INV_SQRT2 = 1.0 / math.sqrt(2.0)
BANDWIDTH_DEFINITIONS = {
    "bandwidth_S_hz": "lowest frequency where sigma_max(S) first rises to 1/sqrt(2) (-3 dB) from below "
                      "(Skogestad & Postlethwaite omega_B); nominal (reduced) model",
    "bandwidth_T_hz": "lowest frequency where sigma_max(T) first falls below 1/sqrt(2) (-3 dB), i.e. the "
                      "closed-loop -3 dB bandwidth of the worst direction; nominal model",
    "bandwidth_T_last_hz": "highest frequency where sigma_max(T) crosses 1/sqrt(2) from above "
                           "(Skogestad & Postlethwaite omega_BT); can sit at a resonance",
}
# A pole counts as "on the imaginary axis" if |Re p| <= rtol * max(1, |p|).
AXIS_RTOL = 1e-9


# =====================================================================================
# BLAS threading
# =====================================================================================
@contextlib.contextmanager
def _one_blas_thread():
    from threadpoolctl import threadpool_limits

    # threadpoolctl limits the BLAS libraries that are loaded; load slycot's bundled
    # OpenBLAS (numpy's and scipy's come with numpy / scipy.linalg) before limiting.
    with contextlib.suppress(ImportError):
        import slycot  # noqa: F401
    with threadpool_limits(limits=1, user_api="blas"):
        yield


def single_threaded_blas(fn=None):
    """Run with every loaded BLAS limited to one thread (``threadpoolctl``).

    Use as a decorator (``@single_threaded_blas``) or as a context manager
    (``with single_threaded_blas(): ...``). The previous thread counts are
    restored afterwards.

    Parameters
    ----------
    fn : callable, optional
        Function to wrap. Without it a context manager is returned.
    """
    if fn is None:
        return _one_blas_thread()

    @functools.wraps(fn)
    def wrapper(*args, **kwargs):
        with _one_blas_thread():
            return fn(*args, **kwargs)
    return wrapper


# =====================================================================================
# models
# =====================================================================================
def as_ss(name: str, sys_, *, continuous: bool = True):
    """Return ``sys_`` as a ``control.StateSpace`` with finite matrices.

    Parameters
    ----------
    name : str
        Argument name used in error messages.
    sys_ : control.StateSpace or control.TransferFunction
    continuous : bool, default True
        Require a continuous-time model (``dt = 0``).

    Returns
    -------
    control.StateSpace

    Raises
    ------
    ValueError
        Wrong type, NaN/inf entries, or a discrete model where a continuous one is required.
    """
    import control as ct
    if isinstance(sys_, ct.TransferFunction):
        sys_ = ct.ss(sys_)
    if not isinstance(sys_, ct.StateSpace):
        raise ValueError(f"{name}: expected a control.StateSpace or TransferFunction, got {type(sys_).__name__}")
    for part in ("A", "B", "C", "D"):
        m = np.asarray(getattr(sys_, part), dtype=float)
        if not np.all(np.isfinite(m)):
            raise ValueError(f"{name}: matrix {part} has NaN/inf entries")
    if continuous and sys_.isdtime(strict=True):
        raise ValueError(f"{name}: expected a continuous-time model (dt = 0), got dt = {sys_.dt}")
    return sys_


def static_gain(D):
    """A static gain as a state-less continuous ``control.StateSpace``.

    Parameters
    ----------
    D : array_like, shape (ny, nu)
        Feedthrough matrix (a scalar or 1-D array is promoted to 2-D).

    Returns
    -------
    control.StateSpace
        Zero states, ``y = D u``.
    """
    import control as ct
    D = np.atleast_2d(np.asarray(D, dtype=float))
    return ct.ss(np.zeros((0, 0)), np.zeros((0, D.shape[1])), np.zeros((D.shape[0], 0)), D)


def dc_gain(sys_) -> np.ndarray:
    """DC gain ``G(0) = D - C A^-1 B`` of a continuous model.

    Parameters
    ----------
    sys_ : control.StateSpace
        Continuous model without a pole at ``s = 0``.

    Returns
    -------
    ndarray, shape (ny, nu)
        In the model's units (plant: sensor V / controller V).
    """
    A = np.asarray(sys_.A, dtype=float)
    if A.size == 0:
        return np.asarray(sys_.D, dtype=float).copy()
    return np.asarray(sys_.D, dtype=float) - sys_.C @ np.linalg.solve(A, sys_.B)


def load_state_space_npz(path):
    """Read a state-space model from an ``.npz`` file.

    Parameters
    ----------
    path : path
        ``.npz`` with continuous ``A, B, C, D`` (required) and optionally the
        discrete ``Ad, Bd, Cd, Dd, dt`` [s].

    Returns
    -------
    G : control.StateSpace
        Continuous model.
    Gd : control.StateSpace or None
        Discrete model with sample time ``dt``, if the file holds one.

    Raises
    ------
    FileNotFoundError
        No such file.
    ValueError
        Missing arrays, inconsistent shapes or NaN/inf entries.
    """
    import control as ct
    z = fileio.load_npz(path, required=("A", "B", "C", "D"))
    A, B, C, D = (np.atleast_2d(np.asarray(z[k], dtype=float)) for k in "ABCD")
    n = A.shape[0]
    if A.shape != (n, n) or B.shape[0] != n or C.shape[1] != n or D.shape != (C.shape[0], B.shape[1]):
        raise ValueError(f"{path}: inconsistent shapes A{A.shape} B{B.shape} C{C.shape} D{D.shape}")
    for k, v in (("A", A), ("B", B), ("C", C), ("D", D)):
        if not np.all(np.isfinite(v)):
            raise ValueError(f"{path}: array {k} has NaN/inf entries")
    G = ct.ss(A, B, C, D)
    Gd = None
    if all(k in z for k in ("Ad", "Bd", "Cd", "Dd", "dt")):
        dt = float(np.asarray(z["dt"]).ravel()[0])
        Gd = ct.ss(*(np.atleast_2d(np.asarray(z[k], float)) for k in ("Ad", "Bd", "Cd", "Dd")), dt)
    return G, Gd


# =====================================================================================
# frequency responses and their scalar measures
# =====================================================================================
def freqresp(sys_, freq_hz) -> np.ndarray:
    """Complex frequency response at ``freq_hz``.

    Continuous models are evaluated at ``s = j 2 pi f``, discrete ones at
    ``z = exp(j 2 pi f dt)`` (keep ``f`` below the Nyquist frequency).

    Parameters
    ----------
    sys_ : control.StateSpace
        ``ny x nu`` model.
    freq_hz : array_like, shape (F,) or scalar
        Frequencies [Hz].

    Returns
    -------
    ndarray, complex, shape (F, ny, nu)
        Frequency first; in the model's units.
    """
    f = np.atleast_1d(np.asarray(freq_hz, dtype=float))
    if sys_.nstates == 0:
        return np.broadcast_to(np.asarray(sys_.D, dtype=complex), (f.size,) + sys_.D.shape).copy()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", FutureWarning)
        resp = sys_.frequency_response(2 * np.pi * f)
        data = resp.frdata if hasattr(resp, "frdata") else resp.fresp
    return np.moveaxis(np.asarray(data).reshape(sys_.noutputs, sys_.ninputs, f.size), -1, 0)


# the eigenvector condition number below which ss_response evaluates in modal form
MODAL_COND_MAX = 1e8


def ss_response(A, B, C, D, points, *, modal: str = "auto") -> np.ndarray:
    """``C (p I - A)^-1 B + D`` at the complex points ``p``: the one state-space evaluation kernel.

    :func:`freqresp` evaluates a python-control model; this evaluates raw matrices, fast: at
    ``p = exp(j 2 pi f dt)`` a discrete model, at ``p = j 2 pi f`` a continuous one.

    Parameters
    ----------
    A, B, C, D : array_like
        State-space matrices (``n x n``, ``n x nu``, ``ny x n``, ``ny x nu``).
    points : array_like, complex, shape (F,)
        Evaluation points ``z`` or ``s``.
    modal : {"auto", "always", "never"}
        ``"always"``: one eigendecomposition of ``A`` (``C V diag(1/(p - lambda)) V^-1 B``);
        ``"never"``: one linear solve per point; ``"auto"``: modal when the eigenvectors' condition
        number is below :data:`MODAL_COND_MAX`, else per point.

    Returns
    -------
    ndarray, complex, shape (F, ny, nu)
    """
    if modal not in ("auto", "always", "never"):
        raise ValueError(f"modal: expected 'auto', 'always' or 'never', got {modal!r}")
    A, B, C, D = (np.asarray(m, float) for m in (A, B, C, D))
    p = np.asarray(points)
    if A.shape[0] == 0:
        return np.broadcast_to(D, (p.size,) + D.shape).astype(complex)
    if modal != "never":
        lam, V = np.linalg.eig(A)
        if modal == "always" or np.linalg.cond(V) < MODAL_COND_MAX:
            CV, VB = C @ V, np.linalg.solve(V, B)
            return D[None] + np.einsum("ik,fk,kj->fij", CV, 1.0 / (p[:, None] - lam[None]), VB)
    n = A.shape[0]
    return np.stack([D + C @ np.linalg.solve(pp * np.eye(n) - A, B) for pp in p])


def sigma_max(H: np.ndarray) -> np.ndarray:
    """Largest singular value of each matrix of a stack.

    Parameters
    ----------
    H : ndarray, shape (F, p, m)

    Returns
    -------
    ndarray, shape (F,)
        In the units of ``H``.
    """
    return np.linalg.svd(H, compute_uv=False)[:, 0]


def singular_values(H: np.ndarray) -> np.ndarray:
    """All singular values of each matrix of a stack, descending.

    Parameters
    ----------
    H : ndarray, shape (F, p, m)

    Returns
    -------
    ndarray, shape (F, min(p, m))
        In the units of ``H``.
    """
    return np.linalg.svd(H, compute_uv=False)


def db(x):
    """``20 log10(x)`` [dB] without a divide-by-zero warning (``x = 0`` gives ``-inf``).

    Parameters
    ----------
    x : array_like
        Non-negative magnitudes.

    Returns
    -------
    ndarray, same shape as ``x``
    """
    with np.errstate(divide="ignore"):
        return 20 * np.log10(np.asarray(x, dtype=float))


def max_real_pole(A) -> float:
    """Largest real part of the eigenvalues of ``A`` [rad/s]; ``-inf`` for an empty ``A``.

    Parameters
    ----------
    A : array_like, shape (n, n)

    Returns
    -------
    float
    """
    A = np.asarray(A, dtype=float)
    return float(np.max(np.linalg.eigvals(A).real)) if A.size else -np.inf


def crossing_hz(f, y, level, rising: bool, first: bool = True) -> float:
    """Frequency where ``y`` crosses ``level`` (log-log interpolation).

    Parameters
    ----------
    f : ndarray, shape (F,)
        Increasing frequencies [Hz].
    y : array_like, shape (F,)
        Positive magnitudes.
    level : float
        Positive crossing level (same units as ``y``).
    rising : bool
        Crossing from below (S); else from above (T).
    first : bool, default True
        The first crossing; else the last one.

    Returns
    -------
    float
        Crossing frequency [Hz]; 0.0 when ``y`` starts already past the level for
        a rising first crossing; NaN when no crossing exists.
    """
    y = np.asarray(y, dtype=float)
    above = y >= level
    if rising:
        idx = np.flatnonzero(~above[:-1] & above[1:])
        if above[0] and first:
            return 0.0
    else:
        idx = np.flatnonzero(above[:-1] & ~above[1:])
    if idx.size == 0:
        return float("nan")
    i = int(idx[0] if first else idx[-1])
    lf0, lf1 = np.log(f[i]), np.log(f[i + 1])
    ly0, ly1, ll = np.log(y[i]), np.log(y[i + 1]), np.log(level)
    t = 0.0 if ly1 == ly0 else (ll - ly0) / (ly1 - ly0)
    return float(np.exp(lf0 + t * (lf1 - lf0)))


def analysis_grid_hz(systems=(), f_min_hz: float = 0.01, f_max_hz: float = 5000.0, n: int = 2500) -> np.ndarray:
    """Log-spaced frequency grid densified around lightly damped poles.

    Around every pole ``p`` of the given ``StateSpace`` models with damping
    ``zeta = -Re p / |p| < 0.3`` and ``f0 = |p| / 2 pi`` inside the range, 41 points
    span ``f0 (1 +/- 8 zeta)`` and 21 more span ``f0 (1 +/- 3 %)``, so that
    resonance peaks of ``zeta = 0.002`` are resolved.

    Parameters
    ----------
    systems : iterable of control.StateSpace or None
        Models whose poles densify the grid (``None`` entries are skipped).
    f_min_hz, f_max_hz : float
        Range [Hz].
    n : int, default 2500
        Points of the log-spaced base grid.

    Returns
    -------
    ndarray, shape (F,)
        Sorted unique frequencies [Hz] in ``[f_min_hz, f_max_hz]``.
    """
    parts = [np.logspace(np.log10(f_min_hz), np.log10(f_max_hz), n)]
    for s_ in systems:
        if s_ is None or s_.nstates == 0:
            continue
        for p in np.linalg.eigvals(np.asarray(s_.A, dtype=float)):
            w0 = abs(p)
            if w0 == 0:
                continue
            zeta = -p.real / w0
            f0 = w0 / (2 * np.pi)
            if f_min_hz < f0 < f_max_hz and abs(zeta) < 0.3 and p.imag >= 0:
                z = max(abs(zeta), 1e-4)
                parts.append(f0 * (1 + 8 * z * np.linspace(-1, 1, 41)))
                parts.append(f0 * (1 + 0.03 * np.linspace(-1, 1, 21)))
    f = np.unique(np.concatenate(parts))
    return f[(f >= f_min_hz) & (f <= f_max_hz)]


def refine_peak(fun, f, y, n_peaks: int = 6, n_fine: int = 101, rounds: int = 3):
    """Refine the grid maximum of ``y = fun(f)`` around its largest local maxima.

    Each of the ``n_peaks`` largest local maxima gets ``rounds`` successive zooms
    of ``n_fine`` points between its neighbours.

    Parameters
    ----------
    fun : callable
        ``fun(freq_hz (N,)) -> (N,)`` values.
    f : ndarray, shape (F,)
        Grid [Hz].
    y : array_like, shape (F,)
        ``fun(f)``.
    n_peaks, n_fine, rounds : int

    Returns
    -------
    peak : float
        Largest value found (units of ``y``).
    peak_hz : float
        Where it occurs [Hz].
    """
    y = np.asarray(y)
    loc = np.flatnonzero(np.r_[True, y[1:] >= y[:-1]] & np.r_[y[:-1] >= y[1:], True])
    loc = loc[np.argsort(y[loc])[::-1][:n_peaks]]
    best_y, best_f = float(y.max()), float(f[int(np.argmax(y))])
    for i in loc:
        lo, hi = f[max(i - 1, 0)], f[min(i + 1, f.size - 1)]
        for _ in range(rounds):
            if hi <= lo:
                break
            ff = np.linspace(lo, hi, n_fine)
            yy = fun(ff)
            j = int(np.argmax(yy))
            if yy[j] > best_y:
                best_y, best_f = float(yy[j]), float(ff[j])
            lo, hi = ff[max(j - 1, 0)], ff[min(j + 1, n_fine - 1)]
    return best_y, best_f
