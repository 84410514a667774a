"""The report shows everything: its pass count agrees with the project's checker of a run folder against the
paper (tests/data/shared/tools/compare_to_paper.py), the pipeline's final line names it, and it shows the
design's own warnings."""

import json
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from nanosim.cli import main

from cli_run import COMPARE_TOOL


# --- the report shows everything and agrees with the checker ------------------------------------------
def _fake_run(folder: Path, *, fail=False, drop=()):
    """The json files of a run with chosen values (every band passes unless ``fail``)."""
    folder.mkdir(parents=True, exist_ok=True)
    from nanosim.paper import STAGE_MODES_HZ
    modes = {"modes": [{"freq_hz": f, "damping_ratio": 0.004 if not fail else 0.02, "axis": "XY"}
                       for f in (*(1.002 * np.asarray(STAGE_MODES_HZ)), 1650.0)],
             "static_gain_um_per_V": (3.0 * np.array([[-2.022, -1.19, 3.212], [2.542, -3.022, 0.48],
                                                      [0.99, 0.99, 0.99]])).tolist(),
             "constraint_violation_ratio": 0.0037}
    ident = {"fit_percent": [[98.8, 99.4, 98.7], [99.1, 98.7, 99.5], [98.8, 98.5, 85.0 if fail else 98.5]],
             "total_order": 39}
    des = {"gamma": 1.18, "controller_order": 19, "S_peak_nominal": 1.23, "S_peak_full": 1.23,
           "bandwidth_S_hz": 34.4, "bandwidth_T_hz": 62.0 if not fail else None}
    met = {"bandwidth_S_hz": 28.1, "bandwidth_T_hz": 70.7, "step_2um": {"rise_ms": 3.5, "peak_ms": 7.0,
           "settling_ms": 12.5 if not fail else 25.0, "overshoot_percent": 5.6},
           "resolution_sigma_nm": {"open_loop": 11.6, "closed_loop": 1.6},
           "hysteresis": {"open_loop_percent": 15.5, "closed_loop_nm": 13.0},
           "creep": {"open_loop_drift_nm": 269.0, "closed_loop_drift_nm": 0.97},
           "contouring": [{"speed_um_s": 1000.0, "mean_error_nm": 98.0, "max_error_nm": 342.0}],
           "small_steps": {"plateau_means_nm": [0.0, 8.9, 20.5, 29.7, 39.9, 49.7]}}
    for name, data in (("modes.json", modes), ("identify.json", ident), ("design.json", des),
                       ("metrics.json", met)):
        if name not in drop:
            (folder / name).write_text(json.dumps(data))
    return folder


def _tool_count(run: Path) -> tuple[int, int]:
    """The checker's count; its mode rows take the stage's modes as the paper's Tustin d2c reports them."""
    from nanosim.paper import tustin_warp_hz
    modes_file = run / "modes.json"
    if modes_file.exists():
        doc = json.loads(modes_file.read_text())
        for m in doc["modes"]:
            if m["freq_hz"] < 1000:
                m["freq_hz"] = float(tustin_warp_hz(m["freq_hz"]))
        modes_file = run.parent / "modes_warped.json"
        modes_file.write_text(json.dumps(doc))
    out = subprocess.run([sys.executable, str(COMPARE_TOOL), str(run), "--modes-json", str(modes_file)],
                         capture_output=True, text=True).stdout
    n_ok, n = re.search(r"(\d+) of (\d+) inside their bands", out).groups()
    return int(n_ok), int(n)


@pytest.mark.parametrize("case", ["pass", "fail", "no design.json", "no metrics.json"])
def test_report_counts_what_compare_to_paper_counts(tmp_path, case):
    """The report's pass count is the checker's, however many quantities are missing."""
    from nanosim.pipeline.report import pass_count, write_report

    drop = {"no design.json": ("design.json",), "no metrics.json": ("metrics.json",)}.get(case, ())
    run = _fake_run(tmp_path / "run", fail=case == "fail", drop=drop)
    md, _ = write_report(run)
    n_ok, n = pass_count(run)
    assert (n_ok, n) == _tool_count(run)
    assert f"{n_ok} of {n} checked quantities" in md.read_text()
    assert (n_ok < n) == (case != "pass")


def test_pipeline_final_line_names_the_report_and_the_report_count(monkeypatch, tmp_path, capsys):
    import nanosim.pipeline.run as prun
    from nanosim.pipeline.report import write_report

    def fake_pipeline(out, cfg):
        _fake_run(Path(out), fail=True)
        write_report(out)

    monkeypatch.setattr(prun, "run_pipeline", fake_pipeline)
    assert main(["pipeline", "--out", str(tmp_path / "run")]) == 0
    line = capsys.readouterr().out.strip().splitlines()[-1]
    n_ok, n = re.search(r"(\d+) of (\d+) checked quantities", line).groups()
    assert str(tmp_path / "run" / "report.html") in line
    assert f"{n_ok} of {n} checked quantities" in (tmp_path / "run" / "report.md").read_text()


def test_report_shows_the_designs_own_warnings(tmp_path):
    from nanosim.pipeline.report import write_report

    run = _fake_run(tmp_path / "run")
    des = json.loads((run / "design.json").read_text())
    clean = dict(des, discretization_within_1_percent=True, Eo_max_dB_below_140Hz=-25.0,
                 controller_fastest_pole_rad_s=5e4, closed_loop_min_damping_nominal=0.02)
    (run / "design.json").write_text(json.dumps(clean))
    md, page = write_report(run)
    text = md.read_text()
    assert "## Warnings" in text and "None:" in text.split("## Warnings")[1].split("##")[0]
    bad = dict(des, discretization_within_1_percent=False, discretization_max_rel_error=0.034,
               Eo_max_dB_below_140Hz=-15.27, controller_fastest_pole_rad_s=9.9e11,
               closed_loop_min_damping_nominal=0.0037, closed_loop_min_damping_nominal_hz=474.3, stable_twin=False)
    (run / "design.json").write_text(json.dumps(bad))
    md, page = write_report(run)
    warn = md.read_text().split("## Warnings")[1].split("\n## ")[0]
    items = [ln for ln in warn.splitlines() if ln.startswith("- ")]
    assert len(items) == 5, warn
    for needle in ("3.4 %", "-15.3 dB", "-20 dB", "9.9e+11 rad/s", "0.0037 at 474 Hz", "UNSTABLE"):
        assert needle in warn, needle
    assert "design warning(s)" in md.read_text().splitlines()[2]
    assert "<ul class='warn'>" in page.read_text()
