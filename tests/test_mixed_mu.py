"""Mixed real/complex mu (D-G scalings) and the parametric LFT of the stage's uncertainty set.

Published/analytic answers used:
- rank-one M = a b^H: mixed mu = inf_x sum_real |Re z_i + x Im z_i| + sqrt(1 + x^2) sum_complex |z_i|,
  z_i = conj(b_i) a_i (Young, "The rank one mixed mu problem and Kharitonov-type analysis", Automatica
  30(12), 1994; Chen, Fan & Nett, IEEE TAC 1994), and the D-G upper bound is exact for rank one;
- a scalar real parameter: mu = |m| if m is real, 0 otherwise;
- a first-order discrete loop with an uncertain gain: the destabilising gain is known in closed form.
"""
from __future__ import annotations

import math

import control as ct
import numpy as np
import pytest
import scipy.optimize

from nanosim.design.mu import mixed_mu_upper_bound, mu_upper_bound
from nanosim.design.parametric import merge_modes, parametric_lft, robust_stability_mixed_mu
from nanosim.design.uncertainty import ModalPlant

DT = 250e-6


def rank_one_mu(a, b, real):
    z = np.conj(b) * a
    zr, zc = z[real], z[~real]

    def f(x):
        return float(np.sum(np.abs(zr.real + x * zr.imag)) + math.sqrt(1 + x * x) * np.sum(np.abs(zc)))

    # convex in x: the minimum is at a kink (-Re z / Im z of a real entry) or a smooth stationary point
    kinks = [-v.real / v.imag for v in zr if abs(v.imag) > 1e-15]
    best = min([f(0.0)] + [f(x) for x in kinks])
    res = scipy.optimize.minimize_scalar(f, bounds=(-1e4, 1e4), method="bounded", options={"xatol": 1e-10})
    return min(best, res.fun)


@pytest.mark.parametrize("pattern", [[1, 1, 1, 1, 1], [1, 1, 1, 0, 0], [1, 0, 1, 0, 1], [0, 0, 0, 0, 1]])
def test_rank_one_mixed_mu_matches_the_closed_form(pattern):
    real = np.array(pattern, bool)
    rng = np.random.default_rng(sum(pattern))
    for _ in range(3):
        a = rng.standard_normal(5) + 1j * rng.standard_normal(5)
        b = rng.standard_normal(5) + 1j * rng.standard_normal(5)
        exact = rank_one_mu(a, b, real)
        r = mixed_mu_upper_bound(np.outer(a, b.conj()), real)
        assert r.upper[0] >= exact * (1 - 1e-9)               # an upper bound
        assert r.upper[0] == pytest.approx(exact, rel=2e-3)    # and tight for rank one
        if real.any():
            assert r.upper[0] < r.complex_upper[0]


def test_scalar_real_parameter():
    real = np.array([True])
    assert mixed_mu_upper_bound(np.array([[-2.5]]), real).upper[0] == pytest.approx(2.5, rel=1e-12)
    # no real delta makes 1 - m delta vanish when m is not real
    assert mixed_mu_upper_bound(np.array([[1.0 + 0.5j]]), real).upper[0] < 1e-3
    assert mixed_mu_upper_bound(np.array([[1.0 + 0.5j]]), np.array([False])).upper[0] == pytest.approx(abs(1 + .5j))


def test_all_complex_structure_is_the_complex_bound():
    rng = np.random.default_rng(3)
    M = rng.standard_normal((4, 4, 4)) + 1j * rng.standard_normal((4, 4, 4))
    r = mixed_mu_upper_bound(M, np.zeros(4, bool))
    ref = mu_upper_bound(M, [(1, 1)] * 4, lower=False).upper
    np.testing.assert_allclose(r.upper, ref, rtol=1e-6)


def test_upper_bound_is_above_a_destabilising_real_perturbation():
    # mu >= rho_R(M Delta) for every real Delta in the unit box (Young 1994); scan a grid
    rng = np.random.default_rng(7)
    real = np.ones(3, bool)
    for _ in range(3):
        M = rng.standard_normal((3, 3)) + 0.3j * rng.standard_normal((3, 3))
        lo = 0.0
        g = np.linspace(-1, 1, 21)
        for d in np.array(np.meshgrid(g, g, g)).reshape(3, -1).T:
            ev = np.linalg.eigvals(M @ np.diag(d))
            ev = ev[np.abs(ev.imag) < 1e-9 * max(1.0, np.abs(ev).max())]
            if ev.size:
                lo = max(lo, float(np.abs(ev.real).max()))
        r = mixed_mu_upper_bound(M, real)
        assert lo <= r.upper[0] * (1 + 1e-9) <= r.complex_upper[0] * (1 + 1e-9)


def two_mode_plant():
    wn = 2 * np.pi * np.array([176.0, 470.0])
    zeta = np.array([0.004, 0.006])
    Phi = np.array([[1.0, 0.2], [0.1, 1.0]])
    A = np.zeros((4, 4))
    B = np.zeros((4, 2))
    C = np.zeros((2, 4))
    for i in range(2):
        A[2 * i:2 * i + 2, 2 * i:2 * i + 2] = [[0.0, 1.0], [-wn[i] ** 2, -2 * zeta[i] * wn[i]]]
        B[2 * i + 1] = wn[i] ** 2 * Phi[i]
        C[i, 2 * i] = 1.0
    return ct.c2d(ct.ss(A, B, C, 0), DT, "zoh")


def test_lft_is_exact_at_the_vertices_of_the_set():
    G = two_mode_plant()
    lft = parametric_lft(G)
    mp = ModalPlant(G, DT)
    f = np.array([20.0, 176.0, 181.0, 470.0, 485.0, 1500.0])
    zf = np.exp(2j * np.pi * f * DT)
    for fs, zs, g, dd in [(1.03, 0.5, 0.75, 1), (0.97, 2.0, 1.0, 0), (1.03, 2.0, 0.75, 0), (0.97, 0.5, 1.0, 1),
                          (1.01, 1.3, 0.8, 1)]:
        delta = lft.delta_at(fs, zs, g, dd, f)
        assert np.abs(delta).max() <= 1 + 1e-9            # the member is inside the unit box
        assert np.all(delta[:, lft.real].imag == 0)
        exact = mp.response(f, fs, zs) * g * (zf ** -dd)[:, None, None]
        np.testing.assert_allclose(lft.plant_response(delta, f), exact, rtol=1e-9, atol=1e-9 * np.abs(exact).max())
    # outside the set: some parameter leaves the unit box
    assert np.abs(lft.delta_at(1.05, 1.0, 1.0, 0, f)).max() > 1.0


def test_centre_plant_is_the_lft_at_zero():
    G = two_mode_plant()
    lft = parametric_lft(G)
    f = np.geomspace(5.0, 1900.0, 40)
    P22 = lft.blocks(f)[3]
    ref = np.array([lft.centre(np.exp(2j * np.pi * fk * DT)) for fk in f])
    np.testing.assert_allclose(P22, ref, rtol=1e-9, atol=1e-12)


def test_uncertain_gain_of_a_first_order_loop():
    # y = b/(z - p) u, u = -kp y: closed-loop pole p - kp b g leaves the unit disk at
    # g* = (1 + p)/(kp b) (z = -1, the Nyquist frequency).  g = c (1 + r delta) with
    # c = 0.875, r = 1/7 over [0.75, 1]: delta* = (g*/c - 1)/r and mu = 1/delta*.
    p, b, kp = 0.5, 1.0, 1.2
    G = ct.ss(p, b, 1.0, 0.0, DT)
    K = ct.ss([], [], [], [[kp]], DT)
    f = np.linspace(10.0, 2000.0, 200)
    res = robust_stability_mixed_mu(G, K, None, f, freq_scale_range=(1.0, 1.0), damping_scale_range=(1.0, 1.0),
                                    delay_samples_range=(0, 0))
    g_star = (1 + p) / (kp * b)
    mu_exact = 1.0 / ((g_star / 0.875 - 1) * 7.0)
    assert res.centre_stable
    assert res.mu_peak == pytest.approx(mu_exact, rel=1e-6)
    assert res.mu_peak_freq_hz == pytest.approx(2000.0)
    # a gain range reaching g* is not robustly stable, and mu says so
    bad = robust_stability_mixed_mu(G, K, None, f, input_gain_range=(0.75, 1.3), freq_scale_range=(1.0, 1.0),
                                    damping_scale_range=(1.0, 1.0), delay_samples_range=(0, 0))
    assert bad.mu_peak > 1.0 and not bad.robustly_stable


def test_mixed_mu_rejects_bad_input():
    with pytest.raises(ValueError, match="real: expected 3 booleans"):
        mixed_mu_upper_bound(np.eye(3), [True, False])
    with pytest.raises(ValueError, match="delay_samples_range"):
        parametric_lft(two_mode_plant(), delay_samples_range=(0, 2))
    with pytest.raises(ValueError, match="discrete"):
        parametric_lft(ct.ss(-1.0, 1.0, 1.0, 0.0))


def test_repeated_scalar_blocks():
    # delta I (repeated): 1 - delta lambda_i(M) = 0, so mu = rho(M) for a complex delta and the
    # largest |real eigenvalue| for a real one (0 if there is none)
    rng = np.random.default_rng(2)
    V = rng.standard_normal((4, 4)) + 1j * rng.standard_normal((4, 4))
    lam = np.array([0.5, 2 + 2j, 2 - 1j, -1 + 2.5j])
    M = V @ np.diag(lam) @ np.linalg.inv(V)
    one = np.zeros(4, int)
    assert mixed_mu_upper_bound(M, np.zeros(4, bool), groups=one).upper[0] == pytest.approx(np.abs(lam).max(),
                                                                                             rel=1e-4)
    assert mixed_mu_upper_bound(M, np.ones(4, bool), groups=one).upper[0] == pytest.approx(0.5, rel=1e-4)
    # treating the repeated parameter as four independent ones is a (much) larger set
    assert mixed_mu_upper_bound(M, np.ones(4, bool)).upper[0] > 2.0
    with pytest.raises(ValueError, match="mixes real and complex"):
        mixed_mu_upper_bound(M, np.array([True, True, False, False]), groups=one)


def test_merge_modes_keeps_a_column_stacked_model():
    # a model identified column by column holds each mode once per column: stack the same
    # plant twice, each copy driven by one input; merging gives back one copy per mode
    G = two_mode_plant()
    A = np.kron(np.eye(2), G.A)
    B = np.vstack([G.B @ np.diag([1.0, 0.0]), G.B @ np.diag([0.0, 1.0])])
    G2 = ct.ss(A, B, np.hstack([G.C, G.C]), G.D, DT)
    mm = merge_modes(G2)
    assert mm.G.nstates == G.nstates and mm.n_merged == 4
    assert mm.error_rel < 1e-8 and mm.residue_rank_ratio < 1e-8
    f = np.geomspace(1.0, 1900.0, 30)
    ref = np.array([G(np.exp(2j * np.pi * fk * DT)) for fk in f])
    np.testing.assert_allclose(np.array([mm.G(np.exp(2j * np.pi * fk * DT)) for fk in f]), ref, rtol=1e-7,
                               atol=1e-9 * np.abs(ref).max())
