"""Build the PKXYZ stage MJCF from its geometry with ``mujoco.MjSpec``.

Every body is a solid of the geometry (:mod:`nanosim.plant.geometry`) at the
alloy's density, every notch hinge a set of hinge joints at the notch centre
whose stiffnesses come from :mod:`nanosim.plant.hinges` (bending: Paros &
Weisbord full form; out-of-plane bending and torsion: Lobontiu's integrals),
and the APA35XS a slide joint with its datasheet stiffness and a force
actuator. The notches are rigid in translation (their axial and shear
stiffnesses are 1e7-1e8 N/m, three orders above everything else that moves).

Loop closures. The part has 11 closed loops (two parallelograms and the
actuator per chain, two table closures). Each loop is cut in the middle of a
rigid link or in a solid lug, never at a notch, so every notch keeps its
springs on real joints; the cut is a ``weld``. MuJoCo's weld regularization
is relative to the constraint-space inertia, so the rotational rows of a weld
on a light body are soft unless ``torquescale`` puts them on the same footing
as the translational rows (see mjcf/README.md, "Numerics").

Compliance levels. ``full``: bending, out-of-plane bending and torsion at every
notch, every loop welded (nv = 111, for modal analysis). ``reduced`` (the
simulation model): the parallelograms as joint-coupled pseudo-rigid-body
linkages (bending only; on the closure manifold each coupled joint turns by
+/- the crank angle, so a notch's spring rides on the joint that turns with
it), h1 and h2 with all three rotations (their out-of-plane bending and
torsion set the table's tilt and twist), the APA a spatial tendon whose moving
end rides on the crank. tests/test_stage_model.py checks both agree below 1 kHz.
"""
from __future__ import annotations

import math
import re
from dataclasses import dataclass, field
from pathlib import Path

import mujoco
import numpy as np

from nanosim.plant.geometry import (CALIBRATED_GEOMETRY, CHAINS, HINGE_FAMILIES, StageGeometry, chain_points,
                                    notch_frames)
from nanosim.plant.hinges import notch_stiffness

__all__ = ["Numerics", "DampingSpec", "BuildOptions", "LEVELS", "LEVEL_NUMERICS", "write_bundled", "build_spec",
           "stage_xml", "SCENE_XML", "joint_name"]

DIRECTIONS = ("bend", "oop", "tor")
LEVELS = ("full", "reduced")


@dataclass(frozen=True)
class Numerics:
    """Integrator and loop-closure settings (they must not shape the physics; see the tests).

    Attributes
    ----------
    timestep_s : divides the 250 us control period.
    closure_timeconst_s, closure_dampratio : weld ``solref``; MuJoCo clamps the time constant
        to >= 2 timesteps.
    closure_impedance : weld ``solimp`` d0 = d_width (MuJoCo's maximum is 0.9999).
    torquescale : weld rotational rows times this (m): puts rotation residuals on the scale of
        millimetre translations of the light links.
    """

    timestep_s: float = 25e-6
    closure_timeconst_s: float = 50e-6
    closure_dampratio: float = 0.5
    closure_impedance: float = 0.9999
    torquescale: float = 100.0


@dataclass(frozen=True)
class DampingSpec:
    """Damping per source as loss factors, applied as stiffness-proportional viscous damping.

    A spring k with loss factor eta gets c = eta k / (2 pi f_ref): its loss factor is eta at f_ref.
    hinge_loss_factor : aluminium notch hinges (material damping of the alloy).
    piezo_loss_factor : APA35XS, 1 / Q_m of its soft-PZT stack and shell interfaces.
    """

    hinge_loss_factor: float = 4.80e-3     # fitted: nanosim.plant.calibrate.fit_damping
    piezo_loss_factor: float = 0.0494      # fitted: nanosim.plant.calibrate.fit_damping
    reference_frequency_Hz: float = 350.0  # about the geometric mean of the modes below 1 kHz (about 175-670 Hz)

    def beta_s(self, loss_factor: float) -> float:
        """Stiffness-proportional damping coefficient (s) for a loss factor."""
        return loss_factor / (2.0 * math.pi * self.reference_frequency_Hz)


# The full model's stiffest local modes reach 32 kHz: a 5 us step keeps it stable (it is for analysis).
LEVEL_NUMERICS = {"reduced": Numerics(), "full": Numerics(timestep_s=5e-6, closure_timeconst_s=10e-6)}


@dataclass(frozen=True)
class BuildOptions:
    """What to build: compliance level, which chain carries the table in the tree, numerics, damping.

    numerics : None takes :data:`LEVEL_NUMERICS` of the level.
    """

    level: str = "reduced"
    tree_chain: str = "a"
    numerics: Numerics | None = None
    damping: DampingSpec = field(default_factory=DampingSpec)

    @property
    def resolved_numerics(self) -> Numerics:
        """The numerics in use."""
        return self.numerics if self.numerics is not None else LEVEL_NUMERICS.get(self.level, Numerics())


def joint_name(chain: str, notch: str, direction: str) -> str:
    """MJCF name of a notch joint, e.g. ``a_crank_base_bend``."""
    return f"{chain}_{notch}_{direction}"


def _rot_z(deg: float) -> np.ndarray:
    c, s = math.cos(math.radians(deg)), math.sin(math.radians(deg))
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def _quat(axes: np.ndarray) -> np.ndarray:
    """Wxyz quaternion of a rotation matrix whose columns are the local x, y, z axes."""
    q = np.zeros(4)
    mujoco.mju_mat2Quat(q, np.ascontiguousarray(axes, float).ravel())
    return q


def _frame(x_axis, y_axis) -> np.ndarray:
    x = np.asarray(x_axis, float) / np.linalg.norm(x_axis)
    y = np.asarray(y_axis, float) - (np.asarray(y_axis, float) @ x) * x
    y /= np.linalg.norm(y)
    return np.column_stack([x, y, np.cross(x, y)])


class _Builder:
    def __init__(self, g: StageGeometry, opt: BuildOptions):
        if opt.level not in LEVELS:
            raise ValueError(f"level: expected one of {LEVELS}, got {opt.level!r}")
        if opt.tree_chain not in CHAINS:
            raise ValueError(f"tree_chain: expected one of {CHAINS}, got {opt.tree_chain!r}")
        self.g, self.opt = g, opt
        self.rho = g.material.density_kg_per_m3
        self.spec = mujoco.MjSpec()
        self.spec.modelname = "pkxyz_stage"
        self.world_pos = {}          # body name -> world position of its origin
        self.bodies = {}
        self.points = chain_points(g)
        self.frames = notch_frames(g)
        self.azimuths, _ = g.tripod

    # -- primitives ---------------------------------------------------------------------------
    def body(self, parent: str | None, name: str, pos_w: np.ndarray):
        pb = self.spec.worldbody if parent is None else self.bodies[parent]
        ppos = np.zeros(3) if parent is None else self.world_pos[parent]
        b = pb.add_body(name=name, pos=pos_w - ppos)
        self.bodies[name], self.world_pos[name] = b, np.asarray(pos_w, float)
        return b

    def box(self, body: str, name: str, center_w, axes_w, half, material="link", density=None, mass=None):
        kw = {}
        if mass is not None:
            kw["mass"] = float(mass)
        else:
            kw["density"] = float(self.rho if density is None else density)
        b = self.spec.worldbody if body == "world" else self.bodies[body]
        origin = np.zeros(3) if body == "world" else self.world_pos[body]
        b.add_geom(name=name, type=mujoco.mjtGeom.mjGEOM_BOX, size=np.asarray(half, float),
                   pos=np.asarray(center_w, float) - origin, quat=_quat(axes_w), material=material, **kw)

    def bar(self, body: str, name: str, p0_w, p1_w, width_axis_w, width, thickness, material="link"):
        """Box from p0 to p1 with ``width`` along ``width_axis`` and ``thickness`` across."""
        p0, p1 = np.asarray(p0_w, float), np.asarray(p1_w, float)
        axes = _frame(p1 - p0, width_axis_w)       # x along the bar, y along the width
        self.box(body, name, (p0 + p1) / 2, axes, (np.linalg.norm(p1 - p0) / 2, width / 2, thickness / 2), material)

    def link(self, body: str, p0_w, p1_w, width_axis_w, family: str):
        """A rocker of four-bar ``family`` ('fb1' or 'fb2') from p0 to p1, on ``body`` (named like it)."""
        sec = getattr(self.g.chain, f"{family}_rocker")
        self.bar(body, body, p0_w, p1_w, width_axis_w, sec.width_m, sec.thickness_m)

    # -- notch joints -----------------------------------------------------------------------------
    def notch(self, child: str, chain: str, notch: str, R: np.ndarray, directions=DIRECTIONS, lump=()):
        """Hinge joints of one notch on ``child``.

        ``lump``: ((notch, factor), ...) other notches whose bending angle is ``sqrt(factor)`` times this
        joint's angle on the closure manifold; their springs are added here with that factor (same energy).
        """
        fam = next(f for f, names in HINGE_FAMILIES.items() if notch in names)
        k = notch_stiffness(self.g.material, self.g.notch(f"{chain}_{notch}"))
        k_nom = notch_stiffness(self.g.material, self.g.chain.notch(fam))
        axes = dict(zip(DIRECTIONS, self.frames[notch]))
        vals = {"bend": k.bending_Nm_per_rad, "oop": k.out_of_plane_Nm_per_rad, "tor": k.torsion_Nm_per_rad}
        noms = {"bend": k_nom.bending_Nm_per_rad, "oop": k_nom.out_of_plane_Nm_per_rad,
                "tor": k_nom.torsion_Nm_per_rad}
        extra = sum(f * notch_stiffness(self.g.material, self.g.notch(f"{chain}_{n}")).bending_Nm_per_rad
                    for n, f in lump)
        beta = self.opt.damping.beta_s(self.opt.damping.hinge_loss_factor)
        self.notch_marker(child, chain, notch, self.world_pos[child], R)
        for d in directions:
            kval = vals[d] + (extra if d == "bend" else 0.0)
            kw = {}
            if kval != noms[d]:
                kw = {"stiffness": [kval, 0.0, 0.0], "damping": [beta * kval, 0.0, 0.0]}
            self.bodies[child].add_joint(self.spec.find_default(f"{fam}_{d}"), name=joint_name(chain, notch, d),
                                         axis=R @ axes[d], pos=[0.0, 0.0, 0.0], **kw)

    def notch_marker(self, body: str, chain: str, notch: str, pos_w: np.ndarray, R: np.ndarray):
        """A cylinder site (group 3) showing a notch: radius = cut radius, length = width, along its axis."""
        h = self.g.notch(f"{chain}_{notch}")
        bend, oop, _ = self.frames[notch]
        axes = _frame(R @ oop, R @ np.cross(bend, oop))      # z = bending axis
        origin = np.zeros(3) if body == "stage" else self.world_pos[body]
        self.bodies[body].add_site(name=f"{chain}_{notch}_notch", type=mujoco.mjtGeom.mjGEOM_CYLINDER,
                                   size=[h.radius_m, h.width_m / 2, 0.0], pos=np.asarray(pos_w) - origin,
                                   quat=_quat(axes), group=3, rgba=[0.78, 0.16, 0.63, 1.0])

    def couple(self, name: str, joint1: str, joint2: str, ratio: float):
        """Joint equality joint1 = ratio * joint2 (exactly linear: a parallelogram on its closure manifold)."""
        eq = self.spec.add_equality(self.spec.find_default("coupling"), type=mujoco.mjtEq.mjEQ_JOINT, name=name,
                                    name1=joint1, name2=joint2, objtype=mujoco.mjtObj.mjOBJ_JOINT)
        data = np.zeros(12)
        data[1] = ratio
        eq.data = data

    def weld(self, name: str, body1: str, body2: str, anchor_w: np.ndarray):
        eq = self.spec.add_equality(self.spec.find_default("closure"), type=mujoco.mjtEq.mjEQ_WELD,
                                    name=name, name1=body1, name2=body2, objtype=mujoco.mjtObj.mjOBJ_BODY)
        data = np.zeros(12)
        data[0:3] = anchor_w - (self.world_pos[body2] if body2 != "world" else 0.0)
        data[10] = self.opt.resolved_numerics.torquescale
        eq.data = data

    # -- model ---------------------------------------------------------------------------------------
    def defaults(self):
        s, num = self.spec, self.opt.resolved_numerics
        top = s.add_default("pkxyz", s.default)
        top.geom.contype, top.geom.conaffinity = 0, 0
        top.site.group = 4
        for fam in HINGE_FAMILIES:
            k = notch_stiffness(self.g.material, self.g.chain.notch(fam))
            vals = {"bend": k.bending_Nm_per_rad, "oop": k.out_of_plane_Nm_per_rad, "tor": k.torsion_Nm_per_rad}
            beta = self.opt.damping.beta_s(self.opt.damping.hinge_loss_factor)
            for d in DIRECTIONS:
                dd = s.add_default(f"{fam}_{d}", top)
                dd.joint.type = mujoco.mjtJoint.mjJNT_HINGE
                dd.joint.stiffness = [vals[d], 0.0, 0.0]
                dd.joint.damping = [beta * vals[d], 0.0, 0.0]
        apa = s.add_default("apa_stack", top)
        kp = self.g.actuator.stiffness_N_per_m
        apa.joint.type = mujoco.mjtJoint.mjJNT_SLIDE
        apa.joint.stiffness = [kp, 0.0, 0.0]
        apa.joint.damping = [self.opt.damping.beta_s(self.opt.damping.piezo_loss_factor) * kp, 0.0, 0.0]
        for name in ("closure", "coupling"):
            cl = s.add_default(name, top)
            cl.equality.solref = [num.closure_timeconst_s, num.closure_dampratio]
            cl.equality.solimp = [num.closure_impedance, num.closure_impedance, 0.001, 0.5, 2.0]
        pz = s.add_default("piezo", top)
        pz.tendon.stiffness = [kp, 0.0, 0.0]
        pz.tendon.damping = [self.opt.damping.beta_s(self.opt.damping.piezo_loss_factor) * kp, 0.0, 0.0]

    def options(self):
        o, num = self.spec.option, self.opt.resolved_numerics
        o.timestep = num.timestep_s
        o.integrator = mujoco.mjtIntegrator.mjINT_IMPLICITFAST
        o.solver = mujoco.mjtSolver.mjSOL_NEWTON
        o.iterations, o.tolerance = 6, 1e-10
        # no contacts or gravity (mjcf/README, Numerics); no island discovery: the stage is one island (every
        # body is in the closed chains), and finding it again each step costs about a seventh of the step
        o.disableflags = int(mujoco.mjtDisableBit.mjDSBL_CONTACT | mujoco.mjtDisableBit.mjDSBL_GRAVITY
                             | mujoco.mjtDisableBit.mjDSBL_ISLAND)
        self.spec.compiler.degree = False
        for name, rgba in (("link", (0.72, 0.74, 0.78, 1)), ("table", (0.55, 0.6, 0.7, 1)),
                           ("target", (0.85, 0.65, 0.2, 1)), ("piezo", (0.15, 0.35, 0.75, 1)),
                           ("probe", (0.2, 0.7, 0.3, 1)), ("base", (0.35, 0.35, 0.38, 1))):
            self.spec.add_material(name=name, rgba=rgba)

    # -- one chain ------------------------------------------------------------------------------------
    def _frame_vectors(self, idx: int):
        P = self.points
        R = _rot_z(self.azimuths[idx] + 180.0)
        return R, R @ np.eye(3)[0], R @ P["y"], np.eye(3)[2], R @ P["u"], R @ P["w"]

    def lower(self, idx: int, ch: str, split_foot: bool):
        """Four-bar 1, the APA and the foot. ``split_foot``: the chain's leg hangs from the table and
        closes here, so the foot's follower-side half is left for :meth:`leg_down` (weld at the foot centre).
        """
        c, P = self.g.chain, self.points
        full = self.opt.level == "full"
        R, x, y, z, u, w = self._frame_vectors(idx)
        W = lambda p: R @ p                                   # noqa: E731  chain frame -> world
        rf = c.fb1_notch.radius_m
        bend = DIRECTIONS if full else ("bend",)
        cb, ct, fb, ft = (W(P[n]) for n in ("crank_base", "crank_top", "follower_base", "follower_top"))
        pa, pb = W(P["apa_crank"]), W(P["apa_base"])
        # crank; in the reduced model its base joint also carries the APA's notches: the APA is a
        # two-pin link whose crank-side pin (offset d from the crank axis) drops by d theta when the
        # crank turns by theta, so the APA turns by -d theta / L and its notches by (1 + d/L) and d/L theta
        self.body("stage", f"{ch}_crank", cb)
        if full:
            self.notch(f"{ch}_crank", ch, "crank_base", R)
        else:
            d_over_L = (P["apa_crank"][0] - P["crank_base"][0]) / np.linalg.norm(P["apa_base"] - P["apa_crank"])
            self.notch(f"{ch}_crank", ch, "crank_base", R, bend,
                       lump=(("apa_crank", (1.0 + d_over_L) ** 2), ("apa_base", d_over_L ** 2)))
        self.link(f"{ch}_crank", cb + rf * z, ct - rf * z, y, "fb1")
        # foot (four-bar 1 coupler): whole on the crank, or its crank-side half
        oh = c.fb1_rocker.thickness_m / 2 + c.foot_overhang_m
        f0, f1 = ft - oh * x + rf * z, ct + oh * x + rf * z
        fmid = W(P["foot_top"]) - c.foot.thickness_m * z
        self.body(f"{ch}_crank", f"{ch}_foot", ct)
        self.notch(f"{ch}_foot", ch, "crank_top", R, bend)
        lo_x = fmid if split_foot else f0
        self.box(f"{ch}_foot", f"{ch}_foot", (lo_x + f1) / 2 + c.foot.thickness_m / 2 * z, np.column_stack([x, y, z]),
                 (np.linalg.norm(f1 - lo_x) / 2, c.foot.width_m / 2, c.foot.thickness_m / 2))
        # follower
        if full:
            mid = (fb + ft) / 2
            self.body("stage", f"{ch}_follower_low", fb)
            self.notch(f"{ch}_follower_low", ch, "follower_base", R)
            self.link(f"{ch}_follower_low", fb + rf * z, mid, y, "fb1")
            if split_foot:
                # the foot's follower-side half hangs from the leg (leg_down adds the upper follower there)
                self.pending_follower[ch] = (ft, mid, R)
            else:
                self.body(f"{ch}_foot", f"{ch}_follower_up", ft)
                self.notch(f"{ch}_follower_up", ch, "follower_top", R)
                self.link(f"{ch}_follower_up", mid, ft - rf * z, y, "fb1")
                self.weld(f"{ch}_fb1_closure", f"{ch}_follower_low", f"{ch}_follower_up", mid)
        else:
            self.body("stage", f"{ch}_follower", fb)
            self.notch(f"{ch}_follower", ch, "follower_base", R, bend, lump=(("follower_top", 1.0),))
            self.notch_marker(f"{ch}_follower", ch, "follower_top", ft, R)
            self.link(f"{ch}_follower", fb + rf * z, ft - rf * z, y, "fb1")
            crank_j = joint_name(ch, "crank_base", "bend")
            self.couple(f"{ch}_fb1_coupler", joint_name(ch, "crank_top", "bend"), crank_j, -1.0)
            self.couple(f"{ch}_fb1_follower", joint_name(ch, "follower_base", "bend"), crank_j, 1.0)
        self.apa(ch, R, x, y, z, pa, pb)
        return R

    def apa(self, ch, R, x, y, z, pa, pb):
        """APA35XS between a notch on the crank and a notch on the base."""
        g, c = self.g, self.g.chain
        act = g.actuator
        ra = c.apa_notch.radius_m
        m_move = act.moving_fraction * act.mass_kg
        end_len = act.length_m * act.moving_fraction
        rest = act.length_m - end_len
        axes_x = np.column_stack([x, y, z])
        anchor_c = pb + (ra + 1.5e-3) * x
        self.body(f"{ch}_crank", f"{ch}_apa_end", pa)
        self.box(f"{ch}_apa_end", f"{ch}_apa_end", pa + (ra + end_len / 2) * x, axes_x,
                 (end_len / 2, act.width_m / 2, act.height_m / 2), material="piezo", mass=m_move)
        if self.opt.level == "full":
            # moving end on the crank notch, stack as a slide joint, shell, anchor on the base notch
            self.notch(f"{ch}_apa_end", ch, "apa_crank", R)
            self.body(f"{ch}_apa_end", f"{ch}_apa_shell", pa + (ra + end_len) * x)
            self.bodies[f"{ch}_apa_shell"].add_joint(self.spec.find_default("apa_stack"), name=f"{ch}_apa", axis=x)
            self.box(f"{ch}_apa_shell", f"{ch}_apa_shell", pa + (ra + end_len + rest / 2) * x, axes_x,
                     (rest / 2, act.width_m / 2, act.height_m / 2), material="piezo", mass=act.mass_kg - m_move)
            self.body(f"{ch}_apa_shell", f"{ch}_apa_anchor", pb)
            self.notch(f"{ch}_apa_anchor", ch, "apa_base", R)
            self.box(f"{ch}_apa_anchor", f"{ch}_apa_anchor", anchor_c, axes_x,
                     (1.5e-3, act.width_m / 2, act.height_m / 2), material="base")
            self.weld(f"{ch}_apa_closure", "stage", f"{ch}_apa_anchor", anchor_c)
        else:
            # spatial tendon between the notch centres; the moving end rides on the crank, the rest
            # of the actuator (which turns by d/L theta about its base notch) is lumped on the base
            self.bodies[f"{ch}_apa_end"].add_site(name=f"{ch}_apa_crank_site", pos=[0.0, 0.0, 0.0])
            self.notch_marker(f"{ch}_apa_end", ch, "apa_crank", pa, R)
            self.notch_marker("stage", ch, "apa_base", pb, R)
            self.box("stage", f"{ch}_apa_shell", pa + (ra + end_len + rest / 2) * x, axes_x,
                     (rest / 2, act.width_m / 2, act.height_m / 2), material="piezo", mass=act.mass_kg - m_move)
            self.box("stage", f"{ch}_apa_anchor", anchor_c, axes_x,
                     (1.5e-3, act.width_m / 2, act.height_m / 2), material="base")
            self.bodies["stage"].add_site(name=f"{ch}_apa_base_site", pos=pb)
            ten = self.spec.add_tendon(self.spec.find_default("piezo"), name=f"{ch}_piezo")
            ten.wrap_site(f"{ch}_apa_base_site")
            ten.wrap_site(f"{ch}_apa_crank_site")

    def _leg_geometry(self, idx):
        c, P = self.g.chain, self.points
        R, x, y, z, u, w = self._frame_vectors(idx)
        pts = {n: R @ P[n] for n in ("h1", "h2", "rocker_p_base", "rocker_p_top", "rocker_n_base", "rocker_n_top")}
        depth = c.leg_block.thickness_m
        span = 2 * c.leg_half_spacing_m + c.fb2_rocker.thickness_m
        return R, u, w, y, pts, np.column_stack([u, y, w]), (depth / 2, span / 2, c.leg_block.width_m / 2)

    def leg_up(self, idx: int, ch: str):
        """h1, four-bar 2 and the leg top, from the foot up (the chain that carries the table)."""
        c = self.g.chain
        full = self.opt.level == "full"
        R, u, w, y, p, blk_axes, blk_half = self._leg_geometry(idx)
        rs, r2, depth = c.swing_notch.radius_m, c.fb2_notch.radius_m, c.leg_block.thickness_m
        bend = DIRECTIONS if full else ("bend",)
        self.body(f"{ch}_foot", f"{ch}_leg_base", p["h1"])
        self.notch(f"{ch}_leg_base", ch, "h1", R)
        self.box(f"{ch}_leg_base", f"{ch}_leg_base", p["h1"] + (rs + depth / 2) * u, blk_axes, blk_half)
        rpb, rpt, rnb, rnt = p["rocker_p_base"], p["rocker_p_top"], p["rocker_n_base"], p["rocker_n_top"]
        self.body(f"{ch}_leg_base", f"{ch}_rocker_p", rpb)
        self.notch(f"{ch}_rocker_p", ch, "rocker_p_base", R, bend)
        self.link(f"{ch}_rocker_p", rpb + r2 * u, rpt - r2 * u, w, "fb2")
        self.body(f"{ch}_rocker_p", f"{ch}_leg_top", rpt)
        self.notch(f"{ch}_leg_top", ch, "rocker_p_top", R, bend)
        self.box(f"{ch}_leg_top", f"{ch}_leg_top", p["h2"] - (rs + depth / 2) * u, blk_axes, blk_half)
        self._rocker_n(ch, R, u, w, rnb, rnt, parent_base=f"{ch}_leg_base", parent_top=f"{ch}_leg_top")
        if not full:
            rock_j = joint_name(ch, "rocker_p_base", "bend")
            self.couple(f"{ch}_fb2_coupler", joint_name(ch, "rocker_p_top", "bend"), rock_j, -1.0)
            self.couple(f"{ch}_fb2_follower", joint_name(ch, "rocker_n_base", "bend"), rock_j, 1.0)

    def _rocker_n(self, ch, R, u, w, rnb, rnt, parent_base, parent_top, hanging=False):
        c = self.g.chain
        r2 = c.fb2_notch.radius_m
        if self.opt.level == "full":
            rmid = (rnb + rnt) / 2
            self.body(parent_base, f"{ch}_rocker_n_low", rnb)
            self.notch(f"{ch}_rocker_n_low", ch, "rocker_n_base", R)
            self.link(f"{ch}_rocker_n_low", rnb + r2 * u, rmid, w, "fb2")
            self.body(parent_top, f"{ch}_rocker_n_up", rnt)
            self.notch(f"{ch}_rocker_n_up", ch, "rocker_n_top", R)
            self.link(f"{ch}_rocker_n_up", rmid, rnt - r2 * u, w, "fb2")
            self.weld(f"{ch}_fb2_closure", f"{ch}_rocker_n_low", f"{ch}_rocker_n_up", rmid)
        elif hanging:
            self.body(parent_top, f"{ch}_rocker_n", rnt)
            self.notch(f"{ch}_rocker_n", ch, "rocker_n_top", R, ("bend",), lump=(("rocker_n_base", 1.0),))
            self.notch_marker(f"{ch}_rocker_n", ch, "rocker_n_base", rnb, R)
            self.link(f"{ch}_rocker_n", rnb + r2 * u, rnt - r2 * u, w, "fb2")
        else:
            self.body(parent_base, f"{ch}_rocker_n", rnb)
            self.notch(f"{ch}_rocker_n", ch, "rocker_n_base", R, ("bend",), lump=(("rocker_n_top", 1.0),))
            self.notch_marker(f"{ch}_rocker_n", ch, "rocker_n_top", rnt, R)
            self.link(f"{ch}_rocker_n", rnb + r2 * u, rnt - r2 * u, w, "fb2")

    def leg_down(self, idx: int, ch: str):
        """A leg hanging from the table: h2, leg top, four-bar 2, leg base, h1, the foot's other half, weld."""
        c, P = self.g.chain, self.points
        full = self.opt.level == "full"
        R, u, w, y, p, blk_axes, blk_half = self._leg_geometry(idx)
        x, z = R @ np.eye(3)[0], np.eye(3)[2]
        rs, r2, depth = c.swing_notch.radius_m, c.fb2_notch.radius_m, c.leg_block.thickness_m
        bend = DIRECTIONS if full else ("bend",)
        self.body("table", f"{ch}_leg_top", p["h2"])
        self.notch(f"{ch}_leg_top", ch, "h2", R)
        self.box(f"{ch}_leg_top", f"{ch}_leg_top", p["h2"] - (rs + depth / 2) * u, blk_axes, blk_half)
        rpb, rpt, rnb, rnt = p["rocker_p_base"], p["rocker_p_top"], p["rocker_n_base"], p["rocker_n_top"]
        self.body(f"{ch}_leg_top", f"{ch}_rocker_p", rpt)
        self.notch(f"{ch}_rocker_p", ch, "rocker_p_top", R, bend)
        self.link(f"{ch}_rocker_p", rpb + r2 * u, rpt - r2 * u, w, "fb2")
        self.body(f"{ch}_rocker_p", f"{ch}_leg_base", rpb)
        self.notch(f"{ch}_leg_base", ch, "rocker_p_base", R, bend)
        self.box(f"{ch}_leg_base", f"{ch}_leg_base", p["h1"] + (rs + depth / 2) * u, blk_axes, blk_half)
        self._rocker_n(ch, R, u, w, rnb, rnt, parent_base=f"{ch}_leg_base", parent_top=f"{ch}_leg_top", hanging=True)
        if not full:
            rock_j = joint_name(ch, "rocker_p_top", "bend")
            self.couple(f"{ch}_fb2_coupler", joint_name(ch, "rocker_p_base", "bend"), rock_j, -1.0)
            self.couple(f"{ch}_fb2_follower", joint_name(ch, "rocker_n_top", "bend"), rock_j, 1.0)
        # the foot's follower-side half, on h1; welded to the crank-side half at the foot centre
        rf = c.fb1_notch.radius_m
        ft = R @ P["follower_top"]
        oh = c.fb1_rocker.thickness_m / 2 + c.foot_overhang_m
        f0 = ft - oh * x + rf * z
        fmid = R @ P["foot_top"] - c.foot.thickness_m * z
        self.body(f"{ch}_leg_base", f"{ch}_foot_h1", p["h1"])
        self.notch(f"{ch}_foot_h1", ch, "h1", R)
        self.box(f"{ch}_foot_h1", f"{ch}_foot_h1", (f0 + fmid) / 2 + c.foot.thickness_m / 2 * z,
                 np.column_stack([x, y, z]), (np.linalg.norm(fmid - f0) / 2, c.foot.width_m / 2,
                                              c.foot.thickness_m / 2))
        if full and ch in self.pending_follower:
            ftop, mid, Rf = self.pending_follower.pop(ch)
            self.body(f"{ch}_foot_h1", f"{ch}_follower_up", ftop)
            self.notch(f"{ch}_follower_up", ch, "follower_top", Rf)
            self.link(f"{ch}_follower_up", mid, ftop - rf * z, y, "fb1")
            self.weld(f"{ch}_fb1_closure", f"{ch}_follower_low", f"{ch}_follower_up", mid)
        self.weld(f"{ch}_leg_closure", f"{ch}_foot", f"{ch}_foot_h1", fmid + c.foot.thickness_m / 2 * z)

    def table(self):
        """Table plate, target mount and cube, on the tree chain's h2 notch."""
        g, t = self.g, self.g.table
        tc = self.opt.tree_chain
        idx = CHAINS.index(tc)
        R, *_ = self._frame_vectors(idx)
        h2 = R @ self.points["h2"]
        zc = float(self.points["table_z"])
        center = np.array([0.0, 0.0, zc])
        self.body(f"{tc}_leg_top", "table", h2)
        self.notch("table", tc, "h2", R)
        rs = g.chain.swing_notch.radius_m
        rv = t.hinge_radius_m + rs * self.points["u"][0]         # plate vertex: the notch's table-side face
        verts = []
        for i in range(3):
            Ri, *_ = self._frame_vectors(i)
            p2 = Ri @ self.points["h2"]
            verts.append(p2[:2] / np.linalg.norm(p2[:2]) * rv)
        mesh_v = [(*v, zz) for zz in (-t.plate_thickness_m / 2, t.plate_thickness_m / 2) for v in verts]
        self.spec.add_mesh(name="table_plate", uservert=np.array(mesh_v).ravel())
        tb = self.bodies["table"]
        tb.add_geom(name="table", type=mujoco.mjtGeom.mjGEOM_MESH, meshname="table_plate",
                    pos=center - self.world_pos["table"], density=self.rho, material="table")
        # target mount and cube
        top = zc + t.plate_thickness_m / 2
        tb.add_geom(name="target_mount", type=mujoco.mjtGeom.mjGEOM_CYLINDER,
                    size=[t.mount_diameter_m / 2, t.mount_height_m / 2, 0],
                    pos=np.array([0, 0, top + t.mount_height_m / 2]) - self.world_pos["table"], density=self.rho,
                    material="table")
        hc = t.target_side_m / 2
        cz = top + t.mount_height_m + hc
        cube_c = np.array([0.0, 0.0, cz])
        tb.add_geom(name="target_cube", type=mujoco.mjtGeom.mjGEOM_BOX, size=[hc, hc, hc],
                    pos=cube_c - self.world_pos["table"], density=t.target_density_kg_per_m3, material="target")
        tb.add_site(name="table_center", pos=center - self.world_pos["table"])
        for ax, e in zip("xyz", np.eye(3)):
            tb.add_site(name=f"cube_face_{ax}", pos=cube_c + hc * e - self.world_pos["table"])
        return cube_c, hc

    def probes(self, cube_c, hc, gap=0.5e-3, zero_offset_m=(0.0, 0.0, 0.0)):
        st = self.bodies["stage"]
        for ax, e in zip("xyz", np.eye(3)):
            pos = cube_c + (hc + gap) * e
            st.add_site(name=f"probe_{ax}", pos=pos)
            st.add_geom(name=f"probe_{ax}", type=mujoco.mjtGeom.mjGEOM_CYLINDER, size=[1.5e-3, 3e-3, 0],
                        pos=pos + 3e-3 * e, quat=_quat(_frame(np.roll(e, 1), np.roll(e, 2))),
                        material="probe")
        self.spec.add_numeric(name="probe_gap_m", data=[gap])
        self.spec.add_numeric(name="probe_zero_offset_m", data=list(zero_offset_m))

    def build(self) -> mujoco.MjSpec:
        self.options()
        self.defaults()
        st = self.spec.worldbody.add_body(name="stage", childclass="pkxyz")
        self.bodies["stage"], self.world_pos["stage"] = st, np.zeros(3)
        bt = self.g.base_plate_thickness_m
        st.add_geom(name="base_plate", type=mujoco.mjtGeom.mjGEOM_CYLINDER, size=[0.045, bt / 2, 0],
                    pos=[0, 0, -bt / 2], material="base")
        self.pending_follower = {}
        tc = self.opt.tree_chain
        for idx, ch in enumerate(CHAINS):
            self.lower(idx, ch, split_foot=(ch != tc))
        self.leg_up(CHAINS.index(tc), tc)
        cube_c, hc = self.table()
        for idx, ch in enumerate(CHAINS):
            if ch != tc:
                self.leg_down(idx, ch)
        self.probes(cube_c, hc, self.g.table.probe_gap_m, (0.0, 0.0, self.g.table.probe_z_zero_offset_m))
        for ch in CHAINS:
            # force (N) on the APA, positive = extension; ctrl is the blocked force of the free-strain voltage
            target, trn = ((f"{ch}_apa", mujoco.mjtTrn.mjTRN_JOINT) if self.opt.level == "full"
                           else (f"{ch}_piezo", mujoco.mjtTrn.mjTRN_TENDON))
            self.spec.add_actuator(name=f"piezo_{ch}", target=target, trntype=trn,
                                   gainprm=[1.0] + [0.0] * 9, biasprm=[0.0] * 10)
        for ax in "xyz":
            self.spec.add_sensor(name=f"probe_{ax}", type=mujoco.mjtSensor.mjSENS_FRAMEPOS,
                                 objtype=mujoco.mjtObj.mjOBJ_SITE, objname=f"cube_face_{ax}",
                                 reftype=mujoco.mjtObj.mjOBJ_SITE, refname=f"probe_{ax}")
        self.spec.add_sensor(name="table_pos", type=mujoco.mjtSensor.mjSENS_FRAMEPOS,
                             objtype=mujoco.mjtObj.mjOBJ_SITE, objname="table_center")
        self.spec.add_numeric(name="piezo_force_per_volt_N", data=[self.g.actuator.force_per_volt_N])
        self.spec.add_key(name="home")
        return self.spec


def build_spec(g: StageGeometry = CALIBRATED_GEOMETRY, options: BuildOptions | None = None) -> mujoco.MjSpec:
    """The stage as an ``MjSpec`` (compile with ``spec.compile()``)."""
    return _Builder(g, options or BuildOptions()).build()


def stage_xml(g: StageGeometry = CALIBRATED_GEOMETRY, options: BuildOptions | None = None) -> str:
    """The stage MJCF text (device only; ``scene.xml`` includes it).

    ``MjSpec.to_xml`` writes the tendons' compiled rest lengths with 6 digits; the sites it measures
    them between are rounded too, so the APA tendons would start pre-loaded (0.01 N, a 20 nm drift).
    The rest length is left out: MuJoCo then measures it at load time, on the XML's own sites.
    """
    spec = build_spec(g, options)
    spec.compile()
    return re.sub(r' springlength="[^"]*"', "", spec.to_xml())


SCENE_XML = """<mujoco model="pkxyz_scene">
  <include file="pkxyz_stage.xml"/>
  <statistic center="0 0 0.045" extent="0.1"/>
  <visual>
    <headlight diffuse="0.6 0.6 0.6" ambient="0.3 0.3 0.3" specular="0 0 0"/>
    <global azimuth="120" elevation="-25"/>
  </visual>
  <worldbody>
    <light pos="0 0 0.3" dir="0 0 -1" directional="true"/>
  </worldbody>
</mujoco>
"""


def write_bundled(mjcf_dir: str | Path, g: StageGeometry = CALIBRATED_GEOMETRY) -> list[Path]:
    """Regenerate the bundled models: simulation model in ``mjcf_dir``, full one in ``mjcf_dir/full``."""
    from nanosim.fileio import write_text

    out = []
    for sub, level in (("", "reduced"), ("full", "full")):
        d = Path(mjcf_dir) / sub
        write_text(d / "scene.xml", SCENE_XML)
        out.append(write_text(d / "pkxyz_stage.xml", stage_xml(g, BuildOptions(level=level))))
    return out
