"""The best layout (``replicate.compare.best_layout``): the offline limit every method is read against."""

import json

import numpy as np
import pytest

from replicate.compare.best_layout import best_layout, covered_area

from ..conftest import ROOT


def test_the_square_reaches_its_ceiling(params, regions):
    """Nine polygons fit in the 3 × 3 m square without overlap: the best layout covers N·A(Cov)/A(Reg)."""
    xy, coverage = best_layout(regions["square"].polygon, 9, params.coverage.radius, params.coverage.edges)
    assert coverage == pytest.approx(0.7797, abs=2e-4)
    assert coverage == pytest.approx(covered_area(regions["square"].polygon, xy, 0.5, 30) / 9.0)


def test_bedok_beats_every_committed_lloyd_layout(params, regions):
    """On Bedok the best layout lies above Lloyd's, converged (500 steps) or at T, with any gains."""
    xy, coverage = best_layout(regions["bedok"].polygon, 9, params.coverage.radius, params.coverage.edges)
    baselines = json.loads((ROOT / "metrics" / "summary.json").read_text())["baselines"]
    lloyd = max(v["coverage"] for k, v in baselines.items() if k.startswith("lloyd") and k.endswith("/bedok"))
    assert coverage > lloyd and coverage > 0.76
    assert xy.shape == (9, 2) and np.isfinite(xy).all()


def test_scoring_within_reach_gives_the_whole_fleets_layout(params):
    """Greedy placement and local search score only what lies within reach of a change; against a reference that
    scores every candidate against the whole fleet and lake they pick the same points on an L-shaped lake with an
    island."""
    import shapely
    from shapely.geometry import Polygon

    from replicate.compare.best_layout import TIE, Candidates, gains, greedy, local_search
    from replicate.world.geometry import coverage_polygons, polygon_offsets

    r, e = params.coverage.radius, params.coverage.edges
    lake = Polygon([(0, 0), (4, 0), (4, 1.5), (1.5, 1.5), (1.5, 4), (0, 4)], [[(0.5, 0.5), (0.9, 0.5), (0.9, 0.9)]])
    gx, gy = np.meshgrid(np.arange(-0.5, 4.5, 0.1), np.arange(-0.5, 4.5, 0.1))
    grid = np.stack([gx.ravel(), gy.ravel()], axis=1)
    grid = grid[shapely.intersects_xy(lake.buffer(r), grid[:, 0], grid[:, 1])]

    xy, covered = [], None
    for _ in range(8):
        g = gains(lake, covered, grid, r, e)
        xy.append(grid[int(np.argmax(g >= g.max() - TIE))])
        cov = shapely.intersection(coverage_polygons(np.array(xy[-1:]), r, e)[0], lake)
        covered = cov if covered is None else shapely.union(covered, cov)
    clipped = shapely.intersection(coverage_polygons(grid, r, e), lake)
    placed = greedy(Candidates(grid, shapely.area(clipped), clipped, None, polygon_offsets(r, e)), 8, r)
    np.testing.assert_array_equal(placed, np.array(xy))

    reference, step = placed.copy(), 0.1
    compass = np.array([[np.cos(a), np.sin(a)] for a in np.arange(8) * np.pi / 4])
    while step >= 1e-3:
        improved = False
        for i in range(len(reference)):
            rest = shapely.union_all(coverage_polygons(np.delete(reference, i, axis=0), r, e))
            moves = np.concatenate([reference[i:i + 1], reference[i] + step * compass])
            g = gains(lake, rest, moves, r, e)
            k = int(np.argmax(g))
            if k > 0 and g[k] > g[0] + TIE:
                reference[i], improved = moves[k], True
        step = step if improved else step / 2
    np.testing.assert_array_equal(local_search(lake, placed, 0.1, r, e, 1e-3), reference)


def test_every_evaluated_lake_keeps_the_tenth_of_a_radius_grid(params):
    """The cap on candidate points (``MAX_CANDIDATES``) is for lakes kept in metres: no lake, fleet and density of
    the evaluation suite or the yardstick reaches it, so their best layouts are those the grid of R/10 finds."""
    from replicate.compare import best_layout as bl
    from replicate.compare.suite import suite_cells, suite_lakes
    from replicate.compare.yardstick import yardstick_cells, yardstick_lakes
    from replicate.world.regions import at_density

    radius = params.coverage.radius
    worlds = [(suite_lakes(params), suite_cells(params)), (yardstick_lakes(params), yardstick_cells(params))]
    largest = 0.0
    for lakes, cells in worlds:
        for cell in cells:
            region, drawn_for = lakes[getattr(cell, "region", getattr(cell, "lake", None))]
            minx, miny, maxx, maxy = at_density(region, drawn_for, cell.n_agents).polygon.bounds
            largest = max(largest, (maxx - minx + 2 * radius) * (maxy - miny + 2 * radius) / (radius / 10) ** 2)
    assert 1000 < largest < bl.MAX_CANDIDATES / 2


def test_a_lake_hundreds_of_radii_across_gets_a_coarser_grid(monkeypatch):
    """A lake 120 radii across: the grid is coarsened to the cap, and the layout still reaches the ceiling (nine
    polygons fit without overlap, found by the local search from the coarse grid)."""
    from shapely.geometry import box

    from replicate.compare import best_layout as bl

    seen = []
    real_greedy = bl.greedy
    monkeypatch.setattr(bl, "greedy", lambda c, *a, **k: seen.append(len(c.grid)) or real_greedy(c, *a, **k))
    lake = box(0, 0, 60, 60)
    xy, coverage = bl.best_layout(lake, 9, 0.5, 30)
    assert max(seen) <= bl.MAX_CANDIDATES * 1.02
    assert coverage == pytest.approx(9 * covered_area(box(-1, -1, 1, 1), np.zeros((1, 2)), 0.5, 30) / 3600, rel=1e-9)


def test_lloyds_layout_is_a_start_of_the_search(params):
    """On an L-shaped lake Lloyd's layout (from a layout bunched in one corner) ends with its points in the water
    and centroidal (a further step moves no point), and the best layout covers at least as much as Lloyd's
    layout refined by the same local search, with every place in the water."""
    import shapely
    from shapely.geometry import Polygon

    from replicate.compare.baselines import voronoi_centroids
    from replicate.compare.best_layout import lloyd_layout, local_search

    r, e = params.coverage.radius, params.coverage.edges
    lake = Polygon([(0, 0), (4, 0), (4, 1.5), (1.5, 1.5), (1.5, 4), (0, 4)])
    start = np.array([[0.2 + 0.1 * k, 0.2 + 0.05 * k] for k in range(6)])
    xy = lloyd_layout(lake, start, iterations=500, tolerance=1e-6)
    assert shapely.intersects_xy(lake, xy[:, 0], xy[:, 1]).all()
    np.testing.assert_allclose(voronoi_centroids(lake, xy), xy, atol=1e-4)
    refined = covered_area(lake, local_search(lake, xy, 0.1, r, e, 1e-3), r, e) / lake.area
    best, coverage = best_layout(lake, 6, r, e)
    assert coverage >= refined - 1e-9 and shapely.intersects_xy(lake, best[:, 0], best[:, 1]).all()


def test_on_a_large_lake_the_layout_gathers_toward_the_fleet(params):
    """On a 20 × 20 m lake every full disc ties: greedy placement takes the first of them, or with ``toward`` the
    nearest to that point, and the three buoys' layout stays within a few radii of it at the same coverage."""
    import shapely
    from shapely.geometry import box

    from replicate.compare.best_layout import Candidates, greedy
    from replicate.world.geometry import coverage_polygons, polygon_offsets

    r, e = params.coverage.radius, params.coverage.edges
    lake = box(0, 0, 20, 20)
    gx, gy = np.meshgrid(np.arange(0, 20.01, 0.25), np.arange(0, 20.01, 0.25))
    grid = np.stack([gx.ravel(), gy.ravel()], axis=1)
    clipped = shapely.intersection(coverage_polygons(grid, r, e), lake)
    c = Candidates(grid, shapely.area(clipped), clipped, None, polygon_offsets(r, e))
    first = greedy(c, 3, r)
    near = greedy(c, 3, r, toward=np.array([15.0, 12.0]))
    assert np.linalg.norm(first - [15.0, 12.0], axis=1).min() > 10
    assert np.linalg.norm(near - [15.0, 12.0], axis=1).max() < 4 * r
    assert covered_area(lake, near, r, e) == pytest.approx(covered_area(lake, first, r, e))


def test_a_large_grid_clips_each_polygon_when_scored_to_the_same_numbers(params, regions, monkeypatch):
    """A grid of more than ``KEPT_CLIPS`` points keeps only its polygons' water and clips a polygon again when it
    is scored (``replicate plan`` at a field radius held 1.3 GB with every clip kept): the same water, the same
    greedy layout and the same search, bit for bit, as with every clip kept, on Bedok at N = 9."""
    import shapely

    from replicate.compare import best_layout as module

    r, e, bedok = params.coverage.radius, params.coverage.edges, regions["bedok"].polygon
    shapely.prepare(bedok)
    kept = module.Candidates.of(bedok, r / 10, (0.5, 0.5), r, e)
    layout, coverage = best_layout(bedok, 9, r, e, quick=True)
    monkeypatch.setattr(module, "KEPT_CLIPS", 1000)  # Bedok's grid holds several thousand points: parts of 1,000
    clipped = module.Candidates.of(bedok, r / 10, (0.5, 0.5), r, e)
    assert kept.clipped is not None and clipped.clipped is None and len(clipped.grid) > 3 * 1000
    np.testing.assert_array_equal(clipped.water, kept.water)
    np.testing.assert_array_equal(module.greedy(clipped, 9, r), module.greedy(kept, 9, r))
    again, same = best_layout(bedok, 9, r, e, quick=True)
    np.testing.assert_array_equal(again, layout)
    assert same == coverage


def test_a_policys_final_layout_is_a_start_of_the_search(params, monkeypatch):
    """``best_coverage_from``: the search from a policy's final layout (a point on land first moved to the nearest
    water) is kept where it beats the best layout, and never lowers it."""
    from shapely.geometry import box

    from replicate.compare import best_layout as bl

    r, e = params.coverage.radius, params.coverage.edges
    lake = box(0, 0, 3, 3)
    start = np.array([[0.5, 0.5], [1.5, 0.5], [2.5, 0.5], [0.5, 1.5], [1.5, 1.5], [2.5, 1.5], [0.5, 2.5],
                      [1.5, 2.5], [3.4, 2.5]])  # the last on land, 0.4 m east of the shore
    best, from_policy = bl.best_coverage_from(lake, 9, r, e, start)
    assert best == pytest.approx(bl.best_coverage(lake, 9, r, e)) and best >= bl.best_coverage(lake, 9, r, e)
    monkeypatch.setattr(bl, "best_coverage", lambda *args: 0.1)  # a search that found little
    found, from_policy = bl.best_coverage_from(lake, 9, r, e, start)
    moved = start.copy()
    moved[-1] = [3.0, 2.5]
    refined = bl.local_search(lake, moved, bl.grid_spacing(lake, r), r, e, 1e-3)
    assert from_policy and found == pytest.approx(covered_area(lake, refined, r, e) / lake.area) and found > 0.5


def test_one_buoys_water_tightens_the_bound_only_on_the_narrowest_rectangle(params):
    """Why the upper bound min(1, N·A(Cov)/A(Reg)) is not tightened by a strip bound (N times the most water one
    coverage polygon can hold, max_x A(Cov(x) ∩ Reg)): that is below A(Cov) only where no whole polygon fits in the
    lake, and among the suite's lakes and fleets that is the rectangle at N = 5 alone (N = 9 fits one exactly);
    elsewhere the bound's slack is the overlap the best layout cannot avoid at the shore, which no bound on one
    buoy's water sees."""
    import shapely

    from replicate.compare.suite import lake_kinds, suite_lake
    from replicate.world.regions import at_density

    su, r = params.general.suite, params.coverage.radius
    narrow = []
    for name in lake_kinds(params):
        region, drawn_for = suite_lake(params, name)
        for n in su.named_fleets if name in params.regions else su.lake_fleets:
            inscribed = shapely.maximum_inscribed_circle(at_density(region, drawn_for, n).polygon, r / 1000)
            if shapely.length(inscribed) < r * (1 - 1e-6):
                narrow.append((name, n))
    assert narrow == [("rectangle", 5)]
