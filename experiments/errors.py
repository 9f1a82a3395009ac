"""The errors of the experiments: one root, each also the builtin that fits."""

from __future__ import annotations

__all__ = ["ExperimentError", "ExperimentParameterError", "ExperimentOutputError"]


class ExperimentError(Exception):
    """Root of the errors an experiment raises on purpose."""


class ExperimentParameterError(ExperimentError, ValueError):
    """A parameter of an experiment is out of its range."""


class ExperimentOutputError(ExperimentError, OSError):
    """The experiment's output folder cannot be made."""
