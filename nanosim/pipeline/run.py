"""``nanosim pipeline`` and the single steps: modes -> identify -> design -> characterize -> report.

Every step writes into a folder it is given; :func:`run_pipeline` and the CLI
give them a staging folder (:func:`nanosim.pipeline.runfolder.staged_run`), so
a run folder is complete or untouched.
"""
from __future__ import annotations

import dataclasses
import gc
import multiprocessing
import os
import sys
import threading
import time
from pathlib import Path

import numpy as np

from nanosim.fileio import save_figure, write_json, write_npz
from nanosim.pipeline import artifacts as A
from nanosim.pipeline.config import CharacterizeConfig, DesignConfig, IdentifyConfig, PipelineConfig

__all__ = ["step_modes", "write_twin_npz", "step_identify", "step_design", "step_characterize", "step_report",
           "PIPELINE_STEPS", "run_pipeline", "characterize_batch", "modes_task", "design_task", "spawn_pool",
           "stop_pool", "wait_result", "experiment_specs", "experiment_jobs", "experiments_names", "file_digest",
           "compensation_specs", "compensation_jobs", "write_compensation_results"]


def step_modes(out: Path, mjcf=None) -> None:
    """``modes.json`` and one mode-shape PNG per mode below 1 kHz in ``modes/``."""
    from nanosim.plant.mjcf import load_model
    from nanosim.plant.modes import modal_analysis, modes_json
    from nanosim.plots.modes import mode_shape_figures

    model = load_model(mjcf)
    write_json(out / A.MODES_JSON, modes_json(model))
    for name, fig in mode_shape_figures(model, modal_analysis(model)):
        save_figure(fig, out / A.MODES_DIR / name)


def write_twin_npz(out: Path, mjcf=None) -> Path:
    """``twin.npz`` (and ``twin.mat``): MuJoCo's linearization of the ideal stage (controller V -> sensor V)."""
    from nanosim.plant.runplant import RunPlant

    from nanosim.pipeline.identify import save_model_mat

    tw = RunPlant.load(mjcf).twin
    s = tw.sys_V
    save_model_mat((out / A.TWIN_NPZ).with_suffix(".mat"), tw.sysd_V, s, ("A", "B", "C"), ("X", "Y", "Z"),
                   "controller V -> sensor V (5 um/V); ideal MuJoCo stage, linear piezo")
    return write_npz(out / A.TWIN_NPZ, A=s.A, B=s.B, C=s.C, D=s.D, Ad=tw.sysd_V.A, Bd=tw.sysd_V.B,
                     Cd=tw.sysd_V.C, Dd=tw.sysd_V.D, dt=tw.dt_s,
                     units=np.array("controller V -> sensor V (5 um/V); ideal MuJoCo stage, linear piezo"))


def step_identify(out: Path, config: IdentifyConfig, mjcf=None, progress=None, on_model=None) -> None:
    """Identify the stage (``model.npz``, ``identify.json``, Figs. 4-7) into ``out``.

    ``on_model(path)`` is called once ``model.npz`` is written (see :func:`run_identify`).
    """
    from nanosim.pipeline.identify import run_identify
    from nanosim.plant.mjcf import load_model
    from nanosim.plant.runplant import RunPlant

    model = load_model(mjcf)
    twin = RunPlant.of_model(model).twin
    run_identify(out, config, model=model, twin=twin, progress=progress, on_model=on_model)


def step_design(out: Path, config: DesignConfig, model_npz=None, mjcf=None) -> None:
    """Reduce, design and discretize from ``model_npz`` (default ``out/model.npz``) into ``out``."""
    from nanosim.pipeline.design import run_design

    run_design(model_npz or out / A.MODEL_NPZ, out, config, twin=str(write_twin_npz(out, mjcf)), progress=False)


def step_characterize(out: Path, config: CharacterizeConfig, controller_npz=None, mjcf=None) -> None:
    """Run the registered experiments with ``controller_npz`` (default ``out/controller.npz``)."""
    from nanosim.pipeline.characterize import run_characterize

    run_characterize(controller_npz or out / A.CONTROLLER_NPZ, out, config, mjcf=mjcf, progress=True)


def step_report(out: Path) -> None:
    """Write ``report.md`` and ``report.html`` from the run folder's files."""
    from nanosim.pipeline.report import write_report

    write_report(out)


PIPELINE_STEPS = ("modes", "identify", "design", "characterize", "characterize_twin", "compensation", "budget",
                  "report")


def _daemon_map(fn, items, workers: int):
    """``[fn(x) for x in items]`` on ``workers`` daemon threads: Ctrl-C returns at once (a
    ``ThreadPoolExecutor`` would wait for the running tasks), as ``run_characterize`` does.
    """
    todo, results, errors = list(items), {}, []
    lock = threading.Lock()

    def work():
        while not errors:
            with lock:
                if not todo:
                    return
                i = len(items) - len(todo)
                x = todo.pop(0)
            try:
                results[i] = fn(x)
            except BaseException as exc:  # noqa: BLE001  (handed to the calling thread)
                errors.append(exc)

    threads = [threading.Thread(target=work, daemon=True, name=f"characterize-{k}") for k in range(max(1, workers))]
    for t in threads:
        t.start()
    for t in threads:
        while t.is_alive():
            t.join(0.2)
    if errors:
        raise errors[0]
    return [results[i] for i in range(len(items))]


def characterize_batch(controller_npz, out_dir, seed: int, mjcf=None, *, twin: bool = False,
                       workers: int = 1) -> dict:
    """``nanosim characterize`` (``--twin``) on the batch engine: one member, compiled electronics.

    The same experiments, stage, controller and seed as
    :func:`~nanosim.pipeline.characterize.run_characterize`, each run by
    :func:`~nanosim.experiments.batch_suite.run_experiments_batch` with exact products, which
    gives the single-stage numbers bit for bit (``tests/test_batch.py``, ``tests/test_batch_kernel.py``);
    writes the same ``metrics.json`` and figures into ``out_dir`` (the wall times into its
    ``timings.json``). The MuJoCo member steps with one compiled call for its electronics per
    period instead of a dozen numpy calls; the twin runs in the compiled loop. ``workers``
    experiments run side by side (threads; MuJoCo steps without the GIL).
    """
    from nanosim import constants as C
    from nanosim import experiments
    from nanosim.design.controller import DiscreteController
    from nanosim.design.architectures.protocol import read_controller_file
    from nanosim.experiments.batch_suite import MemberPlant, run_experiments_batch
    from nanosim.experiments.registry import ExperimentContext
    from nanosim.fileio import save_figure
    from nanosim.pipeline.characterize import make_plant_factory, write_metrics
    from nanosim.plant.modes import modal_analysis

    out = Path(out_dir)
    names = list(experiments.load_builtin())
    ctrl = DiscreteController(read_controller_file(controller_npz, dt=C.CONTROL_PERIOD_S))
    factory, base, run_plant = make_plant_factory(twin, mjcf=mjcf)
    G0 = modal_analysis(base.model).static_gain_um_per_V if "creep" in names else None
    plant = MemberPlant(twin=run_plant.twin if twin else None,
                        model=base.model, home_um=base.table_um.copy(), static_gain_um_per_V=G0, base_stage=base)

    def one(name):
        t0 = time.perf_counter()
        (met,), (res,) = run_experiments_batch([name], [plant], ctrl.config, engine="twin" if twin else "mujoco",
                                               seed=seed, exact=True, nthread=1)
        return name, met, res, round(time.perf_counter() - t0, 2)

    order = sorted(names, key=lambda n: -experiments.get(n).cost)
    done = {name: (met, res, sec) for name, met, res, sec in _daemon_map(one, order, workers)}
    metrics, seconds = {}, {}
    ctx = ExperimentContext(factory=factory, controller=DiscreteController(ctrl.config), seed=seed,
                            static_gain_um_per_V=G0, base_stage=base)
    for name in names:                   # registry order, as run_characterize
        met, res, seconds[name] = done[name]
        if "errors" in met:
            raise RuntimeError(f"characterize: experiment {name!r} failed: {met['errors'][name]}")
        metrics.update(met)
        exp = experiments.get(name)
        if exp.figure is not None and exp.figure_name:
            save_figure(exp.figure(res[name], ctx), out / exp.figure_name)
    write_metrics(out, metrics, twin=twin, seed=seed, seconds=seconds)
    return metrics


def modes_task(out: str, mjcf) -> float:
    """``step_modes`` as a pool task; returns its wall time [s]."""
    t0 = time.perf_counter()
    step_modes(Path(out), mjcf)
    return round(time.perf_counter() - t0, 2)


def design_task(out: str, config: DesignConfig, mjcf, controller_ready=None) -> float:
    """``step_design`` as a pool task; returns its wall time [s].

    ``controller_ready`` (an ``Event``, e.g. a manager's): set when the design starts its
    robustness analysis (:func:`nanosim.pipeline.design.write_robustness`), which analyses the
    final ``controller.npz``; the figures and the analysis are then still to come. The caller
    checks that ``controller.npz`` did not change after that (:func:`file_digest`).
    """
    from nanosim.pipeline import design as D

    original = D.write_robustness

    def signalling(*args, **kwargs):
        controller_ready.set()
        return original(*args, **kwargs)

    if controller_ready is not None:
        D.write_robustness = signalling
    t0 = time.perf_counter()
    try:
        step_design(Path(out), config, mjcf=mjcf)
    finally:
        D.write_robustness = original
    return round(time.perf_counter() - t0, 2)


def file_digest(path) -> str:
    """SHA-256 of a file's bytes."""
    import hashlib

    return hashlib.sha256(Path(path).read_bytes()).hexdigest()


def spawn_pool(workers: int):
    """A ``spawn`` process pool whose workers leave Ctrl-C to the main process and end with it
    (:func:`nanosim.pipeline.workers.worker_init`).
    """
    from nanosim.pipeline.workers import worker_init

    return multiprocessing.get_context("spawn").Pool(max(1, workers), initializer=worker_init)


def stop_pool(pool) -> None:
    """Stop a pool's workers now (Ctrl-C or a failed task): do not wait for their running tasks.

    The caller drops its references to the pool and its jobs, then calls ``gc.collect()``, so the
    pool's semaphores are released before the CLI leaves (it may leave through ``os._exit``).
    """
    pool.terminate()
    pool.join()


def wait_result(job):
    """``job.get()`` of an ``AsyncResult``, waiting in short slices so that Ctrl-C is seen at once."""
    while not job.ready():
        job.wait(0.2)
    return job.get()


def experiment_specs(run_dir: Path, seed: int, mjcf, *, twin_too: bool = True) -> list:
    """Every registered experiment of one run folder as a task, the longest first.

    One task per experiment and plant (MuJoCo, and the linear twin with ``twin_too``), each
    :func:`~nanosim.pipeline.characterize.experiment_task` (the batch engine, one member, the
    numbers of ``characterize_batch``). Returns ``[(cost, twin, name, fn, args), ...]``.
    """
    from nanosim import experiments
    from nanosim.pipeline.characterize import experiment_task

    names = list(experiments.load_builtin())
    todo = [(experiments.get(n).cost * (0.3 if tw else 1.0), tw, n) for tw in ((False, True) if twin_too else (False,))
            for n in names]
    todo.sort(key=lambda t: -t[0])                # the twin runs about 3x faster than MuJoCo
    ctrl = str(Path(run_dir) / A.CONTROLLER_NPZ)
    mj = None if mjcf is None else str(mjcf)
    return [(c, tw, n, experiment_task, (ctrl, str(Path(run_dir) / (A.TWIN_DIR if tw else "")), n, seed, mj, tw))
            for c, tw, n in todo]


def experiment_jobs(pool, run_dir: Path, seed: int, mjcf, *, twin_too: bool = True) -> list:
    """Submit :func:`experiment_specs` to ``pool``, the longest first; returns ``[(twin, name, job), ...]``."""
    return [(tw, n, pool.apply_async(fn, args)) for _, tw, n, fn, args in
            experiment_specs(run_dir, seed, mjcf, twin_too=twin_too)]


def compensation_specs(run_dir: Path, seed: int, mjcf) -> list:
    """The hysteresis-compensation cases (:mod:`nanosim.pipeline.compensation`) of ``run_dir``'s controller
    as tasks, one per case: ``[(fn, args), ...]``.
    """
    from nanosim.pipeline.compensation import CASES, compensation_task

    ctrl = str(Path(run_dir) / A.CONTROLLER_NPZ)
    mj = None if mjcf is None else str(mjcf)
    return [(compensation_task, (ctrl, key, seed, mj)) for key, *_ in CASES]


def compensation_jobs(pool, run_dir: Path, seed: int, mjcf) -> list:
    """Submit :func:`compensation_specs` to ``pool``; returns their ``AsyncResult`` s."""
    return [pool.apply_async(fn, args) for fn, args in compensation_specs(run_dir, seed, mjcf)]


def step_budget(run_dir: Path, mjcf=None) -> None:
    """The analytic noise budget of the run's exported controller on X (:func:`nanosim.pipeline.budget.run_budget`:
    ``budget.json``, ``budget.npz`` and its figures; the report's "Noise budget, analytic" section).
    """
    from nanosim.pipeline.budget import run_budget

    run_budget(run_dir, Path(run_dir) / A.CONTROLLER_NPZ, axis=0, mjcf=mjcf)


def write_compensation_results(run_dir: Path, results: list, seed: int) -> float:
    """Write the cases of :func:`compensation_jobs` (``[(case, seconds), ...]``) into ``run_dir``
    (``compensation.json`` and its figure); their seconds go to its ``timings.json``. Returns the step's
    wall time [s]: the cases' seconds (summed: the cost the step adds) and the writing.
    """
    from nanosim.pipeline.compensation import write_compensation
    from nanosim.pipeline.timings import record_timings

    t0 = time.perf_counter()
    write_compensation(run_dir, [case for case, _ in results], seed=seed)
    seconds = {case.key: sec for case, sec in results}
    seconds["write"] = round(time.perf_counter() - t0, 2)
    record_timings(run_dir, {A.COMPENSATION_JSON: {"case_seconds": seconds}})
    return round(sum(seconds.values()), 2)


def experiments_names() -> list:
    """The registered experiments, in registry order."""
    from nanosim import experiments

    return list(experiments.load_builtin())


def run_pipeline(out: Path, config: PipelineConfig | None = None, *, progress: bool = True) -> dict:
    """Run every step into ``out`` (normally a staging folder); returns ``{"stage_seconds": ..., "seed": ...}``.

    ``pipeline.json`` holds the seed; the stage wall times go to ``timings.json`` (under ``pipeline.json``).

    Independent work runs side by side on two worker processes: the modes beside the
    identification, the design as soon as ``model.npz`` exists (beside the second operating
    point's identification), then every experiment of the MuJoCo stage and of the linear twin
    as one task each, the longest first. No experiment is shortened, and each runs the code and
    seed it runs alone (:func:`~nanosim.pipeline.characterize.experiment_task`), so the numbers
    do not depend on the schedule.
    """
    cfg = config or PipelineConfig()
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    ident_cfg = dataclasses.replace(cfg.identify, seed=cfg.seed)
    names = [n for n in PIPELINE_STEPS if n != "characterize_twin" or cfg.characterize_twin_too]
    twin_too = "characterize_twin" in names
    timings: dict[str, float] = {}
    bar = None
    if progress:
        from tqdm import tqdm
        bar = tqdm(total=len(names), desc="nanosim pipeline", unit="step", file=sys.stderr)

    def done(name, seconds, running=None):
        timings[name] = seconds
        if bar:
            bar.update(1)
            if running:
                bar.set_postfix_str(f"running {running}")

    t_start = time.perf_counter()
    mj = cfg.mjcf_arg
    cores = min(2, os.cpu_count() or 1)
    # one worker more than cores: the design's analysis and figures (after controller.npz is final)
    # run beside the first experiments on the other workers
    from nanosim.pipeline.workers import start_manager, stop_deferred, stop_manager

    stopping = threading.Event()           # set while the main thread stops the pool under the launcher thread
    pool = manager = None
    try:
        with stop_deferred():              # Ctrl-C/SIGTERM while the workers start: once they can be stopped
            pool = spawn_pool(cores + 1 if cores > 1 else 1)
        manager = start_manager(multiprocessing.get_context("spawn"))
        ready = manager.Event()
        jobs = {"modes": pool.apply_async(modes_task, (str(out), mj))}
        launched: dict = {}

        def launch_experiments():
            # a thread: the experiments start as soon as the controller is final, while the main
            # thread is still identifying the second operating point
            try:
                while not (ready.is_set() or jobs["design"].ready()):
                    jobs["design"].wait(0.1)
                if jobs["design"].ready() and not jobs["design"].successful():
                    return                    # the main thread raises the design's error
                launched["t0"] = time.perf_counter()
                launched["digest"] = file_digest(out / A.CONTROLLER_NPZ)
                launched["jobs"] = experiment_jobs(pool, out, cfg.seed, mj, twin_too=twin_too)
                launched["compensation"] = compensation_jobs(pool, out, cfg.seed, mj)
            except BaseException as exc:  # noqa: BLE001  (handed to the main thread)
                if not stopping.is_set():     # else the main thread is stopping the pool under this thread
                    launched["error"] = exc

        launcher = threading.Thread(target=launch_experiments, daemon=True, name="launch-experiments")

        def start_design(_path=None):
            jobs["design"] = pool.apply_async(design_task, (str(out), cfg.design, mj, ready))
            launcher.start()

        if bar:
            bar.set_postfix_str("running identify, modes")
        t0 = time.perf_counter()
        step_identify(out, ident_cfg, cfg.mjcf, on_model=start_design)
        done("identify", round(time.perf_counter() - t0, 2), "modes, design")
        if "design" not in jobs:
            start_design()
        done("modes", wait_result(jobs["modes"]), "design")
        while launcher.is_alive():
            launcher.join(0.2)
        if "error" in launched:
            raise launched["error"]
        if "jobs" not in launched:
            jobs["design"].get()          # the design failed: raise its error
        t0, digest, exp_jobs = launched["t0"], launched["digest"], launched["jobs"]
        comp_jobs = launched["compensation"]
        done("design", wait_result(jobs["design"]), "characterize")
        if file_digest(out / A.CONTROLLER_NPZ) != digest:     # not the analysed controller: run them again
            exp_jobs = experiment_jobs(pool, out, cfg.seed, mj, twin_too=twin_too)
            comp_jobs = compensation_jobs(pool, out, cfg.seed, mj)
        parts: dict = {False: {}, True: {}}
        left = {False: len(experiments_names()), True: len(experiments_names()) if twin_too else 0}
        for tw, _, job in exp_jobs:
            name, met, sec = wait_result(job)
            parts[tw][name] = (met, sec)
            left[tw] -= 1
            if left[tw] == 0:
                done("characterize_twin" if tw else "characterize", round(time.perf_counter() - t0, 2))
        comp_results = [wait_result(job) for job in comp_jobs]
    except BaseException:
        stopping.set()
        if pool is not None:
            stop_pool(pool)   # Ctrl-C or a failed step: stop the workers now, do not wait for them
        if manager is not None:
            stop_manager(manager)
        pool = jobs = job = exp_jobs = comp_jobs = start_design = ready = manager = launched = launcher = None
        gc.collect()
        raise
    manager.shutdown()
    pool.close()
    pool.join()
    from nanosim.pipeline.characterize import write_task_metrics

    from nanosim.pipeline.timings import record_timings

    write_task_metrics(out, parts[False], cfg.seed)
    if twin_too:
        write_task_metrics(out / A.TWIN_DIR, parts[True], cfg.seed, twin=True, run_dir=out)
    done("compensation", write_compensation_results(out, comp_results, cfg.seed), "budget")
    t0 = time.perf_counter()
    step_budget(out, mj)
    done("budget", round(time.perf_counter() - t0, 2))
    timings["overlapped_wall"] = round(time.perf_counter() - t_start, 2)
    write_json(out / A.PIPELINE_JSON, {"seed": cfg.seed})
    record_timings(out, {A.PIPELINE_JSON: {"stage_seconds": timings}})    # the report reads it
    if bar:
        bar.set_postfix_str("running report")
    t0 = time.perf_counter()
    step_report(out)
    done("report", round(time.perf_counter() - t0, 2))
    if bar:
        bar.close()
    record_timings(out, {A.PIPELINE_JSON: {"stage_seconds": timings}})
    return {"stage_seconds": timings, "seed": cfg.seed}
