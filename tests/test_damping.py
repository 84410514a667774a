"""Inner active-damping loop and the two-degree-of-freedom controller
(nanosim.design.damping_loop / damped_plant, DiscreteController with [e; y])."""
from __future__ import annotations

import numpy as np
import pytest
from numpy.testing import assert_allclose

control = pytest.importorskip("control")
pytest.importorskip("slycot")
from nanosim import fileio  # noqa: E402
import nanosim.design as D  # noqa: E402
from nanosim.design.controller import DiscreteController  # noqa: E402
from nanosim.pipeline.config import DesignConfig  # noqa: E402
from nanosim.pipeline.design import run_design  # noqa: E402
from test_design import paper_like_plant  # noqa: E402

ct = control


def closed_loop_poles(G):
    p = np.linalg.eigvals(np.asarray(G.A, float))
    return p[p.imag > 0]


def damping_in_band(A, lo_hz, hi_hz):
    p = np.linalg.eigvals(np.asarray(A, float))
    f = np.abs(p) / (2 * np.pi)
    sel = (p.imag > 0) & (f > lo_hz) & (f < hi_hz)
    return -p.real[sel] / np.abs(p[sel])


def test_velocity_feedback_adds_analytic_damping():
    # G = g0 w^2 / (s^2 + 2 zeta w s + w^2); u = -c s y adds c w g0 / 2 ... with g0 decoupled away:
    # Ky = -c s G(0)^-1 -> s^2 + (2 zeta w + c w^2) s + w^2, i.e. zeta + zeta_added (c = 2 zeta_added / w).
    f1, zeta, g0 = 176.0, 0.004, 0.6
    w = 2 * np.pi * f1
    G = ct.ss(ct.tf([g0 * w * w], [1, 2 * zeta * w, w * w]))
    for za in (0.05, 0.1, 0.2):
        dl = D.damping_loop(G, za, lowpass_hz=100 * f1)        # low-pass far away: pure velocity feedback
        assert dl.mode_hz == pytest.approx(f1, rel=1e-9)          # |p| / 2 pi = natural frequency
        Gd = D.damped_plant(G, dl)
        p = closed_loop_poles(Gd)
        pm = p[np.argmin(np.abs(np.abs(p) - w))]
        assert_allclose(-pm.real / abs(pm), zeta + za, rtol=0.03)
        assert_allclose(D.dc_gain(Gd), D.dc_gain(G), rtol=1e-9)        # Ky(0) = 0: static gain kept


def test_damping_loop_rejects_bad_input():
    G = paper_like_plant()
    with pytest.raises(ValueError, match="destabilizes"):     # 400 Hz lag flips the in-phase 474 Hz modes
        D.damped_plant(G, D.damping_loop(G, 0.1, lowpass_hz=400.0))
    with pytest.raises(ValueError, match="zeta_added"):
        D.damping_loop(G, -0.1)
    with pytest.raises(ValueError, match="lowpass_hz"):
        D.damping_loop(G, 0.1, lowpass_hz=float("nan"))
    with pytest.raises(ValueError, match="lightly damped"):
        D.damping_loop(ct.ss(ct.tf([1.0], [1.0, 1.0])), 0.1)


@pytest.fixture(scope="module")
def designs():
    G = paper_like_plant()
    red = D.reduce_model(G, 10)
    # this synthetic plant's 460/474 Hz modes are in phase with the first ones (collocated), so the
    # low-pass goes above them (the MuJoCo stage's are in anti-phase: there it sits at 400 Hz)
    dl = D.damping_loop(red.G_reduced, 0.1, lowpass_hz=2000.0)
    one = D.design_hinf(red.G_reduced, G_full=G)
    two = D.design_hinf(D.damped_plant(red.G_reduced, dl), G_full=D.damped_plant(G, dl))
    import dataclasses
    return G, red, one, dataclasses.replace(two, damping=dl)


def test_two_dof_loop_equals_design_on_damped_plant(designs):
    # r -> y of u = K e + Ky y on the *undamped* plant equals T of the design on Gd.
    # (nominal model: the 39-state synthetic plant repeats every pole three times, and the
    # frequency response of its fed-back realization is only good to ~3e-4 near resonance)
    G, red, _, two = designs
    f = np.array([1.0, 10.0, 32.0, 100.0, 176.0, 245.0, 474.0])
    Gf, Kf, Kyf = D.freqresp(red.G_reduced, f), D.freqresp(two.K, f), D.freqresp(two.damping.Ky, f)
    I = np.eye(3)
    T_2dof = np.linalg.solve(I + Gf @ (Kf - Kyf), Gf @ Kf)
    Gdf = D.freqresp(two.G_nominal, f)
    T_design = np.linalg.solve(I + Gdf @ Kf, Gdf @ Kf)
    assert_allclose(T_2dof, T_design, rtol=1e-6, atol=1e-7)      # |T| ~ 1 on the diagonal
    fi = np.searchsorted(two.freq_hz, 32.0)
    Tgrid = np.linalg.solve(I + D.freqresp(red.G_reduced, two.freq_hz[fi:fi + 1]) @ (
        D.freqresp(two.K, two.freq_hz[fi:fi + 1]) - D.freqresp(two.damping.Ky, two.freq_hz[fi:fi + 1])),
        D.freqresp(red.G_reduced, two.freq_hz[fi:fi + 1]) @ D.freqresp(two.K, two.freq_hz[fi:fi + 1]))
    assert_allclose(Tgrid[0], two.nominal.T_f[fi], rtol=1e-6, atol=1e-7)     # the design's own analysis
    # the feedback operator is K - Ky
    KfbF = D.freqresp(two.feedback_controller(), f)
    assert_allclose(KfbF, Kf - Kyf, rtol=1e-9, atol=1e-12)


def test_damping_loop_damps_first_modes_keeps_bandwidth(designs):
    # Paper single loop: the controller inverts the lightly damped 175/179/245 Hz modes and the
    # closed loop keeps zeta = 0.005. With the inner loop they end up at zeta >= 0.05.
    # (minimal nominal model: the synthetic full plant repeats each mode per input column, and
    # those copies are uncontrollable, so they keep zeta = 0.005 whatever the feedback)
    # The closed loops compared: K around the nominal plant, and the outer K around the damped plant
    # Gd (the loop that runs: equal to u = K e + Ky y on the undamped plant, see the test above).
    # Each closed loop also holds the controllers' poles at the plant's lightly damped transmission
    # zeros (263.8/270.2 Hz, zeta ~0.005 in both: the inner loop cannot move zeros), so the modes are
    # matched one to one to the plant's own resonances in 150-300 Hz (175/179/245 Hz) by frequency.
    from scipy.optimize import linear_sum_assignment
    G, red, one, two = designs

    def closed_loop_mode_damping(Gn, K, modes_hz):
        p = np.linalg.eigvals(np.asarray(D.loop_functions(Gn, K)[0].A, float))
        p = p[p.imag > 0]
        f = np.abs(p) / (2 * np.pi)
        _, i = linear_sum_assignment(np.abs(f[None, :] - modes_hz[:, None]))   # one pole per mode
        assert_allclose(f[i], modes_hz, rtol=0.05)             # the same modes, shifted a few %
        return -p.real[i] / np.abs(p[i])

    pm = np.linalg.eigvals(np.asarray(red.G_reduced.A, float))
    fm = np.abs(pm[pm.imag > 0]) / (2 * np.pi)
    modes_hz = np.sort(fm[(fm > 150) & (fm < 300)])
    assert_allclose(modes_hz, [175.0, 179.0, 245.0], rtol=1e-3)
    z_one = closed_loop_mode_damping(red.G_reduced, one.K, modes_hz)
    z_two = closed_loop_mode_damping(two.G_nominal, two.K, modes_hz)
    print(f"closed-loop damping of the {modes_hz.round(0)} Hz modes: single loop {z_one.round(4)}, "
          f"with the damping loop {z_two.round(4)}")
    assert np.all(z_one < 0.01)
    assert np.all(z_two >= 0.05)
    assert two.gamma < 1.1 * one.gamma
    assert_allclose(two.bandwidth_S_hz, one.bandwidth_S_hz, rtol=0.1)
    assert two.nominal.S_peak < 1.45                      # the paper's bound on ||S||


def test_run_design_two_dof_controller_rings_less(tmp_path):
    G = paper_like_plant()
    Gd = ct.c2d(G, 1 / 4000, "zoh")
    model = fileio.write_npz(tmp_path / "model.npz", A=G.A, B=G.B, C=G.C, D=G.D,
                          Ad=Gd.A, Bd=Gd.B, Cd=Gd.C, Dd=Gd.D, dt=1 / 4000)
    ring = {}
    for name, zeta in (("single", None), ("damped", 0.1)):
        out = tmp_path / name
        cfg = DesignConfig.paper(damping_zeta=zeta or 0.0, damping_lowpass_hz=2000.0)
        d = run_design(model, out, cfg, progress=False, figures=False)
        assert not list(out.glob("*.png")) and (out / "robustness.json").is_file()     # figures=False: files only
        z = np.load(out / "controller.npz", allow_pickle=False)
        ctrl = DiscreteController.from_npz(out / "controller.npz")
        assert ctrl.two_dof == (zeta is not None)
        assert int(z["n_error"]) == 3 and z["Bkd"].shape[1] == (6 if zeta else 3)
        if zeta:    # outer K: 10 plant + 6 damping-loop + 9 weight states; exported [K, Ky] adds Ky's 6
            assert d.damping is not None and d.controller_order == 25 and z["Akd"].shape == (31, 31)
        # hold the origin; a 5 ms input-disturbance pulse on actuator A (like a hysteresis kink)
        x = np.zeros(Gd.nstates)
        n = 2000
        ys = np.empty((n, 3))
        for k in range(n):
            ys[k] = Gd.C @ x
            e = -ys[k]
            u = ctrl.step(e, ys[k]) if ctrl.two_dof else ctrl.step(e)
            dist = np.array([0.05, 0.0, 0.0]) if 100 <= k < 120 else 0.0
            x = Gd.A @ x + Gd.B @ (u + dist)
        ring[name] = np.abs(ys[800:, :2]).max()             # 0.2-0.5 s after the pulse
        tail = ys[-400:, 0]
        assert np.all(np.isfinite(ys)) and abs(tail.mean()) < 1e-3
        if zeta:
            # Ky(0) = 0 exactly in the exported discrete controller (Tustin keeps s = 0 at z = 1) ...
            js = __import__("json").loads((out / "design.json").read_text())
            assert js["damping_loop_discretization"]["dc_gain_abs_max"] < 1e-9
            # ... so a constant reading offset (the Z probe reads -5 V at home) changes nothing:
            # measurement y = y_true + offset, reference = offset + 0.4 V step on X.
            runs = []
            for offset in (np.zeros(3), np.array([0.3, -1.0, -5.0])):
                ctrl.reset(measurement_V=offset)
                x = np.zeros(Gd.nstates)
                r = offset + np.array([0.4, 0.0, 0.0])
                traj = []
                for _ in range(2000):
                    y = Gd.C @ x + offset
                    x = Gd.A @ x + Gd.B @ ctrl.step(r - y, y)
                    traj.append(Gd.C @ x)
                runs.append(np.array(traj))
            assert_allclose(runs[1], runs[0], atol=1e-9)
            assert_allclose(runs[0][-1], [0.4, 0.0, 0.0], atol=2e-3)     # creep lag still settling
    print(f"residual ring 0.2-0.5 s after the pulse (sensor V): {ring}")
    assert ring["damped"] < 0.1 * ring["single"]


def test_discrete_two_dof_controller_api():
    rng = np.random.default_rng(3)
    n = 4
    A = np.diag([0.5, 0.9, -0.3, 0.7])
    B, C, Dm = rng.normal(size=(n, 6)), rng.normal(size=(3, n)), rng.normal(size=(3, 6))
    ctrl = DiscreteController.from_matrices(A, B, C, Dm, 1 / 4000, n_error=3)
    assert ctrl.two_dof and ctrl.config.n_measurement == 3
    with pytest.raises(ValueError, match="measurement_V"):
        ctrl.step(np.zeros(3))
    with pytest.raises(ValueError, match="measurement_V"):
        ctrl.step(np.zeros(3), [0.0, np.nan, 0.0])
    with pytest.raises(ValueError, match="n_error"):
        DiscreteController.from_matrices(A, B, C, Dm, 1 / 4000, n_error=2)
    E, Y = rng.normal(size=(50, 3)), rng.normal(size=(50, 3))
    ctrl.reset()
    U = np.array([ctrl.step(e, y) for e, y in zip(E, Y)])
    x, ref = np.zeros(n), []
    for e, y in zip(E, Y):
        v = np.r_[e, y]
        ref.append(C @ x + Dm @ v)
        x = A @ x + B @ v
    assert_allclose(U, np.array(ref), rtol=1e-12, atol=1e-12)
    assert_allclose(ctrl.run(E, measurement_seq=Y), U, rtol=1e-12, atol=1e-12)
    # equilibrium start: constant y, zero error -> constant output from the first sample
    y0 = np.array([0.3, -0.2, 1.0])
    ctrl.reset(measurement_V=y0)
    U0 = np.array([ctrl.step(np.zeros(3), y0) for _ in range(20)])
    assert_allclose(U0, np.broadcast_to(U0[0], U0.shape), rtol=1e-10, atol=1e-12)
    one = DiscreteController.from_matrices(A, B[:, :3], C, Dm[:, :3], 1 / 4000)
    with pytest.raises(ValueError, match="error only"):
        one.step(np.zeros(3), np.zeros(3))
