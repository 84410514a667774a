"""``nanosim pipeline --seeds 0-4``: the whole chain for several seeds, batched where it pays.

Layout: ``DIR/seed_<s>/`` is a complete single-seed run folder (the same files
as ``nanosim pipeline --seed s``, its own ``report.md``), ``DIR/seeds.json`` and
``DIR/report.md`` summarize all seeds: for every banded quantity of the report
the number of seeds inside the band, and the mean and worst value over the
seeds.

What is shared or scheduled together:

* the modes (seed-independent) are computed once;
* every seed's identification, design and Section 5 experiments (one task per experiment
  and plant, each on the batch engine with one member) are tasks on one pool of worker
  processes, a seed's design submitted when its identification is done and its experiments
  when its design is done: the two cores stay busy across seeds (one seed's design beside
  another's simulations), and each task runs the code and seed of the single-seed pipeline,
  so every seed's numbers are those of ``nanosim pipeline --seed s``;
* the identification records of a seed run in parallel (MuJoCo rollout threads).
"""
from __future__ import annotations

import dataclasses
import gc
import json
import math
import shutil
import sys
import time
from pathlib import Path

import numpy as np

from nanosim.fileio import write_json, write_text
from nanosim.pipeline import artifacts as A
from nanosim.pipeline import mc_stats
from nanosim.pipeline.config import PipelineConfig
from nanosim.pipeline.timings import record_timings

__all__ = ["acceptance_summary", "parse_seeds", "run_pipeline_seeds"]

_KEY = ("bandwidth_S_hz", "bandwidth_T_hz", "step_2um.settling_ms", "step_2um.overshoot_percent",
        "resolution_sigma_nm.open_loop", "resolution_sigma_nm.closed_loop", "hysteresis.open_loop_percent",
        "hysteresis.closed_loop_nm", "creep.open_loop_drift_nm", "creep.closed_loop_drift_nm",
        mc_stats.CONTOUR_MEAN_METRIC)


MAX_SEEDS = 1000        # a bound on --seeds: 1000 seeds are ~1000 pipeline runs, more is a typo


def parse_seeds(text: str, *, sort: bool = True) -> tuple[int, ...]:
    """``"0-4"`` or ``"0,3,7"`` (or a mix) -> distinct seeds, sorted (or in the order given, ``sort=False``).

    Raises
    ------
    ValueError
        Not a range/list of integers >= 0, a seed listed twice (``1,1``, ``0-3,2``), or more than
        :data:`MAX_SEEDS` seeds (checked before any list is built).
    """
    out: dict[int, None] = {}
    what = f"a range like 0-4 or a list like 0,3,7 of at most {MAX_SEEDS} integers >= 0"
    try:
        for part in str(text).split(","):
            a, dash, b = part.strip().partition("-")
            lo, hi = int(a), int(b) if dash else int(a)
            if lo < 0 or hi < lo:
                raise ValueError
            if hi - lo + 1 > MAX_SEEDS:             # before the range is built
                raise OverflowError(f"{hi - lo + 1}")
            twice = next((s for s in range(lo, hi + 1) if s in out), None)
            if twice is not None:                   # which run would the second one be?
                raise LookupError(twice)
            out.update(dict.fromkeys(range(lo, hi + 1)))
            if len(out) > MAX_SEEDS:
                raise OverflowError(f"more than {MAX_SEEDS}")
    except LookupError as exc:
        raise ValueError(f"--seeds: expected distinct seeds, got seed {exc.args[0]} twice in {text!r}") from None
    except OverflowError as exc:
        raise ValueError(f"--seeds: expected at most {MAX_SEEDS} seeds, got {exc} in {text!r}") from None
    except ValueError:
        raise ValueError(f"--seeds: expected {what}, got {text!r}") from None
    return tuple(sorted(out)) if sort else tuple(out)


def _seed_dir(out: Path, seed: int) -> Path:
    return out / A.pipeline_seed_dir(seed)


def _identify_task(seed_dir: str, ident_cfg, mjcf) -> float:
    """One seed's identification (a pool task); returns its wall time [s]."""
    from nanosim.pipeline.run import step_identify

    t0 = time.perf_counter()
    step_identify(Path(seed_dir), ident_cfg, mjcf)
    return round(time.perf_counter() - t0, 2)


def _schedule(out: Path, seeds, cfg: PipelineConfig, workers: int, say) -> dict:
    """Every seed's identification, design and experiments as tasks on one process pool.

    A seed's design becomes ready when its identification is done, its experiments (one task
    per experiment and plant) when its design is done. The pool gets one task per worker at a
    time, the most urgent ready one first: designs (they unlock a seed's experiments), then
    identifications, then experiments, the longest first; so the workers stay busy across
    seeds (one seed's design beside another seed's simulations) and the last seed's
    experiments are not left for the end. Each task runs the code and seed of the single-seed
    pipeline, so every seed's numbers are those of ``nanosim pipeline --seed s``. Returns the
    summed task seconds per kind.
    """
    import heapq
    import queue

    from nanosim.pipeline.characterize import write_task_metrics
    from nanosim.pipeline.compensation import CASES
    from nanosim.pipeline.run import (compensation_specs, design_task, experiment_specs, experiments_names,
                                      modes_task, spawn_pool, stop_pool, write_compensation_results)
    from nanosim.pipeline.workers import stop_deferred

    mj = cfg.mjcf_arg
    n_exp = len(experiments_names()) * (2 if cfg.characterize_twin_too else 1)
    totals = {"modes": 0.0, "identify": 0.0, "design": 0.0, "characterize": 0.0, "characterize_twin": 0.0,
              "compensation": 0.0}
    ready: list = []              # heap of (urgency, cost, order, kind, seed, fn, args)
    order = iter(range(10 ** 9))

    def push(urgency, cost, kind, seed, fn, args):
        heapq.heappush(ready, (urgency, -cost, next(order), kind, seed, fn, args))

    for s in seeds:
        _seed_dir(out, s).mkdir(parents=True, exist_ok=True)
    modes_dir = out / ".modes"          # computed once, then copied into every seed's folder
    modes_dir.mkdir(parents=True, exist_ok=True)
    push(-1, 0.0, "modes", seeds[0], modes_task, (str(modes_dir), mj))
    for s in seeds:
        icfg = dataclasses.replace(cfg.identify, seed=s)
        push(1, 0.0, "identify", s, _identify_task, (str(_seed_dir(out, s)), icfg, mj))
    parts = {s: {False: {}, True: {}} for s in seeds}
    comp: dict = {s: [] for s in seeds}        # the hysteresis-compensation cases of each seed as they come in
    left = {s: n_exp for s in seeds}
    finished: queue.SimpleQueue = queue.SimpleQueue()
    pool = None
    running = 0
    try:
        with stop_deferred():          # Ctrl-C/SIGTERM while the workers start: once they can be stopped
            pool = spawn_pool(workers)
        while ready or running:
            while ready and running < workers:
                _, _, _, kind, s, fn, args = heapq.heappop(ready)
                pool.apply_async(fn, args, callback=lambda r, k=kind, s=s: finished.put((k, s, r, None)),
                                 error_callback=lambda e, k=kind, s=s: finished.put((k, s, None, e)))
                running += 1
            try:
                kind, s, result, exc = finished.get(timeout=0.2)
            except queue.Empty:
                continue
            running -= 1
            if exc is not None:
                raise exc
            if kind == "modes":
                totals["modes"] += result
                for other in seeds:
                    shutil.copytree(modes_dir, _seed_dir(out, other), dirs_exist_ok=True)
                shutil.rmtree(modes_dir)
            elif kind == "identify":
                totals["identify"] += result
                push(0, 0.0, "design", s, design_task, (str(_seed_dir(out, s)), cfg.design, mj))
            elif kind == "design":
                totals["design"] += result
                say(f"seed {s}: identified and designed")
                for cost, tw, _, fn, args in experiment_specs(_seed_dir(out, s), s, mj,
                                                              twin_too=cfg.characterize_twin_too):
                    push(2, cost, "twin" if tw else "mujoco", s, fn, args)
                for fn, args in compensation_specs(_seed_dir(out, s), s, mj):   # about as long as the twin's longest
                    push(2, 2.0, "compensation", s, fn, args)                     # experiment
            elif kind == "compensation":
                comp[s].append(result)
                if len(comp[s]) == len(CASES):
                    totals["compensation"] += write_compensation_results(_seed_dir(out, s), comp[s], s)
            else:
                name, met, sec = result
                tw = kind == "twin"
                parts[s][tw][name] = (met, sec)
                totals["characterize_twin" if tw else "characterize"] += sec
                left[s] -= 1
                if left[s] == 0:
                    write_task_metrics(_seed_dir(out, s), parts[s][False], s)
                    if cfg.characterize_twin_too:
                        write_task_metrics(_seed_dir(out, s) / A.TWIN_DIR, parts[s][True], s, twin=True,
                                           run_dir=_seed_dir(out, s))
                    say(f"seed {s}: experiments done")
    except BaseException:
        if pool is not None:
            stop_pool(pool)    # Ctrl-C or a failed task: stop the workers now
        pool = ready = finished = None
        gc.collect()           # release the pool's semaphores now
        raise
    pool.close()
    pool.join()
    return {k: round(v, 2) for k, v in totals.items()}


def run_pipeline_seeds(out, seeds, config: PipelineConfig | None = None, *, progress: bool = True,
                       workers: int | None = None) -> dict:
    """Run the pipeline for every seed into ``out`` (normally a staging folder); returns ``seeds.json``'s
    content with the wall times of ``timings.json`` (``stage_seconds``, ``wall_seconds``, ``task_seconds_all_seeds``).

    The modes are computed once (copied into every seed's folder); they and every seed's
    identification, design and experiments are tasks on one pool of worker processes
    (:func:`_schedule`).
    """
    from nanosim.pipeline.report import pass_count, run_acceptance_doc, write_report
    from nanosim.pipeline.run import step_budget
    from nanosim.pipeline.scaleout import cpu_workers

    cfg = config or PipelineConfig()
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)

    def say(msg):
        if progress:
            print(f"  {msg}", file=sys.stderr, flush=True)

    timings: dict[str, float] = {}
    t = time.perf_counter()
    task_seconds = _schedule(out, seeds, cfg, max(1, min(2 * len(seeds), workers or cpu_workers())), say)
    timings["modes_identify_design_characterize"] = round(time.perf_counter() - t, 2)
    t = time.perf_counter()      # the noise budget (analytic, seconds) and the report of every seed
    per_seed = {}
    mj = cfg.mjcf_arg
    for s in seeds:
        d = _seed_dir(out, s)
        step_budget(d, mj)
        write_json(d / A.PIPELINE_JSON, {"seed": s})
        record_timings(d, {A.PIPELINE_JSON: {"stage_seconds": {"shared_with_other_seeds": timings,
                                                               "task_seconds_all_seeds": task_seconds}}})
        write_report(d)
        ok, nb = pass_count(d)
        per_seed[s] = {"in_band": ok, "banded": nb, "metrics": _key_metrics(d),
                       "acceptance": run_acceptance_doc(d)}
    timings["report"] = round(time.perf_counter() - t, 2)
    doc = _summary(seeds, per_seed)
    write_json(out / A.SEEDS_JSON, doc)
    write_json(out / A.PIPELINE_JSON, {"seeds": list(seeds)})
    wall = {"stage_seconds": timings, "wall_seconds": round(sum(timings.values()), 2),
            "task_seconds_all_seeds": task_seconds}
    record_timings(out, {A.SEEDS_JSON: wall, A.PIPELINE_JSON: {"stage_seconds": timings}})
    write_text(out / A.REPORT_MD, _report(doc, timings))
    return {**doc, **wall}


def _key_metrics(run: Path) -> dict:
    from nanosim.pipeline.mc_stats import flatten_metrics

    p = run / A.METRICS_JSON
    flat = flatten_metrics(json.loads(p.read_text())) if p.is_file() else {}
    return {k: flat.get(k) for k in _KEY}


def _summary(seeds, per_seed) -> dict:
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
            "metrics": rows, "acceptance": acceptance_summary(seeds, per_seed)}


def acceptance_summary(seeds, per_seed) -> dict:
    """Per criterion: the value and verdict on every seed, the worst value and whether every seed passes."""
    from nanosim.pipeline.scorecard import worst_of
    first = per_seed[seeds[0]].get("acceptance") or {}
    rows = []
    for i, c in enumerate(first.get("criteria", [])):
        cells = [per_seed[s]["acceptance"]["criteria"][i] for s in seeds]
        vals = [x["value"] for x in cells]
        worst = worst_of(c["key"], vals)
        verdicts = [x["pass"] for x in cells]
        rows.append({"key": c["key"], "label": c["label"], "unit": c["unit"], "criterion": c["criterion"],
                     "per_seed": vals, "worst": worst,
                     "every_seed": None if any(v is None for v in verdicts) else all(verdicts)})
    return {"controller": first.get("controller"), "controller_order": first.get("controller_order"),
            "criteria": rows, "met_on_every_seed": sum(1 for r in rows if r["every_seed"]),
            "measured": sum(1 for r in rows if r["every_seed"] is not None)}


def _report(doc: dict, stage_seconds: dict) -> str:
    seeds = doc["seeds"]
    lines = [f"# nanosim pipeline, seeds {', '.join(map(str, seeds))}", "",
             f"**Checked quantities inside their bands: mean {doc['in_band_mean']:.1f} of {doc['banded']} over "
             f"{len(seeds)} seeds, worst seed {doc['in_band_worst']} of {doc['banded']}.** Each seed's own report: "
             + ", ".join(f"[seed {s}]({A.pipeline_seed_dir(s)}/{A.REPORT_MD}) ({doc['in_band_per_seed'][str(s)]}/"
                         f"{doc['banded_per_seed'][str(s)]})" for s in seeds) + ".", "",
             "| quantity (MuJoCo stage) | " + " | ".join(f"seed {s}" for s in seeds) + " | mean | min | max |",
             "|---|" + "---|" * (len(seeds) + 3)]
    for k, r in doc["metrics"].items():
        vals = " | ".join("n/a" if (v is None or not math.isfinite(v)) else f"{v:.4g}" for v in r["per_seed"])
        f = (lambda x: "n/a" if x is None else f"{x:.4g}")
        lines.append(f"| `{k}` | {vals} | {f(r['mean'])} | {f(r['min'])} | {f(r['max'])} |")
    acc = doc.get("acceptance") or {}
    if acc.get("criteria"):
        from nanosim.pipeline.scorecard import format_value
        lines += ["", "## Controllers", "",
                  f"Exported controller: `{acc['controller']}` ({acc['controller_order']} states), designed on each "
                  "seed's own identified model. Acceptance against the bench specification "
                  "(nanosim/pipeline/scorecard.py, ACCEPTANCE), worst case over the "
                  f"seeds: **{acc['met_on_every_seed']} of {acc['measured']} measured criteria met on every seed** "
                  "(the feedback loop's own S bandwidth is measured by `nanosim compare`; every seed's report has "
                  "the bench and its default rule).", "",
                  "| criterion | target | " + " | ".join(f"seed {s}" for s in seeds) + " | worst | every seed |",
                  "|---|---|" + "---|" * (len(seeds) + 2)]
        for r in acc["criteria"]:
            vals = " | ".join(format_value(v, r["unit"]) for v in r["per_seed"])
            ok = "n/a" if r["every_seed"] is None else ("yes" if r["every_seed"] else "**NO**")
            lines.append(f"| {r['label']} | {r['criterion']} | {vals} | "
                         f"{format_value(r['worst'], r['unit'], with_unit=True)} | {ok} |")
    lines += ["", "Stage wall times (s), all seeds: " + ", ".join(f"{k} {v:.1f}" for k, v in
                                                                    stage_seconds.items()), ""]
    return "\n".join(lines)
