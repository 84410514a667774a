"""(f) feedforward: model-inversion feedforward on top of a feedback design (tracking and contouring).

A two-degree-of-freedom structure (Devasia, Eleftheriou & Moheimani, IEEE TCST 15(5),
2007, Sec. IV; Clayton et al., J. Dyn. Sys. Meas. Control 131, 2009)::

    r_f  = T_d(s) r                                   reference model, per axis
    u_ff = sum_m P_m b_m(s) r_f                        approximate plant inverse
    u    = Ke (r_f - y) + Ky y + u_ff                  the feedback design (Ke, Ky) on r_f

* ``T_d = w_d^3/(s + w_d)^3``: a critically damped reference model; its states give
  ``r_f`` and its first three derivatives, so the inverse needs no preview;
* basis ``b_m``: ``s/(s + w_h)`` (0.05 Hz) for the static part, ``s/(s + w_c)`` at the creep
  corners 0.5, 2 and 8 Hz (the creep's slow rise), and ``s, s^2, s^3`` (velocity,
  acceleration, jerk: the inertia of the first modes and the loop's delay);
* ``P_m`` (3 x 3): least-squares fit of ``G_loop(j w) sum_m P_m b_m(j w) = I`` from 0.2 Hz to
  0.9 x the lowest identified mode, ``G_loop`` the identified model with the loop's delay
  (the fit advances the command by the delay);
* every basis function vanishes at DC, so at equilibrium the command is the feedback's
  alone (``reset_at`` gives no kick; a constant reading does not leak into the command).
  Optionally (``notches=True``) the command is notched at the modes.

The protocol: the controller reads ``e = r - y`` and ``y`` like every two-degree-of-freedom
controller and forms ``r = e + y`` internally; it is an ordinary
:class:`~nanosim.design.controller.DiscreteController` with ``n_error = 3``.

Tuning rule: the fit band is 0.2 Hz to 0.9 x the lowest identified mode; the reference
model corner ``f_d`` is the lowest mode / 1.5 (2 % settling of ``T_d`` about 8.4 / w_d);
the feedback design is the bench design named ``base`` (default ``hinf-damped``: a feedback loop that
damps the modes, which the notch-only designs leave undamped). The reference model's own 2 % settling,
about ``8.4 / w_d``, bounds the step from below whatever the feedback; ``nanosim compare`` measures the
step of this design beside the others.
"""
from __future__ import annotations

import math

import numpy as np

from nanosim.design.architectures.common import (
    DT_S,
    IDENTIFIED_DELAY_SAMPLES,
    BenchDesign,
    as_discrete,
    distinct_modes_hz,
    freqresp_z,
)

__all__ = ["design_feedforward", "fit_inverse", "feedforward_controller", "basis_response", "default_basis",
           "loop_plant_response",
           "TUNING_RULE", "DEFAULT_BASE"]

TUNING_RULE = ("model-inversion feedforward (static, creep and derivative terms fitted to the inverse of the "
               "identified model with the loop's delay, 0.2 Hz to 0.9 x the first mode) through a critically damped "
               "3rd-order reference model at first mode / 1.5, on top of the feedback design 'base'")
# the feedback design under the feedforward: the best 2 um step with overshoot <= 10 % before lqg existed (twin,
# seed 0: settling 40 ms; the notch-only designs leave the modes undamped and ring for ~0.3 s); see the docstring
DEFAULT_BASE = "hinf-damped"
POLY_ORDER = 3
NOTCH_ZETA = 0.7
HIGHPASS_HZ = 0.05
CREEP_HZ = (0.5, 2.0, 8.0)
FIT_LOW_HZ = 0.2


def _notch_response(f_hz, modes_hz, zeta):
    s = 2j * np.pi * np.asarray(f_hz, float)
    out = np.ones_like(s)
    for fm in modes_hz:
        w = 2 * np.pi * fm
        out = out * (s * s + w * w) / (s * s + 2 * zeta * w * s + w * w)
    return out


def basis_response(basis, freq_hz) -> np.ndarray:
    """Responses (F, M) of the inverse's basis functions: ``("hp", f_c)`` is ``s/(s + 2 pi f_c)``,
    ``("d", m)`` is ``s^m``.
    """
    s = 2j * np.pi * np.asarray(freq_hz, float)
    cols = []
    for kind, v in basis:
        if kind == "hp":
            cols.append(s / (s + 2 * np.pi * v))
        elif kind == "d":
            cols.append(s ** int(v))
        else:
            raise ValueError(f"basis: expected ('hp', f_c) or ('d', m), got {(kind, v)!r}")
    return np.stack(cols, axis=1)


def default_basis(order: int = POLY_ORDER, creep_hz=CREEP_HZ) -> tuple:
    """Static part through high-passes at 0.05 Hz and the creep corners, then ``s .. s^order``."""
    return (("hp", HIGHPASS_HZ),) + tuple(("hp", f) for f in creep_hz) + tuple(("d", m) for m in range(1, order + 1))


def loop_plant_response(Gd, freq_hz, delay_samples: int = IDENTIFIED_DELAY_SAMPLES, Ky=None) -> np.ndarray:
    """``(I - G_loop Ky)^-1 G_loop`` on ``freq_hz`` (F, ny, nu): the plant a command added to ``u`` sees
    (``G_loop`` = identified model with the loop's delay; ``Ky`` the base design's measurement path).
    """
    f = np.asarray(freq_hz, float)
    Gf = freqresp_z(Gd, f) * np.exp(-2j * np.pi * f * delay_samples * float(Gd.dt))[:, None, None]
    if Ky is None:
        return Gf
    return np.linalg.solve(np.eye(Gf.shape[1]) - Gf @ freqresp_z(Ky, f), Gf)


def fit_inverse(Gd, freq_hz, basis, *, delay_samples: int = IDENTIFIED_DELAY_SAMPLES, notch_hz=(),
                notch_zeta: float = NOTCH_ZETA, Ky=None) -> np.ndarray:
    """Least-squares ``P_m`` with ``Gp N sum_m P_m b_m(j w) ~ I`` on ``freq_hz`` (relative fit), ``Gp`` the
    plant the command sees (:func:`loop_plant_response`).

    Returns
    -------
    ndarray, shape (M, nu, ny)
        ``P_m`` for the basis functions ``b_m`` (:func:`basis_response`).
    """
    f = np.asarray(freq_hz, float)
    Gf = loop_plant_response(Gd, f, delay_samples, Ky)
    Gf = Gf * _notch_response(f, notch_hz, notch_zeta)[:, None, None]
    ny, nu = Gf.shape[1], Gf.shape[2]
    Bf = basis_response(basis, f)
    scale = np.abs(Bf).max(axis=0)                 # column scaling for conditioning
    M = np.concatenate([Gf * (Bf[:, m] / scale[m])[:, None, None] for m in range(len(basis))], axis=2)
    A = M.reshape(-1, nu * len(basis))
    Ar = np.vstack([A.real, A.imag])
    P = np.empty((len(basis), nu, ny))
    for j in range(ny):
        b = np.zeros((f.size, ny), complex)
        b[:, j] = 1.0
        bv = b.reshape(-1)
        x, *_ = np.linalg.lstsq(Ar, np.concatenate([bv.real, bv.imag]), rcond=None)
        P[:, :, j] = x.reshape(len(basis), nu) / scale[:, None]
    return P


def feedforward_controller(base: BenchDesign, P: np.ndarray, basis, ref_hz: float, notch_hz, dt: float = DT_S,
                           notch_zeta: float = NOTCH_ZETA):
    """The discrete ``[e; y] -> u`` controller of the module docstring around ``base``.

    Returns
    -------
    control.StateSpace
        States: reference model and feedforward filters, then the base design's.
    """
    import control as ct
    from scipy.linalg import block_diag
    n = P.shape[2]
    k = max([int(v) for kind, v in basis if kind == "d"] + [1])
    hps = [float(v) for kind, v in basis if kind == "hp"]
    wd = 2 * math.pi * ref_hz
    # reference model per axis: x = [r_f, r_f', ..., r_f^(k-1)], T_d = wd^k/(s + wd)^k; then one state per
    # high-pass q' = -wc q + r_f (output r_f - wc q = s/(s + wc) r_f)
    coeffs = np.poly(np.full(k, -wd))
    Ar1 = np.zeros((k, k))
    Ar1[:-1, 1:] = np.eye(k - 1)
    Ar1[-1] = -coeffs[1:][::-1]
    nh = len(hps)
    na = k + nh
    Ar = np.zeros((na, na))
    Ar[:k, :k] = Ar1
    Br = np.zeros((na, 1))
    Br[k - 1, 0] = wd ** k
    for i, fc in enumerate(hps):
        Ar[k + i, 0] = 1.0
        Ar[k + i, k + i] = -2 * math.pi * fc
    rows_C, rows_D = [], []
    hp_i = 0
    for kind, v in basis:               # one output row per basis function
        c = np.zeros(na)
        dd = 0.0
        if kind == "hp":
            c[0] = 1.0
            c[k + hp_i] = -2 * math.pi * float(v)
            hp_i += 1
        else:
            m = int(v)
            if m < k:
                c[m] = 1.0
            else:                       # the k-th derivative: last row of the companion form
                c[:k] = Ar1[-1]
                dd = wd ** k
        rows_C.append(c)
        rows_D.append(dd)
    Cb, Db = np.array(rows_C), np.array(rows_D)
    A = block_diag(*[Ar] * n)
    B = block_diag(*[Br] * n)
    nu = P.shape[1]
    C_ff = np.zeros((nu, A.shape[0]))
    D_ff = np.zeros((nu, n))
    for ax in range(n):
        sl = slice(ax * na, (ax + 1) * na)
        for m in range(len(basis)):
            C_ff[:, sl] += np.outer(P[m][:, ax], Cb[m])
            D_ff[:, ax] += P[m][:, ax] * Db[m]
    C_rf = np.zeros((n, A.shape[0]))
    for ax in range(n):
        C_rf[ax, ax * na] = 1.0
    R = ct.ss(A, B, np.vstack([C_rf, C_ff]), np.vstack([np.zeros((n, n)), D_ff]))       # r -> [r_f; u_ff_raw]
    if notch_hz:
        s = ct.tf("s")
        Ns = 1
        for fm in notch_hz:
            w = 2 * math.pi * fm
            Ns = Ns * (s * s + w * w) / (s * s + 2 * notch_zeta * w * s + w * w)
        Nss = ct.ss(Ns)
        Nm = ct.ss(*(block_diag(*[np.asarray(getattr(Nss, mm), float)] * nu) for mm in "ABCD"))
        Id = ct.ss(np.zeros((0, 0)), np.zeros((0, n)), np.zeros((n, 0)), np.eye(n))
        R = ct.ss(ct.append(Id, Nm) * R)
    Rd = ct.ss(ct.c2d(R, dt, "tustin"))
    # interconnect with the base [Ke, Ky] (inputs [e_b; y]); overall inputs [e; y], r = e + y
    Kb = base.K
    Ak, Bk, Ck, Dk = (np.asarray(m, float) for m in (Kb.A, Kb.B, Kb.C, Kb.D))
    two = Bk.shape[1] > n
    Bke, Bky = Bk[:, :n], (Bk[:, n:] if two else np.zeros((Ak.shape[0], n)))
    Dke, Dky = Dk[:, :n], (Dk[:, n:] if two else np.zeros((Dk.shape[0], n)))
    Ar_, Br_, Cr_, Dr_ = (np.asarray(m, float) for m in (Rd.A, Rd.B, Rd.C, Rd.D))
    Crf, Cff = Cr_[:n], Cr_[n:]
    Drf, Dff = Dr_[:n], Dr_[n:]
    # r = e + y ; e_b = r_f - y = Crf xr + Drf (e + y) - y
    I = np.eye(n)
    A_tot = np.block([[Ar_, np.zeros((Ar_.shape[0], Ak.shape[0]))],
                      [Bke @ Crf, Ak]])
    B_e = np.vstack([Br_, Bke @ Drf])
    B_y = np.vstack([Br_, Bke @ (Drf - I) + Bky])
    C_tot = np.hstack([Dke @ Crf + Cff, Ck])
    D_e = Dke @ Drf + Dff
    D_y = Dke @ (Drf - I) + Dky + Dff
    return ct.ss(A_tot, np.hstack([B_e, B_y]), C_tot, np.hstack([D_e, D_y]), dt)


def design_feedforward(G, *, dt: float = DT_S, delay_samples: int = IDENTIFIED_DELAY_SAMPLES, base=DEFAULT_BASE,
                       ref_ratio: float = 1.5, fit_ratio: float | None = None, order: int = POLY_ORDER,
                       notches: bool | None = None) -> BenchDesign:
    """Model-inversion feedforward on top of the feedback design ``base``.

    Parameters
    ----------
    G : control.StateSpace
        Identified plant (discrete at ``dt``, or continuous: Tustin), 3 x 3.
    dt : float
        Control period [s].
    delay_samples : int
        Loop delay [samples] the inverse compensates.
    base : str or BenchDesign
        The feedback design (a bench name, designed from ``G``, or a design).
    ref_ratio : float
        Reference-model corner = lowest mode / ``ref_ratio``.
    fit_ratio : float or None
        Top of the fit band = ``fit_ratio`` x lowest mode (default 0.9, or 0.5 with notches).
    order : int
        Highest derivative of the inverse (and order of the reference model).
    notches : bool or None
        Notch the command at the identified modes (default: when ``base`` has no damping path).

    Returns
    -------
    BenchDesign
        Two-degree-of-freedom controller, inputs ``[e; y]``.
    """
    from nanosim.design.architectures import design
    Gd = as_discrete(G, dt)
    fb = design(base, Gd, dt=dt, delay_samples=delay_samples) if isinstance(base, str) else base
    if not isinstance(fb, BenchDesign):
        raise ValueError(f"base: expected a bench name or a BenchDesign, got {type(base).__name__}")
    modes = distinct_modes_hz(Gd)
    f1 = modes[0] if modes else 0.25 / dt
    if notches is None:             # a base without a damping path leaves the modes undamped: notch the command
        notches = not fb.two_dof
    nmodes = modes if notches else []
    if fit_ratio is None:
        fit_ratio = 0.5 if notches else 0.9
    f = np.geomspace(FIT_LOW_HZ, fit_ratio * f1, 300)
    basis = default_basis(order)
    Ky = fb.split()[1]
    P = fit_inverse(Gd, f, basis, delay_samples=delay_samples, notch_hz=nmodes, Ky=Ky)
    ref_hz = f1 / ref_ratio
    K = feedforward_controller(fb, P, basis, ref_hz, nmodes, dt)
    Gf = loop_plant_response(Gd, f, delay_samples, Ky)
    Bf = basis_response(basis, f)
    Finv = sum(P[m][None] * Bf[:, m][:, None, None] for m in range(P.shape[0]))
    resid = Gf * _notch_response(f, nmodes, NOTCH_ZETA)[:, None, None] @ Finv - np.eye(Gf.shape[1])
    params = {"base": fb.name, "base_parameters": fb.parameters, "reference_model_hz": ref_hz,
              "reference_model_order": order, "fit_band_hz": [FIT_LOW_HZ, fit_ratio * f1],
              "inverse_fit_max_rel_error": float(np.linalg.norm(resid, 2, axis=(1, 2)).max()),
              "inverse_basis": [list(b) for b in basis], "inverse_coefficients": P.tolist(), "notch_hz": nmodes,
              "notch_zeta": NOTCH_ZETA,
              "static_highpass_hz": HIGHPASS_HZ, "loop_delay_samples": delay_samples}
    return BenchDesign("feedforward", K, fb.n_error, TUNING_RULE, params)
