"""Notch-hinge stiffness formulas against closed forms and worked numbers."""
import math

import pytest
from numpy.testing import assert_allclose

from nanosim.plant.hinges import (AL_7075_T6, TI_6AL_4V, NotchHinge, bending_stiffness_integral_Nm_per_rad,
                                  notch_stiffness, paros_weisbord_stiffness_Nm_per_rad)

WORKED = NotchHinge(0.3e-3, 1.0e-3, 6.0e-3)     # t = 0.3 mm, R = 1 mm, b = 6 mm (mjcf/SOURCES.md item 7)


@pytest.mark.parametrize("t_mm, R_mm", [(0.05, 1.0), (0.1, 1.0), (0.3, 1.0), (0.6, 1.0), (0.2, 0.75), (0.4, 2.0)])
def test_paros_weisbord_full_form_equals_the_euler_bernoulli_integral(t_mm, R_mm):
    h = NotchHinge(t_mm * 1e-3, R_mm * 1e-3, 6e-3)
    assert_allclose(paros_weisbord_stiffness_Nm_per_rad(AL_7075_T6.youngs_modulus_Pa, h),
                    bending_stiffness_integral_Nm_per_rad(AL_7075_T6, h), rtol=1e-9)


def test_thin_notch_tends_to_the_simplified_paros_weisbord_formula():
    # k -> 2 E b t^(5/2) / (9 pi sqrt(R)) for t << R
    E = AL_7075_T6.youngs_modulus_Pa
    h = NotchHinge(0.002e-3, 1e-3, 6e-3)
    simple = 2 * E * h.width_m * h.thickness_m ** 2.5 / (9 * math.pi * math.sqrt(h.radius_m))
    assert_allclose(paros_weisbord_stiffness_Nm_per_rad(E, h), simple, rtol=2e-3)


def test_worked_numbers_7075_and_ti64():
    k = notch_stiffness(AL_7075_T6, WORKED)
    assert_allclose(k.bending_Nm_per_rad, 1.560, rtol=1e-3)
    assert_allclose(k.out_of_plane_Nm_per_rad, 345, rtol=3e-3)
    assert_allclose(k.torsion_Nm_per_rad, 2.25, rtol=3e-3)
    assert_allclose(k.axial_N_per_m, 1.15e8, rtol=5e-3)
    kt = notch_stiffness(TI_6AL_4V, WORKED)
    assert_allclose(kt.bending_Nm_per_rad, 2.477, rtol=1e-3)     # stiffer in proportion to E
    assert_allclose(kt.bending_Nm_per_rad / k.bending_Nm_per_rad, 113.8 / 71.7, rtol=1e-12)


def test_scaling_laws():
    # bending ~ b and ~ E; out-of-plane ~ b^3 for b >> h; bending ~ t^(5/2) for t << R
    k = notch_stiffness(AL_7075_T6, WORKED)
    k2 = notch_stiffness(AL_7075_T6, NotchHinge(0.3e-3, 1e-3, 12e-3))
    assert_allclose(k2.bending_Nm_per_rad / k.bending_Nm_per_rad, 2.0, rtol=1e-12)
    assert_allclose(k2.out_of_plane_Nm_per_rad / k.out_of_plane_Nm_per_rad, 8.0, rtol=1e-12)
    thin = [notch_stiffness(AL_7075_T6, NotchHinge(t, 1e-3, 6e-3)).bending_Nm_per_rad for t in (1e-6, 2e-6)]
    assert_allclose(thin[1] / thin[0], 2 ** 2.5, rtol=2e-3)


def test_bad_notch_is_rejected_with_its_argument():
    with pytest.raises(ValueError, match="thickness_m"):
        NotchHinge(-1e-4, 1e-3, 6e-3)
    with pytest.raises(ValueError, match="width_m"):
        NotchHinge(1e-3, 1e-3, 0.5e-3)
