"""Benchmark: subspace identification of three 3x1 columns (13 states, 16000 samples each).

Run with::

    python -m pytest tests/bench/bench_identification.py --benchmark-enable

(a bare ``tests/bench`` directory only collects this file if ``bench_*.py`` is
in pytest's ``python_files``).  Both benchmarks share the group
``identification``, so the pytest-benchmark table shows the identification
time relative to the baseline, which is the time to simulate the same three
records through the identified models with ``scipy.signal.dlsim``.  The
ratio measured within the run is also stored in ``extra_info`` and printed.
"""
from __future__ import annotations

import importlib.util
import time
from pathlib import Path

import numpy as np
import pytest
import scipy.signal as ss

import identification as ident

FS = 4000.0


def _load_identification_tests():
    """The test module tests/test_identification.py, whose plant generator the benchmark reuses."""
    path = Path(__file__).resolve().parents[1] / "test_identification.py"
    spec = importlib.util.spec_from_file_location("_nanosim_test_identification_for_bench", path)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def _column_plant(seed):
    """13-state 3x1 column: six light modes 175-740 Hz plus a 30 rad/s creep pole (ZOH, 4 kHz)."""
    rng = np.random.default_rng(seed)
    f = np.array([175.0, 179.0, 245.0, 460.0, 474.0, 740.0]) * rng.uniform(0.98, 1.02, 6)
    _, sysd, _ = _load_identification_tests().column_plant(rng, f, fs=FS)
    return sysd


@pytest.fixture(scope="module")
def columns():
    """Three (u, y) records, one per actuator, with 1 % output noise."""
    data = []
    for seed in range(3):
        ex = ident.paper_excitation(fs=FS, seed=seed)
        _, y, _ = ss.dlsim((*_column_plant(seed), 1.0 / FS), ex.u)
        y = y + 0.01 * y.std(axis=0) * np.random.default_rng(seed).normal(size=y.shape)
        data.append((np.asarray(ex.u), y))
    return data


def _identify_all(columns):
    return [ident.subspace_id(y, u, fs=FS) for u, y in columns]


def _simulate_all(models, columns):
    return [ss.dlsim((m.A, m.B, m.C, m.D, m.dt_s), u, x0=m.x0)[1] for m, (u, _) in zip(models, columns)]


def _best_time(fn, repeats=3):
    best = np.inf
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        best = min(best, time.perf_counter() - t0)
    return best


@pytest.mark.benchmark(group="identification")
def test_bench_identify_three_columns(benchmark, columns):
    models = _identify_all(columns)  # warm-up, also gives the baseline models
    baseline_s = _best_time(lambda: _simulate_all(models, columns))
    result = benchmark.pedantic(_identify_all, args=(columns,), rounds=3, iterations=1, warmup_rounds=0)
    assert [m.order for m in result] == [13, 13, 13]
    for m, (u, y) in zip(result, columns):
        assert np.all(ident.fit_percent(y, ident.simulate(m, u, m.x0)) > 98.0)
    stats = getattr(benchmark, "stats", None)
    ident_s = stats.stats.min if stats is not None else _best_time(lambda: _identify_all(columns))
    ratio = ident_s / baseline_s
    benchmark.extra_info.update(
        identify_s=ident_s, baseline_dlsim_s=baseline_s, ratio_identify_over_dlsim=ratio
    )
    print(
        f"\nidentify 3 columns (13 states, 16000 samples): {ident_s:.3f} s; "
        f"dlsim baseline: {baseline_s:.3f} s; ratio {ratio:.2f}"
    )


@pytest.mark.benchmark(group="identification")
def test_bench_baseline_dlsim_three_columns(benchmark, columns):
    models = _identify_all(columns)
    benchmark.pedantic(_simulate_all, args=(models, columns), rounds=3, iterations=1, warmup_rounds=0)
