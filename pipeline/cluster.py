"""The run's Dask cluster: a scheduler's workers, or this process's threads;
tasks mapped over it with a progress bar.

Tasks cross to workers as small picklable jobs (paths, URLs and a
:class:`~pipeline.scratch.Scratch` root, never open files).  Workers of a
scheduler may share no disk with this machine: they read inputs, the work
folder and the store by URL, with the credentials of their own environment,
or those of the job file's ``storage_options``, which :func:`connect` hands to
every worker (:class:`pipeline.worker_setup.StorageOptions`), over the scheduler's connection (TLS
on a cluster that spans machines).
"""

from __future__ import annotations

import os
import sys
import time
from collections.abc import Callable
from typing import Any

from . import urls
from .config import RunConfig
from .errors import PipelineError

__all__ = ["Progress", "close", "connect", "map_tasks"]


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
    """A Dask client: the given scheduler, or an in-process cluster of threads."""
    import dask
    from distributed import Client, LocalCluster

    address = config.scheduler_address
    if address:
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
    threads = config.workers or os.cpu_count() or 1
    # the worker's statistical profiler walks every thread's stack 100 times a
    # second for the dashboard's profile page: 1% of a run's wall time, for a
    # page nobody opens on an in-process cluster
    with dask.config.set({"distributed.worker.profile.enabled": False}):
        cluster = LocalCluster(
            n_workers=1, threads_per_worker=threads, processes=False, dashboard_address=":0", memory_limit=0
        )
    return Client(cluster, set_as_default=False), cluster


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
) -> list:
    """``fn`` over ``items`` on the cluster; ``finished(item, result)`` runs here
    as each task ends (to record it), before the next result is taken."""
    from distributed import as_completed

    results: list[Any] = [None] * len(items)
    if not items:
        return results
    futures = client.map(fn, items, pure=False)
    index = {f.key: i for i, f in enumerate(futures)}
    for future in as_completed(futures, loop=client.loop):
        result = future.result()
        i = index[future.key]
        results[i] = result
        if finished is not None:
            finished(items[i], result)
        progress.update(points(result))
    return results
