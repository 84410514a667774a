"""Tests of the DAC / amplifier / piezo actuator chain and the gauge / ADC sensor chain."""
from __future__ import annotations

import numpy as np
import pytest
from numpy.testing import assert_allclose, assert_array_equal

from nanosim import constants as C
from nanosim.plant.electronics import (ActuatorChain, ElectronicsConfig, SensorChain, child_seed,
                                 quantize)
from nanosim.plant.piezo import PiezoConfig, loop_hysteresis_percent

LSB_V = 20.0 / 2 ** 16


def quiet(**kw):
    """A 16-bit +/-10 V DAC and the default ADC and amplifier clipping, without noise, drift, delay or filters.

    (The computation delay, the amplifier and gauge bandwidths and every noise have their own tests
    below; these exact quantisation/saturation checks need them off.)
    """
    base = dict(dac_bits=16, dac_noise=False, sensor_noise=False, amplifier_noise=False, thermal_drift=False,
                computation_delay_samples=0, amplifier_bandwidth_Hz=None, gauge_bandwidth_Hz=None)
    base.update(kw)
    return ElectronicsConfig(**base)


# --- exact linear chain --------------------------------------------------------

def test_all_off_is_exactly_linear():
    rng = np.random.default_rng(0)
    u = rng.uniform(-5, 12, (1000, 3))          # includes out-of-range commands
    chain = ActuatorChain(ElectronicsConfig.ideal(), PiezoConfig.linear(), seed=1)
    out = chain.run(u)
    assert_array_equal(out.v_free_V, 20.0 * u)
    assert_array_equal(out.v_piezo_V, 20.0 * u)
    assert_array_equal(out.u_dac_V, u)
    assert not out.saturated.any()
    s = chain.step(u[0])
    assert_array_equal(s.v_free_V, 20.0 * u[0])

    d = rng.uniform(-80, 80, (1000, 3))
    sensor = SensorChain(ElectronicsConfig.ideal(), seed=1)
    r = sensor.run(d)
    assert_array_equal(r.reading_um, d)
    assert_array_equal(r.reading_V, d / 5.0)
    assert not r.clipped.any()


# --- DAC and amplifier -----------------------------------------------------------

def test_saturation_clips_and_flags():
    chain = ActuatorChain(quiet(), PiezoConfig.linear(), seed=0)
    s = chain.step([-2.0, 3.0, 9.0])
    assert_allclose(s.v_piezo_V, [-20.0, 60.0, 150.0], rtol=0, atol=20 * LSB_V)
    assert_array_equal(s.saturated, [True, False, True])
    s = chain.step([-0.9999, 7.5, 12.0])        # in range (7.5 V is a DAC code); 12 V also clips the DAC
    assert_array_equal(s.saturated, [False, False, True])
    assert_allclose(s.u_dac_V[2], 10.0 - LSB_V, rtol=0, atol=1e-15)
    assert_allclose(s.v_piezo_V[1:], [150.0, 150.0], rtol=0, atol=0)
    # -1.0 V is not a DAC code: it rounds to -3277 LSB = -1.00006 V, which the amplifier clips
    s = chain.step([-1.0, 0.0, 0.0])
    assert_array_equal(s.saturated, [True, False, False])
    assert s.v_piezo_V[0] == -20.0
    # DAC clipping flagged even with amplifier saturation off
    chain = ActuatorChain(quiet(saturation=False), PiezoConfig.linear(), seed=0)
    s = chain.step([12.0, -12.0, 9.0])
    assert_array_equal(s.saturated, [True, True, False])
    assert_allclose(s.v_piezo_V, 20 * np.array([10 - LSB_V, -10.0, 9.0]), rtol=0, atol=20 * LSB_V)


def test_dac_quantization():
    cfg = quiet()
    assert_allclose(cfg.dac_lsb_V, LSB_V, rtol=0, atol=0)
    chain = ActuatorChain(cfg, PiezoConfig.linear(), seed=0)
    u = np.random.default_rng(1).uniform(-1, 7.5, (5000, 3))
    out = chain.run(u)
    codes = out.u_dac_V / LSB_V
    assert_array_equal(codes, np.round(codes))
    assert np.max(np.abs(out.u_dac_V - u)) <= LSB_V / 2
    assert_array_equal(out.v_free_V, 20.0 * out.u_dac_V)
    values, overflow = quantize(np.array([0.4 * LSB_V, 0.6 * LSB_V, 11.0]), 16, 10.0)
    assert_allclose(values, [0.0, LSB_V, 10.0 - LSB_V], rtol=0, atol=0)
    assert_array_equal(overflow, [False, False, True])


def test_dac_noise_std_and_independence():
    sigma = 1e-3
    # the white part alone (the flicker part: test_dac_noise_spectrum_is_white_with_flicker_corner)
    cfg = ElectronicsConfig.ideal(dac_noise=True, dac_noise_V=sigma, dac_flicker_corner_Hz=None)
    chain = ActuatorChain(cfg, PiezoConfig.linear(), seed=5)
    n = 100_000
    out = chain.run(np.full((n, 3), 2.0))
    e = out.u_dac_V - 2.0
    # std of the sample std ~ sigma / sqrt(2n) = 0.22 %: 1.5 % is > 6 sigma
    assert_allclose(e.std(axis=0), sigma, rtol=0.015)
    assert_allclose(e.mean(axis=0), 0.0, atol=5 * sigma / np.sqrt(n))
    corr = np.corrcoef(e.T)
    assert np.max(np.abs(corr - np.eye(3))) < 0.02
    lag1 = np.mean(e[1:] * e[:-1]) / sigma ** 2
    assert abs(lag1) < 0.02                      # white


def test_default_chain_loop_hysteresis():
    """Full default chain (DAC quantisation, saturation, PI, creep; no noise), slow 1.65 V loop."""
    chain = ActuatorChain(quiet(), PiezoConfig(), seed=0)
    n = 20_000
    u = np.concatenate([np.linspace(0, 1.65, n + 1), np.linspace(1.65, 0, n + 1)[1:]])
    out = chain.run(np.repeat(u[:, None], 3, axis=1))
    out_pct, in_pct = loop_hysteresis_percent(out.v_piezo_V[:, 0], out.v_free_V[:, 0])
    assert_allclose(out_pct, 15.0, atol=3.0)
    assert_allclose(in_pct, 14.0, atol=3.0)
    assert not out.saturated.any()


# --- sensor -------------------------------------------------------------------

def test_adc_step_on_slow_ramp():
    cfg = quiet()
    assert_allclose(cfg.adc_lsb_V, LSB_V, rtol=0, atol=0)
    sensor = SensorChain(cfg, seed=0)
    d = np.linspace(0.0, 0.05, 20001)[:, None] * np.ones(3)   # 0 -> 50 nm
    r = sensor.run(d)
    levels_nm = np.unique(r.reading_um[:, 0]) * 1e3
    steps_nm = np.diff(levels_nm)
    assert_allclose(steps_nm, 1.52587890625, rtol=1e-9)          # 20/2**16 V x 5 um/V
    assert_allclose(levels_nm.size, 50 / 1.52587890625 + 1, atol=1)
    codes = r.reading_V / LSB_V
    assert_array_equal(codes, np.round(codes))
    assert np.max(np.abs(r.reading_um - d)) <= 5 * LSB_V / 2 + 1e-12


def test_sensor_clip_flags():
    sensor = SensorChain(quiet(), seed=0)
    r = sensor.step([-60.0, 0.0, 55.0])
    assert_array_equal(r.clipped, [True, False, True])
    assert_allclose(r.reading_um, [-50.0, 0.0, 50.0], rtol=0, atol=5 * LSB_V)
    r = sensor.run(np.array([[49.0, -49.0, 50.0]]))
    assert_array_equal(r.clipped, [[False, False, True]])    # +10 V is one LSB over the ADC range


@pytest.mark.parametrize("band_Hz, expected_nm", [(None, 0.3 * np.sqrt(2.0)), (1000.0, 0.3)])
def test_gauge_noise_std(band_Hz, expected_nm):
    cfg = ElectronicsConfig.ideal(sensor_noise=True, sensor_noise_band_Hz=band_Hz)
    assert_allclose(cfg.sensor_noise_std_nm, expected_nm, rtol=1e-12)
    sensor = SensorChain(cfg, seed=11)
    n = 100_000
    r = sensor.run(np.full((n, 3), 12.0))
    e_nm = (r.reading_um - 12.0) * 1e3
    assert_allclose(e_nm.std(axis=0), expected_nm, rtol=0.015)
    assert_allclose(e_nm.mean(axis=0), 0.0, atol=5 * expected_nm / np.sqrt(n))


def test_sensor_noise_with_adc_is_quantised():
    sensor = SensorChain(ElectronicsConfig(), seed=2)
    r = sensor.run(np.zeros((4000, 3)))
    codes = r.reading_V / LSB_V
    assert_array_equal(codes, np.round(codes))
    # 0.71 nm per sample (9.5 pm/sqrt(Hz) over the 5 kHz gauge filter's 5.6 kHz noise bandwidth)
    # vs a 1.53 nm LSB: |code| <= 2 is > 4.8 sigma
    assert set(np.unique(codes)) <= {-2.0, -1.0, 0.0, 1.0, 2.0}
    assert_allclose(ElectronicsConfig().sensor_noise_std_nm, 0.3 * np.sqrt(5000 * (np.pi / 4) / np.sin(np.pi / 4)
                                                                           / 1000), rtol=1e-12)


# --- determinism, seeds, step == run -------------------------------------------

def test_determinism_and_reset():
    u = np.random.default_rng(2).uniform(0, 3, (3000, 3))
    a = ActuatorChain(seed=42).run(u)
    b = ActuatorChain(seed=42).run(u)
    c = ActuatorChain(seed=43).run(u)
    for f in a._fields:
        assert_array_equal(getattr(a, f), getattr(b, f))
    assert not np.array_equal(a.u_dac_V, c.u_dac_V)
    chain = ActuatorChain(seed=42)
    chain.run(u)
    chain.reset()
    assert_array_equal(chain.run(u).v_free_V, a.v_free_V)

    d = np.random.default_rng(3).uniform(-10, 10, (3000, 3))
    s1 = SensorChain(seed=9).run(d)
    s2 = SensorChain(seed=9).run(d)
    assert_array_equal(s1.reading_V, s2.reading_V)
    sensor = SensorChain(seed=9)
    sensor.run(d)
    sensor.reset()
    assert_array_equal(sensor.run(d).reading_V, s1.reading_V)


def test_run_equals_repeated_step_bitwise():
    rng = np.random.default_rng(4)
    u = np.clip(np.cumsum(rng.normal(0, 0.05, (6000, 3)), axis=0), -2, 9)   # > 1 noise block, saturates
    a, b = ActuatorChain(seed=3), ActuatorChain(seed=3)
    ra = a.run(u)
    steps = [b.step(x) for x in u]
    for i, f in enumerate(ra._fields):
        assert_array_equal(getattr(ra, f), np.array([s[i] for s in steps]))
    assert ra.saturated.any()

    d = np.cumsum(rng.normal(0, 1.0, (6000, 3)), axis=0)
    sa, sb = SensorChain(seed=3), SensorChain(seed=3)
    r = sa.run(d)
    rs = [sb.step(x) for x in d]
    assert_array_equal(r.reading_V, np.array([x.reading_V for x in rs]))
    assert_array_equal(r.clipped, np.array([x.clipped for x in rs]))


@pytest.mark.parametrize("seed", [7, np.random.SeedSequence(7)], ids=["int", "SeedSequence"])
def test_same_master_seed_gives_independent_streams(seed):
    # |rho| of two independent records of 60000 samples: sd 0.004, so 0.03 is 7 sd
    cfg = ElectronicsConfig.ideal(dac_noise=True, sensor_noise=True)
    n = 20_000
    act = ActuatorChain(cfg, PiezoConfig.linear(), seed=seed).run(np.zeros((n, 3))).u_dac_V
    sen = SensorChain(cfg, seed=seed).run(np.zeros((n, 3))).reading_um
    rho = np.corrcoef(act.ravel(), sen.ravel())[0, 1]
    assert abs(rho) < 0.03
    with pytest.raises(ValueError, match="seed"):
        child_seed(-1, 0)


def test_child_seed_of_a_seed_sequence_is_its_spawned_child_without_advancing_it():
    ss = np.random.SeedSequence(123)
    kids = np.random.SeedSequence(123).spawn(3)
    for k in (2, 0, 1):
        assert_array_equal(child_seed(ss, k).generate_state(4), kids[k].generate_state(4))
    assert ss.n_children_spawned == 0


def test_stream_seeds_are_distinct_per_seed_purpose_and_index():
    # the defect this replaces: run seed s's second stream was seed s + 1's first
    from nanosim.plant.noise import stream_seed
    purposes = ("bandwidth", "creep", "hysteresis", "resolution", "identification", "identification.excitation")
    seeds = {(s, p, k): stream_seed(s, p, k) for s in range(50) for p in purposes for k in range(6)}
    assert len(set(seeds.values())) == len(seeds)
    assert all(0 <= v < 2 ** 63 for v in seeds.values())
    assert stream_seed(3, "creep", 1) == stream_seed(np.int64(3), "creep", np.int64(1))
    # a stage built from s's stream 1 and one from s + 1's stream 0 draw uncorrelated DAC noise
    cfg = ElectronicsConfig.ideal(dac_noise=True)
    n = 20_000
    a = ActuatorChain(cfg, PiezoConfig.linear(), seed=stream_seed(4, "creep", 1)).run(np.zeros((n, 3))).u_dac_V
    b = ActuatorChain(cfg, PiezoConfig.linear(), seed=stream_seed(5, "creep", 0)).run(np.zeros((n, 3))).u_dac_V
    assert abs(np.corrcoef(a.ravel(), b.ravel())[0, 1]) < 0.03


@pytest.mark.parametrize("args, name", [((-1, "x"), "seed"), ((1.5, "x"), "seed"), ((True, "x"), "seed"),
                                        ((0, ""), "purpose"), ((0, 3), "purpose"), ((0, "x", -1), "index")])
def test_stream_seed_rejects_bad_input(args, name):
    from nanosim.plant.noise import stream_seed
    with pytest.raises(ValueError, match=f"^{name}: expected"):
        stream_seed(*args)


# --- errors -------------------------------------------------------------------

@pytest.mark.parametrize("bad, msg", [
    ([0.0, 1.0], "expected shape"),
    ([[0.0, 1.0, 2.0]], "expected shape"),
    ([0.0, np.nan, 1.0], "NaN/inf"),
    ([0.0, np.inf, 1.0], "NaN/inf"),
    (["a", "b", "c"], "numeric"),
])
def test_actuator_bad_input_raises_before_state_change(bad, msg):
    chain, ref = ActuatorChain(seed=1), ActuatorChain(seed=1)
    chain.step([0.5, 0.5, 0.5])
    ref.step([0.5, 0.5, 0.5])
    with pytest.raises(ValueError, match="u_V") as err:
        chain.step(bad)
    assert msg in str(err.value)
    with pytest.raises(ValueError, match="u_V"):
        chain.run(np.array([[0.0, 1.0, np.nan]]))
    with pytest.raises(ValueError, match="u_V"):
        chain.run(np.zeros((5, 2)))
    u = np.full((50, 3), 1.0)
    assert_array_equal(chain.run(u).v_free_V, ref.run(u).v_free_V)   # noise stream and state untouched


def test_sensor_bad_input_raises_before_state_change():
    sensor, ref = SensorChain(seed=1), SensorChain(seed=1)
    with pytest.raises(ValueError, match="displacement_um"):
        sensor.step([0.0, np.nan, 0.0])
    with pytest.raises(ValueError, match="displacement_um"):
        sensor.run(np.zeros(3))
    d = np.zeros((10, 3))
    assert_array_equal(sensor.run(d).reading_V, ref.run(d).reading_V)


@pytest.mark.parametrize("kwargs, name", [
    (dict(dac_bits=0), "dac_bits"),
    (dict(adc_bits=16.5), "adc_bits"),
    (dict(dac_noise_V=-1e-3), "dac_noise_V"),
    (dict(command_range_V=(7.5, -1.0)), "command_range_V"),
    (dict(command_range_V=(0.0, 1.0, 2.0)), "command_range_V"),
    (dict(sample_rate_Hz=0.0), "sample_rate_Hz"),
    (dict(sensor_noise_band_Hz=-5.0), "sensor_noise_band_Hz"),
])
def test_config_validation(kwargs, name):
    with pytest.raises(ValueError, match=name):
        ElectronicsConfig(**kwargs)


def test_defaults_follow_constants():
    cfg = ElectronicsConfig()
    assert cfg.amplifier_gain == C.AMPLIFIER_GAIN
    assert cfg.command_range_V == C.COMMAND_RANGE_V
    assert cfg.sample_rate_Hz == C.CONTROL_RATE_HZ
    assert_allclose(cfg.adc_lsb_V * cfg.sensor_um_per_V * 1e3, C.ADC_LSB_NM, rtol=1e-15)
    assert cfg.dt_s == 1 / 4000


# speed: tests/bench/bench_electronics.py (ratios measured in the same run)


# --- shaped DAC noise and a DAC spanning the command range (nanosim.stage bench settings) -----
def test_shaped_dac_noise_keeps_rms_and_rolls_off_two_poles():
    from scipy.signal import welch
    e = ElectronicsConfig.ideal(dac_noise=True, dac_noise_V=1e-3, dac_noise_corner_Hz=10.0, dac_flicker_corner_Hz=None)
    n = ActuatorChain(e, PiezoConfig.linear(), seed=5).run(np.zeros((400_000, 3))).u_dac_V
    np.testing.assert_allclose(n.std(axis=0), 1e-3, rtol=0.06)
    f, p = welch(n[:, 0], fs=4000.0, nperseg=8192)
    # two poles at 10 Hz: PSD(200 Hz) / PSD(2 Hz) ~ ((1+0.04)/(1+400))^2 = 6.7e-6
    ratio = np.interp(200.0, f, p) / np.interp(2.0, f, p)
    assert ratio < 3e-5


def test_shaped_dac_noise_step_equals_run_bit_for_bit():
    e = ElectronicsConfig(dac_noise_V=1e-3, dac_noise_corner_Hz=10.0)
    a = ActuatorChain(e, seed=2)
    b = ActuatorChain(e, seed=2)
    u = np.random.default_rng(0).uniform(0, 2, size=(2000, 3))
    r = a.run(u)
    s = np.array([b.step(x).v_free_V for x in u])
    assert np.array_equal(r.v_free_V, s)


def test_dac_spanning_command_range_has_finer_lsb_and_exact_ends():
    e = ElectronicsConfig.ideal(dac_quantization=True, saturation=True, dac_bits=16, dac_full_scale_V=4.25,
                                dac_center_V=3.25)
    np.testing.assert_allclose(e.dac_lsb_V, 8.5 / 2**16, rtol=1e-12)
    s = ActuatorChain(e, PiezoConfig.linear()).run(np.array([[-1.0, 1.0, 7.6]]))
    np.testing.assert_allclose(s.u_dac_V[0, 0], -1.0, atol=1e-15)
    assert abs(s.u_dac_V[0, 1] - 1.0) <= e.dac_lsb_V / 2
    assert s.saturated[0].tolist() == [False, False, True]


# --- the DAC's stated resolution and range, the legs' thermal drift ---------------------------------

def test_default_dac_is_18_bits_over_10_volts_and_its_dithered_quantization_is_inside_the_input_budget():
    e = ElectronicsConfig()
    assert (e.dac_bits, e.dac_full_scale_V, e.dac_center_V) == (C.DAC_BITS, C.DAC_FULL_SCALE_V, C.DAC_CENTER_V)
    assert_allclose(e.dac_lsb_V, 20.0 / 2 ** 18, rtol=1e-15)
    assert_allclose(e.dac_quantization_rms_V, 20.0 / 2 ** 18 / np.sqrt(12), rtol=1e-15)    # 22.0 uV
    # every broadband input source in all (quantisation, DAC white, amplifier) at most ~30 uV per sample
    broadband = np.sqrt(e.dac_quantization_rms_V ** 2 + e.dac_noise_V ** 2 + e.amplifier_noise_V ** 2)
    assert broadband < 30e-6
    assert_allclose(C.BROADBAND_INPUT_NOISE_V, broadband, rtol=1e-12)
    # a 16-bit DAC over the same range would alone be three times that
    assert ElectronicsConfig(dac_bits=16).dac_quantization_rms_V > 80e-6
    # the DAC white noise is the AD669-class density over the Nyquist band
    assert_allclose(e.dac_noise_V, 120e-9 * np.sqrt(2000.0), rtol=1e-12)


def _drift_chain(seed=3, **kw):
    e = ElectronicsConfig.ideal(thermal_drift=True, **kw)
    return e, ActuatorChain(e, PiezoConfig.linear(), seed=seed)


def test_thermal_drift_level_is_the_differential_expansion_over_the_free_stroke():
    e = ElectronicsConfig.ideal(thermal_drift=True, thermal_drift_K=0.01)
    elongation_m = (23.4e-6 - 12e-6) * 15e-3 * 0.01                # d_alpha L sigma_T
    assert_allclose(e.thermal_drift_V, elongation_m / (55e-6 / 150.0) / 20.0, rtol=1e-12)
    assert ElectronicsConfig.ideal().thermal_drift_V == 0.0


def test_thermal_drift_is_a_stationary_second_order_process_with_its_rms_and_spectrum():
    # the air: AR(1) with tau_air; the leg: a first-order lag tau_leg of it; scaled to the leg's rms
    e, ch = _drift_chain(thermal_drift_tau_s=0.02, thermal_air_tau_s=0.05)
    n = 400_000                                                      # 100 s = 2000 air correlation times
    x = ch.run(np.zeros((n, 3))).u_dac_V / e.thermal_drift_V
    assert_allclose(x.var(axis=0), 1.0, rtol=0.12)
    # autocorrelation of the lag of an OU process: (t1 e^{-k/t1} - t2 e^{-k/t2}) / (t1 - t2), k in seconds
    t1, t2 = 0.05, 0.02
    for lag_s in (0.01, 0.05, 0.1):
        k = int(round(lag_s * e.sample_rate_Hz))
        want = (t1 * np.exp(-lag_s / t1) - t2 * np.exp(-lag_s / t2)) / (t1 - t2)
        got = np.mean(x[k:] * x[:-k], axis=0) / x.var(axis=0)
        assert_allclose(got, want, atol=0.05), lag_s
    # stationary from the first sample: the first samples of 400 streams have unit variance
    first = np.array([_drift_chain(seed=s, thermal_drift_tau_s=0.02, thermal_air_tau_s=0.05)[1].step(np.zeros(3))
                      .u_dac_V for s in range(400)]) / e.thermal_drift_V
    assert_allclose(first.var(), 1.0, rtol=0.15)                     # 1200 deviates: 4 % relative std


def test_thermal_drift_step_equals_run_and_reset_replays():
    _, a = _drift_chain()
    _, b = _drift_chain()
    r = a.run(np.zeros((5000, 3))).u_dac_V
    s = np.array([b.step(np.zeros(3)).u_dac_V for _ in range(5000)])
    assert_array_equal(r, s)
    a.reset()
    assert_array_equal(a.run(np.zeros((5000, 3))).u_dac_V, r)


# --- the bench loop: delay, amplifier bandwidth, gauge filter, noise spectra --------

def test_computation_delay_shifts_the_command_by_whole_samples():
    u = np.random.default_rng(4).uniform(0, 3, (200, 3))
    for d in (0, 1, 3):
        a = ActuatorChain(quiet(computation_delay_samples=d, dac_quantization=False), PiezoConfig.linear())
        b = ActuatorChain(quiet(computation_delay_samples=d, dac_quantization=False), PiezoConfig.linear())
        r = a.run(u).v_free_V
        s = np.array([b.step(x).v_free_V for x in u])
        assert_array_equal(r, s)
        assert_array_equal(r[:d], 0.0)
        assert_allclose(r[d:], 20.0 * u[:len(u) - d], rtol=1e-15)


def test_amplifier_lag_period_means_match_the_first_order_step_response():
    """Unit step into tau v' = u - v: mean over period k is 1 - (tau/T)(1 - a) a^k, a = exp(-T/tau)."""
    fa, T = 10e3, 1 / 4000
    tau, a = 1 / (2 * np.pi * fa), np.exp(-T / (1 / (2 * np.pi * fa)))
    cfg = quiet(amplifier_bandwidth_Hz=fa, dac_quantization=False, saturation=False)
    v = ActuatorChain(cfg, PiezoConfig.linear()).run(np.full((6, 3), 1.0)).v_piezo_V[:, 0] / 20.0
    k = np.arange(6)
    assert_allclose(v, 1 - (tau / T) * (1 - a) * a ** k, rtol=1e-12)
    # a slow sine lags by tau (16 us at 10 kHz): phase at 50 Hz = -2 pi 50 tau within 1 %
    t = np.arange(8000) / 4000
    u = 1 + 0.1 * np.sin(2 * np.pi * 50 * t)
    y = ActuatorChain(cfg, PiezoConfig.linear()).run(np.repeat(u[:, None], 3, 1)).v_piezo_V[:, 0] / 20
    ref = np.exp(-2j * np.pi * 50 * t)
    ph = np.angle(np.sum((y - 1) * ref) / np.sum((u - 1) * ref))
    # the period mean of a held sample also lags by T/2 relative to the sample itself
    assert_allclose(-ph, 2 * np.pi * 50 * (tau + 0.0), rtol=0.02, atol=2 * np.pi * 50 * 0.5e-6)


@pytest.mark.parametrize("fc, mag_tol, deg_tol", [(5000.0, 0.002, 1.0), (1000.0, 0.04, 6.0)])
def test_gauge_filter_matches_the_butterworth_response(fc, mag_tol, deg_tol):
    """Sampled sines through the gauge: gain and phase of the continuous 2-pole Butterworth at 100-740 Hz."""
    from scipy.signal import butter, freqs
    cfg = quiet(gauge_bandwidth_Hz=fc, adc_quantization=False, sensor_clip=False)
    t = np.arange(16000) / 4000
    b, a = butter(2, 2 * np.pi * fc, analog=True)
    for f in (100.0, 175.0, 460.0, 500.0, 740.0):
        d = np.sin(2 * np.pi * f * t)
        y = SensorChain(cfg).run(np.repeat(d[:, None], 3, 1)).reading_um[4000:, 0]
        ref = np.exp(-2j * np.pi * f * t[4000:])
        h_meas = np.sum(y * ref) / np.sum(d[4000:] * ref)
        h = freqs(b, a, [2 * np.pi * f])[1][0]
        tol_m, tol_d = (1e-3, 0.05) if f == 500.0 else (mag_tol, deg_tol)   # prewarped: exact at 500 Hz
        assert_allclose(abs(h_meas), abs(h), rtol=tol_m)
        assert_allclose(np.angle(h_meas), np.angle(h), atol=np.deg2rad(tol_d))
    # starts at steady state: a constant reads as itself
    assert_allclose(SensorChain(cfg).run(np.full((50, 3), 7.0)).reading_um, 7.0, rtol=1e-12)


def test_dac_noise_spectrum_is_white_with_flicker_corner():
    """PSD = e_n^2 (1 + f_c / f): +10.4 dB at 1 Hz and +0.4 dB at 100 Hz over the white level, f_c = 10 Hz."""
    from scipy.signal import welch
    e = ElectronicsConfig.ideal(dac_noise=True, dac_noise_V=1e-4, dac_flicker_corner_Hz=10.0)
    n = ActuatorChain(e, PiezoConfig.linear(), seed=3).run(np.zeros((1_600_000, 3))).u_dac_V
    f, p = welch(n, fs=4000.0, nperseg=2 ** 16, axis=0)
    p = p.mean(axis=1)
    white = (1e-4) ** 2 / 2000.0
    for fq, expect in ((1.0, 11.0), (100.0, 1.1), (1000.0, 1.01)):
        band = (f > 0.8 * fq) & (f < 1.25 * fq)
        assert_allclose(p[band].mean() / white, expect, rtol=0.25)


def test_amplifier_noise_std_and_seed_stream():
    e = ElectronicsConfig.ideal(amplifier_noise=True, amplifier_noise_V=2e-5)
    a = ActuatorChain(e, PiezoConfig.linear(), seed=1).run(np.zeros((100_000, 3)))
    assert_allclose(a.v_piezo_V.std(axis=0) / 20.0, 2e-5, rtol=0.015)
    assert_array_equal(a.u_dac_V, 0.0)                      # input-referred, added after the DAC code
    d = ActuatorChain(ElectronicsConfig.ideal(dac_noise=True, dac_noise_V=2e-5, dac_flicker_corner_Hz=None),
                      PiezoConfig.linear(), seed=1).run(np.zeros((1000, 3)))
    assert np.abs(np.corrcoef(d.v_piezo_V[:, 0], a.v_piezo_V[:1000, 0])[0, 1]) < 0.1


def test_default_bench_chain_step_equals_run_bit_for_bit():
    u = np.random.default_rng(9).uniform(0, 2, size=(3000, 3))
    a, b = ActuatorChain(seed=4), ActuatorChain(seed=4)
    assert_array_equal(a.run(u).v_free_V, np.array([b.step(x).v_free_V for x in u]))
    d = np.random.default_rng(10).normal(size=(3000, 3))
    s1, s2 = SensorChain(seed=4), SensorChain(seed=4)
    assert_array_equal(s1.run(d).reading_V, np.array([s2.step(x).reading_V for x in d]))
