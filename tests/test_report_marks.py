"""What the report, the scorecard and the Monte Carlo's first line tell a reader: marks, counts, estimates."""
from __future__ import annotations

import json
import math
import re

import pytest

from nanosim.pipeline.report import write_report


def _rows(html: str, label: str) -> list[str]:
    return [r for r in re.findall(r"<tr[^>]*>.*?</tr>", html) if f"<td>{label}</td>" in r]


def test_html_marks_a_failed_criterion_without_markdown_asterisks(tmp_path):
    """The acceptance table's failed rows: red in HTML, bold NO in markdown, never a literal ``**NO**`` in HTML."""
    (tmp_path / "design.json").write_text(json.dumps({"gamma": 1.2, "controller_order": 21}))
    (tmp_path / "metrics.json").write_text(json.dumps({"bandwidth_S_hz": 10.0, "bandwidth_T_hz": 90.0,
                                                      "resolution_sigma_nm": {"open_loop": 11.0, "closed_loop": 4.0}}))
    md, html = write_report(tmp_path)
    page, text = html.read_text(), md.read_text()
    assert "**NO**" not in page and "**NO**" in text
    failed = _rows(page, "S bandwidth from the reference record (measured)")
    assert failed and all("class='no'" in r and "<td>NO</td>" in r for r in failed)


def test_rows_measured_without_a_band_are_not_coloured(tmp_path):
    """'measured (no band)': counted as compare_to_paper.py counts them, neither green nor red."""
    (tmp_path / "metrics.json").write_text(json.dumps({"bandwidth_T_hz": 300.0}))      # far from the paper's
    _, html = write_report(tmp_path)
    rows = _rows(html.read_text(), "T bandwidth on the stage")
    assert len(rows) == 1
    assert "measured (no band)" in rows[0] and "class=" not in rows[0].split(">")[0]
    assert "<td>counted</td>" in rows[0]


def test_scorecard_counts_only_criteria_that_ran():
    """With --only, the criteria of experiments that did not run are 'not measured', not failed."""
    from nanosim.pipeline.scorecard import ACCEPTANCE, choose_default, flatten_metrics

    acceptance = {k: {"pass": None, "worst": None} for k in ACCEPTANCE}
    acceptance["bandwidth_S_hz"] = {"pass": True, "worst": 40.0}
    acceptance["step_settling_ms"] = {"pass": False, "worst": 30.0}
    doc = {"controllers": {"a": {"source": "bench", "acceptance": acceptance, "acceptance_met": 1,
                                 "acceptance_total": 2, "summary": {k: {"worst": None} for k in
                                                                    ("multiloop_disk_margin",
                                                                     "bandwidth_S_feedback_hz")}}}}
    name, why = choose_default(doc)
    assert name == "a"
    assert "(not: step_settling_ms)" in why
    assert f"not measured in this comparison: {', '.join(k for k in ACCEPTANCE if acceptance[k]['pass'] is None)}" \
        in why
    # no -3 dB crossing of T in the measured band: no bandwidth (n/a), not -inf
    assert flatten_metrics({"bandwidth_T_hz": -math.inf})["bandwidth_T_hz"] is None
    assert flatten_metrics({"bandwidth_T_hz": 95.0})["bandwidth_T_hz"] == 95.0


def test_montecarlo_estimate_scales_with_the_samples_and_the_workers():
    from nanosim.pipeline.montecarlo import (MAX_SAMPLES, SAMPLE_WORKER_SECONDS, SPREAD_ENGINE, check_sample_count,
                                             estimate_seconds, format_duration)

    one = estimate_seconds(1, 0, 1)
    assert one["total"] == pytest.approx(SAMPLE_WORKER_SECONDS["twin"])
    est = estimate_seconds(20, 10, 2)
    assert est["twin"] == pytest.approx(10 * SAMPLE_WORKER_SECONDS["twin"])
    assert est["mujoco"] == pytest.approx(5 * (SAMPLE_WORKER_SECONDS["mujoco"] + SAMPLE_WORKER_SECONDS[SPREAD_ENGINE]))
    assert est["total"] == pytest.approx(est["twin"] + est["mujoco"])
    check_sample_count(MAX_SAMPLES, 10, 2)                         # the limit itself is accepted
    n = 10 ** 12
    with pytest.raises(ValueError, match=r"^--n: expected at most 100000 samples, got 1000000000000 \(about \d+ days"):
        check_sample_count(n, 10, 2)
    assert format_duration(30) == "30 s" and format_duration(600) == "10 min" and format_duration(3 * 86400) == \
        "3 days"


def test_seeds_are_distinct():
    from nanosim.pipeline.seeds import parse_seeds

    assert parse_seeds("3,0-2") == (0, 1, 2, 3)
    for text, twice in (("1,1", 1), ("0-3,2", 2), ("4,2-5", 4)):
        with pytest.raises(ValueError, match=f"seed {twice} twice"):
            parse_seeds(text)


def test_characterize_only_labels_the_plant_per_experiment(tmp_path):
    """--twin --only X into a MuJoCo run: X is labelled the twin, the others keep MuJoCo."""
    from nanosim import experiments
    from nanosim.fileio import write_npz
    import numpy as np
    from nanosim.pipeline.characterize import plant_description, run_characterize
    from nanosim.pipeline.config import CharacterizeConfig

    ctrl = write_npz(tmp_path / "c.npz", Akd=np.zeros((1, 1)), Bkd=np.zeros((1, 3)), Ckd=np.zeros((3, 1)),
                     Dkd=np.zeros((3, 3)), dt=2.5e-4)
    out = tmp_path / "run"
    out.mkdir()
    (out / "metrics.json").write_text(json.dumps({"plant": plant_description(False), "seed": 0}))
    m = run_characterize(ctrl, out, CharacterizeConfig(only="small_steps", twin=True), progress=False)
    by = m["plant_by_experiment"]
    assert by["small_steps"] == plant_description(True)
    assert all(by[n] == plant_description(False) for n in experiments.load_builtin() if n != "small_steps")
    assert m["plant"].startswith("mixed: ") and "small_steps on the linear twin" in m["plant"]
    assert json.loads((out / "metrics.json").read_text())["plant_by_experiment"] == by
