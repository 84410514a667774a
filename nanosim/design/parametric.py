"""Robust stability over the stage's *parametric* uncertainty set by mixed (real/complex) mu.

:func:`~nanosim.design.uncertainty.robust_stability_mu` covers the modal-frequency
uncertainty by one unstructured complex output block; a +-3 % shift of a mode damped at
``zeta ~ 0.003`` then weighs ~20 at resonance, and every loop that damps the mode gets a
mu bound far above 1.  Here the same set (:class:`~nanosim.design.uncertainty.UncertaintySet`)
is written as a linear fractional transformation (LFT) with *real* parameters, so that
``mu < 1`` certifies stability for every plant of the set (Skogestad & Postlethwaite,
2nd ed., Sec. 7.4 and 8.10; Fan, Tits & Doyle, IEEE TAC 1991):

Modes (real scalars, two per perturbed eigenvalue)
    Each eigenvalue ``lambda = exp(s dt)`` that the set perturbs
    (:meth:`~nanosim.design.uncertainty.ModalPlant.mode_kind`) moves, over the box
    ``freq_scale x damping_scale``, within an annular sector of radius
    ``exp(sigma' dt)`` and angle ``omega_d' dt`` (``sigma' = -zeta' w_n'``,
    ``omega_d' = w_n' sqrt(1 - zeta'^2)``, extremes at the corners of the box).  That
    sector is covered exactly by ``lambda' = lambda_c (m + a delta_r + j b delta_t)``,
    ``delta_r, delta_t in [-1, 1]`` (radial and tangential), with ``lambda_c`` at the
    sector's centre angle and radius.  The residue scales with ``(1 - lambda') / (1 -
    lambda)`` as in :func:`~nanosim.design.uncertainty.perturbed_plant` (each mode keeps
    its static gain), which keeps the LFT exact:
    ``x+ = lambda0 x + b0 u + (lambda' - lambda0) (x - q u)``, ``q = b / (1 - lambda)``.
    A real pole gets one real parameter on ``exp(s freq_scale dt)``.  Each physical mode
    has its own two parameters, shared (repeated) by both members of its pair and by its
    per-column copies (:func:`parametric_lft`); distinct modes move independently (a
    superset of the common scaling of the sampled check: conservative there, never
    optimistic).
Piezo gain (real scalar per input)
    ``c (1 + r delta_g)``, ``c`` the centre and ``r`` the relative radius of the range.
Computation delay (complex scalar, repeated over the inputs)
    ``z^-d`` for ``d`` in ``{d_lo, d_hi}`` (``d_hi - d_lo <= 1``) lies on the disk of
    centre ``(z^-d_lo + z^-d_hi) / 2`` and radius ``|z^-d_lo - z^-d_hi| / 2``.
    :func:`robust_stability_mixed_mu` does not use the disk: it analyses each integer
    delay exactly, one LFT per delay.

The centre loop (every ``delta = 0``) must be stable (checked in state space); then
``mu(M(e^{j w dt})) < 1`` at every frequency proves robust stability.  The frequency
grid is the caller's plus a dense grid over each mode's shifted band.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import control as ct
import numpy as np
import scipy.linalg

from nanosim.design.loopargs import check_freq, check_int, check_range, describe, is_lti
from nanosim.design.loopresponse import (
    closed_loop_matrix,
    feedback_operator_ss,
    frequency_response,
    stability,
    to_state_space,
)
from nanosim.design.margins import refine_mu_peak
from nanosim.design.mixed_mu import mixed_mu_upper_bound
from nanosim.design.uncertainty import STAGE_MU_RANGES as _STAGE_RANGES
from nanosim.design.uncertainty import ModalPlant

SAME_MODE_REL = 0.003

__all__ = ["SAME_MODE_REL", "ModalMerge", "merge_modes", "ParametricLFT", "MixedRobustStabilityResult",
           "parametric_lft", "mode_band_grid", "robust_stability_mixed_mu"]


@dataclass(frozen=True, eq=False)
class ParametricLFT:
    """Frequency-domain LFT of a discrete plant with the stage's parametric uncertainty.

    ``P(z)`` maps ``[w; u_c]`` to ``[z; y]`` (``w = Delta z``); :meth:`closed` closes
    ``u_c = -Kfb y`` and returns ``M`` (the map ``w -> z``).

    Attributes
    ----------
    real : ndarray of bool, shape (n_delta,)
        Kind of each scalar parameter (modes and gains real, delays complex).
    groups : ndarray of int, shape (n_delta,)
        Entries with one label are one repeated parameter: the copies of one physical
        mode (see :func:`parametric_lft`) and the delay of every input.
    labels : tuple of str
        What each parameter is, e.g. ``"mode 175.5 Hz radial"``.
    centre : control.StateSpace
        The plant at ``Delta = 0`` (centre modes, centre gains, centre delay FIR).
    mode_bands_hz : tuple of (float, float)
        Frequency band each perturbed pair can move over [Hz].
    dt : float
    """

    real: np.ndarray
    groups: np.ndarray
    labels: tuple
    centre: ct.StateSpace
    mode_bands_hz: tuple
    dt: float
    _data: dict

    def blocks(self, freq_hz: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """``(P11, P12, P21, P22)`` on ``freq_hz`` [Hz], each ``(F, rows, cols)``."""
        d = self._data
        f = np.asarray(freq_hz, dtype=float)
        zf = np.exp(2j * np.pi * f * self.dt)
        F, nu, ny = f.size, d["nu"], d["ny"]
        nm, nw = d["lam0"].size, d["owner"].size
        nd = self.real.size
        c, r = d["gain_c"], d["gain_r"]
        dlo, dhi = d["delay"]
        cd = 0.5 * (zf ** -dlo + zf ** -dhi)                       # (F,)
        rd = 0.5 * np.abs(zf ** -dlo - zf ** -dhi)
        inv = 1.0 / (zf[:, None] - d["lam0"][None, :])             # (F, nm)
        Xu = inv[:, :, None] * d["b0"][None]                       # (F, nm, nu): x per u_p
        Xw = np.zeros((F, nm, nw), complex)                        # x per w_m
        Xw[:, d["owner"], np.arange(nw)] = inv[:, d["owner"]] * d["coef"][None, :]
        Grest = d["rest"](f)                                       # (F, ny, nu)
        Gc = np.einsum("ym,fmu->fyu", d["Cm"], Xu) + Grest         # centre plant
        SXuQ = Xu[:, d["owner"], :] - d["q"][d["owner"]][None]     # (F, nw, nu): z_m per u_p
        SXw = Xw[:, d["owner"], :]                                 # (F, nw, nw)
        Eu = (cd * c)[:, None, None] * np.eye(nu)[None]
        Ewg = (cd * c * r)[:, None, None] * np.eye(nu)[None]
        Ewd = rd[:, None, None] * np.eye(nu)[None]
        P11 = np.zeros((F, nd, nd), complex)
        P12 = np.zeros((F, nd, nu), complex)
        P21 = np.zeros((F, ny, nd), complex)
        im, ig, idl = slice(0, nw), slice(nw, nw + nu), slice(nw + nu, nw + 2 * nu)
        P11[:, im, im] = SXw
        P11[:, im, ig] = SXuQ @ Ewg
        P12[:, im, :] = SXuQ @ Eu
        P12[:, ig, :] = np.eye(nu)[None]
        P21[:, :, im] = np.einsum("ym,fmw->fyw", d["Cm"], Xw)
        P21[:, :, ig] = Gc @ Ewg
        if dhi > dlo:
            P11[:, im, idl] = SXuQ @ Ewd
            P11[:, idl, ig] = c * r * np.eye(nu)[None]
            P12[:, idl, :] = c * np.eye(nu)[None]
            P21[:, :, idl] = Gc @ Ewd
        P22 = Gc @ Eu
        return P11, P12, P21, P22

    def delta_at(self, freq_scale: float, damping_scale: float, input_gain: float, delay_samples: int,
                 freq_hz) -> np.ndarray:
        """Parameters ``(F, n_delta)`` that give the member of
        :func:`~nanosim.design.uncertainty.perturbed_plant` with these factors (exactly;
        inside the unit box when the factors are inside the set).  The delay parameter
        depends on frequency, the others do not.
        """
        d = self._data
        f = np.asarray(freq_hz, dtype=float)
        lam_new, _ = d["modal"].poles(float(freq_scale), float(damping_scale))
        lam_new = lam_new[d["pert"]]
        n_delay = d["nu"] if d["delay"][1] > d["delay"][0] else 0
        out = np.empty(self.real.size - n_delay, complex)
        nw = d["owner"].size
        for j in range(lam_new.size):
            idx = np.flatnonzero(d["owner"] == j)
            rhs = lam_new[j] - d["lam0"][j]
            if idx.size == 2:
                c0, c1 = d["coef"][idx]
                out[idx] = np.linalg.solve([[c0.real, c1.real], [c0.imag, c1.imag]], [rhs.real, rhs.imag])
            else:
                out[idx] = rhs.real / d["coef"][idx[0]].real if d["coef"][idx[0]] != 0 else 0.0
        g = (float(input_gain) - d["gain_c"]) / (d["gain_c"] * d["gain_r"]) if d["gain_r"] else 0.0
        out[nw:] = g
        if not n_delay:
            return np.broadcast_to(out.real, (f.size, out.size)).astype(complex)
        zf = np.exp(2j * np.pi * f * self.dt)
        dlo, dhi = d["delay"]
        cd = 0.5 * (zf ** -dlo + zf ** -dhi)
        rd = 0.5 * np.abs(zf ** -dlo - zf ** -dhi)
        with np.errstate(divide="ignore", invalid="ignore"):
            dd = np.where(rd > 0, (zf ** -int(delay_samples) - cd) / np.where(rd > 0, rd, 1.0), 0.0)
        return np.concatenate([np.broadcast_to(out.real, (f.size, out.size)).astype(complex),
                               np.repeat(dd[:, None], d["nu"], axis=1)], axis=1)

    def plant_response(self, delta: np.ndarray, freq_hz) -> np.ndarray:
        """The plant ``P22 + P21 Delta (I - P11 Delta)^-1 P12`` for parameters ``delta``
        ``(F, n_delta)`` on ``freq_hz`` [Hz], ``(F, ny, nu)``.
        """
        P11, P12, P21, P22 = self.blocks(freq_hz)
        Dl = np.asarray(delta, complex)[:, :, None] * np.eye(self.real.size)[None]
        return P22 + P21 @ Dl @ np.linalg.solve(np.eye(self.real.size)[None] - P11 @ Dl, P12)

    def closed(self, Kfb_f: np.ndarray, freq_hz: np.ndarray) -> np.ndarray:
        """``M = P11 - P12 Kfb (I + P22 Kfb)^-1 P21`` (``u_c = -Kfb y``), ``(F, n, n)``."""
        P11, P12, P21, P22 = self.blocks(freq_hz)
        ny = P22.shape[1]
        X = np.linalg.solve(np.eye(ny)[None] + P22 @ Kfb_f, P21)
        return P11 - P12 @ Kfb_f @ X


@dataclass(frozen=True, eq=False)
class ModalMerge:
    """A plant with each physical mode once (:func:`merge_modes`).

    Attributes
    ----------
    G : control.StateSpace
        The merged plant (real modal realization, same sample time).
    n_merged : int
        Eigenvalues removed by merging.
    residue_rank_ratio : float
        Largest ``sigma_2 / sigma_1`` of a merged mode's summed residue (what the
        rank-one residue drops).
    error_rel : float
        ``max_f sigma_max(G - G_merged) / max_f sigma_max(G)`` on the check grid.
    """

    G: ct.StateSpace
    n_merged: int
    residue_rank_ratio: float
    error_rel: float


def merge_modes(G, freq_hz=None) -> ModalMerge:
    """Each physical mode of an identified model once, with a rank-one residue.

    ``nanosim identify`` stacks one model per input column, so each structural mode
    appears once per column (eigenvalues within a few 0.01 %).  Eigenvalues within
    :data:`SAME_MODE_REL` of each other (same sign of the imaginary part) are merged:
    the mean eigenvalue, and the rank-one part ``sigma_1 u v^H`` of their summed
    residue ``sum_i c_i b_i^T`` (a mode of a structure drives and is seen through one
    mode shape).  Other eigenvalues stay.  The result is what the stage's modal
    uncertainty acts on (one frequency and one damping per mode) and is much smaller.

    Parameters
    ----------
    G : control.StateSpace
        Discrete, diagonalisable.
    freq_hz : array_like or None
        Grid [Hz] for ``error_rel`` (default 400 points from 1 Hz to Nyquist).

    Returns
    -------
    ModalMerge
    """
    if not is_lti(G) or not (G.dt not in (None, 0, True) and G.dt > 0):
        raise ValueError(f"G: expected a discrete control.StateSpace, got {describe(G)}")
    dt = float(G.dt)
    mp = ModalPlant(G, dt)
    kind = mp.mode_kind()
    lam, CV, VB = mp.lam, mp.CV, mp.VinvB
    used = np.zeros(lam.size, bool)
    modes: list[tuple[complex, np.ndarray, np.ndarray]] = []     # (lambda, c, b) with Im lambda >= 0
    ratio, merged = 0.0, 0
    for k in np.argsort(np.abs(mp.s)):
        if used[k] or lam[k].imag < 0 or (kind[k] == 1 and mp.s[k].imag < 0):
            continue
        if kind[k] == 1:
            grp = [j for j in range(lam.size) if kind[j] == 1 and not used[j] and mp.s[j].imag > 0
                   and abs(abs(mp.s[j]) - abs(mp.s[k])) <= SAME_MODE_REL * abs(mp.s[k])]
            R = sum(np.outer(CV[:, j], VB[j]) for j in grp)
            U, sv, Vh = np.linalg.svd(R)
            if len(grp) > 1:
                ratio = max(ratio, float(sv[1] / sv[0]))
                merged += 2 * (len(grp) - 1)
            modes.append((complex(np.mean(lam[grp])), U[:, 0] * math.sqrt(sv[0]), Vh[0] * math.sqrt(sv[0])))
            used[grp] = True
        else:
            modes.append((complex(lam[k]), CV[:, k], VB[k]))
            used[k] = True
    # conjugate partners of non-structural complex poles are covered by the pairs above
    blocks_A, blocks_B, blocks_C = [], [], []
    for lk, c, b in modes:
        if abs(lk.imag) > 1e-12 * max(1.0, abs(lk)):
            blocks_A.append(np.array([[lk.real, -lk.imag], [lk.imag, lk.real]]))
            blocks_B.append(np.vstack([b.real, b.imag]))
            blocks_C.append(np.column_stack([2 * c.real, -2 * c.imag]))
        else:
            blocks_A.append(np.array([[lk.real]]))
            blocks_B.append(np.real(b)[None, :])
            blocks_C.append(np.real(c)[:, None])
    A = scipy.linalg.block_diag(*blocks_A) if blocks_A else np.zeros((0, 0))
    B = np.vstack(blocks_B) if blocks_B else np.zeros((0, mp.nu))
    C = np.hstack(blocks_C) if blocks_C else np.zeros((mp.C.shape[0], 0))
    Gm = ct.ss(A, B, C, mp.D, dt)
    f = np.geomspace(1.0, 0.5 / dt, 400) if freq_hz is None else np.asarray(freq_hz, float)
    G0 = frequency_response(G, f)
    E = frequency_response(Gm, f) - G0
    err = float(np.max(np.linalg.svd(E, compute_uv=False)[:, 0]) / np.max(np.linalg.svd(G0, compute_uv=False)[:, 0]))
    return ModalMerge(G=Gm, n_merged=int(merged), residue_rank_ratio=ratio, error_rel=err)


def _sector(s: complex, fr: tuple, zr: tuple, dt: float):
    """``(lambda_c, m, a, b)`` covering ``exp(s' dt)`` over the frequency x damping box."""
    wn = abs(s)
    zeta = -s.real / wn
    sig, om = [], []
    for fs in fr:
        for zs in zr:
            z2 = zeta * zs
            if z2 >= 1:
                raise ValueError(f"damping_scale_range: a mode with zeta {zeta:.3g} becomes overdamped at "
                                 f"x{zs}; expected zeta x damping_scale < 1")
            sig.append(-z2 * wn * fs)
            om.append(wn * fs * math.sqrt(1 - z2 * z2))
    Rlo, Rhi = math.exp(min(sig) * dt), math.exp(max(sig) * dt)
    phic = 0.5 * (min(om) + max(om)) * dt
    phim = 0.5 * (max(om) - min(om)) * dt
    sign = 1.0 if s.imag > 0 else -1.0
    lam_c = np.exp(1j * sign * phic)
    m = 0.5 * (Rhi + Rlo * math.cos(phim))
    a = 0.5 * (Rhi - Rlo * math.cos(phim))
    b = Rhi * math.sin(phim)
    return lam_c, m, a, sign * b, (min(om) / (2 * math.pi), max(om) / (2 * math.pi))


def parametric_lft(G, *, input_gain_range=_STAGE_RANGES["input_gain_range"],
                   freq_scale_range=_STAGE_RANGES["freq_scale_range"],
                   damping_scale_range=_STAGE_RANGES["damping_scale_range"],
                   delay_samples_range=_STAGE_RANGES["delay_samples_range"]) -> ParametricLFT:
    """The LFT of the module docstring for a discrete plant ``G`` (``ny x nu``).

    Parameters
    ----------
    G : control.StateSpace or TransferFunction
        Discrete, diagonalisable plant (the identified model: the loop as run).
    input_gain_range, freq_scale_range, damping_scale_range : (float, float)
        Factors on nominal, as in :class:`~nanosim.design.uncertainty.UncertaintySet`.
    delay_samples_range : (int, int)
        Absolute input delays [samples], ``d_hi - d_lo <= 1``.

    Returns
    -------
    ParametricLFT

    Notes
    -----
    An identified model holds each physical mode once per identified column (three
    eigenvalues within a few 0.01 % of each other).  Eigenvalues whose natural
    frequencies lie within :data:`SAME_MODE_REL` of each other, both members of each
    pair included, are one physical mode: their radial parameters are one repeated real
    parameter, and so are their tangential ones.  Distinct modes of the stage are
    at least 1.5 % apart (the XY split), and each moves on its own.
    """
    if not is_lti(G):
        raise TypeError(f"G: expected a discrete control.StateSpace or TransferFunction, got {describe(G)}")
    if not (G.dt not in (None, 0, True) and G.dt > 0):
        raise ValueError(f"G: expected a discrete system with a sample time [s], got dt={G.dt!r}")
    dt = float(G.dt)
    glo, ghi = check_range("input_gain_range", input_gain_range)
    fr = check_range("freq_scale_range", freq_scale_range)
    zr = check_range("damping_scale_range", damping_scale_range)
    dlo, dhi = check_range("delay_samples_range", delay_samples_range, positive=False, integer=True)
    if dhi - dlo > 1:
        raise ValueError(f"delay_samples_range: expected at most one sample between the ends (the disk covers "
                         f"two delays), got {delay_samples_range!r}")
    mp = ModalPlant(G, dt)
    kind = mp.mode_kind()
    pert = np.flatnonzero(kind > 0)
    rest = np.flatnonzero(kind == 0)
    lam0, b0, q, coef, owner, labels, bands, groups = [], [], [], [], [], [], [], []
    clusters: list[tuple[float, int]] = []                 # (w_n, label) of each physical mode
    for j, k in enumerate(pert):
        lam, s, bk = mp.lam[k], mp.s[k], mp.VinvB[k]
        if kind[k] == 1:
            lab = next((c[1] for c in clusters if abs(abs(s) - c[0]) <= SAME_MODE_REL * c[0]), None)
            if lab is None:
                lab = 2 * len(clusters)
                clusters.append((abs(s), lab))
            groups += [lab, lab + 1]
            lam_c, m, a, b, band = _sector(s, fr, zr, dt)
            l0 = lam_c * m
            coef += [lam_c * a, 1j * lam_c * b]
            owner += [j, j]
            fhz = abs(s) / (2 * math.pi)
            labels += [f"mode {fhz:.1f} Hz radial", f"mode {fhz:.1f} Hz tangential"]
            if s.imag > 0 and lab // 2 not in [b[2] for b in bands]:
                bands.append((band[0], band[1], lab // 2))
        else:
            e = [math.exp(s.real * fs * dt) for fs in fr]
            l0 = 0.5 * (e[0] + e[1])
            coef.append(0.5 * abs(e[1] - e[0]))
            owner.append(j)
            groups.append(-1 - j)
            labels.append(f"real pole {abs(s) / (2 * math.pi):.3g} Hz")
        lam0.append(l0)
        b0.append(bk * (1 - l0) / (1 - lam))
        q.append(bk / (1 - lam))
    nu, ny = mp.nu, mp.C.shape[0]
    lam0 = np.array(lam0, complex)
    b0 = np.array(b0, complex).reshape(len(pert), nu)
    q_arr = np.array(q, complex).reshape(len(pert), nu)
    Cm = mp.CV[:, pert]
    CVr, Br, lr = mp.CV[:, rest], mp.VinvB[rest], mp.lam[rest]

    def rest_response(f):
        zf = np.exp(2j * np.pi * f * dt)
        R = 1.0 / (zf[:, None] - lr[None, :])
        return np.einsum("ym,fm,mu->fyu", CVr, R, Br) + mp.D[None]

    c = 0.5 * (glo + ghi)
    r = (ghi - glo) / (ghi + glo)
    n_delay = nu if dhi > dlo else 0
    labels += [f"piezo gain input {i}" for i in range(nu)] + [f"delay input {i}" for i in range(n_delay)]
    real = np.array([True] * (len(owner) + nu) + [False] * n_delay)
    g_arr = np.array(groups, int)
    base = (g_arr.max() + 1) if g_arr.size else 0
    g_arr = np.where(g_arr < 0, base - g_arr, g_arr)            # real poles: labels of their own
    top = (g_arr.max() + 1) if g_arr.size else 0
    g_arr = np.concatenate([g_arr, top + np.arange(nu), np.full(n_delay, top + nu)])   # gains own, delay repeated
    g_arr.setflags(write=False)
    # centre plant: centre modes, gain c, FIR (z^-dlo + z^-dhi)/2
    lam_all = mp.lam.astype(complex).copy()
    fac = np.ones(lam_all.size, complex)
    lam_all[pert] = lam0
    fac[pert] = (1 - lam0) / (1 - mp.lam[pert])
    An = mp.V @ np.diag(lam_all) @ np.linalg.inv(mp.V)
    Bn = mp.V @ (fac[:, None] * mp.VinvB)
    if np.abs(An.imag).max() > 1e-8 * max(1.0, np.abs(An.real).max()):
        raise ValueError("G: the centre plant is not real (unpaired complex poles?)")
    P = ct.ss(An.real, Bn.real * c, mp.C, mp.D * c, dt)
    P = ct.series(_fir_delay(nu, dlo, dhi, dt), P)
    data = {"nu": nu, "ny": ny, "lam0": lam0, "b0": b0, "q": q_arr, "coef": np.array(coef, complex),
            "owner": np.array(owner, int), "Cm": Cm, "rest": rest_response, "gain_c": c, "gain_r": r,
            "delay": (dlo, dhi), "modal": mp, "pert": pert}
    real.setflags(write=False)
    return ParametricLFT(real=real, groups=g_arr, labels=tuple(labels), centre=ct.ss(P.A, P.B, P.C, P.D, dt),
                         mode_bands_hz=tuple(sorted((b[0], b[1]) for b in bands)), dt=dt, _data=data)


def _fir_delay(n: int, dlo: int, dhi: int, dt: float) -> ct.StateSpace:
    """``(z^-dlo + z^-dhi) / 2`` per channel as a state-space (``dhi`` registers)."""
    if dhi == 0:
        return ct.ss(np.zeros((0, 0)), np.zeros((0, n)), np.zeros((n, 0)), np.eye(n), dt)
    N = dhi * n
    A = np.zeros((N, N))
    A[n:, :-n] = np.eye(N - n)
    B = np.zeros((N, n))
    B[:n] = np.eye(n)
    C = np.zeros((n, N))
    D = np.zeros((n, n))
    for d in (dlo, dhi):
        if d == 0:
            D += 0.5 * np.eye(n)
        else:
            C[:, (d - 1) * n:d * n] += 0.5 * np.eye(n)
    return ct.ss(A, B, C, D, dt)


@dataclass(frozen=True, eq=False)
class MixedRobustStabilityResult:
    """Robust stability over the parametric set by the mixed-mu upper bound.

    Attributes
    ----------
    mu_peak : float
        Peak over frequency of the mixed-mu upper bound (on the grid, or refined between
        grid points with ``refine``), the worst over the set's delays; ``inf`` when a
        centre loop is unstable.
        ``centre_stable and mu_peak < 1`` proves stability for every plant of the set.
    mu_peak_freq_hz : float
    freq_hz, mu_upper, complex_upper : ndarray, shape (F,)
        Grid [Hz], mixed bound and the bound with every parameter taken complex.
    centre_stable : bool
        Every delay's centre loop is stable.
    centre_spectral_radius : float
        The largest over the delays.
    n_parameters : int
        Scalar parameters (real and complex).
    n_real : int
    labels : tuple of str
    merge_error_rel, merge_residue_rank_ratio : float or None
        :class:`ModalMerge` figures of the analysed plant (None: not merged).
    """

    mu_peak: float
    mu_peak_freq_hz: float
    freq_hz: np.ndarray
    mu_upper: np.ndarray
    complex_upper: np.ndarray
    centre_stable: bool
    centre_spectral_radius: float
    n_parameters: int
    n_real: int
    labels: tuple
    merge_error_rel: float | None = None
    merge_residue_rank_ratio: float | None = None

    @property
    def robustly_stable(self) -> bool:
        """``centre_stable and mu_peak < 1`` (a sufficient condition)."""
        return bool(self.centre_stable and self.mu_peak < 1.0)


def mode_band_grid(lft: ParametricLFT, n_per_band: int = 40) -> np.ndarray:
    """Dense grid [Hz] over each perturbed mode's band (+-1 % beyond its ends)."""
    pts = [np.linspace(lo * 0.99, hi * 1.01, n_per_band) for lo, hi in lft.mode_bands_hz]
    return np.concatenate(pts) if pts else np.zeros(0)


def robust_stability_mixed_mu(G_nominal, K, Ky, freq_hz, *, input_gain_range=_STAGE_RANGES["input_gain_range"],
                              freq_scale_range=_STAGE_RANGES["freq_scale_range"],
                              damping_scale_range=_STAGE_RANGES["damping_scale_range"],
                              delay_samples_range=_STAGE_RANGES["delay_samples_range"], n_per_band: int = 24,
                              merge: bool = True, refine: bool = True) -> MixedRobustStabilityResult:
    """Mixed-mu robust stability of ``u = K e + Ky y`` over the parametric set.

    Parameters
    ----------
    G_nominal : control.StateSpace
        Discrete plant (controller V -> sensor V; the loop as run, no delay added).
    K, Ky : discrete controllers ``nu x ny`` (``Ky`` may be None), same sample time.
    freq_hz : array_like
        Base grid [Hz] (<= Nyquist); a dense grid over each mode's band is added.
    input_gain_range, freq_scale_range, damping_scale_range, delay_samples_range
        The set (see :func:`parametric_lft`); delays absolute [samples].
    n_per_band : int
        Points of the dense grid per mode band.
    merge : bool
        Analyse :func:`merge_modes` of ``G_nominal`` (each physical mode once; the
        result states the merge's error).  Without it, every eigenvalue is its own mode.
    refine : bool
        Refine the peak between grid points.

    Returns
    -------
    MixedRobustStabilityResult

    Notes
    -----
    The set's delays are integers, so each delay is analysed on its own (exactly, no
    delay disk) and the worst is reported.  A centre loop (centre gains and modes) that
    is unstable for some delay is a member of the set that is unstable: ``mu_peak`` is
    then ``inf``.
    """
    check_int("n_per_band", n_per_band, 2)
    dlo, dhi = check_range("delay_samples_range", delay_samples_range, positive=False, integer=True)
    mm = merge_modes(G_nominal) if merge else None
    G_nominal = mm.G if merge else G_nominal
    kw = {"input_gain_range": input_gain_range, "freq_scale_range": freq_scale_range,
          "damping_scale_range": damping_scale_range}
    lfts = [parametric_lft(G_nominal, delay_samples_range=(d, d), **kw) for d in range(dlo, dhi + 1)]
    lft = lfts[0]
    dt = lft.dt
    nyq = 0.5 / dt
    f0 = check_freq(freq_hz, "discrete", dt)
    if f0.min() <= 0:
        raise ValueError(f"freq_hz: expected positive frequencies (a controller integrator is infinite at 0 Hz), "
                         f"got min {f0.min()!r}")
    f = np.unique(np.concatenate([f0, mode_band_grid(lft, n_per_band)]))
    f = f[(f > 0) & (f <= nyq)]
    Ks = to_state_space(K, dt, "K")
    Kys = None if Ky is None else to_state_space(Ky, dt, "Ky")
    Kfb = feedback_operator_ss(Ks, Kys, dt)
    Kf = frequency_response(Kfb, f)
    ok, rho = True, 0.0
    pk, fpk = -math.inf, math.nan
    upper, cupper = np.zeros(f.size), np.zeros(f.size)
    for one in lfts:          # one exact delay at a time: the set's delays are integers
        ok1, rho1 = stability(closed_loop_matrix(one.centre, Kfb), True)
        ok, rho = ok and ok1, max(rho, rho1)
        if not ok1:
            pk, fpk = math.inf, math.nan
            break
        mb = mixed_mu_upper_bound(one.closed(Kf, f), one.real, groups=one.groups, peak_only=True)
        upper, cupper = np.maximum(upper, mb.upper), np.maximum(cupper, mb.complex_upper)
        top = float(np.max(mb.upper))
        if refine:
            p1, f1 = refine_mu_peak(
                lambda fr, o=one: mixed_mu_upper_bound(o.closed(frequency_response(Kfb, fr), fr), o.real,
                                                       groups=o.groups, peak_only=True, floor=top).upper,
                f, np.asarray(mb.upper))
            p1 = max(p1, top)
        else:
            i = int(np.argmax(mb.upper))
            p1, f1 = float(mb.upper[i]), float(f[i])
        if p1 > pk:
            pk, fpk = p1, f1
    out = [f, upper, cupper]
    for a in out:
        a.setflags(write=False)
    return MixedRobustStabilityResult(mu_peak=float(pk), mu_peak_freq_hz=float(fpk), freq_hz=out[0],
                                      mu_upper=out[1], complex_upper=out[2], centre_stable=bool(ok),
                                      centre_spectral_radius=float(rho), n_parameters=int(lft.real.size),
                                      n_real=int(lft.real.sum()), labels=lft.labels,
                                      merge_error_rel=None if mm is None else mm.error_rel,
                                      merge_residue_rank_ratio=None if mm is None else mm.residue_rank_ratio)
