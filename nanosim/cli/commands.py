"""The commands of the ``nanosim`` command line: parsed arguments -> config dataclasses -> pipeline steps."""
from __future__ import annotations

import json
import math
import sys
import time
from pathlib import Path

from nanosim.validation import named_message
from nanosim import constants as C
from nanosim.pipeline import artifacts as A
from nanosim.pipeline.config import (CharacterizeConfig, CompareConfig, DesignConfig,
                                     IdentifyConfig, MonteCarloConfig, PipelineConfig)
from nanosim.paper import PAPER_IDENTIFIED_ORDER_PER_COLUMN, PAPER_PRBS_BANDS_HZ
from nanosim.cli.checks import (_check_controller, _check_mjcf, _check_model, _check_model_mat, _check_weights,
                                _load_mjcf)


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
    cfg = CharacterizeConfig(seed=args.seed, only=args.only, twin=args.twin, feedforward=args.feedforward,
                             drive=args.drive)
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
