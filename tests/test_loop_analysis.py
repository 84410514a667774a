"""Tests of the loop analysis (nanosim.design.robustness and its modules) against published numbers.

Conventions under test (see the module docstring): plant G is ny x nu, negative
feedback e = r - y, 2-DOF controller u = K e + Ky y, feedback operator Kfb = K - Ky;
frequency responses are (F, rows, cols) with frequencies in Hz.

Sources
-------
[SP]   S. Skogestad, I. Postlethwaite, "Multivariable Feedback Control: Analysis and
       Design", 2nd ed., Wiley 2005 (text version of 29 Aug 2001).  Sec. 3.7.1 (spinning
       satellite, eqs. 3.76-3.80, pp. 91-93), Example 8.10 (p. 324), Sec. 8.11.3 and
       Table 8.1 (distillation column, mu-analysis, pp. 333-335).
[SPG]  P. Seiler, A. Packard, P. Gahinet, "An Introduction to Disk Margins", IEEE Control
       Systems Magazine 40(5):78-95, 2020 (arXiv:2003.04771).
[MW]   MathWorks Robust Control Toolbox documentation, ``diskmargin`` reference page,
       examples "Disk Margins of MIMO Feedback Loop" and "Sensitivity of Disk-Based
       Margins to Gain Increase and Decrease" (R2020a and later).
[MW-old] The same page in an earlier release (plant c = [1 8; -10 1]).
"""
from __future__ import annotations

import json
import math

import control as ct
import numpy as np
import pytest

from nanosim.design import robustness as la


# ----------------------------------------------------------------------------------------
# plants of the published examples
# ----------------------------------------------------------------------------------------
def satellite(c=((1.0, 10.0), (-10.0, 1.0))):
    """Spinning satellite [SP] (3.77), a = 10: A = [0 a; -a 0], B = I, C = [1 a; -a 1]."""
    return ct.ss([[0.0, 10.0], [-10.0, 0.0]], np.eye(2), np.array(c, float), np.zeros((2, 2)))


def distillation():
    """[SP] Sec. 8.11.3 / Table 8.1: G = 1/(75s+1) G0 and the inverse-based controller
    K = 0.7 (75s+1)/(s+1e-5) G0^-1 (the 1e-5 approximates the integrator as in Table 8.1)."""
    G0 = np.array([[87.8, -86.4], [108.2, -109.6]])
    g = ct.ss(ct.tf([1.0], [75.0, 1.0]))
    G = ct.append(g, g) * ct.ss([], [], [], G0)
    k = ct.ss(ct.tf([0.7 * 75.0, 0.7], [1.0, 1e-5]))
    K = ct.append(k, k) * ct.ss([], [], [], np.linalg.inv(G0))
    wP = ct.tf([0.5 * 10.0, 0.5], [10.0, 1e-5])   # w_P = 0.5 (10s+1)/(10s)  [SP] (8.132)
    wI = ct.tf([1.0, 0.2], [0.5, 1.0])            # w_I = (s+0.2)/(0.5s+1)   [SP] Sec. 8.11.3
    return G, K, wP, wI


def stage(dt=250e-6):
    """A 3x3 stage-like plant: three light modes (420, 470, 900 Hz) with input coupling,
    unit static gain per axis, sampled with a ZOH at the 4 kHz control period."""
    wn = 2 * np.pi * np.array([420.0, 470.0, 900.0])
    zeta = np.array([0.02, 0.03, 0.015])
    Phi = np.array([[1.0, 0.1, 0.05], [0.08, 1.0, 0.1], [0.05, 0.05, 1.0]])
    A = np.zeros((6, 6))
    B = np.zeros((6, 3))
    C = np.zeros((3, 6))
    for i in range(3):
        A[2 * i:2 * i + 2, 2 * i:2 * i + 2] = [[0.0, 1.0], [-wn[i] ** 2, -2 * zeta[i] * wn[i]]]
        B[2 * i + 1] = wn[i] ** 2 * Phi[i]
        C[i, 2 * i] = 1.0
    Gd = ct.c2d(ct.ss(A, B, C, 0), dt, "zoh")
    ki = 2 * np.pi * 5.0
    integ = ct.ss(ct.tf([ki * dt, 0.0], [1.0, -1.0], dt))
    K = ct.append(integ, integ, integ) * ct.ss([], [], [], np.linalg.inv(Phi), dt)
    return Gd, ct.ss(K.A, K.B, K.C, K.D, dt)


# ----------------------------------------------------------------------------------------
# disk margins: published values
# ----------------------------------------------------------------------------------------
def test_siso_disk_margins_match_matlab_and_paper():
    # [MW] "Sensitivity of Disk-Based Margins to Gain Increase and Decrease":
    # L = 25/(s^3 + 10 s^2 + 10 s + 10); DGM for sigma = -2, 0, +2 (4 decimals printed).
    # [SPG] same L: alpha = 0.46 at w0 = 1.94 rad/s, DGM [0.63, 1.59] (+-4.05 dB),
    # DPM +-25.8 deg.
    L = ct.tf(25, [1, 10, 10, 10])
    f = np.logspace(-2, 2, 200)
    published = {-2.0: (0.4013, 1.3745), 0.0: (0.6273, 1.5942), 2.0: (0.7717, 1.7247)}
    for skew, (gmin, gmax) in published.items():
        rep = la.disk_margins(L, 1.0, f, skew=skew)
        m = rep.input
        assert m.gain_margin[0] == pytest.approx(gmin, abs=1.5e-4)
        assert m.gain_margin[1] == pytest.approx(gmax, abs=1.5e-4)
        # SISO: loop-at-a-time, input and output margins are one and the same
        for other in (rep.output, rep.input_loop_at_a_time[0], rep.output_loop_at_a_time[0]):
            assert other.alpha == pytest.approx(m.alpha, rel=1e-6)
    m = la.disk_margins(L, 1.0, f).input
    assert m.alpha == pytest.approx(0.46, abs=0.005)
    assert 2 * np.pi * m.freq_hz == pytest.approx(1.94, abs=0.02)
    assert m.gain_margin_db[1] == pytest.approx(4.05, abs=0.01)
    assert m.phase_margin_deg == pytest.approx(25.8, abs=0.05)
    assert m.alpha_upper_bound == pytest.approx(m.alpha, rel=1e-9)   # scalar problem: exact


def test_siso_disk_margin_is_inverse_peak_of_balanced_sensitivity_and_inside_classical():
    # [SPG] eq. for SISO loops: alpha = 1 / ||S - I/2||_inf (sigma = 0); the classical gain
    # and phase margins (ct.stability_margins) can never be smaller than the disk-based ones.
    s = ct.tf("s")
    loops = (ct.tf(25, [1, 10, 10, 10]), 2.0 / (s + 1) ** 3,
             6.25 * (s + 3) * (s + 5) / (s * (s + 1) ** 2 * (s ** 2 + 0.18 * s + 100)))   # [SPG] examples
    for L in loops:
        f = np.logspace(-3, 2, 200)
        S = la.frequency_response(ct.feedback(1, L), f)[:, 0, 0]
        m = la.disk_margins(L, 1.0, f).input
        assert m.alpha <= 1.0 / np.max(np.abs(S - 0.5)) * (1 + 1e-9)   # refinement only raises the peak
        S_dense = la.frequency_response(ct.feedback(1, L), np.logspace(-3, 2, 20000))[:, 0, 0]
        assert m.alpha == pytest.approx(1.0 / np.max(np.abs(S_dense - 0.5)), rel=1e-5)
        gm, pm, *_ = ct.stability_margins(L)
        assert gm >= m.gain_margin[1] * (1 - 1e-9)
        assert pm >= m.phase_margin_deg * (1 - 1e-9)


def test_matlab_diskmargin_example_spinning_satellite_with_coupled_controller():
    # [MW] "Disk Margins of MIMO Feedback Loop": P = satellite (a = 10), C = [1 -2; 0 1],
    # Lo = P*C.  DMo(1), DMo(2): GainMargin [0 Inf], PhaseMargin [-90 90], DiskMargin 2.
    # MMo: GainMargin [0.6839 1.4621], PhaseMargin [-21.2607 21.2607], DiskMargin 0.3754,
    # LowerBound 0.3754, UpperBound 0.3762, Frequency 0.
    P = satellite()
    C = np.array([[1.0, -2.0], [0.0, 1.0]])
    f = np.concatenate([[0.0], np.logspace(-3, 2, 120)])
    rep = la.disk_margins(P, C, f)
    assert rep.closed_loop_stable is True
    for m in rep.output_loop_at_a_time:
        assert m.alpha == pytest.approx(2.0, abs=1e-3)
        assert m.gain_margin[0] < 1e-3 and m.gain_margin[1] > 1e3
        assert m.phase_margin_deg == pytest.approx(90.0, abs=0.05)
    mm = rep.output
    # our alpha is the mu-upper-bound value; MATLAB brackets the true margin in [LB, UB]
    assert 0.3754 - 1e-4 <= mm.alpha <= 0.3762 + 1e-4
    assert mm.alpha <= mm.alpha_upper_bound <= 0.3762 + 1e-4
    assert mm.freq_hz < 1e-3          # MATLAB: Frequency 0 (mu is flat near DC)
    # the published gain / phase margins are those of the published DiskMargin 0.3754
    gmin, gmax, pm = la.disk_gain_phase(0.3754)
    assert (gmin, gmax) == pytest.approx((0.6839, 1.4621), abs=1e-4)
    assert pm == pytest.approx(21.2607, abs=3e-3)   # 3e-3 deg ~ rounding of alpha to 4 decimals
    # and ours differ from them only through alpha
    assert mm.gain_margin[1] == pytest.approx(1.4621, abs=2e-3)
    assert mm.phase_margin_deg == pytest.approx(21.2607, abs=0.1)


def test_input_output_margin_alone_bounds_the_others_and_gives_the_same_worst():
    # the input+output perturbation set holds the input-only and output-only ones, so its margin is the smallest;
    # computing it alone (the Monte Carlo's per-sample figure) gives the same worst margin, bit for bit
    P = satellite()
    C = np.array([[1.0, -2.0], [0.0, 1.0]])
    f = np.concatenate([[0.0], np.logspace(-3, 2, 120)])
    full = la.disk_margins(P, C, f, refine=False)
    io = la.disk_margins(P, C, f, refine=False, input_output_only=True)
    assert full.input_output.alpha <= min(full.input.alpha, full.output.alpha) + 1e-12
    assert full.worst() is full.input_output
    assert io.input is None and io.output is None and io.alpha_input_f is None and io.alpha_output_f is None
    assert io.worst().alpha == full.worst().alpha and io.worst().freq_hz == full.worst().freq_hz
    assert np.array_equal(io.alpha_input_output_f, full.alpha_input_output_f)


def test_matlab_diskmargin_example_earlier_release():
    # [MW-old]: c = [1 8; -10 1], C = [1 -2; 0 1], L = P*C.  DM(1), DM(2): DiskMargin 2.
    # MM: GainMargin [0.6071 1.6472], PhaseMargin [-27.4762 27.4762], DiskMargin 0.4890,
    # LowerBound 0.4890, UpperBound 0.4899, Frequency 0.2250 (rad/s).
    P = satellite(c=((1.0, 8.0), (-10.0, 1.0)))
    C = np.array([[1.0, -2.0], [0.0, 1.0]])
    f = np.concatenate([[0.0], np.logspace(-3, 2, 120)])
    rep = la.disk_margins(P, C, f)
    assert [m.alpha for m in rep.output_loop_at_a_time] == pytest.approx([2.0, 2.0], abs=1e-3)
    assert 0.4890 - 1e-4 <= rep.output.alpha <= 0.4899 + 1e-4
    assert 2 * np.pi * rep.output.freq_hz == pytest.approx(0.2250, rel=0.1)
    gmin, gmax, pm = la.disk_gain_phase(0.4890)
    assert (gmin, gmax) == pytest.approx((0.6071, 1.6472), abs=1e-4)
    assert pm == pytest.approx(27.4762, abs=3e-3)   # 3e-3 deg ~ rounding of alpha to 4 decimals


def test_spinning_satellite_loop_at_a_time_versus_multiloop():
    # [SP] Sec. 3.7.1, K = I: breaking one loop gives L1 = 1/s, "an infinite gain margin
    # and a phase margin of 90 deg" per loop; yet with input gains (1 + e1, 1 + e2), (3.80),
    # e1 = -e2 destabilises for |e1| > 1/sqrt(a^2 + 1) ~ 0.1.  At steady state
    # sigma_max(T) = 10.05 and sigma_max(S) = 10.
    # [SPG] MIMO section: multiloop input disk margin 0.0998, simultaneous input/output
    # 0.0499 (values as transcribed in RobustAndOptimalControl.jl test/test_diskmargin.jl).
    P = satellite()
    f = np.concatenate([[0.0], np.logspace(-3, 1.5, 100)])
    rep = la.disk_margins(P, np.eye(2), f)
    for m in rep.input_loop_at_a_time + rep.output_loop_at_a_time:
        assert m.alpha == pytest.approx(2.0, abs=1e-6)
        assert m.gain_margin[1] > 1e6
        assert m.phase_margin_deg == pytest.approx(90.0, abs=1e-3)
    assert rep.input.alpha == pytest.approx(0.0998, abs=5e-4)
    assert rep.output.alpha == pytest.approx(0.0998, abs=5e-4)
    assert rep.input_output.alpha == pytest.approx(0.0499, abs=5e-4)
    r = la.loop_transfer_response(P, np.eye(2), [0.0])
    assert la.sigma_max(r.T_o)[0] == pytest.approx(10.05, abs=0.005)
    assert la.sigma_max(r.S_o)[0] == pytest.approx(10.0, abs=1e-9)
    # brute force on (3.80): real gains just beyond / inside 1/sqrt(101)
    crit = 1 / math.sqrt(101.0)
    for e, stable in ((1.02 * crit, False), (0.98 * crit, True)):
        Pp = la.perturbed_plant(P, input_gain=[1 + e, 1 - e])
        p = la.closed_loop_poles(Pp, np.eye(2))
        assert bool(np.max(p.real) < 0) is stable


def test_spinning_satellite_mu_of_T_equals_sigma_max_for_any_structure():
    # [SP] Example 8.10: "mu(T) = sigma_max(T) irrespective of the structure of the complex
    # multiplicative perturbation (full-block, diagonal ...)"; at low frequencies ~10.
    P = satellite()
    f = np.logspace(-3, 2, 40) / (2 * np.pi)    # 40 points: avoids the plant poles at 10 rad/s
    T = la.loop_transfer_response(P, np.eye(2), f).T_o
    mu_diag = la.mu_upper_bound(T, [(1, 1), (1, 1)])
    mu_full = la.mu_upper_bound(T, [(2, 2)])
    np.testing.assert_allclose(mu_diag.upper, la.sigma_max(T), rtol=1e-4)
    np.testing.assert_allclose(mu_full.upper, la.sigma_max(T), rtol=1e-12)
    assert np.all(mu_diag.lower <= mu_diag.upper * (1 + 1e-12))
    np.testing.assert_allclose(mu_diag.lower, mu_diag.upper, rtol=1e-3)
    assert mu_diag.upper[0] == pytest.approx(10.05, abs=0.01)


# ----------------------------------------------------------------------------------------
# mu: the distillation column of [SP] Sec. 8.11.3
# ----------------------------------------------------------------------------------------
def _distillation_N(omega):
    G, K, wP, wI = distillation()
    f = omega / (2 * np.pi)
    r = la.loop_transfer_response(G, K, f)
    wi = la.frequency_response(wI, f)[:, :, :1]
    wp = la.frequency_response(wP, f)[:, :, :1]
    # N of [SP] (8.123): [[-wI T_I, -wI K S], [wP S G, wP S]]; here K S = KS_fb (1-DOF)
    top = np.concatenate([-wi * r.T_i, -wi * r.KS_fb], axis=2)
    bot = np.concatenate([wp * r.SG, wp * r.S_o], axis=2)
    return np.concatenate([top, bot], axis=1)


def test_distillation_mu_matches_skogestad_table_8_1():
    # [SP] Table 8.1 (p. 335), omega = logspace(-3, 3, 61) rad/s, blk = [1 1; 1 1; 2 2]:
    # "muRP ... (ans = 5.7726)"; RS blk = [1 1; 1 1]: "muRS ... (ans = 0.5242)";
    # NP: sigma_max(wP S) approaches 1/2 = 0.5 at high frequency (p. 334).
    N = _distillation_N(np.logspace(-3, 3, 61))
    rp = la.mu_upper_bound(N, [(1, 1), (1, 1), (2, 2)])
    rs = la.mu_upper_bound(N[:, :2, :2], [(1, 1), (1, 1)])
    assert rp.upper.max() == pytest.approx(5.7726, rel=2e-4)
    assert rs.upper.max() == pytest.approx(0.5242, rel=2e-4)
    assert la.sigma_max(N[:, 2:, 2:]).max() == pytest.approx(0.5, abs=1e-4)
    assert np.all(rp.lower <= rp.upper * (1 + 1e-12))
    assert rp.lower.max() == pytest.approx(rp.upper.max(), rel=1e-3)   # bounds are tight here
    # [SP] p. 334: "The peak value of mu_DeltaI(M) over frequency is ||M||_DeltaI = 0.53"
    # (RS: w_I T_I is a scalar times I) and the RP peak "is close to 6".
    Nd = _distillation_N(np.logspace(-3, 3, 241))
    rs_dense = la.mu_upper_bound(Nd[:, :2, :2], [(1, 1), (1, 1)], lower=False).upper.max()
    assert rs_dense == pytest.approx(0.53, abs=0.005)
    assert round(la.mu_upper_bound(Nd, [(1, 1), (1, 1), (2, 2)], lower=False).upper.max()) == 6


def test_distillation_mu_cross_check_dkpy():
    # Optional cross-check: dkpy (PyPI, D-K iteration toolbox) ships the same example as a
    # doctest, SsvLmiBisection(...).compute_ssv -> 5.77.  Skipped unless dkpy is installed.
    dkpy = pytest.importorskip("dkpy")
    N = _distillation_N(np.logspace(-3, 3, 61))
    blocks = [dkpy.ComplexFullBlock(1, 1), dkpy.ComplexFullBlock(1, 1), dkpy.ComplexFullBlock(2, 2)]
    mu_dk, *_ = dkpy.SsvLmiBisection(n_jobs=None).compute_ssv(np.moveaxis(N, 0, -1), blocks)   # (n, n, F)
    ours = la.mu_upper_bound(N, [(1, 1), (1, 1), (2, 2)], lower=False).upper
    np.testing.assert_allclose(ours, mu_dk, rtol=2e-3)


# ----------------------------------------------------------------------------------------
# mu: defining properties and an independent implementation
# ----------------------------------------------------------------------------------------
def test_mu_limits_full_block_and_diagonal_matrix():
    rng = np.random.default_rng(0)
    M = rng.standard_normal((5, 4, 4)) + 1j * rng.standard_normal((5, 4, 4))
    # one full block: mu = sigma_max
    full = la.mu_upper_bound(M, [(4, 4)])
    np.testing.assert_allclose(full.upper, la.sigma_max(M), rtol=1e-12)
    np.testing.assert_allclose(full.lower, la.sigma_max(M), rtol=1e-12)
    # diagonal M, scalar blocks: mu = spectral radius = max |m_ii|
    Dm = np.zeros_like(M)
    idx = np.arange(4)
    Dm[:, idx, idx] = M[:, idx, idx]
    diag = la.mu_upper_bound(Dm, [(1, 1)] * 4)
    rho = np.max(np.abs(M[:, idx, idx]), axis=1)
    np.testing.assert_allclose(diag.upper, rho, rtol=1e-6)
    np.testing.assert_allclose(diag.lower, rho, rtol=1e-6)
    # general matrix: rho(M) <= lower <= upper <= sigma_max(M)
    for blocks in ([(1, 1)] * 4, [(1, 1), (2, 2), (1, 1)], [(1, 2), (3, 2)]):
        b = la.mu_upper_bound(M, blocks)
        assert np.all(b.lower <= b.upper * (1 + 1e-12))
        assert np.all(b.upper <= la.sigma_max(M) * (1 + 1e-12))
        if all(r == c for r, c in blocks):
            assert np.all(np.max(np.abs(np.linalg.eigvals(M)), axis=1) <= b.lower * (1 + 1e-9))


def test_mu_lower_bound_is_achieved_by_a_structured_perturbation():
    # Definition of mu (Packard & Doyle 1993, Automatica 29(1); Skogestad & Postlethwaite sec. 8.8):
    # 1/mu = smallest sigma_max(Delta), Delta structured, with det(I - M Delta) = 0. A lower bound
    # that is attained means a structured Delta with sigma_max(Delta_i) = 1/lower makes I - M Delta
    # singular; det(I) = 1 sets the scale of the determinant.
    #
    # (a) rank one, M = a b^H: det(I - M Delta) = 1 - sum_i b_i^H Delta_i a_i, so mu = sum_i |a_i| |b_i|
    # (block norms) and Delta_i = b_i a_i^H / (|a_i| |b_i| mu) is destabilising (exact; for complex
    # scalars Delta_i = exp(-j arg(a_i conj(b_i))) / mu).
    rng = np.random.default_rng(5)
    for blocks in ([(1, 1)] * 3, [(1, 1), (2, 2), (1, 1)], [(1, 2), (3, 2)]):
        n, m = sum(c for _, c in blocks), sum(r for r, _ in blocks)
        a = rng.standard_normal(n) + 1j * rng.standard_normal(n)
        bv = rng.standard_normal(m) + 1j * rng.standard_normal(m)
        zc, wr = np.cumsum([0] + [c for _, c in blocks]), np.cumsum([0] + [r for r, _ in blocks])
        parts = [(a[zc[i]:zc[i + 1]], bv[wr[i]:wr[i + 1]]) for i in range(len(blocks))]
        mu = sum(np.linalg.norm(ai) * np.linalg.norm(bi) for ai, bi in parts)
        b = la.mu_upper_bound(np.outer(a, bv.conj()), blocks)
        assert b.upper[0] == pytest.approx(mu, rel=1e-9), blocks
        assert b.lower[0] == pytest.approx(mu, rel=1e-9), blocks
        Delta = np.zeros((m, n), complex)
        for i, (ai, bi) in enumerate(parts):
            Delta[wr[i]:wr[i + 1], zc[i]:zc[i + 1]] = np.outer(bi, ai.conj()) / (
                np.linalg.norm(ai) * np.linalg.norm(bi) * b.lower[0])
        assert abs(np.linalg.det(np.eye(n) - np.outer(a, bv.conj()) @ Delta)) < 1e-8, blocks
    # (b) general M, three complex scalars (2S + F <= 3: the D-scaling bound equals mu). At the
    # returned optimal scales d with a simple sigma_max(D M D^-1) = sigma u v^H + ..., |u_i| = |v_i|
    # and Delta = diag(v_i / u_i) / mu gives M Delta (D^-1 u) = D^-1 u: I - M Delta is singular.
    M = rng.standard_normal((3, 3)) + 1j * rng.standard_normal((3, 3))
    b = la.mu_upper_bound(M, [(1, 1)] * 3)
    assert b.lower[0] == pytest.approx(b.upper[0], rel=1e-9)
    d = b.d_scales[0]
    U, sv, Vh = np.linalg.svd(d[:, None] * M / d[None, :])
    assert sv[1] < 0.9 * sv[0]                                   # simple sigma_max
    ratio = Vh[0].conj() / U[:, 0]
    Delta = np.diag(ratio / np.abs(ratio)) / b.lower[0]          # sigma_max(Delta_i) = 1 / lower
    assert abs(np.linalg.det(np.eye(3) - M @ Delta)) < 1e-8
    assert b.lower[0] >= np.max(np.abs(np.linalg.eigvals(M))) - 1e-12
    # scaling M by 2 scales mu by 2 (homogeneity)
    b2 = la.mu_upper_bound(2 * M, [(1, 1)] * 3)
    assert b2.upper[0] == pytest.approx(2 * b.upper[0], rel=1e-6)


def test_mu_upper_bound_agrees_with_slycot_ab13md():
    # SLICOT AB13MD (Fan, Tits & Doyle 1991 upper bound), independent implementation.
    ab13md = pytest.importorskip("slycot").ab13md
    rng = np.random.default_rng(1)
    for blocks in ([(1, 1)] * 3, [(1, 1), (1, 1), (2, 2)], [(2, 2), (1, 1), (3, 3)]):
        n = sum(r for r, _ in blocks)
        M = rng.standard_normal((8, n, n)) + 1j * rng.standard_normal((8, n, n))
        ours = la.mu_upper_bound(M, blocks, lower=False).upper
        ref = [ab13md(Mk, np.array([r for r, _ in blocks]), np.array([2] * len(blocks)))[0] for Mk in M]
        np.testing.assert_allclose(ours, ref, rtol=1e-3)


# ----------------------------------------------------------------------------------------
# loop maps: signs pinned against control.feedback and between the two implementations
# ----------------------------------------------------------------------------------------
def _random_2dof(dt=250e-6, seed=3):
    rng = np.random.default_rng(seed)

    def stable(n, p, m, scale):
        A = rng.standard_normal((n, n))
        A *= scale / max(abs(np.linalg.eigvals(A)))
        return ct.ss(A, rng.standard_normal((n, m)), rng.standard_normal((p, n)),
                     0.2 * rng.standard_normal((p, m)), dt)

    return stable(4, 3, 2, 0.9), stable(3, 2, 3, 0.8), stable(2, 2, 3, 0.7)


def test_state_space_and_frequency_maps_agree_for_2dof_with_delay():
    G, K, Ky = _random_2dof()
    f = np.array([0.0, 1.0, 50.0, 333.0, 1999.0, 2000.0])
    for d in (0, 1, 2):
        r = la.loop_transfer_response(G, K, f, Ky=Ky, delay_samples=d)
        s = la.loop_transfer_ss(G, K, Ky=Ky, delay_samples=d)
        for name in ("S_o", "T_o", "S_i", "T_i", "KS", "KS_fb", "SG", "T_ry"):
            np.testing.assert_allclose(la.frequency_response(getattr(s, name), f), getattr(r, name),
                                       atol=1e-10, err_msg=f"{name}, delay {d}")
        # closed-loop realization: plant + delay + K + Ky states, each once
        assert s.closed_loop.nstates == G.nstates + d * G.ninputs + K.nstates + Ky.nstates
        p = la.closed_loop_poles(G, K, Ky, delay_samples=d)
        assert np.max(np.abs(p)) == pytest.approx(s.stability_measure, rel=1e-9)


def test_loop_maps_signs_match_control_feedback():
    # 1-DOF: S_o = feedback(I, G K), T_o = feedback(G K, I), K S_o = feedback(K, G),
    # S_o G = feedback(G, K), S_i = feedback(I, K G) -- python-control's negative feedback.
    rng = np.random.default_rng(11)

    def stable(n, p, m):
        A = rng.standard_normal((n, n))
        A -= (max(np.linalg.eigvals(A).real) + 1.0) * np.eye(n)
        return ct.ss(A, rng.standard_normal((n, m)), rng.standard_normal((p, n)), 0.3 * rng.standard_normal((p, m)))

    G, K = stable(3, 2, 2), stable(2, 2, 2)
    f = np.logspace(-2, 1, 7)
    r = la.loop_transfer_response(G, K, f)
    Iy, Iu = ct.ss([], [], [], np.eye(2)), ct.ss([], [], [], np.eye(2))
    ref = {"S_o": ct.feedback(Iy, G * K), "T_o": ct.feedback(G * K, Iy), "KS_fb": ct.feedback(K, G),
           "KS": ct.feedback(K, G), "SG": ct.feedback(G, K), "S_i": ct.feedback(Iu, K * G),
           "T_i": ct.feedback(K * G, Iu), "T_ry": ct.feedback(G * K, Iy)}
    for name, sysr in ref.items():
        np.testing.assert_allclose(getattr(r, name), la.frequency_response(sysr, f), atol=1e-10, err_msg=name)
    # 2-DOF: u = K r - (K - Ky) y; the r -> u map is (I + Kfb G)^-1 K, not K S_o
    Ky = ct.ss([], [], [], [[0.3, 0.0], [0.0, -0.2]])
    r2 = la.loop_transfer_response(G, K, f, Ky=Ky)
    Kfb = K - Ky
    np.testing.assert_allclose(r2.S_o, la.frequency_response(ct.feedback(Iy, G * Kfb), f), atol=1e-10)
    np.testing.assert_allclose(r2.KS, la.frequency_response(ct.feedback(Iu, Kfb * G) * K, f), atol=1e-10)
    np.testing.assert_allclose(r2.T_ry, la.frequency_response(ct.feedback(G, Kfb) * K, f), atol=1e-10)
    assert not np.allclose(r2.T_ry, r2.T_o)


def test_continuous_delay_is_exact_in_frequency_and_pade_in_state_space():
    G = ct.ss(ct.tf([1.0], [1e-3, 1.0]))
    dt = 250e-6
    f = np.array([1.0, 10.0, 100.0])
    r0 = la.loop_transfer_response(G, 2.0, f)
    r1 = la.loop_transfer_response(G, 2.0, f, delay_samples=1, dt=dt)
    np.testing.assert_allclose(r1.Lo[:, 0, 0], r0.Lo[:, 0, 0] * np.exp(-2j * np.pi * f * dt), rtol=1e-12)
    s = la.loop_transfer_ss(G, 2.0, delay_samples=1, dt=dt)
    np.testing.assert_allclose(la.frequency_response(s.S_o, f), r1.S_o, rtol=1e-6)


# ----------------------------------------------------------------------------------------
# parametric plant, robust stability, damping, summary
# ----------------------------------------------------------------------------------------
def test_perturbed_plant_moves_modes_keeps_dc_and_adds_delay():
    wn, zeta, dt = 2 * np.pi * 300.0, 0.02, 250e-6
    Gc = ct.ss(ct.tf([wn ** 2], [1.0, 2 * zeta * wn, wn ** 2]))
    for G in (Gc, ct.c2d(Gc, dt, "zoh")):
        f = np.array([0.0, 100.0, 299.0, 1000.0])
        same = la.perturbed_plant(G, 1.0, 1.0, 1.0, 0)
        np.testing.assert_allclose(la.frequency_response(same, f), la.frequency_response(G, f), atol=1e-9)
        P = la.perturbed_plant(G, 1.03, 2.0, 1.0, 0)
        ld = la.least_damped_pole(P)
        assert ld.freq_hz == pytest.approx(309.0, rel=1e-9)
        assert ld.zeta == pytest.approx(0.04, rel=1e-9)
        assert la.frequency_response(P, [0.0])[0, 0, 0].real == pytest.approx(1.0, rel=1e-9)
        Pd = la.perturbed_plant(G, 1.0, 1.0, [0.5], 1, dt=dt)
        ratio = la.frequency_response(Pd, f)[:, 0, 0] / la.frequency_response(G, f)[:, 0, 0]
        expect = 0.5 * np.exp(-2j * np.pi * f * dt)
        tol = 1e-9 if ct.isdtime(G, strict=True) else 0.02   # Pade(3) for the continuous plant
        np.testing.assert_allclose(ratio, expect, atol=tol)
    # per-channel input gains: G diag(g)
    P, g = satellite(), np.array([1.3, 0.6])
    f = np.array([0.0, 0.5, 3.0])
    np.testing.assert_allclose(la.frequency_response(la.perturbed_plant(P, input_gain=g), f),
                               la.frequency_response(P, f) * g[None, None, :], atol=1e-12)


def test_least_damped_pole_continuous_and_discrete():
    wn, zeta, dt = 2 * np.pi * 120.0, 0.07, 250e-6
    s = complex(-zeta * wn, wn * math.sqrt(1 - zeta ** 2))
    poles_s = np.array([s, s.conjugate(), -5.0, -2000.0])
    a = la.least_damped_pole(poles_s)
    b = la.least_damped_pole(np.exp(poles_s * dt), dt=dt)
    for ld in (a, b):
        assert ld.zeta == pytest.approx(zeta, rel=1e-9)
        assert ld.freq_hz == pytest.approx(120.0, rel=1e-9)
    assert la.least_damped_pole(np.append(np.exp(poles_s * dt), 0.0), dt=dt).zeta == pytest.approx(zeta)
    assert la.least_damped_pole(poles_s, f_band_hz=(200.0, 1e4)).freq_hz == pytest.approx(2000 / (2 * np.pi))
    assert la.least_damped_pole([0.5 + 0.0j, 1.2], dt=dt).zeta < 0   # unstable real z-pole


def test_robust_stability_mu_on_stage_like_plant():
    Gd, K = stage()
    f = np.logspace(-1, np.log10(2000.0), 90)
    res = la.robust_stability_mu(Gd, K, None, 250e-6, f, n_levels=2, n_random=6)
    assert res.nominal_stable
    assert np.all(res.mu_lower <= res.mu_upper * (1 + 1e-12))
    assert res.mu_peak >= res.mu_upper.max() * (1 - 1e-12)
    assert 300.0 < res.mu_peak_freq_hz < 1000.0
    # the covering contains every sampled plant: mu < 1 must imply sampled stability
    assert res.mu_peak < 1.0 and res.robustly_stable
    assert res.sampled_all_stable and res.sampled_worst < 1.0
    assert res.n_samples == 2 ** 3 * 2 * 2 * 2 + 6
    np.testing.assert_allclose(res.input_gain_center, 0.875)
    np.testing.assert_allclose(res.input_gain_radius, 0.125 / 0.875)
    # a gain set that reaches 4x nominal destabilises both checks
    bad = la.robust_stability_mu(Gd, K, None, 250e-6, f, input_gain_range=(0.75, 4.0), n_levels=2,
                                 n_random=0, refine=False)
    assert not bad.sampled_all_stable and bad.sampled_worst > 1.0
    assert bad.mu_peak > 1.0 and not bad.robustly_stable


def test_robustness_summary_is_json_with_units_in_keys():
    Gd, K = stage()
    f = np.logspace(-1, np.log10(2000.0), 50)
    summ = la.robustness_summary(Gd, K, f, delay_samples=1, f_band_hz=(50.0, 2000.0),
                                 robust={"n_levels": 2, "n_random": 0, "refine": False})
    text = json.dumps(summ, allow_nan=False)
    back = json.loads(text)
    for key in ("closed_loop_stable", "spectral_radius", "least_damped_zeta", "least_damped_freq_hz",
                "peak_So", "peak_So_freq_hz", "peak_Si", "peak_Si_freq_hz", "disk_margin_alpha",
                "gain_margin_db", "phase_margin_deg", "disk_margin_freq_hz",
                "dm_input_loop_at_a_time_alpha"):
        assert key in back, key
    assert back["closed_loop_stable"] is True
    worst = min(back[f"dm_{k}_alpha"] for k in ("input", "output", "input_output"))
    assert back["disk_margin_alpha"] == worst
    assert back["gain_margin_db"][1] == pytest.approx(20 * math.log10(la.disk_gain_phase(worst)[1]), rel=1e-12)
    assert worst <= min(back["dm_input_loop_at_a_time_alpha"] + back["dm_output_loop_at_a_time_alpha"])
    r = la.loop_transfer_response(Gd, K, f, delay_samples=1)
    assert back["peak_So"] >= r.peak("S_o")[0] * (1 - 1e-12)       # refined peak >= grid peak
    dense = la.loop_transfer_response(Gd, K, np.linspace(300.0, 600.0, 3001), delay_samples=1)
    assert back["peak_So"] == pytest.approx(dense.peak("S_o")[0], rel=1e-4)
    assert len(back["dm_output_loop_at_a_time_alpha"]) == 3


# ----------------------------------------------------------------------------------------
# argument errors: raised before any work, naming argument, expectation and value
# ----------------------------------------------------------------------------------------
def test_errors_name_the_argument():
    G, K, _ = _random_2dof()
    with pytest.raises(ValueError, match=r"K: expected 2 outputs x 3 inputs.*got 3 x 2"):
        la.loop_transfer_response(G, ct.ss(K.A.T, K.C.T, K.B.T, K.D.T, K.dt), [1.0])
    with pytest.raises(ValueError, match=r"freq_hz: .*Nyquist frequency 2000.0 Hz, got up to 2500.0 Hz"):
        la.loop_transfer_response(G, K, [1.0, 2500.0])
    with pytest.raises(ValueError, match=r"dt: delay_samples=1 needs the sample period"):
        la.loop_transfer_response(ct.ss(ct.tf(1, [1, 1])), 1.0, [1.0], delay_samples=1)
    with pytest.raises(ValueError, match=r"mixed time bases"):
        la.loop_transfer_response(G, ct.ss(np.zeros((2, 2)) - np.eye(2), np.ones((2, 3)), np.ones((2, 2)), 0), [1.0])
    with pytest.raises(TypeError, match=r"delay_samples: expected a non-negative integer.*0.5"):
        la.loop_transfer_response(G, K, [1.0], delay_samples=0.5)
    with pytest.raises(ValueError, match=r"M: the blocks .* need M of shape \(F, 3, 3\).*got \(2, 4, 4\)"):
        la.mu_upper_bound(np.zeros((2, 4, 4)), [(1, 1), (2, 2)])
    with pytest.raises(ValueError, match=r"blocks: expected positive sizes"):
        la.mu_upper_bound(np.zeros((2, 2)), [(2, 0)])
    with pytest.raises(ValueError, match=r"freq_hz: expected strictly increasing"):
        la.disk_margins(G, K, [10.0, 1.0])
    with pytest.raises(ValueError, match=r"input_gain_range: expected"):
        la.robust_stability_mu(*stage(), None, 250e-6, [1.0, 2.0], input_gain_range=(1.0, 0.5))


# ----------------------------------------------------------------------------------------
# the loop as run (nanosim.experiments.loop.run_closed_loop on a Stage): its delay
# ----------------------------------------------------------------------------------------
def _two_dof_controller(Gd):
    """u = K e + Ky y: integral action on decoupled axes and a zero-DC derivative Ky."""
    dt = Gd.dt
    G0inv = np.linalg.inv(np.real(ct.dcgain(Gd)))
    integ = ct.ss(ct.tf([2 * np.pi * 40.0 * dt, 0.0], [1.0, -1.0], dt))
    der = ct.ss(ct.tf([0.05, -0.05], [1.0, 0.0], dt))
    K = ct.append(integ, integ, integ) * ct.ss([], [], [], G0inv, dt)
    Ky = ct.append(der, der, der) * ct.ss([], [], [], G0inv, dt)
    K2 = ct.ss(scipy_block_diag(K.A, Ky.A), scipy_block_diag(K.B, Ky.B), np.hstack([K.C, Ky.C]),
               np.hstack([K.D, Ky.D]), dt)
    return K, Ky, K2


def scipy_block_diag(*m):
    import scipy.linalg
    return scipy.linalg.block_diag(*m)


def test_loop_as_run_is_the_record_row_plant_delayed_by_one_sample():
    # run_closed_loop computes u_k from the reading y_k that stage.step(u_{k-1}) returned, and
    # stage.step(u_k) returns y_{k+1}.  In the convention of a record row (u_k, reading after
    # step(u_k)) -- the identified model's, LoopPlant.twin for a ZOH model -- the loop as run is
    # that plant followed by exactly RECORD_ROW_DELAY_SAMPLES = 1 sample, to rounding error.
    from types import SimpleNamespace

    from nanosim.design.controller import DiscreteController
    from nanosim.experiments.loop import LoopProtocol, run_closed_loop
    from nanosim.plant.stage import StageConfig
    from nanosim.plant.twin import TwinStage

    Gd, _ = stage()
    Gd = ct.ss(Gd.A, Gd.B, Gd.C, 0.02 * np.eye(3), Gd.dt)      # a feedthrough, like the twin's residualised modes
    K, Ky, K2 = _two_dof_controller(Gd)
    st = TwinStage(SimpleNamespace(sysd_V=Gd, dt_s=Gd.dt), config=StageConfig.ideal())
    ctrl = DiscreteController.from_matrices(K2.A, K2.B, K2.C, K2.D, Gd.dt, n_error=3)
    n = 200
    r = np.zeros((n, 3))
    r[10:] = [0.5, -0.3, 0.2]                                      # um
    y = run_closed_loop(st, ctrl, r, protocol=LoopProtocol(0.0, 0.0)).y_um
    err = {}
    for d in (0, 1, 2):
        T = la.loop_transfer_ss(la.LoopPlant.twin(Gd).G, K, Ky, delay_samples=d).T_ry
        yp = ct.forced_response(T, U=r.T).outputs.T
        err[d] = np.abs(y - yp).max() / np.abs(y).max()
    assert la.RECORD_ROW_DELAY_SAMPLES == 1
    assert err[1] < 1e-9
    assert err[0] > 1e-3 and err[2] > 1e-3


def test_bench_electronics_add_their_delay_and_filters_to_the_loop_as_run():
    # With the bench electronics (computation delay, amplifier lag, gauge filter; nanosim.plant.filters)
    # the loop as run is LoopPlant.twin(..., electronics) with 1 + computation_delay_samples samples.
    from types import SimpleNamespace

    from nanosim.design.controller import DiscreteController
    from nanosim.experiments.loop import LoopProtocol, run_closed_loop
    from nanosim.plant.electronics import ElectronicsConfig
    from nanosim.plant.stage import StageConfig
    from nanosim.plant.twin import TwinStage

    Gd, _ = stage()
    K, Ky, K2 = _two_dof_controller(Gd)
    elec = ElectronicsConfig.ideal(computation_delay_samples=1, amplifier_bandwidth_Hz=10e3, gauge_bandwidth_Hz=5e3)
    st = TwinStage(SimpleNamespace(sysd_V=Gd, dt_s=Gd.dt), config=StageConfig(electronics=elec,
                                                                              piezo=StageConfig.ideal().piezo,
                                                                              floor=StageConfig.ideal().floor))
    ctrl = DiscreteController.from_matrices(K2.A, K2.B, K2.C, K2.D, Gd.dt, n_error=3)
    r = np.zeros((200, 3))
    r[10:] = [0.5, -0.3, 0.2]
    y = run_closed_loop(st, ctrl, r, protocol=LoopProtocol(0.0, 0.0)).y_um
    plant = la.LoopPlant.twin(Gd, elec)
    assert plant.delay_samples == 2
    T = la.loop_transfer_ss(plant.G, K, Ky, delay_samples=plant.delay_samples).T_ry
    yp = ct.forced_response(T, U=r.T).outputs.T
    assert np.abs(y - yp).max() / np.abs(y).max() < 1e-9
    T1 = la.loop_transfer_ss(la.LoopPlant.twin(Gd).G, K, Ky, delay_samples=2).T_ry    # delays without filters
    assert np.abs(y - ct.forced_response(T1, U=r.T).outputs.T).max() / np.abs(y).max() > 1e-3


def test_mujoco_reading_responds_to_the_command_of_its_own_row(ideal, twin):
    # Stage.step (MuJoCo) has the timing of the twin's record-row model: the reading after
    # step(u_0) already moves (a model fit to record rows has a feedthrough), and the impulse
    # response matches LoopPlant.twin(...).G within the linearization error, not one sample later.
    ideal.reset()
    n = 80
    u = np.zeros((n, 3))
    u[0] = [0.05, -0.03, 0.04]
    y0 = ideal.sensors.step(ideal.table_um).reading_V
    dy = ideal.run(u).sensor_V - y0
    ideal.reset()
    yp = ct.forced_response(la.LoopPlant.twin(twin.sysd_V).G, U=u.T).outputs.T
    same_row = np.abs(dy - yp).max() / np.abs(dy).max()
    next_row = np.abs(dy[1:] - yp[:-1]).max() / np.abs(dy).max()
    assert np.abs(dy[0]).max() > 1e-4                  # sensor V, after one period
    assert same_row < 1e-3 and next_row > 0.2      # the twin is MuJoCo's exact linearization (3e-5 here)


def test_analyze_controller_on_the_loop_as_run():
    Gd, _ = stage()
    K, Ky, K2 = _two_dof_controller(Gd)
    plant = la.LoopPlant.twin(Gd)
    f = np.logspace(-1, np.log10(2000.0), 60)
    res = la.analyze_controller(K2, plant, n_error=3, freq_hz=f, n_levels=2, n_random=0)
    ref = la.robustness_summary(plant.G, K, f, Ky, delay_samples=1)
    for key in ("peak_So", "peak_Si", "peak_To", "peak_Ti", "peak_KS", "peak_SG", "dm_input_alpha",
                "dm_output_alpha", "least_damped_zeta", "spectral_radius"):
        assert res.summary[key] == pytest.approx(ref[key], rel=1e-9), key
    assert res.delay_samples == 1 and res.robust is not None
    assert res.summary["mu_covering_peak"] >= res.summary["mu_covering_lower_peak"] * (1 - 1e-9)
    # mu_peak is the mixed (real-parametric) bound; mu < 1 would have to agree with the sampled check
    assert res.mixed is not None and res.summary["mu_n_parameters"] == res.mixed.n_parameters
    # this loop has unstable members (sampled spectral radius 1.03): the mixed analysis must not
    # certify it (here its centre loop with one extra sample is already unstable: mu = inf, JSON null)
    assert not res.summary["sampled_all_stable"] and res.summary["sampled_worst"] > 1.0
    assert not res.mixed.robustly_stable and not res.summary["mu_robustly_stable"]
    assert res.mixed.centre_spectral_radius > 1.0 and res.summary["mu_peak"] is None
    back = json.loads(json.dumps(res.to_dict(), allow_nan=False))
    assert back["uncertainty_set"]["extra_delay_samples_range"] == [0, 1]
    assert res.robust.sampled_worst_parameters["delay_samples"] in (1, 2)     # the loop's 1 + (0 or 1)
    # the 2-DOF split and the error-only form agree on the feedback operator K - Ky
    Kc, Kyc = la.controller_systems(K2, n_error=3)
    np.testing.assert_allclose(la.frequency_response(Kc - Kyc, f), la.frequency_response(K - Ky, f), atol=1e-9)
    assert la.controller_systems(K)[1] is None
    with pytest.raises(ValueError, match="controller: sample time"):
        la.analyze_controller(ct.ss(K2.A, K2.B, K2.C, K2.D, 1e-3), plant, n_error=3, freq_hz=f[f < 400])


def test_analyze_controller_repeats_are_served_once_and_stay_independent():
    # the robust LQG rule's mu check and robustness.json analyse the same loop within one command (an
    # analysis_memo scope): the second call is a copy of the first (same numbers), a caller editing its summary
    # does not change the next answer, and any change of the inputs (here the sampling seed or the controller) is
    # a new analysis; outside a scope nothing is kept
    from nanosim.design import robustness as rb

    Gd, _ = stage()
    _, _, K2 = _two_dof_controller(Gd)
    plant = la.LoopPlant.twin(Gd)
    f = np.logspace(-1, np.log10(2000.0), 40)
    kw = dict(n_error=3, freq_hz=f, n_levels=2, n_random=2)
    assert rb._MEMO.get() is None
    with rb.analysis_memo():
        memo = rb._MEMO.get()
        a = la.analyze_controller(K2, plant, **kw)
        assert len(memo) == 1
        a.summary["peak_So"] = -1.0
        b = la.analyze_controller(K2, plant, **kw)
        assert len(memo) == 1 and b.summary["peak_So"] > 1.0
        assert b.summary["sampled_worst"] == a.summary["sampled_worst"]
        with rb.analysis_memo():                        # a nested scope shares the outer memory
            assert rb._MEMO.get() is memo
        c = la.analyze_controller(K2, plant, seed=1, **kw)
        assert len(memo) == 2 and c is not b
        K3 = ct.ss(K2.A, K2.B, 0.5 * np.asarray(K2.C), 0.5 * np.asarray(K2.D), K2.dt)
        d = la.analyze_controller(K3, plant, **kw)
        assert len(memo) == 3
        assert np.abs(np.sort_complex(d.poles) - np.sort_complex(b.poles)).max() > 1e-3
    assert rb._MEMO.get() is None
    e = la.analyze_controller(K2, plant, **kw)
    assert e.summary["sampled_worst"] == b.summary["sampled_worst"] and e.summary["peak_So"] == b.summary["peak_So"]

def test_perturbed_plant_moves_the_modes_not_the_signal_chain_filters():
    # The gauge's Tustin-discretized Butterworth (3 identical channels, poles in the left half
    # of the z-plane, zeta 0.7) is not a structural mode: only the light modes move.
    from nanosim.plant.electronics import ElectronicsConfig

    Gd, _ = stage()
    elec = ElectronicsConfig.ideal(computation_delay_samples=1, amplifier_bandwidth_Hz=10e3, gauge_bandwidth_Hz=5e3)
    plant = la.LoopPlant.twin(Gd, elec)
    P = la.perturbed_plant(plant.G, 1.03, 0.5)
    p0 = np.linalg.eigvals(plant.G.A)
    p1 = np.linalg.eigvals(P.A)
    light = la.least_damped_pole(P)
    assert light.freq_hz == pytest.approx(1.03 * 900.0, rel=1e-6) and light.zeta == pytest.approx(0.0075, rel=1e-6)
    filt = p0[(np.abs(p0) > 1e-3) & (p0.real < 0)]                       # the gauge filter's poles
    assert filt.size == 6 and all(np.min(np.abs(p1 - q)) < 1e-6 for q in filt)
    f = np.logspace(0, np.log10(2000.0), 40)
    K, Ky, _ = _two_dof_controller(Gd)
    res = la.robust_stability_mu(plant.G, K, Ky, None, f, nominal_delay_samples=plant.delay_samples,
                                 delay_samples_range=(2, 2), n_levels=2, n_random=0, refine=False)
    assert res.n_samples == 2 ** 3 * 2 * 2 * 1
