"""The water near each point of a long shore (``world.local_water``) against shapely's overlay of the whole outline:
on the real lakes of ``data/lakes/`` (arms, islands) and a box, for points in the water, on the shore and off it."""

from __future__ import annotations

import numpy as np
import pytest
import shapely
from shapely.geometry import box

from replicate.world.geometry import long_shore, polygon_offsets
from replicate.world.local_water import LocalWater
from replicate.world.regions import region_from_file

from ..conftest import ROOT


@pytest.mark.parametrize("lake", ["mae_kuang_reservoir", "lake_silach", "box"])
def test_the_overlap_areas_are_shapelys(params, lake):
    """A(K(p) ∩ Reg) for 4,000 points over the lake's box grown by R, and the clipped polygons, agree with
    shapely's intersection with the whole outline to float rounding (1e-12 of A(K))."""
    region = (box(0, 0, 3, 3) if lake == "box" else
              region_from_file(ROOT / "data" / "lakes" / f"{lake}.geojson", area=params.world.region_area).polygon)
    r, offsets = params.coverage.radius, polygon_offsets(params.coverage.radius, params.coverage.edges)
    minx, miny, maxx, maxy = region.bounds
    points = np.random.default_rng(0).uniform([minx - r, miny - r], [maxx + r, maxy + r], size=(4000, 2))
    polygons = shapely.polygons(points[:, None] + offsets)
    want = shapely.area(shapely.intersection(polygons, region))
    water = LocalWater.of(region, r)
    full = shapely.Polygon(offsets).area
    assert np.abs(water.overlap_areas(points, offsets) - want).max() < 1e-12 * full
    assert np.abs(shapely.area(water.clip(polygons, points)) - want).max() < 1e-12 * full
    assert ((want > 0) & (want < full - 1e-9)).mean() > 0.2  # the shore is well sampled, not only open water


def test_only_long_shores_take_the_local_water(params, regions):
    """The area tables of every region a committed run trained on stay shapely's (``geometry.LONG_SHORE_VERTICES``);
    the real reservoirs with arms and islands take the local water."""
    assert not any(long_shore(r.polygon) for r in regions.values())
    for lake in ("mae_kuang_reservoir", "lake_silach"):
        assert long_shore(region_from_file(ROOT / "data" / "lakes" / f"{lake}.geojson").polygon)


def test_lloyds_cells_on_a_long_shore_have_shapelys_centroids(params, monkeypatch):
    """Clairvoyant Lloyd's targets on Mae Kuang (1,712 vertices): the clipped Voronoi cells' centroids by the
    compiled clipping equal shapely's to 1e-8 m (the rounding of a cell holding a sliver of water, over its area),
    with small fleets bunched over the lake and its land (cells all on land go to the nearest water), a shared
    point, one buoy (its cell is the whole lake) and no usable diagram."""
    from replicate.compare import baselines

    region = region_from_file(ROOT / "data" / "lakes" / "mae_kuang_reservoir.geojson",
                              area=params.world.region_area).polygon
    minx, miny, maxx, maxy = region.bounds
    rng = np.random.default_rng(1)
    spread = rng.uniform([minx, miny], [maxx, maxy], size=(40, 9, 2))
    spread[3, 2] = spread[3, 1]
    bunched = rng.uniform([minx, miny], [maxx, maxy], size=(400, 1, 2)) + rng.normal(0, 0.01, size=(400, 3, 2))
    lone = spread[:5, :1]
    fast = [baselines.voronoi_centroids(region, xy) for xy in (spread, bunched, lone)]
    monkeypatch.setattr(baselines, "long_shore", lambda region: False)
    for got, xy in zip(fast, (spread, bunched, lone)):
        np.testing.assert_allclose(got, baselines.voronoi_centroids(region, xy), rtol=0, atol=1e-8)
    assert not shapely.intersects_xy(region, bunched[..., 0], bunched[..., 1]).all()  # some cells are dry
    dry = baselines.water_centroids(region, np.array([], dtype=object), 3)
    assert [part.shape for part in dry] == [(0, 3, 2), (0, 3), (0, 1)]


def test_the_area_table_of_a_long_shore_is_shapelys(params):
    """The area table of Lake Silach (861 vertices: ``local_water``) against shapely's at its nodes, at the paper's
    scale and in metres (a 60 m radius: coordinates of kilometres, tiles cut only where asked)."""
    from replicate.world.geometry import _build_area_table, minkowski

    lake = ROOT / "data" / "lakes" / "lake_silach.geojson"
    for region, radius in ((region_from_file(lake, area=params.world.region_area).polygon, params.coverage.radius),
                           (region_from_file(lake, area=None).polygon, 60.0)):
        offsets = polygon_offsets(radius, params.coverage.edges)
        eroded, dilated = minkowski(region, offsets)
        h = radius / 2
        origin, _, table = _build_area_table(region.wkb, radius, params.coverage.edges, h, eroded.wkb, dilated.wkb)
        i, j = np.nonzero((table > 0) & (table < shapely.Polygon(offsets).area))
        pick = np.random.default_rng(0).choice(len(i), size=min(2000, len(i)), replace=False)
        nodes = origin + np.stack([i[pick], j[pick]], axis=1) * h
        want = shapely.area(shapely.intersection(shapely.polygons(nodes[:, None] + offsets), region))
        assert np.abs(table[i[pick], j[pick]] - want).max() < 1e-9 * shapely.Polygon(offsets).area


def test_every_generated_lake_keeps_shapelys_overlay(params):
    """The claim that no number of the generated lakes moves: every lake the general policy trains, is chosen or
    is tested on has at most ``LONG_SHORE_VERTICES`` vertices."""
    from replicate.compare.suite import suite_lakes
    from replicate.learn.training_worlds import baseline_worlds

    lakes = [r for r, _ in baseline_worlds(params, params.general)] + [r for r, _ in suite_lakes(params).values()]
    long = {r.name for r in lakes if long_shore(r.polygon)}
    assert long == {"mae_kuang_reservoir", "lake_silach"}


def test_the_greedy_layout_on_a_long_shore_is_shapelys(params):
    """On Lake Silach (861 vertices, ten islands) the greedy placement measured and scored by the compiled clipping
    places every buoy where shapely's overlay places it, and covers the same water."""
    from replicate.compare.best_layout import Candidates, covered_area, greedy, grid_spacing

    region = region_from_file(ROOT / "data" / "lakes" / "lake_silach.geojson", area=params.world.region_area).polygon
    r, e = params.coverage.radius, params.coverage.edges
    spacing = 2 * grid_spacing(region, r)
    local, shapelys = (Candidates.of(region, spacing, (0.0, 0.0), r, e, w) for w in (LocalWater.of(region, r), None))
    np.testing.assert_allclose(local.water, shapelys.water, rtol=0, atol=1e-12)
    fast = greedy(local, 9, r)
    np.testing.assert_array_equal(fast, greedy(shapelys, 9, r))
    assert covered_area(region, fast, r, e) > 0.5 * region.area
