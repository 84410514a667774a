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


def _png(path):
    from matplotlib.figure import Figure

    from nanosim.fileio import save_figure
    fig = Figure(figsize=(1, 1))
    fig.subplots().plot([0, 1])
    save_figure(fig, path)


def test_report_shows_every_figure_of_the_run_folder(tmp_path):
    """Every registered figure (Fig. 18a-b included), unregistered PNGs and the twin folder's reach the report."""
    from nanosim.pipeline import artifacts as A

    made = []
    for art in A.FIGURES:
        rel = art.name.replace("*", "01_176Hz")
        _png(tmp_path / rel)
        made.append(rel)
    _png(tmp_path / "twin" / "fig18_bandwidth_step.png")
    _png(tmp_path / "extra_figure.png")
    made += ["twin/fig18_bandwidth_step.png", "extra_figure.png"]
    md, html = write_report(tmp_path)
    text, page = md.read_text(), html.read_text()
    for rel in made:
        assert f"]({rel})" in text, rel
        assert f"src='{rel}'" in page, rel
    assert "fig18_T_KS.png" in text                       # Fig. 18a-b of the design step


def test_every_figure_the_experiments_write_is_registered():
    from nanosim import experiments
    from nanosim.pipeline import artifacts as A

    names = {a.name for a in A.FIGURES}
    for name in experiments.load_builtin():
        exp = experiments.get(name)
        if exp.figure_name:
            assert exp.figure_name in names, exp.figure_name


def test_controller_section_describes_the_exported_bench_design_not_the_hinf_reference():
    """design.json of an lqg export: the report names the lqg design, its order and prefilter notches; an
    H-infinity export keeps the H-infinity paragraph."""
    from nanosim.pipeline.report import architecture_section
    des = {"architecture": "lqg", "reduced_order": 14,
           "damping_loop": {"zeta_added": 0.1, "mode_hz": 176.0, "lowpass_hz": 400.0},
           "exported_controller": {"architecture": "lqg", "tuning_rule": "LQG rule", "controller_order": 49,
                                   "parameters": {"reference_prefilter": {
                                       "notches": [{"freq_hz": 452.2, "zeta_zero": 0.063, "zeta_pole": 0.7}],
                                       "prefilter_states": 6}}}}
    text = architecture_section(des)
    assert "`lqg` design (49 states)" in text and "LQG rule" in text
    assert "notches at 452 Hz (zeta 0.063 -> 0.7)" in text and "6 of the states" in text
    assert "H-infinity mixed-sensitivity" not in text
    des.pop("exported_controller")
    des["architecture"] = "mixsyn"
    assert "H-infinity mixed-sensitivity" in architecture_section(des)


def test_controllers_section_scores_the_run_against_the_bench_acceptance(tmp_path):
    """metrics.json + robustness.json -> the acceptance table: a 12 ms step and an unstable-centre mu fail, the rest
    pass; the feedback-loop S bandwidth is not measured by the pipeline (n/a)."""
    (tmp_path / "design.json").write_text(json.dumps({"architecture": "lqg", "exported_controller": {
        "architecture": "lqg", "tuning_rule": "rule", "controller_order": 49, "parameters": {}}}))
    (tmp_path / "metrics.json").write_text(json.dumps({
        "bandwidth_S_hz": 44.0, "step_2um": {"settling_ms": 12.0, "overshoot_percent": 0.3, "rise_ms": 3.5},
        "resolution_sigma_table_nm": {"closed_loop": 1.8},
        "contouring": [{"speed_um_s": 1000.0, "mean_error_nm": 23.0, "max_error_nm": 150.0}]}))
    (tmp_path / "robustness.json").write_text(json.dumps({"plants": {"identified": {
        "dm_input_alpha": 0.45, "dm_output_alpha": 0.43, "mu_centre_stable": False, "mu_peak": None}}}))
    md, _ = write_report(tmp_path)
    text = md.read_text()
    sec = text[text.index("## Controllers"):text.index("## Paper vs simulation")]
    rows = {line.split("|")[1].strip(): [c.strip() for c in line.split("|")[2:-1]]
            for line in sec.splitlines() if line.startswith("| ") and "criterion" not in line}
    assert rows["S bandwidth from the reference record (measured)"] == [">= 32 Hz", "44.0 Hz", "yes"]
    assert rows["2 um step, 2 % settling"] == ["<= 11 ms", "12.0 ms", "**NO**"]
    assert rows["multiloop disk margin alpha (identified model = the loop as run)"] == [">= 0.4", "0.43", "yes"]
    assert rows["mu upper bound over the uncertainty set"] == ["< 1", "inf", "**NO**"]
    assert rows["S bandwidth of the feedback loop (measured, PRBS at the reading)"] == [">= 32 Hz", "n/a", "n/a"]
    assert "5 of 7 measured criteria met" in sec
    assert "not the exported `lqg` controller" in text


def test_seeds_summary_takes_the_worst_seed_per_criterion():
    from nanosim.pipeline.scorecard import run_acceptance
    from nanosim.pipeline.seeds import acceptance_summary

    def seed(settle, bw):
        return {"acceptance": {"controller": "lqg", "controller_order": 49, "criteria": run_acceptance(
            {"bandwidth_S_hz": bw, "step_2um": {"settling_ms": settle, "overshoot_percent": 0.3}}, None)}}
    acc = acceptance_summary([0, 1, 2], {0: seed(6.0, 45.0), 1: seed(10.5, 43.0), 2: seed(11.5, 44.0)})
    rows = {r["key"]: r for r in acc["criteria"]}
    assert rows["step_settling_ms"]["worst"] == 11.5 and rows["step_settling_ms"]["every_seed"] is False
    assert rows["bandwidth_S_hz"]["worst"] == 43.0 and rows["bandwidth_S_hz"]["every_seed"] is True
    assert rows["mu_peak"]["every_seed"] is None and rows["mu_peak"]["worst"] is None
    assert acc["met_on_every_seed"] == 2 and acc["measured"] == 3      # bandwidth, overshoot; settling fails


def test_report_shows_the_stage_wall_times_of_timings_json(tmp_path):
    """The wall times live in timings.json (result files hold none); a folder written before it keeps its
    pipeline.json stage_seconds."""
    from nanosim.pipeline.timings import read_timings, record_timings

    (tmp_path / "pipeline.json").write_text(json.dumps({"seed": 0}))
    record_timings(tmp_path, {"pipeline.json": {"stage_seconds": {"identify": 12.5, "design": 3.25}}})
    record_timings(tmp_path, {"metrics.json": {"experiment_seconds": {"creep": 1.0}}})
    assert read_timings(tmp_path, "pipeline.json")["stage_seconds"]["design"] == 3.25
    md, _ = write_report(tmp_path)
    assert "Stage wall times (s): identify 12.5, design 3.25" in md.read_text()
    old = tmp_path / "old"
    old.mkdir()
    (old / "pipeline.json").write_text(json.dumps({"stage_seconds": {"modes": 7.0}, "seed": 0}))
    md, _ = write_report(old)
    assert "Stage wall times (s): modes 7.0" in md.read_text()
