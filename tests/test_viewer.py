"""Viewer unit tests: geom conversion, exaggeration closure, waveforms, CLI errors."""
from __future__ import annotations

import argparse
import socket

import mujoco
import numpy as np
import pytest

from nanosim.plant.modes import modal_analysis, volts_to_force_N
from nanosim.viewer import add_view_arguments, port_is_free, run_view
from nanosim.viewer import scene as sc
from nanosim.viewer import waveforms as wf
from nanosim.viewer.exaggerate import (LINK_LENGTH_M, Exaggerator, closure_error, exaggerate_q,
                                       static_deflection_q, table_displacement_m)


# ---------------------------------------------------------------- scene
def test_geom_specs_cover_model_in_mm(model):
    from nanosim.plant.geometry import CALIBRATED_GEOMETRY as G
    specs = sc.geom_specs(model)
    assert len(specs) == model.ngeom            # every geom of the stage is drawable
    by = {s.name: s for s in specs}
    plate = by["base_plate"]
    assert plate.kind == "cylinder"
    np.testing.assert_allclose(plate.dims_mm[:2], [45.0, 4.0])           # r 45 mm, 4 mm thick
    side = G.table.target_side_m * 1000
    np.testing.assert_allclose(by["target_cube"].dims_mm, [side] * 3, rtol=1e-5)
    np.testing.assert_allclose(by["a_apa_end"].pos_mm, model.geom("a_apa_end").pos * 1000)
    crank = by["a_crank"]                         # links are boxes with their real cross-section
    assert crank.kind == "box"
    np.testing.assert_allclose(np.sort(crank.dims_mm), np.sort([G.chain.fb1_rocker.thickness_m * 1000,
                                                                G.chain.fb1_rocker.width_m * 1000,
                                                                (G.chain.fb1_length_m - 2 * G.chain.fb1_notch.radius_m)
                                                                * 1000]), rtol=1e-5)
    table = by["table"]
    assert table.kind == "mesh" and table.faces.shape[1] == 3
    assert table.vertices_mm.dtype == np.float32
    kinds = {s.kind for s in specs}
    assert kinds == {"box", "cylinder", "mesh"}


def test_colours_tell_parts_apart(model):
    by = {s.name: s for s in sc.geom_specs(model)}
    groups = {"link": by["a_crank"], "table": by["table"], "target": by["target_cube"],
              "probe": by["probe_x"], "base": by["base_plate"]}
    for mat, spec in groups.items():
        assert spec.material == mat and spec.color == sc.MATERIAL_COLORS[mat]
    colours = {s.color for s in groups.values()} | {sc.HINGE_COLOR, sc.TENDON_COLOR}
    assert len(colours) == len(groups) + 2


def test_hinges_and_piezo_tendons(model):
    from nanosim.plant.geometry import CALIBRATED_GEOMETRY as G
    hinges = sc.hinge_specs(model)
    assert len(hinges) == 36                   # every notch of the part: 12 per chain, drawn at its size
    for h in hinges:                           # marker cylinder axis = the notch's bending axis
        z = np.zeros(9)
        mujoco.mju_quat2Mat(z, h.wxyz)
        if h.joint >= 0 and h.name.replace("_notch", "_bend") == model.joint(h.joint).name:
            np.testing.assert_allclose(np.abs(z.reshape(3, 3)[:, 2] @ model.jnt_axis[h.joint]), 1.0, atol=1e-6)
    h1 = next(h for h in hinges if h.name == "a_h1_notch")
    notch = G.notch("a_h1")
    np.testing.assert_allclose([h1.radius_mm, h1.length_mm], [notch.radius_m * 1000, notch.width_m * 1000],
                               rtol=1e-5)
    tendons = sc.tendon_specs(model)
    assert [t.name for t in tendons] == ["a_piezo", "b_piezo", "c_piezo"]
    data = mujoco.MjData(model)
    mujoco.mj_forward(model, data)
    segs = sc.tendon_segments_mm(tendons, data.site_xpos)
    assert segs.shape == (3, 2, 3) and segs.dtype == np.float32
    length = np.linalg.norm(segs[:, 1] - segs[:, 0], axis=1)
    np.testing.assert_allclose(length, data.ten_length[[model.tendon(t.name).id for t in tendons]] * 1000, rtol=1e-5)


def test_capsule_mesh_extent():
    v, f = sc.capsule_mesh(1.2, 16.0)
    assert f.max() < len(v)
    np.testing.assert_allclose(v[:, 2].min(), -9.2, atol=1e-5)
    np.testing.assert_allclose(v[:, 2].max(), 9.2, atol=1e-5)
    np.testing.assert_allclose(np.hypot(v[:, 0], v[:, 1]).max(), 1.2, atol=1e-5)


# ---------------------------------------------------------------- exaggeration
def test_exaggerate_q_formula():
    np.testing.assert_allclose(exaggerate_q([1.0, 2.0], [0.5, 1.0], 10.0), [5.5, 11.0])


def test_closure_at_10000x_static_deflection(model):
    dq = static_deflection_q(model, np.array([volts_to_force_N(), 0.0, 0.0]))   # 1 controller volt on A
    assert 1e-6 < table_displacement_m(model, dq) < 50e-6                        # micrometre scale
    ex = Exaggerator(model)
    d = ex.pose_delta(dq, 1e4)
    err = closure_error(model, d.qpos)
    welds = [err["b_leg_closure"], err["c_leg_closure"]]
    assert max(welds) < 0.01 * LINK_LENGTH_M
    assert max(err.values()) < 0.01 * LINK_LENGTH_M
    # and the picture really moved by ~ the exaggerated amount
    home = Exaggerator(model).pose_delta(np.zeros(model.nv), 1.0).xpos.copy()
    assert np.abs(d.xpos - home).max() > 1e-3


def test_closure_at_10000x_mode_shape(model):
    ex = Exaggerator(model)
    for mode in modal_analysis(model).physical[:6]:
        dq = mode.shape_q * (1e-6 / table_displacement_m(model, mode.shape_q))   # a table point moves 1 um
        d = ex.pose_delta(dq, 1e4)
        assert max(closure_error(model, d.qpos).values()) < 0.01 * LINK_LENGTH_M, mode.freq_hz


def test_small_exaggeration_is_linear(model):
    from nanosim.plant.mechanics import mechanical_matrices
    dq = static_deflection_q(model, np.array([0.0, volts_to_force_N(), 0.0]))
    dq *= 1e-6 / np.linalg.norm(mechanical_matrices(model).table @ dq)           # table centre moves 1 um
    assert 1e-6 <= table_displacement_m(model, dq) < 1.1e-6                      # a face moves a little more
    ex = Exaggerator(model)
    site = model.site("table_center").id
    p0 = ex.pose_delta(np.zeros(model.nv), 1.0).site_xpos[site].copy()
    p10 = ex.pose_delta(dq, 10.0).site_xpos[site].copy()
    expected = 10 * mechanical_matrices(model).table @ dq                          # 10 um, linear
    np.testing.assert_allclose(np.linalg.norm(p10 - p0), 10e-6, rtol=1e-2)
    np.testing.assert_allclose(p10 - p0, expected, atol=1e-2 * 10e-6)


# ---------------------------------------------------------------- waveforms
def test_hold_and_step():
    w = wf.Waveform("hold", offset_um=(1.0, 2.0, 3.0))
    np.testing.assert_allclose(w(np.array([0.0, 5.0])), [[1, 2, 3], [1, 2, 3]])
    s = wf.Waveform("step", amplitude_um=4.0, freq_hz=0.0, t_step_s=0.5, direction=(0, 1, 0))
    np.testing.assert_allclose(s(np.array([0.2, 0.5, 3.0]))[:, 1], [0.0, 4.0, 4.0])
    sq = wf.step(np.array([0.1, 0.6, 1.1]), freq_hz=1.0)
    np.testing.assert_allclose(sq, [1.0, 0.0, 1.0])


def test_sine_and_triangle_analytic():
    t = np.linspace(0, 2, 401)
    w = wf.Waveform("sine", amplitude_um=3.0, freq_hz=2.5, direction=(0, 0, 1))
    np.testing.assert_allclose(w(t)[:, 2], 3.0 * np.sin(2 * np.pi * 2.5 * t), atol=1e-12)
    np.testing.assert_allclose(w(t)[:, :2], 0.0)
    tri = wf.triangle(np.array([0.0, 0.125, 0.25, 0.5, 0.75, 1.0]), 1.0)
    np.testing.assert_allclose(tri, [0.0, 0.5, 1.0, 0.0, -1.0, 0.0], atol=1e-12)


def test_contour_45_degrees():
    speed = 10.0
    period = wf.contour_period_s((20, 20), speed)
    np.testing.assert_allclose(period, 2 * np.hypot(20, 20) / speed)
    t = np.array([0.0, period / 4, period / 2, 3 * period / 4, period])
    p = wf.contour(t, (20, 20), speed)
    np.testing.assert_allclose(p, [[0, 0, 0], [10, 10, 0], [20, 20, 0], [10, 10, 0], [0, 0, 0]], atol=1e-9)
    tt = np.linspace(0, period, 1001)
    pp = wf.contour(tt, (20, 20), speed)
    np.testing.assert_allclose(pp[:, 0], pp[:, 1])                      # on the 45-degree line
    v = np.linalg.norm(np.diff(pp[:, :2], axis=0), axis=1) / np.diff(tt)
    inner = np.abs(tt[1:] - period / 2) > 2 * (tt[1] - tt[0])
    np.testing.assert_allclose(v[inner], speed, rtol=1e-6)               # constant speed
    with pytest.raises(ValueError):
        wf.contour(0.0, (20, 20), 0.0)
    with pytest.raises(ValueError):
        wf.Waveform("square")


# ---------------------------------------------------------------- CLI
def _args(*argv):
    p = argparse.ArgumentParser()
    add_view_arguments(p)
    return p.parse_args(list(argv))


def test_defaults():
    a = _args()
    assert (a.port, a.host, a.controller, a.mjcf, a.seconds) == (8080, "127.0.0.1", None, None, None)


def test_missing_controller(capsys, tmp_path):
    rc = run_view(_args("--controller", str(tmp_path / "nope.npz"), "--port", "1"))
    err = capsys.readouterr().err.strip().splitlines()
    assert rc != 0 and len(err) == 1 and "no such file" in err[0] and "nope.npz" in err[0]


def test_malformed_mjcf(capsys, tmp_path):
    bad = tmp_path / "bad.xml"
    bad.write_text("<mujoco><worldbody><body></mujoco>")
    rc = run_view(_args("--mjcf", str(bad)))
    err = capsys.readouterr().err.strip().splitlines()
    assert rc != 0 and len(err) == 1 and "not a valid MuJoCo model" in err[0]


def test_busy_port(capsys):
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        s.listen(1)
        port = s.getsockname()[1]
        assert not port_is_free("127.0.0.1", port)
        rc = run_view(_args("--port", str(port)))
    err = capsys.readouterr().err.strip().splitlines()
    assert rc != 0 and len(err) == 1 and f"port {port} is busy" in err[0]


def test_live_closed_loop_tracks_a_reference(tmp_path):
    """The viewer's physics thread runs the H-infinity loop (controller.npz) on the stage."""
    from nanosim.fileio import write_npz
    from nanosim.design import design_hinf, discretize_controller, reduce_model
    from nanosim.plant.linearize import linearize
    from nanosim.plant.stage import Stage, StageConfig
    from nanosim.viewer.sim import LiveSim, load_controller

    twin = linearize(Stage(config=StageConfig.ideal()))
    kd = discretize_controller(design_hinf(reduce_model(twin.sys_V, order=10).G_reduced).K, dt=1 / 4000).Kd
    path = write_npz(tmp_path / "controller.npz", Akd=kd.A, Bkd=kd.B, Ckd=kd.C, Dkd=kd.D, dt=1 / 4000)
    sim = LiveSim(controller=load_controller(path))
    assert sim.controller_on
    ref = np.array([2.0, -1.0, 0.5])
    y = np.array([sim.step(ref) for _ in range(1200)])
    np.testing.assert_allclose(y[-200:].mean(axis=0), ref, atol=0.01)      # within 10 nm after 0.25 s


def test_linear_physics_follows_mujoco():
    """The viewer's fast backend (MuJoCo's linearization) moves the mechanism like MuJoCo does."""
    from nanosim.viewer.sim import LiveSim

    sims = {ph: LiveSim(physics=ph) for ph in ("mujoco", "linear")}     # open loop, ideal electronics
    ref = np.array([3.0, -2.0, 1.0])
    out = {}
    for ph, sim in sims.items():
        y = np.array([sim.step(ref) for _ in range(400)])                # 0.1 s
        out[ph] = (y, sim.qpos)
    (y_mj, q_mj), (y_lin, q_lin) = out["mujoco"], out["linear"]
    from nanosim.plant.mechanics import home_data
    q0 = home_data(sims["mujoco"].model).qpos
    peak = np.abs(y_mj).max()
    np.testing.assert_allclose(y_lin, y_mj, atol=0.02 * peak)            # probes within 2 % of the stroke
    dq_mj, dq_lin = q_mj - q0, q_lin - q0
    np.testing.assert_allclose(dq_lin, dq_mj, atol=0.03 * np.abs(dq_mj).max())
    with pytest.raises(ValueError, match="physics"):
        LiveSim(physics="fast")
