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

import time

import numpy as np
import pytest
import scipy.linalg as la
import scipy.signal as ss

import identification as ident

FS = 4000.0


def _column_plant(seed):
    """13-state 3x1 column: six light modes 175-740 Hz plus a 30 rad/s creep pole (ZOH, 4 kHz)."""
    rng = np.random.default_rng(seed)
    f = np.array([175.0, 179.0, 245.0, 460.0, 474.0, 740.0]) * rng.uniform(0.98, 1.02, 6)
    zeta = rng.uniform(0.002, 0.01, 6)
    n = 13
    A = np.zeros((n, n))
    B = np.zeros((n, 1))
    C = np.zeros((3, n))
    for k, (fk, zk) in enumerate(zip(f, zeta)):
        w = 2 * np.pi * fk
        A[2 * k : 2 * k + 2, 2 * k : 2 * k + 2] = [[0.0, 1.0], [-w * w, -2 * zk * w]]
        B[2 * k + 1, 0] = w * w
        C[:, 2 * k] = rng.normal(size=3) / (k + 1)
    C[:, 0] += 1.0
    A[12, 12], B[12, 0] = -30.0, 30.0
    C[:, 12] = 0.15 * rng.normal(size=3)
    M = np.zeros((n + 1, n + 1))
    M[:n, :n], M[:n, n:] = A, B
    E = la.expm(M / FS)
    return E[:n, :n], E[:n, n:], C, np.zeros((3, 1))


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
