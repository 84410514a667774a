"""(e) robust: Glover-McFarlane H-infinity loop shaping against the stage's uncertainty set.

McFarlane & Glover (1990); Skogestad & Postlethwaite, *Multivariable Feedback Control*,
2nd ed. (2005), Sec. 9.4. The loop shape is the decoupled PI-with-notches shape, its
notches widened (pole damping 1.0) so that they still cover a mode moved by the uncertainty
set (every modal frequency +-3 %, damping down to x0.5)::

    Gs = Gloop W1,  W1 = G(1)^-1 diag(w1),  w1 = k (s + wz)/(s + wl) prod_m N_m(s) * LP(s)
    K_inf: robust stabilization of the normalized coprime factors of Gs (gamma = 1.1 gamma_min)
    K = -W1 K_inf          (u = K e; the formula's K_inf is positive feedback)

``Gloop`` is the identified model (the loop as run; times ``z^-d`` with ``delay_samples = d``),
in continuous time by inverse Tustin (``z^-1`` becomes the all-pass ``(1 - s dt/2)/(1 + s dt/2)``); ``K`` goes back to
4 kHz with Tustin, so the discrete loop is the Tustin image of the designed one. The
plant is first reduced to ``reduced_order`` states (DC-matched balanced truncation).

Tuning rule: on a grid of shaping gains ``k`` (the crossover of the shaped loop), the
largest whose controller keeps a multiloop disk margin of at least 0.4 at plant input
and output and a mu upper bound below 0.95 over the uncertainty set
(:func:`nanosim.design.robustness.analyze_controller`, identified model with the loop's
delay), with ``gamma_min`` <= 4 (a normalized-coprime-factor stability margin >= 0.25).
"""
from __future__ import annotations

import math

import numpy as np

from nanosim.design.architectures.common import (
    DT_S,
    IDENTIFIED_DELAY_SAMPLES,
    BenchDesign,
    as_continuous,
    as_discrete,
    dc_gain_z,
    distinct_modes_hz,
)
from nanosim.design.lti import single_threaded_blas
from nanosim.design.robustness import DISK_MARGIN_TARGET

__all__ = ["design_robust", "ncf_controller", "TUNING_RULE"]

TUNING_RULE = ("Glover-McFarlane loop shaping of the decoupled PI-notch shape (notches covering +-3 % of every "
               "mode); the largest shaping gain with multiloop disk margin >= 0.4, mu < 0.95 over the uncertainty "
               "set and gamma_min <= 4")
GAINS = (1.0, 1.5, 2.0, 2.5, 3.0, 3.5, 4.0, 5.0)
PI_ZERO_HZ = 30.0
NOTCH_ZETA = 1.0
LOWPASS_HZ = 600.0
REDUCED_ORDER = 16
MU_MAX = 0.95
DISK_MARGIN_MIN = DISK_MARGIN_TARGET
GAMMA_MAX = 4.0


def ncf_controller(Gs, gamma_factor: float = 1.1):
    """Normalized-coprime-factor robust stabilization (S&P eqs. 9.66-9.69, ``D`` allowed).

    Parameters
    ----------
    Gs : control.StateSpace
        Continuous shaped plant.
    gamma_factor : float
        ``gamma = gamma_factor * gamma_min`` (> 1).

    Returns
    -------
    K_inf : control.StateSpace
        Positive-feedback controller ``u = K_inf y``.
    gamma_min : float
        ``sqrt(1 + rho(X Z))``; the stability margin is ``1 / gamma_min``.
    """
    import control as ct
    from scipy.linalg import solve_continuous_are
    A, B, C, D = (np.asarray(m, float) for m in (Gs.A, Gs.B, Gs.C, Gs.D))
    S = np.eye(B.shape[1]) + D.T @ D
    R = np.eye(C.shape[0]) + D @ D.T
    Si, Ri = np.linalg.inv(S), np.linalg.inv(R)
    Ar = A - B @ Si @ D.T @ C
    Z = solve_continuous_are(Ar.T, C.T, B @ Si @ B.T, R)
    X = solve_continuous_are(Ar, B, C.T @ Ri @ C, S)
    gmin = math.sqrt(1.0 + float(np.max(np.abs(np.linalg.eigvals(X @ Z)))))
    g = gamma_factor * gmin
    F = -Si @ (D.T @ C + B.T @ X)
    L = (1 - g * g) * np.eye(A.shape[0]) + X @ Z
    LTi = np.linalg.inv(L.T)
    Ak = A + B @ F + g * g * LTi @ Z @ C.T @ (C + D @ F)
    Bk = g * g * LTi @ Z @ C.T
    Ck = B.T @ X
    Dk = -D.T
    return ct.ss(Ak, Bk, Ck, Dk), gmin


def _shape(G0_inv, gain: float, modes_hz, notch_zeta: float, pi_zero_hz: float, lowpass_hz: float):
    """Continuous ``W1 = G0_inv diag(w1)``."""
    import control as ct
    s = ct.tf("s")
    wz, wl = 2 * math.pi * pi_zero_hz, 2 * math.pi * 0.01
    w = gain * (s + wz) / (s + wl)
    for f in modes_hz:
        wm = 2 * math.pi * f
        w = w * (s * s + wm * wm) / (s * s + 2 * notch_zeta * wm * s + wm * wm)
    wf = 2 * math.pi * lowpass_hz
    w = w * wf * wf / (s * s + 1.4 * wf * s + wf * wf)
    ws = ct.ss(w)
    n = G0_inv.shape[0]
    from scipy.linalg import block_diag
    Wd = ct.ss(block_diag(*[ws.A] * n), block_diag(*[ws.B] * n), block_diag(*[ws.C] * n),
               block_diag(*[ws.D] * n))
    return ct.ss(ct.series(Wd, ct.ss(np.zeros((0, 0)), np.zeros((0, n)), np.zeros((n, 0)), G0_inv)))


@single_threaded_blas
def design_robust(G, *, dt: float = DT_S, delay_samples: int = IDENTIFIED_DELAY_SAMPLES, gains=GAINS,
                  reduced_order: int = REDUCED_ORDER, mu_max: float = MU_MAX,
                  disk_margin_min: float = DISK_MARGIN_MIN) -> BenchDesign:
    """Glover-McFarlane loop shaping, tuned by the rule of the module docstring.

    Parameters
    ----------
    G : control.StateSpace
        Identified plant (discrete at ``dt``, or continuous), 3 x 3.
    dt : float
        Control period [s].
    delay_samples : int
        Loop delay [samples], in the design model and in every check.
    gains : sequence of float
        Shaping gains tried (ascending).
    reduced_order : int
        States of the design model.
    mu_max, disk_margin_min : float
        The robustness the chosen gain must keep.

    Returns
    -------
    BenchDesign
        Error-only controller.
    """
    import control as ct

    from nanosim.design.architectures.hinf_damped import tustin_delay
    from nanosim.design.reduction import reduce_model
    from nanosim.design.robustness import LoopPlant, analyze_controller
    Gd = as_discrete(G, dt)
    G0_inv = np.linalg.inv(dc_gain_z(Gd))
    modes = distinct_modes_hz(Gd)
    Gc = reduce_model(as_continuous(Gd), reduced_order).G_reduced
    Gloop = ct.ss(ct.series(tustin_delay(Gc.ninputs, delay_samples, dt), Gc)) if delay_samples else Gc
    plant = LoopPlant.identified(Gd, delay_samples)
    chosen, tried = None, []
    for k in sorted(gains):
        W1 = _shape(G0_inv, k, modes, NOTCH_ZETA, PI_ZERO_HZ, LOWPASS_HZ)
        Kinf, gmin = ncf_controller(ct.ss(ct.series(W1, Gloop)))
        Kc = ct.ss(ct.series(Kinf, W1))
        Kc = ct.ss(Kc.A, Kc.B, -np.asarray(Kc.C), -np.asarray(Kc.D))
        Kd = ct.ss(ct.c2d(Kc, dt, "tustin"))
        rob = analyze_controller(Kd, plant)
        s = rob.summary
        dm = min(s["dm_input_alpha"] or 0.0, s["dm_output_alpha"] or 0.0)
        row = {"shaping_gain": k, "gamma_min": gmin, "multiloop_disk_margin": dm, "mu_peak": s.get("mu_peak"),
               "closed_loop_stable": s.get("closed_loop_stable")}
        tried.append(row)
        ok = (s.get("closed_loop_stable") and dm >= disk_margin_min and s.get("mu_peak") is not None
              and s["mu_peak"] < mu_max and gmin <= GAMMA_MAX)
        if ok:
            chosen = (k, gmin, Kd, s)
        elif chosen is not None:
            break
    if chosen is None:
        raise ValueError(f"G: no shaping gain in {list(gains)} meets mu < {mu_max} and disk margin >= "
                         f"{disk_margin_min}: {tried}")
    k, gmin, Kd, s = chosen
    params = {"shaping_gain": k, "pi_zero_hz": PI_ZERO_HZ, "notch_hz": modes, "notch_zeta": NOTCH_ZETA,
              "lowpass_hz": LOWPASS_HZ, "gamma_min": gmin, "gamma": 1.1 * gmin, "ncf_stability_margin": 1 / gmin,
              "reduced_order": reduced_order, "controller_order": int(Kd.nstates),
              "predicted_multiloop_disk_margin": min(s["dm_input_alpha"], s["dm_output_alpha"]),
              "predicted_mu_peak": s["mu_peak"], "tried": tried, "loop_delay_samples": delay_samples}
    return BenchDesign("robust", Kd, G0_inv.shape[0], TUNING_RULE, params)
