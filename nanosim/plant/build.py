"""Generate the PKXYZ stage MJCF from named geometry and calibrated parameters.

The XML in ``mjcf/`` is produced by :func:`write_stage_xml`; edit
:data:`DEFAULT_PARAMS` (or run ``nanosim calibrate``) and regenerate rather
than hand-editing the XML. All quantities are SI (m, kg, N, s, rad).

Kinematics (see ``mjcf/README.md``): the rows of inv(J) are the leg directions
u_k of a symmetric tripod, azimuth phi_k = 128.5, -111.5, 8.5 deg, elevation
58.63 deg. Chain k stands at azimuth phi_k + 180 deg and its leg (four-bar 2)
rises along +u_k from a foot to the table. Four-bar 1 moves the foot radially
inward, which moves the table along u_k: alpha_k = (u_k . p) / (L1 cos(eps)).
"""
from __future__ import annotations

import math
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from nanosim import constants as C

CHAINS = ("a", "b", "c")
LEG_AZIMUTH_DEG = (128.5, -111.5, 8.5)       # rows of inv(J), paper Eq. 2
LEG_ELEVATION_DEG = 58.63                    # atan(z / r) of the rows of inv(J)


@dataclass(frozen=True)
class StageParams:
    """Geometry (m), materials and calibrated stiffness/damping of the stage."""

    # geometry
    table_radius: float = 10e-3          # circumradius of the triangle's hinge points
    table_thickness: float = 3e-3
    cube_half: float = 4e-3              # target cube, 8 mm
    leg_length: float = 20e-3            # L2: h1 -> h2 along u
    leg_half_width: float = 4e-3         # four-bar 2 rockers at +/- this along a
    fourbar1_length: float = 16e-3       # L1: crank pivot -> coupler
    fourbar1_spacing: float = 10e-3      # crank-follower spacing (radial)
    base_pivot_height: float = 5e-3
    piezo_arm: float = 0.002419              # r_p: crank pivot -> piezo attachment
    piezo_length: float = 20e-3
    rocker_radius: float = 1.2e-3
    # materials (aluminium 7075, paper Sec. 2: monolithic EDM part)
    density: float = 2810.0              # kg/m^3
    link_density_scale: float = 0.3034      # calibrated: lumps flexure blocks not drawn
    table_extra_mass: float = 0.01997     # kg, calibrated
    lever_block_mass: float = 0.01026     # kg, actuator mounting block on the lever (calibrated)
    lever_block_height: float = 14e-3    # m above the lever pivot
    # stiffness (calibrated on the linearization, see nanosim.calibrate)
    k_fourbar1: float = 0.943              # N m/rad per notch hinge
    k_fourbar2: float = 0.3955
    k_swing: float = 0.1527                 # h1 and h2
    k_piezo: float = C.PIEZO_STIFFNESS_N_PER_M
    k_lever: float = 0.1818                 # N m/rad, lever pivot notch hinge
    k_crank_bend: float = 10.75           # N m/rad, lever -> crank (PRB flexible crank)
    # damping: c = beta * k (stiffness-proportional), seconds
    beta_hinge: float = 1.301e-06
    beta_piezo: float = 1.781e-05
    # fabrication imperfection: chain A hinges this much stiffer (XY split)
    chain_a_stiffness_factor: float = 1.14
    # probes
    probe_gap: float = 0.5e-3
    probe_z_zero_offset: float = 25e-6   # Z gauge zeroed mid-stroke (see README)
    # numerics
    timestep: float = 12.5e-6            # 20 substeps per 250 us control period
    closure_timeconst: float = 25e-6     # 2 x timestep (MuJoCo's floor)
    closure_dampratio: float = 0.5       # k = 1/(tau*zeta)^2: stiff closure, little added damping

    def with_(self, **kw) -> "StageParams":
        return replace(self, **kw)


DEFAULT_PARAMS = StageParams()


def notch_hinge_stiffness(E: float, b: float, t: float, R: float) -> float:
    """Rotational stiffness (N m/rad) of a circular notch hinge.

    Paros & Weisbord (1965), simplified for t << R:
    k = 2 E b t^(5/2) / (9 pi R^(1/2)). E in Pa, width b, minimum thickness t
    and cut radius R in m.
    """
    return 2.0 * E * b * t**2.5 / (9.0 * math.pi * math.sqrt(R))


def leg_unit_vectors() -> np.ndarray:
    """(3, 3) rows u_k of the tripod legs in the world frame."""
    eps = math.radians(LEG_ELEVATION_DEG)
    return np.array([[math.cos(eps) * math.cos(math.radians(p)),
                      math.cos(eps) * math.sin(math.radians(p)),
                      math.sin(eps)] for p in LEG_AZIMUTH_DEG])


def _v(x) -> str:
    return " ".join(f"{float(c):.9g}" for c in np.atleast_1d(x))


def _chain_geometry(p: StageParams):
    """Key points of one chain in its local frame (x radial out, y tangential, z up)."""
    eps = math.radians(LEG_ELEVATION_DEG)
    u = np.array([-math.cos(eps), 0.0, math.sin(eps)])         # leg, foot -> table
    a = np.array([0.0, 1.0, 0.0])                              # h1/h2 axis
    w = np.cross(u, a)                                         # four-bar 2 hinge axis
    table_z = p.base_pivot_height + p.fourbar1_length + 2e-3 + p.leg_length * math.sin(eps)
    top = np.array([p.table_radius, 0.0, table_z])             # h2
    bottom = top - p.leg_length * u                            # h1
    crank_x = bottom[0] + p.fourbar1_spacing / 2
    return dict(u=u, a=a, w=w, table_z=table_z, top=top, bottom=bottom, crank_x=crank_x)


def stage_xml(p: StageParams = DEFAULT_PARAMS) -> str:
    """Return the stage MJCF (device only; ``scene.xml`` includes it)."""
    g = _chain_geometry(p)
    u, w = g["u"], g["w"]
    table_z = g["table_z"]
    rho_link = p.density * p.link_density_scale
    L1, L2 = p.fourbar1_length, p.leg_length
    s2 = p.leg_half_width
    z0 = p.base_pivot_height
    foot_z = z0 + L1
    xc = g["crank_x"]
    xf = xc - p.fourbar1_spacing
    bottom = g["bottom"]
    out: list[str] = []
    A = out.append
    A('<mujoco model="pkxyz_stage">')
    A('  <compiler angle="radian" autolimits="true"/>')
    A(f'  <option timestep="{p.timestep:.9g}" integrator="implicitfast" solver="Newton"'
      ' iterations="6" tolerance="1e-10">')
    A('    <flag contact="disable" gravity="disable"/>')
    A('  </option>')
    A('  <size memory="2M"/>')
    A('  <custom>')
    A(f'    <numeric name="probe_gap_m" data="{p.probe_gap:.9g}"/>')
    A(f'    <numeric name="probe_zero_offset_m" data="0 0 {p.probe_z_zero_offset:.9g}"/>')
    A(f'    <numeric name="piezo_force_per_volt_N" data="{C.PIEZO_FORCE_PER_PIEZO_V:.9g}"/>')
    A('  </custom>')
    A('  <default>')
    A('    <default class="pkxyz">')
    A(f'      <equality solref="{p.closure_timeconst:.9g} {p.closure_dampratio:.9g}" solimp="0.9999 0.9999 0.001 0.5 2"/>')
    A(f'      <geom type="capsule" density="{rho_link:.9g}" contype="0" conaffinity="0" material="link"/>')
    A('      <site size="0.6e-3" group="4"/>')
    # Each parallelogram has four notch hinges turning by +/-theta; on the closure
    # manifold follower == crank and h2 == -h1, so the hinge springs are lumped onto
    # the load-path joints (same energy), and followers/tabs carry none: a soft
    # closure cannot hold a spring on a near-massless body.
    hinge_classes = (("fourbar1", 2 * p.k_fourbar1), ("fourbar2", 2 * p.k_fourbar2), ("swing", 2 * p.k_swing))
    for cname, k in hinge_classes:
        A(f'      <default class="{cname}">')
        A(f'        <joint type="hinge" stiffness="{k:.9g}" damping="{p.beta_hinge * k:.9g}"/>')
        A('      </default>')
    A('      <default class="follower">')
    A('        <joint type="hinge" stiffness="0" damping="0"/>')
    A('      </default>')
    A('      <default class="lever">')
    A(f'        <joint type="hinge" stiffness="{p.k_lever:.9g}" damping="{p.beta_hinge * p.k_lever:.9g}"/>')
    A('        <geom type="box" material="piezo"/>')
    A('      </default>')
    A('      <default class="table">')
    A(f'        <geom density="{p.density:.9g}" material="table"/>')
    A('      </default>')
    A('    </default>')
    A('  </default>')
    # triangular prism mesh for the table
    r_tri = p.table_radius * 1.6
    verts = []
    for zz in (-p.table_thickness / 2, p.table_thickness / 2):
        for k in range(3):
            ang = math.radians(90 + 120 * k)
            verts.append((r_tri * math.cos(ang), r_tri * math.sin(ang), zz))
    A('  <asset>')
    A(f'    <mesh name="table_prism" vertex="{_v(np.array(verts).ravel())}"/>')
    A('    <material name="link" rgba="0.72 0.74 0.78 1"/>')
    A('    <material name="table" rgba="0.55 0.6 0.7 1"/>')
    A('    <material name="target" rgba="0.85 0.65 0.2 1"/>')
    A('    <material name="piezo" rgba="0.15 0.35 0.75 1"/>')
    A('    <material name="probe" rgba="0.2 0.7 0.3 1"/>')
    A('    <material name="base" rgba="0.35 0.35 0.38 1"/>')
    A('  </asset>')
    A('  <worldbody>')
    A('    <body name="stage" childclass="pkxyz">')
    A('      <geom name="base_plate" type="cylinder" size="0.06 0.002" pos="0 0 -0.002" material="base"/>')

    welds = []
    tendons = []
    eqs = []
    for idx, ch in enumerate(CHAINS):
        psi = LEG_AZIMUTH_DEG[idx] + 180.0
        kf = p.chain_a_stiffness_factor if ch == "a" else 1.0
        A(f'      <body name="{ch}_chain" euler="0 0 {math.radians(psi):.9g}">')
        # four-bar 1: crank and follower rockers vertical, hinge axes along y (tangential)
        A(f'        <site name="{ch}_piezo_base" pos="{_v([xc + p.piezo_length, 0, z0 + p.piezo_arm])}"/>')
        A(f'        <geom name="{ch}_piezo_mount" type="box" size="2e-3 3e-3 {(z0 + p.piezo_arm) / 2:.9g}"'
          f' pos="{_v([xc + p.piezo_length + 2e-3, 0, (z0 + p.piezo_arm) / 2])}" material="base"/>')
        # lever: the piezo pushes it at piezo_arm; it carries the actuator block and
        # drives the crank through a torsion spring (PRB flexible crank, fixed tendon)
        A(f'        <body name="{ch}_lever" pos="{_v([xc, 0, z0])}">')
        A(f'          <joint name="{ch}_lever" class="lever" axis="0 1 0"{_kscale(kf, p.k_lever, p.beta_hinge)}/>')
        A(f'          <geom name="{ch}_lever" type="box" size="1e-3 1e-3 {p.lever_block_height / 2:.9g}"'
          f' pos="1.5e-3 {s2 + 3e-3:.9g} {p.lever_block_height / 2:.9g}" mass="1e-4"/>')
        A(f'          <geom name="{ch}_lever_block" type="box" size="2e-3 2e-3 2e-3"'
          f' pos="1.5e-3 {s2 + 3e-3:.9g} {p.lever_block_height:.9g}" mass="{p.lever_block_mass:.9g}"/>')
        A(f'          <site name="{ch}_crank_site" pos="1e-3 0 {p.piezo_arm:.9g}"/>')
        A('        </body>')
        A(f'        <body name="{ch}_crank" pos="{_v([xc, 0, z0])}">')
        A(f'          <joint name="{ch}_crank" class="fourbar1" axis="0 1 0"{_kscale(kf, 2 * p.k_fourbar1, p.beta_hinge)}/>')
        A(f'          <geom name="{ch}_crank" fromto="0 0 0 0 0 {L1:.9g}" size="{p.rocker_radius:.9g}"/>')
        A(f'          <body name="{ch}_foot" pos="0 0 {L1:.9g}">')
        A(f'            <joint name="{ch}_foot" class="fourbar1" axis="0 1 0"{_kscale(kf, 2 * p.k_fourbar1, p.beta_hinge)}/>')
        A(f'            <geom name="{ch}_foot" type="box" size="{p.fourbar1_spacing / 2 + 1e-3:.9g} {s2 + 1.5e-3:.9g} 1e-3"'
          f' pos="{-p.fourbar1_spacing / 2:.9g} 0 1e-3"/>')
        bx = bottom - np.array([xc, 0, foot_z])
        A(f'            <body name="{ch}_leg_base" pos="{_v(bx)}">')
        A(f'              <joint name="{ch}_h1" class="swing" axis="0 1 0"{_kscale(kf, 2 * p.k_swing, p.beta_hinge)}/>')
        A(f'              <geom name="{ch}_leg_base" fromto="0 {-s2:.9g} 0 0 {s2:.9g} 0" size="{p.rocker_radius:.9g}"/>')
        for sgn, rname in ((1, "rocker_p"), (-1, "rocker_n")):
            if sgn == 1:
                A(f'              <body name="{ch}_{rname}" pos="0 {s2:.9g} 0">')
                A(f'                <joint name="{ch}_{rname}" class="fourbar2" axis="{_v(w)}"{_kscale(kf, 2 * p.k_fourbar2, p.beta_hinge)}/>')
                A(f'                <geom name="{ch}_{rname}" fromto="0 0 0 {_v(L2 * u)}" size="{p.rocker_radius:.9g}"/>')
                A(f'                <body name="{ch}_leg_top" pos="{_v(L2 * u)}">')
                A(f'                  <joint name="{ch}_leg_top" class="fourbar2" axis="{_v(w)}"{_kscale(kf, 2 * p.k_fourbar2, p.beta_hinge)}/>')
                A(f'                  <geom name="{ch}_leg_top" fromto="0 0 0 0 {-2 * s2:.9g} 0" size="{p.rocker_radius:.9g}"/>')
                if ch == "a":
                    _table_body(A, p, ch, psi, s2, table_z, g)
                else:
                    A(f'                  <body name="{ch}_tab" pos="0 {-s2:.9g} 0">')
                    A(f'                    <joint name="{ch}_h2" class="follower" axis="0 1 0"/>')
                    A(f'                    <geom name="{ch}_tab" type="sphere" size="1.2e-3"/>')
                    A('                  </body>')
                    welds.append(ch)
                A('                </body>')
                A('              </body>')
            else:
                A(f'              <body name="{ch}_{rname}" pos="0 {-s2:.9g} 0">')
                A(f'                <joint name="{ch}_{rname}" class="follower" axis="{_v(w)}"/>')
                A(f'                <geom name="{ch}_{rname}" fromto="0 0 0 {_v(L2 * u)}" size="{p.rocker_radius:.9g}"/>')
                A('              </body>')
        A('            </body>')
        A('          </body>')
        A('        </body>')
        A(f'        <body name="{ch}_follower" pos="{_v([xf, 0, z0])}">')
        A(f'          <joint name="{ch}_follower" class="follower" axis="0 1 0"/>')
        A(f'          <geom name="{ch}_follower" fromto="0 0 0 0 0 {L1:.9g}" size="{p.rocker_radius:.9g}"/>')
        A('        </body>')
        A('      </body>')
        tendons.append(ch)
        eqs.append(ch)
    # probes: fixed to the base, reading the cube faces along X, Y, Z
    cube_c = np.array([0, 0, table_z + p.table_thickness / 2 + p.cube_half])
    hc = p.cube_half
    for ax, e in zip("xyz", np.eye(3)):
        pos = cube_c + (hc + p.probe_gap) * e
        body_pos = pos + 3e-3 * e
        A(f'      <site name="probe_{ax}" pos="{_v(pos)}"/>')
        A(f'      <geom name="probe_{ax}" type="cylinder" size="1.5e-3 3e-3" pos="{_v(body_pos)}"'
          f' zaxis="{_v(e)}" material="probe"/>')
    A('    </body>')
    A('  </worldbody>')
    A('  <equality>')
    for ch in eqs:
        # parallelogram closure: coupler stays parallel, follower follows the crank
        A(f'    <joint name="{ch}_fourbar1_coupler" class="pkxyz" joint1="{ch}_foot" joint2="{ch}_crank" polycoef="0 -1 0 0 0"/>')
        A(f'    <joint name="{ch}_fourbar1_follower" class="pkxyz" joint1="{ch}_follower" joint2="{ch}_crank" polycoef="0 1 0 0 0"/>')
        A(f'    <joint name="{ch}_fourbar2_coupler" class="pkxyz" joint1="{ch}_leg_top" joint2="{ch}_rocker_p" polycoef="0 -1 0 0 0"/>')
        A(f'    <joint name="{ch}_fourbar2_follower" class="pkxyz" joint1="{ch}_rocker_n" joint2="{ch}_rocker_p" polycoef="0 1 0 0 0"/>')
    for ch in welds:
        A(f'    <weld name="{ch}_table_closure" class="pkxyz" body1="{ch}_tab" body2="table"/>')
    A('  </equality>')
    A('  <tendon>')
    for ch in tendons:
        A(f'    <spatial name="{ch}_piezo" stiffness="{p.k_piezo:.9g}" damping="{p.beta_piezo * p.k_piezo:.9g}"'
          ' width="1.6e-3" material="piezo">')
        A(f'      <site site="{ch}_piezo_base"/>')
        A(f'      <site site="{ch}_crank_site"/>')
        A('    </spatial>')
        kb = p.k_crank_bend * (p.chain_a_stiffness_factor if ch == "a" else 1.0)
        A(f'    <fixed name="{ch}_crank_bend" stiffness="{kb:.9g}" damping="{p.beta_hinge * kb:.9g}">')
        A(f'      <joint joint="{ch}_lever" coef="1"/>')
        A(f'      <joint joint="{ch}_crank" coef="-1"/>')
        A('    </fixed>')
    A('  </tendon>')
    A('  <actuator>')
    for ch in tendons:
        # force on the tendon in N; positive lengthens (piezo extends)
        A(f'    <general name="piezo_{ch}" tendon="{ch}_piezo" gainprm="1" biasprm="0 0 0"/>')
    A('  </actuator>')
    A('  <sensor>')
    for ax in "xyz":
        A(f'    <framepos name="probe_{ax}" objtype="site" objname="cube_face_{ax}" reftype="site" refname="probe_{ax}"/>')
    A('    <framepos name="table_pos" objtype="site" objname="table_center"/>')
    A('  </sensor>')
    A('  <keyframe>')
    A('    <key name="home" qpos="' + " ".join(["0"] * _nq_placeholder()) + '"/>')
    A('  </keyframe>')
    A('</mujoco>')
    return "\n".join(out) + "\n"


def _nq_placeholder() -> int:
    # per chain: lever, crank, foot, follower, h1, two rockers, leg top, h2
    return 3 * 9


def _kscale(factor: float, k: float, beta: float) -> str:
    """Per-joint override when a chain's hinges are stiffer (fabrication imperfection)."""
    if factor == 1.0:
        return ""
    return f' stiffness="{factor * k:.9g}" damping="{factor * beta * k:.9g}"'


def _table_body(A, p: StageParams, ch: str, psi: float, s2: float, table_z: float, g) -> None:
    """Triangular table with target cube, hung on chain A's h2 hinge."""
    psi_r = math.radians(psi)
    # leg_top origin (chain frame) = top + s2*a; table center at (0, 0, table_z)
    rel_chain = np.array([0.0, 0.0, table_z]) - (g["top"] + np.array([0.0, s2, 0.0]))
    A(f'                  <body name="table" pos="{_v(rel_chain)}" euler="0 0 {-psi_r:.9g}">')
    hinge_world = g["top"][0] * np.array([math.cos(psi_r), math.sin(psi_r), 0.0])
    axis_world = np.array([-math.sin(psi_r), math.cos(psi_r), 0.0])
    A(f'                    <joint name="{ch}_h2" class="follower" pos="{_v(hinge_world)}" axis="{_v(axis_world)}"/>')
    A('                    <geom name="table" class="table" type="mesh" mesh="table_prism"/>')
    if p.table_extra_mass > 0:
        A(f'                    <geom name="table_ballast" class="table" type="cylinder" size="3e-3 1e-3"'
          f' pos="0 0 {-p.table_thickness / 2 - 1e-3:.9g}" mass="{p.table_extra_mass:.9g}"/>')
    hc = p.cube_half
    cz = p.table_thickness / 2 + hc
    A(f'                    <geom name="target_cube" class="table" type="box" size="{hc:.9g} {hc:.9g} {hc:.9g}"'
      f' pos="0 0 {cz:.9g}" material="target"/>')
    A('                    <site name="table_center" pos="0 0 0"/>')
    for ax, e in zip("xyz", np.eye(3)):
        A(f'                    <site name="cube_face_{ax}" pos="{_v(np.array([0, 0, cz]) + hc * e)}"/>')
    A('                  </body>')


SCENE_XML = """<mujoco model="pkxyz_scene">
  <include file="pkxyz_stage.xml"/>
  <statistic center="0 0 0.03" extent="0.12"/>
  <visual>
    <headlight diffuse="0.6 0.6 0.6" ambient="0.3 0.3 0.3" specular="0 0 0"/>
    <global azimuth="120" elevation="-25"/>
  </visual>
  <worldbody>
    <light pos="0 0 0.3" dir="0 0 -1" directional="true"/>
  </worldbody>
</mujoco>
"""


def write_stage_xml(directory: str | Path, params: StageParams = DEFAULT_PARAMS) -> Path:
    """Write ``pkxyz_stage.xml`` and ``scene.xml`` into ``directory``."""
    from nanosim.fileio import write_text

    directory = Path(directory)
    write_text(directory / "scene.xml", SCENE_XML)
    return write_text(directory / "pkxyz_stage.xml", stage_xml(params))
