"""``nanosim pipeline`` and the single steps: modes -> identify -> design -> characterize -> report.

Every step writes into a folder it is given; :func:`run_pipeline` and the CLI
give them a staging folder (:func:`nanosim.pipeline.runfolder.staged_run`), so
a run folder is complete or untouched.
"""
from __future__ import annotations

import gc
import multiprocessing
import os
import signal
import sys
import threading
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import numpy as np

from nanosim.fileio import save_figure, write_json, write_npz
from nanosim.pipeline import artifacts as A
from nanosim.pipeline.config import CharacterizeConfig, DesignConfig, IdentifyConfig, PipelineConfig

__all__ = ["step_modes", "write_twin_npz", "step_identify", "step_design", "step_characterize", "step_report",
           "PIPELINE_STEPS", "run_pipeline", "characterize_batch"]


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
    """``twin.npz``: MuJoCo's linearization of the ideal stage (controller V -> sensor V)."""
    from nanosim.plant.linearize import linearize
    from nanosim.plant.stage import Stage, StageConfig

    tw = linearize(Stage(config=StageConfig.ideal(), mjcf=mjcf))
    s = tw.sys_V
    return write_npz(out / A.TWIN_NPZ, A=s.A, B=s.B, C=s.C, D=s.D, Ad=tw.sysd_V.A, Bd=tw.sysd_V.B,
                     Cd=tw.sysd_V.C, Dd=tw.sysd_V.D, dt=tw.dt_s,
                     units=np.array("controller V -> sensor V (5 um/V); ideal MuJoCo stage, linear piezo"))


def step_identify(out: Path, config: IdentifyConfig, mjcf=None, progress=None) -> None:
    """Identify the stage (``model.npz``, ``identify.json``, Figs. 4-7) into ``out``."""
    from nanosim.pipeline.identify import run_identify
    from nanosim.plant.linearize import linearize
    from nanosim.plant.mjcf import load_model
    from nanosim.plant.stage import Stage, StageConfig

    model = load_model(mjcf)
    twin = linearize(Stage(config=StageConfig.ideal(), model=model))
    run_identify(out, config, model=model, twin=twin, progress=progress)


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


PIPELINE_STEPS = ("modes", "identify", "design", "characterize", "characterize_twin", "report")


def _ignore_sigint() -> None:
    """Pool initializer: Ctrl-C goes to the main process, which stops the worker (no traceback from it)."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)


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
    writes the same ``metrics.json`` and figures into ``out_dir``. The MuJoCo member steps with
    one compiled call for its electronics per period instead of a dozen numpy calls; the twin
    runs in the compiled loop. ``workers`` experiments run side by side (threads; MuJoCo steps
    without the GIL).
    """
    from nanosim import constants as C
    from nanosim import experiments
    from nanosim.design.controller import DiscreteController
    from nanosim.experiments.batch_suite import MemberPlant, run_experiments_batch
    from nanosim.experiments.registry import ExperimentContext
    from nanosim.fileio import save_figure
    from nanosim.pipeline.characterize import make_factory
    from nanosim.plant.linearize import linearize
    from nanosim.plant.modes import modal_analysis
    from nanosim.plant.stage import Stage, StageConfig

    out = Path(out_dir)
    names = list(experiments.load_builtin())
    ctrl = DiscreteController.from_npz(controller_npz, expected_dt=C.CONTROL_PERIOD_S)
    factory, base = make_factory(twin, mjcf=mjcf)
    G0 = modal_analysis(base.model).static_gain_um_per_V if "creep" in names else None
    plant = MemberPlant(twin=linearize(Stage(config=StageConfig.ideal(), model=base.model)) if twin else None,
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
    metrics["experiment_seconds"] = seconds
    metrics["plant"] = "linear twin (same electromechanics)" if twin else "MuJoCo stage, every effect on"
    metrics["seed"] = seed
    metrics["units"] = {"nm": "nanometres", "um": "micrometres", "hz": "Hz", "ms": "milliseconds"}
    write_json(out / A.METRICS_JSON, metrics)
    return metrics


def _characterize_twin(out: str, seed: int, mjcf) -> float:
    """The twin's experiments (run in a worker process, on the batch engine); returns their wall time [s]."""
    t0 = time.perf_counter()
    characterize_batch(Path(out) / A.CONTROLLER_NPZ, Path(out) / A.TWIN_DIR, seed, mjcf, twin=True)
    return round(time.perf_counter() - t0, 2)


def run_pipeline(out: Path, config: PipelineConfig | None = None, *, progress: bool = True) -> dict:
    """Run every step into ``out`` (normally a staging folder); returns ``pipeline.json``'s content."""
    cfg = config or PipelineConfig()
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    ident_cfg = cfg.identify if cfg.identify.seed == cfg.seed else IdentifyConfig(
        seed=cfg.seed, order=cfg.identify.order, ideal=cfg.identify.ideal,
        operating_points_piezo_V=cfg.identify.operating_points_piezo_V)
    steps = {
        "modes": lambda: step_modes(out, cfg.mjcf),
        "identify": lambda: step_identify(out, ident_cfg, cfg.mjcf),
        "design": lambda: step_design(out, cfg.design, mjcf=cfg.mjcf),
        # the batch engine (one member; same metrics.json as step_characterize, compiled electronics)
        "characterize": lambda: characterize_batch(out / A.CONTROLLER_NPZ, out, cfg.seed, cfg.mjcf,
                                                   workers=min(2, os.cpu_count() or 1)),
        "characterize_twin": lambda: step_characterize(out / A.TWIN_DIR, CharacterizeConfig(seed=cfg.seed, twin=True),
                                                       controller_npz=out / A.CONTROLLER_NPZ, mjcf=cfg.mjcf),
        "report": lambda: step_report(out),
    }
    names = [n for n in PIPELINE_STEPS if n != "characterize_twin" or cfg.characterize_twin_too]
    timings: dict[str, float] = {}
    bar = None
    if progress:
        from tqdm import tqdm
        bar = tqdm(total=len(names), desc="nanosim pipeline", unit="step", file=sys.stderr)

    def timed(name):
        if bar:
            bar.set_postfix_str(f"running {name}")
        t0 = time.perf_counter()
        steps[name]()
        timings[name] = round(time.perf_counter() - t0, 2)
        if bar:
            bar.update(1)

    # Independent steps run side by side (no experiment is shortened): the modes beside the
    # identification (a thread), the twin's experiments beside the MuJoCo ones (a process of its
    # own, so the two do not compete for the GIL; results do not depend on it).
    t_start = time.perf_counter()
    with ThreadPoolExecutor(1) as side:
        modes = side.submit(timed, "modes")
        timed("identify")
        modes.result()
    timed("design")
    twin = pool = None
    if "characterize_twin" in names:
        pool = multiprocessing.get_context("spawn").Pool(1, initializer=_ignore_sigint)
        twin = pool.apply_async(_characterize_twin, (str(out), cfg.seed, None if cfg.mjcf is None else str(cfg.mjcf)))
    try:
        timed("characterize")
        if twin is not None:
            timings["characterize_twin"] = twin.get()
            if bar:
                bar.update(1)
    except BaseException:
        if pool is not None:     # Ctrl-C or a failed step: stop the twin's experiments now, do not wait for them
            pool.terminate()
            pool.join()
            pool = twin = None   # release its semaphores now (the CLI may leave through os._exit)
            gc.collect()
        raise
    if pool is not None:
        pool.close()
        pool.join()
    timings["overlapped_wall"] = round(time.perf_counter() - t_start, 2)
    write_json(out / A.PIPELINE_JSON, {"stage_seconds": timings, "seed": cfg.seed})   # the report reads it
    timed("report")
    if bar:
        bar.close()
    result = {"stage_seconds": timings, "seed": cfg.seed}
    write_json(out / A.PIPELINE_JSON, result)
    return result
