"""Upper bounds of the mixed real / complex structured singular value (D-G scalings), one per frequency.

:func:`mixed_mu_upper_bound` handles structures of scalar blocks, independent or repeated, each real
or complex (real parameters such as a modal frequency; complex ones such as a delay disk), with the
D-G scalings of Fan, Tits & Doyle (IEEE TAC 36(1), 1991), used by :mod:`~nanosim.design.parametric`.
The complex bounds it starts from are those of :mod:`~nanosim.design.mu` (which re-exports this
module's names).
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import scipy.optimize

from nanosim.design.mu import _check_M, _mu_ub_one, _osborne_batch, _scaled_sigma_max, _Structure

__all__ = ["MixedMuBounds", "mixed_mu_upper_bound", "SCREEN_LEVELS", "SCREEN_MAXITER", "LEVELS", "MAXITER",
           "ACCURATE_LEVELS", "ACCURATE_MAXITER"]


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
