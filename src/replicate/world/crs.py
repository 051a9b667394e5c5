"""Is an outline file's CRS the one its coordinates are in? A GeoJSON may declare a CRS its reader does not know
(and reads as WGS 84 without a word), and a file's coordinates may land far outside where its CRS is used (x and
y swapped): both are refused by name, before the lake lands somewhere else."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from replicate.core.schema import RegionError


def declared_crs(path: Path) -> str | None:
    """The CRS name a GeoJSON file's ``crs`` member declares, if any (the readers fall back to WGS 84 on a name
    they do not know)."""
    if path.suffix.lower() not in (".geojson", ".json"):
        return None
    try:
        crs = json.loads(path.read_text()).get("crs") or {}
        return str(crs.get("properties", {}).get("name")) if crs else None
    except (ValueError, UnicodeDecodeError, AttributeError):
        return None


def check_declared_crs(path: Path, read_as) -> None:
    """Refuse a GeoJSON whose declared CRS the reader did not take: a name it does not know (``EPSG:99999``) is
    read as WGS 84 without a word, and the lake would land somewhere else."""
    from pyproj import CRS
    from pyproj.exceptions import CRSError

    declared = declared_crs(path)
    if declared is None:
        return
    try:
        known = CRS.from_user_input(declared)
    except CRSError:
        raise RegionError(f"{path}: declares the CRS {declared!r}, which is not a known CRS (the reader would take "
                          "it for WGS 84); write the file with the CRS its coordinates are in, e.g. EPSG:4326") \
            from None
    if not known.equals(read_as, ignore_axis_order=True):
        raise RegionError(f"{path}: declares the CRS {declared!r} but was read as {read_as.to_string()}; write "
                          "the file with a CRS the readers take (an EPSG code)")


LATITUDE_SLACK = 2.0  # degrees a lake may reach past its CRS's stated area of use, north or south
LONGITUDE_SLACK = 30.0  # east or west: a national grid stretches one UTM zone across a country (Finnmark in
# EPSG:25833 lies 7.5° east of its zone); x and y swapped land far further off


def degrees_outside(lon: float, west: float, east: float) -> float:
    """How many degrees of longitude ``lon`` lies outside the interval from ``west`` eastwards to ``east`` (one that
    crosses the 180th meridian, west > east, included)."""
    span, offset = (east - west) % 360, (lon - west) % 360
    return 0.0 if offset <= span else min(offset - span, 360 - offset)


def check_area_of_use(path: Path, polys) -> None:
    """Refuse coordinates far outside the area where their CRS is used (a UTM file with easting and northing
    swapped lands thousands of kilometres off its zone, or nowhere on Earth): named with where they land."""
    area = polys.crs.area_of_use
    if area is None or (area.west <= -180 and area.east >= 180):  # a world CRS: no zone to stray from
        return
    west, south, east, north = polys.to_crs("EPSG:4326").total_bounds
    finite = bool(np.isfinite([west, south, east, north]).all())
    inside = (finite and south >= area.south - LATITUDE_SLACK and north <= area.north + LATITUDE_SLACK
              and max(degrees_outside(west, area.west, area.east),
                      degrees_outside(east, area.west, area.east)) <= LONGITUDE_SLACK)
    if not inside:
        where = "nowhere on Earth" if not finite else f"at {west:.4g}…{east:.4g}°E, {south:.4g}…{north:.4g}°N"
        raise RegionError(f"{path}: its coordinates land {where}, outside where {polys.crs.to_string()} is used "
                          f"({area.west:g}…{area.east:g}°E, {area.south:g}…{area.north:g}°N); are x and y swapped, or "
                          "is the CRS not the one the coordinates are in?")
