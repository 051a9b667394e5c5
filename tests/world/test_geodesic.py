"""Geodesic cells through the water (``replicate.world.geodesic``) and geodesic Lloyd against Euclidean Lloyd."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
import shapely
from shapely.geometry import box

from replicate.compare import baselines
from replicate.core.studies import LloydConfig
from replicate.world.env import CoverageEnv
from replicate.world.geodesic import geodesic_cells, geodesic_targets, water_graph

SQUARE = box(-1.5, -1.5, 1.5, 1.5)
U_LAKE = box(0, 0, 3, 1).union(box(0, 0, 1, 3)).union(box(2, 0, 3, 3))  # two arms joined at the bottom


def test_edges_stay_in_the_water():
    """No edge of the raster graph crosses land: not the U's middle, not a 1 cm spit."""
    spit = box(0, 0, 2, 2).difference(box(0.995, 0.3, 1.005, 2.0))
    for lake in (U_LAKE, spit):
        g = water_graph(lake, 0.1)
        a, b = g.graph.nonzero()
        assert shapely.covers(lake, shapely.linestrings(np.stack([g.points[a], g.points[b]], axis=1))).all()
        assert shapely.contains_xy(lake, g.points[:, 0], g.points[:, 1]).all()
    g = water_graph(spit, 0.1)
    cells = geodesic_cells(g, np.array([[0.5, 1.9], [1.5, 1.9]]))
    left = g.points[:, 0] < 1.0
    assert (cells.owner[left & (g.points[:, 1] > 0.3)] == 0).all()  # either side of the spit is its buoy's
    assert (cells.owner[~left & (g.points[:, 1] > 0.3)] == 1).all()


def test_on_a_convex_lake_the_targets_are_lloyds_to_the_raster():
    g = water_graph(SQUARE, 0.05)
    for seed in range(3):
        xy = np.random.default_rng(seed).uniform(-1.4, 1.4, (9, 2))
        target, _, distance = geodesic_targets(g, xy, 0.5)
        np.testing.assert_allclose(target, baselines.voronoi_centroids(SQUARE, xy), atol=0.1)
        assert np.all(np.abs(distance - np.linalg.norm(target - xy, axis=1)) <= 0.1 + 0.05 * distance)


def test_in_a_u_shaped_lake_a_buoy_sails_around_the_land():
    """One buoy at the tip of the U's left arm: the distance to the tip of the right arm is the way round the
    bottom (about 4.9 m, the straight line is 2 m); the centroid of its cell, the whole U, lies on the land
    between the arms, so its target is the nearest water, and its waypoint leads down its own arm, the leg to it
    in the water."""
    g = water_graph(U_LAKE, 0.05)
    xy = np.array([[0.5, 2.9]])
    cells = geodesic_cells(g, xy)
    far_tip = g.tree.query([2.5, 2.9])[1]
    assert 4.8 < cells.distance[far_tip] < 5.2
    target, waypoint, distance = geodesic_targets(g, xy, 0.5)
    assert shapely.covers(U_LAKE, shapely.points(target)).all()
    assert shapely.contains_xy(box(1, 1, 2, 3), 1.5, 1.36)  # where the cell's centroid lies: land
    assert waypoint[0, 0] < 1.0 and waypoint[0, 1] < 2.9 - 0.3  # down its own arm
    assert shapely.covers(U_LAKE, shapely.linestrings(np.stack([xy, waypoint], axis=1))).all()
    assert distance[0] > np.linalg.norm(target[0] - xy[0]) + 0.3  # sailing is longer than flying


@pytest.mark.parametrize("m", [2, 3, 6])
def test_buoys_at_one_point_get_cells_and_targets_of_their_own(m):
    g = water_graph(SQUARE, 0.1)
    corner = np.array([1.5, -1.5])
    xy = np.vstack([np.repeat(corner[None], m, axis=0), [[0.0, 0.0], [-1.0, 1.0]]])
    cells = geodesic_cells(g, xy)
    assert len(set(cells.source)) == len(xy)
    target, _, _ = geodesic_targets(g, xy, 0.5)
    assert len({tuple(t) for t in target[:m]}) == m


def test_geodesic_lloyd_covers_the_square_as_lloyd_does_behind_the_wall(params, regions):
    """On a convex lake geodesic Lloyd is Lloyd to the raster: with a brisk gain (as the tuned Lloyd's), the same
    coverage at T within 0.01, and no buoy outside the water."""
    square = regions["square"]
    world = dataclasses.replace(params.world, n_agents=9)
    gains = LloydConfig(gain=50.0, damping=0.2, converged_steps=0)
    cover = {}
    for name, policy in (("lloyd", baselines.lloyd(gains)),
                         ("geodesic", baselines.geodesic_lloyd(gains, spacing=0.05, lookahead=0.5))):
        env = CoverageEnv(square, world, params.coverage, n_envs=8, reward=None, wall=True)
        env.reset(seed=5)
        for _ in range(world.episode_length):
            env.step(policy(env))
        assert shapely.covers(square.polygon, shapely.points(env.pos.reshape(-1, 2))).all()
        cover[name] = float(env.coverage_fraction().mean())
    assert cover["lloyd"] > 0.77
    assert cover["geodesic"] == pytest.approx(cover["lloyd"], abs=0.01)
