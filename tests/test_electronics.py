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
    """Default electronics with both noise sources off."""
    return ElectronicsConfig(dac_noise=False, sensor_noise=False, **kw)


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
    cfg = ElectronicsConfig.ideal(dac_noise=True, dac_noise_V=sigma)
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
    assert set(np.unique(codes)) <= {-1.0, 0.0, 1.0}   # 0.42 nm noise vs 1.53 nm LSB


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


def test_same_master_seed_gives_independent_streams():
    cfg = ElectronicsConfig.ideal(dac_noise=True, sensor_noise=True)
    n = 20_000
    act = ActuatorChain(cfg, PiezoConfig.linear(), seed=7).run(np.zeros((n, 3))).u_dac_V
    sen = SensorChain(cfg, seed=7).run(np.zeros((n, 3))).reading_um
    rho = np.corrcoef(act.ravel(), sen.ravel())[0, 1]
    assert abs(rho) < 0.03
    ss = np.random.SeedSequence(123)
    assert child_seed(ss, 0) is ss
    with pytest.raises(ValueError, match="seed"):
        child_seed(-1, 0)


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


# --- speed (timed only with --benchmark-enable) -----------------------------------

def test_bench_actuator_step(benchmark):
    chain = ActuatorChain(seed=0)
    u = np.array([0.5, 1.0, 1.5])
    benchmark(chain.step, u)


def test_bench_actuator_run_40000(benchmark):
    u = np.random.default_rng(0).uniform(0, 3, (40_000, 3))
    chain = ActuatorChain(seed=0)
    out = benchmark(chain.run, u)
    assert out.v_free_V.shape == (40_000, 3)


def test_bench_sensor_step(benchmark):
    sensor = SensorChain(seed=0)
    d = np.array([1.0, -2.0, 3.0])
    benchmark(sensor.step, d)


# --- shaped DAC noise and a DAC spanning the command range (nanosim.stage bench settings) -----
def test_shaped_dac_noise_keeps_rms_and_rolls_off_two_poles():
    from scipy.signal import welch
    e = ElectronicsConfig.ideal(dac_noise=True, dac_noise_V=1e-3, dac_noise_corner_Hz=10.0)
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
    e = ElectronicsConfig.ideal(dac_quantization=True, saturation=True, dac_full_scale_V=4.25, dac_center_V=3.25)
    np.testing.assert_allclose(e.dac_lsb_V, 8.5 / 2**16, rtol=1e-12)
    s = ActuatorChain(e, PiezoConfig.linear()).run(np.array([[-1.0, 1.0, 7.6]]))
    np.testing.assert_allclose(s.u_dac_V[0, 0], -1.0, atol=1e-15)
    assert abs(s.u_dac_V[0, 1] - 1.0) <= e.dac_lsb_V / 2
    assert s.saturated[0].tolist() == [False, False, True]
