"""Ablation of the paper's controller on the simulated stage.

Usage::

    OPENBLAS_NUM_THREADS=1 python tools/paper_design_ablation.py --out runs/ablation [--seed 0]
        [--mujoco] [--fixed-controller] [--rows "v2,no creep,..."] [--mechanism CONTROLLER_NPZ]

Writes ``ablation.json`` and ``ablation.md`` into ``--out``. See
:mod:`nanosim.pipeline.ablation` for the rows and what each one changes.
"""
from __future__ import annotations

import argparse
import json
from pathlib import Path

from nanosim.pipeline import artifacts as A
from nanosim.pipeline.ablation import ablation_rows, markdown_table, ring_mechanism, run_ablation


def main(argv=None) -> int:
    """Parse the arguments, run the rows, write the files."""
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--out", required=True, help=f"folder for {A.ABLATION_JSON} and {A.ABLATION_MD}")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--mujoco", action="store_true", help="MuJoCo mechanics instead of the linear twin")
    p.add_argument("--fixed-controller", action="store_true",
                   help="keep the controller designed on the all-on stage (attribution) instead of redesigning")
    p.add_argument("--rows", default=None, help="comma-separated row names; default all: "
                   + ", ".join(r.name for r in ablation_rows()))
    p.add_argument("--mechanism", default=None, metavar="CONTROLLER_NPZ",
                   help="only the ring-mechanism cases with this controller (noise off), into ring_mechanism.json")
    a = p.parse_args(argv)
    if a.mechanism:
        rows = ring_mechanism(a.mechanism, twin=not a.mujoco)
        Path(a.out).mkdir(parents=True, exist_ok=True)
        Path(a.out, "ring_mechanism.json").write_text(json.dumps(rows, indent=1))
        for r in rows:
            print(f"| {r['case']} | {r['settling_ms']:.1f} ms | {r['overshoot_percent']:.1f} % | "
                  f"{r['rms_after_20ms_nm']:.1f} nm |")
        return 0
    rows = [r.strip() for r in a.rows.split(",")] if a.rows else None
    res = run_ablation(a.out, seed=a.seed, twin=not a.mujoco, redesign=not a.fixed_controller, rows=rows)
    out = Path(a.out)
    (out / A.ABLATION_JSON).write_text(json.dumps(res, indent=1))
    (out / A.ABLATION_MD).write_text(markdown_table(res))
    print(markdown_table(res))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
