"""MJCF geoms -> viser primitive descriptions (pure, no server).

viser sends float32 and the stage is ~0.1 m across, so every length is
converted to millimetres (``MM = 1000``). Each geom is described in its
body's frame; the viewer creates one scene frame per body and moves only the
body frames, so a scene update is ``nbody`` poses, not ``ngeom``.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import mujoco
import numpy as np

__all__ = ["MM", "GeomSpec", "HingeSpec", "TendonSpec", "geom_color", "quat_z_to", "capsule_mesh", "geom_specs",
           "hinge_specs", "tendon_specs", "tendon_segments_mm", "body_poses_mm", "heat_color"]

MM = 1000.0  # metres -> millimetres

# colours (RGB 0..255) by MJCF material name; unknown materials use the MJCF rgba
MATERIAL_COLORS = {
    "link": (184, 188, 199),     # light grey flexure links
    "table": (120, 140, 185),    # slate-blue moving table
    "target": (235, 160, 40),    # orange target cube
    "piezo": (40, 90, 205),      # blue piezo actuators / levers
    "probe": (45, 175, 80),      # green capacitive probes
    "base": (85, 85, 92),        # dark grey base and mounts
}
HINGE_COLOR = (200, 40, 160)     # magenta hinge markers
TENDON_COLOR = (30, 110, 255)    # piezo stacks drawn as lines
DEFAULT_COLOR = (200, 200, 200)

_GEOM_KIND = {
    int(mujoco.mjtGeom.mjGEOM_SPHERE): "sphere",
    int(mujoco.mjtGeom.mjGEOM_CAPSULE): "capsule",
    int(mujoco.mjtGeom.mjGEOM_ELLIPSOID): "ellipsoid",
    int(mujoco.mjtGeom.mjGEOM_CYLINDER): "cylinder",
    int(mujoco.mjtGeom.mjGEOM_BOX): "box",
    int(mujoco.mjtGeom.mjGEOM_MESH): "mesh",
}


@dataclass(frozen=True)
class GeomSpec:
    """One geom as a viser primitive, in its body frame, lengths in mm.

    kind : 'box' (dims = full extents), 'cylinder' (radius, height = full
        length along local z), 'capsule' (radius, length = cylinder part along
        local z; drawn as a mesh), 'sphere' (radius), 'ellipsoid' (radii),
        'mesh' (vertices, faces).
    """

    name: str
    body: int
    kind: str
    pos_mm: np.ndarray
    wxyz: np.ndarray
    color: tuple[int, int, int]
    material: str
    dims_mm: np.ndarray = field(default_factory=lambda: np.zeros(3))
    vertices_mm: np.ndarray | None = None
    faces: np.ndarray | None = None


@dataclass(frozen=True)
class HingeSpec:
    """A hinge joint marker: short cylinder on the joint axis, in the body frame."""

    name: str
    joint: int              # joint whose angle is the notch's bending (-1: none)
    body: int
    pos_mm: np.ndarray
    wxyz: np.ndarray        # rotates +z onto the joint axis
    radius_mm: float
    length_mm: float


@dataclass(frozen=True)
class TendonSpec:
    """A spatial tendon drawn as line segments between consecutive sites."""

    name: str
    sites: tuple[int, ...]


def _name(model, objtype, i, prefix):
    n = mujoco.mj_id2name(model, objtype, i)
    return n if n else f"{prefix}{i}"


def geom_color(model: mujoco.MjModel, g: int) -> tuple[tuple[int, int, int], str]:
    """(RGB colour, material name) of geom ``g``."""
    mat = int(model.geom_matid[g])
    if mat >= 0:
        mname = _name(model, mujoco.mjtObj.mjOBJ_MATERIAL, mat, "mat")
        if mname in MATERIAL_COLORS:
            return MATERIAL_COLORS[mname], mname
        rgba = model.mat_rgba[mat]
    else:
        mname, rgba = "", model.geom_rgba[g]
    return tuple(int(round(255 * c)) for c in rgba[:3]), mname


def quat_z_to(axis: np.ndarray) -> np.ndarray:
    """Unit quaternion (wxyz) rotating +z onto ``axis``."""
    a = np.asarray(axis, float)
    a = a / np.linalg.norm(a)
    z = np.array([0.0, 0.0, 1.0])
    c = float(z @ a)
    if c < -1 + 1e-12:
        return np.array([0.0, 1.0, 0.0, 0.0])
    v = np.cross(z, a)
    q = np.array([1.0 + c, *v])
    return q / np.linalg.norm(q)


def capsule_mesh(radius: float, length: float, n_around: int = 16, n_cap: int = 4):
    """(vertices, faces) of a capsule along z: cylinder part ``length``, centred."""
    rings = []
    # bottom cap (south pole up to equator), then top cap (equator to north pole)
    for k in range(n_cap + 1):
        phi = -np.pi / 2 + (np.pi / 2) * k / n_cap
        rings.append((radius * np.cos(phi), -length / 2 + radius * np.sin(phi)))
    for k in range(n_cap + 1):
        phi = (np.pi / 2) * k / n_cap
        rings.append((radius * np.cos(phi), length / 2 + radius * np.sin(phi)))
    th = np.linspace(0, 2 * np.pi, n_around, endpoint=False)
    verts = np.array([(r * np.cos(t), r * np.sin(t), z) for r, z in rings for t in th])
    faces = []
    nr = len(rings)
    for i in range(nr - 1):
        for j in range(n_around):
            a = i * n_around + j
            b = i * n_around + (j + 1) % n_around
            c = (i + 1) * n_around + j
            d = (i + 1) * n_around + (j + 1) % n_around
            faces += [(a, b, d), (a, d, c)]
    return verts.astype(np.float32), np.array(faces, dtype=np.uint32)


def geom_specs(model: mujoco.MjModel, include_groups=(0, 1, 2)) -> list[GeomSpec]:
    """Every visible geom of supported type as a :class:`GeomSpec` (mm)."""
    out = []
    for g in range(model.ngeom):
        kind = _GEOM_KIND.get(int(model.geom_type[g]))
        if kind is None or int(model.geom_group[g]) not in include_groups:
            continue
        size = model.geom_size[g] * MM
        color, mname = geom_color(model, g)
        kw = {}
        if kind == "box":
            dims = 2 * size
        elif kind == "cylinder":
            dims = np.array([size[0], 2 * size[1], 0.0])
        elif kind == "capsule":
            dims = np.array([size[0], 2 * size[1], 0.0])
        elif kind == "sphere":
            dims = np.array([size[0], 0.0, 0.0])
        elif kind == "ellipsoid":
            dims = size.copy()
        else:  # mesh
            m = int(model.geom_dataid[g])
            va, vn = model.mesh_vertadr[m], model.mesh_vertnum[m]
            fa, fn = model.mesh_faceadr[m], model.mesh_facenum[m]
            kw["vertices_mm"] = (model.mesh_vert[va:va + vn] * MM).astype(np.float32)
            kw["faces"] = model.mesh_face[fa:fa + fn].astype(np.uint32)
            dims = np.ptp(kw["vertices_mm"], axis=0)
        out.append(GeomSpec(name=_name(model, mujoco.mjtObj.mjOBJ_GEOM, g, "geom"),
                            body=int(model.geom_bodyid[g]), kind=kind,
                            pos_mm=model.geom_pos[g] * MM, wxyz=model.geom_quat[g].copy(),
                            color=color, material=mname, dims_mm=np.asarray(dims, float), **kw))
    return out


def _notch_joint(model: mujoco.MjModel, notch_site_name: str) -> int:
    """The joint whose rotation is the notch's bending angle (-1 if the model has none)."""
    stem = notch_site_name[: -len("_notch")]
    ch, notch = stem.split("_", 1)
    carriers = {"follower_top": "follower_base", "rocker_n_top": "rocker_n_base", "rocker_n_base": "rocker_n_top",
                "apa_crank": "crank_base", "apa_base": "crank_base"}
    for name in (f"{stem}_bend", f"{ch}_{carriers.get(notch, notch)}_bend"):
        j = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_JOINT, name)
        if j >= 0:
            return j
    return -1


def hinge_specs(model: mujoco.MjModel, radius_mm: float = 1.6, length_mm: float = 3.0) -> list[HingeSpec]:
    """A marker for every flexure hinge.

    Stage v2 models carry one cylinder site per notch (``{chain}_{notch}_notch``: radius = cut radius,
    length = notch width, axis = bending axis), drawn at its true size; older models get a marker of
    the given size on every hinge joint.
    """
    out = []
    for i in range(model.nsite):
        name = _name(model, mujoco.mjtObj.mjOBJ_SITE, i, "site")
        if name.endswith("_notch") and model.site_type[i] == mujoco.mjtGeom.mjGEOM_CYLINDER:
            out.append(HingeSpec(name=name, joint=_notch_joint(model, name), body=int(model.site_bodyid[i]),
                                 pos_mm=model.site_pos[i] * MM, wxyz=model.site_quat[i].copy(),
                                 radius_mm=float(model.site_size[i, 0] * MM),
                                 length_mm=float(2 * model.site_size[i, 1] * MM)))
    if out:
        return out
    for j in range(model.njnt):
        if model.jnt_type[j] != mujoco.mjtJoint.mjJNT_HINGE:
            continue
        out.append(HingeSpec(name=_name(model, mujoco.mjtObj.mjOBJ_JOINT, j, "joint"), joint=j,
                             body=int(model.jnt_bodyid[j]), pos_mm=model.jnt_pos[j] * MM,
                             wxyz=quat_z_to(model.jnt_axis[j]), radius_mm=radius_mm, length_mm=length_mm))
    return out


def tendon_specs(model: mujoco.MjModel, suffix: str = "_piezo") -> list[TendonSpec]:
    """Spatial tendons whose name ends with ``suffix``, as site chains."""
    out = []
    for t in range(model.ntendon):
        name = _name(model, mujoco.mjtObj.mjOBJ_TENDON, t, "tendon")
        if not name.endswith(suffix):
            continue
        adr, num = model.tendon_adr[t], model.tendon_num[t]
        sites = tuple(int(model.wrap_objid[w]) for w in range(adr, adr + num)
                      if model.wrap_type[w] == mujoco.mjtWrap.mjWRAP_SITE)
        if len(sites) >= 2:
            out.append(TendonSpec(name=name, sites=sites))
    return out


def tendon_segments_mm(specs: list[TendonSpec], site_xpos: np.ndarray) -> np.ndarray:
    """(nseg, 2, 3) float32 line segments (mm) for the tendons from site positions (m)."""
    segs = [(site_xpos[s0], site_xpos[s1]) for sp in specs for s0, s1 in zip(sp.sites[:-1], sp.sites[1:])]
    if not segs:
        return np.zeros((0, 2, 3), np.float32)
    return (np.asarray(segs) * MM).astype(np.float32)


def body_poses_mm(data: mujoco.MjData) -> tuple[np.ndarray, np.ndarray]:
    """(positions mm (nbody, 3), wxyz (nbody, 4)) of all bodies from ``data``."""
    return data.xpos * MM, data.xquat.copy()


def heat_color(x: float) -> tuple[int, int, int]:
    """Colour for a value in [0, 1]: blue (0) -> yellow -> red (1)."""
    x = float(np.clip(x, 0.0, 1.0))
    stops = np.array([[40, 60, 200], [240, 220, 40], [220, 30, 30]], float)
    if x < 0.5:
        c = stops[0] + (stops[1] - stops[0]) * (x / 0.5)
    else:
        c = stops[1] + (stops[2] - stops[1]) * ((x - 0.5) / 0.5)
    return tuple(int(v) for v in c)
