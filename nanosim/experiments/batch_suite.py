"""Run the registered experiments on B stages at once, with each experiment's own code.

Every member runs the experiment's ``run(ctx)`` in its own thread, with a
stage factory and a controller that stand for that member of a batch. The
stage stand-in does no work itself: ``run_closed_loop`` (through
:func:`nanosim.experiments.loop.run_closed_loop`'s batch hook), ``stage.run``,
``stage.sensors.step`` and ``stage.table_um`` are requests, and when every
member has made its next request (the experiments' control flow does not
depend on the data) the batch executes them together on a
:class:`~nanosim.plant.batch.BatchTwinStage` or
:class:`~nanosim.plant.batch.BatchMujocoStage`. The references, the analysis
and the metrics are therefore exactly the experiment's, and member ``b``
gives the numbers of the single-stage run with its plant and seed
(``tests/test_batch.py``). If the members' requests ever differ, the
experiment is rerun member by member (a batch of one) and the result is the
same.
"""
from __future__ import annotations

import threading
from dataclasses import dataclass
from typing import Any, Callable, Sequence

import numpy as np

from nanosim.experiments import registry
from nanosim.experiments.batch_loop import BatchController, run_closed_loop_batch
from nanosim.experiments.loop import LOOP_PROTOCOL, LoopProtocol
from nanosim.experiments.registry import ExperimentContext
from nanosim import constants as C
from nanosim.plant.batch import BatchMujocoStage, BatchTwinStage
from nanosim.plant.electronics import SensorSample
from nanosim.plant.floor import floor_model
from nanosim.plant.stage import StageConfig

__all__ = ["MemberPlant", "BatchDivergence", "run_experiments_batch"]


@dataclass(frozen=True)
class MemberPlant:
    """One member's plant.

    Attributes
    ----------
    twin : LinearTwin or TwinMatrices or None
        Discrete linear twin (engine ``"twin"``).
    model : mujoco.MjModel or None
        Compiled stage: engine ``"mujoco"``, and the floor vibration of a twin (as
        ``characterize --twin``: the floor model of the MuJoCo stage the twin came from).
    home_um : ndarray, shape (3,)
        Noise-free reading at home (the MuJoCo stage's ``table_um``).
    static_gain_um_per_V : ndarray, shape (3, 3) or None
        Static gain for the experiments' open-loop moves (creep).
    base_stage : Stage or None
        Nominal stage for the figures' predictions (not used by ``run``).
    """

    twin: Any = None
    model: Any = None
    home_um: np.ndarray | None = None
    static_gain_um_per_V: np.ndarray | None = None
    base_stage: Any = None


class BatchDivergence(RuntimeError):
    """The members of a batch made different requests (their control flow depends on the data)."""


class _Request:
    __slots__ = ("member", "op", "key", "args", "result", "error", "done")

    def __init__(self, member, op, key, args):
        self.member, self.op, self.key, self.args = member, op, key, args
        self.result = self.error = None
        self.done = False


class _Lockstep:
    """Collects one request per live member, then executes them together (in the last caller's thread)."""

    def __init__(self, n: int, execute: Callable[[list], None]):
        self._cv = threading.Condition()
        self._live = n
        self._pending: list[_Request] = []
        self._execute = execute

    def call(self, req: _Request):
        with self._cv:
            self._pending.append(req)
            self._flush()
            while not req.done:
                self._cv.wait()
        if req.error is not None:
            raise req.error
        return req.result

    def leave(self) -> None:
        with self._cv:
            self._live -= 1
            self._flush()

    def _flush(self) -> None:
        if not self._pending or len(self._pending) < self._live:
            return
        reqs, self._pending = self._pending, []
        try:
            self._execute(reqs)
        except BaseException as exc:          # noqa: BLE001 -- handed to every requesting member
            for r in reqs:
                r.error = exc
        for r in reqs:
            r.done = True
        self._cv.notify_all()


class _ControllerMember:
    """Member ``b`` of a :class:`BatchController`, with the API the experiments use."""

    def __init__(self, bank: BatchController, member: int):
        self.bank, self.member = bank, member
        self.config = bank.configs[member]

    @property
    def two_dof(self) -> bool:
        return self.bank.two_dof

    def reset(self, x0=None, *, measurement_V=None) -> None:
        """Zero state, or with ``measurement_V`` the bumpless start at that reading (:meth:`reset_at`)."""
        if x0 is not None:
            raise ValueError("x0: a batch member starts from zero or from a measurement")
        if measurement_V is None:
            self.bank.reset(members=[self.member])
        else:
            self.reset_at(measurement_V)

    def reset_at(self, measurement_V) -> None:
        """The member's :meth:`BatchController.reset_at` (zero command), as :meth:`DiscreteController.reset_at`."""
        y = np.zeros((self.bank.n, len(measurement_V)))
        y[self.member] = measurement_V
        self.bank.reset_at(y, members=[self.member])


class _SensorsMember:
    def __init__(self, stage: "_StageMember"):
        self._stage = stage

    def step(self, displacement_um):
        return self._stage._request("read", np.asarray(displacement_um, dtype=float))


class _StageMember:
    """Member ``b``'s ``k``-th stage; every call is a request to the batch."""

    def __init__(self, suite: "_Suite", member: int, key: int, seed: int, config):
        self._suite, self.member, self.key, self.seed, self.config = suite, member, key, seed, config
        self.sensors = _SensorsMember(self)

    def variant(self, config, seed: int | None = None) -> "_StageMember":
        """A fresh stage of this member with other electromechanics (``Stage.variant``)."""
        return self._suite.new_stage(self.member, self.seed if seed is None else seed, config)

    def _request(self, op, *args):
        return self._suite.lockstep.call(_Request(self.member, op, self.key, args))

    @property
    def table_um(self) -> np.ndarray:
        return self._request("table")

    def run(self, u_V):
        return self._request("run", np.asarray(u_V, dtype=float))

    def closed_loop(self, controller, ref_um, *, protocol: LoopProtocol = LOOP_PROTOCOL):
        """Batch hook of :func:`~nanosim.experiments.loop.run_closed_loop` (the same :class:`LoopProtocol`)."""
        if not isinstance(controller, _ControllerMember):
            raise ValueError("controller: a batch member's loop needs its batch controller (ctx.controller)")
        return self._request("closed_loop", controller, np.asarray(ref_um, dtype=float), protocol)


class _Suite:
    """One experiment on B members: stage groups (one per factory call index), one controller bank."""

    def __init__(self, plants, bank: BatchController, make_stage, config):
        self.plants, self.bank, self.make_stage, self.config = plants, bank, make_stage, config
        self.n = len(plants)
        self.lockstep = _Lockstep(self.n, self._execute)
        self.groups: dict[int, Any] = {}
        self._calls = [0] * self.n
        self._made: dict[int, dict[int, tuple]] = {}

    def new_stage(self, member: int, seed: int, config) -> _StageMember:
        key = self._calls[member]
        self._calls[member] += 1
        self._made.setdefault(key, {})[member] = (int(seed), config)
        return _StageMember(self, member, key, seed, config)

    def factory(self, member: int):
        return lambda seed: self.new_stage(member, seed, self.config)

    def _group(self, key: int):
        if key not in self.groups:
            made = self._made[key]
            configs = {c for _, c in made.values()}           # frozen dataclasses: equal configs hash alike
            if len(made) != self.n or len(configs) != 1:
                raise BatchDivergence(f"stage {key} was made by {len(made)} of {self.n} members "
                                      f"with {len(configs)} configurations")
            self.groups[key] = self.make_stage([made[b][0] for b in range(self.n)], made[0][1])
        return self.groups[key]

    def _execute(self, reqs: list) -> None:
        ops = {(r.op, r.key) for r in reqs}
        if len(ops) != 1:
            raise BatchDivergence(f"members made different requests: {sorted(ops)[:3]}")
        op, key = ops.pop()
        stage = self._group(key)
        if op == "table":
            for r in reqs:
                r.result = stage.table_um[r.member].copy()
        elif op == "read":
            d = stage.table_um.copy()
            for r in reqs:
                d[r.member] = r.args[0]
            sens = stage.electronics.read(d)
            for r in reqs:
                b = r.member
                r.result = SensorSample(sens.reading_V[b].copy(), sens.reading_um[b].copy(), sens.clipped[b].copy())
        elif op == "run":
            shapes = {r.args[0].shape for r in reqs}
            if len(shapes) != 1:
                raise BatchDivergence(f"open-loop runs of different shapes {sorted(shapes)}")
            u = np.zeros((self.n,) + shapes.pop())
            for r in reqs:
                u[r.member] = r.args[0]
            traces = stage.run(u)
            for r in reqs:
                r.result = traces[r.member]
        elif op == "closed_loop":
            sig = {(r.args[1].shape, r.args[2], r.args[0].bank is self.bank) for r in reqs}
            if len(sig) != 1 or not sig.pop()[2]:
                raise BatchDivergence("closed loops of different lengths, protocols or controllers")
            ref = np.empty((self.n,) + reqs[0].args[1].shape)
            ref[:] = reqs[0].args[1]
            for r in reqs:
                ref[r.member] = r.args[1]
            traces = run_closed_loop_batch(stage, self.bank, ref, protocol=reqs[0].args[2])
            for r in reqs:
                r.result = traces[r.member]
        else:   # pragma: no cover
            raise ValueError(f"op: unknown request {op!r}")

    def close(self) -> None:
        for g in self.groups.values():
            close = getattr(g, "close", None)
            if close is not None:
                close()


def _run_one(exp, plants, controllers, make_stage, seeds, exact, config):
    """Run ``exp`` on every member together; returns per-member results (exceptions in place of failures)."""
    n = len(plants)
    bank = BatchController(controllers, n=n, exact=exact) if not isinstance(controllers, list) \
        else BatchController(controllers, exact=exact)
    suite = _Suite(plants, bank, make_stage, config)
    results: list = [None] * n

    def work(b):
        try:
            ctx = ExperimentContext(factory=suite.factory(b), controller=_ControllerMember(bank, b), seed=seeds[b],
                                    static_gain_um_per_V=plants[b].static_gain_um_per_V,
                                    base_stage=plants[b].base_stage)
            results[b] = exp.run(ctx)
        except BaseException as exc:        # noqa: BLE001 -- reported per member
            results[b] = exc
        finally:
            suite.lockstep.leave()

    threads = [threading.Thread(target=work, args=(b,), daemon=True, name=f"batch-{exp.name}-{b}") for b in range(n)]
    try:
        for t in threads:
            t.start()
        for t in threads:
            t.join()
    finally:
        suite.close()
    return results


def run_experiments_batch(names: Sequence[str], plants: Sequence[MemberPlant], controllers, *, engine: str = "twin",
                          seed=0, config=None, exact: bool = False, nthread: int | None = None,
                          progress: Callable[[str], None] | None = None) -> tuple[list[dict], list[dict]]:
    """Run registered experiments on every member at once.

    Parameters
    ----------
    names : sequence of str
        Registered experiment names (``experiments.load_builtin()`` first).
    plants : sequence of MemberPlant
        One per member.
    controllers : ControllerConfig or DiscreteController, or a list of one per member
    engine : {"twin", "mujoco"}
        Linear twins (``plants[b].twin``) or MuJoCo stages (``plants[b].model``).
    seed : int or sequence of int
        Experiment seed (``ExperimentContext.seed``) of every member, or one per member. One
        seed for all: every member sees the same noise, so members differ by their plants only.
    config : StageConfig, optional
        Electromechanics (default: every effect on).
    exact : bool
        Bit-for-bit single-stage products (see :class:`BatchController`); default the
        faster products: a ``gemm`` for shared matrices, members side by side for per-member ones
        (equal to 1e-12 relative).
    nthread : int, optional
        Threads stepping MuJoCo members.
    progress : callable, optional
        Called with each experiment's name when it has finished on every member.

    Returns
    -------
    metrics : list of dict
        Per member, the merged ``metrics`` of the experiments (failed experiments
        under ``"errors"``).
    results : list of dict
        Per member, ``{name: result object}``.
    """
    plants = list(plants)
    seeds = [int(seed)] * len(plants) if isinstance(seed, (int, np.integer)) else [int(x) for x in seed]
    if len(seeds) != len(plants):
        raise ValueError(f"seed: expected one seed or {len(plants)} (one per plant), got {len(seeds)}")
    if engine not in ("twin", "mujoco"):
        raise ValueError(f"engine: expected 'twin' or 'mujoco', got {engine!r}")
    if isinstance(controllers, (list, tuple)):
        controllers = list(controllers)
        if len(controllers) != len(plants):
            raise ValueError(f"controllers: expected {len(plants)} (one per plant), got {len(controllers)}")

    config = config or StageConfig()

    def make_stage_for(members):
        def make(stage_seeds, cfg):
            ps = [plants[b] for b in members]
            if engine == "twin":
                floors = [floor_model(p.model, C.CONTROL_PERIOD_S) for p in ps] \
                    if all(p.model is not None for p in ps) else None
                return BatchTwinStage([p.twin for p in ps], stage_seeds, config=cfg,
                                      home_um=np.array([p.home_um if p.home_um is not None else np.zeros(3)
                                                        for p in ps]), exact=exact, floor_models=floors)
            return BatchMujocoStage([p.model for p in ps], stage_seeds, config=cfg, nthread=nthread)
        return make

    metrics: list[dict] = [{} for _ in plants]
    results: list[dict] = [{} for _ in plants]
    for name in names:
        exp = registry.get(name)
        out = _run_one(exp, plants, controllers, make_stage_for(range(len(plants))), seeds, exact, config)
        if any(isinstance(r, BatchDivergence) for r in out):
            out = []
            for b in range(len(plants)):      # one member at a time: same numbers, no batching
                ctl = [controllers[b]] if isinstance(controllers, list) else controllers
                out += _run_one(exp, [plants[b]], ctl, make_stage_for([b]), [seeds[b]], exact, config)
        for b, r in enumerate(out):
            if isinstance(r, BaseException):
                if isinstance(r, (KeyboardInterrupt, SystemExit)):
                    raise r
                metrics[b].setdefault("errors", {})[name] = f"{type(r).__name__}: {r}"
            else:
                results[b][name] = r
                metrics[b].update(exp.metrics(r))
        if progress is not None:
            progress(name)
    return metrics, results
