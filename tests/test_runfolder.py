"""The run folder's writer lock (an OS file lock) and what the next writer does with a stopped writer's leftovers."""
from __future__ import annotations

import os
import subprocess
import sys
import time

import pytest

from nanosim.pipeline.runfolder import RunFolderError, staged_run, writer_lock

ENV = dict(os.environ, OPENBLAS_NUM_THREADS="1")


def _names(folder):
    return sorted(p.name for p in folder.iterdir())


def test_a_normal_writer_leaves_only_the_run(tmp_path):
    with staged_run(tmp_path / "run") as stage:
        assert (tmp_path / ".run.lock").is_file()                  # held while the command writes
        (stage / "a.txt").write_text("x")
    assert _names(tmp_path) == ["run"]                             # lock and staging folder gone


def test_a_held_lock_refuses_a_second_writer_naming_the_writer(tmp_path):
    from filelock import FileLock

    (tmp_path / ".run.staging-4242").mkdir()                       # the writer's staging folder names its pid
    other = FileLock(str(tmp_path / ".run.lock"), thread_local=False)
    other.acquire()
    try:
        with pytest.raises(RunFolderError, match=r"another nanosim process \(pid 4242\) is writing"):
            with staged_run(tmp_path / "run"):
                pass
        with pytest.raises(RunFolderError, match="another nanosim process"):
            with writer_lock(tmp_path / "run"):
                pass
    finally:
        other.release()
    assert (tmp_path / ".run.staging-4242").is_dir()               # the live writer's folder is not touched


def test_the_next_writer_clears_a_stopped_writers_staging_folder_and_lock_and_says_so(tmp_path, capsys):
    """A lock file nobody holds and a staging folder: a writer killed on this host or on another one."""
    (tmp_path / ".run.lock").write_text("")
    (tmp_path / ".run.staging-77").mkdir()
    (tmp_path / ".run.staging-77" / "half.npz").write_text("partial")
    with staged_run(tmp_path / "run") as stage:
        (stage / "a.txt").write_text("x")
    said = [ln for ln in capsys.readouterr().err.splitlines() if ln.strip()]
    assert len(said) == 1 and "removed the unfinished staging folder" in said[0] and "pid 77" in said[0]
    assert _names(tmp_path) == ["run"]


def test_the_lock_is_released_by_the_os_when_its_holder_is_killed(tmp_path):
    """SIGKILL of the holder (no clean-up runs): the lock is free at once, whatever pid it had."""
    code = ("import sys, time; from nanosim.pipeline.runfolder import staged_run\n"
            "with staged_run(sys.argv[1]) as s:\n    print('in', flush=True); time.sleep(120)\n")
    p = subprocess.Popen([sys.executable, "-c", code, str(tmp_path / "run")], stdout=subprocess.PIPE, text=True,
                         env=ENV)
    try:
        assert p.stdout.readline().strip() == "in"
        with pytest.raises(RunFolderError, match=f"pid {p.pid}"):
            with staged_run(tmp_path / "run"):
                pass
        p.kill()
        p.wait(30)
    finally:
        if p.poll() is None:
            p.kill()
    t0 = time.monotonic()
    with staged_run(tmp_path / "run") as stage:
        (stage / "a.txt").write_text("x")
    assert time.monotonic() - t0 < 10
    assert _names(tmp_path) == ["run"]
