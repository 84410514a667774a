"""Scan patterns, the synthetic sample, imaging and its metrics, and ``nanosim scan``'s command line.

Geometry is checked against the patterns' closed forms; imaging against a perfect trajectory
(the image must reproduce the truth) and against a pure delay, whose trace/retrace offset is
``2 v tau`` (the trace image shifted by ``+v tau``, the retrace by ``-v tau``).
"""
from __future__ import annotations

import json

import numpy as np
import pytest

from nanosim.cli import main
from nanosim.experiments import scan as S
from nanosim.experiments.loop import FS, LoopTrace
from nanosim.fileio import write_npz


def _perfect(pattern, delay_samples: int = 0, smoothing: bool = True) -> LoopTrace:
    """A loop record whose table (and sensor) follow the reference exactly, ``delay_samples`` late."""
    ref = S.pattern_reference(pattern, smoothing=smoothing)
    table = ref.copy()
    if delay_samples:
        table[delay_samples:] = ref[:-delay_samples]
        table[:delay_samples] = ref[0]
    return LoopTrace(pattern.t_s, ref, table.copy(), table, np.zeros_like(ref), np.zeros(ref.shape, bool))


# ---------------------------------------------------------------------------------------------- geometry
@pytest.mark.parametrize("slow", ["staircase", "ramp"])
def test_raster_covers_the_square(slow):
    size, px, f = 20.0, 64, 5.0
    p = S.raster(size, px, f, slow_axis=slow)
    assert len(p.t_s) == round((px + 1) / f * FS) and np.count_nonzero(p.imaged) == round(px / f * FS)
    x, y = p.xy_um[p.imaged].T
    o = 2 * size * f * 0.0025 / 2                       # default overscan: half the interpolation at trace speed
    assert x.min() == pytest.approx(-o, abs=1e-9) and x.max() == pytest.approx(size + o, abs=1e-3)
    trace = p.direction[p.imaged] > 0
    assert np.all(np.diff(x)[trace[:-1] & trace[1:]] > 0)          # trace: X rising
    pitch = size / px
    if slow == "staircase":                              # one line per pixel row, at its centre
        np.testing.assert_allclose(np.unique(y), (np.arange(px) + 0.5) * pitch, atol=1e-12)
    else:                                                # a ramp of one pitch per line period
        ramp = y[1:] < size                              # the last quarter line is clipped at the field's edge
        np.testing.assert_allclose(np.diff(y)[ramp] * FS, pitch * f, rtol=1e-9)
        assert ramp.mean() > 1 - 0.3 / px
    ref = S.pattern_reference(p)                         # after the command interpolation: every pixel covered
    assert S.coverage_mask(ref[p.imaged, :2], size, px).all()


def test_spiral_clv_speed_is_constant_and_cav_turns_evenly():
    size, px, f = 20.0, 64, 2.0
    clv = S.spiral(size, px, f, velocity="linear")
    xy = clv.xy_um[clv.imaged]
    r = np.hypot(*(xy - size / 2).T)
    assert r[0] == pytest.approx(0.0, abs=1e-12) and r[-1] == pytest.approx(size / 2, rel=1e-3)
    speed = np.hypot(*np.diff(xy, axis=0).T) * FS
    outer = r[1:] > 2 * size / px                        # chords are arcs to 1e-4 beyond two rings
    v = speed[outer]
    assert np.ptp(v) / v.mean() < 2e-3
    assert v.mean() * clv.frame_s == pytest.approx(np.pi * (size / 2) ** 2 / (size / px), rel=0.01)  # area / pitch
    cav = S.spiral(size, px, f, velocity="angular")
    c = cav.xy_um[cav.imaged] - size / 2
    th = np.unwrap(np.arctan2(c[1:, 1], c[1:, 0]))
    np.testing.assert_allclose(np.diff(th) * FS / (2 * np.pi), f / 2, rtol=1e-7)   # pixels/2 rings per frame
    np.testing.assert_allclose(np.hypot(*c.T), size / 2 * cav.t_s[cav.imaged] / cav.frame_s, atol=1e-12)


def test_lissajous_frequencies_and_closure():
    size, px, f = 20.0, 64, 4.0
    p = S.lissajous(size, px, f)
    n = round(np.pi * px / 4)
    T = px / f
    assert p.freqs_hz == pytest.approx((n / T, (n - 1) / T))
    xy = p.xy_um[p.imaged] - size / 2
    spec = np.abs(np.fft.rfft(xy, axis=0))
    freqs = np.fft.rfftfreq(len(xy), 1 / FS)
    assert freqs[np.argmax(spec[:, 0])] == pytest.approx(n / T)
    assert freqs[np.argmax(spec[:, 1])] == pytest.approx((n - 1) / T)
    assert np.abs(xy).max() == pytest.approx(size / 2, rel=1e-4)
    q = S.lissajous(size, px, f, freqs_hz=(30.0, 29.0))
    assert q.freqs_hz == (30.0, 29.0)


def test_rosette_is_a_turning_diameter():
    size, px, f = 20.0, 32, 4.0
    p = S.rosette(size, px, f)
    f1, f2 = p.freqs_hz
    T = px / f
    assert (f1 - f2) * T == pytest.approx(1.0) and round((f1 + f2) * T) % 2 == 1
    t = p.t_s[p.imaged]
    c = p.xy_um[p.imaged] - size / 2
    np.testing.assert_allclose(np.hypot(*c.T), size / 2 * np.abs(np.cos(np.pi * (f1 + f2) * t)), atol=1e-9)


def test_pattern_errors_before_any_work():
    for call, name in ((lambda: S.raster(20, 0, 10), "pixels"), (lambda: S.raster(-1, 8, 10), "size_um"),
                       (lambda: S.raster(20, 8, np.nan), "line_rate_hz"),
                       (lambda: S.raster(20, 8, 10, slow_axis="zigzag"), "slow_axis"),
                       (lambda: S.spiral(20, 8, 10, velocity="warp"), "velocity"),
                       (lambda: S.lissajous(20, 8, 10, freqs_hz=(1.0,)), "freqs_hz"),
                       (lambda: S.scan_pattern("hexagon", 20, 8, 10), "pattern"),
                       (lambda: S.scan_pattern("raster", 20, 8, 10, freqs_hz=(1, 2)), "freqs_hz"),
                       (lambda: S.Sample(roughness_nm=-1), "roughness_nm")):
        with pytest.raises(ValueError, match=rf"^{name}: expected"):
            call()


# ---------------------------------------------------------------------------------------------- sample
def test_sample_is_seeded_and_has_its_roughness():
    a, b, c = S.Sample(seed=3), S.Sample(seed=3), S.Sample(seed=4)
    x, y = np.meshgrid(np.linspace(0, 20, 101), np.linspace(0, 20, 101))
    assert np.array_equal(a.height_nm(x, y), b.height_nm(x, y))
    assert not np.array_equal(a.height_nm(x, y), c.height_nm(x, y))
    flat = S.Sample(grating_height_nm=0.0, roughness_nm=5.0)
    grid = flat.period_um / flat.grid * np.arange(flat.grid)          # the synthesis grid: rms exactly sigma
    h = flat.height_nm(grid[None, :], grid[:, None])
    assert h.std() == pytest.approx(5.0, rel=1e-9)
    g = S.Sample(roughness_nm=0.0)                   # pillars: 0 in the gaps, H on the tops (tanh edges)
    assert g.height_nm(0.75 * g.pitch_um, 0.25 * g.pitch_um) == pytest.approx(0.0, abs=1e-12)
    assert g.height_nm(0.25 * g.pitch_um, 0.25 * g.pitch_um) == pytest.approx(100.0, rel=1e-12)


# ---------------------------------------------------------------------------------------------- imaging
@pytest.mark.parametrize("name", S.PATTERNS)
def test_perfect_trajectory_reproduces_the_truth(name):
    p = S.scan_pattern(name, 20.0, 128, 10.0)
    res = S.analyse_scan(p, _perfect(p), S.Sample(), placement="reference")
    m = res.metrics()
    assert m["position_error_max_nm"] == pytest.approx(0.0, abs=1e-9)
    # the resampling alone (records half a pixel apart, cell means, linear interpolation) stays under the
    # default 1 % limit; the raster, one record line per pixel row, under 0.5 %
    assert m["image_error_fraction"] < (5e-3 if name == "raster" else 1e-2), m
    cover = {"raster": 1.0, "lissajous": 1.0, "spiral": np.pi / 4, "rosette": np.pi / 4}[name]
    assert m["coverage_fraction"] == pytest.approx(cover, abs=0.03)
    # the image reaches nearly every covered pixel: only the rim between turnarounds is left out
    assert m["imaged_fraction"] > 0.97, m
    if name == "raster":
        assert abs(res.trace_retrace_offset_um) < 0.02 * p.pitch_um


def test_form_image_is_exact_for_a_plane_and_does_not_bridge_gaps():
    """A height linear in x and y is imaged exactly wherever the records reach (cell means and linear
    interpolation are exact for a plane); between two bands of records farther apart than
    MAX_EDGE_PIXELS pitches nothing is imaged, next to them everything is."""
    size, px = 10.0, 64
    p = size / px
    x = np.linspace(0.0, size, 4001)

    def band(y0, y1):                                   # records on every pixel row from y0 to y1, dense in x
        rows = np.arange(y0, y1 + 1e-9, p)
        return np.column_stack([np.tile(x, rows.size), np.repeat(rows, x.size)])

    xy = np.concatenate([band(0.0, 3.0), band(7.0, size)])
    h = 3.0 * xy[:, 0] - 2.0 * xy[:, 1] + 5.0
    img = S.form_image(xy, h, size, px)
    X, Y = np.meshgrid((np.arange(px) + 0.5) * p, (np.arange(px) + 0.5) * p)
    ok = np.isfinite(img)
    np.testing.assert_allclose(img[ok], (3.0 * X - 2.0 * Y + 5.0)[ok], rtol=0, atol=1e-9)
    gap = (Y > 3.0) & (Y < 7.0)                         # 4 um = 25.6 pitches between the bands
    assert not ok[gap].any()
    inner = (X > p) & (X < size - p) & ~gap & (Y > p) & (Y < size - p)     # pixel centres inside a band
    assert ok[inner].all()
    # the same gap narrower than MAX_EDGE_PIXELS pitches is bridged
    xy2 = np.concatenate([band(0.0, 3.0), band(3.0 + 2 * p, size)])
    img2 = S.form_image(xy2, 3.0 * xy2[:, 0] - 2.0 * xy2[:, 1] + 5.0, size, px)
    assert np.isfinite(img2[(X > p) & (X < size - p) & (Y > p) & (Y < size - p)]).all()
    with pytest.raises(ValueError, match="max_edge_pixels"):
        S.form_image(xy, h, size, px, max_edge_pixels=0.0)


def test_pure_delay_gives_trace_retrace_offset_two_v_tau():
    size, px, f, d = 20.0, 128, 2.0, 20            # tau = 20 samples = 5 ms
    p = S.raster(size, px, f)
    o = 2 * size * f * 0.0025 / 2
    v = 2 * (size + 2 * o) * f                      # trace speed, um/s
    tau = d / FS
    res = S.analyse_scan(p, _perfect(p, d), S.Sample(), placement="reference")
    assert res.trace_retrace_offset_um == pytest.approx(2 * v * tau, rel=0.03)
    # the distortion is the lag, -v tau along X in the trace's middle
    mid = res.distortion_um[px // 2, px // 4:3 * px // 4, 0]
    assert np.nanmedian(mid) == pytest.approx(0.0, abs=v * tau)      # trace and retrace cells average out
    assert res.position_rms_nm == pytest.approx(1e3 * v * tau, rel=0.05)
    # placed at the sensor (which follows the table), the delay moves nothing in the image
    at_sensor = S.analyse_scan(p, _perfect(p, d), S.Sample(), placement="sensor")
    assert abs(at_sensor.trace_retrace_offset_um) < 0.02 * p.pitch_um


def test_offset_estimator_on_shifted_images():
    rng = np.random.default_rng(0)
    base = np.cumsum(rng.standard_normal((40, 400)), axis=1)
    x = np.arange(400)
    shift = 3.4                                      # pixels
    trace = np.array([np.interp(x - shift, x, r) for r in base])
    assert S.trace_retrace_offset_um(trace, base, 0.1) == pytest.approx(0.1 * shift, abs=0.01)
    assert S.trace_retrace_offset_um(base, trace, 0.1) == pytest.approx(-0.1 * shift, abs=0.01)


def test_line_rate_at_limit_interpolates_the_crossing():
    r = np.array([1.0, 2.0, 5.0, 10.0, 20.0])
    e = 1e-4 * r ** 2                                 # a power law crosses at sqrt(limit / 1e-4)
    rate, status = S.line_rate_at_limit(r, e, 0.01)
    assert status == "crossed" and rate == pytest.approx(10.0)
    rate, status = S.line_rate_at_limit(r, e, 0.0042)
    assert rate == pytest.approx(np.sqrt(42.0), rel=1e-12)
    assert S.line_rate_at_limit(r, e, 1.0) == (20.0, "below_all")
    rate, status = S.line_rate_at_limit(r, e, 1e-5)
    assert np.isnan(rate) and status == "above_all"


# ---------------------------------------------------------------------------------------------- command line
@pytest.fixture(scope="module")
def ctrl(tmp_path_factory):
    """A zero controller (the stage stays at home): enough for the command's checks and files."""
    d = tmp_path_factory.mktemp("scan")
    return write_npz(d / "ctrl.npz", Akd=np.zeros((1, 1)), Bkd=np.zeros((1, 3)), Ckd=np.zeros((3, 1)),
                     Dkd=np.zeros((3, 3)), dt=2.5e-4)


@pytest.mark.parametrize("extra, name", [
    (["--pattern", "hexagon"], "--pattern"), (["--pattern", "raster,raster2"], "--pattern"),
    (["--pixels", "4"], "--pixels"), (["--line-rate", "0"], "--line-rate"), (["--size", "-3"], "--size"),
    (["--freqs", "10", "9"], "--freqs"), (["--limit", "0"], "--limit"), (["--sweep", "5", "-1"], "--sweep"),
    (["--slow-axis", "zigzag"], "--slow-axis"), (["--placement", "tip"], "--placement"),
    (["--controller", "/nonexistent/ctrl.npz"], "--controller")])
def test_cli_errors_one_line_exit_2(extra, name, ctrl, tmp_path, capsys):
    out = tmp_path / "out"
    argv = ["scan", "--controller", str(ctrl), "--out", str(out), "--pattern", "raster", "--twin", *extra]
    try:
        code = main(argv)
    except SystemExit as e:                      # argparse's own checks exit from parse_args
        code = e.code
    assert code == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and name in err, err
    assert not out.exists()


def test_cli_writes_the_scan_folder(ctrl, tmp_path):
    out = tmp_path / "scan"
    assert main(["scan", "--controller", str(ctrl), "--out", str(out), "--twin", "--pixels", "16",
                 "--line-rate", "50", "--sweep", "50", "100"]) == 0
    doc = json.loads((out / "scan.json").read_text())
    assert set(doc["patterns"]) == set(S.PATTERNS) and doc["units"]["nm"] == "nanometres"
    assert doc["sweep_plant"] == doc["plant"] == "linear twin (same electromechanics)"
    for m in doc["patterns"].values():
        assert [r["line_rate_hz"] for r in m["sweep"]] == [50.0, 100.0]
        assert m["line_rate_at_limit_status"] == "above_all"       # the stage never moves: error everywhere
    for f in ("scan.npz", "scan_path.png", "scan_image.png", "scan_error.png", "scan_line_rate.png", "scan.md",
              "manifest.json"):
        assert (out / f).is_file(), f
    from nanosim.pipeline.report import write_report
    md, _ = write_report(out)                         # a run's report shows the Scan section
    text = md.read_text()
    assert "## Scan" in text and "| raster (staircase) |" in text


# ---------------------------------------------------------------------------------------------- viewer
def test_live_scan_of_a_perfect_stage_forms_the_truth():
    from nanosim.viewer.scanlive import LiveScan

    scan = LiveScan("raster", 10.0, 32, 20.0, start_um=(1.0, -2.0, 0.0))
    np.testing.assert_allclose(scan.ref_um[0], (1.0, -2.0, 0.0))          # starts where the reference was
    while not scan.done:
        r = scan.ref_um[scan.k:scan.k + 20]
        scan.record(r, r)                              # sensor and table on the reference
    assert scan.filled == 1.0
    err = scan.image_nm() - scan.truth_nm
    # a pixel is the mean of its trace records: within 2 % rms of the pixel-centre truth
    assert np.sqrt(np.mean(err ** 2)) < 0.02 * (scan.hi - scan.lo)
    rgb = scan.image_rgb()
    assert rgb.shape == (32, 32, 3) and rgb.dtype == np.uint8 and rgb.std() > 20


@pytest.mark.browser
def test_scan_tab_renders_an_image_in_chromium(tmp_path):
    from pathlib import Path

    from nanosim.viewer.screenshots import CHROMIUM, CHROMIUM_ARGS, free_port, wait_until

    if not Path(CHROMIUM).is_file():
        pytest.skip(f"{CHROMIUM} not found: install Debian's chromium (apt-get install -y chromium)")
    pw = pytest.importorskip("playwright.sync_api")
    from PIL import Image

    from nanosim.viewer.server import ViewerApp

    app = ViewerApp(port=free_port(), physics="linear").start()
    try:
        with pw.sync_playwright() as p:
            browser = p.chromium.launch(executable_path=CHROMIUM, args=CHROMIUM_ARGS, headless=True)
            try:
                page = browser.new_page(viewport={"width": 1000, "height": 700})
                page.goto(f"http://127.0.0.1:{app.port}/", timeout=30000)
                page.wait_for_selector("canvas", timeout=30000)
                page.get_by_role("tab", name="Scan").click()
                page.get_by_role("button", name="start scan").click()
                assert wait_until(lambda: app.scan is not None and app.scan.done, 90.0, poll=0.1), \
                    (app.events, None if app.scan is None else app.scan.progress)
                assert app.scan.filled > 0.9
                page.wait_for_timeout(1000)                     # the GUI thread sends the last image
                img = page.locator("img").last
                img.wait_for(timeout=10000)
                shot = tmp_path / "scan_image.png"
                img.screenshot(path=str(shot))
                pix = np.asarray(Image.open(shot).convert("RGB"), float)
                assert pix.shape[0] > 50 and pix.shape[1] > 50, pix.shape
                assert pix.std() > 20.0, f"the scan image looks blank (pixel std {pix.std():.1f})"
                page.screenshot(path=str(tmp_path / "viewer_scan.png"))
            finally:
                browser.close()
    finally:
        app.stop()


# ---------------------------------------------------------------------------------------------- closed loop
def test_batch_scan_equals_the_single_stage_scan(model, twin):
    """One pattern through the batch engine gives the single-stage loop's record and image (a slow
    decoupling integral controller ``C(z) = k_i z / (z - 1) G0^-1``, stable below the 175 Hz modes'
    ``f / Q``)."""
    from nanosim import constants as C
    from nanosim.design.controller import ControllerConfig, DiscreteController
    from nanosim.experiments.batch_loop import BatchController
    from nanosim.plant.batch import BatchTwinStage
    from nanosim.plant.modes import modal_analysis
    from nanosim.plant.twin import TwinStage

    G0_V = modal_analysis(model).static_gain_um_per_V / C.SENSOR_UM_PER_V      # controller V -> sensor V
    K = 2 * np.pi * 0.5 / FS * np.linalg.inv(G0_V)                             # crossover about 0.5 Hz
    cfg = ControllerConfig(np.eye(3), K, np.eye(3), K, 1 / FS)
    pat = S.raster(10.0, 16, 50.0)
    sample = S.Sample()
    single = S.run_scan(TwinStage(twin, seed=1), DiscreteController(cfg), pat, sample)
    (batch,) = S.run_scan_batch(BatchTwinStage(twin, [1]), BatchController(cfg, n=1), [pat], sample)
    assert np.ptp(single.trace.table_um[:, 0]) > 0.1                  # the stage moves
    np.testing.assert_allclose(batch.trace.table_um, single.trace.table_um, rtol=0, atol=1e-9)
    np.testing.assert_allclose(batch.trace.y_um, single.trace.y_um, rtol=0, atol=1e-9)
    assert batch.image.rms_error_nm == pytest.approx(single.image.rms_error_nm, rel=1e-9)
