"""What ``terrain info FILE...`` prints: a summary of each LAS/LAZ input.

:func:`info_json` gives one JSON-ready dictionary per file, :func:`info_report`
the same as readable text. Both read the header, then stream the
classification field once to count classes.

Examples
--------
>>> class_name(2), class_name(8, "1.2"), class_name(8, "1.4"), class_name(70)
('ground', 'model key-point', 'reserved', 'user-defined')
"""

from __future__ import annotations

import math
import os
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import pyproj

from ..inputs.crs import contradiction, crs_label
from ..errors import InputFileError
from ..inputs.header import SourceInfo
from ..inputs.sources import class_counts, discover_inputs, read_info

__all__ = ["class_name", "info_json", "info_report"]

# ASPRS standard point classes (LAS 1.4 R15, table 17).
_CLASS_NAMES = {
    0: "never classified",
    1: "unassigned",
    2: "ground",
    3: "low vegetation",
    4: "medium vegetation",
    5: "high vegetation",
    6: "building",
    7: "low point (noise)",
    8: "reserved",
    9: "water",
    10: "rail",
    11: "road surface",
    12: "reserved",
    13: "wire guard (shield)",
    14: "wire conductor (phase)",
    15: "transmission tower",
    16: "wire-structure connector",
    17: "bridge deck",
    18: "high noise",
    19: "overhead structure",
    20: "ignored ground",
    21: "snow",
    22: "temporal exclusion",
}
_CLASS_NAMES_BEFORE_1_4 = {8: "model key-point", 12: "overlap"}

Inputs = Sequence[str | os.PathLike[str]]


def class_name(code: int, version: str = "1.4") -> str:
    """The ASPRS name of a classification code for a LAS version."""
    if version < "1.4" and code in _CLASS_NAMES_BEFORE_1_4:
        return _CLASS_NAMES_BEFORE_1_4[code]
    if code in _CLASS_NAMES:
        return _CLASS_NAMES[code]
    return "user-defined" if code >= 64 else "reserved"


def info_json(inputs: Inputs, *, keep_going: bool = False) -> list[dict[str, Any]]:
    """One JSON-ready dictionary per input file.

    Parameters
    ----------
    inputs
        Files, directories or glob patterns (see :func:`pipeline.inputs.sources.discover_inputs`).
    keep_going
        When True, a file that cannot be read gives ``{"path": ..., "error": message}``
        and the other files are still reported; when False its
        :class:`~pipeline.errors.InputFileError` is raised.

    Returns
    -------
    list of dict
        :meth:`SourceInfo.to_dict` plus ``crs_name``, ``crs_epsg``,
        ``horizontal_unit``, ``crs_contradiction`` (why the header's bounds
        cannot be coordinates of the CRS record, as a run says it; None when
        they can), ``classes`` (``[{"code", "name", "count"}]``) and
        ``error`` (None).
    """
    entries = []
    for path in discover_inputs(inputs):
        try:
            entries.append(_entry(path))
        except InputFileError as exc:
            if not keep_going:
                raise
            entries.append({"path": str(path), "error": str(exc)})
    return entries


def info_report(inputs: Inputs, *, keep_going: bool = False) -> str:
    """Readable summary of each input file: what ``terrain info`` prints.

    Per file: path, size, LAS version, point format, point count, classes
    with counts, bounds, CRS name and EPSG code (or why there is none), and
    extra-bytes dimensions. Parameters as for :func:`info_json`.
    """
    blocks = [_format(entry) for entry in info_json(inputs, keep_going=keep_going)]
    return "\n\n".join(blocks) + "\n"


def _entry(path: Path) -> dict[str, Any]:
    info = read_info(path)
    counts = class_counts(path)
    entry = info.to_dict()
    entry.update(_crs_summary(info))
    entry["classes"] = [
        {"code": code, "name": class_name(code, info.version), "count": count} for code, count in counts.items()
    ]
    entry["error"] = None
    return entry


def _crs_summary(info: SourceInfo) -> dict[str, Any]:
    crs = info.crs()
    if crs is None:
        return {"crs_name": None, "crs_epsg": None, "crs_kind": None, "horizontal_unit": None,
                "crs_contradiction": None}
    horizontal = crs.sub_crs_list[0] if crs.is_compound and crs.sub_crs_list else crs
    axes = horizontal.axis_info
    # a record the header's bounds cannot be coordinates of (what a run refuses, naming override_crs)
    against = contradiction(crs, info.bounds) if info.point_count and info.bounds_usable else None
    return {
        "crs_name": crs.name,
        "crs_epsg": crs.to_epsg(),
        "crs_kind": crs.type_name,
        "horizontal_unit": axes[0].unit_name if axes else None,
        "crs_contradiction": None if against is None else against[0],
    }


def _decimals(scale: float) -> int:
    if not math.isfinite(scale) or scale <= 0:
        return 3
    return min(9, max(0, math.ceil(-math.log10(scale) - 1e-9)))


def _size(n: int) -> str:
    for unit, factor in (("GiB", 2**30), ("MiB", 2**20), ("KiB", 2**10)):
        if n >= factor:
            return f"{n / factor:.1f} {unit} ({n:,} bytes)"
    return f"{n:,} bytes"


def _format(entry: dict[str, Any]) -> str:
    if entry.get("error"):
        return f"{entry['path']}\n  error        {entry['error'].removeprefix(entry['path'] + ': ')}"
    lines = [str(entry["path"])]

    def row(label: str, text: str) -> None:
        lines.append(f"  {label:<13}{text}")

    row("size", _size(entry["size_bytes"]))
    kind = "COPC (read as LAZ)" if entry["is_copc"] else ("LAZ" if entry["compressed"] else "uncompressed")
    row("LAS", f"{entry['version']}, point format {entry['point_format']}, {kind}")
    row("points", f"{entry['point_count']:,}")
    classes = entry["classes"]
    if not classes:
        row("classes", "none")
    for i, c in enumerate(classes):
        row("classes" if i == 0 else "", f"{c['code']:>3} {c['name']:<26}{c['count']:>12,}")
    minx, miny, minz, maxx, maxy, maxz = entry["bounds"]
    for i, (axis, lo, hi, scale) in enumerate(zip("xyz", (minx, miny, minz), (maxx, maxy, maxz), entry["scales"])):
        d = _decimals(scale)
        row("bounds" if i == 0 else "", f"{axis} {lo:.{d}f} .. {hi:.{d}f}  (extent {hi - lo:.{d}f})")
    row("CRS", _crs_text(entry))
    if entry.get("crs_contradiction"):
        row("", f"wrong? it {entry['crs_contradiction']}; give --override-crs the CRS the coordinates are in")
    dims = entry["extra_dims"]
    row("extra bytes", ", ".join(f"{d['name']} ({d['dtype']})" for d in dims) if dims else "none")
    for i, note in enumerate(entry["notes"]):
        row("notes" if i == 0 else "", f"- {note}")
    return "\n".join(lines)


def _crs_text(entry: dict[str, Any]) -> str:
    if entry["crs_name"] is None:
        return f"none usable: {entry['crs_problem']}" if entry["crs_problem"] else "none"
    crs = pyproj.CRS.from_wkt(entry["crs_wkt"])
    label = crs_label(crs) if entry["crs_epsg"] else f"{crs.name} (no EPSG code)"
    parts = [label, entry["crs_kind"], f"x/y in {entry['horizontal_unit']}"]
    if entry["z_unit"]:
        parts.append(f"z in {entry['z_unit']}")
    return ", ".join(parts)
