"""The list of calibrated parameters (nanosim.calibrated) states the values the model runs with."""
import math

import pytest

from nanosim import constants as C
from nanosim.calibrated import CALIBRATED_PARAMETERS, CalibratedParameter, fitted_figures
from nanosim.plant.build import DampingSpec
from nanosim.plant.geometry import CALIBRATED_GEOMETRY, DEFAULT_GEOMETRY, HINGE_FAMILIES
from nanosim.plant.piezo import PiezoConfig

BY_NAME = {p.name: p for p in CALIBRATED_PARAMETERS}


def test_names_are_unique_and_values_inside_their_bounds():
    assert len(BY_NAME) == len(CALIBRATED_PARAMETERS)
    for p in CALIBRATED_PARAMETERS:
        assert p.inside, p
        assert p.source_figure and p.method


@pytest.mark.parametrize("chain", "abc")
@pytest.mark.parametrize("family", sorted(HINGE_FAMILIES))
def test_notch_webs_are_the_bundled_geometry(chain, family):
    p = BY_NAME[f"chain {chain} {family} notch web"]
    design_m = DEFAULT_GEOMETRY.chain.notch(family).thickness_m
    dev = dict(CALIBRATED_GEOMETRY.thickness_deviation_m)
    for notch in HINGE_FAMILIES[family]:
        web_m = design_m + dev.get(f"{chain}_{notch}", 0.0)
        assert web_m * 1e6 == pytest.approx(p.value, abs=1e-6), (p.name, notch)


def test_section_values_are_the_bundled_geometry():
    c = CALIBRATED_GEOMETRY.chain
    assert BY_NAME["notch cut radius"].value == pytest.approx(c.fb1_notch.radius_m * 1e3, abs=1e-9)
    assert BY_NAME["four-bar 1 rocker width"].value == pytest.approx(c.fb1_rocker.width_m * 1e3, abs=1e-9)
    assert BY_NAME["leg rocker width"].value == pytest.approx(c.fb2_rocker.width_m * 1e3, abs=1e-9)
    assert BY_NAME["target cube side"].value == pytest.approx(CALIBRATED_GEOMETRY.table.target_side_m * 1e3, abs=1e-9)


def test_electromechanical_values_are_the_model_defaults():
    d = DampingSpec()
    assert BY_NAME["DampingSpec.hinge_loss_factor"].value == d.hinge_loss_factor
    assert BY_NAME["DampingSpec.piezo_loss_factor"].value == d.piezo_loss_factor
    assert BY_NAME["THERMAL_DRIFT_K_RMS"].value == C.THERMAL_DRIFT_K_RMS
    assert BY_NAME["THERMAL_DRIFT_K_RMS"].bound == tuple(C.THERMAL_DRIFT_K_BOUNDS)
    assert BY_NAME["CREEP_PER_DECADE"].value == C.CREEP_PER_DECADE
    w0 = [p for p in CALIBRATED_PARAMETERS if p.name.startswith("piezo hysteresis")][0]
    assert w0.value == pytest.approx(PiezoConfig().pi_linear_weight, rel=1e-9)


def test_on_bound_is_the_distance_to_an_end():
    at = CalibratedParameter("x", 2.0, "1", (1.0, 2.0), True, "fig", "fit")
    inner = CalibratedParameter("x", 1.5, "1", (1.0, 2.0), True, "fig", "fit")
    free = CalibratedParameter("x", 1.5, "1", None, False, "fig", "fit")
    assert at.on_bound and not inner.on_bound and not free.on_bound
    assert at.to_dict()["on_bound"] is True
    # the wire-EDM bound is reached by chain b's swing webs, which the parasitic-mode floor asks for
    assert BY_NAME["chain b swing notch web"].on_bound and not BY_NAME["chain c swing notch web"].on_bound
    assert "the open-loop sigma at rest, 11.4 nm (Sec. 5)" in fitted_figures()


def test_bad_entries_are_refused():
    with pytest.raises(ValueError, match="value"):
        CalibratedParameter("x", math.nan, "1", None, False, "f", "m")
    with pytest.raises(ValueError, match="bound"):
        CalibratedParameter("x", 1.0, "1", (2.0, 1.0), True, "f", "m")
