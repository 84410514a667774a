"""Real-time discrete H-infinity controller (runs at the 4 kHz control rate).

Loads the discrete controller written by :func:`nanosim.pipeline.design.run_design`
(``controller.npz``: ``Akd, Bkd, Ckd, Dkd, dt``) and implements::

    x[k+1] = Akd x[k] + Bkd e[k]
    u[k]   = Ckd x[k] + Dkd e[k]

Units: ``e`` = tracking error ``r - y`` in **sensor volts** (X, Y, Z; 5 um/V),
``u`` = command in **controller volts** for actuators A, B, C (before the x20
piezo amplifier; the paper's command range is -1 ... 7.5 V, see
``nanosim.constants.COMMAND_RANGE_V``). Saturation is *not* applied here: the
plant/simulator owns actuator limits. Sign convention: negative feedback,
``e = r - y``, ``u = +K e`` (see :mod:`nanosim.design`).

Two-degree-of-freedom controllers (an H-infinity tracking loop around an
active-damping loop, ``nanosim.design.DampingLoop``) have ``n_error`` error
inputs followed by ``n_in - n_error`` measurement inputs ``y`` [sensor V]::

    u[k] = Ckd x[k] + Dkd [e[k]; y[k]],   e = r - y

and are stepped with ``step(e, y)``. ``n_error`` is stored in
``controller.npz``; files without it are one-degree-of-freedom.

The controller is pure numpy: ``[x[k+1]; u[k]] = M @ [x[k]; e[k]]`` with the
stacked matrix ``M = [[Akd, Bkd], [Ckd, Dkd]]`` precomputed, one matrix-vector
product per step.
"""
from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from nanosim import fileio

__all__ = ["ControllerConfig", "DiscreteController", "bumpless_state"]

_REQUIRED = ("Akd", "Bkd", "Ckd", "Dkd", "dt")
_OPTIONAL = ("n_error",)


def _floats(name: str, value) -> np.ndarray:
    """``value`` as a float array; ``ValueError`` naming ``name`` for anything that is not real numbers."""
    if np.iscomplexobj(value):
        raise ValueError(f"{name}: expected real numbers, got complex values")
    try:
        return np.asarray(value, dtype=float)
    except (TypeError, ValueError):
        raise ValueError(f"{name}: expected numbers, got {type(value).__name__}") from None


def _readonly(a) -> np.ndarray:
    a = np.array(a, dtype=float, copy=True)
    a.setflags(write=False)
    return a


@dataclass(frozen=True, eq=False)
class ControllerConfig:
    """Immutable discrete controller matrices (read-only arrays).

    Attributes
    ----------
    Akd : ndarray, shape (n, n)
    Bkd : ndarray, shape (n, n_in)
        ``n_in`` = error channels (3: X, Y, Z) [sensor V], followed by the
        measurement channels of a two-degree-of-freedom controller.
    Ckd : ndarray, shape (n_out, n)
        ``n_out`` = number of commands (3: A, B, C) [controller V].
    Dkd : ndarray, shape (n_out, n_in)
    dt : float
        Sample time [s] (1/4000 for the paper's controller).
    n_error : int or None
        Number of error inputs ``e = r - y``; the remaining ``n_in - n_error``
        inputs take the measurement ``y`` [sensor V]. ``None``: all inputs are errors.
    """

    Akd: np.ndarray
    Bkd: np.ndarray
    Ckd: np.ndarray
    Dkd: np.ndarray
    dt: float
    n_error: int | None = None

    def __post_init__(self):
        mats = {}
        for k in ("Akd", "Bkd", "Ckd", "Dkd"):
            a = _floats(k, getattr(self, k))
            if a.ndim != 2:
                raise ValueError(f"{k}: expected a 2-D matrix, got shape {a.shape}")
            if not np.all(np.isfinite(a)):
                raise ValueError(f"{k}: contains NaN/inf")
            mats[k] = a
        A, B, C, D = mats["Akd"], mats["Bkd"], mats["Ckd"], mats["Dkd"]
        n = A.shape[0]
        if A.shape != (n, n):
            raise ValueError(f"Akd: expected a square matrix, got shape {A.shape}")
        if B.shape[0] != n:
            raise ValueError(f"Bkd: expected {n} rows (states), got shape {B.shape}")
        if C.shape[1] != n:
            raise ValueError(f"Ckd: expected {n} columns (states), got shape {C.shape}")
        if D.shape != (C.shape[0], B.shape[1]):
            raise ValueError(f"Dkd: expected shape {(C.shape[0], B.shape[1])}, got {D.shape}")
        dt = _floats("dt", self.dt)
        if dt.size != 1 or not np.isfinite(dt) or float(dt) <= 0:
            raise ValueError(f"dt: expected one positive sample time in s, got {self.dt!r}")
        for k, a in mats.items():
            object.__setattr__(self, k, _readonly(a))
        object.__setattr__(self, "dt", float(dt.ravel()[0]))
        nin = B.shape[1]
        ne = nin if self.n_error is None else self.n_error
        try:
            ne_i = int(np.asarray(ne).ravel()[0])
        except (TypeError, ValueError, IndexError, OverflowError):
            raise ValueError(f"n_error: expected an integer, got {self.n_error!r}") from None
        if ne_i != float(np.asarray(ne).ravel()[0]) or not 1 <= ne_i <= nin or (ne_i != nin and nin - ne_i != ne_i):
            raise ValueError(f"n_error: expected {nin} (errors only) or {nin // 2} (errors then measurements), "
                             f"got {self.n_error!r}")
        object.__setattr__(self, "n_error", ne_i)

    @property
    def n_states(self) -> int:
        """Controller states."""
        return self.Akd.shape[0]

    @property
    def n_in(self) -> int:
        """Controller inputs (errors, then measurements for a two-degree-of-freedom controller)."""
        return self.Bkd.shape[1]

    @property
    def n_measurement(self) -> int:
        """Measurement inputs of a two-degree-of-freedom controller (0 otherwise)."""
        return self.n_in - self.n_error

    @property
    def n_out(self) -> int:
        """Controller outputs (controller volts, one per actuator)."""
        return self.Ckd.shape[0]

    @property
    def spectral_radius(self) -> float:
        """Max |eig(Akd)| (< 1 for a stable controller)."""
        return float(np.max(np.abs(np.linalg.eigvals(self.Akd)))) if self.n_states else 0.0


def bumpless_state(config: ControllerConfig, measurement_V, command_V=None) -> np.ndarray:
    """A state that starts a loop at the reading ``measurement_V`` with the output ``command_V``.

    The equilibrium for zero error at the reading, ``x = (I - Akd)^-1 Bkd [0; y]`` (zero for a
    one-degree-of-freedom controller), plus a correction along the controller's slowest modes
    (the integrators: eigenvalues of ``Akd`` nearest ``z = 1``) that makes the first output
    ``u = Ckd x + Dkd [0; y]`` equal ``command_V``; with fewer slow modes than commands the
    least-squares correction is used. The slow modes then carry the command and move at their
    leak rate, so a loop started this way does not kick.

    Parameters
    ----------
    config : ControllerConfig
    measurement_V : array_like, shape (n_measurement,)
        The reading [sensor V] (ignored by a one-degree-of-freedom controller).
    command_V : array_like, shape (n_out,), optional
        The command the actuators hold [controller V]; default zero (a stage at rest at home).

    Returns
    -------
    ndarray, shape (n_states,)
    """
    n = config.n_states
    u_target = np.zeros(config.n_out) if command_V is None else _floats("command_V", command_V)
    if u_target.shape != (config.n_out,) or not np.isfinite(u_target).all():
        raise ValueError(f"command_V: expected {config.n_out} finite values, got shape {u_target.shape}")
    inp = np.zeros(config.n_in)
    x_eq = np.zeros(n)
    if config.n_measurement:
        y = _floats("measurement_V", measurement_V)
        if y.shape != (config.n_measurement,) or not np.isfinite(y).all():
            raise ValueError(f"measurement_V: expected {config.n_measurement} finite values, got shape {y.shape}")
        inp[config.n_error:] = y
        if n:
            x_eq = np.linalg.solve(np.eye(n) - config.Akd, config.Bkd @ inp)
    du = u_target - (config.Ckd @ x_eq + config.Dkd @ inp)
    if n == 0 or not du.any():
        return x_eq
    lam, V = np.linalg.eig(config.Akd)
    order = np.argsort(np.abs(1.0 - lam))
    dx = np.zeros(n)
    for k in range(min(n, config.n_out), n + 1):      # as few (as slow) modes as reproduce the command
        Vs = V[:, order[:k]]
        coef, *_ = np.linalg.lstsq(config.Ckd @ Vs, du.astype(complex), rcond=None)
        dx = (Vs @ coef).real
        if np.abs(config.Ckd @ dx - du).max() <= 1e-9 * max(1.0, np.abs(du).max()):
            break
    return x_eq + dx


class DiscreteController:
    """Discrete state-space controller with internal state.

    Parameters
    ----------
    config : ControllerConfig
        Immutable matrices; the instance only holds the state ``x``.

    Examples
    --------
    >>> ctrl = DiscreteController.from_npz("out/controller.npz")      # doctest: +SKIP
    >>> u = ctrl.step(r - y)     # sensor V in, controller V out      # doctest: +SKIP
    """

    __slots__ = ("config", "_M", "_xe", "_n", "_nin", "_ne", "_out")

    def __init__(self, config: ControllerConfig):
        if not isinstance(config, ControllerConfig):
            raise ValueError(f"config: expected a ControllerConfig, got {type(config).__name__}")
        self.config = config
        n, nin = config.n_states, config.n_in
        self._n, self._nin, self._ne = n, nin, config.n_error
        self._M = np.ascontiguousarray(np.block([[config.Akd, config.Bkd], [config.Ckd, config.Dkd]]))
        self._xe = np.zeros(n + nin)          # [x; e] work vector
        self._out = np.empty(n + config.n_out)

    # --- construction ------------------------------------------------------------
    @classmethod
    def from_matrices(cls, Akd, Bkd, Ckd, Dkd, dt: float, n_error: int | None = None) -> "DiscreteController":
        """Build from the four discrete matrices and the sample time [s]
        (``n_error``: see :class:`ControllerConfig`).
        """
        return cls(ControllerConfig(Akd, Bkd, Ckd, Dkd, dt, n_error))

    @classmethod
    def from_npz(cls, path: str | os.PathLike, expected_dt: float | None = None) -> "DiscreteController":
        """Load ``controller.npz`` (keys ``Akd, Bkd, Ckd, Dkd, dt``; no pickle).

        Raises
        ------
        FileNotFoundError
            The file does not exist.
        ValueError
            Not a readable ``.npz``, missing keys, or inconsistent shapes / values.
        """
        path = Path(path)
        data = fileio.load_npz(path, required=_REQUIRED)
        extra = {k: data[k] for k in _OPTIONAL if k in data}
        try:
            ctrl = cls(ControllerConfig(*(data[k] for k in _REQUIRED), **extra))
        except ValueError as exc:
            raise ValueError(f"{path}: {exc}") from None
        if expected_dt is not None and abs(ctrl.config.dt - expected_dt) > 1e-9 * expected_dt:
            raise ValueError(f"{path}: dt: expected the loop's sample time {expected_dt:g} s, "
                             f"got {ctrl.config.dt:g} s")
        return ctrl

    # --- state -----------------------------------------------------------------------
    @property
    def state(self) -> np.ndarray:
        """Copy of the controller state ``x`` (shape ``(n_states,)``)."""
        return self._xe[: self._n].copy()

    @property
    def two_dof(self) -> bool:
        """True if :meth:`step` also needs the measurement ``y``."""
        return self._nin > self._ne

    def reset(self, x0=None, *, measurement_V=None) -> None:
        """Set the state to zero (or to ``x0``, shape ``(n_states,)``).

        With ``measurement_V`` (two-degree-of-freedom controllers only) the state
        is the equilibrium for zero error and a constant measurement
        ``y = measurement_V`` [sensor V], so that starting at a non-zero reading
        gives no transient: ``x = (I - Akd)^-1 Bkd [0; y]``.
        """
        if measurement_V is not None:
            if x0 is not None:
                raise ValueError("reset: give x0 or measurement_V, not both")
            if not self.two_dof:
                raise ValueError("measurement_V: this controller has no measurement inputs")
            y = self._check("measurement_V", measurement_V, self._nin - self._ne)
            c = self.config
            x0 = np.linalg.solve(np.eye(self._n) - c.Akd, c.Bkd[:, self._ne:] @ y) if self._n else np.zeros(0)
        if x0 is None:
            self._xe[:] = 0.0
            return
        x0 = _floats("x0", x0)
        if x0.shape != (self._n,) or not np.all(np.isfinite(x0)):
            raise ValueError(f"x0: expected {self._n} finite values, got shape {x0.shape}")
        self._xe[: self._n] = x0
        self._xe[self._n:] = 0.0

    def reset_at(self, measurement_V, command_V=None) -> None:
        """Start a loop at the reading ``measurement_V`` [sensor V] without a kick: the first
        command for zero error equals ``command_V`` [controller V] (default zero, a stage at rest
        at home); see :func:`bumpless_state`. A one-degree-of-freedom controller started at zero
        command gets the zero state.

        The plain equilibrium at the reading (:meth:`reset` with ``measurement_V``) is not a
        bumpless start: with integrators that leak its output is whatever holds the reading
        through the measurement path (tens of volts for the LQG designs at the home reading).
        """
        self.reset(bumpless_state(self.config, measurement_V, command_V))

    # --- stepping ----------------------------------------------------------------------
    def feedback(self, reference_V, measurement_V) -> np.ndarray:
        """One closed-loop sample: ``step(r - y)``, or ``step(r - y, y)`` for a
        two-degree-of-freedom controller (``r``, ``y`` in sensor V).
        """
        y = _floats("measurement_V", measurement_V)
        e = _floats("reference_V", reference_V) - y
        return self.step(e, y) if self.two_dof else self.step(e)

    @staticmethod
    def _check(name, value, n) -> np.ndarray:
        v = _floats(name, value)
        if v.shape != (n,):
            raise ValueError(f"{name}: expected shape ({n},), got {v.shape}")
        if not np.isfinite(v).all():
            raise ValueError(f"{name}: contains NaN/inf")
        return v

    def step(self, error_V, measurement_V=None) -> np.ndarray:
        """Advance one sample.

        Parameters
        ----------
        error_V : array_like, shape (n_error,)
            Tracking error ``r - y`` at sample k [sensor V] (X, Y, Z).
        measurement_V : array_like, shape (n_measurement,), optional
            Measured output ``y`` at sample k [sensor V]; required by (and only
            accepted for) two-degree-of-freedom controllers.

        Returns
        -------
        ndarray, shape (n_out,)
            Command ``u[k]`` [controller V] (A, B, C); the state advances to k+1.

        Raises
        ------
        ValueError
            A wrong shape, NaN/inf in an input, or an input so large that the next state or the
            command is not finite; the state is then left as it was.
        """
        e = self._check("error_V", error_V, self._ne)
        xe = self._xe
        n = self._n
        if self._nin > self._ne:
            if measurement_V is None:
                raise ValueError("measurement_V: this controller has an active-damping loop; pass the measured "
                                 f"output y ({self._nin - self._ne} values, sensor V) as well as the error")
            xe[n + self._ne:] = self._check("measurement_V", measurement_V, self._nin - self._ne)
        elif measurement_V is not None:
            raise ValueError("measurement_V: this controller takes the error only")
        xe[n:n + self._ne] = e
        np.dot(self._M, xe, out=self._out)
        if not np.isfinite(self._out).all():        # the state is kept as it was
            raise ValueError(f"error_V: the controller's next state or command overflows (not finite) for this "
                             f"input (largest |value| {np.abs(xe[n:]).max():.3g} V)")
        xe[:n] = self._out[:n]
        return self._out[n:].copy()

    def run(self, error_seq, reset: bool = True, measurement_seq=None) -> np.ndarray:
        """Apply :meth:`step` to a whole sequence.

        Parameters
        ----------
        error_seq : array_like, shape (N, n_error)
            Errors [sensor V], one row per sample.
        reset : bool, default True
            Start from the zero state (otherwise continue from the current one).
        measurement_seq : array_like, shape (N, n_measurement), optional
            Measurements [sensor V] for a two-degree-of-freedom controller.

        Returns
        -------
        ndarray, shape (N, n_out)
            Commands [controller V]. The state is left at sample N.
        """
        E = _floats("error_seq", error_seq)
        if E.ndim != 2 or E.shape[1] != self._ne:
            raise ValueError(f"error_seq: expected shape (N, {self._ne}), got {E.shape}")
        if not np.isfinite(E).all():
            raise ValueError("error_seq: contains NaN/inf")
        if self.two_dof:
            if measurement_seq is None:
                raise ValueError("measurement_seq: this controller has an active-damping loop; pass y as well")
            Y = _floats("measurement_seq", measurement_seq)
            if Y.shape != (E.shape[0], self._nin - self._ne) or not np.isfinite(Y).all():
                raise ValueError(f"measurement_seq: expected finite shape ({E.shape[0]}, {self._nin - self._ne}), "
                                 f"got {Y.shape}")
            E = np.hstack([E, Y])
        elif measurement_seq is not None:
            raise ValueError("measurement_seq: this controller takes the error only")
        if reset:
            self.reset()
        n, M = self._n, self._M
        A, B = M[:n, :n], M[:n, n:]
        C, D = M[n:, :n], M[n:, n:]
        U = E @ D.T                           # feedthrough part, vectorized
        x = self._xe[:n].copy()
        for k in range(E.shape[0]):
            U[k] += C @ x
            x = A @ x + B @ E[k]
        self._xe[:n] = x
        return U

    def __repr__(self) -> str:
        c = self.config
        return (f"DiscreteController(n_states={c.n_states}, n_error={c.n_error}, n_measurement={c.n_measurement}, "
                f"n_out={c.n_out}, "
                f"dt={c.dt:g} s, spectral_radius={c.spectral_radius:.6f})")
