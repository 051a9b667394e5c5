"""Regions to cover (SPEC §2): the square, the rectangle, and any waterbody polygon.

A region is a shapely polygon in simulation metres, centred on its centroid and scaled uniformly to a target
area (9 m² in the paper). A polygon read from a file goes through geopandas in its own CRS → UTM
(``estimate_utm_crs``) → centred → scaled; the scale is kept so that results can be mapped back to the map.
``at_density`` scales a region for another fleet at the density it was drawn for.
"""

from __future__ import annotations

import dataclasses
import json
import math
import warnings
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import shapely
from shapely import affinity
from shapely.geometry import MultiPolygon, Polygon, box
from shapely.validation import explain_validity

from replicate.core import artifacts
from replicate.core.schema import RegionError
from replicate.world.crs import check_area_of_use, check_declared_crs, declared_crs


@dataclass(frozen=True)
class Region:
    """A region in simulation metres.

    ``scale`` is real metres per simulation metre (1.0 for the synthetic shapes); ``utm_crs`` and ``offset``
    (the UTM coordinates of the centroid) map simulation coordinates back to the map:
    ``utm = offset + scale * xy``.
    """

    name: str
    polygon: Polygon
    scale: float = 1.0
    utm_crs: str | None = None
    offset: tuple[float, float] = (0.0, 0.0)
    source: str = "synthetic"
    attribution: str = ""
    notes: tuple[str, ...] = field(default_factory=tuple)

    @property
    def area(self) -> float:
        return float(self.polygon.area)

    def to_map(self, xy) -> np.ndarray:
        """Simulation positions [..., 2] → the map's (UTM metres): ``offset + scale · xy``."""
        return np.asarray(self.offset) + self.scale * np.asarray(xy, dtype=float)

    def centre_lonlat(self) -> tuple[float, float] | None:
        """Where the lake lies, (lon, lat) of its centroid in WGS84 (None for a synthetic region): what a user
        checks against the map (a file with latitude first lands elsewhere)."""
        if self.utm_crs is None:
            return None
        from pyproj import Transformer

        lon, lat = Transformer.from_crs(self.utm_crs, "EPSG:4326", always_xy=True).transform(*self.offset)
        return round(float(lon), 6), round(float(lat), 6)

    def centre_text(self) -> str:
        """The centre as a user reads it on a map, "60.8787°E 56.1036°N" ("" for a synthetic region)."""
        if (centre := self.centre_lonlat()) is None:
            return ""
        lon, lat = centre
        return f"{abs(lon):.4f}°{'E' if lon >= 0 else 'W'} {abs(lat):.4f}°{'N' if lat >= 0 else 'S'}"

    def map_polygon(self) -> Polygon:
        """The water in UTM metres (the map's CRS, ``utm_crs``)."""
        return affinity.affine_transform(self.polygon, [self.scale, 0, 0, self.scale, *self.offset])

    def to_geojson(self) -> dict:
        """The simulation-metre polygon with its provenance, as a GeoJSON FeatureCollection (no CRS)."""
        return {
            "type": "FeatureCollection",
            "features": [
                {
                    "type": "Feature",
                    "properties": {
                        "name": self.name,
                        "scale_m_per_sim_m": self.scale,
                        "utm_crs": self.utm_crs,
                        "offset": list(self.offset),
                        "source": self.source,
                        "attribution": self.attribution,
                    },
                    "geometry": shapely.geometry.mapping(self.polygon),
                }
            ],
        }


def check_polygon(geom, what: str = "region") -> Polygon:
    """Refuse anything that is not one valid, non-empty polygon; a multi-part input keeps its largest part."""
    if geom is None:
        raise RegionError(f"{what}: no geometry")
    if not isinstance(geom, shapely.Geometry):
        raise RegionError(f"{what}: expected a shapely geometry, got {type(geom).__name__}")
    if geom.is_empty:
        raise RegionError(f"{what}: the geometry is empty")
    if isinstance(geom, MultiPolygon):
        parts = sorted(geom.geoms, key=lambda g: g.area, reverse=True)
        warnings.warn(
            f"{what}: multi-part polygon with {len(parts)} parts; using the largest "
            f"({parts[0].area / geom.area:.1%} of the area)",
            stacklevel=2,
        )
        geom = parts[0]
    if not isinstance(geom, Polygon):
        raise RegionError(f"{what}: expected a Polygon, got a {geom.geom_type}")
    if not geom.is_valid:
        raise RegionError(f"{what}: invalid polygon ({explain_validity(geom)}); repair the outline (for example "
                          "shapely.make_valid, or Fix geometries in QGIS)")
    if not np.isfinite(np.asarray(geom.exterior.coords)).all():
        raise RegionError(f"{what}: coordinates are not finite")
    if geom.area <= 0:
        raise RegionError(f"{what}: the polygon has zero area")
    return geom


def normalise(polygon: Polygon, area: float | None) -> tuple[Polygon, float, tuple[float, float]]:
    """Centre ``polygon`` on its centroid and scale it uniformly to ``area`` (kept as is when ``None``).

    Returns the new polygon, the real-metres-per-simulation-metre scale and the original centroid.
    """
    c = polygon.centroid
    moved = affinity.translate(polygon, -c.x, -c.y)
    if area is None:
        return moved, 1.0, (c.x, c.y)
    factor = math.sqrt(area / polygon.area)
    scaled = affinity.scale(moved, factor, factor, origin=(0.0, 0.0))
    return shapely.set_precision(scaled, 0.0), 1.0 / factor, (c.x, c.y)


def box_region(name: str, width: float, height: float) -> Region:
    """An axis-aligned rectangle centred at the origin (the paper's square and rectangle)."""
    if not (width > 0 and height > 0):
        raise RegionError(f"{name}: width and height must be positive, got {width} x {height}")
    return Region(name, box(-width / 2, -height / 2, width / 2, height / 2))


def read_outline(path: str | Path, layer: str | None = None):
    """Read a vector file with geopandas and return (polygon, crs, properties of its feature)."""
    import geopandas as gpd

    path = Path(path)
    if not path.exists():
        raise RegionError(f"{path}: no such file")
    try:
        with warnings.catch_warnings():  # a NaN vertex warns inside the reader; it is refused below, by name
            warnings.simplefilter("ignore", RuntimeWarning)
            gdf = gpd.read_file(path, layer=layer) if layer else gpd.read_file(path)
    except Exception as exc:  # noqa: BLE001 - any reader failure is a bad input
        raise RegionError(f"{path}: cannot be read as a vector file ({exc})") from exc
    if not isinstance(gdf, gpd.GeoDataFrame) or "geometry" not in gdf:
        raise RegionError(f"{path}: holds a table without geometries; give a vector file of the outline (GeoJSON, "
                          "shapefile, GeoPackage)")
    if gdf.empty:
        raise RegionError(f"{path}: the file holds no features")
    if gdf.crs is None:
        raise RegionError(f"{path}: the file has no CRS; write it with one (for example EPSG:4326)")
    check_declared_crs(path, gdf.crs)
    gdf = gdf[~gdf.geometry.is_empty & gdf.geometry.notna()]
    if gdf.geometry.has_z.any():  # a 3-D outline (heights of the shore): the water's outline is its 2-D shadow
        gdf = gdf.set_geometry(shapely.force_2d(gdf.geometry.values))
    polys = gdf[gdf.geom_type.isin(["Polygon", "MultiPolygon"])]
    if polys.empty:
        kinds = sorted(set(gdf.geom_type))
        raise RegionError(f"{path}: no polygon features (found {kinds or 'only empty geometries'})")
    if not np.isfinite(shapely.get_coordinates(polys.geometry.values)).all():
        raise RegionError(f"{path}: the outline has coordinates that are not numbers (NaN or infinite); fix or "
                          "remove those vertices")
    if len(polys) > 1:
        warnings.warn(f"{path}: {len(polys)} polygon features; using the largest", stacklevel=2)
    if polys.crs.is_geographic:
        minx, miny, maxx, maxy = polys.total_bounds
        if not (-180 <= minx <= maxx <= 360 and -90 <= miny <= maxy <= 90):
            declared = declared_crs(path)
            why = (f"the file declares the CRS {declared!r}, which the reader does not know and read as WGS 84"
                   if declared else "GeoJSON without a CRS means WGS 84")
            raise RegionError(f"{path}: the coordinates ({minx:.6g} … {maxx:.6g}, {miny:.6g} … {maxy:.6g}) are not "
                              f"longitudes and latitudes, but the file's CRS is {polys.crs.to_string()} ({why}); "
                              "write the file with the CRS its coordinates are in")
    check_area_of_use(path, polys)
    utm = estimate_utm(polys, path)
    areas = polys.to_crs(utm).area
    row = polys.loc[areas.idxmax()]
    props = {k: v for k, v in row.items() if k != "geometry" and isinstance(v, (str, int, float))}
    return row.geometry, polys.crs, props


# Real areas a buoy swarm covers: smaller is a pond a buoy spans, larger is not a lake (a continent is ~1e13 m²)
MIN_AREA_M2, MAX_AREA_M2 = 100.0, 1e11
MAX_VERTICES = 2_000  # an outline's vertices: shore rays, wall steps and clippings scale with them (Mae Kuang: 1,712)


def simplified_outline(utm: Polygon) -> tuple[Polygon, str]:
    """An outline of more than ``MAX_VERTICES`` vertices simplified (Douglas-Peucker, islands kept) with the
    smallest tolerance, doubling from 1e-4 of the lake's size, that brings it under them → (outline, a note saying
    by how much, or "")."""
    count = shapely.get_num_coordinates(utm)
    if count <= MAX_VERTICES:
        return utm, ""
    tolerance = 1e-4 * math.sqrt(utm.area)
    simple = utm
    while shapely.get_num_coordinates(simple) > MAX_VERTICES:
        simple = check_polygon(shapely.simplify(utm, tolerance, preserve_topology=True), "the simplified outline")
        tolerance *= 2
    change = abs(simple.area - utm.area) / utm.area
    return simple, (f"the outline's {count:,} vertices were simplified to {shapely.get_num_coordinates(simple):,}, "
                    f"no point moved more than {tolerance / 2:.3g} m (area changed by {change:.3%})")


def estimate_utm(frame, what) -> object:
    """The UTM CRS of ``frame``'s geometries, or a RegionError that says why there is none."""
    try:
        return frame.estimate_utm_crs()
    except RuntimeError as exc:
        raise RegionError(f"{what}: no UTM zone fits this outline ({exc}: it may lie near a pole or span many "
                          "zones); project it into a metric CRS of your own and pass that file") from None


def region_from_geometry(
    name: str,
    geometry,
    crs,
    area: float | None = 9.0,
    source: str = "",
    attribution: str = "",
) -> Region:
    """Geometry in any CRS → UTM (``estimate_utm_crs``) → centred → scaled to ``area`` (``None``: real scale)."""
    import geopandas as gpd

    if crs is None:
        raise RegionError(f"{name}: the geometry has no CRS")
    notes: list[str] = []
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        poly = check_polygon(geometry, name)
    for w in caught:
        notes.append(str(w.message))
        warnings.warn(str(w.message), stacklevel=2)
    gs = gpd.GeoSeries([poly], crs=crs)
    utm_crs = estimate_utm(gs, name)
    utm_poly = check_polygon(gs.to_crs(utm_crs).iloc[0], f"{name} (UTM)")
    if not MIN_AREA_M2 <= utm_poly.area <= MAX_AREA_M2:
        raise RegionError(f"{name}: its area is {utm_poly.area:.4g} m², outside the {MIN_AREA_M2:g}-{MAX_AREA_M2:g} m² "
                          "of a waterbody a buoy swarm covers; check the outline and its CRS")
    utm_poly, simplified = simplified_outline(utm_poly)
    if simplified:
        notes.append(simplified)
        warnings.warn(simplified, stacklevel=2)
    sim, scale, offset = normalise(utm_poly, area)
    if area is not None:
        notes.append(f"scaled to {area:g} m²: 1 simulation metre = {scale:.1f} m ({utm_crs.to_string()})")
    return Region(
        name=name,
        polygon=check_polygon(sim, name),
        scale=scale,
        utm_crs=utm_crs.to_string(),
        offset=offset,
        source=source,
        attribution=attribution,
        notes=tuple(notes),
    )


def region_from_file(path: str | Path, name: str | None = None, area: float | None = 9.0) -> Region:
    """Any vector file (GeoJSON, shapefile, GeoPackage ...) in any CRS → a region (SPEC §2)."""
    path = Path(path)
    geometry, crs, props = read_outline(path)
    attribution = ""
    if path.suffix.lower() in (".geojson", ".json"):
        try:
            attribution = json.loads(path.read_text()).get("attribution", "")
        except (ValueError, UnicodeDecodeError):
            attribution = ""
    if not attribution and props.get("attribution"):  # the feature's own, with its licence
        licence = props.get("licence", props.get("license"))
        attribution = str(props["attribution"]) + (f" (licence: {licence})" if licence else "")
    source = props.get("source", props.get("NAME", props.get("name", path.name)))
    source = source if isinstance(source, str) else str(props.get("upstream", props.get("name", path.name)))
    return region_from_geometry(name or path.stem, geometry, crs, area, source=source, attribution=attribution)


def make_region(name: str, spec, area: float, root: str | Path = ".") -> Region:
    """Build the region named in ``params.yaml`` (``regions.<name>``), scaled to ``area``."""
    if spec.kind == "box":
        if spec.width is None or spec.height is None:
            raise RegionError(f"regions.{name}: a box needs width and height")
        region = box_region(name, spec.width, spec.height)
        if not math.isclose(region.area, area, rel_tol=1e-9):
            raise RegionError(f"regions.{name}: box area {region.area:g} m² differs from world.region_area {area:g}")
        return region
    if spec.path is None:
        raise RegionError(f"regions.{name}: a file region needs a path")
    path = Path(root) / spec.path
    if not path.exists() and (Path(spec.path).name == "bedok_outline.geojson"):
        from replicate.core.params import packaged

        path = packaged("bedok_outline.geojson")  # outside the repository: the outline installed with the package
    return region_from_file(path, name=name, area=area)


def signed_distance(polygon: Polygon, xy: np.ndarray) -> np.ndarray:
    """D(x) of eq. (sw-RegAtt): Euclidean distance to the boundary, negative inside. xy: [..., 2] → [...]."""
    xy = np.asarray(xy, dtype=float)
    flat = xy.reshape(-1, 2)
    dist = shapely.distance(polygon.exterior, shapely.points(flat))
    for interior in polygon.interiors:
        dist = np.minimum(dist, shapely.distance(interior, shapely.points(flat)))
    inside = shapely.contains_xy(polygon, flat[:, 0], flat[:, 1])
    return np.where(inside, -dist, dist).reshape(xy.shape[:-1])


RUN_REGION = "region.json"  # a run's region, written beside its actors: evaluate, export and resume read it


def write_run_region(run: Path, region: Region) -> None:
    """The region a run trains on, into the run folder: its polygon in simulation metres (WKB, exact: WKT rounds)
    and the map transform, so a run trained on a file is evaluated, exported and resumed without the file."""

    artifacts.write_json(Path(run) / RUN_REGION, {
        "name": region.name, "wkb_hex": shapely.to_wkb(region.polygon, hex=True), "scale": region.scale,
        "utm_crs": region.utm_crs, "offset": list(region.offset), "source": region.source})


def read_run_region(run: Path) -> Region | None:
    """The region a run folder records (``write_run_region``, or a bare ``region.wkt``), else None."""
    run = Path(run)
    try:
        if (run / RUN_REGION).exists():
            d = json.loads((run / RUN_REGION).read_text())
            return Region(d["name"], shapely.from_wkb(d["wkb_hex"]), float(d["scale"]), d["utm_crs"],
                          tuple(d["offset"]), d.get("source", "synthetic"))
        if (run / "region.wkt").exists():
            return Region(run.name, shapely.from_wkt((run / "region.wkt").read_text()))
    except (ValueError, KeyError, TypeError, shapely.errors.GEOSException) as exc:
        raise RegionError(f"{run}: the run's region record is damaged ({exc}); pass --region") from None
    return None


def at_density(region: Region, drawn_for: int, n_agents: int) -> Region:
    """``region`` scaled for ``n_agents`` buoys at the density it was drawn for (the same N·A(Cov)/A(Reg))."""
    s = (n_agents / drawn_for) ** 0.5
    return dataclasses.replace(region, polygon=affinity.scale(region.polygon, s, s, origin=(0, 0)),
                               scale=region.scale / s)
