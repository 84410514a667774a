"""The sampled stage: electromechanics on the MuJoCo plant and its linear twin."""
import control as ct
import numpy as np
import pytest
from numpy.testing import assert_allclose
from scipy.signal import max_len_seq

from nanosim import constants as C
from nanosim.plant.electronics import ElectronicsConfig
from nanosim.plant.modes import modal_analysis
from nanosim.plant.piezo import PiezoConfig, PiezoModel, loop_hysteresis_percent
from nanosim.plant.noise import stream_seed
from nanosim.plant.stage import Stage, StageConfig, run_open_loop_batch

PAPER_SIGMA_OPEN_NM = 11.4          # paper Sec. 5, Fig. 16


def test_twin_dc_gain_and_modes_equal_modal_analysis(ideal, twin):
    res = modal_analysis(ideal.model)
    assert_allclose(twin.dc_gain_um_per_V, res.static_gain_um_per_V, rtol=1e-6, atol=1e-9)
    wn = np.sort(np.abs(np.linalg.eigvals(twin.sys_V.A))) / (2 * np.pi)
    assert_allclose(wn[::2], [m.freq_hz for m in res.below(2500.0)], rtol=1e-3)   # the twin keeps modes < 2.5 kHz


def test_twin_step_response_matches_ideal_stage(ideal, twin):
    n = 800
    for act in range(3):
        ideal.reset()
        u = np.zeros((n, 3))
        u[:, act] = 0.05
        y0 = ideal.table_um.copy()
        y = ideal.run(u).sensor_um - y0
        t = np.arange(n + 1) * twin.dt_s
        ylin = ct.forced_response(twin.sysd_V, T=t, U=np.vstack([u, u[-1:]]).T).outputs.T[1:]
        err = np.abs(y - ylin * C.SENSOR_UM_PER_V).max()
        assert err < 0.02 * np.abs(y).max(), (act, err)


def test_twin_frequency_response_matches_ideal_stage(twin):
    """Periodic MLS excitation, third period: the FFT ratio is the stage's exact FRF.

    Two periods (2 s) let the transient of the least damped mode (zeta 0.003 at 175 Hz, time constant
    0.3 s) decay to 1e-3; after one period 4 % of it would remain at the resonance.
    """
    mls = 0.02 * (2.0 * max_len_seq(12)[0] - 1.0)   # 4095 samples
    period = len(mls)
    u = np.zeros((3, 3 * period, 3))
    for act in range(3):
        u[act, :, act] = np.tile(mls, 3)
    traces = run_open_loop_batch(u, seeds=[0, 1, 2], config=StageConfig.ideal())
    f = np.fft.rfftfreq(period, d=1 / C.CONTROL_RATE_HZ)
    band = (f > 1.0) & (f < 1000.0)
    z = np.exp(2j * np.pi * f[band] / C.CONTROL_RATE_HZ)
    for act, tr in enumerate(traces):
        y = tr.sensor_V[2 * period:]
        U = np.fft.rfft(u[act, 2 * period:, act])[band]
        H_stage = np.fft.rfft(y, axis=0)[band] / U[:, None]
        # trace row k is the reading at the end of the period of command k: one sample advance vs the
        # twin's y[k] = C x[k]; no sub-period lag (the probes are read after the period's last substep)
        H_twin = np.array([twin.sysd_V(zz)[:, act] for zz in z]) * z[:, None]
        peak = np.abs(H_twin).max()
        assert np.abs(H_stage - H_twin).max() < 0.02 * peak


def test_hysteresis_loop_on_actuator_a():
    """Paper Fig. 14: 0 -> 1.65 -> 0 V on A moves about (-10, +, +) um with 15 % output hysteresis."""
    st = Stage(seed=0, config=StageConfig(electronics=ElectronicsConfig.ideal(saturation=True)))
    n = 4000
    up = np.linspace(0, 1.65, n // 2)
    v = np.concatenate([up, up[::-1]])
    u = np.zeros((n, 3))
    u[:, 0] = v
    tr = st.run(u)
    d = tr.table_um - tr.table_um[0]
    travel = d[n // 2 - 1]
    assert travel[0] < -8.0 and travel[1] > 0 and travel[2] > 0
    assert_allclose(travel[0], -10.0, rtol=0.2)                          # paper: -10 um
    out_pct, in_pct = loop_hysteresis_percent(v, -d[:, 0])             # X moves negative
    assert 12.0 <= out_pct <= 18.0, out_pct
    assert 11.0 <= in_pct <= 17.0, in_pct


def test_creep_after_step_and_all_actuators_creep_mostly_in_z():
    """A smooth 2.5 V move, then a 10 s hold: drift continues the move; all three together drift in Z."""
    cfg = StageConfig(electronics=ElectronicsConfig.ideal(), piezo=PiezoConfig())
    n_ramp, n_hold = 200, 40000                                          # 50 ms ramp, 10 s hold
    ramp = 2.5 * 0.5 * (1 - np.cos(np.pi * np.arange(n_ramp) / n_ramp))
    prof = np.concatenate([ramp, np.full(n_hold, 2.5)])
    cmd = np.zeros((2, len(prof), 3))
    cmd[0, :, 0] = prof                                                  # actuator A only
    cmd[1] = prof[:, None]                                               # all three
    tr_a, tr_all = run_open_loop_batch(cmd, seeds=[0, 0], config=cfg)
    after = slice(n_ramp + 200, n_ramp + 600)                            # 50-150 ms after the move
    end = slice(-400, None)                                              # last 0.1 s
    # the piezo model's own prediction: the free-strain voltage of the profile (the hold is static for the
    # mechanics, so only creep moves the table after the ramp, in proportion to v_free)
    v_free = PiezoModel(PiezoConfig(), n_channels=1).run(C.AMPLIFIER_GAIN * prof[:, None])[:, 0]
    expected = v_free[end].mean() / v_free[after].mean() - 1.0
    for tr in (tr_a, tr_all):
        move = tr.table_um[after].mean(0) - tr.table_um[0]
        drift = tr.table_um[end].mean(0) - tr.table_um[after].mean(0)
        # every axis drifts by the same fraction of its move, in the move's direction (measured: within 0.3 %)
        assert_allclose(drift / move, expected, rtol=0.02)
    drift_all = tr_all.table_um[end].mean(0) - tr_all.table_um[after].mean(0)
    assert abs(drift_all[2]) > 5 * max(abs(drift_all[0]), abs(drift_all[1]))


def test_open_loop_noise_at_rest_matches_paper():
    """The one calibrated noise level (the legs' thermal drift), predicted on streams it was not fitted on.

    tools/fit_drift_level.py solved the level for the paper's 11.4 nm (rms over X and Y of 4 s after 0.3 s
    at rest) on the streams ``stream_seed(s, "fit_drift_level")``, s = 0-19. Held out here: s = 20-39
    (40 probe records), whose rms sigma must lie within 10 % of 11.4 nm.
    """
    traces = run_open_loop_batch(np.zeros((20, 17200, 3)),
                                 seeds=[stream_seed(s, "fit_drift_level") for s in range(20, 40)])
    var = np.array([(tr.sensor_um[1200:, :2] * 1e3).var(axis=0) for tr in traces])
    assert_allclose(np.sqrt(np.mean(var)), PAPER_SIGMA_OPEN_NM, rtol=0.10)


def test_adc_ramp_shows_1p5nm_steps():
    cfg = StageConfig(electronics=ElectronicsConfig.ideal(adc_quantization=True), piezo=PiezoConfig.linear())
    st = Stage(config=cfg)
    u = np.zeros((4000, 3))
    u[:, 2] = np.linspace(0, 0.003, 4000)                                # ~30 nm slow ramp
    y = st.run(u).sensor_um[:, 0] * 1e3
    steps = np.diff(np.unique(np.round(y, 6)))
    assert_allclose(steps, C.ADC_LSB_NM, rtol=1e-6)
    assert_allclose(C.ADC_LSB_NM, 1.526, rtol=1e-3)


def test_saturation_clips_and_flags():
    st = Stage(config=StageConfig(electronics=ElectronicsConfig.ideal(saturation=True), piezo=PiezoConfig.linear()))
    tr = st.run(np.array([[9.0, -3.0, 1.0]] * 4))
    assert_allclose(tr.piezo_V[-1], [150.0, -20.0, 20.0])
    assert tr.saturated[-1].tolist() == [True, True, False]


def test_same_seed_bit_identical_and_different_seed_differs():
    u = np.random.default_rng(5).uniform(0, 1, size=(300, 3))
    a = Stage(seed=3).run(u)
    b = Stage(seed=3).run(u)
    c = Stage(seed=4).run(u)
    for k, v in a.as_arrays().items():
        assert np.array_equal(v, getattr(b, k)), k
    assert not np.array_equal(a.sensor_V, c.sensor_V)


def test_step_and_run_agree_exactly():
    u = np.random.default_rng(1).uniform(0, 0.5, size=(60, 3))
    s1, s2 = Stage(seed=2), Stage(seed=2)
    ys = np.array([s1.step(ui) for ui in u])
    assert np.array_equal(ys, s2.run(u).sensor_V)


@pytest.mark.parametrize("bad, match", [(np.zeros(2), "shape"), (np.array([0.0, np.nan, 0.0]), "NaN"),
                                        (np.array([np.inf, 0, 0]), "NaN/inf")])
def test_bad_commands_raise_before_simulating(bad, match):
    st = Stage(config=StageConfig.ideal())
    with pytest.raises(ValueError, match="u_V") as err:
        st.step(bad)
    assert match.split("/")[0] in str(err.value)
    assert st.time_s == 0.0
    with pytest.raises(ValueError, match="u_V"):
        st.run(np.zeros((5, 2)))


# --- stage v2: computation delay, floor vibration, noise budget ------------------------------------

def test_computation_delay_shifts_the_mujoco_response_by_one_sample(model):
    """Same command, delay 1 vs 0 (everything else off): the response is the same, one period later."""
    from dataclasses import replace
    base = StageConfig.ideal()
    u = np.zeros((200, 3))
    u[20:, 0] = 0.2
    y0 = Stage(config=base, model=model).run(u).table_um
    y1 = Stage(config=replace(base, electronics=ElectronicsConfig.ideal(computation_delay_samples=1)),
               model=model).run(u).table_um
    assert_allclose(y1[1:], y0[:-1], rtol=0, atol=1e-9)


def test_floor_model_statics_match_mujoco_under_a_body_force(model):
    """Base acceleration a is an inertial load -m a at every body's centre of mass: MuJoCo agrees statically."""
    import mujoco
    from nanosim.plant.floor import floor_model
    from nanosim.plant.mechanics import home_data
    from nanosim.plant.mjcf import probe_layout
    fm = floor_model(model)
    adr, bias = probe_layout(model)
    for axis in range(3):
        out = []
        for da in (0.0, 2.0):                 # 2 m/s^2 of base acceleration along the axis
            d = home_data(model)
            d.xfrc_applied[:, :3] = 0.0
            d.xfrc_applied[1:, axis] = -da * model.body_mass[1:]
            for _ in range(40):               # settle, 2 s
                mujoco.mj_step(model, d, int(round(0.05 / model.opt.timestep)))
            out.append((d.sensordata[adr] + bias) * 1e6)
        static = (out[1] - out[0]) / 2.0
        assert_allclose(static, fm.static_um_per_m_s2[:, axis], rtol=0.03,
                        atol=0.03 * np.abs(fm.static_um_per_m_s2).max())


def test_floor_vibration_sigma_matches_its_spectrum(model):
    """Sampled relative motion vs the integral of |H|^2 S_a over the Nyquist band (white, ZOH) within 8 %."""
    from nanosim.plant.floor import FloorConfig, FloorVibration, floor_model
    fm = floor_model(model)
    S = 3e-11
    d = FloorVibration(fm, FloorConfig(accel_psd_m2_s4_Hz=S), seed=3).run(120_000)[20_000:]
    f = np.linspace(0.05, 2000.0, 200_001)
    z = np.exp(2j * np.pi * f * fm.dt_s)
    n = fm.Ad.shape[0]
    var = np.zeros(3)
    for k, zk in enumerate(z):
        H = zk * fm.Cd @ np.linalg.solve(zk * np.eye(n) - fm.Ad, fm.Bd)      # (3, 3): um per m/s^2
        var += (np.abs(H) ** 2).sum(axis=1)
    var *= S * (f[1] - f[0])
    assert_allclose(d.std(axis=0), np.sqrt(var), rtol=0.08)


def test_vc_floor_psd_is_its_stated_basis():
    """VC-C (12.5 um/s per 1/3 octave) through a 0.01 plateau: the default 3e-11 at ~11 Hz, 4.7e-10 and
    6.5e-10 (m/s^2)^2/Hz at the 175 and 245 Hz modes (mjcf/SOURCES.md item 9); a flat velocity per
    proportional band is an acceleration PSD rising as f."""
    from nanosim.plant.floor import vc_accel_psd
    band_Hz = 175.0 * 2 ** (1 / 6) - 175.0 / 2 ** (1 / 6)            # the 1/3-octave band's edges
    assert_allclose(vc_accel_psd(175.0), (2 * np.pi * 175.0 * 12.5e-6 * 0.01) ** 2 / band_Hz, rtol=1e-12)
    assert_allclose([vc_accel_psd(175.0), vc_accel_psd(245.0)], [4.7e-10, 6.5e-10], rtol=0.01)
    assert_allclose(vc_accel_psd(11.0), C.FLOOR_ACCEL_PSD_M2_S4_HZ, rtol=0.03)
    assert_allclose(vc_accel_psd(1000.0) / vc_accel_psd(10.0), 100.0, rtol=1e-12)
    assert_allclose(vc_accel_psd(175.0, velocity_um_s=25.0), 4 * vc_accel_psd(175.0), rtol=1e-12)   # VC-B
    with pytest.raises(ValueError, match="transmissibility: expected a finite value > 0, got -1"):
        vc_accel_psd(175.0, transmissibility=-1.0)


def test_twin_and_mujoco_stage_share_the_floor_series(model, twin):
    from nanosim.plant.floor import floor_model
    from nanosim.plant.twin import TwinStage
    cfg = StageConfig(electronics=ElectronicsConfig.ideal(), piezo=PiezoConfig.linear())
    a = Stage(seed=5, config=cfg, model=model)
    home = a.table_um.copy()
    ta = a.run(np.zeros((400, 3))).table_um - home
    tb = TwinStage(twin, seed=5, config=cfg, home_um=home, floor_model=floor_model(model)).run(np.zeros((400, 3)))
    assert_allclose(tb.table_um - home, ta, rtol=0, atol=1e-9)
    assert np.abs(ta).max() > 1e-4                                       # the floor moves the table


def test_noise_budget_adds_up_on_the_twin(model, twin):
    """One source at a time: the variances add up to the all-sources variance (linear plant)."""
    from nanosim.experiments.loop import run_closed_loop
    from nanosim.experiments.resolution import RESOLUTION_PROTOCOL, noise_budget, noise_sources
    from nanosim.plant.floor import floor_model
    from nanosim.plant.twin import TwinStage
    from nanosim.design.controller import ControllerConfig, DiscreteController
    cfg = StageConfig(piezo=PiezoConfig.linear())
    assert set(noise_sources(cfg)) == {"DAC electronics", "DAC quantization", "amplifier", "thermal drift",
                                       "floor vibration", "gauge", "ADC quantization"}
    # the loop opened (K = 0): the sources add up exactly in variance, up to their finite-record cross terms
    K = DiscreteController(ControllerConfig(Akd=np.zeros((1, 1)), Bkd=np.zeros((1, 3)), Ckd=np.zeros((3, 1)),
                                            Dkd=np.zeros((3, 3)), dt=1 / 4000))
    st = TwinStage(twin, seed=2, config=cfg, home_um=Stage(model=model).table_um, floor_model=floor_model(model))
    rows = noise_budget(st, K, seed=2, duration_s=3.0, open_loop=False)
    total = run_closed_loop(st.variant(cfg, 2), K, np.zeros((12000, 3)),
                            protocol=RESOLUTION_PROTOCOL).y_um[:, 0].std() * 1e3
    assert_allclose(np.sqrt(sum(r["sensor_nm"] ** 2 for r in rows.values())), total, rtol=0.05)
    assert_allclose(sum(r["sensor_share"] for r in rows.values()), 1.0, rtol=1e-12)
