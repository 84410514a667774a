"""Circular notch flexure hinges: stiffness in every compliant direction, from published formulas.

A circular notch hinge is a web of minimum thickness ``t`` between two cuts of
radius ``R`` in a link of width ``b`` (the width runs along the hinge's rotation
axis). Along the web, -R <= x <= R, the thickness is

    h(x) = t + 2 (R - sqrt(R^2 - x^2)).

Sources
-------
* In-plane bending (the hinge's working rotation): Paros & Weisbord, "How to
  design flexure hinges", Machine Design 37 (1965) 151-156, full (not the
  t << R simplified) equation, :func:`paros_weisbord_stiffness_Nm_per_rad`.
* Out-of-plane bending, torsion and axial stiffness: the Euler-Bernoulli
  compliance integrals of Lobontiu, *Compliant Mechanisms: Design of Flexure
  Hinges* (CRC, 2002), ch. 2 (Castigliano's theorem on the same profile), with
  the torsion constant of a thin rectangle from Roark's *Formulas for Stress
  and Strain* (Young & Budynas, 7th ed., Table 10.7 case 4):
  J = b h^3 [1/3 - 0.21 (h/b)(1 - h^4 / (12 b^4))] for b >= h.

  For in-plane bending the same integral equals the Paros-Weisbord full
  equation (tests/test_hinges.py checks this to 1e-9). Beam theory agrees with
  FEM within about 10 % for 0.05 < t/R < 0.65 (Yong, Lu & Handley,
  Precis. Eng. 32 (2008) 63-70); that is the formula uncertainty.

All quantities SI: m, Pa, N m/rad, N/m.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

__all__ = ["Material", "AL_7075_T6", "TI_6AL_4V", "NotchHinge", "NotchStiffness", "notch_stiffness",
           "paros_weisbord_stiffness_Nm_per_rad"]


@dataclass(frozen=True)
class Material:
    """An isotropic structural material (SI)."""

    name: str
    youngs_modulus_Pa: float
    shear_modulus_Pa: float
    density_kg_per_m3: float
    source: str


# ASM Aerospace Specification Metals data sheets (asm.matweb.com), typical values.
AL_7075_T6 = Material("aluminium 7075-T6", 71.7e9, 26.9e9, 2810.0,
                      "ASM Aerospace Specification Metals, Aluminum 7075-T6 data sheet (E 71.7 GPa, "
                      "G 26.9 GPa, 2.81 g/cm^3)")
TI_6AL_4V = Material("titanium Ti-6Al-4V (grade 5)", 113.8e9, 44.0e9, 4430.0,
                     "ASM Aerospace Specification Metals, Titanium Ti-6Al-4V (grade 5) annealed data sheet "
                     "(E 113.8 GPa, G 44 GPa, 4.43 g/cm^3)")


@dataclass(frozen=True)
class NotchHinge:
    """Geometry of one circular notch: minimum thickness, cut radius and width (m)."""

    thickness_m: float
    radius_m: float
    width_m: float

    def __post_init__(self):
        for name in ("thickness_m", "radius_m", "width_m"):
            v = getattr(self, name)
            if not (math.isfinite(v) and v > 0):
                raise ValueError(f"NotchHinge.{name}: expected a positive length in m, got {v!r}")
        if self.thickness_m > self.width_m:
            raise ValueError(f"NotchHinge: thickness_m ({self.thickness_m}) must not exceed width_m "
                             f"({self.width_m}); the torsion formula assumes a web wider than thick")

    def profile_m(self, x_m: np.ndarray) -> np.ndarray:
        """Web thickness h(x) (m) at positions -R <= x <= R along the notch."""
        R = self.radius_m
        return self.thickness_m + 2.0 * (R - np.sqrt(np.maximum(R * R - x_m * x_m, 0.0)))

    def with_thickness(self, thickness_m: float) -> "NotchHinge":
        """The same notch with another minimum thickness."""
        return NotchHinge(thickness_m, self.radius_m, self.width_m)


@dataclass(frozen=True)
class NotchStiffness:
    """Stiffness of one notch in each direction (SI).

    bending_Nm_per_rad : about the working axis (in-plane, Paros-Weisbord full form).
    out_of_plane_Nm_per_rad : about the in-plane axis normal to the web (across the width).
    torsion_Nm_per_rad : about the web's own axis.
    axial_N_per_m : along the web's own axis.
    """

    bending_Nm_per_rad: float
    out_of_plane_Nm_per_rad: float
    torsion_Nm_per_rad: float
    axial_N_per_m: float


def paros_weisbord_stiffness_Nm_per_rad(E_Pa: float, hinge: NotchHinge) -> float:
    """Rotational stiffness of a circular notch about its working axis, Paros & Weisbord (1965), full form.

    alpha/M = 3 / (2 E b R^2) / (2 beta + beta^2) * [(3 + 4 beta + 2 beta^2) / ((1 + beta)(2 beta + beta^2))
              + 6 (1 + beta) / (2 beta + beta^2)^(3/2) * arctan(sqrt((2 + beta) / beta))],  beta = t / (2 R).
    """
    t, R, b = hinge.thickness_m, hinge.radius_m, hinge.width_m
    beta = t / (2.0 * R)
    g = 2.0 * beta + beta * beta
    bracket = ((3.0 + 4.0 * beta + 2.0 * beta * beta) / ((1.0 + beta) * g)
               + 6.0 * (1.0 + beta) / g ** 1.5 * math.atan(math.sqrt((2.0 + beta) / beta)))
    compliance = 3.0 / (2.0 * E_Pa * b * R * R) / g * bracket
    return 1.0 / compliance


_GL_X, _GL_W = np.polynomial.legendre.leggauss(200)


def _integrate(hinge: NotchHinge, f) -> float:
    """Integral over the notch, -R..R, of f(h(x)) dx (Gauss-Legendre on x = R sin(theta)).

    The substitution clusters nodes near the web, where the integrands peak.
    """
    R = hinge.radius_m
    theta = 0.5 * math.pi * _GL_X                     # -pi/2..pi/2
    x = R * np.sin(theta)
    dx = R * np.cos(theta) * 0.5 * math.pi
    return float(np.sum(_GL_W * f(hinge.profile_m(x)) * dx))


def notch_stiffness(material: Material, hinge: NotchHinge) -> NotchStiffness:
    """Stiffness of ``hinge`` cut in ``material`` in its four compliant directions.

    Bending from Paros-Weisbord (full); out-of-plane bending, torsion and axial from
    Lobontiu's (2002) compliance integrals, torsion constant from Roark.
    """
    E, G, b = material.youngs_modulus_Pa, material.shear_modulus_Pa, hinge.width_m

    def torsion_constant(h):
        return b * h ** 3 * (1.0 / 3.0 - 0.21 * (h / b) * (1.0 - h ** 4 / (12.0 * b ** 4)))

    c_oop = _integrate(hinge, lambda h: 12.0 / (E * h * b ** 3))
    c_tor = _integrate(hinge, lambda h: 1.0 / (G * torsion_constant(h)))
    c_ax = _integrate(hinge, lambda h: 1.0 / (E * b * h))
    return NotchStiffness(bending_Nm_per_rad=paros_weisbord_stiffness_Nm_per_rad(E, hinge),
                          out_of_plane_Nm_per_rad=1.0 / c_oop, torsion_Nm_per_rad=1.0 / c_tor,
                          axial_N_per_m=1.0 / c_ax)


def bending_stiffness_integral_Nm_per_rad(material: Material, hinge: NotchHinge) -> float:
    """In-plane bending stiffness from the Euler-Bernoulli integral 1 / int 12 dx / (E b h^3) (check on P&W)."""
    E, b = material.youngs_modulus_Pa, hinge.width_m
    return 1.0 / _integrate(hinge, lambda h: 12.0 / (E * b * h ** 3))
