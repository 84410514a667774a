"""Disk margins, loop-at-a-time and multiloop, and closed-loop pole damping.

Disk margins follow Seiler, Packard & Gahinet, "An Introduction to Disk Margins",
IEEE Control Systems Magazine 40(5), 2020, and MATLAB ``diskmargin``: a loop factor
``f`` in the disk ``D(alpha, sigma) = {(1 + (1 - sigma)/2 delta) / (1 - (1 + sigma)/2
delta), |delta| < alpha}`` (skew ``sigma``, default 0 = symmetric) multiplies each
broken channel; ``alpha = 1 / sup_f mu_Delta(S + (sigma - 1)/2 I)`` with ``Delta``
diagonal complex.  Loop conventions: :mod:`~nanosim.design.loopresponse`.
"""
from __future__ import annotations

import math
import numbers
from dataclasses import dataclass

import control as ct
import numpy as np

from nanosim.design.loopargs import is_lti
from nanosim.design.loopresponse import LoopResponse, PreparedLoop
from nanosim.design.lti import db, refine_peak
from nanosim.design.mu import mu_upper_bound

__all__ = ["DiskMargin", "DiskMarginReport", "LeastDampedPole", "disk_gain_phase", "disk_margins",
           "least_damped_pole", "refine_mu_peak"]


def refine_mu_peak(fun, f: np.ndarray, y: np.ndarray) -> tuple[float, float]:
    """:func:`nanosim.design.lti.refine_peak` with few evaluations, for costly ``fun``
    (mu bounds): the 3 largest maxima, 4 zooms of 9 points (bracket / 256).
    """
    return refine_peak(lambda fr: np.asarray(fun(fr), dtype=float), f, y, n_peaks=3, n_fine=9, rounds=4)


def _check_skew(skew) -> float:
    if isinstance(skew, bool) or not isinstance(skew, numbers.Real) or not math.isfinite(skew):
        raise ValueError(f"skew: expected a finite real number (0 = symmetric), got {skew!r}")
    return float(skew)


def disk_gain_phase(alpha: float, skew: float = 0.0) -> tuple[float, float, float]:
    """Gain interval and phase margin guaranteed by a disk margin.

    Parameters
    ----------
    alpha : float
        Disk size (>= 0).
    skew : float
        Skew ``sigma`` (0: symmetric, > 0 favours gain increase).

    Returns
    -------
    gmin, gmax : float
        Real-axis intercepts of ``D(alpha, sigma)`` [factor]: ``gmin = (2 - alpha (1 -
        sigma)) / (2 + alpha (1 + sigma))`` clipped at 0 and ``gmax = (2 + alpha (1 -
        sigma)) / (2 - alpha (1 + sigma))``, ``inf`` once ``alpha (1 + sigma) >= 2``.
    phase_margin_deg : float
        Largest ``phi`` with ``exp(+-j phi)`` in the disk: ``arccos((4 - alpha^2 (1 +
        sigma^2)) / (4 + alpha^2 (1 - sigma^2)))`` [deg].
    """
    if isinstance(alpha, bool) or not isinstance(alpha, numbers.Real) or not (alpha >= 0):
        raise ValueError(f"alpha: expected a real number >= 0, got {alpha!r}")
    s = _check_skew(skew)
    a = float(alpha)
    if math.isinf(a):
        return 0.0, math.inf, 180.0
    gmin = max(0.0, (2 - a * (1 - s)) / (2 + a * (1 + s))) if (2 + a * (1 + s)) > 0 else 0.0
    den = 2 - a * (1 + s)
    gmax = (2 + a * (1 - s)) / den if den > 0 else math.inf
    c = (4 - a * a * (1 + s * s)) / (4 + a * a * (1 - s * s)) if (4 + a * a * (1 - s * s)) > 0 else -1.0
    pm = math.degrees(math.acos(min(1.0, max(-1.0, c))))
    return gmin, gmax, pm


@dataclass(frozen=True)
class DiskMargin:
    """One disk margin.

    Attributes
    ----------
    alpha : float
        Guaranteed disk size, ``1 / peak mu upper bound`` (0 if the nominal loop is
        unstable).
    alpha_upper_bound : float
        ``1 / peak mu lower bound``: the true disk margin lies in
        ``[alpha, alpha_upper_bound]`` (equal for scalar problems).
    skew : float
    gain_margin : tuple of float
        ``(gmin, gmax)`` factors (``gmax`` may be ``inf``).
    gain_margin_db : tuple of float
        The same in dB.
    phase_margin_deg : float
        Symmetric disk phase margin ``+-`` [deg].
    freq_hz : float
        Frequency of the critical (largest-mu) point [Hz].
    location : str
        'input[i]', 'output[i]', 'input', 'output' or 'input+output'.
    """

    alpha: float
    alpha_upper_bound: float
    skew: float
    gain_margin: tuple
    gain_margin_db: tuple
    phase_margin_deg: float
    freq_hz: float
    location: str


def _make_dm(mu_ub: float, mu_lb: float, f: float, skew: float, location: str, stable) -> DiskMargin:
    if stable is False:
        alpha = alpha_ub = 0.0
    else:
        alpha = 1.0 / mu_ub if mu_ub > 0 else math.inf
        alpha_ub = 1.0 / mu_lb if mu_lb > 0 else math.inf
        alpha_ub = max(alpha_ub, alpha)
    gmin, gmax, pm = disk_gain_phase(alpha, skew)
    return DiskMargin(alpha=alpha, alpha_upper_bound=alpha_ub, skew=skew, gain_margin=(gmin, gmax),
                      gain_margin_db=(float(db(gmin)), float(db(gmax))), phase_margin_deg=pm, freq_hz=f,
                      location=location)


@dataclass(frozen=True, eq=False)
class DiskMarginReport:
    """Loop-at-a-time and multiloop disk margins of one loop.

    Attributes
    ----------
    input_loop_at_a_time : tuple of DiskMargin
        One per plant input, breaking that channel with the others closed (uses the
        diagonal of ``S_i``).
    output_loop_at_a_time : tuple of DiskMargin
        One per plant output (diagonal of ``S_o``).
    input, output : DiskMargin or None
        Multiloop: independent simultaneous disk factors in all inputs (outputs),
        ``mu`` of ``S + (sigma - 1)/2 I`` with diagonal complex ``Delta`` (None when
        :func:`disk_margins` was asked for the input+output margin only).
    input_output : DiskMargin
        Independent factors in all inputs *and* outputs at once, ``mu`` of
        ``[[S_i + (sigma-1)/2 I, -Kfb S_o], [S_o G, S_o + (sigma-1)/2 I]]``.
    freq_hz : ndarray, shape (F,)
        Analysis grid [Hz].
    alpha_input_f, alpha_output_f, alpha_input_output_f : ndarray, shape (F,)
        Frequency-wise multiloop disk margins ``1 / mu_upper`` on the grid (the first
        two None with ``input``, ``output``).
    closed_loop_stable : bool or None
        Nominal stability (None when the systems were given as response stacks).
    skew : float
    """

    input_loop_at_a_time: tuple
    output_loop_at_a_time: tuple
    input: DiskMargin | None
    output: DiskMargin | None
    input_output: DiskMargin
    freq_hz: np.ndarray
    alpha_input_f: np.ndarray | None
    alpha_output_f: np.ndarray | None
    alpha_input_output_f: np.ndarray
    closed_loop_stable: bool | None
    skew: float

    def worst(self) -> DiskMargin:
        """The smallest of the multiloop margins computed (of the three, or the input+output one alone)."""
        return min((m for m in (self.input, self.output, self.input_output) if m is not None), key=lambda m: m.alpha)


def _io_matrix(r: LoopResponse, c: float) -> np.ndarray:
    Iu, Iy = np.eye(r.S_i.shape[1]), np.eye(r.S_o.shape[1])
    top = np.concatenate([r.S_i + c * Iu, -r.KS_fb], axis=2)
    bot = np.concatenate([r.SG, r.S_o + c * Iy], axis=2)
    return np.concatenate([top, bot], axis=1)


def disk_margins(G, K, freq_hz, Ky=None, *, delay_samples: int = 0, dt=None, skew: float = 0.0,
                 refine: bool = True, input_output_only: bool = False) -> DiskMarginReport:
    """Disk margins (Seiler, Packard & Gahinet 2020; MATLAB ``diskmargin(P, C)``).

    Loop-at-a-time margins use ``alpha_k = 1 / sup_f |S_kk + (sigma - 1)/2|`` (``S_i``
    for inputs, ``S_o`` for outputs); multiloop margins ``alpha = 1 / sup_f mu(...)``
    with :func:`~nanosim.design.mu.mu_upper_bound` on the grid, the largest peaks refined
    between grid neighbours (when the systems are LTI or static).  A
    nominally unstable loop gets ``alpha = 0``.

    Parameters
    ----------
    G, K, Ky, delay_samples, dt
        As in :func:`~nanosim.design.loopresponse.loop_transfer_response`; only ``Kfb = K - Ky`` matters.  A
        continuous delay is exact in the responses and a Pade(3) approximant in the
        nominal-stability check.
    freq_hz : array_like, shape (F,)
        Strictly increasing analysis grid [Hz] (include 0 to catch a DC peak).
    skew : float
        Disk skew ``sigma`` (0: symmetric gain variation).
    refine : bool
        Refine the peaks between grid points.
    input_output_only : bool
        Of the multiloop margins, compute the input+output one only (the report's
        ``input`` and ``output`` are None). It bounds the other two from below (its
        perturbation set holds theirs), so :meth:`DiskMarginReport.worst` is unchanged;
        it saves two thirds of the mu computations.

    Returns
    -------
    DiskMarginReport
    """
    loop = PreparedLoop(G, K, Ky, delay_samples, dt)
    s = _check_skew(skew)
    f = loop.check_freq(freq_hz, increasing=True)
    c = (s - 1.0) / 2.0
    st = loop.stability()
    stable = None if st is None else st[0]
    r = loop.response(f)
    can_refine = refine and not loop.has_stack

    out_i, out_o = [], []
    for kind_, S, n in (("input", r.S_i, loop.nu), ("output", r.S_o, loop.ny)):
        for k in range(n):
            y = np.abs(S[:, k, k] + c)
            if can_refine:
                def fun(fr, kind_=kind_, k=k):
                    rr = loop.response(fr)
                    return np.abs((rr.S_i if kind_ == "input" else rr.S_o)[:, k, k] + c)
                pk, fpk = refine_peak(fun, f, y, n_peaks=3)
            else:
                i = int(np.argmax(y))
                pk, fpk = float(y[i]), float(f[i])
            dm = _make_dm(pk, pk, fpk, s, f"{kind_}[{k}]", stable)
            (out_i if kind_ == "input" else out_o).append(dm)

    def multiloop(build, blocks, label):
        Mf = build(r)
        mb = mu_upper_bound(Mf, blocks, lower=True, peak_only=True)
        if can_refine:
            top = float(np.max(mb.upper))
            pk, fpk = refine_mu_peak(lambda fr: mu_upper_bound(build(loop.response(fr)), blocks, lower=False,
                                                               peak_only=True, floor=top).upper, f, mb.upper)
            lb_pk = float(mu_upper_bound(build(loop.response(np.array([fpk]))), blocks, lower=True).lower[0])
        else:
            i = int(np.argmax(mb.upper))
            pk, fpk = float(mb.upper[i]), float(f[i])
            lb_pk = float(mb.lower[i])
        lb_pk = max(lb_pk, float(np.nanmax(mb.lower)))
        with np.errstate(divide="ignore"):
            curve = np.where(mb.upper > 0, 1.0 / mb.upper, np.inf)
        return _make_dm(pk, min(lb_pk, pk), fpk, s, label, stable), curve

    mi = ai = mo = ao = None
    if not input_output_only:
        mi, ai = multiloop(lambda rr: rr.S_i + c * np.eye(loop.nu), [(1, 1)] * loop.nu, "input")
        mo, ao = multiloop(lambda rr: rr.S_o + c * np.eye(loop.ny), [(1, 1)] * loop.ny, "output")
    mio, aio = multiloop(lambda rr: _io_matrix(rr, c), [(1, 1)] * (loop.nu + loop.ny), "input+output")
    f_ro = f.copy()
    for a in (f_ro, ai, ao, aio):
        if a is not None:
            a.setflags(write=False)
    return DiskMarginReport(input_loop_at_a_time=tuple(out_i), output_loop_at_a_time=tuple(out_o),
                            input=mi, output=mo, input_output=mio, freq_hz=f_ro, alpha_input_f=ai,
                            alpha_output_f=ao, alpha_input_output_f=aio, closed_loop_stable=stable,
                            skew=s)


# =====================================================================================
# closed-loop poles and damping
# =====================================================================================
@dataclass(frozen=True)
class LeastDampedPole:
    """The least-damped pole.

    Attributes
    ----------
    zeta : float
        Damping ratio ``-Re(s) / |s|`` (negative: unstable; 0 for a pole at ``s = 0``).
    freq_hz : float
        Natural frequency ``|s| / (2 pi)`` [Hz].
    pole : complex
        The pole as given (``z`` for discrete systems).
    pole_s : complex
        Its continuous equivalent ``s`` [rad/s] (``log(z) / dt`` for discrete poles).
    """

    zeta: float
    freq_hz: float
    pole: complex
    pole_s: complex


def least_damped_pole(system_or_poles, dt=None, *, f_band_hz=None) -> LeastDampedPole:
    """Least-damped pole of a system or a pole list, continuous or discrete.

    Parameters
    ----------
    system_or_poles : control.StateSpace, control.TransferFunction or array_like
        A system (its poles; discrete when ``dt > 0``) or poles: ``z`` when ``dt`` is
        given, else ``s`` [rad/s].
    dt : float or None
        Sample period [s] for a pole list (ignored for systems, which carry their own).
    f_band_hz : (float, float) or None
        Only poles with natural frequency in this band [Hz].

    Returns
    -------
    LeastDampedPole
        Discrete poles are mapped with ``s = log(z) / dt`` (principal branch); poles at
        ``z = 0`` (pure delays) are infinitely damped and skipped.

    Raises
    ------
    ValueError
        If no pole is left.
    """
    if is_lti(system_or_poles):
        sysx = system_or_poles
        p = np.asarray(sysx.poles(), dtype=complex)
        T = float(sysx.dt) if ct.isdtime(sysx, strict=True) and sysx.dt is not True else None
        if ct.isdtime(sysx, strict=True) and sysx.dt is True:
            raise ValueError("system_or_poles: discrete system with dt=True; expected a numeric dt")
    else:
        p = np.atleast_1d(np.asarray(system_or_poles, dtype=complex))
        if p.ndim != 1:
            raise ValueError(f"system_or_poles: expected a 1-D pole array, got shape {p.shape}")
        if dt is not None and (isinstance(dt, bool) or not isinstance(dt, numbers.Real) or not dt > 0):
            raise ValueError(f"dt: expected a positive sample period [s] or None, got {dt!r}")
        T = None if dt is None else float(dt)
    if T is not None:
        keep = np.abs(p) > 0
        pz = p[keep]
        s = np.log(pz) / T
    else:
        pz = p
        s = p
    wn = np.abs(s)
    with np.errstate(invalid="ignore", divide="ignore"):
        zeta = np.where(wn > 0, -s.real / np.where(wn > 0, wn, 1.0), 0.0)
    fhz = wn / (2 * np.pi)
    sel = np.isfinite(s)
    if f_band_hz is not None:
        try:
            lo, hi = (float(v) for v in f_band_hz)
        except (TypeError, ValueError):
            raise ValueError(f"f_band_hz: expected a (low, high) pair in Hz, got {f_band_hz!r}") from None
        sel &= (fhz >= lo) & (fhz <= hi)
    if not np.any(sel):
        raise ValueError(f"system_or_poles: no pole left (f_band_hz={f_band_hz!r})")
    idx = np.nonzero(sel)[0]
    k = idx[int(np.argmin(zeta[idx]))]
    return LeastDampedPole(zeta=float(zeta[k]), freq_hz=float(fhz[k]), pole=complex(pz[k]),
                           pole_s=complex(s[k]))


