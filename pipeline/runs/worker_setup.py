"""What every worker of a scheduler is given when a run connects to it."""

from __future__ import annotations

from typing import Any

from distributed.diagnostics.plugin import WorkerPlugin

from .. import urls

__all__ = ["StorageOptions"]


class StorageOptions(WorkerPlugin):
    """The job file's ``storage_options``, applied in every worker process
    (now and when a worker joins later)."""

    name = "terrain-storage-options"

    def __init__(self, options: dict[str, Any]) -> None:
        self.options = dict(options)

    def setup(self, worker) -> None:
        urls.use_storage_options(self.options)
