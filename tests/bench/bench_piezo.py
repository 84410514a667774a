"""Cost of the thermally activated piezo operators in Stage.run, a ratio measured in the same run.

Run: OPENBLAS_NUM_THREADS=1 python -m pytest tests/bench/bench_piezo.py --benchmark-enable -s

``Stage.run`` of 1 s with every effect on, with the default piezo (thermally activated operators)
and with the baseline ``PiezoConfig.kelvin_voigt()`` (athermal operators and the Kelvin-Voigt creep
filter: the same operator count without thermal activation). Target: the default costs at most 5 %
more than the baseline. Each configuration is timed ROUNDS times, alternating, and the ratio is
taken between the fastest of each (the timeit convention: slower repeats are other processes
interfering on a shared machine); every round is printed. The piezo chain alone (``PiezoModel.run``
of the same 1 s) is timed too, to show what the operators cost in isolation.
"""
import time

import numpy as np
import pytest

from nanosim.plant.piezo import PiezoConfig, PiezoModel
from nanosim.plant.stage import Stage, StageConfig

SIM_S = 1.0
ROUNDS = 5
TARGET_RATIO = 1.05


def _fmt(values):
    return ", ".join(f"{v * 1e3:.1f}" for v in values)


@pytest.fixture(scope="module")
def setup():
    u = np.random.default_rng(0).uniform(0, 1, size=(int(SIM_S * 4000), 3))
    stages = {name: Stage(seed=0, config=StageConfig(piezo=p))
              for name, p in (("thermal", PiezoConfig()), ("kelvin_voigt", PiezoConfig.kelvin_voigt()))}
    for st in stages.values():          # load the compiled routines before timing
        st.run(u[:10])
    return stages, u


def _time(f):
    t0 = time.process_time()
    f()
    return time.process_time() - t0


def test_stage_run_thermal_piezo_costs_at_most_5_percent(setup):
    stages, u = setup

    def run(st):
        st.reset()
        st.run(u)

    times = {k: [] for k in stages}
    for _ in range(ROUNDS):
        for k, st in stages.items():
            times[k].append(_time(lambda: run(st)))
    ratio = min(times["thermal"]) / min(times["kelvin_voigt"])
    piezo = {}
    v = 20.0 * u
    for name, p in (("thermal", PiezoConfig()), ("kelvin_voigt", PiezoConfig.kelvin_voigt())):
        m = PiezoModel(p)
        m.run(v[:10])
        piezo[name] = min(_time(lambda: (m.reset(), m.run(v))) for _ in range(ROUNDS))
    print(f"\nStage.run {SIM_S:g} s, CPU ms per round: thermal [{_fmt(times['thermal'])}], "
          f"kelvin_voigt [{_fmt(times['kelvin_voigt'])}]; ratio of the fastest {ratio:.3f} (target <= {TARGET_RATIO})")
    print(f"PiezoModel.run alone: thermal {piezo['thermal'] * 1e3:.2f} ms, "
          f"kelvin_voigt {piezo['kelvin_voigt'] * 1e3:.2f} ms")
    assert ratio <= TARGET_RATIO
