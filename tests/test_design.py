"""Tests for nanosim.design / nanosim.weights: reduction, H-infinity mixed sensitivity,
discretization and the run_design pipeline.

Known-answer problems:
* SISO: Skogestad & Postlethwaite, Multivariable Feedback Control, 2nd ed. (Wiley 2005),
  Example 2.11 (Sec. 2.8.3): G = 200/((10s+1)(0.05s+1)^2), wP = (s/M + wB)/(s + wB*A),
  M = 1.5, wB = 10, A = 1e-4, wu = 1 (S/KS design) -> gamma_min = 1.37 (book, 3 digits).
* MIMO: same book, Example 3.8 (1st ed. numbering, as in python-control's
  examples/robust_mimo.py): G = 1/(0.2s+1)(s+1) [[1, 1], [1+2s, 2]], wP as above with
  wB = 0.25 on both outputs, Wu = I -> gamma = 2.80 (book).
"""
from __future__ import annotations

import json
import warnings

import numpy as np
import pytest

control = pytest.importorskip("control")
pytest.importorskip("slycot")

from nanosim import constants, paper  # noqa: E402
import nanosim.design as D  # noqa: E402
from nanosim.design.weights import PAPER_WEIGHTS, Weights, WeightSpec  # noqa: E402

ct = control


# --------------------------------------------------------------------------------------
# plants
# --------------------------------------------------------------------------------------
def sp_example_2_11_plant():
    s = ct.tf("s")
    return ct.ss(200 / ((10 * s + 1) * (0.05 * s + 1) ** 2))


def sp_weight(M=1.5, wb=10.0, A=1e-4):
    """wP = (s/M + wB)/(s + wB*A) = ((1/M) s + wB) / (s + wB*A)."""
    return WeightSpec((1.0 / M, wb), (1.0, wb * A))


def sp_example_3_8_plant():
    den = [0.2, 1.2, 1.0]
    return ct.ss(ct.tf([[[1], [1]], [[2, 1], [2]]], [[den, den], [den, den]]))


MODES = ((175.0, "XY1"), (179.0, "XY2"), (245.0, "Z"), (460.0, "XY1"), (474.0, "XY2"), (740.0, "Z"))


def paper_like_plant(zeta=0.005, xy_low=0.7, z_low=0.94, creep_pole=29.0, creep_zero=32.0, theta_deg=30.0,
                     detune=0.0):
    """Synthetic 3x3, 39-state stand-in for the paper's identified model.

    Modal sum (paper Sec. 3 modes, damping ``zeta``): XY modes (175/460 Hz along one
    in-plane direction, 179/474 Hz along the orthogonal one, rotated ``theta_deg``)
    drive rows X, Y only; Z modes (245, 740 Hz) drive row Z only. Shares of the static
    gain: ``xy_low`` for the low XY pair, ``z_low`` for 245 Hz; the residues add up to
    the DC gain 0.6 * J [sensor V / controller V] (3.0 um/V * J / 5 um/V). Each input
    column is realized separately (12 modal states + 1 creep state = 13, 39 total) and
    fed through the creep lag c(s) = (p/z)(s + z)/(s + p), p = 29, z = 32 rad/s,
    c(0) = 1. ``detune`` shifts column j's frequencies by (j - 1) * detune (a "twin").
    """
    J = constants.JACOBIAN_J
    K0 = 0.6 * J
    th = np.deg2rad(theta_deg)
    d1, d2 = np.array([np.cos(th), np.sin(th)]), np.array([-np.sin(th), np.cos(th)])
    proj = {"XY1": np.outer(d1, d1), "XY2": np.outer(d2, d2)}
    share = (xy_low, xy_low, z_low, 1 - xy_low, 1 - xy_low, 1 - z_low)
    R = []
    for (_, ax), sh in zip(MODES, share):
        r = np.zeros((3, 3))
        if ax == "Z":
            r[2] = sh * K0[2]
        else:
            r[:2] = sh * proj[ax] @ K0[:2]
        R.append(r)
    assert np.allclose(sum(R), K0)
    p, z = creep_pole, creep_zero
    A, B, C = np.zeros((39, 39)), np.zeros((39, 3)), np.zeros((3, 39))
    for j in range(3):
        o = 13 * j
        for i, ((f, _), Ri) in enumerate(zip(MODES, R)):
            w = 2 * np.pi * f * (1 + detune * (j - 1))
            k = o + 2 * i
            A[k:k + 2, k:k + 2] = [[0, 1], [-w * w, -2 * zeta * w]]
            A[k + 1, o + 12] = w * w * (p / z) * (z - p)      # creep state -> mode input
            B[k + 1, j] = w * w * p / z
            C[:, k] = Ri[:, j]
        A[o + 12, o + 12] = -p
        B[o + 12, j] = 1.0
    return ct.ss(A, B, C, np.zeros((3, 3)))


@pytest.fixture(scope="module")
def paper_case():
    G = paper_like_plant()
    red = D.reduce_model(G, 10)
    des = D.design_hinf(red.G_reduced, PAPER_WEIGHTS, G_full=G, G_twin=paper_like_plant(detune=0.005))
    return G, red, des


# --------------------------------------------------------------------------------------
# weights
# --------------------------------------------------------------------------------------
def test_paper_weights_values():
    W = Weights()
    assert W == PAPER_WEIGHTS
    assert W.Wp.num == (0.6667, 314.2) and W.Wp.den == (1.0, 0.03142)
    assert W.Wt.power == 2 and W.Wu.is_static and W.Wu.num == (0.15,)
    # paper Sec. 4.2: Wt high-frequency gain 120 dB; Wp DC gain 1e4 (S bound 0.01 %)
    assert 20 * np.log10(W.Wt.hf_gain()) == pytest.approx(120.0, abs=1e-9)
    assert W.Wp.dc_gain() == pytest.approx(314.2 / 0.03142, rel=1e-12)
    assert W.order_for(3, 3) == 9


def test_weights_roundtrip_json_toml(tmp_path):
    W = Weights()
    d = W.to_dict()
    assert Weights.from_dict(d) == W
    (tmp_path / "w.json").write_text(json.dumps(d))
    assert Weights.from_file(tmp_path / "w.json") == W
    toml = ("Wu = 0.15\n\n"
            "[Wp]\nnum = [0.6667, 314.2]\nden = [1, 0.03142]\n\n"
            "[Wt]\nnum = [1, 314.2]\nden = [0.001, 628.3]\npower = 2\n")
    (tmp_path / "w.toml").write_text(toml)
    assert Weights.from_file(tmp_path / "w.toml") == W


def test_weights_from_paper_targets_json():
    """The paper's weights, read from the project's copy of paper_targets.json, are PAPER_WEIGHTS."""
    import pathlib
    path = pathlib.Path(__file__).parent / "data" / "shared" / "reference" / "paper_targets.json"
    assert Weights.from_file(path) == PAPER_WEIGHTS


@pytest.mark.parametrize("bad, match", [
    ({"Wp": {"den": [1, 0]}, "Wt": 1, "Wu": 1}, "num"),
    ({"wp": 1, "Wt": 1, "Wu": 1}, "case sensitive"),
    ({"Wp": {"num": [1, 2, 3], "den": [1, 1]}, "Wt": 1, "Wu": 1}, "improper"),
    ({"Wp": {"num": [1], "den": [1, 1], "power": 0}, "Wt": 1, "Wu": 1}, "power"),
    ({"Wp": {"num": [1], "den": [1, float("nan")]}, "Wt": 1, "Wu": 1}, "finite"),
])
def test_weights_bad_input(bad, match):
    with pytest.raises(ValueError, match=match):
        Weights.from_dict(bad).check()


def test_bad_weight_integrator_named():
    G = sp_example_2_11_plant()
    # Wp with an integrator (A = 0): pole at s = 0 -> rejected before slycot, message names Wp
    with pytest.raises(ValueError, match=r"Wp.*imaginary axis.*integrator"):
        D.design_hinf(G, Weights(Wp=sp_weight(A=0.0), Wt=None, Wu=1.0))
    # Wt with an undamped pole pair at 100 rad/s
    with pytest.raises(ValueError, match=r"Wt.*imaginary axis"):
        D.design_hinf(G, Weights(Wp=sp_weight(), Wt=WeightSpec((1.0, 0.0, 1.0), (1.0, 0.0, 1e4)), Wu=1.0))
    # unstable weight
    with pytest.raises(ValueError, match=r"Wu.*unstable"):
        D.design_hinf(G, Weights(Wp=sp_weight(), Wt=None, Wu=WeightSpec((1.0,), (1.0, -1.0))))


# --------------------------------------------------------------------------------------
# H-infinity assumption checks on the generalized plant
# --------------------------------------------------------------------------------------
def test_check_assumptions_integrator_weight():
    G = sp_example_2_11_plant()
    s = ct.tf("s")
    Wp_int = ct.ss((s / 1.5 + 10) / s)                     # integrator, bypassing Weights.check
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        P = ct.augw(G, Wp_int, ct.ss(np.zeros((0, 0)), np.zeros((0, 1)), np.zeros((1, 0)), [[1.0]]))
    rep = D.check_assumptions(P, 1, 1, raise_on_failure=False)
    assert not rep.ok
    assert any("not detectable" in m for m in rep.failures)
    assert any("(A4)" in m for m in rep.failures)
    with pytest.raises(ValueError, match="imaginary axis"):
        D.check_assumptions(P, 1, 1)


def test_check_assumptions_D12_rank():
    # S-only weighting of a strictly proper plant: u has no feedthrough to z -> D12 = 0
    G = sp_example_2_11_plant()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        P = ct.augw(G, ct.ss(sp_weight().tf()))
    with pytest.raises(ValueError, match=r"D12.*not full column rank"):
        D.check_assumptions(P, 1, 1)


def test_check_assumptions_ok_and_plant_integrator():
    G = sp_example_2_11_plant()
    P = D.generalized_plant(G, Weights(Wp=sp_weight(), Wt=None, Wu=1.0))
    assert D.check_assumptions(P, 1, 1).ok
    s = ct.tf("s")
    with pytest.raises(ValueError, match="G_nominal has a pole on the imaginary axis"):
        D.design_hinf(ct.ss(1 / (s * (s + 1))), Weights(Wp=sp_weight(), Wt=None, Wu=1.0))


# --------------------------------------------------------------------------------------
# known-answer syntheses
# --------------------------------------------------------------------------------------
def test_siso_skogestad_example_2_11_gamma():
    # S&P 2nd ed. Example 2.11: gamma = 1.37 (quoted to 3 digits -> rtol 1 %)
    d = D.design_hinf(sp_example_2_11_plant(), Weights(Wp=sp_weight(), Wt=None, Wu=1.0))
    assert d.gamma == pytest.approx(1.37, rel=0.01)
    assert d.controller_order == 4                       # 3 plant + 1 weight state
    assert d.stable_nominal
    # the achieved closed-loop norm on the grid equals gamma (grid is a lower bound)
    assert d.gamma_grid == pytest.approx(d.gamma, rel=2e-3)
    # book: wB* = 10 rad/s -> S bandwidth about 10 rad/s (1.6 Hz) give or take
    assert 0.5 < d.bandwidth_S_hz < 3.0


def test_mimo_skogestad_example_3_8_gamma():
    # S&P Example 3.8 design 1 (python-control examples/robust_mimo.py): gamma = 2.80
    d = D.design_hinf(sp_example_3_8_plant(), Weights(Wp=sp_weight(wb=0.25), Wt=None, Wu=1.0))
    assert d.gamma == pytest.approx(2.80, rel=0.01)
    assert d.stable_nominal


def test_mimo_diagonal_equals_siso():
    G = sp_example_2_11_plant()
    W = Weights(Wp=sp_weight(), Wt=None, Wu=1.0)
    g1 = D.design_hinf(G, W).gamma
    g2 = D.design_hinf(ct.append(G, G), W)
    assert g2.gamma == pytest.approx(g1, rel=1e-3)
    assert g2.controller_order == 8


def test_sign_convention_u_equals_plus_K_e():
    """mixsyn/hinfsyn's K is used as u = +K e, e = r - y (negative feedback)."""
    G = sp_example_2_11_plant()
    d = D.design_hinf(G, Weights(Wp=sp_weight(), Wt=None, Wu=1.0))
    K = d.K
    Ag, Bg, Cg = G.A, G.B, G.C
    Ak, Bk, Ck, Dk = K.A, K.B, K.C, K.D
    # x_g' = Ag x_g + Bg u,  y = Cg x_g,  e = r - y,  x_k' = Ak x_k + Bk e,  u = Ck x_k + Dk e
    A_neg = np.block([[Ag - Bg @ Dk @ Cg, Bg @ Ck], [-Bk @ Cg, Ak]])
    A_pos = np.block([[Ag + Bg @ Dk @ Cg, Bg @ Ck], [Bk @ Cg, Ak]])   # u = +K (r + y): wrong sign
    assert np.max(np.linalg.eigvals(A_neg).real) < 0
    assert np.max(np.linalg.eigvals(A_pos).real) > 0
    # S = 1/(1 + G K) is tiny at low frequency (Wp bound: |S| <= gamma*A = 1.4e-4)
    w = 2 * np.pi * 1e-4
    s = 1j * w
    Gj = (Cg @ np.linalg.solve(s * np.eye(3) - Ag, Bg))[0, 0]
    Kj = (Ck @ np.linalg.solve(s * np.eye(Ak.shape[0]) - Ak, Bk) + Dk)[0, 0]
    assert abs(1 / (1 + Gj * Kj)) < 1e-3
    # and the library's loop functions agree with this convention
    assert abs(D.freqresp(d.S, [1e-4])[0, 0, 0] - 1 / (1 + Gj * Kj)) < 1e-9
    assert d.sign_convention.startswith("negative feedback")


# --------------------------------------------------------------------------------------
# reduction and uncertainty
# --------------------------------------------------------------------------------------
def test_reduction_dc_gain_and_hsv(paper_case):
    G, red, _ = paper_case
    assert red.full_order == 39 and red.order == 10
    assert red.G_reduced.nstates == 10
    dc_full = D.dc_gain(G)
    np.testing.assert_allclose(dc_full, 0.6 * constants.JACOBIAN_J, rtol=1e-12, atol=1e-12)
    rel = np.max(np.abs(D.dc_gain(red.G_reduced) - dc_full)) / np.max(np.abs(dc_full))
    assert rel <= 1e-6 and red.dc_gain_matched
    h = red.hankel_sv
    assert h.shape == (39,) and np.all(np.diff(h) <= 1e-9 * h[0])
    # paper Fig. 8 pattern (built into the synthetic plant): 10 HSV > 30, the rest < 3
    assert h[9] > 30 and h[10] < 3
    assert red.reduced_stable and red.n_unstable == 0
    # balanced-truncation/SPA bound ||G - Gr||_inf <= 2 * sum(dropped HSV) on a grid
    f = D.analysis_grid_hz([G], 0.1, 5000, 800)
    err = D.sigma_max(D.freqresp(G, f) - D.freqresp(red.G_reduced, f)).max()
    assert err <= red.error_bound_hinf * (1 + 1e-6)


def test_reduction_unstable_and_integrator_models():
    G = paper_like_plant()
    A = G.A.copy()
    A[38, 38] = +5.0                                       # one creep pole pushed into the RHP
    Gu = ct.ss(A, G.B, G.C, G.D)
    with pytest.warns(UserWarning, match="unstable"):
        red = D.reduce_model(Gu, 10)
    assert red.n_unstable == 1 and red.order == 10
    assert np.any(np.isclose(np.linalg.eigvals(red.G_reduced.A), 5.0, atol=1e-6))
    assert red.dc_gain_rel_error < 1e-6
    A[38, 38] = 0.0                                        # integrator: DC gain infinite
    with pytest.raises(ValueError, match="s ~ 0"):
        D.reduce_model(ct.ss(A, G.B, G.C, G.D), 10)
    with pytest.raises(ValueError, match="order"):
        D.reduce_model(G, 40)


def test_multiplicative_uncertainty_known():
    G = paper_like_plant()
    f = np.array([1.0, 10.0, 100.0])
    np.testing.assert_allclose(D.multiplicative_uncertainty(G, G, f), 0.0, atol=1e-12)
    Gp = ct.series(G, ct.ss(np.zeros((0, 0)), np.zeros((0, 3)), np.zeros((3, 0)), 1.1 * np.eye(3)))
    # G_P = (I + E_o) G with E_o = 0.1 I
    np.testing.assert_allclose(D.multiplicative_uncertainty(Gp, G, f), 0.1, rtol=1e-9)


def test_uncertainty_paper_like(paper_case):
    G, red, _ = paper_case
    # Paper Sec. 4 / Fig. 10(b): sigma_max(E_o), E_o = (G_P - G) G^-1, is "less than -20 dB below
    # 140 Hz" (paper_targets.json reduction.Eo_max_sv_dB_below_140Hz = -20). Dense grid, 1-140 Hz.
    # (this synthetic plant reaches -20.8 dB near 29 Hz)
    f = np.geomspace(1.0, 140.0, 500)
    eo_db = 20 * np.log10(D.multiplicative_uncertainty(G, red.G_reduced, f))
    assert eo_db.max() < -20.0, (eo_db.max(), f[np.argmax(eo_db)])


# --------------------------------------------------------------------------------------
# paper-like 3x3 design
# --------------------------------------------------------------------------------------
def test_paper_like_design(paper_case, record_property):
    G, red, d = paper_case
    assert d.controller_order == red.order + 9 == 19 == paper.PAPER_CONTROLLER_ORDER
    assert d.stable_nominal and d.stable_full and d.stable_twin
    assert 1.0 <= d.gamma < 2.0
    assert d.gamma_grid == pytest.approx(d.gamma, rel=5e-3)
    # physics: tight low-frequency tracking, T ~ I at low frequency
    assert d.sigma_S_at(1.0) < 0.05
    assert d.sigma_S_at(1.0, "full") < 0.05
    Tlow = D.singular_values(D.loop_freqresp(D.freqresp(G, [0.1]), D.freqresp(d.K, [0.1]))[1])[0]
    np.testing.assert_allclose(Tlow, 1.0, atol=0.01)
    # nominal S peak bounded by gamma / |Wp(inf)| = 1.5 gamma; bandwidths ordered
    assert d.S_peak_nominal <= 1.5 * d.gamma * 1.01
    assert 5 < d.bandwidth_S_hz < d.bandwidth_T_hz < 200
    summary = {"gamma": d.gamma, "S_peak_nominal": d.S_peak_nominal, "S_peak_full": d.S_peak_full,
               "S_peak_twin": d.twin.S_peak, "bandwidth_S_hz": d.bandwidth_S_hz, "bandwidth_T_hz": d.bandwidth_T_hz}
    for k, v in summary.items():
        record_property(k, v)
    print("paper-like plant:", {k: round(v, 4) for k, v in summary.items()})


def test_gamma_relax_suboptimal_controller(paper_case):
    G, red, d_opt = paper_case
    d = D.design_hinf(red.G_reduced, PAPER_WEIGHTS, G_full=G, gamma_relax=0.01)
    assert d.gamma_opt == pytest.approx(d_opt.gamma, rel=1e-9)
    assert d.gamma == pytest.approx(1.01 * d.gamma_opt, rel=1e-12)
    assert d.gamma_grid <= d.gamma * (1 + 1e-6)
    assert d.controller_order == 19 and d.stable_nominal and d.stable_full
    fastest = lambda K: np.max(np.abs(np.linalg.eigvals(K.A)))  # noqa: E731
    assert fastest(d.K) < 1e-3 * fastest(d_opt.K)               # no near-infinite controller pole
    print(f"gamma_relax=0.01: gamma {d.gamma:.4f}, S_peak nominal {d.S_peak_nominal:.3f}, "
          f"full {d.S_peak_full:.3f}, BW S {d.bandwidth_S_hz:.1f} Hz, BW T {d.bandwidth_T_hz:.1f} Hz, "
          f"fastest controller pole {fastest(d.K):.3g} rad/s (optimal: {fastest(d_opt.K):.3g})")
    with pytest.raises(ValueError, match="gamma_relax"):
        D.design_hinf(red.G_reduced, PAPER_WEIGHTS, gamma_relax=-1)


# --------------------------------------------------------------------------------------
# discretization
# --------------------------------------------------------------------------------------
def test_discretization_paper_like(paper_case):
    _, _, d = paper_case
    disc = D.discretize_controller(d.K, 1 / 4000)
    assert disc.max_rel_error < 0.01 and disc.within_tol
    assert disc.Kd.dt == pytest.approx(1 / 4000)
    assert "tustin" in disc.errors_by_method
    err, _, _, _ = D.discretization_error(d.K, disc.Kd, 500.0)
    assert err == pytest.approx(disc.max_rel_error, rel=1e-9)
    assert np.max(np.abs(np.linalg.eigvals(disc.Kd.A))) < 1
    # the sampled loop with the ZOH full plant is stable
    assert D.discrete_closed_loop(ct.c2d(d.G_full, 1 / 4000, "zoh"), disc.Kd)[0]
    print("discretization:", disc.method, disc.max_rel_error, disc.errors_by_method)


def test_discretization_tustin_smooth_controller():
    # a controller without sharp features below 500 Hz: plain Tustin meets 1 % and is kept
    d = D.design_hinf(sp_example_2_11_plant(), Weights(Wp=sp_weight(), Wt=None, Wu=1.0))
    disc = D.discretize_controller(d.K, 1 / 4000)
    assert disc.method == "tustin" and disc.max_rel_error < 0.01
    with pytest.raises(ValueError, match="Nyquist"):
        D.discretize_controller(d.K, 1 / 4000, f_check_hz=2500.0)
    with pytest.raises(ValueError, match="method"):
        D.discretize_controller(d.K, 1 / 4000, method="euler")


# --------------------------------------------------------------------------------------
# run_design end to end
# --------------------------------------------------------------------------------------
def test_run_design_artifacts(tmp_path):
    from scipy.io import loadmat

    from nanosim.pipeline.config import DesignConfig
    from nanosim.pipeline.design import run_design

    from nanosim import fileio
    G = paper_like_plant()
    Gd = ct.c2d(G, 1 / 4000, "zoh")
    model = fileio.write_npz(tmp_path / "model.npz", A=G.A, B=G.B, C=G.C, D=G.D,
                          Ad=Gd.A, Bd=Gd.B, Cd=Gd.C, Dd=Gd.D, dt=1 / 4000)
    out = tmp_path / "out"
    d = run_design(model, out, DesignConfig.paper(), progress=False)
    assert d.controller_order == 19 and d.reduction.order == 10
    z = np.load(out / "controller.npz", allow_pickle=False)
    for k in ("Ak", "Bk", "Ck", "Dk", "Akd", "Bkd", "Ckd", "Dkd", "dt", "units"):
        assert k in z.files
        assert z[k].dtype != object
    assert z["Akd"].shape == (19, 19) and z["Bkd"].shape == (19, 3) and float(z["dt"]) == 1 / 4000
    js = json.loads((out / "design.json").read_text())
    for k in ("gamma", "controller_order", "reduced_order", "hankel_sv", "S_peak_nominal", "S_peak_full",
              "bandwidth_S_hz", "bandwidth_T_hz", "weights", "stable_full", "stable_nominal",
              "discretization_max_rel_error", "discretization_check_band_hz", "units"):
        assert k in js, k
    assert js["controller_order"] == 19 and js["reduced_order"] == 10
    assert js["discretization_max_rel_error"] < 0.01 and js["discretization_check_band_hz"] == 500.0
    assert js["stable_discrete_full"] is True
    m = loadmat(out / "design.mat")
    assert m["K_A"].shape == (19, 19) and m["G_A"].shape == (39, 39)
    # time domain: the exported 4 kHz controller on the ZOH full plant tracks a 2 um X step
    from nanosim.design.controller import DiscreteController
    ctrl = DiscreteController.from_npz(out / "controller.npz")
    x = np.zeros(Gd.nstates)
    r = np.array([0.4, 0.0, 0.0])                       # 0.4 sensor V = 2 um on X
    ys = np.empty((800, 3))
    for k in range(800):                                # 0.2 s
        ys[k] = Gd.C @ x
        x = Gd.A @ x + Gd.B @ ctrl.step(r - ys[k])
    t = np.arange(800) / 4000
    yx = ys[:, 0] / 0.4
    rise = t[np.argmax(yx >= 0.9)] - t[np.argmax(yx >= 0.1)]
    overshoot = 100 * (yx.max() - 1)
    outside = np.flatnonzero(np.abs(yx - 1) > 0.02)
    settle = t[outside[-1] + 1] if outside.size else 0.0
    print(f"2 um X step: rise {rise * 1e3:.1f} ms, overshoot {overshoot:.1f} %, 2 % settling {settle * 1e3:.1f} ms, "
          f"max |Y|,|Z| {np.abs(ys[:, 1:]).max() / 0.4 * 100:.2f} % of step")
    assert abs(yx[-1] - 1) < 0.01 and np.all(np.abs(ys[-1, 1:]) < 0.004)
    assert rise < 0.05
    pngs = sorted(p.name for p in out.glob("*.png"))
    from nanosim.pipeline import artifacts as A
    # 8 paper figures + 2 robustness; the mixsyn reference is the exported design, so no reference_fig*
    assert pngs == sorted(a.name for a in A.FIGURES if a.step == "design" and not a.is_pattern)
    assert all((out / p).stat().st_size > 10_000 for p in pngs)
    assert (out / A.ROBUSTNESS_JSON).is_file()
    assert not list(out.glob(".*"))                     # no temp files left behind


def test_run_design_missing_model(tmp_path):
    from nanosim.pipeline.design import run_design
    with pytest.raises(FileNotFoundError):
        run_design(tmp_path / "nope.npz", tmp_path / "out", progress=False)
    from nanosim import fileio
    fileio.write_npz(tmp_path / "bad.npz", A=np.eye(2), B=np.ones((2, 1)))
    with pytest.raises(ValueError, match="missing"):
        run_design(tmp_path / "bad.npz", tmp_path / "out", progress=False)
