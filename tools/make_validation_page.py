"""Generate the documentation's validation page (and the README's headline table) from run folders.

Usage::

    python tools/make_validation_page.py --runs runs/p0 runs/p1 ... [--compare runs/bench]
        [--montecarlo runs/mc] [--ablation runs/p1 ...] [--out docs/validation.md] [--readme README.md]

``--runs``: folders of ``nanosim pipeline`` (one per seed; the folders of ``nanosim pipeline --seeds`` too), read
through :func:`nanosim.pipeline.predictions.validation_rows` and :func:`~nanosim.pipeline.predictions.seed_summary`;
``--compare``: a ``nanosim compare`` folder (``scorecard.json``); ``--montecarlo``: a ``nanosim montecarlo`` folder
(``summary.json``); ``--ablation``: folders holding the ``ablation.json`` of ``nanosim ablation`` (one per
seed); with ``--ablation`` and no ``--runs`` the ablation table is written as a page of its own.
The calibrated parameters come from :data:`nanosim.calibrated.CALIBRATED_PARAMETERS`. Nothing on
the page is typed: every number is read from those files. ``--readme`` rewrites the block between
``<!-- headline:begin -->`` and ``<!-- headline:end -->`` of the README with the headline table.
"""
from __future__ import annotations

import argparse
import json
import math
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from nanosim import __version__  # noqa: E402
from nanosim.calibrated import CALIBRATED_PARAMETERS  # noqa: E402
from nanosim.paper import PAPER  # noqa: E402
from nanosim.pipeline.predictions import seed_summary, validation_rows  # noqa: E402

BEGIN, END = "<!-- headline:begin -->", "<!-- headline:end -->"
# closed-loop figures over the seeds: label, unit, paper value, whether higher is better
SEED_ROWS = {"settling_ms": ("2 um step settling (2 %)", "ms", PAPER["settle"], False),
             "overshoot_percent": ("2 um step overshoot", "%", None, False),
             "bandwidth_S_hz": ("S bandwidth (reference to error)", "Hz", PAPER["bwS"], True),
             "sigma_closed_nm": ("closed-loop sigma, sensor", "nm", PAPER["sig_c"], False),
             "sigma_closed_table_nm": ("closed-loop sigma, true table position", "nm", None, False),
             "sigma_open_nm": ("open-loop sigma at rest", "nm", PAPER["sig_o"], False),
             "contour_mean_nm_1000": ("contour error, mean at 1000 um/s", "nm", PAPER["contour_mean"], False)}
HEADLINE = ("bandwidth_S_hz", "settling_ms", "sigma_closed_nm", "contour_mean_nm_1000")


def fmt(v) -> str:
    """A cell: 3 significant digits, lists joined, None as n/a."""
    if v is None or (isinstance(v, float) and math.isnan(v)):
        return "n/a"
    if isinstance(v, (list, tuple)):
        return ", ".join(fmt(x) for x in v)
    if isinstance(v, bool):
        return "yes" if v else "no"
    if isinstance(v, (int, np.integer)):
        return str(int(v))
    if isinstance(v, (float, np.floating)):
        return f"{v:.3g}" if abs(v) < 1e4 else f"{v:.0f}"
    return str(v)


def table(head: list, rows: list) -> list[str]:
    """Markdown table lines."""
    out = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    out += ["| " + " | ".join(fmt(c) if not isinstance(c, str) else c for c in r) + " |" for r in rows]
    return out


def run_folders(paths) -> list[Path]:
    """Each path as a run folder; a ``nanosim pipeline --seeds`` folder gives its seed folders."""
    out = []
    for p in map(Path, paths):
        if (p / "metrics.json").is_file():
            out.append(p)
        else:
            out += sorted(d for d in p.iterdir() if (d / "metrics.json").is_file())
    if not out:
        raise SystemExit("--runs: expected folders of nanosim pipeline (with metrics.json), "
                         f"got {list(map(str, paths))}")
    return out


def seed_of(run: Path) -> str:
    """The run's seed from ``pipeline.json``."""
    try:
        return str(json.loads((run / "pipeline.json").read_text()).get("seed", "?"))
    except (OSError, ValueError):
        return "?"


def _scalar(v):
    return float(v) if isinstance(v, (int, float)) and not isinstance(v, bool) else None


def paper_vs_simulation(runs: list[Path]) -> list[str]:
    """Every checked quantity: the paper, the mean and the range over the runs, fitted or predicted."""
    per = [validation_rows(r) for r in runs]
    rows = []
    for i, first in enumerate(per[0]):
        vals = [p[i]["simulation"] for p in per if i < len(p)]
        nums = [x for x in map(_scalar, vals) if x is not None]
        if nums and len(nums) == len(vals):
            sim, rng = float(np.mean(nums)), f"{fmt(min(nums))} - {fmt(max(nums))}"
        else:
            sim, rng = vals[0], "-"
        rows.append([first["quantity"], first["paper"], sim, rng, first["unit"], first["status"], first["note"]])
    return table(["quantity", "paper", "simulation (mean)", "range over runs", "unit", "fitted or predicted", "note"],
                 rows)


def closed_loop(runs: list[Path]) -> tuple[list[str], dict]:
    """Mean and worst over the runs of the closed-loop figures."""
    stats = seed_summary(runs)["stats"]
    rows, worst = [], {}
    for key, (label, unit, paper, higher) in SEED_ROWS.items():
        st = stats.get(key)
        if not st:
            continue
        worst[key] = st["min"] if higher else st["max"]
        rows.append([label, paper, st["mean"], worst[key], unit, st["n"]])
    return table(["quantity", "paper", "mean", "worst", "unit", "runs"], rows), stats


def calibrated() -> list[str]:
    """The calibrated parameters (nanosim.calibrated)."""
    rows = []
    for p in CALIBRATED_PARAMETERS:
        bound = "none" if p.bound is None else f"[{fmt(p.bound[0])}, {fmt(p.bound[1])}]"
        kind = "fit bound" if p.bounded else "checked range"
        rows.append([p.name, p.value, p.unit, f"{bound} ({kind})" if p.bound else bound, p.on_bound,
                     p.source_figure, p.method])
    return table(["parameter", "value", "unit", "bound", "on bound", "fitted to", "how"], rows)


def scorecard(folder: Path) -> list[str]:
    """Acceptance of every controller of a ``nanosim compare`` folder, worst case over its seeds."""
    doc = json.loads((folder / "scorecard.json").read_text())
    keys = list(doc["acceptance"])
    rows = []
    for name, c in doc["controllers"].items():
        acc = c["acceptance"]
        cells = [f"{fmt(acc[k]['worst'])} {'✓' if acc[k]['pass'] else ('✗' if acc[k]['pass'] is False else '')}"
                 for k in keys]
        rows.append([f"`{name}`", f"{c['acceptance_met']} / {c['acceptance_total']}", *cells])
    out = [f"Plant: {doc['plant']}; seeds {', '.join(map(str, doc['seeds']))}. Worst case over the seeds against the "
           "bench specification (`nanosim/pipeline/scorecard.py`, `ACCEPTANCE`): "
           + "; ".join(f"`{k}` {v}" for k, v in doc["acceptance"].items()) + ".", ""]
    out += table(["controller", "criteria met", *[f"`{k}`" for k in keys]], rows)
    out += ["", f"Default by the rule: `{doc.get('default')}` ({doc.get('default_reason')})."]
    return out


def architecture(controller_npz: str) -> str:
    """The ``method`` a controller file states (its bench architecture), or ``unknown`` when the file is gone."""
    try:
        with np.load(controller_npz) as z:
            return str(z["method"]) if "method" in z.files else "unknown"
    except OSError:
        return "unknown"


def montecarlo(folder: Path) -> list[str]:
    """The yield table of a ``nanosim montecarlo`` folder (or of each controller's folder inside it)."""
    out = []
    own = folder / "summary.json"
    if own.is_file() and "yield" in json.loads(own.read_text()):
        folders = [folder]
    else:                   # several controllers: one Monte Carlo folder each
        folders = sorted(d for d in folder.iterdir() if (d / "summary.json").is_file())
    bench = folder / "montecarlo_bench.json"
    files = json.loads(bench.read_text())["controllers"] if bench.is_file() else {}
    for f in folders:
        s = json.loads((f / "summary.json").read_text())
        name = f"{f.name} (`{architecture(files[f.name]['file'])}`)" if f.name in files else f.name
        rows = [[y["label"], f"`{y['metric']}`", f"{y['pass']}/{y['n']}", y["yield_percent"],
                 f"{fmt(y['ci95_percent'][0])} - {fmt(y['ci95_percent'][1])}", y.get("median"), y.get("worst"),
                 y["unit"]] for y in s["yield"]]
        out += [f"**{name}**: {s['n']} fabricated stages, tolerance seed {s['seed']}; cross-checked on MuJoCo: "
                f"{s.get('crosscheck_pass', 0)} of {s.get('crosscheck_n', 0)} agree.", ""]
        out += table(["limit", "metric", "pass", "yield [%]", "95 % Wilson interval [%]", "median", "worst", "unit"],
                     rows) + [""]
    return out


MECHANICS = {"twin": "the linear twin in the bench's electromechanics", "mujoco": "MuJoCo"}
ABLATION_COLUMNS = {"settling_ms": "settling (ms)", "sigma_closed_nm": "sigma closed, sensor (nm)",
                    "sigma_closed_table_nm": "sigma closed, table (nm)",
                    "contour_mean_nm_1000": "contour mean at 1000 um/s (nm)", "bandwidth_S_hz": "S bandwidth (Hz)"}


def ablation(folders) -> list[str]:
    """The ablation rows of ``nanosim ablation`` folders: each row's mean over the folders (seeds) and their range."""
    docs = [json.loads((Path(f) / "ablation.json").read_text()) for f in folders]
    first = docs[0]
    mech = sorted({d["mechanics"] for d in docs})
    seeds = ", ".join(str(d["seed"]) for d in docs)
    how = "the controller redesigned per row" if first["redesign"] else "the controller of the all-on stage"
    out = [f"The paper's procedure (identification, 10-state model, the paper's weights) on the stage with one bench "
           f"element switched off or changed per row; {how}; "
           f"mechanics: {', '.join(MECHANICS.get(m, m) for m in mech)}; seed(s) {seeds}. Mean over the seeds (range "
           "when there are several).", ""]
    by_name = {}
    for d in docs:
        for r in d["rows"]:
            by_name.setdefault(r["name"], (r["change"], []))[1].append(r)
    t = first["targets"]
    rows = [["paper", "", *[t.get(k, "") if k != "sigma_closed_table_nm" else "" for k in ABLATION_COLUMNS]]]
    for name, (change, rs) in by_name.items():
        cells = []
        for k in ABLATION_COLUMNS:
            v = np.array([r[k] for r in rs], float)
            cells.append(fmt(float(np.mean(v))) if len(v) == 1 else
                         f"{fmt(float(np.mean(v)))} ({fmt(float(np.min(v)))} - {fmt(float(np.max(v)))})")
        rows.append([name, change, *cells])
    return out + table(["row", "change", *ABLATION_COLUMNS.values()], rows)


def ablation_page(folders) -> str:
    """A page of its own holding only the ablation table of ``folders``."""
    cmd = "python tools/make_validation_page.py --ablation " + " ".join(map(str, folders))
    lines = ["# Ablation", "", "```{note}", "This page is generated from the ablation.json that `nanosim ablation "
             "--run RUN` writes for a `nanosim pipeline --paper-design` run folder; do not edit it. Regenerate with",
             "",
             f"    {cmd} --out docs/ablation.md", "```", "", f"nanosim {__version__}.", ""]
    return "\n".join(lines + ablation(folders)).rstrip() + "\n"


def headline(stats: dict, n_runs: int) -> list[str]:
    """The README's one table: the paper's closed-loop figures against the simulation's mean and worst."""
    rows = []
    for key in HEADLINE:
        label, unit, paper, higher = SEED_ROWS[key]
        st = stats.get(key)
        if st:
            rows.append([label, f"{fmt(paper)} {unit}", f"{fmt(st['mean'])} {unit}",
                         f"{fmt(st['min'] if higher else st['max'])} {unit}"])
    return table(["", "paper", f"simulation, mean of {n_runs} seed(s)", "worst"], rows)


def page(args) -> tuple[str, list[str]]:
    """The page's markdown and the headline table."""
    runs = run_folders(args.runs)
    cmd = "python tools/make_validation_page.py --runs " + " ".join(map(str, args.runs))
    if args.compare:
        cmd += f" --compare {args.compare}"
    if args.montecarlo:
        cmd += f" --montecarlo {args.montecarlo}"
    if args.ablation:
        cmd += " --ablation " + " ".join(map(str, args.ablation))
    cl, stats = closed_loop(runs)
    lines = ["# Validation", "",
             "```{note}", "This page is generated from run folders; do not edit it. Regenerate with", "",
             f"    {cmd} --out docs/validation.md", "```", "",
             f"nanosim {__version__}; pipeline runs of seeds {', '.join(seed_of(r) for r in runs)} "
             f"(MuJoCo stage, every effect on).", "",
             "## Paper vs simulation", "",
             "Fitted: a model parameter was set from this paper number (see the calibrated parameters below). "
             "Predicted: nothing was set from it.", ""]
    lines += paper_vs_simulation(runs) + ["", "## Closed loop over the seeds", ""] + cl
    lines += ["", "## Calibrated parameters", "",
              "The parameters set by fitting the model to a paper figure (`nanosim.calibrated`); every other "
              "parameter has a datasheet, the paper or the geometry as its source.", ""] + calibrated()
    if args.compare:
        lines += ["", "## Bench scorecard", ""] + scorecard(Path(args.compare))
    if args.montecarlo:
        lines += ["", "## Monte Carlo yield", ""] + montecarlo(Path(args.montecarlo))
    if args.ablation:
        lines += ["", "## Ablation: what each bench element does to the paper's design", ""] + ablation(args.ablation)
    return "\n".join(lines).rstrip() + "\n", headline(stats, len(runs))


def replace_headline(readme: Path, table_lines: list[str]) -> None:
    """Rewrite the README's marked headline block."""
    text = readme.read_text()
    if BEGIN not in text or END not in text:
        raise SystemExit(f"--readme: expected {BEGIN} and {END} in {readme}")
    head, rest = text.split(BEGIN, 1)
    _, tail = rest.split(END, 1)
    readme.write_text(head + BEGIN + "\n" + "\n".join(table_lines) + "\n" + END + tail)


def main(argv=None) -> int:
    """Command line (see the module docstring)."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--runs", nargs="+", help="nanosim pipeline folders (one per seed); without them, only the "
                                              "--ablation table is written, as a page of its own")
    ap.add_argument("--compare", help="a nanosim compare folder (scorecard.json)")
    ap.add_argument("--montecarlo", help="a nanosim montecarlo folder (summary.json)")
    ap.add_argument("--ablation", nargs="+", help="folders with the ablation.json of nanosim ablation (one per seed)")
    ap.add_argument("--out", default=str(ROOT / "docs" / "validation.md"), help="the page to write")
    ap.add_argument("--readme", help="README whose marked headline block is rewritten")
    args = ap.parse_args(argv)
    if not args.runs:
        if not args.ablation or args.readme:
            raise SystemExit("--runs: expected folders of nanosim pipeline (or --ablation alone, without --readme)")
        Path(args.out).write_text(ablation_page(args.ablation))
        print(f"wrote {args.out}")
        return 0
    text, head = page(args)
    Path(args.out).write_text(text)
    if args.readme:
        replace_headline(Path(args.readme), head)
    print(f"wrote {args.out}" + (f" and the headline of {args.readme}" if args.readme else ""))
    return 0


if __name__ == "__main__":
    sys.exit(main())
