"""Linear mechanics of the stage on the loop-closure manifold.

The flexure stage is a pseudo-rigid-body model: hinge joints with stiffness
and damping, loops closed by equality constraints, piezo tendons with
stiffness. About the home keyframe the motion is tiny (um on a 50 mm part),
so the equations of motion are linear:

    M q'' + Cd q' + K q = B f,      G q = 0,

with G the equality-constraint Jacobian. With N an orthonormal basis of
null(G), q = N z gives the exact constrained model
(N^T M N) z'' + (N^T Cd N) z' + (N^T K N) z = N^T B f, free of the stiff
constraint modes that MuJoCo's soft constraints add. MuJoCo's own
finite-difference linearization (``mjd_transitionFD``) is compared against
this in the tests.
"""
from __future__ import annotations

from dataclasses import dataclass

import mujoco
import numpy as np
import scipy.linalg as sla

__all__ = ["MechanicalMatrices", "home_data", "mechanical_matrices", "static_compliance", "reduced_modes"]


@dataclass(frozen=True)
class MechanicalMatrices:
    """Generalized matrices at the home keyframe (SI units).

    Attributes
    ----------
    M, Cd, K : (nv, nv) mass (kg, kg m^2), damping and stiffness matrices.
    B : (nv, nu) generalized force per newton of actuator (tendon) force.
    G : (neq_rows, nv) equality-constraint Jacobian.
    probe : (3, nv) probe displacement (m) per unit generalized displacement,
        rows X, Y, Z.
    table : (3, nv) table-centre displacement (m) per unit generalized displacement.
    N : (nv, nz) orthonormal basis of null(G).
    """

    M: np.ndarray
    Cd: np.ndarray
    K: np.ndarray
    B: np.ndarray
    G: np.ndarray
    probe: np.ndarray
    table: np.ndarray
    N: np.ndarray

    @property
    def reduced(self):
        """(Mr, Cr, Kr, Br, probe_r, table_r) on the constraint manifold."""
        N = self.N
        return (N.T @ self.M @ N, N.T @ self.Cd @ N, N.T @ self.K @ N, N.T @ self.B,
                self.probe @ N, self.table @ N)


def home_data(model: mujoco.MjModel) -> mujoco.MjData:
    """MjData reset to the ``home`` keyframe (or qpos0) with kinematics computed."""
    data = mujoco.MjData(model)
    key = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_KEY, "home")
    if key >= 0:
        mujoco.mj_resetDataKeyframe(model, data, key)
    mujoco.mj_forward(model, data)
    return data


def constraint_jacobian(model: mujoco.MjModel, data: mujoco.MjData) -> np.ndarray:
    """Dense (nefc, nv) constraint Jacobian of ``data`` (MuJoCo stores it sparse for large models)."""
    if data.nefc == 0:
        return np.zeros((0, model.nv))
    if mujoco.mj_isSparse(model):
        J = np.zeros((data.nefc, model.nv))
        mujoco.mju_sparse2dense(J, data.efc_J, data.efc_J_rownnz, data.efc_J_rowadr, data.efc_J_colind)
        return J
    return data.efc_J[:data.nefc * model.nv].reshape(data.nefc, model.nv).copy()


def tendon_jacobian(model: mujoco.MjModel, data: mujoco.MjData) -> np.ndarray:
    """Dense (ntendon, nv) tendon Jacobian of ``data``."""
    if model.ntendon == 0:
        return np.zeros((0, model.nv))
    Jt = np.zeros((model.ntendon, model.nv))
    mujoco.mju_sparse2dense(Jt, data.ten_J, model.ten_J_rownnz, model.ten_J_rowadr, model.ten_J_colind)
    return Jt


def mechanical_matrices(model: mujoco.MjModel) -> MechanicalMatrices:
    """Assemble M, damping, stiffness, input and output matrices at home."""
    data = home_data(model)
    nv = model.nv
    M = np.zeros((nv, nv))
    mujoco.mj_fullM(model, data, M)
    # joints: diagonal stiffness/damping (hinge and slide: one dof per joint)
    K = np.zeros((nv, nv))
    Cd = np.diag(model.dof_damping.copy())
    for j in range(model.njnt):
        K[model.jnt_dofadr[j], model.jnt_dofadr[j]] += model.jnt_stiffness[j]
    Jt = tendon_jacobian(model, data)
    K += Jt.T @ np.diag(model.tendon_stiffness) @ Jt
    Cd += Jt.T @ np.diag(model.tendon_damping) @ Jt
    # actuator moment arms: generalized force per unit control (force actuators)
    B = np.zeros((nv, model.nu))
    for i in range(model.nu):
        data.ctrl[:] = 0.0
        data.ctrl[i] = 1.0
        mujoco.mj_fwdActuation(model, data)
        B[:, i] = data.qfrc_actuator
    data.ctrl[:] = 0.0
    eq_rows = data.efc_type == mujoco.mjtConstraint.mjCNSTR_EQUALITY
    G = constraint_jacobian(model, data)[eq_rows]
    probe = np.zeros((3, nv))
    jacp = np.zeros((3, nv))
    for i, ax in enumerate("xyz"):
        mujoco.mj_jacSite(model, data, jacp, None, model.site(f"cube_face_{ax}").id)
        probe[i] = jacp[i]
    table = np.zeros((3, nv))
    mujoco.mj_jacSite(model, data, table, None, model.site("table_center").id)
    # 1e-7 relative: 9-digit XML rounding leaves ~1e-10 singular values on true null directions
    N = sla.null_space(G, rcond=1e-7) if G.shape[0] else np.eye(nv)
    return MechanicalMatrices(M=M, Cd=Cd, K=K, B=B, G=G, probe=probe, table=table, N=N)


def static_compliance(mm: MechanicalMatrices) -> np.ndarray:
    """(3, nu) probe displacement (m) per newton of actuator force at DC."""
    Mr, Cr, Kr, Br, Pr, Tr = mm.reduced
    return Pr @ np.linalg.solve(Kr, Br)


def reduced_modes(mm: MechanicalMatrices):
    """Undamped natural frequencies (Hz), modal damping ratios and shapes.

    Returns (freq_hz (n,), zeta (n,), shapes_q (nv, n)) sorted by frequency,
    with shapes mass-normalised in the reduced coordinates and mapped to q.
    """
    Mr, Cr, Kr, Br, Pr, Tr = mm.reduced
    w2, V = sla.eigh(Kr, Mr)
    w = np.sqrt(np.maximum(w2, 0.0))
    zeta = np.einsum("ij,jk,ki->i", V.T, Cr, V) / (2.0 * np.maximum(w, 1e-30))
    return w / (2 * np.pi), zeta, mm.N @ V
