"""How a run ends when it is stopped: SIGINT, SIGTERM and SIGKILL sent to a real ``nanosim pipeline``.

Each signal goes to the ``python -m nanosim`` process itself (``subprocess``, SIGINT at its default:
a shell's background job would start it ignored): SIGINT and SIGTERM during the identification,
SIGINT during the characterization. Checked: the exit status (128 + the signal), the time to exit, that no process
of the run is left, that nothing is left beside the run folder, and that the previous run folder
is byte for byte what it was.
"""
from __future__ import annotations

import hashlib
import os
import re
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from nanosim.pipeline.runfolder import write_manifest

pytestmark = pytest.mark.skipif(not Path("/proc/self/stat").is_file(), reason="reads the process tree from /proc")

ENV = dict(os.environ, OPENBLAS_NUM_THREADS="1")
#: Time the run has from the signal to its exit, and then for its processes to be gone [s].
EXIT_WITHIN_S = 2.0
#: Time the workers of a run killed with SIGKILL have to notice it and leave [s].
ORPHANS_GONE_WITHIN_S = 10.0


def _default_sigint():
    signal.signal(signal.SIGINT, signal.SIG_DFL)


def start(out: Path, log: Path) -> subprocess.Popen:
    return subprocess.Popen([sys.executable, "-m", "nanosim", "pipeline", "--out", str(out)], env=ENV,
                            stdout=subprocess.DEVNULL, stderr=open(log, "w"), preexec_fn=_default_sigint)


def _stat(pid: int):
    """(parent pid, state letter) of a process, None if it is gone."""
    try:
        text = Path(f"/proc/{pid}/stat").read_text()
    except OSError:
        return None
    fields = text[text.rindex(")") + 2:].split()
    return int(fields[1]), fields[0]


def descendants(pid: int) -> set[int]:
    """Every process below ``pid`` (children, their children, ...)."""
    parent = {}
    for d in Path("/proc").iterdir():
        if d.name.isdigit():
            st = _stat(int(d.name))
            if st is not None:
                parent[int(d.name)] = st[0]
    found, frontier = set(), {pid}
    while frontier:
        frontier = {p for p, pp in parent.items() if pp in frontier} - found
        found |= frontier
    return found


def alive(pids) -> set[int]:
    """The processes of ``pids`` that still run (a zombie has ended)."""
    out = set()
    for p in pids:
        st = _stat(p)
        if st is not None and st[1] != "Z":
            out.add(p)
    return out


def digest(folder: Path) -> dict:
    return {p.relative_to(folder).as_posix(): hashlib.sha256(p.read_bytes()).hexdigest()
            for p in sorted(folder.rglob("*")) if p.is_file()}


def wait_until(condition, proc, log: Path, timeout_s: float = 900.0) -> None:
    deadline = time.monotonic() + timeout_s
    while not condition():
        assert proc.poll() is None, log.read_text()
        assert time.monotonic() < deadline, f"the run never reached the step: {log.read_text()[-2000:]}"
        time.sleep(0.1)


@pytest.fixture
def previous(tmp_path):
    """A sealed run folder the pipeline would replace: its sha256 must survive a stopped run."""
    run = tmp_path / "run"
    run.mkdir()
    (run / "metrics.json").write_text('{"units": {}, "previous": true}\n')
    write_manifest(run, seed=0, command=["nanosim", "pipeline", "--out", "run"])
    return run, digest(run)


def _at_step(step: str, run: Path, log: Path):
    """A condition that holds once the run is inside ``step`` (its progress bar names the running step)."""
    if step == "identification":           # the staging folder exists and the identification runs
        return lambda: "running identify" in log.read_text() and any(run.parent.glob(f".{run.name}.staging-*"))
    return lambda: "running characterize" in log.read_text()


def stop_and_check(proc, sig, run: Path, before: dict, log: Path) -> None:
    kids = descendants(proc.pid)
    assert kids, "a pipeline runs its steps on worker processes"
    t0 = time.monotonic()
    proc.send_signal(sig)
    rc = proc.wait(timeout=60)
    took = time.monotonic() - t0
    err = log.read_text()
    assert rc == 128 + sig, err[-2000:]
    assert took <= EXIT_WITHIN_S, f"exit {took:.1f} s after the signal"
    said = re.findall(r"nanosim pipeline: (?:interrupted|terminated)[^\r\n]*", err)   # after the bar, on its line
    word = "terminated (SIGTERM)" if sig == signal.SIGTERM else "interrupted"
    assert len(said) == 1 and said[0].startswith(f"nanosim pipeline: {word}; the run folder was left"), err[-2000:]
    assert "Traceback" not in err, err[-3000:]
    time.sleep(EXIT_WITHIN_S)
    assert alive(kids) == set(), f"processes of the run still alive {EXIT_WITHIN_S} s after it exited"
    assert sorted(p.name for p in run.parent.iterdir() if p.name.startswith(f".{run.name}")) == []
    assert digest(run) == before


@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM], ids=["SIGINT", "SIGTERM"])
def test_stopped_during_identification(previous, tmp_path, sig):
    run, before = previous
    log = tmp_path / "stderr.txt"
    proc = start(run, log)
    try:
        wait_until(_at_step("identification", run, log), proc, log)
        time.sleep(1.0)                          # inside the simulation
        stop_and_check(proc, sig, run, before, log)
    finally:
        if proc.poll() is None:
            proc.kill()


@pytest.mark.slow
def test_stopped_during_characterization(previous, tmp_path, sig=signal.SIGINT):
    """Ctrl-C while the workers run the experiments. SIGTERM takes the same clean-up (one handler raises
    either exception) and is sent during the identification, where the workers run too."""
    run, before = previous
    log = tmp_path / "stderr.txt"
    proc = start(run, log)
    try:
        wait_until(_at_step("characterization", run, log), proc, log)
        time.sleep(1.0)
        stop_and_check(proc, sig, run, before, log)
    finally:
        if proc.poll() is None:
            proc.kill()


def test_killed_run_leaves_no_worker_and_the_next_run_starts(previous, tmp_path):
    """SIGKILL: the workers leave by themselves; the next writer clears the staging folder and lock and says so."""
    run, before = previous
    log = tmp_path / "stderr.txt"
    proc = start(run, log)
    try:
        wait_until(_at_step("identification", run, log), proc, log)
        time.sleep(1.0)
        kids = descendants(proc.pid)
        assert kids
        proc.send_signal(signal.SIGKILL)
        assert proc.wait(timeout=30) == -signal.SIGKILL
    finally:
        if proc.poll() is None:
            proc.kill()
    deadline = time.monotonic() + ORPHANS_GONE_WITHIN_S
    while alive(kids) and time.monotonic() < deadline:
        time.sleep(0.2)
    assert alive(kids) == set(), f"workers alive {ORPHANS_GONE_WITHIN_S:g} s after their parent was killed"
    left = sorted(p.name for p in tmp_path.iterdir() if p.name.startswith(".run"))
    assert f".run.staging-{proc.pid}" in left                # what SIGKILL leaves: no clean-up can run
    assert digest(run) == before
    # the next writer takes the lock, removes the dead writer's staging folder, says so in one line
    log2 = tmp_path / "stderr2.txt"
    nxt = start(run, log2)
    try:
        wait_until(lambda: (tmp_path / f".run.staging-{nxt.pid}").is_dir(), nxt, log2)
        said = [ln for ln in log2.read_text().splitlines() if "removed the unfinished staging folder" in ln]
        assert len(said) == 1 and f"pid {proc.pid}" in said[0]
        assert not (tmp_path / f".run.staging-{proc.pid}").exists()
        wait_until(_at_step("identification", run, log2), nxt, log2)    # its workers started (slow under load)
        time.sleep(1.0)                          # inside the simulation, as test_stopped_during_identification
        stop_and_check(nxt, signal.SIGTERM, run, before, log2)
    finally:
        if nxt.poll() is None:
            nxt.kill()


@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM], ids=["SIGINT", "SIGTERM"])
def test_stopped_montecarlo_prints_one_line_and_leaves_no_worker(tmp_path, sig):
    """Ctrl-C/SIGTERM of a Monte Carlo on a local pool: no worker traceback, no worker left, the folder resumable."""
    import numpy as np

    from nanosim.fileio import write_npz

    ctrl = write_npz(tmp_path / "c.npz", Akd=np.zeros((1, 1)), Bkd=np.zeros((1, 3)), Ckd=np.zeros((3, 1)),
                     Dkd=np.zeros((3, 3)), dt=2.5e-4)
    log = tmp_path / "stderr.txt"
    out = tmp_path / "mc"
    proc = subprocess.Popen([sys.executable, "-m", "nanosim", "montecarlo", "--controller", str(ctrl), "--n", "4",
                             "--workers", "2", "--out", str(out)], env=ENV, stdout=subprocess.DEVNULL,
                            stderr=open(log, "w"), preexec_fn=_default_sigint)
    try:
        wait_until(lambda: "chunks of" in log.read_text() and len(descendants(proc.pid)) >= 3, proc, log)
        time.sleep(2.0)                          # the workers are inside their first samples
        first = log.read_text().splitlines()[0]
        assert first.startswith("  montecarlo: 4 linear-twin samples and 4 MuJoCo cross-checks to run, about ")
        kids = descendants(proc.pid)
        t0 = time.monotonic()
        proc.send_signal(sig)
        rc = proc.wait(timeout=60)
        took = time.monotonic() - t0
    finally:
        if proc.poll() is None:
            proc.kill()
    err = log.read_text()
    assert rc == 128 + sig and took <= EXIT_WITHIN_S, (rc, took, err[-2000:])
    assert "Traceback" not in err, err[-3000:]
    said = re.findall(r"nanosim montecarlo: (?:interrupted|terminated)[^\r\n]*", err)
    assert len(said) == 1 and said[0].endswith("every finished sample is kept; a rerun resumes it")
    time.sleep(EXIT_WITHIN_S)
    assert alive(kids) == set()
    assert sorted(p.name for p in tmp_path.iterdir() if p.name.startswith(".mc")) == []     # the lock is gone
    assert (out / "montecarlo.json").is_file() and not (out / "manifest.json").exists()     # unsealed: a rerun resumes
