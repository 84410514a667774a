"""B stages stepped together: the electronics vectorized over B, the linear twin in numpy, MuJoCo on threads.

:class:`BatchTwinStage` and :class:`BatchMujocoStage` have the API of
:class:`~nanosim.plant.twin.TwinStage` and :class:`~nanosim.plant.stage.Stage`
with a leading batch axis: ``step(u (B, 3)) -> reading (B, 3)``,
``table_um (B, 3)``, ``last_saturated (B, 3)``, ``read()`` (one gauge sample
of the current position, as ``stage.sensors.step(stage.table_um)``) and
``run(u (B, N, 3)) -> list of Trace``. Member ``b`` is the stage
``Stage(seed=seeds[b], model=models[b])`` (or ``TwinStage(twins[b], seeds[b])``).

The electronics (:mod:`nanosim.plant.batch_electronics`) apply every effect
of the bench (DAC quantisation and noise, amplifier saturation,
the piezo's hysteresis and creep (:mod:`nanosim.plant.piezo`), gauge noise and clipping, ADC) to all
``3 B`` channels at once, from the same config objects as the single stage.

Equality with the single-stage path (``tests/test_batch.py``): every member
gives bit for bit the numbers of the single stage with its seed. The twin's
products are stacked ``matmul`` calls (one BLAS ``gemv`` per member, the
single twin's own call), and the MuJoCo members run ``mj_step`` with the
same substeps as :meth:`Stage.step`, which :meth:`Stage.run`'s rollout
matches exactly.
"""
from __future__ import annotations

import itertools
import os
from concurrent.futures import ThreadPoolExecutor
from typing import NamedTuple, Sequence

import mujoco
import numpy as np

from nanosim import constants as C
from nanosim.plant import batch_kernel
from nanosim.plant.batch_electronics import BatchElectronics, BatchReading
from nanosim.plant.floor import FloorConfig, floor_model
from nanosim.plant.mechanics import home_data
from nanosim.plant.mjcf import custom_numeric, probe_layout
from nanosim.plant.noise import NormalStream, child_seed
from nanosim.plant.stage import StageConfig, Trace, rollout_probes_um
from nanosim.validation import as_finite_array

__all__ = ["BatchElectronics", "BatchTwinStage", "BatchMujocoStage", "BatchReading", "TwinMatrices"]

UM_PER_V = C.SENSOR_UM_PER_V


def _seeds(seeds) -> list:
    seeds = list(seeds)
    if not seeds:
        raise ValueError("seeds: expected at least one seed (one per batch member), got none")
    return seeds


_FLOOR_STREAM = 4            # nanosim.plant.floor.FloorVibration's child stream (electronics docstring)
_FLOOR_CHUNK = 4096


class _BatchFloor:
    """Floor vibration of B members (:class:`nanosim.plant.floor.FloorVibration` vectorized).

    Per member: the base acceleration from its own seed (stream 4, drawn in chunks) and its own
    floor model; ``x+ = Ad x + Bd a``, displacement ``Cd x+`` (stacked products, one ``gemv`` per member;
    with ``exact=False`` one :func:`member_products` of the stacked ``[x; a]``).
    """

    def __init__(self, models, config: FloorConfig, seeds, exact: bool = True):
        self.active = config.enabled and config.accel_psd_m2_s4_Hz > 0
        self._seeds = list(seeds)
        if not self.active:
            return
        self._Ad = np.stack([m.Ad for m in models])
        self._Bd = np.stack([m.Bd for m in models])
        self._Cd = np.stack([m.Cd for m in models])
        self._sigma = [float(np.sqrt(config.accel_psd_m2_s4_Hz / (2.0 * m.dt_s))) for m in models]
        self._P = None
        if not exact:            # [x+; d] = [[Ad, Bd], [Cd Ad, Cd Bd]] [x; a], members last (member_products)
            P = np.concatenate([np.concatenate([self._Ad, self._Bd], axis=2),
                                np.concatenate([self._Cd @ self._Ad, self._Cd @ self._Bd], axis=2)], axis=1)
            self._P = np.ascontiguousarray(P.transpose(1, 2, 0))
        self.reset()

    def reset(self) -> None:
        if not self.active:
            return
        self._x = np.zeros(self._Ad.shape[:2] + (1,))
        self._streams = [NormalStream(child_seed(s, _FLOOR_STREAM), 3) for s in self._seeds]
        self._buf = np.empty((0, len(self._seeds), 3, 1))
        self._i = 0

    def take_accel(self, n: int) -> np.ndarray:
        """The base accelerations of the next ``n`` periods, ``(n, B, 3)`` (as ``n`` :meth:`step` calls draw them)."""
        out = np.empty((n, len(self._seeds), 3))
        filled = 0
        while filled < n:
            if self._i == len(self._buf):
                self._refill()
            k = min(n - filled, len(self._buf) - self._i)
            out[filled:filled + k] = self._buf[self._i:self._i + k, :, :, 0]
            self._i += k
            filled += k
        return out

    def _refill(self) -> None:
        self._buf = np.stack([sg * st.take(_FLOOR_CHUNK) for sg, st in zip(self._sigma, self._streams)],
                             axis=1)[..., None]
        self._i = 0

    def step(self) -> np.ndarray:
        """Displacement ``(B, 3)`` um at the end of the next period."""
        if self._i == len(self._buf):
            self._refill()
        a = self._buf[self._i]
        self._i += 1
        if self._P is not None:
            nx = self._x.shape[1]
            out = member_products(self._P, np.concatenate([self._x, a], axis=1)[:, :, 0])
            self._x = out[:, :nx, None]
            return out[:, nx:]
        self._x = np.matmul(self._Ad, self._x) + np.matmul(self._Bd, a)
        return np.matmul(self._Cd, self._x)[:, :, 0]


class _BatchStageBase:
    """Shared stepping, reading and open-loop logic; subclasses move the mechanics."""

    dt_s: float
    compiled = False
    compiled_electronics = False

    def _init_common(self, seeds, config: StageConfig | None) -> None:
        self.config = config or StageConfig()
        self.seeds = _seeds(seeds)
        self.n = len(self.seeds)
        self.dt_s = 1.0 / self.config.electronics.sample_rate_Hz

    def reset(self) -> None:
        """Home state, virgin piezos, noise streams rewound (every member)."""
        self.electronics = BatchElectronics(self.config.electronics, self.config.piezo, self.seeds)
        if self.compiled_electronics:
            self.electronics.use_compiled_steps()
        self.floor = _BatchFloor(self._floor_models, self.config.floor, self.seeds, getattr(self, "exact", True)) \
            if self._floor_models else None
        self.time_s = 0.0
        self._floor_ahead = None
        self.last_piezo_V = np.zeros((self.n, 3))
        self.last_saturated = np.zeros((self.n, 3), dtype=bool)
        self.last_clipped = np.zeros((self.n, 3), dtype=bool)
        self._reset_mechanics()

    def read(self) -> BatchReading:
        """One gauge sample of the current positions (``stage.sensors.step(stage.table_um)``)."""
        return self.electronics.read(self.table_um)

    def step(self, u_V) -> np.ndarray:
        """Apply controller volts ``(B, 3)`` for one period; return the readings ``(B, 3)`` in sensor V."""
        u = np.asarray(u_V, dtype=float)
        if u.shape != (self.n, 3):
            u = as_finite_array("u_V", u_V, shape=(self.n, 3))
        _, v_piezo, v_free, sat = self.electronics.actuate(u)
        self._advance(v_free)
        self._add_floor()
        self.time_s += self.dt_s
        sens = self.electronics.read(self.table_um)
        self.last_piezo_V, self.last_saturated, self.last_clipped = v_piezo, sat, sens.clipped
        return sens.reading_V

    def run(self, u_V) -> list[Trace]:
        """Open-loop run of ``(B, N, 3)`` commands (or one ``(N, 3)`` array for every member)."""
        u = _member_commands(u_V, self.n)
        n = u.shape[1]
        pz, sat, tb, yv, yu, cl = (np.empty((self.n, n, 3)) for _ in range(6))     # members first
        t0 = self.time_s
        k_start = n
        if self.compiled and n and batch_kernel.supported(self, started=False):
            k_start = 1                     # the first period starts the gauge filter, then the compiled loop
        for k in range(min(n, k_start)):
            _, v_piezo, v_free, s = self.electronics.actuate(np.ascontiguousarray(u[:, k]))
            self._advance(v_free)
            self._add_floor()
            self.time_s += self.dt_s
            sens = self.electronics.read(self.table_um)
            pz[:, k], sat[:, k], tb[:, k], yv[:, k], yu[:, k], cl[:, k] = v_piezo, s, self.table_um, \
                sens.reading_V, sens.reading_um, sens.clipped
            self.last_piezo_V, self.last_saturated, self.last_clipped = v_piezo, s, sens.clipped
        if k_start < n:
            rest = batch_kernel.twin_open_loop(self, np.ascontiguousarray(np.swapaxes(u[:, k_start:], 0, 1)))
            for whole, part in zip((pz, sat, tb, yv, yu, cl), rest):
                whole[:, k_start:] = part
        t = self._trace_time(t0, n)
        return [Trace(t_s=t, u_V=np.array(u[b]), piezo_V=pz[b].copy(), saturated=sat[b].astype(bool),
                      table_um=tb[b].copy(), sensor_V=yv[b].copy(), sensor_um=yu[b].copy(),
                      clipped=self._trace_clipped(cl[b].astype(bool))) for b in range(self.n)]

    def _add_floor(self) -> None:
        if self.floor is not None and self.floor.active:
            fl, self._floor_ahead = getattr(self, "_floor_ahead", None), None
            self.table_um = self.table_um + (fl if fl is not None else self.floor.step())

    # subclass hooks
    def _reset_mechanics(self) -> None:
        raise NotImplementedError

    def _advance(self, v_free_V: np.ndarray) -> None:
        raise NotImplementedError

    def _trace_time(self, t0: float, n: int) -> np.ndarray:
        return t0 + self.dt_s * np.arange(1, n + 1)

    def _trace_clipped(self, clipped: np.ndarray) -> np.ndarray:
        return clipped


class TwinMatrices(NamedTuple):
    """Discrete linear twin at the control period, controller V -> sensor V."""

    A: np.ndarray
    B: np.ndarray
    C: np.ndarray
    D: np.ndarray

    @classmethod
    def of(cls, tw) -> "TwinMatrices":
        """The float matrices of a :class:`~nanosim.plant.twin.LinearTwin` (its ``sysd_V``) or a ``TwinMatrices``."""
        if isinstance(tw, TwinMatrices):
            return cls(*(np.asarray(m, dtype=float) for m in tw))
        if hasattr(tw, "sysd_V"):
            s = tw.sysd_V
            return cls(*(np.asarray(m, dtype=float) for m in (s.A, s.B, s.C, s.D)))
        raise ValueError(f"twins: expected a LinearTwin or TwinMatrices, got {type(tw).__name__}")

    def input_scaled(self, factor: float) -> "TwinMatrices":
        """This twin with its input gain times ``factor`` (``B`` and ``D`` scaled)."""
        return TwinMatrices(self.A, self.B * factor, self.C, self.D * factor)


def member_products(PS: np.ndarray, xv: np.ndarray) -> np.ndarray:
    """``P_b @ xv[b]`` of every member, ``(B, m)``, from the members-last stack ``PS`` ``(m, k, B)`` and
    ``xv`` ``(B, k)``: each sum left to right over ``k`` (a multiply then an add per term), the arithmetic
    of :func:`nanosim.plant.batch_kernel.member_products`, so both paths give the same bits.
    """
    xt = xv.T
    out = PS[:, 0, :] * xt[0]
    for j in range(1, PS.shape[1]):
        out += PS[:, j, :] * xt[j]
    return out.T


def _stack_twins(twins, n: int):
    """Shared ``(A, B, C, D)`` or per-member stacks ``(n, ., .)``."""
    if isinstance(twins, TwinMatrices) or hasattr(twins, "sysd_V"):
        return False, TwinMatrices.of(twins)
    twins = list(twins)
    if len(twins) != n:
        raise ValueError(f"twins: expected {n} twins (one per seed), got {len(twins)}")
    ms = [TwinMatrices.of(t) for t in twins]
    shapes = {tuple(m.shape for m in mm) for mm in ms}
    if len(shapes) != 1:
        raise ValueError(f"twins: expected twins of one order, got shapes {sorted(shapes)}")
    return True, tuple(np.stack([m[i] for m in ms]) for i in range(4))


class BatchTwinStage(_BatchStageBase):
    """B linear twins in the same electromechanics as :class:`~nanosim.plant.twin.TwinStage`.

    Parameters
    ----------
    twins : LinearTwin or TwinMatrices, or a list of B of them
        One shared discrete twin (controller V -> sensor V at the control
        period) or one per member (Monte Carlo samples).
    seeds : sequence of int
        One seed per member.
    config : StageConfig, optional
        Electromechanics (default: every effect on).
    home_um : array_like, shape (3,) or (B, 3), optional
        Reading at home (the MuJoCo stage's ``table_um``); default 0.
    floor_models : FloorModel or list of B, optional
        Floor vibration (:func:`nanosim.plant.floor.floor_model` of the MuJoCo model each twin
        came from), as ``TwinStage(floor_model=...)``; None: no floor vibration.
    exact : bool
        True (default): the twin's products are those of ``TwinStage`` (one ``gemv``
        per member and matrix), bit for bit. False: ``[x+; y] = [[A, B], [C A, C B + D]] [x; v]``
        in one product (a ``gemm`` for a shared twin), about twice as fast, equal to
        1e-12 relative (summation order).
    compiled : bool
        True (default): :meth:`run` and :func:`~nanosim.experiments.batch_loop.run_closed_loop_batch`
        step the members in the compiled loop (:mod:`nanosim.plant.batch_kernel`) when numba is
        installed: the same operations in the same order and the same BLAS products, the same
        numbers (``tests/test_batch_kernel.py``). False: one numpy call per effect and period.
    """

    def __init__(self, twins, seeds: Sequence[int], config: StageConfig | None = None, home_um=None,
                 exact: bool = True, floor_models=None, compiled: bool = True):
        self.compiled = bool(compiled)
        self._init_common(seeds, config)
        if floor_models is not None and not isinstance(floor_models, (list, tuple)):
            floor_models = [floor_models] * self.n
        if floor_models is not None and len(floor_models) != self.n:
            raise ValueError(f"floor_models: expected {self.n} (one per seed), got {len(floor_models)}")
        self._floor_models = floor_models
        self.per_member, (A, B, Cm, D) = _stack_twins(twins, self.n)
        self._A, self._B, self._C, self._D = A, B, Cm, D     # (n, n) shared or (B, n, n) stacks
        self.exact = bool(exact)
        if not self.exact:
            top = np.concatenate([A, B], axis=-1)
            bottom = np.concatenate([Cm @ A, Cm @ B + D], axis=-1)
            P = np.concatenate([top, bottom], axis=-2)
            # per member: members last, (m, k, B), for member_products; shared: P.T for xv @ P.T
            self._P = np.ascontiguousarray(P.transpose(1, 2, 0) if self.per_member else P.T)
            self._xv = np.zeros((self.n, A.shape[-1] + B.shape[-1]))
        home = np.zeros(3) if home_um is None else np.asarray(home_um, dtype=float)
        self._home_um = np.broadcast_to(home, (self.n, 3)).copy()
        self._gain = self.config.electronics.amplifier_gain
        self.reset()

    def _reset_mechanics(self) -> None:
        self._x = np.zeros((self.n, self._A.shape[-1]))
        self.table_um = self._home_um.copy()

    def _advance(self, v_free_V: np.ndarray) -> None:
        if not self.exact:
            nx = self._x.shape[1]
            xv = self._xv
            xv[:, :nx] = self._x
            np.divide(v_free_V, self._gain, out=xv[:, nx:])
            out = member_products(self._P, xv) if self.per_member else xv @ self._P
            self._x = out[:, :nx]
            self.table_um = self._home_um + UM_PER_V * out[:, nx:]
            return
        v = (v_free_V / self._gain)[:, :, None]
        x = self._x[:, :, None]
        matmul = np.matmul
        x = matmul(self._A, x) + matmul(self._B, v)       # one gemv per member, as TwinStage's A @ x
        y = matmul(self._C, x) + matmul(self._D, v)
        self._x = x[:, :, 0]
        self.table_um = self._home_um + UM_PER_V * y[:, :, 0]

    def _trace_time(self, t0: float, n: int) -> np.ndarray:
        return self.dt_s * np.arange(1, n + 1)          # as TwinStage.run

    def kernel_twin(self) -> tuple:
        """The twin for :func:`nanosim.plant.batch_kernel.twin_closed_loop`:
        ``(mode, A, B, C, D, P, x)``, matrices as ``(1 or B, ., .)`` stacks (a per-member ``P``, mode 3,
        members last: ``(m, k, B)``), ``x`` a contiguous copy.
        """
        e3 = np.zeros((1, 0, 0))
        x = np.ascontiguousarray(self._x)
        if not self.exact:
            if getattr(self, "_P3", None) is None:
                self._P3 = self._P if self.per_member else self._P[None]     # (m, k, B); P.T if shared
            return (3 if self.per_member else 2), e3, e3, e3, e3, self._P3, x
        mats = tuple(np.ascontiguousarray(m if self.per_member else m[None]) for m in
                     (self._A, self._B, self._C, self._D))
        return (1 if self.per_member else 0), *mats, e3, x

    def kernel_twin_done(self, x: np.ndarray) -> None:
        """Take the twin state back from the compiled loop."""
        self._x = x

    def _trace_clipped(self, clipped: np.ndarray) -> np.ndarray:
        return np.zeros_like(clipped)                    # as TwinStage.run


def _member_commands(u_V, n_members: int) -> np.ndarray:
    """``(B, N, 3)`` commands from ``(B, N, 3)`` or one ``(N, 3)`` array for every member."""
    u = as_finite_array("u_V", u_V)
    if u.ndim == 2:
        u = np.broadcast_to(u, (n_members,) + u.shape)
    if u.ndim != 3 or u.shape[0] != n_members or u.shape[2] != 3:
        raise ValueError(f"u_V: expected shape ({n_members}, N, 3) or (N, 3), got {u.shape}")
    return u


def _member_views(model, data, adr, bias) -> tuple:
    """``(model, data, ctrl, probes, bias)`` of one member: ``data``'s ctrl array and its probe
    components (a strided view of ``sensordata`` when the addresses are evenly spaced, else the
    addresses), made once so that stepping a member does little under the GIL.
    """
    step = int(adr[1] - adr[0])
    even = step > 0 and int(adr[2] - adr[1]) == step
    probes = data.sensordata[int(adr[0]):int(adr[2]) + 1:step] if even else adr
    return model, data, data.ctrl, probes, bias


def _step_claimed(members, forces, substeps, out, claims, n) -> None:
    """Step members as they are claimed from the shared counter ``claims`` (``next`` is atomic under
    the GIL) until all ``n`` are taken: a thread that is behind (a busy core) takes fewer.
    """
    for i in claims:
        if i >= n:
            return
        _step_members(members, forces, substeps, out, (i,))


def _step_members(members, forces, substeps, out, idx) -> None:
    for i in idx:
        m, d, ctrl, probes, bias = members[i]
        ctrl[:] = forces[i]
        mujoco.mj_step(m, d, substeps)
        mujoco.mj_kinematics(m, d)                     # update_position_sensors: the reading at the end
        mujoco.mj_sensorPos(m, d)                      # of the period, as Stage.step
        out[i] = ((probes if probes.dtype.kind == "f" else d.sensordata[probes]) + bias) * 1e6


class BatchMujocoStage(_BatchStageBase):
    """B MuJoCo stages stepped from a thread pool (``mj_step`` releases the GIL).

    Parameters
    ----------
    models : MjModel or list of B MjModel
        One shared model or one per member (Monte Carlo samples).
    seeds : sequence of int
        One seed per member.
    config : StageConfig, optional
    nthread : int, optional
        Threads stepping the members (default: the number of CPUs, at most B; the calling
        thread steps one share). Results do not depend on it.
    compiled : bool
        True (default): the electronics of each period are one compiled call
        (:meth:`BatchElectronics.use_compiled_steps`, numba; the same numbers).

    Notes
    -----
    Use as a context manager, or call :meth:`close`, to stop the threads.
    """

    def __init__(self, models, seeds: Sequence[int], config: StageConfig | None = None,
                 nthread: int | None = None, compiled: bool = True):
        self.compiled_electronics = bool(compiled)
        self._init_common(seeds, config)
        ms = list(models) if isinstance(models, (list, tuple)) else [models] * self.n
        if len(ms) != self.n:
            raise ValueError(f"models: expected {self.n} models (one per seed), got {len(ms)}")
        self.models = ms
        self._floor_models = [floor_model(m, self.dt_s) for m in ms] if self.config.floor.enabled else None
        dt_model = {m.opt.timestep for m in ms}
        ratio = self.dt_s / ms[0].opt.timestep
        self.substeps = int(round(ratio))
        if len(dt_model) != 1 or abs(ratio - self.substeps) > 1e-9 * ratio:
            raise ValueError(f"models: expected one timestep dividing the control period {self.dt_s} s, "
                             f"got {sorted(dt_model)}")
        layouts = [probe_layout(m) for m in ms]
        self._adr = [a for a, _ in layouts]
        self._bias = [b for _, b in layouts]
        self._force_per_V = np.array([float(custom_numeric(m, "piezo_force_per_volt_N",
                                                           C.PIEZO_FORCE_PER_PIEZO_V)[0]) for m in ms])[:, None]
        nthread = int(nthread or min(self.n, os.cpu_count() or 1))
        if nthread < 1:
            raise ValueError(f"nthread: expected a positive integer, got {nthread}")
        self.nthread = min(nthread, self.n)
        self._parts = [list(range(self.n))[k::self.nthread] for k in range(self.nthread)]
        self._pool = ThreadPoolExecutor(self.nthread - 1) if self.nthread > 1 else None
        self.reset()

    def run(self, u_V) -> list[Trace]:
        """Open-loop run of ``(B, N, 3)`` commands (or one ``(N, 3)`` array for every member).

        As :meth:`Stage.run`: the electronics of every period first (open loop), then each
        member's mechanics in one ``mujoco.rollout`` (members on the threads), the floor and the
        gauges; member ``b`` equals ``Stage(seed=seeds[b]).run(u[b])`` bit for bit.
        """
        u = _member_commands(u_V, self.n)
        n = u.shape[1]
        if n == 0:
            return super().run(u)
        pz, vf = np.empty((n, self.n, 3)), np.empty((n, self.n, 3))
        sat = np.empty((n, self.n, 3), dtype=bool)
        for k in range(n):
            _, pz[k], vf[k], sat[k] = self.electronics.actuate(np.ascontiguousarray(u[:, k]))
        forces = np.ascontiguousarray(np.swapaxes(vf, 0, 1))          # (B, N, 3)
        table = np.empty((self.n, n, 3))

        def roll(idx):
            for b in idx:
                table[b] = rollout_probes_um(self.models[b], [self.datas[b]], self.datas[b],      # as Stage.run
                                             self._force_per_V[b, 0] * forces[b][None], self.substeps,
                                             self._adr[b], self._bias[b])[0]

        if self._pool is None:
            roll(range(self.n))
        else:
            futures = [self._pool.submit(roll, part) for part in self._parts[1:]]
            roll(self._parts[0])
            for f in futures:
                f.result()
        tb, yv, yu, cl = (np.empty((n, self.n, 3)) for _ in range(4))
        for k in range(n):
            tb[k] = table[:, k]
            if self.floor is not None and self.floor.active:
                tb[k] = tb[k] + self.floor.step()
            sens = self.electronics.read(tb[k])
            yv[k], yu[k], cl[k] = sens.reading_V, sens.reading_um, sens.clipped
        t = self.time_s + self.dt_s * np.arange(1, n + 1)
        self.time_s = float(t[-1])
        self.table_um = tb[-1].copy()
        self.last_piezo_V, self.last_saturated, self.last_clipped = pz[-1], sat[-1], cl[-1].astype(bool)
        return [Trace(t_s=t, u_V=np.array(u[b]), piezo_V=pz[:, b].copy(), saturated=sat[:, b].copy(),
                      table_um=tb[:, b].copy(), sensor_V=yv[:, b].copy(), sensor_um=yu[:, b].copy(),
                      clipped=cl[:, b].astype(bool)) for b in range(self.n)]

    def _reset_mechanics(self) -> None:
        self.datas = [home_data(m) for m in self.models]
        self._members = [_member_views(m, d, a, b)
                         for m, d, a, b in zip(self.models, self.datas, self._adr, self._bias)]
        self.table_um = np.array([(d.sensordata[a] + b) * 1e6 for d, a, b in zip(self.datas, self._adr, self._bias)])

    def _advance(self, v_free_V: np.ndarray) -> None:
        forces = self._force_per_V * v_free_V
        out = np.empty((self.n, 3))
        args = (self._members, forces, self.substeps, out)
        if self._pool is None:
            _step_members(*args, range(self.n))
        else:
            # members are claimed one at a time by the threads (the calling thread too), so a thread
            # held up by a busy core takes fewer; each member's numbers do not depend on its thread.
            # The calling thread first draws this period's floor vibration (it does not depend on
            # the mechanics; _add_floor adds it as usual) while the other threads step.
            claims = itertools.count()
            futures = [self._pool.submit(_step_claimed, *args, claims, self.n) for _ in self._parts[1:]]
            if self.floor is not None and self.floor.active:
                self._floor_ahead = self.floor.step()
            _step_claimed(*args, claims, self.n)
            for f in futures:
                f.result()
        self.table_um = out

    def close(self) -> None:
        """Stop the stepping threads."""
        if self._pool is not None:
            self._pool.shutdown(wait=True)
            self._pool = None

    def __enter__(self) -> "BatchMujocoStage":
        return self

    def __exit__(self, *exc) -> None:
        self.close()
