"""The error hierarchy of meshcore: every error raised on purpose is a ``MeshError``."""

from __future__ import annotations

__all__ = ["MeshError", "InvalidInputError", "InvalidMeshError"]


class MeshError(Exception):
    """Root of all errors raised by meshcore."""


class InvalidInputError(MeshError, ValueError):
    """An argument has the wrong shape, type, value or option name."""


class InvalidMeshError(MeshError, ValueError):
    """A mesh breaks one of the structural rules checked by :func:`meshcore.validate`."""
