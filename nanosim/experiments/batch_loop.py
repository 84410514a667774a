"""B closed loops stepped together: a bank of discrete controllers and the batched bench loop.

:class:`BatchController` holds B controller states (one shared
:class:`~nanosim.design.controller.ControllerConfig` or one per member) and
steps them with one batched matrix product. :func:`run_closed_loop_batch` is
:func:`nanosim.experiments.loop.run_closed_loop` over the members of a batch
stage (:mod:`nanosim.plant.batch`), with the same start
(:class:`~nanosim.experiments.loop.LoopProtocol`: every member's controller
started at its reading, the approach, the hold) and the same record.

On a :class:`~nanosim.plant.batch.BatchTwinStage` the loop runs compiled
(:mod:`nanosim.plant.batch_kernel`, numba) with the same operations and products
(``tests/test_batch_kernel.py``); ``compiled=False`` keeps the numpy loop.

Every member gives bit for bit the single-stage numbers (``tests/test_batch.py``):
the controller product is a stacked ``matmul``, one BLAS ``gemv`` per member,
the single controller's own call. A member padded to a larger order (members
of different orders) agrees to 1e-12 relative (the zeros change the BLAS
summation blocks).
"""
from __future__ import annotations

import numpy as np

from nanosim.design.controller import ControllerConfig, DiscreteController, bumpless_state
from nanosim.experiments.loop import FS, LOOP_PROTOCOL, UM_PER_V, LoopProtocol, LoopTrace
from nanosim.plant import batch_kernel

__all__ = ["BatchController", "run_closed_loop_batch"]


def _config(c) -> ControllerConfig:
    if isinstance(c, DiscreteController):
        return c.config
    if isinstance(c, ControllerConfig):
        return c
    raise ValueError(f"controllers: expected ControllerConfig or DiscreteController, got {type(c).__name__}")


class BatchController:
    """B discrete controllers (``u = Ckd x + Dkd [e; y]``) stepped together.

    Parameters
    ----------
    controllers : ControllerConfig or DiscreteController, or a sequence of B of them
        One controller for every member, or one per member (padded with inert
        zero states to the largest order; input/output counts must agree).
    n : int, optional
        Number of members when one controller is shared.
    exact : bool
        True (default): one ``gemv`` per member, the single controller's product, bit for
        bit. False: one ``gemm`` for a shared controller (faster; equal to 1e-12 relative).
    """

    def __init__(self, controllers, n: int | None = None, exact: bool = True):
        if isinstance(controllers, (ControllerConfig, DiscreteController)):
            if n is None or int(n) < 1:
                raise ValueError(f"n: expected the number of members (>= 1) for a shared controller, got {n!r}")
            cfgs = [_config(controllers)]
            self.n = int(n)
        else:
            cfgs = [_config(c) for c in controllers]
            if not cfgs:
                raise ValueError("controllers: expected at least one controller")
            self.n = len(cfgs)
        sig = {(c.n_in, c.n_out, c.n_error) for c in cfgs}
        if len(sig) != 1:
            raise ValueError(f"controllers: expected one (n_in, n_out, n_error) for all members, got {sorted(sig)}")
        dts = {c.dt for c in cfgs}
        if len(dts) != 1:
            raise ValueError(f"controllers: expected one sample time, got {sorted(dts)}")
        c0 = cfgs[0]
        self.n_in, self.n_out, self.n_error, self.dt = c0.n_in, c0.n_out, c0.n_error, c0.dt
        ns = max(c.n_states for c in cfgs)
        self.n_states = ns
        self.configs = cfgs if len(cfgs) == self.n else cfgs * self.n
        M = np.stack([self._padded(c, ns) for c in cfgs])
        self._M = M[0] if len(cfgs) == 1 else M           # shared (p, q) or per member (B, p, q)
        self._MT = np.ascontiguousarray(M[0].T) if (len(cfgs) == 1 and not exact) else None
        self._xe = np.zeros((self.n, ns + self.n_in, 1))
        self._out = np.empty((self.n, ns + self.n_out, 1))

    @staticmethod
    def _padded(c: ControllerConfig, ns: int) -> np.ndarray:
        n = c.n_states
        M = np.zeros((ns + c.n_out, ns + c.n_in))
        M[:n, :n], M[:n, ns:] = c.Akd, c.Bkd
        M[ns:, :n], M[ns:, ns:] = c.Ckd, c.Dkd
        return M

    @property
    def two_dof(self) -> bool:
        """True if the controllers also take the measurement ``y``."""
        return self.n_in > self.n_error

    @property
    def state(self) -> np.ndarray:
        """Copy of the states, shape ``(B, n_states)``."""
        return self._xe[:, :self.n_states, 0].copy()

    def reset(self, members=None) -> None:
        """Zero the state of ``members`` (default: all)."""
        idx = slice(None) if members is None else members
        self._xe[idx] = 0.0

    def reset_at(self, measurement_V, members=None, command_V=None) -> None:
        """Start ``members`` at the readings ``measurement_V`` ``(B, n_measurement)`` without a kick:
        each member's :func:`~nanosim.design.controller.bumpless_state` for the commands
        ``command_V`` ``(B, n_out)`` (default zero), as :meth:`DiscreteController.reset_at`.
        """
        idx = np.arange(self.n) if members is None else np.atleast_1d(np.arange(self.n)[members])
        y = np.asarray(measurement_V, dtype=float)
        u = None if command_V is None else np.asarray(command_V, dtype=float)
        ns = self.n_states
        for b in idx:
            c = self.configs[b]
            x0 = np.zeros(ns)
            x0[:c.n_states] = bumpless_state(c, y[b] if c.n_measurement else None, None if u is None else u[b])
            self._xe[b, :ns, 0] = x0
            self._xe[b, ns:, 0] = 0.0

    def kernel_arrays(self) -> tuple:
        """The bank for :func:`nanosim.plant.batch_kernel.twin_closed_loop`: ``(mode, matrix, xe, n_states,
        n_error, two_dof)``; ``xe`` ``(B, n_states + n_in)`` is a view of the state (updated in place).
        """
        xe = self._xe.reshape(self.n, -1)
        if self._MT is not None:
            return 0, self._MT[None], xe, self.n_states, self.n_error, self.two_dof
        if self._M.ndim == 2:
            return 1, np.ascontiguousarray(self._M[None]), xe, self.n_states, self.n_error, self.two_dof
        return 2, np.ascontiguousarray(self._M), xe, self.n_states, self.n_error, self.two_dof

    def feedback(self, reference_V: np.ndarray, measurement_V: np.ndarray) -> np.ndarray:
        """One sample of every loop: ``e = r - y`` (and ``y``) -> commands ``(B, n_out)``.

        The result is a view of an internal buffer, valid until the next call (copy it to keep it).
        """
        ns, ne = self.n_states, self.n_error
        xe = self._xe[:, :, 0]
        xe[:, ns:ns + ne] = reference_V - measurement_V
        if self.two_dof:
            xe[:, ns + ne:] = measurement_V
        if self._MT is not None:
            out = np.dot(xe, self._MT, out=self._out[:, :, 0])
        else:
            out = np.matmul(self._M, self._xe, out=self._out)[:, :, 0]
        xe[:, :ns] = out[:, :ns]
        return out[:, ns:]          # a view of a buffer the next call overwrites


def run_closed_loop_batch(stage, controller: BatchController, ref_um, *, protocol: LoopProtocol = LOOP_PROTOCOL,
                          compiled: bool = True) -> list[LoopTrace]:
    """:func:`~nanosim.experiments.loop.run_closed_loop` on every member of a batch stage.

    Parameters
    ----------
    stage : BatchTwinStage or BatchMujocoStage
    controller : BatchController
        Same number of members as ``stage``.
    ref_um : array_like, shape (N, 3) or (B, N, 3)
        Reference of every member (um from the probe origin).
    protocol : LoopProtocol
        The start of the record, as in :func:`~nanosim.experiments.loop.run_closed_loop`.
    compiled : bool
        True (default): a :class:`~nanosim.plant.batch.BatchTwinStage` runs in the compiled loop
        (:mod:`nanosim.plant.batch_kernel`, numba) when numba is installed; equal to the numpy path to
        1e-12 (matrix products summed in another order). False: the numpy path.

    Returns
    -------
    list of LoopTrace
        One per member.
    """
    if not isinstance(protocol, LoopProtocol):
        raise ValueError(f"protocol: expected a LoopProtocol, got {type(protocol).__name__}")
    nb = stage.n
    if controller.n != nb:
        raise ValueError(f"controller: expected {nb} members (as the stage), got {controller.n}")
    ref = np.asarray(ref_um, dtype=float)
    if ref.ndim == 2:
        ref = np.broadcast_to(ref, (nb,) + ref.shape)
    if ref.ndim != 3 or ref.shape[0] != nb or ref.shape[2] != 3:
        raise ValueError(f"ref_um: expected shape (N, 3) or ({nb}, N, 3), got {ref.shape}")
    y = stage.read().reading_V
    fast = compiled and batch_kernel.supported(stage) and controller.n_out == 3
    if y.any():                             # LoopProtocol rule 1, every member (start_controller)
        controller.reset_at(y)
    else:
        controller.reset()
    if protocol.n_before_record:
        n = protocol.n_before_record
        start = y * UM_PER_V
        w = protocol.weights()
        if fast:
            r = start[None] + w[:, None, None] * (ref[:, 0] - start)[None]    # the loop's r, row by row
            y, _ = batch_kernel.twin_closed_loop(stage, controller.kernel_arrays(),
                                                 r[:, :, :controller.n_error] / UM_PER_V, y, False)
        else:
            for k in range(n):
                r = start + w[k] * (ref[:, 0] - start)
                y = stage.step(controller.feedback(r / UM_PER_V, y))
    n = ref.shape[1]
    if fast:
        rv = np.ascontiguousarray(np.swapaxes(ref, 0, 1)) / UM_PER_V
        _, (yv, tb, us, sat) = batch_kernel.twin_closed_loop(stage, controller.kernel_arrays(),
                                                             rv[:, :, :controller.n_error], y, True)
        return _traces(ref, yv, tb, us, sat)
    yv, tb, us = (np.empty((nb, n, 3)) for _ in range(3))       # members first, as the compiled loop's
    sat = np.empty((nb, n, 3), dtype=bool)
    rv = np.ascontiguousarray(np.swapaxes(ref, 0, 1)) / UM_PER_V      # (N, B, 3): rv[k] contiguous
    for k in range(n):
        u = controller.feedback(rv[k], y)
        yv[:, k] = y
        tb[:, k] = stage.table_um
        us[:, k] = u
        y = stage.step(u)
        sat[:, k] = stage.last_saturated
    return _traces(ref, yv, tb, us, sat)


def _traces(ref, yv, tb, us, sat) -> list[LoopTrace]:
    """One trace per member from the ``(B, N, 3)`` records (members first: each trace holds its own rows)."""
    nb, n = yv.shape[:2]
    ys = np.multiply(yv, UM_PER_V, out=yv)   # the same product per element as the single loop's y * UM_PER_V
    t = np.arange(n) / FS
    return [LoopTrace(t_s=t, ref_um=np.array(ref[b]), y_um=ys[b], table_um=tb[b], u_V=us[b], saturated=sat[b])
            for b in range(nb)]
