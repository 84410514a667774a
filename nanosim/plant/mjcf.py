"""Load the stage MJCF, check it has what the simulator needs, apply overrides.

Overrides act on the compiled model so they work for any MJCF that follows
the naming convention (chains ``a``, ``b``, ``c``; joints ``{chain}_crank``,
``{chain}_h1``...; actuators ``piezo_{chain}``; sites ``cube_face_{x,y,z}``).
"""
from __future__ import annotations

import os
from pathlib import Path
from typing import Mapping

import mujoco
import numpy as np

from importlib import resources

from nanosim.plant.geometry import HINGE_FAMILIES as GEOMETRY_FAMILIES

__all__ = ["MJCF_DIR", "DEFAULT_MJCF", "FULL_MJCF", "default_mjcf", "load_model", "check_model", "custom_numeric",
           "probe_layout", "update_position_sensors", "probe_readings_um"]

MJCF_DIR = Path(str(resources.files("nanosim.mjcf")))
DEFAULT_MJCF = MJCF_DIR / "scene.xml"           # the simulation model (reduced compliance)
FULL_MJCF = MJCF_DIR / "full" / "scene.xml"     # every notch compliant in bending, out-of-plane and torsion

REQUIRED_ACTUATORS = ("piezo_a", "piezo_b", "piezo_c")
REQUIRED_SITES = ("cube_face_x", "cube_face_y", "cube_face_z", "table_center",
                  "probe_x", "probe_y", "probe_z")
REQUIRED_SENSORS = ("probe_x", "probe_y", "probe_z")

# hinge families: joints are named {chain}_{notch}_{bend|oop|tor} (mjcf/README.md); the v1 family
# names still work as aliases
HINGE_FAMILIES = {fam: tuple(notches) for fam, notches in GEOMETRY_FAMILIES.items()}
FAMILY_ALIASES = {"fourbar1": "fb1", "fourbar2": "fb2", "lever": "apa"}


def default_mjcf() -> Path:
    """Bundled scene, or ``$NANOSIM_MJCF`` when set."""
    env = os.environ.get("NANOSIM_MJCF")
    return Path(env) if env else DEFAULT_MJCF


def load_model(path: str | os.PathLike | None = None, *,
               stiffness_scale: Mapping[str, float] | None = None,
               body_mass_kg: Mapping[str, float] | None = None) -> mujoco.MjModel:
    """Compile the stage model and check it.

    Parameters
    ----------
    path : MJCF file; default the bundled ``mjcf/scene.xml``.
    stiffness_scale : {family: factor} scales stiffness and damping of every joint of a
        notch family (``fb1``, ``fb2``, ``swing``; v1 names ``fourbar1``, ``fourbar2`` are
        aliases) in every modelled direction, or of a tendon or joint by name (e.g.
        ``a_piezo``, ``a_crank_base_bend``). The family ``apa`` (v1 name ``lever``) is refused
        with the bundled model: it lumps the APA's notches into the crank joints, so there is
        no joint of that family to scale (scale the crank joints by name instead).
    body_mass_kg : {body: mass} sets a body's mass, scaling its inertia alike.

    Raises
    ------
    FileNotFoundError : the file does not exist.
    ValueError : the XML is malformed or lacks the stage's actuators/sensors,
        or an override names something that does not exist.
    """
    path = Path(path) if path is not None else default_mjcf()
    if not path.is_file():
        raise FileNotFoundError(f"mjcf: no such file {str(path)!r} (expected a MuJoCo XML model)")
    try:
        model = mujoco.MjModel.from_xml_path(str(path))
    except ValueError as exc:
        detail = " ".join(line.strip() for line in str(exc).strip().splitlines()[:2]) or "parse error"
        raise ValueError(f"mjcf: {path} is not a valid MuJoCo model: {detail}") from None
    check_model(model, str(path))
    if stiffness_scale:
        _scale_stiffness(model, stiffness_scale)
    if body_mass_kg:
        for name, mass in body_mass_kg.items():
            bid = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, name)
            if bid < 0:
                raise ValueError(f"body_mass_kg: no body named {name!r} in the model")
            if not (np.isfinite(mass) and mass > 0):
                raise ValueError(f"body_mass_kg[{name!r}]: expected a positive mass in kg, got {mass!r}")
            factor = mass / model.body_mass[bid]
            model.body_mass[bid] = mass
            model.body_inertia[bid] *= factor
        mujoco.mj_setConst(model, mujoco.MjData(model))
    return model


def check_model(model: mujoco.MjModel, origin: str = "model") -> None:
    """Raise ValueError if the model lacks what the stage simulator needs."""
    def missing(objtype, names):
        return [n for n in names if mujoco.mj_name2id(model, objtype, n) < 0]

    for label, objtype, names in (("actuators", mujoco.mjtObj.mjOBJ_ACTUATOR, REQUIRED_ACTUATORS),
                                  ("sites", mujoco.mjtObj.mjOBJ_SITE, REQUIRED_SITES),
                                  ("sensors", mujoco.mjtObj.mjOBJ_SENSOR, REQUIRED_SENSORS)):
        gone = missing(objtype, names)
        if gone:
            raise ValueError(f"mjcf: {origin} lacks the stage's {label} {gone} "
                             f"(expected {list(names)})")


def _scale_stiffness(model: mujoco.MjModel, scale: Mapping[str, float]) -> None:
    for key, factor in scale.items():
        if not (np.isfinite(factor) and factor > 0):
            raise ValueError(f"stiffness_scale[{key!r}]: expected a positive factor, got {factor!r}")
        hit = False
        fam = FAMILY_ALIASES.get(key, key)
        if fam in HINGE_FAMILIES:
            for j in range(model.njnt):
                parts = model.joint(j).name.split("_", 1)
                notch = parts[1].rsplit("_", 1)[0] if len(parts) == 2 else ""
                if notch in HINGE_FAMILIES[fam]:
                    model.jnt_stiffness[j] *= factor
                    model.dof_damping[model.jnt_dofadr[j]] *= factor
                    hit = True
            if not hit:
                raise ValueError(f"stiffness_scale: family {key!r} has no joints in this model (the simulation "
                                 f"model lumps the APA notches on the crank joints); scale the crank joints by name "
                                 f"instead, e.g. {{'a_crank_base_bend': {factor!r}}}")
        else:
            tid = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_TENDON, key)
            jid = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_JOINT, key)
            if tid >= 0:
                model.tendon_stiffness[tid] *= factor
                model.tendon_damping[tid] *= factor
                hit = True
            elif jid >= 0:
                model.jnt_stiffness[jid] *= factor
                model.dof_damping[model.jnt_dofadr[jid]] *= factor
                hit = True
        if not hit:
            raise ValueError(f"stiffness_scale: {key!r} is neither a hinge family "
                             f"{sorted(HINGE_FAMILIES)} nor a tendon or joint of the model")


def custom_numeric(model: mujoco.MjModel, name: str, default) -> np.ndarray:
    """A ``<custom><numeric>`` value from the MJCF, or ``default``."""
    nid = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_NUMERIC, name)
    if nid < 0:
        return np.atleast_1d(np.asarray(default, dtype=float))
    adr, size = model.numeric_adr[nid], model.numeric_size[nid]
    return model.numeric_data[adr:adr + size].copy()


def probe_layout(model: mujoco.MjModel) -> tuple[np.ndarray, np.ndarray]:
    """Sensordata addresses of the X, Y, Z probe-axis components and the bias (m) added to them.

    reading = framepos component + gap - zero offset (``<custom>`` numerics of the MJCF).
    """
    adr = np.array([model.sensor_adr[model.sensor(f"probe_{a}").id] + i for i, a in enumerate("xyz")])
    bias = custom_numeric(model, "probe_gap_m", 0.0)[0] - custom_numeric(model, "probe_zero_offset_m", [0, 0, 0])
    return adr, bias


def update_position_sensors(model: mujoco.MjModel, data: mujoco.MjData) -> None:
    """Recompute position-stage sensors (the probes) for ``data``'s current ``qpos``.

    ``mj_step`` evaluates sensors before it integrates, so after a step ``sensordata`` describes
    the state one substep earlier; this brings the probes to the end of the step (~3 us).
    """
    mujoco.mj_kinematics(model, data)
    mujoco.mj_sensorPos(model, data)


def probe_readings_um(model: mujoco.MjModel, data: mujoco.MjData) -> np.ndarray:
    """Noise-free probe readings (um) of ``data``'s current sensordata."""
    adr, bias = probe_layout(model)
    return (data.sensordata[adr] + bias) * 1e6
