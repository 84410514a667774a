"""Regenerate the malformed-file corpus used by tests/test_fuzz.py (run from the repository root).

    python tests/corpus/make_corpus.py

Every file is small and deterministic (fixed seeds); the MJCF variants are cut from the bundled stage.
Expected outcome of each file: a one-line ``ValueError`` (or ``FileNotFoundError``), never anything else.
"""
from __future__ import annotations

import io
import re
import zipfile
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
STAGE = HERE.parents[1] / "nanosim" / "mjcf" / "pkxyz_stage.xml"


def _npz_bytes(**arrays) -> bytes:
    buf = io.BytesIO()
    np.savez(buf, **arrays)
    return buf.getvalue()


def controller(**over):
    base = dict(Akd=np.zeros((2, 2)), Bkd=np.zeros((2, 3)), Ckd=np.zeros((3, 2)), Dkd=np.zeros((3, 3)), dt=2.5e-4)
    base.update(over)
    return {k: v for k, v in base.items() if v is not None}


def npz_files() -> dict[str, bytes]:
    good = _npz_bytes(**controller())
    rng = np.random.default_rng(15)
    zbuf = io.BytesIO()
    with zipfile.ZipFile(zbuf, "w") as z:
        z.writestr("readme.txt", "a zip archive without .npy members")
    bad_npy = io.BytesIO()
    with zipfile.ZipFile(bad_npy, "w") as z:
        z.writestr("Akd.npy", b"\x93NUMPY\x01\x00garbage header")
    return {
        "empty.npz": b"",
        "garbage.npz": rng.bytes(4096),
        "truncated.npz": good[: len(good) // 2],
        "truncated_tail.npz": good[:-20],
        "zip_without_arrays.npz": zbuf.getvalue(),
        "zip_with_broken_npy.npz": bad_npy.getvalue(),
        "object_array.npz": _npz_bytes(Akd=np.array([{"x": 1}], dtype=object)),
        "controller_wrong_shapes.npz": _npz_bytes(**controller(Bkd=np.zeros((3, 3)))),
        "controller_nan.npz": _npz_bytes(**controller(Akd=np.full((2, 2), np.nan))),
        "controller_dt_text.npz": _npz_bytes(**controller(dt=np.array("fast"))),
        "controller_dt_1ms.npz": _npz_bytes(**controller(dt=1e-3)),
        "controller_dt_vector.npz": _npz_bytes(**controller(dt=np.array([2.5e-4, 2.5e-4]))),
        "controller_missing_Ckd.npz": _npz_bytes(**controller(Ckd=None)),
        "controller_3d.npz": _npz_bytes(**controller(Akd=np.zeros((2, 2, 1)))),
        "controller_complex.npz": _npz_bytes(**controller(Akd=np.zeros((2, 2), complex) + 1j)),
        "controller_strings.npz": _npz_bytes(**controller(Akd=np.array([["a", "b"], ["c", "d"]]))),
        "controller_n_error_bad.npz": _npz_bytes(**controller(n_error=np.array(7))),
        "model_no_arrays.npz": _npz_bytes(),
        "model_wrong_shapes.npz": _npz_bytes(A=np.zeros((3, 3)), B=np.zeros((2, 3)), C=np.zeros((3, 3)),
                                             D=np.zeros((3, 3)), dt=np.array(2.5e-4)),
    }


def mjcf_files() -> dict[str, str]:
    stage = STAGE.read_text()

    def drop(tag):
        return re.sub(rf"\s*<{tag}>.*?</{tag}>", "", stage, flags=re.S)

    return {
        "empty.xml": "",
        "not_xml.xml": "\x00\x01\x02 this is not XML \xff",
        "truncated.xml": stage[: len(stage) // 2],
        "unclosed.xml": "<mujoco><worldbody><body>",
        "wrong_root.xml": stage.replace("<mujoco", "<robot", 1).replace("</mujoco>", "</robot>"),
        "missing_actuators.xml": drop("actuator"),
        "missing_sensors.xml": drop("sensor"),
        "missing_include.xml": '<mujoco><include file="no_such_part.xml"/></mujoco>',
        "bad_attribute.xml": stage.replace('timestep="1.25e-05"', 'timestep="fast"', 1),
        "timestep_not_dividing.xml": stage.replace('timestep="1.25e-05"', 'timestep="3e-05"', 1),
        "negative_mass.xml": '<mujoco><worldbody><body><inertial pos="0 0 0" mass="-1" diaginertia="1 1 1"/>'
                             '<joint type="slide"/></body></worldbody></mujoco>',
        "plain_model.xml": '<mujoco><worldbody><body><geom type="sphere" size="0.01"/><joint type="slide"/>'
                           '</body></worldbody></mujoco>',
    }


def main() -> None:
    for name, data in npz_files().items():
        (HERE / "npz").mkdir(exist_ok=True)
        (HERE / "npz" / name).write_bytes(data)
    for name, text in mjcf_files().items():
        (HERE / "mjcf").mkdir(exist_ok=True)
        (HERE / "mjcf" / name).write_text(text, encoding="utf-8", errors="surrogateescape")


if __name__ == "__main__":
    main()
