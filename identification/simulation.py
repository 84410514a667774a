"""Simulation, initial-state estimation and one-step prediction of identified discrete models."""
from __future__ import annotations

import numpy as np

from .checks import as_matrix, as_signal, same_length, state_space
from .regression import lstsq_scaled, observability_powers

__all__ = ["simulate", "estimate_x0", "predict"]


def _model_matrices(model):
    try:
        A, B, C, D = model.A, model.B, model.C, model.D
    except AttributeError:
        raise ValueError(
            f"model: expected an IdentifiedModel (or object with A, B, C, D), got {type(model).__name__}"
        ) from None
    return state_space(A, B, C, D, prefix="model.")


def _initial_state(x0, n: int) -> np.ndarray:
    """Checked initial state of ``n`` entries (zeros when ``x0`` is None)."""
    x = np.zeros(n) if x0 is None else as_signal("x0", x0, max_ndim=1)[:, 0]
    if x.shape[0] != n:
        raise ValueError(f"x0: expected shape ({n},), got ({x.shape[0]},)")
    return x


def _run_recursion(F, drive, x, C, D, u) -> np.ndarray:
    """Outputs ``C x(k) + D u(k)`` of ``x(k+1) = F x(k) + drive(k)`` from ``x(0) = x``.

    ``drive`` has shape ``(n_samples, n)`` and ``u`` ``(n_samples, n_inputs)``.
    """
    N, n = drive.shape
    X = np.empty((N, n))
    Ft = np.ascontiguousarray(F.T)
    for k in range(N):
        X[k] = x
        x = x @ Ft + drive[k]
    return X @ C.T + u @ D.T


def simulate(model, u, x0=None) -> np.ndarray:
    """Pure (open-loop) simulation of a discrete state-space model.

    ``x(k+1) = A x(k) + B u(k)``, ``y(k) = C x(k) + D u(k)``; the noise model
    ``K`` is not used (this is simulation, not one-step prediction).

    Parameters
    ----------
    model : IdentifiedModel
        Or any object with discrete-time ``A, B, C, D`` attributes.
    u : array_like, shape (n_samples, n_inputs) or (n_samples,)
        Input sequence (1-D only for single-input models).
    x0 : array_like, shape (n,), optional
        Initial state (default zeros), e.g. ``model.x0`` for the
        identification record or :func:`estimate_x0` for another record.

    Returns
    -------
    numpy.ndarray, shape (n_samples, n_outputs)
        Simulated output.
    """
    A, B, C, D = _model_matrices(model)
    us = as_signal("u", u)
    n, m = B.shape
    if us.shape[1] != m:
        raise ValueError(f"u: expected {m} input channel(s), got {us.shape[1]}")
    x = _initial_state(x0, n)
    return _run_recursion(A, us @ B.T, x, C, D, us)


def estimate_x0(model, y, u) -> np.ndarray:
    """Least-squares initial state for a data record.

    Finds ``x0`` minimising ``||y - simulate(model, u, x0)||`` (Frobenius
    norm over all samples and outputs), so fit measures are not spoiled by an
    unknown initial condition.

    Parameters
    ----------
    model : IdentifiedModel
        Or any object with discrete-time ``A, B, C, D`` attributes.
    y : array_like, shape (n_samples, n_outputs) or (n_samples,)
        Measured output.
    u : array_like, shape (n_samples, n_inputs) or (n_samples,)
        Input.

    Returns
    -------
    numpy.ndarray, shape (n,)
    """
    A, B, C, D = _model_matrices(model)
    ys = as_signal("y", y)
    us = as_signal("u", u)
    same_length("y", ys, "u", us)
    if ys.shape[1] != C.shape[0]:
        raise ValueError(f"y: expected {C.shape[0]} output channel(s), got {ys.shape[1]}")
    if us.shape[1] != B.shape[1]:
        raise ValueError(f"u: expected {B.shape[1]} input channel(s), got {us.shape[1]}")
    resid = ys - simulate(model, us)
    N, l = ys.shape
    O = observability_powers(A, C, N)
    return lstsq_scaled(O.reshape(N * l, -1), resid.reshape(N * l))


def predict(model, y, u, x0=None) -> np.ndarray:
    """One-step-ahead prediction with the innovation-form Kalman predictor.

    ``yhat(k) = C xhat(k) + D u(k)``,
    ``xhat(k+1) = A xhat(k) + B u(k) + K (y(k) - yhat(k))``.

    Parameters
    ----------
    model : IdentifiedModel
        Model with a Kalman gain ``K``.
    y : array_like, shape (n_samples, n_outputs) or (n_samples,)
        Measured output.
    u : array_like, shape (n_samples, n_inputs) or (n_samples,)
        Input.
    x0 : array_like, shape (n,), optional
        Initial state estimate (default zeros).

    Returns
    -------
    numpy.ndarray, shape (n_samples, n_outputs)
        Predicted output; ``y - yhat`` estimates the innovations ``e``.
    """
    A, B, C, D = _model_matrices(model)
    try:
        K = as_matrix("model.K", model.K, rows=A.shape[0], cols=C.shape[0])
    except AttributeError:
        raise ValueError("model: expected a Kalman gain attribute K, got none") from None
    ys = as_signal("y", y)
    us = as_signal("u", u)
    same_length("y", ys, "u", us)
    n, m = B.shape
    l = C.shape[0]
    if ys.shape[1] != l:
        raise ValueError(f"y: expected {l} output channel(s), got {ys.shape[1]}")
    if us.shape[1] != m:
        raise ValueError(f"u: expected {m} input channel(s), got {us.shape[1]}")
    x = _initial_state(x0, n)
    # xhat(k+1) = (A - K C) xhat + (B - K D) u + K y
    Ak = A - K @ C
    drive = us @ (B - K @ D).T + ys @ K.T
    return _run_recursion(Ak, drive, x, C, D, us)
