"""Coordinate reference systems: decide each file's CRS and the target CRS, and reproject.

:func:`resolve_crs` turns the files' CRS records plus the ``in_crs``,
``override_crs`` and ``out_crs`` parameters into a :class:`CrsPlan`: one
source CRS per file, one target CRS (projected: the mesh is built in linear
units), its horizontal unit, and notes for the run report. CRSs travel as WKT
strings so that the plan and its :class:`Reprojector` recipes pickle and
store as plain text.

Before anything is transformed, each file's header bounds are tested against
its CRS (:func:`contradiction`): degrees within 180 and 90, geocentric
coordinates near the ellipsoid's surface, projected ones near the CRS's area
of use.  A record that its file's coordinates contradict stops the run, with
``override_crs`` as the way out.

A note on heights: pyproj transforms z only when both the source and the
target CRS have a vertical component (compound or 3D CRSs). Between 2D CRSs
z passes through unchanged, keeping the files' vertical datum and unit.  Into
a target with a vertical component from files without one, z is converted to
the target's vertical unit (the unit only: the files name no datum to shift
from), so that the store's unit is the heights' own.  The plan also says how
a height compares with a horizontal distance (:attr:`CrsPlan.height_scale`),
which slopes need when the two units differ.

Examples
--------
>>> r = Reprojector("EPSG:4326", "EPSG:32631")   # any pyproj input, stored as WKT
>>> x, y, z = r.transform([3.0], [0.0], [10.0])
>>> round(float(x[0]), 3), round(float(y[0]), 3), float(z[0])
(500000.0, 0.0, 10.0)
>>> Reprojector("EPSG:2154", "EPSG:2154").is_identity
True
"""

from __future__ import annotations

import math
import threading
import warnings
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
import pyproj
from pyproj.exceptions import CRSError

from ..config import BOTH_CRS_OPTIONS
from ..errors import CrsError, UsageError, one_line
from ..urls import Location, as_location

if TYPE_CHECKING:
    from .header import SourceInfo

__all__ = [
    "AREA_TOLERANCE_KM", "SURFACE_TOLERANCE_KM", "CrsPlan", "Reprojector", "contradiction", "crs_label", "resolve_crs",
    "same_crs", "transform_bounds", "working_crs",
]

_MAX_LISTED = 5


# --------------------------------------------------------------------------- small helpers


def same_crs(a: pyproj.CRS, b: pyproj.CRS) -> bool:
    """Whether two CRSs are equivalent (names and axis order aside).

    Examples
    --------
    >>> same_crs(pyproj.CRS("EPSG:2154"), pyproj.CRS("EPSG:2154").to_wkt())
    True
    """
    return bool(pyproj.CRS.from_user_input(a).equals(pyproj.CRS.from_user_input(b), ignore_axis_order=True))


def crs_label(crs: pyproj.CRS) -> str:
    """``"name (EPSG:code)"``, or just the name when no EPSG code matches.

    Examples
    --------
    >>> crs_label(pyproj.CRS("EPSG:2154"))
    'RGF93 v1 / Lambert-93 (EPSG:2154)'
    """
    epsg = crs.to_epsg()
    return f"{crs.name} (EPSG:{epsg})" if epsg else crs.name


def _list_paths(paths: Sequence[Path | str]) -> str:
    names = [str(p) for p in paths[:_MAX_LISTED]]
    more = len(paths) - len(names)
    return ", ".join(names) + (f" and {more} more" if more > 0 else "")


def _unwrap(crs: pyproj.CRS) -> pyproj.CRS:
    while crs.is_bound and crs.source_crs is not None:
        crs = crs.source_crs
    return crs


def _horizontal(crs: pyproj.CRS) -> pyproj.CRS:
    crs = _unwrap(crs)
    if crs.is_compound and crs.sub_crs_list:
        return _unwrap(crs.sub_crs_list[0])
    return crs


def _has_vertical(crs: pyproj.CRS) -> bool:
    crs = _unwrap(crs)
    return bool(crs.is_compound or len(crs.axis_info) >= 3)


def _vertical_unit(crs: pyproj.CRS) -> str | None:
    crs = _unwrap(crs)
    if crs.is_compound and len(crs.sub_crs_list) > 1:
        axes = _unwrap(crs.sub_crs_list[1]).axis_info
        return axes[0].unit_name if axes else None
    if len(crs.axis_info) >= 3:
        return crs.axis_info[2].unit_name
    return None


def _horizontal_unit(crs: pyproj.CRS) -> str:
    axes = _horizontal(crs).axis_info
    return axes[0].unit_name if axes else "unknown"


def unit_metres(name: str | None) -> float | None:
    """Metres in one unit of length named as PROJ names it (``"US survey foot"``), or None if unknown."""
    from pyproj.database import get_units_map

    unit = get_units_map(category="linear").get(name) if name else None
    return None if unit is None else float(unit.conv_factor)


def cf_units(name: str | None) -> str | None:
    """A unit of length as CF writes it (``"metre"``, ``"0.3048 metre"``), or None if unknown."""
    metres = unit_metres(name)
    if metres is None:
        return None
    return "metre" if metres == 1.0 else f"{metres!r} metre"


def cf_metres(units: str) -> float | None:
    """Metres in a unit of length written by :func:`cf_units`, or None if it is not one."""
    words = units.split()
    if not words or words[-1] != "metre" or len(words) > 2:
        return None
    try:
        return float(words[0]) if len(words) == 2 else 1.0
    except ValueError:
        return None


def _user_crs(text: str, option: str) -> pyproj.CRS:
    if not isinstance(text, str) or not text.strip():
        raise CrsError(f"{option} must be a CRS such as 'EPSG:2154', a WKT or a PROJ string, got {text!r}")
    try:
        return _described(pyproj.CRS.from_user_input(text.strip()))
    except CRSError as exc:
        raise CrsError(f"{option}={text!r} is not a CRS pyproj understands ({one_line(exc)})") from exc


def _described(crs: pyproj.CRS) -> pyproj.CRS:
    """``crs``, once it is known that the store can describe it (CF grid
    mapping and axes); CRSError for one that parses but cannot be: a damaged
    record, such as a projection short of its parameters."""
    try:
        crs.to_cf()
        crs.cs_to_cf()
    except Exception as exc:  # noqa: BLE001 - pyproj raises KeyError, ValueError, ... on such records
        raise CRSError(f"its definition is incomplete ({type(exc).__name__}: {one_line(exc)})") from None
    return crs


class _CrsCache:
    """Parse each distinct WKT once."""

    def __init__(self) -> None:
        self._by_wkt: dict[str, pyproj.CRS] = {}

    def get(self, wkt: str) -> pyproj.CRS:
        """The CRS of ``wkt``; CRSError for one that does not parse, or that
        parses but cannot be described as the store describes it (a file's
        damaged record: a projection short of its parameters)."""
        crs = self._by_wkt.get(wkt)
        if crs is None:
            crs = self._by_wkt[wkt] = _described(pyproj.CRS.from_wkt(wkt))
        return crs


# --------------------------------------------------------------------------- plausibility

AREA_TOLERANCE_KM = 500.0
"""How far (km) a file's header bounds may lie outside the area of use of its
projected CRS.  Zones are used well beyond their bands: a UTM zone routinely
1-3 degrees past its 6 (up to 330 km), Denmark's UTM 32N on Bornholm (200 km
east of the band), Norway's UTM 33N over the whole country (Finnmark lies
nearly 500 km east of the band, the west coast 400 km west of it).  A
distance, not degrees, since a degree of longitude shrinks towards the poles
where those zones are stretched furthest.  Coordinates under a wrong record
land much farther: UTM 12N metres (Yellowstone) read as Lambert-93 lie 1,075
km south of France, and most wrong records give points the projection cannot
even take back to longitude and latitude."""

SURFACE_TOLERANCE_KM = 50.0
"""How far (km) geocentric coordinates may lie from the ellipsoid's surface:
every point a survey measures lies within 11 km of it (ocean trenches to the
highest peaks, the geoid within 110 m).  Projected or geographic coordinates
under a geocentric record lie thousands of km inside the earth."""

_KM_PER_DEGREE = 111.32
"""Kilometres in a degree of latitude, or of longitude on the equator (near enough for a tolerance)."""


def contradiction(crs: pyproj.CRS, bounds: Sequence[float]) -> tuple[str, bool] | None:
    """Why header ``bounds`` ``(minx, miny, minz, maxx, maxy, maxz)`` cannot be
    coordinates of ``crs``, or None when they can (or when it cannot be told).

    Bounds are contradicted when no part of them can hold coordinates of the
    CRS, so that a few stray points (named when they are transformed) or a
    stale header bound do not condemn a file.  The reason reads after the
    CRS's name (``"is in degrees, but ..."``); the flag says whether the
    coordinates are impossible (degrees wholly past 180 or 90, geocentric
    coordinates away from the earth's surface) rather than far from where the
    CRS is used (:data:`AREA_TOLERANCE_KM`), or beyond what its projection
    covers.

    Examples
    --------
    >>> utm_12n_metres = (515368.6, 4918340.4, 2322.9, 515401.0, 4918381.1, 2338.6)
    >>> contradiction(pyproj.CRS("EPSG:4326"), utm_12n_metres)[1]
    True
    >>> contradiction(pyproj.CRS("EPSG:32612"), utm_12n_metres) is None
    True
    """
    return _Domain(crs).contradiction(bounds)


class _Domain:
    """Where coordinates of one CRS can lie: what testing a file's bounds
    needs (a Transformer, the area of use) is built once, on first use."""

    def __init__(self, crs: pyproj.CRS) -> None:
        self.crs = _horizontal(crs)
        self._to_lonlat: pyproj.Transformer | None = None
        self._area: tuple[float, float, float, float] | None = None

    def contradiction(self, bounds: Sequence[float]) -> tuple[str, bool] | None:
        """See :func:`contradiction`."""
        if self.crs.is_geographic:
            return self._outside_degrees(bounds)
        if self.crs.is_geocentric:
            return self._off_the_surface(bounds)
        if self.crs.is_projected:
            return self._outside_area(bounds)
        return None

    def _unit(self) -> tuple[str, float]:
        """The axes' unit and its size in metres or radians."""
        axes = self.crs.axis_info
        return (axes[0].unit_name, axes[0].unit_conversion_factor) if axes else ("unknown", 1.0)

    def _outside_degrees(self, bounds: Sequence[float]) -> tuple[str, bool] | None:
        unit, radians = self._unit()
        minx, miny, _, maxx, maxy, _ = (math.degrees(v * radians) for v in bounds)
        if minx <= 180 and maxx >= -180 and miny <= 90 and maxy >= -90:
            return None  # a stray point beyond the pole is named when it is transformed
        return (
            f"is in {unit}s, but its {_bounds_text(bounds)} lie outside longitudes -180 to 180 and latitudes -90 to 90"
        ), True

    def _off_the_surface(self, bounds: Sequence[float]) -> tuple[str, bool] | None:
        ellipsoid = self.crs.ellipsoid
        if ellipsoid is None:
            return None
        metres = self._unit()[1]
        spans = [(bounds[k] * metres, bounds[k + 3] * metres) for k in range(3)]
        nearest = math.hypot(*(0.0 if lo <= 0.0 <= hi else min(abs(lo), abs(hi)) for lo, hi in spans))
        farthest = math.hypot(*(max(abs(lo), abs(hi)) for lo, hi in spans))
        off_km = max(nearest - ellipsoid.semi_major_metre, ellipsoid.semi_minor_metre - farthest) / 1000.0
        if off_km <= SURFACE_TOLERANCE_KM:
            return None
        return (
            f"is geocentric (earth-centred x, y, z), but its {_bounds_text(bounds, with_z=True)} lie "
            f"{off_km:,.0f} km or more from the surface of its ellipsoid ({ellipsoid.name})"
        ), True

    def _outside_area(self, bounds: Sequence[float]) -> tuple[str, bool] | None:
        minx, miny, _, maxx, maxy, _ = bounds
        try:
            if self._to_lonlat is None:
                self._to_lonlat = pyproj.Transformer.from_crs(self.crs, self.crs.geodetic_crs, always_xy=True)
                self._area = _area_of_use(self.crs)
            lonlat = self._to_lonlat.transform_bounds(minx, miny, maxx, maxy, densify_pts=21)
        except (CRSError, pyproj.exceptions.ProjError):
            return None  # no way to tell
        if not all(math.isfinite(v) for v in lonlat):
            return f"cannot hold its {_bounds_text(bounds)}: they lie beyond what its projection covers", False
        if self._area is None:
            return None
        off_km = _km_outside(self._area, lonlat)
        if off_km <= AREA_TOLERANCE_KM:
            return None
        west, south, east, north = self._area
        lon0, lat0, lon1, lat1 = lonlat
        return (
            f"is for lon {_degrees(west, east)}, lat {_degrees(south, north)}, but its {_bounds_text(bounds)} "
            f"lie at lon {_degrees(lon0, lon1)}, lat {_degrees(lat0, lat1)}, {off_km:,.0f} km outside that area"
        ), False


def _bounds_text(bounds: Sequence[float], with_z: bool = False) -> str:
    minx, miny, minz, maxx, maxy, maxz = bounds
    spans = [("x", minx, maxx), ("y", miny, maxy)] + ([("z", minz, maxz)] if with_z else [])
    return "header bounds (" + ", ".join(f"{a} {lo:,.10g} to {hi:,.10g}" for a, lo, hi in spans) + ")"


def _degrees(low: float, high: float) -> str:
    low_text, high_text = f"{low:.2f}", f"{high:.2f}"
    return low_text if low_text == high_text else f"{low_text} to {high_text}"


def _area_of_use(crs: pyproj.CRS) -> tuple[float, float, float, float] | None:
    """(west, south, east, north) in degrees: the CRS's own area of use, or
    that of the EPSG (or other authority's) CRS it matches (a file's WKT
    record seldom carries its area)."""
    area = crs.area_of_use
    if area is None:
        for match in crs.list_authority(min_confidence=70):
            try:
                area = pyproj.CRS.from_authority(match.auth_name, match.code).area_of_use
            except CRSError:
                continue
            if area is not None:
                break
    return None if area is None else area.bounds


def _km_outside(area: Sequence[float], box: Sequence[float]) -> float:
    """Roughly how far (km) the lon/lat ``box`` lies outside ``area`` (both
    west, south, east, north; east < west across the antimeridian); 0 where
    they meet.  A longitude gap is measured at the box's latitude farthest
    from the equator, where it is shortest."""
    west, south, east, north = area
    lon0, lat0, lon1, lat1 = box
    east += 360.0 if east < west else 0.0
    lon1 += 360.0 if lon1 < lon0 else 0.0
    dlat = max(south - lat1, lat0 - north, 0.0)
    dlon = min(max(west - (lon1 + k), (lon0 + k) - east, 0.0) for k in (-360.0, 0.0, 360.0))
    shrink = math.cos(math.radians(min(90.0, max(abs(lat0), abs(lat1)))))
    return _KM_PER_DEGREE * math.hypot(dlat, dlon * shrink)


# --------------------------------------------------------------------------- reprojection

_thread_state = threading.local()


def transform_bounds(source_wkt: str, target_wkt: str, box: tuple[float, float, float, float]) -> tuple[float, float, float, float]:
    """The box (xmin, ymin, xmax, ymax) of ``source_wkt`` as a box of
    ``target_wkt`` that holds it (its edges densified), by the calling
    thread's cached Transformer."""
    x0, y0, x1, y1 = _thread_transformer(source_wkt, target_wkt).transform_bounds(*box, densify_pts=21)
    return float(x0), float(y0), float(x1), float(y1)


def _thread_transformer(source_wkt: str, target_wkt: str) -> pyproj.Transformer:
    """The calling thread's Transformer for this pair (pyproj Transformers are not thread-safe)."""
    cache: dict[tuple[str, str], pyproj.Transformer] | None = getattr(_thread_state, "transformers", None)
    if cache is None:
        cache = _thread_state.transformers = {}
    key = (source_wkt, target_wkt)
    transformer = cache.get(key)
    if transformer is None:
        with warnings.catch_warnings():
            # "Best transformation is not available": resolve_crs already put it in the plan's notes.
            warnings.filterwarnings("ignore", message="Best transformation is not available")
            transformer = cache[key] = pyproj.Transformer.from_crs(
                pyproj.CRS.from_wkt(source_wkt), pyproj.CRS.from_wkt(target_wkt), always_xy=True
            )
    return transformer


@dataclass(frozen=True)
class Reprojector:
    """A picklable recipe for reprojecting points: source and target CRS as WKT.

    The pyproj Transformer is built lazily, once per thread, on first use and
    never pickled. When source and target are the same CRS no Transformer is
    built at all and :meth:`transform` returns its inputs as float64 arrays.

    Parameters
    ----------
    source_wkt, target_wkt
        The CRSs. Anything :meth:`pyproj.CRS.from_user_input` accepts is
        turned into WKT2 on construction.

    Examples
    --------
    >>> import pickle
    >>> r = pickle.loads(pickle.dumps(Reprojector("EPSG:2154", "EPSG:4326")))
    >>> lon, lat, h = r.transform([700000.0], [6600000.0], [0.0])
    >>> round(float(lon[0]), 6), round(float(lat[0]), 6)
    (3.0, 46.5)
    """

    source_wkt: str
    target_wkt: str
    z_factor: float = 1.0
    """Multiplies z after the transformation: a unit conversion pyproj does not
    do (files without a vertical CRS into a target with one)."""
    is_identity: bool = field(init=False, compare=False)
    _same_crs: bool = field(init=False, compare=False, repr=False)

    def __post_init__(self) -> None:
        source = _user_crs(self.source_wkt, "source CRS")
        target = _user_crs(self.target_wkt, "target CRS")
        if not pyproj.crs.is_wkt(self.source_wkt):
            object.__setattr__(self, "source_wkt", source.to_wkt())
        if not pyproj.crs.is_wkt(self.target_wkt):
            object.__setattr__(self, "target_wkt", target.to_wkt())
        if not (math.isfinite(self.z_factor) and self.z_factor > 0):
            raise UsageError(f"z_factor must be a positive number, got {self.z_factor!r}")
        same = self.source_wkt == self.target_wkt or same_crs(source, target)
        object.__setattr__(self, "_same_crs", same)
        object.__setattr__(self, "is_identity", same and self.z_factor == 1.0)

    def transform(
        self, x: np.ndarray, y: np.ndarray, z: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Reproject coordinate arrays; returns new float64 arrays (x, y, z).

        Raises
        ------
        CrsError
            If some points cannot be transformed (PROJ returns inf for them).
        """
        xs = np.asarray(x, dtype=np.float64)
        ys = np.asarray(y, dtype=np.float64)
        zs = np.asarray(z, dtype=np.float64)
        if not xs.shape == ys.shape == zs.shape:
            raise UsageError(f"x, y, z must have the same shape, got {xs.shape}, {ys.shape}, {zs.shape}")
        if self.is_identity:
            return xs, ys, zs
        if self._same_crs:
            tx, ty, tz = xs, ys, zs
        else:
            tx, ty, tz = _thread_transformer(self.source_wkt, self.target_wkt).transform(xs, ys, zs)
            tx, ty, tz = (np.asarray(a, dtype=np.float64) for a in (tx, ty, tz))
        if self.z_factor != 1.0:
            tz = tz * self.z_factor
        bad = ~(np.isfinite(tx) & np.isfinite(ty) & np.isfinite(tz))
        if bad.any():
            src, dst = pyproj.CRS.from_wkt(self.source_wkt), pyproj.CRS.from_wkt(self.target_wkt)
            raise CrsError(
                f"{int(bad.sum()):,} of {bad.size:,} points could not be transformed from "
                f"{crs_label(src)} to {crs_label(dst)} (outside the area either CRS covers?)"
            )
        return tx, ty, tz

    def to_dict(self) -> dict[str, Any]:
        """A JSON-ready dictionary (inverse of :meth:`from_dict`)."""
        return {"source_wkt": self.source_wkt, "target_wkt": self.target_wkt, "z_factor": self.z_factor}

    @classmethod
    def from_dict(cls, data: Mapping[str, Any]) -> Reprojector:
        """Rebuild from :meth:`to_dict` output."""
        return cls(source_wkt=data["source_wkt"], target_wkt=data["target_wkt"], z_factor=data.get("z_factor", 1.0))


# --------------------------------------------------------------------------- the plan


@dataclass(frozen=True)
class CrsPlan:
    """The CRS decisions for one run.

    Parameters
    ----------
    paths
        The input files, in the order given to :func:`resolve_crs`.
    source_wkts
        Each file's source CRS (WKT2) after the ``in_crs`` override.
    target_wkt
        The CRS of the outputs (WKT2); always projected (linear units).
    target_name
        Its name and EPSG code when one matches.
    horizontal_unit
        Unit of the target's x and y, e.g. ``"metre"``, ``"US survey foot"``.
    vertical_unit
        Unit of the target's vertical axis when it has one, else None.
    notes
        Lines for the run report: overrides, reprojections, what happens to z.
    height_unit
        Unit of the output heights when the target or the files declare it
        (e.g. ``"US survey foot"``), else None.
    height_scale
        A height times this is in the horizontal unit: what a slope needs.
        Undeclared heights are taken to be in the horizontal unit of their
        files (metres beside degrees), as is the custom.
    z_factors
        Per file, what multiplies its z after reprojection (empty: all 1).
    """

    paths: tuple[Location, ...]
    source_wkts: tuple[str, ...]
    target_wkt: str
    target_name: str
    horizontal_unit: str
    vertical_unit: str | None = None
    notes: tuple[str, ...] = ()
    height_unit: str | None = None
    height_scale: float = 1.0
    z_factors: tuple[float, ...] = ()

    def __post_init__(self) -> None:
        if len(self.paths) != len(self.source_wkts):
            raise UsageError(f"{len(self.paths)} paths but {len(self.source_wkts)} source CRSs")
        if self.z_factors and len(self.z_factors) != len(self.paths):
            raise UsageError(f"{len(self.paths)} paths but {len(self.z_factors)} z factors")

    def z_factor(self, index: int) -> float:
        """What multiplies the z of input ``index`` after reprojection."""
        return self.z_factors[index] if self.z_factors else 1.0

    def source_wkt(self, path: str | Path) -> str:
        """The source CRS (WKT) of one input file."""
        try:
            return self.source_wkts[self.paths.index(as_location(path))]
        except ValueError:
            raise UsageError(f"{path}: not one of the plan's input files") from None

    def reprojector(self, path: str | Path) -> Reprojector:
        """The recipe taking one file's points to the target CRS."""
        return Reprojector(self.source_wkt(path), self.target_wkt, self.z_factor(self.paths.index(as_location(path))))

    def to_dict(self) -> dict[str, Any]:
        """A JSON-ready dictionary (inverse of :meth:`from_dict`)."""
        return {
            "paths": [str(p) for p in self.paths],
            "source_wkts": list(self.source_wkts),
            "target_wkt": self.target_wkt,
            "target_name": self.target_name,
            "horizontal_unit": self.horizontal_unit,
            "vertical_unit": self.vertical_unit,
            "notes": list(self.notes),
            "height_unit": self.height_unit,
            "height_scale": self.height_scale,
            "z_factors": list(self.z_factors),
        }

    @classmethod
    def from_dict(cls, data: Mapping[str, Any]) -> CrsPlan:
        """Rebuild from :meth:`to_dict` output."""
        return cls(
            paths=tuple(as_location(p) for p in data["paths"]),
            source_wkts=tuple(data["source_wkts"]),
            target_wkt=data["target_wkt"],
            target_name=data["target_name"],
            horizontal_unit=data["horizontal_unit"],
            vertical_unit=data.get("vertical_unit"),
            notes=tuple(data.get("notes", ())),
            height_unit=data.get("height_unit"),
            height_scale=data.get("height_scale", 1.0),
            z_factors=tuple(data.get("z_factors", ())),
        )


def resolve_crs(
    infos: Sequence[SourceInfo],
    in_crs: str | None = None,
    out_crs: str | None = None,
    *,
    override_crs: str | None = None,
) -> CrsPlan:
    """Decide the source CRS of every file and the target CRS.

    Parameters
    ----------
    infos
        Header information of the input files (:func:`pipeline.inputs.sources.read_info`).
    in_crs
        CRS of the inputs whose CRS is missing or broken (anything
        ``pyproj.CRS.from_user_input`` accepts; PDAL's ``default_srs``).  A
        file's valid CRS is kept, and a note says so when it differs from
        ``in_crs``.
    out_crs
        CRS of the outputs. Default: the files' common CRS.
    override_crs
        CRS of every input, whatever its record says (PDAL's
        ``override_srs``); a note names each file whose record it replaces.
        Not with ``in_crs``.

    Returns
    -------
    CrsPlan

    Raises
    ------
    CrsError
        On a bad ``in_crs``/``override_crs``/``out_crs`` string; when files
        without a usable CRS are given no ``in_crs``; when a file's header
        bounds contradict its CRS record (:func:`contradiction`), or cannot
        be coordinates of the CRS given for it; when files in different CRSs
        are given no ``out_crs``; when the target CRS is not projected (e.g.
        geographic, in degrees).
    UsageError
        When both ``in_crs`` and ``override_crs`` are given.
    """
    if len(infos) == 0:
        raise UsageError("no input files to resolve a CRS for")
    if in_crs is not None and override_crs is not None:
        raise UsageError(BOTH_CRS_OPTIONS)
    given = _given_crss(in_crs, override_crs)
    user_out = _user_crs(out_crs, "out_crs") if out_crs is not None else None
    notes: list[str] = []

    sources, chosen_by = _file_crss(infos, _CrsCache(), *given, notes)
    groups = _group_by_crs(sources)

    plausible = _check_coordinates(infos, groups, chosen_by, notes)

    target = _target_crs(user_out, groups, infos)
    _check_target(
        target, from_option=user_out is not None,
        infos=[info for info, ok in zip(infos, plausible) if ok],
        sources=[crs for crs, ok in zip(sources, plausible) if ok],
    )

    target_wkt = target.to_wkt()
    horizontal_unit = _horizontal_unit(target)
    z_factors, heights = _height_factors(groups, target, infos, notes)
    if all(same_crs(crs, target) for crs, _ in groups):
        notes.append(f"no reprojection: every file is already in {crs_label(target)}")
    if horizontal_unit != "metre":
        notes.append(f"horizontal unit is {horizontal_unit}: distances and cell sizes are in {horizontal_unit}")
    height_unit, height_scale = _output_heights(heights, target, notes)

    return CrsPlan(
        paths=tuple(info.path for info in infos),
        source_wkts=tuple(target_wkt if same_crs(crs, target) else crs.to_wkt() for crs in sources),
        target_wkt=target_wkt,
        target_name=crs_label(target),
        horizontal_unit=horizontal_unit,
        vertical_unit=_vertical_unit(target),
        notes=tuple(notes),
        height_unit=height_unit,
        height_scale=height_scale,
        z_factors=tuple(z_factors) if any(f != 1.0 for f in z_factors) else (),
    )


def working_crs(
    infos: Sequence[SourceInfo], in_crs: str | None = None, *, override_crs: str | None = None
) -> tuple[str, str] | None:
    """The CRS to work in when no ``out_crs`` is given (meshes, cells and the
    ground filter's sizes need linear coordinates): None when the files' one
    CRS (their records, ``in_crs``, ``override_crs``, as :func:`resolve_crs`
    takes them) is projected; when it is geographic or geocentric, the WGS 84
    UTM zone at the centre of their bounds, ``("EPSG:326zz", its name)``.
    None too where :func:`resolve_crs` will refuse the files anyway (and say
    why)."""
    if in_crs is not None and override_crs is not None:
        return None
    try:
        sources, _ = _file_crss(infos, _CrsCache(), *_given_crss(in_crs, override_crs), [])
    except CrsError:
        return None
    groups = _group_by_crs(sources)
    if len(groups) != 1:
        return None
    h = _horizontal(groups[0][0])
    if h.is_projected or not (h.is_geographic or h.is_geocentric):
        return None
    return _suggest_utm(infos, sources)


def _given_crss(
    in_crs: str | None, override_crs: str | None
) -> tuple[pyproj.CRS | None, pyproj.CRS | None, str, pyproj.CRS | None]:
    """The CRSs the options ``in_crs`` and ``override_crs`` name (not both),
    then the option that gives the files' CRS and that CRS: the arguments of
    :func:`_file_crss` after the infos and the cache."""
    user_in = _user_crs(in_crs, "in_crs") if in_crs is not None else None
    user_override = _user_crs(override_crs, "override_crs") if override_crs is not None else None
    option, user = ("override_crs", user_override) if user_override is not None else ("in_crs", user_in)
    return user_in, user_override, option, user


def _file_crss(
    infos: Sequence[SourceInfo], cache: _CrsCache, user_in: pyproj.CRS | None, user_override: pyproj.CRS | None,
    option: str, user: pyproj.CRS | None, notes: list[str],
) -> tuple[list[pyproj.CRS], list[str | None]]:
    """Each file's CRS: its own record, or ``user``, the CRS the option named
    ``option`` gives; and per file that option (None: its own record).  Notes
    are appended to ``notes``.  Files without a usable CRS, when none is
    given, are an error naming them."""
    sources: list[pyproj.CRS] = []
    chosen_by: list[str | None] = []  # per file, the option whose CRS it takes; None: its own record
    unusable: list[str] = []
    defaulted: list[Path] = []
    for info in infos:
        file_crs: pyproj.CRS | None = None
        problem = info.crs_problem
        if info.crs_wkt is not None:
            try:
                file_crs = cache.get(info.crs_wkt)
            except CRSError as exc:
                problem = f"stored CRS unparsable ({one_line(exc)})"
        if file_crs is not None and user_override is None:
            if user_in is not None and not same_crs(file_crs, user_in):
                notes.append(
                    f"{info.path}: its own CRS {crs_label(file_crs)} is kept; in_crs={crs_label(user_in)!r} "
                    "is for files without a usable CRS (override_crs replaces every file's)"
                )
            sources.append(file_crs)
            chosen_by.append(None)
        elif user is not None:
            if file_crs is not None:
                if not same_crs(file_crs, user):
                    notes.append(
                        f"{info.path}: its CRS record {crs_label(file_crs)} is replaced by {option}={crs_label(user)!r}"
                    )
            elif problem:
                notes.append(f"{info.path}: {problem}; using {option}={crs_label(user)!r}")
            else:
                defaulted.append(info.path)
            sources.append(user)
            chosen_by.append(option)
        else:
            unusable.append(f"{info.path} ({problem or 'no CRS record'})")
    if unusable:
        shown = ", ".join(unusable[:_MAX_LISTED])
        more = len(unusable) - _MAX_LISTED
        raise CrsError(
            f"no usable CRS for {len(unusable)} file(s): {shown}"
            + (f" and {more} more" if more > 0 else "")
            + "; give in_crs (e.g. in_crs='EPSG:2154') to say which CRS they are in"
        )
    if defaulted and user is not None:
        notes.append(f"{option}={crs_label(user)!r} used for file(s) without a CRS: {_list_paths(defaulted)}")

    return sources, chosen_by


def _group_by_crs(sources: list[pyproj.CRS]) -> list[tuple[pyproj.CRS, list[int]]]:
    """The files' CRSs, each once, in order of first use, with the indices of the files in it."""
    groups: list[tuple[pyproj.CRS, list[int]]] = []
    for i, crs in enumerate(sources):
        for group_crs, members in groups:
            if group_crs is crs or same_crs(group_crs, crs):
                members.append(i)
                break
        else:
            groups.append((crs, [i]))
    return groups


def _target_crs(user_out: pyproj.CRS | None, groups: list[tuple[pyproj.CRS, list[int]]],
                infos: Sequence[SourceInfo]) -> pyproj.CRS:
    """``out_crs`` when given, else the files' one CRS; files in several CRSs need ``out_crs``."""
    if user_out is not None:
        return user_out
    elif len(groups) == 1:
        return groups[0][0]
    else:
        listing = "; ".join(
            f"{crs_label(crs)}: {_list_paths([infos[i].path for i in members])}" for crs, members in groups
        )
        raise CrsError(
            f"input files are in {len(groups)} different CRSs and no out_crs was given: {listing}; "
            "give out_crs to reproject them all to one CRS"
        )


def _height_factors(groups: list[tuple[pyproj.CRS, list[int]]], target: pyproj.CRS, infos: Sequence[SourceInfo],
                    notes: list[str]) -> tuple[list[float], list[_Heights]]:
    """Each file's factor from its heights' unit to the target's, and each CRS
    group's heights; the notes of each reprojection are appended to ``notes``."""
    z_factors = [1.0] * len(infos)
    heights: list[_Heights] = []
    for crs, members in groups:
        group_infos = [infos[i] for i in members]
        h = _heights(crs, target, group_infos)
        heights.append(h)
        for i in members:
            z_factors[i] = h.factor
        if not same_crs(crs, target):
            notes.extend(_reprojection_notes(crs, target, group_infos, h))
    return z_factors, heights


def _check_coordinates(
    infos: Sequence[SourceInfo], groups: Sequence[tuple[pyproj.CRS, list[int]]], chosen_by: Sequence[str | None],
    notes: list[str],
) -> list[bool]:
    """Whether each file's header bounds are coordinates of its CRS (False
    for a file with none to judge).

    A CRS record they contradict is a CrsError (the way out:
    ``override_crs``), and so is a CRS given by ``in_crs`` or
    ``override_crs`` that cannot hold them at all; one given that is only
    used far from them gets a note (the user's word stands)."""
    plausible = [False] * len(infos)
    errors: list[tuple[int, str]] = []
    for crs, members in groups:
        domain = _Domain(crs)
        for i in members:
            info = infos[i]
            if not (info.point_count and info.bounds_usable):
                continue  # no coordinates to judge
            found = domain.contradiction(info.bounds)
            if found is None:
                plausible[i] = True
                continue
            (reason, impossible), option = found, chosen_by[i]
            if option is None:
                errors.append((i, (
                    f"{info.path}: its CRS record {crs_label(crs)} {reason}; if the record is wrong, "
                    "give override_crs the CRS the coordinates are in"
                )))
            elif impossible:
                errors.append((i, (
                    f"{info.path}: {option}={crs_label(crs)!r} {reason}; give {option} the CRS the coordinates are in"
                )))
            else:
                notes.append(f"{info.path}: {option}={crs_label(crs)!r} {reason}; is it the CRS of these coordinates?")
    if errors:
        errors.sort()
        rest = [infos[i].path for i, _ in errors[1:]]
        raise CrsError(errors[0][1] + (f" ({len(rest)} more file(s) likewise: {_list_paths(rest)})" if rest else ""))
    return plausible


@dataclass(frozen=True)
class _Heights:
    """What becomes of one CRS group's heights."""

    declared: str | None
    """The unit the files' heights are declared in (vertical CRS or GeoTIFF key), if any."""
    presumed: str
    """``declared``, or the custom for undeclared heights: the horizontal unit (metres beside degrees)."""
    unit: str | None
    """The unit of these heights in the output, when known."""
    factor: float
    """Multiplies z after reprojection."""

    @property
    def presumed_out(self) -> str:
        """The unit of these heights in the output, known or presumed."""
        return self.unit or self.presumed


def _heights(source: pyproj.CRS, target: pyproj.CRS, members: Sequence[SourceInfo]) -> _Heights:
    declared_keys = {m.z_unit for m in members if m.z_unit}
    declared = _vertical_unit(source) or (declared_keys.pop() if len(declared_keys) == 1 else None)
    presumed = declared or ("metre" if _horizontal(source).is_geographic else _horizontal_unit(source))
    if not _has_vertical(target):
        return _Heights(declared, presumed, declared, 1.0)
    target_unit = _vertical_unit(target) or "metre"
    if _has_vertical(source):  # PROJ converts z itself
        return _Heights(declared, presumed, target_unit, 1.0)
    have, want = unit_metres(presumed), unit_metres(target_unit)
    factor = 1.0 if have is None or want is None else have / want
    return _Heights(declared, presumed, target_unit, factor)


def _output_heights(heights: Sequence[_Heights], target: pyproj.CRS, notes: list[str]) -> tuple[str | None, float]:
    """The unit of the output heights (when declared) and the scale that puts them in the horizontal unit."""
    units = {h.unit for h in heights}
    presumed = {h.presumed_out for h in heights}
    if len(presumed) > 1:
        notes.append(
            f"the files' heights are in different units ({', '.join(sorted(presumed))}) and the DEM mixes them: "
            "reproject to an out_crs with a vertical component (e.g. out_crs='EPSG:32631+5773') to convert them to one"
        )
        return None, 1.0
    unit = units.pop() if len(units) == 1 else None
    z_unit = presumed.pop()
    if z_unit == _horizontal_unit(target):
        return unit, 1.0
    z_metres = unit_metres(z_unit)
    axes = _horizontal(target).axis_info
    xy_metres = axes[0].unit_conversion_factor if axes else None
    if z_metres is None or not xy_metres:
        return unit, 1.0
    return unit, z_metres / xy_metres


def _check_target(
    target: pyproj.CRS, *, from_option: bool, infos: Sequence[SourceInfo], sources: Sequence[pyproj.CRS]
) -> None:
    """Refuse targets whose x, y are not linear coordinates."""
    h = _horizontal(target)
    what = f"out_crs={crs_label(target)!r}" if from_option else f"the files' CRS {crs_label(target)}"
    if h.is_projected or h.type_name == "Engineering CRS":
        return
    if h.is_geographic:
        kind = "geographic (degrees)"
    elif h.is_geocentric:
        kind = "geocentric (earth-centred x, y, z)"
    elif h.is_vertical:
        kind = "vertical only (no x, y)"
    else:
        kind = f"not projected ({h.type_name})"
    hint = _suggest_utm(infos, sources)
    if hint:
        suggestion = f"use out_crs={hint[0]!r} ({hint[1]}) or a national grid"
    else:
        suggestion = "give out_crs the EPSG code of a UTM zone or national grid"
    raise CrsError(f"{what} is {kind}; meshes need a projected CRS in metres or feet: {suggestion}")


def _suggest_utm(infos: Sequence[SourceInfo], sources: Sequence[pyproj.CRS]) -> tuple[str, str] | None:
    """The WGS 84 UTM zone at the centre of the files' header bounds: ``("EPSG:326zz", its name)``."""
    wgs84 = pyproj.CRS.from_epsg(4326)
    lons: list[float] = []
    lats: list[float] = []
    for info, crs in zip(infos, sources):
        minx, miny, minz, maxx, maxy, maxz = info.bounds
        try:  # z too: geocentric x and y alone make no latitude
            lon, lat, _ = pyproj.Transformer.from_crs(crs, wgs84, always_xy=True).transform(
                (minx + maxx) / 2, (miny + maxy) / 2, (minz + maxz) / 2
            )
        except (CRSError, pyproj.exceptions.ProjError):
            continue
        if math.isfinite(lon) and math.isfinite(lat) and -180 <= lon <= 180 and -90 <= lat <= 90:
            lons.append(lon)
            lats.append(lat)
    if not lons:
        return None
    lon, lat = sum(lons) / len(lons), sum(lats) / len(lats)
    zone = int((lon + 180) // 6) % 60 + 1
    north = lat >= 0
    code = (32600 if north else 32700) + zone
    return f"EPSG:{code}", f"WGS 84 / UTM zone {zone}{'N' if north else 'S'}"


def _reprojection_notes(
    source: pyproj.CRS, target: pyproj.CRS, members: Sequence[SourceInfo], heights: _Heights
) -> list[str]:
    names = _list_paths([m.path for m in members])
    notes = [f"{names}: reprojected from {crs_label(source)} to {crs_label(target)}"]
    if _has_vertical(target) and not _has_vertical(source):
        unit_text = heights.declared or f"undeclared, presumably {heights.presumed}"
        if heights.factor != 1.0:
            change = f"z is converted from {heights.presumed} to {heights.unit} (x{heights.factor:.12g})"
        else:
            change = f"z stays in {heights.presumed} ({unit_text})"
        notes.append(
            f"{names}: {change}, the unit of {crs_label(target)}'s heights; the files name no vertical datum, "
            "so no datum shift is applied: their heights are taken to be in the target's vertical datum"
        )
        return notes
    if _has_vertical(source) and _has_vertical(target):
        notes.append(
            f"{names}: z is transformed too, both CRSs having a vertical component "
            f"({_vertical_unit(source)} -> {_vertical_unit(target)})"
        )
        try:
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")  # pyproj warns about the missing grid: we say it below
                group = pyproj.transformer.TransformerGroup(source, target, always_xy=True)
            best_missing = not group.best_available
        except (CRSError, pyproj.exceptions.ProjError):
            best_missing = False
        if best_missing:
            notes.append(
                f"{names}: PROJ lacks a grid for the most accurate transformation to {crs_label(target)} "
                "(install proj-data or enable PROJ_NETWORK); a coarser one is used and heights may be left unchanged"
            )
        return notes
    presumed = heights.presumed
    unit_text = heights.declared or f"undeclared, presumably {presumed}"
    notes.append(
        f"{names}: z is not transformed (pyproj changes z only when both CRSs are compound/3D): "
        f"heights keep the files' vertical datum and unit ({unit_text})"
    )
    target_unit = _horizontal_unit(target)
    if presumed != target_unit:
        notes.append(f"{names}: z stays in {presumed} while x and y become {target_unit} (slopes allow for it)")
    return notes
