"""``nanosim montecarlo``: one controller on a population of fabricated stages.

Each sample is a stage cut with the tolerances of
:mod:`nanosim.plant.tolerances` (sample ``i`` of seed ``S`` is the same
whatever ``--n``). Per sample: the modes, the static gain, closed-loop
stability and the disk margin of the loop with the sample's linear twin
(piezo small-signal gain and creep included), and the Section 5 experiments
(every registered experiment) on the sample's linear twin in the full
electromechanics, batched (:mod:`nanosim.experiments.batch_suite`). A subset
(``--crosscheck``, default 10) is rerun on MuJoCo and compared metric by
metric, against the reading spread of the sample's twin at indistinguishable physics
(``mc_stats.reading_spread``: 2 K + 1 twins whose input gains differ by ppm). Samples run in chunks on
a local process pool or a Dask cluster (:mod:`nanosim.pipeline.scaleout`).

Run folder (incremental; see the README):

* ``montecarlo.json`` -- the plan (seed, controller sha256, tolerance model, experiments); a rerun
  with another plan into the same folder is refused;
* ``tolerances.json``, ``spec.json``;
* ``samples/sample_NNNNN.json`` -- written atomically as each chunk finishes, so a rerun skips
  them and Ctrl-C loses nothing finished; ``crosscheck/sample_NNNNN.json`` likewise (MuJoCo), and
  ``crosscheck_spread/sample_NNNNN.json`` (the twin's reading spread: per metric min, max, mean, std);
  each with its ``units``;
* ``summary.json`` (yield, worst cases, sensitivity, cross-check), the figures and ``report.md``;
* ``timings.json`` -- the wall times (per sample, per phase, in all), kept out of the files above so
  that they do not depend on the machine, the chunking or the scheduler;
* ``manifest.json`` last.

A staging folder (``runfolder.staged_run``) would throw away finished samples
on Ctrl-C, so this command writes in place: it checks its input and the folder,
and connects to the scheduler (or starts the pool), before it writes anything;
then it holds the folder's writer lock, removes a previous ``manifest.json``
before it changes anything, and seals the folder with a new manifest only when
everything is written.
"""
from __future__ import annotations

import contextlib
import dataclasses
import hashlib
import json
import math
import sys
import time
from pathlib import Path

import numpy as np

from nanosim.fileio import save_figure, write_json, write_text
from nanosim.pipeline import artifacts as A
from nanosim.pipeline import mc_stats
from nanosim.pipeline.config import MonteCarloConfig
from nanosim.pipeline.runfolder import (MANIFEST_JSON, RunFolderError, check_writable, sha256_file, write_manifest,
                                        writer_lock)
from nanosim.pipeline.scaleout import check_scheduler, open_executor, run_tasks
from nanosim.pipeline.timings import record_timings

__all__ = ["run_montecarlo", "montecarlo_plan", "run_chunk", "sample_plants", "summarize", "report_markdown",
           "sample_units", "load_sample_flats", "MAX_SAMPLES", "SAMPLE_WORKER_SECONDS", "estimate_seconds",
           "check_sample_count", "format_duration"]

SENSITIVITY_EXTRA = ("mode_1_hz", "xy_split_percent", "disk_margin_alpha")
SPREAD_ENGINE = "twin-spread"

#: Largest ``--n``: the sample files are numbered with five digits (``sample_NNNNN.json``).
MAX_SAMPLES = 100_000
#: Wall seconds one worker spends on one sample, per engine (every registered experiment, the bundled
#: stage): the scale of the estimate printed before a Monte Carlo starts, calibrated on the per-sample
#: ``seconds`` that ``timings.json`` records for single-worker runs; a loaded or faster machine differs.
SAMPLE_WORKER_SECONDS = {"twin": 6.0, "mujoco": 120.0, SPREAD_ENGINE: 8.0}


def format_duration(seconds: float) -> str:
    """``"45 s"``, ``"12 min"``, ``"3.2 h"``, ``"41 days"``."""
    if seconds < 120:
        return f"{seconds:.0f} s"
    if seconds < 7200:
        return f"{seconds / 60:.0f} min"
    if seconds < 2 * 86400:
        return f"{seconds / 3600:.1f} h"
    return f"{seconds / 86400:.0f} days"


def estimate_seconds(n_twin: int, n_mujoco: int, workers: int) -> dict:
    """Estimated wall time of ``n_twin`` linear-twin samples and ``n_mujoco`` cross-checked ones [s].

    ``workers`` share the samples evenly (:data:`SAMPLE_WORKER_SECONDS` per sample and worker); each
    cross-checked sample also runs its twin's reading spread. Returns ``{"twin", "mujoco", "total"}``,
    the MuJoCo share including that spread.
    """
    w = max(1, int(workers))
    twin = n_twin * SAMPLE_WORKER_SECONDS["twin"] / w
    mujoco = n_mujoco * (SAMPLE_WORKER_SECONDS["mujoco"] + SAMPLE_WORKER_SECONDS[SPREAD_ENGINE]) / w
    return {"twin": twin, "mujoco": mujoco, "total": twin + mujoco}


def check_sample_count(n: int, crosscheck: int, workers: int | None) -> None:
    """Refuse ``--n`` above :data:`MAX_SAMPLES`, stating the time it would take (``ValueError`` naming ``--n``)."""
    if n > MAX_SAMPLES:
        from nanosim.pipeline.scaleout import cpu_workers

        w = workers or cpu_workers()
        est = estimate_seconds(n, min(crosscheck, n), w)["total"]
        raise ValueError(f"--n: expected at most {MAX_SAMPLES} samples, got {n} (about {format_duration(est)} on "
                         f"{w} worker(s)); split the population into folders with other --seed values")


# ------------------------------------------------------------------------------ worker side
def _controller_config(d: dict):
    from nanosim.design.controller import ControllerConfig

    return ControllerConfig(np.asarray(d["Akd"]), np.asarray(d["Bkd"]), np.asarray(d["Ckd"]), np.asarray(d["Dkd"]),
                            float(d["dt"]), d.get("n_error"))


def _loop_figures(twin_piezo, ctrl, electronics) -> dict:
    """Closed-loop stability and the worst multiloop disk margin on the sample's twin (loop as run).

    ``twin_piezo`` carries one piezo slope (:func:`_loop_figures_over_gain` calls it at both ends) and the bench
    electronics go around it (amplifier lag, gauge filter, computation delay), as ``robustness.json``'s twin.
    """
    from nanosim.design.robustness import (LoopPlant, closed_loop_poles, controller_systems, disk_margins,
                                           stage_grid_hz)

    plant = LoopPlant.twin(twin_piezo.sysd_V, electronics)
    K, Ky = controller_systems(ctrl)
    poles = closed_loop_poles(plant.G, K, Ky, plant.delay_samples)
    rho = float(np.max(np.abs(poles))) if poles.size else 0.0
    out = {"closed_loop_stable": bool(rho < 1.0), "spectral_radius": rho}
    f = stage_grid_hz(plant, K, Ky, n=300)
    rep = disk_margins(plant.G, K, f, Ky, delay_samples=plant.delay_samples, refine=False, input_output_only=True)
    w = rep.worst()
    out.update({"disk_margin_alpha": float(w.alpha), "disk_margin_freq_hz": float(w.freq_hz),
                "gain_margin_db": float(w.gain_margin_db[1]), "phase_margin_deg": float(w.phase_margin_deg),
                "disk_margin_location": w.location})
    return out


def _loop_figures_over_gain(twin_post_reversal, twin_nominal, ctrl, electronics) -> dict:
    """:func:`_loop_figures` at both ends of the piezo's gain range, the slope after a reversal (the piezo's
    small-signal gain) and nominal (a monotone move; the linear piezo): the worst end's figures, each end's margin
    (``disk_margin_alpha_post_reversal``, ``disk_margin_alpha_nominal``) and stability at both.
    """
    lo = _loop_figures(twin_post_reversal, ctrl, electronics)
    hi = _loop_figures(twin_nominal, ctrl, electronics)
    out = dict(min(lo, hi, key=lambda r: r["disk_margin_alpha"]))
    out.update({"closed_loop_stable": lo["closed_loop_stable"] and hi["closed_loop_stable"],
                "spectral_radius": max(lo["spectral_radius"], hi["spectral_radius"]),
                "disk_margin_alpha_post_reversal": lo["disk_margin_alpha"],
                "disk_margin_alpha_nominal": hi["disk_margin_alpha"]})
    return out


def sample_plants(indices, seed: int, ctrl=None, mjcf=None, with_loop: bool = True):
    """Models, member plants and plant-level records (modes, gain, loop figures) of samples ``indices``."""
    from nanosim.experiments.batch_suite import MemberPlant
    from nanosim.plant.linearize import linearize
    from nanosim.plant.runplant import RunPlant
    from nanosim.plant.mjcf import load_model
    from nanosim.plant.modes import modal_analysis
    from nanosim.plant.stage import Stage
    from nanosim.plant.tolerances import default_tolerances, sample_model

    tm = default_tolerances(load_model(mjcf))
    plants, records = [], []
    for i in indices:
        values = tm.sample(seed, i)
        model = sample_model(values, tm, mjcf)
        modes = modal_analysis(model)
        f = [m.freq_hz for m in modes.below(1000.0)]
        z = [m.damping_ratio for m in modes.below(1000.0)]
        G0 = modes.static_gain_um_per_V
        twin = RunPlant.of_model(model).twin
        rec = {"index": int(i), "tolerances": values, "modes_hz": f, "damping_ratio": z,
               "static_gain_um_per_V": G0.tolist(),
               "xy_split_percent": 100.0 * (f[1] - f[0]) / (0.5 * (f[1] + f[0])) if len(f) > 1 else math.nan}
        stage = Stage(model=model)
        if with_loop and ctrl is not None:
            rec.update(_loop_figures_over_gain(linearize(stage, include_piezo=True), twin, ctrl,
                                               stage.config.electronics))
        home = stage.table_um.copy()
        plants.append(MemberPlant(twin=twin, model=model, home_um=home, static_gain_um_per_V=G0))
        records.append(rec)
    return plants, records, tm


def run_chunk(plan: dict, indices: list, engine: str, sink) -> list[dict]:
    """Worker task: samples ``indices`` (plant records and experiments on ``engine``); JSON-ready records.

    ``engine`` ``"twin"`` or ``"mujoco"``: each sample's experiments; :data:`SPREAD_ENGINE`: each sample's twin
    at every :func:`mc_stats.spread_gain_factors`, all in one batch, and per sample the
    :func:`mc_stats.reading_spread` of the flat metrics. Each record's ``seconds`` (the chunk's wall time per
    sample) is moved to ``timings.json`` by the driver.
    """
    from nanosim import experiments
    from nanosim.design.lti import single_threaded_blas
    from nanosim.experiments.batch_suite import run_experiments_batch
    from nanosim.plant.batch import TwinMatrices

    t0 = time.perf_counter()
    experiments.load_builtin()
    ctrl = _controller_config(plan["controller"])
    spread = engine == SPREAD_ENGINE
    factors = mc_stats.spread_gain_factors() if spread else None
    with single_threaded_blas():
        plants, records, _ = sample_plants(indices, plan["seed"], ctrl, plan.get("mjcf"), with_loop=engine == "twin")
        sink.put(len(indices))
        members = ([dataclasses.replace(p, twin=TwinMatrices.of(p.twin).input_scaled(f)) for p in plants
                    for f in factors] if spread else plants)
        # exact products: a sample's numbers do not depend on which samples share its batch (chunking,
        # executor, resumed runs)
        metrics, _ = run_experiments_batch(plan["experiments"], members, ctrl, engine="twin" if spread else engine,
                                           seed=plan["seed"], exact=True, nthread=1,
                                           progress=lambda name: sink.put(len(indices)))
    dt = (time.perf_counter() - t0) / max(1, len(indices))
    if spread:
        k = len(factors)
        return [{"index": int(i), "engine": SPREAD_ENGINE, "input_gain_factors": factors.tolist(),
                 "spread": mc_stats.reading_spread([mc_stats.flatten_metrics(m) for m in metrics[j * k:(j + 1) * k]]),
                 "seconds": dt} for j, i in enumerate(indices)]
    out = []
    for rec, met in zip(records, metrics):
        rec.update(engine=engine, metrics=met, seconds=dt)
        out.append(rec if engine == "twin" else {k: rec[k] for k in ("index", "engine", "metrics", "seconds")})
    return out


# ------------------------------------------------------------------------------ driver side
def sample_units(tm, engine: str) -> dict:
    """The ``units`` entry of a sample record: the tolerances' from the tolerance model ``tm``, the metrics'
    (``metrics.json``'s suffixes) and, for the linear-twin records, the plant-level figures'.
    """
    from nanosim.pipeline.characterize import METRICS_UNITS

    by_kind: dict = {}
    for t in tm.tolerances:
        by_kind.setdefault(t.name.partition(".")[0], {})[t.name] = "dimensionless factor" if t.unit == "-" else t.unit
    tol = {}
    for kind, units in by_kind.items():
        if len(set(units.values())) == 1 and (len(units) > 1 or kind not in units):
            tol[f"{kind}.*"] = next(iter(units.values()))
        else:
            tol.update(units)
    out = {"metrics": dict(METRICS_UNITS)}
    if engine == SPREAD_ENGINE:
        return {"spread": "per flat metric (the names of summary.json's cross-check): min, max, mean and std in the "
                          "metric's unit (metrics), n the count", "metrics": out["metrics"],
                "input_gain_factors": "dimensionless factor on the twin's input gain"}
    if engine == "twin":
        out = {"tolerances": tol, **out, "modes_hz, *_freq_hz": "Hz", "damping_ratio": "damping ratio",
               "static_gain_um_per_V": "um per controller V", "xy_split_percent": "%",
               "spectral_radius": "|z| of the closed-loop poles",
               "disk_margin_alpha": "disk-margin alpha, dimensionless (as robustness.json's *_alpha), the worse of "
                                    "the piezo's two ends (*_post_reversal, *_nominal)",
               "disk_margin_alpha_post_reversal, disk_margin_alpha_nominal": "disk-margin alpha, dimensionless",
               "gain_margin_db": "dB", "phase_margin_deg": "degrees"}
    return out


def _sample_path(out: Path, sub: str, i: int) -> Path:
    return out / sub / A.mc_sample_json(i)


def montecarlo_plan(controller_path: Path, s: MonteCarloConfig, names, tm_dict) -> dict:
    """The plan of a Monte Carlo: what every worker needs (:func:`run_chunk`) and the identity of the run.

    The ``identity`` (seed, SHA-256 of the controller file, of the MJCF or ``"bundled"``, the experiment list
    and the SHA-256 of the tolerance set) is written into ``montecarlo.json``; a rerun into the same folder
    resumes only when its identity is the same, so samples of two different runs never mix.

    Parameters
    ----------
    controller_path : path
        ``controller.npz`` (read and checked; its matrices go into the plan).
    s : MonteCarloConfig
        Its ``seed`` and ``mjcf`` are used.
    names : sequence of str
        The registered experiments each sample runs.
    tm_dict : dict
        The tolerance set (:meth:`nanosim.plant.tolerances.ToleranceModel.to_dict`).

    Returns
    -------
    dict
        ``identity``, ``seed``, ``experiments``, ``mjcf`` and ``controller`` (its discrete matrices, ``dt`` and
        ``n_error``), JSON-ready.
    """
    from nanosim.design.architectures.protocol import read_controller_file

    c = read_controller_file(controller_path, name="--controller")
    mjcf_sha = sha256_file(Path(s.mjcf)) if s.mjcf else "bundled"
    ident = {"seed": s.seed, "controller_sha256": sha256_file(controller_path), "mjcf": mjcf_sha,
             "experiments": list(names), "tolerances_sha256": hashlib.sha256(
                 json.dumps(tm_dict, sort_keys=True).encode()).hexdigest()}
    return {"identity": ident, "seed": s.seed, "experiments": list(names), "mjcf": str(s.mjcf) if s.mjcf else None,
            "controller": {"Akd": c.Akd, "Bkd": c.Bkd, "Ckd": c.Ckd, "Dkd": c.Dkd, "dt": c.dt, "n_error": c.n_error}}


def _chunks(indices: list, size: int) -> list:
    return [indices[k:k + size] for k in range(0, len(indices), size)]


def _check_out(out: Path, plan: dict) -> None:
    """Refuse an ``out`` holding another Monte Carlo or files that are not one (reads only)."""
    prev = out / A.MONTECARLO_JSON
    if prev.is_file():
        try:
            old = json.loads(prev.read_text()).get("identity")
        except (ValueError, AttributeError):
            old = None
        if old != plan["identity"]:
            raise RunFolderError(f"--out: {str(out)!r} holds a Monte Carlo with another controller, seed, stage "
                                 "or experiment list; choose another folder")
    elif out.is_dir() and any(out.iterdir()):
        raise RunFolderError(f"--out: {str(out)!r} is not empty and holds no Monte Carlo; choose another folder")


def run_montecarlo(controller_path, out, settings: MonteCarloConfig | None = None, *, progress: bool = True,
                   say=None) -> dict:
    """Run (or resume) a Monte Carlo into ``out``; returns ``summary.json``'s content with this run's wall
    times (``timings``, ``wall_seconds``), which go to ``timings.json`` with each sample's ``seconds``.

    Parameters
    ----------
    controller_path : path
        ``controller.npz`` (the one controller of every sample).
    out : path
        Run folder (created; a rerun resumes it).
    settings : MonteCarloConfig
    progress : bool
        Progress bar (stderr) aggregated over the workers.
    say : callable, optional
        One-line status messages (default: stderr).
    """
    settings = settings or MonteCarloConfig()
    from nanosim import experiments
    from nanosim.plant.mjcf import load_model
    from nanosim.plant.tolerances import default_tolerances

    say = say or (lambda msg: print(f"  {msg}", file=sys.stderr, flush=True))
    controller_path = Path(controller_path).resolve()
    known = experiments.load_builtin()
    spec = mc_stats.load_spec(settings.spec) if settings.spec else mc_stats.default_spec()
    names = list(settings.experiments or known)
    bad = [n for n in names if n not in known]
    if bad:
        raise ValueError(f"experiments: unknown {bad[0]!r}; expected some of {list(known)}")
    check_scheduler(settings.scheduler)                     # its form, before anything is written
    out = check_writable(out).resolve()
    tm = default_tolerances(load_model(settings.mjcf))
    plan = montecarlo_plan(controller_path, settings, names, tm.to_dict())
    _check_out(out, plan)
    n_cross = min(settings.crosscheck, settings.n)
    phases = ((A.MC_SAMPLES_DIR, "twin", settings.n), (A.MC_CROSSCHECK_DIR, "mujoco", n_cross),
              (A.MC_SPREAD_DIR, SPREAD_ENGINE, n_cross))

    def todo_of(sub, count):
        return [i for i in range(count) if not _sample_path(out, sub, i).is_file()]

    check_sample_count(settings.n, settings.crosscheck, settings.workers)
    n_twin, n_mj = len(todo_of(A.MC_SAMPLES_DIR, settings.n)), len(todo_of(A.MC_CROSSCHECK_DIR, n_cross))

    def announce():
        """The estimate, on the first line (after a scheduler answered, so that its error stays one line)."""
        if not (n_twin or n_mj):
            return
        from nanosim.pipeline.scaleout import cpu_workers

        w = settings.workers or (cpu_workers() if settings.scheduler is None else None)
        est = estimate_seconds(n_twin, n_mj, w or 1)
        on = f"{w} worker(s)" if w else "1 worker (divide by the cluster's workers)"
        say(f"montecarlo: {n_twin} linear-twin samples and {n_mj} MuJoCo cross-checks to run, about "
            f"{format_duration(est['total'])} on {on}, {format_duration(est['mujoco'])} of it the MuJoCo "
            f"cross-check (--crosscheck 0 skips it); Ctrl-C or SIGTERM keeps every finished sample, a rerun "
            "resumes")

    if settings.scheduler is None:
        announce()

    t_start = time.perf_counter()
    with contextlib.ExitStack() as stack:
        # connect (Dask) or start the pool before anything is written: a scheduler that does not answer
        # leaves --out as it was; a sealed folder keeps its manifest until the work starts
        scale = (stack.enter_context(open_executor(settings.scheduler, settings.workers))
                 if any(todo_of(sub, count) for sub, _, count in phases) else None)
        if settings.scheduler is not None:
            announce()
        stack.enter_context(writer_lock(out))
        _check_out(out, plan)                               # again under the lock
        out.mkdir(exist_ok=True)
        # the work starts: a folder being changed is no longer sealed (a rerun resumes it, skipping the
        # finished samples, and seals it again)
        (out / MANIFEST_JSON).unlink(missing_ok=True)
        write_json(out / A.MONTECARLO_JSON, {"identity": plan["identity"], "n": settings.n, "mjcf": plan["mjcf"],
                                     "experiments": names, "engine": "linear twin, every effect on",
                                     "crosscheck_engine": "MuJoCo, every effect on"})
        write_json(out / A.TOLERANCES_JSON, tm.to_dict())
        write_json(out / A.SPEC_JSON, spec)
        timings = {}
        for sub, engine, count in phases:
            todo = todo_of(sub, count)
            t0 = time.perf_counter()
            if todo:
                if scale is None:
                    scale = stack.enter_context(open_executor(settings.scheduler, settings.workers))
                size = settings.chunk or max(1, min(64, math.ceil(len(todo) / (2 * scale.workers))))
                if engine != "twin":
                    size = settings.chunk or max(1, math.ceil(len(todo) / scale.workers))
                say(f"{len(todo)} of {count} {engine} samples to run ({count - len(todo)} done) on "
                    f"{scale.description}, chunks of {size}")
                units = len(names) + 1

                rec_units = sample_units(tm, engine)
                seconds: dict = {}

                def done(task, records, sub=sub, rec_units=rec_units, seconds=seconds):
                    for rec in records:
                        path = _sample_path(out, sub, rec["index"])
                        seconds[f"{sub}/{path.name}"] = {"seconds": rec.pop("seconds", None)}
                        write_json(path, {**rec, "units": rec_units})

                try:
                    run_tasks(scale, run_chunk, [(plan, c, engine) for c in _chunks(todo, size)], done,
                              total_units=count * units, done_units=(count - len(todo)) * units,
                              desc=f"montecarlo {engine}", progress=progress)
                finally:                    # the finished samples' times too when interrupted
                    if seconds:
                        record_timings(out, seconds)
            key = engine.replace("-", "_")
            timings[f"{key}_seconds"] = round(time.perf_counter() - t0, 2)
            timings[f"{key}_samples_run"] = len(todo)
        summary = summarize(out, settings, spec, names, tm)
        write_json(out / A.SUMMARY_JSON, summary)
        wall = {"timings": timings, "wall_seconds": round(time.perf_counter() - t_start, 2)}
        record_timings(out, {A.SUMMARY_JSON: wall})
        write_text(out / A.REPORT_MD, report_markdown(summary))
        write_manifest(out, seed=settings.seed)
    return {**summary, **wall}


def _load(out: Path, sub: str, n: int) -> list[dict]:
    return [json.loads(_sample_path(out, sub, i).read_text()) for i in range(n) if _sample_path(out, sub, i).is_file()]


def load_sample_flats(out: Path, n: int) -> list[dict]:
    """The flat records (metrics and plant-level figures) of the twin samples ``0 ... n-1`` found in ``out``."""
    return [_flat(r) for r in _load(Path(out), A.MC_SAMPLES_DIR, n)]


def _flat(rec: dict) -> dict:
    flat = mc_stats.flatten_metrics(rec.get("metrics", {}))
    for k in ("closed_loop_stable", "disk_margin_alpha", "disk_margin_alpha_post_reversal", "disk_margin_alpha_nominal",
              "gain_margin_db", "phase_margin_deg", "xy_split_percent"):
        if k in rec:
            flat[k] = float(rec[k])
    for j, f in enumerate(rec.get("modes_hz", [])[:6]):
        flat[f"mode_{j + 1}_hz"] = float(f)
    return flat


def summarize(out: Path, settings: MonteCarloConfig, spec: dict, names, tm) -> dict:
    """Yield, worst cases, sensitivity and cross-check from the sample files; writes the figures."""
    from nanosim.plots.montecarlo import fig_crosscheck, fig_histograms, fig_sensitivity

    recs = _load(out, A.MC_SAMPLES_DIR, settings.n)
    idx = [r["index"] for r in recs]
    flats = [_flat(r) for r in recs]
    table = mc_stats.yield_table(flats, spec)
    worst = mc_stats.worst_cases(idx, flats, spec)
    X = np.array([tm.normalized(r["tolerances"]) for r in recs]) if recs else np.zeros((0, len(tm.names)))
    groups = [t.group for t in tm.tolerances]
    sens_metrics = [lim["metric"] for lim in spec["limits"] if lim["metric"] != "closed_loop_stable"]
    sens = mc_stats.sensitivity(X, list(tm.names), groups, flats, sens_metrics + list(SENSITIVITY_EXTRA))
    cross = []
    n_cross = min(settings.crosscheck, settings.n)
    spreads = {r["index"]: r["spread"] for r in _load(out, A.MC_SPREAD_DIR, n_cross)}
    for rec in _load(out, A.MC_CROSSCHECK_DIR, n_cross):
        twin = next((f for r, f in zip(recs, flats) if r["index"] == rec["index"]), None)
        if twin is not None:
            c = mc_stats.compare_crosscheck(twin, mc_stats.flatten_metrics(rec["metrics"]),
                                            spread=spreads.get(rec["index"]))
            c["sample"] = rec["index"]
            cross.append(c)
    errors = {r["index"]: r["metrics"]["errors"] for r in recs if r.get("metrics", {}).get("errors")}
    summary = {"n": len(recs), "seed": settings.seed, "experiments": list(names), "yield": table,
               "worst_cases": worst, "sensitivity": sens, "crosscheck": cross,
               "crosscheck_pass": sum(c["all_ok"] for c in cross), "crosscheck_n": len(cross),
               "crosscheck_pass_relative_only": sum(c["all_ok_relative"] for c in cross),
               "crosscheck_rule": (f"every metric within {100 * mc_stats.CROSSCHECK_REL_TOL:g} % of the twin's, or "
                                   "within its reading resolution (crosscheck_resolution) of the twin's reading or "
                                   "of the range of the twin's readings at indistinguishable physics "
                                   "(crosscheck_spread)"),
               "crosscheck_resolution": dict(mc_stats.CROSSCHECK_RESOLUTION),
               "crosscheck_spread": {"input_gain_factors": mc_stats.spread_gain_factors().tolist(),
                                     "folder": A.MC_SPREAD_DIR},
               "crosscheck_pass_without_spread": sum(c["all_ok_without_spread"] for c in cross),
               "crosscheck_bias": mc_stats.crosscheck_bias(cross),
               "crosscheck_max_rel_diff": max((r["rel_diff"] for c in cross for r in c["metrics"].values()),
                                              default=None),
               "errors": errors}
    if recs:
        save_figure(fig_histograms(flats, spec), out / A.FIG_MC_HISTOGRAMS)
        if sens:
            save_figure(fig_sensitivity(sens), out / A.FIG_MC_SENSITIVITY)
        if cross:
            save_figure(fig_crosscheck(cross, 100 * mc_stats.CROSSCHECK_REL_TOL), out / A.FIG_MC_CROSSCHECK)
    return summary


def _fmt(v) -> str:
    if v is None or (isinstance(v, float) and not math.isfinite(v)):
        return "n/a"
    return f"{v:.4g}" if isinstance(v, float) else str(v)


def report_markdown(summary: dict) -> str:
    """``report.md`` of a Monte Carlo folder."""
    lines = [f"# Monte Carlo: {summary['n']} fabricated stages (seed {summary['seed']})", "",
             f"Tolerances: `{A.TOLERANCES_JSON}` (per-notch thickness and radius, link width, target mass, piezo gain;"
             " each with its distribution and source). Experiments on each sample's linear twin, every effect on.",
             "", f"## Yield against the spec (`{A.SPEC_JSON}`)", "",
             "| limit | metric | bound | unit | pass | yield | 95 % CI | median | worst |",
             "|---|---|---|---|---|---|---|---|---|"]
    for r in summary["yield"]:
        bound = " ".join(x for x in ((f">= {r['min']:g}" if r.get("min") is not None else ""),
                                     (f"<= {r['max']:g}" if r.get("max") is not None else "")) if x)
        ci = r["ci95_percent"]
        lines.append(f"| {r['label']} | `{r['metric']}` | {bound} | {r['unit']} | {r['pass']}/{r['n']} | "
                     f"{_fmt(r['yield_percent'])} % | {_fmt(ci[0])}-{_fmt(ci[1])} % | {_fmt(r.get('median'))} | "
                     f"{_fmt(r.get('worst'))} |")
    lines += ["", "## Worst cases", "", "| metric | samples (value) |", "|---|---|"]
    for m, rows in summary["worst_cases"].items():
        lines.append(f"| `{m}` | " + ", ".join(f"#{r['sample']} ({_fmt(r['value'])})" for r in rows) + " |")
    lines += ["", "## Sensitivity (adjusted R^2 of each tolerance group alone; top variables by Spearman rho)", "",
              "| metric | groups (adj. R^2) | top variables (rho) |", "|---|---|---|"]
    for m, s in summary["sensitivity"].items():
        g = ", ".join(f"{d['group']} ({_fmt(d['adjusted_r2'])})" for d in s["groups"][:3])
        v = ", ".join(f"{d['name']} ({d['spearman_rho']:+.2f})" for d in s["top_variables"][:3])
        lines.append(f"| `{m}` | {g} | {v} |")
    tol = 100 * mc_stats.CROSSCHECK_REL_TOL
    factors = summary.get("crosscheck_spread", {}).get("input_gain_factors") or [1.0]
    ppm = 1e6 * max(abs(f - 1) for f in factors)
    lines += ["", f"## MuJoCo cross-check ({summary['crosscheck_pass']} of {summary['crosscheck_n']} samples with "
              f"every metric agreeing; {summary.get('crosscheck_pass_without_spread', 0)} without the twin's spread, "
              f"{summary.get('crosscheck_pass_relative_only', 0)} within {tol:g} % alone)", "",
              f"A MuJoCo metric agrees with the twin's when it is within {tol:g} % of it, or within the metric's "
              "reading resolution of it or of the range of the twin's readings at indistinguishable physics: "
              f"{len(factors)} runs of the sample's twin with its input gain changed by 0-{ppm:.3g} ppm "
              f"(`{A.MC_SPREAD_DIR}/`). Quantized DAC and ADC readings turn such a change into a different count "
              "here and there, and the loop carries it on, so a metric read off one sample (the step's peak) "
              "spreads over several counts at the same physics.", "",
              f"Resolution ({mc_stats.READING_QUANTA_PER_METRIC} ADC counts, or {mc_stats.READING_QUANTA_PER_METRIC} "
              "control periods for a time read between samples: each metric is a difference of two readings or "
              "instants, each rounded to one quantum): " +
              ", ".join(f"`{m}` {_fmt(q)} {mc_stats.unit_of(m)}" for m, q in mc_stats.CROSSCHECK_RESOLUTION.items()),
              ""]
    if summary["crosscheck"]:
        lines += ["| sample | metrics agreeing | largest relative difference not within the resolution | "
                  "metrics agreeing only through the twin's spread (twin range, MuJoCo) |", "|---|---|---|---|"]
        for c in summary["crosscheck"]:
            judged = {m: r for m, r in c["metrics"].items() if not r.get("within_resolution", False)}
            big = max(judged.items(), key=lambda kv: kv[1]["rel_diff"]) if judged else None
            worst = (f"`{big[0]}` {100 * big[1]['rel_diff']:.2f} % ({_fmt(big[1]['twin'])} vs "
                     f"{_fmt(big[1]['mujoco'])} {mc_stats.unit_of(big[0])})") if big else "none"
            by_spread = [f"`{m}` ({_fmt(r['twin_min'])}-{_fmt(r['twin_max'])}, {_fmt(r['mujoco'])} "
                         f"{mc_stats.unit_of(m)})" for m, r in c["metrics"].items()
                         if r["ok"] and not r["ok_without_spread"]]
            lines.append(f"| #{c['sample']} | {sum(r['ok'] for r in c['metrics'].values())}/{len(c['metrics'])} | "
                         f"{worst} | {', '.join(by_spread) or 'none'} |")
        bias = summary.get("crosscheck_bias") or {}
        if bias:
            lines += ["", "Systematic difference over these samples: MuJoCo minus the mean of the twin's readings at "
                      "indistinguishable physics, mean and standard error (a single sample's spread averages out, "
                      "so a bias far below one sample's resolution shows here).", "",
                      "| metric | mean difference | standard error | unit | mean difference, % of the twin's |",
                      "|---|---|---|---|---|"]
            for m, b in bias.items():
                lines.append(f"| `{m}` | {b['mean_diff']:+.4g} | {_fmt(b['std_err'])} | {mc_stats.unit_of(m)} | "
                             f"{b['mean_diff_percent']:+.3g} |")
    lines += ["", "## Figures", ""]
    for name, fig, present in (("histograms", A.FIG_MC_HISTOGRAMS, summary["n"] > 0),
                               ("sensitivity", A.FIG_MC_SENSITIVITY, bool(summary["sensitivity"])),
                               ("cross-check", A.FIG_MC_CROSSCHECK, bool(summary["crosscheck"]))):
        if present:
            lines += [f"![{name}]({fig})", ""]
    if summary["errors"]:
        lines += ["## Errors", ""] + [f"- sample {i}: {e}" for i, e in summary["errors"].items()]
    return "\n".join(lines) + "\n"
