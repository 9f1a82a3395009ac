"""What the header of one LAS/LAZ file says: :class:`SourceInfo`, the record that
:mod:`pipeline.inputs.sources` reads and :mod:`pipeline.inputs.crs` plans from.

It is a module of its own so that the CRS plan can take headers without
importing the readers, which use the CRS helpers (no circle between them).
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np
import pyproj

from ..urls import Location, as_location

__all__ = ["SourceInfo"]


@dataclass(frozen=True)
class SourceInfo:
    """What the header and VLRs of one LAS/LAZ file say (no point is read).

    Parameters
    ----------
    path
        The file (a URL for a remote object).
    size_bytes
        File size in bytes.
    version
        LAS version, e.g. ``"1.4"``.
    point_format
        Point data record format, 0-10.
    point_count
        Number of points announced by the header.
    bounds
        ``(minx, miny, minz, maxx, maxy, maxz)`` from the header, in file units.
    scales, offsets
        Per-axis scale and offset turning stored integers into coordinates.
    crs_wkt
        The file's CRS as WKT2 (pyproj), or None when absent or unusable.
    crs_problem
        Why a CRS record present in the file could not be used
        (e.g. ``"WKT record present but unparsable: \\"''\\""``), else None.
    has_extra_bytes
        Whether point records carry extra-bytes dimensions.
    is_copc
        Whether the file is a Cloud Optimized Point Cloud (read as plain LAZ).
    compressed
        Whether the points are LAZ-compressed.
    z_unit
        Unit of z when the file declares one (vertical CRS or GeoTIFF
        VerticalUnitsGeoKey), else None.
    extra_dims
        ``(name, dtype)`` of each extra-bytes dimension, e.g. ``("Deviation", "uint16")``.
    notes
        Non-fatal oddities found in the header (unread VLRs, disagreeing CRS
        records, short point data, ...).
    """

    path: Location
    size_bytes: int
    version: str
    point_format: int
    point_count: int
    bounds: tuple[float, float, float, float, float, float]
    scales: tuple[float, float, float]
    offsets: tuple[float, float, float]
    crs_wkt: str | None
    crs_problem: str | None
    has_extra_bytes: bool
    is_copc: bool
    compressed: bool = False
    z_unit: str | None = None
    extra_dims: tuple[tuple[str, str], ...] = ()
    notes: tuple[str, ...] = ()

    @property
    def bounds_usable(self) -> bool:
        """Whether the header's bounds can place the file: finite, min <= max,
        with a finite span, and not all zero (never filled in) when it
        announces points."""
        b = self.bounds
        if not all(np.isfinite(b)) or b[0] > b[3] or b[1] > b[4] or b[2] > b[5]:
            return False
        if not all(math.isfinite(b[k + 3] - b[k]) for k in range(3)):  # a span past the largest float
            return False
        return self.point_count == 0 or any(v != 0 for v in b)

    def crs(self) -> pyproj.CRS | None:
        """The CRS as a pyproj object, or None."""
        return None if self.crs_wkt is None else pyproj.CRS.from_wkt(self.crs_wkt)

    def to_dict(self) -> dict[str, Any]:
        """A JSON-ready dictionary (inverse of :meth:`from_dict`)."""
        return {
            "path": str(self.path),
            "size_bytes": self.size_bytes,
            "version": self.version,
            "point_format": self.point_format,
            "point_count": self.point_count,
            "bounds": list(self.bounds),
            "scales": list(self.scales),
            "offsets": list(self.offsets),
            "crs_wkt": self.crs_wkt,
            "crs_problem": self.crs_problem,
            "has_extra_bytes": self.has_extra_bytes,
            "is_copc": self.is_copc,
            "compressed": self.compressed,
            "z_unit": self.z_unit,
            "extra_dims": [{"name": n, "dtype": t} for n, t in self.extra_dims],
            "notes": list(self.notes),
        }

    @classmethod
    def from_dict(cls, data: Mapping[str, Any]) -> SourceInfo:
        """Rebuild from :meth:`to_dict` output."""
        return cls(
            path=as_location(data["path"]),
            size_bytes=int(data["size_bytes"]),
            version=str(data["version"]),
            point_format=int(data["point_format"]),
            point_count=int(data["point_count"]),
            bounds=tuple(float(v) for v in data["bounds"]),  # type: ignore[arg-type]
            scales=tuple(float(v) for v in data["scales"]),  # type: ignore[arg-type]
            offsets=tuple(float(v) for v in data["offsets"]),  # type: ignore[arg-type]
            crs_wkt=data.get("crs_wkt"),
            crs_problem=data.get("crs_problem"),
            has_extra_bytes=bool(data["has_extra_bytes"]),
            is_copc=bool(data["is_copc"]),
            compressed=bool(data.get("compressed", False)),
            z_unit=data.get("z_unit"),
            extra_dims=tuple((d["name"], d["dtype"]) for d in data.get("extra_dims", ())),
            notes=tuple(data.get("notes", ())),
        )
