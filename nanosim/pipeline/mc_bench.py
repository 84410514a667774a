"""``nanosim montecarlo --controller A.npz B.npz ...``: several controllers on the same fabricated stages.

Each controller runs the Monte Carlo of :mod:`nanosim.pipeline.montecarlo` into its own sub-folder
(``OUT/<name>/``, a complete Monte Carlo folder that resumes on its own), with the same seed, so every
controller meets the same ``n`` stages and the same noise. The top folder then compares them:

* ``montecarlo_bench.json`` -- the plan (seed, each controller's name, file and sha256); a rerun with
  another seed or another controller under a name already used is refused;
* ``summary.json`` -- per controller: the yield over every limit with its 95 % interval, the yield of each
  limit, the twin's disk margin alpha over the samples (median, 5th percentile, worst), the median and worst
  of each limit's metric, and the MuJoCo cross-check count;
* ``fig_mc_bench.png`` and ``report.md``; ``manifest.json`` last.

Names are the files' stems (``lqg.npz`` -> ``lqg``); files that share a stem are named by their folder.
"""
from __future__ import annotations

import json
import math
import sys
from pathlib import Path

import numpy as np

from nanosim.fileio import save_figure, write_json, write_text
from nanosim.pipeline import artifacts as A
from nanosim.pipeline.config import MonteCarloConfig
from nanosim.pipeline.montecarlo import load_sample_flats, run_montecarlo
from nanosim.pipeline.runfolder import (MANIFEST_JSON, RunFolderError, check_writable, sha256_file, write_manifest,
                                        writer_lock)

__all__ = ["controller_names", "run_montecarlo_bench", "bench_rows", "bench_report_markdown"]

# the disk margin's sample-level name (``samples/*.json``): the worse of the piezo's two ends, worst location
ALPHA = "disk_margin_alpha"


def controller_names(paths) -> dict:
    """``{name: path}`` for the controller files ``paths``: each file's stem, or ``folder-stem`` where stems
    repeat.

    Raises
    ------
    ValueError
        Fewer than two files, or two files that would share a name.
    """
    paths = [Path(p) for p in paths]
    if len(paths) < 2:
        raise ValueError(f"controller: expected at least two files to compare, got {len(paths)}")
    stems = [p.stem for p in paths]
    names = [f"{p.resolve().parent.name}-{p.stem}" if stems.count(p.stem) > 1 else p.stem for p in paths]
    for i, n in enumerate(names):
        if n in names[:i]:
            raise ValueError(f"controller: {str(paths[names.index(n)])!r} and {str(paths[i])!r} share the name "
                             f"{n!r}; rename one file")
        if n in (A.MANIFEST_JSON, A.SUMMARY_JSON, A.MC_BENCH_JSON, A.REPORT_MD, A.FIG_MC_BENCH) or n.startswith("."):
            raise ValueError(f"controller: {str(paths[i])!r} gives the name {n!r}, which is reserved; rename it")
    return dict(zip(names, paths))


def _check_out(out: Path, plan: dict) -> None:
    """Refuse an ``out`` holding another kind of folder, another seed, or another controller under a used name."""
    prev = out / A.MC_BENCH_JSON
    if prev.is_file():
        try:
            old = json.loads(prev.read_text())
        except ValueError:
            old = None
        if not isinstance(old, dict) or old.get("seed") != plan["seed"]:
            raise RunFolderError(f"--out: {str(out)!r} holds a Monte Carlo comparison with another seed; "
                                 "choose another folder")
        clash = [n for n, c in plan["controllers"].items()
                 if n in old.get("controllers", {}) and old["controllers"][n]["sha256"] != c["sha256"]]
        if clash:
            raise RunFolderError(f"--out: {str(out)!r} holds another controller named {clash[0]!r}; "
                                 "choose another folder")
    elif out.is_dir() and any(out.iterdir()):
        raise RunFolderError(f"--out: {str(out)!r} is not empty and holds no Monte Carlo comparison; "
                             "choose another folder")


def _quantiles(v: np.ndarray) -> dict:
    v = v[np.isfinite(v)]
    if not v.size:
        return {"median": math.nan, "p5": math.nan, "worst": math.nan, "n": 0}
    return {"median": float(np.median(v)), "p5": float(np.percentile(v, 5)), "worst": float(v.min()),
            "n": int(v.size)}


def bench_rows(summaries: dict, flats: dict) -> list[dict]:
    """One row per controller from its Monte Carlo ``summary.json`` content and its samples' flat records.

    Parameters
    ----------
    summaries : dict
        ``{name: summary}`` (:func:`nanosim.pipeline.montecarlo.summarize`'s result).
    flats : dict
        ``{name: [flat record per sample]}`` (:func:`nanosim.pipeline.montecarlo.load_sample_flats`).
    """
    rows = []
    for name, s in summaries.items():
        every = next(r for r in s["yield"] if r["metric"] == "all")
        alpha = np.array([f.get(ALPHA, math.nan) for f in flats[name]], float)
        rows.append({"controller": name, "n": every["n"], "pass": every["pass"],
                     "yield_percent": every["yield_percent"], "ci95_percent": every["ci95_percent"],
                     "disk_margin_alpha": _quantiles(alpha),
                     "limits": {r["metric"]: {k: r.get(k) for k in ("label", "unit", "min", "max", "pass",
                                                                    "yield_percent", "median", "worst")}
                                for r in s["yield"] if r["metric"] != "all"},
                     "crosscheck_pass": s.get("crosscheck_pass", 0), "crosscheck_n": s.get("crosscheck_n", 0),
                     "errors": len(s.get("errors") or {})})
    return rows


def _fmt(v, digits: int = 4) -> str:
    if v is None or (isinstance(v, float) and not math.isfinite(v)):
        return "n/a"
    return f"{v:.{digits}g}" if isinstance(v, float) else str(v)


def bench_report_markdown(doc: dict) -> str:
    """``report.md`` of a Monte Carlo comparison (``summary.json``'s content)."""
    rows = doc["controllers"]
    lines = [f"# Monte Carlo comparison: {len(rows)} controllers on the same {rows[0]['n'] if rows else 0} "
             f"fabricated stages (seed {doc['seed']})", "",
             "Every controller meets the same stages (tolerances: each sub-folder's `tolerances.json`) and the "
             "same noise; each sub-folder is that controller's complete Monte Carlo (`report.md` there). Disk "
             "margin alpha: the loop with each stage's linear twin, worst loop location and the worse of the "
             "piezo's two ends.", "",
             "| controller | yield, every limit | 95 % CI | disk margin alpha: median | 5th percentile | worst | "
             "MuJoCo cross-check | samples with errors |", "|---|---|---|---|---|---|---|---|"]
    for r in rows:
        a = r["disk_margin_alpha"]
        ci = r["ci95_percent"]
        lines.append(f"| `{r['controller']}` | {r['pass']}/{r['n']} ({_fmt(r['yield_percent'])} %) | "
                     f"{_fmt(ci[0])}-{_fmt(ci[1])} % | {_fmt(a['median'], 3)} | {_fmt(a['p5'], 3)} | "
                     f"{_fmt(a['worst'], 3)} | {r['crosscheck_pass']}/{r['crosscheck_n']} | {r['errors']} |")
    limits = list(rows[0]["limits"]) if rows else []
    if limits:
        lines += ["", "Per limit: samples passing, median and worst.", "",
                  "| controller | " + " | ".join(f"{rows[0]['limits'][m]['label']} [{rows[0]['limits'][m]['unit']}]"
                                                 for m in limits) + " |",
                  "|---|" + "---|" * len(limits)]
        for r in rows:
            cells = []
            for m in limits:
                x = r["limits"].get(m, {})
                cells.append(f"{x.get('pass')}/{r['n']}: {_fmt(x.get('median'))}, {_fmt(x.get('worst'))}")
            lines.append(f"| `{r['controller']}` | " + " | ".join(cells) + " |")
    lines += ["", f"![comparison]({A.FIG_MC_BENCH})", ""]
    return "\n".join(lines) + "\n"


def run_montecarlo_bench(controllers, out, settings: MonteCarloConfig | None = None, *, progress: bool = True,
                         say=None) -> dict:
    """Run (or resume) the Monte Carlo of every controller into ``out/<name>/`` and compare them.

    Parameters
    ----------
    controllers : sequence of path
        At least two ``controller.npz`` files (names: :func:`controller_names`).
    out : path
        The comparison's folder (created; a rerun resumes every controller's Monte Carlo).
    settings : MonteCarloConfig
        The same for every controller.
    progress, say
        As :func:`nanosim.pipeline.montecarlo.run_montecarlo`.

    Returns
    -------
    dict
        ``summary.json``'s content and ``wall_seconds``.
    """
    import time

    from nanosim.plots.montecarlo import fig_bench

    settings = settings or MonteCarloConfig()
    say = say or (lambda msg: print(f"  {msg}", file=sys.stderr, flush=True))
    named = controller_names(controllers)
    plan = {"seed": settings.seed, "n": settings.n,
            "controllers": {n: {"file": str(Path(p).resolve()), "sha256": sha256_file(Path(p))}
                            for n, p in named.items()}}
    out = check_writable(out).resolve()
    _check_out(out, plan)
    t0 = time.perf_counter()
    with writer_lock(out):
        _check_out(out, plan)                          # again under the lock
        out.mkdir(exist_ok=True)
        (out / MANIFEST_JSON).unlink(missing_ok=True)
        write_json(out / A.MC_BENCH_JSON, plan)
        summaries, flats = {}, {}
        for k, (name, path) in enumerate(named.items()):
            say(f"controller {k + 1} of {len(named)}: {name}")
            summaries[name] = run_montecarlo(path, out / name, settings, progress=progress, say=say)
            flats[name] = load_sample_flats(out / name, settings.n)
        doc = {"seed": settings.seed, "n": settings.n, "controllers": bench_rows(summaries, flats),
               "units": {"yield_percent": "%", "ci95_percent": "%", "disk_margin_alpha": "dimensionless",
                         "limits": "each limit's own unit (its 'unit')"}}
        write_json(out / A.SUMMARY_JSON, doc)
        save_figure(fig_bench(doc["controllers"], {n: [f.get(ALPHA, math.nan) for f in v] for n, v in flats.items()}),
                    out / A.FIG_MC_BENCH)
        write_text(out / A.REPORT_MD, bench_report_markdown(doc))
        write_manifest(out, seed=settings.seed)
    return {**doc, "wall_seconds": round(time.perf_counter() - t0, 2)}
