"""Logging for the command line: plain lines for people, JSON lines for schedulers."""

from __future__ import annotations

import json
import logging
import os
import sys
import time
from typing import Any

__all__ = ["LOGGER", "configure", "JsonFormatter"]

LOGGER = logging.getLogger("terrain")


class JsonFormatter(logging.Formatter):
    """One JSON object per record: time (UTC, ISO 8601), level, message, and any
    ``extra={"data": {...}}`` fields."""

    def format(self, record: logging.LogRecord) -> str:
        out: dict[str, Any] = {
            "time": time.strftime("%Y-%m-%dT%H:%M:%S", time.gmtime(record.created)) + f".{int(record.msecs):03d}Z",
            "level": record.levelname.lower(),
            "logger": record.name,
            "message": record.getMessage(),
        }
        data = getattr(record, "data", None)
        if isinstance(data, dict):
            out.update(data)
        if record.exc_info:
            out["traceback"] = self.formatException(record.exc_info)
        return json.dumps(out, default=str)


def configure(verbosity: int = 0, as_json: bool = False) -> None:
    """Send the ``terrain`` log to stderr: -1 errors only, 0 progress messages,
    1 debug details (and Dask's own messages)."""
    handler = logging.StreamHandler(sys.stderr)
    handler.setFormatter(JsonFormatter() if as_json else logging.Formatter("%(message)s"))
    LOGGER.handlers[:] = [handler]
    LOGGER.propagate = False
    LOGGER.setLevel({-1: logging.ERROR, 0: logging.INFO}.get(verbosity, logging.DEBUG))
    # Dask's cluster chatter, asyncio's notes about futures left behind at
    # shutdown and laspy's own reports of the errors we report: only with -v
    quiet = logging.WARNING if verbosity > 0 else logging.CRITICAL
    for name in ("distributed", "asyncio", "tornado", "laspy"):
        logging.getLogger(name).setLevel(quiet)
    # distributed sets its loggers' levels from the Dask config when imported
    level = logging.getLevelName(quiet).lower()
    if "dask" in sys.modules:
        import dask

        dask.config.set({"logging.distributed": level})
    else:
        os.environ["DASK_LOGGING__DISTRIBUTED"] = level
