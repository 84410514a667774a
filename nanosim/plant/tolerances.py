"""Fabrication tolerances of the stage, stated in one place, and the map from a sample to an MjModel.

Every tolerance is one random variable with a distribution and its source:

=========================  ============  ==================================  ==========================================
variable (per ...)         nominal       distribution                        source
=========================  ============  ==================================  ==========================================
notch thickness t (notch)  from k (1)    uniform +/-5 um                     fine wire EDM, 4-6 passes: +/-5 um
                                                                             (notes/stage_v2_sources.md item 8: Mecvil,
                                                                             xmake, jccnc vendor data) (2)
notch cut radius R (notch) 1.0 mm        uniform +/-5 um                     same EDM tolerance on the cut path
link width w (moving link) 2.4 mm        uniform +/-5 um                     same EDM tolerance; PRB links are rigid, so
                                                                             it changes the link's mass (m ~ w) only
target mass (stage)        table body    uniform +/-2 %                      assumption [E]: machined target and mount,
                                                                             fastener and adhesive mass not toleranced
piezo gain (actuator)      1             uniform +/-10 %                     assumption [E]: no APA35XS datasheet spread
                                                                             in reach (notes item 1); catalogue strokes
                                                                             are "typical" values
=========================  ============  ==================================  ==========================================

(1) The nominal thickness of each hinge family follows from the model's
calibrated stiffness by Paros & Weisbord's notch formula
``k = 2 E b t^(5/2) / (9 pi sqrt(R))`` (7075-T6, E = 71.7 GPa, b = 8 mm,
R = 1 mm; mjcf/README.md "Hinges": 0.22 / 0.16 / 0.11 / 0.12 mm and the
crank-bend equivalent 0.59 mm). (2) Uniform because a tolerance band is
what the vendors state: the maximum-entropy law given only its bounds.
Notch stiffness then scales as ``k / k0 = (t / t0)^(5/2) (R0 / R)^(1/2)``
(Paros-Weisbord; dk/k = 2.5 dt/t: +/-11 % on a 0.11 mm swing hinge).

The model is built on the *symmetric* nominal: today's MJCF makes chain A
14 % stiffer (``chain_a_stiffness_factor``, an imposed fabrication
imperfection); :func:`sample_model` starts from the median of the three
chains for every joint and tendon, so any asymmetry of a sample comes from
its own hinge deviations.

Today's MJCF (``nanosim/mjcf/pkxyz_stage.xml``) lumps the notches onto
load-path joints; per chain ``{c}`` in ``a, b, c``:

=========================================  ===================  =========
notches                                    MJCF element         family
=========================================  ===================  =========
crank_base, follower_base                  joint ``{c}_crank``  fourbar1
crank_top, follower_top                    joint ``{c}_foot``   fourbar1
rocker_p_base, rocker_n_base               joint ``{c}_rocker_p`` fourbar2
rocker_p_top, rocker_n_top                 joint ``{c}_leg_top``  fourbar2
h1, h2                                     joint ``{c}_h1``     swing
lever                                      joint ``{c}_lever``  lever
crank_bend (equivalent notch)              tendon ``{c}_crank_bend``  crank bend
=========================================  ===================  =========

A joint carrying two notches gets ``(k(t1, R1) + k(t2, R2)) / 2`` times its
symmetric nominal (stiffness and damping alike: damping is
stiffness-proportional in the MJCF). Link widths scale the masses of the
bodies ``{c}_crank, {c}_foot, {c}_leg_base, {c}_rocker_p, {c}_leg_top,
{c}_rocker_n, {c}_follower``; the target mass scales the ``table`` body; the
piezo gain of actuator ``piezo_{c}`` scales its force per volt
(``actuator_gainprm``). Notch names follow :data:`nanosim.plant.geometry`'s
``{chain}_{notch}`` convention so the map can move to the geometry-built MJCF
by changing :func:`sample_model` alone.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Mapping, Sequence

import mujoco
import numpy as np

from nanosim.plant.mjcf import load_model

__all__ = ["Tolerance", "ToleranceModel", "NOTCHES", "LINK_BODIES", "default_tolerances", "sample_model",
           "notch_stiffness_ratio", "EDM_TOLERANCE_M"]

CHAINS = ("a", "b", "c")
EDM_TOLERANCE_M = 5e-6              # fine wire EDM (notes/stage_v2_sources.md item 8)
_E_PA, _B_M, _R_M = 71.7e9, 8e-3, 1e-3
_EDM_SOURCE = "fine wire EDM +/-5 um (notes/stage_v2_sources.md item 8: Mecvil, xmake, jccnc vendor data)"

# notch -> (MJCF element kind, element suffix, family, notches lumped on that element)
NOTCHES: dict[str, tuple[str, str, str]] = {
    "crank_base": ("joint", "crank", "fourbar1"), "follower_base": ("joint", "crank", "fourbar1"),
    "crank_top": ("joint", "foot", "fourbar1"), "follower_top": ("joint", "foot", "fourbar1"),
    "rocker_p_base": ("joint", "rocker_p", "fourbar2"), "rocker_n_base": ("joint", "rocker_p", "fourbar2"),
    "rocker_p_top": ("joint", "leg_top", "fourbar2"), "rocker_n_top": ("joint", "leg_top", "fourbar2"),
    "h1": ("joint", "h1", "swing"), "h2": ("joint", "h1", "swing"),
    "lever": ("joint", "lever", "lever"),
    "crank_bend": ("tendon", "crank_bend", "crank bend"),
}
LINK_BODIES = ("crank", "foot", "leg_base", "rocker_p", "leg_top", "rocker_n", "follower")
_LINK_WIDTH_M = 2.4e-3              # 2 x rocker_radius of the MJCF links


@dataclass(frozen=True)
class Tolerance:
    """One toleranced quantity.

    Attributes
    ----------
    name : str
        ``thickness.{chain}_{notch}``, ``radius.{chain}_{notch}``, ``width.{chain}_{link}``,
        ``target_mass`` or ``piezo_gain.{chain}``.
    group : str
        Sensitivity group (e.g. ``notch thickness, swing``).
    nominal : float
        Nominal value in ``unit``.
    half_width : float
        Half width of the uniform distribution, in ``unit`` (``nominal +/- half_width``).
    unit : str
    source : str
    """

    name: str
    group: str
    nominal: float
    half_width: float
    unit: str
    source: str

    def to_dict(self) -> dict:
        """JSON form (distribution spelled out)."""
        return {"name": self.name, "group": self.group, "nominal": self.nominal, "unit": self.unit,
                "distribution": f"uniform, nominal +/- {self.half_width:g} {self.unit}", "source": self.source}


@dataclass(frozen=True)
class ToleranceModel:
    """A set of independent tolerances; samples are reproducible per (seed, index)."""

    tolerances: tuple

    @property
    def names(self) -> tuple[str, ...]:
        """Variable names, in column order of :meth:`sample`."""
        return tuple(t.name for t in self.tolerances)

    @property
    def groups(self) -> tuple[str, ...]:
        """Distinct sensitivity groups, in first-appearance order."""
        return tuple(dict.fromkeys(t.group for t in self.tolerances))

    def sample(self, seed: int, index: int) -> dict[str, float]:
        """Sample ``index`` of the population with master ``seed`` (independent of how many are drawn).

        Returns
        -------
        dict
            ``{name: value}`` in each tolerance's unit.
        """
        if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or seed < 0:
            raise ValueError(f"seed: expected a non-negative integer, got {seed!r}")
        if isinstance(index, bool) or not isinstance(index, (int, np.integer)) or index < 0:
            raise ValueError(f"index: expected a non-negative integer, got {index!r}")
        u = np.random.default_rng([int(seed), int(index)]).uniform(-1.0, 1.0, len(self.tolerances))
        return {t.name: float(t.nominal + t.half_width * x) for t, x in zip(self.tolerances, u)}

    def nominal(self) -> dict[str, float]:
        """Every variable at its nominal value."""
        return {t.name: float(t.nominal) for t in self.tolerances}

    def normalized(self, values: Mapping[str, float]) -> np.ndarray:
        """Deviations in units of the half width (-1 ... 1), in :attr:`names` order."""
        return np.array([(values[t.name] - t.nominal) / t.half_width if t.half_width else 0.0
                         for t in self.tolerances])

    def to_dict(self) -> dict:
        """JSON form: every tolerance with its distribution and source."""
        return {"tolerances": [t.to_dict() for t in self.tolerances]}


def _thickness_from_k(k_Nm_per_rad: float) -> float:
    """Paros-Weisbord simplified, inverted: notch thickness (m) of stiffness ``k``."""
    return (9.0 * math.pi * math.sqrt(_R_M) * k_Nm_per_rad / (2.0 * _E_PA * _B_M)) ** 0.4


def notch_stiffness_ratio(t_m: float, t0_m: float, R_m: float = _R_M, R0_m: float = _R_M) -> float:
    """``k / k0 = (t / t0)^(5/2) (R0 / R)^(1/2)`` (Paros & Weisbord, circular notch, t << R)."""
    if not (t_m > 0 and t0_m > 0 and R_m > 0 and R0_m > 0):
        raise ValueError(f"notch_stiffness_ratio: expected positive lengths, got t={t_m}, t0={t0_m}, R={R_m}, "
                         f"R0={R0_m}")
    return (t_m / t0_m) ** 2.5 * math.sqrt(R0_m / R_m)


def _symmetric_nominal(model: mujoco.MjModel) -> dict[str, tuple[float, float]]:
    """(stiffness, damping) of every chain element at the median of the three chains."""
    out = {}
    for kind, suffix, _ in set(NOTCHES.values()):
        if kind == "joint":
            ids = [model.joint(f"{c}_{suffix}").id for c in CHAINS]
            k = [model.jnt_stiffness[i] for i in ids]
            d = [model.dof_damping[model.jnt_dofadr[i]] for i in ids]
        else:
            ids = [model.tendon(f"{c}_{suffix}").id for c in CHAINS]
            k = [model.tendon_stiffness[i] for i in ids]
            d = [model.tendon_damping[i] for i in ids]
        out[f"{kind}:{suffix}"] = (float(np.median(k)), float(np.median(d)))
    return out


def default_tolerances(model: mujoco.MjModel | None = None) -> ToleranceModel:
    """The tolerance model of the bundled stage (see the module docstring).

    Parameters
    ----------
    model : MjModel, optional
        Stage whose calibrated stiffnesses give the nominal notch thicknesses (default: bundled).
    """
    model = load_model() if model is None else model
    sym = _symmetric_nominal(model)
    tols = []
    for c in CHAINS:
        for notch, (kind, suffix, family) in NOTCHES.items():
            k_elem = sym[f"{kind}:{suffix}"][0]
            lumped = sum(1 for v in NOTCHES.values() if v[:2] == (kind, suffix))
            t0 = _thickness_from_k(k_elem / lumped)
            tols.append(Tolerance(f"thickness.{c}_{notch}", f"notch thickness, {family}", t0 * 1e6,
                                  EDM_TOLERANCE_M * 1e6, "um", _EDM_SOURCE))
    for c in CHAINS:
        for notch, (_, _, family) in NOTCHES.items():
            tols.append(Tolerance(f"radius.{c}_{notch}", "notch radius", _R_M * 1e6, EDM_TOLERANCE_M * 1e6, "um",
                                  _EDM_SOURCE))
    for c in CHAINS:
        for link in LINK_BODIES:
            tols.append(Tolerance(f"width.{c}_{link}", "link width", _LINK_WIDTH_M * 1e6, EDM_TOLERANCE_M * 1e6,
                                  "um", _EDM_SOURCE + "; mass ~ width"))
    table = float(model.body_mass[model.body("table").id])
    tols.append(Tolerance("target_mass", "target mass", table * 1e3, 0.02 * table * 1e3, "g",
                          "assumption [E]: machined target and mount, +/-2 % (fasteners, adhesive)"))
    for c in CHAINS:
        tols.append(Tolerance(f"piezo_gain.{c}", "piezo gain", 1.0, 0.10, "-",
                              "assumption [E]: +/-10 % unit-to-unit stroke per volt (no APA35XS datasheet "
                              "spread in reach, notes item 1)"))
    return ToleranceModel(tuple(tols))


def sample_model(values: Mapping[str, float], tolerances: ToleranceModel, mjcf=None) -> mujoco.MjModel:
    """The MjModel of one fabricated stage: the one place that maps tolerances onto the MJCF.

    Parameters
    ----------
    values : mapping
        ``{name: value}`` from :meth:`ToleranceModel.sample` (or :meth:`ToleranceModel.nominal`).
    tolerances : ToleranceModel
        The model the values belong to (nominal values).
    mjcf : path, optional
        Stage MJCF (default: the bundled one).

    Returns
    -------
    mujoco.MjModel
        Chains at the symmetric nominal, then every notch, link, target and actuator
        deviation of the sample applied.
    """
    missing = [n for n in tolerances.names if n not in values]
    if missing:
        raise ValueError(f"values: expected a value for every tolerance, missing {missing[:3]}")
    nom = {t.name: t.nominal for t in tolerances.tolerances}
    base = load_model(mjcf)
    sym = _symmetric_nominal(base)
    # tendons and masses through load_model's overrides
    scale: dict[str, float] = {}
    elem_ratio: dict[tuple[str, str, str], list[float]] = {}
    for c in CHAINS:
        for notch, (kind, suffix, _) in NOTCHES.items():
            t = values[f"thickness.{c}_{notch}"] * 1e-6
            t0 = nom[f"thickness.{c}_{notch}"] * 1e-6
            R = values[f"radius.{c}_{notch}"] * 1e-6
            elem_ratio.setdefault((kind, c, suffix), []).append(notch_stiffness_ratio(t, t0, R, _R_M))
    masses = {}
    for c in CHAINS:
        for link in LINK_BODIES:
            bid = base.body(f"{c}_{link}").id
            masses[f"{c}_{link}"] = float(base.body_mass[bid]) * values[f"width.{c}_{link}"] / nom[f"width.{c}_{link}"]
    masses["table"] = values["target_mass"] * 1e-3
    for (kind, c, suffix), ratios in elem_ratio.items():
        if kind == "tendon":
            current = float(base.tendon_stiffness[base.tendon(f"{c}_{suffix}").id])
            scale[f"{c}_{suffix}"] = sym[f"tendon:{suffix}"][0] / current * float(np.mean(ratios))
    model = load_model(mjcf, stiffness_scale=scale, body_mass_kg=masses)
    for (kind, c, suffix), ratios in elem_ratio.items():
        if kind == "joint":
            j = model.joint(f"{c}_{suffix}").id
            k0, d0 = sym[f"joint:{suffix}"]
            s = float(np.mean(ratios))
            model.jnt_stiffness[j] = k0 * s
            model.dof_damping[model.jnt_dofadr[j]] = d0 * s
    for c in CHAINS:
        model.actuator_gainprm[model.actuator(f"piezo_{c}").id, 0] *= values[f"piezo_gain.{c}"]
    return model


def sample_models(tolerances: ToleranceModel, seed: int, indices: Sequence[int], mjcf=None) -> list:
    """``[sample_model(tolerances.sample(seed, i), tolerances, mjcf) for i in indices]``."""
    return [sample_model(tolerances.sample(seed, i), tolerances, mjcf) for i in indices]
