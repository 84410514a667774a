"""``nanosim characterize``: run the registered experiments, write metrics.json and their figures."""
from __future__ import annotations

import functools
import json
import os
import sys
import time
import queue
from dataclasses import replace
import threading
from pathlib import Path

from nanosim import constants as C
from nanosim import experiments
from nanosim.design.controller import DiscreteController
from nanosim.design.architectures.protocol import read_controller_file
from nanosim.experiments.registry import ExperimentContext
from nanosim.fileio import save_figure, write_json
from nanosim.pipeline import artifacts as A
from nanosim.pipeline.config import CharacterizeConfig
from nanosim.pipeline.timings import read_timings, record_timings
from nanosim.plant.floor import floor_model
from nanosim.plant.runplant import RunPlant
from nanosim.plant.modes import modal_analysis
from nanosim.plant.stage import STAGE_ELECTRONICS, Stage, StageConfig
from nanosim.plant.twin import TwinStage

__all__ = ["stage_config", "make_factory", "make_plant_factory", "run_characterize", "experiment_task",
           "write_task_metrics", "METRICS_UNITS", "plant_description", "write_metrics"]

# metrics.json's "units": the unit suffixes of its keys
METRICS_UNITS = {"nm": "nanometres", "um": "micrometres", "hz": "Hz", "ms": "milliseconds", "us": "microseconds"}


def plant_description(twin: bool) -> str:
    """The ``plant`` entry of ``metrics.json`` (and of ``scorecard.json``)."""
    return "linear twin (same electromechanics)" if twin else "MuJoCo stage, every effect on"


def stage_config(drive: str = "voltage") -> StageConfig | None:
    """The stage config of ``characterize --drive``: None (the bench's) for ``"voltage"``, else the bench
    electronics with that amplifier (:attr:`~nanosim.plant.electronics.ElectronicsConfig.drive`).
    """
    if drive == "voltage":
        return None
    return StageConfig(electronics=replace(STAGE_ELECTRONICS, drive=drive))


def make_factory(twin: bool, mjcf=None, config: StageConfig | None = None):
    """Stage factory: the MuJoCo stage, or the linear twin in the same electromechanics.

    Returns
    -------
    factory : callable
        ``factory(seed) -> stage``.
    base : Stage
        The nominal MuJoCo stage the factory was built from.
    """
    return make_plant_factory(twin, mjcf, config)[:2]


def make_plant_factory(twin: bool, mjcf=None, config: StageConfig | None = None):
    """:func:`make_factory` and the plant of the run it linearized.

    Returns
    -------
    factory, base
        As :func:`make_factory`.
    plant : RunPlant or None
        The ideal stage of ``base.model`` and its linear twin (the twin factory's), for whatever else of the
        command needs the twin; None for the MuJoCo factory.
    """
    base = Stage(config=config, mjcf=mjcf)
    if not twin:
        model = base.model
        return (lambda seed: Stage(seed=seed, config=config, model=model)), base, None
    plant = RunPlant.of_model(base.model)
    lin = plant.twin
    home = base.table_um.copy()
    fm = floor_model(base.model, base.dt_s)
    return (lambda seed: TwinStage(lin, seed=seed, config=config, home_um=home, floor_model=fm)), base, plant


def _run_in_threads(task, names, workers: int):
    """Yield ``task(name)`` for every name as the results arrive, on ``workers`` daemon threads.

    Daemon threads (not a ``ThreadPoolExecutor``, whose exit waits for every queued task) so that
    Ctrl-C ends the command at once: the main thread stops waiting, the staging folder is
    removed and the process exits without running the remaining experiments.
    """
    todo: queue.SimpleQueue = queue.SimpleQueue()
    for n in names:
        todo.put(n)
    done: queue.SimpleQueue = queue.SimpleQueue()
    stop = threading.Event()

    def worker():
        while not stop.is_set():
            try:
                n = todo.get_nowait()
            except queue.Empty:
                return
            try:
                done.put((task(n), None))
            except BaseException as exc:  # noqa: BLE001  (handed to the main thread)
                done.put((None, exc))

    threads = [threading.Thread(target=worker, name=f"characterize-{k}", daemon=True) for k in range(workers)]
    for t in threads:
        t.start()
    try:
        for _ in names:
            while True:
                try:
                    result, exc = done.get(timeout=0.2)
                    break
                except queue.Empty:
                    continue
            if exc is not None:
                raise exc
            yield result
    finally:
        stop.set()


def run_characterize(controller_path, out_dir, config: CharacterizeConfig | None = None, *, mjcf=None,
                     progress: bool = True) -> dict:
    """Run the experiments; write ``metrics.json`` (merged with an existing one for ``only``) and figures.

    The experiments' wall times go to ``timings.json`` (:mod:`nanosim.pipeline.timings`), in registry order.

    Experiments are independent (fresh stage and controller each), so they run
    on ``config.workers`` threads (default: up to 2); MuJoCo steps without the
    GIL. Results do not depend on the number of workers.
    """
    cfg = config or CharacterizeConfig()
    out = Path(out_dir)
    known = experiments.load_builtin()
    names = list(known) if not cfg.only else [cfg.only]
    unknown = [n for n in names if n not in known]
    if unknown:
        raise ValueError(f"only: unknown experiment {unknown[0]!r}; expected one of {list(known)}")
    ctrl = DiscreteController(read_controller_file(controller_path, dt=C.CONTROL_PERIOD_S))
    factory, base = make_factory(cfg.twin, mjcf=mjcf, config=stage_config(cfg.drive))
    G0 = modal_analysis(base.model).static_gain_um_per_V if "creep" in names else None
    metrics: dict = {}
    prev = out / A.METRICS_JSON
    timing: dict = {}
    if cfg.only and prev.is_file():
        metrics = json.loads(prev.read_text())
        timing = {**metrics.pop("experiment_seconds", {}),      # a metrics.json written before timings.json
                  **read_timings(out, A.METRICS_JSON).get("experiment_seconds", {})}

    def context() -> ExperimentContext:
        return ExperimentContext(factory=factory, controller=DiscreteController(ctrl.config), seed=cfg.seed,
                                 static_gain_um_per_V=G0, base_stage=base, feedforward=cfg.feedforward)

    def task(name):
        t0 = time.perf_counter()
        return name, experiments.get(name).run(context()), round(time.perf_counter() - t0, 2)

    bar = None
    if progress:
        from tqdm import tqdm
        bar = tqdm(total=len(names), desc="characterize", unit="exp", file=sys.stderr)
    results = {}
    workers = cfg.workers or min(2, os.cpu_count() or 1)
    order = sorted(names, key=lambda n: -experiments.get(n).cost)
    running = list(order)
    if bar:
        bar.set_postfix_str("running " + ", ".join(running[:workers]))
    try:
        for name, r, seconds in _run_in_threads(task, order, workers):
            results[name], timing[name] = r, seconds
            running.remove(name)
            if bar:
                bar.set_postfix_str(("running " + ", ".join(running[:workers])) if running else "figures")
                bar.update(1)
    finally:
        if bar:
            bar.close()
    for name in names:       # main thread: figures in registry order
        exp = experiments.get(name)
        metrics.update(exp.metrics(results[name]))
        if exp.figure is not None and exp.figure_name:
            save_figure(exp.figure(results[name], context()), out / exp.figure_name)
    # the plant of each experiment: --only adds one experiment to a run whose others may have run elsewhere
    prev_plant = metrics.pop("plant", None)
    by_exp = dict(metrics.pop("plant_by_experiment", None) or
                  ({n: prev_plant for n in known} if cfg.only and prev_plant else {}))
    by_exp.update({n: plant_description(cfg.twin) for n in names})
    metrics.pop("feedforward", None)
    if cfg.feedforward is not None:             # the compensation the hysteresis, tracking and contouring ran with
        metrics["feedforward"] = cfg.feedforward
    metrics.pop("drive", None)
    if cfg.drive != "voltage":                  # the amplifier every experiment ran with (absent: voltage)
        metrics["drive"] = cfg.drive
    write_metrics(out, metrics, twin=cfg.twin, seed=cfg.seed, seconds=_in_registry_order(timing, known),
                  plant_by_experiment=by_exp if cfg.only else None)
    return metrics


def _in_registry_order(seconds: dict, known) -> dict:
    """``{experiment: seconds}`` in registry order (then any other name), not in the order the workers finished."""
    return {**{n: seconds[n] for n in known if n in seconds}, **{n: v for n, v in seconds.items() if n not in known}}


@functools.lru_cache(maxsize=4)
def _member_setup(twin: bool, mjcf):
    """The nominal stage, factory, static gain and batch member of a process (built once per process)."""
    from nanosim.experiments.batch_suite import MemberPlant

    factory, base, run_plant = make_plant_factory(twin, mjcf=mjcf)
    G0 = modal_analysis(base.model).static_gain_um_per_V
    plant = MemberPlant(twin=run_plant.twin if twin else None,
                        model=base.model, home_um=base.table_um.copy(), static_gain_um_per_V=G0, base_stage=base)
    return factory, base, G0, plant


def experiment_task(controller_npz, out_dir, name: str, seed: int, mjcf=None, twin: bool = False) -> tuple:
    """One registered experiment on the batch engine (one member, exact products), as a pool task.

    Runs ``name`` exactly as :func:`nanosim.pipeline.run.characterize_batch` does (same stage,
    controller, seed and code path, so the same numbers bit for bit), saves its figure into
    ``out_dir`` and returns ``(name, metrics, seconds)``; :func:`write_task_metrics` merges the
    tasks' metrics into ``metrics.json`` (their seconds into ``timings.json``). Experiments are
    independent, so the tasks of one or several runs can be spread over worker processes in any order.
    """
    from nanosim.experiments.batch_suite import run_experiments_batch

    t0 = time.perf_counter()
    experiments.load_builtin()
    exp = experiments.get(name)
    ctrl = DiscreteController(read_controller_file(controller_npz, dt=C.CONTROL_PERIOD_S))
    factory, base, G0, plant = _member_setup(bool(twin), None if mjcf is None else str(mjcf))
    (met,), (res,) = run_experiments_batch([name], [plant], ctrl.config, engine="twin" if twin else "mujoco",
                                           seed=seed, exact=True, nthread=1)
    seconds = round(time.perf_counter() - t0, 2)
    if "errors" in met:
        raise RuntimeError(f"characterize: experiment {name!r} failed: {met['errors'][name]}")
    if exp.figure is not None and exp.figure_name:
        ctx = ExperimentContext(factory=factory, controller=DiscreteController(ctrl.config), seed=seed,
                                static_gain_um_per_V=G0, base_stage=base)
        Path(out_dir).mkdir(parents=True, exist_ok=True)
        save_figure(exp.figure(res[name], ctx), Path(out_dir) / exp.figure_name)
    return name, met, seconds


def write_task_metrics(out_dir, parts, seed: int, twin: bool = False, run_dir=None) -> dict:
    """``metrics.json`` from :func:`experiment_task` results ``parts`` (``name -> (metrics, seconds)``).

    Merged in registry order, with the keys :func:`nanosim.pipeline.run.characterize_batch` writes;
    the seconds go to the ``timings.json`` of ``run_dir`` (default ``out_dir``; the pipeline's run
    folder for its ``twin/`` sub-folder).
    """
    metrics: dict = {}
    for name in experiments.load_builtin():
        if name not in parts:
            raise ValueError(f"parts: expected a result for every registered experiment, {name!r} is missing")
        metrics.update(parts[name][0])
    return write_metrics(out_dir, metrics, twin=twin, seed=seed,
                         seconds={name: parts[name][1] for name in experiments.load_builtin()}, run_dir=run_dir)


def write_metrics(out_dir, metrics: dict, *, twin: bool, seed: int, seconds: dict, run_dir=None,
                  plant_by_experiment: dict | None = None) -> dict:
    """Write ``metrics`` with its ``plant``, ``seed`` and ``units`` as ``out_dir/metrics.json``; the experiments'
    ``seconds`` go to the ``timings.json`` of ``run_dir`` (default ``out_dir``). Returns ``metrics``.

    ``plant_by_experiment`` (``{experiment: plant}``) labels each experiment with the plant it ran on
    (``characterize --only`` into a run whose other experiments ran on another plant); ``plant`` is
    then that plant if they all share it, else ``"mixed: ..."`` naming each.
    """
    metrics["plant"] = plant_description(twin)
    if plant_by_experiment:
        metrics["plant_by_experiment"] = dict(plant_by_experiment)
        kinds = set(plant_by_experiment.values())
        if len(kinds) > 1:
            metrics["plant"] = "mixed: " + "; ".join(
                f"{', '.join(n for n, p in plant_by_experiment.items() if p == k)} on the {k}" for k in sorted(kinds))
    metrics["seed"] = seed
    metrics["units"] = dict(METRICS_UNITS)
    path = write_json(Path(out_dir) / A.METRICS_JSON, metrics)
    root = Path(out_dir if run_dir is None else run_dir)
    record_timings(root, {path.relative_to(root).as_posix(): {"experiment_seconds": seconds}})
    return metrics
