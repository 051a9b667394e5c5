"""The fast geometry against the exact shapely reference on random configurations of every region (SPEC §4)."""

from __future__ import annotations

import numpy as np
import pytest
import shapely

from replicate.world.geometry import CoverageGeometry, cover_terms_exact, minkowski, polygon_offsets, union_area_exact

REGIONS = ("square", "rectangle", "bedok")


@pytest.fixture(scope="module")
def geometries(params, regions):
    c = params.coverage
    return {
        name: CoverageGeometry(regions[name].polygon, c.radius, c.edges, c.table_spacing, c.raster_spacing)
        for name in REGIONS
    }


def random_configs(region, rng, n_env=150, n=9):
    """Half uniform over the region's box grown by 1 m, half clumped around a random interior point."""
    minx, miny, maxx, maxy = region.bounds
    spread = rng.uniform((minx - 1, miny - 1), (maxx + 1, maxy + 1), (n_env // 2, n, 2))
    centre = rng.uniform((minx, miny), (maxx, maxy), (n_env - n_env // 2, 1, 2))
    clumped = centre + rng.normal(0.0, 0.4, (n_env - n_env // 2, n, 2))
    return np.concatenate([spread, clumped])


@pytest.mark.parametrize("name", REGIONS)
def test_cover_terms_match_shapely(name, regions, geometries, params):
    region = regions[name].polygon
    xy = random_configs(region, np.random.default_rng(1))
    exact = cover_terms_exact(region, xy, params.coverage.radius, params.coverage.edges)
    fast = geometries[name].cover_terms(xy)
    np.testing.assert_array_equal(fast.inside, exact.inside)
    np.testing.assert_array_equal(fast.disjoint, exact.disjoint)
    assert np.abs(fast.area - exact.area).max() < 1e-3  # SPEC §4: per-agent terms within 1e-3 m²
    assert np.abs(fast.distance - exact.distance).max() < 1e-9  # exact: distance to Reg ⊕ K


@pytest.mark.parametrize("name", REGIONS)
def test_union_matches_shapely(name, regions, geometries, params):
    region = regions[name].polygon
    xy = random_configs(region, np.random.default_rng(2))
    geo = geometries[name]
    exact = union_area_exact(region, xy, params.coverage.radius, params.coverage.edges)
    fast = geo.union_area(xy, geo.cover_terms(xy).area)
    assert np.abs(fast - exact).max() < 0.005 * region.area  # SPEC §4: within 0.5 % of A(Reg)


@pytest.mark.parametrize("name", REGIONS)
def test_marginal_contribution_matches_shapely(name, regions, geometries, params):
    """A(∪_b Cov(b) ∩ Reg) − A(∪_{b≠a} Cov(b) ∩ Reg), the difference reward, per agent."""
    region = regions[name].polygon
    c = params.coverage
    xy = random_configs(region, np.random.default_rng(3), n_env=20)
    geo = geometries[name]
    union, marginal = geo.union_area(xy, geo.cover_terms(xy).area, marginal=True)
    full = union_area_exact(region, xy, c.radius, c.edges)
    for a in range(xy.shape[1]):
        without = union_area_exact(region, np.delete(xy, a, axis=1), c.radius, c.edges)
        assert np.abs(marginal[:, a] - (full - without)).max() < 0.005 * region.area
    assert np.abs(union - full).max() < 0.005 * region.area


def raster_counts(geo, xy, area):
    """The raster kernel's outputs by brute force: every cell of every stamp visited (no clipping) →
    (excess cells [E], cells shared with another stamp [E, N]); stamps in agent order as in the kernel."""
    n_env, n = area.shape
    excess, shared = np.zeros(n_env), np.zeros((n_env, n))
    diff = xy[:, :, None, :] - xy[:, None, :, :]
    close = (diff**2).sum(-1) < (2 * geo.radius) ** 2
    close[:, np.arange(n), np.arange(n)] = False
    involved = close.any(axis=2) & (area > 0)
    for e in range(n_env):
        stamps = {}
        for a in np.nonzero(involved[e])[0]:
            u = (xy[e, a] - geo.raster_origin) / geo.raster_h
            cell = np.floor(u).astype(int)
            q = ((u - cell) * geo.subpixel).astype(int)
            k = q[0] * geo.subpixel + q[1]
            cols = np.arange(2 * geo.stencil_reach + 1)
            stamps[a] = {(cell[0] + c - geo.stencil_reach) * geo.ny + cell[1] + y
                         for c in cols for y in range(geo.stencil_lo[k, c], geo.stencil_hi[k, c] + 1)
                         if geo.mask[(cell[0] + c - geo.stencil_reach) * geo.ny + cell[1] + y]}
        for a, cells in stamps.items():
            others = set().union(*(stamps[b] for b in stamps if b != a))
            earlier = set().union(*(stamps[b] for b in stamps if b < a))
            excess[e] += len(cells & earlier)
            shared[e, a] = len(cells & others)
    return excess, shared


@pytest.mark.parametrize("name", REGIONS)
def test_raster_kernel_counts_every_shared_cell(name, regions, geometries):
    """The kernel sweeps runs of rows, not cells: its union and each stamp's shared cells must equal those of
    counting every cell of every stamp."""
    region = regions[name].polygon
    xy = random_configs(region, np.random.default_rng(4), n_env=24)
    geo = geometries[name]
    area = geo.cover_terms(xy).area
    excess, shared = raster_counts(geo, xy, area)
    assert_kernel_counts(geo, xy, area, excess, shared)
    assert excess.sum() > 0 and (shared == 0).any()  # both overlapping and lone stamps were drawn


def assert_kernel_counts(geo, xy, area, excess, shared):
    """``union_area``, plain and marginal, equals the brute-force counts exactly."""
    h2 = geo.raster_h**2
    union, marginal = geo.union_area(xy, area, marginal=True)
    np.testing.assert_allclose(union, area.sum(axis=1) - excess * h2, rtol=0, atol=1e-12)
    np.testing.assert_allclose(geo.union_area(xy, area), union, rtol=0, atol=0)  # the plain path's own sweep
    expected = np.where(shared > 0, np.maximum(area - shared * h2, 0.0), area)
    np.testing.assert_allclose(marginal, expected, rtol=0, atol=1e-12)


@pytest.mark.parametrize("edges, spacing", [(30, 0.25), (4, 0.1), (3, 0.25), (6, 0.05)])
def test_raster_kernel_counts_on_coarse_grids_few_edges_and_ties(edges, spacing, regions):
    """The kernel on other coverage polygons and rasters down to the coarsest allowed (R/2), with buoys on the
    grid's lines (ties between runs' ends), on the same point, and exactly 2R apart."""
    region, radius = regions["bedok"].polygon, 0.5
    geo = CoverageGeometry(region, radius, edges, 0.05, spacing)
    rng = np.random.default_rng(5)
    xy = random_configs(region, rng, n_env=16)
    snapped = geo.raster_origin + np.round((xy - geo.raster_origin) / spacing) * spacing  # on the grid's lines
    twins = xy.copy()
    twins[:, 1] = twins[:, 0]  # two buoys on one point
    apart = xy.copy()
    apart[:, 1] = apart[:, 0] + [2 * radius, 0.0]  # exactly 2R: not "close"
    xy = np.concatenate([xy, snapped, twins, apart])
    area = geo.cover_terms(xy).area
    assert_kernel_counts(geo, xy, area, *raster_counts(geo, xy, area))


def test_coverage_geometry_refuses_a_raster_coarser_than_half_the_radius(regions):
    with pytest.raises(ValueError, match="R/2"):
        CoverageGeometry(regions["square"].polygon, 0.5, 30, 0.01, 0.3)


def test_union_is_exact_without_overlaps(regions, geometries, params):
    """No two coverage polygons overlap → the union is the sum of the per-agent terms, no raster involved."""
    xy = np.array([[[x, y] for x in (-1.0, 0.0, 1.0) for y in (-1.0, 0.0, 1.0)]])  # the 3 × 3 grid
    geo = geometries["square"]
    exact = union_area_exact(regions["square"].polygon, xy, params.coverage.radius, params.coverage.edges)
    terms = geo.cover_terms(xy)
    assert geo.union_area(xy, terms.area)[0] == terms.area.sum()
    assert geo.union_area(xy, terms.area)[0] == pytest.approx(exact[0], abs=9 * 1e-3)
    assert exact[0] / 9.0 == pytest.approx(0.780, abs=5e-4)  # SPEC §7: the grid reaches the ceiling


def test_minkowski_erosion_and_dilation_are_exact(regions):
    region = regions["bedok"].polygon
    offsets = polygon_offsets(0.5, 30)
    eroded, dilated = minkowski(region, offsets)
    rng = np.random.default_rng(4)
    minx, miny, maxx, maxy = dilated.bounds
    pts = rng.uniform((minx, miny), (maxx, maxy), (3000, 2))
    cov = shapely.polygons(pts[:, None, :] + offsets)
    np.testing.assert_array_equal(shapely.contains_xy(eroded, pts[:, 0], pts[:, 1]), shapely.within(cov, region))
    np.testing.assert_array_equal(shapely.contains_xy(dilated, pts[:, 0], pts[:, 1]), shapely.intersects(cov, region))


def test_exact_contact_follows_eq5_with_closed_sets(regions, params):
    """Coverage polygons touching the square's left side exactly, from inside and from outside (K reaches R to
    the left: it has a vertex at 180°), plus random configurations: the fast branches are the shapely reference's
    ("inside", "partial" with area 0), not one case lower as an open reading of the sets would score them."""
    c = params.coverage
    region = regions["square"].polygon
    minx = region.bounds[0]
    touch = np.array([[[minx + c.radius, 0.0], [minx - c.radius, 0.0], [minx + c.radius, 0.3],
                       [minx - c.radius, -0.7]]])
    exact = cover_terms_exact(region, touch, c.radius, c.edges)
    assert exact.inside[0].tolist() == [True, False, True, False]
    assert exact.disjoint[0].tolist() == [False, False, False, False]
    closed = CoverageGeometry(region, c.radius, c.edges, c.table_spacing, c.raster_spacing)
    fast = closed.cover_terms(touch)
    np.testing.assert_array_equal(fast.inside, exact.inside)
    np.testing.assert_array_equal(fast.disjoint, exact.disjoint)
    assert np.abs(fast.area - exact.area).max() < 1e-3 and np.all(fast.distance == 0.0)
    assert fast.inside[0].tolist() == [True, False, True, False] and not fast.disjoint.any()
    xy = random_configs(region, np.random.default_rng(7))
    exact, fast = cover_terms_exact(region, xy, c.radius, c.edges), closed.cover_terms(xy)
    np.testing.assert_array_equal(fast.inside, exact.inside)
    np.testing.assert_array_equal(fast.disjoint, exact.disjoint)
