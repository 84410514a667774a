"""Argument checks and time base of the loop-analysis functions.

Shared by :mod:`~nanosim.design.loopresponse`, :mod:`~nanosim.design.margins`,
:mod:`~nanosim.design.mu` and :mod:`~nanosim.design.uncertainty`: every public
function there validates its arguments here, before any computation, and names the
offending argument, what was expected and what arrived.

Systems are ``control.StateSpace`` / ``control.TransferFunction`` objects, static
gains (scalars, 2-D arrays) or, where allowed, frequency-response stacks of shape
``(F, rows, cols)``. All LTI arguments of one call share one time base: continuous,
or discrete with one sample period ``dt`` [s]; static gains fit either.
"""
from __future__ import annotations

import math
import numbers

import control as ct
import numpy as np

__all__ = ["LTI_TYPES", "is_lti", "is_static_lti", "describe", "check_system", "io_shape", "check_delay",
           "timebase", "check_freq", "check_range", "check_scale", "check_int", "json_num"]

LTI_TYPES = (ct.StateSpace, ct.TransferFunction)


def is_lti(x) -> bool:
    """True for a ``control.StateSpace`` or ``control.TransferFunction``."""
    return isinstance(x, LTI_TYPES)


def is_static_lti(x) -> bool:
    """True for an LTI object without dynamics (it fits either time base)."""
    if isinstance(x, ct.StateSpace):
        return x.nstates == 0
    return all(np.size(np.trim_zeros(np.atleast_1d(d), "f")) <= 1 and np.size(np.trim_zeros(np.atleast_1d(n), "f")) <= 1
               for row_n, row_d in zip(x.num, x.den) for n, d in zip(row_n, row_d))


def describe(x) -> str:
    """Short description of an argument for error messages."""
    if is_lti(x):
        return f"{type(x).__name__} with {x.noutputs} outputs, {x.ninputs} inputs, dt={x.dt!r}"
    if isinstance(x, np.ndarray):
        return f"ndarray of shape {x.shape} and dtype {x.dtype}"
    return f"{type(x).__name__} {x!r}"[:200]


def check_system(name: str, x, *, allow_none: bool = False, allow_stack: bool = True) -> None:
    """Reject anything that is not an LTI system, a static gain or (optionally) a
    stack of frequency responses ``(F, rows, cols)``.

    Raises
    ------
    TypeError, ValueError
        Naming ``name``.
    """
    if x is None:
        if allow_none:
            return
        raise TypeError(f"{name}: expected a control.StateSpace/TransferFunction or a gain matrix, got None")
    if is_lti(x):
        return
    if isinstance(x, numbers.Number) and not isinstance(x, bool):
        return
    if isinstance(x, (np.ndarray, list, tuple)):
        a = np.asarray(x)
        if a.dtype.kind not in "biufc" or a.dtype.kind == "b":
            raise TypeError(f"{name}: expected numeric values, got {describe(a)}")
        ok_dims = (0, 2, 3) if allow_stack else (0, 2)
        if a.ndim not in ok_dims:
            raise ValueError(f"{name}: expected a scalar, a 2-D gain matrix"
                             + (" or a (F, rows, cols) frequency-response stack" if allow_stack else "")
                             + f", got an array of shape {a.shape}")
        return
    raise TypeError(f"{name}: expected a control.StateSpace/TransferFunction or a gain matrix, got {describe(x)}")


def io_shape(x) -> tuple[int, int]:
    """``(outputs, inputs)`` of a system, gain or response stack."""
    if is_lti(x):
        return x.noutputs, x.ninputs
    a = np.asarray(x)
    if a.ndim == 0:
        return 1, 1
    return a.shape[-2], a.shape[-1]


def check_delay(delay_samples) -> int:
    """A non-negative integer number of samples (integral floats accepted)."""
    if isinstance(delay_samples, bool) or not isinstance(delay_samples, numbers.Integral):
        if isinstance(delay_samples, numbers.Real) and not isinstance(delay_samples, bool) \
                and float(delay_samples).is_integer():
            delay_samples = int(delay_samples)
        else:
            raise TypeError(f"delay_samples: expected a non-negative integer number of samples, "
                            f"got {delay_samples!r}")
    if delay_samples < 0:
        raise ValueError(f"delay_samples: expected >= 0, got {delay_samples}")
    return int(delay_samples)


def check_int(name: str, v, lo: int) -> int:
    """An integer ``>= lo`` (bools rejected)."""
    if isinstance(v, bool) or not isinstance(v, numbers.Integral) or v < lo:
        raise ValueError(f"{name}: expected an integer >= {lo}, got {v!r}")
    return int(v)


def timebase(systems: dict, dt) -> tuple[str | None, float | None]:
    """Common time base of the LTI entries of ``systems`` and the ``dt`` argument.

    Returns
    -------
    kind : {'discrete', 'continuous', None}
        None when there are only static gains.
    T : float or None
        Sample period of the discrete systems, or the ``dt`` argument [s].
    """
    if dt is not None:
        if isinstance(dt, bool) or not isinstance(dt, numbers.Real) or not (dt > 0) or not math.isfinite(dt):
            raise ValueError(f"dt: expected a positive sample period in seconds or None, got {dt!r}")
        dt = float(dt)
    kinds: dict[str, str] = {}
    sample: dict[str, float] = {}
    for name, x in systems.items():
        if not is_lti(x) or x.dt is None or is_static_lti(x):
            continue
        if ct.isdtime(x, strict=True):
            if x.dt is True:
                raise ValueError(f"{name}: discrete system with unspecified sample period (dt=True); "
                                 f"expected a numeric dt in seconds")
            kinds[name] = "discrete"
            sample[name] = float(x.dt)
        else:
            kinds[name] = "continuous"
    if len(set(kinds.values())) > 1:
        raise ValueError("mixed time bases: " + ", ".join(f"{k} is {v}" for k, v in kinds.items())
                         + "; expected all continuous or all discrete with one dt")
    if not kinds:
        return None, dt
    kind = next(iter(kinds.values()))
    if kind == "continuous":
        return kind, dt
    T = next(iter(sample.values()))
    for name, t in sample.items():
        if not math.isclose(t, T, rel_tol=1e-9):
            raise ValueError(f"{name}: sample period {t} s differs from {T} s of the other systems")
    if dt is not None and not math.isclose(dt, T, rel_tol=1e-9):
        raise ValueError(f"dt: {dt} s given but the discrete systems have dt = {T} s")
    return kind, T


def check_freq(freq_hz, kind, T, *, increasing: bool = False) -> np.ndarray:
    """A non-empty 1-D grid of finite frequencies >= 0 Hz (<= Nyquist when discrete)."""
    try:
        f = np.asarray(freq_hz, dtype=float)
    except (TypeError, ValueError):
        raise TypeError(f"freq_hz: expected a 1-D array of frequencies in Hz, got {describe(freq_hz)}") from None
    if f.ndim == 0:
        f = f.reshape(1)
    if f.ndim != 1 or f.size == 0:
        raise ValueError(f"freq_hz: expected a non-empty 1-D array in Hz, got shape {f.shape}")
    if not np.all(np.isfinite(f)) or np.any(f < 0):
        raise ValueError(f"freq_hz: expected finite frequencies >= 0 Hz, got min {np.nanmin(f)!r}, "
                         f"max {np.nanmax(f)!r}")
    if increasing and f.size > 1 and np.any(np.diff(f) <= 0):
        raise ValueError("freq_hz: expected strictly increasing frequencies (peaks are refined "
                         "between grid neighbours)")
    if kind == "discrete":
        nyq = 0.5 / T
        if f.max() > nyq * (1 + 1e-9):
            raise ValueError(f"freq_hz: discrete systems (dt={T} s) are defined up to the Nyquist "
                             f"frequency {nyq} Hz, got up to {f.max()} Hz")
    return f


def check_range(name: str, rng, *, positive: bool = True, integer: bool = False):
    """A ``(low, high)`` pair of finite numbers with ``low <= high``."""
    try:
        lo, hi = rng
    except (TypeError, ValueError):
        raise ValueError(f"{name}: expected a (low, high) pair, got {rng!r}") from None
    for v in (lo, hi):
        if isinstance(v, bool) or not isinstance(v, numbers.Real) or not math.isfinite(v):
            raise ValueError(f"{name}: expected finite numbers, got {rng!r}")
        if integer and not float(v).is_integer():
            raise ValueError(f"{name}: expected integers, got {rng!r}")
    if lo > hi or (positive and lo <= 0) or (integer and lo < 0):
        raise ValueError(f"{name}: expected {'0 <' if positive else ''} low <= high, got {rng!r}")
    return (int(lo), int(hi)) if integer else (float(lo), float(hi))


def check_scale(name: str, v, lo_ok: float = 0.0) -> float:
    """A finite real number ``> lo_ok``."""
    if isinstance(v, bool) or not isinstance(v, numbers.Real) or not math.isfinite(v) or not (v > lo_ok):
        raise ValueError(f"{name}: expected a finite real number > {lo_ok}, got {v!r}")
    return float(v)


def json_num(x):
    """JSON-safe float: non-finite values become None."""
    x = float(x)
    return x if math.isfinite(x) else None
