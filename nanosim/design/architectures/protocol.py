r"""What the bench runs: discrete state spaces, Python objects, and how a name becomes a controller.

The loop protocol
-----------------
The closed loop (:func:`nanosim.experiments.loop.run_closed_loop`) and the viewer call
four things on a controller; :class:`~nanosim.design.controller.DiscreteController`
has them all:

* ``feedback(reference_V, measurement_V) -> u_V`` (3,) controller volts, once per sample;
* ``reset(x0=None, *, measurement_V=None)`` -- zero state, or the equilibrium at a reading;
* ``reset_at(measurement_V)`` -- start at a reading without a kick;
* ``two_dof`` -- True if ``reset`` takes ``measurement_V``.

A user's controller object needs only ``step(error_V, measurement_V) -> u_V`` and
``reset(measurement_V=None)``; :class:`ObjectController` adds the rest. Reference-aware
controllers (feedforward) need no more than this: with ``e = r - y`` and ``y`` they have
``r = e + y``, so a feedforward is an ordinary two-degree-of-freedom controller with
inputs ``[e; y]`` (:mod:`nanosim.design.architectures.feedforward`).

Controller files
----------------
One reader, :func:`read_controller_file`, for every command (``--controller`` of characterize,
montecarlo and view, ``--controllers`` of compare). A controller file is a
``.npz`` or a MATLAB ``.mat`` file holding one state space

.. math:: x_{k+1} = A x_k + B [e_k; y_k], \qquad u_k = C x_k + D [e_k; y_k]

with the variables

* ``Akd, Bkd, Ckd, Dkd`` (what ``nanosim design`` writes as ``controller.npz``) or ``A, B, C, D``
  (a python-control or MATLAB ``ss``), 3 outputs (controller V), 3 error inputs ``e = r - y``
  (sensor V) and optionally 3 measurement inputs ``y`` (a two-degree-of-freedom controller);
* ``dt`` (or MATLAB's ``Ts``): the sample time in seconds, required. It must be the loop's
  period, 2.5e-4 s (4 kHz); ``dt = 0`` marks a continuous ``A, B, C, D``, mapped to 4 kHz by
  Tustin. A file without it is refused, naming the variable: the sample time is never assumed;
* ``n_error`` (optional): the number of error inputs (default 3; all inputs if 3, then 3
  measurements if there are 6).

Controller specifications (``nanosim compare --controllers ...``)
------------------------------------------------------------------
* a design name (:data:`nanosim.design.architectures.DESIGN_RULES`: the scored bench and ``lqg-bandwidth``),
  designed from the identified model;
* a controller file (above);
* ``module:function`` or ``path/to/file.py:function``: ``function()`` returns a fresh
  controller object (``step``/``reset``), a ``DiscreteController``/``ControllerConfig``, or a
  discrete StateSpace.
"""
from __future__ import annotations

import importlib
import importlib.util
import os
import re
import sys
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable

import numpy as np

from nanosim.design.architectures.common import DT_S, BenchDesign, split_2dof
from nanosim.design.controller import ControllerConfig, DiscreteController

__all__ = ["ObjectController", "ControllerSpec", "load_controller", "config_from_arrays", "is_bench_name",
           "read_controller_file", "CONTROLLER_FILE_SUFFIXES"]

#: File types :func:`read_controller_file` reads.
CONTROLLER_FILE_SUFFIXES = (".npz", ".mat")

_SPEC_FUNC = re.compile(r"^(?P<mod>[^:]+):(?P<func>[A-Za-z_][A-Za-z0-9_]*)$")


class ObjectController:
    """A user's controller object behind the loop protocol.

    Parameters
    ----------
    obj : object
        Has ``step(error_V, measurement_V) -> u_V`` (3 error and 3 measurement values in
        sensor V in, 3 commands in controller V out) and ``reset(measurement_V=None)``.
    n : int
        Channels (3).
    """

    two_dof = True

    def __init__(self, obj, n: int = 3):
        for m in ("step", "reset"):
            if not callable(getattr(obj, m, None)):
                raise ValueError(f"controller: expected an object with step(error_V, measurement_V) and "
                                 f"reset(measurement_V=None), got {type(obj).__name__} without {m}()")
        self.obj = obj
        self.n = int(n)

    def reset(self, x0=None, *, measurement_V=None) -> None:
        """Reset the object (``x0`` is not supported: objects own their state)."""
        if x0 is not None:
            raise ValueError("x0: a controller object owns its state; reset it with measurement_V")
        self.obj.reset(measurement_V=None if measurement_V is None else np.asarray(measurement_V, float).copy())

    def reset_at(self, measurement_V) -> None:
        """Start at the reading ``measurement_V`` [sensor V]."""
        self.reset(measurement_V=measurement_V)

    def step(self, error_V, measurement_V=None) -> np.ndarray:
        """One sample of the object's ``step``; the command is checked (shape and finite)."""
        e = np.asarray(error_V, float)
        y = np.zeros(self.n) if measurement_V is None else np.asarray(measurement_V, float)
        u = np.asarray(self.obj.step(e.copy(), y.copy()), dtype=float)
        if u.shape != (self.n,) or not np.all(np.isfinite(u)):
            raise ValueError(f"controller: step() must return {self.n} finite commands (controller V), got "
                             f"shape {u.shape}" + ("" if u.shape != (self.n,) else " with NaN/inf"))
        return u

    def feedback(self, reference_V, measurement_V) -> np.ndarray:
        """``step(r - y, y)``."""
        y = np.asarray(measurement_V, float)
        return self.step(np.asarray(reference_V, float) - y, y)


@dataclass(frozen=True, eq=False)
class ControllerSpec:
    """A resolved controller: how to make fresh instances and, if it is linear, its matrices.

    Attributes
    ----------
    name : str
        Label in the scorecard (the bench name, file stem or ``module:function``).
    source : str
        Where it came from (``bench``, a path, ``module:function``).
    make : callable
        ``make()`` -> a fresh controller with the loop protocol (zero state).
    config : ControllerConfig or None
        Matrices of a linear time-invariant controller (None for an object).
    design : BenchDesign or None
        The bench design (tuning rule, parameters), for bench names.
    """

    name: str
    source: str
    make: Callable[[], Any]
    config: ControllerConfig | None = None
    design: BenchDesign | None = None

    @property
    def is_lti(self) -> bool:
        """True if the controller is a discrete state space (the robustness analysis applies)."""
        return self.config is not None

    def systems(self):
        """``(K, Ky)`` discrete StateSpaces of ``u = K e + Ky y`` (``Ky`` None for error-only)."""
        import control as ct
        if self.config is None:
            raise ValueError(f"{self.name}: a controller object has no state-space matrices")
        c = self.config
        return split_2dof(ct.ss(c.Akd, c.Bkd, c.Ckd, c.Dkd, c.dt), c.n_error)


def is_bench_name(spec: str) -> bool:
    """True if ``spec`` names a bench architecture or another named design rule (``DESIGN_RULES``)."""
    from nanosim.design.architectures import DESIGN_RULES
    return spec in DESIGN_RULES


def _n_error(n_in: int, n_out: int, given) -> int | None:
    if given is not None:
        return int(np.asarray(given).ravel()[0])
    if n_in == 2 * n_out:
        return n_out
    return None


def config_from_arrays(data: dict, source: str, dt: float = DT_S) -> ControllerConfig:
    """A :class:`ControllerConfig` from ``Akd..Dkd, dt`` or ``A, B, C, D, dt`` arrays.

    A continuous system (``dt = 0`` with ``A..D``) is mapped to ``dt`` by Tustin.

    Raises
    ------
    ValueError
        Missing matrices, no sample time (``dt``/``Ts``), wrong shapes or a sample time other than ``dt``.
    """
    import control as ct
    keys = ("Akd", "Bkd", "Ckd", "Dkd") if "Akd" in data else ("A", "B", "C", "D")
    missing = [k for k in keys if k not in data]
    if missing:
        raise ValueError(f"{source}: expected the matrices A, B, C, D (and dt) of a state space, missing "
                         f"{', '.join(missing)}")
    A, B, C, D = (np.atleast_2d(np.asarray(data[k], float)) for k in keys)
    if A.size == 0:
        A = np.zeros((0, 0))
    key = "dt" if "dt" in data else ("Ts" if "Ts" in data else None)
    if key is None:
        raise ValueError(f"{source}: dt: expected the variable dt, the controller's sample time in s "
                         f"({dt:g} for the loop, 0 for a continuous A, B, C, D), found only "
                         f"{', '.join(sorted(map(str, data)))}")
    try:
        T = float(np.asarray(data[key], float).ravel()[0])
    except (TypeError, ValueError, IndexError):
        raise ValueError(f"{source}: {key}: expected the sample time in s, got {data[key]!r}") from None
    if not np.isfinite(T) or T < 0:
        raise ValueError(f"{source}: {key}: expected a sample time >= 0 s, got {T!r}")
    ne = _n_error(B.shape[1], C.shape[0], data.get("n_error"))
    if T == 0.0:
        if keys[0] == "Akd":
            raise ValueError(f"{source}: dt: expected the control period {dt:g} s, got 0")
        sysd = ct.c2d(ct.ss(A, B, C, D), dt, "tustin")
        A, B, C, D, T = sysd.A, sysd.B, sysd.C, sysd.D, dt
    if abs(T - dt) > 1e-9 * dt:
        raise ValueError(f"{source}: dt: expected the control period {dt:g} s (or 0 for a continuous system), "
                         f"got {T:g} s")
    try:
        return ControllerConfig(A, B, C, D, T, ne)
    except ValueError as exc:
        raise ValueError(f"{source}: {exc}") from None


def read_controller_file(path, *, dt: float = DT_S, n: int = 3, name: str = "controller") -> ControllerConfig:
    """Read a controller file (``.npz`` or ``.mat``, see the module docstring) as a :class:`ControllerConfig`.

    The one reader of controller files: ``nanosim characterize``, ``montecarlo``, ``view`` and
    ``compare`` all read their controllers with it.

    Parameters
    ----------
    path : path
        The file.
    dt : float
        The loop's sample time [s]; a discrete controller must have it, a continuous one is
        mapped to it by Tustin.
    n : int
        Channels (3 commands, 3 error inputs).
    name : str
        The argument named in error messages (``--controller``).

    Raises
    ------
    ValueError
        Not a ``.npz``/``.mat`` file, unreadable, missing matrices or sample time, wrong shapes,
        another sample time, or not 3 commands and 3 error inputs; the message starts with ``name``.
    FileNotFoundError
        No such file.
    """
    p = Path(path)
    if p.is_dir():
        raise ValueError(f"{name}: expected a controller file (.npz or .mat), got the directory {str(p)!r}")
    if not p.is_file():
        raise FileNotFoundError(f"{name}: no such file {str(p)!r}")
    try:
        cfg = _load_matrix_file(p, dt)
        _check_io(cfg, n, str(p))
    except (OSError, ValueError, KeyError) as exc:
        msg = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
        for prefix in (f"controller {str(p)!r}: ", "controller: "):
            msg = msg[len(prefix):] if msg.startswith(prefix) else msg
        if str(p) not in msg:
            msg = f"{str(p)!r}: {msg}"
        raise ValueError(f"{name}: {msg}") from None
    return cfg


def _load_matrix_file(path: Path, dt: float) -> ControllerConfig:
    if path.suffix == ".npz":
        from nanosim import fileio
        data = dict(fileio.load_npz(path))
    elif path.suffix == ".mat":
        from scipy.io import loadmat
        try:
            raw = loadmat(path)
        except Exception as exc:    # scipy raises several types for a bad file
            raise ValueError(f"{path}: not a readable .mat file ({exc})") from None
        data = {k: v for k, v in raw.items() if not k.startswith("__")}
    else:
        raise ValueError(f"controller: expected a .npz or .mat file, got {str(path)!r}")
    for key, v in data.items():
        if np.iscomplexobj(v):
            raise ValueError(f"{path}: {key}: expected real values, got a complex array")
    for key in ("dt", "Ts"):
        if key in data and np.size(data[key]) != 1:
            raise ValueError(f"{path}: {key}: expected one sample time in seconds, got {np.size(data[key])} values")
    return config_from_arrays(data, str(path), dt)


def _import_function(spec: str):
    m = _SPEC_FUNC.match(spec)
    if not m:
        raise ValueError(f"controller: expected a bench name, a .npz/.mat file or module:function, got {spec!r}")
    mod, func = m.group("mod"), m.group("func")
    if mod.endswith(".py"):
        p = Path(mod)
        if not p.is_file():
            raise ValueError(f"controller: no such file {mod!r} (in {spec!r})")
        name = f"nanosim_user_{p.stem}"
        s = importlib.util.spec_from_file_location(name, p)
        module = importlib.util.module_from_spec(s)
        sys.modules[name] = module
        s.loader.exec_module(module)
    else:
        try:
            module = importlib.import_module(mod)
        except ImportError as exc:
            raise ValueError(f"controller: cannot import module {mod!r} ({exc})") from None
    fn = getattr(module, func, None)
    if not callable(fn):
        raise ValueError(f"controller: module {mod!r} has no function {func!r}")
    return fn


def _as_config(obj, dt: float):
    import control as ct
    if isinstance(obj, DiscreteController):
        return obj.config
    if isinstance(obj, ControllerConfig):
        return obj
    if isinstance(obj, BenchDesign):
        return obj.config
    if isinstance(obj, ct.StateSpace):
        return config_from_arrays({"A": obj.A, "B": obj.B, "C": obj.C, "D": obj.D, "dt": float(obj.dt or 0.0)},
                                  "controller", dt)
    return None


def load_controller(spec: str, model=None, *, dt: float = DT_S, n: int = 3) -> ControllerSpec:
    """Resolve a controller specification (see the module docstring).

    Parameters
    ----------
    spec : str
        Bench name, ``.npz``/``.mat`` path, or ``module:function``.
    model : control.StateSpace or None
        Identified plant; required for bench names.
    dt : float
        Control period [s].
    n : int
        Channels (3).

    Returns
    -------
    ControllerSpec
    """
    from nanosim.design.architectures import DESIGN_RULES, design
    if not isinstance(spec, str) or not spec:
        raise ValueError(f"controller: expected a non-empty string, got {spec!r}")
    if spec in DESIGN_RULES:
        if model is None:
            raise ValueError(f"controller {spec!r}: bench designs need the identified model (--model)")
        d = design(spec, model, dt=dt)
        cfg = d.config
        return ControllerSpec(spec, "bench", lambda: DiscreteController(cfg), cfg, d)
    p = Path(spec)
    if p.suffix in (".npz", ".mat") and ":" not in spec.replace(os.sep, "/").split("/")[-1]:
        if not p.is_file():
            raise ValueError(f"controller: no such file {spec!r}")
        cfg = _load_matrix_file(p, dt)
        _check_io(cfg, n, spec)
        return ControllerSpec(p.stem, str(p), lambda: DiscreteController(cfg), cfg)
    fn = _import_function(spec)
    first = fn()
    cfg = _as_config(first, dt)
    mod, func = spec.rsplit(":", 1)
    label = f"{Path(mod).stem}:{func}" if mod.endswith(".py") else spec
    if cfg is not None:
        _check_io(cfg, n, spec)
        return ControllerSpec(label, spec, lambda: DiscreteController(cfg), cfg)
    ObjectController(first, n)          # checks the methods before any run
    made = [first]

    def make():
        obj = made.pop() if made else fn()
        return ObjectController(obj, n)
    return ControllerSpec(label, spec, make)


def _check_io(cfg: ControllerConfig, n: int, spec: str) -> None:
    if cfg.n_out != n or cfg.n_error != n:
        raise ValueError(f"controller {spec!r}: expected {n} commands and {n} error inputs "
                         f"(then {n} measurements for two degrees of freedom), got {cfg.n_out} outputs, "
                         f"{cfg.n_error} error and {cfg.n_measurement} measurement inputs")
