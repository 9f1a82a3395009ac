"""The run's Dask cluster: a scheduler's workers, or this process's threads;
tasks mapped over it with a progress bar.

Tasks cross to workers as small picklable jobs (paths, URLs and a
:class:`~pipeline.tiling.scratch.Scratch` root, never open files).  Workers of a
scheduler may share no disk with this machine: they read inputs, the work
folder and the store by URL, with the credentials of their own environment,
or those of the job file's ``storage_options``, which :func:`connect` hands to
every worker (:class:`pipeline.runs.worker_setup.StorageOptions`), over the scheduler's connection (TLS
on a cluster that spans machines).

Without a scheduler the tasks run on a pool of this process's threads
(:class:`LocalThreads`): the kernels release the GIL, and an in-process Dask
cluster would add nothing but its start-up (a third of a second, and as much
again to import it) to a one-file job.
"""

from __future__ import annotations

import os
import queue
import sys
import threading
import time
from collections.abc import Callable, Collection, Mapping
from concurrent.futures import FIRST_COMPLETED, Future
from concurrent.futures import wait as wait_futures
from typing import Any

from .. import urls
from ..config import RunConfig
from ..errors import PipelineError

__all__ = ["Progress", "LocalThreads", "close", "connect", "map_tasks"]


class LocalThreads:
    """A pool of this process's threads that runs a run's tasks.

    Its threads are daemons: an interrupted run exits without waiting for the
    tasks still running (their work is redone when the run resumes).
    """

    def __init__(self, threads: int):
        self._tasks: queue.SimpleQueue = queue.SimpleQueue()
        self._pending: set[Future] = set()
        self._lock = threading.Lock()
        self._threads = [
            threading.Thread(target=self._work, name=f"terrain-{k}", daemon=True) for k in range(max(1, threads))
        ]
        for t in self._threads:
            t.start()

    @property
    def threads(self) -> int:
        return len(self._threads)

    def submit(self, fn: Callable, item: Any) -> Future:
        future: Future = Future()
        with self._lock:
            self._pending.add(future)
        self._tasks.put((future, fn, item))
        return future

    def _work(self) -> None:
        while True:
            task = self._tasks.get()
            if task is None:
                return
            future, fn, item = task
            if future.set_running_or_notify_cancel():
                try:
                    future.set_result(fn(item))
                except BaseException as exc:  # handed to the caller, as a worker would
                    future.set_exception(exc)
            with self._lock:
                self._pending.discard(future)

    def cancel_pending(self) -> None:
        """Cancel the tasks not yet started (those running finish)."""
        with self._lock:
            for future in list(self._pending):
                future.cancel()

    def wait_running(self) -> None:
        """Until the tasks running now have ended: a run that failed leaves no
        task writing behind it, which a run started next in this process (a
        resume) would race with."""
        with self._lock:
            running = list(self._pending)
        wait_futures(running)

    def close(self) -> None:
        self.cancel_pending()
        for _ in self._threads:
            self._tasks.put(None)


class Progress:
    """A one-line progress bar on stderr (only when it is a terminal or forced)."""

    def __init__(self, label: str, total: int, enabled: bool):
        self.label = label
        self.total = total
        self.enabled = enabled
        self.done = 0
        self.points = 0
        self.start = time.perf_counter()

    def update(self, points: int = 0) -> None:
        self.done += 1
        self.points += points
        if not self.enabled:
            return
        elapsed = max(time.perf_counter() - self.start, 1e-9)
        width = 30
        filled = int(width * self.done / max(self.total, 1))
        rate = f", {self.points / elapsed / 1e6:.2f} M points/s" if self.points else ""
        sys.stderr.write(
            f"\r{self.label:<6} [{'#' * filled}{'.' * (width - filled)}] {self.done}/{self.total}{rate}"
        )
        if self.done == self.total:
            sys.stderr.write("\n")
        sys.stderr.flush()


def connect(config: RunConfig):
    """The run's cluster: a Dask client of the given scheduler, or a pool of
    this process's threads (:class:`LocalThreads`); and what :func:`close`
    needs besides it."""
    address = config.scheduler_address
    if not address:
        return LocalThreads(config.workers or os.cpu_count() or 1), None
    from distributed import Client

    try:
        # not the process's default client: a caller's own, and its dask config, stay as they were
        client = Client(address, timeout="10s", set_as_default=False)
    except OSError as exc:
        raise PipelineError(f"cannot reach the Dask scheduler at {address}: {exc}") from None
    options = urls.storage_options()
    if options:  # the job file's credentials, for workers that read and write URLs
        from .worker_setup import StorageOptions

        client.register_plugin(StorageOptions(options), name=StorageOptions.name)
    return client, None


def close(client, cluster) -> None:
    client.close()
    if cluster is not None:
        cluster.close()


def map_tasks(
    client,
    fn: Callable,
    items: list,
    progress: Progress,
    points: Callable[[Any], int],
    finished: Callable[[Any, Any], None] | None = None,
    after: Mapping[int, Collection[int]] | None = None,
) -> list:
    """``fn`` over ``items`` on the cluster; ``finished(item, result)`` runs here
    as each task ends (to record it), before the next result is taken.

    ``after[i]``: the items (by index) whose tasks must end before item ``i``'s
    starts; it is submitted as the last of them ends, so the others keep the
    cores busy meanwhile (no barrier between sets of tasks)."""
    results: list[Any] = [None] * len(items)
    if not items:
        return results
    waiting = {i: set(before) for i, before in (after or {}).items() if before}
    released: dict[int, list[int]] = {}
    for i, before in waiting.items():
        for j in before:
            released.setdefault(j, []).append(i)

    def ready(i: int) -> list[int]:
        """The items that item ``i``'s end lets start."""
        out = []
        for k in released.get(i, ()):
            waiting[k].discard(i)
            if not waiting[k]:
                out.append(k)
        return out

    first = [i for i in range(len(items)) if i not in waiting]
    if isinstance(client, LocalThreads):
        running = {client.submit(fn, items[i]): i for i in first}
        try:
            while running:
                ended, _ = wait_futures(running, return_when=FIRST_COMPLETED)
                for future in ended:
                    i = running.pop(future)
                    _take(future.result(), i, items, results, finished, progress, points)
                    running.update((client.submit(fn, items[k]), k) for k in ready(i))
        except BaseException as exc:
            client.cancel_pending()  # a failed task ends the stage, as on a cluster
            if not isinstance(exc, KeyboardInterrupt):  # (an interrupt exits at once)
                client.wait_running()
            raise
        return results
    from distributed import as_completed as as_completed_on_cluster

    futures = client.map(fn, [items[i] for i in first], pure=False)
    index = {f.key: i for i, f in zip(first, futures)}
    pending = as_completed_on_cluster(futures, loop=client.loop)
    del futures
    for future in pending:
        key, result = future.key, future.result()
        # let go of a task once its result is here: a result lives on the worker that made it, and
        # while the future is held, losing that worker runs the task again, whose files (a route's
        # spills, a tile's piece) a later stage may be reading as it rewrites them
        future.release()
        del future
        i = index[key]
        _take(result, i, items, results, finished, progress, points)
        for k in ready(i):
            later = client.submit(fn, items[k], pure=False)
            index[later.key] = k
            pending.add(later)
            del later
    return results


def _take(result, i: int, items: list, results: list, finished, progress: Progress, points) -> None:
    results[i] = result
    if finished is not None:
        finished(items[i], result)
    progress.update(points(result))
