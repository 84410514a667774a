"""Where the scene labels go: apart from each other on screen, whatever the stage's size."""
from __future__ import annotations

import numpy as np

from nanosim.viewer import scene as sc

__all__ = ["VIEW_DIR", "LABEL_TEXTS", "label_boxes", "box_gap", "label_positions"]

VIEW_DIR = np.array([95.0, -110.0, 62.0])   # from the look-at point towards the first camera
LABEL_CHAR_MM, LABEL_HEIGHT_MM = 0.9, 1.8   # a label's text at the first camera's zoom (about 8 px per mm)
LABEL_CLEAR_MM = 3.0                        # wanted gap between the table label and any other label


def label_boxes(anchors: dict, texts: dict, view_dir=VIEW_DIR) -> dict:
    """Screen boxes (u0, u1, w0, w1) in mm of centred labels seen along ``view_dir``."""
    v = np.asarray(view_dir, float) / np.linalg.norm(view_dir)
    right = np.cross(v, [0.0, 0.0, 1.0])
    right /= np.linalg.norm(right)
    up = np.cross(right, v)
    out = {}
    for k, p in anchors.items():
        u, w = float(p @ right), float(p @ up)
        half = 0.5 * LABEL_CHAR_MM * len(texts[k])
        out[k] = (u - half, u + half, w - 0.5 * LABEL_HEIGHT_MM, w + 0.5 * LABEL_HEIGHT_MM)
    return out


def box_gap(a, b) -> float:
    """Distance (mm) between two screen boxes; 0 when they touch or overlap."""
    du = max(a[0] - b[1], b[0] - a[1], 0.0)
    dw = max(a[2] - b[3], b[2] - a[3], 0.0)
    return float(np.hypot(du, dw))


LABEL_TEXTS = {"table": "table + target cube", **{f"probe_{a}": f"probe {a.upper()}" for a in "xyz"}}


def label_positions(model, data, view_dir=VIEW_DIR) -> dict[str, np.ndarray]:
    """Anchors (mm) of the scene labels, apart from each other whatever the stage's size.

    Piezo labels sit above the piezo bases and each probe label is pushed outward from the
    table (the Z probe's upward). The table label ("table + target cube", which used to sit on
    "probe Z") takes, among places around and below the table, the one farthest on screen
    (first camera, :data:`VIEW_DIR`) from every other label. Offsets scale with ``model.stat.extent``.
    """
    ext = float(model.stat.extent) * sc.MM
    table = data.site_xpos[model.site("table_center").id] * sc.MM
    out, texts = {}, dict(LABEL_TEXTS)
    for t in sc.tendon_specs(model):
        out[t.name] = data.site_xpos[t.sites[0]] * sc.MM + np.array([0.0, 0.0, 0.05 * ext])
        texts[t.name] = f"piezo {t.name[0].upper()}"
    for ax in "xyz":
        p = data.geom_xpos[model.geom(f"probe_{ax}").id] * sc.MM
        away = p - table
        if ax != "z":
            away[2] = 0.0                         # sideways: the cube sits high above the table centre
        away /= max(np.linalg.norm(away), 1e-9)
        out[f"probe_{ax}"] = p + 0.08 * ext * away + np.array([0.0, 0.0, 0.03 * ext])
    # seen from the first camera (between +X and -Y) the X and Y probes point to the same side of the
    # screen: the Y label goes a line and a half higher
    out["probe_y"] = out["probe_y"] + np.array([0.0, 0.0, 0.07 * ext])
    others = label_boxes(out, texts, view_dir)
    cands = sorted(((r, h, th) for r in (0.12, 0.2, 0.3) for h in (-0.08, 0.12, -0.16)
                    for th in np.linspace(0.0, 2 * np.pi, 16, endpoint=False)), key=lambda c: np.hypot(c[0], c[1]))
    best, best_gap = None, -1.0
    for r, h, th in cands:                      # the nearest place to the table with a clear gap, else the clearest
        cand = table + ext * np.array([r * np.cos(th), r * np.sin(th), h])
        gap = min(box_gap(label_boxes({"table": cand}, texts, view_dir)["table"], b) for b in others.values())
        if gap > best_gap + 1e-9:
            best, best_gap = cand, gap
        if gap >= LABEL_CLEAR_MM:
            break
    out["table"] = best
    return out
