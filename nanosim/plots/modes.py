"""Mode-shape figures of the MuJoCo stage; each returns a Figure and writes nothing."""
from __future__ import annotations

import mujoco
import numpy as np

from nanosim.artifact_names import mode_shape_png
from nanosim.plant.modes import MODE_SHAPES_MAX_HZ, posed_data

__all__ = ["mode_shape_figures", "mode_shape_file_name"]


_BOX_EDGES = [(i, j) for i in range(8) for j in range(i + 1, 8) if bin(i ^ j).count("1") == 1]
_CORNERS = np.array([[(i >> k & 1) * 2 - 1 for k in range(3)] for i in range(8)], float)


def _segments_mm(model: mujoco.MjModel, data: mujoco.MjData) -> list:
    """The moving mechanism as (2, 3) segments in mm: every box as its 12 edges (links drawn with
    their real cross-section), capsules/cylinders as their axis, meshes as their bounding box.
    """
    segs = []
    lines = (int(mujoco.mjtGeom.mjGEOM_CAPSULE), int(mujoco.mjtGeom.mjGEOM_CYLINDER))
    boxes = (int(mujoco.mjtGeom.mjGEOM_BOX), int(mujoco.mjtGeom.mjGEOM_MESH))
    for g in range(model.ngeom):
        if model.geom_bodyid[g] <= 1:
            continue
        c, R, size = data.geom_xpos[g], data.geom_xmat[g].reshape(3, 3), model.geom_size[g]
        kind = int(model.geom_type[g])
        if kind in lines:
            axis = R[:, 2] * size[1]
            segs.append(np.stack([c - axis, c + axis]) * 1e3)
        elif kind in boxes:
            if kind == boxes[1]:
                m = int(model.geom_dataid[g])
                v = model.mesh_vert[model.mesh_vertadr[m]:model.mesh_vertadr[m] + model.mesh_vertnum[m]]
                size = np.abs(v).max(axis=0)
            corners = c + (_CORNERS * size) @ R.T
            segs.extend(np.stack([corners[i], corners[j]]) * 1e3 for i, j in _BOX_EDGES)
    return segs


def _tendons_mm(model: mujoco.MjModel, data: mujoco.MjData) -> list:
    """Piezo tendons (spatial tendons named ``*_piezo``) as (2, 3) segments in mm, first to last site."""
    out = []
    for t in range(model.ntendon):
        if not (mujoco.mj_id2name(model, mujoco.mjtObj.mjOBJ_TENDON, t) or "").endswith("_piezo"):
            continue
        adr, num = model.tendon_adr[t], model.tendon_num[t]
        sites = [int(model.wrap_objid[w]) for w in range(adr, adr + num)
                 if model.wrap_type[w] == mujoco.mjtWrap.mjWRAP_SITE]
        if len(sites) >= 2:
            out.append(np.stack([data.site_xpos[sites[0]], data.site_xpos[sites[-1]]]) * 1e3)
    return out


def mode_shape_file_name(index: int, mode) -> str:
    """``mode_01_176Hz.png`` for the first mode (index 0): :func:`nanosim.artifact_names.mode_shape_png`."""
    return mode_shape_png(index, mode.freq_hz)


def mode_shape_figures(model: mujoco.MjModel, result, fmax_hz: float = MODE_SHAPES_MAX_HZ,
                       max_displacement_mm: float = 4.0) -> list:
    """One Figure per physical mode below ``fmax_hz``: home (grey) vs exaggerated shape (red).

    The shape is scaled in joint space so the largest body displacement is
    ``max_displacement_mm``; links are drawn as box wireframes (their cross-sections) and the
    table's displacement as an arrow.

    Returns
    -------
    list of (file name, matplotlib.figure.Figure)
    """
    from matplotlib.figure import Figure

    figures = []
    home = posed_data(model, np.zeros(model.nv), 0.0)
    home_segs = _segments_mm(model, home)
    tb = model.body("table").id
    for i, mode in enumerate(result.below(fmax_hz)):
        disp = result.body_displacement(mode)
        scale = max_displacement_mm * 1e-3 / max(np.abs(disp).max(), 1e-12)
        moved = posed_data(model, mode.shape_q, scale)
        fig = Figure(figsize=(7.5, 6))
        ax = fig.add_subplot(projection="3d")
        for s in home_segs:
            ax.plot(*s.T, color="0.75", lw=1.2)
        for s in _segments_mm(model, moved):
            ax.plot(*s.T, color="tab:red", lw=0.8)
        for s in _tendons_mm(model, moved):
            ax.plot(*s.T, color="tab:blue", lw=3, alpha=0.6)
        p0, p1 = home.xpos[tb] * 1e3, moved.xpos[tb] * 1e3
        ax.quiver(*p0, *(p1 - p0), color="tab:blue", lw=2, arrow_length_ratio=0.25)
        ax.scatter(*p0, color="0.3", s=30, label="table, home")
        ax.scatter(*p1, color="tab:blue", s=40, label="table, exaggerated")
        lim = np.array([-50.0, 50.0])
        ax.set_xlim(lim)
        ax.set_ylim(lim)
        ax.set_zlim(0, 100)
        ax.set_xlabel("x (mm)")
        ax.set_ylabel("y (mm)")
        ax.set_zlabel("z (mm)")
        d = p1 - p0
        ax.set_title(f"Mode {i + 1}: {mode.freq_hz:.1f} Hz, zeta {mode.damping_ratio:.4f}, axis {mode.axis}\n"
                     f"grey: home; red: shape (blue: piezo tendons) scaled to {max_displacement_mm:g} mm largest "
                     f"motion; "
                     f"table moves ({d[0]:+.1f}, {d[1]:+.1f}, {d[2]:+.1f}) mm", fontsize=9)
        ax.legend(loc="upper left", fontsize=8)
        ax.view_init(elev=22, azim=-60)
        figures.append((mode_shape_file_name(i, mode), fig))
    return figures
