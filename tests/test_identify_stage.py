"""Identification on the simulated stage (issue 4): the ideal stage against its modal analysis."""
import numpy as np
import pytest
from numpy.testing import assert_allclose

import identification as ident
from nanosim.experiments.sysid import IdentifySettings, assemble, identify_stage
from nanosim.plant.mjcf import load_model
from nanosim.plant.modes import modal_analysis


@pytest.fixture(scope="module")
def ideal_result():
    return identify_stage(IdentifySettings(seed=0, order_per_column=12, ideal=True))


def test_ideal_stage_fits_at_least_99_percent(ideal_result):
    assert ideal_result.fit_percent.shape == (3, 3)
    assert np.all(ideal_result.fit_percent >= 99.0), ideal_result.fit_percent


def test_ideal_stage_modes_match_modal_analysis(ideal_result):
    truth = modal_analysis(load_model()).below(1000.0)
    for col in ideal_result.columns:
        m = ident.modes_from_model(col.A, col.dt_s)
        for mode in truth:
            i = int(np.argmin(np.abs(m.freq_hz - mode.freq_hz)))
            if abs(m.freq_hz[i] - mode.freq_hz) > 0.01 * mode.freq_hz:
                continue                     # a mode this column does not see (zero residue)
            assert_allclose(m.damping[i], mode.damping_ratio, rtol=0.3)
    seen = {round(f) for col in ideal_result.columns for f in ident.modes_from_model(col.A, col.dt_s).freq_hz}
    # every mode the probes see is identified somewhere within 1 %; on the geometry-built stage v2 the
    # 740 Hz Z mode has a sensor participation of about 0.001 (paper: identified), reported in the note
    for mode in truth:
        if max(mode.sensor_participation) < 0.01:
            continue
        assert any(abs(f - mode.freq_hz) <= 0.01 * mode.freq_hz for f in seen), mode.freq_hz


def test_ideal_stage_dc_gain_matches_static_gain(ideal_result):
    truth = modal_analysis(load_model()).static_gain_um_per_V / 5.0          # sensor V per controller V
    dc = np.real(np.asarray(ideal_result.sysd.dcgain()))
    assert_allclose(dc, truth, atol=0.02 * np.abs(truth).max())


def test_assembled_model_is_block_diagonal_of_columns(ideal_result):
    G = assemble(ideal_result.columns)
    z = np.exp(2j * np.pi * 50.0 / 4000.0)
    for j, col in enumerate(ideal_result.columns):
        Hj = col.C @ np.linalg.solve(z * np.eye(col.order) - col.A, col.B) + col.D
        assert_allclose(G(z)[:, j], Hj[:, 0], rtol=1e-9)
