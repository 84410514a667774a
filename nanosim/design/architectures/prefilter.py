"""Reference prefilter of a two-degree-of-freedom loop: notches at the closed loop's ringing pairs.

A step through a feedback loop excites every closed-loop pole of the reference-to-output map
``T_ry``. Where a lightly damped pair carries a visible share of the step, the output rings
for ``~4 / (zeta w)`` seconds after the rise (on this stage, for example, the second XY pair,
about 450 Hz, in the ``lqg`` loop). Feedback cannot remove that ring without changing the loop; a prefilter on the
reference can: a notch whose zeros sit on the pair (mapped pole by pole, so exactly on it)
and whose poles are well damped keeps the pair from being excited. The loop's feedback
operator, so its margins, mu, sensitivities and noise, is unchanged: only the reference path
changes (a low-frequency group delay of about ``2 (zeta_p - zeta_z) / w`` per notch, 0.45 ms
at 450 Hz).

Rule (:func:`design_reference_prefilter`):

* the pairs of ``T_ry``'s diagonal, on the identified model with the loop delay, above
  :data:`RING_MIN_HZ` with ``zeta < RING_ZETA_MAX`` and a unit-step amplitude of at least
  :data:`RING_MIN_STEP_FRACTION` (half the 2 % settling band) on some axis (:func:`ringing_pairs`);
* pairs within :data:`GROUP_REL_GAP` of each other form one group, notched once at the
  group's geometric centre with zero damping ``max(zeta of the group, half its relative width)``
  and pole damping :data:`NOTCH_POLE_ZETA`, mapped pole by pole (:func:`matched_notch`);
* the same filter on every axis, so that a straight path stays straight (different delays on
  X and Y would turn a 45 degree line's lag into contour error).

Lag equalization (:func:`equalize_reference_lag`). At low frequency ``T_ry(s) = T_0 (I - s Lambda + O(s^2))``,
``T_0 = T_ry(0)``: a ramp of velocity ``v`` on axis ``j`` is followed ``Lambda v`` behind, so axis ``i``
lags by ``Lambda_ij v_j``.
A straight path stays straight only if every axis lags by the same time; a loop designed on a model whose
axes differ (the parallel kinematics, the per-column identification) does not, and a diagonal contour
then leaves its line by ``|Lambda_xx - Lambda_yy| v / sqrt(2)`` (Koren, *Cross-coupled biaxial computer
control for manufacturing systems*, J. Dyn. Sys. Meas. Control 102, 1980: the contour error of a
biaxial system is set by the axes' mismatch, not by their common lag). The prefilter

    F(s) = I - (lambda I - Lambda) s / (1 + s tau_f),   lambda = max_j Lambda_jj,

gives ``T_ry F = T_0 (I - s lambda I + O(s^2))``: every axis follows with the slowest axis's lag and
no cross lag. ``Lambda = T_0^-1 dt C (I - A)^-2 B`` exactly, from the discrete ``T_ry`` (``z = e^(s dt)``);
``tau_f`` (:data:`LAG_FILTER_S`) rolls the derivative off well below the first mode, where the
correction (a difference of lags, a few per cent of ``lambda``) is already negligible.

The prefilter is realized inside the controller: with ``r = e + y`` (the bench feeds
``e = r - y`` and ``y``), ``u = K [F r - y; y] = K [F e + (F - I) y; y]``
(:func:`with_reference_prefilter`), so the result is an ordinary ``[e; y]`` controller.
"""
from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np

from nanosim.design.architectures.common import DT_S, IDENTIFIED_DELAY_SAMPLES, mode_groups, tf_to_ss

__all__ = ["RingPair", "ringing_pairs", "reference_notch", "matched_notch", "with_reference_prefilter",
           "design_reference_prefilter", "reference_lag_matrix", "lag_equalizer", "equalize_reference_lag",
           "LAG_FILTER_S", "RING_ZETA_MAX", "RING_MIN_STEP_FRACTION", "RING_MIN_HZ", "NOTCH_POLE_ZETA",
           "GROUP_REL_GAP"]

RING_ZETA_MAX = 0.1
RING_MIN_STEP_FRACTION = 0.01
RING_MIN_HZ = 100.0
NOTCH_POLE_ZETA = 0.7
GROUP_REL_GAP = 0.05
# relative offset from a pole at which its residue is evaluated
RESIDUE_STEP = 1e-6
# time constant of the lag equalizer's derivative [s]: corner at 160 Hz, below the first pair (~175 Hz)
# and a fifth of the loop's lag (~5 ms), so the correction is complete over the scan band
LAG_FILTER_S = 1e-3


@dataclass(frozen=True)
class RingPair:
    """A lightly damped closed-loop pole pair of ``T_ry`` and its share of a unit step on one axis."""

    freq_hz: float
    zeta: float
    step_fraction: float
    axis: int


def ringing_pairs(G, Ke, Ky=None, *, delay_samples: int = IDENTIFIED_DELAY_SAMPLES, dt: float = DT_S,
                  zeta_max: float = RING_ZETA_MAX, min_step_fraction: float = RING_MIN_STEP_FRACTION,
                  f_min_hz: float = RING_MIN_HZ) -> list[RingPair]:
    """Lightly damped pole pairs of the diagonal of ``T_ry`` that carry a visible share of a step.

    A simple pole ``lam`` of ``T_ry`` with residue ``r_jj = lim (z - lam) T_jj(z)`` puts
    ``r_jj lam^k / (lam - 1)`` into the response of output ``j`` to a unit step on axis ``j``: a
    complex pair contributes an oscillation of amplitude ``2 |r_jj / (1 - lam)|``. The residue is
    taken by the limit (not from eigenvectors), so the repeated, uncontrollable pole copies of a
    non-minimal closed-loop realization carry none.

    Parameters
    ----------
    G : control.StateSpace
        Discrete plant at ``dt`` (controller V -> sensor V), ny x nu.
    Ke, Ky : control.StateSpace
        ``u = Ke e + Ky y`` (``Ky`` None for one degree of freedom).
    delay_samples : int
        Loop delay added at the plant input [samples].
    dt : float
        Control period [s].
    zeta_max, min_step_fraction, f_min_hz : float
        Damping ratio below which, step share (of a unit step, same axis) from which and
        frequency [Hz] above which a pair counts.

    Returns
    -------
    list of RingPair
        Ascending in frequency.
    """
    from nanosim.design.loopresponse import loop_transfer_ss
    T = loop_transfer_ss(G, Ke, Ky, delay_samples=delay_samples, dt=dt).T_ry
    A, B, C, D = (np.asarray(m, float) for m in (T.A, T.B, T.C, T.D))
    if A.shape[0] == 0:
        return []
    lam = np.linalg.eigvals(A)
    s = np.log(lam.astype(complex)) / dt
    w = np.abs(s)
    with np.errstate(divide="ignore", invalid="ignore"):
        zeta = np.where(w > 0, -s.real / w, 1.0)
    cand = np.flatnonzero((lam.imag > 0) & (zeta < zeta_max) & (w > 2 * np.pi * f_min_hz))
    n = A.shape[0]
    out = []
    for i in cand:
        # residue r = lim (z - lam) T(z), central in z (exact to O(eps^2)); zero for uncontrollable or
        # unobservable copies of a pole (the closed-loop realization is not minimal)
        res = 0
        for z in lam[i] * (1 + np.array([RESIDUE_STEP, -RESIDUE_STEP])):
            res = res + (z - lam[i]) * (C @ np.linalg.solve(z * np.eye(n) - A, B) + D) / 2
        for j in range(min(C.shape[0], B.shape[1])):
            amp = 2 * abs(res[j, j] / (1 - lam[i]))
            if amp >= min_step_fraction:
                out.append(RingPair(float(w[i] / (2 * np.pi)), float(zeta[i]), float(amp), j))
    return sorted(out, key=lambda p: (p.freq_hz, p.axis))


def reference_notch(pairs, *, dt: float = DT_S, pole_zeta: float = NOTCH_POLE_ZETA,
                    rel_gap: float = GROUP_REL_GAP):
    """SISO notch filter over the groups of ``pairs`` (rule of the module docstring), unit DC gain.

    Returns
    -------
    F : control.StateSpace or None
        Discrete at ``dt``; None when ``pairs`` is empty.
    notches : list of dict
        ``freq_hz``, ``zeta_zero``, ``zeta_pole`` and the group's ``f_low_hz``/``f_high_hz``.
    """
    import control as ct
    pairs = list(pairs)
    notches, F = [], None
    for lo, hi in mode_groups([(p.freq_hz, p.zeta) for p in pairs], rel_gap):
        zz = max([p.zeta for p in pairs if lo <= p.freq_hz <= hi] + [(hi - lo) / (hi + lo)])
        fc = float(np.sqrt(lo * hi))
        N = matched_notch(fc, pole_zeta, zz, dt)
        F = N if F is None else ct.ss(ct.series(F, N))
        notches.append({"freq_hz": fc, "zeta_zero": float(zz), "zeta_pole": float(pole_zeta),
                        "f_low_hz": float(lo), "f_high_hz": float(hi)})
    return F, notches


def matched_notch(f_hz: float, zeta_pole: float, zeta_zero: float, dt: float = DT_S):
    """Notch ``(s^2 + 2 zz w s + w^2)/(s^2 + 2 zp w s + w^2)`` mapped pole by pole (``z = exp(s dt)``), unit DC gain.

    Unlike Tustin, the matched map puts the zeros exactly on the discrete closed-loop pair
    ``exp(dt w (-zz +- j sqrt(1 - zz^2)))`` they are meant to cancel.
    """
    import control as ct
    if not 0.0 < f_hz < 0.5 / dt:
        raise ValueError(f"f_hz: expected a frequency in (0, {0.5 / dt:g}) Hz (below Nyquist), got {f_hz!r}")
    for name, z in (("zeta_pole", zeta_pole), ("zeta_zero", zeta_zero)):
        if not 0.0 <= z <= 1.0:
            raise ValueError(f"{name}: expected a damping ratio in [0, 1], got {z!r}")
    w = 2 * np.pi * f_hz

    def pair(zeta):
        return np.real(np.poly(np.exp(dt * np.roots([1.0, 2 * zeta * w, w * w]))))
    num, den = pair(zeta_zero), pair(zeta_pole)
    return ct.ss(ct.tf(num * den.sum() / num.sum(), den, dt))


def with_reference_prefilter(K, F, n_error: int):
    """The controller ``u = K [F r - y; y]`` for the bench's inputs ``[e; y]`` (``r = e + y``).

    Parameters
    ----------
    K : control.StateSpace
        Discrete controller, inputs ``[e]`` (``n_error``) or ``[e; y]``.
    F : control.StateSpace
        SISO prefilter, applied to every reference channel, or ``n_error x n_error`` (same ``dt``).
    n_error : int
        Number of error (and reference) channels.

    Returns
    -------
    control.StateSpace
        Inputs ``[e; y]`` (``2 n_error``), states ``[F states (n_error copies of a SISO F); K states]``.
    """
    import control as ct
    n = n_error
    if K.ninputs not in (n, 2 * n):
        raise ValueError(f"K: expected {n} or {2 * n} inputs, got {K.ninputs}")
    if not np.isclose(float(F.dt), float(K.dt)):
        raise ValueError(f"F: expected the controller's sample time {K.dt}, got {F.dt}")
    if (F.ninputs, F.noutputs) not in ((1, 1), (n, n)):
        raise ValueError(f"F: expected a SISO or {n} x {n} prefilter, got {F.noutputs} x {F.ninputs}")
    Fa, Fb, Fc, Fd = (np.asarray(m, float) for m in (F.A, F.B, F.C, F.D))
    I_n = np.eye(n)
    if F.ninputs == 1 and n > 1:
        Ab, Bb, Cb, Db = (np.kron(I_n, m) for m in (Fa, Fb, Fc, Fd))    # F on each channel
    else:
        Ab, Bb, Cb, Db = Fa, Fb, Fc, Fd
    nf = Ab.shape[0]
    # M: [e; y] -> [F (e + y) - y; y], or [F (e + y) - y] for a one-degree-of-freedom K
    Bm = np.hstack([Bb, Bb])
    Cm = np.vstack([Cb, np.zeros((n, nf))])[:K.ninputs]
    Dm = np.block([[Db, Db - I_n], [np.zeros((n, n)), I_n]])[:K.ninputs]
    Ka, Kb, Kc, Kd = (np.asarray(m, float) for m in (K.A, K.B, K.C, K.D))
    nk = Ka.shape[0]
    # series M -> K, states [x_F; x_K]
    A = np.block([[Ab, np.zeros((nf, nk))], [Kb @ Cm, Ka]])
    B = np.vstack([Bm, Kb @ Dm])
    C = np.hstack([Kd @ Cm, Kc])
    D = Kd @ Dm
    return ct.ss(A, B, C, D, K.dt)


def design_reference_prefilter(G, K, n_error: int, *, delay_samples: int = IDENTIFIED_DELAY_SAMPLES,
                               dt: float = DT_S):
    """``(K2, parameters)``: ``K`` with the reference notch of the module docstring's rule.

    ``K2`` is ``K`` itself when no pair qualifies. ``parameters`` (JSON-ready) lists the ringing
    pairs found before and after, and the notches.
    """
    from nanosim.design.architectures.common import split_2dof
    Ke, Ky = split_2dof(K, n_error)
    pairs = ringing_pairs(G, Ke, Ky, delay_samples=delay_samples, dt=dt)
    F, notches = reference_notch(pairs, dt=dt)
    K2 = K if F is None else with_reference_prefilter(K, F, n_error)
    after = pairs if F is None else ringing_pairs(G, *split_2dof(K2, n_error), delay_samples=delay_samples, dt=dt)
    params = {"rule": f"notch the reference at the pairs of T_ry with zeta < {RING_ZETA_MAX:g} above "
                      f"{RING_MIN_HZ:g} Hz carrying >= {100 * RING_MIN_STEP_FRACTION:g} % of a step "
                      f"(groups within {100 * GROUP_REL_GAP:g} %, pole damping {NOTCH_POLE_ZETA:g}, "
                      "the same filter on every axis)",
              "ringing_pairs": [asdict(p) for p in pairs], "notches": notches,
              "ringing_pairs_after": [asdict(p) for p in after],
              "prefilter_states": 0 if F is None else int(F.nstates) * n_error}
    return K2, params


def reference_lag_matrix(G, Ke, Ky=None, *, delay_samples: int = IDENTIFIED_DELAY_SAMPLES) -> np.ndarray:
    """``Lambda`` [s] of ``T_ry(s) = T_0 (I - s Lambda + O(s^2))`` for ``u = Ke e + Ky y`` around the discrete ``G``.

    ``Lambda_ij`` is how far output ``i`` trails a unit-velocity ramp on reference ``j`` once the loop
    has settled (the diagonal: each axis's tracking lag), relative to the loop's static gain ``T_0``.
    Computed exactly from the discrete closed loop ``T(z) = C (z I - A)^-1 B + D``:
    ``dT/ds = dt dT/dz = -dt C (I - A)^-2 B`` at ``z = 1``.

    Examples
    --------
    A loop ``T(s) = 1 / (1 + s / w)`` trails a ramp by ``1 / w``:

    >>> import control as ct
    >>> w, dt = 2 * np.pi * 30, 2.5e-4
    >>> G = ct.c2d(ct.ss(ct.tf([w], [1, 0])), dt, "tustin")          # integrator, crossover w
    >>> K = ct.ss([], [], [], [[1.0]], dt)
    >>> round(float(reference_lag_matrix(G, K)[0, 0] * w), 2)
    1.0
    """
    from nanosim.design.loopresponse import loop_transfer_ss
    T = loop_transfer_ss(G, Ke, Ky, delay_samples).T_ry
    A, B, C, D = (np.asarray(m, float) for m in (T.A, T.B, T.C, T.D))
    M = np.linalg.solve(np.eye(A.shape[0]) - A, B)
    T0 = C @ M + D
    return np.linalg.solve(T0, float(T.dt) * C @ np.linalg.solve(np.eye(A.shape[0]) - A, M))


def lag_equalizer(lag_s, dt: float = DT_S, tau_f_s: float = LAG_FILTER_S):
    """``(F, lambda_s)``: ``I - (lambda I - Lambda) s / (1 + s tau_f)`` (module docstring), Tustin at ``dt``.

    Parameters
    ----------
    lag_s : (n, n) array
        ``Lambda`` [s] (:func:`reference_lag_matrix`).
    dt : float
        Control period [s].
    tau_f_s : float
        Derivative roll-off [s].
    """
    import control as ct
    Lam = np.asarray(lag_s, float)
    if Lam.ndim != 2 or Lam.shape[0] != Lam.shape[1] or not np.all(np.isfinite(Lam)):
        raise ValueError(f"lag_s: expected a finite square matrix, got shape {Lam.shape}")
    if not (np.isfinite(tau_f_s) and tau_f_s > 0):
        raise ValueError(f"tau_f_s: expected a time > 0 [s], got {tau_f_s!r}")
    n = Lam.shape[0]
    lam = float(np.max(np.diag(Lam)))
    M = Lam - lam * np.eye(n)
    D = tf_to_ss([1.0, 0.0], [tau_f_s, 1.0], dt)                             # s / (1 + s tau_f)
    a, b, c, d = (float(np.asarray(m).item()) for m in (D.A, D.B, D.C, D.D))
    I_n = np.eye(n)
    F = ct.ss(a * I_n, b * M, c * I_n, d * M + I_n, dt)                      # I + M D(s)
    return F, lam


def equalize_reference_lag(G, K, n_error: int, *, delay_samples: int = IDENTIFIED_DELAY_SAMPLES,
                           dt: float = DT_S, tau_f_s: float = LAG_FILTER_S):
    """``(K2, parameters)``: ``K`` (inputs ``[e]`` or ``[e; y]``) with the lag equalizer in its reference path.

    The lag matrix is taken on ``G`` with ``K`` as given (any prefilter already inside it counts);
    ``parameters`` (JSON-ready) holds the lag matrix before and after [ms] and the common lag.
    """
    from nanosim.design.architectures.common import split_2dof
    before = reference_lag_matrix(G, *split_2dof(K, n_error), delay_samples=delay_samples)
    F, lam = lag_equalizer(before, dt, tau_f_s)
    K2 = with_reference_prefilter(K, F, n_error)
    after = reference_lag_matrix(G, *split_2dof(K2, n_error), delay_samples=delay_samples)
    params = {"rule": "every axis follows a ramp with the slowest axis's lag and no cross lag: "
                      "F = I - (lambda I - Lambda) s / (1 + s tau_f), "
                      "Lambda = -T_0^-1 dT_ry/ds at 0 on the identified model",
              "tau_f_ms": 1e3 * tau_f_s, "common_lag_ms": 1e3 * lam,
              "lag_matrix_ms": (1e3 * before).tolist(), "lag_matrix_after_ms": (1e3 * after).tolist(),
              "prefilter_states": int(F.nstates)}
    return K2, params
