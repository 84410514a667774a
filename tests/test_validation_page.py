"""tools/make_validation_page.py: the validation page and the README's headline come from run folders."""
import importlib.util
import json
from pathlib import Path

import pytest

from nanosim.calibrated import CALIBRATED_PARAMETERS
from nanosim.pipeline.mc_stats import wilson_interval

TOOL = Path(__file__).resolve().parents[1] / "tools" / "make_validation_page.py"


@pytest.fixture(scope="module")
def tool():
    spec = importlib.util.spec_from_file_location("make_validation_page", TOOL)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def _run(folder: Path, seed: int, settling_ms: float, bandwidth_hz: float) -> Path:
    folder.mkdir(parents=True)
    met = {"bandwidth_S_hz": bandwidth_hz, "step_2um": {"settling_ms": settling_ms, "overshoot_percent": 1.0},
           "resolution_sigma_nm": {"open_loop": 11.5, "closed_loop": 1.8},
           "resolution_sigma_table_nm": {"closed_loop": 1.7},
           "hysteresis": {"open_loop_percent": 15.0, "open_loop_input_percent": 14.0,
                          "open_loop_travel_um": [-10.0, 7.0, 5.5]},
           "contouring": [{"speed_um_s": 1000.0, "mean_error_nm": 40.0, "max_error_nm": 90.0}]}
    (folder / "metrics.json").write_text(json.dumps(met))
    (folder / "pipeline.json").write_text(json.dumps({"seed": seed}))
    return folder


def _montecarlo(folder: Path) -> Path:
    folder.mkdir()
    lo, hi = wilson_interval(3, 4)
    y = [{"metric": "bandwidth_S_hz", "label": "S bandwidth", "unit": "Hz", "min": 28, "n": 4, "pass": 3,
          "yield_percent": 75.0, "ci95_percent": [100 * lo, 100 * hi], "median": 35.0, "worst": 27.0}]
    (folder / "summary.json").write_text(json.dumps({"n": 4, "seed": 0, "yield": y, "crosscheck_pass": 0,
                                                     "crosscheck_n": 0}))
    return folder


def test_page_reads_every_number_from_the_runs(tool, tmp_path):
    runs = [_run(tmp_path / "p0", 0, 7.0, 36.0), _run(tmp_path / "p1", 1, 9.0, 34.0)]
    mc = _montecarlo(tmp_path / "mc")
    readme = tmp_path / "README.md"
    readme.write_text(f"# x\n\n{tool.BEGIN}\nold\n{tool.END}\n\nafter\n")
    out = tmp_path / "validation.md"
    assert tool.main(["--runs", *map(str, runs), "--montecarlo", str(mc), "--out", str(out),
                      "--readme", str(readme)]) == 0
    text = out.read_text()
    assert "seeds 0, 1" in text and "generated from run folders" in text
    # the settling's mean and worst over the two runs, the bandwidth's worst is the lower
    vs_paper, over_seeds = [ln for ln in text.splitlines() if ln.startswith("| 2 um step settling (2 %) | 11 |")]
    assert "| 8 | 7 - 9 | ms | predicted |" in vs_paper and "| 8 | 9 | ms | 2 |" in over_seeds
    row = [ln for ln in text.splitlines() if ln.startswith("| S bandwidth (reference to error) |")][-1]
    assert "| 35 | 34 | Hz | 2 |" in row
    for p in CALIBRATED_PARAMETERS:
        assert f"| {p.name} |" in text
    assert "| 3/4 | 75 |" in text
    head = readme.read_text()
    assert "old" not in head and head.endswith(f"{tool.END}\n\nafter\n")
    assert "| 2 um step settling (2 %) | 11 ms | 8 ms | 9 ms |" in head


def test_scorecard_section_reads_the_acceptance_of_every_controller(tool, tmp_path):
    from nanosim.pipeline.scorecard import run_acceptance

    crit = {r["key"]: r for r in run_acceptance({"bandwidth_S_hz": 36.0, "step_2um": {"settling_ms": 12.0}}, None)}
    acc = {k: {"criterion": r["criterion"], "worst": r["value"], "pass": r["pass"]} for k, r in crit.items()}
    doc = {"controllers": {"lqg": {"acceptance": acc, "acceptance_met": sum(bool(a["pass"]) for a in acc.values()),
                                   "acceptance_total": len(acc)}},
           "seeds": [0], "plant": "linear twin", "acceptance": {k: a["criterion"] for k, a in acc.items()},
           "default": "lqg", "default_reason": "the only bench design"}
    (tmp_path / "bench").mkdir()
    (tmp_path / "bench" / "scorecard.json").write_text(json.dumps(doc))
    text = "\n".join(tool.scorecard(tmp_path / "bench"))
    row = [ln for ln in text.splitlines() if ln.startswith("| `lqg` |")][0]
    assert f"| {doc['controllers']['lqg']['acceptance_met']} / {len(acc)} |" in row
    assert "36 ✓" in row and "12 ✗" in row
    assert "Default by the rule: `lqg`" in text


def test_folders_without_runs_are_refused(tool, tmp_path):
    (tmp_path / "empty").mkdir()
    with pytest.raises(SystemExit, match="--runs: expected folders of nanosim pipeline"):
        tool.main(["--runs", str(tmp_path / "empty"), "--out", str(tmp_path / "v.md")])


def test_ablation_section_is_each_row_mean_and_range_over_the_seeds(tool, tmp_path):
    def doc(seed, settle, sigma):
        row = {"name": "linear piezo", "change": "hysteresis and creep off", "settling_ms": settle,
               "sigma_closed_nm": sigma, "sigma_closed_table_nm": sigma - 0.1, "contour_mean_nm_1000": 20.0,
               "bandwidth_S_hz": 33.0}
        folder = tmp_path / f"a{seed}"
        folder.mkdir()
        (folder / "ablation.json").write_text(json.dumps({
            "seed": seed, "mechanics": "twin", "redesign": True, "rows": [row],
            "targets": {"settling_ms": 11, "sigma_closed_nm": 1.89, "contour_mean_nm_1000": 40, "bandwidth_S_hz": 32}}))
        return folder
    folders = [doc(0, 9.0, 1.5), doc(1, 11.0, 1.7)]
    text = "\n".join(tool.ablation(folders))
    assert "seed(s) 0, 1" in text and "redesigned per row" in text
    row = [ln for ln in text.splitlines() if ln.startswith("| linear piezo |")][0]
    assert "| 10 (9 - 11) | 1.6 (1.5 - 1.7) |" in row
    assert [ln for ln in text.splitlines() if ln.startswith("| paper |")][0].startswith("| paper |  | 11 | 1.89 |")
    out = tmp_path / "ablation.md"
    assert tool.main(["--ablation", *map(str, folders), "--out", str(out)]) == 0
    page = out.read_text()
    assert page.startswith("# Ablation") and row in page and "generated from the ablation.json" in page
    with pytest.raises(SystemExit, match="--runs: expected"):
        tool.main(["--out", str(out)])
