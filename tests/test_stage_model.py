"""The stage v2 MJCF against the paper's targets, its own geometry, and MuJoCo's own dynamics."""
from pathlib import Path

import mujoco
import numpy as np
import pytest
from numpy.testing import assert_allclose
from scipy.optimize import linprog

from nanosim import constants as C
from nanosim import paper as P
from nanosim.plant.build import BuildOptions, LEVEL_NUMERICS, Numerics, build_spec, stage_xml
from nanosim.plant.calibrate import calibration_params, fit_damping, get_param, summarize
from nanosim.plant.geometry import CALIBRATED_GEOMETRY, DEFAULT_GEOMETRY, chain_points
from nanosim.plant.hinges import notch_stiffness
from nanosim.plant.mechanics import mechanical_matrices, reduced_modes
from nanosim.plant.mjcf import DEFAULT_MJCF, load_model
from nanosim.plant.modes import (constraint_violation_ratio, linearize_fd, modal_analysis, table_rotation_urad,
                                 volts_to_force_N)

MJCF_DIR = Path(__file__).resolve().parent.parent / "nanosim" / "mjcf"
FULL_MJCF = MJCF_DIR / "full" / "scene.xml"


def six(result) -> np.ndarray:
    return np.array([m.freq_hz for m in result.below(1000.0)])


@pytest.fixture(scope="module")
def modal(model):
    return modal_analysis(model)


@pytest.fixture(scope="module")
def full_model():
    return load_model(FULL_MJCF)


@pytest.fixture(scope="module")
def full_modal(full_model):
    return modal_analysis(full_model)


@pytest.mark.parametrize("path", sorted(MJCF_DIR.glob("*.xml")), ids=lambda p: p.name)
def test_every_mjcf_compiles_and_steps_without_warning(path):
    m = mujoco.MjModel.from_xml_path(str(path))
    d = mujoco.MjData(m)
    mujoco.mj_resetDataKeyframe(m, d, 0)
    rng = np.random.default_rng(0)
    n_sub = int(round(C.CONTROL_PERIOD_S / m.opt.timestep))
    for _ in range(int(C.CONTROL_RATE_HZ * 1.0)):          # 1 s of random commands
        d.ctrl[:] = rng.uniform(*C.COMMAND_RANGE_V, size=3) * volts_to_force_N()
        mujoco.mj_step(m, d, n_sub)
    assert all(w.number == 0 for w in d.warning), [w.number for w in d.warning]
    assert np.all(np.isfinite(d.qpos))


def test_full_model_steps_without_warning(full_model):
    d = mujoco.MjData(full_model)
    mujoco.mj_resetDataKeyframe(full_model, d, 0)
    d.ctrl[:] = 7.5 * volts_to_force_N()
    mujoco.mj_step(full_model, d, 4000)                      # 20 ms of full-stroke push at its 5 us step
    assert all(w.number == 0 for w in d.warning)
    assert np.all(np.isfinite(d.qpos))


def test_bundled_mjcf_is_the_generator_output():
    # the shipped XML is build.write_bundled(CALIBRATED_GEOMETRY): regenerate it rather than hand-edit
    assert (MJCF_DIR / "pkxyz_stage.xml").read_text() == stage_xml(CALIBRATED_GEOMETRY, BuildOptions(level="reduced"))
    assert (MJCF_DIR / "full" / "pkxyz_stage.xml").read_text() == stage_xml(CALIBRATED_GEOMETRY,
                                                                             BuildOptions(level="full"))


def test_static_gain_is_3um_per_volt_times_J(modal):
    target = C.STATIC_GAIN_SCALE_UM_PER_V * C.JACOBIAN_J
    err = np.abs(modal.static_gain_um_per_V - target).max() / np.abs(target).max()
    assert err <= 0.05, (modal.static_gain_um_per_V, err)
    assert np.all(np.sign(modal.static_gain_um_per_V) == np.sign(target))


def test_modes_match_paper_with_axes_split_and_damping(modal):
    phys = modal.below(1000.0)
    assert len(phys) == 6, [m.freq_hz for m in phys]
    # the stage the paper's procedure implies: its Tustin-warped modes and damping, unwarped
    for mode, f, axis, zeta in zip(phys, P.STAGE_MODES_HZ, P.PAPER_MODE_AXES, P.STAGE_MODE_DAMPING_MEAN):
        assert_allclose(mode.freq_hz, f, rtol=0.01)
        assert (mode.axis == "Z") == (axis == "Z"), (mode.freq_hz, mode.axis)
        assert 0.5 * zeta <= mode.damping_ratio <= 1.5 * zeta, (mode.freq_hz, mode.damping_ratio, zeta)
    for lo, hi in ((0, 1), (3, 4)):                          # XY pairs split 1-4 %
        split = phys[hi].freq_hz / phys[lo].freq_hz - 1
        assert 0.01 <= split <= 0.04, split


def test_fd_modes_agree_with_exact_closures(model, modal):
    f_exact, _, _ = reduced_modes(mechanical_matrices(model))
    assert_allclose(six(modal), f_exact[:6], rtol=2e-3)


@pytest.mark.parametrize("factor", [0.5, 2.0])
def test_numerics_do_not_shape_the_physics(modal, factor):
    # timestep and closure softness (solref time constant) scaled together: modes move < 0.5 %
    num = LEVEL_NUMERICS["reduced"]
    m = build_spec(CALIBRATED_GEOMETRY, BuildOptions(numerics=Numerics(
        timestep_s=num.timestep_s * factor if factor < 1 else num.timestep_s,
        closure_timeconst_s=num.closure_timeconst_s * factor))).compile()
    assert_allclose(six(modal_analysis(m)), six(modal), rtol=5e-3)


@pytest.mark.parametrize("chain", ["b", "c"])
def test_chain_that_closes_the_tree_does_not_shape_the_physics(modal, chain):
    m = build_spec(CALIBRATED_GEOMETRY, BuildOptions(tree_chain=chain)).compile()
    assert_allclose(six(modal_analysis(m)), six(modal), rtol=5e-3)


def test_full_and_reduced_models_agree_below_1kHz(modal, full_modal):
    assert_allclose(six(full_modal), six(modal), rtol=0.01)
    assert_allclose(full_modal.static_gain_um_per_V, modal.static_gain_um_per_V, rtol=0.01, atol=0.02)


def test_full_model_modes_do_not_depend_on_the_jacobian_form(full_model, full_modal):
    # the full model (nv = 111) solves its closures with MuJoCo's sparse Jacobian, which 4.0.0 factors wrongly
    # in some trees (google-deepmind/mujoco#3767); the dense solve must give the same physics
    assert mujoco.mj_isSparse(full_model)
    dense = load_model(FULL_MJCF)
    dense.opt.jacobian = mujoco.mjtJacobian.mjJAC_DENSE
    assert not mujoco.mj_isSparse(dense)
    dense_modal = modal_analysis(dense)
    f = np.array([m.freq_hz for m in full_modal.modes if not m.is_constraint][:12])
    f_dense = np.array([m.freq_hz for m in dense_modal.modes if not m.is_constraint][:12])
    assert_allclose(f, f_dense, rtol=1e-6)
    assert_allclose(full_modal.static_gain_um_per_V, dense_modal.static_gain_um_per_V, rtol=0, atol=1e-4)


def test_parasitic_modes_lie_above_1kHz_and_are_reported_to_3kHz(full_modal):
    below = [m for m in full_modal.physical if m.freq_hz < 1000.0]
    assert len(below) == 6
    upto3k = [m for m in full_modal.physical if m.freq_hz < 3000.0]
    assert len(upto3k) > 6                                   # tilt/twist of links, leg torsion...
    for m in upto3k:
        assert_allclose(sum(m.kinetic_energy_share.values()), 1.0, rtol=1e-9)


def test_table_rotates_at_full_stroke_through_parasitic_compliance(model, full_model):
    rot = table_rotation_urad(model)
    rot_full = table_rotation_urad(full_model)
    for ax in "XYZ":
        r = np.linalg.norm(rot[ax])
        assert 1.0 < r < 1000.0, (ax, rot[ax])              # ideal 1-DOF hinges would give exactly 0
        assert_allclose(np.linalg.norm(rot_full[ax]), r, rtol=0.05)


def test_masses_follow_from_the_geometry(model):
    g = CALIBRATED_GEOMETRY
    rho = g.material.density_kg_per_m3
    c, t = g.chain, g.table
    foot = rho * c.foot.width_m * c.foot.thickness_m * (c.fb1_spacing_m + c.fb1_rocker.thickness_m + 2 *
                                                        c.foot_overhang_m)
    assert_allclose(model.body("a_foot").mass, foot, rtol=1e-5)      # tree chain: whole foot
    assert_allclose(model.body("b_foot").mass + model.body("b_foot_h1").mass, foot, rtol=1e-5)
    crank = rho * c.fb1_rocker.width_m * c.fb1_rocker.thickness_m * (c.fb1_length_m - 2 * c.fb1_notch.radius_m)
    assert_allclose(model.body("a_crank").mass, crank, rtol=1e-5)
    cube = t.target_density_kg_per_m3 * t.target_side_m ** 3
    mount = rho * np.pi * (t.mount_diameter_m / 2) ** 2 * t.mount_height_m
    assert model.body("table").mass > cube + mount
    assert_allclose(model.body("a_apa_end").mass, g.actuator.moving_fraction * g.actuator.mass_kg, rtol=1e-5)


def test_hinge_joints_carry_the_notch_formulas(model, full_model):
    g = CALIBRATED_GEOMETRY
    k = {n: notch_stiffness(g.material, g.notch(n)) for n in ("a_h1", "b_h2", "c_rocker_p_base", "a_crank_top")}
    assert_allclose(model.joint("a_h1_oop").stiffness, k["a_h1"].out_of_plane_Nm_per_rad, rtol=1e-5)
    assert_allclose(model.joint("b_h2_tor").stiffness, k["b_h2"].torsion_Nm_per_rad, rtol=1e-5)
    assert_allclose(model.joint("c_rocker_p_base_bend").stiffness, k["c_rocker_p_base"].bending_Nm_per_rad,
                    rtol=1e-5)
    assert_allclose(full_model.joint("a_crank_top_tor").stiffness, k["a_crank_top"].torsion_Nm_per_rad, rtol=1e-5)
    # the APA's two notches ride on the crank joint with the two-pin link's angle ratios
    p = chain_points(g)
    d_over_L = (p["apa_crank"][0] - p["crank_base"][0]) / np.linalg.norm(p["apa_base"] - p["apa_crank"])
    ks = {n: notch_stiffness(g.material, g.notch(n)).bending_Nm_per_rad for n in ("a_crank_base", "a_apa_crank",
                                                                                   "a_apa_base")}
    lumped = ks["a_crank_base"] + ks["a_apa_crank"] * (1 + d_over_L) ** 2 + ks["a_apa_base"] * d_over_L ** 2
    assert_allclose(model.joint("a_crank_base_bend").stiffness, lumped, rtol=1e-5)
    assert_allclose(model.tendon_stiffness[model.tendon("a_piezo").id],
                    C.PIEZO_BLOCKING_FORCE_N / C.PIEZO_FREE_STROKE_M, rtol=1e-5)


def test_calibration_stays_inside_its_stated_bounds():
    for p in calibration_params(DEFAULT_GEOMETRY):
        v = get_param(CALIBRATED_GEOMETRY, p.path)
        assert p.lo - 1e-12 <= v <= p.hi + 1e-12, (p.path, v, p.lo, p.hi)
    for name, dt in CALIBRATED_GEOMETRY.thickness_deviation_m:
        assert abs(dt) <= 10e-6 + 1e-12, name


def test_damping_comes_from_two_sources_fitted_to_appendix_A(modal):
    fit = fit_damping(CALIBRATED_GEOMETRY)
    opt = BuildOptions().damping
    assert_allclose([fit.hinge_loss_factor, fit.piezo_loss_factor],
                    [opt.hinge_loss_factor, opt.piezo_loss_factor], rtol=0.02)
    assert np.all(np.abs(fit.zeta / fit.target - 1) < 0.5)
    assert_allclose(fit.zeta, [m.damping_ratio for m in modal.below(1000.0)], rtol=0.02)


def test_symmetric_design_has_degenerate_pairs():
    s = summarize(DEFAULT_GEOMETRY)
    ixy, _ = s.observed()
    f = s.freq_hz[ixy]
    assert_allclose(f[1], f[0], rtol=1e-6)
    assert_allclose(f[3], f[2], rtol=1e-6)


def test_closure_violation_under_half_percent(model):
    assert constraint_violation_ratio(model) < 0.005


def travel_um(G) -> np.ndarray:
    """Travel per axis within the command range and the gauges' +/-50 um (Z gauge zeroed 25 um up)."""
    offset_um = np.array([0.0, 0.0, 25.0])
    A_ub = np.vstack([G, -G])
    b_ub = np.concatenate([C.SENSOR_RANGE_UM + offset_um, C.SENSOR_RANGE_UM - offset_um])
    out = []
    for axis in range(3):
        ext = []
        for sgn in (1, -1):
            r = linprog(-sgn * G[axis], A_ub=A_ub, b_ub=b_ub, bounds=[C.COMMAND_RANGE_V] * 3)
            assert r.success
            ext.append(G[axis] @ r.x)
        out.append(ext[0] - ext[1])
    return np.array(out)


def test_travel_is_the_papers_gain_travel(modal):
    # 3.0 um/V x J over -1..7.5 V: 100 um in X and Y (gauge-limited), 75.7 um in Z (3 x 8.5 V x 2.97 um/V)
    target = travel_um(C.STATIC_GAIN_SCALE_UM_PER_V * C.JACOBIAN_J)
    assert np.all(travel_um(modal.static_gain_um_per_V) >= 0.95 * target), (travel_um(modal.static_gain_um_per_V),
                                                                             target)


def test_linearization_matches_small_amplitude_nonlinear_steps(model):
    A, B = linearize_fd(model)
    mm = mechanical_matrices(model)
    nv, n_sub, n = model.nv, int(round(C.CONTROL_PERIOD_S / model.opt.timestep)), 240
    Cx = np.hstack([mm.probe, np.zeros((3, nv))])
    force = 0.05 * volts_to_force_N()                        # 0.05 controller V step
    adr = [model.sensor_adr[model.sensor(f"probe_{a}").id] + i for i, a in enumerate("xyz")]
    for act in range(3):
        d = mujoco.MjData(model)
        mujoco.mj_resetDataKeyframe(model, d, 0)
        mujoco.mj_forward(model, d)
        p0 = d.sensordata[adr].copy()
        x = np.zeros(2 * nv)
        y_nl, y_lin = [], []
        for _ in range(n):
            d.ctrl[:] = 0
            d.ctrl[act] = force
            mujoco.mj_step(model, d, n_sub)
            y_nl.append(d.sensordata[adr] - p0)
            for _ in range(n_sub):
                x = A @ x + B[:, act] * force
            y_lin.append(Cx @ x)
        y_nl, y_lin = np.array(y_nl), np.array(y_lin)
        assert np.abs(y_nl - y_lin).max() < 0.02 * np.abs(y_nl).max()


def test_lowest_closure_mode_reported(modal):
    assert modal.lowest_constraint_hz > C.CONTROL_RATE_HZ / 2


def test_missing_file_has_clear_error():
    with pytest.raises(FileNotFoundError, match="no such file"):
        load_model("/nonexistent/stage.xml")


def test_malformed_xml_has_clear_error(tmp_path):
    bad = tmp_path / "bad.xml"
    bad.write_text("<mujoco><worldbody><body>")
    with pytest.raises(ValueError, match="not a valid MuJoCo model"):
        load_model(bad)


def test_model_without_stage_parts_is_rejected(tmp_path):
    plain = tmp_path / "plain.xml"
    plain.write_text("<mujoco><worldbody><body><joint/><geom size='0.01'/></body></worldbody></mujoco>")
    with pytest.raises(ValueError, match="lacks the stage's actuators"):
        load_model(plain)


def test_stiffness_override_moves_modes_as_sqrt():
    base = modal_analysis(load_model()).below(1000.0)[0].freq_hz
    # the simulation model carries the APA notches on the crank joints (family fb1)
    scale = {fam: 1.2 for fam in ("fb1", "fb2", "swing")} | {f"{c}_piezo": 1.2 for c in "abc"}
    stiff = modal_analysis(load_model(stiffness_scale=scale)).below(1000.0)[0].freq_hz
    assert_allclose(stiff / base, np.sqrt(1.2), rtol=0.01)   # all springs x1.2 -> f x sqrt(1.2)


def test_bad_override_names_the_problem():
    with pytest.raises(ValueError, match="stiffness_scale"):
        load_model(stiffness_scale={"no_such_family": 2.0})
    with pytest.raises(ValueError, match="body_mass_kg"):
        load_model(body_mass_kg={"table": -1.0})


def test_default_mjcf_is_bundled():
    assert DEFAULT_MJCF.is_file()
    assert FULL_MJCF.is_file()
