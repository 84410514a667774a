"""Structured singular value (mu) bounds of complex matrices, one per frequency.

Blocks follow MATLAB's ``mussv`` convention: block ``(r, c)`` is a complex full
``Delta_i`` of size ``r x c``; ``M`` is ``(sum c) x (sum r)``; ``(1, 1)`` is a complex
scalar.  Repeated scalar blocks are not supported.  Used by the multiloop disk margins
(:mod:`~nanosim.design.margins`) and the robust-stability test over the stage's
uncertainty set (:mod:`~nanosim.design.uncertainty`).

:func:`mixed_mu_upper_bound` handles structures of scalar blocks, independent or
repeated, each real or complex (real parameters such as a modal frequency; complex ones
such as a delay disk), with the D-G scalings of Fan, Tits & Doyle (IEEE TAC 36(1), 1991), used by
:mod:`~nanosim.design.parametric`.
"""
from __future__ import annotations

import math
import numbers
from dataclasses import dataclass

import numpy as np
import scipy.linalg
import scipy.optimize

from nanosim.design.loopargs import describe

__all__ = ["MuBounds", "MixedMuBounds", "mu_upper_bound", "mu_lower_bound", "mixed_mu_upper_bound"]


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


# =====================================================================================
# mixed real / complex scalar structures (D-G scalings)
# =====================================================================================
@dataclass(frozen=True, eq=False)
class MixedMuBounds:
    """Upper bounds of the mixed structured singular value, one per frequency.

    Attributes
    ----------
    upper : ndarray, shape (F,)
        ``sqrt(max(0, lambda_max(Mt^H Mt + j (Gt Mt - Mt^H Gt))))`` at the returned scalings,
        ``Mt = D M D^-1`` (a valid upper bound whatever the optimiser did).
    complex_upper : ndarray, shape (F,)
        Every entry an independent complex scalar (Osborne-balanced ``D``, ``G = 0``); ``upper <= complex_upper``.
    real : ndarray of bool, shape (n,)
    optimized : ndarray of bool, shape (F,)
        Where the D-G optimisation ran (elsewhere ``upper`` is the complex bound).
    """

    upper: np.ndarray
    complex_upper: np.ndarray
    real: np.ndarray
    optimized: np.ndarray

    def __post_init__(self):
        for name in ("upper", "complex_upper", "real", "optimized"):
            getattr(self, name).setflags(write=False)


# soft-maximum sharpness and iterations (screening pass, full pass); on the stage's 35-parameter
# problems the full pass agrees with (8, 64, 512) x 200 iterations to 1e-3 at a quarter of the time
SCREEN_LEVELS = (32.0,)
SCREEN_MAXITER = 30
LEVELS = (16.0, 256.0)
MAXITER = 100
# without peak screening (every frequency optimised): the slower, tighter setting
ACCURATE_LEVELS = (8.0, 64.0, 512.0)
ACCURATE_MAXITER = 200


class _DGStructure:
    """Scalings of a structure of (possibly repeated) scalar blocks: ``T`` block diagonal
    (``exp(y)`` on a 1 x 1 block, a full complex matrix on a repeated block) and ``Gt``
    Hermitian block diagonal on the real blocks; ``theta`` packs them (scalar ``y``,
    then ``Re T, Im T`` of repeated blocks, then scalar ``g``, then ``X, Y`` of repeated real
    blocks with ``Gt_b = (X + X^T)/2 + j (Y - Y^T)/2``).
    """

    def __init__(self, real: np.ndarray, groups: np.ndarray):
        self.n = real.size
        self.real = real
        labels = list(dict.fromkeys(groups.tolist()))
        self.blocks = [np.flatnonzero(groups == g) for g in labels]
        self.real_block = [bool(real[b[0]]) for b in self.blocks]
        self.sc = np.array([b[0] for b in self.blocks if b.size == 1], dtype=int)
        self.rep = [b for b in self.blocks if b.size > 1]
        self.sc_real = np.array([b[0] for b, r in zip(self.blocks, self.real_block) if b.size == 1 and r], dtype=int)
        self.rep_real = [b for b, r in zip(self.blocks, self.real_block) if b.size > 1 and r]
        # index grids of the repeated blocks, built once (np.ix_ per call dominated the optimiser's overhead)
        self.rep_ix = [np.ix_(b, b) for b in self.rep]
        self.rep_real_ix = [np.ix_(b, b) for b in self.rep_real]
        self.n_theta = (len(self.sc) + sum(2 * b.size ** 2 for b in self.rep) + len(self.sc_real)
                        + sum(2 * b.size ** 2 for b in self.rep_real))

    def start(self, y0: np.ndarray) -> np.ndarray:
        return self.embed(y0, np.zeros(self.n))

    def embed(self, y: np.ndarray, g: np.ndarray) -> np.ndarray:
        """``theta`` of the diagonal scalings ``T = diag(exp(y))``, ``Gt = diag(g)``."""
        th = [y[self.sc]]
        for b in self.rep:
            th += [np.diag(np.exp(y[b])).ravel(), np.zeros(b.size ** 2)]
        th.append(g[self.sc_real])
        for b in self.rep_real:
            th += [np.diag(g[b]).ravel(), np.zeros(b.size ** 2)]
        return np.concatenate(th)

    def unpack(self, th):
        n = self.n
        T = np.zeros((n, n), complex)
        Ti = np.zeros((n, n), complex)
        G = np.zeros((n, n), complex)
        k = len(self.sc)
        y = th[:k]
        T[self.sc, self.sc] = np.exp(y)
        Ti[self.sc, self.sc] = np.exp(-y)
        for b, ix in zip(self.rep, self.rep_ix):
            r2 = b.size ** 2
            Tb = (th[k:k + r2] + 1j * th[k + r2:k + 2 * r2]).reshape(b.size, b.size)
            k += 2 * r2
            T[ix] = Tb
            Ti[ix] = np.linalg.inv(Tb)
        G[self.sc_real, self.sc_real] = th[k:k + len(self.sc_real)]
        k += len(self.sc_real)
        for b, ix in zip(self.rep_real, self.rep_real_ix):
            r2 = b.size ** 2
            X = th[k:k + r2].reshape(b.size, b.size)
            Y = th[k + r2:k + 2 * r2].reshape(b.size, b.size)
            k += 2 * r2
            G[ix] = 0.5 * (X + X.T) + 0.5j * (Y - Y.T)
        return T, Ti, G

    def hermitian(self, M, th):
        T, Ti, G = self.unpack(th)
        Mt = T @ M @ Ti
        GM = G @ Mt
        return Mt, T, Ti, G, Mt.conj().T @ Mt + 1j * (GM - GM.conj().T)

    def value(self, M, th) -> float:
        if not np.all(np.isfinite(th)):
            return math.inf
        try:
            H = self.hermitian(M, th)[-1]
            lam = np.linalg.eigvalsh(H)[-1]
        except np.linalg.LinAlgError:
            return math.inf
        return math.sqrt(max(float(lam), 0.0)) if np.isfinite(lam) else math.inf

    def gradient(self, Mt, T, Ti, G, V, w):
        """Gradient of ``sum_k w_k lambda_k`` (eigenvectors ``V``) with respect to ``theta``."""
        A = Mt @ V
        Cm = A - 1j * (G @ V)
        E = Mt.conj().T @ Cm
        P = Ti @ A
        U = Ti @ V
        GT = (Cm.conj() * w) @ P.T - (E.conj() * w) @ U.T           # d/dT (complex), n x n
        GG = (V.conj() * w) @ A.T                                    # d/dGt
        out = [2.0 * np.real(np.diag(GT)[self.sc] * np.diag(T)[self.sc])]
        for ix in self.rep_ix:
            g = GT[ix]
            out += [2.0 * np.real(g).ravel(), -2.0 * np.imag(g).ravel()]
        out.append(-2.0 * np.imag(np.diag(GG)[self.sc_real]))
        for ix in self.rep_real_ix:
            g = GG[ix]
            out += [-np.imag(g + g.T).ravel(), -np.real(g - g.T).ravel()]
        return np.concatenate(out)


def _mixed_ub_one(M, st: _DGStructure, y0: np.ndarray, top: int = 6, levels=None, maxiter=None, th0=None):
    """D-G upper bound at one frequency from the complex scales ``y0`` (``log d``), or from
    ``th0`` (scalings of a neighbouring frequency) when that is better.
    """
    levels = LEVELS if levels is None else levels
    maxiter = MAXITER if maxiter is None else maxiter

    def f_and_g(th, p, scale):
        try:
            Mt, T, Ti, G, H = st.hermitian(M, th)
            lam, V = np.linalg.eigh(H)
        except np.linalg.LinAlgError:
            return 1e300, np.zeros_like(th)
        lam, V = lam[::-1][:top], V[:, ::-1][:, :top]
        w = np.exp(p * (lam - lam[0]) / scale)
        Z = w.sum()
        w /= Z
        return lam[0] + scale * math.log(Z) / p, st.gradient(Mt, T, Ti, G, V, w)

    y0 = np.clip(y0 - y0[-1], -30, 30)
    th = st.start(y0)
    if th0 is not None and st.value(M, th0) < st.value(M, th):
        th = th0
    elif st.rep:
        # independent scalars first (fewer unknowns), then the full blocks from there
        ind = _DGStructure(st.real, np.arange(st.n))
        _, th_ind = _mixed_ub_one(M, ind, y0, top, levels, maxiter)
        th = st.embed(th_ind[:st.n], ind.unpack(th_ind)[2].diagonal().real)
    best = (st.value(M, th), th)
    bounds = [(-30.0, 30.0)] * len(st.sc) + [(None, None)] * (st.n_theta - len(st.sc))
    for p in levels:
        scale = max(best[0] ** 2, 1e-12)
        with np.errstate(over="ignore", invalid="ignore"):
            res = scipy.optimize.minimize(f_and_g, best[1], args=(p, scale), jac=True, method="L-BFGS-B",
                                          bounds=bounds, options={"maxiter": maxiter, "ftol": 1e-12, "gtol": 1e-10})
        v = st.value(M, res.x)
        if v < best[0]:
            best = (v, res.x)
        if best[0] == 0.0:
            break
    return best[0], best[1]


def _check_real(real, n: int) -> np.ndarray:
    r = np.asarray(real)
    if r.dtype != bool or r.shape != (n,):
        raise ValueError(f"real: expected {n} booleans (one per scalar block, True = real parameter), "
                         f"got {r.dtype} of shape {r.shape}")
    return r.copy()


def mixed_mu_upper_bound(M, real, *, groups=None, peak_only: bool = False, floor=None) -> MixedMuBounds:
    """Upper bound of the mixed structured singular value for scalar blocks (independent or repeated).

    ``Delta = diag(delta_1 ... delta_n)`` with ``delta_i`` real where ``real[i]`` and
    complex elsewhere.  With ``D = diag(d) > 0`` and real diagonal ``G`` (zero on the
    complex blocks), ``mu(M) <= beta`` whenever
    ``M^H D M + j (G M - M^H G) - beta^2 D <= 0`` (Fan, Tits & Doyle 1991; Skogestad &
    Postlethwaite, 2nd ed., Sec. 8.10).  With ``Mt = D^1/2 M D^-1/2`` and
    ``Gt = G D^-1`` this is ``beta^2 >= lambda_max(Mt^H Mt + j (Gt Mt - Mt^H Gt))``
    (for a repeated block ``Mt = T M T^-1`` with ``D = T^H T`` and ``Gt = T^-H G T^-1``); the
    scalings are optimised by L-BFGS-B on a soft maximum of the top eigenvalues,
    started from the complex D-scaling bound (:func:`mu_upper_bound`), and the value
    returned is the exact eigenvalue at the final scalings.

    Parameters
    ----------
    M : array_like, complex, shape (F, n, n) or (n, n)
    real : array_like of bool, shape (n,)
    groups : array_like of int, shape (n,), optional
        Entries with the same label form one *repeated* scalar block ``delta I``
        (same kind; full ``D`` and ``G`` blocks there).  Default: every entry its own block.
    peak_only : bool
        Screen for the peak: a short optimisation with every entry an independent scalar
        (a larger set, so a valid bound) at each frequency whose complex bound exceeds
        ``floor``, each started from its neighbour's scalings; then the full structure in
        decreasing order of that screen until it falls below the largest bound found.
        Elsewhere ``upper`` is the screen's value (valid, and below the peak).  Without
        it every frequency gets the full, slower optimisation.
    floor : float or None
        With ``peak_only``: a value the peak is known to reach.

    Returns
    -------
    MixedMuBounds
    """
    Ms = _check_M(M, [(1, 1)] * (np.shape(M)[-1] if np.ndim(M) >= 2 else 1))
    n = Ms.shape[1]
    real = _check_real(real, n)
    grp = np.arange(n) if groups is None else np.asarray(groups)
    if grp.shape != (n,) or grp.dtype.kind not in "iu":
        raise ValueError(f"groups: expected {n} integer labels, got {grp.dtype} of shape {grp.shape}")
    for g in np.unique(grp):
        if np.unique(real[grp == g]).size > 1:
            raise ValueError(f"groups: block {g} mixes real and complex entries")
    st = _Structure(tuple((1, 1) for _ in range(n)))
    dg = _DGStructure(real, grp)
    F = Ms.shape[0]
    X = _osborne_batch(Ms, st) if n > 1 else np.zeros((F, 1))
    cub = _scaled_sigma_max(Ms, st, X)
    ub = cub.copy()
    done = np.zeros(F, bool)
    if not real.any() and groups is None:
        for k in range(F):
            ub[k], _ = _mu_ub_one(Ms[k], st, X[k])
            done[k] = True
        return MixedMuBounds(ub, ub.copy(), real, done)
    if peak_only:
        # screening: independent scalars (a larger set, so valid bounds), each frequency started
        # from its neighbour's scalings; then the full structure where the screen exceeds the peak
        ind = _DGStructure(real, np.arange(n))
        keep = np.flatnonzero(cub > (-math.inf if floor is None else float(floor)))
        th_prev, k_prev = None, -2
        for k in keep:
            u, th_prev = _mixed_ub_one(Ms[k], ind, X[k], levels=SCREEN_LEVELS, maxiter=SCREEN_MAXITER,
                                       th0=th_prev if k == k_prev + 1 else None)
            ub[k], k_prev = min(ub[k], u), k
        if not dg.rep:
            done[keep] = True
            return MixedMuBounds(ub, cub, real, done)
        best = -math.inf if floor is None else float(floor)
        for k in sorted(keep, key=lambda i: -ub[i]):
            if ub[k] <= best:
                break
            u, _ = _mixed_ub_one(Ms[k], dg, X[k])
            ub[k] = min(ub[k], u)
            done[k] = True
            best = max(best, ub[k])
        return MixedMuBounds(ub, cub, real, done)
    for k in range(F):
        ub[k] = min(ub[k], _mixed_ub_one(Ms[k], dg, X[k], levels=ACCURATE_LEVELS, maxiter=ACCURATE_MAXITER)[0])
        done[k] = True
    return MixedMuBounds(ub, cub, real, done)
