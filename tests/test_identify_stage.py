"""Identification on the simulated stage: the ideal stage against its modal analysis."""
import numpy as np
import pytest
from numpy.testing import assert_allclose

import identification as ident
from nanosim import constants as C
from nanosim.experiments.sysid import IdentifySettings, assemble, identify_on_twin, identify_stage
from nanosim.paper import STAGE_MODES_HZ
from nanosim.plant.mjcf import load_model
from nanosim.plant.modes import modal_analysis


@pytest.fixture(scope="module")
def ideal_result():
    # 14 states per column: the six modes below 1 kHz and two for the filters and the sample delay
    return identify_stage(IdentifySettings(seed=0, order_per_column=14, ideal=True))


def test_ideal_stage_fits_at_least_99_percent(ideal_result):
    assert ideal_result.fit_percent.shape == (3, 3)
    assert np.all(ideal_result.fit_percent >= 99.0), ideal_result.fit_percent


def test_ideal_stage_modes_match_modal_analysis(ideal_result):
    """Noise-free records of the ideal stage: every mode below 1 kHz that a column's actuator drives
    (participation at least 1 % of the mode's largest) is identified in that column within 1e-4 of the MuJoCo
    modal analysis's frequency and 2 % of its damping ratio.
    The stage's twist (the paper's 740 Hz Z mode, 670 Hz unwarped) has a sensor participation of about 0.001
    (paper: identified): the paper's 50-200 Hz PRBS bands leave it 16 dB down; the default 1 kHz band finds it
    in every column.
    The lower tilt mode has a node at chain c (actuator participation 2e-4 in column C, 0.03 in A and B)."""
    truth = modal_analysis(load_model()).below(1000.0)
    weak = [mode.freq_hz for mode in truth if max(mode.sensor_participation) < 0.01]
    assert len(weak) == 1 and weak[0] == pytest.approx(STAGE_MODES_HZ[5], rel=0.01), weak
    n_checked = 0
    for j, col in enumerate(ideal_result.columns):
        m = ident.modes_from_model(col.A, col.dt_s)
        for mode in truth:
            if mode.actuator_participation[j] < 0.01 * max(mode.actuator_participation):
                continue
            n_checked += 1
            i = int(np.argmin(np.abs(m.freq_hz - mode.freq_hz)))
            assert m.freq_hz[i] == pytest.approx(mode.freq_hz, rel=1e-4), (mode.freq_hz, m.freq_hz)
            assert m.damping[i] == pytest.approx(mode.damping_ratio, rel=0.02), (mode.freq_hz, m.damping[i])
    assert n_checked == 17                               # 6 modes x 3 columns, less the tilt's node at chain c


def test_ideal_stage_dc_gain_matches_static_gain(ideal_result):
    """DC gain of the identified model vs MuJoCo's static gain: within 0.6 % of the largest entry (seed 0,
    measured 0.33 %; the records hold 5 s of data, so the lowest frequencies are fitted, not measured)."""
    truth = modal_analysis(load_model()).static_gain_um_per_V / 5.0          # sensor V per controller V
    dc = np.real(np.asarray(ideal_result.sysd.dcgain()))
    assert_allclose(dc, truth, atol=0.006 * np.abs(truth).max())


def test_identify_on_twin_finds_the_modes_of_the_stage(model):
    """Noise-free records of the ideal stage's linear twin: the twin's static gain is MuJoCo's (the
    linearization is exact at DC), and every mode below 1 kHz that a column's actuator drives (participation
    at least 1 % of the mode's largest) is identified in that column within 1e-4 of MuJoCo's modal analysis,
    as on the MuJoCo stage itself."""
    result, twin = identify_on_twin(model, IdentifySettings(seed=0, order_per_column=14, ideal=True))
    truth = modal_analysis(model)
    gain_V = truth.static_gain_um_per_V / C.SENSOR_UM_PER_V                    # sensor V per controller V
    assert_allclose(np.real(np.asarray(twin.sys_V.dcgain())), gain_V, rtol=0, atol=1e-6 * np.abs(gain_V).max())
    n_checked = 0
    for j, col in enumerate(result.columns):
        m = ident.modes_from_model(col.A, col.dt_s)
        for mode in truth.below(1000.0):
            if mode.actuator_participation[j] < 0.01 * max(mode.actuator_participation):
                continue
            n_checked += 1
            assert np.min(np.abs(m.freq_hz - mode.freq_hz)) <= 1e-4 * mode.freq_hz, (mode.freq_hz, m.freq_hz)
    assert n_checked == 17                               # 6 modes x 3 columns, less the tilt's node at chain c


def test_assembled_model_is_block_diagonal_of_columns(ideal_result):
    G = assemble(ideal_result.columns)
    z = np.exp(2j * np.pi * 50.0 / 4000.0)
    for j, col in enumerate(ideal_result.columns):
        Hj = col.C @ np.linalg.solve(z * np.eye(col.order) - col.A, col.B) + col.D
        assert_allclose(G(z)[:, j], Hj[:, 0], rtol=1e-9)


def test_the_default_bands_put_power_at_the_top_mode():
    """A PRBS held P samples has the spectrum sinc^2(f P / fs): at the stage's top mode (670.3 Hz) the paper's
    200 Hz band (P = 10) is 15.83 dB under its low-frequency level, on the way to its 800 Hz null; the 1 kHz band
    (P = 2) 1.67 dB. Welch, 1.5 dB."""
    import scipy.signal as ss

    from nanosim.constants import CONTROL_RATE_HZ as fs
    from nanosim.constants import DEFAULT_PRBS_BANDS_HZ
    assert DEFAULT_PRBS_BANDS_HZ[:3] == (50.0, 100.0, 200.0) and max(DEFAULT_PRBS_BANDS_HZ) == 1000.0
    f_top = STAGE_MODES_HZ[5]
    for band_hz, hold, expect_db in ((200.0, 10, -15.83), (1000.0, 2, -1.67)):
        assert ident.prbs_hold_samples(band_hz, fs=fs) == hold
        assert 10 * np.log10(np.sinc(f_top * hold / fs) ** 2) == pytest.approx(expect_db, abs=0.01)
        f, p = ss.welch(ident.prbs(2**17, band_hz, fs=fs, seed=1), fs=fs, nperseg=1024)
        low = p[(f > 5) & (f < 40)].mean()
        at = p[np.argmin(np.abs(f - f_top))]
        assert 10 * np.log10(at / low) == pytest.approx(expect_db, abs=1.5), band_hz


def test_identify_config_names_bad_bands():
    from nanosim.paper import PAPER_PRBS_BANDS_HZ
    from nanosim.pipeline.config import IdentifyConfig
    assert IdentifyConfig(bands_hz=PAPER_PRBS_BANDS_HZ).bands_hz == (50.0, 100.0, 200.0)
    for bad in ((), (50.0, 2500.0), [50.0], (0.0,), (True,), ("50",)):
        with pytest.raises(ValueError, match=r"bands_hz: expected a non-empty tuple of band edges in \(0, 2000\] Hz"):
            IdentifyConfig(bands_hz=bad)


def test_a_real_pole_slower_than_the_record_is_removed_and_the_rest_kept():
    """A column with a 200 Hz mode and two real poles (tau 0.05 s and 20 s) on a 2 s record: the 20 s pole is
    dropped, the others stay exactly, and the refitted column reproduces the record's fast part."""
    import dataclasses

    from nanosim.experiments.sysid import without_slow_poles
    dt = 250e-6
    w, z = 2 * np.pi * 200.0, 0.01
    r = np.exp(-z * w * dt)
    th = w * np.sqrt(1 - z * z) * dt
    A = np.zeros((4, 4))
    A[:2, :2] = r * np.array([[np.cos(th), -np.sin(th)], [np.sin(th), np.cos(th)]])
    A[2, 2], A[3, 3] = np.exp(-dt / 0.05), np.exp(-dt / 20.0)
    B = np.array([[1.0], [0.5], [0.02], [1e-4]])
    C = np.array([[1.0, 0.0, 1.0, 1.0], [0.0, 1.0, 0.5, 0.5], [0.3, 0.2, 0.1, 0.2]])
    u = np.random.default_rng(0).choice([-1.0, 1.0], size=8000)
    x = np.zeros(4)
    ys = np.empty((u.size, 3))
    for k, uk in enumerate(u):
        ys[k] = C @ x
        x = A @ x + B[:, 0] * uk
    col = ident.subspace_id(ys, u[:, None], order=4, fs=1 / dt)
    col = dataclasses.replace(col, A=A, B=B, C=C, D=np.zeros((3, 1)), K=np.zeros((4, 3)), x0=np.zeros(4), order=4)
    kept = without_slow_poles(col, 2.0, u, ys)
    assert kept.order == 3
    np.testing.assert_allclose(np.sort_complex(np.linalg.eigvals(kept.A)),
                               np.sort_complex(np.linalg.eigvals(A)[:3]), rtol=1e-9)
    assert ident.fit_percent(ys, ident.simulate(kept, u[:, None], kept.x0)).min() > 99.0
    assert without_slow_poles(col, 30.0, u, ys) is col            # nothing slower than 30 s: unchanged
