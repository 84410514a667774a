"""Modal analysis of the MuJoCo stage about its home keyframe.

The plant is linearized by MuJoCo itself (``mjd_transitionFD``, centred
differences, one integrator step of ``model.opt.timestep``); the discrete
eigenvalues mu map to continuous ones by lambda = log(mu) / dt. The soft loop
closures add stiff "constraint modes"; a mode is flagged as one when its
shape leaves the closure manifold (the part of phi outside null(G), over
||phi||, above ``CONSTRAINT_RATIO``; G the closure Jacobian) and excluded
from :attr:`ModalResult.physical`.

Each mode also carries its kinetic-energy share by part (links, table and
target, actuators; :func:`kinetic_energy_shares`), and :func:`modes_json`
reports the table's parasitic rotation at full stroke
(:func:`table_rotation_urad`).
"""
from __future__ import annotations

from dataclasses import dataclass

import mujoco
import numpy as np

from nanosim import constants as C
from nanosim.paper import PAPER_FULL_STROKE_UM
from nanosim.ramps import raised_cosine
from nanosim.plant.mechanics import home_data, mechanical_matrices

__all__ = ["Mode", "ModalResult", "body_part", "kinetic_energy_shares", "volts_to_force_N", "linearize_fd",
           "modal_analysis", "constraint_violation_ratio", "table_rotation_urad", "modes_json", "posed_data",
           "FULL_STROKE_UM", "MODES_LIST_MAX_HZ", "MODE_SHAPES_MAX_HZ"]

CONSTRAINT_RATIO = 0.05
# Two cutoffs: `nanosim modes` and modes.json list the physical modes below MODES_LIST_MAX_HZ; the mode-shape
# figures (the pipeline's modes/ folder) draw those below MODE_SHAPES_MAX_HZ.
MODES_LIST_MAX_HZ = 3000.0
MODE_SHAPES_MAX_HZ = 1000.0


@dataclass(frozen=True)
class Mode:
    """One vibration mode.

    Attributes
    ----------
    freq_hz : undamped natural frequency |lambda| / 2 pi (Hz).
    damping_ratio : -Re(lambda) / |lambda|.
    axis : 'X', 'Y', 'Z' or 'XY' from the probe participation.
    sensor_participation : (3,) probe X, Y, Z share of this mode's static
        contribution, relative to the strongest mode's largest entry.
    actuator_participation : (nu,) the same per actuator (A, B, C): a mode with a
        node at one chain is nearly invisible in that actuator's column.
    is_constraint : the shape violates the loop closures (numerical mode).
    shape_q : (nv,) joint-space shape (real part, unit max-norm).
    kinetic_energy_share : {part: share} of the mode's kinetic energy, parts from :data:`PARTS`.
    """

    freq_hz: float
    damping_ratio: float
    axis: str
    sensor_participation: np.ndarray
    is_constraint: bool
    constraint_ratio: float
    shape_q: np.ndarray
    kinetic_energy_share: dict = None
    actuator_participation: np.ndarray = None

    def to_json(self) -> dict:
        """JSON-ready dict (units in the keys)."""
        return {"freq_hz": float(self.freq_hz), "damping_ratio": float(self.damping_ratio),
                "axis": self.axis, "sensor_participation": [float(v) for v in self.sensor_participation],
                "actuator_participation": [float(v) for v in self.actuator_participation],
                "kinetic_energy_share": {k: float(v) for k, v in (self.kinetic_energy_share or {}).items()},
                "is_constraint": bool(self.is_constraint)}


@dataclass(frozen=True)
class ModalResult:
    """All modes of the linearized stage, sorted by frequency.

    Attributes
    ----------
    static_gain_um_per_V : (3, 3) probe displacement per controller volt
        (x20 amplifier and linear piezo included), rows X, Y, Z, columns A, B, C.
    body_names : names matching the rows of :meth:`body_displacement`.
    body_jacobians : (nbody, 3, nv) body-origin displacement per joint displacement.
    """

    modes: tuple[Mode, ...]
    static_gain_um_per_V: np.ndarray
    timestep_s: float
    body_names: tuple[str, ...]
    body_jacobians: np.ndarray

    @property
    def physical(self) -> tuple[Mode, ...]:
        """The modes that respect the loop closures."""
        return tuple(m for m in self.modes if not m.is_constraint)

    def below(self, freq_hz: float) -> tuple[Mode, ...]:
        """Physical modes below ``freq_hz``."""
        return tuple(m for m in self.physical if m.freq_hz < freq_hz)

    def body_displacement(self, mode: Mode) -> np.ndarray:
        """(nbody, 3) body-origin displacement of a mode shape (same scale as shape_q)."""
        return self.body_jacobians @ mode.shape_q

    @property
    def lowest_constraint_hz(self) -> float:
        """Frequency of the lowest closure (constraint) mode, Hz."""
        f = [m.freq_hz for m in self.modes if m.is_constraint]
        return float(min(f)) if f else float("inf")


PARTS = ("links", "table_target", "actuators")


def body_part(name: str) -> str | None:
    """Which part a body belongs to: 'actuators' (APA bodies), 'table_target' (table, its lugs),
    'links' (every other moving body); None for the fixed base.
    """
    if name in ("", "world", "stage"):
        return None
    if "_apa" in name:
        return "actuators"
    if name == "table" or name.endswith("_table_lug"):
        return "table_target"
    return "links"


def kinetic_energy_shares(model: mujoco.MjModel, shapes_q: np.ndarray) -> list[dict]:
    """Kinetic-energy share by part of each column of ``shapes_q`` (joint velocities), at home.

    Each body contributes 1/2 m |v_com|^2 + 1/2 w^T I w with its own mass and inertia.
    """
    data = home_data(model)
    shapes = np.atleast_2d(np.asarray(shapes_q, float).T).T
    jacp, jacr = np.zeros((3, model.nv)), np.zeros((3, model.nv))
    energy = np.zeros((len(PARTS), shapes.shape[1]))
    for b in range(1, model.nbody):
        part = body_part(model.body(b).name)
        if part is None or model.body_mass[b] == 0.0:
            continue
        mujoco.mj_jacBodyCom(model, data, jacp, jacr, b)
        v, w = jacp @ shapes, jacr @ shapes
        R = data.ximat[b].reshape(3, 3)
        I = R @ np.diag(model.body_inertia[b]) @ R.T
        energy[PARTS.index(part)] += (0.5 * model.body_mass[b] * np.sum(v * v, axis=0)
                                      + 0.5 * np.sum(w * (I @ w), axis=0))
    total = np.maximum(energy.sum(axis=0), 1e-300)
    return [{p: float(energy[i, k] / total[k]) for i, p in enumerate(PARTS)} for k in range(shapes.shape[1])]


def _axis_label(part: np.ndarray) -> str:
    xy, z = np.hypot(part[0], part[1]), part[2]
    if z > xy:
        return "Z"
    if part[0] > 4 * part[1]:
        return "X"
    if part[1] > 4 * part[0]:
        return "Y"
    return "XY"


def volts_to_force_N() -> float:
    """Tendon force per controller volt for a linear piezo: 20 x 27 N / 150 V."""
    return C.AMPLIFIER_GAIN * C.PIEZO_FORCE_PER_PIEZO_V


def linearize_fd(model: mujoco.MjModel, eps: float = 1e-8):
    """MuJoCo's discrete linearization at home: (A (2nv, 2nv), B (2nv, nu))."""
    data = home_data(model)
    nx = 2 * model.nv + model.na
    A = np.zeros((nx, nx))
    B = np.zeros((nx, model.nu))
    mujoco.mjd_transitionFD(model, data, eps, True, A, B, None, None)
    return A, B


def modal_analysis(model: mujoco.MjModel) -> ModalResult:
    """Linearize about ``home`` and return every mode with its classification."""
    nv, dt = model.nv, model.opt.timestep
    A, B = linearize_fd(model)
    mm = mechanical_matrices(model)
    mu, V = np.linalg.eig(A)
    W = np.linalg.inv(V)
    lam = np.log(mu.astype(complex)) / dt
    Cx = np.hstack([mm.probe, np.zeros((3, nv + model.na))])
    Bc = B / dt
    gain_static = Cx @ np.linalg.solve(np.eye(A.shape[0]) - A, B)       # m per N
    static_um_per_V = gain_static * volts_to_force_N() * 1e6
    entries = []
    for i in np.flatnonzero(lam.imag > 1e-6):
        v = V[:nv, i]
        res = (Cx @ V[:, i:i + 1]) @ (W[i:i + 1, :] @ Bc)             # residue (3, nu)
        contrib = 2 * np.abs(res) / np.abs(lam[i]) ** 2                # pair, static
        shape = np.real(v * np.exp(-1j * np.angle(v[np.argmax(np.abs(v))])))
        shape = shape / np.max(np.abs(shape))
        off = shape - mm.N @ (mm.N.T @ shape)
        ratio = np.linalg.norm(off) / max(np.linalg.norm(shape), 1e-300) if mm.G.size else 0.0
        entries.append((abs(lam[i]) / (2 * np.pi), -lam[i].real / abs(lam[i]),
                        np.linalg.norm(contrib, axis=1), ratio, shape, np.linalg.norm(contrib, axis=0)))
    strongest = max((e[2].max() for e in entries if e[3] < CONSTRAINT_RATIO), default=1.0)
    shares = kinetic_energy_shares(model, np.column_stack([e[4] for e in entries])) if entries else []
    modes = tuple(sorted((Mode(freq_hz=float(f), damping_ratio=float(z), axis=_axis_label(p),
                               sensor_participation=p / strongest, is_constraint=bool(r >= CONSTRAINT_RATIO),
                               constraint_ratio=float(r), shape_q=s, kinetic_energy_share=ke,
                               actuator_participation=pa / strongest)
                          for (f, z, p, r, s, pa), ke in zip(entries, shares)), key=lambda m: m.freq_hz))
    data = home_data(model)
    names, jacs = [], []
    jacp = np.zeros((3, nv))
    for b in range(1, model.nbody):
        mujoco.mj_jacBody(model, data, jacp, None, b)
        names.append(model.body(b).name)
        jacs.append(jacp.copy())
    return ModalResult(modes=modes, static_gain_um_per_V=static_um_per_V, timestep_s=dt,
                       body_names=tuple(names), body_jacobians=np.array(jacs))


def constraint_violation_ratio(model: mujoco.MjModel, volts=(7.5, -1.0, -1.0), settle_s: float = 0.15) -> float:
    """Closure violation at full stroke relative to the table displacement.

    Drives the actuators with a smooth ramp to ``volts`` (controller volts,
    linear piezo), settles, and returns max closure error (as a length: angle
    errors times the leg length) over the table displacement.
    """
    data = home_data(model)
    x0 = data.site("table_center").xpos.copy()
    n = int(round(settle_s / model.opt.timestep))
    ramp = raised_cosine(n, 0.5)
    force = np.asarray(volts) * volts_to_force_N()
    for k in range(n):
        data.ctrl[:] = ramp[k] * force
        mujoco.mj_step(model, data)
    disp = np.linalg.norm(data.site("table_center").xpos - x0)
    rows = np.flatnonzero(data.efc_type[:data.nefc] == mujoco.mjtConstraint.mjCNSTR_EQUALITY)
    lever = 20e-3
    err = 0.0
    for eq_id in np.unique(data.efc_id[rows]):
        r = data.efc_pos[rows[data.efc_id[rows] == eq_id]]
        if model.eq_type[eq_id] == mujoco.mjtEq.mjEQ_WELD:
            ts = model.eq_data[eq_id, 10] or 1.0
            err = max(err, np.abs(r[:3]).max(), np.abs(r[3:]).max() / ts * lever)   # lengths; angles x lever
        else:
            err = max(err, np.abs(r).max() * lever)                                 # joint angles x lever
    return float(err / disp)


FULL_STROKE_UM = PAPER_FULL_STROKE_UM        # paper Sec. 2 (nanosim.paper)


def table_rotation_urad(model: mujoco.MjModel, stroke_um: float = FULL_STROKE_UM) -> dict:
    """Static table rotation (urad, about world X, Y, Z) for a pure translation of ``stroke_um`` per axis.

    The actuator forces that move the probes by ``stroke_um`` along one axis and zero along the
    others (inverse of the static probe compliance) are applied on the closure manifold; the
    table's rotation comes from the parasitic (out-of-plane and torsional) notch compliance.
    """
    mm = mechanical_matrices(model)
    Mr, Cr, Kr, Br, Pr, Tr = mm.reduced
    X = np.linalg.solve(Kr, Br)                                  # reduced coordinates per newton
    G = Pr @ X                                                   # probe m per newton
    data = home_data(model)
    jacr = np.zeros((3, model.nv))
    mujoco.mj_jacBody(model, data, None, jacr, model.body("table").id)
    out = {}
    for i, ax in enumerate("XYZ"):
        f = np.linalg.solve(G, stroke_um * 1e-6 * np.eye(3)[i])
        out[ax] = (jacr @ (mm.N @ (X @ f)) * 1e6).tolist()
    return out


def modes_json(model: mujoco.MjModel, fmax_hz: float = MODES_LIST_MAX_HZ,
               full_model: mujoco.MjModel | None = None) -> dict:
    """The dict printed by ``nanosim modes --json``: every physical mode below ``fmax_hz`` and more.

    ``full_model``: the full-compliance model of the same stage; its modes below ``fmax_hz``, table
    rotation and the agreement of its modes below 1 kHz with ``model``'s are added under
    ``full_compliance``.
    """
    res = modal_analysis(model)
    extra = {}
    if full_model is not None:
        full = modal_analysis(full_model)
        a = np.array([m.freq_hz for m in res.below(1000.0)])
        b = np.array([m.freq_hz for m in full.below(1000.0)])
        extra = {"full_compliance": {
            "modes": [m.to_json() for m in full.below(fmax_hz)],
            "table_rotation_urad": table_rotation_urad(full_model),
            "modes_below_1kHz_difference_percent": (100 * (a / b - 1)).tolist() if len(a) == len(b) else None,
        }}
    return {
        "modes": [m.to_json() for m in res.below(fmax_hz)],
        "static_gain_um_per_V": res.static_gain_um_per_V.tolist(),
        "table_rotation_urad": table_rotation_urad(model),
        "full_stroke_um": FULL_STROKE_UM,
        "constraint_violation_ratio": constraint_violation_ratio(model),
        "lowest_constraint_mode_hz": res.lowest_constraint_hz,
        "units": {"freq_hz": "Hz", "static_gain_um_per_V": "um per controller volt (x20 amplifier, linear piezo)",
                  "table_rotation_urad": "urad about world X, Y, Z for a full_stroke_um translation along each "
                                         "axis alone",
                  "kinetic_energy_share": "share of the mode's kinetic energy in links, table+target, actuators"},
        **extra,
    }


def posed_data(model: mujoco.MjModel, shape_q: np.ndarray, scale: float) -> mujoco.MjData:
    """MjData at q = q_home + scale * shape (joint space), forward kinematics done."""
    data = home_data(model)
    data.qpos[:] = data.qpos + scale * shape_q
    mujoco.mj_kinematics(model, data)
    return data
