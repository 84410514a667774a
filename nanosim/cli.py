"""``nanosim`` command line: modes, identify, design, characterize, pipeline, report, montecarlo, sweep, budget, view.

argparse -> config dataclasses (:mod:`nanosim.pipeline.config`, the only home
of defaults) -> pipeline steps. Every user error prints one line and exits 2.
"""
from __future__ import annotations

import argparse
import dataclasses
import json
import math
import os
import sys
import threading
import time
from pathlib import Path

from nanosim import __version__
from nanosim.validation import Terminated, named_message
from nanosim import constants as C
from nanosim.pipeline import artifacts as A
from nanosim.pipeline.workers import stop_signals
from nanosim.pipeline.config import (DEFAULT_ARCHITECTURE, DEFAULT_DAMPING_ZETA, DEFAULT_REDUCED_ORDER,
                                     DESIGN_ARCHITECTURES, CharacterizeConfig, CompareConfig, DesignConfig,
                                     IdentifyConfig, MonteCarloConfig, PipelineConfig)
from nanosim.paper import PAPER_IDENTIFIED_ORDER_PER_COLUMN, PAPER_PRBS_BANDS_HZ, PAPER_REDUCED_ORDER

__all__ = ["build_parser", "main"]


class _OneLineParser(argparse.ArgumentParser):
    """argparse that reports a usage error on one line (no usage block) and exits 2."""

    def error(self, message: str):
        self.exit(2, f"{self.prog}: error: {message} (see --help)\n")


def _field_default(config_class, name: str):
    """The default of field ``name`` of a config dataclass, also of one that needs arguments (CompareConfig)."""
    return next(f.default for f in dataclasses.fields(config_class) if f.name == name)


# --- argument types: the message names what was expected and what arrived ---------------------
def _int_at_least(lo: int):
    def parse(text: str) -> int:
        try:
            v = int(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected an integer >= {lo}, got {text!r}") from None
        if v < lo:
            raise argparse.ArgumentTypeError(f"expected an integer >= {lo}, got {v}")
        return v
    return parse


def _float_in(lo: float, hi: float, lo_open: bool = False):
    def parse(text: str) -> float:
        try:
            v = float(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected a number, got {text!r}") from None
        if not math.isfinite(v) or v < lo or v > hi or (lo_open and v == lo):
            span = f"{'(' if lo_open else '['}{lo:g}, {hi:g}]"
            raise argparse.ArgumentTypeError(f"expected a finite number in {span}, got {text}")
        return v
    return parse


def _file(text: str) -> str:
    p = Path(text)
    if p.is_dir():
        raise argparse.ArgumentTypeError(f"expected a file, got the directory {text!r}")
    if not p.is_file():
        raise argparse.ArgumentTypeError(f"no such file {text!r}")
    return text


def _type_error(name: str, exc: BaseException) -> argparse.ArgumentTypeError:
    """An argparse type's error (argparse puts ``argument NAME:`` in front)."""
    return argparse.ArgumentTypeError(named_message(name, exc)[len(name) + 2:])


def _out_folder(name: str):
    """``--out``/``--plot``: a folder that can be created or written, checked before any work."""
    def parse(text: str) -> str:
        from nanosim.pipeline.runfolder import RunFolderError, check_writable
        try:
            check_writable(text, name)
        except RunFolderError as exc:
            raise _type_error(name, exc) from None
        return text
    return parse


def _scheduler(text: str) -> str:
    """``--scheduler``: ``local`` or ``tcp://HOST:PORT`` (its form; whether it answers is known by connecting)."""
    from nanosim.pipeline.scaleout import check_scheduler
    try:
        return check_scheduler(text)
    except ValueError as exc:
        raise _type_error("--scheduler", exc) from None


def _seeds(sort: bool):
    """``--seeds``: ``0-4``, ``0,3,7`` or a mix, at most ``seeds.MAX_SEEDS`` distinct seeds."""
    def parse(text: str) -> tuple:
        from nanosim.pipeline.seeds import parse_seeds
        try:
            return parse_seeds(text, sort=sort)
        except ValueError as exc:
            raise _type_error("--seeds", exc) from None
    return parse


# --- checks of file contents, before any work: the message names the argument ----------------
def _load_mjcf(path):
    """The MJCF model (``None``: the bundled stage); errors name ``--mjcf``."""
    from nanosim.plant.mjcf import load_model
    try:
        return load_model(path)
    except (OSError, ValueError) as exc:
        raise ValueError(named_message("--mjcf", exc)) from None


def _check_mjcf(args) -> None:
    if getattr(args, "mjcf", None) is not None:
        _load_mjcf(args.mjcf)


def _check_controller(path, mjcf=None) -> Path:
    """``--controller``: matches its sealed run folder (if any), a controller file at the loop's period
    (:func:`~nanosim.design.architectures.protocol.read_controller_file`), and it stabilizes the stage.

    Stability is checked before any simulation: the discrete closed loop of the controller and the
    linear twin of the stage as the loop runs it (MuJoCo's linearization of the ideal stage, the
    bench electronics, the one-sample computation delay) must have every pole inside the unit circle.
    """
    import numpy as np

    from nanosim.design.architectures.protocol import read_controller_file
    from nanosim.design.robustness import closed_loop_poles, controller_systems
    from nanosim.pipeline.design import twin_loop_plant
    from nanosim.pipeline.runfolder import verify_input_file
    from nanosim.plant.runplant import RunPlant

    p = verify_input_file(path, "--controller").resolve()       # a sealed run's controller must match it
    cfg = read_controller_file(p, dt=C.CONTROL_PERIOD_S, name="--controller")
    plant = twin_loop_plant(RunPlant.of_model(_load_mjcf(mjcf)).twin.sysd_V)
    K, Ky = controller_systems(cfg)
    poles = closed_loop_poles(plant.G, K, Ky, plant.delay_samples)
    rho = float(np.max(np.abs(poles))) if poles.size else 0.0
    if not rho < 1.0:
        raise ValueError(f"--controller: {str(path)!r} does not stabilize the stage: a closed-loop pole at "
                         f"|z| = {rho:.4g} >= 1 with the linear twin (the loop as run); refused before the simulation")
    return p


def _check_model(path) -> Path:
    """``--model``: a model.npz (or a run folder holding one) matching its sealed run folder (if any)."""
    from nanosim.design.lti import load_state_space_npz
    from nanosim.pipeline.runfolder import verify_input_file

    p = Path(path)
    if p.is_dir():
        p = p / A.MODEL_NPZ
    if not p.is_file():
        raise ValueError(f"--model: expected a model.npz or a run folder holding one, got {str(path)!r}"
                         + (" (no model.npz in it)" if Path(path).is_dir() else ""))
    p = verify_input_file(p, "--model").resolve()                 # a sealed run's model must match it
    try:
        _, Gd = load_state_space_npz(p)
    except (OSError, ValueError) as exc:
        raise ValueError(named_message("--model", exc)) from None
    if Gd is not None and not math.isclose(float(Gd.dt), C.CONTROL_PERIOD_S, rel_tol=1e-9):
        raise ValueError(f"--model: expected a discrete model at the loop's period dt = {C.CONTROL_PERIOD_S:g} s, "
                         f"got dt = {float(Gd.dt)!r} s in {str(p)!r}")
    return p


def _check_model_mat(path) -> Path:
    """``--model`` as a MATLAB state space ``A, B, C, D, Ts`` (discrete at the loop's period, or continuous)."""
    import identification as ident
    try:
        *_, ts = ident.load_state_space(path)
    except (OSError, ValueError) as exc:
        raise ValueError(named_message("--model", exc)) from None
    if ts > 0 and not math.isclose(ts, C.CONTROL_PERIOD_S, rel_tol=1e-9):
        raise ValueError(f"--model: expected Ts = {C.CONTROL_PERIOD_S:g} s (the loop's period) or 0 (continuous), "
                         f"got Ts = {ts!r} s in {str(path)!r}")
    return Path(path).resolve()


def _check_weights(path):
    """``--weights``: a JSON/TOML file of usable weights (design, pipeline and sweep share this check)."""
    if path is None:
        return None
    from nanosim.design.weights import Weights
    try:
        Weights.coerce(path).check()
    except (OSError, ValueError) as exc:
        msg = named_message("--weights", exc)[len("--weights: "):]
        where = "" if str(path) in msg else f"{str(path)!r}: "           # name the file that arrived
        raise ValueError(f"--weights: {where}{msg}") from None
    return path


# --- commands ------------------------------------------------------------------------------
def _cmd_modes(args) -> int:
    from nanosim.fileio import save_figure
    from nanosim.plant.mjcf import FULL_MJCF, load_model
    from nanosim.plant.modes import modal_analysis, modes_json
    from nanosim.plots.modes import mode_shape_figures

    model = _load_mjcf(args.mjcf)                  # --plot was checked by its type, before any work
    if args.plot:
        for name, fig in mode_shape_figures(model, modal_analysis(model), fmax_hz=args.fmax):
            print(save_figure(fig, Path(args.plot) / name))
        return 0
    full = load_model(FULL_MJCF) if args.mjcf is None else None      # bundled stage: its full-compliance twin too
    data = modes_json(model, fmax_hz=args.fmax, full_model=full)
    if args.json:
        print(json.dumps(data, indent=2))
        return 0
    print(f"{'#':>2} {'freq (Hz)':>10} {'zeta':>8} {'axis':>4}  sensor participation X, Y, Z")
    for i, m in enumerate(data["modes"], 1):
        sp = ", ".join(f"{v:.3f}" for v in m["sensor_participation"])
        print(f"{i:>2} {m['freq_hz']:10.1f} {m['damping_ratio']:8.4f} {m['axis']:>4}  {sp}")
    print("static gain (um per controller V), rows X Y Z, columns A B C:")
    for row in data["static_gain_um_per_V"]:
        print("   " + " ".join(f"{v:8.3f}" for v in row))
    print(f"closure violation at full stroke: {100 * data['constraint_violation_ratio']:.3f} % of table motion")
    print(f"lowest closure (constraint) mode: {data['lowest_constraint_mode_hz']:.0f} Hz")
    return 0


def _design_config(args) -> DesignConfig:
    _check_weights(args.weights)
    if args.paper_design:
        return DesignConfig.paper(weights=args.weights)
    return DesignConfig(reduced_order=args.reduced_order, damping_zeta=args.damping_zeta, weights=args.weights,
                        architecture=args.architecture)


def _say(msg: str) -> None:
    print(f"  {msg}", file=sys.stderr, flush=True)


def _bands_hz(args) -> tuple:
    """The identification's PRBS bands: the paper's with ``--paper-bands``, else the default."""
    return PAPER_PRBS_BANDS_HZ if args.paper_bands else C.DEFAULT_PRBS_BANDS_HZ


def _cmd_identify_data(args) -> int:
    """``nanosim identify --data FILE``: a model from the user's record (checked before any work)."""
    import identification as ident
    from nanosim.pipeline.identify import run_identify_data
    from nanosim.pipeline.runfolder import staged_run

    stage_only = [o for o, on in (("--ideal", args.ideal), ("--per-column-poles", not args.shared_poles),
                                  ("--paper-bands", args.paper_bands), ("--mjcf", args.mjcf is not None)) if on]
    if stage_only:
        raise ValueError(f"--data: {stage_only[0]} applies to the simulated stage's experiments, not to a record")
    try:
        ident.load_record(args.data)
    except (OSError, ValueError) as exc:
        raise ValueError(named_message("--data", exc)) from None
    t0 = time.perf_counter()
    with staged_run(args.out, keep_existing=True) as stage:
        doc = run_identify_data(args.data, stage, order=args.order, progress=_say)
    print(f"identify done in {time.perf_counter() - t0:.1f} s: order {doc['order']}, validation fit "
          f"{', '.join(f'{v:.1f} %' for v in doc['fit_percent'])}: {Path(args.out) / A.MODEL_NPZ}")
    return 0


def _cmd_identify(args) -> int:
    from nanosim.pipeline.run import step_identify
    from nanosim.pipeline.runfolder import staged_run

    if args.data is not None:
        return _cmd_identify_data(args)
    order = PAPER_IDENTIFIED_ORDER_PER_COLUMN if args.order is None else args.order
    cfg = IdentifyConfig(seed=args.seed, order=order, ideal=args.ideal, shared_poles=args.shared_poles,
                         bands_hz=_bands_hz(args))
    _check_mjcf(args)
    t0 = time.perf_counter()
    with staged_run(args.out, keep_existing=True, seed=args.seed) as stage:
        _say("simulating the identification experiments (3 actuators x 2 records, 2 operating points)")
        step_identify(stage, cfg, args.mjcf, progress=_say)
    print(f"identify done in {time.perf_counter() - t0:.1f} s: {Path(args.out) / A.MODEL_NPZ}")
    return 0


def _cmd_design(args) -> int:
    from nanosim.pipeline.run import step_design
    from nanosim.pipeline.runfolder import staged_run

    cfg = _design_config(args)
    mat = Path(args.model).suffix.lower() == ".mat"
    model = _check_model_mat(args.model) if mat else _check_model(args.model)
    _check_mjcf(args)
    t0 = time.perf_counter()
    with staged_run(args.out, keep_existing=True) as stage:
        if mat:                         # the MATLAB state space as a model.npz in the run folder
            from nanosim.pipeline.identify import model_npz_from_mat
            model = model_npz_from_mat(model, Path(stage) / A.MODEL_NPZ)
        step_design(stage, cfg, model_npz=model, mjcf=args.mjcf)
    print(f"design done in {time.perf_counter() - t0:.1f} s: {Path(args.out) / A.CONTROLLER_NPZ}")
    return 0


def _cmd_characterize(args) -> int:
    from nanosim import experiments
    from nanosim.pipeline.run import step_characterize
    from nanosim.pipeline.runfolder import staged_run

    known = experiments.load_builtin()
    if args.only is not None and args.only not in known:
        raise ValueError(f"--only: expected one of {', '.join(known)}, got {args.only!r}")
    _check_mjcf(args)
    controller = _check_controller(args.controller, args.mjcf)         # validate before any work
    cfg = CharacterizeConfig(seed=args.seed, only=args.only, twin=args.twin, feedforward=args.feedforward)
    t0 = time.perf_counter()
    with staged_run(args.out, keep_existing=True, seed=args.seed) as stage:
        step_characterize(stage, cfg, controller_npz=controller, mjcf=args.mjcf)
    print(f"characterize done in {time.perf_counter() - t0:.1f} s: {Path(args.out) / A.METRICS_JSON}")
    return 0


def _cmd_pipeline(args) -> int:
    from nanosim.pipeline.report import pass_count
    from nanosim.pipeline.run import run_pipeline
    from nanosim.pipeline.runfolder import staged_run

    if args.seeds is not None and args.seed is not None:
        raise ValueError(f"--seed: expected either --seed or --seeds, got --seed {args.seed} and --seeds "
                         f"{','.join(map(str, args.seeds))}")
    seed = 0 if args.seed is None else args.seed
    cfg = PipelineConfig(seed=seed, mjcf=args.mjcf,
                         identify=IdentifyConfig(seed=seed, bands_hz=_bands_hz(args)), design=_design_config(args))
    _check_mjcf(args)
    t0 = time.perf_counter()
    if args.seeds is not None:                  # several seeds, batched (nanosim.pipeline.seeds); parsed by its type
        from nanosim.pipeline.seeds import run_pipeline_seeds
        seeds = args.seeds
        with staged_run(args.out, seed=seeds[0]) as stage:
            doc = run_pipeline_seeds(stage, seeds, cfg)
        span = (f"{seeds[0]}-{seeds[-1]}" if seeds == tuple(range(seeds[0], seeds[-1] + 1))
                else ",".join(map(str, seeds)))
        print(f"pipeline done in {time.perf_counter() - t0:.1f} s for seeds {span}: checked quantities inside "
              f"their bands: mean {doc['in_band_mean']:.1f}, worst seed {doc['in_band_worst']} of {doc['banded']}; "
              f"report: {Path(args.out) / A.REPORT_MD}")
        return 0
    with staged_run(args.out, seed=seed) as stage:
        run_pipeline(stage, cfg)
        n_ok, n_band = pass_count(stage)
    report = Path(args.out) / A.REPORT_HTML
    print(f"pipeline done in {time.perf_counter() - t0:.1f} s; {n_ok} of {n_band} checked quantities inside "
          f"their bands; report: {report}")
    return 0


#: A file that marks a run folder of a command whose report that command writes itself.
_OWN_REPORT = ((A.MONTECARLO_JSON, "montecarlo"), (A.MC_BENCH_JSON, "montecarlo"), (A.SCORECARD_JSON, "compare"),
               (A.SWEEP_JSON, "sweep"))


def _check_run_kind(run, option: str, what: str) -> None:
    """Refuse a run folder written by ``montecarlo``, ``compare`` or ``sweep`` where ``what`` needs a
    pipeline/characterize run (its own report is written by that command).
    """
    for name, command in _OWN_REPORT:
        if name in run.files:
            raise ValueError(f"{option}: {str(run.path)!r} is a nanosim {command} run folder (it holds {name}); "
                             f"{what} a pipeline or characterize run, and nanosim {command} writes its own report")


def _cmd_report(args) -> int:
    from nanosim.pipeline.report import pass_count, write_report
    from nanosim.pipeline.runfolder import sealed_run, staged_run

    run = sealed_run(args.run)                  # refuse a folder whose files do not match its manifest
    _check_run_kind(run, "--run", "nanosim report rewrites the report of")
    with staged_run(args.run, keep_existing=True, seed=run.seed) as stage:
        write_report(stage)
        n_ok, n_band = pass_count(stage)
    print(f"{n_ok} of {n_band} checked quantities inside their bands; report: {Path(args.run) / A.REPORT_HTML}")
    return 0


def _cmd_ablation(args) -> int:
    import tempfile

    from nanosim.fileio import write_json, write_text
    from nanosim.pipeline.ablation import ablation_rows, markdown_table, run_ablation
    from nanosim.pipeline.report import write_report
    from nanosim.pipeline.runfolder import sealed_run, staged_run

    names = [r.name for r in ablation_rows()]
    unknown = [r for r in args.rows or () if r not in names]
    if unknown:
        raise ValueError(f"--rows: expected names among {names}, got {unknown}")
    run = sealed_run(args.run)                  # refuse a folder whose files do not match its manifest
    _check_run_kind(run, "--run", "nanosim ablation adds its table to")
    _check_mjcf(args)
    seed = 0 if run.seed is None else int(run.seed)
    with staged_run(args.run, keep_existing=True, seed=seed) as stage, tempfile.TemporaryDirectory() as work:
        res = run_ablation(work, seed=seed, twin=not args.mujoco, redesign=not args.fixed_controller,
                           rows=args.rows, mjcf=args.mjcf, log=lambda *a, **k: None, progress=True)
        write_json(stage / A.ABLATION_JSON, res)
        write_text(stage / A.ABLATION_MD, markdown_table(res))
        write_report(stage)
    print(f"ablation of {len(res['rows'])} rows (seed {seed}); report: {Path(args.run) / A.REPORT_HTML}")
    return 0


def _cmd_montecarlo(args) -> int:
    from nanosim.pipeline.mc_stats import CROSSCHECK_REL_TOL, load_spec
    from nanosim.pipeline.montecarlo import check_sample_count, run_montecarlo

    check_sample_count(args.n, args.crosscheck, args.workers)         # before any work, with the estimate

    _check_mjcf(args)
    for c in args.controller:
        _check_controller(c, args.mjcf)         # validate before any work (--scheduler's form: its type)
    if len(args.controller) > 1:
        from nanosim.pipeline.mc_bench import controller_names
        controller_names(args.controller)
    if args.spec:
        load_spec(args.spec)
    _check_mjcf(args)
    cfg = MonteCarloConfig(n=args.n, seed=args.seed, crosscheck=args.crosscheck, spec=args.spec,
                           scheduler=args.scheduler, workers=args.workers, mjcf=args.mjcf)
    if len(args.controller) > 1:
        from nanosim.pipeline.mc_bench import run_montecarlo_bench
        doc = run_montecarlo_bench(args.controller, args.out, cfg, say=_say)
        best = max(doc["controllers"], key=lambda r: (r["yield_percent"], r["disk_margin_alpha"]["p5"]))
        print(f"montecarlo of {len(doc['controllers'])} controllers done in {doc['wall_seconds']:.1f} s: "
              + ", ".join(f"{r['controller']} {r['pass']}/{r['n']}" for r in doc["controllers"])
              + f"; highest yield: {best['controller']}; report: {Path(args.out) / A.REPORT_MD}")
        return 0
    s = run_montecarlo(args.controller[0], args.out, cfg, say=_say)
    y = next(r for r in s["yield"] if r["metric"] == "all")
    tol = f"{100 * CROSSCHECK_REL_TOL:g} %"
    print(f"montecarlo done in {s['wall_seconds']:.1f} s: yield {y['pass']}/{y['n']} ({y['yield_percent']:.1f} %), "
          f"MuJoCo cross-check {s['crosscheck_pass']}/{s['crosscheck_n']} within {tol} or the reading resolution "
          f"of the twin's spread ({s.get('crosscheck_pass_without_spread', 0)} without the spread, "
          f"{s.get('crosscheck_pass_relative_only', 0)} within {tol} alone); "
          f"report: {Path(args.out) / A.REPORT_MD}")
    return 0


def _cmd_sweep(args) -> int:
    from nanosim.pipeline.config import SweepConfig
    from nanosim.pipeline.runfolder import staged_run
    from nanosim.pipeline.sweep import check_params, parse_param, run_sweep

    cfg = SweepConfig(params=tuple(parse_param(p) for p in args.param), seed=args.seed, design=_design_config(args),
                      scheduler=args.scheduler, workers=args.workers, mjcf=args.mjcf)
    _check_mjcf(args)
    check_params(cfg.params, cfg.mjcf)
    t0 = time.perf_counter()
    with staged_run(args.out, seed=args.seed) as stage:
        doc = run_sweep(stage, cfg, say=_say)
    print(f"sweep done in {time.perf_counter() - t0:.1f} s: {len(doc['points'])} points, {len(doc['pareto'])} on the "
          f"Pareto front; report: {Path(args.out) / A.REPORT_MD}")
    return 0


def _cmd_budget(args) -> int:
    from nanosim.pipeline.budget import run_budget
    from nanosim.pipeline.runfolder import staged_run

    controller = _check_controller(args.controller)         # validate before any work
    _check_mjcf(args)
    t0 = time.perf_counter()
    with staged_run(args.out, keep_existing=True, seed=args.seed) as stage:
        doc = run_budget(stage, controller, axis=C.AXES.index(args.axis), simulate_s=args.simulate or None,
                         seed=args.seed, mjcf=args.mjcf, progress=_say)
    chk = doc.get("check")
    extra = (f"; simulated {chk['simulated_table_nm']['total']:.3f} nm ({args.simulate:g} s records)" if chk else "")
    print(f"budget done in {time.perf_counter() - t0:.1f} s: {args.axis} table sigma "
          f"{doc['sigma_table_nm']['total']:.3f} nm (analytic){extra}: {Path(args.out) / A.BUDGET_JSON}")
    return 0


def _cmd_compare(args) -> int:
    from nanosim.pipeline.compare import check_controllers, check_only, run_compare
    from nanosim.pipeline.runfolder import staged_run

    check_only(args.only)                       # everything checked before any progress output
    check_controllers(args.controllers)
    if args.model is not None:
        _check_model(args.model)
    _check_mjcf(args)
    cfg = CompareConfig(controllers=tuple(args.controllers), seeds=args.seeds, twin=args.twin,
                        only=tuple(args.only) if args.only else None, model=args.model,
                        robustness=not args.no_robustness)
    t0 = time.perf_counter()
    with staged_run(args.out, seed=cfg.seeds[0]) as stage:
        doc = run_compare(stage, cfg, mjcf=args.mjcf, progress=_say)
    met = ", ".join(f"{n} {v['acceptance_met']}/{v['acceptance_total']}" for n, v in doc["controllers"].items())
    default = doc["default"] if doc["default"] is not None else f"none ({doc['default_reason']})"
    print(f"compare done in {time.perf_counter() - t0:.1f} s; measured criteria met on every seed: {met}; "
          f"default by the rule: {default}; "
          f"scorecard: {Path(args.out) / A.SCORECARD_MD}")
    return 0



def _cmd_scan(args) -> int:
    from nanosim.pipeline.runfolder import staged_run
    from nanosim.pipeline.scan import SCAN_JSON, ScanConfig, run_scan_folder

    patterns = tuple(dict.fromkeys(p.strip() for p in args.pattern.split(",")))
    cfg = ScanConfig(patterns=patterns, size_um=args.size, pixels=args.pixels, line_rate_hz=args.line_rate,
                     slow_axis=args.slow_axis, spiral_velocity=args.spiral_velocity,
                     freqs_hz=tuple(args.freqs) if args.freqs else None, placement=args.placement,
                     twin=args.twin, seed=args.seed, limit_fraction=args.limit / 100.0,
                     sweep_hz=tuple(args.sweep) if args.sweep else (), sweep_mujoco=args.sweep_mujoco)
    if args.freqs and not set(patterns) & {"lissajous", "rosette"}:
        raise ValueError("--freqs: applies to the lissajous and rosette patterns only")
    cfg.check()                                              # every option, before any work
    controller = _check_controller(args.controller)
    _check_mjcf(args)
    t0 = time.perf_counter()
    with staged_run(args.out, keep_existing=True, seed=args.seed) as stage:
        doc = run_scan_folder(stage, controller, cfg, mjcf=args.mjcf)
    summary = "; ".join(f"{n} {100 * m['image_error_fraction']:.2f} %" if m["image_error_fraction"] is not None
                        and math.isfinite(m["image_error_fraction"]) else f"{n} n/a (nothing imaged)"
                        for n, m in doc["patterns"].items())
    print(f"scan done in {time.perf_counter() - t0:.1f} s; image error (of the height range) at "
          f"{cfg.line_rate_hz:g} Hz: {summary}; {Path(args.out) / SCAN_JSON}")
    return 0

# --- parser --------------------------------------------------------------------------------
def _add_design_arguments(parser) -> None:
    parser.add_argument("--weights", default=None, type=_file,
                        help="JSON or TOML file with Wp, Wt, Wu (default: the paper's)")
    parser.add_argument("--reduced-order", dest="reduced_order", type=_int_at_least(1),
                        default=DEFAULT_REDUCED_ORDER,
                        help=f"states of the design model (default {DEFAULT_REDUCED_ORDER}; "
                             f"paper {PAPER_REDUCED_ORDER})")
    parser.add_argument("--damping-zeta", dest="damping_zeta", type=_float_in(0.0, 1.0),
                        default=DEFAULT_DAMPING_ZETA,
                        help="damping ratio the inner active-damping loop adds to the first mode "
                             f"(default {DEFAULT_DAMPING_ZETA}; 0 = no damping loop)")
    parser.add_argument("--paper-design", dest="paper_design", action="store_true",
                        help="export the paper's own design: 10-state model, single S/KS/T H-infinity loop, no "
                             "damping loop, no design delay (architecture mixsyn with the paper's settings)")
    parser.add_argument("--architecture", choices=DESIGN_ARCHITECTURES, default=DEFAULT_ARCHITECTURE,
                        help=f"exported controller (default {DEFAULT_ARCHITECTURE}: the four-block H-infinity "
                             "design, the paper's weights plus an input-disturbance channel, which damps the first "
                             "mode pair); any bench member (lqg, paper, robust, ...); mixsyn: the S/KS/T design of "
                             "--weights/--reduced-order/--damping-zeta, always made as the reference")


def build_parser() -> argparse.ArgumentParser:
    """The ``nanosim`` argument parser (one-line usage errors, exit 2)."""
    from nanosim.design.architectures import BENCH
    from nanosim.pipeline.montecarlo import MAX_SAMPLES
    from nanosim.pipeline.seeds import MAX_SEEDS
    from nanosim.pipeline.sweep import param_names          # the names parse_param accepts
    from nanosim.plant.modes import MODES_LIST_MAX_HZ

    mc_default = MonteCarloConfig()

    p = _OneLineParser(prog="nanosim", description=__doc__.splitlines()[0])
    p.add_argument("--version", action="version", version=f"nanosim {__version__}")
    out = _out_folder("--out")
    sub = p.add_subparsers(dest="command", required=True)
    seed_help = "seed of every random source (integer >= 0)"
    m = sub.add_parser("modes", help="modal analysis of the MJCF stage")
    m.add_argument("--mjcf", default=None, type=_file, help="stage MJCF (default: the bundled scene.xml)")
    m.add_argument("--json", action="store_true", help="print JSON (modes, static gain, closure violation)")
    m.add_argument("--plot", metavar="DIR", default=None, type=_out_folder("--plot"),
                   help="write one PNG per mode shape into DIR")
    m.add_argument("--fmax", type=_float_in(0.0, 1e6, lo_open=True), default=MODES_LIST_MAX_HZ,
                   help="list modes below this frequency (Hz, > 0)")
    m.set_defaults(func=_cmd_modes)
    i = sub.add_parser("identify", help="identify the 3x3 model from simulated experiments, or a model from "
                                        "your own record (--data)")
    i.add_argument("--out", required=True, type=out, help="run folder for artifacts")
    i.add_argument("--data", default=None, type=_file, metavar="FILE",
                   help="identify from this record instead of the simulated stage: .npz/.mat (v5, v7.3) with u "
                        "(samples x inputs), y (samples x outputs) and Ts (s), or .csv with columns t, u1..un, "
                        "y1..ym")
    i.add_argument("--seed", type=_int_at_least(0), default=0, help=seed_help)
    i.add_argument("--order", type=_int_at_least(0), default=None,
                   help=f"states per 3x1 column (default {PAPER_IDENTIFIED_ORDER_PER_COLUMN}, the paper's; "
                        "0: choose from the singular values); with --data the model's order (default: from the "
                        "singular values)")
    i.add_argument("--ideal", action="store_true", help="every electromechanical effect off")
    i.add_argument("--per-column-poles", dest="shared_poles", action="store_false",
                   help="keep each column's own estimate of every mode, as the paper (default: the modes the "
                        "columns share re-estimated jointly, one pole per mode)")
    i.add_argument("--paper-bands", action="store_true",
                   help="PRBS in the paper's 50/100/200 Hz bands only (default: also a 1 kHz band, which "
                        "excites the 740 Hz mode)")
    i.add_argument("--mjcf", default=None, type=_file)
    i.set_defaults(func=_cmd_identify)
    d = sub.add_parser("design", help="reduce the model and synthesize the controller (default: the four-block "
                                      "H-infinity design; --architecture NAME for another, --paper-design the paper's)")
    d.add_argument("--model", required=True, type=_file,
                   help="model.npz from 'nanosim identify', or a MATLAB .mat state space A, B, C, D, Ts")
    d.add_argument("--out", required=True, type=out)
    _add_design_arguments(d)
    d.add_argument("--mjcf", default=None, type=_file)
    d.set_defaults(func=_cmd_design)
    c = sub.add_parser("characterize", help="closed-loop experiments of the paper's Section 5")
    c.add_argument("--controller", required=True, type=_file, help="controller.npz from 'nanosim design'")
    c.add_argument("--out", required=True, type=out)
    c.add_argument("--only", default=None, help="run one registered experiment (hysteresis, creep, resolution, "
                                                "small_steps, bandwidth, tracking, contouring, ...)")
    c.add_argument("--twin", action="store_true", help="run against the linear twin (same electromechanics)")
    c.add_argument("--seed", type=_int_at_least(0), default=0, help=seed_help)
    c.add_argument("--mjcf", default=None, type=_file)
    c.add_argument("--feedforward", default=None, choices=("inverse-pi",),
                   help="hysteresis compensation: the inverse Prandtl-Ishlinskii operator of the piezo, open loop "
                        "(hysteresis) and behind the controller (hysteresis, tracking, contouring)")
    c.set_defaults(func=_cmd_characterize)
    pl = sub.add_parser("pipeline", help="run the whole chain on the bundled stage")
    pl.add_argument("--out", required=True, type=out, help="run folder for artifacts")
    pl.add_argument("--seed", type=_int_at_least(0), default=None, help=f"{seed_help}; default 0")
    pl.add_argument("--seeds", default=None, type=_seeds(sort=True), metavar="0-4",
                    help=f"several seeds (a range or a list, at most {MAX_SEEDS}), batched; one folder per seed and a "
                         "summary report")
    pl.add_argument("--mjcf", default=None, type=_file)
    pl.add_argument("--paper-bands", action="store_true",
                    help="identify with the paper's 50/100/200 Hz PRBS bands only (default: also a 1 kHz band)")
    _add_design_arguments(pl)
    pl.set_defaults(func=_cmd_pipeline)
    r = sub.add_parser("report", help="verify a run folder against its manifest and rewrite its report")
    r.add_argument("--run", required=True, metavar="DIR", help="run folder written by nanosim (with manifest.json)")
    r.set_defaults(func=_cmd_report)
    ab = sub.add_parser("ablation", help="the paper's controller with each stage-model element switched off or "
                                         "changed, to show what each contributes: adds ablation.json and its table "
                                         "to a run's report")
    ab.add_argument("--run", required=True, metavar="DIR", help="run folder written by nanosim (its seed is used)")
    ab.add_argument("--rows", nargs="+", default=None, metavar="ROW",
                    help="names of the rows to run (default all; an unknown name lists them)")
    ab.add_argument("--mujoco", action="store_true", help="MuJoCo mechanics instead of the linear twin (slow)")
    ab.add_argument("--fixed-controller", action="store_true",
                    help="keep the controller designed on the all-on stage instead of redesigning per row")
    ab.add_argument("--mjcf", default=None, type=_file)
    ab.set_defaults(func=_cmd_ablation)
    mc = sub.add_parser("montecarlo", help="controllers on a population of fabricated stages (tolerances)")
    mc.add_argument("--n", type=_int_at_least(1), default=mc_default.n,
                    help=f"number of fabricated stages (default {mc_default.n}, at most {MAX_SAMPLES}; the first "
                         "line states the estimated time)")
    mc.add_argument("--controller", required=True, type=_file, nargs="+", metavar="FILE",
                    help="controller.npz from 'nanosim design' (several: each on the same stages, "
                         "compared; one sub-folder each, named by the file)")
    mc.add_argument("--out", required=True, type=out, help="run folder (a rerun resumes it)")
    mc.add_argument("--seed", type=_int_at_least(0), default=0, help=seed_help)
    mc.add_argument("--spec", default=None, type=_file, help="JSON spec (limits with units); default: paper bands")
    mc.add_argument("--crosscheck", type=_int_at_least(0), default=mc_default.crosscheck,
                    help=f"samples rerun on MuJoCo (default {mc_default.crosscheck})")
    mc.add_argument("--scheduler", default=None, type=_scheduler,
                    help="Dask scheduler tcp://HOST:8786, or 'local' for a LocalCluster "
                         "(default: a local process pool)")
    mc.add_argument("--workers", type=_int_at_least(1), default=None, help="local worker processes (default: CPUs)")
    mc.add_argument("--mjcf", default=None, type=_file)
    mc.set_defaults(func=_cmd_montecarlo)
    sw = sub.add_parser("sweep", help="flexure design sweep: bandwidth vs travel vs resolution, Pareto front")
    sw.add_argument("--param", action="append", required=True, metavar="NAME=start:stop:n",
                    help=f"{param_names()}; repeat for a grid")
    sw.add_argument("--out", required=True, type=out, help="run folder for artifacts")
    sw.add_argument("--seed", type=_int_at_least(0), default=0, help=seed_help)
    sw.add_argument("--scheduler", default=None, type=_scheduler,
                    help="Dask scheduler tcp://HOST:8786, or 'local' (LocalCluster)")
    sw.add_argument("--workers", type=_int_at_least(1), default=None, help="local worker processes (default: CPUs)")
    sw.add_argument("--mjcf", default=None, type=_file)
    _add_design_arguments(sw)
    sw.set_defaults(func=_cmd_sweep)
    cp = sub.add_parser("compare", help="controllers through the Section 5 suite and the robustness analysis, "
                                        "scored (scorecard.md/.html/.json)")
    cp.add_argument("--controllers", nargs="+", required=True, metavar="CTRL",
                    help=f"bench names ({', '.join(BENCH)}), .npz/.mat state spaces (A, B, C, D, dt) or "
                         "module:function returning a controller object")
    compare_seeds = _field_default(CompareConfig, "seeds")
    cp.add_argument("--seeds", type=_seeds(sort=True), default=compare_seeds,
                    help=f"seeds, a range like 0-4 or a list (default {','.join(map(str, compare_seeds))}; "
                         f"at most {MAX_SEEDS})")
    cp.add_argument("--out", required=True, type=out, help="run folder for the scorecard")
    cp.add_argument("--model", default=None, help="identified model.npz (or a run folder holding one) for the "
                                                   "bench designs and the analysis (default: identify on the first "
                                                   "seed)")
    cp.add_argument("--twin", action="store_true", help="run against the linear twin (same electromechanics)")
    cp.add_argument("--only", nargs="+", default=None, metavar="EXP", help="run only these registered experiments")
    cp.add_argument("--no-robustness", dest="no_robustness", action="store_true",
                    help="skip robustness.json (the mu analysis takes ~10 s per controller)")
    cp.add_argument("--mjcf", default=None, type=_file)
    cp.set_defaults(func=_cmd_compare)
    from nanosim.pipeline.scan import DEFAULT_SWEEP_HZ, ScanConfig
    sc_default = ScanConfig()
    sc = sub.add_parser("scan", help="image a synthetic sample with raster, spiral, Lissajous or rosette scans in "
                                     "closed loop: image error, distortion, the line rate at an error limit")
    sc.add_argument("--pattern", default=",".join(sc_default.patterns), metavar="NAME[,NAME]",
                    help="raster, spiral, lissajous, rosette, or a comma list (default: all four)")
    sc.add_argument("--controller", required=True, type=_file, help="controller.npz from 'nanosim design'")
    sc.add_argument("--out", required=True, type=out, help="folder for scan.json, scan.npz, figures and scan.md "
                                                           "(a run folder: added to it)")
    sc.add_argument("--twin", action="store_true", help="run against the linear twin (same electromechanics)")
    sc.add_argument("--seed", type=_int_at_least(0), default=0, help=seed_help)
    sc.add_argument("--size", type=_float_in(0.0, 1e3, lo_open=True), default=sc_default.size_um, metavar="UM",
                    help=f"side of the square field, um (default {sc_default.size_um:g})")
    sc.add_argument("--pixels", type=_int_at_least(8), default=sc_default.pixels,
                    help=f"pixels per side (default {sc_default.pixels})")
    sc.add_argument("--line-rate", type=_float_in(0.0, 1e4, lo_open=True), default=sc_default.line_rate_hz,
                    metavar="HZ", help=f"lines per second; every pattern's frame lasts pixels / line rate "
                                       f"(default {sc_default.line_rate_hz:g})")
    sc.add_argument("--slow-axis", choices=("staircase", "ramp"), default=sc_default.slow_axis,
                    help="raster slow axis (default %(default)s)")
    sc.add_argument("--spiral-velocity", choices=("linear", "angular"), default=sc_default.spiral_velocity,
                    help="spiral at constant linear or angular velocity (default %(default)s)")
    sc.add_argument("--freqs", nargs=2, type=_float_in(0.0, 1e5, lo_open=True), default=None, metavar="HZ",
                    help="Lissajous f_x f_y or rosette f_1 f_2 (default: from the line rate, closing in one frame)")
    sc.add_argument("--placement", choices=("sensor", "reference"), default=sc_default.placement,
                    help="the image puts each record at the sensor reading or at the commanded position "
                         "(default %(default)s)")
    sc.add_argument("--limit", type=_float_in(0.0, 100.0, lo_open=True), default=100 * sc_default.limit_fraction,
                    metavar="PERCENT", help="image error limit, %% of the height range (default %(default)g)")
    sc.add_argument("--sweep", nargs="*", type=_float_in(0.0, 1e4, lo_open=True), default=list(DEFAULT_SWEEP_HZ),
                    metavar="HZ", help="line rates of the sweep (default %(default)s; --sweep alone: no sweep)")
    sc.add_argument("--sweep-mujoco", action="store_true",
                    help="run the sweep on MuJoCo too (default: on the linear twin, compiled; on MuJoCo it takes "
                         "hours)")
    sc.add_argument("--mjcf", default=None, type=_file)
    sc.set_defaults(func=_cmd_scan)
    bu = sub.add_parser("budget", help="closed-loop noise budget of a controller: each source's spectrum through "
                                       "the loop's transfer functions (analytic), stacked PSD and cumulative "
                                       "amplitude spectrum")
    bu.add_argument("--controller", required=True, type=_file, help="controller.npz from 'nanosim design'")
    bu.add_argument("--out", required=True, type=out, help="run folder (budget.json, budget.npz, figures)")
    bu.add_argument("--axis", choices=C.AXES, default="X", help="axis of the budget (default X)")
    bu.add_argument("--simulate", type=_float_in(0.0, 600.0), default=0.0, metavar="SECONDS",
                    help="also simulate the budget on the linear twin with records of this length (one source at "
                         "a time and all together) and compare (default 0: analytic only)")
    bu.add_argument("--seed", type=_int_at_least(0), default=0, help=seed_help)
    bu.add_argument("--mjcf", default=None, type=_file)
    bu.set_defaults(func=_cmd_budget)
    from nanosim.viewer import add_view_arguments, run_view
    v = sub.add_parser("view", help="browser 3D view (viser)")
    add_view_arguments(v)
    v.set_defaults(func=run_view)
    return p


def _options(parser: argparse.ArgumentParser, command: str) -> set:
    """The option strings of a subcommand (``--order``, ...)."""
    for action in parser._subparsers._group_actions:
        sub = action.choices.get(command)
        if sub is not None:
            return {o for a in sub._actions for o in a.option_strings}
    return set()


#: Exit status of a command stopped by SIGINT (Ctrl-C) and by SIGTERM: 128 + the signal's number.
EXIT_SIGINT, EXIT_SIGTERM = 128 + 2, 128 + 15


def main(argv=None) -> int:
    """Entry point; returns the exit status (0 ok, 2 user error, 130 SIGINT, 143 SIGTERM)."""
    parser = build_parser()
    args = parser.parse_args(argv)
    prog = f"nanosim {args.command}"
    with stop_signals():
        try:
            return int(args.func(args) or 0)
        except KeyboardInterrupt as exc:
            term = isinstance(exc, Terminated)
            kept = ("every finished sample is kept; a rerun resumes it" if args.command == "montecarlo"
                    else "the run folder was left as it was before this command")
            print(f"{prog}: {'terminated (SIGTERM)' if term else 'interrupted'}; {kept}", file=sys.stderr)
            status = EXIT_SIGTERM if term else EXIT_SIGINT
            if threading.active_count() > 1:    # experiment threads may be inside MuJoCo: finalizing under them crashes
                sys.stdout.flush()
                sys.stderr.flush()
                os._exit(status)
            return status
        except (ValueError, OSError) as exc:        # user errors, file-system errors included
            msg = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
            if isinstance(exc, OSError) and exc.filename and str(exc.filename) not in msg:
                msg = f"{msg}: {exc.filename}"
            field, sep, rest = msg.partition(": ")                  # a config field's error names its option
            if sep and field.isidentifier() and f"--{field.replace('_', '-')}" in _options(parser, args.command):
                msg = f"--{field.replace('_', '-')}: {rest}"
            print(f"{prog}: error: {msg}", file=sys.stderr)
            return 2


if __name__ == "__main__":
    sys.exit(main())
