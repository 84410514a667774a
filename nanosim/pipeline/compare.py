"""``nanosim compare``: controllers through the Section 5 suite and the robustness analysis, scored.

For every controller (a bench design from the identified model, a state-space file or a
``module:function`` object, :mod:`nanosim.design.architectures.protocol`) and every seed:

1. the registered experiments (``nanosim characterize``'s suite, or ``only`` of them) on the
   MuJoCo stage or the linear twin, a fresh controller per experiment;
2. the sensitivity of the feedback loop measured directly, with a PRBS added to the reading
   (:func:`reading_disturbance_sensitivity`, the scorecard's ``bandwidth_S_feedback_hz``), for every
   controller by the same method: the bandwidth experiment's ``S`` (``bandwidth_S_hz``) comes from the
   reference record, which gives the feedback loop's ``S`` only for one degree of freedom or a controller
   whose matrices are known (a ``module:function`` object is taken as one degree of freedom), and on the
   hysteretic stage the two excitations can give different answers for the same ``S``;
3. once per linear controller (seed-independent): ``robustness.json`` and its figures on
   the identified model as it is (it is the loop as run) and on the linear twin as the loop
   runs it: the one-sample delay, the computation delay and the bench's amplifier and gauge
   filters, as ``nanosim design`` analyses it
   (:func:`nanosim.pipeline.design.write_robustness`).

The scorecard (:mod:`nanosim.pipeline.scorecard`) then gives mean, spread and worst case
per metric and controller, acceptance against the bench specification per metric, and the default chosen by
its rule; the overlaid figures are :mod:`nanosim.plots.compare`.
"""
from __future__ import annotations

import os
import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from nanosim import constants as C
from nanosim import experiments
from nanosim.design.architectures.protocol import ControllerSpec, load_controller
from nanosim.design.lti import crossing_hz
from nanosim.experiments.bandwidth import (
    PRBS_AMPLITUDE_UM,
    PRBS_DURATION_S,
    h1_in_band,
    prbs_references,
    sigma_in_band,
)
from nanosim.experiments.loop import FS, LOOP_PROTOCOL, UM_PER_V, LoopProtocol, run_closed_loop
from nanosim.experiments.registry import ExperimentContext
from nanosim.fileio import save_figure, write_json, write_npz
from nanosim.pipeline import artifacts as A
from nanosim.pipeline.export import write_controller_exports
from nanosim.pipeline.config import CompareConfig
from nanosim.pipeline.scorecard import scorecard, write_scorecard
from nanosim.pipeline.runfolder import run_relative
from nanosim.pipeline.timings import record_timings
from nanosim.plant.noise import stream_seed
from nanosim.validation import named_message

__all__ = ["reading_disturbance_sensitivity", "ReadingDisturbanceSensitivity", "run_compare", "resolve_model",
           "check_controllers", "check_only"]


# =====================================================================================
# the feedback loop's sensitivity, measured with a disturbance at the reading
# =====================================================================================
class _ReadingOffset:
    """A stage whose readings carry ``offset_V[k]`` from its ``start``-th step on (sensor-side disturbance)."""

    def __init__(self, stage, offset_V: np.ndarray, start: int):
        self._stage = stage
        self._d = offset_V
        self._start = start
        self._k = 0

    def step(self, u_V):
        y = self._stage.step(u_V)
        j = self._k - self._start
        self._k += 1
        if 0 <= j < len(self._d):
            y = y + self._d[j]
        return y

    def __getattr__(self, name):
        return getattr(self._stage, name)


@dataclass(frozen=True)
class ReadingDisturbanceSensitivity:
    """``sigma_max(S_o)`` of the feedback loop measured with a PRBS added to the reading.

    Attributes
    ----------
    freq_hz : ndarray, shape (F,)
    sigma_S : ndarray, shape (F,)
    bandwidth_S_hz : float
        First -3 dB crossing of ``sigma_max(S_o)`` from below [Hz].
    """

    freq_hz: np.ndarray
    sigma_S: np.ndarray
    bandwidth_S_hz: float


def reading_disturbance_sensitivity(factory, controller, seed: int = 0, duration_s: float = PRBS_DURATION_S,
                                    amplitude_um: float = PRBS_AMPLITUDE_UM,
                                    protocol: LoopProtocol = LOOP_PROTOCOL) -> ReadingDisturbanceSensitivity:
    """Output sensitivity ``S_o = (I + G Kfb)^-1`` of the loop as run, measured directly.

    With ``r = 0`` and a disturbance ``d`` added to the reading the controller sees
    (``y_meas = y + d``), ``y_meas = S_o d`` whatever the controller's reference path;
    three uncorrelated PRBS of ``amplitude_um`` (the bandwidth experiment's swing), MIMO H1.

    The bandwidth experiment (:func:`nanosim.experiments.bandwidth.bandwidth`) has the same ``S`` from its
    reference record without a second record: ``I - T`` for one degree of freedom, the indirect method
    (:func:`~nanosim.experiments.bandwidth.indirect_sensitivity_sigma`) for two. This measurement is kept
    beside it because it needs nothing of the controller (a ``module:function`` object's reference path is
    unknown, and the bandwidth experiment takes it as one degree of freedom), so ``nanosim compare`` scores
    every controller by one method; and because the two excitations are different experiments on a
    hysteretic stage: they agree on a linear loop (``tests/test_bandwidth_sensitivity.py``) and not exactly
    with the piezo's hysteresis in the loop, where each is the best linear description of the loop under its
    own excitation.
    """
    n = int(duration_s * FS)
    d_um = prbs_references(n, amplitude_um, stream_seed(seed, "feedback_sensitivity.disturbance"))
    d_um = d_um - d_um.mean(axis=0)
    n_before = protocol.n_before_record
    stage = _ReadingOffset(factory(stream_seed(seed, "feedback_sensitivity")), d_um / UM_PER_V, start=n_before - 1)
    cl = run_closed_loop(stage, controller, np.zeros((n, 3)), protocol=protocol)
    f, H = h1_in_band(d_um, cl.y_um)
    sS = sigma_in_band(H)
    return ReadingDisturbanceSensitivity(freq_hz=f, sigma_S=sS,
                                         bandwidth_S_hz=crossing_hz(f, sS, 1 / np.sqrt(2), rising=True))


# =====================================================================================
# model and controllers
# =====================================================================================
def resolve_model(model, out: Path, seed: int, mjcf=None, progress=None):
    """The identified model (discrete StateSpace) and its path: ``model`` (a ``model.npz`` or a
    folder holding one), or a fresh identification into ``out/identified``.
    """
    from nanosim.design.lti import load_state_space_npz
    if model is None:
        from nanosim.pipeline.config import IdentifyConfig
        from nanosim.pipeline.run import step_identify
        folder = out / "identified"
        folder.mkdir(parents=True, exist_ok=True)
        if progress:
            progress(f"identifying the stage (seed {seed}) for the bench designs")
        step_identify(folder, IdentifyConfig(seed=seed), mjcf)
        model = folder / A.MODEL_NPZ
    p = Path(model)
    if p.is_dir():
        p = p / A.MODEL_NPZ
    G, Gd = load_state_space_npz(p)
    if Gd is None:
        import control as ct
        Gd = ct.ss(ct.c2d(G, C.CONTROL_PERIOD_S, "tustin"))
    return Gd, p


def check_controllers(controllers) -> None:
    """Every ``--controllers`` entry loadable, before any work or progress output (``ValueError``).

    Bench names are designed later (they need the identified model); files are read and checked
    (state space, 3 channels, the control period; a file in a sealed run folder must match its
    manifest) and ``module:function`` entries imported and called once, as :func:`run_compare` does.
    Two entries with the same label are refused.
    """
    from nanosim.pipeline.runfolder import verify_input_file

    labels = []
    for c in controllers:
        if _is_bench(c):
            labels.append(c)
            continue
        try:
            if Path(c).suffix in (".npz", ".mat") and Path(c).is_dir():
                raise ValueError(f"expected a file, got the directory {c!r}")
            if Path(c).is_file():
                verify_input_file(c, "--controllers")
            labels.append(load_controller(c, None).name)
        except ValueError as exc:
            raise ValueError(named_message("--controllers", exc, aliases=("controller",),
                                            empty="cannot be loaded")) from None
        except Exception as exc:            # noqa: BLE001 -- a user's module failing to import or run
            raise ValueError(f"--controllers: {c!r} failed to load: {type(exc).__name__}: {exc}") from None
    dup = sorted({x for x in labels if labels.count(x) > 1})
    if dup:
        raise ValueError(f"--controllers: expected distinct names, got {dup[0]!r} more than once ({labels}); "
                         "rename a file")


def check_only(only) -> list:
    """The experiments ``only`` names (all registered ones for ``None``); ``ValueError`` naming ``--only``."""
    known = experiments.load_builtin()
    names = list(only) if only else list(known)
    bad = [n for n in names if n not in known]
    if bad:
        raise ValueError(f"--only: unknown experiment {bad[0]!r}; expected some of {list(known)}")
    return names


def _robustness(spec: ControllerSpec, out: Path, Gd, twin_sysd) -> dict | None:
    from nanosim.design.robustness import LoopPlant
    from nanosim.pipeline.design import twin_loop_plant, write_robustness
    if not spec.is_lti:
        return None
    plants = {"identified": LoopPlant.identified(Gd)}
    if twin_sysd is not None:
        plants["twin"] = twin_loop_plant(twin_sysd)
    return write_robustness(out, spec.config, plants)


def _save_controller(spec: ControllerSpec, path: Path) -> None:
    if spec.config is None:
        return
    c = spec.config
    extra = {}
    if spec.design is not None:
        extra["tuning_rule"] = np.array(spec.design.tuning_rule)
    write_npz(path, Akd=c.Akd, Bkd=c.Bkd, Ckd=c.Ckd, Dkd=c.Dkd, dt=np.float64(c.dt), n_error=np.int64(c.n_error),
              name=np.array(spec.name), **extra)
    write_controller_exports(path, c.Akd, c.Bkd, c.Ckd, c.Dkd, c.dt, c.n_error)


# =====================================================================================
# one controller on one seed
# =====================================================================================
_READING_DISTURBANCE = "reading_disturbance_sensitivity"     # its job name beside the registered experiments


def _run_suite(spec: ControllerSpec, names, factory, base, G0, seed: int, workers: int) -> dict:
    """Results of the registered experiments ``names`` and the extra measurements, by name."""
    def context():
        return ExperimentContext(factory=factory, controller=spec.make(), seed=seed, static_gain_um_per_V=G0,
                                 base_stage=base)

    def task(name):
        if name == _READING_DISTURBANCE:
            return name, reading_disturbance_sensitivity(factory, spec.make(), seed=seed)
        return name, experiments.get(name).run(context())

    jobs = list(names) + [_READING_DISTURBANCE]
    order = sorted(jobs, key=lambda n: -(experiments.get(n).cost if n in names else 2))
    with ThreadPoolExecutor(max_workers=workers) as pool:
        return dict(pool.map(task, order))


def _metrics(results: dict, names) -> dict:
    out: dict = {}
    for n in names:
        out.update(experiments.get(n).metrics(results[n]))
    fs = results[_READING_DISTURBANCE]
    out["bandwidth_S_feedback_hz"] = fs.bandwidth_S_hz
    return out


# =====================================================================================
# the command
# =====================================================================================
def run_compare(out_dir, config: CompareConfig, *, mjcf=None, progress=None) -> dict:
    """Run every controller of ``config`` on every seed; write the scorecard and the figures.

    Parameters
    ----------
    out_dir : path
        Run folder (normally a staging folder, :func:`nanosim.pipeline.runfolder.staged_run`).
    config : CompareConfig
    mjcf : path, optional
    progress : callable, optional
        ``progress(message)``.

    Returns
    -------
    dict
        The content of ``scorecard.json`` (the wall times are in ``timings.json``).
    """
    from nanosim.pipeline.characterize import METRICS_UNITS, make_factory
    from nanosim.plant.linearize import linearize
    from nanosim.plant.modes import modal_analysis
    from nanosim.plant.stage import Stage, StageConfig
    from nanosim.plots.compare import compare_figures

    say = progress or (lambda m: None)
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    names = check_only(config.only)
    t0 = time.perf_counter()
    needs_model = any(_is_bench(c) for c in config.controllers)
    Gd, model_path = (resolve_model(config.model, out, min(config.seeds), mjcf, say) if needs_model or config.model
                      else (None, None))
    specs: list[ControllerSpec] = []
    for c in config.controllers:
        say(f"controller {c}: loading" + (" (designing from the identified model)" if _is_bench(c) else ""))
        specs.append(load_controller(c, Gd))
    labels = [s.name for s in specs]
    if len(set(labels)) != len(labels):
        raise ValueError(f"--controllers: two controllers share a name ({labels}); rename a file")
    factory, base = make_factory(config.twin, mjcf=mjcf)
    G0 = modal_analysis(base.model).static_gain_um_per_V if "creep" in names else None
    twin_sysd = linearize(Stage(config=StageConfig.ideal(), model=base.model)).sysd_V
    workers = config.workers or min(2, os.cpu_count() or 1)
    per: dict = {}
    first_results: dict = {}
    robustness: dict = {}
    seconds: dict = {}          # wall times, for timings.json (the result files hold none)
    for spec in specs:
        folder = out / spec.name
        folder.mkdir(parents=True, exist_ok=True)
        _save_controller(spec, folder / A.CONTROLLER_NPZ)
        if config.robustness and spec.is_lti and Gd is not None:
            say(f"{spec.name}: robustness analysis (identified model = loop as run, and twin)")
            robustness[spec.name] = _robustness(spec, folder, Gd, twin_sysd)
        per[spec.name] = {}
        for seed in config.seeds:
            say(f"{spec.name}: seed {seed}, {len(names)} experiments + feedback sensitivity "
                f"({'twin' if config.twin else 'MuJoCo'})")
            t = time.perf_counter()
            res = _run_suite(spec, names, factory, base, G0, seed, workers)
            m = _metrics(res, names)
            m["units"] = dict(METRICS_UNITS)
            path = write_json(folder / A.compare_seed_dir(seed) / A.METRICS_JSON, m)
            seconds[path.relative_to(out).as_posix()] = {"run_seconds": round(time.perf_counter() - t, 2)}
            per[spec.name][seed] = m
            if seed == min(config.seeds):
                first_results[spec.name] = res
    analyses, so_bw = {}, {}
    if Gd is not None:
        from nanosim.design.architectures.common import sensitivity_bandwidth_hz
        from nanosim.design.robustness import LoopPlant, loop_transfer_response, stage_grid_hz
        plant = LoopPlant.identified(Gd)
        for spec in specs:
            if spec.is_lti:
                K, Ky = spec.systems()
                f = stage_grid_hz(plant, K, Ky, n=400)
                analyses[spec.name] = loop_transfer_response(plant.G, K, f, Ky=Ky, delay_samples=plant.delay_samples)
                so_bw[spec.name] = sensitivity_bandwidth_hz(analyses[spec.name])
    for name, fig in compare_figures(first_results, analyses).items():
        save_figure(fig, out / name)
    doc = scorecard(specs, per, robustness, config, So_bandwidths=so_bw,
                    model_path=None if model_path is None else run_relative(model_path, out))
    write_scorecard(out, doc)
    seconds[A.SCORECARD_JSON] = {"seconds": round(time.perf_counter() - t0, 1)}
    record_timings(out, seconds)
    return doc


def _is_bench(spec: str) -> bool:
    from nanosim.design.architectures import DESIGN_RULES
    return spec in DESIGN_RULES

