"""Input checks shared by the identification modules.

Every check raises a short :class:`ValueError` naming the argument, what was
expected and what arrived, before any numerical work is done.
"""
from __future__ import annotations

import numbers

import numpy as np

__all__ = ["as_signal", "as_matrix", "square_matrix", "state_space", "same_length", "positive_float",
           "nonneg_float", "positive_int", "welch_segment_length", "not_degenerate", "frozen_array"]


def as_signal(name: str, value, *, max_ndim: int = 2) -> np.ndarray:
    """Return ``value`` as a finite float array of shape ``(n_samples, n_channels)``.

    A 1-D array is treated as a single channel.
    """
    try:
        arr = np.asarray(value, dtype=float)
    except (TypeError, ValueError):
        raise ValueError(f"{name}: expected a numeric array, got {type(value).__name__}") from None
    if arr.ndim not in range(1, max_ndim + 1):
        raise ValueError(
            f"{name}: expected a 1-D (n_samples,) or 2-D (n_samples, n_channels) array, "
            f"got ndim={arr.ndim} with shape {arr.shape}"
        )
    if arr.ndim == 1:
        arr = arr[:, None]
    if arr.shape[0] == 0 or arr.shape[1] == 0:
        raise ValueError(f"{name}: expected a non-empty array, got shape {arr.shape}")
    finite = np.isfinite(arr)
    if not finite.all():
        bad = int(arr.size - np.count_nonzero(finite))
        raise ValueError(f"{name}: expected finite values, got {bad} NaN/inf entries")
    return arr


def as_matrix(name: str, value, *, rows: int | None = None, cols: int | None = None) -> np.ndarray:
    """Return ``value`` as a finite 2-D float matrix, optionally with fixed dimensions."""
    try:
        arr = np.asarray(value, dtype=float)
    except (TypeError, ValueError):
        raise ValueError(f"{name}: expected a numeric matrix, got {type(value).__name__}") from None
    if arr.ndim != 2:
        raise ValueError(f"{name}: expected a 2-D matrix, got ndim={arr.ndim} with shape {arr.shape}")
    if rows is not None and arr.shape[0] != rows:
        raise ValueError(f"{name}: expected {rows} rows, got shape {arr.shape}")
    if cols is not None and arr.shape[1] != cols:
        raise ValueError(f"{name}: expected {cols} columns, got shape {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise ValueError(f"{name}: expected finite values, got NaN/inf entries")
    return arr


def square_matrix(name: str, value) -> np.ndarray:
    """Return ``value`` as a finite square float matrix (see :func:`as_matrix`)."""
    arr = as_matrix(name, value)
    if arr.shape[0] != arr.shape[1]:
        raise ValueError(f"{name}: expected a square matrix, got shape {arr.shape}")
    return arr


def state_space(A, B, C, D, *, prefix: str = "") -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Return state-space matrices as finite float matrices of consistent shapes.

    ``A`` must be square ``(n, n)``, ``B`` have ``n`` rows, ``C`` ``n``
    columns and ``D`` shape ``(n_outputs, n_inputs)``.  Errors name each matrix
    as ``prefix + "A"`` etc. (e.g. ``prefix="model."``).
    """
    A = square_matrix(f"{prefix}A", A)
    n = A.shape[0]
    B = as_matrix(f"{prefix}B", B, rows=n)
    C = as_matrix(f"{prefix}C", C, cols=n)
    D = as_matrix(f"{prefix}D", D, rows=C.shape[0], cols=B.shape[1])
    return A, B, C, D


def same_length(name_a: str, a: np.ndarray, name_b: str, b: np.ndarray) -> None:
    if a.shape[0] != b.shape[0]:
        raise ValueError(
            f"{name_a}, {name_b}: expected the same number of samples, "
            f"got {a.shape[0]} and {b.shape[0]}"
        )


def positive_float(name: str, value) -> float:
    if isinstance(value, bool) or not isinstance(value, numbers.Real):
        raise ValueError(f"{name}: expected a positive real number, got {value!r}")
    v = float(value)
    if not np.isfinite(v) or v <= 0.0:
        raise ValueError(f"{name}: expected a positive finite number, got {value!r}")
    return v


def nonneg_float(name: str, value) -> float:
    if isinstance(value, bool) or not isinstance(value, numbers.Real):
        raise ValueError(f"{name}: expected a non-negative real number, got {value!r}")
    v = float(value)
    if not np.isfinite(v) or v < 0.0:
        raise ValueError(f"{name}: expected a non-negative finite number, got {value!r}")
    return v


def positive_int(name: str, value, *, minimum: int = 1) -> int:
    if isinstance(value, bool) or not isinstance(value, numbers.Integral):
        raise ValueError(f"{name}: expected an integer >= {minimum}, got {value!r}")
    v = int(value)
    if v < minimum:
        raise ValueError(f"{name}: expected an integer >= {minimum}, got {v}")
    return v


def welch_segment_length(nperseg, n: int, fs: float) -> int:
    """Checked Welch segment length for ``n`` samples at ``fs`` Hz.

    Default ``min(n, max(256, round(fs)))`` (about 1 Hz resolution when
    enough data is available); an integer in ``[2, n]`` otherwise.
    """
    if nperseg is None:
        nperseg = min(n, max(256, int(round(fs))))
    nperseg = positive_int("nperseg", nperseg, minimum=2)
    if nperseg > n:
        raise ValueError(f"nperseg: expected at most n_samples={n}, got {nperseg}")
    return nperseg


def not_degenerate(name: str, arr: np.ndarray) -> None:
    """Reject channels that are constant (this includes all-zero channels)."""
    spread = np.ptp(arr, axis=0)
    scale = np.max(np.abs(arr), axis=0)
    flat = np.flatnonzero(spread <= 1e-12 * np.maximum(scale, np.finfo(float).tiny))
    if flat.size:
        raise ValueError(
            f"{name}: expected every channel to vary in time, got constant "
            f"(or all-zero) channel(s) {flat.tolist()}"
        )


def frozen_array(arr) -> np.ndarray:
    """Return a read-only copy of ``arr`` so frozen dataclasses stay immutable."""
    out = np.array(arr, copy=True)
    out.flags.writeable = False
    return out
