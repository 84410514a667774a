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
coordinates, ``P_ii(0) = 1``):

1. ``D_f = -beta P_ii(0)`` with ``beta = 2``: a feedthrough larger in magnitude than the static
   gain, opposite in sign, puts a zero pair ``w_z`` of ``P_ii + D_f`` below the first resonance
   ``w_1`` (pole-zero order reversed: the root locus of the integrator then bends into the
   left half plane). ``w_1`` is the lowest mode whose peak in ``P_ii`` is at least a quarter of the
   axis's largest.
2. The single-mode model of the axis (Aphale et al. 2007: the modes out of the band lumped into the
   feedthrough): ``P_ii ~ r_1 w_1^2 / (s^2 + w_1^2) + d``, ``r_1`` the first mode's static contribution
   (its modal residue, :func:`first_mode_residue`, every identified copy summed) and
   ``d = P_ii(0) - r_1`` the other modes'. Then::

       P_ii + D_f = -(|D_f| - d) (s^2 + w_z^2) / (s^2 + w_1^2),   w_z^2 = w_1^2 (1 - r_1 / (|D_f| - d))

   and the loop ``(k_c/s)(|D_f| - d)(s^2 + w_z^2)/(s^2 + w_1^2)`` has the root locus of integral force
   feedback, whose largest damping ``zeta_max = (w_1 - w_z) / (2 w_z)`` is reached at
   ``g = k_c (|D_f| - d) = w_1 sqrt(w_1 / w_z)`` (Preumont, *Vibration Control of Active Structures*, the
   integral-force-feedback chapter; the IRC root locus of Aphale et al. 2007). A mode with ``r_1 <= 0``
   cannot be damped this way (the design refuses it). The model leaves out a weakly coupled mode next to
   ``w_1`` (the other lateral mode, 2.5 Hz away on this stage), whose pole and zero nearly cancel in ``P_ii``.
3. ``k_t`` on the damped loop ``w_i -> y_i``. Its poles are those of the single-mode loop,
   ``s^3 + g s^2 + w_1^2 s + g w_z^2 = 0`` (:func:`irc_single_mode_poles`): a real pole ``-a`` and the damped
   pair ``(w, zeta_1)``; its static gain is ``1 / (beta - 1)``. Below the optimum ``g``, ``a`` is about
   ``k_c (|D_f| - P_ii(0))``, the IRC integrator's own lag, far below ``w_1``. The tracking integrator
   ``k_t / s`` meets both:

   - on the lag, ``(k_t / (beta - 1)) a / (s (s + a))`` closes to ``s^2 + a s + a k_t / (beta - 1)``, of
     damping ``1 / sqrt 2`` at ``k_t = (beta - 1) a / 2`` (the modulus optimum of an integrator on a
     first-order lag); its reference-to-error bandwidth is then ``0.34 a``;
   - on the resonance ``w^2 / (s^2 + 2 zeta_1 w s + w^2)`` the gain margin is ``2 zeta_1 w / k'``; for
     ``GM = 2`` (6 dB), ``k_t = (beta - 1) 2 zeta_1 w / GM``;

   ``k_t`` is the smaller of the two. A second-order model alone (no ``a``) over-estimates ``k_t`` as soon
   as ``k_c`` is lowered: the lag then dominates the tracking loop.
4. Checks and per-axis reduction: a factor ``c_i`` in ``(0, 1]`` scales each axis's ``k_c`` (``g = c_i g_opt``;
   ``k_t`` follows from step 3 at that ``g``; ``c`` is the parameter ``k_c_reduction``). Axis ``i`` passes when its
   loop broken at its output ``y_i`` and at its decoupled input ``v_i``, every other loop closed, keeps a
   symmetric disk margin ``>= 0.5`` and all the loops closed together are nominally stable (the discrete
   loop as run with the identified model). First each axis's loops alone, the others open: ``c_i`` is
   lowered by bisection to the largest factor that passes. Then all together from those factors: the
   failing axis with the smallest margin is lowered by bisection, the others held, until every axis passes
   (an unstable joint loop, no one axis's failure, scales every factor together). An axis is lowered only
   as far as its own check needs.

   What lowers ``k_c`` on this stage: the second lateral group (445-452 Hz) has a negative residue
   ``r_2`` in ``P_00`` and ``P_11`` (the probe sees it opposite to the piezo, the stage is not
   collocated), and integral feedback moves such a pole to the right by about ``k_c |r_2| / 2``: the
   group's own damping ``zeta_2 w_2`` bounds the lateral ``k_c`` (about a fifth of the optimum on the
   identified model), the lateral ``zeta_1`` (about 0.06) and with it ``a`` and ``k_t``. Z, without such
   a group near its loop's crossover, keeps ``c = 1`` on the identified model.

At low frequency the damping loop is a positive feedback of gain ``P_ii(0) / |D_f| = 1 / beta``: the
output sensitivity is ``beta / (beta - 1)`` times the tracking loop's, so the feedback S bandwidth is
below the reference-to-error one.

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
    as_discrete,
    dc_gain_z,
    disk_margin_summary,
    distinct_modes_hz,
    freqresp_z,
    loop_response,
    max_gain,
    reference_error_bandwidth_hz,
    sensitivity_bandwidth_hz,
    split_2dof,
)

__all__ = ["IrcRule", "IRC_RULE", "design_irc", "irc_controller", "closed_loop_poles", "first_pair_damping",
           "irc_max_damping", "irc_single_mode_poles", "first_mode_residue", "TUNING_RULE"]


@dataclass(frozen=True)
class IrcRule:
    """The IRC tuning rule's constants (module docstring).

    Attributes
    ----------
    feedthrough_factor : float
        ``beta`` of ``D_f = -beta P_ii(0)`` (> 1).
    gain_margin : float
        Gain margin of the tracking integrator on the damped first pair (factor, 2 = 6 dB).
    min_disk_margin : float
        Disk margin each axis's loop keeps, broken at its output and at its decoupled input, the others closed.
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
               "gain for the maximum damping of the single-mode model of the axis's first mode, "
               "k_c (|D_f| - d) = w1 sqrt(w1 / w_z); tracking integrator the smaller of the modulus optimum on "
               "the damping loop's lag a and k_t = 2 zeta_1 w / GM with GM = 2 (6 dB) on its damped pair; each "
               "axis's k_c (k_t following) lowered by bisection until the loop broken at that axis, the others "
               "closed, keeps a disk margin >= 0.5 and all loops are stable together")


def irc_max_damping(w1: float, wz: float) -> tuple[float, float]:
    """``(loop gain g, zeta_max)`` of the IRC/IFF root locus: ``g = w1 sqrt(w1/wz)``, ``zeta = (w1 - wz)/(2 wz)``."""
    return float(w1 * np.sqrt(w1 / wz)), float((w1 - wz) / (2.0 * wz))


def irc_single_mode_poles(g: float, w1: float, wz: float) -> tuple[float, float, float]:
    """``(a, w, zeta)`` of the single-mode IRC loop ``s^3 + g s^2 + w1^2 s + g wz^2 = 0``: the real pole ``-a``
    [rad/s] and the complex pair (natural frequency ``w`` [rad/s], damping ``zeta``).
    """
    r = np.roots([1.0, g, w1 * w1, g * wz * wz])
    c = r[np.argmax(r.imag)]
    a = r[np.argmin(np.abs(r.imag))]
    return float(-a.real), float(abs(c)), float(-c.real / abs(c))


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


def first_pair_damping(poles_z, f_hz: float, dt: float = DT_S, rel_band: float = 0.25, exclude=None,
                       tol: float = 1e-4) -> tuple[float, float]:
    """``(freq_hz, zeta)`` of the least damped closed-loop pair within ``rel_band`` of ``f_hz``.

    ``exclude``: open-loop poles (z); a closed-loop pole within ``tol`` of one of them is a pole the loop
    does not move (uncontrollable or unobservable from it, such as the duplicate copies of a mode in a
    column-by-column identified model, which the loop moves by a few 1e-5 through their slightly different
    columns) and is skipped. ``tol = 1e-4`` is a damping change of ``tol / (2 pi f dt)``, 4e-4 at 176 Hz.
    """
    pz = np.asarray(poles_z, complex)
    if exclude is not None and len(exclude):
        ex = np.asarray(exclude, complex)
        pz = pz[np.min(np.abs(pz[:, None] - ex[None, :]), axis=1) > tol]
    s = np.log(pz) / dt
    w = np.abs(s)
    near = (s.imag > 0) & (np.abs(w / (2 * np.pi) - f_hz) <= rel_band * f_hz)
    if not near.any():
        raise ValueError(f"poles: no closed-loop pair within {100 * rel_band:g} % of {f_hz:g} Hz")
    z = -s.real[near] / w[near]
    k = int(np.argmin(z))
    return float(w[near][k] / (2 * np.pi)), float(z[k])


def first_mode_residue(Pd, i: int, f_hz: float, rel_tol: float = 1e-3) -> float:
    """Static contribution ``r_1`` of the mode at ``f_hz`` to ``P_ii(1)`` (discrete ``Pd``).

    ``P_ii(z) = D_ii + sum_k R_k / (z - z_k)``, ``R_k = (C v_k)_i (w_k^T B)_i`` over the eigenvalues of ``A``;
    a lightly damped pair contributes ``2 Re(R_k / (1 - z_k))`` at ``z = 1``, the ``r_1`` of
    ``r_1 w_1^2 / (s^2 + 2 zeta_1 w_1 s + w_1^2)``. Every copy of the mode (within ``rel_tol``, the same mode
    identified in several columns) is summed. Negative when the sensor sees the mode opposite to the actuator.
    """
    A, B, C = (np.asarray(m, float) for m in (Pd.A, Pd.B, Pd.C))
    zk, V = np.linalg.eig(A)
    R = (C[i] @ V) * np.linalg.solve(V, B[:, i])
    s = np.log(zk.astype(complex)) / float(Pd.dt)
    near = (s.imag > 0) & (np.abs(np.abs(s) / (2 * np.pi * f_hz) - 1.0) <= rel_tol)
    return float(np.sum(2.0 * (R[near] / (1.0 - zk[near])).real))


def _axes_only(K2, on, n: int):
    """``K2`` (:func:`irc_controller`, states ``[x_c; x_t]``) with the states of the axes not in ``on`` removed
    (their gains are zero: those states drive nothing, and ``x_c`` would hold a pole at ``z = 1``).
    """
    import control as ct
    keep = np.concatenate([np.asarray(on, int), n + np.asarray(on, int)])
    A, B, C, D = (np.asarray(m, float) for m in (K2.A, K2.B, K2.C, K2.D))
    return ct.ss(A[np.ix_(keep, keep)], B[keep], C[:, keep], D, K2.dt)


def _axis_alphas(Pf, Kf) -> np.ndarray:
    """Per axis, the smaller symmetric disk margin of the loop broken at its output ``y_i`` and at its decoupled
    input ``v_i``, every other loop closed (``Pf`` (F, n, n) decoupled plant, ``Kf`` feedback operator).
    """
    from nanosim.design.loops import sensitivities
    So, Si = sensitivities(Pf, Kf)[2:]
    po = np.abs(np.diagonal(So, axis1=1, axis2=2) - 0.5).max(axis=0)
    pi = np.abs(np.diagonal(Si, axis1=1, axis2=2) - 0.5).max(axis=0)
    return 1.0 / np.maximum(po, pi)


def _reduce_per_axis(check, n: int, min_margin: float, start=None) -> np.ndarray:
    """Per-axis factors ``c`` in (0, 1] (module docstring, step 4).

    ``check(c)`` returns ``(stable, alpha)``: nominal stability of all the loops closed together and each
    axis's margin. While an axis fails, the failing axis with the smallest margin is lowered by bisection,
    the others held, to the largest factor at which its own margin holds with all loops stable. An unstable
    loop is no one axis's failure: all the factors are then scaled together to the largest stable scale.
    """
    c = np.ones(n) if start is None else np.array(start, float)
    for _ in range(6 * n):
        stable, alpha = check(c)
        if not stable:                      # not one axis's failure: every factor scaled together
            c = c * max_gain(lambda x: check(x * c)[0], 1e-3, 1.0, rel_tol=0.01)
            continue
        bad = np.flatnonzero(alpha < min_margin)
        if not bad.size:
            return c
        i = int(bad[np.argmin(alpha[bad])])

        def ok(x, i=i):
            cc = c.copy()
            cc[i] = x
            s, a = check(cc)
            return s and a[i] >= min_margin
        c[i] = max_gain(ok, 1e-3 * c[i], c[i], rel_tol=0.01)
    raise ValueError("the per-axis reduction did not settle")


def _alone_then_together(check, n: int, min_margin: float) -> np.ndarray:
    """Per-axis factors of step 4: each axis's loops alone (``check(c, axes)`` with the other axes open), then all
    together from those factors (:func:`_reduce_per_axis`).
    """
    c = np.ones(n)
    for i in range(n):
        def alone(ci, i=i):
            s, a = check(ci, [i])
            return s, np.where(np.arange(n) == i, a, np.inf)
        c[i] = _reduce_per_axis(alone, n, min_margin)[i]
    return _reduce_per_axis(lambda ci: check(ci, list(range(n))), n, min_margin, start=c)


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
    r1 = np.array([first_mode_residue(Pd, i, axis_modes[i]) for i in range(n)])
    if np.any(r1 <= 0):
        raise ValueError(f"G: the first mode's residue in P_ii is not positive ({r1.tolist()}): the collocated "
                         "pole-zero order the IRC needs is missing")
    w1 = 2 * np.pi * np.array(axis_modes)
    Dr = np.abs(Df) - (P0 - r1)                  # |D_f| - d, d = P_ii(0) - r_1 the other modes' static part
    wz = w1 * np.sqrt(1.0 - r1 / Dr)
    g_opt, zeta_pred = (np.array(v) for v in zip(*(irc_max_damping(a, b) for a, b in zip(w1, wz))))
    kc_opt = g_opt / Dr
    # the checks' grid: the analysis grid, and 0.01 % steps within 3 % of every mode (a lateral group the
    # damping loop leaves lightly damped has a sensitivity peak a fraction of a hertz wide)
    f = np.unique(np.concatenate([analysis_grid_hz(dt, n=500, modes=modes)]
                                 + [f0 * np.linspace(0.97, 1.03, 601) for f0 in modes if f0 < 0.485 / dt]))
    Pf = freqresp_z(Pd, f)

    def gains(c):
        """Step 3: ``k_c`` and the rule's ``k_t`` at the damping factors ``c``, from the single-mode loop."""
        sm = np.array([irc_single_mode_poles(ci * g, a, b) for ci, g, a, b in zip(c, g_opt, w1, wz)])
        kt_lag = (rule.feedthrough_factor - 1.0) * sm[:, 0] / 2.0
        kt_res = (rule.feedthrough_factor - 1.0) * 2.0 * sm[:, 2] * sm[:, 1] / rule.gain_margin
        return np.asarray(c) * kc_opt, np.minimum(kt_lag, kt_res), sm

    def check(c, axes):
        """Step 4: nominal stability of the loops of ``axes`` closed together and each axis's disk margin."""
        kc, kt, _ = gains(c)
        K2 = _axes_only(irc_controller(np.eye(n), Df, kc, kt, dt), axes, n)
        Ke, Ky = split_2dof(K2, n)
        stable = bool(np.max(np.abs(closed_loop_poles(Pd, K2, n))) < 1.0)
        return stable, _axis_alphas(Pf, freqresp_z(Ke, f) - freqresp_z(Ky, f))

    c = _alone_then_together(check, n, rule.min_disk_margin)
    kc, kt, sm = gains(c)
    poles_open = np.linalg.eigvals(np.asarray(Gd.A, float))
    Kd = _damping_only(irc_controller(np.eye(n), Df, kc, 0.0, dt), n)
    damped = [first_pair_damping(closed_loop_poles(Pd, Kd, n), axis_modes[i], dt, exclude=poles_open)
              for i in range(n)]
    K2 = irc_controller(G0_inv, Df, kc, kt, dt)
    Ke, Ky = split_2dof(K2, n)
    Gf = freqresp_z(Gd, f)
    r = loop_response(Gf, f, Ke, Ky, delay_samples=delay_samples, dt=dt)
    poles_all = closed_loop_poles(Gd, K2, n)
    params = {"rule": asdict(rule), "coordinates": "decoupled v = G(1) u, one SISO loop per axis",
              "axis_modes_hz": axis_modes, "feedthrough_Df": Df.tolist(),
              "first_mode_residue": r1.tolist(),
              "zero_below_first_mode_hz": (wz / (2 * np.pi)).tolist(),
              "damping_gain_rad_s": kc.tolist(), "k_c_reduction": c.tolist(),
              "predicted_max_damping_single_mode": zeta_pred.tolist(),
              "single_mode_at_design": [{"real_pole_rad_s": a, "pair_rad_s": w, "damping_ratio": z}
                                        for a, w, z in sm],
              "first_pair_damped": [{"freq_hz": fr, "damping_ratio": z} for fr, z in damped],
              "first_pair_closed_loop": [dict(zip(("freq_hz", "damping_ratio"), first_pair_damping(
                  poles_all, axis_modes[i], dt, exclude=poles_open))) for i in range(n)],
              "tracking_gain_rad_s": kt.tolist(),
              "tracking_bandwidth_rule_hz": (kt / (2 * np.pi)).tolist(),
              "axis_disk_margin": check(c, list(range(n)))[1].tolist(),
              "predicted_bandwidth_S_hz": sensitivity_bandwidth_hz(r),
              "predicted_bandwidth_reference_error_hz": reference_error_bandwidth_hz(r),
              "predicted_disk_margin": disk_margin_summary(r), "loop_delay_samples": delay_samples,
              "units": {"feedthrough_Df": "decoupled sensor V per decoupled controller V",
                        "first_mode_residue": "decoupled sensor V per decoupled controller V (static)",
                        "damping_gain_rad_s": "rad/s", "tracking_gain_rad_s": "rad/s",
                        "single_mode_at_design": "rad/s (real_pole_rad_s, pair_rad_s)"}}
    return BenchDesign("irc", K2, n, TUNING_RULE, params)


def _damping_only(K2, n):
    """The damping loops of ``K2`` alone: its first ``n`` states (``x_c``), without the tracking integrators."""
    import control as ct
    A, B, C, D = (np.asarray(m, float) for m in (K2.A, K2.B, K2.C, K2.D))
    return ct.ss(A[:n, :n], B[:n], C[:, :n], D, K2.dt)
