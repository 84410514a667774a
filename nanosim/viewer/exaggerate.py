"""Joint-space exaggeration of micrometre deflections (pure, no server).

The real motion is ~1e-6 of the part size, invisible on screen. Scaling the
*joint* coordinates, q = q0 + k (q - q0), and re-running forward kinematics
keeps every body attached to its parent; the loop closures (table welds) are
kept to first order because the deflection lies (to first order) in the
null space of the closure Jacobian. :func:`closure_error` measures what is
left over.
"""
from __future__ import annotations

import mujoco
import numpy as np

from nanosim.plant.mechanics import constraint_jacobian, home_data, mechanical_matrices

__all__ = ["LINK_LENGTH_M", "exaggerate_q", "Exaggerator", "project_closures", "closure_error",
           "static_deflection_q", "table_displacement_m"]

LINK_LENGTH_M = 0.020   # typical link length, the yardstick for closure errors


def exaggerate_q(q: np.ndarray, q0: np.ndarray, k: float) -> np.ndarray:
    """q0 + k (q - q0)."""
    q = np.asarray(q, float)
    q0 = np.asarray(q0, float)
    return q0 + float(k) * (q - q0)


class Exaggerator:
    """Exaggerated kinematics on a private scratch MjData.

    ``pose(q, k)`` returns the scratch data with ``xpos``, ``xquat``,
    ``site_xpos`` set for the exaggerated configuration. Not thread-safe:
    use one instance per thread.
    """

    def __init__(self, model: mujoco.MjModel, q0: np.ndarray | None = None):
        if model.nq != model.nv:
            raise ValueError("exaggerate: only hinge/slide models (nq == nv) are supported")
        self.model = model
        self.data = mujoco.MjData(model)
        self.q0 = home_data(model).qpos.copy() if q0 is None else np.asarray(q0, float).copy()

    def pose(self, q: np.ndarray, k: float, project: bool = True) -> mujoco.MjData:
        self.data.qpos[:] = exaggerate_q(q, self.q0, k)
        if project and self.model.neq and k != 1.0:
            project_closures(self.model, self.data)
        mujoco.mj_kinematics(self.model, self.data)
        return self.data

    def pose_delta(self, dq: np.ndarray, k: float) -> mujoco.MjData:
        """Pose for q = q0 + k dq (e.g. a mode shape)."""
        return self.pose(self.q0 + np.asarray(dq, float), k)


def _equality_residual(model, data):
    mujoco.mj_fwdPosition(model, data)
    rows = np.flatnonzero(data.efc_type[:data.nefc] == mujoco.mjtConstraint.mjCNSTR_EQUALITY)
    J = constraint_jacobian(model, data)[rows]
    return data.efc_pos[rows].copy(), J.copy()


def project_closures(model: mujoco.MjModel, data: mujoco.MjData, iters: int = 12,
                     tol: float = 1e-10) -> float:
    """Move ``data.qpos`` to the nearest point on the loop-closure manifold.

    Second-order terms of a large exaggerated rotation open the loops (the
    three chains meet the table in different places); damped Gauss-Newton
    with minimum-norm steps, dq = -J^T (J J^T + lam I)^-1 r, closes them
    while changing q as little as possible. Returns the final max |residual|.
    """
    res = np.inf
    for _ in range(iters):
        r, J = _equality_residual(model, data)
        res = float(np.max(np.abs(r))) if r.size else 0.0
        if res < tol:
            break
        lam = 1e-12 * max(1.0, float(np.trace(J @ J.T)))
        dq = -J.T @ np.linalg.solve(J @ J.T + lam * np.eye(len(r)), r)
        data.qpos[:] += dq
    return res


def closure_error(model: mujoco.MjModel, qpos: np.ndarray) -> dict[str, float]:
    """Loop-closure residual of every equality at ``qpos``.

    Returns {equality name: residual}: for welds the anchor position error (m),
    for joint couplings the angle error (rad).
    """
    data = mujoco.MjData(model)
    data.qpos[:] = qpos
    mujoco.mj_fwdPosition(model, data)
    out: dict[str, float] = {}
    rows = np.flatnonzero(data.efc_type[:data.nefc] == mujoco.mjtConstraint.mjCNSTR_EQUALITY)
    for eq in range(model.neq):
        name = mujoco.mj_id2name(model, mujoco.mjtObj.mjOBJ_EQUALITY, eq) or f"eq{eq}"
        r = data.efc_pos[rows[data.efc_id[rows] == eq]]
        if model.eq_type[eq] == mujoco.mjtEq.mjEQ_WELD:
            out[name] = float(np.linalg.norm(r[:3]))
        else:
            out[name] = float(np.linalg.norm(r))
    return out


def static_deflection_q(model: mujoco.MjModel, force_N: np.ndarray) -> np.ndarray:
    """Static joint deflection (rad) on the closure manifold for actuator forces (N)."""
    mm = mechanical_matrices(model)
    Mr, Cr, Kr, Br, Pr, Tr = mm.reduced
    z = np.linalg.solve(Kr, Br @ np.asarray(force_N, float))
    return mm.N @ z


def table_displacement_m(model: mujoco.MjModel, dq: np.ndarray) -> float:
    """Largest linearized displacement (m) of the table's sites (its centre, the gauge faces) for deflection dq.

    The sites off the centre make a twist count: a Z twist barely moves the centre, but turns the faces.
    """
    data = home_data(model)
    table = model.body("table").id
    jac = np.zeros((3, model.nv))
    out = 0.0
    for i in np.flatnonzero(model.site_bodyid == table):
        mujoco.mj_jacSite(model, data, jac, None, int(i))
        out = max(out, float(np.linalg.norm(jac @ dq)))
    return out
