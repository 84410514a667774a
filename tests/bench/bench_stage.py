"""Simulation speed: bare mj_step vs Stage.run with every effect on, in the same run.

Run: python -m pytest tests/bench/bench_stage.py --benchmark-enable -s
Reports simulated seconds per wall second for each, and their cost ratio.
Targets: Stage.run costs <= 1.3x bare stepping; Stage.run >= 1.0x real time on one core with the v2
simulation model.
"""
import time

import mujoco
import numpy as np
import pytest

from nanosim.plant.mechanics import home_data
from nanosim.plant.stage import Stage

SIM_S = 1.0


def _bare(model):
    d = home_data(model)
    n_sub = int(round(2.5e-4 / model.opt.timestep))
    for _ in range(int(SIM_S * 4000)):
        d.ctrl[:] = 1.0
        mujoco.mj_step(model, d, n_sub)


def _stage(st, u):
    st.reset()
    st.run(u)


@pytest.fixture(scope="module")
def setup():
    st = Stage(seed=0)
    u = np.random.default_rng(0).uniform(0, 1, size=(int(SIM_S * 4000), 3))
    return st, u


def test_bare_mj_step(benchmark, setup):
    st, _ = setup
    benchmark.pedantic(_bare, args=(st.model,), rounds=3, iterations=1)
    benchmark.extra_info["sim_s_per_wall_s"] = SIM_S / benchmark.stats["mean"]


def test_stage_run_all_effects(benchmark, setup):
    st, u = setup
    benchmark.pedantic(_stage, args=(st, u), rounds=3, iterations=1)
    benchmark.extra_info["sim_s_per_wall_s"] = SIM_S / benchmark.stats["mean"]


def test_ratio_report(setup):
    """Wall-clock and CPU-time real-time factors in the same run (CPU time: one core's worth of work,
    which other processes on a shared machine do not inflate as much as the wall clock)."""
    st, u = setup
    t0, c0 = time.perf_counter(), time.process_time()
    _bare(st.model)
    bare, bare_cpu = time.perf_counter() - t0, time.process_time() - c0
    t0, c0 = time.perf_counter(), time.process_time()
    _stage(st, u)
    stage, stage_cpu = time.perf_counter() - t0, time.process_time() - c0
    print(f"\nbare mj_step: {SIM_S / bare:.2f} x real time; Stage.run (all effects): {SIM_S / stage:.2f} x real "
          f"time; cost ratio Stage/bare = {stage / bare:.2f}")
    print(f"CPU time: bare mj_step {SIM_S / bare_cpu:.2f} x real time; Stage.run {SIM_S / stage_cpu:.2f} x real time "
          f"({st.model.nv} dofs, {st.substeps} substeps of {st.model.opt.timestep * 1e6:g} us per period)")
