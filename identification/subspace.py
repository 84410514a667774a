"""Discrete-time MIMO subspace identification (PO-MOESP) and simulation.

Identifies the innovation-form model

    x(k+1) = A x(k) + B u(k) + K e(k)
    y(k)   = C x(k) + D u(k) + e(k)

from one record of input/output data, as in Section 3 of the seed paper
(which used MATLAB's state-space parametrisation methods).

Algorithm (PO-MOESP, Verhaegen 1994; see also Van Overschee & De Moor 1996,
ch. 4, for the unifying oblique-projection view):

1. Inputs and outputs are scaled to unit RMS per channel (undone at the end,
   so the returned model acts on the raw data; no mean is removed).
2. Block Hankel matrices with ``i = horizon`` block rows of past/future data
   are stacked as ``[U_f; U_p; Y_p; Y_f]`` and reduced by one economic QR
   factorisation (the LQ factorisation of the stack), so no matrix with the
   full number of samples is ever decomposed by an SVD.
3. The SVD of the block ``L32`` (the part of ``Y_f`` explained by the past
   data ``[U_p; Y_p]`` after removing ``U_f``) gives the extended
   observability matrix ``Gamma_i = U_1 S_1^(1/2)``.  ``C`` is its first
   block row and ``A`` follows from the shift invariance of ``Gamma_i`` by
   least squares.
4. Given ``A`` and ``C``, the output is linear in ``(x0, B, D)``; these are
   found by one linear least-squares fit of the *simulated* output to the
   data (output-error criterion), so the returned model maximises the
   simulation fit for the identified poles and the initial condition of the
   record does not bias ``B`` and ``D``.
5. ``K`` and the innovation covariance come from the Kalman-filter state
   sequence ``X_f = Gamma_i^+ L32 L22^+ W_p`` of the past data: the residuals
   ``w = x(k+1) - A x - B u`` and ``v = y - C x - D u`` are regressed as
   ``w = K v``.  If that predictor ``A - K C`` is not stable, ``K`` is
   recomputed from the discrete algebraic Riccati equation with the sample
   covariances of ``(w, v)``.

References
----------
M. Verhaegen, "Identification of the deterministic part of MIMO state space
models given in innovations form from input-output data", Automatica 30(1),
61-74, 1994.

P. Van Overschee and B. De Moor, *Subspace Identification for Linear
Systems: Theory, Implementation, Applications*, Kluwer, 1996.
"""
from __future__ import annotations

import warnings
from dataclasses import dataclass

import numpy as np
import scipy.linalg as _la

from .regression import fit_x0_B_D
from .checks import (
    as_signal,
    frozen_array,
    not_degenerate,
    positive_float,
    positive_int,
    same_length,
)

__all__ = [
    "IdentifiedModel",
    "subspace_id",
    "select_order",
    "default_horizon",
]

_EPS = np.finfo(float).eps


@dataclass(frozen=True, eq=False)
class IdentifiedModel:
    """Discrete-time innovation-form state-space model.

    ``x(k+1) = A x(k) + B u(k) + K e(k)``, ``y(k) = C x(k) + D u(k) + e(k)``,
    sample time ``dt_s``.  The state basis is arbitrary (balanced-like from the
    SVD); compare models through basis-independent quantities (poles,
    frequency response, DC gain).

    Attributes
    ----------
    A : numpy.ndarray, shape (n, n)
    B : numpy.ndarray, shape (n, n_inputs)
    C : numpy.ndarray, shape (n_outputs, n)
    D : numpy.ndarray, shape (n_outputs, n_inputs)
        Zero if identified with ``feedthrough=False``.
    K : numpy.ndarray, shape (n, n_outputs)
        Steady-state Kalman (innovation) gain.
    dt_s : float
        Sample time in s.
    order : int
        Number of states ``n``.
    singular_values : numpy.ndarray, shape (horizon * n_outputs,)
        Singular values used for order selection (data scaled to unit RMS),
        in decreasing order.
    x0 : numpy.ndarray, shape (n,)
        Initial state that best explains the identification record.
    noise_cov : numpy.ndarray, shape (n_outputs, n_outputs)
        Innovation covariance estimate ``E[e e^T]`` in output units**2.
    horizon : int
        Number of block rows ``i`` of the Hankel matrices.
    input_names, output_names : tuple of str or None
        Optional channel labels.
    """

    A: np.ndarray
    B: np.ndarray
    C: np.ndarray
    D: np.ndarray
    K: np.ndarray
    dt_s: float
    order: int
    singular_values: np.ndarray
    x0: np.ndarray
    noise_cov: np.ndarray
    horizon: int
    input_names: tuple | None = None
    output_names: tuple | None = None

    @property
    def fs(self) -> float:
        """Sampling frequency in Hz."""
        return 1.0 / self.dt_s

    @property
    def n_inputs(self) -> int:
        return self.B.shape[1]

    @property
    def n_outputs(self) -> int:
        return self.C.shape[0]

    @property
    def poles(self) -> np.ndarray:
        """Discrete-time poles (eigenvalues of ``A``), shape (n,)."""
        return np.linalg.eigvals(self.A)

    def to_statespace(self):
        """Discrete ``control.StateSpace`` ``(A, B, C, D, dt_s)`` with the channel labels (K dropped)."""
        import control

        kw = {}
        if self.input_names:
            kw["inputs"] = list(self.input_names)
        if self.output_names:
            kw["outputs"] = list(self.output_names)
        return control.ss(self.A, self.B, self.C, self.D, self.dt_s, **kw)

    def dc_gain(self) -> np.ndarray:
        """Static gain ``C (I - A)^-1 B + D``, shape (n_outputs, n_inputs)."""
        n = self.order
        return self.C @ np.linalg.solve(np.eye(n) - self.A, self.B) + self.D


# ----------------------------------------------------------------------------
# order selection
# ----------------------------------------------------------------------------
def select_order(singular_values, max_order: int, *, floor_ratio: float = 10.0, rtol: float = 1e-9) -> int:
    """Model order from the singular values of the subspace step.

    Rule: the noise floor is the median of the singular values beyond
    ``max_order`` (these can only come from noise and numerical error); the
    order is the number of the first ``max_order`` singular values that lie
    more than ``floor_ratio`` (default 10, i.e. 20 dB) above that floor and
    above ``rtol * s[0]``.  For noiseless data this is the largest
    singular-value gap (the floor is rounding error); with noise, modes whose
    excitation is buried within 20 dB of the noise floor are not counted.

    Parameters
    ----------
    singular_values : array_like, shape (n_sv,)
        Decreasing, non-negative.
    max_order : int
        Largest admissible order, ``1 <= max_order < n_sv``.
    floor_ratio : float, default 10.0
        Required margin above the noise floor (amplitude ratio).
    rtol : float, default 1e-9
        Singular values below ``rtol * s[0]`` are never counted.

    Returns
    -------
    int
        Order in ``[1, max_order]``.
    """
    s = np.asarray(singular_values, dtype=float)
    if s.ndim != 1 or s.size < 2:
        raise ValueError(f"singular_values: expected a 1-D array with >= 2 values, got shape {s.shape}")
    max_order = positive_int("max_order", max_order)
    if max_order >= s.size:
        raise ValueError(f"max_order: expected < number of singular values ({s.size}), got {max_order}")
    floor_ratio = positive_float("floor_ratio", floor_ratio)
    floor = float(np.median(s[max_order:]))
    thresh = max(floor_ratio * floor, rtol * s[0])
    n = int(np.count_nonzero(s[:max_order] > thresh))
    return max(n, 1)


def default_horizon(n_outputs: int, max_order: int) -> int:
    """Default number of block rows ``i`` of the Hankel matrices.

    ``i = max(ceil(2 * max_order / n_outputs) + 1, 30)``: at least twice the
    block rows needed to observe ``max_order`` states, and never below 30
    samples so that closely spaced, lightly damped modes (a few Hz apart at
    kHz sampling) rotate apart within the horizon.
    """
    return max(int(np.ceil(2 * max_order / n_outputs)) + 1, 30)


# ----------------------------------------------------------------------------
# identification
# ----------------------------------------------------------------------------
def _hankel_columns(x: np.ndarray, rows: int) -> np.ndarray:
    """(n_samples - rows + 1, rows * n_channels) matrix; row c holds x[c:c+rows] time-major."""
    w = np.lib.stride_tricks.sliding_window_view(x, rows, axis=0)  # (j, ch, rows)
    return np.ascontiguousarray(w.transpose(0, 2, 1)).reshape(w.shape[0], -1)


def _names(label: str, names, count: int):
    if names is None:
        return None
    names = tuple(str(v) for v in names)
    if len(names) != count:
        raise ValueError(f"{label}: expected {count} names, got {len(names)}")
    return names


def subspace_id(
    y,
    u,
    order: int | None = None,
    horizon: int | None = None,
    *,
    fs: float,
    max_order: int = 20,
    feedthrough: bool = True,
    enforce_stability: bool = False,
    input_names=None,
    output_names=None,
) -> IdentifiedModel:
    """Identify a discrete MIMO state-space model by subspace identification.

    PO-MOESP (Verhaegen 1994) with LQ-reduced block Hankel matrices, order
    from the singular values (Van Overschee & De Moor 1996), and ``(x0, B,
    D)`` fitted by linear least squares on the simulated output; see the
    module docstring for the steps.

    Parameters
    ----------
    y : array_like, shape (n_samples, n_outputs) or (n_samples,)
        Measured outputs (any units).
    u : array_like, shape (n_samples, n_inputs) or (n_samples,)
        Inputs (any units), same number of samples as ``y``.  Each channel
        must vary (a constant input cannot identify dynamics).
    order : int, optional
        Number of states.  Default: chosen by :func:`select_order` among
        ``1..max_order`` (a ``UserWarning`` is issued if it reaches
        ``max_order``).
    horizon : int, optional
        Block rows ``i`` of the past and future Hankel matrices (samples).
        Default :func:`default_horizon`, reduced if the record is short.
        Requires ``(horizon - 1) * n_outputs >= order`` (or ``max_order``).
    fs : float
        Sampling frequency in Hz (the model's ``dt_s = 1 / fs``).
    max_order : int, default 20
        Largest order considered when ``order`` is None.
    feedthrough : bool, default True
        Estimate ``D``; if False, ``D = 0``.
    enforce_stability : bool, default False
        Reflect poles with ``|z| >= 1`` to ``1 / conj(z)`` (same frequency)
        before ``B, D`` are fitted.  Noise can push very lightly damped poles
        slightly outside the unit circle; use this when the model will be
        simulated.
    input_names, output_names : sequence of str, optional
        Channel labels stored in the model.

    Returns
    -------
    IdentifiedModel

    Notes
    -----
    The data are used as given (no detrending): the model maps the raw ``u``
    to the raw ``y`` from the estimated initial state ``x0``.  Remove
    operating-point offsets first if ``y`` is not zero for ``u = 0`` at rest.
    The cost is dominated by one QR factorisation of a
    ``(n_samples - 2 i + 1) x 2 i (n_inputs + n_outputs)`` matrix.

    Examples
    --------
    >>> model = subspace_id(y, u, fs=4000.0)            # doctest: +SKIP
    >>> fit_percent(y, simulate(model, u, x0=model.x0))  # doctest: +SKIP
    """
    ys = as_signal("y", y)
    us = as_signal("u", u)
    same_length("y", ys, "u", us)
    fs = positive_float("fs", fs)
    not_degenerate("u", us)
    not_degenerate("y", ys)
    n_samples, l = ys.shape
    m = us.shape[1]
    max_order = positive_int("max_order", max_order)
    if order is not None:
        order = positive_int("order", order)
    if not isinstance(feedthrough, (bool, np.bool_)):
        raise ValueError(f"feedthrough: expected True or False, got {feedthrough!r}")
    needed = order if order is not None else max_order
    what = "order" if order is not None else "max_order"
    # (i - 1) * l >= n for the shift invariance; with automatic order selection
    # a few singular values beyond max_order are needed for the noise floor.
    min_i = -(-needed // l) + 1
    if order is None:
        min_i = max(min_i, -(-(max_order + 3) // l))

    def min_samples(i):  # j = N - 2 i + 1 columns >= 2 i (m + l) rows
        return 2 * i * (m + l + 1) - 1

    if horizon is None:
        i = default_horizon(l, needed)
        while i > min_i and n_samples < min_samples(i):
            i -= 1
        i = max(i, min_i)
    else:
        i = positive_int("horizon", horizon, minimum=2)
        if i < min_i:
            raise ValueError(
                f"horizon: expected >= {min_i} for {what}={needed} with {l} output(s), got {i}"
            )
    if n_samples < min_samples(i):
        raise ValueError(
            f"y, u: expected at least {min_samples(i)} samples for horizon={i} ({what}={needed}, "
            f"{m} input(s), {l} output(s)), got {n_samples}"
        )
    in_names = _names("input_names", input_names, m)
    out_names = _names("output_names", output_names, l)

    # ---- scaling -----------------------------------------------------------
    su = np.sqrt(np.mean(us**2, axis=0))
    sy = np.sqrt(np.mean(ys**2, axis=0))
    un = us / su
    yn = ys / sy

    # ---- LQ of the block Hankel stack [Uf; Up; Yp; Yf] --------------------
    hu = _hankel_columns(un, 2 * i)  # (j, 2 i m)
    hy = _hankel_columns(yn, 2 * i)  # (j, 2 i l)
    j = hu.shape[0]
    r1, r2 = i * m, i * (m + l)
    wp = np.concatenate([hu[:, : i * m], hy[:, : i * l]], axis=1)  # past data, (j, r2)
    H = np.concatenate([hu[:, i * m :], wp, hy[:, i * l :]], axis=1)
    del hu, hy
    R = np.linalg.qr(H, mode="r")
    del H
    L = R.T / np.sqrt(j)
    # persistency of excitation: the input rows [U_f; U_p] must have full rank
    d_in = np.abs(np.concatenate([np.diag(L)[:r1], np.diag(L)[r1 : r1 + i * m]]))
    if d_in.min() <= 1e-10 * d_in.max():
        raise ValueError(
            f"u: expected an input persistently exciting of order {2 * i} (e.g. PRBS), got a "
            f"rank-deficient input Hankel matrix (a few sinusoids or a too slowly varying signal?)"
        )
    L22 = L[r1 : r1 + r2, r1 : r1 + r2]
    L32 = L[r1 + r2 :, r1 : r1 + r2]

    Us, sv, Vt = np.linalg.svd(L32)
    if order is None:
        n = select_order(sv, max_order)
        if n == max_order:
            warnings.warn(
                f"order: automatic selection reached max_order={max_order}; the system may need more "
                f"states (increase max_order or pass order)",
                UserWarning,
                stacklevel=2,
            )
    else:
        n = order
    if n >= sv.size:
        raise ValueError(f"order: expected < horizon * n_outputs = {sv.size}, got {n}")

    sq = np.sqrt(sv[:n])
    gamma = Us[:, :n] * sq
    C = gamma[:l].copy()
    A = np.linalg.lstsq(gamma[:-l], gamma[l:], rcond=None)[0]
    if enforce_stability:
        A = _reflect_unstable(A)

    # ---- (x0, B, D) by output-error least squares -------------------------
    x0, B, D = fit_x0_B_D(A, C, un, yn, feedthrough)

    # ---- Kalman gain from the state sequence -------------------------------
    # X_f^T = W_p^T (Gamma^+ L32 L22^+)^T ; Gamma^+ L32 = S1^(1/2) V1^T
    gl = (sq[:, None] * Vt[:n])  # (n, r2)
    zt = np.linalg.lstsq(L22.T, gl.T, rcond=1e-10)[0]  # (r2, n) = (Gamma^+ L32 L22^+)^T
    X = wp @ zt  # (j, n), state at times i .. i + j - 1
    t = np.arange(i, i + j)
    v = yn[t] - X @ C.T - un[t] @ D.T
    w = X[1:] - X[:-1] @ A.T - un[t[:-1]] @ B.T
    v1 = v[:-1]
    K, Rn = _kalman_gain(A, C, w, v1)

    # ---- undo scaling -------------------------------------------------------
    B = B / su
    C = C * sy[:, None]
    D = D * sy[:, None] / su
    K = K / sy
    Rn = Rn * np.outer(sy, sy)

    return IdentifiedModel(
        A=frozen_array(A),
        B=frozen_array(B),
        C=frozen_array(C),
        D=frozen_array(D),
        K=frozen_array(K),
        dt_s=1.0 / fs,
        order=n,
        singular_values=frozen_array(sv),
        x0=frozen_array(x0),
        noise_cov=frozen_array(Rn),
        horizon=i,
        input_names=in_names,
        output_names=out_names,
    )


def _reflect_unstable(A: np.ndarray) -> np.ndarray:
    lam, V = np.linalg.eig(A)
    mag = np.abs(lam)
    bad = mag >= 1.0
    if not bad.any():
        return A
    lam = lam.copy()
    lam[bad] = lam[bad] / mag[bad] ** 2  # 1 / conj(z): same angle, radius 1/|z|
    lam[mag == 1.0] *= 1.0 - 1e-9
    A2 = V @ np.diag(lam) @ np.linalg.inv(V)
    return np.real(A2)


def _kalman_gain(A, C, w, v):
    """Innovation gain and covariance from state/output residual sequences."""
    n, l = A.shape[0], C.shape[0]
    N = v.shape[0]
    Rv = v.T @ v / N
    Sw = w.T @ v / N
    Qw = w.T @ w / N
    # innovation variance floor: 1e-10 of the (unit) output variance
    ridge = 1e-10 * np.eye(l)
    K = np.linalg.solve(Rv + ridge, Sw.T).T
    if np.max(np.abs(np.linalg.eigvals(A - K @ C)), initial=0.0) < 1.0:
        return K, Rv
    try:
        P = _la.solve_discrete_are(A.T, C.T, Qw + 1e-10 * np.eye(n), Rv + ridge, s=Sw)
        K = np.linalg.solve(C @ P @ C.T + Rv + ridge, (A @ P @ C.T + Sw).T).T
        Rk = C @ P @ C.T + Rv
        if np.max(np.abs(np.linalg.eigvals(A - K @ C))) < 1.0:
            return K, Rk
    except (np.linalg.LinAlgError, ValueError):
        pass
    return np.zeros((n, l)), Rv


# ----------------------------------------------------------------------------
# impulse-response machinery
# ----------------------------------------------------------------------------
