"""Tolerance model, population statistics, and ``nanosim montecarlo`` / ``nanosim sweep`` end to end (tiny N)."""
import json
import math
from pathlib import Path

import numpy as np
import pytest
from scipy import stats

from nanosim.pipeline import mc_stats
from nanosim.pipeline.config import MonteCarloConfig
from nanosim.pipeline.montecarlo import run_montecarlo
from nanosim.pipeline.runfolder import RunFolderError, verify_manifest
from nanosim.pipeline.sweep import PARETO_TIES, parse_param, pareto_front, point_model
from nanosim.plant.mjcf import load_model
from nanosim.plant.modes import modal_analysis
from nanosim.plant.tolerances import default_tolerances, notch_stiffness_ratio, sample_model


@pytest.fixture(scope="module")
def tm():
    return default_tolerances()


# --- tolerance model ---------------------------------------------------------------------------------
def test_samples_reproducible_bounded_and_sourced(tm):
    a, b = tm.sample(3, 5), tm.sample(3, 5)
    assert a == b and a != tm.sample(3, 6) and a != tm.sample(4, 5)
    for t in tm.tolerances:
        assert abs(a[t.name] - t.nominal) <= t.half_width
        assert t.source and t.unit
    assert tm.layout == "v2" and len([n for n in tm.names if n.startswith("thickness.")]) == 3 * 12
    x = np.array([tm.normalized(tm.sample(0, i)) for i in range(300)])
    assert np.all(np.abs(x) <= 1) and abs(x.mean()) < 0.02 and abs(x.var() - 1 / 3) < 0.01     # uniform(-1, 1)


def test_nominal_sample_is_symmetric_and_deviations_follow_the_notch_formula(tm, model):
    from nanosim.plant.geometry import CALIBRATED_GEOMETRY
    from nanosim.plant.hinges import notch_stiffness

    nominal = sample_model(tm.nominal(), tm)
    for j in ("h1_bend", "h2_tor", "crank_base_bend"):
        k = [nominal.jnt_stiffness[nominal.joint(f"{c}_{j}").id] for c in "abc"]
        assert k[0] == pytest.approx(k[1], rel=1e-12) and k[0] == pytest.approx(k[2], rel=1e-12)
    f = [m.freq_hz for m in modal_analysis(nominal).below(1000.0)]
    assert f[1] / f[0] - 1 < 2e-4                                  # no imposed chain asymmetry: XY pair degenerate
    v = tm.nominal()
    t0, R0 = v["thickness.a_h1"], v["radius.a_h2"]
    v["thickness.a_h1"] = t0 + 5.0
    v["radius.a_h2"] = R0 + 5.0
    v["target_mass"] *= 1.02
    v["piezo_gain.c"] = 1.1
    v["width.a_foot"] += 5.0
    m = sample_model(v, tm)
    mat, nh = CALIBRATED_GEOMETRY.material, CALIBRATED_GEOMETRY.chain.swing_notch

    def k(t_um):
        return notch_stiffness(mat, nh.with_thickness(t_um * 1e-6)).bending_Nm_per_rad

    ratio = m.jnt_stiffness[m.joint("a_h1_bend").id] / m.jnt_stiffness[m.joint("b_h1_bend").id]
    assert ratio == pytest.approx(k(t0 + 5) / k(t0), rel=1e-5)      # the builder's notch formula (XML digits)
    radius = m.jnt_stiffness[m.joint("a_h2_bend").id] / m.jnt_stiffness[m.joint("b_h2_bend").id]
    assert radius == pytest.approx(k(t0 * (R0 / (R0 + 5)) ** 0.2) / k(t0), rel=1e-5)   # equivalent thickness
    assert radius < 1 < ratio
    assert m.body_mass[m.body("table").id] == pytest.approx(1.02 * nominal.body_mass[nominal.body("table").id])
    assert m.actuator_gainprm[m.actuator("piezo_c").id, 0] == pytest.approx(1.1)
    assert m.body_mass[m.body("a_foot").id] / nominal.body_mass[nominal.body("a_foot").id] == pytest.approx(2405 / 2400)


def test_v1_stage_maps_onto_its_lumped_springs():
    from nanosim.plant.mjcf import MJCF_DIR

    v1 = MJCF_DIR / "v1" / "scene.xml"
    base = load_model(v1)
    tm1 = default_tolerances(base)
    assert tm1.layout == "v1"
    v = tm1.nominal()
    t0 = v["thickness.a_h1"]
    v["thickness.a_h1"] = v["thickness.a_h2"] = t0 + 5.0
    m = sample_model(v, tm1, v1)
    k = [base.jnt_stiffness[base.joint(f"{c}_h1").id] for c in "abc"]
    assert m.jnt_stiffness[m.joint("b_h1").id] == pytest.approx(np.median(k), rel=1e-12)   # chain A's 14 % removed
    ratio = m.jnt_stiffness[m.joint("a_h1").id] / m.jnt_stiffness[m.joint("b_h1").id]
    assert ratio == pytest.approx(((t0 + 5) / t0) ** 2.5, rel=1e-12)
    assert ratio == pytest.approx(notch_stiffness_ratio(t0 + 5, t0), rel=1e-15)


# --- statistics ----------------------------------------------------------------------------------------
def test_wilson_interval_and_yield_table():
    lo, hi = mc_stats.wilson_interval(0, 10)
    assert lo == 0.0 and hi == pytest.approx(0.2775, abs=1e-4)       # textbook value, z = 1.96
    # the closed form at the exact quantile z = 1.95996...
    z = stats.norm.ppf(0.975)
    p, n = 0.8, 10
    d = 1 + z * z / n
    c, h = (p + z * z / (2 * n)) / d, z * math.sqrt(p * (1 - p) / n + z * z / (4 * n * n)) / d
    assert mc_stats.wilson_interval(8, 10) == pytest.approx((c - h, c + h), rel=1e-12)
    assert mc_stats.wilson_interval(9, 10, confidence=0.99)[0] < mc_stats.wilson_interval(9, 10)[0]
    lo, hi = mc_stats.wilson_interval(8, 10)
    assert (lo, hi) == pytest.approx((0.4902, 0.9433), abs=1e-4)
    # every sample passing: the upper end is 1 exactly
    for n in (2, 100, 200, 1000):
        assert mc_stats.wilson_interval(n, n)[1] == 1.0 and mc_stats.wilson_interval(0, n)[0] == 0.0
    spec = mc_stats.check_spec({"limits": [{"metric": "bandwidth_S_hz", "min": 28, "unit": "Hz"},
                                           {"metric": "step_2um.overshoot_percent", "max": 10, "unit": "%"}]})
    flats = [{"bandwidth_S_hz": b, "step_2um.overshoot_percent": o} for b, o in ((30, 5), (27, 5), (29, 12), (31, 1))]
    rows = {r["metric"]: r for r in mc_stats.yield_table(flats, spec)}
    assert rows["bandwidth_S_hz"]["pass"] == 3 and rows["all"]["pass"] == 2
    assert rows["bandwidth_S_hz"]["worst"] == 27 and rows["step_2um.overshoot_percent"]["worst"] == 12
    worst = mc_stats.worst_cases([10, 11, 12, 13], flats, spec, k=1)
    assert worst["bandwidth_S_hz"][0]["sample"] == 11


def test_spec_units_and_flat_names_are_checked():
    with pytest.raises(ValueError, match="unit must be 'nm'"):
        mc_stats.check_spec({"limits": [{"metric": "resolution_sigma_nm.closed_loop", "max": 3, "unit": "um"}]})
    with pytest.raises(ValueError, match="'min' and/or 'max'"):
        mc_stats.check_spec({"limits": [{"metric": "bandwidth_S_hz", "unit": "Hz"}]})
    flat = mc_stats.flatten_metrics({"tracking": [{"waveform": "sine", "freq_hz": 20.0, "rms_error_nm": 3.0}],
                                     "contouring": [{"speed_um_s": 1000.0, "mean_error_nm": 90.0}],
                                     "small_steps": {"targets_nm": [0, 10], "plateau_means_nm": [0, 12.5]}})
    assert flat["tracking.sine_20hz.rms_error_nm"] == 3.0 and flat["contouring.1000um_s.mean_error_nm"] == 90.0
    assert flat["small_steps.max_error_nm"] == 2.5
    assert mc_stats.unit_of("contouring.1000um_s.axis_tracking_error_um") == "um"
    assert mc_stats.unit_of("resolution_sigma_nm.closed_loop") == "nm"
    mc_stats.check_spec(mc_stats.default_spec())


def test_sensitivity_finds_the_driving_group():
    rng = np.random.default_rng(1)
    X = rng.uniform(-1, 1, size=(200, 6))
    groups = ["a", "a", "b", "b", "c", "c"]
    y = 3 * X[:, 2] + 0.1 * rng.standard_normal(200)
    s = mc_stats.sensitivity(X, [f"v{i}" for i in range(6)], groups, [{"m_hz": v} for v in y], ["m_hz"])["m_hz"]
    assert s["groups"][0]["group"] == "b" and s["groups"][0]["adjusted_r2"] > 0.95
    assert all(g["adjusted_r2"] < 0.05 for g in s["groups"][1:])
    assert s["top_variables"][0]["name"] == "v2"


def test_pareto_front_and_sweep_parameters():
    pts = [{"bandwidth_S_hz": 30, "travel_um": 80, "resolution_nm": 2.0},
           {"bandwidth_S_hz": 25, "travel_um": 70, "resolution_nm": 2.5},       # dominated by 0
           {"bandwidth_S_hz": 20, "travel_um": 120, "resolution_nm": 2.0},
           {"bandwidth_S_hz": 35, "travel_um": 60, "resolution_nm": math.nan}]
    assert pareto_front(pts) == [0, 2] == pareto_front(pts, ties={})
    # ties: a point behind another by less than the tolerance in every objective stays on the front
    near = [{"bandwidth_S_hz": 30.0, "travel_um": 80.0, "resolution_nm": 2.00},
            {"bandwidth_S_hz": 29.8, "travel_um": 79.95, "resolution_nm": 2.03},    # 0.7 %, 0.06 %, 1.5 % behind 0
            {"bandwidth_S_hz": 29.0, "travel_um": 80.0, "resolution_nm": 2.00},     # 3.3 % behind 0 in bandwidth
            {"bandwidth_S_hz": 30.0, "travel_um": 80.0, "resolution_nm": 2.10}]     # 4.8 % behind 0 in sigma
    tol = {"bandwidth_S_hz": 0.01, "resolution_nm": 0.02, "travel_um": 1e-3}
    assert pareto_front(near, ties={}) == [0]
    assert pareto_front(near, ties=tol) == [0, 1]
    assert pareto_front(near, ties=dict(tol, resolution_nm=0.05)) == [0, 1, 3]
    assert all(PARETO_TIES[k] > 0 for k in ("bandwidth_S_hz", "resolution_nm", "travel_um"))
    # dominance with ties is not transitive: p < q < r < p (each ahead by > 10 % in one objective, behind by <= 10 %
    # in the others) leaves no point undominated, and the front falls back to the strict one (all three)
    cyc = [dict(zip("abc", v)) for v in ((1.0, 1.0, 1.0), (1.15, 0.95, 0.95), (1.08, 1.1, 0.89))]
    assert pareto_front(cyc, up=("a", "b", "c"), down=(), ties={k: 0.1 for k in "abc"}) == [0, 1, 2]
    assert pareto_front(cyc[:2], up=("a", "b", "c"), down=(), ties={k: 0.1 for k in "abc"}) == [1]
    assert parse_param("thickness.swing=150:210:3") == ("thickness.swing", 150.0, 210.0, 3)
    assert parse_param("thickness.fourbar2=60:80:2")[0] == "thickness.fb2"
    assert parse_param("length_mm.leg_length=16:24:3")[0] == "length_mm.leg_length"
    for bad in ("thickness.swing=90:130", "nope=1:2:2", "target_mass_g=0:2:2", "length_mm.nope=1:2:2"):
        with pytest.raises(ValueError, match="--param"):
            parse_param(bad)
    base = load_model()
    m = point_model({"stiffness.swing": 2.0, "target_mass_g": 30.0})
    assert m.jnt_stiffness[m.joint("b_h1_bend").id] == pytest.approx(2 * base.jnt_stiffness[base.joint("b_h1_bend").id])
    assert m.body_mass[m.body("table").id] == pytest.approx(0.030)
    thick = point_model({"thickness.swing": 200.0, "length_mm.leg_length": 22.0})
    assert thick.jnt_stiffness[thick.joint("c_h1_bend").id] > base.jnt_stiffness[base.joint("c_h1_bend").id]


# --- end to end ----------------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def controller_npz(tmp_path_factory, model):
    from nanosim.fileio import write_npz
    from nanosim.plant.modes import modal_analysis

    G0 = modal_analysis(model).static_gain_um_per_V
    T = 2.5e-4
    # 0.5 Hz integral loop: stable at both piezo ends despite Q ~ 100 modes (at 1 Hz the loop is unstable at the
    # nominal slope, at 178 Hz: the Monte Carlo reports the worse end)
    g = 2 * np.pi * 0.5 * T * np.linalg.inv(G0 / 5.0)
    return write_npz(tmp_path_factory.mktemp("ctrl") / "controller.npz", Akd=0.9995 * np.eye(3), Bkd=np.eye(3),
                     Ckd=g, Dkd=g, dt=np.float64(T))


def _samples(folder):
    return {p.name: json.loads(p.read_text()) for p in sorted((folder / "samples").glob("sample_*.json"))}


def test_montecarlo_writes_per_sample_resumes_and_seals(tmp_path, controller_npz):
    out = tmp_path / "mc"
    cfg = MonteCarloConfig(n=2, seed=4, crosscheck=1, workers=1, experiments=("small_steps",))
    s = run_montecarlo(controller_npz, out, cfg, progress=False)
    assert s["n"] == 2 and s["crosscheck_n"] == 1
    assert {"summary.json", "report.md", "tolerances.json", "spec.json", "montecarlo.json",
            "fig_mc_histograms.png"} <= {p.name for p in out.iterdir()}
    verify_manifest(out)
    first = _samples(out)
    assert set(first) == {"sample_00000.json", "sample_00001.json"}
    rec = first["sample_00000.json"]
    assert rec["closed_loop_stable"] and 0 < rec["disk_margin_alpha"] < 2 and len(rec["modes_hz"]) == 6
    assert rec["disk_margin_alpha"] == min(rec["disk_margin_alpha_post_reversal"], rec["disk_margin_alpha_nominal"])
    cross = s["crosscheck"][0]["metrics"]
    assert cross, "the MuJoCo cross-check compared no metric"
    # the twin's spread holds the sample's own twin (gain factor 1, same bits): its reading is inside every range
    spread = json.loads((out / "crosscheck_spread" / "sample_00000.json").read_text())
    assert spread["input_gain_factors"] == mc_stats.spread_gain_factors().tolist()
    twin0 = mc_stats.flatten_metrics(rec["metrics"])
    assert set(spread["spread"]) == set(twin0)
    for name, r in spread["spread"].items():
        assert r["min"] <= twin0[name] <= r["max"] and r["n"] == mc_stats.spread_gain_factors().size, name
    assert all("within_spread" in r for r in cross.values())
    mtimes = {p: p.stat().st_mtime_ns for p in (out / "samples").iterdir()}
    s2 = run_montecarlo(controller_npz, out, MonteCarloConfig(n=3, seed=4, crosscheck=1, workers=1,
                                                              experiments=("small_steps",)), progress=False)
    assert s2["timings"]["twin_samples_run"] == 1 and s2["timings"]["mujoco_samples_run"] == 0
    assert s2["timings"]["twin_spread_samples_run"] == 0
    assert all(p.stat().st_mtime_ns == t for p, t in mtimes.items())       # finished samples untouched
    verify_manifest(out)
    with pytest.raises(RunFolderError, match="another controller, seed"):
        run_montecarlo(controller_npz, out, MonteCarloConfig(n=2, seed=5, crosscheck=0, workers=1,
                                                             experiments=("small_steps",)), progress=False)


def test_bench_figure_takes_an_interval_end_rounded_past_its_yield():
    # a 95 % interval computed elsewhere may end an ulp below a 100 % yield: drawn, not refused
    from nanosim.plots.montecarlo import fig_bench

    rows = [{"controller": "a", "n": 100, "yield_percent": 100.0, "ci95_percent": [96.3, 99.99999999999999]},
            {"controller": "b", "n": 100, "yield_percent": 0.0, "ci95_percent": [1e-15, 3.7]}]
    fig = fig_bench(rows, {"a": [0.1, 0.2, 0.15], "b": []})
    assert len(fig.axes) == 2


def test_controller_names_are_stems_or_folder_stems():
    from nanosim.pipeline.mc_bench import controller_names

    got = controller_names(["/x/lqg.npz", "/x/paper.npz"])
    assert list(got) == ["lqg", "paper"]
    got = controller_names(["/runs/a/controller.npz", "/runs/b/controller.npz", "/runs/a/paper.npz"])
    assert list(got) == ["a-controller", "b-controller", "paper"]
    with pytest.raises(ValueError, match="share the name 'a-controller'"):
        controller_names(["/runs/a/controller.npz", "/runs/a/controller.npz"])
    with pytest.raises(ValueError, match="at least two"):
        controller_names(["/x/lqg.npz"])


def test_montecarlo_of_two_controllers_is_each_ones_own_run_and_compares_them(tmp_path, controller_npz):
    from nanosim.fileio import write_npz
    from nanosim.pipeline.mc_bench import run_montecarlo_bench

    z = np.load(controller_npz)
    slow = write_npz(tmp_path / "slow.npz", Akd=z["Akd"], Bkd=z["Bkd"], Ckd=0.5 * z["Ckd"], Dkd=0.5 * z["Dkd"],
                     dt=z["dt"])
    fast = tmp_path / "fast.npz"
    fast.write_bytes(Path(controller_npz).read_bytes())
    cfg = MonteCarloConfig(n=2, seed=4, crosscheck=0, workers=1, experiments=("small_steps",))
    out = tmp_path / "cmp"
    doc = run_montecarlo_bench([fast, slow], out, cfg, progress=False)
    verify_manifest(out)
    assert [r["controller"] for r in doc["controllers"]] == ["fast", "slow"]
    # each sub-folder is that controller's own Monte Carlo, bit for bit
    single = tmp_path / "single"
    run_montecarlo(slow, single, cfg, progress=False)
    assert _samples(single) == _samples(out / "slow")
    for r in doc["controllers"]:
        flats = [mc_stats.flatten_metrics(x["metrics"]) | {"disk_margin_alpha": x["disk_margin_alpha"]}
                 for x in _samples(out / r["controller"]).values()]
        alpha = np.array([f["disk_margin_alpha"] for f in flats])
        assert r["n"] == 2 and r["disk_margin_alpha"]["worst"] == alpha.min()
        assert r["disk_margin_alpha"]["median"] == pytest.approx(np.median(alpha), rel=1e-12)
        s = json.loads((out / r["controller"] / "summary.json").read_text())
        assert r["pass"] == next(y["pass"] for y in s["yield"] if y["metric"] == "all")
    # half the loop gain: a different loop, a different margin
    a = {r["controller"]: r["disk_margin_alpha"]["median"] for r in doc["controllers"]}
    assert a["fast"] != a["slow"]
    assert {"montecarlo_bench.json", "summary.json", "report.md", "fig_mc_bench.png", "manifest.json"} <= {
        p.name for p in out.iterdir()}
    assert "| `slow` |" in (out / "report.md").read_text()
    # a rerun resumes (nothing to run) and seals again; another seed is refused
    mtimes = {p: p.stat().st_mtime_ns for p in (out / "fast" / "samples").iterdir()}
    run_montecarlo_bench([fast, slow], out, cfg, progress=False)
    assert all(p.stat().st_mtime_ns == t for p, t in mtimes.items())
    verify_manifest(out)
    with pytest.raises(RunFolderError, match="another seed"):
        run_montecarlo_bench([fast, slow], out, MonteCarloConfig(n=2, seed=5, crosscheck=0, workers=1,
                                                                 experiments=("small_steps",)), progress=False)


def _result_bytes(folder):
    """Every file of a run folder but the two that may differ between runs with the same seed."""
    from nanosim.pipeline.artifacts import MANIFEST_JSON, TIMINGS_JSON

    return {p.relative_to(folder).as_posix(): p.read_bytes() for p in sorted(folder.rglob("*"))
            if p.is_file() and p.name not in (TIMINGS_JSON, MANIFEST_JSON)}


def test_chunking_and_the_cluster_do_not_change_a_bit(tmp_path, controller_npz):
    """5 samples as one chunk of 5 on one local worker vs 5 chunks of 1 on a 2-worker Dask cluster: other batch
    compositions and placements, the same sample records bit for bit, and every file but timings.json and
    manifest.json byte-identical."""
    pytest.importorskip("distributed")
    from nanosim.pipeline.artifacts import TIMINGS_JSON

    cfg = dict(n=5, seed=7, crosscheck=0, experiments=("small_steps",))
    run_montecarlo(controller_npz, tmp_path / "local", MonteCarloConfig(**cfg, workers=1, chunk=5), progress=False)
    run_montecarlo(controller_npz, tmp_path / "dask", MonteCarloConfig(**cfg, workers=2, chunk=1, scheduler="local"),
                   progress=False)
    a, b = _samples(tmp_path / "local"), _samples(tmp_path / "dask")
    assert len(a) == 5 and a.keys() == b.keys()
    for k in a:
        assert a[k]["metrics"] and a[k]["metrics"] == b[k]["metrics"]       # JSON floats round-trip: bitwise
        assert "seconds" not in a[k]                                        # wall time: in timings.json
        assert a[k]["units"]["tolerances"] == {"thickness.*": "um", "radius.*": "um", "width.*": "um",
                                               "target_mass": "g", "piezo_gain.*": "dimensionless factor"}
    ra, rb = _result_bytes(tmp_path / "local"), _result_bytes(tmp_path / "dask")
    assert ra.keys() == rb.keys() and [k for k in ra if ra[k] != rb[k]] == []
    timings = json.loads((tmp_path / "dask" / TIMINGS_JSON).read_text())["files"]
    assert {f"samples/sample_{i:05d}.json" for i in range(5)} | {"summary.json"} == set(timings)
    assert TIMINGS_JSON in verify_manifest(tmp_path / "dask")["files_sha256"]


def test_same_seed_same_bytes_but_timings(tmp_path, controller_npz):
    """``nanosim characterize --twin --only small_steps`` twice: only timings.json and manifest.json differ."""
    import subprocess
    import sys

    from nanosim.pipeline.artifacts import METRICS_JSON, TIMINGS_JSON

    for name in ("a", "b"):
        subprocess.run([sys.executable, "-m", "nanosim", "characterize", "--controller", str(controller_npz),
                        "--out", str(tmp_path / name), "--twin", "--only", "small_steps", "--seed", "3"],
                       check=True, capture_output=True, timeout=600)
    ra, rb = _result_bytes(tmp_path / "a"), _result_bytes(tmp_path / "b")
    assert METRICS_JSON in ra and ra.keys() == rb.keys() and [k for k in ra if ra[k] != rb[k]] == []
    assert "experiment_seconds" not in json.loads(ra[METRICS_JSON])
    timings = json.loads((tmp_path / "a" / TIMINGS_JSON).read_text())["files"]
    assert list(timings[METRICS_JSON]["experiment_seconds"]) == ["small_steps"]
    assert TIMINGS_JSON in verify_manifest(tmp_path / "a")["files_sha256"]


def test_crosscheck_agreement_is_relative_or_within_two_reading_quanta():
    # the ADC count is 20 V / 2^16 x 5 um/V = 1.526 nm; each metric with a resolution is a difference of two
    # readings (or two instants), so it is resolved to two counts (two control periods). A closed-loop creep
    # drift of 0.03 vs 0.04 nm (33 %) is far below it and agrees; an overshoot 1.1 counts apart agrees; a contour
    # error of 23.2 vs 21.6 nm (7 %, 1.6 nm, an averaged metric) does not
    lsb = 20.0 / 2 ** 16 * 5.0 * 1e3
    assert mc_stats.READING_QUANTA_PER_METRIC == 2
    assert mc_stats.CROSSCHECK_RESOLUTION["creep.closed_loop_drift_nm"] == pytest.approx(2 * lsb, rel=1e-12)
    assert mc_stats.CROSSCHECK_RESOLUTION["hysteresis.closed_loop_nm"] == pytest.approx(2 * lsb, rel=1e-12)
    assert mc_stats.CROSSCHECK_RESOLUTION["step_2um.overshoot_percent"] == pytest.approx(200 * lsb / 2000, rel=1e-12)
    assert mc_stats.CROSSCHECK_RESOLUTION["step_2um.rise_ms"] == pytest.approx(0.5)
    twin = {"creep.closed_loop_drift_nm": 0.03, "step_2um.rise_ms": 3.0, "contouring.1000um_s.mean_error_nm": 23.2,
            "bandwidth_S_hz": 52.0, "step_2um.overshoot_percent": 0.763, "hysteresis.closed_loop_nm": 0.2}
    mj = {"creep.closed_loop_drift_nm": 0.04, "step_2um.rise_ms": 3.5, "contouring.1000um_s.mean_error_nm": 21.6,
          "bandwidth_S_hz": 53.0, "step_2um.overshoot_percent": 0.763 + 100 * 3.2 * lsb / 2000,
          "hysteresis.closed_loop_nm": 0.2 + 2.01 * lsb}
    c = mc_stats.compare_crosscheck(twin, mj)
    m = c["metrics"]
    assert m["creep.closed_loop_drift_nm"]["ok"] and not m["creep.closed_loop_drift_nm"]["ok_relative"]
    assert m["creep.closed_loop_drift_nm"]["within_resolution"] and not m["bandwidth_S_hz"]["within_resolution"]
    assert m["step_2um.rise_ms"]["ok"] and not m["step_2um.rise_ms"]["ok_relative"]     # two samples
    assert m["bandwidth_S_hz"]["ok"] and m["bandwidth_S_hz"]["ok_relative"]              # 1.9 %
    assert not m["contouring.1000um_s.mean_error_nm"]["ok"]
    assert not m["step_2um.overshoot_percent"]["ok"]                                     # 3.2 counts, 29 %
    assert not m["hysteresis.closed_loop_nm"]["ok"]                                      # 2.01 counts
    assert m["contouring.1000um_s.mean_error_nm"]["abs_diff"] == pytest.approx(1.6)
    assert not c["all_ok"] and not c["all_ok_relative"]
    twin["contouring.1000um_s.mean_error_nm"] = 22.0                                     # 1.8 %
    mj["step_2um.overshoot_percent"] = 0.763 + 100 * 1.1 * lsb / 2000                     # 1.1 counts, 10 %
    mj["hysteresis.closed_loop_nm"] = 0.2 + 1.9 * lsb
    c = mc_stats.compare_crosscheck(twin, mj)
    assert c["all_ok"] and not c["all_ok_relative"]
    # two rises two samples apart plus a hair: not within the two quanta
    c = mc_stats.compare_crosscheck({"step_2um.rise_ms": 3.0}, {"step_2um.rise_ms": 3.5001})
    assert not c["all_ok"]


def test_crosscheck_agrees_within_the_resolution_of_the_twins_spread():
    # seed 1's sample 9: twin 0.605 %, MuJoCo 0.763 % (3.2 nm apart, 2.1 counts) fails the two-count
    # rule on the twin's reading alone; the twin's readings at 0-8 ppm span 0.529-0.691 %: MuJoCo is 1.4 nm above
    # the range, within two counts; a range ending at 0.60 % leaves it 3.3 nm (2.1 counts) out
    lsb = 20.0 / 2 ** 16 * 5.0 * 1e3
    f = mc_stats.spread_gain_factors()
    assert f.size == 2 * mc_stats.SPREAD_MEMBERS_PER_SIDE + 1 and f[f.size // 2] == 1.0
    assert np.max(np.abs(f - 1)) == pytest.approx(8e-6, rel=1e-9)
    m = "step_2um.overshoot_percent"
    twin, mj = {m: 0.605, "bandwidth_S_hz": 36.0}, {m: 0.763, "bandwidth_S_hz": 36.1}
    assert not mc_stats.compare_crosscheck(twin, mj)["all_ok"]
    flats = [{m: v, "bandwidth_S_hz": 36.0 + 0.001 * k} for k, v in enumerate((0.529, 0.605, 0.691, 0.6, 0.62))]
    spread = mc_stats.reading_spread(flats)
    assert spread[m] == pytest.approx({"min": 0.529, "max": 0.691, "mean": 0.609, "std": np.std(
        [0.529, 0.605, 0.691, 0.6, 0.62], ddof=1), "n": 5})
    c = mc_stats.compare_crosscheck(twin, mj, spread=spread)
    row = c["metrics"][m]
    assert c["all_ok"] and row["within_spread"] and not row["within_resolution"] and not row["ok_relative"]
    assert not row["ok_without_spread"] and not c["all_ok_without_spread"]
    assert row["spread_gap"] * 20 == pytest.approx(1.44, abs=1e-9) and row["spread_gap"] * 20 / lsb < 2
    spread[m]["max"] = 0.60
    row = mc_stats.compare_crosscheck(twin, mj, spread=spread)["metrics"][m]
    assert not row["ok"] and row["spread_gap"] * 20 / lsb == pytest.approx(3.26 / lsb)
    # a metric without a resolution agrees through the spread only inside the twin's range
    twin2, mj2 = {"bandwidth_S_hz": 30.0}, {"bandwidth_S_hz": 36.003}
    assert mc_stats.compare_crosscheck(twin2, mj2, spread=mc_stats.reading_spread(flats))["all_ok"]
    assert not mc_stats.compare_crosscheck(twin2, {"bandwidth_S_hz": 36.0045},
                                           spread=mc_stats.reading_spread(flats))["all_ok"]


def test_crosscheck_bias_is_the_mean_difference_from_the_twins_spread_centre():
    m = "step_2um.overshoot_percent"
    spreads = [{m: {"min": 0.5, "max": 0.7, "mean": 0.6, "std": 0.05, "n": 17}},
               {m: {"min": 0.9, "max": 1.1, "mean": 1.0, "std": 0.05, "n": 17}}, None]
    pairs = [(0.55, 0.65), (1.05, 0.98), (0.4, 0.44)]          # (twin, MuJoCo); the third sample has no spread
    cross = [mc_stats.compare_crosscheck({m: a}, {m: b}, spread=sp) for (a, b), sp in zip(pairs, spreads)]
    b = mc_stats.crosscheck_bias(cross)[m]
    d = np.array([0.65 - 0.6, 0.98 - 1.0, 0.44 - 0.4])
    assert b["n"] == 3 and b["mean_diff"] == pytest.approx(d.mean(), rel=1e-12)
    assert b["std_err"] == pytest.approx(d.std(ddof=1) / np.sqrt(3), rel=1e-12)
    assert b["mean_diff_percent"] == pytest.approx(100 * np.mean(d / np.array([0.6, 1.0, 0.4])), rel=1e-12)
    assert math.isnan(mc_stats.crosscheck_bias(cross[:1])[m]["std_err"])


def test_quantizers_make_the_loop_path_sensitive_to_a_ppm_gain_change():
    # why the cross-check needs the twin's spread: 17 twins of one stage whose input gains differ by 0-8 ppm, in a
    # loop with the LQG of the identified seed-0 model, a 2 um step. With the DAC and ADC quantizers (noise on or
    # off) the table paths part by more than an ADC count; without them (noise on or off) by a hundredth of a nm, as a
    # gain change of ppm should (8 ppm of 2 um is 16 pm)
    import dataclasses

    from nanosim import constants as C
    from nanosim.design.architectures.lqg import lqg_controller
    from nanosim.design.controller import ControllerConfig
    from nanosim.design.lti import load_state_space_npz
    from nanosim.experiments.batch_loop import BatchController, run_closed_loop_batch
    from nanosim.plant.batch import BatchTwinStage, TwinMatrices
    from nanosim.plant.floor import floor_model
    from nanosim.plant.linearize import linearize
    from nanosim.plant.stage import Stage, StageConfig

    K = lqg_controller(load_state_space_npz(Path(__file__).parent / "data" / "identified_seed0.npz")[1])
    ctrl = ControllerConfig(np.asarray(K.A), np.asarray(K.B), np.asarray(K.C), np.asarray(K.D), float(K.dt),
                            n_error=3)
    m = load_model()
    base = TwinMatrices.of(linearize(Stage(config=StageConfig.ideal(), model=m)))
    factors = mc_stats.spread_gain_factors()
    twins = [base.input_scaled(f) for f in factors]
    home = Stage(model=m).table_um.copy()
    ref = np.zeros((1240, 3))
    ref[40:, 0] = 2.0
    full = StageConfig()
    e = full.electronics
    quiet = dict(dac_noise=False, amplifier_noise=False, sensor_noise=False)
    no_quant = dict(dac_quantization=False, adc_quantization=False)

    def path_spread_nm(electronics, floor):
        cfg = dataclasses.replace(full, electronics=dataclasses.replace(e, **electronics), floor=floor)
        stage = BatchTwinStage(twins, [0] * len(twins), config=cfg, home_um=np.tile(home, (len(twins), 1)),
                               floor_models=[floor_model(m)] * len(twins))
        tab = np.array([t.table_um[:, 0] for t in run_closed_loop_batch(stage, BatchController([ctrl] * len(twins)),
                                                                         ref)])
        return 1e3 * np.abs(tab - tab[len(twins) // 2]).max()

    off = type(full.floor).off()
    assert path_spread_nm({}, full.floor) > C.ADC_LSB_NM
    assert path_spread_nm(quiet, off) > C.ADC_LSB_NM
    assert path_spread_nm(no_quant, full.floor) < 0.05
    assert path_spread_nm({**quiet, **no_quant}, off) < 0.05


def test_a_peak_minus_mean_reading_is_resolved_to_two_adc_counts():
    # |Q(a) - Q(b)| <= |a - b| + q per sample, so the step's overshoot (peak reading minus the pre-step mean, in
    # the code's own step_metrics and ADC quantiser) of two records differs by at most 2 ||a - b||_inf + 2 q; and
    # two records a hair apart can read two counts apart, so one count is too fine
    from nanosim import constants as C
    from nanosim.experiments.loop import step_metrics
    from nanosim.plant.electronics import quantize

    q_um = C.ADC_LSB_NM * 1e-3
    step_um, k0 = 2.0, 40
    t = np.arange(1200) / 4000.0

    def overshoot(y_true_um):
        y = quantize(y_true_um / C.SENSOR_UM_PER_V, C.ADC_BITS, C.ADC_FULL_SCALE_V)[0] * C.SENSOR_UM_PER_V
        return step_metrics(t[:-k0], y[k0:] - y[:k0].mean(), step_um)[3]

    rng = np.random.default_rng(0)
    beyond_one_count = 0
    for _ in range(200):
        resp = step_um * (1 - np.exp(-t[:-k0] / 1e-3) * np.cos(2 * np.pi * 180 * t[:-k0]))
        a = np.concatenate([np.zeros(k0), resp]) + rng.normal(0, 2e-3, t.size)
        d = rng.uniform(-1, 1, t.size) * rng.choice([1e-6, 1e-4, 3e-4])
        b = a + d
        diff_counts = abs(overshoot(a) - overshoot(b)) * step_um / 100 / q_um
        assert diff_counts <= 2 * np.abs(d).max() / q_um + 2 + 1e-9
        beyond_one_count += diff_counts > 1.0
    assert beyond_one_count >= 1        # records within 0.2 count of each other, read more than one count apart
    # the bound is reached: the peak rounds up in one record, the whole pre-step baseline down in the other
    eps = 1e-9
    a = np.zeros(t.size)
    a[:k0] = 0.5 * q_um - eps
    a[k0:] = step_um
    peak_um = (round(step_um / q_um) + 7.5) * q_um           # on a rounding edge, as is the baseline
    a[k0 + 20] = peak_um - eps
    b = a.copy()
    b[:k0] = 0.5 * q_um + eps
    b[k0 + 20] = peak_um + eps
    assert abs(overshoot(a) - overshoot(b)) * step_um / 100 / q_um == pytest.approx(0.0, abs=1e-9)
    b[:k0] = 0.5 * q_um - eps
    a[:k0] = 0.5 * q_um + eps
    assert abs(overshoot(a) - overshoot(b)) * step_um / 100 / q_um == pytest.approx(2.0, abs=1e-6)


def test_sweep_point_with_the_bandwidth_rule_end_to_end(tmp_path):
    # one point (the nominal stage's fb2 web): modes from the point's model, a controller redesigned by the named rule
    # on the point's identified twin, and the measured S bandwidth near the rule's prediction for it
    from nanosim.design.architectures.lqg import ROBUST_MIN_DISK_MARGIN
    from nanosim.pipeline.config import DesignConfig, SweepConfig
    from nanosim.pipeline.sweep import run_sweep
    from nanosim.plant.modes import modal_analysis

    cfg = SweepConfig(params=(("target_mass_g", 10.0, 10.0, 1),), workers=1,
                      design=DesignConfig(architecture="lqg-bandwidth"))
    doc = run_sweep(tmp_path, cfg, progress=False)
    assert doc["design"]["architecture"] == "lqg-bandwidth"
    (pt,) = doc["points"]
    rec = json.loads(next((tmp_path / "points").glob("*.json")).read_text())
    first = modal_analysis(point_model({"target_mass_g": 10.0})).physical[0].freq_hz
    assert rec["first_mode_hz"] == pytest.approx(first, rel=1e-9)
    assert rec["architecture"] == "lqg-bandwidth" and rec["exported_rule_met"] is True
    assert pt["exported_disk_margin"] >= ROBUST_MIN_DISK_MARGIN and pt["exported_mu_peak"] < 1.0
    # measured reference to error on the twin (PRBS) inside the predictions on the identified model at the two ends
    # of the piezo's gain range (the slope after a reversal, which it holds, and a monotone move's, 1.36 x)
    lo = rec["exported_predicted_bandwidth_ref_to_error_hz"]
    hi = rec["exported_predicted_bandwidth_ref_to_error_top_hz"]
    assert 0.97 * lo <= pt["bandwidth_S_hz"] <= 1.03 * hi and hi > lo
    report = (tmp_path / "report.md").read_text()
    assert "--architecture lqg-bandwidth" in report and "the smallest control weight" in report


def test_pareto_figure_keeps_a_flat_axis_readable():
    # a parameter that leaves travel unchanged to 1e-8 (the table mass): its axis spans +-0.5 % of the value instead
    # of 1e-6 um (unreadable ticks); an axis that spreads keeps matplotlib's limits
    from nanosim.plots.montecarlo import fig_pareto

    travel = np.array([74.2767441, 74.2767452, 74.2767470])
    lo, hi = travel.mean() * 0.995, travel.mean() * 1.005
    pts = [{"travel_um": t, "bandwidth_S_hz": b, "resolution_nm": 2.0} for t, b in zip(travel, (57.7, 53.2, 45.8))]
    ax = fig_pareto(pts, [0], "travel_um", "bandwidth_S_hz", "resolution_nm").axes[0]
    assert ax.get_xlim() == pytest.approx((lo, hi)) and ax.get_ylim()[0] < 45.8 < 57.7 < ax.get_ylim()[1]


def test_sweep_report_columns_follow_the_design_rule():
    # an lqg rule's points show its own margin, mu and weight; the H-infinity design's its gamma (the lqg rows'
    # gamma belongs to the H-infinity reference design, not to the exported controller)
    from nanosim.pipeline.sweep import report_markdown

    pt = {"index": 0, "label": "target_mass_g=10", "first_mode_hz": 172.6, "travel_um": 74.28, "bandwidth_S_hz": 53.2,
          "bandwidth_T_hz": 137.0, "resolution_nm": 2.07, "gamma": 1.207, "exported_disk_margin": 0.659,
          "exported_mu_peak": 0.982, "exported_control_weight": 0.001, "pareto": True}
    doc = {"parameters": [{"name": "target_mass_g", "values": [10.0]}], "points": [pt], "pareto_ties": PARETO_TIES,
           "design": {"architecture": "lqg-bandwidth"}}
    rows = [ln for ln in report_markdown(doc, 1.0).splitlines() if ln.startswith("| ")]
    assert rows[0].endswith("| disk margin | mu | R_u | Pareto |")
    assert rows[1].endswith("| 0.659 | 0.982 | 0.001 | yes |")
    doc["design"]["architecture"] = "hinf"
    rows = [ln for ln in report_markdown(doc, 1.0).splitlines() if ln.startswith("| ")]
    assert rows[0].endswith("| gamma | Pareto |") and rows[1].endswith("| 1.207 | yes |") and "0.659" not in rows[1]
