"""Batch engine throughput, each target a ratio measured in the same run.

Run: OPENBLAS_NUM_THREADS=1 python -m pytest tests/bench/bench_batch.py --benchmark-enable -s

* MuJoCo: B stages in closed loop stepped from 2 threads vs 1 thread (target >= 1.8x), beside the machine's
  own ceiling for two: the same B split over two independent single-threaded processes.
* Linear twin, every effect on, B = 256 members with their own twins, a 29-state two-degree-of-freedom
  controller, on 2 worker processes of 128 members: aggregate simulated seconds per wall second
  (target >= 1000x real time), next to the single-stage twin loop (TwinStage + DiscreteController).
  The batch runs in the compiled loop (nanosim.plant.batch_kernel); each worker first loads it from
  numba's cache with a short run that is not timed. The noise of the timed second is drawn inside it.

Each configuration is timed ROUNDS times, alternating, and the ratio is taken between the fastest of
each (the timeit convention: slower repeats are other processes interfering, which on this 2-vCPU
virtual machine move a single timing by up to 40 %); every round and the median are printed too.
"""
import multiprocessing
import time

import numpy as np
import pytest

from nanosim.design.controller import ControllerConfig, DiscreteController
from nanosim.experiments.batch_loop import BatchController, run_closed_loop_batch
from nanosim.experiments.loop import LoopProtocol, run_closed_loop
from nanosim.plant.batch import BatchMujocoStage, BatchTwinStage
from nanosim.plant.linearize import linearize
from nanosim.plant.mjcf import load_model
from nanosim.plant.modes import modal_analysis
from nanosim.plant.stage import Stage, StageConfig
from nanosim.plant.twin import TwinStage

TWIN_B, TWIN_SIM_S = 256, 1.0
MJ_B, MJ_SIM_S = 16, 0.1
ROUNDS = 3


def _rounds(*configs):
    """Time each zero-argument callable ROUNDS times, alternating; returns the lists of results."""
    out = [[] for _ in configs]
    for _ in range(ROUNDS):
        for res, f in zip(out, configs):
            res.append(f())
    return out


def _fmt(values, digits=0):
    return ", ".join(f"{v:.{digits}f}" for v in values)


def controller_29(G0_um_per_V) -> ControllerConfig:
    """A stable 29-state controller with inputs [e; y]: a leaky integrator through inv(G0) and a
    26-state stable filter of the measurement (the cost depends on the dimensions only)."""
    rng = np.random.default_rng(0)
    T = 2.5e-4
    g = 2 * np.pi * 20 * T * np.linalg.inv(G0_um_per_V / 5.0)
    Ar = rng.standard_normal((26, 26))
    Ar *= 0.95 / np.max(np.abs(np.linalg.eigvals(Ar)))
    A = np.zeros((29, 29))
    A[:3, :3] = 0.9995 * np.eye(3)
    A[3:, 3:] = Ar
    B = np.zeros((29, 6))
    B[:3, :3] = np.eye(3)
    B[3:, 3:] = 0.01 * rng.standard_normal((26, 3))
    C = np.hstack([g, 1e-3 * rng.standard_normal((3, 26))])
    D = np.hstack([g, np.zeros((3, 3))])
    return ControllerConfig(A, B, C, D, T, n_error=3)


def _reference(n):
    ref = np.zeros((n, 3))
    ref[:, 0] = 2.0 * np.sin(2 * np.pi * 10 * np.arange(n) / 4000.0)
    return ref


def _on_processes(worker, args_per_process):
    """Run ``worker(*args, barrier)`` on one spawned process per entry, started together; returns the results."""
    n = len(args_per_process)
    ctx = multiprocessing.get_context("spawn")
    with ctx.Manager() as mgr, ctx.Pool(n) as pool:
        barrier = mgr.Barrier(n)
        return pool.starmap(worker, [(*args, barrier) for args in args_per_process])


def _twin_worker(n_members, seed0, sim_s, barrier):
    """One worker process: n_members twins (their own copies) in closed loop; returns its run time."""
    model = load_model()
    tw = linearize(Stage(config=StageConfig.ideal(), model=model))
    home = Stage(model=model).table_um
    ctrl = controller_29(modal_analysis(model).static_gain_um_per_V)
    # warm-up, not timed: the compiled loop's one-time load from numba's cache (about 0.3 s per process)
    warm = BatchTwinStage([tw], [seed0], home_um=home, exact=False)
    run_closed_loop_batch(warm, BatchController(ctrl, n=1, exact=False), _reference(8), protocol=LoopProtocol(0.0, 0.0))
    stage = BatchTwinStage([tw] * n_members, list(range(seed0, seed0 + n_members)), home_um=home, exact=False)
    bank = BatchController(ctrl, n=n_members, exact=False)
    ref = _reference(int(sim_s * 4000))
    if barrier is not None:
        barrier.wait()
    t0, c0 = time.perf_counter(), time.process_time()
    run_closed_loop_batch(stage, bank, ref, protocol=LoopProtocol(0.0, 0.0))
    return time.perf_counter() - t0, time.process_time() - c0


def twin_aggregate(processes=2, members=TWIN_B, sim_s=TWIN_SIM_S) -> float:
    """Aggregate real-time factor of ``members`` twins split over ``processes`` worker processes."""
    per = members // processes
    times = _on_processes(_twin_worker, [(per, k * per, sim_s) for k in range(processes)])
    twin_aggregate.cpu_rt = members * sim_s / max(c for _, c in times)      # per CPU-second of the slowest worker
    return members * sim_s / max(w for w, _ in times)


def single_twin_rt(sim_s=0.5) -> float:
    model = load_model()
    tw = linearize(Stage(config=StageConfig.ideal(), model=model))
    ctrl = DiscreteController(controller_29(modal_analysis(model).static_gain_um_per_V))
    st = TwinStage(tw, seed=0, home_um=Stage(model=model).table_um)
    ref = _reference(int(sim_s * 4000))
    t0 = time.perf_counter()
    run_closed_loop(st, ctrl, ref, protocol=LoopProtocol(0.0, 0.0))
    return sim_s / (time.perf_counter() - t0)


def mujoco_rt(nthread, members=MJ_B, sim_s=MJ_SIM_S) -> float:
    model = load_model()
    ctrl = controller_29(modal_analysis(model).static_gain_um_per_V)
    ref = _reference(int(sim_s * 4000))
    with BatchMujocoStage(model, list(range(members)), nthread=nthread) as stage:
        bank = BatchController(ctrl, n=members, exact=False)
        t0 = time.perf_counter()
        run_closed_loop_batch(stage, bank, ref, protocol=LoopProtocol(0.0, 0.0))
        return members * sim_s / (time.perf_counter() - t0)


def _mujoco_worker(members, barrier):
    """One process stepping ``members`` MuJoCo stages on one thread; returns its wall time per member-second."""
    model = load_model()
    ctrl = controller_29(modal_analysis(model).static_gain_um_per_V)
    ref = _reference(int(MJ_SIM_S * 4000))
    with BatchMujocoStage(model, list(range(members)), nthread=1) as stage:
        bank = BatchController(ctrl, n=members, exact=False)
        barrier.wait()
        t0 = time.perf_counter()
        run_closed_loop_batch(stage, bank, ref, protocol=LoopProtocol(0.0, 0.0))
        return time.perf_counter() - t0


def mujoco_two_processes_rt(members=MJ_B) -> float:
    """The machine's own ceiling for two: ``members`` stages split over two independent single-threaded processes
    (no shared memory, no thread pool); aggregate real-time factor, by the slower process."""
    return members * MJ_SIM_S / max(_on_processes(_mujoco_worker, [(members // 2,)] * 2))


def test_mujoco_two_threads_vs_one(benchmark):
    benchmark.pedantic(mujoco_rt, args=(2,), rounds=1, iterations=1)
    ones, twos, procs = _rounds(lambda: mujoco_rt(1), lambda: mujoco_rt(2), mujoco_two_processes_rt)
    one, two, proc = max(ones), max(twos), max(procs)
    print(f"\nMuJoCo batch, B = {MJ_B}: 1 thread {_fmt(ones, 2)}x real time, 2 threads {_fmt(twos, 2)}x; "
          f"ratio of the fastest {two / one:.2f}, of the medians {np.median(twos) / np.median(ones):.2f} "
          f"(target >= 1.8); the machine's ceiling, two independent single-threaded processes: "
          f"{_fmt(procs, 2)}x, ratio {proc / one:.2f} (medians {np.median(procs) / np.median(ones):.2f})")
    benchmark.extra_info.update(one_thread_rt=one, two_threads_rt=two, ratio=two / one,
                                ratio_median=float(np.median(twos) / np.median(ones)),
                                two_processes_rt=proc, ratio_two_processes=proc / one)


def test_twin_batch_aggregate(benchmark):
    benchmark.pedantic(twin_aggregate, kwargs=dict(sim_s=0.1), rounds=1, iterations=1)
    cpu = []

    def aggregate():
        agg = twin_aggregate()
        cpu.append(twin_aggregate.cpu_rt)
        return agg

    singles, one_procs, aggs = _rounds(single_twin_rt, lambda: twin_aggregate(processes=1, members=TWIN_B // 2),
                                       aggregate)
    single, agg = max(singles), max(aggs)
    print(f"\nlinear twin, every effect on, 29-state controller: single stage {_fmt(singles, 1)}x real time; "
          f"batch of {TWIN_B // 2} on 1 process {_fmt(one_procs)}x aggregate; batch of {TWIN_B} on 2 processes "
          f"{_fmt(aggs)}x aggregate: fastest {agg:.0f}x, median {np.median(aggs):.0f}x (target >= 1000x; "
          f"{_fmt(cpu)}x counting each worker's CPU seconds, what 2 idle cores give); "
          f"batch / single = {agg / single:.0f}")
    benchmark.extra_info.update(single_rt=single, one_process_rt=max(one_procs), aggregate_rt=agg,
                                aggregate_rt_median=float(np.median(aggs)))


if __name__ == "__main__":
    pytest.main([__file__, "--benchmark-enable", "-s", "-q"])
