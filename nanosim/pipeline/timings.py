"""``timings.json``: the wall-clock times of a run folder, kept out of its result files.

The result files (``metrics.json``, ``design.json``, Monte Carlo samples, sweep points,
``scorecard.json``, ...) hold only what the inputs and the seed determine, so two runs
with the same seed give the same bytes. The wall-clock times the commands measure go to
one ``timings.json`` per run folder (:data:`nanosim.pipeline.artifacts.TIMINGS_JSON`), under
the path of the result file they describe, with that file's field names::

    {"units": "...",
     "files": {"design.json": {"timings_s": {...}},
               "metrics.json": {"experiment_seconds": {...}},
               "twin/metrics.json": {"experiment_seconds": {...}},
               "pipeline.json": {"stage_seconds": {...}}}}

It is a plain output of the run (the manifest lists it); only it and ``manifest.json``
differ between two runs with the same seed. One writer at a time: the run folder's
writer (the staging folder or the writer lock of :mod:`nanosim.pipeline.runfolder`).
"""
from __future__ import annotations

import json
import os
from pathlib import Path
from typing import Mapping

from nanosim.fileio import write_json
from nanosim.pipeline.artifacts import TIMINGS_JSON

__all__ = ["TIMINGS_UNITS", "record_timings", "read_timings"]

TIMINGS_UNITS = ("wall-clock seconds (every number, whatever its key; *_samples_run: the number of samples that "
                 "run of the command computed); under files: the result file each entry belongs to, relative to "
                 "this folder")


def _load(run_dir: Path) -> dict:
    p = run_dir / TIMINGS_JSON
    try:
        doc = json.loads(p.read_text())
    except (FileNotFoundError, ValueError):
        return {}
    return doc if isinstance(doc, dict) and isinstance(doc.get("files"), dict) else {}


def record_timings(run_dir: str | os.PathLike, entries: Mapping[str, Mapping]) -> Path:
    """Merge ``{result file: {field: value}}`` into ``run_dir``'s ``timings.json``; returns its path.

    A field given again replaces the earlier one; the files are kept sorted by name.
    """
    run_dir = Path(run_dir)
    files = _load(run_dir).get("files", {})
    for rel, fields in entries.items():
        files[str(rel)] = {**files.get(str(rel), {}), **dict(fields)}
    return write_json(run_dir / TIMINGS_JSON, {"units": TIMINGS_UNITS, "files": dict(sorted(files.items()))})


def read_timings(run_dir: str | os.PathLike, rel: str) -> dict:
    """The timing fields recorded for result file ``rel`` of ``run_dir`` (empty if none)."""
    return dict(_load(Path(run_dir)).get("files", {}).get(str(rel), {}))
