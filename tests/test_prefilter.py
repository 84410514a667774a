"""The reference prefilter (#13): ringing pairs of T_ry, the notch rule and the two-degree-of-freedom realization.

Analytic loop: ``T(z)`` is the zero-order-hold discretization of ``w^2 / (s^2 + 2 zeta w s + w^2)`` and
``G = T / (1 - T)`` with ``K = 1``, so that ``T_ry = T`` exactly and its step response is the sampled
continuous one: one pair at ``w`` with damping ``zeta`` whose oscillation has amplitude
``1 / sqrt(1 - zeta^2)`` (the envelope of ``1 - exp(-zeta w t) sin(w_d t + phi) / sqrt(1 - zeta^2)``).
"""
from __future__ import annotations

import numpy as np
import pytest
from numpy.testing import assert_allclose

ct = pytest.importorskip("control")

from nanosim.design.architectures.common import DT_S, freqresp_z, split_2dof  # noqa: E402
from nanosim.design.architectures.prefilter import (  # noqa: E402
    NOTCH_POLE_ZETA,
    RingPair,
    design_reference_prefilter,
    equalize_reference_lag,
    lag_equalizer,
    reference_lag_matrix,
    reference_notch,
    ringing_pairs,
    with_reference_prefilter,
)
from nanosim.design.loopresponse import loop_transfer_response, loop_transfer_ss  # noqa: E402

F_HZ = np.geomspace(1.0, 1900.0, 400)


def _second_order(f_hz, zeta):
    w = 2 * np.pi * f_hz
    return ct.ss(ct.c2d(ct.tf([w * w], [1, 2 * zeta * w, w * w]), DT_S, "zoh"))


def _loop_with_T(T):
    """``G = T / (1 - T)`` and ``K = 1``: the loop's T_ry is T."""
    return ct.ss(ct.feedback(T, ct.ss([], [], [], [[1.0]], DT_S), sign=1)), ct.ss([], [], [], [[1.0]], DT_S)


@pytest.mark.parametrize("f_hz, zeta", [(450.0, 0.066), (300.0, 0.02)])
def test_ringing_pair_of_a_second_order_loop_has_the_textbook_frequency_damping_and_amplitude(f_hz, zeta):
    G, K = _loop_with_T(_second_order(f_hz, zeta))
    pairs = ringing_pairs(G, K, None, dt=DT_S)
    assert len(pairs) == 1
    p = pairs[0]
    assert p.freq_hz == pytest.approx(f_hz, rel=1e-9)
    assert p.zeta == pytest.approx(zeta, rel=1e-8)
    assert p.step_fraction == pytest.approx(1 / np.sqrt(1 - zeta ** 2), rel=1e-8)
    assert p.axis == 0


def test_ringing_pairs_ignore_well_damped_low_and_small_pairs():
    G, K = _loop_with_T(_second_order(450.0, 0.15))                  # zeta above 0.1
    assert ringing_pairs(G, K, None, dt=DT_S) == []
    G, K = _loop_with_T(_second_order(60.0, 0.05))                   # below 100 Hz
    assert ringing_pairs(G, K, None, dt=DT_S) == []
    # a 450 Hz pair that carries 0.5 % of the step beside a dominant first-order response
    T = ct.ss(ct.parallel(ct.c2d(ct.tf([0.995 * 200.0], [1, 200.0]), DT_S, "zoh"),
                          0.005 * ct.c2d(ct.tf([(2 * np.pi * 450) ** 2], [1, 2 * 0.05 * 2 * np.pi * 450,
                                                                           (2 * np.pi * 450) ** 2]), DT_S, "zoh")))
    G, K = _loop_with_T(T)
    assert ringing_pairs(G, K, None, dt=DT_S) == []
    p = ringing_pairs(G, K, None, dt=DT_S, min_step_fraction=0.004)
    assert len(p) == 1 and p[0].step_fraction == pytest.approx(0.005 / np.sqrt(1 - 0.05 ** 2), rel=1e-6)


def test_notch_groups_close_pairs_once_and_keeps_far_pairs_apart():
    pairs = [RingPair(448.0, 0.066, 0.04, 0), RingPair(454.0, 0.062, 0.05, 1), RingPair(640.0, 0.08, 0.02, 0)]
    F, notches = reference_notch(pairs)
    assert len(notches) == 2
    n0 = notches[0]
    assert n0["freq_hz"] == pytest.approx(np.sqrt(448.0 * 454.0))
    assert n0["zeta_zero"] == pytest.approx(0.066) and n0["zeta_pole"] == NOTCH_POLE_ZETA
    assert notches[1]["freq_hz"] == pytest.approx(640.0) and notches[1]["zeta_zero"] == pytest.approx(0.08)
    assert F.nstates == 4
    H = freqresp_z(F, np.array([1e-3, n0["freq_hz"], 640.0]))[:, 0, 0]
    assert abs(H[0]) == pytest.approx(1.0, abs=1e-6)                  # unit DC gain
    # depth at a centre: zeta_zero / zeta_pole times the other notch's gain there
    assert abs(H[1]) < 0.066 / NOTCH_POLE_ZETA * 1.2
    assert abs(H[2]) < 0.08 / NOTCH_POLE_ZETA * 1.2
    assert reference_notch([]) == (None, [])
    wide, n = reference_notch([RingPair(440.0, 0.01, 0.04, 0), RingPair(460.0, 0.01, 0.04, 1)])
    assert n[0]["zeta_zero"] == pytest.approx(20.0 / 900.0)            # half the group's relative width


@pytest.mark.parametrize("two_dof", [False, True])
def test_prefilter_keeps_the_feedback_and_multiplies_the_reference_path(two_dof):
    """u = K [F r - y; y]: the feedback operator Ke - Ky is unchanged, Ke becomes Ke F (1 DOF) and
    T_ry becomes T_ry F; with F from the rule the ring is gone."""
    T = _second_order(450.0, 0.066)
    G, K = _loop_with_T(T)
    if two_dof:                                     # Ke = 1.3 - 0.3/z, Ky = 0.3 - 0.3/z: the same feedback 1
        K = ct.ss([[0.0]], [[1.0, 1.0]], [[-0.3]], [[1.3, 0.3]], DT_S)
    n_error = 1
    F, _ = reference_notch(ringing_pairs(G, *split_2dof(K, n_error), dt=DT_S))
    K2 = with_reference_prefilter(K, F, n_error)
    assert K2.ninputs == 2 and K2.nstates == F.nstates + K.nstates
    Ke, Ky = split_2dof(K, n_error)
    Ke2, Ky2 = split_2dof(K2, n_error)
    fb = freqresp_z(Ke, F_HZ) - (0 if Ky is None else freqresp_z(Ky, F_HZ))
    fb2 = freqresp_z(Ke2, F_HZ) - freqresp_z(Ky2, F_HZ)
    np.testing.assert_allclose(fb2, fb, rtol=0, atol=1e-12)
    Ff = freqresp_z(F, F_HZ)
    np.testing.assert_allclose(freqresp_z(Ke2, F_HZ), freqresp_z(Ke, F_HZ) * Ff, rtol=1e-10, atol=1e-12)
    Gf = freqresp_z(G, F_HZ)
    r1 = loop_transfer_response(Gf, freqresp_z(Ke, F_HZ), F_HZ, Ky=None if Ky is None else freqresp_z(Ky, F_HZ),
                                dt=DT_S)
    r2 = loop_transfer_response(Gf, freqresp_z(Ke2, F_HZ), F_HZ, Ky=freqresp_z(Ky2, F_HZ), dt=DT_S)
    np.testing.assert_allclose(r2.T_ry, r1.T_ry * Ff, rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(r2.S_o, r1.S_o, rtol=1e-9, atol=1e-12)
    assert ringing_pairs(G, Ke2, Ky2, dt=DT_S, min_step_fraction=1e-6) == []     # the zeros sit on the pair
    # the step: before, the 450 Hz ring is still 10 % of the step at 3 ms; after, under 1 %
    t = np.arange(0, 0.02, DT_S)
    for KK, limit in ((K, None), (K2, 0.01)):
        a, b = split_2dof(KK, n_error)
        Try = loop_transfer_ss(G, a, b, dt=DT_S).T_ry
        y = ct.step_response(Try, T=t).outputs.ravel()
        late = np.abs(y[t >= 0.003] - 1).max()
        assert (late > 0.1) if limit is None else (late < limit), late
    assert y[-1] == pytest.approx(1.0, abs=1e-3)                       # unit static gain (residual ring 2e-4)


def test_design_reference_prefilter_without_ringing_pairs_returns_the_controller():
    G, K = _loop_with_T(_second_order(450.0, 0.5))
    K2, p = design_reference_prefilter(G, K, 1)
    assert K2 is K and p["notches"] == [] and p["prefilter_states"] == 0


def test_prefilter_rejects_mismatched_inputs_and_sample_times():
    F, _ = reference_notch([RingPair(450.0, 0.06, 0.05, 0)])
    with pytest.raises(ValueError, match="K: expected 1 or 2 inputs, got 3"):
        with_reference_prefilter(ct.ss([], [], [], [[1.0, 0.0, 0.0]], DT_S), F, 1)
    with pytest.raises(ValueError, match="F: expected the controller's sample time"):
        with_reference_prefilter(ct.ss([], [], [], [[1.0]], 2 * DT_S), F, 1)


def test_matched_notch_rejects_frequencies_above_nyquist_and_bad_damping():
    from nanosim.design.architectures.prefilter import matched_notch
    with pytest.raises(ValueError, match=r"f_hz: expected a frequency in \(0, 2000\) Hz"):
        matched_notch(2500.0, 0.7, 0.05)
    with pytest.raises(ValueError, match=r"zeta_zero: expected a damping ratio in \[0, 1\], got -0.1"):
        matched_notch(450.0, 0.7, -0.1)
    N = matched_notch(450.0, 0.7, 0.0)                               # zeros on the unit circle: a null at 450 Hz
    assert abs(freqresp_z(N, np.array([450.0]))[0, 0, 0]) < 1e-9


# --- lag equalization -------------------------------------------------------------------------------------------
def _two_axis_loop(f1_hz, f2_hz, coupling=0.0):
    """Two integrator axes closed by unit feedback at crossovers ``f1``, ``f2`` (``T_jj = w_j / (s + w_j)``,
    ramp lag ``1 / w_j``), Tustin at the control period; ``coupling`` adds ``coupling x`` axis 2's integrator
    to axis 1's output."""
    w1, w2 = 2 * np.pi * f1_hz, 2 * np.pi * f2_hz
    Gc = ct.ss(np.zeros((2, 2)), np.diag([w1, w2]), np.array([[1.0, coupling], [0.0, 1.0]]), np.zeros((2, 2)))
    return ct.ss(ct.c2d(Gc, DT_S, "tustin")), ct.ss([], [], [], np.eye(2), DT_S)


def _ramp_lags(G, K, n=2000):
    """Steady tracking lag [s] of each axis behind a unit-velocity ramp on both references at once."""
    T = loop_transfer_ss(G, *split_2dof(K, 2)).T_ry
    t = np.arange(n) * DT_S
    _, y = ct.forced_response(T, T=t, U=np.vstack([t, t]))
    return t[-1] - np.asarray(y)[:, -1]


def test_lag_matrix_of_two_first_order_loops_is_their_time_constants():
    G, K = _two_axis_loop(30.0, 36.0)
    Lam = reference_lag_matrix(G, K)
    assert_allclose(np.diag(Lam), [1 / (2 * np.pi * 30.0), 1 / (2 * np.pi * 36.0)], rtol=1e-9)
    assert_allclose([Lam[0, 1], Lam[1, 0]], 0.0, atol=1e-15)
    # the ramp response's steady lag is the row sum (both references ramp)
    assert_allclose(_ramp_lags(G, K), Lam.sum(axis=1), rtol=1e-6)


@pytest.mark.parametrize("coupling", [0.0, 0.05])
def test_lag_equalizer_gives_every_axis_the_slowest_axis_lag_and_no_cross_lag(coupling):
    """Axes at 30 and 36 Hz (5.31 and 4.42 ms, a diagonal ramp leaves its line by 0.63 um per mm/s of
    speed): after the equalizer both trail by the slower axis's lag, to 1e-9 of it, cross lags gone."""
    G, K = _two_axis_loop(30.0, 36.0, coupling)
    before = _ramp_lags(G, K)
    assert abs(before[0] - before[1]) > 5e-4
    K2, p = equalize_reference_lag(G, K, 2)
    Lam2 = np.asarray(p["lag_matrix_after_ms"]) * 1e-3
    lam = max(np.diag(reference_lag_matrix(G, K)))
    assert p["common_lag_ms"] == pytest.approx(1e3 * lam, rel=1e-12)
    assert_allclose(Lam2, lam * np.eye(2), atol=1e-9 * lam)
    assert_allclose(_ramp_lags(G, K2), [lam, lam], rtol=1e-6)
    # the feedback operator is untouched: the loop's S from an output disturbance is the same
    f = np.geomspace(1.0, 1000.0, 50)
    Ke2, Ky2 = split_2dof(K2, 2)
    S1 = loop_transfer_response(G, Ke2, f, Ky=Ky2).S_o
    S0 = loop_transfer_response(G, K, f).S_o
    assert_allclose(S1, S0, rtol=1e-9, atol=1e-12)


def test_lag_equalizer_rejects_a_non_square_matrix_and_a_bad_time_constant():
    with pytest.raises(ValueError, match="lag_s: expected a finite square matrix, got shape"):
        lag_equalizer(np.zeros((2, 3)))
    with pytest.raises(ValueError, match=r"tau_f_s: expected a time > 0 \[s\], got 0"):
        lag_equalizer(np.eye(2), tau_f_s=0)
