"""``nanosim`` command line: modes, identify, design, characterize, pipeline, view."""
from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path


def _cmd_modes(args) -> int:
    from .model import load_model
    from .modes import modal_analysis, modes_json, plot_mode_shapes

    model = load_model(args.mjcf)
    if args.plot:
        res = modal_analysis(model)
        for p in plot_mode_shapes(model, res, args.plot, fmax_hz=args.fmax):
            print(p)
        return 0
    data = modes_json(model, fmax_hz=args.fmax)
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


def _cmd_pipeline(args) -> int:
    from ._io import write_json
    from .model import load_model
    from .modes import modes_json

    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    timings = {}
    stages = _pipeline_stages()
    try:
        from tqdm import tqdm
        bar = tqdm(total=len(stages), desc="nanosim pipeline", unit="stage", file=sys.stderr)
    except ImportError:  # pragma: no cover
        bar = None
    for name, fn in stages:
        t0 = time.perf_counter()
        if bar:
            bar.set_postfix_str(name)
        fn(args, out)
        timings[name] = round(time.perf_counter() - t0, 2)
        if bar:
            bar.update(1)
    if bar:
        bar.close()
    write_json(out / "pipeline.json", {"stage_seconds": timings, "seed": args.seed})
    print(f"pipeline done in {sum(timings.values()):.1f} s: {timings}; results in {out}")
    return 0


def _stage_modes(args, out: Path) -> None:
    from ._io import write_json
    from .model import load_model
    from .modes import modes_json

    write_json(out / "modes.json", modes_json(load_model(args.mjcf)))


def _pipeline_stages():
    return [("modes", _stage_modes)]


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="nanosim", description=__doc__)
    sub = p.add_subparsers(dest="command", required=True)
    m = sub.add_parser("modes", help="modal analysis of the MJCF stage")
    m.add_argument("--mjcf", default=None, help="stage MJCF (default: bundled mjcf/scene.xml)")
    m.add_argument("--json", action="store_true", help="print JSON (modes, static gain, closure violation)")
    m.add_argument("--plot", metavar="DIR", default=None, help="write one PNG per mode shape into DIR")
    m.add_argument("--fmax", type=float, default=1000.0, help="list modes below this frequency (Hz)")
    m.set_defaults(func=_cmd_modes)
    pl = sub.add_parser("pipeline", help="run the whole chain on the bundled stage")
    pl.add_argument("--out", required=True, help="run folder for artifacts")
    pl.add_argument("--seed", type=int, default=0)
    pl.add_argument("--mjcf", default=None)
    pl.set_defaults(func=_cmd_pipeline)
    try:
        from .viewer import add_view_arguments, run_view
    except Exception:  # viewer optional at import time
        add_view_arguments = None
    if add_view_arguments is not None:
        v = sub.add_parser("view", help="browser 3D view (viser)")
        add_view_arguments(v)
        v.set_defaults(func=run_view)
    return p


def main(argv=None) -> int:
    args = build_parser().parse_args(argv)
    try:
        return int(args.func(args) or 0)
    except (ValueError, FileNotFoundError) as exc:
        print(f"nanosim {args.command}: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        return 130


if __name__ == "__main__":
    sys.exit(main())
