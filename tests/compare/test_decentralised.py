"""Decentralised Lloyd (``compare.decentralised``): the baseline that sees what the policy sees."""

from __future__ import annotations

import numpy as np
import pytest

from replicate.compare.baselines import lloyd, voronoi_centroids
from replicate.compare.decentralised import decentralised_lloyd, local_centroids
from replicate.compare.evaluate import rollout
from replicate.core.studies import LloydConfig
from replicate.world.coverage import coverage_fraction
from replicate.world.env import CoverageEnv
from replicate.world.geometry import water_grid


def test_knowing_everything_and_hearing_everyone_it_is_lloyd(regions):
    """With every buoy heard and the whole lake known, the local centroids are Lloyd's clipped Voronoi centroids,
    to the raster's resolution."""
    import shapely

    water = regions["bedok"].polygon
    rng = np.random.default_rng(0)
    minx, miny, maxx, maxy = water.bounds
    cand = rng.uniform((minx, miny), (maxx, maxy), size=(400, 2))
    pos = cand[shapely.contains_xy(water, cand[:, 0], cand[:, 1])][:18].reshape(3, 6, 2)
    points = water_grid(water, 0.02)
    known = np.ones((3, 6, len(points)), bool)
    got = local_centroids(pos, known, points, k=5, comm_range=100.0, alive=None)
    np.testing.assert_allclose(got, voronoi_centroids(water, pos), atol=0.02)


def test_a_buoy_alone_heads_for_the_middle_of_the_water_it_knows(regions):
    """One buoy at the square's corner, hearing no one, knowing the water within 1 m: its target is the centroid
    of that quarter disc, 4/(3π) m along each side, not the square's middle (0, 0) that clairvoyant Lloyd aims
    at."""
    points = water_grid(regions["square"].polygon, 0.01)
    pos = np.array([[[-1.5, -1.5]]])
    known = np.linalg.norm(points - pos[0, 0], axis=1)[None, None] <= 1.0
    target = local_centroids(pos, known, points, k=4, comm_range=2.0, alive=None)[0, 0]
    assert target == pytest.approx([-1.5 + 4 / (3 * np.pi), -1.5 + 4 / (3 * np.pi)], abs=0.01)


def test_it_spreads_over_the_square_from_the_corner(params, regions):
    """From the corner patch, 9 buoys: decentralised Lloyd spreads (coverage more than twice its start) and ends
    within 0.1 of clairvoyant Lloyd with the same gains (on the square it measured 0.712 against 0.699: a buoy
    that sees less of the lake also aims less at the far side of it)."""
    gains = LloydConfig(gain=2.0, damping=0.5, converged_steps=0)
    env = CoverageEnv(regions["square"], params.world, params.coverage, n_envs=4)
    finals = {}
    for name, policy in (("decentralised", decentralised_lloyd(gains, 0.05)), ("clairvoyant", lloyd(gains))):
        trace = rollout(env, policy, 50, seed=1)
        cover = coverage_fraction(regions["square"].polygon, trace["live"], 0.5, 30)
        finals[name] = cover.mean()
        start = coverage_fraction(regions["square"].polygon, trace["positions"][0], 0.5, 30).mean()
    assert finals["decentralised"] > 2 * start
    assert abs(finals["decentralised"] - finals["clairvoyant"]) < 0.1


def test_a_buoy_senses_every_raster_point_within_reach(regions):
    """``sense`` reads the grid cells around each buoy: it marks exactly the points within ``reach`` (a reach that
    is no multiple of the spacing), also for a buoy outside the lake's bounds, as a distance to every point does."""
    from replicate.compare.decentralised import Raster, sense

    raster = Raster(regions["bedok"].polygon, 0.07)
    rng = np.random.default_rng(3)
    minx, miny, maxx, maxy = regions["bedok"].polygon.bounds
    pos = rng.uniform((minx - 1, miny - 1), (maxx + 1, maxy + 1), size=(2, 7, 2))
    known = sense(np.zeros((2, 7, len(raster.points)), bool), pos, raster, 0.53)
    brute = np.linalg.norm(raster.points[None, None] - pos[:, :, None], axis=-1) <= 0.53
    np.testing.assert_array_equal(known, brute)
    assert known.any()
