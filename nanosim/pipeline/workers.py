"""Worker processes that never outlive the command that started them.

Every local process pool of the pipeline (``multiprocessing.Pool``,
``ProcessPoolExecutor``) and every ``multiprocessing`` manager starts its
processes with :func:`worker_init`:

* SIGINT is ignored: Ctrl-C in a terminal reaches the whole process group, and
  the main process alone decides what happens (it stops the workers; no worker
  prints a traceback);
* a daemon thread watches the parent. A ``spawn`` child holds the read end of a
  pipe whose write end only the parent holds (``multiprocessing.parent_process().sentinel``);
  the kernel closes it when the parent dies, whatever killed it (SIGKILL, the
  out-of-memory killer), and the worker leaves at once with :data:`ORPHAN_EXIT_CODE`.
  Without a sentinel (a ``fork`` child) the thread polls ``os.getppid()``, which
  changes when the parent dies and the child is re-parented.

The multiprocessing resource tracker leaves by itself once the last process holding
its pipe is gone, so it follows the workers.

In the main process, :func:`stop_signals` turns SIGINT and SIGTERM into
:class:`KeyboardInterrupt` and :class:`~nanosim.validation.Terminated`, and
:func:`stop_deferred` holds them back while a pool or a manager is being started
(a signal in the middle of starting one would leave half-started processes that
nothing stops); the signal takes effect when the pool exists and can be stopped.
"""
from __future__ import annotations

import contextlib
import os
import signal
import threading

from nanosim.validation import Terminated

__all__ = ["ORPHAN_EXIT_CODE", "PARENT_POLL_S", "worker_init", "watch_parent", "start_manager",
           "terminate_executor", "stop_manager", "stop_signals", "stop_deferred"]

#: Exit status of a worker that found its parent gone.
ORPHAN_EXIT_CODE = 3
#: Poll interval of the ``os.getppid()`` fallback [s].
PARENT_POLL_S = 0.5


def watch_parent(poll_s: float = PARENT_POLL_S) -> threading.Thread:
    """Start a daemon thread that ends this process as soon as its parent is gone; returns the thread."""
    import multiprocessing
    from multiprocessing.connection import wait

    parent = multiprocessing.parent_process()
    sentinel = getattr(parent, "sentinel", None) if parent is not None else None
    ppid = os.getppid()

    def watch():
        while True:
            if sentinel is not None:
                try:
                    if wait([sentinel], timeout=None):
                        os._exit(ORPHAN_EXIT_CODE)
                except OSError:
                    os._exit(ORPHAN_EXIT_CODE)
            else:
                threading.Event().wait(poll_s)
                if os.getppid() != ppid:
                    os._exit(ORPHAN_EXIT_CODE)

    t = threading.Thread(target=watch, daemon=True, name="nanosim-parent-watch")
    t.start()
    return t


def worker_init(*initargs) -> None:
    """Initializer of every worker and manager process: ignore SIGINT, leave when the parent dies.

    SIGTERM keeps its default (the process ends): the main process stops its workers with it.
    """
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    watch_parent()


def start_manager(ctx):
    """A started ``SyncManager`` of context ``ctx`` whose server process runs :func:`worker_init`."""
    from multiprocessing.managers import SyncManager

    manager = SyncManager(ctx=ctx)
    try:
        manager.start(initializer=worker_init)
    except BaseException:                  # Ctrl-C/SIGTERM while the server boots: end it, it has no work yet
        proc = getattr(manager, "_process", None)
        if proc is not None:
            with contextlib.suppress(OSError, ValueError, AttributeError, AssertionError):
                proc.kill()
                proc.join(2.0)
        raise
    return manager


def stop_manager(manager, timeout_s: float = 2.0) -> None:
    """Stop a manager now (Ctrl-C, SIGTERM or a failed step): end its server process, then shut it down.

    ``manager.shutdown()`` alone asks the server to leave and waits up to a second for it, twice; a
    stopping command has nothing left to ask it, so the server is sent SIGTERM first.
    """
    proc = getattr(manager, "_process", None)
    with contextlib.suppress(OSError, ValueError, AttributeError, AssertionError):
        if proc is not None and proc.is_alive():
            proc.terminate()
            proc.join(timeout_s)
            if proc.is_alive():
                proc.kill()
                proc.join(timeout_s)
    with contextlib.suppress(Exception):
        manager.shutdown()


def terminate_executor(pool, timeout_s: float = 2.0) -> None:
    """Stop a ``ProcessPoolExecutor`` now: cancel its queued tasks and end its running workers.

    ``shutdown(cancel_futures=True)`` alone lets each running task finish (minutes for an
    experiment), so the worker processes are sent SIGTERM, then SIGKILL after ``timeout_s``.
    """
    procs = list((getattr(pool, "_processes", None) or {}).values())
    for p in procs:
        try:
            p.terminate()
        except (OSError, ValueError, AttributeError):
            pass
    pool.shutdown(wait=False, cancel_futures=True)
    for p in procs:
        try:
            p.join(timeout_s)
            if p.is_alive():
                p.kill()
                p.join(timeout_s)
        except (OSError, ValueError, AttributeError, AssertionError):
            pass


_STOP = {"installed": False, "deferring": 0, "pending": [], "stopping": []}


def _stop_exception(signum: int) -> KeyboardInterrupt:
    return Terminated() if signum == signal.SIGTERM else KeyboardInterrupt()


def _on_stop_signal(signum, _frame):
    if _STOP["stopping"] or _STOP["pending"]:
        return                          # the clean-up of the first signal is running: let it finish
    if _STOP["deferring"]:
        _STOP["pending"].append(signum)
        return
    _STOP["stopping"].append(signum)
    raise _stop_exception(signum)


@contextlib.contextmanager
def stop_signals():
    """SIGINT and SIGTERM raise :class:`KeyboardInterrupt` / :class:`~nanosim.validation.Terminated`, once.

    The first signal starts the clean-up that Ctrl-C runs (workers stopped, the staging folder and
    the lock removed); a second one arriving during that clean-up is ignored so that it can finish.
    The previous handlers are restored on leaving. Outside the main thread: nothing changes.
    """
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    previous = {s: signal.signal(s, _on_stop_signal) for s in (signal.SIGINT, signal.SIGTERM)}
    _STOP.update(installed=True, deferring=0, pending=[], stopping=[])
    try:
        yield
    finally:
        for s, h in previous.items():
            signal.signal(s, h if h is not None else signal.SIG_DFL)
        _STOP.update(installed=False, deferring=0, pending=[], stopping=[])


@contextlib.contextmanager
def stop_deferred():
    """Hold back SIGINT/SIGTERM (under :func:`stop_signals`) until the block has finished.

    For starting processes (a pool, a manager, a task that spawns a worker): the signal is raised
    when the block ends, where the caller's clean-up knows every process it started.
    """
    main = threading.current_thread() is threading.main_thread()
    if main:
        _STOP["deferring"] += 1
    try:
        yield
    finally:
        if main:
            _STOP["deferring"] -= 1
    if main and _STOP["deferring"] == 0 and _STOP["pending"]:
        signum = _STOP["pending"].pop()
        _STOP["pending"].clear()
        _STOP["stopping"].append(signum)
        raise _stop_exception(signum)
