"""(i) irc: integral resonant control of the first mode with an integral tracking loop.

Integral resonant control (Aphale, Fleming & Moheimani, "Integral resonant control of
collocated smart structures", Smart Mater. Struct. 16 (2007) 439) with the outer tracking
integrator of Fleming & Leang (*Design, Modeling and Control of Nanopositioning Systems*,
Springer 2014), decentralised: one SISO loop per axis in the decoupled coordinates
``v = G(1) u`` (the plant ``P = G G(1)^-1`` is the identity at DC, the Jacobian decoupling of
the paper's Eq. 2 applied through the identified static gain). Per axis ``i``::

    y~_i = y_i + D_f v_i                     (the feedthrough, computed inside the controller)
    v_i  = (k_c / s) (y~_i + w_i)            (the IRC damping integrator)
    w_i  = (k_t / s) e_i,  e = r - y         (the tracking integrator)
    u    = G(1)^-1 v

Tuning rule (:class:`IrcRule`), per axis, on ``P_ii`` (the identified diagonal in decoupled
coordinates):

1. ``D_f = -beta P_ii(0)`` with ``beta = 2``: a feedthrough larger in magnitude than the static
   gain, opposite in sign, puts a zero pair ``w_z`` of ``P_ii + D_f`` below the first resonance
   ``w_1`` (pole-zero order reversed: the root locus of the integrator then bends into the
   left half plane). For one mode ``P = w_1^2 / (s^2 + w_1^2)``, ``w_z = w_1 sqrt(1 - 1/beta)``.
2. ``k_c`` for the maximum damping of the first mode: the loop ``(k_c/s)|D_f|(s^2 + w_z^2)/(s^2 + w_1^2)``
   has the root locus of integral force feedback, whose largest damping
   ``zeta_max = (w_1 - w_z) / (2 w_z)`` is reached at ``k_c |D_f| = w_1 sqrt(w_1 / w_z)``
   (Preumont, *Vibration Control of Active Structures*, the integral-force-feedback chapter; the IRC root
   locus of Aphale et al. 2007). ``w_z`` is the lowest lightly damped zero of
   ``P_ii(s) + D_f`` (continuous, inverse Tustin of the identified model) below ``w_1``, the lowest
   mode whose peak in ``P_ii`` is at least a quarter of the axis's largest.
3. ``k_t`` from the bandwidth rule of an integrator on a damped resonance: ``k_t / s`` around
   ``w_1^2 / (s^2 + 2 zeta_1 w_1 s + w_1^2)`` has the gain margin ``2 zeta_1 w_1 / k_t``; for a gain
   margin of ``GM = 2`` (6 dB), ``k_t = 2 zeta_1 w_1 / GM``, the closed-loop bandwidth about
   ``k_t / (2 pi)`` Hz. ``zeta_1`` is the damping of the first pair with the damping loops closed
   (the discrete loop with the identified model).
4. Both gains are checked on the discrete loop as run with the identified model (nominal stability,
   loop-at-a-time disk margin ``>= 0.5``): ``k_c`` with the damping loops alone, ``k_t`` with the
   whole loop. A gain the check refuses is lowered by bisection to the largest factor of it the
   check accepts (``k_c_reduction``, ``k_t_reduction``; 1 when the rule's value passes). The sample
   delay of the loop and the modes above the first are what the single-mode rule does not see.

The integrators are forward Euler (``k T / (z - 1)``), so the controller is strictly proper and
``D_f v`` needs no algebraic loop; the tracking integrator leaks below ``LEAK_HZ`` (0.01 Hz, as every
bench integrator) so that the controller has no pole at ``z = 1`` (the damping integrator has none:
``D_f`` closes it).
"""
from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np

from nanosim.design.architectures.common import (
    DT_S,
    LEAK_HZ,
    IDENTIFIED_DELAY_SAMPLES,
    BenchDesign,
    analysis_grid_hz,
    as_continuous,
    as_discrete,
    closed_loop_spectral_radius,
    dc_gain_z,
    disk_margin_summary,
    distinct_modes_hz,
    freqresp_z,
    loop_at_a_time_alpha,
    loop_response,
    max_gain,
    sensitivity_bandwidth_hz,
    split_2dof,
)

__all__ = ["IrcRule", "IRC_RULE", "design_irc", "irc_controller", "closed_loop_poles", "first_pair_damping",
           "irc_max_damping", "TUNING_RULE"]


@dataclass(frozen=True)
class IrcRule:
    """The IRC tuning rule's constants (module docstring).

    Attributes
    ----------
    feedthrough_factor : float
        ``beta`` of ``D_f = -beta P_ii(0)`` (> 1).
    gain_margin : float
        Gain margin of the tracking integrator on the damped first mode (factor, 2 = 6 dB).
    min_disk_margin : float
        Loop-at-a-time disk margin the whole loop keeps.
    """

    feedthrough_factor: float = 2.0
    gain_margin: float = 2.0
    min_disk_margin: float = 0.5

    def __post_init__(self):
        if not self.feedthrough_factor > 1.0:
            raise ValueError(f"feedthrough_factor: expected a value > 1, got {self.feedthrough_factor!r}")
        if not self.gain_margin > 1.0:
            raise ValueError(f"gain_margin: expected a value > 1, got {self.gain_margin!r}")
        if not 0.0 < self.min_disk_margin < 2.0:
            raise ValueError(f"min_disk_margin: expected a value in (0, 2), got {self.min_disk_margin!r}")


IRC_RULE = IrcRule()
TUNING_RULE = ("IRC per decoupled axis (Aphale, Fleming & Moheimani 2007): D_f = -2 P_ii(0); damping integrator "
               "gain for the maximum damping of the first mode, k_c |D_f| = w1 sqrt(w1 / w_z); tracking integrator "
               "k_t = 2 zeta_1 w1 / GM with GM = 2 (6 dB), zeta_1 the damped first pair; both lowered if the loop "
               "as run has a loop-at-a-time disk margin < 0.5")


def irc_max_damping(w1: float, wz: float) -> tuple[float, float]:
    """``(loop gain g, zeta_max)`` of the IRC/IFF root locus: ``g = w1 sqrt(w1/wz)``, ``zeta = (w1 - wz)/(2 wz)``."""
    return float(w1 * np.sqrt(w1 / wz)), float((w1 - wz) / (2.0 * wz))


def irc_controller(G0_inv, feedthrough, k_c, k_t, dt: float = DT_S):
    """The discrete two-degree-of-freedom IRC controller, inputs ``[e; y]``, outputs ``u`` (module docstring).

    Parameters
    ----------
    G0_inv : ndarray, shape (n, n)
        Inverse static gain (decoupling).
    feedthrough, k_c, k_t : array_like, shape (n,)
        ``D_f`` [decoupled V / V], damping and tracking integrator gains [rad/s] per axis.
    dt : float
        Control period [s].

    Returns
    -------
    control.StateSpace
        States ``[x_c (n); x_t (n)]``; ``x_c = v``.
    """
    import control as ct
    n = G0_inv.shape[0]
    Df, kc, kt = (np.broadcast_to(np.asarray(a, float), (n,)) for a in (feedthrough, k_c, k_t))
    I = np.eye(n)
    # x_c+ = x_c + dt k_c (y + D_f x_c + k_t x_t);  x_t+ = leak x_t + dt e
    leak = np.exp(-2 * np.pi * LEAK_HZ * dt)        # the tracking integrator leaks below LEAK_HZ: no pole at z = 1
    A = np.block([[I + dt * np.diag(kc * Df), dt * np.diag(kc * kt)], [np.zeros((n, n)), leak * I]])
    B = np.block([[np.zeros((n, n)), dt * np.diag(kc)], [dt * I, np.zeros((n, n))]])
    C = np.hstack([np.asarray(G0_inv, float), np.zeros((n, n))])
    return ct.ss(A, B, C, np.zeros((n, 2 * n)), dt)


def closed_loop_poles(Gd, K2, n_error: int) -> np.ndarray:
    """Poles (z) of the discrete loop ``u = K2 [r - y; y]`` around ``Gd`` at ``r = 0`` (strictly proper ``K2``)."""
    A, B, C, D = (np.asarray(m, float) for m in (Gd.A, Gd.B, Gd.C, Gd.D))
    Ak, Bk, Ck, Dk = (np.asarray(m, float) for m in (K2.A, K2.B, K2.C, K2.D))
    if np.any(Dk):
        raise ValueError("K2: expected a strictly proper controller (D = 0)")
    ny = C.shape[0]
    M = np.vstack([-np.eye(ny)[:n_error], np.eye(ny)])[:Bk.shape[1]]      # [e; y] = M y at r = 0
    Acl = np.block([[A, B @ Ck], [Bk @ M @ C, Ak + Bk @ M @ D @ Ck]])
    return np.linalg.eigvals(Acl)


def first_pair_damping(poles_z, f_hz: float, dt: float = DT_S, rel_band: float = 0.25, exclude=None
                       ) -> tuple[float, float]:
    """``(freq_hz, zeta)`` of the least damped closed-loop pair within ``rel_band`` of ``f_hz``.

    ``exclude``: open-loop poles (z); a closed-loop pole within ``1e-5`` of one of them is a pole the loop
    does not move (uncontrollable or unobservable from it, such as the duplicate copies of a mode in a
    column-by-column identified model) and is skipped.
    """
    pz = np.asarray(poles_z, complex)
    if exclude is not None and len(exclude):
        ex = np.asarray(exclude, complex)
        pz = pz[np.min(np.abs(pz[:, None] - ex[None, :]), axis=1) > 1e-5]
    s = np.log(pz) / dt
    w = np.abs(s)
    near = (s.imag > 0) & (np.abs(w / (2 * np.pi) - f_hz) <= rel_band * f_hz)
    if not near.any():
        raise ValueError(f"poles: no closed-loop pair within {100 * rel_band:g} % of {f_hz:g} Hz")
    z = -s.real[near] / w[near]
    k = int(np.argmin(z))
    return float(w[near][k] / (2 * np.pi)), float(z[k])


def _lowest_zero_below(Pc, i, df, w1):
    """Lowest lightly damped zero pair [rad/s] of ``P_ii(s) + D_f`` below ``w1`` (continuous)."""
    import scipy.linalg as sla
    A, B, C, D = (np.asarray(m, float) for m in (Pc.A, Pc.B, Pc.C, Pc.D))
    n = A.shape[0]
    M = np.block([[A, B[:, i:i + 1]], [C[i:i + 1], D[i:i + 1, i:i + 1] + df]])
    N = np.zeros_like(M)
    N[:n, :n] = np.eye(n)
    z = sla.eigvals(M, N)
    z = z[np.isfinite(z) & (z.imag > 0)]
    w = np.abs(z)
    cand = w[(w < w1) & (-z.real < 0.3 * w)]
    if not cand.size:
        raise ValueError(f"G: P_{i}{i} + D_f has no zero pair below the first mode ({w1 / (2 * np.pi):.1f} Hz): "
                         "the collocated pole-zero order the IRC needs is missing")
    return float(cand.max())


def design_irc(G, *, dt: float = DT_S, delay_samples: int = IDENTIFIED_DELAY_SAMPLES, rule: IrcRule = IRC_RULE
               ) -> BenchDesign:
    """IRC damping plus integral tracking, tuned by :class:`IrcRule` (module docstring).

    Parameters
    ----------
    G : control.StateSpace
        Identified plant (discrete at ``dt``, or continuous: Tustin), square.
    dt : float
        Control period [s].
    delay_samples : int
        Loop delay [samples] of every check.
    rule : IrcRule
        The tuning rule's constants.

    Returns
    -------
    BenchDesign
        Two-degree-of-freedom controller, inputs ``[e; y]``.
    """
    import control as ct
    if delay_samples:
        raise ValueError(f"delay_samples: the IRC design checks the loop as identified (0), got {delay_samples}")
    Gd = as_discrete(G, dt)
    G0 = dc_gain_z(Gd)
    G0_inv = np.linalg.inv(G0)
    n = G0.shape[0]
    Pd = ct.ss(Gd.A, Gd.B @ G0_inv, Gd.C, Gd.D @ G0_inv, dt)
    Pc = as_continuous(Pd)
    modes = distinct_modes_hz(Gd)
    if not modes:
        raise ValueError("G: no lightly damped mode to damp")
    fm = np.array(modes)
    Pm = freqresp_z(Pd, fm)
    # the first mode of each axis: the lowest with a peak of at least a quarter of the axis's largest
    peaks = np.abs(np.diagonal(Pm, axis1=1, axis2=2))
    axis_modes = [float(fm[np.flatnonzero(peaks[:, i] >= 0.25 * peaks[:, i].max())[0]]) for i in range(n)]
    P0 = np.diag(dc_gain_z(Pd)).copy()
    Df = -rule.feedthrough_factor * P0
    wz, kc = np.zeros(n), np.zeros(n)
    zeta_pred = np.zeros(n)
    for i in range(n):
        w1 = 2 * np.pi * axis_modes[i]
        wz[i] = _lowest_zero_below(Pc, i, Df[i], w1)
        g, zeta_pred[i] = irc_max_damping(w1, wz[i])
        kc[i] = g / abs(Df[i])
    f = analysis_grid_hz(dt, n=500, modes=modes)
    Gf = freqresp_z(Gd, f)

    def passes(K2):
        Ke, Ky = split_2dof(K2, n)
        if closed_loop_spectral_radius(Gd, Ke, Ky, delay_samples) >= 1.0:
            return False
        Kf = freqresp_z(Ke, f) - freqresp_z(Ky, f)
        return loop_at_a_time_alpha(Gf, Kf, delay_samples, dt, f) >= rule.min_disk_margin

    # the damping loops alone (no tracking integrators): stable with the disk margin, else lowered
    damp = lambda c: _damping_only(irc_controller(G0_inv, Df, c * kc, 0.0, dt), n)

    def damp_ok(c):
        Kd = damp(c)
        if not _stable(Gd, Kd, n):
            return False
        return loop_at_a_time_alpha(Gf, -freqresp_z(Kd, f)[:, :, n:], delay_samples, dt, f) >= rule.min_disk_margin

    kc_red = 1.0 if damp_ok(1.0) else max_gain(damp_ok, 1e-3, 1.0, rel_tol=0.01)
    kc = kc * kc_red
    poles_open = np.linalg.eigvals(np.asarray(Gd.A, float))
    poles = closed_loop_poles(Gd, damp(1.0), n)
    damped = [first_pair_damping(poles, axis_modes[i], dt, exclude=poles_open) for i in range(n)]
    kt = np.array([2.0 * zeta * 2 * np.pi * fr / rule.gain_margin for fr, zeta in damped])
    track = lambda c: irc_controller(G0_inv, Df, kc, c * kt, dt)
    kt_red = 1.0 if passes(track(1.0)) else max_gain(lambda c: passes(track(c)), 1e-3, 1.0, rel_tol=0.01)
    kt = kt * kt_red
    K2 = track(1.0)
    Ke, Ky = split_2dof(K2, n)
    r = loop_response(Gf, f, Ke, Ky, delay_samples=delay_samples, dt=dt)
    poles_all = closed_loop_poles(Gd, K2, n)
    params = {"rule": asdict(rule), "coordinates": "decoupled v = G(1) u, one SISO loop per axis",
              "axis_modes_hz": axis_modes, "feedthrough_Df": Df.tolist(),
              "zero_below_first_mode_hz": (wz / (2 * np.pi)).tolist(),
              "damping_gain_rad_s": kc.tolist(), "k_c_reduction": float(kc_red),
              "predicted_max_damping_single_mode": zeta_pred.tolist(),
              "first_pair_damped": [{"freq_hz": fr, "damping_ratio": z} for fr, z in damped],
              "first_pair_closed_loop": [dict(zip(("freq_hz", "damping_ratio"), first_pair_damping(
                  poles_all, axis_modes[i], dt, exclude=poles_open))) for i in range(n)],
              "tracking_gain_rad_s": kt.tolist(), "k_t_reduction": float(kt_red),
              "tracking_bandwidth_rule_hz": (kt / (2 * np.pi)).tolist(),
              "predicted_bandwidth_S_hz": sensitivity_bandwidth_hz(r),
              "predicted_disk_margin": disk_margin_summary(r), "loop_delay_samples": delay_samples,
              "units": {"feedthrough_Df": "decoupled sensor V per decoupled controller V",
                        "damping_gain_rad_s": "rad/s", "tracking_gain_rad_s": "rad/s"}}
    return BenchDesign("irc", K2, n, TUNING_RULE, params)


def _damping_only(K2, n):
    """The damping loops of ``K2`` alone: its first ``n`` states (``x_c``), without the tracking integrators."""
    import control as ct
    A, B, C, D = (np.asarray(m, float) for m in (K2.A, K2.B, K2.C, K2.D))
    return ct.ss(A[:n, :n], B[:n], C[:, :n], D, K2.dt)


def _stable(Gd, K2, n) -> bool:
    return bool(np.max(np.abs(closed_loop_poles(Gd, K2, n))) < 1.0)
