"""The error hierarchy of the pipeline: every error raised on purpose is a ``PipelineError``."""

from __future__ import annotations

__all__ = ["PipelineError", "UsageError"]


class PipelineError(Exception):
    """Root of all errors raised by the pipeline."""


class UsageError(PipelineError, ValueError):
    """A command-line argument or parameter is invalid."""
