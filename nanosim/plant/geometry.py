"""Parametric geometry of the monolithic PKXYZ flexure (paper Sec. 2), SI units in every name.

The part is three identical kinematic chains around a triangular table (paper
Sec. 2, Fig. 1). Chain k stands at azimuth psi_k = phi_k + 180 deg, where
(phi_k, eps) are the azimuth and elevation of row k of inv(J) (the paper's
Jacobian, Eq. 2): the chain is stiff along u_k and compliant across it, so
u_k . p = cos(eps) * (foot displacement). In the chain frame (x radially
outward, y tangential = ``a``, z up) a chain is, from the base:

1. **Four-bar 1** (parallelogram, actuated): crank and follower rockers,
   vertical, ``fb1_length_m`` long and ``fb1_spacing_m`` apart, four notches
   with axes along y; its coupler (the *foot*, a block) translates radially.
2. **APA35XS** between two notch hinges (paper Sec. 2: "mounted between two
   hinges, one on the crank of the four-bar mechanism and the other on the
   base"), horizontal, normal to the crank, pushing it ``apa_arm_m`` above the
   crank's base notch; the lever ratio is fb1_length / apa_arm.
3. **h1**, a notch with axis along y on top of the foot (the "out-of-plane
   rotation" between the four-bars).
4. **Four-bar 2** (the leg, parallelogram): two rockers along u_k at
   y = +/- ``leg_half_spacing_m``, notches with axes w = u x y, between a leg
   base block (on h1) and a leg top block; its coupler translates along y.
5. **h2**, a notch with axis along y, from the leg top to a vertex of the table.

The table is an equilateral plate; the target cube stands on a cylindrical
mount at its centre. Every mass and inertia follows from these solids at the
alloy's density (the APA from its own mass, see :class:`ActuatorSpec`).
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field, replace

import numpy as np

from nanosim import constants as C
from nanosim.plant.hinges import AL_7075_T6, Material, NotchHinge

__all__ = ["CHAINS", "HINGE_FAMILIES", "Section", "TableGeometry", "ChainGeometry", "ActuatorSpec",
           "StageGeometry", "DEFAULT_GEOMETRY", "CALIBRATED_GEOMETRY", "tripod_from_jacobian", "chain_points",
           "notch_frames"]

CHAINS = ("a", "b", "c")
# notch families -> notch names within a chain
HINGE_FAMILIES = {
    "fb1": ("crank_base", "crank_top", "follower_base", "follower_top"),
    "fb2": ("rocker_p_base", "rocker_p_top", "rocker_n_base", "rocker_n_top"),
    "swing": ("h1", "h2"),
    "apa": ("apa_base", "apa_crank"),
}


def tripod_from_jacobian(J: np.ndarray = C.JACOBIAN_J) -> tuple[tuple[float, float, float], float]:
    """Leg azimuths (deg) and common elevation (deg) from the rows of inv(J).

    The three rows of inv(J) have equal norm and elevation to 4 digits and azimuths
    120 deg apart (a symmetric tripod); the symmetric tripod fitted to them is returned.
    """
    rows = np.linalg.inv(np.asarray(J, float))
    az = np.degrees(np.arctan2(rows[:, 1], rows[:, 0]))
    el = np.degrees(np.arcsin(rows[:, 2] / np.linalg.norm(rows, axis=1)))
    offset = np.degrees(np.angle(np.mean(np.exp(1j * np.radians(az - np.array([0.0, -240.0, -120.0]))))))
    azimuths = tuple(float((offset + d + 180.0) % 360.0 - 180.0) for d in (0.0, -240.0, -120.0))
    return azimuths, float(np.mean(el))


@dataclass(frozen=True)
class Section:
    """Rectangular link cross-section: ``width_m`` along the link's hinge axes, ``thickness_m`` across."""

    width_m: float
    thickness_m: float


@dataclass(frozen=True)
class TableGeometry:
    """Triangular table, target cube and its mount."""

    hinge_radius_m: float = 4.0e-3          # h2 notches on this circle (table vertices)
    plate_thickness_m: float = 4.3e-3
    lug_length_m: float = 2.0e-3            # plate piece at each vertex that carries the h2 notch
    lug_width_m: float = 3.0e-3
    mount_diameter_m: float = 4.0e-3        # cylindrical post under the cube
    mount_height_m: float = 5.5e-3
    target_side_m: float = 14.7e-3          # polished cube read by the three gauges (paper Sec. 2)
    target_density_kg_per_m3: float = AL_7075_T6.density_kg_per_m3
    probe_gap_m: float = 0.5e-3             # gauge face to target face at rest
    probe_z_zero_offset_m: float = 25e-6    # Z gauge zeroed 25 um above rest (mid-stroke, see mjcf/README.md)


@dataclass(frozen=True)
class ChainGeometry:
    """One kinematic chain (all three are equal up to the fabrication deviations)."""

    fb1_length_m: float = 30.0e-3           # rocker length, base notch -> top notch
    fb1_spacing_m: float = 13.2e-3          # crank-follower distance (radial)
    fb1_rocker: Section = Section(11.6e-3, 2.0e-3)
    foot: Section = Section(11.6e-3, 10.5e-3)  # width (y) x height (z)
    foot_overhang_m: float = 1.0e-3         # foot extends past each rocker
    crank_pivot_height_m: float = 4.0e-3    # base notches above the base plate top
    apa_arm_m: float = 2.5e-3               # APA line above the crank's base notch
    leg_length_m: float = 29.4e-3           # h1 -> h2 along u (rockers: this - 2 (R_swing + block + R_fb2))
    leg_half_spacing_m: float = 2.7e-3      # four-bar 2 rockers at y = +/- this
    leg_offset_m: float = 3.5e-3            # chain plane offset from the stage axis along y (pinwheel)
    fb2_rocker: Section = Section(3.0e-3, 1.65e-3)  # width along w, thickness along y
    leg_block: Section = Section(6.0e-3, 4.2e-3)    # leg base/top blocks: width along w, depth along u
    fb1_notch: NotchHinge = NotchHinge(0.30e-3, 1.07e-3, 11.6e-3)
    fb2_notch: NotchHinge = NotchHinge(0.08e-3, 1.07e-3, 3.0e-3)
    swing_notch: NotchHinge = NotchHinge(0.175e-3, 1.07e-3, 2.55e-3)
    apa_notch: NotchHinge = NotchHinge(0.40e-3, 1.07e-3, 6.0e-3)

    def notch(self, family: str) -> NotchHinge:
        """The nominal notch of a hinge family (``fb1``, ``fb2``, ``swing``, ``apa``)."""
        return {"fb1": self.fb1_notch, "fb2": self.fb2_notch, "swing": self.swing_notch,
                "apa": self.apa_notch}[family]


@dataclass(frozen=True)
class ActuatorSpec:
    """Cedrat APA35XS amplified piezo actuator.

    Free stroke, blocked force and maximum voltage: paper Sec. 2 (55 um, 27 N,
    150 V); stiffness = blocked force / free stroke. The mass and outline are
    estimates (no datasheet in reach; XS-series outline about 15 x 9 x 6 mm):
    ``mass_kg`` is bounded in mjcf/README.md. Split: the moving end carries one
    third of the actuator (Rayleigh's effective mass of a uniform spring fixed
    at the other end), the base-side body the rest.
    """

    free_stroke_m: float = C.PIEZO_FREE_STROKE_M
    blocked_force_N: float = C.PIEZO_BLOCKING_FORCE_N
    max_voltage_V: float = C.PIEZO_MAX_V
    mass_kg: float = 2.5e-3
    moving_fraction: float = 1.0 / 3.0
    length_m: float = 15.0e-3               # hinge centre to hinge centre
    width_m: float = 9.0e-3                 # along y
    height_m: float = 6.0e-3                # along z

    @property
    def stiffness_N_per_m(self) -> float:
        """Axial stiffness, blocked force / free stroke."""
        return self.blocked_force_N / self.free_stroke_m

    @property
    def force_per_volt_N(self) -> float:
        """Blocked force per piezo volt (the actuator's force source per free-strain volt)."""
        return self.blocked_force_N / self.max_voltage_V


@dataclass(frozen=True)
class StageGeometry:
    """The whole stage: material, table, chains, actuators and fabrication deviations.

    thickness_deviation_m : ((hinge name, dt), ...) -- per-notch deviation of the minimum
        thickness from nominal, e.g. ``(("a_h1", 4e-6),)``; hinge names are
        ``{chain}_{notch}`` with notch names from :data:`HINGE_FAMILIES`.
    """

    material: Material = AL_7075_T6
    table: TableGeometry = field(default_factory=TableGeometry)
    chain: ChainGeometry = field(default_factory=ChainGeometry)
    actuator: ActuatorSpec = field(default_factory=ActuatorSpec)
    thickness_deviation_m: tuple[tuple[str, float], ...] = ()
    base_plate_thickness_m: float = 4.0e-3

    def with_(self, **kw) -> "StageGeometry":
        """A copy with top-level fields replaced."""
        return replace(self, **kw)

    def with_chain(self, **kw) -> "StageGeometry":
        """A copy with chain fields replaced."""
        return replace(self, chain=replace(self.chain, **kw))

    def with_table(self, **kw) -> "StageGeometry":
        """A copy with table fields replaced."""
        return replace(self, table=replace(self.table, **kw))

    def design_notch(self, hinge_name: str) -> NotchHinge:
        """The notch ``{chain}_{name}``'s family design notch (no fabrication deviation)."""
        ch, name = hinge_name.split("_", 1)
        if ch not in CHAINS:
            raise ValueError(f"hinge name {hinge_name!r}: expected '<chain>_<notch>' with chain in {CHAINS}")
        fam = next((f for f, names in HINGE_FAMILIES.items() if name in names), None)
        if fam is None:
            raise ValueError(f"hinge name {hinge_name!r}: unknown notch {name!r}")
        return self.chain.notch(fam)

    def notch(self, hinge_name: str) -> NotchHinge:
        """The notch ``{chain}_{name}`` with its fabrication deviation applied."""
        nominal = self.design_notch(hinge_name)
        dt = dict(self.thickness_deviation_m).get(hinge_name, 0.0)
        return nominal.with_thickness(nominal.thickness_m + dt) if dt else nominal

    @property
    def tripod(self) -> tuple[tuple[float, float, float], float]:
        """(leg azimuths deg, elevation deg) from the paper's Jacobian."""
        return tripod_from_jacobian()


# The nominal design (the design study of nanosim.plant.calibrate.DESIGN_PARAMS, rounded to machinable values).
DEFAULT_GEOMETRY = StageGeometry()


def _calibrated() -> StageGeometry:
    """The bundled stage: nominal design + the calibration of nanosim.plant.calibrate.CALIBRATION_PARAMS.

    Every value below is inside its stated bound (mjcf/README.md): each chain's notch webs within
    +/-10 um of their design value (standard wire EDM; one bound on the total, so the chains'
    differences -- the asymmetry that splits the XY pairs -- stay inside it), cut radius within
    +/-10 um, link widths within +/-0.1 mm, target mass within +/-10 %, each bound read as a 2-sigma
    tolerance (a Gaussian prior on the deviation, ``calibrate.fit(..., prior=2)``), so none sits on its
    bound. The targets are the paper's modes unwarped (``nanosim.paper.STAGE_MODES_HZ``). The family
    values stay at the design webs; each chain's web is stored as its deviation. Reproduce with
    ``python tools/calibrate_stage.py`` (the best of twelve starts).
    """
    g = DEFAULT_GEOMETRY
    c = g.chain
    R = 1.071e-3
    b1, b2 = 11.596e-3, 2.988e-3
    ch = replace(c, fb1_rocker=replace(c.fb1_rocker, width_m=b1), foot=replace(c.foot, width_m=b1),
                 fb2_rocker=replace(c.fb2_rocker, width_m=b2),
                 fb1_notch=NotchHinge(c.fb1_notch.thickness_m, R, b1),
                 fb2_notch=NotchHinge(c.fb2_notch.thickness_m, R, b2),
                 swing_notch=NotchHinge(c.swing_notch.thickness_m, R, c.swing_notch.width_m),
                 apa_notch=NotchHinge(c.apa_notch.thickness_m, R, c.apa_notch.width_m))
    web_um = {"a_fb1": 296.1, "a_fb2": 77.5, "a_swing": 172.7, "a_apa": 399.0,
              "b_fb1": 293.8, "b_fb2": 83.3, "b_swing": 185.0, "b_apa": 398.3,
              "c_fb1": 302.8, "c_fb2": 78.5, "c_swing": 172.9, "c_apa": 400.7}
    dev = {key: round(t * 1e-6 - c.notch(key[2:]).thickness_m, 12) for key, t in web_um.items()}
    per_notch = tuple(sorted((f"{key[0]}_{n}", dt) for key, dt in dev.items() for n in HINGE_FAMILIES[key[2:]]
                             if dt != 0.0))
    return replace(g, chain=ch, table=replace(g.table, target_side_m=14.834e-3), thickness_deviation_m=per_notch)


CALIBRATED_GEOMETRY = _calibrated()


def chain_points(g: StageGeometry) -> dict[str, np.ndarray]:
    """Notch centres (m) of one chain in its own frame, its unit vectors u, y, w and the table height.

    Origin on the stage axis at the base plate's top face. Every link starts one cut
    radius from the centre of the notch it hangs on (the notch's cuts span +/- R along
    its web).
    """
    c, t = g.chain, g.table
    _, el = g.tripod
    eps = math.radians(el)
    u = np.array([-math.cos(eps), 0.0, math.sin(eps)])     # leg: foot -> table
    y = np.array([0.0, 1.0, 0.0])
    w = np.cross(u, y)                                      # four-bar 2 hinge axis
    r1, rs, r2 = c.fb1_notch.radius_m, c.swing_notch.radius_m, c.fb2_notch.radius_m
    ra = c.apa_notch.radius_m
    depth = c.leg_block.thickness_m
    leg = c.leg_length_m
    z_ct = c.crank_pivot_height_m + c.fb1_length_m
    z_foot_top = z_ct + r1 + c.foot.thickness_m
    off = c.leg_offset_m
    if abs(off) >= t.hinge_radius_m:
        raise ValueError(f"leg_offset_m: expected |offset| < table hinge radius {t.hinge_radius_m}, got {off}")
    h2_x = math.sqrt(t.hinge_radius_m ** 2 - off ** 2)
    h1_x = h2_x - leg * u[0]
    foot_top = np.array([h1_x - rs * u[0], off, z_foot_top])
    h1 = foot_top + rs * u
    h2 = h1 + leg * u
    crank_x = foot_top[0] + c.fb1_spacing_m / 2.0
    crank_base = np.array([crank_x, off, c.crank_pivot_height_m])
    p = {
        "u": u, "y": y, "w": w,
        "table_z": np.array(h2[2]),
        "foot_top": foot_top,
        "crank_base": crank_base,
        "crank_top": crank_base + np.array([0.0, 0.0, c.fb1_length_m]),
        "follower_base": crank_base - np.array([c.fb1_spacing_m, 0.0, 0.0]),
        "follower_top": crank_base + np.array([-c.fb1_spacing_m, 0.0, c.fb1_length_m]),
        "h1": h1, "h2": h2,
    }
    s = c.leg_half_spacing_m * y
    inset = (rs + depth + r2) * u
    p["rocker_p_base"], p["rocker_n_base"] = h1 + inset + s, h1 + inset - s
    p["rocker_p_top"], p["rocker_n_top"] = h2 - inset + s, h2 - inset - s
    x_face = crank_x + c.fb1_rocker.thickness_m / 2.0
    p["apa_crank"] = np.array([x_face + ra, off, c.crank_pivot_height_m + c.apa_arm_m])
    p["apa_base"] = p["apa_crank"] + np.array([g.actuator.length_m + 2.0 * ra, 0.0, 0.0])
    return p


def notch_frames(g: StageGeometry) -> dict[str, tuple[np.ndarray, np.ndarray, np.ndarray]]:
    """Per notch name: (bending axis, out-of-plane axis, torsion axis = web direction), chain frame."""
    p = chain_points(g)
    x, y, z, u, w = np.eye(3)[0], p["y"], np.eye(3)[2], p["u"], p["w"]
    frames = {}
    for n in HINGE_FAMILIES["fb1"]:
        frames[n] = (y, x, z)              # vertical rockers bending about y
    for n in HINGE_FAMILIES["fb2"]:
        frames[n] = (w, y, u)              # leg rockers along u bending about w
    for n in HINGE_FAMILIES["swing"]:
        frames[n] = (y, w, u)              # h1, h2: web along the leg, bending about y
    for n in HINGE_FAMILIES["apa"]:
        frames[n] = (y, z, x)              # APA hinges: web along the APA (x), bending about y
    return frames
