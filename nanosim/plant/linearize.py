"""Linear twin of the stage: small-signal plant from MuJoCo's own linearization.

``linearize(stage)`` returns python-control state-space models from
controller volts (A, B, C) to sensor volts (5 um/V) or to um:

1. ``mjd_transitionFD`` gives the one-substep map x+ = Ad x + Bd f (f in N).
2. A real Schur form of Ad ordered by |log(mu)| / h and a Sylvester solve
   split it into the physical band (below ``f_cut_hz``) and the fast closure
   modes; the fast part is residualised (its DC gain moved into D), so the DC
   gain is exact and the twin has a dozen states.
3. The slow block becomes continuous by Ac = log(A11) / h,
   Bc = (A11 - I)^-1 Ac B1, the exact inverse of a zero-order hold over h.
4. Inputs are scaled by the amplifier and piezo force (20 x 27 N / 150 V per
   controller volt; optionally the piezo's small-signal gain and creep filter),
   outputs by 1e6 um/m and 1 / 5 sensor V per um.
"""
from __future__ import annotations

from dataclasses import dataclass

import control as ct
import numpy as np
import scipy.linalg as sla

from nanosim import constants as C
from nanosim.plant.mechanics import mechanical_matrices
from nanosim.plant.modes import linearize_fd, volts_to_force_N

__all__ = ["LinearTwin", "linearize"]


@dataclass(frozen=True)
class LinearTwin:
    """Small-signal plant of a Stage.

    Attributes
    ----------
    sys_V : continuous, controller V -> sensor V (3x3).
    sys_um : continuous, controller V -> um (3x3).
    sysd_V : discrete at the control period (ZOH), controller V -> sensor V.
    dt_s : control period (s).
    qpos_C, qpos_D : with ``with_qpos``: joint displacements from home
        ``dq = qpos_C x + qpos_D v`` (nv rows; rad or m) for the state ``x`` of
        ``sysd_V`` and its input ``v`` (controller V), fast closure modes
        residualised like the probe outputs. For drawing the mechanism.
    """

    sys_V: ct.StateSpace
    sys_um: ct.StateSpace
    sysd_V: ct.StateSpace
    dt_s: float
    qpos_C: np.ndarray | None = None
    qpos_D: np.ndarray | None = None

    @property
    def dc_gain_um_per_V(self) -> np.ndarray:
        """Static gain of the twin, um per controller V, shape (3, 3)."""
        return np.real(ct.dcgain(self.sys_um))


def _slow_continuous(Ad: np.ndarray, Bd: np.ndarray, Cm: np.ndarray, h: float, f_cut_hz: float):
    """Continuous model of the slow modes of a substep map, fast modes residualised.

    The split is done on the discrete map (ordered real Schur form + Sylvester
    solve) because the stiffest closure modes of the implicit integrator have
    negative real multipliers, where log(Ad) has no real continuous meaning.
    """
    wcut = 2 * np.pi * f_cut_hz

    def slow(re, im):
        mu = complex(re, im)
        return mu != 0 and abs(np.log(mu)) / h < wcut

    T, Q, k = sla.schur(Ad, output="real", sort=slow)
    A11, A12, A22 = T[:k, :k], T[:k, k:], T[k:, k:]
    X = sla.solve_sylvester(A11, -A22, -A12)
    Bt = Q.T @ Bd
    Ct = Cm @ Q
    B1 = Bt[:k] - X @ Bt[k:]
    C1 = Ct[:, :k]
    C2 = Ct[:, :k] @ X + Ct[:, k:]
    D = C2 @ np.linalg.solve(np.eye(len(A22)) - A22, Bt[k:])     # fast part at steady state
    mu, V = np.linalg.eig(A11)
    Ac = np.real(V @ np.diag(np.log(mu)) @ np.linalg.inv(V)) / h
    Bc = np.linalg.solve(A11 - np.eye(k), Ac @ B1)                # exact ZOH inverse
    return Ac, Bc, C1, D


def linearize(stage, f_cut_hz: float = 2500.0, include_piezo: bool = False, with_qpos: bool = False) -> LinearTwin:
    """Linear twin of ``stage`` about its home keyframe.

    Parameters
    ----------
    stage : :class:`nanosim.stage.Stage` (its ``model`` is linearized).
    f_cut_hz : modes above this (the soft-closure modes) are residualised.
    include_piezo : also include the piezo's small-signal hysteresis gain and
        the creep filter of ``stage.config.piezo`` (default: linear piezo,
        the "ideal" stage with every effect off).
    with_qpos : also return the joint-displacement outputs (``qpos_C``, ``qpos_D``);
        not with ``include_piezo``.
    """
    if with_qpos and include_piezo:
        raise ValueError("with_qpos: only for the mechanical twin (include_piezo=False)")
    model = stage.model
    h = model.opt.timestep
    Ad, Bd = linearize_fd(model)
    nv = model.nv
    probe = mechanical_matrices(model).probe
    Cm = np.hstack([probe, np.zeros((3, Ad.shape[0] - nv))])
    if with_qpos:
        Cm = np.vstack([Cm, np.hstack([np.eye(nv), np.zeros((nv, Ad.shape[0] - nv))])])
    A, B, C_all, D_all = _slow_continuous(Ad, Bd, Cm, h, f_cut_hz)
    Cm_s, D = C_all[:3], D_all[:3]
    gain_in = volts_to_force_N()
    sys_m = ct.ss(A, B * gain_in, Cm_s, D * gain_in)
    if include_piezo:
        sys_m = sys_m * _piezo_small_signal(stage)
    sys_um = sys_m * 1e6
    sys_V = sys_um * (1.0 / C.SENSOR_UM_PER_V)
    dt = stage.dt_s
    sysd_V = ct.c2d(sys_V, dt, "zoh")
    qpos_C = qpos_D = None
    if with_qpos:
        # ZOH keeps the continuous state basis, C and D, so the qpos rows read sysd_V's state through the
        # continuous map (no second c2d, whose round-off differs); python-control may have moved sys_V's
        # output scaling into B: x_V = alpha x_q
        Bq, BV = B * gain_in, np.asarray(sys_V.B)
        alpha = float(np.vdot(Bq, BV) / np.vdot(Bq, Bq))
        if not (np.array_equal(np.asarray(sys_V.A), A) and np.allclose(alpha * Bq, BV, rtol=1e-12, atol=0.0)):
            raise RuntimeError("linearize: the qpos outputs do not share the twin's state")   # pragma: no cover
        qpos_C, qpos_D = C_all[3:] / alpha, D_all[3:] * gain_in
    return LinearTwin(sys_V=sys_V, sys_um=sys_um, sysd_V=sysd_V, dt_s=dt, qpos_C=qpos_C, qpos_D=qpos_D)


def _piezo_small_signal(stage) -> ct.StateSpace:
    """3x3 diagonal small-signal piezo model: gain w0 times the small-signal creep (PiezoConfig.small_signal_creep)."""
    cfg = stage.config.piezo
    gain = cfg.small_signal_gain() if cfg.hysteresis else 1.0
    tf = ct.tf([gain], [1.0])
    gains, taus, s0 = cfg.small_signal_creep()
    if gains:
        filt = ct.tf([1.0], [1.0])
        for c_k, tau in zip(gains, taus):
            filt = filt + ct.tf([c_k], [tau, 1.0])
        tf = tf * filt * s0
    return ct.ss(ct.append(*(ct.ss(tf) for _ in range(3))))
