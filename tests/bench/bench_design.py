"""Benchmark: H-infinity synthesis wall time relative to same-size baselines.

Run explicitly (the file name is outside pytest's default ``test_*.py`` pattern and
``pyproject.toml`` disables benchmarks by default)::

    pytest tests/bench/bench_design.py --benchmark-enable -s

Each benchmark times its own baseline in the same process and run, so the reported
ratio is insensitive to the machine speed and load:

* ``care``   -- ``scipy.linalg.solve_continuous_are`` of the generalized plant's
  control Riccati equation (19 states, the size of one gamma iteration's X-Riccati);
* ``balred`` -- the 39 -> 10 state DC-matched balanced reduction (slycot ab09nd).

Ratios are stored in ``benchmark.extra_info`` and printed. Baselines and synthesis
run with BLAS limited to one thread (what ``nanosim.design`` does internally).
"""
from __future__ import annotations

import importlib.util
import timeit
import warnings
from pathlib import Path

import numpy as np
import pytest

ct = pytest.importorskip("control")
pytest.importorskip("slycot")
pytest.importorskip("pytest_benchmark")

from scipy.linalg import solve_continuous_are  # noqa: E402

import nanosim.design as D  # noqa: E402


def _paper_like_plant():
    """Reuse the synthetic 39-state paper-like plant defined in tests/test_design.py."""
    path = Path(__file__).resolve().parents[1] / "test_design.py"
    spec = importlib.util.spec_from_file_location("_nanosim_test_design_for_bench", path)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod.paper_like_plant()


@pytest.fixture(scope="module")
def problem():
    G = _paper_like_plant()
    red = D.reduce_model(G, 10)
    P = D.generalized_plant(red.G_reduced)
    return G, red, P


def _best(fn, repeat=7):
    fn()  # warm-up
    return min(timeit.repeat(fn, number=1, repeat=repeat))


def _baselines(G, P):
    nw = nmeas = 3
    A, B, C, Dm = (np.asarray(getattr(P, k), float) for k in "ABCD")
    B2 = B[:, nw:]
    C1, D12 = C[:-nmeas], Dm[:-nmeas, nw:]
    Q, R, S = C1.T @ C1, D12.T @ D12, C1.T @ D12

    def care():
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            return solve_continuous_are(A, B2, Q, R, s=S)

    def balred():
        return ct.balanced_reduction(G, 10, method="matchdc")

    return {"care": _best(care), "balred": _best(balred)}


def _report(benchmark, name, t_fn, base):
    ratios = {f"ratio_vs_{k}": t_fn / v for k, v in base.items()}
    benchmark.extra_info.update({"wall_s_best": t_fn, **{f"baseline_{k}_s": v for k, v in base.items()}, **ratios})
    print(f"\n{name}: best {t_fn * 1e3:.1f} ms; " + ", ".join(
        f"{k} {base[k] * 1e3:.2f} ms -> ratio {ratios['ratio_vs_' + k]:.1f}x" for k in base))


def test_bench_hinfsyn(benchmark, problem):
    """slycot sb10ad on the 19-state generalized plant (3 measurements, 3 controls),
    with BLAS limited to one thread as nanosim.design does; one extra run with the
    default OpenBLAS threading is recorded for comparison."""
    G, red, P = problem
    with D.single_threaded_blas():
        base = _baselines(G, P)
        t_syn = _best(lambda: ct.hinfsyn(P, 3, 3), repeat=5)
        K, _, gamma, _ = benchmark(ct.hinfsyn, P, 3, 3)
    assert K.nstates == 19 and 1.0 < gamma < 2.0
    t0 = timeit.default_timer()
    ct.hinfsyn(P, 3, 3)
    t_default_threads = timeit.default_timer() - t0
    benchmark.extra_info["wall_s_default_blas_threads_single_run"] = t_default_threads
    _report(benchmark, "hinfsyn (sb10ad, 1 BLAS thread)", t_syn, base)
    print(f"hinfsyn with default BLAS threading (one run): {t_default_threads * 1e3:.0f} ms")


def test_bench_design_hinf(benchmark, problem):
    """Whole design_hinf: checks + synthesis + closed-loop analysis with the full model."""
    G, red, P = problem
    with D.single_threaded_blas():
        base = _baselines(G, P)
    t_des = _best(lambda: D.design_hinf(red.G_reduced, None, G_full=G), repeat=3)
    d = benchmark.pedantic(D.design_hinf, args=(red.G_reduced, None), kwargs={"G_full": G}, rounds=3, iterations=1)
    assert d.controller_order == 19 and d.stable_full
    _report(benchmark, "design_hinf (synthesis + analysis)", t_des, base)


def test_bench_discretize(benchmark, problem):
    G, red, P = problem
    d = D.design_hinf(red.G_reduced, None)
    with D.single_threaded_blas():
        base = _baselines(G, P)
    t_disc = _best(lambda: D.discretize_controller(d.K), repeat=3)
    disc = benchmark.pedantic(D.discretize_controller, args=(d.K,), rounds=3, iterations=1)
    assert disc.within_tol
    _report(benchmark, f"discretize_controller (auto -> {disc.method})", t_disc, base)
