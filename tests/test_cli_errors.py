"""Bad command-line input: one line naming the argument, exit 2, no traceback, ``--out`` untouched.

Every case fails before any work, so the CLI runs in this process (``main(argv)``). The cases cover
every argument whose value the CLI reads (montecarlo/sweep --scheduler, --weights, --seeds, an
uncreatable --out, file contents, compare --controllers, --mjcf, view --controller, tampered run
folders, --param, an empty --out); each names the argument the message must hold.
"""
from __future__ import annotations

import json
import os
from pathlib import Path

import numpy as np
import pytest

from nanosim.cli import main
from nanosim.fileio import write_json, write_npz
from nanosim.pipeline.runfolder import MANIFEST_JSON, write_manifest


def _controller(path, dt=2.5e-4, A=None, B=None):
    return write_npz(path, Akd=np.zeros((1, 1)) if A is None else A, Bkd=np.zeros((1, 3)) if B is None else B,
                     Ckd=np.zeros((3, 1)), Dkd=np.zeros((3, 3)), dt=dt)


def _model(path):
    return write_npz(path, A=-np.eye(2), B=np.ones((2, 3)), C=np.ones((3, 2)), D=np.zeros((3, 3)))


def _sealed_mc(folder: Path, ctrl: Path) -> Path:
    """A sealed Monte Carlo folder of ``ctrl`` (seed 0, bundled stage, every experiment), without samples."""
    from nanosim import experiments
    from nanosim.pipeline import mc_stats
    from nanosim.pipeline.config import MonteCarloConfig
    from nanosim.pipeline.artifacts import MONTECARLO_JSON as PLAN_JSON
    from nanosim.pipeline.montecarlo import montecarlo_plan
    from nanosim.plant.mjcf import load_model
    from nanosim.plant.tolerances import default_tolerances

    names = list(experiments.load_builtin())
    tm = default_tolerances(load_model())
    plan = montecarlo_plan(ctrl.resolve(), MonteCarloConfig(n=1, seed=0), names, tm.to_dict())
    folder.mkdir()
    write_json(folder / PLAN_JSON, {"identity": plan["identity"], "n": 1, "mjcf": None, "experiments": names})
    write_json(folder / "tolerances.json", tm.to_dict())
    write_json(folder / "spec.json", mc_stats.default_spec())
    write_json(folder / "summary.json", {"n": 0})
    write_manifest(folder, seed=0, command=["nanosim", "montecarlo"])
    return folder


@pytest.fixture(scope="module")
def fx(tmp_path_factory):
    d = tmp_path_factory.mktemp("fx")
    f = {"ctrl": _controller(d / "ctrl.npz"), "baddt": _controller(d / "baddt.npz", dt=0.5),
         "nan": _controller(d / "nan.npz", A=np.full((1, 1), np.nan)),
         "shape": _controller(d / "shape.npz", B=np.zeros((2, 3))),
         "keys": write_npz(d / "keys.npz", Akd=np.zeros((1, 1))),
         "model": _model(d / "model.npz"), "model_keys": write_npz(d / "model_keys.npz", A=np.zeros((2, 2))),
         "model_dt": write_npz(d / "model_dt.npz", A=-np.eye(2), B=np.ones((2, 3)), C=np.ones((3, 2)),
                               D=np.zeros((3, 3)), Ad=0.5 * np.eye(2), Bd=np.ones((2, 3)), Cd=np.ones((3, 2)),
                               Dd=np.zeros((3, 3)), dt=1e-3)}
    for name, text in (("empty.npz", ""), ("text.npz", "not a zip"), ("bad.xml", "<mujoco><worldbody><body>"),
                       ("notjson.json", "{nope"), ("wmissing.json", '{"Wp": 1}')):
        (d / name).write_text(text)
        f[name.replace(".", "_")] = d / name
    (d / "adir.npz").mkdir()
    f["adir"] = d / "adir.npz"
    # a run folder sealed, then changed: --controller/--model taken from it are refused
    t = d / "tampered"
    t.mkdir()
    _controller(t / "controller.npz")
    _model(t / "model.npz")
    (t / "metrics.json").write_text("{}")
    write_manifest(t, seed=0, command=["nanosim", "test"])
    (t / "metrics.json").write_text('{"changed": 1}')
    f["tampered"] = t
    # sealed run folders used as --out (must keep every file and the manifest's bytes)
    s = d / "sealed"
    s.mkdir()
    _model(s / "model.npz")
    write_manifest(s, seed=0, command=["nanosim", "test"])
    f["sealed"] = s
    f["sealed_mc"] = _sealed_mc(d / "sealed_mc", f["ctrl"])
    # a .mat state space without its sample time; a controller that destabilizes the stage (u = 100 y)
    from scipy.io import savemat
    savemat(d / "nodt.mat", {"A": np.zeros((1, 1)), "B": np.zeros((1, 3)), "C": np.zeros((3, 1)),
                             "D": np.zeros((3, 3))})
    f["nodt_mat"] = d / "nodt.mat"
    f["unstable"] = write_npz(d / "unstable.npz", Akd=np.zeros((1, 1)), Bkd=np.zeros((1, 3)), Ckd=np.zeros((3, 1)),
                              Dkd=-100.0 * np.eye(3), dt=2.5e-4)
    # a sealed compare folder (its scorecard): not a run that report or ablation writes into
    c = d / "sealed_compare"
    c.mkdir()
    write_json(c / "scorecard.json", {"controllers": {}})
    write_manifest(c, seed=0, command=["nanosim", "compare"])
    f["sealed_compare"] = c
    from nanosim.plant.mjcf import DEFAULT_MJCF
    f["mjcf"] = DEFAULT_MJCF
    f["d"] = d
    return f


NEW = "{o}/run"               # a new --out: must not exist afterwards, nor anything else in {o}
BAD = [
    # (argv, the argument the line must name[, a further word it must hold])
    # 1, 10: the scheduler's form, before anything is written
    (("montecarlo", "--controller", "{ctrl}", "--out", NEW, "--scheduler", "foo", "--n", "1"), "--scheduler"),
    (("montecarlo", "--controller", "{ctrl}", "--out", NEW, "--scheduler", "tcp://", "--n", "1"), "--scheduler"),
    (("montecarlo", "--controller", "{ctrl}", "--out", NEW, "--scheduler", "tcp://127.0.0.1:notaport"),
     "--scheduler", "tcp://HOST:PORT"),
    (("sweep", "--param", "piezo_gain=1:2:2", "--out", NEW, "--scheduler", "tcp://"), "--scheduler"),
    (("sweep", "--param", "piezo_gain=1:2:2", "--out", NEW, "--scheduler", "tcp://127.0.0.1:notaport"),
     "--scheduler"),
    # 2: a sealed Monte Carlo keeps its manifest
    (("montecarlo", "--controller", "{ctrl}", "--out", "{sealed_mc}", "--scheduler", "foo", "--n", "1"),
     "--scheduler"),
    # 3, 4: --weights checked up front (one validator for design, pipeline, sweep)
    (("sweep", "--param", "piezo_gain=1:1:1", "--out", NEW, "--workers", "1", "--weights", "{notjson_json}"),
     "--weights", "cannot parse"),
    (("sweep", "--param", "piezo_gain=1:1:1", "--out", NEW, "--weights", "{wmissing_json}"), "--weights", "Wt"),
    (("pipeline", "--out", NEW, "--weights", "{notjson_json}"), "--weights"),
    (("pipeline", "--out", NEW, "--weights", "{wmissing_json}"), "--weights", "wmissing.json"),
    (("design", "--model", "{model}", "--out", NEW, "--weights", "{notjson_json}"), "--weights"),
    (("design", "--model", "{model}", "--out", "{sealed}", "--weights", "{wmissing_json}"), "--weights"),
    # 5, 6: --seeds
    (("pipeline", "--out", NEW, "--seeds", ""), "--seeds", "got ''"),
    (("pipeline", "--out", NEW, "--seeds", "0-1000000000000"), "--seeds", "at most 1000"),
    (("compare", "--controllers", "paper", "--out", NEW, "--seeds", "0-1000000000000"), "--seeds", "at most 1000"),
    (("compare", "--controllers", "paper", "--out", NEW, "--seeds", "0-400,500-1100"), "--seeds", "at most 1000"),
    # 7: an --out that cannot be created (os.access says yes to root on /proc)
    (("identify", "--out", "/proc/nope/run"), "--out", "/proc"),
    (("design", "--model", "{model}", "--out", "/proc/nope/run"), "--out"),
    (("characterize", "--controller", "{ctrl}", "--out", "/proc/nope/run"), "--out"),
    (("pipeline", "--out", "/proc/nope/run"), "--out"),
    (("montecarlo", "--controller", "{ctrl}", "--out", "/proc/nope/run"), "--out"),
    (("sweep", "--param", "piezo_gain=1:2:2", "--out", "/proc/nope/run"), "--out"),
    (("compare", "--controllers", "paper", "--out", "/proc/nope/run"), "--out"),
    (("modes", "--plot", "/proc/nope/run"), "--plot"),
    # 8: file contents name their argument
    (("design", "--model", "{empty_npz}", "--out", NEW), "--model", "not an .npz"),
    (("design", "--model", "{text_npz}", "--out", NEW), "--model"),
    (("design", "--model", "{model_keys}", "--out", NEW), "--model", "missing"),
    (("design", "--model", "{model_dt}", "--out", NEW), "--model", "dt = 0.001"),
    (("identify", "--order", "61", "--out", NEW), "--order", "got 61"),
    (("characterize", "--controller", "{empty_npz}", "--out", NEW), "--controller"),
    (("characterize", "--controller", "{keys}", "--out", NEW), "--controller", "missing"),
    (("characterize", "--controller", "{baddt}", "--out", NEW), "--controller", "dt"),
    (("characterize", "--controller", "{nan}", "--out", NEW), "--controller", "nan"),
    (("characterize", "--controller", "{shape}", "--out", NEW), "--controller"),
    (("montecarlo", "--controller", "{text_npz}", "--out", NEW), "--controller"),
    (("montecarlo", "--controller", "{baddt}", "--out", NEW), "--controller", "dt"),
    (("montecarlo", "--controller", "{shape}", "--out", "{sealed_mc}"), "--controller"),
    (("compare", "--controllers", "paper", "--out", NEW, "--model", "{empty_npz}"), "--model"),
    (("compare", "--controllers", "paper", "--out", NEW, "--model", "{model_keys}"), "--model"),
    (("compare", "--controllers", "paper", "--out", NEW, "--model", "{d}/nonexist.npz"), "--model"),
    # 9: every --controllers entry checked before any progress line
    (("compare", "--controllers", "nosuch", "--out", NEW, "--model", "{model}"), "--controllers", "nosuch"),
    (("compare", "--controllers", "paper", "{d}/nonexist.npz", "--out", NEW, "--model", "{model}"),
     "--controllers", "no such file"),
    (("compare", "--controllers", "nosuchmod:fn", "--out", NEW, "--model", "{model}"), "--controllers"),
    (("compare", "--controllers", "os:nosuchfn", "--out", NEW, "--model", "{model}"), "--controllers"),
    (("compare", "--controllers", "{baddt}", "--out", NEW, "--model", "{model}"), "--controllers", "dt"),
    (("compare", "--controllers", "{adir}", "--out", NEW, "--model", "{model}"), "--controllers", "directory"),
    (("compare", "--controllers", "paper", "paper", "--out", NEW, "--model", "{model}"), "--controllers"),
    # 11: --mjcf loaded before any work or progress output
    (("identify", "--out", NEW, "--mjcf", "{bad_xml}"), "--mjcf", "not a valid MuJoCo model"),
    (("pipeline", "--out", NEW, "--mjcf", "{bad_xml}"), "--mjcf"),
    (("sweep", "--param", "piezo_gain=1:1:1", "--out", NEW, "--workers", "1", "--mjcf", "{bad_xml}"), "--mjcf"),
    (("montecarlo", "--controller", "{ctrl}", "--out", NEW, "--mjcf", "{bad_xml}"), "--mjcf"),
    (("characterize", "--controller", "{ctrl}", "--out", NEW, "--mjcf", "{bad_xml}"), "--mjcf"),
    (("design", "--model", "{model}", "--out", "{sealed}", "--mjcf", "{bad_xml}"), "--mjcf"),
    (("compare", "--controllers", "paper", "--out", NEW, "--mjcf", "{bad_xml}"), "--mjcf"),
    (("sweep", "--param", "thickness.swing=150:200:2", "--out", NEW, "--mjcf", "{mjcf}"), "--mjcf"),
    # 12, 15: view --controller
    (("view", "--controller", "{baddt}", "--seconds", "1", "--port", "0"), "--controller", "dt"),
    (("view", "--controller", "{adir}", "--seconds", "1", "--port", "0"), "--controller", "directory"),
    # 13: inputs from a sealed run folder that changed since
    (("montecarlo", "--controller", "{tampered}/controller.npz", "--out", NEW), "--controller", "changed"),
    (("compare", "--controllers", "paper", "--out", NEW, "--model", "{tampered}/model.npz"), "--model", "changed"),
    (("compare", "--controllers", "paper", "--out", NEW, "--model", "{tampered}"), "--model", "changed"),
    (("compare", "--controllers", "{tampered}/controller.npz", "--out", NEW), "--controllers", "changed"),
    # 14, 15: --param
    (("sweep", "--param", "thickness.crank_bend=10:20:2", "--out", NEW), "--param", "length_mm"),
    (("sweep", "--param", "stiffness.lever=1:2:2", "--out", NEW), "--param", "apa"),
    (("sweep", "--param", "target_mass_g=1:2:3:4", "--out", NEW), "--param", "3 fields"),
    # 15: empty --out, parents of a failed --out, compare --only
    (("identify", "--out", ""), "--out", "got ''"),
    (("montecarlo", "--controller", "{ctrl}", "--out", ""), "--out"),
    (("montecarlo", "--controller", "{ctrl}", "{ctrl}", "--out", NEW), "--controller", "share the name"),
    (("modes", "--plot", ""), "--plot"),
    (("identify", "--out", "{o}/deep/x/y", "--mjcf", "{bad_xml}"), "--mjcf"),
    (("compare", "--controllers", "paper", "--out", NEW, "--model", "{model}", "--only", "nosuch"), "--only"),
    # which seed wins, why run one twice: refused
    (("pipeline", "--out", NEW, "--seed", "3", "--seeds", "0-1"), "--seed", "either --seed or --seeds"),
    (("pipeline", "--out", NEW, "--seeds", "1,1"), "--seeds", "seed 1 twice"),
    (("pipeline", "--out", NEW, "--seeds", "0-3,2"), "--seeds", "seed 2 twice"),
    # a sample time is never assumed: the variable is named
    (("compare", "--controllers", "{nodt_mat}", "--out", NEW, "--model", "{model}"), "--controllers",
     "expected the variable dt"),
    (("characterize", "--controller", "{nodt_mat}", "--out", NEW), "--controller", "expected the variable dt"),
    (("montecarlo", "--controller", "{nodt_mat}", "--out", NEW), "--controller", "expected the variable dt"),
    (("view", "--controller", "{nodt_mat}", "--seconds", "1", "--port", "0"), "--controller", "variable dt"),
    # an unstable loop is refused before the simulation starts
    (("characterize", "--controller", "{unstable}", "--out", NEW), "--controller", "does not stabilize"),
    (("montecarlo", "--controller", "{unstable}", "--out", NEW, "--n", "1"), "--controller", "does not stabilize"),
    # a population too large to run: refused at once, with the time it would take
    (("montecarlo", "--controller", "{ctrl}", "--out", NEW, "--n", "1000000000000"), "--n", "at most 100000",
     "days"),
    # folders of other commands
    (("report", "--run", "{sealed_mc}"), "--run", "montecarlo run folder"),
    (("report", "--run", "{sealed_compare}"), "--run", "compare run folder"),
    (("ablation", "--run", "{sealed_compare}"), "--run", "compare run folder"),
]


def _id(case):
    argv = case[0]
    return " ".join([argv[0], *argv[-2:]]).replace("{", "").replace("}", "")


def _snapshot(path: Path):
    if not path.exists():
        return None
    manifest = path / MANIFEST_JSON
    return (sorted(p.relative_to(path).as_posix() for p in path.rglob("*")),
            manifest.read_bytes() if manifest.is_file() else None)


@pytest.mark.parametrize("case", BAD, ids=[_id(c) for c in BAD])
def test_bad_input_one_line_exit_2_out_untouched(fx, tmp_path, capsys, case):
    argv, name, *words = case
    o = tmp_path / "o"
    o.mkdir()
    argv = [a.format(o=o, **fx) for a in argv]
    out = next((argv[i + 1] for i, a in enumerate(argv) if a in ("--out", "--plot")), None)
    before = _snapshot(Path(out)) if out and Path(out).is_dir() and Path(out).is_absolute() else None
    try:
        rc = main(argv)
    except SystemExit as exc:                       # argparse
        rc = exc.code
    cap = capsys.readouterr()
    lines = [ln for ln in (cap.err + cap.out).splitlines() if ln.strip()]
    assert "Traceback" not in cap.err + cap.out
    assert rc == 2 and len(lines) == 1, lines
    assert name in lines[0], lines[0]
    for w in words:
        assert w.lower() in lines[0].lower(), (w, lines[0])
    assert not any(o.iterdir()), sorted(os.listdir(o))          # no --out, no parents, no lock or staging left
    if before is not None:
        assert _snapshot(Path(out)) == before                   # an existing run folder: same files, same manifest


def test_sweep_help_lists_what_parse_param_accepts(capsys):
    from nanosim.pipeline.sweep import chain_length_fields, parse_param

    with pytest.raises(SystemExit):
        main(["sweep", "--help"])
    text = " ".join(capsys.readouterr().out.split())
    assert "crank_bend" not in text
    for fam in ("fb1", "fb2", "swing", "apa", "fourbar1", "lever"):
        assert fam in text
        parse_param(f"thickness.{fam}=100:120:2")
    for field in chain_length_fields():
        assert field in text
        parse_param(f"length_mm.{field}=10:12:2")


def test_a_scheduler_that_does_not_answer_leaves_a_sealed_montecarlo_as_it_was(fx, tmp_path, capsys, monkeypatch):
    """Defect 2: the connection is made before the manifest goes (and the API checks the address's form too)."""
    distributed = pytest.importorskip("distributed")
    import shutil

    from nanosim.pipeline.config import MonteCarloConfig
    from nanosim.pipeline.montecarlo import run_montecarlo

    run = tmp_path / "mc"
    shutil.copytree(fx["sealed_mc"], run)
    before = _snapshot(run)

    def refused(*args, **kwargs):
        raise OSError("Connection refused")

    monkeypatch.setattr(distributed, "Client", refused)
    rc = main(["montecarlo", "--controller", str(fx["ctrl"]), "--out", str(run), "--n", "2", "--crosscheck", "0",
               "--scheduler", "tcp://127.0.0.1:1"])
    cap = capsys.readouterr()
    lines = [ln for ln in (cap.err + cap.out).splitlines() if ln.strip()]
    assert rc == 2 and len(lines) == 1 and "--scheduler" in lines[0] and "cannot reach" in lines[0], lines
    assert _snapshot(run) == before
    assert sorted(os.listdir(tmp_path)) == ["mc"]                # no lock left beside it
    with pytest.raises(ValueError, match="--scheduler"):
        run_montecarlo(fx["ctrl"], run, MonteCarloConfig(n=2, crosscheck=0, scheduler="foo"), progress=False)
    assert _snapshot(run) == before
    assert json.loads((run / MANIFEST_JSON).read_text())["files_sha256"]


def test_a_failed_command_leaves_no_parent_folders(tmp_path):
    """Defect 15: the parents of a new --out are created for the run and removed again if it fails."""
    from nanosim.pipeline.runfolder import staged_run, writer_lock

    for ctx in (staged_run, writer_lock):
        with pytest.raises(ValueError, match="failed"), ctx(tmp_path / "deep" / "x" / "y"):
            raise ValueError("failed")
        assert not any(tmp_path.iterdir()), sorted(os.listdir(tmp_path))
    with staged_run(tmp_path / "deep" / "run") as stage:
        (stage / "f.txt").write_text("x")
    assert (tmp_path / "deep" / "run" / "f.txt").is_file()


@pytest.mark.parametrize("flag, bands", [([], (50.0, 100.0, 200.0, 1000.0)), (["--paper-bands"], (50.0, 100.0, 200.0))])
def test_paper_bands_reach_the_pipelines_identification(monkeypatch, tmp_path, flag, bands):
    import nanosim.pipeline.run as run
    from nanosim.cli import main
    seen = []

    def fake(stage, cfg):
        seen.append(cfg)
        raise RuntimeError("stop before any work")
    monkeypatch.setattr(run, "run_pipeline", fake)
    with pytest.raises(RuntimeError, match="stop before any work"):
        main(["pipeline", "--out", str(tmp_path / "run"), *flag])
    assert seen[0].identify.bands_hz == bands
    assert not (tmp_path / "run").exists()                  # the staged folder is removed: nothing half-written
