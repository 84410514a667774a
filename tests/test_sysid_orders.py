"""Per-column identification order (issue 13): no resonance that only one column has.

Actuator A sits near the nodal lines of the 176.3 Hz and 464.5 Hz modes (the stage's
3-fold symmetry; MuJoCo's linearization gives them 1/1000 and 1/250 of their weight in
columns B and C), so at the paper's 13 states per column its model has spare states.
With the record-row pairing they became a lightly damped 11.9 Hz pole-zero pair
(zeta 0.013) on seed 0; nanosim.experiments.sysid re-identifies a column at two states
less per resonance that no other column has.
"""
from __future__ import annotations

import math
from types import SimpleNamespace

import numpy as np
import pytest

from nanosim.experiments.sysid import IdentifySettings, identify_stage, merged_modes, unshared_resonances_hz
from nanosim.plant.mjcf import load_model
from nanosim.plant.modes import modal_analysis


def _column(modes, dt=250e-6):
    """A column whose A has the given (freq_hz, zeta) pairs (discrete, block-diagonal)."""
    blocks = []
    for f, z in modes:
        w = 2 * math.pi * f
        s = complex(-z * w, w * math.sqrt(1 - z * z))
        p = np.exp(s * dt)
        blocks.append(np.array([[p.real, p.imag], [-p.imag, p.real]]))
    n = 2 * len(blocks)
    A = np.zeros((n, n))
    for k, b in enumerate(blocks):
        A[2 * k:2 * k + 2, 2 * k:2 * k + 2] = b
    return SimpleNamespace(A=A, dt_s=dt)


def test_a_resonance_of_one_column_only_is_flagged():
    cols = [_column([(176.36, 0.004), (244.5, 0.007)]),
            _column([(176.50, 0.004), (244.5, 0.007)]),                 # 0.08 % apart: the same mode
            _column([(176.36, 0.004), (244.5, 0.007), (11.9, 0.013), (30.0, 0.5)])]
    out = unshared_resonances_hz(cols)
    assert out[0] == [] and out[1] == []
    assert len(out[2]) == 1 and out[2][0] == pytest.approx(11.9, rel=1e-6)   # not the heavily damped 30 Hz pair
    two = unshared_resonances_hz([_column([(100.0, 0.01)]), _column([(100.5, 0.01)])])   # 0.5 % apart
    assert [len(x) for x in two] == [1, 1] and two[1][0] == pytest.approx(100.5, rel=1e-9)


@pytest.mark.slow
def test_identified_modes_are_the_stages_and_no_column_has_its_own():
    res = identify_stage(IdentifySettings(seed=0))
    assert unshared_resonances_hz(res.columns) == [[], [], []]
    # modes the probes see (participation >= 0.01); stage v2's 740 Hz Z mode has 0.001 and is not identified
    truth = [m.freq_hz for m in modal_analysis(load_model()).below(1000.0) if max(m.sensor_participation) >= 0.01]
    found = [m["freq_hz"] for m in merged_modes(res) if m["seen_in_columns"] >= 2]
    for f in truth:                          # every mode of MuJoCo's stage, within 1 %
        assert min(abs(g - f) / f for g in found) < 0.01, (f, found)
    for g in found:                          # and nothing else
        assert min(abs(g - f) / f for f in truth) < 0.01, (g, truth)
    assert np.all(res.fit_percent > 95.0)
