"""Regions (SPEC §2): the paper's three, any file in any CRS, and a clear refusal of bad input."""

from __future__ import annotations

import json
import re

import numpy as np
import pytest
import shapely
from shapely.geometry import LineString, MultiPolygon, Point, Polygon, box

from replicate.world.regions import (
    RegionError,
    box_region,
    check_polygon,
    region_from_file,
    region_from_geometry,
    signed_distance,
)


def test_paper_regions(regions):
    assert regions["square"].polygon.bounds == (-1.5, -1.5, 1.5, 1.5)
    assert regions["rectangle"].polygon.bounds == (-4.5, -0.5, 4.5, 0.5)
    for region in regions.values():
        assert region.area == pytest.approx(9.0, rel=1e-9)


def test_bedok_goes_through_utm_48n(regions):
    bedok = regions["bedok"]
    assert bedok.utm_crs == "EPSG:32648"
    centroid = bedok.polygon.centroid
    assert abs(centroid.x) < 1e-9 and abs(centroid.y) < 1e-9
    # data/README.md: 833,275 m² in UTM 48N → 1 simulation metre ≈ sqrt(833275 / 9) ≈ 304 m
    assert bedok.scale == pytest.approx(np.sqrt(833_275 / 9), rel=1e-3)
    assert any("304" in note for note in bedok.notes)
    assert "Singapore Open Data Licence" in bedok.attribution


def test_any_crs_gives_the_same_region(tmp_path):
    """A polygon written in lon/lat and the same polygon written in Web Mercator give the same region."""
    import geopandas as gpd

    lonlat = Polygon([(103.92, 1.34), (103.925, 1.34), (103.925, 1.343), (103.921, 1.344)])
    gdf = gpd.GeoDataFrame({"name": ["lake"]}, geometry=[lonlat], crs="EPSG:4326")
    gdf.to_file(tmp_path / "a.geojson")
    gdf.to_crs("EPSG:3857").to_file(tmp_path / "b.gpkg")
    a = region_from_file(tmp_path / "a.geojson")
    b = region_from_file(tmp_path / "b.gpkg")
    assert a.utm_crs == b.utm_crs == "EPSG:32648"
    assert a.polygon.area == pytest.approx(9.0)
    assert a.polygon.symmetric_difference(b.polygon).area < 1e-6
    real = region_from_file(tmp_path / "a.geojson", area=None)  # real scale: kept in metres
    assert real.scale == 1.0 and real.area > 100_000


def test_signed_distance(regions):
    d = signed_distance(regions["square"].polygon, np.array([[0.0, 0.0], [1.0, 0.0], [2.0, 0.0], [2.0, 2.0]]))
    np.testing.assert_allclose(d, [-1.5, -0.5, 0.5, np.hypot(0.5, 0.5)])


def test_box_region_rejects_bad_size():
    with pytest.raises(RegionError, match="positive"):
        box_region("flat", 3.0, 0.0)


@pytest.mark.parametrize(
    "geom, message",
    [
        (Polygon(), "empty"),
        (Polygon([(0, 0), (1, 1), (1, 0), (0, 1)]), "invalid polygon.*Self-intersection"),
        (LineString([(0, 0), (1, 1)]), "expected a Polygon, got a LineString"),
        (Point(0, 0), "expected a Polygon, got a Point"),
        (None, "no geometry"),
        ("POLYGON", "expected a shapely geometry"),
    ],
)
def test_bad_geometry_is_refused(geom, message):
    with pytest.raises(RegionError, match=message):
        check_polygon(geom)


def test_multipolygon_uses_largest_part_and_says_so():
    geom = MultiPolygon([box(0, 0, 1, 1), box(5, 5, 8, 8)])
    with pytest.warns(UserWarning, match="largest"):
        poly = check_polygon(geom)
    assert poly.area == 9.0


def test_geometry_without_crs_is_refused():
    with pytest.raises(RegionError, match="no CRS"):
        region_from_geometry("lake", box(0, 0, 1, 1), crs=None)


def write_geojson(path, features, crs=True):
    doc = {"type": "FeatureCollection", "features": features}
    if crs:
        doc["crs"] = {"type": "name", "properties": {"name": "urn:ogc:def:crs:OGC:1.3:CRS84"}}
    path.write_text(json.dumps(doc))
    return path


def feature(geom):
    return {"type": "Feature", "properties": {}, "geometry": shapely.geometry.mapping(geom)}


def test_bad_files_are_refused(tmp_path):
    with pytest.raises(RegionError, match="no such file"):
        region_from_file(tmp_path / "missing.geojson")
    (tmp_path / "junk.geojson").write_text("this is not json {")
    with pytest.raises(RegionError, match="cannot be read"):
        region_from_file(tmp_path / "junk.geojson")
    empty = write_geojson(tmp_path / "empty.geojson", [])
    with pytest.raises(RegionError, match="no features"):
        region_from_file(empty)
    lines = write_geojson(tmp_path / "lines.geojson", [feature(LineString([(103.9, 1.3), (103.91, 1.31)]))])
    with pytest.raises(RegionError, match="no polygon features"):
        region_from_file(lines)
    bowtie = Polygon([(103.9, 1.3), (103.91, 1.31), (103.91, 1.3), (103.9, 1.31)])
    bad = write_geojson(tmp_path / "bowtie.geojson", [feature(bowtie)])
    with pytest.raises(RegionError, match="invalid polygon"):
        region_from_file(bad)


def test_file_without_crs_is_refused(tmp_path):
    import geopandas as gpd

    with pytest.warns(UserWarning, match="crs"):
        gpd.GeoDataFrame(geometry=[box(0, 0, 10, 10)]).to_file(tmp_path / "nocrs.shp")
    with pytest.raises(RegionError, match="no CRS"):
        region_from_file(tmp_path / "nocrs.shp")


@pytest.mark.parametrize("name, geometry, crs, message", [
    ("projected", box(380000, 148000, 381000, 149000), "EPSG:4326", "are not longitudes and latitudes"),
    ("pole", Polygon([(0, 89), (120, 89), (-120, 89.5)]), "EPSG:4326", "no UTM zone fits"),
    ("continent", box(-10, 35, 40, 60), "EPSG:4326", "outside the 100-1e+11 m²"),
    ("puddle", box(103.9, 1.3, 103.90001, 1.30001), "EPSG:4326", "its area is 1.23 m²"),
])
def test_outlines_no_buoy_swarm_can_use_are_refused_with_the_reason(tmp_path, name, geometry, crs, message):
    import geopandas as gpd

    path = tmp_path / f"{name}.geojson"
    if name == "projected":  # a GeoJSON written without a CRS: readers take WGS 84
        path.write_text(json.dumps({"type": "FeatureCollection", "features": [
            {"type": "Feature", "properties": {}, "geometry": shapely.geometry.mapping(geometry)}]}))
    else:
        gpd.GeoDataFrame(geometry=[geometry], crs=crs).to_file(path)
    with pytest.raises(RegionError, match=re.escape(message)):
        region_from_file(path)


def test_an_outline_of_200000_vertices_is_simplified_and_says_by_how_much():
    """A lake of 200,000 vertices with a 20,000-vertex island (1.2 x 0.7 km, its shore rippled by 3 m): simplified
    to at most ``MAX_VERTICES``, the island kept, the tolerance and the area's change in the notes (a lake this
    dense once gave no result after 445 s)."""
    from replicate.world.regions import MAX_VERTICES, region_from_geometry

    t = np.linspace(0, 2 * np.pi, 200_000, endpoint=False)
    r = 600 + 80 * np.sin(7 * t) + 3 * np.sin(997 * t)
    h = np.linspace(0, 2 * np.pi, 20_000, endpoint=False)
    lake = shapely.Polygon(np.c_[500_000 + r * np.cos(t), 6_219_500 + 0.6 * r * np.sin(t)],
                           [np.c_[500_000 + 100 * np.cos(h), 6_219_500 + 60 * np.sin(h)]])
    with pytest.warns(UserWarning, match="simplified"):
        region = region_from_geometry("dense", lake, "EPSG:32641", area=None)
    assert shapely.get_num_coordinates(region.polygon) <= MAX_VERTICES and len(region.polygon.interiors) == 1
    note = next(n for n in region.notes if "simplified" in n)
    assert "no point moved more than" in note and abs(region.area - lake.area) / lake.area < 1e-3
