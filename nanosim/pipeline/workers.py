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
"""
from __future__ import annotations

import os
import signal
import threading

__all__ = ["ORPHAN_EXIT_CODE", "PARENT_POLL_S", "worker_init", "watch_parent", "start_manager",
           "terminate_executor"]

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
    manager.start(initializer=worker_init)
    return manager


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
