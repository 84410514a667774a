"""The step filter: the piezo's step model (Masing gains, log creep) and the settling-time search.

Analytic cases: a first-order unit step ``1 - exp(-t / tau)`` enters a band ``b`` at ``tau ln(1 / b)``; the
Masing branch ``w0 d + sum_i w_i max(d - 2 r_i, 0)`` has the slope ``w0 + sum_(2 r_i < d) w_i``; a chain of
``n`` Kelvin-Voigt elements per decade of equal gain ``c`` rises by ``n c`` per decade between its extreme
time constants.
"""
from __future__ import annotations

import math
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from numpy.testing import assert_allclose

ct = pytest.importorskip("control")

from nanosim import constants as C  # noqa: E402
from nanosim.design.architectures.common import DT_S, freqresp_z, split_2dof  # noqa: E402
from nanosim.design.architectures.prefilter import reference_lag_matrix  # noqa: E402
from nanosim.design.architectures.step_filter import (  # noqa: E402
    CREEP_ELEMENTS_PER_DECADE,
    PiezoStepModel,
    design_step_filter,
    piezo_step_model,
    settling_time_s,
    step_filter_coefficients,
)
from nanosim.design.lti import load_state_space_npz  # noqa: E402
from nanosim.paper import PAPER, PAPER_PRBS_AMPLITUDE_V, PAPER_SETTLING_BAND  # noqa: E402
from nanosim.plant.piezo import PiezoConfig  # noqa: E402

MODEL = Path(__file__).parent / "data" / "identified_seed0.npz"


@pytest.mark.parametrize("band", [0.02, 0.05])
def test_settling_time_of_a_first_order_step_is_tau_ln_one_over_band(band):
    tau = 2e-3
    t = np.arange(400) * DT_S
    y = 1.0 - np.exp(-t / tau)
    assert settling_time_s(y, DT_S, band) == pytest.approx(tau * math.log(1 / band), abs=DT_S)
    assert settling_time_s(np.full(10, 0.5), DT_S, band) == pytest.approx(10 * DT_S)     # never inside: the record


def test_branch_slope_is_the_derivative_of_the_masing_branch():
    p = PiezoConfig()
    w0, _ = p.hysteresis_weights()
    assert p.branch_slope(0.0) == pytest.approx(w0, rel=1e-12) == pytest.approx(p.small_signal_gain(0.0))
    for d in (3.0, 9.0, 50.0):                       # between thresholds 2 r_i (2, 4, 7, 11, 16, 22, 30, 40, 54, ...)
        h = 1e-4
        branch = [(d + s) * p.small_signal_gain(d + s) for s in (-h, h)]
        assert p.branch_slope(d) == pytest.approx((branch[1] - branch[0]) / (2 * h), rel=1e-9)
    assert p.branch_slope(9.0) > p.small_signal_gain(9.0) > p.branch_slope(0.0)       # the branch steepens
    assert replace(p, hysteresis=False).branch_slope(5.0) == 1.0
    with pytest.raises(ValueError, match="excursion_piezo_V"):
        p.branch_slope(-1.0)


def test_piezo_step_model_of_a_diagonal_stage():
    """A 2 um step through a 0.25 sensor V per controller V stage: 1.6 controller V, 32 V at the piezo; gains from
    the tangent to the branch's end slope over the identification's secant; the creep rate at 32 V."""
    G = ct.ss([], [], [], 0.25 * np.eye(3), DT_S)
    p = PiezoConfig()
    m = piezo_step_model(G, p)
    d = 2.0 / C.SENSOR_UM_PER_V / 0.25 * C.AMPLIFIER_GAIN
    assert m.step_piezo_V == pytest.approx(d, rel=1e-12)
    ident = p.small_signal_gain(2 * PAPER_PRBS_AMPLITUDE_V * C.AMPLIFIER_GAIN)
    expected = [p.small_signal_gain(0) / ident, 0.5 * (m.gains[0] + m.gains[2]), p.branch_slope(d) / ident]
    assert_allclose(m.gains, expected, rtol=1e-12)
    assert m.gains[0] < m.gains[1] < m.gains[2]
    assert m.creep_per_decade == pytest.approx(p.creep_rate_per_decade(d), rel=1e-12)
    assert m.creep_tau_s[0] == pytest.approx(C.CREEP_TAU_MIN_S)
    # a linear piezo: one gain, no creep
    lin = piezo_step_model(G, PiezoConfig.linear())
    assert lin.gains == (1.0, 1.0, 1.0) and lin.creep_per_decade == 0.0 and lin.creep_tau_s == ()
    with pytest.raises(ValueError, match="step_um"):
        piezo_step_model(G, p, step_um=0.0)
    with pytest.raises(ValueError, match="G: expected a square"):
        piezo_step_model(ct.ss([], [], [], np.ones((3, 2)), DT_S), p)


def test_creep_filter_rises_by_the_creep_rate_per_decade():
    taus = tuple(1e-3 * 10 ** (k / CREEP_ELEMENTS_PER_DECADE) for k in range(9))       # 1 ms .. 10 s
    m = PiezoStepModel(step_piezo_V=4.0, gains=(1.0, 1.0, 1.0), creep_per_decade=0.05, creep_tau_s=taus)
    P = m.creep_filter(1e-4)
    t = np.array([0.01, 0.1, 1.0])
    _, y = ct.step_response(P, T=np.arange(int(1.0 / 1e-4) + 1) * 1e-4)
    y = np.asarray(np.squeeze(y), float)
    yk = y[np.round(t / 1e-4).astype(int)]
    # one decade apart, well inside the chain: the rise is the rate (the discrete chain's ripple, a few per cent)
    assert_allclose(np.diff(yk), 0.05, rtol=0.1)


def _loop(wc_hz=40.0):
    """A 3-axis loop with overshoot: plant 1 / (s (1 + s / 400 Hz)) per axis, PI controller."""
    wc, wp = 2 * np.pi * wc_hz, 2 * np.pi * 400.0
    Gc = ct.tf([wp], [1, wp, 0])
    Kc = ct.tf([wc, wc * wc / 3], [1, 2 * np.pi * 0.01])          # PI, its integrator leaking below 0.01 Hz
    G1 = ct.ss(ct.c2d(Gc, DT_S, "zoh"))
    K1 = ct.ss(ct.c2d(Kc, DT_S, "tustin"))
    G = ct.append(G1, G1, G1)
    K = ct.append(K1, K1, K1)
    return ct.ss(G), ct.ss(K)


def test_step_filter_shortens_the_predicted_settling_and_keeps_the_feedback():
    G, K = _loop()
    m = PiezoStepModel(step_piezo_V=4.0, gains=(0.9, 1.0, 1.1), creep_per_decade=0.0, creep_tau_s=())
    K2, p = design_step_filter(G, K, 3, model=m)
    for f in p["filters"]:
        before, after = np.max(f["predicted_settling_ms_before"]), np.max(f["predicted_settling_ms"])
        assert after < 0.8 * before
        assert np.max(f["predicted_overshoot_percent"]) <= 1.02 * p["overshoot_limit_percent"]
    assert p["predicted_settling_ms_worst"] <= max(np.max(f["predicted_settling_ms"]) for f in p["filters"]) + 1e-9
    # the feedback part K_e - K_y is K; the reference path is K F
    Ke, Ky = split_2dof(K2, 3)
    fr = np.array([3.0, 40.0, 300.0])
    assert_allclose(freqresp_z(Ke, fr) - freqresp_z(Ky, fr), freqresp_z(K, fr), rtol=1e-8, atol=1e-10)
    # X and Y share one filter: identical axes keep identical lags (a straight path in the plane stays straight)
    lag = reference_lag_matrix(G, Ke, Ky)
    assert lag[0, 0] == pytest.approx(lag[1, 1], rel=1e-9)
    assert abs(lag[0, 1]) < 1e-9 * abs(lag[0, 0])
    assert p["prefilter_states"] == 2 * 3 and K2.nstates == K.nstates + 6
    # the filter is a unit-static-gain biquad
    b, a = step_filter_coefficients(p["filters"][0]["fz_hz"], p["filters"][0]["zeta_z"],
                                    p["filters"][0]["fp_hz"], p["filters"][0]["zeta_p"])
    assert np.sum(b) / np.sum(a) == pytest.approx(1.0, rel=1e-12)
    with pytest.raises(ValueError, match="groups"):
        design_step_filter(G, K, 3, model=m, groups=((0, 1),))


def test_hinf_step_filter_predicts_the_papers_settling_on_the_identified_model():
    """The default design's step filter, on the bundled identified model: the predicted worst settling of the
    paper's step over the piezo's gain band with its creep is inside the paper's 11 ms (Fig. 18c)."""
    pytest.importorskip("slycot")
    from nanosim.design.architectures import design
    G = load_state_space_npz(MODEL)[1]
    p = design("hinf", G).parameters
    st = p["reference_step_filter"]
    worst_2pct = max(np.max(f["predicted_settling_ms"]) for f in st["filters"])
    before = max(np.max(f["predicted_settling_ms_before"]) for f in st["filters"])
    assert worst_2pct <= PAPER["settle"] < before
    # the model's overshoot stays inside half the band (the search's limit), every gain and axis
    assert st["overshoot_limit_percent"] == pytest.approx(50 * PAPER_SETTLING_BAND)
    for f in st["filters"]:
        assert np.max(f["predicted_overshoot_percent"]) <= 1.02 * st["overshoot_limit_percent"]
    assert [f["axes"] for f in st["filters"]] == [["X", "Y"], ["Z"]]
    assert p["controller_order"] == (p["feedback_order"] + p["reference_prefilter"]["prefilter_states"]
                                     + p["reference_lag_equalizer"]["prefilter_states"] + st["prefilter_states"])
