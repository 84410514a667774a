"""The charge amplifier (ElectronicsConfig(drive="charge"), nanosim.plant.charge_drive): physics and config."""
from __future__ import annotations

import numpy as np
import pytest

from nanosim import constants as C
from nanosim.pipeline.config import CharacterizeConfig
from nanosim.plant.batch_electronics import BatchElectronics
from nanosim.plant.electronics import ActuatorChain, ElectronicsConfig
from nanosim.plant.filters import AmplifierLag
from nanosim.plant.piezo import PiezoConfig, PiezoModel, loop_hysteresis_percent

FS = C.CONTROL_RATE_HZ


def _triangle(period_s: float, peak_V: float = 1.65) -> np.ndarray:
    """Fig. 14's command on actuator A: 0 -> peak -> 0 V over ``period_s``, from rest."""
    n = int(period_s * FS)
    tri = np.concatenate([np.linspace(0, 1, n // 2), np.linspace(1, 0, n - n // 2)])
    u = np.zeros((n, 3))
    u[:, 0] = peak_V * tri
    return u


def _width_percent(period_s: float, **electronics) -> float:
    u = _triangle(period_s)
    s = ActuatorChain(ElectronicsConfig.ideal(**electronics), seed=0).run(u)
    return loop_hysteresis_percent(u[:, 0], s.v_free_V[:, 0])[0]


def test_voltage_drive_is_the_amplifier_into_the_piezo_bit_for_bit():
    # the default chain is DAC -> amplifier -> piezo, nothing after the piezo
    assert ElectronicsConfig().drive == "voltage"
    u = _triangle(0.5) + 0.01
    e = ElectronicsConfig.ideal(amplifier_bandwidth_Hz=C.AMPLIFIER_BANDWIDTH_HZ)
    s = ActuatorChain(e, seed=3).run(u)
    lag = AmplifierLag(C.AMPLIFIER_BANDWIDTH_HZ, e.dt_s, 3)
    v = lag.run(e.amplifier_gain * u)
    ref = PiezoModel(PiezoConfig(), e.dt_s, 3).run(v)
    np.testing.assert_array_equal(s.v_piezo_V, v)
    np.testing.assert_array_equal(s.v_free_V, ref)
    # every effect on: an explicit voltage drive is the default, bit for bit
    a = ActuatorChain(ElectronicsConfig(), seed=5).run(u)
    b = ActuatorChain(ElectronicsConfig(drive="voltage"), seed=5).run(u)
    np.testing.assert_array_equal(a.v_free_V, b.v_free_V)


def test_fig14_loop_is_the_residual_fraction_of_the_voltage_drive():
    v = _width_percent(2.0)
    assert 13.0 < v < 16.0                                    # the calibrated Fig. 14 loop (15 %)
    # far above the crossover the loop is exactly the residual fraction
    hf = _width_percent(2.0, drive="charge", charge_crossover_Hz=1e-4) / v
    assert hf == pytest.approx(C.CHARGE_RESIDUAL_HYSTERESIS, abs=0.005)
    # at the default 0.1 Hz crossover the 2 s loop from rest keeps the residual plus its voltage-driven part
    ratio = _width_percent(2.0, drive="charge") / v
    assert C.CHARGE_RESIDUAL_HYSTERESIS < ratio < C.CHARGE_RESIDUAL_HYSTERESIS + 0.15
    # a residual of 1 is the voltage drive
    assert _width_percent(2.0, drive="charge", charge_residual=1.0) == pytest.approx(v, rel=1e-12)


def test_hysteresis_returns_below_the_crossover():
    # a 0.01 Hz triangle (100 s), a decade below the 0.1 Hz crossover: the voltage drive's loop
    slow = _width_percent(100.0, drive="charge") / _width_percent(100.0)
    assert slow == pytest.approx(1.0, abs=0.05)
    # in between (0.05 Hz) mostly back
    assert _width_percent(20.0, drive="charge") / _width_percent(20.0) > 0.8
    # and a crossover above the loop's rate gives it back at the Fig. 14 rate too
    assert _width_percent(2.0, drive="charge", charge_crossover_Hz=10.0) / _width_percent(2.0) > 0.95


def test_charge_drive_settles_to_the_voltage_drive_after_a_step():
    n = int(30.0 * FS)                                        # 30 s = 19 time constants of the 0.1 Hz crossover
    u = np.zeros((n, 3))
    u[:, 0] = 1.5
    v = ActuatorChain(ElectronicsConfig.ideal(), seed=0).run(u).v_free_V[:, 0]
    q = ActuatorChain(ElectronicsConfig.ideal(drive="charge"), seed=0).run(u).v_free_V[:, 0]
    h = 1.5 * C.AMPLIFIER_GAIN
    assert abs(q[int(0.01 * FS)] - h) < 0.3 * abs(v[int(0.01 * FS)] - h)   # charge-driven at first
    assert abs(q[-1] - v[-1]) < 2e-3 * h                                    # voltage-driven at DC


def test_charge_drive_step_equals_run_and_reset_replays():
    u = _triangle(0.3) + 0.02 * np.sin(np.arange(1200) / 7.0)[:, None]
    ch = ActuatorChain(ElectronicsConfig(drive="charge"), seed=2)
    r = ch.run(u)
    ch.reset()
    s = np.array([ch.step(x).v_free_V for x in u])
    np.testing.assert_array_equal(s, r.v_free_V)


def test_config_errors_name_the_argument():
    with pytest.raises(ValueError, match=r"drive: expected one of voltage, charge, got 'current'"):
        ElectronicsConfig(drive="current")
    with pytest.raises(ValueError, match="charge_crossover_Hz: expected a finite value > 0, got 0"):
        ElectronicsConfig(drive="charge", charge_crossover_Hz=0.0)
    with pytest.raises(ValueError, match=r"charge_residual: expected a fraction in \[0, 1\], got 1.5"):
        ElectronicsConfig(charge_residual=1.5)
    with pytest.raises(ValueError, match="drive: expected one of voltage, charge, got 'current'"):
        CharacterizeConfig(drive="current")
    with pytest.raises(ValueError, match="electronics.drive: the batch electronics runs the voltage drive only"):
        BatchElectronics(ElectronicsConfig(drive="charge"), PiezoConfig(), [0])


@pytest.mark.parametrize("drive", ["voltage", "charge"])
def test_characterize_runs_every_experiment_with_the_drive_and_records_it(tmp_path, drive):
    import json

    from nanosim import experiments
    from nanosim.experiments.registry import Experiment, register, unregister
    from nanosim.fileio import write_npz
    from nanosim.pipeline.characterize import run_characterize

    def run(ctx):
        stage = ctx.factory(ctx.seed)
        return stage.config.electronics.drive, stage.actuators._charge is not None

    experiments.load_builtin()
    register(Experiment("drive_probe", run=run, metrics=lambda r: {"drive_probe": list(r)}, order=5, cost=0.1))
    try:
        ctrl = write_npz(tmp_path / "c.npz", Akd=np.zeros((1, 1)), Bkd=np.zeros((1, 3)), Ckd=np.zeros((3, 1)),
                         Dkd=0.01 * np.eye(3), dt=2.5e-4)
        m = run_characterize(ctrl, tmp_path / "out", CharacterizeConfig(only="drive_probe", twin=True, drive=drive),
                             progress=False)
    finally:
        unregister("drive_probe")
    assert m["drive_probe"] == [drive, drive == "charge"]
    saved = json.loads((tmp_path / "out" / "metrics.json").read_text())
    assert saved.get("drive", "voltage") == drive
    assert ("drive" in saved) == (drive == "charge")          # the default run's metrics.json is unchanged


def test_cli_drive_option(tmp_path):
    from nanosim.cli import build_parser

    p = build_parser()
    args = p.parse_args(["characterize", "--controller", __file__, "--out", str(tmp_path / "o"), "--drive", "charge"])
    assert args.drive == "charge"
    assert p.parse_args(["characterize", "--controller", __file__, "--out", str(tmp_path / "o")]).drive == "voltage"
    with pytest.raises(SystemExit):
        p.parse_args(["characterize", "--controller", __file__, "--out", str(tmp_path / "o"), "--drive", "current"])
