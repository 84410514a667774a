"""The four-block H-infinity design (S, SG, KS, T) and its export as the default controller."""
import json
import math
from pathlib import Path

import numpy as np
import pytest
from numpy.testing import assert_allclose

ct = pytest.importorskip("control")
pytest.importorskip("slycot")

from nanosim import constants  # noqa: E402
from nanosim.design.architectures import DESIGN_RULES, design  # noqa: E402
from nanosim.design.architectures.common import closed_loop_spectral_radius, dc_gain_z  # noqa: E402
from nanosim.design.architectures.hinf_fourblock import (  # noqa: E402
    BANDWIDTH_MARGIN,  # noqa: E402
    HYSTERESIS_FRACTION,
    REFERENCE_STEP_UM,
    RESONANT_PEAK,
    disturbance_weight,
    fourblock_plant,
    input_noise_V,
    least_damping_near,
    mode_damping,
)
from nanosim.design.lti import freqresp, load_state_space_npz  # noqa: E402
from nanosim.design.weights import Weights  # noqa: E402

MODEL = Path(__file__).parent / "data" / "identified_seed0.npz"
FIRST_PAIR_HZ = 175.5          # the identified model's first mode (tests/data/identified_seed0.npz)


@pytest.fixture(scope="module")
def model():
    return load_state_space_npz(MODEL)[1]


@pytest.fixture(scope="module")
def fourblock(model):
    return design("hinf", model)


def test_architecture_names_are_the_design_rules_and_the_reference():
    from nanosim.pipeline.config import DEFAULT_ARCHITECTURE, DESIGN_ARCHITECTURES
    assert set(DESIGN_ARCHITECTURES) == set(DESIGN_RULES) | {"mixsyn"}
    assert DEFAULT_ARCHITECTURE == "hinf"


def test_disturbance_weight_levels_come_from_the_hysteresis_and_the_noise_budget():
    G0 = np.diag([1.2, 0.8, 2.0])
    Wd, parts = disturbance_weight(G0, 250e-6)
    assert Wd.ninputs == Wd.noutputs == 3
    low = abs(freqresp(Wd, np.array([1e-3]))[0, 0, 0])
    assert low == pytest.approx(HYSTERESIS_FRACTION / 0.8 + parts["floor_level"], rel=1e-3)
    floor = input_noise_V() / (REFERENCE_STEP_UM / constants.SENSOR_UM_PER_V)
    assert parts["floor_level"] == pytest.approx(floor, rel=1e-12)
    assert input_noise_V() == pytest.approx(math.hypot(constants.DAC_WHITE_NOISE_V, constants.AMPLIFIER_NOISE_V))
    # flat up to the Nyquist low-pass: at 176 Hz (the first pair) the full hysteresis level
    mid = abs(freqresp(Wd, np.array([176.0]))[0, 1, 1])
    assert mid == pytest.approx(HYSTERESIS_FRACTION / 0.8 + floor, rel=0.01)
    # the second-order Butterworth at Nyquist: -3 dB at 2 kHz, -40 dB/decade above
    nyq = abs(freqresp(Wd, np.array([2000.0]))[0, 2, 2])
    assert nyq == pytest.approx(mid / math.sqrt(2), rel=0.01)
    assert abs(freqresp(Wd, np.array([20e3]))[0, 2, 2]) < 0.02 * mid
    # band-limited variant: one pole at 32 Hz, at 320 Hz the hysteresis part is 1/10 of its level
    Wb, _ = disturbance_weight(G0, 250e-6, bandwidth_hz=32.0)
    mid_b = abs(freqresp(Wb, np.array([320.0]))[0, 1, 1])
    assert mid_b == pytest.approx(HYSTERESIS_FRACTION / 0.8 / math.hypot(1, 10) + floor, rel=0.03)
    with pytest.raises(ValueError, match="bandwidth_hz"):
        disturbance_weight(G0, bandwidth_hz=-1.0)


def test_generalized_plant_blocks_are_the_four_block_problem():
    """With the loop open (u = 0): z = [Wp (r - G Wd d); 0; Wt G Wd d], v = r - G Wd d."""
    G = ct.ss(ct.tf([[[2.0], [0.0]], [[0.0], [1.0]]], [[[1, 30, 400], [1]], [[1], [1, 20, 900]]]))
    W = Weights()
    Wd, _ = disturbance_weight(dc_gain_z(G), 250e-6)
    P = fourblock_plant(G, W, Wd)
    assert (P.ninputs, P.noutputs) == (6, 8)
    f = np.array([3.0, 40.0])
    Pf, Gf, Wdf = freqresp(P, f), freqresp(G, f), freqresp(Wd, f)
    wp, wt = W.Wp.freqresp(f), W.Wt.freqresp(f)
    for k in range(f.size):
        GWd = Gf[k] @ Wdf[k]
        np.testing.assert_allclose(Pf[k, 0:2, 0:2], wp[k] * np.eye(2), rtol=1e-9, atol=1e-9)
        np.testing.assert_allclose(Pf[k, 0:2, 2:4], -wp[k] * GWd, rtol=1e-7, atol=1e-6)
        np.testing.assert_allclose(Pf[k, 4:6, 2:4], wt[k] * GWd, rtol=1e-7, atol=1e-6)
        np.testing.assert_allclose(Pf[k, 6:8, 2:4], -GWd, rtol=1e-7, atol=1e-6)
        np.testing.assert_allclose(Pf[k, 2:4, 4:6], 0.15 * np.eye(2), rtol=1e-12, atol=1e-12)
    with pytest.raises(ValueError, match="weights.Wt"):
        fourblock_plant(G, Weights(Wt=None), Wd)


def test_four_block_design_is_stable_with_finite_gamma_and_damps_the_first_pair(model, fourblock):
    p = fourblock.parameters
    assert math.isfinite(p["gamma"]) and p["gamma"] >= p["gamma_min"] > 0
    assert p["gamma_grid_check"] <= 1.05 * p["gamma"]
    assert p["controller_order"] == fourblock.K.nstates
    assert fourblock.K.ninputs == 6                      # two degrees of freedom: u = K (F r - y), inputs [e; y]
    pf, eq = p["reference_prefilter"], p["reference_lag_equalizer"]
    st = p["reference_step_filter"]
    assert p["controller_order"] == (p["feedback_order"] + pf["prefilter_states"] + eq["prefilter_states"]
                                     + st["prefilter_states"])
    assert pf["ringing_pairs"] and not pf["ringing_pairs_after"]
    # the lag equalizer: every axis trails a ramp by the slowest axis's lag, no cross lag, on the identified model
    after = np.asarray(eq["lag_matrix_after_ms"])
    assert_allclose(after, eq["common_lag_ms"] * np.eye(3), atol=1e-6 * eq["common_lag_ms"])
    assert eq["common_lag_ms"] == pytest.approx(max(np.diag(eq["lag_matrix_ms"])), rel=1e-12)
    assert closed_loop_spectral_radius(model, *fourblock.split()) < 1.0
    # the required S bandwidth, predicted on the identified model for the feedback loop (I + G K)^-1
    assert p["predicted_bandwidth_S_hz"] >= p["required_bandwidth_S_hz"] == pytest.approx(BANDWIDTH_MARGIN * 32.0)
    assert p["weights"]["Wd"]["corner_hz"] == pytest.approx(59.0)      # the paper's T bandwidth
    # the first pair: the paper's S/KS/T optimum leaves it at (near) open-loop damping, the four-block one damps it
    open_loop = min(z for f, z in __import__("nanosim.design.architectures.common", fromlist=["x"])
                    .lightly_damped_modes(model) if abs(f / FIRST_PAIR_HZ - 1) < 0.05)
    paper = design("paper", model)
    z_paper = least_damping_near(mode_damping(model, paper.K, min_peak=RESONANT_PEAK), FIRST_PAIR_HZ)
    z_four = p["closed_loop_least_damping_first_pair"]
    assert z_paper is not None and z_paper < 2 * open_loop
    # ten times the paper design's: the band-limited hysteresis weight keeps a third of its level at the pair
    assert z_four is not None and z_four >= 0.03 and z_four > 10 * z_paper


def test_reference_notch_leaves_the_feedback_of_the_one_degree_of_freedom_design(model, fourblock):
    """u = K (F r - y): the feedback part K_e - K_y is the 1-DOF design's K, the reference path K F has F's zeros
    on the ringing pairs; on the identified model the notched step has no pair left ringing."""
    from nanosim.design.architectures.common import freqresp_z
    one = design("hinf", model, reference_prefilter=False)
    assert one.K.ninputs == 3 and one.parameters["reference_prefilter"] is None
    f = np.array([5.0, 32.0, 120.0, 600.0])
    Ke, Ky = (freqresp_z(k, f) for k in fourblock.split())
    np.testing.assert_allclose(Ke - Ky, freqresp_z(one.K, f), rtol=1e-7, atol=1e-9)
    for notch in fourblock.parameters["reference_prefilter"]["notches"]:
        fn = np.array([notch["freq_hz"]])
        # the reference path K_e = K F: at the notch's centre |F| is at most zeta_zero / zeta_pole (a second-order
        # notch's depth; the group's notch spans its pairs) times the step filter's gain there (its largest of the
        # axis groups)
        from scipy.signal import freqz

        from nanosim.design.architectures.step_filter import step_filter_coefficients
        step_gain = max(abs(freqz(*step_filter_coefficients(sf["fz_hz"], sf["zeta_z"], sf["fp_hz"], sf["zeta_p"]),
                                  worN=fn, fs=1 / constants.CONTROL_PERIOD_S)[1][0])
                        for sf in fourblock.parameters["reference_step_filter"]["filters"])
        ref_path = np.linalg.norm(freqresp_z(fourblock.split()[0], fn)[0], 2)
        bound = (notch["zeta_zero"] / notch["zeta_pole"] * max(step_gain, 1.0)
                 * np.linalg.norm(freqresp_z(one.K, fn)[0], 2))
        assert ref_path <= bound and notch["zeta_zero"] / notch["zeta_pole"] < 0.2


@pytest.mark.slow
def test_default_export_is_the_four_block_design(tmp_path):
    from nanosim.pipeline.design import run_design
    out = tmp_path / "design"
    run_design(MODEL, out, figures=False)
    des = json.loads((out / "design.json").read_text())
    z = np.load(out / "controller.npz")
    assert des["architecture"] == "hinf" and des["exported_controller"]["architecture"] == "hinf"
    assert z["Akd"].shape[0] == des["controller_order"] == des["exported_controller"]["controller_order"]
    assert des["gamma"] == pytest.approx(float(z["gamma"]))
    assert des["reference_design"]["architecture"] == "mixsyn"
    assert "Wd" in des["exported_controller"]["parameters"]["weights"]


@pytest.mark.slow
@pytest.mark.parametrize("name", sorted(DESIGN_RULES))
def test_every_architecture_exports_consistent_files(tmp_path, model, name):
    """The export step of ``nanosim design --architecture NAME``: controller.npz's states are design.json's order."""
    from nanosim.pipeline.design import _export_bench
    units = np.array(["e: tracking error", "u: controller volts"])
    entries = _export_bench(tmp_path, model, float(model.dt), 0, units, lambda msg: None, name)
    z = np.load(tmp_path / "controller.npz")
    assert entries["architecture"] == name == entries["exported_controller"]["architecture"]
    assert z["Akd"].shape[0] == entries["controller_order"] == entries["exported_controller"]["controller_order"]
    assert int(z["n_error"]) == 3 and z["Bkd"].shape[1] in (3, 6)
    if entries["gamma"] is not None:
        assert float(z["gamma"]) == pytest.approx(entries["gamma"]) and math.isfinite(entries["gamma"])


def test_bandwidth_margin_is_the_piezo_gain_ratio_of_the_two_prbs_excursions(model):
    """BANDWIDTH_MARGIN's source: the Masing secant gain of the piezo at the identification PRBS's excursion
    (+-0.5 controller V) over the one at the bandwidth experiment's (+-2 um through the identified static gain),
    rounded to one decimal."""
    from nanosim.experiments.bandwidth import PRBS_AMPLITUDE_UM
    from nanosim.experiments.sysid import IdentifySettings
    from nanosim.plant.piezo import PiezoConfig
    piezo = PiezoConfig()
    g = constants.AMPLIFIER_GAIN
    ident_pp_V = 2 * IdentifySettings().amplitude_V * g
    um_per_V = constants.SENSOR_UM_PER_V * np.linalg.norm(dc_gain_z(model), axis=0)    # per controller V, per actuator
    bw_pp_V = 2 * PRBS_AMPLITUDE_UM / um_per_V * g
    ratio = np.array([piezo.small_signal_gain(ident_pp_V) / piezo.small_signal_gain(v) for v in bw_pp_V])
    assert np.all(bw_pp_V < ident_pp_V)                      # the loop's excursions are the smaller ones
    assert_allclose(np.round(ratio, 1), BANDWIDTH_MARGIN)
    assert_allclose(ratio, 1.09, atol=0.01)
