"""``nanosim pipeline --seeds 0-4``: the whole chain for several seeds, batched where it pays.

Layout: ``DIR/seed_<s>/`` is a complete single-seed run folder (the same files
as ``nanosim pipeline --seed s``, its own ``report.md``), ``DIR/seeds.json`` and
``DIR/report.md`` summarize all seeds: for every banded quantity of the report
the number of seeds inside the band, and the mean and worst value over the
seeds.

What is shared or batched:

* the modes (seed-independent) are computed once;
* each seed's identification and design run as one task on a local process pool (one
  seed's fitting and design beside another seed's simulations);
* the Section 5 experiments run with every seed as one member of a batch
  (:func:`nanosim.experiments.batch_suite.run_experiments_batch`): on MuJoCo
  the members are stepped from a thread pool, on the linear twin the members
  are vectorized, each member with its own controller and seed, bit for bit
  the single-seed numbers;
* the identification records of a seed run in parallel (MuJoCo rollout threads).
"""
from __future__ import annotations

import json
import math
import shutil
import sys
import time
from concurrent.futures import ProcessPoolExecutor
from multiprocessing import get_context
from pathlib import Path

import numpy as np

from nanosim.fileio import save_figure, write_json, write_text
from nanosim.pipeline import artifacts as A
from nanosim.pipeline.config import IdentifyConfig, PipelineConfig

__all__ = ["parse_seeds", "run_pipeline_seeds", "SEEDS_JSON"]

SEEDS_JSON = "seeds.json"
_KEY = ("bandwidth_S_hz", "bandwidth_T_hz", "step_2um.settling_ms", "step_2um.overshoot_percent",
        "resolution_sigma_nm.open_loop", "resolution_sigma_nm.closed_loop", "hysteresis.open_loop_percent",
        "hysteresis.closed_loop_nm", "creep.open_loop_drift_nm", "creep.closed_loop_drift_nm",
        "contouring.1000um_s.mean_error_nm")


def parse_seeds(text: str) -> tuple[int, ...]:
    """``"0-4"`` or ``"0,3,7"`` (or a mix) -> sorted distinct seeds."""
    out = set()
    try:
        for part in str(text).split(","):
            part = part.strip()
            if "-" in part:
                a, b = (int(x) for x in part.split("-", 1))
                if b < a:
                    raise ValueError
                out.update(range(a, b + 1))
            else:
                out.add(int(part))
    except ValueError:
        raise ValueError(f"--seeds: expected a range like 0-4 or a list like 0,3,7 of integers >= 0, got {text!r}") \
            from None
    if not out or min(out) < 0:
        raise ValueError(f"--seeds: expected integers >= 0, got {text!r}")
    return tuple(sorted(out))


def _seed_dir(out: Path, seed: int) -> Path:
    return out / f"seed_{seed}"


def _design_task(seed_dir: str, design_cfg, mjcf) -> str:
    from nanosim.pipeline.run import step_design

    step_design(Path(seed_dir), design_cfg, mjcf=mjcf)
    return seed_dir


def _identify_design_task(seed_dir: str, ident_cfg, design_cfg, mjcf) -> tuple[str, float, float]:
    """One seed's identification then design (a pool task); returns the folder and the two durations [s]."""
    from nanosim.pipeline.run import step_identify

    t0 = time.perf_counter()
    step_identify(Path(seed_dir), ident_cfg, mjcf)
    t1 = time.perf_counter()
    _design_task(seed_dir, design_cfg, mjcf)
    return seed_dir, round(t1 - t0, 2), round(time.perf_counter() - t1, 2)


def _characterize_all(out: Path, seeds, cfg: PipelineConfig, twin: bool, say) -> dict:
    """Every registered experiment, all seeds as members of one batch; metrics.json and figures per seed."""
    from nanosim import constants as C
    from nanosim import experiments
    from nanosim.design.controller import DiscreteController
    from nanosim.experiments.batch_suite import MemberPlant, run_experiments_batch
    from nanosim.experiments.registry import ExperimentContext
    from nanosim.plant.linearize import linearize
    from nanosim.plant.mjcf import load_model
    from nanosim.plant.modes import modal_analysis
    from nanosim.plant.stage import Stage, StageConfig

    names = experiments.load_builtin()
    model = load_model(cfg.mjcf)
    base = Stage(model=model)
    G0 = modal_analysis(model).static_gain_um_per_V
    tw = linearize(Stage(config=StageConfig.ideal(), model=model)) if twin else None
    plant = MemberPlant(twin=tw, model=model, home_um=base.table_um.copy(), static_gain_um_per_V=G0, base_stage=base)
    ctrls = [DiscreteController.from_npz(_seed_dir(out, s) / A.CONTROLLER_NPZ, expected_dt=C.CONTROL_PERIOD_S).config
             for s in seeds]
    t0 = time.perf_counter()
    done = []
    metrics, results = run_experiments_batch(names, [plant] * len(seeds), ctrls, engine="twin" if twin else "mujoco",
                                             seed=list(seeds), exact=True, progress=lambda n: done.append(n))
    seconds = round(time.perf_counter() - t0, 2)
    say(f"{'twin' if twin else 'MuJoCo'} experiments of {len(seeds)} seeds in {seconds:.1f} s")
    for b, s in enumerate(seeds):
        folder = _seed_dir(out, s) / (A.TWIN_DIR if twin else "")
        folder.mkdir(parents=True, exist_ok=True)
        m = dict(metrics[b])
        for name in names:
            exp = experiments.get(name)
            if name in results[b] and exp.figure is not None and exp.figure_name:
                ctx = ExperimentContext(factory=None, controller=DiscreteController(ctrls[b]), seed=s,
                                        static_gain_um_per_V=G0, base_stage=base)
                save_figure(exp.figure(results[b][name], ctx), folder / exp.figure_name)
        m["experiment_seconds"] = {"all_seeds_batched": seconds}
        m["plant"] = "linear twin (same electromechanics)" if twin else "MuJoCo stage, every effect on"
        m["seed"] = s
        m["units"] = {"nm": "nanometres", "um": "micrometres", "hz": "Hz", "ms": "milliseconds"}
        write_json(folder / A.METRICS_JSON, m)
    return {"seconds": seconds}


def run_pipeline_seeds(out, seeds, config: PipelineConfig | None = None, *, progress: bool = True,
                       workers: int | None = None) -> dict:
    """Run the pipeline for every seed into ``out`` (normally a staging folder); returns ``seeds.json``."""
    from nanosim.pipeline.report import pass_count, write_report
    from nanosim.pipeline.run import step_identify, step_modes
    from nanosim.pipeline.scaleout import cpu_workers

    cfg = config or PipelineConfig()
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)

    def say(msg):
        if progress:
            print(f"  {msg}", file=sys.stderr, flush=True)

    timings: dict[str, float] = {}
    t = time.perf_counter()
    first = _seed_dir(out, seeds[0])
    first.mkdir(parents=True, exist_ok=True)
    step_modes(first, cfg.mjcf)
    for s in seeds[1:]:
        shutil.copytree(first, _seed_dir(out, s), dirs_exist_ok=True)
    timings["modes"] = round(time.perf_counter() - t, 2)
    t = time.perf_counter()
    icfgs = [IdentifyConfig(seed=s, order=cfg.identify.order, ideal=cfg.identify.ideal,
                            operating_points_piezo_V=cfg.identify.operating_points_piezo_V) for s in seeds]
    n = min(len(seeds), workers or cpu_workers())
    if n > 1:
        # each seed identified then designed in a pool task: one seed's fitting and design run beside
        # another seed's simulations (the rollouts use threads of their own); the same numbers as in turn
        with ProcessPoolExecutor(n, mp_context=get_context("spawn")) as pool:
            for s, (_, ti, td) in zip(seeds, pool.map(_identify_design_task, [str(_seed_dir(out, s)) for s in seeds],
                                                       icfgs, [cfg.design] * len(seeds), [cfg.mjcf] * len(seeds))):
                say(f"identified ({ti:.0f} s) and designed ({td:.0f} s) seed {s}")
    else:
        for s, icfg in zip(seeds, icfgs):
            step_identify(_seed_dir(out, s), icfg, cfg.mjcf)
            _design_task(str(_seed_dir(out, s)), cfg.design, cfg.mjcf)
            say(f"identified and designed seed {s}")
    timings["identify_and_design"] = round(time.perf_counter() - t, 2)
    t = time.perf_counter()
    _characterize_all(out, seeds, cfg, twin=False, say=say)
    timings["characterize"] = round(time.perf_counter() - t, 2)
    if cfg.characterize_twin_too:
        t = time.perf_counter()
        _characterize_all(out, seeds, cfg, twin=True, say=say)
        timings["characterize_twin"] = round(time.perf_counter() - t, 2)
    t = time.perf_counter()
    per_seed = {}
    for s in seeds:
        d = _seed_dir(out, s)
        write_json(d / A.PIPELINE_JSON, {"stage_seconds": {"shared_with_other_seeds": timings}, "seed": s})
        write_report(d)
        ok, nb = pass_count(d)
        per_seed[s] = {"in_band": ok, "banded": nb, "metrics": _key_metrics(d)}
    timings["report"] = round(time.perf_counter() - t, 2)
    doc = _summary(seeds, per_seed, timings)
    write_json(out / SEEDS_JSON, doc)
    write_json(out / A.PIPELINE_JSON, {"stage_seconds": timings, "seeds": list(seeds)})
    write_text(out / A.REPORT_MD, _report(doc))
    return doc


def _key_metrics(run: Path) -> dict:
    from nanosim.pipeline.mc_stats import flatten_metrics

    p = run / A.METRICS_JSON
    flat = flatten_metrics(json.loads(p.read_text())) if p.is_file() else {}
    return {k: flat.get(k) for k in _KEY}


def _summary(seeds, per_seed, timings) -> dict:
    counts = [per_seed[s]["in_band"] for s in seeds]
    banded = [per_seed[s]["banded"] for s in seeds]
    rows = {}
    for k in _KEY:
        v = np.array([per_seed[s]["metrics"].get(k) if per_seed[s]["metrics"].get(k) is not None else math.nan
                      for s in seeds], float)
        rows[k] = {"per_seed": v.tolist(), "mean": float(np.nanmean(v)) if np.isfinite(v).any() else None,
                   "min": float(np.nanmin(v)) if np.isfinite(v).any() else None,
                   "max": float(np.nanmax(v)) if np.isfinite(v).any() else None}
    return {"seeds": list(seeds), "in_band_per_seed": dict(zip(map(str, seeds), counts)),
            "banded_per_seed": dict(zip(map(str, seeds), banded)),
            "in_band_mean": float(np.mean(counts)), "in_band_worst": int(min(counts)),
            "banded": int(max(banded)), "all_seeds_all_bands": all(c == b for c, b in zip(counts, banded)),
            "metrics": rows, "stage_seconds": timings, "wall_seconds": round(sum(timings.values()), 2)}


def _report(doc: dict) -> str:
    seeds = doc["seeds"]
    lines = [f"# nanosim pipeline, seeds {', '.join(map(str, seeds))}", "",
             f"**Checked quantities inside their bands: mean {doc['in_band_mean']:.1f} of {doc['banded']} over "
             f"{len(seeds)} seeds, worst seed {doc['in_band_worst']} of {doc['banded']}.** Each seed's own report: "
             + ", ".join(f"[seed {s}](seed_{s}/report.md) ({doc['in_band_per_seed'][str(s)]}/"
                         f"{doc['banded_per_seed'][str(s)]})" for s in seeds) + ".", "",
             "| quantity (MuJoCo stage) | " + " | ".join(f"seed {s}" for s in seeds) + " | mean | min | max |",
             "|---|" + "---|" * (len(seeds) + 3)]
    for k, r in doc["metrics"].items():
        vals = " | ".join("n/a" if (v is None or not math.isfinite(v)) else f"{v:.4g}" for v in r["per_seed"])
        f = (lambda x: "n/a" if x is None else f"{x:.4g}")
        lines.append(f"| `{k}` | {vals} | {f(r['mean'])} | {f(r['min'])} | {f(r['max'])} |")
    lines += ["", "Stage wall times (s), all seeds: " + ", ".join(f"{k} {v:.1f}" for k, v in
                                                                    doc["stage_seconds"].items()), ""]
    return "\n".join(lines)
