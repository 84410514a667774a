"""Structured singular value (mu) bounds of complex matrices, one per frequency.

Blocks follow MATLAB's ``mussv`` convention: block ``(r, c)`` is a complex full
``Delta_i`` of size ``r x c``; ``M`` is ``(sum c) x (sum r)``; ``(1, 1)`` is a complex
scalar.  Repeated scalar blocks are not supported.  Used by the multiloop disk margins
(:mod:`~nanosim.design.margins`) and the robust-stability test over the stage's
uncertainty set (:mod:`~nanosim.design.uncertainty`).

The mixed real / complex bound (:class:`~nanosim.design.mixed_mu.MixedMuBounds`,
:func:`~nanosim.design.mixed_mu.mixed_mu_upper_bound`, D-G scalings) is in :mod:`~nanosim.design.mixed_mu`;
its names are re-exported here.
"""
from __future__ import annotations

import math
import numbers
from dataclasses import dataclass

import numpy as np
import scipy.linalg
import scipy.optimize

from nanosim.design.loopargs import describe

__all__ = ["MuBounds", "mu_upper_bound", "mu_lower_bound"]


@dataclass(frozen=True, eq=False)
class MuBounds:
    """Bounds on the structured singular value at each frequency.

    Attributes
    ----------
    upper : ndarray, shape (F,)
        D-scaling upper bound ``min_D sigma_max(D_l M D_r^-1)`` (evaluated exactly at the
        returned scales, so it is a valid upper bound whatever the optimiser did).
    lower : ndarray, shape (F,)
        Lower bound ``max rho(M Delta)`` over the structured ``Delta`` found by a power
        iteration (NaN when not computed).
    d_scales : ndarray, shape (F, n_blocks)
        Optimal scalings ``d_i`` (last block normalised to 1).
    blocks : tuple of (int, int)
    """

    upper: np.ndarray
    lower: np.ndarray
    d_scales: np.ndarray
    blocks: tuple

    def __post_init__(self):
        for name in ("upper", "lower", "d_scales"):
            getattr(self, name).setflags(write=False)


def _check_blocks(blocks) -> tuple[tuple[int, int], ...]:
    try:
        bl = [tuple(int(v) for v in b) for b in blocks]
        ok = all(len(b) == 2 for b in bl) and len(bl) > 0
        raw_ok = all(all(isinstance(v, numbers.Integral) and not isinstance(v, bool) for v in b)
                     for b in blocks)
    except (TypeError, ValueError):
        ok = raw_ok = False
    if not ok or not raw_ok:
        raise ValueError(f"blocks: expected a non-empty list of (rows, cols) integer pairs, got {blocks!r}")
    if any(r < 1 or c < 1 for r, c in bl):
        raise ValueError(f"blocks: expected positive sizes (complex full blocks; repeated scalar "
                         f"blocks such as (k, 0) are not supported), got {blocks!r}")
    return tuple(bl)


def _check_M(M, blocks) -> np.ndarray:
    a = np.asarray(M)
    if a.dtype.kind not in "iufc":
        raise TypeError(f"M: expected a numeric array, got {describe(a)}")
    if a.ndim == 2:
        a = a[None]
    if a.ndim != 3:
        raise ValueError(f"M: expected shape (F, n, m) or (n, m), got {np.shape(M)}")
    nr = sum(c for _, c in blocks)
    nc = sum(r for r, _ in blocks)
    if a.shape[1:] != (nr, nc):
        raise ValueError(f"M: the blocks {list(blocks)} need M of shape (F, {nr}, {nc}) "
                         f"(rows: sum of block cols, cols: sum of block rows), got {a.shape}")
    if not np.all(np.isfinite(a)):
        raise ValueError("M: contains non-finite values")
    return a.astype(complex)


class _Structure:
    def __init__(self, blocks):
        self.blocks = blocks
        self.nb = len(blocks)
        c = np.cumsum([0] + [c for _, c in blocks])
        r = np.cumsum([0] + [r for r, _ in blocks])
        self.rows = [slice(c[i], c[i + 1]) for i in range(self.nb)]   # rows of M: z-space
        self.cols = [slice(r[i], r[i + 1]) for i in range(self.nb)]   # cols of M: w-space
        self.lrep = np.concatenate([[i] * b[1] for i, b in enumerate(blocks)]).astype(int)
        self.rrep = np.concatenate([[i] * b[0] for i, b in enumerate(blocks)]).astype(int)

    def scale(self, M, x):
        d = np.exp(x)
        return (d[self.lrep][:, None] * M) / d[self.rrep][None, :]

    def block_sums(self, v2, rep):
        return np.bincount(rep, weights=v2, minlength=self.nb)


def _osborne(M, st: _Structure, sweeps: int = 30) -> np.ndarray:
    N = np.zeros((st.nb, st.nb))
    for i in range(st.nb):
        for j in range(st.nb):
            N[i, j] = np.linalg.norm(M[st.rows[i], st.cols[j]])
    N2 = N ** 2
    np.fill_diagonal(N2, 0.0)
    x = np.zeros(st.nb)
    for _ in range(sweeps):
        change = 0.0
        for i in range(st.nb):
            e = np.exp(2 * (x[i] - x))          # (d_i / d_j)^2
            row = float(np.sum(N2[i, :] * e))
            col = float(np.sum(N2[:, i] / e))
            if row > 0 and col > 0:
                step = 0.25 * math.log(col / row)
                x[i] += step
                change = max(change, abs(step))
        if change < 1e-6:
            break
    x = np.clip(x - x[-1], -30, 30)
    return x


def _mu_ub_one(M, st: _Structure, x0=None, stop_below=None):
    """Upper bound at one frequency; returns ``(ub, x)`` with ``x = log d`` (last 0).

    With ``stop_below``, returns as soon as a (valid) bound at or below it is found.
    """
    if st.nb == 1:
        return float(np.linalg.norm(M, 2)), np.zeros(1)

    def true_ub(y):
        return float(np.linalg.norm(st.scale(M, np.append(y, 0.0)), 2))

    def f_and_g(y, p):
        A = st.scale(M, np.append(y, 0.0))
        U, s, Vh = np.linalg.svd(A, full_matrices=False)
        if s[0] == 0:
            return 0.0, np.zeros_like(y)
        q = (s / s[0]) ** (2 * p)
        Z = q.sum()
        w = q / Z
        gu = st.block_sums((U.real ** 2 + U.imag ** 2) @ w, st.lrep)
        gv = st.block_sums((Vh.real ** 2 + Vh.imag ** 2).T @ w, st.rrep)
        return math.log(s[0]) + math.log(Z) / (2 * p), (gu - gv)[:-1]

    cands = [_osborne(M, st)]
    if x0 is not None:
        cands.append(np.asarray(x0, float))
    ys = [np.clip(c[:-1] - c[-1], -30, 30) for c in cands]
    y = min(ys, key=true_ub)
    bounds = [(-30.0, 30.0)] * (st.nb - 1)
    for p in (8.0, 128.0, 1024.0):
        res = scipy.optimize.minimize(f_and_g, y, args=(p,), jac=True, method="L-BFGS-B", bounds=bounds,
                                      options={"maxiter": 100, "ftol": 1e-12, "gtol": 1e-9})
        y = res.x
        if stop_below is not None and true_ub(y) <= stop_below:
            break
    return true_ub(y), np.append(y, 0.0)


def _mu_lb_one(M, st: _Structure, x=None, ub=None, iters: int = 50, n_random: int = 2,
               rng=None) -> float:
    """Lower bound ``max rho(M Delta)`` over structured ``Delta`` with unit blocks, by a
    power-type fixed-point iteration (align each ``Delta_i`` with the left/right
    eigenvectors of the dominant eigenvalue of ``M Delta``).
    """
    n, m = M.shape
    if st.nb == 1:
        return float(np.linalg.norm(M, 2))
    A = st.scale(M, x) if x is not None else M
    U, _, Vh = np.linalg.svd(A)
    MH = M.conj().T

    def delta_from(g, h):
        ng = np.sqrt(st.block_sums(g.real ** 2 + g.imag ** 2, st.rrep))
        nh = np.sqrt(st.block_sums(h.real ** 2 + h.imag ** 2, st.lrep))
        ok = (ng > 0) & (nh > 0)
        gs = g / np.where(ok, ng, 1.0)[st.rrep]
        hs = h / np.where(ok, nh, 1.0)[st.lrep]
        D = np.outer(gs, hs.conj())
        D *= (st.rrep[:, None] == st.lrep[None, :]) & ok[st.rrep][:, None]
        return D

    def run(D):
        best = 0.0
        for _ in range(iters):
            lam, VL, VR = scipy.linalg.eig(M @ D, left=True, right=True)
            k = int(np.argmax(np.abs(lam)))
            r = float(abs(lam[k]))
            if r <= best * (1 + 1e-10):
                best = max(best, r)
                break
            best = r
            if ub is not None and r >= ub * (1 - 1e-9):
                break
            D = delta_from(MH @ VL[:, k], VR[:, k])
        return best

    best = run(delta_from(Vh[0].conj(), U[:, 0]))
    rng = np.random.default_rng(0) if rng is None else rng
    for _ in range(n_random):
        if ub is not None and best >= ub * (1 - 1e-3):
            break
        g = rng.standard_normal(m) + 1j * rng.standard_normal(m)
        h = rng.standard_normal(n) + 1j * rng.standard_normal(n)
        best = max(best, run(delta_from(g, h)))
    return best


def _osborne_batch(Ms: np.ndarray, st: _Structure, sweeps: int = 30) -> np.ndarray:
    """Osborne balancing of the block-norm matrices of a stack, vectorised over
    frequency; returns ``log d`` of shape (F, nb), last block 0.
    """
    F = Ms.shape[0]
    N2 = np.empty((F, st.nb, st.nb))
    for i in range(st.nb):
        for j in range(st.nb):
            blk = Ms[:, st.rows[i], st.cols[j]]
            N2[:, i, j] = np.sum(blk.real ** 2 + blk.imag ** 2, axis=(1, 2))
    idx = np.arange(st.nb)
    N2[:, idx, idx] = 0.0
    x = np.zeros((F, st.nb))
    for _ in range(sweeps):
        change = 0.0
        for i in range(st.nb):
            e = np.exp(2 * (x[:, i:i + 1] - x))
            row = np.sum(N2[:, i, :] * e, axis=1)
            col = np.sum(N2[:, :, i] / e, axis=1)
            ok = (row > 0) & (col > 0)
            step = np.where(ok, 0.25 * np.log(np.where(ok, col, 1.0) / np.where(ok, row, 1.0)), 0.0)
            x[:, i] += step
            change = max(change, float(np.max(np.abs(step))))
        if change < 1e-6:
            break
    return np.clip(x - x[:, -1:], -30, 30)


def _scaled_sigma_max(Ms: np.ndarray, st: _Structure, X: np.ndarray) -> np.ndarray:
    d = np.exp(X)
    A = d[:, st.lrep][:, :, None] * Ms / d[:, st.rrep][:, None, :]
    return np.linalg.svd(A, compute_uv=False)[:, 0]


def mu_upper_bound(M, blocks, *, lower: bool = True, peak_only: bool = False, floor=None) -> MuBounds:
    """Structured singular value bounds of complex matrices (one per frequency).

    Upper bound: ``min over positive block-diagonal D of sigma_max(D_l M D_r^-1)``,
    started from Osborne balancing of the block-norm matrix and minimised over
    ``log d`` with L-BFGS-B on a smooth Schatten-``2p`` surrogate (``p = 4, 32, 256``);
    the returned value is the exact ``sigma_max`` at the final scales (a valid upper
    bound).  Lower bound: ``rho(M Delta)`` maximised over structured ``Delta`` with
    ``sigma_max(Delta_i) = 1`` by a power-type fixed-point iteration started from the
    upper bound's singular vectors (and a few random starts); ``lower <= mu <= upper``.

    Parameters
    ----------
    M : array_like, complex, shape (F, n, m) or (n, m)
        ``n = sum of block cols``, ``m = sum of block rows``.
    blocks : sequence of (int, int)
        ``(rows, cols)`` of each complex full block ``Delta_i`` (``(1, 1)``: complex
        scalar), MATLAB ``mussv`` convention.
    lower : bool
        Also compute the lower bound (else ``MuBounds.lower`` is NaN).
    peak_only : bool
        Screen for the peak over frequency: the D scales are optimised only where the
        Osborne-balanced bound (vectorised, cheap) exceeds the largest optimised bound
        found so far, in decreasing order of the Osborne bound; elsewhere ``upper`` is
        the Osborne bound (still a valid upper bound, at most the peak) and ``lower`` the
        spectral radius of ``M`` (a valid lower bound when every block is square, else
        0).  ``max(upper)`` is the same as without screening.
    floor : float or None
        With ``peak_only``: a value the peak is known to reach (e.g. from a coarser
        grid); only frequencies whose bound may exceed it are optimised.

    Returns
    -------
    MuBounds
    """
    bl = _check_blocks(blocks)
    Ms = _check_M(M, bl)
    st = _Structure(bl)
    F = Ms.shape[0]
    ub = np.empty(F)
    lb = np.full(F, np.nan)
    ds = np.empty((F, st.nb))
    rng = np.random.default_rng(0)
    if peak_only and st.nb > 1:
        X = _osborne_batch(Ms, st)
        ub[:] = _scaled_sigma_max(Ms, st, X)
        ds[:] = np.exp(X)
        if lower:
            square = all(r == c for r, c in bl)
            lb[:] = np.max(np.abs(np.linalg.eigvals(Ms)), axis=1) if square else 0.0
        best = -math.inf if floor is None else float(floor)
        for k in np.argsort(-ub, kind="stable"):
            if ub[k] <= best:
                break
            u, x = _mu_ub_one(Ms[k], st, X[k], stop_below=best if math.isfinite(best) else None)
            if u < ub[k]:
                ub[k], ds[k] = u, np.exp(x)
            best = max(best, ub[k])
            if lower:
                lb[k] = min(max(lb[k], _mu_lb_one(Ms[k], st, np.log(ds[k]), ub[k], rng=rng)), ub[k])
        return MuBounds(upper=ub, lower=lb, d_scales=ds, blocks=bl)
    x_prev = None
    for k in range(F):
        ub[k], x = _mu_ub_one(Ms[k], st, x_prev)
        x_prev = x
        ds[k] = np.exp(x)
        if lower:
            lb[k] = min(_mu_lb_one(Ms[k], st, x, ub[k], rng=rng), ub[k])
    return MuBounds(upper=ub, lower=lb, d_scales=ds, blocks=bl)


def mu_lower_bound(M, blocks) -> np.ndarray:
    """Lower bound of the structured singular value (see :func:`mu_upper_bound`).

    Returns
    -------
    ndarray, shape (F,)
    """
    return mu_upper_bound(M, blocks, lower=True).lower.copy()


# the mixed bound's names, from nanosim.design.mixed_mu (imported on first use: it builds on this module)
_MIXED = ("MixedMuBounds", "mixed_mu_upper_bound", "SCREEN_LEVELS", "SCREEN_MAXITER", "LEVELS", "MAXITER",
          "ACCURATE_LEVELS", "ACCURATE_MAXITER")


def __getattr__(name):
    if name in _MIXED:
        from nanosim.design import mixed_mu
        return getattr(mixed_mu, name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
