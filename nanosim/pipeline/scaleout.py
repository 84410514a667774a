"""Where independent tasks run: in this process, a local process pool, or a Dask cluster.

:func:`open_executor` gives a ``concurrent.futures``-style executor and a
progress channel for the three cases:

* ``scheduler=None``: a :class:`~concurrent.futures.ProcessPoolExecutor` with
  one worker per CPU (``workers=1``: in this process, no pool);
* ``scheduler="local"``: a Dask ``LocalCluster`` on 127.0.0.1 sized to the
  machine (one single-threaded worker process per CPU);
* ``scheduler="tcp://HOST:8786"``: an existing Dask scheduler (start one with
  ``dask scheduler`` and ``dask worker``, dask-jobqueue on Slurm/PBS, or the
  Dask Kubernetes operator; see the README).

The same task functions run unchanged on all of them (module-level functions
with plain data in and JSON-ready data out). Tasks report progress by putting
integers on the channel they are given (a manager queue locally, a
``distributed.Queue`` on Dask); :func:`run_tasks` adds them to one progress
bar, so the ETA covers every worker.
"""
from __future__ import annotations

import contextlib
import multiprocessing
import os
import queue
import sys
import time
import uuid
from concurrent.futures import FIRST_COMPLETED, Future, ProcessPoolExecutor, wait
from dataclasses import dataclass
from typing import Any, Callable, Iterable

from nanosim.pipeline.workers import (start_manager, stop_deferred, stop_manager, terminate_executor,
                                     worker_init)

__all__ = ["ScaleOut", "open_executor", "run_tasks", "cpu_workers", "check_scheduler"]


def cpu_workers() -> int:
    """CPUs this process may use."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:      # pragma: no cover -- not Linux
        return max(1, os.cpu_count() or 1)


def check_scheduler(scheduler: str | None) -> str | None:
    """``None``, ``"local"`` or a Dask address ``PROTOCOL://HOST:PORT``; ``ValueError`` naming ``--scheduler``.

    Checks the form only (before any work); whether a scheduler answers there is known only by
    connecting (:func:`open_executor`).
    """
    if scheduler is None or scheduler == "local":
        return scheduler
    from urllib.parse import urlsplit

    expected = (f"--scheduler: expected 'local' or an address tcp://HOST:PORT (e.g. tcp://10.0.0.5:8786), "
                f"got {scheduler!r}")
    if not isinstance(scheduler, str) or "://" not in scheduler:
        raise ValueError(expected)
    try:
        url = urlsplit(scheduler)
        port = url.port
    except ValueError:
        raise ValueError(expected) from None
    if not url.scheme.isalnum() or not url.hostname or port is None or not 0 < port < 65536 \
            or url.path not in ("", "/") or url.query or url.fragment:
        raise ValueError(expected)
    return scheduler


class _InlineExecutor:
    """Runs each task at submit time in this process (one worker, no pickling)."""

    def submit(self, fn, *args, **kwargs) -> Future:
        fut: Future = Future()
        try:
            fut.set_result(fn(*args, **kwargs))
        except BaseException as exc:      # noqa: BLE001 -- delivered through the future
            if isinstance(exc, KeyboardInterrupt):
                raise
            fut.set_exception(exc)
        return fut

    def shutdown(self, wait: bool = True, cancel_futures: bool = False) -> None:
        return None


class _DaskChannel:
    """Progress channel on a ``distributed.Queue`` (picklable; workers reconnect to it)."""

    def __init__(self, client):
        from distributed import Queue

        self._q = Queue(f"nanosim-progress-{uuid.uuid4().hex}", client=client)

    @property
    def sink(self):
        return self._q

    def drain(self) -> int:
        total = 0
        with contextlib.suppress(Exception):
            n = self._q.qsize()
            if n:
                items = self._q.get(batch=n)
                total = sum(int(x) for x in items)
        return total


class _QueueChannel:
    """Progress channel on a local queue (a manager proxy for worker processes)."""

    def __init__(self, q):
        self._q = q

    @property
    def sink(self):
        return self._q

    def drain(self) -> int:
        total = 0
        while True:
            try:
                total += int(self._q.get_nowait())
            except (queue.Empty, EOFError, OSError):
                return total


class _BarSink:
    """Progress sink of in-process tasks: updates the bar directly."""

    def __init__(self, bar):
        self._bar = bar

    def put(self, n) -> None:
        self._bar.update(int(n))


@dataclass
class ScaleOut:
    """An open executor.

    Attributes
    ----------
    executor : object
        ``submit(fn, *args) -> concurrent.futures.Future``.
    channel : object
        Progress channel: ``sink`` (pass it to tasks; they call ``sink.put(n)``) and ``drain()``.
    description : str
        Where the tasks run (for logs and the run record).
    workers : int
        Number of workers.
    """

    executor: Any
    channel: Any
    description: str
    workers: int


@contextlib.contextmanager
def open_executor(scheduler: str | None = None, workers: int | None = None):
    """Open an executor (see the module docstring); yields a :class:`ScaleOut`.

    Parameters
    ----------
    scheduler : None, "local" or "tcp://HOST:PORT"
    workers : int, optional
        Worker processes for the local pool or the LocalCluster (default: CPUs).
    """
    n = int(workers) if workers else cpu_workers()
    if n < 1:
        raise ValueError(f"workers: expected a positive integer, got {workers!r}")
    if scheduler is None:
        if n == 1:
            yield ScaleOut(_InlineExecutor(), _QueueChannel(queue.Queue()), "this process", 1)
            return
        ctx = multiprocessing.get_context("spawn")
        # workers and the manager ignore SIGINT and leave when this process dies (nanosim.pipeline.workers)
        with start_manager(ctx) as manager, ProcessPoolExecutor(max_workers=n, mp_context=ctx,
                                                                initializer=worker_init) as pool:
            try:
                yield ScaleOut(pool, _QueueChannel(manager.Queue()), f"local process pool ({n} workers)", n)
            except BaseException:
                terminate_executor(pool)        # Ctrl-C, SIGTERM or a failed task: the running tasks too
                stop_manager(manager)
                raise
        return
    check_scheduler(scheduler)
    try:
        from distributed import Client, LocalCluster
    except ImportError:       # pragma: no cover -- dask[distributed] is a dependency
        raise ValueError("--scheduler: needs dask[distributed] (pip install 'dask[distributed]')") from None
    cluster = None
    try:
        if scheduler == "local":
            cluster = LocalCluster(n_workers=n, threads_per_worker=1, processes=True, host="127.0.0.1",
                                   dashboard_address=None)
            client = Client(cluster)
            where = f"Dask LocalCluster on 127.0.0.1 ({n} workers)"
        else:
            try:
                client = Client(scheduler, timeout=10)
            except (OSError, TimeoutError) as exc:
                raise ValueError(f"--scheduler: cannot reach the Dask scheduler at {scheduler} ({exc})") from None
            except ValueError as exc:           # an address distributed cannot parse or a protocol it lacks
                raise ValueError(f"--scheduler: cannot use the address {scheduler!r} ({exc})") from None
            n = max(1, len(client.scheduler_info().get("workers", {})))
            where = f"Dask scheduler {scheduler} ({n} workers)"
        executor = client.get_executor(pure=False)
        try:
            yield ScaleOut(executor, _DaskChannel(client), where, n)
        except BaseException:
            with contextlib.suppress(Exception):        # Ctrl-C, SIGTERM, a failed task: cancel on the cluster
                executor.shutdown(wait=False)
            raise
        finally:
            client.close()
    finally:
        if cluster is not None:
            cluster.close()


def run_tasks(scale: ScaleOut, fn: Callable, tasks: Iterable[tuple], on_result: Callable[[tuple, Any], None], *,
              total_units: int, desc: str, progress: bool = True, done_units: int = 0) -> None:
    """Submit ``fn(*task, sink)`` for every task; call ``on_result(task, result)`` as each finishes.

    Tasks report progress units with ``sink.put(n)``; the bar shows them across all workers.
    A task's failure propagates after the results that finished before it were handled.
    """
    bar = None
    if progress:
        from tqdm import tqdm
        bar = tqdm(total=total_units, initial=done_units, desc=desc, unit="step", file=sys.stderr,
                   smoothing=0.05, dynamic_ncols=True)
    sink = scale.channel.sink
    if isinstance(scale.executor, _InlineExecutor) and bar is not None:
        sink = _BarSink(bar)                # tasks run inside submit: update the bar as they report
    futures = {}
    try:
        inline = isinstance(scale.executor, _InlineExecutor)
        for task in tasks:
            with contextlib.nullcontext() if inline else stop_deferred():   # a local pool starts a worker in submit
                futures[scale.executor.submit(fn, *task, sink)] = task
        pending = set(futures)
        while pending:
            done, pending = wait(pending, timeout=0.5, return_when=FIRST_COMPLETED)
            got = scale.channel.drain()
            if bar is not None and got:
                bar.update(got)
            for fut in done:
                on_result(futures[fut], fut.result())
        if bar is not None:
            time.sleep(0.05)
            bar.update(scale.channel.drain())
    except BaseException:
        for fut in futures:
            fut.cancel()
        raise
    finally:
        if bar is not None:
            bar.close()
