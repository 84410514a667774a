"""The LQG controller of the lqg bench designs: its synthesis from the stage's noise levels and its design model.

On this stage the closed-loop resolution is set by the DAC noise, an input disturbance that rings the
lightly damped first XY pair. Minimising the output variance for a known input-noise spectrum is the
linear-quadratic-Gaussian problem [1]_, solved here on the identified model as the loop runs it::

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

The design model: :func:`shifted_modes` moves the structural modes above :data:`SHIFT_ABOVE_HZ`,
:func:`design_input_gains` places the piezo gain inside the uncertainty set's range;
:func:`predicted_noise_sigma_nm` is the closed-loop noise figure the rules rank their members by.
The rules that pick the loop are in :mod:`~nanosim.design.architectures.lqg_rules`, the design in
:mod:`~nanosim.design.architectures.lqg`.

References
----------
.. [1] H. Kwakernaak and R. Sivan, *Linear Optimal Control Systems*, Wiley, 1972.
.. [2] J. C. Doyle and G. Stein, "Robustness with observers", IEEE TAC 24(4), 1979.
.. [3] G. F. Franklin, J. D. Powell and M. Workman, *Digital Control of Dynamic Systems*, 3rd ed., 1998.
"""
from __future__ import annotations

import numpy as np

from nanosim import constants
from nanosim.design.robustness import IDENTIFIED_DELAY_SAMPLES, IDENTIFIED_INPUT_GAIN_OF_NOMINAL
from nanosim.design.architectures.common import DT_S, LEAK_HZ

__all__ = ["lqg_controller", "delay_augmented", "CONTROL_WEIGHT", "INTEGRAL_WEIGHT", "MEASUREMENT_INFLATION",
           "DISTURBANCE_NOISE_V", "DISTURBANCE_CORNER_HZ", "DESIGN_FREQ_SCALE", "SHIFT_ABOVE_HZ",
           "SMALL_SIGNAL_GAIN", "ROBUST_GAIN_FRACTIONS", "gauge_noise_per_sample_V", "shifted_modes",
           "design_input_gains", "predicted_noise_sigma_nm", "disturbance_noise_V", "input_scaled", "with_delay"]

CONTROL_WEIGHT = 0.03
INTEGRAL_WEIGHT = 0.03
MEASUREMENT_INFLATION = (3.0, 4.0, 5.0, 7.0, 10.0)
DISTURBANCE_NOISE_V = 1e-5
DISTURBANCE_CORNER_HZ = 1.0
# the design model's structural modes above SHIFT_ABOVE_HZ (the second XY group and up; not the first XY pair nor
# the first Z mode) sit at or above the top of STAGE_UNCERTAINTY's frequency range
DESIGN_FREQ_SCALE = 1.03
SHIFT_ABOVE_HZ = 300.0
# the piezo's tangent slope after a long monotone move (nanosim.plant.piezo) over the identified model's slope;
# reported (parameters["spectral_radius_small_signal_gain"]), not a criterion
SMALL_SIGNAL_GAIN = 1.75
# the design model's piezo gain of the robust rule: these fractions of the uncertainty set's (log) gain range on the
# identified model, from its centre to its top (design_input_gains)
ROBUST_GAIN_FRACTIONS = (0.5, 0.75, 1.0)


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


def input_scaled(Gd, gain: float):
    """``Gd`` with every input channel's gain times ``gain``."""
    import control as ct
    if gain == 1.0:
        return Gd
    return ct.ss(Gd.A, np.asarray(Gd.B, float) * gain, Gd.C, np.asarray(Gd.D, float) * gain, Gd.dt)


def with_delay(Gd, delay_samples: int):
    """``z^-d Gd`` as a StateSpace (:func:`delay_augmented`, no feedthrough)."""
    import control as ct
    A, B, C = delay_augmented(Gd, delay_samples)
    return ct.ss(A, B, C, np.zeros((C.shape[0], B.shape[1])), Gd.dt)
