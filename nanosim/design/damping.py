"""Active damping: an inner loop for the lightly damped first modes (beyond the paper).

Two degrees of freedom
----------------------
A mixed-sensitivity S/KS/T design inverts the plant: its controller has
zeros on the lightly damped plant poles (the first XY pair, about 175 Hz, damping
ratio a few thousandths), so the closed loop keeps them with their open-loop damping.
Any input disturbance there (the piezo's hysteresis, DAC noise) then rings for
``1/(zeta w)``, a few tenths of a second.
With a damping loop the loop is ``u = K e + Ky y``: ``Ky`` is a band-limited
velocity feedback (:func:`damping_loop`) closed first, ``Gd = (I - G Ky)^-1 G``
(:func:`damped_plant`), and ``K`` is the H-infinity controller for ``Gd`` with
the same weights. Then ``r -> y`` is exactly ``T = Gd K (I + Gd K)^-1`` and
``r -> e`` is ``S = (I + Gd K)^-1``, so every weight bound of the design holds
for the tracking loop; the feedback operator is ``K - Ky``
(``u = K r - (K - Ky) y``, :func:`nanosim.design.loops.feedback_operator`).
The reference never passes through ``Ky`` (no derivative kick on steps).
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from nanosim import constants as C
from nanosim.design.lti import as_ss, dc_gain, max_real_pole

__all__ = ["DampingLoop", "damping_loop", "damped_plant"]


@dataclass(frozen=True, eq=False)
class DampingLoop:
    """Inner active-damping loop ``u = Ky y`` (positive-feedback convention).

    ``Ky(s) = -c s wf^2 / (s^2 + 2 zeta_f wf s + wf^2) * G(0)^-1``: velocity
    feedback in decoupled (sensor) coordinates, low-passed at ``lowpass_hz``.
    For a mode ``G0 w1^2 / (s^2 + 2 zeta w1 s + w1^2)`` the feedback
    ``-c s`` adds ``c w1 / 2`` to its damping ratio (``s^2 + (2 zeta w1 + c w1^2) s
    + w1^2``), so ``c = 2 zeta_added / w1``. The low-pass lag (90 deg at
    ``lowpass_hz``) turns the feedback of the non-collocated second mode set
    (460-475 Hz) from destabilizing into damping. ``Ky(0) = 0``: no effect on
    static gain or creep.

    Attributes
    ----------
    Ky : control.StateSpace
        ``ny -> nu``, sensor V -> controller V.
    zeta_added : float
        Damping ratio added to the first mode (design value, dimensionless).
    mode_hz : float
        First lightly damped plant mode the gain is scaled for [Hz].
    lowpass_hz, lowpass_zeta : float
        Second-order low-pass corner [Hz] and its damping ratio.
    gain_c_s : float
        ``c`` in ``-c s`` [s].
    """

    Ky: Any
    zeta_added: float
    mode_hz: float
    lowpass_hz: float
    lowpass_zeta: float
    gain_c_s: float

    def to_dict(self) -> dict:
        """JSON-ready description (``design.json["damping_loop"]``)."""
        return {"type": "band-limited velocity feedback, u = Ky y, Ky = -c s wf^2/(s^2 + 2 zf wf s + wf^2) G(0)^-1",
                "zeta_added": self.zeta_added, "mode_hz": self.mode_hz, "lowpass_hz": self.lowpass_hz,
                "lowpass_zeta": self.lowpass_zeta, "gain_c_s": self.gain_c_s}


def _first_lightly_damped_hz(G, zeta_max: float = 0.05, f_min_hz: float = 20.0) -> float:
    p = np.linalg.eigvals(np.asarray(G.A, float)) if G.nstates else np.array([])
    w = np.abs(p)
    ok = (p.imag > 0) & (w > 2 * np.pi * f_min_hz) & (-p.real < zeta_max * w)
    if not np.any(ok):
        raise ValueError(f"G: no lightly damped mode (zeta < {zeta_max}) above {f_min_hz} Hz to damp")
    return float(w[ok].min() / (2 * np.pi))


def damping_loop(G, zeta_added: float = C.DEFAULT_DAMPING_ZETA, *, mode_hz: float | None = None,
                 lowpass_hz: float = C.DEFAULT_DAMPING_LOWPASS_HZ,
                 lowpass_zeta: float = 0.7) -> DampingLoop:
    """Band-limited velocity feedback that damps the first plant modes.

    Parameters
    ----------
    G : control.StateSpace
        Plant (controller V -> sensor V), square, stable DC gain.
    zeta_added : float, default 0.1
        Damping ratio to add to the first mode (> 0, <= 0.5).
    mode_hz : float, optional
        First mode [Hz]; default the lowest pole of ``G`` above 20 Hz with ``zeta < 0.05``.
    lowpass_hz : float, default 400
        Low-pass corner [Hz] (between the first and the second mode set).
    lowpass_zeta : float, default 0.7
        Damping ratio of the low-pass.

    Returns
    -------
    DampingLoop
    """
    import control as ct
    G = as_ss("G", G)
    if G.noutputs != G.ninputs:
        raise ValueError(f"G: expected a square plant, got {G.noutputs}x{G.ninputs}")
    for nm, v, lo, hi in (("zeta_added", zeta_added, 0.0, 0.5), ("lowpass_hz", lowpass_hz, 0.0, np.inf),
                          ("lowpass_zeta", lowpass_zeta, 0.0, 2.0)):
        if not (isinstance(v, (int, float)) and math.isfinite(v) and lo < v <= hi):
            raise ValueError(f"{nm}: expected a number in ({lo}, {hi}], got {v!r}")
    f1 = _first_lightly_damped_hz(G) if mode_hz is None else float(mode_hz)
    if not (math.isfinite(f1) and f1 > 0):
        raise ValueError(f"mode_hz: expected a positive frequency in Hz, got {mode_hz!r}")
    G0 = dc_gain(G)
    cond = np.linalg.cond(G0)
    if cond > 1e8:
        raise ValueError(f"G: DC gain is singular (condition number {cond:.3g}); cannot decouple")
    w1, wf = 2 * np.pi * f1, 2 * np.pi * float(lowpass_hz)
    c = 2.0 * float(zeta_added) / w1
    n = G.noutputs
    Af = np.array([[0.0, 1.0], [-wf * wf, -2 * lowpass_zeta * wf]])     # x1' = x2; F = wf^2 x1 / ...
    A = np.kron(np.eye(n), Af)
    B = np.kron(np.eye(n), np.array([[0.0], [1.0]]))
    Cv = np.kron(np.eye(n), np.array([[0.0, -c * wf * wf]]))           # -c s wf^2 / (...)
    Ky = ct.ss(A, B, np.linalg.inv(G0) @ Cv, np.zeros((n, n)))
    return DampingLoop(Ky=Ky, zeta_added=float(zeta_added), mode_hz=f1, lowpass_hz=float(lowpass_hz),
                       lowpass_zeta=float(lowpass_zeta), gain_c_s=float(c))


def damped_plant(G, damping: DampingLoop | None):
    """``Gd = (I - G Ky)^-1 G``: the plant seen by the outer loop.

    Parameters
    ----------
    G : control.StateSpace or None
        Plant, ``ny x nu`` (controller V -> sensor V), continuous.
    damping : DampingLoop or None

    Returns
    -------
    control.StateSpace or None
        The damped plant (same units); ``G`` itself if ``damping`` or ``G`` is None.

    Raises
    ------
    ValueError
        The damping loop destabilizes a stable plant.
    """
    if damping is None or G is None:
        return G
    import control as ct
    G = as_ss("G", G)
    Gd = ct.feedback(G, damping.Ky, sign=+1)
    Gd = ct.ss(np.asarray(Gd.A), np.asarray(Gd.B), np.asarray(Gd.C), np.asarray(Gd.D))
    if max_real_pole(G.A) < 0 <= max_real_pole(Gd.A):
        p = np.linalg.eigvals(np.asarray(Gd.A))
        bad = p[(p.real >= 0) & (p.imag >= 0)]
        raise ValueError(f"damping loop: it destabilizes the plant (closed-loop poles at "
                         f"{', '.join(f'{abs(q) / (2 * np.pi):.1f} Hz' for q in bad)}); the low-pass at "
                         f"{damping.lowpass_hz:g} Hz gives the wrong phase there -- move lowpass_hz or lower "
                         f"zeta_added")
    return Gd
