"""Integral resonant control (``irc`` on the bench) and the second-order-section export.

Analytic reference: the IRC loop on one mode, ``(k_c/s)|D_f|(s^2 + w_z^2)/(s^2 + w_1^2)``, closes to
``s^3 + g s^2 + w_1^2 s + g w_z^2 = 0`` with ``g = k_c |D_f|`` (the root locus of integral force
feedback, Preumont, Vibration Control of Active Structures); its complex pair's damping at
the design's gain is the value the twin's closed loop is held to. The maximum over ``g``,
``(w_1 - w_z)/(2 w_z)`` at ``g = w_1 sqrt(w_1/w_z)``, is checked against the cubic itself.
"""
from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import numpy as np
import pytest

from nanosim.design.architectures import BENCH, design
from nanosim.design.architectures.common import DT_S, closed_loop_spectral_radius, freqresp_z, split_2dof
from nanosim.design.architectures.irc import IrcRule, closed_loop_poles, design_irc, irc_max_damping
from nanosim.design.sos import sos_frequency_response, state_space_sos

MODEL = Path(__file__).parent / "data" / "identified_seed0.npz"


def _cubic_damping(g, w1, wz):
    r = np.roots([1.0, g, w1 * w1, g * wz * wz])
    c = r[np.argmax(r.imag)]
    return float(-c.real / abs(c))


def test_max_damping_formula_is_the_peak_of_the_root_locus():
    w1, wz = 2 * np.pi * 176.0, 2 * np.pi * 176.0 / np.sqrt(2)
    g_opt, zeta_max = irc_max_damping(w1, wz)
    gs = g_opt * np.logspace(-1, 1, 2001)
    zs = np.array([_cubic_damping(g, w1, wz) for g in gs])
    assert zs.max() == pytest.approx(zeta_max, rel=1e-3)
    assert gs[np.argmax(zs)] == pytest.approx(g_opt, rel=0.01)


@pytest.fixture(scope="module")
def twin_irc(twin):
    return design_irc(twin.sysd_V), twin


def test_irc_damps_the_first_pair_on_the_twin(twin_irc):
    d, twin = twin_irc
    p = d.parameters
    G = twin.sysd_V
    s = np.log(np.linalg.eigvals(np.asarray(G.A, float)).astype(complex)) / DT_S
    band = (s.imag > 0) & (np.abs(s) / (2 * np.pi) > 150) & (np.abs(s) / (2 * np.pi) < 200)
    zeta_open = float(np.min(-s.real[band] / np.abs(s[band])))
    sc = np.log(closed_loop_poles(G, d.K, 3).astype(complex)) / DT_S
    band = (sc.imag > 0) & (np.abs(sc) / (2 * np.pi) > 150) & (np.abs(sc) / (2 * np.pi) < 200)
    zeta_closed = float(np.min(-sc.real[band] / np.abs(sc[band])))       # the least damped pair near 176 Hz
    # the single-mode root locus at the design's gain, for the X and Y axes (their first mode: 175-178 Hz)
    computed = []
    for i in (0, 1):
        assert 170.0 < p["axis_modes_hz"][i] < 182.0
        w1, wz = 2 * np.pi * p["axis_modes_hz"][i], 2 * np.pi * p["zero_below_first_mode_hz"][i]
        computed.append(_cubic_damping(p["damping_gain_rad_s"][i] * abs(p["feedthrough_Df"][i]), w1, wz))
    assert zeta_closed >= 0.8 * min(computed), (zeta_closed, computed)
    assert zeta_closed >= 10 * zeta_open, (zeta_closed, zeta_open)
    Ke, Ky = split_2dof(d.K, 3)
    assert closed_loop_spectral_radius(G, Ke, Ky) < 1.0
    assert p["predicted_disk_margin"]["loop_at_a_time"] >= 0.5 - 1e-9


def test_irc_is_on_the_bench_and_stable_with_the_identified_model():
    from nanosim.design.lti import load_state_space_npz
    assert "irc" in BENCH
    G = load_state_space_npz(MODEL)[1]
    d = design("irc", G)
    Ke, Ky = split_2dof(d.K, 3)
    assert closed_loop_spectral_radius(G, Ke, Ky) < 1.0
    assert d.config.spectral_radius < 1.0                  # the controller itself: no pole at z = 1
    assert d.n_error == 3 and d.tuning_rule and json.dumps(d.parameters)
    assert all(z["damping_ratio"] > 0.03 for z in d.parameters["first_pair_closed_loop"][:2])
    assert d.parameters["rule"] == dataclasses.asdict(IrcRule())


def test_irc_rule_is_a_frozen_value_with_checked_fields():
    with pytest.raises(dataclasses.FrozenInstanceError):
        IrcRule().feedthrough_factor = 3.0
    with pytest.raises(ValueError, match="feedthrough_factor"):
        IrcRule(feedthrough_factor=0.5)
    with pytest.raises(ValueError, match="gain_margin"):
        IrcRule(gain_margin=1.0)


def test_sos_export_reproduces_the_state_space_response(twin_irc):
    d, _ = twin_irc
    A, B, C, D, dt = d.matrices
    S = state_space_sos(A, B, C, D)
    assert S.shape[:2] == (3, 6) and S.shape[3] == 6
    np.testing.assert_array_equal(S[..., 3], 1.0)                   # a0 = 1 in every section
    f = np.logspace(-1, np.log10(0.49 / dt), 400)
    H = sos_frequency_response(S, f, dt)
    Hs = freqresp_z(d.K, f)
    scale = np.abs(Hs).max(axis=0, keepdims=True)
    nz = scale[0] > 0
    rel = np.abs(H - Hs)[:, nz] / np.maximum(np.abs(Hs)[:, nz], 1e-6 * scale[:, nz])
    assert rel.max() < 1e-9, rel.max()
    assert np.all(np.abs(H[:, ~nz]) == 0)                           # channels without dynamics stay zero


def test_controller_exports_write_mat_and_sos(tmp_path, twin_irc):
    import scipy.io

    from nanosim.pipeline.export import CONTROLLER_SOS_JSON, CONTROLLER_SOS_NPZ, write_controller_exports
    d, _ = twin_irc
    A, B, C, D, dt = d.matrices
    files = write_controller_exports(tmp_path / "controller.npz", A, B, C, D, dt, 3)
    assert [f.name for f in files] == ["controller.mat", CONTROLLER_SOS_NPZ, CONTROLLER_SOS_JSON]
    m = scipy.io.loadmat(tmp_path / "controller.mat")
    np.testing.assert_array_equal(m["A"], A)
    np.testing.assert_array_equal(m["D"], D)
    assert float(m["Ts"].ravel()[0]) == dt and int(m["n_error"].ravel()[0]) == 3
    doc = json.loads((tmp_path / CONTROLLER_SOS_JSON).read_text())
    np.testing.assert_array_equal(np.array(doc["sos"]), np.load(tmp_path / CONTROLLER_SOS_NPZ)["sos"])
    assert doc["dt"] == dt and "sos" in doc["units"]
