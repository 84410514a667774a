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
from nanosim.design.architectures.lqg import delay_augmented, design_lqg, lqg_controller  # noqa: E402
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
    d = design_lqg(model)
    Ke, Ky = d.split()
    f = analysis_grid_hz(DT_S, n=400)
    Gf = freqresp_z(model, f)
    r = loop_response(Gf, f, Ke, Ky, delay_samples=0)
    assert disk_margin_summary(r)["multiloop"] >= 0.45
    assert d.parameters["predicted_bandwidth_S_hz"] >= 32.0
    # DAC white noise at the plant input -> X reading: closed loop below a quarter of the open loop (sigma)
    fn = np.unique(np.concatenate([np.geomspace(1.0, 1999.0, 3000), np.linspace(150, 520, 3000)]))
    G = freqresp_z(model, fn) - np.asarray(model.D)[None]
    Kfb = freqresp_z(Ke, fn) - freqresp_z(Ky, fn)
    H = np.linalg.solve(np.eye(3) + G @ Kfb, G)
    var_cl = np.trapezoid((np.abs(H[:, 0, :]) ** 2).sum(axis=1), fn)
    var_ol = np.trapezoid((np.abs(G[:, 0, :]) ** 2).sum(axis=1), fn)
    assert np.sqrt(var_cl / var_ol) < 1 / 4
    assert d.parameters["input_noise_V"] == constants.DAC_WHITE_NOISE_V


def test_design_config_exports_lqg_by_default_and_the_paper_design_stays_hinf():
    from nanosim.pipeline.config import DesignConfig
    assert DesignConfig().architecture == "lqg"
    assert DesignConfig.paper().architecture == "hinf"
    with pytest.raises(ValueError, match="architecture"):
        DesignConfig(architecture="pid")
