"""Input/output records from files: ``.npz``, ``.mat`` (v5 and v7.3) and ``.csv``.

A record is the inputs ``u`` (samples x inputs), the outputs ``y`` (samples x
outputs) and the sample time ``Ts`` [s] of one experiment, in any units.

Accepted names
--------------
``.npz`` and ``.mat`` (MATLAB variables):

* inputs: ``u`` (also ``U``, ``inputs``);
* outputs: ``y`` (also ``Y``, ``outputs``);
* sample time: ``Ts`` [s] (also ``dt``, ``Ts_s``, ``dt_s``), or the sampling frequency ``fs`` [Hz]
  (also ``fs_hz``, ``Fs``), or a time vector ``t`` [s] (also ``time``, ``t_s``) of uniform spacing;
* optional ``input_names``, ``output_names`` (strings).

A 1-D ``u`` or ``y`` is one channel. ``.mat`` v7.3 files are HDF5 (read with ``h5py``);
MATLAB stores them column-major, so their arrays are transposed back to MATLAB's shape.

``.csv``: a header row naming the columns ``t, u1..un, y1..ym`` (``t`` in seconds; also
``time``, ``t_s``), comma separated, one row per sample. The columns ``u<k>`` are the inputs
and ``y<k>`` the outputs, in the order of ``k``.

Every check raises ``ValueError`` with a one-line message naming the file, the variable,
what was expected and what arrived: a missing variable, a wrong shape (more channels than
samples: a transposed matrix), NaN/inf, unequal lengths, a constant input, a non-positive
sample time, a time vector that is not increasing or not uniform (relative spacing error
above :data:`UNIFORM_RTOL`), too few samples (:data:`MIN_SAMPLES`).
"""
from __future__ import annotations

import csv
import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np

__all__ = ["Record", "load_record", "record_from_arrays", "load_state_space", "INPUT_NAMES", "OUTPUT_NAMES",
           "TS_NAMES", "FS_NAMES", "T_NAMES", "MIN_SAMPLES", "UNIFORM_RTOL"]

INPUT_NAMES = ("u", "U", "inputs")
OUTPUT_NAMES = ("y", "Y", "outputs")
TS_NAMES = ("Ts", "dt", "Ts_s", "dt_s")
FS_NAMES = ("fs", "fs_hz", "Fs")
T_NAMES = ("t", "time", "t_s")
# fewest samples a record may have: the subspace identification's Hankel matrices need many more
# columns than rows (horizon ~ 2 x order block rows per channel)
MIN_SAMPLES = 200
# a time vector is uniform when every spacing is within this fraction of the mean spacing (covers
# the rounding of a CSV written with 6 significant digits)
UNIFORM_RTOL = 1e-3


@dataclass(frozen=True, eq=False)
class Record:
    """One experiment: inputs, outputs and the sample time.

    Attributes
    ----------
    u : numpy.ndarray, shape (n_samples, n_inputs)
    y : numpy.ndarray, shape (n_samples, n_outputs)
    dt_s : float
        Sample time [s].
    input_names, output_names : tuple of str
        Channel labels (``u1..un``, ``y1..ym`` unless the file names them).
    source : str
        The file it came from.
    """

    u: np.ndarray
    y: np.ndarray
    dt_s: float
    input_names: tuple
    output_names: tuple
    source: str = ""

    @property
    def n_samples(self) -> int:
        return self.u.shape[0]

    @property
    def n_inputs(self) -> int:
        return self.u.shape[1]

    @property
    def n_outputs(self) -> int:
        return self.y.shape[1]

    @property
    def fs(self) -> float:
        """Sampling frequency [Hz]."""
        return 1.0 / self.dt_s


def _pick(data: dict, names, where: str, what: str, required: bool = True):
    for n in names:
        if n in data:
            return n, data[n]
    if required:
        found = ", ".join(sorted(k for k in data if not k.startswith("__"))) or "nothing"
        raise ValueError(f"{where}: no {what} (expected a variable named {' or '.join(names)}), found {found}")
    return None, None


def _channels(where: str, name: str, value) -> np.ndarray:
    try:
        a = np.asarray(value, dtype=float)
    except (TypeError, ValueError):
        raise ValueError(f"{where}: {name} must be numeric, got {np.asarray(value).dtype}") from None
    if a.ndim == 0:
        raise ValueError(f"{where}: {name} must be samples x channels, got a scalar")
    if a.ndim == 1:
        a = a[:, None]
    if a.ndim != 2:
        raise ValueError(f"{where}: {name} must be samples x channels (2-D), got shape {a.shape}")
    if a.shape[0] < a.shape[1]:
        raise ValueError(f"{where}: {name} must be samples x channels, got {a.shape[0]} x {a.shape[1]} "
                         f"(more channels than samples: transposed?)")
    bad = ~np.isfinite(a)
    if bad.any():
        r, c = np.argwhere(bad)[0]
        raise ValueError(f"{where}: {name} has {int(bad.sum())} NaN/inf entries (first at sample {int(r)}, "
                         f"channel {int(c) + 1})")
    return a


def _scalar(where: str, name: str, value) -> float:
    a = np.asarray(value, dtype=float).ravel()
    if a.size != 1:
        raise ValueError(f"{where}: {name} must be one number, got {a.size} values")
    return float(a[0])


def _dt_from_time(where: str, name: str, t) -> float:
    t = np.asarray(t, dtype=float).ravel()
    if t.size < 2 or not np.all(np.isfinite(t)):
        raise ValueError(f"{where}: {name} must be a finite time vector of at least 2 samples")
    d = np.diff(t)
    if np.any(d <= 0):
        k = int(np.argmax(d <= 0))
        raise ValueError(f"{where}: {name} must increase, but {name}[{k + 1}] = {t[k + 1]:g} s <= "
                         f"{name}[{k}] = {t[k]:g} s")
    dt = float((t[-1] - t[0]) / (t.size - 1))
    dev = np.abs(d - dt) / dt
    if dev.max() > UNIFORM_RTOL:
        k = int(np.argmax(dev))
        raise ValueError(f"{where}: {name} must be uniformly sampled, but the spacing at sample {k} is {d[k]:g} s "
                         f"against the mean {dt:g} s ({100 * dev[k]:.2g} %, tolerance {100 * UNIFORM_RTOL:g} %)")
    return dt


def _names(data: dict, key: str, prefix: str, n: int, where: str) -> tuple:
    if key not in data:
        return tuple(f"{prefix}{k + 1}" for k in range(n))
    raw = np.asarray(data[key]).ravel()
    names = tuple(str(v).strip() for v in raw)
    if len(names) != n:
        raise ValueError(f"{where}: {key} must name {n} channels, got {len(names)}")
    return names


def record_from_arrays(data: dict, where: str = "record") -> Record:
    """A :class:`Record` from a mapping of variables with the accepted names (module docstring).

    Parameters
    ----------
    data : dict
        Variables by name (``u``, ``y``, one of ``Ts``/``fs``/``t``, optional channel names).
    where : str
        The file (or label) the messages name.

    Returns
    -------
    Record
    """
    nu, u = _pick(data, INPUT_NAMES, where, "inputs")
    ny, y = _pick(data, OUTPUT_NAMES, where, "outputs")
    u = _channels(where, nu, u)
    y = _channels(where, ny, y)
    if u.shape[0] != y.shape[0]:
        raise ValueError(f"{where}: {nu} and {ny} must have the same number of samples, got {u.shape[0]} and "
                         f"{y.shape[0]}")
    kt, ts = _pick(data, TS_NAMES, where, "", required=False)
    kf, fs = _pick(data, FS_NAMES, where, "", required=False)
    kx, t = _pick(data, T_NAMES, where, "", required=False)
    if kt is not None:
        dt = _scalar(where, kt, ts)
    elif kf is not None:
        f = _scalar(where, kf, fs)
        if not np.isfinite(f) or f <= 0:
            raise ValueError(f"{where}: {kf} must be a sampling frequency > 0 Hz, got {f:g}")
        dt = 1.0 / f
    elif kx is not None:
        if np.asarray(t).size != u.shape[0]:
            raise ValueError(f"{where}: {kx} must have one time per sample ({u.shape[0]}), got {np.asarray(t).size}")
        dt, kt = _dt_from_time(where, kx, t), kx
    else:
        raise ValueError(f"{where}: no sample time (expected Ts in seconds, or fs in Hz, or a time vector t)")
    if not np.isfinite(dt) or dt <= 0:
        raise ValueError(f"{where}: {kt} must be a sample time > 0 s, got {dt:g}")
    if u.shape[0] < MIN_SAMPLES:
        raise ValueError(f"{where}: expected at least {MIN_SAMPLES} samples, got {u.shape[0]}")
    flat = [k + 1 for k in range(u.shape[1]) if np.ptp(u[:, k]) == 0]
    if flat:
        raise ValueError(f"{where}: input channel {flat[0]} of {nu} is constant (it cannot identify dynamics)")
    return Record(u=u, y=y, dt_s=float(dt), input_names=_names(data, "input_names", "u", u.shape[1], where),
                  output_names=_names(data, "output_names", "y", y.shape[1], where), source=where)


def _read_npz(path: Path) -> dict:
    import zipfile
    if not zipfile.is_zipfile(path):
        raise ValueError(f"{path}: not an .npz file (expected a zip archive of .npy arrays)")
    try:
        with np.load(path) as z:
            return {k: z[k] for k in z.files}
    except ValueError as exc:
        raise ValueError(f"{path}: not a readable .npz file of plain arrays ({str(exc).splitlines()[0]})") from None


def _is_hdf5(path: Path) -> bool:
    with open(path, "rb") as fh:
        head = fh.read(1024)
    return b"\x89HDF\r\n\x1a\n" in head[:8] or head[512:520] == b"\x89HDF\r\n\x1a\n"


def _read_mat73(path: Path) -> dict:
    import h5py
    out = {}
    with h5py.File(path, "r") as f:
        for k, v in f.items():
            if isinstance(v, h5py.Dataset) and v.dtype.kind in "fiu":
                out[k] = np.asarray(v[()]).T           # column-major on disk: back to MATLAB's shape
    return out


def _read_mat(path: Path) -> dict:
    if _is_hdf5(path):
        try:
            return _read_mat73(path)
        except OSError as exc:
            raise ValueError(f"{path}: not a readable MATLAB v7.3 (HDF5) file ({exc})") from None
    from scipy.io import loadmat
    try:
        d = loadmat(path, squeeze_me=False)
    except Exception as exc:  # scipy raises several types for a broken file  # noqa: BLE001
        raise ValueError(f"{path}: not a readable .mat file ({type(exc).__name__}: {str(exc).splitlines()[0]})") \
            from None
    return {k: v for k, v in d.items() if not k.startswith("__")}


_U_COL = re.compile(r"^u(\d+)$")
_Y_COL = re.compile(r"^y(\d+)$")


def _read_csv(path: Path) -> dict:
    with open(path, newline="") as fh:
        rows = [r for r in csv.reader(fh) if r and not r[0].lstrip().startswith("#")]
    if not rows:
        raise ValueError(f"{path}: empty CSV (expected a header t, u1..un, y1..ym and one row per sample)")
    header = [h.strip() for h in rows[0]]
    ucols = sorted(((int(m.group(1)), i) for i, h in enumerate(header) if (m := _U_COL.match(h))))
    ycols = sorted(((int(m.group(1)), i) for i, h in enumerate(header) if (m := _Y_COL.match(h))))
    tcol = next((i for i, h in enumerate(header) if h in T_NAMES), None)
    missing = [w for w, c in (("t", tcol), ("u1", ucols), ("y1", ycols)) if c is None or c == []]
    if missing:
        raise ValueError(f"{path}: CSV header must name columns t, u1..un, y1..ym; missing {', '.join(missing)} "
                         f"in header {','.join(header)}")
    body = rows[1:]
    width = len(header)
    for k, r in enumerate(body):
        if len(r) != width:
            raise ValueError(f"{path}: row {k + 2} has {len(r)} fields, the header {width}")
    try:
        M = np.array([[float(x) if x.strip() else np.nan for x in r] for r in body], dtype=float)
    except ValueError as exc:
        raise ValueError(f"{path}: CSV fields must be numbers ({exc})") from None
    M = M.reshape(len(body), width)
    return {"t": M[:, tcol], "u": M[:, [i for _, i in ucols]], "y": M[:, [i for _, i in ycols]],
            "input_names": np.array([header[i] for _, i in ucols]),
            "output_names": np.array([header[i] for _, i in ycols])}


def load_record(path) -> Record:
    """Read one input/output record from ``path`` (``.npz``, ``.mat`` v5/v7.3 or ``.csv``; module docstring).

    Parameters
    ----------
    path : path-like

    Returns
    -------
    Record

    Raises
    ------
    FileNotFoundError
        No such file.
    ValueError
        Unknown suffix, unreadable file, missing variable, wrong shape, NaN/inf, unequal lengths,
        a constant input, a bad sample time or time vector (one-line message).
    """
    p = Path(path)
    if not p.is_file():
        raise FileNotFoundError(f"{p}: no such file (expected an .npz, .mat or .csv record)")
    readers = {".npz": _read_npz, ".mat": _read_mat, ".csv": _read_csv}
    reader = readers.get(p.suffix.lower())
    if reader is None:
        raise ValueError(f"{p}: expected an .npz, .mat or .csv record, got the suffix {p.suffix!r}")
    return record_from_arrays(reader(p), where=str(p))


def load_state_space(path) -> tuple:
    """``(A, B, C, D, Ts)`` from a MATLAB ``.mat`` file (v5 or v7.3), as ``ss(A, B, C, D, Ts)`` names them.

    ``Ts`` [s] is the sample time of a discrete model, 0 for a continuous one (also ``dt``);
    a missing ``Ts`` is an error, as is a missing matrix, NaN/inf or inconsistent shapes.
    """
    p = Path(path)
    if not p.is_file():
        raise FileNotFoundError(f"{p}: no such file (expected a .mat state space A, B, C, D, Ts)")
    if p.suffix.lower() != ".mat":
        raise ValueError(f"{p}: expected a MATLAB .mat state space, got the suffix {p.suffix!r}")
    data = _read_mat(p)
    missing = [k for k in "ABCD" if k not in data]
    if missing:
        found = ", ".join(sorted(data)) or "nothing"
        raise ValueError(f"{p}: missing the state-space matrices {', '.join(missing)} (expected A, B, C, D, Ts), "
                         f"found {found}")
    A, B, C, D = (np.atleast_2d(np.asarray(data[k], dtype=float)) for k in "ABCD")
    n = A.shape[0]
    if A.shape != (n, n) or B.shape[0] != n or C.shape[1] != n or D.shape != (C.shape[0], B.shape[1]):
        raise ValueError(f"{p}: inconsistent shapes A{A.shape} B{B.shape} C{C.shape} D{D.shape}")
    for k, v in (("A", A), ("B", B), ("C", C), ("D", D)):
        if not np.all(np.isfinite(v)):
            raise ValueError(f"{p}: matrix {k} has NaN/inf entries")
    key = next((k for k in ("Ts", "dt") if k in data), None)
    if key is None:
        raise ValueError(f"{p}: no sample time (expected Ts in seconds, 0 for a continuous model)")
    ts = _scalar(str(p), key, data[key])
    if not np.isfinite(ts) or ts < 0:
        raise ValueError(f"{p}: {key} must be a sample time >= 0 s, got {ts:g}")
    return A, B, C, D, ts
