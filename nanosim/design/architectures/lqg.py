"""(g) lqg: H2-optimal (LQG) output feedback with integral action, from the stage's known noise levels.

On this stage the closed-loop resolution is set by the DAC noise, an input disturbance that rings the
lightly damped first XY pair. Minimising the output variance for a known input-noise spectrum is the
linear-quadratic-Gaussian problem [1]_, so this design solves it directly on the
identified model as the loop runs it::

    plant       x+ = A x + B (u + w + d),  y = C x + v
    disturbance d+ = a_d d + w_d                                    (hysteresis and creep at the piezo input)
    integrator  xi+ = a xi + e,  e = r - y                          (a: leak at LEAK_HZ)
    estimator   [x; d]_k|k = [x; d]_k|k-1 + M (y_k - C [x]_k|k-1)        (steady-state Kalman, current form)
    command     u = -K_x x_k|k - d_k|k - K_i xi

* ``w``: DAC white noise per sample (:data:`nanosim.constants.DAC_WHITE_NOISE_V`), entering at the
  plant input; ``v``: gauge noise per sample (:func:`gauge_noise_per_sample_V`, the gauge's white
  density over the Nyquist band) times a measurement inflation. The inflation trades noise optimality
  for robustness: a less trusting estimator has a smaller high-frequency gain (the loop-transfer-recovery
  trade-off [2]_).
* ``d``: the piezo's hysteresis and creep act as an input disturbance. A first-order process with a
  :data:`DISTURBANCE_CORNER_HZ` corner in the estimator gives a disturbance observer, and the command
  cancels the estimate (``- d_k|k``): input-side integral action against the hysteresis of a ramp. Its
  intensity (:func:`disturbance_noise_V`) is a noise-first design choice, not a measured quantity: the
  residual of the identification referred to the input
  (:func:`identification.residual.input_referred_residual`) is mostly hysteresis, which follows the
  command rather than the white-driven process a Kalman filter assumes.
* LQR cost ``sum y'y + Q_I xi'xi + R_U u'u`` in sensor and controller volts
  (:data:`INTEGRAL_WEIGHT`, :data:`CONTROL_WEIGHT`).

The estimator is the current (a posteriori) form ([3]_, Sec. 8.2), so the command of sample ``k`` uses
the reading of sample ``k``.

Tuning rules
------------
Robust rule (the exported default, :data:`ROBUST_TUNING_RULE`). The identified model holds the piezo's slope
after a reversal, the low end of the uncertainty set's gain range
(:data:`~nanosim.design.robustness.IDENTIFIED_INPUT_GAIN_OF_NOMINAL`); a monotone move (a step, a ramp) runs
at up to the nominal slope, the top of the range, which the linear twin holds. So the design model's piezo
gain is placed inside the range (:func:`design_input_gains`, fractions :data:`ROBUST_GAIN_FRACTIONS` of the
log range from its centre to its top). Its structural modes above :data:`SHIFT_ABOVE_HZ` are moved up by
the factors :data:`ROBUST_FREQ_SCALES` (:func:`shifted_modes`): an LQG designed at the identified frequencies
loses its phase quickly just above those modes, and the set allows them a few per cent higher together
with one more sample of delay; designed for modes above the set's top, the controller's phase holds over
the set. Each member of :data:`ROBUST_GAIN_FRACTIONS` x :data:`ROBUST_LADDER` (frequency scale, inflation,
``R_U``) is designed; in the order of their predicted DAC- and gauge-noise sigma
(:func:`predicted_noise_sigma_nm`), the first is taken that

1. has a multiloop disk margin of at least :data:`ROBUST_MIN_DISK_MARGIN` on the identified model
   [4]_,
2. is stable at every vertex and sample of :data:`~nanosim.design.uncertainty.STAGE_UNCERTAINTY`
   (:func:`~nanosim.design.architectures.common.uncertainty_vertex_check`), and
3. has a mixed real/complex mu upper bound below :data:`ROBUST_MU_MAX` over it
   (:func:`~nanosim.design.parametric.robust_stability_mixed_mu`, [5]_), as
   ``robustness.json`` reports it.

At most :data:`ROBUST_MAX_MU_CHECKS` mu analyses are run; if none passes, the checked member with the least
mu is returned with ``parameters["robust_rule_met"]`` False. ``parameters["tried"]`` records why each cheaper
member was passed over.

Nominal rule (``robust=False``, :data:`TUNING_RULE`): the identified frequencies and gain, the inflations
:data:`MEASUREMENT_INFLATION` tried in order until the multiloop disk margin reaches :data:`MIN_DISK_MARGIN`.
It is not checked over the uncertainty set.

Gain-range rule (``gain_range_margin=True``, the bench's ``lqg-gain-range``): the robust rule asks its disk
margin on the identified model, the low end of the gain range; this rule designs at
:data:`GAIN_RANGE_FRACTIONS` of the top of the range and asks the margin at both ends. It buys margin on the
twin (a monotone move's slope) with bandwidth and settling: the disturbance observer's closed-loop pole is
cancelled by the reference path only at the design gain, and a loop designed at the top runs its steps below
it.

Bandwidth rule (``seek_bandwidth=True``, ``lqg-bandwidth``): the robust rule fixes the loop's speed by its
weight ``R_U``, so a flexure sweep redesigned by it says little about what the mechanics allow. This rule runs
the robust rule at each weight of :data:`BANDWIDTH_CONTROL_WEIGHTS`, smallest first, and takes the first pick
that meets every check, without the reference prefilter. Robustness is not monotone in bandwidth across the
ladder's scales and inflations, so the weights are scanned rather than bisected. Its checks are made on the
identified model; they do not carry to the top of the gain range (the gain-range rule asks there). It measures
what the mechanics allow; it is not a default.

Reference prefilter (``reference_prefilter=True``, :mod:`~nanosim.design.architectures.prefilter`): a step
excites a lightly damped closed-loop pair of the reference-to-output map; a notch on the reference at that
pair, the same on every axis, removes the ring without touching the feedback operator (so every margin, mu
and noise figure is unchanged), at the price of a fraction of a millisecond of reference delay.

``parameters["spectral_radius_small_signal_gain"]`` reports, not as a criterion, the loop at
:data:`SMALL_SIGNAL_GAIN` x the identified input gain, the piezo's tangent slope at the end of a long monotone
move, above the set's top.

Delay and inputs
----------------
``nanosim identify`` pairs each command with the reading the controller had when it computed it, so the
identified model is the loop as run (``delay_samples = 0``,
:data:`nanosim.design.robustness.IDENTIFIED_DELAY_SAMPLES`, as ``nanosim design`` and the robustness analysis
use it); ``delay_samples = d`` adds ``z^-d`` registers for a model identified from record rows.

Inputs ``[e; y]`` like every two-degree-of-freedom bench controller: the estimator reads ``y``, the
integrator ``e``; the reference enters through the integrator only (no kick on steps), after the reference
prefilter. What these rules give on the stage is on the documentation's explanation page of the default
controller and in the generated validation page.

References
----------
.. [1] H. Kwakernaak and R. Sivan, *Linear Optimal Control Systems*, Wiley, 1972.
.. [2] J. C. Doyle and G. Stein, "Robustness with observers", IEEE TAC 24(4), 1979.
.. [3] G. F. Franklin, J. D. Powell and M. Workman, *Digital Control of Dynamic Systems*, 3rd ed., 1998.
.. [4] P. Seiler, A. Packard and P. Gahinet, "An introduction to disk margins", IEEE Control Systems
   Magazine 40(5), 2020.
.. [5] P. M. Young, M. P. Newlin and J. C. Doyle, "Computing bounds for the mixed mu problem", Int. J.
   Robust Nonlinear Control 5(6), 1995.
"""
from __future__ import annotations

import math
import warnings
from typing import NamedTuple

import numpy as np

from nanosim import constants
from nanosim.design.loopargs import check_scale
from nanosim.design.robustness import IDENTIFIED_DELAY_SAMPLES, IDENTIFIED_INPUT_GAIN_OF_NOMINAL
from nanosim.design.architectures.common import (
    DT_S,
    LEAK_HZ,
    BenchDesign,
    analysis_grid_hz,
    as_discrete,
    closed_loop_spectral_radius,
    disk_margin_summary,
    freqresp_z,
    loop_response,
    reference_error_bandwidth_hz,
    sensitivity_bandwidth_hz,
    uncertainty_vertex_check,
)

__all__ = ["design_lqg", "lqg_controller", "delay_augmented", "TUNING_RULE", "CONTROL_WEIGHT", "INTEGRAL_WEIGHT",
           "MEASUREMENT_INFLATION", "DEFAULT_LADDER", "ROBUST_TUNING_RULE",
           "MIN_DISK_MARGIN", "DISTURBANCE_NOISE_V", "ROBUST_LADDER", "ROBUST_FREQ_SCALES",
           "ROBUST_INFLATIONS", "ROBUST_MIN_DISK_MARGIN", "ROBUST_MU_MAX", "ROBUST_MAX_MU_CHECKS",
           "DISTURBANCE_CORNER_HZ", "DESIGN_FREQ_SCALE", "SHIFT_ABOVE_HZ", "SMALL_SIGNAL_GAIN",
           "GAIN_RANGE_FRACTIONS", "GAIN_RANGE_TUNING_RULE", "BANDWIDTH_CONTROL_WEIGHTS", "BANDWIDTH_TUNING_RULE",
           "gauge_noise_per_sample_V", "shifted_modes", "design_input_gains", "ROBUST_GAIN_FRACTIONS",
           "predicted_noise_sigma_nm", "disturbance_noise_V"]

CONTROL_WEIGHT = 0.03
INTEGRAL_WEIGHT = 0.03
MEASUREMENT_INFLATION = (3.0, 4.0, 5.0, 7.0, 10.0)
# the nominal rule: the inflation ladder at R_u = CONTROL_WEIGHT, tried in order until the disk margin holds
DEFAULT_LADDER = tuple((i, CONTROL_WEIGHT) for i in MEASUREMENT_INFLATION)
MIN_DISK_MARGIN = 0.45
DISTURBANCE_NOISE_V = 1e-5
DISTURBANCE_CORNER_HZ = 1.0
# the design model's structural modes above SHIFT_ABOVE_HZ (the second XY group and up; not the first XY pair nor
# the first Z mode) sit at or above the top of STAGE_UNCERTAINTY's frequency range
DESIGN_FREQ_SCALE = 1.03
SHIFT_ABOVE_HZ = 300.0
# the piezo's tangent slope after a long monotone move (nanosim.plant.piezo) over the identified model's slope;
# reported (parameters["spectral_radius_small_signal_gain"]), not a criterion
SMALL_SIGNAL_GAIN = 1.75
TUNING_RULE = ("LQG on the identified model (the loop as run): Kalman filter from the stage's DAC (input) "
               "and gauge (reading, inflated x3, more if the multiloop disk margin falls below "
               f"{MIN_DISK_MARGIN:g}) noise levels plus an input-disturbance observer (hysteresis, "
               f"{DISTURBANCE_CORNER_HZ:g} Hz process, {DISTURBANCE_NOISE_V:g} V per sample), LQR on the reading "
               f"and its leaky integral (R_u = {CONTROL_WEIGHT:g}, Q_i = {INTEGRAL_WEIGHT:g})")
PREFILTER_RULE = ("a reference prefilter notches the closed loop's ringing pairs (two degrees of freedom, the "
                  "feedback unchanged)")
# the robust rule's members (design frequency scale of the modes above SHIFT_ABOVE_HZ, measurement inflation, R_u)
ROBUST_FREQ_SCALES = (1.03, 1.035, 1.04, 1.045, 1.05)
ROBUST_INFLATIONS = (2.5, 3.0, 4.0, 5.0)
ROBUST_LADDER = tuple((s, i, CONTROL_WEIGHT) for s in ROBUST_FREQ_SCALES for i in ROBUST_INFLATIONS)
# the design model's piezo gain: these fractions of the uncertainty set's (log) gain range on the identified model,
# from its centre to its top (design_input_gains)
ROBUST_GAIN_FRACTIONS = (0.5, 0.75, 1.0)
# the gain-range rule (gain_range_margin=True): from the set's top upwards, inside the piezo's tangent slope after
# a long monotone move (SMALL_SIGNAL_GAIN)
GAIN_RANGE_FRACTIONS = (1.0, 1.25, 1.5)
ROBUST_MIN_DISK_MARGIN = 0.42
ROBUST_MU_MAX = 1.0
# at most this many mixed-mu analyses (the slow part of a design) per design
ROBUST_MAX_MU_CHECKS = 4
ROBUST_TUNING_RULE = ("LQG on the identified model (the loop as run), robust over the stage's uncertainty set: the "
                      "design model's piezo gain at the centre, upper quarter or top of the set's gain range (the "
                      "identified model holds its low end, the slope after a reversal), its "
                      f"structural modes above {SHIFT_ABOVE_HZ:g} Hz designed at x{ROBUST_FREQ_SCALES[0]:g}-"
                      f"{ROBUST_FREQ_SCALES[-1]:g}, measurement inflation {ROBUST_INFLATIONS[0]:g}-"
                      f"{ROBUST_INFLATIONS[-1]:g} (disturbance-observer intensity x inflation / 3), R_u = "
                      f"{CONTROL_WEIGHT:g}, Q_i = {INTEGRAL_WEIGHT:g}; of these, the member with the least predicted "
                      f"noise sigma that has a multiloop disk margin >= {ROBUST_MIN_DISK_MARGIN:g}, is stable at every "
                      f"vertex of the set and has a mixed-mu upper bound < {ROBUST_MU_MAX:g} over it")
# the bandwidth rule (seek_bandwidth=True): the robust rule at each of these LQR control weights R_u, smallest (the
# fastest loops) first, until one meets every check; from 1/300 of the robust rule's weight up to it
BANDWIDTH_CONTROL_WEIGHTS = (1e-4, 3e-4, 0.001, 0.003, 0.01, 0.03)
BANDWIDTH_TUNING_RULE = ("the robust rule below at the smallest LQR control weight R_u of "
                         + ", ".join(f"{w:g}" for w in BANDWIDTH_CONTROL_WEIGHTS)
                         + " (the fastest loops first) at which one of its members meets every check: ")
GAIN_RANGE_TUNING_RULE = (ROBUST_TUNING_RULE.replace(
    "at the centre, upper quarter or top of the set's gain range", "at 1, 1.07 or 1.15 x the top of the set's gain "
    "range").replace(f"a multiloop disk margin >= {ROBUST_MIN_DISK_MARGIN:g}", f"a multiloop disk margin >= "
                     f"{ROBUST_MIN_DISK_MARGIN:g} at both ends of the set's gain range"))


def gauge_noise_per_sample_V(dt: float = DT_S) -> float:
    """Gauge noise per sample [sensor V]: the white density over the Nyquist band."""
    nm_rthz = constants.SENSOR_NOISE_NM_RMS_1KHZ / np.sqrt(1000.0)     # 0.3 nm in 1 kHz: 9.5 pm/sqrt(Hz)
    return float(nm_rthz * np.sqrt(0.5 / dt) / (constants.SENSOR_UM_PER_V * 1e3))


def delay_augmented(Gd, delay_samples: int = 0):
    """``(A, B, C)`` of ``z^-d Gd`` with the delay registers after the plant states (no feedthrough).

    ``d = 0``: ``Gd`` itself without its ``D``. A model from ``nanosim identify`` pairs each command
    with the reading the controller had when it computed it, so the command cannot reach the
    reading of its own sample: its fitted ``D`` (about 1 % of the static gain) is estimation error.
    ``d >= 1``: the last ``nu`` states are the register the command enters, the first feeds the plant.
    """
    A, B, C, D = (np.asarray(m, float) for m in (Gd.A, Gd.B, Gd.C, Gd.D))
    n, m = A.shape[0], B.shape[1]
    d = int(delay_samples)
    if d < 0:
        raise ValueError(f"delay_samples: expected >= 0, got {delay_samples!r}")
    if d == 0:
        return A.copy(), B.copy(), C.copy()
    nq = d * m
    Aa = np.zeros((n + nq, n + nq))
    Aa[:n, :n] = A
    Aa[:n, n:n + m] = B                                  # register 1 feeds the plant
    for j in range(1, d):                                # register j+1 -> register j
        Aa[n + (j - 1) * m:n + j * m, n + j * m:n + (j + 1) * m] = np.eye(m)
    Ba = np.zeros((n + nq, m))
    Ba[n + (d - 1) * m:] = np.eye(m)
    Ca = np.zeros((C.shape[0], n + nq))
    Ca[:, :n] = C
    Ca[:, n:n + m] = D
    return Aa, Ba, Ca


def lqg_controller(Gd, *, control_weight: float = CONTROL_WEIGHT, integral_weight: float = INTEGRAL_WEIGHT,
                   measurement_inflation: float = MEASUREMENT_INFLATION[0],
                   delay_samples: int = IDENTIFIED_DELAY_SAMPLES, disturbance_noise_V: float = DISTURBANCE_NOISE_V,
                   disturbance_corner_hz: float = DISTURBANCE_CORNER_HZ,
                   input_noise_V: float = constants.DAC_WHITE_NOISE_V, measurement_noise_V: float | None = None):
    """The discrete ``[e; y] -> u`` LQG controller of the module docstring.

    ``disturbance_noise_V`` = 0: no disturbance observer (LQG with integral action only).

    Returns
    -------
    control.StateSpace
        States: estimate of ``[x; q; d]``, then the integrators; sample time of ``Gd``.
    """
    import control as ct
    import scipy.linalg as sla
    for nm, v in (("control_weight", control_weight), ("integral_weight", integral_weight),
                  ("measurement_inflation", measurement_inflation)):
        if not (np.isfinite(v) and v > 0):
            raise ValueError(f"{nm}: expected a positive number, got {v!r}")
    if not (np.isfinite(disturbance_noise_V) and disturbance_noise_V >= 0):
        raise ValueError(f"disturbance_noise_V: expected a number >= 0, got {disturbance_noise_V!r}")
    dt = float(Gd.dt)
    Ab, Bb, Cb = delay_augmented(Gd, delay_samples)          # [x; q]
    nb, m, p = Ab.shape[0], Bb.shape[1], Cb.shape[0]
    n = np.asarray(Gd.A).shape[0]
    B, D = np.asarray(Gd.B, float), np.asarray(Gd.D, float)
    use_d = disturbance_noise_V > 0
    nd = m if use_d else 0
    ne = nb + nd
    Ae = np.zeros((ne, ne))
    Ae[:nb, :nb] = Ab
    Ce = np.zeros((p, ne))
    Ce[:, :nb] = Cb
    if use_d:                                                 # d enters with the plant's input
        Ae[:n, nb:] = B
        Ae[nb:, nb:] = np.exp(-2 * np.pi * disturbance_corner_hz * dt) * np.eye(m)
        if delay_samples:
            Ce[:, nb:] = D
    Be = np.vstack([Bb, np.zeros((nd, m))])
    v_V = gauge_noise_per_sample_V(dt) if measurement_noise_V is None else float(measurement_noise_V)
    W = np.zeros((ne, ne))
    Bw = np.zeros((nb, m))                                    # DAC noise enters with the plant's input
    Bw[:n] = B
    W[:nb, :nb] = Bw @ Bw.T * input_noise_V ** 2
    if use_d:
        W[nb:, nb:] = disturbance_noise_V ** 2 * np.eye(m)
    V = (measurement_inflation * v_V) ** 2 * np.eye(p)
    P = sla.solve_discrete_are(Ae.T, Ce.T, W, V)
    M = P @ Ce.T @ np.linalg.inv(Ce @ P @ Ce.T + V)
    leak = float(np.exp(-2 * np.pi * LEAK_HZ * dt))
    Ai = np.block([[Ab, np.zeros((nb, p))], [-Cb, leak * np.eye(p)]])
    Bi = np.vstack([Bb, np.zeros((p, m))])
    Cy = np.hstack([Cb, np.zeros((p, p))])
    Q = Cy.T @ Cy + sla.block_diag(np.zeros((nb, nb)), integral_weight * np.eye(p))
    R = control_weight * np.eye(m)
    S = sla.solve_discrete_are(Ai, Bi, Q, R)
    K = np.linalg.solve(R + Bi.T @ S @ Bi, Bi.T @ S @ Ai)
    Kx = np.hstack([K[:, :nb], np.eye(m)]) if use_d else K[:, :nb]      # the command cancels d
    Ki = K[:, nb:]
    F = np.eye(ne) - M @ Ce
    Acl = Ae - Be @ Kx
    Ak = np.block([[Acl @ F, -Be @ Ki], [np.zeros((p, ne)), leak * np.eye(p)]])
    Bk_e = np.vstack([np.zeros((ne, p)), np.eye(p)])
    Bk_y = np.vstack([Acl @ M, np.zeros((p, p))])
    Ck = np.hstack([-Kx @ F, -Ki])
    return ct.ss(Ak, np.hstack([Bk_e, Bk_y]), Ck, np.hstack([np.zeros((m, p)), -Kx @ M]), dt)


def disturbance_noise_V(measurement_inflation: float) -> float:
    """Disturbance-observer intensity [V per sample] for a measurement inflation: proportional to it, so
    that the observer's bandwidth (set by the ratio of the two) stays that of inflation 3 (a less
    trusting estimator would otherwise reject the hysteresis of a step more slowly).
    """
    return DISTURBANCE_NOISE_V * float(measurement_inflation) / MEASUREMENT_INFLATION[0]


def shifted_modes(Gd, freq_scale: float = DESIGN_FREQ_SCALE, f_min_hz: float = SHIFT_ABOVE_HZ):
    """``Gd`` with its structural modes (pairs with ``zeta < 0.3`` up to 1 kHz, as
    :class:`~nanosim.design.uncertainty.ModalPlant`) above ``f_min_hz`` at ``freq_scale`` x their
    frequency, damping ratios and every mode's DC gain kept; the rest of ``Gd`` as it is.
    """
    import control as ct

    from nanosim.design.uncertainty import MODE_MAX_HZ, MODE_ZETA_MAX
    if not (np.isfinite(freq_scale) and freq_scale > 0):
        raise ValueError(f"freq_scale: expected a positive factor, got {freq_scale!r}")
    A, B, C, D = (np.asarray(m, float) for m in (Gd.A, Gd.B, Gd.C, Gd.D))
    dt = float(Gd.dt)
    lam, V = np.linalg.eig(A)
    with np.errstate(divide="ignore"):
        s = np.log(lam.astype(complex)) / dt
    w = np.abs(s)
    sel = (np.abs(s.imag) > 1e-9 * np.maximum(w, 1.0)) & (w > 2 * np.pi * f_min_hz) & \
        (w <= 2 * np.pi * MODE_MAX_HZ) & (-s.real < MODE_ZETA_MAX * w)
    lam2 = lam.copy()
    lam2[sel] = np.exp(s[sel] * freq_scale * dt)
    fac = np.ones(lam.size, complex)
    fac[sel] = (1.0 - lam2[sel]) / (1.0 - lam[sel])
    An = V @ np.diag(lam2) @ np.linalg.inv(V)
    Bn = V @ (fac[:, None] * np.linalg.solve(V, B.astype(complex)))
    return ct.ss(An.real, Bn.real, C, D, dt)


def predicted_noise_sigma_nm(Gd, K, n_error: int = 3, dt: float = DT_S) -> np.ndarray:
    """Closed-loop sigma [nm] of each reading-free plant output (the table) from the DAC white noise at
    the plant input and the gauge noise at the reading, on the discrete model ``Gd`` (no feedthrough)
    closed by ``u = Ke (r - y) + Ky y`` (stationary covariance, discrete Lyapunov equation).
    """
    import scipy.linalg as sla
    A, B, C = (np.asarray(m, float) for m in (Gd.A, Gd.B, Gd.C))
    Ak, Bk, Ck, Dk = (np.asarray(m, float) for m in (K.A, K.B, K.C, K.D))
    Bfb, Dfb = Bk[:, n_error:] - Bk[:, :n_error], Dk[:, n_error:] - Dk[:, :n_error]
    # y_meas = C x + v; u = Ck xk + Dfb y_meas; x+ = A x + B (u + w); xk+ = Ak xk + Bfb y_meas
    Acl = np.block([[A + B @ Dfb @ C, B @ Ck], [Bfb @ C, Ak]])
    Bw = np.vstack([B, np.zeros((Ak.shape[0], B.shape[1]))])
    Bv = np.vstack([B @ Dfb, Bfb])
    Q = constants.DAC_WHITE_NOISE_V ** 2 * Bw @ Bw.T + gauge_noise_per_sample_V(dt) ** 2 * Bv @ Bv.T
    X = sla.solve_discrete_lyapunov(Acl, Q)
    Cx = np.hstack([C, np.zeros((C.shape[0], Ak.shape[0]))])
    return np.sqrt(np.clip(np.diag(Cx @ X @ Cx.T), 0.0, None)) * constants.SENSOR_UM_PER_V * 1e3


def design_lqg(G, *, dt: float = DT_S, delay_samples: int = IDENTIFIED_DELAY_SAMPLES,
               min_disk_margin: float = MIN_DISK_MARGIN, robust: bool = True,
               reference_prefilter: bool = True, design_input_gain: float | None = None,
               gain_range_margin: bool = False, control_weight: float = CONTROL_WEIGHT,
               seek_bandwidth: bool = False) -> BenchDesign:
    """LQG with integral action by the rule of the module docstring.

    Parameters
    ----------
    G : control.StateSpace
        Identified plant (discrete at ``dt``, or continuous: Tustin), 3 x 3.
    dt : float
        Control period [s].
    delay_samples : int
        Loop delay [samples] in the design model and every check.
    min_disk_margin : float
        Smallest accepted multiloop disk margin of the nominal rule (identified model with the delay); the robust
        rule uses :data:`ROBUST_MIN_DISK_MARGIN`.
    robust : bool
        True (the exported default, :data:`ROBUST_TUNING_RULE`): the members of :data:`ROBUST_LADDER` (design
        modes above :data:`SHIFT_ABOVE_HZ` at x1.03-1.05, measurement inflation 2.5-5, ``R_u`` =
        :data:`CONTROL_WEIGHT`) in the order of their predicted noise sigma; the first with a multiloop disk
        margin >= :data:`ROBUST_MIN_DISK_MARGIN`, stable at every vertex and sample of the uncertainty set, and a
        mixed-mu upper bound below :data:`ROBUST_MU_MAX` over it (at most :data:`ROBUST_MAX_MU_CHECKS` mu
        analyses; else the checked member with the least mu, or without a vertex-stable member the one with the
        least worst vertex radius, with ``parameters["robust_rule_met"]`` False and a warning).
        False (the nominal rule, :data:`TUNING_RULE`): the nominal model, the inflation ladder at
        :data:`CONTROL_WEIGHT`, the first member with ``min_disk_margin``.
    reference_prefilter : bool
        Add the reference notch of :mod:`~nanosim.design.architectures.prefilter` at the loop's ringing
        pairs (default). The feedback operator, so every margin and mu, is the same either way.
    design_input_gain : float or None
        Factor on ``G``'s input gains in the design model (estimator and LQR; every check is on ``G``).
        None: each of :func:`design_input_gains` (robust rule; members of the ladder like the others), 1
        (nominal rule).
    gain_range_margin : bool
        Robust rule only. False (default): the multiloop disk margin is required on ``G`` and recorded at the top
        of the uncertainty set's gain range (``parameters["predicted_disk_margin_top_of_gain_range"]``). True
        (the ``lqg-gain-range`` bench design, :data:`GAIN_RANGE_TUNING_RULE`): required at both ends, with the
        design gains :data:`GAIN_RANGE_FRACTIONS`; if no member holds it at the top, the one with the largest
        margin there is taken (``robust_rule_met`` False, a warning).
    control_weight : float
        Robust rule: the LQR control weight ``R_u`` of its members (default :data:`CONTROL_WEIGHT`).
    seek_bandwidth : bool
        Robust rule only. True (the ``lqg-bandwidth`` design, :data:`BANDWIDTH_TUNING_RULE`): the robust rule at
        each control weight of :data:`BANDWIDTH_CONTROL_WEIGHTS`, smallest first, until its pick meets every check
        (``parameters["bandwidth_search"]`` records each weight tried); if none does, the pick with the least mu
        (``robust_rule_met`` False, a warning). The fastest loops the robust rule accepts.

    Returns
    -------
    BenchDesign
        Two-degree-of-freedom controller, inputs ``[e; y]``. ``parameters["uncertainty_vertices"]``
        holds the brute-force check (:func:`~nanosim.design.architectures.common.uncertainty_vertex_check`)
        of the chosen loop, ``parameters["mu_peak"]`` its mixed-mu bound (robust rule), ``parameters["tried"]``
        every member and the check that rejected it.

    Raises
    ------
    ValueError
        No member's nominal loop is stable with the disk margin (and, robust rule, at every vertex).
    """
    from nanosim.design.architectures.common import split_2dof
    from nanosim.design.uncertainty import ModalPlant
    if seek_bandwidth:
        if not robust:
            raise ValueError("seek_bandwidth: expected robust=True (the bandwidth rule runs the robust rule)")
        return _seek_bandwidth(G, dict(dt=dt, delay_samples=delay_samples, reference_prefilter=reference_prefilter,
                                       design_input_gain=design_input_gain, gain_range_margin=gain_range_margin))
    check_scale("control_weight", control_weight)
    Gd = as_discrete(G, dt)
    Gloop = _with_delay(Gd, delay_samples) if delay_samples else Gd
    f = analysis_grid_hz(dt, n=400)
    Gf = freqresp_z(Gd, f)
    ladder = (tuple((sc, i, control_weight) for sc, i, _ in ROBUST_LADDER) if robust
              else tuple((1.0, i, r) for i, r in DEFAULT_LADDER))
    if design_input_gain is not None:
        gains = (check_scale("design_input_gain", design_input_gain),)
    elif robust:
        gains = design_input_gains(GAIN_RANGE_FRACTIONS if gain_range_margin else ROBUST_GAIN_FRACTIONS)
    else:
        gains = (1.0,)
    members = []
    for g in gains:
        Gdes = _input_scaled(Gd, g)
        design_models = {s: shifted_modes(Gdes, s) if s != 1.0 else Gdes for s in dict.fromkeys(m[0] for m in ladder)}
        for scale, infl, ru in ladder:
            dn = disturbance_noise_V(infl) if robust else DISTURBANCE_NOISE_V
            K = lqg_controller(design_models[scale], delay_samples=delay_samples, measurement_inflation=infl,
                               control_weight=ru, disturbance_noise_V=dn)
            Ke, Ky = split_2dof(K, Gd.noutputs)
            rho = closed_loop_spectral_radius(Gd, Ke, Ky, delay_samples)
            sig = float(predicted_noise_sigma_nm(Gloop, K)[:2].max()) if rho < 1.0 else float("inf")
            members.append(_Member(sig, scale, infl, ru, dn, K, rho, g))
    if robust:
        members.sort(key=lambda m: m.sigma_nm)
    min_dm = ROBUST_MIN_DISK_MARGIN if robust else min_disk_margin
    gain_top = design_input_gains((1.0,))[0]          # the set's top on the identified model (the linear twin's gain)
    tried, best, fallback, short_top, n_mu = [], None, None, None, 0
    check_top = robust and gain_range_margin
    for m in members:
        row = {"design_input_gain": m.gain, "design_freq_scale": m.scale, "measurement_inflation": m.inflation,
               "control_weight": m.ru,
               "predicted_sigma_nm": m.sigma_nm, "spectral_radius": m.rho}
        tried.append(row)
        if m.rho >= 1.0:
            continue
        Ke, Ky = split_2dof(m.K, Gd.noutputs)
        r = loop_response(Gf, f, Ke, Ky, delay_samples=delay_samples, dt=dt)
        dm = disk_margin_summary(r)
        row["multiloop_disk_margin"] = dm["multiloop"]
        if dm["multiloop"] < min_dm:
            continue
        dm_top = disk_margin_summary(loop_response(Gf * gain_top, f, Ke, Ky, delay_samples=delay_samples, dt=dt))
        row["multiloop_disk_margin_top"] = dm_top["multiloop"]
        if check_top and dm_top["multiloop"] < min_dm:
            if short_top is None or dm_top["multiloop"] > short_top.disk_margin_top["multiloop"]:
                short_top = m._replace(response=r, disk_margin=dm, disk_margin_top=dm_top)
            continue
        v = uncertainty_vertex_check(Gloop, Ke, Ky, input_gain_of_nominal=IDENTIFIED_INPUT_GAIN_OF_NOMINAL)
        row["worst_spectral_radius"] = v["worst_spectral_radius"]
        cand = m._replace(response=r, disk_margin=dm, vertices=v, disk_margin_top=dm_top)
        if not robust:
            best = cand
            break
        if fallback is None or v["worst_spectral_radius"] < fallback.vertices["worst_spectral_radius"]:
            fallback = cand
        if not v["all_stable"] or n_mu >= ROBUST_MAX_MU_CHECKS:
            continue
        mu = _mixed_mu_peak(Gloop, m.K, Gd.noutputs)
        n_mu += 1
        row["mu_peak"] = mu
        cand = cand._replace(mu=mu)
        if best is None or mu < best.mu:
            best = cand
        if mu < ROBUST_MU_MAX:
            break
    if best is None:
        best = fallback
    took_short_top = best is None and short_top is not None
    if took_short_top:
        Ke, Ky = split_2dof(short_top.K, Gd.noutputs)
        best = short_top._replace(vertices=uncertainty_vertex_check(
            Gloop, Ke, Ky, input_gain_of_nominal=IDENTIFIED_INPUT_GAIN_OF_NOMINAL))
    if best is None:
        raise ValueError(f"G: no LQG loop of the rule is stable with a multiloop disk margin >= {min_dm}"
                         f"{' at the identified gain' if check_top else ''}: {tried}")
    sig, scale, infl, ru, dn, K, rho, design_input_gain, r, dm, v, mu, dm_top = best
    met = (mu is not None and mu < ROBUST_MU_MAX and not took_short_top) if robust else True
    if took_short_top:
        warnings.warn(f"G: no member of the robust LQG rule has a multiloop disk margin >= {min_dm:g} at the top of "
                      f"the uncertainty set's gain range (x{gain_top:.3g} the identified gain; taken: the largest, "
                      f"{dm_top['multiloop']:.3g}); parameters['robust_rule_met'] is False", stacklevel=2)
    elif not met:
        warnings.warn(f"G: no member of the robust LQG rule has mixed mu < {ROBUST_MU_MAX:g} over the uncertainty set "
                      f"(taken: {'mu %.3g' % mu if mu is not None else 'the least worst vertex radius'}); "
                      "parameters['robust_rule_met'] is False", stacklevel=2)
    prefilter = None
    if reference_prefilter:
        from nanosim.design.architectures.prefilter import design_reference_prefilter
        K_fb = K
        K, prefilter = design_reference_prefilter(Gd, K, Gd.noutputs, delay_samples=delay_samples, dt=dt)
        if K is not K_fb:           # the reference path changed: its response to the reference too
            r = loop_response(Gf, f, *split_2dof(K, Gd.noutputs), delay_samples=delay_samples, dt=dt)
    Ke, Ky = split_2dof(K, Gd.noutputs)
    Pup = ModalPlant(Gd, dt).state_space(1.0, 1.0, SMALL_SIGNAL_GAIN, delay_samples)
    params = {"rule": "robust" if robust else "nominal", "robust_rule_met": met, "uncertainty_vertices": v,
              "design_input_gain": float(design_input_gain),
              "mu_peak": mu,
              "design_freq_scale": scale, "shift_above_hz": SHIFT_ABOVE_HZ,
              "disturbance_noise_V": dn, "disturbance_corner_hz": DISTURBANCE_CORNER_HZ,
              "tried": tried, "control_weight": ru, "integral_weight": INTEGRAL_WEIGHT,
              "measurement_inflation": infl, "input_noise_V": constants.DAC_WHITE_NOISE_V,
              "measurement_noise_V": gauge_noise_per_sample_V(dt), "controller_order": int(K.nstates),
              "predicted_bandwidth_S_hz": sensitivity_bandwidth_hz(r),
              "predicted_bandwidth_ref_to_error_hz": reference_error_bandwidth_hz(r),
              "predicted_bandwidth_ref_to_error_top_hz": reference_error_bandwidth_hz(
                  loop_response(Gf * gain_top, f, Ke, Ky, delay_samples=delay_samples, dt=dt)),
              "predicted_disk_margin": dm,
              "predicted_disk_margin_top_of_gain_range": dm_top, "top_of_gain_range": float(gain_top),
              "gain_range_margin": bool(check_top),
              "predicted_noise_sigma_nm": sig, "closed_loop_spectral_radius": rho,
              "spectral_radius_small_signal_gain": closed_loop_spectral_radius(Pup, Ke, Ky, 0),
              "loop_delay_samples": delay_samples, "reference_prefilter": prefilter}
    rule = (GAIN_RANGE_TUNING_RULE if check_top else ROBUST_TUNING_RULE) if robust else TUNING_RULE
    if robust and control_weight != CONTROL_WEIGHT:
        rule = rule.replace(f"R_u = {CONTROL_WEIGHT:g}", f"R_u = {control_weight:g}")
    if prefilter is not None:
        rule += "; " + PREFILTER_RULE
    return BenchDesign("lqg", K, Gd.noutputs, rule, params)


def _seek_bandwidth(G, kw: dict) -> BenchDesign:
    """The bandwidth rule (``design_lqg(seek_bandwidth=True)``): the robust rule at each control weight of
    :data:`BANDWIDTH_CONTROL_WEIGHTS`, smallest first, until its pick meets every check.
    """
    import dataclasses

    levels, picks = [], []
    for w in BANDWIDTH_CONTROL_WEIGHTS:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", UserWarning)          # a weight whose pick fails: the next weight
            try:
                d = design_lqg(G, control_weight=w, **kw)
            except ValueError as exc:                             # no member stable with the disk margin
                levels.append({"control_weight": w, "error": str(exc)[:200]})
                continue
        p = d.parameters
        levels.append({"control_weight": w, "robust_rule_met": p["robust_rule_met"], "mu_peak": p["mu_peak"],
                       "predicted_bandwidth_S_hz": p["predicted_bandwidth_S_hz"],
                       "members_tried": len(p["tried"])})
        picks.append(d)
        if p["robust_rule_met"]:
            break
    if not picks:
        raise ValueError(f"G: no LQG loop of the bandwidth rule is stable with the disk margin at any control weight "
                         f"{BANDWIDTH_CONTROL_WEIGHTS}")
    d = picks[-1]
    if not d.parameters["robust_rule_met"]:
        d = min(picks, key=lambda x: math.inf if x.parameters["mu_peak"] is None else x.parameters["mu_peak"])
        warnings.warn(f"G: at no control weight of {BANDWIDTH_CONTROL_WEIGHTS} does the robust LQG rule meet every "
                      f"check (taken: R_u {d.parameters['control_weight']:g}, mu {d.parameters['mu_peak']}); "
                      "parameters['robust_rule_met'] is False", stacklevel=3)
    params = dict(d.parameters, rule="bandwidth", bandwidth_search=levels)
    return dataclasses.replace(d, tuning_rule=BANDWIDTH_TUNING_RULE + d.tuning_rule, parameters=params)


class _Member(NamedTuple):
    """A member of a rule's ladder and, once checked, its loop figures."""

    sigma_nm: float
    scale: float
    inflation: float
    ru: float
    dn: float
    K: object
    rho: float
    gain: float = 1.0
    response: object = None
    disk_margin: dict | None = None
    vertices: dict | None = None
    mu: float | None = None
    disk_margin_top: dict | None = None


def _mixed_mu_peak(Gloop, K, n_error: int) -> float:
    """Mixed-mu upper bound over :data:`~nanosim.design.uncertainty.STAGE_UNCERTAINTY` of the loop (``inf`` when a
    centre loop is unstable), as ``robustness.json`` reports it.
    """
    from nanosim.design.robustness import LoopPlant, analyze_controller
    s = analyze_controller(K, LoopPlant.identified(Gloop, 0), n_error=n_error).summary
    return float("inf") if s.get("mu_peak") is None else float(s["mu_peak"])


def design_input_gains(fractions=ROBUST_GAIN_FRACTIONS, uncertainty=None) -> tuple:
    """Piezo gains of the robust rule's design models: ``fractions`` of the uncertainty set's log gain range
    on an identified model (0: its low end, 0.5: its geometric centre, 1: its top), factors on the model's gain.

    The identified model holds the slope after a reversal
    (:data:`~nanosim.design.robustness.IDENTIFIED_INPUT_GAIN_OF_NOMINAL` of nominal, the set's low end); a
    monotone move runs at up to nominal, 1.36 x the identified gain.
    """
    from nanosim.design.uncertainty import STAGE_UNCERTAINTY
    lo, hi = (STAGE_UNCERTAINTY if uncertainty is None else uncertainty).input_gain_range_about(
        IDENTIFIED_INPUT_GAIN_OF_NOMINAL)
    return tuple(float(lo * (hi / lo) ** float(q)) for q in fractions)


def _input_scaled(Gd, gain: float):
    """``Gd`` with every input channel's gain times ``gain``."""
    import control as ct
    if gain == 1.0:
        return Gd
    return ct.ss(Gd.A, np.asarray(Gd.B, float) * gain, Gd.C, np.asarray(Gd.D, float) * gain, Gd.dt)


def _with_delay(Gd, delay_samples: int):
    import control as ct
    A, B, C = delay_augmented(Gd, delay_samples)
    return ct.ss(A, B, C, np.zeros((C.shape[0], B.shape[1])), Gd.dt)
