"""Atomic artifact writers: every file is written to a temp file, then renamed.

Artifacts are plain ``.npz`` arrays, ``.json`` metadata and ``.png`` figures;
nothing is pickled.
"""
from __future__ import annotations

import json
import os
import tempfile
from pathlib import Path
from typing import Any, Mapping

import numpy as np

__all__ = ["write_json", "write_npz", "load_npz", "save_figure", "write_mat", "write_text"]


def _atomic_target(path: str | os.PathLike, suffix: str):
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=suffix, dir=path.parent)
    os.close(fd)
    return path, Path(tmp)


def _read_umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


_UMASK = _read_umask()   # read once: os.umask is process-global and not thread-safe


def _publish(tmp: Path, path: Path) -> None:
    """Give ``tmp`` the permissions a plainly created file would have (0666 & ~umask), then rename it."""
    os.chmod(tmp, 0o666 & ~_UMASK)
    os.replace(tmp, path)


def _to_jsonable(obj: Any):
    if isinstance(obj, np.ndarray):
        return obj.tolist()
    if isinstance(obj, (np.floating,)):
        return float(obj)
    if isinstance(obj, (np.integer,)):
        return int(obj)
    if isinstance(obj, (np.bool_,)):
        return bool(obj)
    raise TypeError(f"not JSON serialisable: {type(obj).__name__}")


def write_json(path: str | os.PathLike, data: Mapping[str, Any]) -> Path:
    """Write ``data`` as indented JSON, atomically. NaN is written as null."""
    path, tmp = _atomic_target(path, ".json")
    text = json.dumps(_nan_to_none(data), indent=2, default=_to_jsonable, allow_nan=False)
    try:
        tmp.write_text(text + "\n")
        _publish(tmp, path)
    finally:
        tmp.unlink(missing_ok=True)
    return path


def _nan_to_none(obj: Any):
    if isinstance(obj, float) and not np.isfinite(obj):
        return None
    if isinstance(obj, dict):
        return {k: _nan_to_none(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [_nan_to_none(v) for v in obj]
    if isinstance(obj, np.ndarray) and obj.dtype.kind == "f":
        return _nan_to_none(obj.tolist())
    return obj


def write_npz(path: str | os.PathLike, **arrays: Any) -> Path:
    """Write arrays to an uncompressed ``.npz`` atomically (no object arrays)."""
    path, tmp = _atomic_target(path, ".npz")
    clean = {}
    for key, val in arrays.items():
        arr = np.asarray(val)
        if arr.dtype == object:
            raise ValueError(f"write_npz: array {key!r} has dtype object; only plain arrays are stored")
        clean[key] = arr
    try:
        with open(tmp, "wb") as fh:
            np.savez(fh, **clean)
        _publish(tmp, path)
    finally:
        tmp.unlink(missing_ok=True)
    return path


def load_npz(path: str | os.PathLike, required: tuple[str, ...] = ()) -> dict[str, np.ndarray]:
    """Load an ``.npz`` written by :func:`write_npz` with ``allow_pickle=False``."""
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"{path}: no such file (expected an .npz artifact)")
    import zipfile

    if not zipfile.is_zipfile(path):
        raise ValueError(f"{path}: not an .npz file (expected a zip archive of .npy arrays)")
    try:
        with np.load(path, allow_pickle=False) as z:
            data = {k: z[k] for k in z.files}
    except ValueError as exc:
        if "pickle" in str(exc).lower():
            raise ValueError(f"{path}: holds object (pickled) arrays; nanosim reads plain numeric arrays only") \
                from None
        raise ValueError(f"{path}: not a readable .npz file ({str(exc).splitlines()[0]})") from None
    except Exception as exc:  # zipfile/format errors  # noqa: BLE001
        raise ValueError(f"{path}: not a readable .npz file ({type(exc).__name__})") from None
    missing = [k for k in required if k not in data]
    if missing:
        raise ValueError(f"{path}: missing arrays {missing}; found {sorted(data)}")
    return data


def save_figure(fig, path: str | os.PathLike, dpi: int = 110) -> Path:
    """Save a matplotlib ``Figure`` as PNG atomically (pyplot is never involved)."""
    path, tmp = _atomic_target(path, ".png")
    try:
        fig.savefig(tmp, dpi=dpi, format="png", bbox_inches="tight")
        _publish(tmp, path)
    finally:
        tmp.unlink(missing_ok=True)
    return path


_MAT_HEADER = b"MATLAB 5.0 MAT-file, Platform: posix, written by nanosim".ljust(116, b" ")


def write_mat(path: str | os.PathLike, data: Mapping[str, Any]) -> Path:
    """Write a MATLAB ``.mat`` file (``scipy.io.savemat``, compressed, 1-D arrays as rows) atomically.

    The 116-byte descriptive header, where scipy writes the creation time, holds a fixed text instead,
    so that the same data give the same bytes (MATLAB reads the header as a comment).
    """
    from scipy.io import savemat

    path, tmp = _atomic_target(path, ".mat")
    try:
        savemat(tmp, data, do_compression=True, oned_as="row")
        with open(tmp, "r+b") as fh:
            fh.write(_MAT_HEADER)
        _publish(tmp, path)
    finally:
        tmp.unlink(missing_ok=True)
    return path


def write_text(path: str | os.PathLike, text: str) -> Path:
    """Write ``text`` to ``path`` atomically."""
    path, tmp = _atomic_target(path, ".tmp")
    try:
        tmp.write_text(text)
        _publish(tmp, path)
    finally:
        tmp.unlink(missing_ok=True)
    return path
