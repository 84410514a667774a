"""Mean and spread of the paper's controller over several pipeline runs.

Usage::

    nanosim pipeline --out runs/pd_s0 --seed 0 --paper-design     # ... one run per seed
    python tools/paper_design_seeds.py runs/pd_s0 runs/pd_s1 ... [--out runs/pd_s0]

Prints the table and, with ``--out``, writes ``paper_design_seeds.json`` there
(the report of that run folder then shows it: ``nanosim report --run DIR``).
"""
from __future__ import annotations

import argparse
import json
from pathlib import Path

from nanosim.pipeline.artifacts import PAPER_DESIGN_SEEDS_JSON
from nanosim.pipeline.predictions import seed_summary


def main(argv=None) -> int:
    """Aggregate the run folders given on the command line."""
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("runs", nargs="+", help="pipeline run folders (one per seed)")
    p.add_argument("--out", default=None, help=f"folder to write {PAPER_DESIGN_SEEDS_JSON} into")
    a = p.parse_args(argv)
    res = seed_summary(a.runs)
    print("| quantity | mean | min | max | n |\n|---|---|---|---|---|")
    for k, s in res["stats"].items():
        print(f"| {k} | {s['mean']:.3g} | {s['min']:.3g} | {s['max']:.3g} | {s['n']} |")
    if a.out:
        Path(a.out, PAPER_DESIGN_SEEDS_JSON).write_text(json.dumps(res, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
