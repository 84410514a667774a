"""Robustness of the product at its edges, by subject.

Run folders that never lie (interrupt, concurrent writers, readers refusing a folder that does not
match its manifest), one-line errors with exit 2 (file-system errors included, write access checked
before any work), validation of every bad value, file permissions, the report's pass count and
warnings, ``--version``, ``python -m nanosim``, the wheel and the viewer's labels. Signals and concurrency are driven
through subprocesses; everything else runs in-process to keep the suite short.
"""
from __future__ import annotations

import hashlib
import json
import os
import re
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from nanosim.cli import build_parser, main
from nanosim.fileio import write_npz

ENV = dict(os.environ, OPENBLAS_NUM_THREADS="1")
# the project's checker of a run folder against the paper, copied into the repository (tests/data/shared/README.md)
COMPARE_TOOL = Path(__file__).resolve().parent / "data" / "shared" / "tools" / "compare_to_paper.py"


def nanosim(*args, cwd=None, timeout=120, umask=None):
    return subprocess.run([sys.executable, "-m", "nanosim.cli", *map(str, args)], capture_output=True, text=True,
                          timeout=timeout, env=ENV, cwd=cwd, umask=-1 if umask is None else umask)


def _default_sigint():
    signal.signal(signal.SIGINT, signal.SIG_DFL)     # a shell's background job would pass SIGINT on ignored


def start(*args, cwd=None):
    return subprocess.Popen([sys.executable, "-m", "nanosim.cli", *map(str, args)], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True, env=ENV, cwd=cwd, preexec_fn=_default_sigint)


def wait_for(condition, proc, timeout=120.0):
    """Wait until ``condition()`` holds while ``proc`` runs (imports take seconds on a loaded machine)."""
    deadline = time.monotonic() + timeout
    while not condition():
        assert proc.poll() is None, proc.communicate()[1]
        assert time.monotonic() < deadline, "the command never started writing"
        time.sleep(0.05)


def zero_controller(path, dt=2.5e-4):
    """A valid (do-nothing) controller file: Akd..Dkd and the loop's sample time."""
    return write_npz(path, Akd=np.zeros((1, 1)), Bkd=np.zeros((1, 3)), Ckd=np.zeros((3, 1)), Dkd=np.zeros((3, 3)),
                     dt=dt)


def digest(folder: Path) -> dict:
    """sha256 of every file under ``folder`` (relative POSIX paths)."""
    return {p.relative_to(folder).as_posix(): hashlib.sha256(p.read_bytes()).hexdigest()
            for p in sorted(folder.rglob("*")) if p.is_file()}


def error_lines(stderr: str) -> list[str]:
    """stderr without progress output (tqdm bars and the indented progress lines)."""
    lines = [ln.split("\r")[-1] for ln in stderr.splitlines()]
    return [ln for ln in lines if ln.strip() and not ln.startswith("  ") and "it/s]" not in ln
            and "exp/s" not in ln and "?exp" not in ln and "step/s" not in ln]


def in_process(capsys, *argv) -> tuple[int, list[str]]:
    """``main(argv)`` in this process: (exit status, stderr lines); argparse errors included."""
    try:
        rc = main([str(a) for a in argv])
    except SystemExit as exc:
        rc = exc.code
    err = capsys.readouterr().err
    assert "Traceback" not in err
    return rc, [ln for ln in err.splitlines() if ln.strip()]


@pytest.fixture(scope="module")
def sealed(tmp_path_factory):
    """A complete run made by the CLI under umask 022: ``characterize --only small_steps`` (a few s)."""
    base = tmp_path_factory.mktemp("sealed")
    ctrl = zero_controller(base / "zero_controller.npz")
    p = nanosim("characterize", "--controller", ctrl, "--out", base / "run", "--only", "small_steps", "--seed", 3,
                umask=0o022)
    assert p.returncode == 0, p.stderr
    return base / "run", ctrl, p


def copy_run(sealed, tmp_path) -> Path:
    dst = tmp_path / "run"
    shutil.copytree(sealed[0], dst)
    return dst


# --- run folders: complete or untouched, sealed by their manifest -------------------------------------
@pytest.mark.parametrize("previous", ["complete run", "no folder"])
def test_ctrl_c_leaves_the_previous_run_or_nothing(sealed, tmp_path, previous):
    """SIGINT during `identify`: exit 130, one line saying so, the previous run byte for byte (or no folder)."""
    run = copy_run(sealed, tmp_path) if previous == "complete run" else tmp_path / "run"
    before = digest(run) if run.exists() else None
    p = start("identify", "--out", run, "--seed", 1)
    wait_for(lambda: list(tmp_path.glob(".run.staging-*")), p)
    time.sleep(1.0)                                    # inside the simulation
    p.send_signal(signal.SIGINT)
    _, err = p.communicate(timeout=60)
    assert p.returncode == 130, err
    lines = error_lines(err)
    assert len(lines) == 1 and "interrupted" in lines[0] and "left as it was" in lines[0], err
    assert "simulating the identification experiments" in err          # identify alone reports progress
    if before is None:
        assert not run.exists()
    else:
        assert digest(run) == before
    assert sorted(q.name for q in tmp_path.iterdir()) == (["run"] if before is not None else [])  # no leftovers


def test_second_writer_on_the_same_out_is_refused(sealed, tmp_path):
    """Two writers on one --out: the second gets one line and exit 2 at once; the folder stays the first's."""
    run = copy_run(sealed, tmp_path)
    before = digest(run)
    first = start("identify", "--out", run, "--seed", 1)
    try:
        wait_for((tmp_path / ".run.lock").exists, first)
        t0 = time.monotonic()
        second = nanosim("identify", "--out", run, "--seed", 2, timeout=60)
        assert second.returncode == 2 and time.monotonic() - t0 < 30
        lines = error_lines(second.stderr)
        assert len(lines) == 1 and "another nanosim process" in lines[0] and str(first.pid) in lines[0], second.stderr
    finally:
        first.send_signal(signal.SIGINT)
        first.communicate(timeout=60)
    assert first.returncode == 130 and digest(run) == before


def test_manifest_seals_every_file(sealed):
    run = sealed[0]
    man = json.loads((run / "manifest.json").read_text())
    assert set(man["files_sha256"]) == set(digest(run)) - {"manifest.json"}
    assert man["seed"] == 3 and man["command"][1:3] == ["characterize", "--controller"]
    assert man["nanosim_version"]


def test_readers_refuse_a_folder_that_no_longer_matches_its_manifest(sealed, tmp_path, capsys):
    run = copy_run(sealed, tmp_path)
    rc, err = in_process(capsys, "report", "--run", run)
    assert rc == 0 and (run / "report.html").is_file()
    from nanosim.pipeline.runfolder import verify_manifest
    verify_manifest(run)                                  # the rewritten report is sealed too
    # a file added after sealing: report and --controller/--model from that folder are refused
    zero_controller(run / "controller.npz")
    rc, err = in_process(capsys, "report", "--run", run)
    assert rc == 2 and len(err) == 1 and "controller.npz was added after the run was sealed" in err[0], err
    rc, err = in_process(capsys, "characterize", "--controller", run / "controller.npz", "--out", tmp_path / "o")
    assert rc == 2 and len(err) == 1 and err[0].startswith("nanosim characterize: error: --controller"), err
    rc, err = in_process(capsys, "design", "--model", run / "controller.npz", "--out", tmp_path / "o")
    assert rc == 2 and len(err) == 1 and "--model" in err[0], err
    # a file changed after sealing: adding to the run (which would seal the change) is refused too
    (run / "controller.npz").unlink()
    (run / "metrics.json").write_text("{}")
    rc, err = in_process(capsys, "characterize", "--controller", sealed[1], "--out", run, "--only", "small_steps")
    assert rc == 2 and len(err) == 1 and "metrics.json changed after the run was sealed" in err[0], err
    rc, err = in_process(capsys, "report", "--run", run)
    assert rc == 2 and "metrics.json changed" in err[0]
    (run / "metrics.json").unlink()
    rc, err = in_process(capsys, "report", "--run", run)
    assert rc == 2 and "metrics.json" in err[0] and "missing" in err[0]
    assert not (tmp_path / "o").exists()


def test_sealed_run_for_compare_and_other_readers(sealed, tmp_path):
    from nanosim.pipeline.runfolder import RunFolderError, sealed_run

    run = copy_run(sealed, tmp_path)
    r = sealed_run(run, required=("metrics.json",))
    assert r.seed == 3 and "metrics.json" in r.files and r.command[1] == "characterize"
    with pytest.raises(RunFolderError, match="design.json is not part of the sealed run"):
        sealed_run(run, required=("design.json",))
    (run / "metrics.json").write_text("{}")
    with pytest.raises(RunFolderError, match="metrics.json changed"):
        sealed_run(run)
    with pytest.raises(RunFolderError, match="no manifest.json"):
        sealed_run(tmp_path)


def test_a_folder_that_is_not_a_run_is_never_replaced(tmp_path, capsys):
    """`--out .` in a project folder must not move the user's files away (staged swap) nor seal them."""
    (tmp_path / "notes.txt").write_text("mine")
    ctrl = zero_controller(tmp_path / "c.npz")
    rc, err = in_process(capsys, "characterize", "--controller", ctrl, "--out", tmp_path, "--only", "small_steps")
    assert rc == 2 and len(err) == 1 and "not a nanosim run folder" in err[0]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["c.npz", "notes.txt"]


def test_a_killed_writer_leaves_nothing_that_survives_the_next_run(tmp_path):
    """SIGKILL between the two renames of the swap: the next writer puts the previous run back first."""
    from nanosim.pipeline.runfolder import staged_run

    dead = 2 ** 22 + 12345                         # above the default pid_max of 4194304: never alive
    (tmp_path / f".run.old-{dead}").mkdir()
    (tmp_path / f".run.old-{dead}" / "a.txt").write_text("previous")
    (tmp_path / f".run.staging-{dead}").mkdir()
    with staged_run(tmp_path / "run", keep_existing=True) as stage:
        assert (stage / "a.txt").read_text() == "previous"
        (stage / "b.txt").write_text("new")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["run"]
    assert sorted(p.name for p in (tmp_path / "run").iterdir()) == ["a.txt", "b.txt", "manifest.json"]


# --- file-system errors: one line, exit 2, before any work --------------------------------------------
@pytest.fixture
def readonly_dir(tmp_path):
    """A directory nobody can write in, also for root: a read-only tmpfs, else chattr +i, else mode 0555."""
    d = tmp_path / "ro"
    d.mkdir()
    undo = None
    if os.geteuid() != 0:
        d.chmod(0o555)
        undo = ["chmod", "755", str(d)]
    elif subprocess.run(["mount", "-t", "tmpfs", "-o", "ro,size=64k", "tmpfs", str(d)],
                        capture_output=True).returncode == 0:
        undo = ["umount", str(d)]
    elif shutil.which("chattr") and subprocess.run(["chattr", "+i", str(d)], capture_output=True).returncode == 0:
        undo = ["chattr", "-i", str(d)]
    else:
        pytest.skip("running as root without mount or chattr: cannot make a directory read-only")
    assert not os.access(d, os.W_OK)
    yield d
    subprocess.run(undo, capture_output=True)


def test_read_only_out_fails_at_once_with_one_line(readonly_dir):
    t0 = time.monotonic()
    p = nanosim("identify", "--out", readonly_dir / "run")
    elapsed = time.monotonic() - t0
    lines = error_lines(p.stderr)
    assert p.returncode == 2 and len(lines) == 1 and "Traceback" not in p.stderr, p.stderr
    assert "--out" in lines[0] and ("read-only" in lines[0] or "permission" in lines[0])
    # before any simulation (not a traceback after a simulation); the bound only allows for a loaded machine
    assert "simulating" not in p.stderr and elapsed < 60
    p = nanosim("modes", "--plot", readonly_dir / "plots")
    assert p.returncode == 2 and len(error_lines(p.stderr)) == 1 and "--plot" in p.stderr


def test_out_naming_a_file_and_plot_into_a_file(tmp_path, capsys):
    afile = tmp_path / "afile"
    afile.write_text("")
    for argv, name in ((("identify", "--out", afile), "--out"), (("modes", "--plot", afile), "--plot"),
                       (("pipeline", "--out", afile), "--out")):
        rc, err = in_process(capsys, *argv)
        assert rc == 2 and len(err) == 1 and name in err[0] and "existing file" in err[0], err


# --- bad values: one line naming the argument, what was expected and what arrived ---------------------
@pytest.fixture
def files(tmp_path):
    bad = tmp_path / "bad.xml"
    bad.write_text("<mujoco><worldbody><body></mujoco>")
    rnd = tmp_path / "random.npz"
    rnd.write_bytes(np.random.default_rng(0).bytes(2048))
    return {"tmp": tmp_path, "out": tmp_path / "out", "bad": bad, "rnd": rnd, "dir": tmp_path,
            "ctrl": zero_controller(tmp_path / "c.npz"), "ctrl1ms": zero_controller(tmp_path / "c1ms.npz", dt=1e-3)}


BAD_VALUES = [
    # (argv, words the single line must hold)
    (("design", "--model", "{ctrl}", "--out", "{out}", "--reduced-order", "0"), ["--reduced-order", "got 0"]),
    (("design", "--model", "{ctrl}", "--out", "{out}", "--damping-zeta", "-1"), ["--damping-zeta", "got -1"]),
    (("pipeline", "--out", "{out}", "--reduced-order", "0"), ["--reduced-order", "got 0"]),
    (("modes", "--fmax", "-5"), ["--fmax", "got -5"]),
    (("modes", "--fmax", "nan"), ["--fmax", "got nan"]),
    (("characterize", "--controller", "{ctrl1ms}", "--out", "{out}"), ["dt", "0.00025", "0.001"]),
    (("identify", "--out", "{out}", "--seed", "-1"), ["--seed", "got -1"]),
    (("characterize", "--controller", "{ctrl}", "--out", "{out}", "--seed", "-1"), ["--seed", "got -1"]),
    (("modes", "--mjcf", "{bad}"), ["not a valid MuJoCo model", "line"]),
    (("modes", "--mjcf", "{dir}"), ["--mjcf", "directory"]),
    (("identify", "--out", "{out}", "--mjcf", "{dir}"), ["--mjcf", "directory"]),
    (("design", "--model", "{rnd}", "--out", "{out}"), ["not an .npz file"]),
    (("characterize", "--controller", "{rnd}", "--out", "{out}"), ["not an .npz file"]),
    (("pipeline", "--out", "{out}", "--weights", "{tmp}/none.toml"), ["--weights", "no such file"]),
    (("view", "--seconds", "-5"), ["--seconds", "-5"]),
    (("view", "--seconds", "nan"), ["--seconds", "nan"]),
    (("view", "--host", "999.1.1.1"), ["--host", "999.1.1.1"]),
]


@pytest.mark.parametrize("argv, words", BAD_VALUES, ids=[" ".join(a[:1] + a[-2:]) for a, _ in BAD_VALUES])
def test_bad_values_one_line_exit_2_and_no_folder_left(files, capsys, argv, words):
    argv = [a.format(**files) for a in argv]
    rc, err = in_process(capsys, *argv)
    assert rc == 2 and len(err) == 1, err
    assert err[0].startswith(f"nanosim {argv[0]}: error: "), err[0]
    for w in words:
        assert w.lower() in err[0].lower(), (w, err[0])
    assert "allow_pickle" not in err[0] and "busy" not in err[0]
    assert not files["out"].exists()                       # no empty --out left behind


def test_malformed_mjcf_keeps_mujocos_detail_line(files, capsys):
    rc, err = in_process(capsys, "modes", "--mjcf", files["bad"])
    assert rc == 2 and re.search(r"line( number)?\s*[=:]?\s*\d", err[0], re.I), err   # not a bare "XML parse error 8:"


def test_object_array_npz_is_refused_without_pickle_advice(tmp_path, capsys):
    obj = tmp_path / "obj.npz"
    np.savez(obj, a=np.array([{"x": 1}], dtype=object))
    rc, err = in_process(capsys, "design", "--model", obj, "--out", tmp_path / "out")
    assert rc == 2 and "object" in err[0] and "allow_pickle" not in err[0]


def test_view_port_0_picks_a_free_port_and_prints_it():
    p = nanosim("view", "--port", "0", "--seconds", "1", timeout=120)
    assert p.returncode == 0, p.stderr
    port = int(re.search(r"nanosim viewer on http://localhost:(\d+)", p.stdout).group(1))
    assert 0 < port < 65536


def test_pipeline_has_the_design_options():
    args = build_parser().parse_args(["pipeline", "--out", "x", "--weights", __file__, "--reduced-order", "10",
                                      "--damping-zeta", "0", "--paper-design"])
    assert (args.weights, args.reduced_order, args.damping_zeta, args.paper_design) == (__file__, 10, 0.0, True)


def test_order_0_chooses_the_order_from_the_singular_values(monkeypatch, tmp_path, capsys):
    """`identify --order 0` (documented: choose from the singular values) reaches subspace_id as order=None,
    which picks the true order of a 2-mode system (4 states) from noisy data."""
    import identification as ident
    import nanosim.pipeline.identify as pid
    from nanosim.pipeline.config import IdentifyConfig

    assert build_parser().parse_args(["identify", "--out", "x", "--order", "0"]).order == 0
    seen = []

    class Stop(Exception):
        pass

    def fake_identify_stage(settings, model=None, progress=None):
        seen.append(settings.order_per_column)
        raise Stop

    monkeypatch.setattr(pid, "identify_stage", fake_identify_stage)
    with pytest.raises(Stop):
        pid.run_identify(tmp_path, IdentifyConfig(order=0))
    assert seen == [None]
    with pytest.raises(SystemExit):
        main(["identify", "--help"])
    assert "0: choose from the singular values" in " ".join(capsys.readouterr().out.split())
    # a discrete 2-mode system (60 Hz and 300 Hz, zeta 0.02 and 0.05) at 4 kHz, measured with 1 % noise
    fs, rng = 4000.0, np.random.default_rng(1)
    poles = []
    for f, z in ((60.0, 0.02), (300.0, 0.05)):
        w = 2 * np.pi * f
        poles += [np.exp((-z * w + 1j * w * np.sqrt(1 - z * z)) / fs)]
    den = np.real(np.poly(np.concatenate([poles, np.conj(poles)])))
    from scipy.signal import lfilter
    u = rng.standard_normal(8000)
    y = lfilter([0, 0.01, 0.02, 0.01], den, u)
    y += 0.01 * np.std(y) * rng.standard_normal(y.size)
    model = ident.subspace_id(y[:, None], u[:, None], order=None, fs=fs, max_order=12)
    assert model.order == 4


# --- file permissions ---------------------------------------------------------------------------------
def test_artifacts_follow_the_umask(sealed):
    run = sealed[0]
    modes = {p.relative_to(run).as_posix(): p.stat().st_mode & 0o777 for p in run.rglob("*") if p.is_file()}
    assert len(modes) >= 3 and set(modes.values()) == {0o644}, modes              # not 0600
    assert (run.stat().st_mode & 0o777) == 0o755


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


# --- version, python -m, usage errors, weights files --------------------------------------------------
def test_version_and_python_m_nanosim(capsys):
    import nanosim

    with pytest.raises(SystemExit) as exc:
        main(["--version"])
    assert exc.value.code == 0 and capsys.readouterr().out.strip() == f"nanosim {nanosim.__version__}"
    p = subprocess.run([sys.executable, "-m", "nanosim", "--help"], capture_output=True, text=True, env=ENV)
    assert p.returncode == 0
    for cmd in ("modes", "identify", "design", "characterize", "pipeline", "report", "view"):
        assert cmd in p.stdout


def test_characterize_bar_names_the_running_experiment(sealed):
    assert "running small_steps" in sealed[2].stderr


def test_usage_errors_are_one_line(capsys):
    rc, err = in_process(capsys, "identify")
    assert rc == 2 and len(err) == 1 and "--out" in err[0] and "usage:" not in err[0]


def test_weights_parse_toml_without_tomllib(tmp_path):
    """Python 3.10 has no tomllib: weights.py falls back on tomli (pyproject: tomli for python < 3.11)."""
    toml = tmp_path / "w.toml"
    toml.write_text("[Wp]\nnum = [0.6667, 314.2]\nden = [1, 0.03142]\n[Wt]\nnum = [1, 314.2]\n"
                    "den = [0.001, 628.3]\npower = 2\n[Wu]\nnum = [0.15]\nden = [1]\n")
    code = ("import sys, types, tomllib\n"
            "t = types.ModuleType('tomli'); t.loads = tomllib.loads; t.TOMLDecodeError = tomllib.TOMLDecodeError\n"
            "sys.modules['tomli'] = t; sys.modules['tomllib'] = None   # import tomllib now fails as on 3.10\n"
            "from nanosim.design.weights import Weights\n"
            f"w = Weights.from_file({str(toml)!r}); print(w.Wt.power, w.Wu.num)\n")
    p = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=ENV)
    assert p.returncode == 0 and p.stdout.split()[0] == "2", p.stderr
    pyproject = (Path(__file__).resolve().parents[1] / "pyproject.toml").read_text()
    assert re.search(r'"tomli[^"]*;\s*python_version\s*<\s*.3\.11.', pyproject)
    assert 'requires-python = ">=3.10"' in pyproject


# --- the package installs from a wheel ----------------------------------------------------------------
@pytest.mark.slow
def test_wheel_installs_and_runs_in_a_fresh_venv(tmp_path):
    """Build the wheel from a copy of the sources, install it into a new venv, run `nanosim modes --json`."""
    root = Path(__file__).resolve().parents[1]
    src = tmp_path / "src"
    src.mkdir()
    for name in ("pyproject.toml", "README.md"):
        shutil.copy2(root / name, src / name)
    skip = shutil.ignore_patterns("__pycache__", "*.pyc", "*.egg-info")
    for pkg in ("nanosim", "identification"):
        shutil.copytree(root / pkg, src / pkg, ignore=skip)
    wheels = tmp_path / "wheels"
    p = subprocess.run([sys.executable, "-m", "pip", "wheel", "--no-deps", "-q", "-w", str(wheels), str(src)],
                       capture_output=True, text=True, timeout=600)
    if p.returncode and ("network" in p.stderr.lower() or "connection" in p.stderr.lower()):
        pytest.skip(f"cannot fetch the build backend: {p.stderr.strip().splitlines()[-1]}")
    assert p.returncode == 0, p.stderr
    (whl,) = wheels.glob("nanosim-*.whl")
    import zipfile
    names = zipfile.ZipFile(whl).namelist()
    assert "nanosim/mjcf/scene.xml" in names and "nanosim/mjcf/pkxyz_stage.xml" in names
    # every module of the sources is in the wheel (a listed package set once left out nanosim.design.architectures)
    sources = {f.relative_to(src).as_posix() for pkg in ("nanosim", "identification")
               for f in (src / pkg).rglob("*.py")}
    assert sources - set(names) == set()
    venv = tmp_path / "venv"
    # a fresh venv that sees the installed dependencies (mujoco, ...); this pip installs into it (no ensurepip)
    subprocess.run([sys.executable, "-m", "venv", "--system-site-packages", "--without-pip", str(venv)], check=True,
                   timeout=300)
    py = venv / "bin" / "python"
    p = subprocess.run([sys.executable, "-m", "pip", "--python", str(py), "install", "-q", "--no-index", str(whl)],
                       capture_output=True, text=True, timeout=600)
    assert p.returncode == 0, p.stderr
    cwd = tmp_path / "elsewhere"
    cwd.mkdir()
    env = {k: v for k, v in ENV.items() if k != "PYTHONPATH"}
    p = subprocess.run([str(py), "-c", "import nanosim; print(nanosim.__file__)"], capture_output=True, text=True,
                       cwd=cwd, env=env)
    assert Path(p.stdout.strip()).resolve().is_relative_to(venv.resolve()), p.stdout   # not the repository
    p = subprocess.run([str(venv / "bin" / "nanosim"), "modes", "--json"], capture_output=True, text=True, cwd=cwd,
                       env=env, timeout=300)
    assert p.returncode == 0, p.stderr
    installed = json.loads(p.stdout)
    here = json.loads(nanosim("modes", "--json").stdout)             # the same command from the repository
    assert len(installed["modes"]) >= 6                                # the paper's six below 1 kHz
    np.testing.assert_allclose([m["freq_hz"] for m in installed["modes"]], [m["freq_hz"] for m in here["modes"]],
                               rtol=1e-9)


# --- the viewer: labels and the physics panel ---------------------------------------------------------
def test_viewer_labels_do_not_overlap_on_the_first_view(model):
    """Labels such as "probe Z" and "table + target cube" do not overlap."""
    from nanosim.plant.mechanics import home_data
    from nanosim.viewer.labels import LABEL_TEXTS, box_gap, label_boxes, label_positions

    anchors = label_positions(model, home_data(model))
    texts = dict(LABEL_TEXTS, **{k: "piezo A" for k in anchors if k not in LABEL_TEXTS})
    boxes = label_boxes(anchors, texts)
    names = sorted(boxes)
    gaps = {(a, b): box_gap(boxes[a], boxes[b]) for i, a in enumerate(names) for b in names[i + 1:]}
    assert min(gaps.values()) > 0.5, min(gaps.items(), key=lambda kv: kv[1])
    assert gaps[("probe_z", "table")] >= 3.0


def test_viewer_auto_physics_text_shows_its_decision_and_fits():
    """The physics choice states the real-time factor it was made on, and fits the panel."""
    from nanosim.viewer.server import AUTO_WINDOW_S, PHYSICS_TEXT_MAX, physics_text

    for physics, rtf in (("mujoco", 0.9612), ("linear", 0.2134), ("linear", 0.0049), ("mujoco", 3.5)):
        text = physics_text(physics, rtf)
        assert f"{rtf:.2f}x" in text and f"{AUTO_WINDOW_S:g} s" in text and len(text) <= PHYSICS_TEXT_MAX, text
        assert ("MuJoCo (" if physics == "mujoco" else "linearized") in text
    assert len(physics_text("mujoco")) <= PHYSICS_TEXT_MAX
