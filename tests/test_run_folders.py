"""Run folders never lie: an interrupted or concurrent writer leaves the previous run or nothing, readers refuse a
folder that does not match its manifest, a folder that is not a run is never replaced, and the files follow the
umask. Signals and concurrency are driven through subprocesses."""

import json
import signal
import time

import pytest


from cli_run import (copy_run, digest, error_lines, in_process, make_sealed_run, nanosim, start, wait_for,
                     zero_controller)


@pytest.fixture(scope="module")
def sealed(tmp_path_factory):
    """A complete run made by the CLI (see :func:`cli_run.make_sealed_run`)."""
    return make_sealed_run(tmp_path_factory.mktemp("sealed"))

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


# --- file permissions ---------------------------------------------------------------------------------
def test_artifacts_follow_the_umask(sealed):
    run = sealed[0]
    modes = {p.relative_to(run).as_posix(): p.stat().st_mode & 0o777 for p in run.rglob("*") if p.is_file()}
    assert len(modes) >= 3 and set(modes.values()) == {0o644}, modes              # not 0600
    assert (run.stat().st_mode & 0o777) == 0o755
