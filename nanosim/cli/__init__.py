"""``nanosim`` command line: modes, identify, design, characterize, pipeline, report, ablation, montecarlo,
sweep, compare, scan, budget, view.

argparse -> config dataclasses (:mod:`nanosim.pipeline.config`, the only home
of defaults) -> pipeline steps. Every user error prints one line and exits 2. The parser and
:func:`main` are here, the commands in :mod:`nanosim.cli.commands`, the argument types and input checks
in :mod:`nanosim.cli.checks`.
"""
from __future__ import annotations

import argparse
import os
import sys
import threading

from nanosim import __version__
from nanosim import constants as C
from nanosim.validation import Terminated
from nanosim.pipeline.workers import stop_signals
from nanosim.pipeline.config import (DEFAULT_ARCHITECTURE, DEFAULT_DAMPING_ZETA, DEFAULT_REDUCED_ORDER,
                                     DESIGN_ARCHITECTURES, CompareConfig, MonteCarloConfig)
from nanosim.paper import PAPER_IDENTIFIED_ORDER_PER_COLUMN, PAPER_REDUCED_ORDER
from nanosim.cli.checks import (_OneLineParser, _field_default, _file, _float_in, _int_at_least, _out_folder,
                                _scheduler, _seeds)
from nanosim.cli.commands import (_cmd_ablation, _cmd_budget, _cmd_characterize, _cmd_compare, _cmd_design,
                                  _cmd_identify, _cmd_modes, _cmd_montecarlo, _cmd_pipeline,
                                  _cmd_report, _cmd_scan, _cmd_sweep)

__all__ = ["build_parser", "main"]


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
    from nanosim.design.architectures import DESIGN_RULES
    from nanosim.pipeline.montecarlo import MAX_SAMPLES
    from nanosim.pipeline.seeds import MAX_SEEDS
    from nanosim.pipeline.sweep import param_names          # the names parse_param accepts
    from nanosim.plant.modes import MODES_LIST_MAX_HZ

    mc_default = MonteCarloConfig()

    p = _OneLineParser(prog="nanosim", description=" ".join(__doc__.split("\n\n")[0].split()))
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
                        "excites the stage's sixth mode; paper: 740 Hz)")
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
                   help="hysteresis compensation: the inverse of a Prandtl-Ishlinskii operator fitted to the "
                        "stage's piezo, open loop (hysteresis) and behind the controller (hysteresis, tracking, "
                        "contouring)")
    c.add_argument("--drive", default="voltage", choices=("voltage", "charge"),
                   help="piezo amplifier of every experiment: voltage (the bench's) or a charge amplifier "
                        "(hysteresis reduced above its 0.1 Hz crossover, voltage drive below it)")
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
                    help=f"named designs ({', '.join(DESIGN_RULES)}), .npz/.mat state spaces (A, B, C, D, dt), "
                         "or module:function / path/to/file.py:function returning a controller object, a "
                         "DiscreteController/ControllerConfig or a discrete StateSpace")
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
    from nanosim.design.robustness import analysis_memo
    with stop_signals(), analysis_memo():           # one memory of loop analyses per command
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

