"""The LQG bench design (#13): delay model, damping it adds, margins and the noise it removes.

Model: ``tests/data/identified_seed0.npz`` (``nanosim identify --seed 0``), as in
tests/test_bench_controllers.py.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

ct = pytest.importorskip("control")

from nanosim import constants  # noqa: E402
from nanosim.design.architectures.common import (  # noqa: E402
    DT_S,
    analysis_grid_hz,
    closed_loop_spectral_radius,
    disk_margin_summary,
    freqresp_z,
    loop_response,
)
from nanosim.design.architectures.lqg import LqgRule, delay_augmented, design_lqg, lqg_controller  # noqa: E402
from nanosim.design.lti import load_state_space_npz  # noqa: E402

MODEL = Path(__file__).parent / "data" / "identified_seed0.npz"


@pytest.fixture(scope="module")
def model():
    return load_state_space_npz(MODEL)[1]


def _one_mode(f_hz=176.0, zeta=0.005, gain=1.0):
    """Three decoupled copies of ``gain w^2/(s^2 + 2 zeta w s + w^2)`` at 4 kHz (Tustin)."""
    w = 2 * np.pi * f_hz
    g = ct.ss(ct.c2d(ct.tf([gain * w * w], [1, 2 * zeta * w, w * w]), DT_S, "tustin"))
    from nanosim.design.architectures.common import diag_ss
    return diag_ss([g] * 3)


def test_delay_augmented_model_is_the_plant_times_z_to_the_minus_d(model):
    f = np.array([1.0, 50.0, 176.0, 460.0, 1500.0])
    Aa, Ba, Ca = delay_augmented(model, 0)
    plain = ct.ss(Aa, Ba, Ca, np.zeros((3, 3)), DT_S)
    np.testing.assert_allclose(freqresp_z(plain, f), freqresp_z(model, f) - np.asarray(model.D)[None], rtol=1e-9,
                               atol=1e-12)
    for d in (1, 2):
        Aa, Ba, Ca = delay_augmented(model, d)
        aug = ct.ss(Aa, Ba, Ca, np.zeros((3, 3)), DT_S)
        want = freqresp_z(model, f) * np.exp(-2j * np.pi * f * d * DT_S)[:, None, None]
        np.testing.assert_allclose(freqresp_z(aug, f), want, rtol=1e-9, atol=1e-12)


@pytest.mark.parametrize("delay", [0, 1])
def test_lqg_damps_a_lightly_damped_mode_through_the_delay(delay):
    """A single 176 Hz mode at zeta 0.005 (Tustin, so the plant has feedthrough: the loop is closed with a
    sample of delay): the loop's least-damped pole above 20 Hz has zeta >= 0.1."""
    G = _one_mode()
    G = ct.ss(G.A, G.B, G.C, 0 * np.asarray(G.D), DT_S) if delay == 0 else G
    K = lqg_controller(G, delay_samples=delay, disturbance_noise_V=3e-5)
    n = 3
    Ke = ct.ss(K.A, K.B[:, :n], K.C, K.D[:, :n], DT_S)
    Ky = ct.ss(K.A, K.B[:, n:], K.C, K.D[:, n:], DT_S)
    assert closed_loop_spectral_radius(G, Ke, Ky, delay) < 1.0
    # closed-loop poles of u = -(Ke - Ky) y around z^-d G (r = 0)
    Aa, Ba, Ca = delay_augmented(G, delay)
    Ak, Bk, Ck, Dk = (np.asarray(m) for m in (K.A, np.asarray(K.B[:, :n]) - np.asarray(K.B[:, n:]), K.C,
                                              np.asarray(K.D[:, :n]) - np.asarray(K.D[:, n:])))
    Acl = np.block([[Aa - Ba @ Dk @ Ca, Ba @ Ck], [-Bk @ Ca, Ak]])
    s = np.log(np.linalg.eigvals(Acl).astype(complex)) / DT_S
    wn = np.abs(s)
    mask = (wn > 2 * np.pi * 20) & (s.imag > 0)
    zeta = -s.real[mask] / wn[mask]
    assert zeta.min() >= 0.1, zeta.min()


def test_lqg_on_the_identified_model_margin_bandwidth_and_dac_noise(model):
    d = design_lqg(model, LqgRule.nominal())
    Ke, Ky = d.split()
    f = analysis_grid_hz(DT_S, n=400)
    Gf = freqresp_z(model, f)
    r = loop_response(Gf, f, Ke, Ky, delay_samples=0)
    assert disk_margin_summary(r)["multiloop"] >= 0.45
    assert d.parameters["predicted_bandwidth_S_hz"] >= 32.0
    # white noise at the plant input -> X reading: closed loop below 30 % of the open loop (sigma)
    fn = np.unique(np.concatenate([np.geomspace(1.0, 1999.0, 3000), np.linspace(150, 520, 3000)]))
    G = freqresp_z(model, fn) - np.asarray(model.D)[None]
    Kfb = freqresp_z(Ke, fn) - freqresp_z(Ky, fn)
    H = np.linalg.solve(np.eye(3) + G @ Kfb, G)
    var_cl = np.trapezoid((np.abs(H[:, 0, :]) ** 2).sum(axis=1), fn)
    var_ol = np.trapezoid((np.abs(G[:, 0, :]) ** 2).sum(axis=1), fn)
    assert np.sqrt(var_cl / var_ol) < 0.3
    assert d.parameters["input_noise_V"] == constants.DAC_WHITE_NOISE_V
    # started at the home reading (Z probe at -25 um): the plain equilibrium holds volts through the
    # measurement path -- a kick -- while reset_at starts at the stage's zero command
    ctrl = d.controller()
    y_home = np.array([0.0, 0.0, -25.0]) / constants.SENSOR_UM_PER_V
    ctrl.reset(measurement_V=y_home)
    assert np.abs(ctrl.step(np.zeros(3), y_home)).max() > 5.0
    ctrl.reset_at(y_home)
    assert np.abs(ctrl.step(np.zeros(3), y_home)).max() < 1e-9


def test_design_config_exports_the_four_block_hinf_by_default_and_the_paper_design_is_mixsyn():
    from nanosim.pipeline.config import DesignConfig
    assert DesignConfig().architecture == "hinf"
    assert DesignConfig.paper().architecture == "mixsyn"
    assert DesignConfig(architecture="lqg").architecture == "lqg"
    with pytest.raises(ValueError, match="architecture"):
        DesignConfig(architecture="pid")


def test_nominal_lqg_vertex_check_records_the_worst_vertex(model):
    """Brute force over STAGE_UNCERTAINTY (96 plants): the nominal rule, designed on the identified model alone,
    is not stable over the whole set (why the exported rule is the robust one), and the recorded worst vertex is
    the loop closed by hand at that vertex."""
    from nanosim.design.uncertainty import ModalPlant
    d = design_lqg(model, LqgRule.nominal())
    Ke, Ky = d.split()
    v = d.parameters["uncertainty_vertices"]
    assert v["n_checked"] == 2 ** 6 + 32
    assert v["worst_spectral_radius"] < 1.03, v
    w = v["worst"]
    P = ModalPlant(model, DT_S).state_space(w["freq_scale"], w["damping_scale"], np.array(w["input_gain"]),
                                            w["extra_delay_samples"])
    assert closed_loop_spectral_radius(P, Ke, Ky, 0) == pytest.approx(v["worst_spectral_radius"], rel=1e-9)
    assert v["all_stable"] is False and v["n_unstable"] > 0 and v["worst_spectral_radius"] > 1.0, v


def test_shifted_modes_moves_only_the_modes_above_300_hz_and_keeps_each_dc_gain(model):
    """Lightly damped pairs (zeta < 0.3) between 300 Hz and 1 kHz at 1.03 x, damping kept; every other pole
    (the 176/178/245 Hz modes, real and filter poles) where it was; the static gain unchanged."""
    from nanosim.design.architectures.lqg import shifted_modes
    Gs = shifted_modes(model, 1.03, 300.0)

    def poles_s(G):
        return np.log(np.linalg.eigvals(np.asarray(G.A)).astype(complex)) / DT_S
    s0 = poles_s(model)
    w0 = np.abs(s0)
    moved = (np.abs(s0.imag) > 1e-6 * w0) & (w0 > 2 * np.pi * 300) & (w0 <= 2 * np.pi * 1000) & (-s0.real < 0.3 * w0)
    expect = np.where(moved, s0 * 1.03, s0)
    got = poles_s(Gs)
    assert moved.sum() >= 12                                  # the 462/472 Hz group, once per column, both signs
    d = np.abs(got[:, None] - expect[None, :]) / np.maximum(np.abs(expect[None, :]), 1.0)
    assert d.min(axis=1).max() < 1e-6 and d.min(axis=0).max() < 1e-6

    def dc(G):
        return np.asarray(G.C) @ np.linalg.solve(np.eye(G.nstates) - np.asarray(G.A), np.asarray(G.B))
    assert np.allclose(dc(Gs), dc(model), rtol=1e-8, atol=1e-10)


def test_predicted_noise_sigma_of_a_first_order_plant_open_loop_is_the_closed_form():
    """x+ = a x + b (u + w), y = x, zero controller: var y = b^2 s_w^2 / (1 - a^2) (DAC noise only
    reaches the table; gauge noise enters through the controller, here zero)."""
    from nanosim.design.architectures.lqg import predicted_noise_sigma_nm
    a, b = 0.9, 0.2
    G = ct.ss(a * np.eye(3), b * np.eye(3), np.eye(3), np.zeros((3, 3)), DT_S)
    K = ct.ss(np.zeros((1, 1)), np.zeros((1, 6)), np.zeros((3, 1)), np.zeros((3, 6)), DT_S)
    sig = predicted_noise_sigma_nm(G, K)
    expect = b * constants.DAC_WHITE_NOISE_V / np.sqrt(1 - a * a) * constants.SENSOR_UM_PER_V * 1e3
    assert np.allclose(sig, expect, rtol=1e-9)


@pytest.mark.parametrize("seed", range(5))
def test_identified_gain_is_the_piezo_gain_under_the_identification_excitation(seed):
    """IDENTIFIED_INPUT_GAIN_OF_NOMINAL, the piezo gain an identified model holds (factor on nominal), is what the
    piezo model (hysteresis and creep, no mechanics) gives over 20-100 Hz for the identification's own excitation:
    between the slope after a reversal (w0) and nominal. 1 %."""
    import scipy.signal as ss

    import identification as ident
    from nanosim.design.robustness import IDENTIFIED_INPUT_GAIN_OF_NOMINAL
    from nanosim.experiments.sysid import IdentifySettings
    from nanosim.plant.piezo import PiezoConfig, PiezoModel
    fs = constants.CONTROL_RATE_HZ
    settings = IdentifySettings()
    ex = ident.paper_excitation(fs=fs, amplitude=settings.amplitude_V, bands_hz=settings.bands_hz, seed=seed)
    v = np.zeros((ex.u.size, 3))
    v[:, 0] = ex.u * constants.AMPLIFIER_GAIN
    h = PiezoModel(PiezoConfig(), n_channels=3).run(v)[:, 0] / constants.AMPLIFIER_GAIN
    f, Pxy = ss.csd(ex.u, h, fs=fs, nperseg=int(fs))
    _, Pxx = ss.welch(ex.u, fs=fs, nperseg=int(fs))
    band = (f >= 20.0) & (f <= 100.0)
    gain = float(np.abs(Pxy[band] / Pxx[band]).mean())
    assert gain == pytest.approx(IDENTIFIED_INPUT_GAIN_OF_NOMINAL, rel=0.01)
    assert PiezoConfig().small_signal_gain() * 0.9 < gain < 1.0


def test_uncertainty_set_is_mapped_onto_the_plant_by_its_piezo_gain():
    """The set's gain range is a factor on nominal; an identified model holds g_id of nominal, so on it the set
    spans 0.75/g_id ... 1/g_id; a twin (nominal piezo) keeps 0.75 ... 1. The mu keywords and the vertex check
    use the mapped range; a bad anchor is named."""
    from nanosim.design.architectures.common import uncertainty_vertex_check
    from nanosim.design.architectures.lqg import design_input_gains
    from nanosim.design.robustness import IDENTIFIED_INPUT_GAIN_OF_NOMINAL as g_id
    from nanosim.design.robustness import LoopPlant
    from nanosim.design.uncertainty import STAGE_UNCERTAINTY, UncertaintySet
    lo, hi = STAGE_UNCERTAINTY.input_gain_range_about(g_id)
    assert (lo, hi) == pytest.approx((0.75 / g_id, 1.0 / g_id), rel=1e-12)
    assert STAGE_UNCERTAINTY.mu_kwargs(0, g_id)["input_gain_range"] == pytest.approx((lo, hi), rel=1e-12)
    assert STAGE_UNCERTAINTY.mu_kwargs(1)["input_gain_range"] == (0.75, 1.0)
    assert design_input_gains((0.0, 0.5, 1.0)) == pytest.approx((lo, np.sqrt(lo * hi), hi), rel=1e-12)
    G = _one_mode()
    assert LoopPlant.identified(G).input_gain_of_nominal == g_id
    assert LoopPlant(G, 0).input_gain_of_nominal == 1.0
    with pytest.raises(ValueError, match=r"input_gain_of_nominal: expected a finite real number > 0\.0, got -1"):
        LoopPlant(G, 0, input_gain_of_nominal=-1)
    with pytest.raises(ValueError, match="input_gain_of_nominal"):
        STAGE_UNCERTAINTY.input_gain_range_about(0.0)
    # a static loop gain k on the plant: stable below its gain limit, so the mapped range decides the check
    K = ct.ss([], [], [], 0.2 * np.eye(3), DT_S)
    only_gain = UncertaintySet(freq_scale_range=(1.0, 1.0), damping_scale_range=(1.0, 1.0),
                               extra_delay_samples_range=(0, 0))
    radius = [uncertainty_vertex_check(G, K, None, only_gain, n_random=0, input_gain_of_nominal=a)
              ["worst_spectral_radius"] for a in (1.0, 0.5)]
    assert radius[1] > radius[0]            # the plant at half nominal: the set reaches twice its gain


def test_a_robust_rule_no_member_meets_says_so(model):
    """The ladder against a mu requirement no member meets (mixed mu < 0.3 over the set): the rule says so (a
    warning, robust_rule_met False) and still returns the checked member with the least mu."""
    import dataclasses
    rule = dataclasses.replace(LqgRule.robust(), design_input_gain=1.0, reference_prefilter=False, mu_max=0.3)
    with pytest.warns(UserWarning, match="mixed mu < 0.3.*robust_rule_met"):
        d = design_lqg(model, rule)
    assert d.parameters["robust_rule_met"] is False and d.parameters["design_input_gain"] == 1.0
    assert "mixed-mu upper bound < 0.3 over it" in d.tuning_rule
    with pytest.raises(ValueError, match="design_input_gain: expected a finite real number > 0.0, got 0"):
        LqgRule(design_input_gain=0)


def test_gain_range_rule_no_member_meets_takes_the_largest_margin_at_the_top(model, monkeypatch):
    """The gain-range rule with the design model at the identified gain against a set whose gain reaches 3 x the
    identified one, where no member keeps the margin: it says so (a warning naming the top, robust_rule_met False)
    and takes the member with the largest margin there, still with the margin at the identified gain."""
    from nanosim.design.architectures import lqg
    import dataclasses

    from nanosim.design.architectures.lqg import ROBUST_MIN_DISK_MARGIN
    monkeypatch.setattr(lqg, "design_input_gains", lambda gains: tuple(3.0 * float(g) for g in gains))
    with pytest.warns(UserWarning, match="at the top of the uncertainty set's gain range.*robust_rule_met"):
        d = design_lqg(model, dataclasses.replace(LqgRule.gain_range(), design_input_gain=1.0,
                                                  reference_prefilter=False))
    p = d.parameters
    assert p["robust_rule_met"] is False and p["gain_range_margin"] is True and p["mu_peak"] is None
    tops = [r["multiloop_disk_margin_top"] for r in p["tried"] if "multiloop_disk_margin_top" in r]
    assert tops and max(tops) < ROBUST_MIN_DISK_MARGIN
    assert p["predicted_disk_margin_top_of_gain_range"]["multiloop"] == max(tops)
    assert p["predicted_disk_margin"]["multiloop"] >= ROBUST_MIN_DISK_MARGIN


def test_bandwidths_of_a_discrete_integrator_loop_match_the_closed_form():
    # u = Ke (r - y) around G = I with Ke = a / (z - 1): S = (z - 1) / (z - 1 + a), and |S(e^{j w T})| = 1/sqrt(2) at
    # cos(w T) = (3 - (1 - a)^2) / (2 + 2 a). One degree of freedom: reference to error is S itself. With half the
    # reference fed past the loop (Ky = Ke / 2, so the feedback is halved and T_ry = G Ke S_o), the reference-to-error
    # map is no longer S_o, and the two figures part
    from nanosim.design.architectures.common import reference_error_bandwidth_hz, sensitivity_bandwidth_hz
    a = 0.2
    Ke = ct.ss(np.eye(3), a * np.eye(3), np.eye(3), np.zeros((3, 3)), DT_S)
    G = ct.ss(np.zeros((0, 0)), np.zeros((0, 3)), np.zeros((3, 0)), np.eye(3), DT_S)
    f = np.geomspace(1.0, 1999.0, 20000)
    r = loop_response(freqresp_z(G, f), f, Ke, None, delay_samples=0)
    exact = np.arccos((3 - (1 - a) ** 2) / (2 + 2 * a)) / (2 * np.pi * DT_S)
    assert sensitivity_bandwidth_hz(r) == pytest.approx(exact, rel=1e-4)
    assert reference_error_bandwidth_hz(r) == pytest.approx(exact, rel=1e-4)
    r2 = loop_response(freqresp_z(G, f), f, Ke, 0.5 * Ke, delay_samples=0)
    assert reference_error_bandwidth_hz(r2) != pytest.approx(sensitivity_bandwidth_hz(r2), rel=0.05)
