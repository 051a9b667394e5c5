"""Waterbody outlines from OpenStreetMap (osmnx), with an offline fallback (SPEC §2, pipeline stage
``fetch_outline``).

``fetch_outline`` asks OSM for ``natural=water`` features of a place and keeps the polygon whose name matches.
When OSM cannot be reached (a short timeout, not osmnx's 180 s default), it falls back to a bundled outline,
warns, and records which source it used. A place that OSM answers for but does not know is an error, never a
silent fallback. ``outline_from_osm_xml`` parses a downloaded ``.osm`` file with the same code path.
"""

from __future__ import annotations

import json
import warnings
from dataclasses import dataclass
from datetime import date
from pathlib import Path

import shapely

from replicate.core import artifacts
from replicate.world.regions import RegionError, check_polygon, read_outline

OSM_ATTRIBUTION = "© OpenStreetMap contributors, available under the Open Database Licence (ODbL)"


class OSMUnavailable(RuntimeError):
    """OpenStreetMap (Nominatim / Overpass) could not be reached."""


@dataclass(frozen=True)
class Outline:
    """A waterbody outline in lon/lat (EPSG:4326) with where it came from."""

    polygon: shapely.Polygon
    name: str
    source: str  # "openstreetmap" or "fallback"
    osm_id: str | None
    tags: dict
    attribution: str
    note: str = ""

    def to_geojson(self) -> dict:
        return {
            "type": "FeatureCollection",
            "crs": {"type": "name", "properties": {"name": "urn:ogc:def:crs:OGC:1.3:CRS84"}},
            "attribution": self.attribution,
            "features": [
                {
                    "type": "Feature",
                    "properties": {
                        "name": self.name,
                        "source": self.source,
                        "osm_id": self.osm_id,
                        "tags": json.dumps(self.tags, sort_keys=True),
                        "attribution": self.attribution,
                        "note": self.note,
                        "retrieved": date.today().isoformat(),
                    },
                    "geometry": shapely.geometry.mapping(self.polygon),
                }
            ],
        }

    def write(self, path: str | Path) -> None:
        artifacts.write_json(path, self.to_geojson())


def pick_feature(gdf, name: str, where: str) -> Outline:
    """The polygon feature of ``gdf`` (osmnx features, indexed by element and id) whose name matches ``name``."""
    if gdf is None or gdf.empty:
        raise RegionError(f"{where}: no water features")
    polys = gdf[gdf.geom_type.isin(["Polygon", "MultiPolygon"])]
    if "name" in polys.columns:
        named = polys[polys["name"].fillna("").str.casefold().str.contains(name.casefold(), regex=False)]
    else:
        named = polys.iloc[0:0]
    if named.empty:
        names = sorted({str(n) for n in polys.get("name", []) if isinstance(n, str)})[:10]
        raise RegionError(f"{where}: no water polygon named {name!r} (named polygons: {names or 'none'})")
    areas = named.to_crs(named.estimate_utm_crs()).area
    key = areas.idxmax()
    row = named.loc[key]
    element, osm_id = key if isinstance(key, tuple) else ("feature", key)
    tags = {k: v for k, v in row.items() if k != "geometry" and isinstance(v, str)}
    return Outline(
        polygon=check_polygon(row.geometry, f"{where}: {row.get('name', name)}"),
        name=str(row.get("name", name)),
        source="openstreetmap",
        osm_id=f"{element}/{osm_id}",
        tags=tags,
        attribution=OSM_ATTRIBUTION,
    )


def outline_from_osm_xml(path: str | Path, name: str, tags: dict | None = None) -> Outline:
    """Parse a downloaded OSM XML file (osmnx ``features_from_xml``) and pick the water polygon ``name``."""
    import osmnx as ox

    path = Path(path)
    if not path.exists():
        raise RegionError(f"{path}: no such OSM XML file")
    try:
        gdf = ox.features_from_xml(path, tags=tags or {"natural": "water"})
    except Exception as exc:  # noqa: BLE001 - any parser failure is a bad input
        raise RegionError(f"{path}: cannot be parsed as OSM XML ({exc})") from exc
    return pick_feature(gdf, name, str(path))


def use_endpoints(nominatim_url: str = "", overpass_url: str = "") -> None:
    """Point osmnx at other Nominatim / Overpass endpoints (a mirror); empty strings keep osmnx's defaults."""
    import osmnx as ox

    if nominatim_url:
        ox.settings.nominatim_url = nominatim_url
    if overpass_url:
        ox.settings.overpass_url = overpass_url


def query_osm(place: str, name: str, tags: dict, timeout: float) -> Outline:
    """Ask OSM (Nominatim + Overpass through osmnx) for the water polygon ``name`` in ``place``."""
    import osmnx as ox
    import requests

    ox.settings.requests_timeout = timeout
    ox.settings.use_cache = False
    try:
        gdf = ox.features_from_place(place, tags)
    except (requests.exceptions.ConnectionError, requests.exceptions.Timeout) as exc:
        raise OSMUnavailable(f"OpenStreetMap could not be reached ({type(exc).__name__})") from exc
    except Exception as exc:  # noqa: BLE001 - osmnx's own errors: the place is unknown or has no such features
        if type(exc).__name__ in ("InsufficientResponseError", "ValueError", "TypeError"):
            raise RegionError(f"OpenStreetMap does not know {place!r} with {tags} ({exc})") from exc
        raise OSMUnavailable(f"OpenStreetMap query failed ({type(exc).__name__}: {exc})") from exc
    return pick_feature(gdf, name, f"OSM {place!r}")


def fetch_outline(place: str, name: str, tags: dict, timeout: float, fallback: str | Path | None) -> Outline:
    """OSM when reachable; else the bundled ``fallback`` outline, with a warning that says so."""
    try:
        return query_osm(place, name, tags, timeout)
    except OSMUnavailable as exc:
        if fallback is None:
            raise
        return fallback_outline(fallback, name, reason=str(exc))


def fallback_outline(path: str | Path, name: str, reason: str) -> Outline:
    """The bundled outline (a GeoJSON in lon/lat with an ``attribution`` member)."""

    path = Path(path)
    geometry, crs, props = read_outline(path)
    if crs is None or not crs.equals("EPSG:4326") and not crs.equals("OGC:CRS84"):
        raise RegionError(f"{path}: the fallback outline must be in lon/lat, got {crs}")
    doc = json.loads(path.read_text())
    note = f"{reason}; used the bundled outline {path.name} instead"
    warnings.warn(f"fetch_outline: {note}", stacklevel=2)
    return Outline(
        polygon=check_polygon(geometry, str(path)),
        name=str(props.get("NAME", name)),
        source="fallback",
        osm_id=None,
        tags={k: str(v) for k, v in props.items()},
        attribution=doc.get("attribution", ""),
        note=note,
    )


def describe_source(outline_path: str) -> str:
    """Where an outline written by the fetch stage came from, for figure titles."""
    props = json.loads(Path(outline_path).read_text())["features"][0]["properties"]
    if props.get("source") == "openstreetmap":
        return f"OpenStreetMap ({props.get('osm_id')}, retrieved {props.get('retrieved')})"
    return f"bundled SLA National Map outline — OpenStreetMap was unreachable ({props.get('retrieved')})"
