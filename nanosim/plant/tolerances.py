"""Fabrication tolerances of the stage, stated in one place, and the map from a sample to an MjModel.

Every tolerance is one random variable with a distribution and its source:

=============================  ===============  =================  =========================================
variable (per ...)             nominal          distribution       source
=============================  ===============  =================  =========================================
notch thickness t (notch)      the stage's      uniform +/-5 um    fine wire EDM, 4-6 passes: +/-5 um
                               notch family                        (mjcf/SOURCES.md item 8:
                                                                   Mecvil, xmake, jccnc vendor data) (1)
notch cut radius R (notch)     the family's R   uniform +/-5 um    the same EDM tolerance on the cut path
link width (moving link)       1 (relative)     uniform +/-5 um    the same EDM tolerance on the link's
                               of 2.4 mm                           in-plane section; the links are rigid,
                                                                   so it sets the link's mass (m ~ w)
target mass (stage)            ``table`` body   uniform +/-2 %     assumption [E]: machined target and
                                                                   mount, fasteners/adhesive not toleranced
piezo gain (actuator)          1                uniform +/-10 %    assumption [E]: no APA35XS datasheet
                                                                   spread in reach (mjcf/SOURCES.md item 1)
=============================  ===============  =================  =========================================

(1) Uniform: a tolerance band is what the vendors state, the maximum-entropy
law given only its bounds. A notch's bending stiffness follows Paros &
Weisbord, ``k ~ t^(5/2) R^(-1/2)`` (:func:`notch_stiffness_ratio`): +/-5 um on
the 83 um four-bar-2 notches of the v2 stage is +/-15 % stiffness.

Samples start from the *symmetric* nominal stage, so the asymmetry of the
chains comes from each sample's own deviations: the bundled stage is built
with per-chain webs that split its XY pairs (v2, ``CALIBRATED_GEOMETRY``;
the symmetric stage has each family at the mean of the three chains' webs,
and its modes are the calibrated pairs' centres to 0.1 %), or with chain A
14 % stiffer (v1, the median of the chains), and both are removed first.

Map (:func:`sample_model`, the one place that knows the MJCF):

* **bundled stage (v2, geometry-built)**: the sample becomes
  ``CALIBRATED_GEOMETRY`` with ``thickness_deviation_m`` set per notch
  (``{chain}_{notch}``, notches of :data:`nanosim.plant.geometry.HINGE_FAMILIES`:
  fb1 crank/follower base/top, fb2 rocker_p/rocker_n base/top, swing h1/h2,
  apa apa_base/apa_crank), the notch radius entering as the equivalent
  thickness of the same bending stiffness ``t (R0 / R)^(1/5)``; the builder
  (:func:`nanosim.plant.build.stage_xml`) derives every joint stiffness
  (bending, out-of-plane, torsion) and every mass from it. Link widths scale
  the masses of the moving links ``{c}_crank, {c}_foot, {c}_leg_base,
  {c}_rocker_p, {c}_leg_top, {c}_rocker_n, {c}_follower``; the target mass
  sets the ``table`` body; the piezo gain scales ``actuator_gainprm`` of
  ``piezo_{c}``.
* **v1 stage** (``--mjcf nanosim/mjcf/v1/scene.xml``, lumped springs): joint
  ``{c}_crank`` carries crank_base + follower_base, ``{c}_foot`` crank_top +
  follower_top, ``{c}_rocker_p`` the two base rockers, ``{c}_leg_top`` the two
  top rockers, ``{c}_h1`` h1 + h2, ``{c}_lever`` the lever notch and tendon
  ``{c}_crank_bend`` the crank's equivalent notch; each element gets the mean
  stiffness ratio of its notches (damping alike) from the median of the three
  chains.
"""
from __future__ import annotations

import math
import tempfile
from dataclasses import dataclass
from pathlib import Path
from typing import Mapping, Sequence

import mujoco
import numpy as np

from nanosim.plant.mjcf import load_model

__all__ = ["Tolerance", "ToleranceModel", "default_tolerances", "sample_model", "sample_models", "model_from_geometry",
           "notch_stiffness_ratio", "EDM_TOLERANCE_M", "LINK_BODIES", "V1_NOTCHES"]

CHAINS = ("a", "b", "c")
EDM_TOLERANCE_M = 5e-6              # fine wire EDM (mjcf/SOURCES.md item 8)
_EDM_SOURCE = "fine wire EDM +/-5 um (mjcf/SOURCES.md item 8: Mecvil, xmake, jccnc vendor data)"
LINK_BODIES = ("crank", "foot", "leg_base", "rocker_p", "leg_top", "rocker_n", "follower")
_LINK_WIDTH_M = 2.4e-3
# v1 (lumped) stage: notch -> (MJCF element kind, element suffix, family)
V1_NOTCHES: dict[str, tuple[str, str, str]] = {
    "crank_base": ("joint", "crank", "fourbar1"), "follower_base": ("joint", "crank", "fourbar1"),
    "crank_top": ("joint", "foot", "fourbar1"), "follower_top": ("joint", "foot", "fourbar1"),
    "rocker_p_base": ("joint", "rocker_p", "fourbar2"), "rocker_n_base": ("joint", "rocker_p", "fourbar2"),
    "rocker_p_top": ("joint", "leg_top", "fourbar2"), "rocker_n_top": ("joint", "leg_top", "fourbar2"),
    "h1": ("joint", "h1", "swing"), "h2": ("joint", "h1", "swing"),
    "lever": ("joint", "lever", "lever"),
    "crank_bend": ("tendon", "crank_bend", "crank bend"),
}
_V1_E_PA, _V1_B_M, _V1_R_M = 71.7e9, 8e-3, 1e-3


@dataclass(frozen=True)
class Tolerance:
    """One toleranced quantity: uniform on ``nominal +/- half_width`` (in ``unit``), with its source.

    ``name``: ``thickness.{chain}_{notch}``, ``radius.{chain}_{notch}``, ``width.{chain}_{link}``,
    ``target_mass`` or ``piezo_gain.{chain}``; ``group``: its sensitivity group.
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
    """Independent tolerances of one stage layout (``"v2"``: geometry-built, ``"v1"``: lumped springs)."""

    tolerances: tuple
    layout: str = "v2"

    @property
    def names(self) -> tuple[str, ...]:
        """Variable names, in the order of :meth:`normalized`."""
        return tuple(t.name for t in self.tolerances)

    @property
    def groups(self) -> tuple[str, ...]:
        """Distinct sensitivity groups, in first-appearance order."""
        return tuple(dict.fromkeys(t.group for t in self.tolerances))

    def sample(self, seed: int, index: int) -> dict[str, float]:
        """Sample ``index`` of the population with master ``seed`` (the same whatever the population size)."""
        for name, v in (("seed", seed), ("index", index)):
            if isinstance(v, bool) or not isinstance(v, (int, np.integer)) or v < 0:
                raise ValueError(f"{name}: expected a non-negative integer, got {v!r}")
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
        """JSON form: the layout and every tolerance with its distribution and source."""
        return {"layout": self.layout, "tolerances": [t.to_dict() for t in self.tolerances]}


def notch_stiffness_ratio(t_m: float, t0_m: float, R_m: float = 1.0, R0_m: float = 1.0) -> float:
    """``k / k0 = (t / t0)^(5/2) (R0 / R)^(1/2)`` (Paros & Weisbord, circular notch, t << R)."""
    if not (t_m > 0 and t0_m > 0 and R_m > 0 and R0_m > 0):
        raise ValueError(f"notch_stiffness_ratio: expected positive lengths, got t={t_m}, t0={t0_m}, R={R_m}, "
                         f"R0={R0_m}")
    return (t_m / t0_m) ** 2.5 * math.sqrt(R0_m / R_m)


def _layout(model: mujoco.MjModel) -> str:
    return "v1" if mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_TENDON, "a_crank_bend") >= 0 else "v2"


def _v1_symmetric(model: mujoco.MjModel) -> dict[str, tuple[float, float]]:
    """(stiffness, damping) of every v1 chain element at the median of the three chains."""
    out = {}
    for kind, suffix, _ in set(V1_NOTCHES.values()):
        if kind == "joint":
            ids = [model.joint(f"{c}_{suffix}").id for c in CHAINS]
            k = [model.jnt_stiffness[i] for i in ids]
            d = [model.dof_damping[model.jnt_dofadr[i]] for i in ids]
        else:
            ids = [model.tendon(f"{c}_{suffix}").id for c in CHAINS]
            k, d = [model.tendon_stiffness[i] for i in ids], [model.tendon_damping[i] for i in ids]
        out[f"{kind}:{suffix}"] = (float(np.median(k)), float(np.median(d)))
    return out


def _notches(layout: str, model) -> list[tuple[str, str, float, float]]:
    """``(notch, group, nominal t [m], nominal R [m])`` of one chain."""
    if layout == "v1":
        sym = _v1_symmetric(model)
        rows = []
        for notch, (kind, suffix, family) in V1_NOTCHES.items():
            lumped = sum(1 for v in V1_NOTCHES.values() if v[:2] == (kind, suffix))
            k = sym[f"{kind}:{suffix}"][0] / lumped      # Paros-Weisbord, inverted (mjcf/v1 README "Hinges")
            t = (9.0 * math.pi * math.sqrt(_V1_R_M) * k / (2.0 * _V1_E_PA * _V1_B_M)) ** 0.4
            rows.append((notch, family, t, _V1_R_M))
        return rows
    from nanosim.plant.geometry import CALIBRATED_GEOMETRY as G, HINGE_FAMILIES

    rows = []
    for family, names in HINGE_FAMILIES.items():
        # the symmetric stage: each family at the mean of the calibrated chains' webs
        t = float(np.mean([G.notch(f"{c}_{names[0]}").thickness_m for c in CHAINS]))
        rows += [(n, family, t, G.chain.notch(family).radius_m) for n in names]
    return rows


def default_tolerances(model: mujoco.MjModel | None = None) -> ToleranceModel:
    """The tolerance model of a stage (see the module docstring).

    Parameters
    ----------
    model : MjModel, optional
        The stage (default: the bundled one); its layout picks the notch list.
    """
    model = load_model() if model is None else model
    layout = _layout(model)
    notches = _notches(layout, model)
    tols = []
    for c in CHAINS:
        for notch, family, t0, _ in notches:
            tols.append(Tolerance(f"thickness.{c}_{notch}", f"notch thickness, {family}", t0 * 1e6,
                                  EDM_TOLERANCE_M * 1e6, "um", _EDM_SOURCE))
    for c in CHAINS:
        for notch, _, _, R0 in notches:
            tols.append(Tolerance(f"radius.{c}_{notch}", "notch radius", R0 * 1e6, EDM_TOLERANCE_M * 1e6, "um",
                                  _EDM_SOURCE))
    for c in CHAINS:
        for link in LINK_BODIES:
            if mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, f"{c}_{link}") >= 0:
                tols.append(Tolerance(f"width.{c}_{link}", "link width", _LINK_WIDTH_M * 1e6, EDM_TOLERANCE_M * 1e6,
                                      "um", _EDM_SOURCE + "; link mass ~ width"))
    table = float(model.body_mass[model.body("table").id])
    tols.append(Tolerance("target_mass", "target mass", table * 1e3, 0.02 * table * 1e3, "g",
                          "assumption [E]: machined target and mount, +/-2 % (fasteners, adhesive)"))
    for c in CHAINS:
        tols.append(Tolerance(f"piezo_gain.{c}", "piezo gain", 1.0, 0.10, "-",
                              "assumption [E]: +/-10 % unit-to-unit stroke per volt (no APA35XS datasheet "
                              "spread in reach, mjcf/SOURCES.md item 1)"))
    return ToleranceModel(tuple(tols), layout)


def model_from_geometry(g, **load_kw) -> mujoco.MjModel:
    """Compile a :class:`~nanosim.plant.geometry.StageGeometry` exactly as the bundled stage is
    (:func:`nanosim.plant.build.stage_xml`, loaded through :func:`~nanosim.plant.mjcf.load_model` with
    ``load_kw``: ``stiffness_scale``, ``body_mass_kg``).
    """
    from nanosim.plant.build import SCENE_XML, stage_xml

    with tempfile.TemporaryDirectory(prefix="nanosim-stage-") as tmp:
        (Path(tmp) / "pkxyz_stage.xml").write_text(stage_xml(g))
        (Path(tmp) / "scene.xml").write_text(SCENE_XML)
        return load_model(Path(tmp) / "scene.xml", **load_kw)


def _v2_model(values: Mapping[str, float], tm: ToleranceModel) -> mujoco.MjModel:
    """The geometry-built stage with the sample's notch deviations (symmetric nominal otherwise)."""
    from nanosim.plant.geometry import CALIBRATED_GEOMETRY

    nom = {t.name: t.nominal for t in tm.tolerances}
    dev = []
    for name in tm.names:
        if name.startswith("thickness."):
            hinge = name.split(".", 1)[1]
            t = values[name] * 1e-6
            R, R0 = values[f"radius.{hinge}"] * 1e-6, nom[f"radius.{hinge}"] * 1e-6
            family_web_m = CALIBRATED_GEOMETRY.design_notch(hinge).thickness_m
            dev.append((hinge, t * (R0 / R) ** 0.2 - family_web_m))          # same bending stiffness as (t, R)
    return model_from_geometry(CALIBRATED_GEOMETRY.with_(thickness_deviation_m=tuple(sorted(dev))))


def _v1_model(values: Mapping[str, float], tm: ToleranceModel, mjcf) -> mujoco.MjModel:
    nom = {t.name: t.nominal for t in tm.tolerances}
    base = load_model(mjcf)
    sym = _v1_symmetric(base)
    ratios: dict[tuple[str, str, str], list[float]] = {}
    for c in CHAINS:
        for notch, (kind, suffix, _) in V1_NOTCHES.items():
            h = f"{c}_{notch}"
            ratios.setdefault((kind, c, suffix), []).append(notch_stiffness_ratio(
                values[f"thickness.{h}"], nom[f"thickness.{h}"], values[f"radius.{h}"], nom[f"radius.{h}"]))
    scale = {f"{c}_{suffix}": sym[f"tendon:{suffix}"][0] / float(base.tendon_stiffness[base.tendon(f"{c}_{suffix}").id])
             * float(np.mean(r)) for (kind, c, suffix), r in ratios.items() if kind == "tendon"}
    model = load_model(mjcf, stiffness_scale=scale)
    for (kind, c, suffix), r in ratios.items():
        if kind == "joint":
            j = model.joint(f"{c}_{suffix}").id
            k0, d0 = sym[f"joint:{suffix}"]
            model.jnt_stiffness[j] = k0 * float(np.mean(r))
            model.dof_damping[model.jnt_dofadr[j]] = d0 * float(np.mean(r))
    return model


def sample_model(values: Mapping[str, float], tolerances: ToleranceModel, mjcf=None) -> mujoco.MjModel:
    """The MjModel of one fabricated stage: the one place that maps tolerances onto the MJCF.

    Parameters
    ----------
    values : mapping
        ``{name: value}`` from :meth:`ToleranceModel.sample` (or :meth:`ToleranceModel.nominal`).
    tolerances : ToleranceModel
        The model the values belong to.
    mjcf : path, optional
        A v1 stage MJCF (default: the bundled geometry-built stage, rebuilt from the sample).
    """
    missing = [n for n in tolerances.names if n not in values]
    if missing:
        raise ValueError(f"values: expected a value for every tolerance, missing {missing[:3]}")
    if tolerances.layout == "v2":
        if mjcf is not None:
            raise ValueError("mjcf: a geometry-built stage is rebuilt from its geometry; pass no --mjcf "
                             "(or a v1 MJCF with lumped springs)")
        model = _v2_model(values, tolerances)
    else:
        model = _v1_model(values, tolerances, mjcf)
    nom = {t.name: t.nominal for t in tolerances.tolerances}
    masses = {"table": values["target_mass"] * 1e-3}
    for name in tolerances.names:
        if name.startswith("width."):
            body = name.split(".", 1)[1]
            masses[body] = float(model.body_mass[model.body(body).id]) * values[name] / nom[name]
    for body, m in masses.items():       # as load_model(body_mass_kg=...): inertia scales with the mass
        bid = model.body(body).id
        model.body_inertia[bid] *= m / model.body_mass[bid]
        model.body_mass[bid] = m
    mujoco.mj_setConst(model, mujoco.MjData(model))
    for c in CHAINS:
        model.actuator_gainprm[model.actuator(f"piezo_{c}").id, 0] *= values[f"piezo_gain.{c}"]
    return model


def sample_models(tolerances: ToleranceModel, seed: int, indices: Sequence[int], mjcf=None) -> list:
    """``[sample_model(tolerances.sample(seed, i), tolerances, mjcf) for i in indices]``."""
    return [sample_model(tolerances.sample(seed, i), tolerances, mjcf) for i in indices]
