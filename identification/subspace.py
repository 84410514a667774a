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
from scipy import fft as _fft

from ._checks import (
    as_matrix,
    as_signal,
    frozen_array,
    not_degenerate,
    positive_float,
    positive_int,
    same_length,
    state_space,
)

__all__ = [
    "IdentifiedModel",
    "subspace_id",
    "select_order",
    "simulate",
    "estimate_x0",
    "predict",
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
    x0, B, D = _fit_x0_B_D(A, C, un, yn, feedthrough)

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
def _obs_powers(A: np.ndarray, C: np.ndarray, n_samples: int) -> np.ndarray:
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


def _fill_forced_regressors(O: np.ndarray, u: np.ndarray, out: np.ndarray) -> None:
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


def _lstsq_scaled(Phi: np.ndarray, target: np.ndarray) -> np.ndarray:
    """Column-normalised least squares; ``Phi`` is overwritten."""
    norms = np.linalg.norm(Phi, axis=0)
    norms[norms == 0] = 1.0
    Phi /= norms
    theta = _la.lstsq(Phi, target, lapack_driver="gelsy", overwrite_a=True, check_finite=False)[0]
    return theta / norms


def _fit_x0_B_D(A, C, u, y, feedthrough):
    N, l = y.shape
    n = A.shape[0]
    m = u.shape[1]
    p = n + n * m + (l * m if feedthrough else 0)
    Phi = np.empty((N, l, p))
    O = _obs_powers(A, C, N)
    Phi[:, :, :n] = O
    _fill_forced_regressors(O, u, Phi[:, :, n : n + n * m])
    del O
    if feedthrough:
        Dreg = Phi[:, :, n + n * m :]
        Dreg[...] = 0.0
        for r in range(l):
            Dreg[:, r, r * m : (r + 1) * m] = u
    theta = _lstsq_scaled(Phi.reshape(N * l, p), y.reshape(N * l))
    x0 = theta[:n]
    B = theta[n : n + n * m].reshape(n, m)
    D = theta[n + n * m :].reshape(l, m) if feedthrough else np.zeros((l, m))
    return x0, B, D


# ----------------------------------------------------------------------------
# simulation
# ----------------------------------------------------------------------------
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
    O = _obs_powers(A, C, N)
    return _lstsq_scaled(O.reshape(N * l, -1), resid.reshape(N * l))


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
