"""Run folders that never lie: staged writes, a manifest written last, and a writer lock.

A command writes into a staging folder beside ``--out`` (a copy of the
previous run, for commands that add to it). Only when every step has
finished is ``manifest.json`` written (sha256 of every file, seed, version,
command line) and the staging folder swapped in place of ``--out``. An
interrupted or failed command (Ctrl-C, SIGTERM) leaves ``--out`` exactly as it
was (or absent), and removes its staging folder and lock. An OS file lock
(:mod:`filelock`, ``.NAME.lock`` beside ``--out``) refuses a second writer on the
same ``--out``, on this host or another one sharing the file system; a writer
killed with SIGKILL leaves its staging folder, which the next writer removes,
saying so in one line.
"""
from __future__ import annotations

import contextlib
import errno
import hashlib
import json
import os
import shutil
import sys
import tempfile
from dataclasses import dataclass
from pathlib import Path

from nanosim.fileio import write_json
from nanosim.pipeline.artifacts import MANIFEST_JSON

__all__ = ["RunFolderError", "MANIFEST_JSON", "SealedRun", "check_writable", "staged_run", "writer_lock",
           "write_manifest", "verify_manifest", "sealed_run", "verify_input_file", "sha256_file", "run_relative"]


class RunFolderError(ValueError):
    """A run folder cannot be written or read (a user error: one line, exit 2)."""


def check_writable(out: str | os.PathLike, name: str = "--out") -> Path:
    """Check before any work that ``out`` can become a run folder; returns it as a Path.

    The nearest existing ancestor of ``out``'s parent must accept a new folder: one is
    created there and removed at once (``os.access`` alone says yes to root on ``/proc``,
    an immutable folder, ...).

    Raises
    ------
    RunFolderError
        ``out`` is empty or an existing file, or its parent is missing/not a directory/not writable.
    """
    if not str(out).strip():
        raise RunFolderError(f"{name}: expected a folder path, got {str(out)!r}")
    out = Path(out)
    if out.exists() and not out.is_dir():
        raise RunFolderError(f"{name}: expected a directory, got an existing file {str(out)!r}")
    parent = out.resolve().parent
    probe = parent
    while not probe.exists():
        probe = probe.parent
    if not probe.is_dir():
        raise RunFolderError(f"{name}: {str(probe)!r} is not a directory")
    denied = f"{name}: cannot write in {str(probe)!r} (permission denied or read-only)"
    if not os.access(probe, os.W_OK | os.X_OK):
        raise RunFolderError(denied)
    try:
        os.rmdir(tempfile.mkdtemp(prefix=".nanosim-probe-", dir=probe))
    except OSError as exc:
        if exc.errno in (errno.EACCES, errno.EPERM, errno.EROFS):
            raise RunFolderError(denied) from None
        raise RunFolderError(f"{name}: cannot create {str(out)!r}: no new folder can be made in {str(probe)!r} "
                             f"({exc.strerror or exc})") from None
    if out.is_dir() and not os.access(out, os.R_OK | os.X_OK):
        raise RunFolderError(f"{name}: cannot read {str(out)!r}")
    return out


def _make_parents(folder: Path) -> list[Path]:
    """``mkdir -p folder``; returns the folders it created, deepest first (see :func:`_remove_empty`)."""
    made = []
    p = folder
    while not p.exists():
        made.append(p)
        p = p.parent
    folder.mkdir(parents=True, exist_ok=True)
    return made


def _remove_empty(folders: list[Path]) -> None:
    """Remove the folders :func:`_make_parents` created if they are still empty (a failed command)."""
    for p in folders:
        try:
            p.rmdir()
        except OSError:
            return


def run_relative(path: str | os.PathLike, run_dir: str | os.PathLike) -> str:
    """``path`` as a run folder's files record it.

    Relative to ``run_dir`` when it lies inside it (the run folder may be a staging folder renamed
    at the end), else absolute.
    """
    p = Path(path).resolve()
    try:
        return p.relative_to(Path(run_dir).resolve()).as_posix()
    except ValueError:
        return str(p)


def sha256_file(path: Path) -> str:
    """Hex sha256 of a file's bytes."""
    h = hashlib.sha256()
    with open(path, "rb") as fh:
        for chunk in iter(lambda: fh.read(1 << 20), b""):
            h.update(chunk)
    return h.hexdigest()


def _sealable_files(folder: Path) -> list[str]:
    """Files a manifest lists: every file but the manifest itself and hidden (temporary) files."""
    return [p.relative_to(folder).as_posix() for p in sorted(folder.rglob("*"))
            if p.is_file() and p.name != MANIFEST_JSON and not p.name.startswith(".")]


def write_manifest(folder: Path, *, seed=None, command=None, history=()) -> Path:
    """Write ``manifest.json`` last: sha256 of every other file, seed, version, command line.

    ``history`` lists the earlier commands of a run that commands added to (``design``,
    ``characterize`` and ``report`` on an existing run), oldest first.
    """
    from nanosim import __version__

    files = {rel: sha256_file(folder / rel) for rel in _sealable_files(folder)}
    return write_json(folder / MANIFEST_JSON, {
        "nanosim_version": __version__, "seed": seed,
        "command": command if command is not None else [Path(sys.argv[0]).name, *sys.argv[1:]],
        "history": list(history),
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
    extra = sorted(set(_sealable_files(folder)) - set(files))
    if extra:
        raise RunFolderError(f"run folder {str(folder)!r}: {extra[0]} was added after the run was sealed"
                             + (f" (and {len(extra) - 1} more)" if len(extra) > 1 else ""))
    return man


@dataclass(frozen=True)
class SealedRun:
    """A run folder whose files match its manifest (see :func:`sealed_run`).

    Attributes
    ----------
    path : Path
        The run folder.
    seed : int or None
        Seed recorded by the command that sealed it.
    nanosim_version : str
        Version that wrote it.
    command : tuple of str
        Command line that sealed it; ``history`` the earlier ones, oldest first.
    files : tuple of str
        Files listed in the manifest (relative, POSIX separators).
    """

    path: Path
    seed: int | None
    nanosim_version: str
    command: tuple
    history: tuple
    files: tuple


def sealed_run(folder: str | os.PathLike, required: tuple[str, ...] = (), name: str = "--run") -> SealedRun:
    """Open a run folder for reading, refusing it unless its manifest matches every file.

    Readers (``nanosim report``, ``nanosim compare``, ...) call this before using a folder.

    Parameters
    ----------
    folder : path
        The run folder.
    required : tuple of str
        Files that must be part of the sealed run (e.g. ``("metrics.json",)``).
    name : str
        Argument name used in the error message.

    Raises
    ------
    RunFolderError
        Not a directory, no manifest, a listed file missing or changed, or a required file not listed.
    """
    folder = Path(folder)
    if not folder.is_dir():
        what = "an existing file" if folder.exists() else "nothing"
        raise RunFolderError(f"{name}: expected a nanosim run folder, got {what} at {str(folder)!r}")
    try:
        man = verify_manifest(folder, required)
    except RunFolderError as exc:
        raise RunFolderError(f"{name}: {exc}") from None
    return SealedRun(path=folder, seed=man.get("seed"), nanosim_version=str(man.get("nanosim_version")),
                     command=tuple(man.get("command") or ()), history=tuple(man.get("history") or ()),
                     files=tuple(man["files_sha256"]))


def verify_input_file(path: str | os.PathLike, name: str) -> Path:
    """Refuse an input file (``--controller``, ``--model``) that lies in a run folder it no longer matches.

    A file whose folder has no manifest (written by the user, or by the API) is accepted as it is;
    a file in a sealed run folder must be listed in the manifest with the same sha256.

    Raises
    ------
    RunFolderError
        The file's run folder does not match its manifest, or the file is not part of it.
    """
    path = Path(path)
    folder = path.resolve().parent
    if (folder / MANIFEST_JSON).is_file():
        sealed_run(folder, required=(path.name,), name=name)
    return path


def _is_run_folder_or_empty(out: Path) -> bool:
    return not out.is_dir() or (out / MANIFEST_JSON).is_file() or not any(out.iterdir())


def _pid_of(p: Path) -> int | None:
    try:
        return int(p.name.rsplit("-", 1)[1])
    except (IndexError, ValueError):
        return None


def _say(msg: str) -> None:
    print(f"  {msg}", file=sys.stderr, flush=True)


def _clean_stale(out: Path, say=_say) -> None:
    """Remove what a stopped writer left beside ``out``; put back a previous run it had moved aside.

    Called with ``out``'s lock held: every staging folder or moved-aside run beside ``out`` then
    belongs to a writer that is gone (killed, or on a host that lost the file system), whatever
    its process id, so this is right across hosts too. Says in one line what it removed.
    """
    mine = {f".{out.name}.staging-{os.getpid()}", f".{out.name}.old-{os.getpid()}"}
    left = [p for p in sorted(out.parent.glob(f".{out.name}.old-*")) if p.name not in mine]
    staging = [p for p in sorted(out.parent.glob(f".{out.name}.staging-*")) if p.name not in mine]
    for p in left:
        if not out.exists():
            os.replace(p, out)                     # killed between the two renames of the swap
            say(f"{str(out)!r}: put back the previous run that a stopped nanosim process (pid {_pid_of(p)}) "
                "had moved aside")
        else:
            shutil.rmtree(p, ignore_errors=True)
    for p in staging:
        shutil.rmtree(p, ignore_errors=True)
    if staging:
        pids = ", ".join(str(_pid_of(p)) for p in staging)
        say(f"{str(out)!r}: removed the unfinished staging folder of a stopped nanosim process (pid {pids})")


class _Lock:
    """The writer lock ``.NAME.lock`` beside a run folder: an OS file lock (:mod:`filelock`).

    The operating system releases the lock when its holder dies, on this host or (``flock`` on NFS,
    byte-range locks on SMB) on another one sharing the file system, so a lock file a killed process
    left behind is taken over without asking who wrote it. The file is removed on release; an
    acquirer that locked a file another process removed meanwhile (its inode no longer at the path)
    lets go and tries again.
    """

    def __init__(self, path: Path):
        from filelock import FileLock

        self.path = path
        self._lock = FileLock(str(path), timeout=0, thread_local=False)
        self.found_stale = False

    def _holds_the_path(self) -> bool:
        fd = getattr(getattr(self._lock, "_context", None), "lock_file_fd", None)
        if fd is None:
            return self.path.exists()
        try:
            return os.path.samestat(os.fstat(fd), os.stat(self.path))
        except OSError:
            return False

    def acquire(self) -> None:
        from filelock import Timeout

        out = self.path.parent / self.path.name[1:-len(".lock")]
        self.found_stale = self.path.exists()
        for _ in range(5):
            try:
                self._lock.acquire(timeout=0)
            except Timeout:
                pids = sorted(_pid_of(p) for p in out.parent.glob(f".{out.name}.staging-*"))
                who = f" (pid {', '.join(map(str, pids))})" if pids else ""
                raise RunFolderError(f"--out: another nanosim process{who} is writing {str(out)!r}; wait for it or "
                                     "choose another folder") from None
            if self._holds_the_path():
                return
            self._lock.release()
        raise RunFolderError(f"--out: cannot take the writer lock {str(self.path)!r} (it keeps being replaced)")

    def release(self) -> None:
        if self._lock.is_locked:
            if self._holds_the_path():
                self.path.unlink(missing_ok=True)      # before letting go: nobody takes a lock on a removed file
            self._lock.release()


@contextlib.contextmanager
def writer_lock(out: str | os.PathLike):
    """The writer lock of run folder ``out`` (for commands that write in place instead of staging).

    The same lock :func:`staged_run` takes: a second writer on ``out`` gets a one-line
    :class:`RunFolderError`; a lock left by a dead process is taken over (see :class:`_Lock`), and
    what that process left beside ``out`` is removed, in one line.
    """
    out = Path(out).resolve()
    made = _make_parents(out.parent)            # removed again if the command fails before writing into them
    lock = _Lock(out.parent / f".{out.name}.lock")
    try:
        lock.acquire()
    except BaseException:
        _remove_empty(made)
        raise
    try:
        _clean_stale(out)
        yield out
        made = []
    finally:
        lock.release()
        _remove_empty(made)


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
    command : list of str, optional
        Recorded in the manifest (default: ``sys.argv``).

    Raises
    ------
    RunFolderError
        ``out`` cannot be written; it holds files that are not a nanosim run (no manifest: it
        would be replaced or sealed); with ``keep_existing``, its files no longer match its
        manifest; or another process is writing it.
    """
    out = check_writable(out).resolve()
    if not _is_run_folder_or_empty(out):
        raise RunFolderError(f"--out: {str(out)!r} holds files but no {MANIFEST_JSON}, so it is not a nanosim run "
                             "folder; choose a new or empty folder")
    made = _make_parents(out.parent)            # removed again unless the run is swapped in
    lock = _Lock(out.parent / f".{out.name}.lock")
    try:
        lock.acquire()
    except BaseException:
        _remove_empty(made)
        raise
    stage = out.parent / f".{out.name}.staging-{os.getpid()}"
    old = out.parent / f".{out.name}.old-{os.getpid()}"
    try:
        _clean_stale(out)
        history = []
        if keep_existing and (out / MANIFEST_JSON).is_file():
            prev = sealed_run(out, name="--out")         # never seal over files changed since
            history = [*prev.history, list(prev.command)]
            seed = prev.seed if seed is None else seed
        if stage.exists():
            shutil.rmtree(stage)
        if keep_existing and out.is_dir():
            shutil.copytree(out, stage, ignore=shutil.ignore_patterns(MANIFEST_JSON))
        else:
            stage.mkdir()
        yield stage
        write_manifest(stage, seed=seed, command=command, history=history)
        if out.exists():
            os.replace(out, old)
        os.replace(stage, out)
        made = []
        shutil.rmtree(old, ignore_errors=True)
    finally:
        shutil.rmtree(stage, ignore_errors=True)
        if old.exists() and not out.exists():       # swap interrupted between the two renames
            os.replace(old, out)
        lock.release()
        _remove_empty(made)
