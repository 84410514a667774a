"""Run folders that never lie: staged writes, a manifest written last, and a writer lock.

A command writes into a staging folder beside ``--out`` (a copy of the
previous run, for commands that add to it). Only when every step has
finished is ``manifest.json`` written (sha256 of every file, seed, version,
command line) and the staging folder swapped in place of ``--out``. An
interrupted or failed command leaves ``--out`` exactly as it was (or absent).
A lock file refuses a second writer on the same ``--out``.
"""
from __future__ import annotations

import contextlib
import hashlib
import json
import os
import shutil
import sys
from dataclasses import dataclass
from pathlib import Path

from nanosim.fileio import write_json

__all__ = ["RunFolderError", "MANIFEST_JSON", "check_writable", "staged_run", "write_manifest", "verify_manifest",
           "sha256_file"]

MANIFEST_JSON = "manifest.json"


class RunFolderError(ValueError):
    """A run folder cannot be written or read (a user error: one line, exit 2)."""


def check_writable(out: str | os.PathLike, name: str = "--out") -> Path:
    """Check before any work that ``out`` can become a run folder; returns it as a Path.

    Raises
    ------
    RunFolderError
        ``out`` is an existing file, or its parent is missing/not a directory/not writable.
    """
    out = Path(out)
    if out.exists() and not out.is_dir():
        raise RunFolderError(f"{name}: expected a directory, got an existing file {str(out)!r}")
    parent = out.resolve().parent
    probe = parent
    while not probe.exists():
        probe = probe.parent
    if not probe.is_dir():
        raise RunFolderError(f"{name}: {str(probe)!r} is not a directory")
    if not os.access(probe, os.W_OK | os.X_OK):
        raise RunFolderError(f"{name}: cannot write in {str(probe)!r} (permission denied or read-only)")
    if out.is_dir() and not os.access(out, os.R_OK | os.X_OK):
        raise RunFolderError(f"{name}: cannot read {str(out)!r}")
    return out


def sha256_file(path: Path) -> str:
    """Hex sha256 of a file's bytes."""
    h = hashlib.sha256()
    with open(path, "rb") as fh:
        for chunk in iter(lambda: fh.read(1 << 20), b""):
            h.update(chunk)
    return h.hexdigest()


def write_manifest(folder: Path, *, seed=None, command=None) -> Path:
    """Write ``manifest.json`` last: sha256 of every other file, seed, version, command line."""
    from nanosim import __version__

    files = {}
    for p in sorted(folder.rglob("*")):
        if p.is_file() and p.name != MANIFEST_JSON and not p.name.startswith("."):
            files[p.relative_to(folder).as_posix()] = sha256_file(p)
    return write_json(folder / MANIFEST_JSON, {
        "nanosim_version": __version__, "seed": seed,
        "command": command if command is not None else [Path(sys.argv[0]).name, *sys.argv[1:]],
        "files_sha256": files})


def verify_manifest(folder: str | os.PathLike, required: tuple[str, ...] = ()) -> dict:
    """Check a run folder against its manifest; returns the manifest.

    Raises
    ------
    RunFolderError
        No manifest, a listed file missing or changed, or a ``required`` file not listed.
    """
    folder = Path(folder)
    mpath = folder / MANIFEST_JSON
    if not mpath.is_file():
        raise RunFolderError(f"run folder {str(folder)!r}: no {MANIFEST_JSON} (incomplete or not a nanosim run)")
    try:
        man = json.loads(mpath.read_text())
        files = man["files_sha256"]
    except (ValueError, KeyError, TypeError):
        raise RunFolderError(f"run folder {str(folder)!r}: {MANIFEST_JSON} is not a valid manifest") from None
    for rel in required:
        if rel not in files:
            raise RunFolderError(f"run folder {str(folder)!r}: {rel} is not part of the sealed run")
    for rel, digest in files.items():
        p = folder / rel
        if not p.is_file():
            raise RunFolderError(f"run folder {str(folder)!r}: {rel} is listed in the manifest but missing")
        if sha256_file(p) != digest:
            raise RunFolderError(f"run folder {str(folder)!r}: {rel} changed after the run was sealed")
    return man


@dataclass
class _Lock:
    path: Path

    def acquire(self) -> None:
        try:
            fd = os.open(self.path, os.O_CREAT | os.O_EXCL | os.O_WRONLY, 0o644)
        except FileExistsError:
            pid = None
            with contextlib.suppress(OSError, ValueError):
                pid = int(self.path.read_text().strip() or "0")
            if pid and _alive(pid):
                raise RunFolderError(f"--out: another nanosim process (pid {pid}) is writing "
                                     f"{str(self.path.parent / self.path.name[1:-5])!r}; wait for it or choose "
                                     "another folder") from None
            self.path.unlink(missing_ok=True)          # stale lock of a dead process
            fd = os.open(self.path, os.O_CREAT | os.O_EXCL | os.O_WRONLY, 0o644)
        with os.fdopen(fd, "w") as fh:
            fh.write(str(os.getpid()))

    def release(self) -> None:
        self.path.unlink(missing_ok=True)


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True


@contextlib.contextmanager
def staged_run(out: str | os.PathLike, *, keep_existing: bool = False, seed=None, command=None):
    """Context manager yielding a staging folder that replaces ``out`` only on success.

    Parameters
    ----------
    out : path
        The run folder.
    keep_existing : bool
        Start from a copy of the existing ``out`` (commands that add to a run, e.g. ``design``).
    seed : int, optional
        Recorded in the manifest.
    """
    out = check_writable(out).resolve()
    out.parent.mkdir(parents=True, exist_ok=True)
    lock = _Lock(out.parent / f".{out.name}.lock")
    lock.acquire()
    stage = out.parent / f".{out.name}.staging-{os.getpid()}"
    old = out.parent / f".{out.name}.old-{os.getpid()}"
    try:
        if stage.exists():
            shutil.rmtree(stage)
        if keep_existing and out.is_dir():
            shutil.copytree(out, stage, ignore=shutil.ignore_patterns(MANIFEST_JSON))
        else:
            stage.mkdir()
        yield stage
        write_manifest(stage, seed=seed, command=command)
        if out.exists():
            os.replace(out, old)
        os.replace(stage, out)
        shutil.rmtree(old, ignore_errors=True)
    finally:
        shutil.rmtree(stage, ignore_errors=True)
        if old.exists() and not out.exists():       # swap interrupted between the two renames
            os.replace(old, out)
        lock.release()
