"""Closed-loop experiment machinery: metrics on analytic signals, twin vs MuJoCo."""
from dataclasses import replace

import numpy as np
import pytest
from numpy.testing import assert_allclose

from nanosim.design.lti import crossing_hz
from nanosim.experiments.contouring import (CONDITIONING_S, conditioning_cycles, contour_error_nm, contour_reference,
                                            contouring, ramp_lags_ms)
from nanosim.experiments.loop import run_closed_loop, step_metrics
from nanosim.experiments.small_steps import small_steps
from nanosim.plant.twin import TwinStage
from nanosim.design.controller import DiscreteController
from nanosim.plant.linearize import linearize
from nanosim.plant.piezo import PiezoConfig
from nanosim.plant.stage import Stage, StageConfig


def test_step_metrics_of_a_second_order_response():
    # y = 1 - exp(-z w t)(cos(wd t) + z/sqrt(1-z^2) sin(wd t)); overshoot = exp(-pi z / sqrt(1 - z^2))
    zeta, wn = 0.5, 2 * np.pi * 50
    wd = wn * np.sqrt(1 - zeta**2)
    t = np.arange(0, 0.2, 1 / 4000)
    y = 1 - np.exp(-zeta * wn * t) * (np.cos(wd * t) + zeta / np.sqrt(1 - zeta**2) * np.sin(wd * t))
    rise, peak, settle, over = step_metrics(t, y, 1.0)
    assert_allclose(over, 100 * np.exp(-np.pi * zeta / np.sqrt(1 - zeta**2)), rtol=0.01)
    assert_allclose(peak, 1e3 * np.pi / wd, atol=0.25)
    assert_allclose(settle, 1e3 * 4 / (zeta * wn), rtol=0.25)      # 2 % settling ~ 4 / (zeta wn)


def test_unsettled_step_reports_infinity():
    t = np.arange(0, 0.05, 1 / 4000)
    y = 1 + 0.1 * np.sin(2 * np.pi * 176 * t)
    assert step_metrics(t, y, 1.0)[2] == float("inf")


def test_first_crossing_of_first_order_sensitivity():
    f = np.logspace(0, 3, 2000)
    fb = 30.0
    sS = np.abs(1j * f / fb / (1 + 1j * f / fb))              # S = s / (s + wb): -3 dB at fb
    assert_allclose(crossing_hz(f, sS, 1 / np.sqrt(2), rising=True), fb, rtol=2e-3)


def test_contour_reference_is_the_45_degree_line_at_the_given_speed():
    ref = contour_reference(100.0)
    assert_allclose(ref[:, 0], ref[:, 1])
    assert_allclose(ref[:, 0].max(), 20.0)
    v = np.hypot(np.diff(ref[:, 0]), np.diff(ref[:, 1])) * 4000
    assert_allclose(np.median(v[v > 0]), 100.0, rtol=0.01)


def test_contour_error_is_the_distance_to_the_45_degree_line():
    ref = contour_reference(1000.0)
    d_nm = 37.0
    normal = np.array([1.0, -1.0, 0.0]) / np.sqrt(2)             # unit normal of the line x = y
    along = np.array([1.0, 1.0, 0.0]) / np.sqrt(2)
    y = ref + 1e-3 * d_nm * normal + 0.8 * along                  # off the line by d, lagging along it
    d, moving = contour_error_nm(ref, y)
    assert_allclose(d, d_nm, rtol=1e-9)
    assert moving.sum() == np.count_nonzero((ref[:, 0] > 0.5) & (ref[:, 0] < 19.5))


def test_ramp_lags_of_delayed_axes_and_the_contour_error_they_give():
    """Axes delayed by 4.5 ms and 4.55 ms: lags 4.5 / 4.55 ms, and on the 1000 um/s line a distance to the
    path of (lag_x - lag_y) v / 2 = 25 nm while both move at constant speed."""
    ref = contour_reference(1000.0)
    fs = 4000.0

    def delayed(x, d_s):                             # x(t - d): exact delay, linear between samples
        t = np.arange(len(x)) / fs
        return np.interp(t - d_s, t, x, left=x[0])

    y = ref.copy()
    y[:, 0], y[:, 1] = delayed(ref[:, 0], 4.5e-3), delayed(ref[:, 1], 4.55e-3)
    d, moving = contour_error_nm(ref, y)
    lag_x, lag_y = ramp_lags_ms(ref, y, moving, fs)
    assert_allclose([lag_x, lag_y], [4.5, 4.55], rtol=2e-3)
    speed = np.hypot(*np.gradient(ref[:, :2], axis=0).T) * fs
    const = np.abs(speed - speed.max()) < 0.01 * speed.max()
    steady = const & np.roll(const, 20) & np.roll(const, -20)     # ramps whose delayed copies are ramps too
    dist_nm = np.abs(y[:, 0] - y[:, 1]) / np.sqrt(2) * 1e3
    assert steady.sum() > 100
    assert_allclose(dist_nm[steady], 0.05e-3 * 1000.0 / 2 * 1e3, rtol=0.02)


def test_conditioning_cycles_cover_the_conditioning_time():
    assert conditioning_cycles(0.1165) == 6                       # 1000 um/s: 6 x 0.1165 s >= 0.6 s
    assert conditioning_cycles(5.7) == 1                          # 10 um/s: at least one cycle
    assert conditioning_cycles(0.2, 0.6) == 3                     # exactly 0.6 s: no extra cycle
    assert conditioning_cycles(0.3, 0.0) == 1
    with pytest.raises(ValueError, match="cycle_s"):
        conditioning_cycles(0.0)
    with pytest.raises(ValueError, match="conditioning_s"):
        conditioning_cycles(0.1, -1.0)


@pytest.fixture(scope="module")
def simple_controller():
    """The paper's mixed-sensitivity design on the reduced linear twin (no identification needed)."""
    from nanosim.design import design_hinf, discretize_controller, reduce_model

    twin = linearize(Stage(config=StageConfig.ideal()))
    red = reduce_model(twin.sys_V, order=10)
    d = design_hinf(red.G_reduced, G_full=twin.sys_V)
    kd = discretize_controller(d.K, dt=1 / 4000).Kd
    return DiscreteController.from_matrices(kd.A, kd.B, kd.C, kd.D, 1 / 4000)


def test_twin_and_mujoco_closed_loops_agree(simple_controller):
    """The --twin flag runs the same code path; with effects off both plants track alike."""
    ref = np.zeros((400, 3))
    ref[40:, 0] = 1.0
    cfg = StageConfig.ideal()
    stage = Stage(config=cfg)
    lin = linearize(Stage(config=StageConfig.ideal()))
    twin = TwinStage(lin, config=cfg, home_um=stage.table_um)
    simple_controller.reset()
    a = run_closed_loop(stage, simple_controller, ref)
    simple_controller.reset()
    b = run_closed_loop(twin, simple_controller, ref)
    assert_allclose(a.y_um, b.y_um, atol=0.02 * 1.0)              # 2 % of the 1 um step
    assert_allclose(a.y_um[-50:, 0].mean(), 1.0, rtol=0.01)       # near-integral action: no offset


def test_small_steps_resolved_with_integral_action(simple_controller):
    fac = lambda s: Stage(seed=s, config=StageConfig.ideal())
    simple_controller.reset()
    r = small_steps(fac, simple_controller, n_steps=3, dwell_s=0.1)
    assert_allclose(r.plateau_mean_nm, r.targets_nm, atol=1.0)


def test_repeated_path_wipes_out_the_approach_memory_of_the_piezo(simple_controller, twin):
    """The record is a cycle of the repeated path: hysteresis memory of the approach gone, linear loop unchanged.

    On the first cycle after the approach from home, an actuator the hold had reversed rejoins its loading
    curve in mid-path, its gain jumps and the axes' lags part; a full cycle between the path's ends wipes that
    memory out. A linear, noise-free stage is periodic from the first cycle.
    """
    home = Stage(config=StageConfig.ideal()).table_um.copy()

    def run(config):
        fac = lambda s: TwinStage(twin, seed=s, config=config, home_um=home)
        return contouring(fac, simple_controller, seed=0, speeds_um_s=(1000.0,))[0]

    assert CONDITIONING_S == 0.6
    hyst = run(StageConfig())
    assert hyst.conditioning_cycles == 6
    assert hyst.first_cycle_mean_error_nm > 3.0 * hyst.mean_error_nm
    assert hyst.first_cycle_max_error_nm > 3.0 * hyst.max_error_nm
    lin = run(StageConfig.ideal())
    assert_allclose(lin.mean_error_nm, lin.first_cycle_mean_error_nm, atol=0.05)
    # the hysteretic stage's recorded cycle is within 4x of the linear loop's X/Y mismatch (no memory jump)
    assert hyst.mean_error_nm < 4.0 * run(replace(StageConfig(), piezo=PiezoConfig.linear())).mean_error_nm
