"""Speed of the bench electronics, each target a ratio measured in the same run.

Run: OPENBLAS_NUM_THREADS=1 python -m pytest tests/bench/bench_electronics.py -s

* The actuator chain (DAC, amplifier, piezo hysteresis and creep) and the sensor chain (gauge filter, noise,
  ADC) are stepped once per 250 us control period by every closed loop: one step must cost well under the
  period (target: at most a quarter of it, CPU time, so the mechanics has the rest).
* ``ActuatorChain.run`` processes a record in blocks: per sample it must beat stepping by at least 5x, with
  the same numbers.
"""
import time

import numpy as np
from numpy.testing import assert_array_equal

from nanosim import constants as C
from nanosim.plant.electronics import ActuatorChain, SensorChain

N = 20_000
STEP_BUDGET = 0.25         # of the control period, CPU time per step
RUN_OVER_STEP = 5.0        # per-sample speed of run() over step()


def _cpu(fn, *args):
    t0 = time.process_time()
    out = fn(*args)
    return time.process_time() - t0, out


def test_actuator_and_sensor_steps_fit_the_control_period():
    u = np.random.default_rng(0).uniform(0, 3, (N, 3))
    chain, sensor = ActuatorChain(seed=0), SensorChain(seed=0)
    t_act, _ = _cpu(lambda: [chain.step(x) for x in u])
    t_sen, _ = _cpu(lambda: [sensor.step(x) for x in u])
    per_act, per_sen = t_act / N, t_sen / N
    print(f"actuator step {1e6 * per_act:.1f} us, sensor step {1e6 * per_sen:.1f} us "
          f"(period {1e6 * C.CONTROL_PERIOD_S:.0f} us)")
    assert per_act <= STEP_BUDGET * C.CONTROL_PERIOD_S
    assert per_sen <= STEP_BUDGET * C.CONTROL_PERIOD_S


def test_actuator_run_beats_stepping_with_the_same_numbers():
    u = np.random.default_rng(0).uniform(0, 3, (N, 3))
    stepped = ActuatorChain(seed=0)
    t_step, outs = _cpu(lambda: [stepped.step(x) for x in u])
    t_run, run = _cpu(ActuatorChain(seed=0).run, u)
    print(f"run {t_step / t_run:.1f}x faster per sample than step")
    assert run.v_free_V.shape == (N, 3)
    assert_array_equal(run.v_free_V, np.array([o.v_free_V for o in outs]))
    assert t_step / t_run >= RUN_OVER_STEP
