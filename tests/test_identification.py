"""Tests for the ``identification`` package.

Systems are generated at random inside the tests and only basis-independent
quantities are compared (poles, DC gain, frequency response, fit).
"""
from __future__ import annotations

import dataclasses
import pathlib
import subprocess
import sys

import control
import numpy as np
import pytest
import scipy.linalg as la
import scipy.signal as ss
from numpy.testing import assert_allclose
from scipy.optimize import linear_sum_assignment

import identification as ident

FS = 4000.0
DT = 1.0 / FS


# ----------------------------------------------------------------------------
# helpers
# ----------------------------------------------------------------------------
def random_system(n, m, l, seed, *, light=False, feedthrough=False, fs=FS):
    """Random stable continuous system (ZOH-discretised), hidden by a similarity transform.

    Complex pairs with natural frequencies in [0.01, 0.3] fs and damping in
    [0.002, 0.01] (``light``) or [0.02, 0.3]; one real pole (1-50 Hz) if ``n``
    is odd.  Returns continuous (A, B, C, D) and discrete (Ad, Bd, Cd, Dd).
    """
    rng = np.random.default_rng(seed)
    blocks = []
    for _ in range(n // 2):
        w = 2 * np.pi * rng.uniform(0.01, 0.3) * fs
        z = rng.uniform(0.002, 0.01) if light else rng.uniform(0.02, 0.3)
        wd = w * np.sqrt(1 - z * z)
        blocks.append(np.array([[-z * w, wd], [-wd, -z * w]]))
    if n % 2:
        blocks.append(np.array([[-2 * np.pi * rng.uniform(1.0, 50.0)]]))
    A = la.block_diag(*blocks)
    B = rng.normal(size=(n, m))
    C = rng.normal(size=(l, n))
    D = 0.1 * rng.normal(size=(l, m)) if feedthrough else np.zeros((l, m))
    T = rng.normal(size=(n, n)) + 3 * np.eye(n)
    A, B, C = la.solve(T, A @ T), la.solve(T, B), C @ T
    M = np.zeros((n + m, n + m))
    M[:n, :n], M[:n, n:] = A, B
    E = la.expm(M / fs)
    return (A, B, C, D), (E[:n, :n], E[:n, n:], C, D)


def column_plant(rng, f, fs=FS):
    """One 1-input, 3-output column: light modes at ``f`` Hz plus a creep pole at 30 rad/s (ZOH at ``fs``).

    Damping ratios in [0.002, 0.01] and output couplings are drawn from
    ``rng``.  Returns continuous (A, B, C, D), discrete (Ad, Bd, Cd, Dd) and
    the damping ratios.
    """
    zeta = rng.uniform(0.002, 0.01, f.size)
    n = 2 * f.size + 1
    A = np.zeros((n, n))
    B = np.zeros((n, 1))
    C = np.zeros((3, n))
    for k, (fk, zk) in enumerate(zip(f, zeta)):
        w = 2 * np.pi * fk
        A[2 * k : 2 * k + 2, 2 * k : 2 * k + 2] = [[0.0, 1.0], [-w * w, -2 * zk * w]]
        B[2 * k + 1, 0] = w * w
        C[:, 2 * k] = rng.normal(size=3) / (k + 1)
    C[:, 0] += 1.0
    A[n - 1, n - 1], B[n - 1, 0] = -30.0, 30.0
    C[:, n - 1] = 0.15 * rng.normal(size=3)
    D = np.zeros((3, 1))
    M = np.zeros((n + 1, n + 1))
    M[:n, :n], M[:n, n:] = A, B
    E = la.expm(M / fs)
    return (A, B, C, D), (E[:n, :n], E[:n, n:], C, D), zeta


def paper_like_plant(seed=0, fs=FS):
    """13 states: 6 modes (175..740 Hz, damping 0.002-0.01) + creep pole at 30 rad/s; 1 input, 3 outputs."""
    rng = np.random.default_rng(seed)
    f = np.array([175.0, 179.0, 245.0, 460.0, 474.0, 740.0])
    sysc, sysd, zeta = column_plant(rng, f, fs)
    return sysc, sysd, f, zeta


def dsim(sysd, u, x0=None):
    Ad, Bd, Cd, Dd = sysd
    _, y, _ = ss.dlsim((Ad, Bd, Cd, Dd, DT), u, x0=x0)
    return y


def dc_gain(sysd):
    Ad, Bd, Cd, Dd = sysd
    return Cd @ la.solve(np.eye(Ad.shape[0]) - Ad, Bd) + Dd


def matched(p_true, p_est):
    """Pair poles by minimum total distance; returns (true, estimate) arrays."""
    assert p_true.size == p_est.size
    r, c = linear_sum_assignment(np.abs(p_true[:, None] - p_est[None, :]))
    return p_true[r], p_est[c]


def prbs_inputs(n_samples, m, seed, band_hz=FS / 2):
    return np.stack([ident.prbs(n_samples, band_hz, fs=FS, seed=1000 * seed + q) for q in range(m)], axis=1)


class TrueModel:
    def __init__(self, sysd, K=None):
        self.A, self.B, self.C, self.D = sysd
        self.K = K


# ----------------------------------------------------------------------------
# signals
# ----------------------------------------------------------------------------
@pytest.mark.parametrize("nbits", [5, 9])
def test_prbs_is_maximum_length_sequence(nbits):
    n = 2**nbits - 1
    u = ident.prbs(n, FS / 2, fs=FS, amplitude=2.0, seed=3)
    x = u / 2.0
    acf = np.array([np.dot(x, np.roll(x, k)) for k in range(n)])
    expected = np.full(n, -1.0)
    expected[0] = n
    assert_allclose(acf, expected, rtol=0, atol=1e-12)


def test_prbs_hold_amplitude_and_seed():
    u = ident.prbs(5000, 100.0, fs=FS, amplitude=0.3, seed=7)
    hold = ident.prbs_hold_samples(100.0, fs=FS)
    assert hold == 20
    assert u.shape == (5000,)
    assert set(np.unique(u)) == {-0.3, 0.3}
    chips = u.reshape(-1, hold)
    assert np.all(chips == chips[:, :1])  # held for exactly `hold` samples
    assert_allclose(ident.prbs(5000, 100.0, fs=FS, amplitude=0.3, seed=7), u, rtol=0, atol=0)
    assert not np.array_equal(ident.prbs(5000, 100.0, fs=FS, amplitude=0.3, seed=8), u)


def test_prbs_channels_are_disjoint_stretches_of_one_mls():
    u = ident.prbs_channels(5000, 100.0, fs=FS, n_channels=3, amplitude=0.3, seed=7)
    hold = ident.prbs_hold_samples(100.0, fs=FS)
    assert u.shape == (5000, 3) and set(np.unique(u)) == {-0.3, 0.3}
    chips = u.reshape(-1, hold, 3)
    assert np.all(chips == chips[:, :1])
    assert np.array_equal(ident.prbs_channels(5000, 100.0, fs=FS, n_channels=3, amplitude=0.3, seed=7), u)
    # the channels continue one another: channel k's chips are the MLS right after channel k - 1's
    nbits = int(np.ceil(np.log2(3 * 250 + 1)))
    x = (np.concatenate([chips[:, 0, k] for k in range(3)]) > 0).astype(int)
    period = 2 ** nbits - 1
    full = ss.max_len_seq(nbits, length=2 * period)[0]
    w = x[:40]
    starts = [i for i in range(period) if (full[i:i + 40] == w).all()]
    assert len(starts) == 1 and (full[starts[0]:starts[0] + x.size] == x).all()
    with pytest.raises(ValueError, match="n_channels"):
        ident.prbs_channels(100, 100.0, fs=FS, n_channels=0)


@pytest.mark.parametrize("seed", range(5))
def test_prbs_channels_give_an_unbiased_mimo_h1(seed):
    """Three channels through a static 3x3 gain with output noise: H1 recovers the matrix in every Welch bin
    of 2-800 Hz (16000 samples, nperseg 2048: 14 averages). Stacking independent ``prbs`` calls gives cyclic
    shifts of one MLS; when two shifts are close the input spectral matrix is nearly singular below one over
    the shift, which biased the closed-loop S estimates by up to 1.9 dB over 8-40 Hz."""
    rng = np.random.default_rng(seed)
    M = np.array([[-2.0, -1.2, 3.2], [2.5, -3.0, 0.5], [1.0, 1.0, 1.0]])
    u = ident.prbs_channels(16000, 800.0, fs=FS, n_channels=3, amplitude=2.0, seed=seed)
    y = u @ M.T + 0.2 * rng.standard_normal((16000, 3))
    est = ident.h1_estimate(u, y, fs=FS, nperseg=2048)
    band = (est.freq_hz >= 2.0) & (est.freq_hz <= 800.0)
    err = np.abs(est.H[band] - M[None]).max(axis=(1, 2)) / np.abs(M).max()
    # output noise 0.2 vs input 2.0 per channel: relative error ~ 0.1 / sqrt(14) per entry; 6 sigma
    assert err.max() < 0.06, err.max()
    lags = ss.correlate(u[:, 0], u[:, 1], mode="full") / 16000 / 4.0
    assert np.abs(lags).max() < 5 / np.sqrt(8000)                 # no lag at which one channel repeats another


def test_prbs_spectrum_flat_to_band():
    band = 100.0
    u = ident.prbs(2**16, band, fs=FS, seed=0)
    spec = ident.signal_spectrum(u, fs=FS, nperseg=2048)
    f, p = spec.freq_hz, spec.psd
    ref = np.mean(p[(f > 2) & (f < 0.2 * band)])
    inband = p[(f > 2) & (f <= band)]
    assert np.all(10 * np.log10(inband / ref) > -4.5)  # sinc^2 is -3.9 dB at band_hz
    null = p[np.argmin(np.abs(f - 2 * band))]
    assert 10 * np.log10(null / ref) < -20
    # Parseval: the PSD integrates to the power
    assert_allclose(np.sum(p) * (f[1] - f[0]), np.mean(u**2), rtol=0.05)


def test_paper_excitation_layout():
    ex = ident.paper_excitation(seed=1)
    assert ex.u.shape == ex.t_s.shape == (16000,)
    assert_allclose(np.max(np.abs(ex.u)), 0.5, rtol=1e-15)
    assert ex.segment_names == ("step", "prbs_50Hz", "prbs_100Hz", "prbs_200Hz")
    assert_allclose(ex.segment_bounds, [[0, 4000], [4000, 8000], [8000, 12000], [12000, 16000]])
    assert_allclose(ex.u[ex.segment("step")], 0.25, rtol=0)
    for name in ex.segment_names[1:]:
        assert set(np.unique(ex.u[ex.segment(name)])) == {0.0, 0.5}
    assert_allclose(np.diff(ex.t_s), DT, rtol=1e-9)
    bip = ident.paper_excitation(seed=1, ride_on_step=False, lead_in_s=0.1)
    assert bip.segment_names[0] == "lead_in" and bip.u.size == 16400
    assert_allclose(bip.u[bip.segment("lead_in")], 0.0, atol=0)
    assert set(np.unique(bip.u[bip.segment("prbs_200Hz")])) == {-0.5, 0.5}
    assert np.array_equal(ident.paper_excitation(seed=1).u, ex.u)
    assert not np.array_equal(ident.paper_excitation(seed=2).u, ex.u)
    with pytest.raises(dataclasses.FrozenInstanceError):
        ex.u = np.zeros(3)
    with pytest.raises(ValueError):
        ex.u[0] = 1.0  # read-only array


def test_signal_spectrum_multichannel_shape():
    u = np.stack([ident.prbs(4000, 200.0, fs=FS, seed=s) for s in range(3)], axis=1)
    spec = ident.signal_spectrum(u, fs=FS)
    assert spec.psd.shape == (3, spec.freq_hz.size)
    assert spec.nperseg == 4000


# ----------------------------------------------------------------------------
# fit factor
# ----------------------------------------------------------------------------
def test_fit_percent_known_values():
    y = np.array([1.0, -1.0, 1.0, -1.0])
    assert_allclose(ident.fit_percent(y, y), 100.0, rtol=1e-15)
    assert_allclose(ident.fit_percent(y, 0.5 * y), 50.0, rtol=1e-14)
    assert_allclose(ident.fit_percent(y, np.zeros(4)), 0.0, atol=1e-12)
    assert_allclose(ident.fit_percent(y, -y), -100.0, rtol=1e-14)
    Y = np.stack([y + 3.0, 2 * y], axis=1)  # mean removed per column
    Yh = np.stack([y + 3.0 + 0.25 * y, 2 * y], axis=1)
    assert_allclose(ident.fit_percent(Y, Yh), [75.0, 100.0], rtol=1e-14)


# ----------------------------------------------------------------------------
# d2c
# ----------------------------------------------------------------------------
@pytest.mark.parametrize("seed", [0, 1, 2])
@pytest.mark.parametrize("prewarp_hz", [None, 150.0])
def test_d2c_tustin_inverts_control_c2d(seed, prewarp_hz):
    (A, B, C, D), _ = random_system(7, 2, 3, seed, light=True, feedthrough=True)
    sysc = control.ss(A, B, C, D)
    pw = None if prewarp_hz is None else 2 * np.pi * prewarp_hz
    sysd = control.c2d(sysc, DT, "tustin", prewarp_frequency=pw)
    cm = ident.d2c_tustin(sysd.A, sysd.B, sysd.C, sysd.D, DT, prewarp_hz=prewarp_hz)
    for got, want in zip((cm.A, cm.B, cm.C, cm.D), (A, B, C, D)):
        assert_allclose(got, want, rtol=0, atol=1e-10 * np.max(np.abs(want)))
    back = ident.d2c(sysd, prewarp_hz=prewarp_hz)
    assert back.isctime()
    assert_allclose(back.A, A, rtol=0, atol=1e-10 * np.max(np.abs(A)))


def test_d2c_zoh_inverts_control_c2d_and_keeps_poles():
    (A, B, C, D), (Ad, Bd, Cd, Dd) = random_system(9, 1, 3, 4, light=True, feedthrough=True)
    cm = ident.d2c_zoh(Ad, Bd, Cd, Dd, DT)
    assert_allclose(cm.A, A, rtol=0, atol=1e-8 * np.max(np.abs(A)))
    assert_allclose(cm.B, B, rtol=0, atol=1e-8 * np.max(np.abs(B)))
    sysd = control.c2d(control.ss(A, B, C, D), DT, "zoh")
    back = ident.d2c(sysd, method="zoh")
    assert_allclose(back.A, A, rtol=0, atol=1e-8 * np.max(np.abs(A)))


def test_d2c_tustin_frequency_warping_identity():
    """G_c(j (2/T) tan(w T / 2)) == G_d(exp(j w T)) exactly."""
    _, sysd = random_system(6, 1, 2, 5, light=True)
    cm = ident.d2c_tustin(*sysd, DT)
    f_d = np.linspace(1.0, 1500.0, 200)
    f_c = np.tan(np.pi * f_d * DT) / (np.pi * DT)
    Gd = ident.frequency_response(sysd, f_d, dt_s=DT)
    Gc = ident.frequency_response(cm, f_c)
    assert_allclose(Gc, Gd, rtol=1e-9, atol=1e-12 * np.max(np.abs(Gd)))


def test_d2c_rejects_pole_at_minus_one():
    with pytest.raises(ValueError, match="A: expected no eigenvalue at z = -1"):
        ident.d2c_tustin([[-1.0]], [[1.0]], [[1.0]], [[0.0]], DT)
    with pytest.raises(ValueError, match="A: expected no eigenvalue on the negative real axis"):
        ident.d2c_zoh([[-0.5]], [[1.0]], [[1.0]], [[0.0]], DT)
    with pytest.raises(ValueError, match="sys: expected a discrete StateSpace"):
        ident.d2c(control.ss([[-1.0]], [[1.0]], [[1.0]], [[0.0]]))


# ----------------------------------------------------------------------------
# frequency domain
# ----------------------------------------------------------------------------
def test_frequency_response_matches_python_control():
    (A, B, C, D), sysd = random_system(6, 2, 3, 6, light=True, feedthrough=True)
    f = np.linspace(0.0, 1900.0, 57)
    Gc = ident.frequency_response((A, B, C, D), f)
    Gd = ident.frequency_response(sysd, f, dt_s=DT)
    ref_c = np.moveaxis(control.ss(A, B, C, D)(2j * np.pi * f), -1, 0)     # python-control: (ny, nu, F)
    ref_d = np.moveaxis(control.ss(*sysd, DT)(np.exp(2j * np.pi * f * DT)), -1, 0)
    assert Gc.shape == (57, 3, 2)                                            # (F, ny, nu)
    assert_allclose(Gc, ref_c, rtol=1e-9, atol=1e-12 * np.max(np.abs(ref_c)))
    assert_allclose(Gd, ref_d, rtol=1e-9, atol=1e-12 * np.max(np.abs(ref_d)))
    assert_allclose(ident.frequency_response(control.ss(*sysd, DT), f), Gd, rtol=1e-12)


def test_h1_estimate_fir_and_first_order():
    n = 2**15
    u = ident.prbs(n, FS / 2, fs=FS, seed=11)
    b = np.array([0.5, 0.3, -0.2, 0.1])
    a1 = 0.9
    y = np.stack([ss.lfilter(b, [1.0], u), ss.lfilter([1 - a1], [1.0, -a1], u)], axis=1)
    est = ident.h1_estimate(u, y, fs=FS, nperseg=1024)
    f = est.freq_hz
    z = np.exp(2j * np.pi * f * DT)
    true = np.stack([np.polyval(b[::-1], 1 / z), (1 - a1) / (1 - a1 / z)])  # (2, nf)
    ok = (est.coherence[:, :, 0].T > 0.99) & (f > 0)
    assert ok[0].mean() > 0.9 and ok[1].mean() > 0.9
    err = np.abs(est.H[:, :, 0].T - true) / np.abs(true)
    assert np.max(err[ok]) < 0.02
    assert est.H.shape == est.coherence.shape == (f.size, 2, 1)
    assert_allclose(est.multiple_coherence, est.coherence[:, :, 0], rtol=1e-12)


def test_h1_estimate_mimo_with_noise():
    n = 2**15
    rng = np.random.default_rng(0)
    u = prbs_inputs(n, 2, seed=3)
    b = [[np.array([1.0, 0.5]), np.array([0.2, -0.3, 0.1])], [np.array([0.0, 1.0]), np.array([-0.7])]]
    y = np.zeros((n, 2))
    for i in range(2):
        for j in range(2):
            y[:, i] += ss.lfilter(b[i][j], [1.0], u[:, j])
    y += 0.05 * rng.normal(size=y.shape)
    est = ident.h1_estimate(u, y, fs=FS, nperseg=512)
    z = np.exp(2j * np.pi * est.freq_hz * DT)
    for i in range(2):
        for j in range(2):
            true = np.polyval(b[i][j][::-1], 1 / z)
            assert_allclose(est.H[1:, i, j], true[1:], rtol=0, atol=0.03)
    assert np.all(est.multiple_coherence[1:] > 0.95)
    assert np.all(est.multiple_coherence[1:] < 1.0)


# ----------------------------------------------------------------------------
# modal analysis
# ----------------------------------------------------------------------------
def test_modes_from_model_continuous_and_discrete():
    fn = np.array([120.0, 45.0, 700.0])
    zeta = np.array([0.005, 0.2, 0.002])
    blocks = [np.array([[0.0, 1.0], [-(2 * np.pi * f) ** 2, -2 * z * 2 * np.pi * f]]) for f, z in zip(fn, zeta)]
    A = la.block_diag(*blocks, [[-30.0]])
    order = np.argsort(fn)
    mc = ident.modes_from_model(A)
    assert_allclose(mc.freq_hz, fn[order], rtol=1e-12)
    assert_allclose(mc.damping, zeta[order], rtol=1e-9)
    assert_allclose(mc.real_poles_s, [-30.0], rtol=1e-12)
    md = ident.modes_from_model(la.expm(A * DT), dt=DT)
    assert_allclose(md.freq_hz, fn[order], rtol=1e-10)
    assert_allclose(md.damping, zeta[order], rtol=1e-7)
    assert_allclose(md.real_poles_s, [-30.0], rtol=1e-10)


# ----------------------------------------------------------------------------
# subspace identification
# ----------------------------------------------------------------------------
def check_model(model, sysd, u, y_clean, *, pole_rtol, fr_rtol, dc_rtol, fit_min):
    n = sysd[0].shape[0]
    assert model.order == n
    p_true, p_est = matched(ident.continuous_poles(sysd[0], DT), ident.continuous_poles(model))
    assert_allclose(p_est, p_true, rtol=pole_rtol)
    assert_allclose(model.dc_gain(), dc_gain(sysd), rtol=dc_rtol, atol=dc_rtol * np.max(np.abs(dc_gain(sysd))))
    f = np.linspace(1.0, 0.45 * FS, 500)
    G = ident.frequency_response(sysd, f, dt_s=DT)
    Gm = ident.frequency_response(model, f)
    assert np.linalg.norm(Gm - G) / np.linalg.norm(G) < fr_rtol
    fit = ident.fit_percent(y_clean, ident.simulate(model, u, model.x0))
    assert np.all(fit >= fit_min), fit


@pytest.mark.parametrize(
    "n, m, l, light, feedthrough, seed",
    [
        (2, 1, 1, False, False, 0),
        (2, 1, 1, True, True, 1),
        (6, 1, 3, True, False, 2),
        (6, 2, 2, False, True, 3),
        (12, 1, 3, True, False, 4),
        (12, 1, 3, False, True, 5),
        (12, 3, 3, True, False, 6),
        (13, 1, 3, True, False, 7),
    ],
)
def test_subspace_noiseless_recovers_system(n, m, l, light, feedthrough, seed):
    _, sysd = random_system(n, m, l, seed, light=light, feedthrough=feedthrough)
    u = prbs_inputs(16000, m, seed)
    x0 = np.random.default_rng(seed).normal(size=n)  # not at rest initially
    y = dsim(sysd, u, x0=x0)
    model = ident.subspace_id(y, u, fs=FS)  # automatic order
    check_model(model, sysd, u, y, pole_rtol=1e-6, fr_rtol=1e-6, dc_rtol=1e-6, fit_min=99.999)


@pytest.mark.parametrize(
    "n, m, l, light, seed",
    [(2, 1, 1, True, 10), (6, 1, 3, False, 11), (6, 1, 3, True, 12), (12, 1, 3, True, 13), (12, 2, 3, True, 14)],
)
def test_subspace_with_output_noise(n, m, l, light, seed):
    _, sysd = random_system(n, m, l, seed, light=light)
    u = prbs_inputs(16000, m, seed)
    y0 = dsim(sysd, u)
    rng = np.random.default_rng(seed)
    y = y0 + 0.01 * y0.std(axis=0) * rng.normal(size=y0.shape)  # 1 % white output noise
    model = ident.subspace_id(y, u, order=n, fs=FS)
    check_model(model, sysd, u, y0, pole_rtol=2e-2, fr_rtol=1e-2, dc_rtol=1e-2, fit_min=99.0)
    if light:  # lightly damped modes: frequency and damping directly
        mt, me = ident.modes_from_model(sysd[0], DT), ident.modes_from_model(model)
        assert_allclose(me.freq_hz, mt.freq_hz, rtol=1e-3)
        assert_allclose(me.damping, mt.damping, rtol=0, atol=1e-3)


@pytest.mark.parametrize("noise", [0.0, 0.01])
def test_subspace_paper_plant_and_excitation(noise):
    """Paper scenario: 13 states, 6 light modes 175-740 Hz + creep pole, step + multi-band PRBS."""
    sysc, sysd, f_true, zeta_true = paper_like_plant(seed=0)
    ex = ident.paper_excitation(seed=0)
    y0 = dsim(sysd, ex.u)
    rng = np.random.default_rng(1)
    y = y0 + noise * y0.std(axis=0) * rng.normal(size=y0.shape)
    model = ident.subspace_id(y, ex.u, fs=ex.fs)
    assert model.order == 13
    modes = ident.modes_from_model(model)
    assert_allclose(modes.freq_hz, f_true, rtol=1e-3 if noise else 1e-9)
    assert_allclose(modes.damping, zeta_true, rtol=0, atol=3e-4 if noise else 1e-9)
    assert_allclose(modes.real_poles_s, [-30.0], rtol=0.1 if noise else 1e-7)
    assert_allclose(model.dc_gain(), dc_gain(sysd), rtol=1e-2 if noise else 1e-8)
    assert np.all(ident.fit_percent(y0, ident.simulate(model, ex.u, model.x0)) > 99.0)
    # continuous model via inverse ZOH keeps the modal frequencies
    sc = ident.d2c(model, method="zoh")
    mc = ident.modes_from_model(sc.A)
    assert_allclose(mc.freq_hz, f_true, rtol=1e-3 if noise else 1e-8)


def test_subspace_auto_order_with_noise():
    _, sysd, _, _ = paper_like_plant(seed=3)
    ex = ident.paper_excitation(seed=3)
    y0 = dsim(sysd, ex.u)
    y = y0 + 0.01 * y0.std(axis=0) * np.random.default_rng(3).normal(size=y0.shape)
    model = ident.subspace_id(y, ex.u, fs=FS, max_order=20)
    assert model.order == 13
    assert ident.select_order(model.singular_values, 20) == 13


def test_auto_order_warns_when_max_order_is_reached():
    _, sysd = random_system(6, 1, 2, 60, light=True)
    u = prbs_inputs(4000, 1, 60)
    with pytest.warns(UserWarning, match="max_order=4"):
        model = ident.subspace_id(dsim(sysd, u), u, fs=FS, max_order=4)
    assert model.order == 4


def test_select_order_rule():
    s = np.array([10.0, 5.0, 1.0, 0.5] + [1e-3] * 20)
    assert ident.select_order(s, 10) == 4
    assert ident.select_order(s, 10, floor_ratio=600.0) == 3
    assert ident.select_order(np.r_[1.0, np.full(10, 0.9)], 5) == 1


def test_estimate_x0_and_simulate():
    _, sysd = random_system(8, 1, 2, 21, light=True)
    u = prbs_inputs(3000, 1, 21)
    x0 = np.random.default_rng(21).normal(size=8)
    y = dsim(sysd, u, x0=x0)
    true = TrueModel(sysd)
    assert_allclose(ident.estimate_x0(true, y, u), x0, rtol=1e-7, atol=1e-9)
    assert_allclose(ident.simulate(true, u, x0), y, rtol=1e-9, atol=1e-12 * np.max(np.abs(y)))
    model = ident.subspace_id(y, u, order=8, fs=FS)
    x0m = ident.estimate_x0(model, y, u)
    assert_allclose(x0m, model.x0, rtol=1e-6, atol=1e-9 * np.max(np.abs(x0m)))
    assert np.all(ident.fit_percent(y, ident.simulate(model, u, x0m)) > 99.999)
    assert np.all(ident.fit_percent(y, ident.simulate(model, u)) < 99.999)  # x0 matters here


def test_kalman_gain_from_innovation_data():
    n, l = 6, 2
    _, sysd = random_system(n, 1, l, 31, light=True)
    rng = np.random.default_rng(31)
    A, C = sysd[0], sysd[2]
    P = la.solve_discrete_are(A.T, C.T, 1e-3 * np.eye(n), np.eye(l))
    K = A @ P @ C.T @ np.linalg.inv(C @ P @ C.T + np.eye(l))  # a true Kalman gain
    assert np.max(np.abs(np.linalg.eigvals(sysd[0] - K @ sysd[2]))) < 1
    u = prbs_inputs(16000, 1, 31)
    yd = dsim(sysd, u)
    e = 0.05 * yd.std(axis=0) * rng.normal(size=yd.shape)
    _, yn, _ = ss.dlsim((sysd[0], K, sysd[2], np.eye(l), DT), e)
    y = yd + yn
    model = ident.subspace_id(y, u, order=n, fs=FS)
    assert np.max(np.abs(np.linalg.eigvals(model.A - model.K @ model.C))) < 1
    e_model = y - ident.predict(model, y, u, model.x0)
    e_sim = y - ident.simulate(model, u, model.x0)
    assert np.all(e_model[200:].var(axis=0) < 1.1 * e.var(axis=0))
    assert np.all(e_model[200:].var(axis=0) < 0.9 * e_sim[200:].var(axis=0))  # K helps prediction
    assert_allclose(np.diag(model.noise_cov), e.var(axis=0), rtol=0.2)


def test_enforce_stability_reflects_unstable_poles():
    z = 1.0002 * np.exp(2j * np.pi * 300.0 * DT)
    Ad = np.array([[z.real, z.imag], [-z.imag, z.real]])
    Ad = la.block_diag(Ad, [[0.95]])
    sysd = (Ad, np.array([[1.0], [0.0], [1.0]]), np.array([[1.0, 0.5, 1.0]]), np.zeros((1, 1)))
    u = prbs_inputs(6000, 1, 41)
    y = dsim(sysd, u)
    free = ident.subspace_id(y, u, order=3, fs=FS)
    assert_allclose(np.sort(np.abs(free.poles)), [0.95, 1.0002, 1.0002], rtol=1e-8)
    stab = ident.subspace_id(y, u, order=3, fs=FS, enforce_stability=True)
    assert np.all(np.abs(stab.poles) < 1.0)
    assert_allclose(np.sort(np.abs(stab.poles)), [0.95, 1 / 1.0002, 1 / 1.0002], rtol=1e-8)
    assert_allclose(np.sort(np.abs(np.angle(stab.poles))), np.sort(np.abs(np.angle(free.poles))), rtol=1e-8)


def test_identified_model_is_frozen_and_labelled():
    _, sysd = random_system(2, 1, 2, 50)
    u = prbs_inputs(2000, 1, 50)
    model = ident.subspace_id(dsim(sysd, u), u, fs=FS, input_names=["A"], output_names=["X", "Y"])
    assert model.input_names == ("A",) and model.output_names == ("X", "Y")
    assert model.dt_s == DT and model.fs == FS
    assert model.A.shape == (2, 2) and model.K.shape == (2, 2) and model.x0.shape == (2,)
    assert model.singular_values.shape == (model.horizon * 2,)
    with pytest.raises(dataclasses.FrozenInstanceError):
        model.order = 3
    with pytest.raises(ValueError):
        model.A[0, 0] = 1.0
    sc = ident.d2c(model)
    assert sc.input_labels == ["A"] and sc.output_labels == ["X", "Y"]


# ----------------------------------------------------------------------------
# errors
# ----------------------------------------------------------------------------
def test_errors_are_specific():
    u = ident.prbs(4000, 1000.0, fs=FS, seed=0)
    y = ss.lfilter([0.1], [1.0, -0.9], u)
    with pytest.raises(ValueError, match=r"y, u: expected the same number of samples, got 4000 and 3999"):
        ident.subspace_id(y, u[:-1], fs=FS)
    bad = y.copy()
    bad[5] = np.nan
    with pytest.raises(ValueError, match=r"y: expected finite values, got 1 NaN/inf"):
        ident.subspace_id(bad, u, fs=FS)
    bad[5] = np.inf
    with pytest.raises(ValueError, match=r"y: expected finite values"):
        ident.subspace_id(bad, u, fs=FS)
    with pytest.raises(ValueError, match=r"u: expected every channel to vary"):
        ident.subspace_id(y, np.zeros_like(u), fs=FS)
    with pytest.raises(ValueError, match=r"u: expected every channel to vary"):
        ident.subspace_id(y, np.full_like(u, 0.3), fs=FS)
    with pytest.raises(ValueError, match=r"y: expected a 1-D \(n_samples,\) or 2-D"):
        ident.subspace_id(y[:, None, None], u, fs=FS)
    with pytest.raises(ValueError, match=r"y, u: expected at least \d+ samples"):
        ident.subspace_id(y[:50], u[:50], order=10, fs=FS)
    with pytest.raises(ValueError, match=r"horizon: expected >= 11"):
        ident.subspace_id(y, u, order=10, horizon=5, fs=FS)
    with pytest.raises(ValueError, match=r"fs: expected a positive"):
        ident.subspace_id(y, u, fs=0.0)
    with pytest.raises(ValueError, match=r"order: expected an integer >= 1"):
        ident.subspace_id(y, u, order=0, fs=FS)
    t = np.arange(4000) * DT
    with pytest.raises(ValueError, match=r"u: expected an input persistently exciting"):
        ident.subspace_id(np.sin(2 * np.pi * 50 * t + 0.3), np.sin(2 * np.pi * 50 * t), fs=FS)
    with pytest.raises(ValueError, match=r"band_hz: expected a value <= fs/2"):
        ident.prbs(100, 3000.0, fs=FS)
    with pytest.raises(ValueError, match=r"n_samples: expected an integer >= 1"):
        ident.prbs(0, 100.0, fs=FS)
    with pytest.raises(ValueError, match=r"y: expected non-constant channels"):
        ident.fit_percent(np.ones(5), np.zeros(5))
    with pytest.raises(ValueError, match=r"yhat: expected shape"):
        ident.fit_percent(np.ones((5, 2)), np.ones((5, 3)))
    with pytest.raises(ValueError, match=r"u, y: expected the same number of samples"):
        ident.h1_estimate(u, y[:-1], fs=FS)
    with pytest.raises(ValueError, match=r"nperseg: expected at most"):
        ident.h1_estimate(u, y, fs=FS, nperseg=10**6)
    with pytest.raises(ValueError, match=r"system: expected"):
        ident.frequency_response("not a system", [1.0])
    with pytest.raises(ValueError, match=r"u: expected 1 input channel"):
        ident.simulate(ident.subspace_id(y, u, order=1, fs=FS), np.ones((10, 2)))


# ----------------------------------------------------------------------------
# package hygiene
# ----------------------------------------------------------------------------
def test_package_does_not_import_nanosim_or_pickle():
    code = "import sys, identification; assert 'nanosim' not in sys.modules, 'nanosim imported'"
    subprocess.run([sys.executable, "-c", code], check=True, cwd=pathlib.Path(__file__).parents[1])
    src = pathlib.Path(ident.__file__).parent
    for path in src.glob("*.py"):
        text = path.read_text()
        assert "pickle" not in text, path
        assert "import nanosim" not in text and "from nanosim" not in text, path
