"""Helpers of the CLI's edge tests: run the CLI in a subprocess or in this process, a do-nothing controller,
folder digests, stderr without progress output, and a sealed run folder made by the CLI."""

import hashlib
import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

from nanosim.cli import main
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



def make_sealed_run(base: Path):
    """A complete run made by the CLI under umask 022: ``characterize --only small_steps`` (a few s).

    Returns ``(run folder, controller file, completed process)``.
    """
    ctrl = zero_controller(base / "zero_controller.npz")
    p = nanosim("characterize", "--controller", ctrl, "--out", base / "run", "--only", "small_steps", "--seed", 3,
                umask=0o022)
    assert p.returncode == 0, p.stderr
    return base / "run", ctrl, p


def copy_run(sealed, tmp_path) -> Path:
    """A copy of the sealed run folder under ``tmp_path``."""
    dst = tmp_path / "run"
    shutil.copytree(sealed[0], dst)
    return dst
