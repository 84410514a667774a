"""report.md / report.html from a run folder's json files."""
import json

from nanosim.pipeline.report import write_report


def test_report_marks_bands_and_names_the_paper(tmp_path):
    (tmp_path / "design.json").write_text(json.dumps({"gamma": 1.2, "controller_order": 21}))
    (tmp_path / "metrics.json").write_text(json.dumps({"bandwidth_S_hz": 31.0,
                                                      "resolution_sigma_nm": {"open_loop": 11.0, "closed_loop": 4.0}}))
    (tmp_path / "twin").mkdir()
    (tmp_path / "twin" / "metrics.json").write_text(json.dumps({"bandwidth_S_hz": 30.0}))
    md, html = write_report(tmp_path)
    text, page = md.read_text(), html.read_text()
    assert "<em>Robust Control of a Parallel-Kinematic Nanopositioner</em>" in page
    row = {line.split("|")[2].strip(): line for line in text.splitlines() if line.count("|") > 8}
    assert row["gamma"].rstrip(" |").endswith("yes")                     # 1.2 <= 1.5
    assert row["controller order"].rstrip(" |").endswith("**NO**")     # 21 != 19
    assert row["S bandwidth on the stage"].rstrip(" |").endswith("yes")  # 31 >= 28
    assert row["resolution sigma, closed loop"].rstrip(" |").endswith("**NO**")
    assert "| S bandwidth (Hz) | 31 | 30 | +1 (+3 %) |" in text             # MuJoCo vs twin table
