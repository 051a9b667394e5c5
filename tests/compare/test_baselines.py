"""Naive swarming and Lloyd's layout: their order on the square, per-environment Voronoi cells, and the
cases that could trap them."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
import shapely

from replicate.compare import baselines, evaluate


def test_baselines_order_on_square(params, regions):
    """Lloyd's converged layout is the practical optimum: at most the ceiling, above naive and random."""
    square = regions["square"]
    p = dataclasses.replace(params, evaluate=dataclasses.replace(params.evaluate, episodes=10))
    cov = {name: evaluate.evaluate_baseline(name, p, square)["coverage"]["mean"]
           for name in ("random", "naive", "lloyd_converged")}
    assert cov["random"] < cov["naive"] < cov["lloyd_converged"] <= 0.7796 + 1e-9
    assert cov["lloyd_converged"] > 0.76
    rect = evaluate.evaluate_baseline("naive", p, regions["rectangle"])
    assert rect["steps"] == params.regions["rectangle"].episode_length == 100  # the region's own T
    cells = baselines.voronoi_centroids(square.polygon, np.array([[-1.0, 0.0], [1.0, 0.0]]))
    np.testing.assert_allclose(cells, [[-0.75, 0.0], [0.75, 0.0]], atol=1e-9)


def test_voronoi_centroids_of_many_environments_are_each_environments_own(regions):
    """The batched Lloyd targets [E, N, 2] equal each environment's alone, bit for bit, also for agents far
    outside the region and for agents at one point."""
    rng = np.random.default_rng(3)
    for region in (regions["square"].polygon, regions["bedok"].polygon):
        xy = rng.uniform(-3, 3, (12, 9, 2))
        xy[4] = 8.0 + 0.01 * rng.normal(size=(9, 2))  # the whole swarm far outside
        xy[7, 2] = xy[7, 5]  # two agents at one point
        batched = baselines.voronoi_centroids(region, xy)
        assert np.array_equal(batched, np.stack([baselines.voronoi_centroids(region, p) for p in xy]))
        assert np.isfinite(batched).all()


def test_agents_at_one_point_split_its_cell_and_steer_apart(regions):
    """The shore wall pins buoys to one vertex: GEOS has no diagram of coincident points, so they share their
    point's cell in wedges, one of whose boundaries points into the water. At a corner of the square, on Bedok's
    shore and in open water, the group gets at least two different targets (in the square, in the water), every
    other agent's target is (to the wedges' 1e-6 m) the one of the diagram without the duplicates, and a layout
    with no shared point is left exactly as it was."""
    for name in ("square", "bedok"):
        region = regions[name].polygon
        shore = np.array(region.exterior.coords[:3])  # two shore vertices and, below, a point of open water
        for point in (*shore[:2], np.array(shapely.get_coordinates(region.point_on_surface())[0]) + 0.3):
            others = np.array(shapely.get_coordinates(region.representative_point())) + [[0.05, 0.02], [-0.4, 0.3]]
            for m in (2, 3, 5):
                xy = np.vstack([np.repeat(point[None], m, axis=0), others])
                target = baselines.voronoi_centroids(region, xy)
                assert np.isfinite(target).all()
                assert len({tuple(t) for t in target[:m]}) >= 2  # the group breaks up
                if name == "square":  # a convex lake holds its cells' centroids (Bedok's arms need not)
                    assert (shapely.distance(region, shapely.points(target)) < 1e-9).all()
                alone = baselines.voronoi_centroids(region, np.vstack([point, others]))
                np.testing.assert_allclose(target[m:], alone[1:], atol=1e-5)
    xy = np.random.default_rng(0).uniform(-1.5, 1.5, (4, 9, 2))
    assert np.array_equal(baselines.separate_coincident(xy, regions["square"].polygon), xy)
    corner = np.array([[1.5, -1.5], [1.5, -1.5 + 1e-15], [0.0, 0.0]])  # 1e-15 apart: GEOS fails as on one point
    assert np.isfinite(baselines.voronoi_centroids(regions["square"].polygon, corner)).all()


def test_naive_interior_falls_back_to_the_middle_of_a_lake_too_shallow_for_a_coverage_polygon(params, regions):
    """Naive swarming's target is Reg ⊖ Cov, the fast path's eroded lake, without building the fast path; a lake
    whose deepest point is closer to the shore than R has none, and its target is then the water at least half
    that depth from the shore: non-empty, inside, off the shore."""
    from shapely.geometry import box

    from replicate.world.geometry import CoverageGeometry

    c = params.coverage
    for name in ("square", "bedok"):
        region = regions[name].polygon
        fast = CoverageGeometry(region, c.radius, c.edges, c.table_spacing, c.raster_spacing)
        assert shapely.equals_exact(baselines.interior(region, c.radius, c.edges), fast.eroded, 0)
    narrow = box(0.0, 0.0, 9.0, 0.8)  # deepest point 0.4 m from the shore, R = 0.5 m
    assert narrow.buffer(-0.5).is_empty
    middle = baselines.interior(narrow, c.radius, c.edges)
    assert not middle.is_empty and narrow.contains(middle)
    assert middle.exterior.distance(narrow.exterior) == pytest.approx(0.2)


def test_naive_swarming_steers_on_a_lake_too_large_for_the_fast_paths_tables(params):
    """A lake 400 coverage radii across (a field radius on a real lake: ``replicate cover --radius-m 25`` on Lake
    Karaguz) has no room for the fast path's area table, which an evaluation never needs: naive swarming steers
    there without building it."""
    from replicate.world.env import CoverageEnv
    from replicate.world.regions import box_region

    lake = box_region("wide", 200.0, 200.0)
    env = CoverageEnv(lake, params.world, params.coverage, n_envs=2, seed=0)
    env.reset()
    action = baselines.naive_swarming(params.evaluate.naive)(env)
    assert action.shape == (2, params.world.n_agents, 2) and np.isfinite(action).all()
    assert env._geometry is None
