"""The shore as a wall: no buoy ever outside the water, islands and spits included; exact crossings."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
import shapely

from replicate.world.env import CoverageEnv
from replicate.world.regions import Region
from replicate.world.shore import (
    PULL_BACK,
    distance_outside,
    first_crossing,
    first_exits,
    outside,
    shoreline,
    wall_step,
)

LAKE = shapely.box(0, 0, 3, 3).difference(shapely.box(1, 1, 2, 2))  # a square lake around a square island
L_SHAPED = shapely.Polygon([(0, 0), (4, 0), (4, 1), (1, 1), (1, 4), (0, 4)])  # concave: an inner corner at (1, 1)


def inside_points(water, rng, count):
    xy = rng.uniform(water.bounds[:2], water.bounds[2:], size=(4 * count, 2))
    return xy[~outside(water, xy)][:count]


@pytest.mark.parametrize("water", [LAKE, L_SHAPED], ids=["island", "concave"])
def test_random_pushes_never_leave_the_water(water):
    """400 buoys pushed hard at random for 300 steps: every position of every step is in the closed water."""
    rng = np.random.default_rng(0)
    pos = inside_points(water, rng, 400)
    vel = rng.normal(size=pos.shape)
    for _ in range(300):
        pos, vel = wall_step(water, pos, pos + 0.1 * vel, vel)
        assert not outside(water, pos).any()
        assert distance_outside(water, pos).max() == 0.0
        vel = 0.75 * vel + 2.0 * rng.normal(size=vel.shape)


def test_a_step_through_a_wall_stops_on_it_and_keeps_its_tangential_speed():
    start, vel = np.array([[2.9, 0.5]]), np.array([[2.0, 1.0]])
    pos, new = wall_step(shapely.box(0, 0, 3, 3), start, start + 0.1 * vel, vel)
    assert 3.0 - 1e-8 <= pos[0, 0] <= 3.0 and pos[0, 1] == pytest.approx(0.5 + 0.1 / 2, abs=1e-8)
    np.testing.assert_allclose(new, [[0.0, 1.0]], atol=1e-12)  # outward component gone, along the shore kept


def test_a_spit_thinner_than_a_step_is_not_tunnelled():
    """Land 1 mm wide splits the lake; a 0.2 m step across it ends before the spit, not on its far side."""
    water = shapely.box(0, 0, 3, 3).difference(shapely.box(1.5, 0.5, 1.501, 3))
    start, vel = np.array([[1.45, 2.0]]), np.array([[2.0, 0.0]])
    pos, _ = wall_step(water, start, start + 0.1 * vel, vel)
    assert pos[0, 0] <= 1.5 and not outside(water, pos).any()


def test_first_crossing_matches_shapely_segment_by_segment():
    rng = np.random.default_rng(3)
    start = inside_points(LAKE, rng, 200)
    end = start + rng.normal(scale=0.8, size=start.shape)
    t = first_crossing(LAKE, start, end)
    for s, e, got in zip(start, end, t):
        line = shapely.LineString([s, e])
        hit = line.intersection(LAKE.boundary)
        want = 1.0 if hit.is_empty else min(line.project(shapely.Point(c), normalized=True)
                                             for c in shapely.get_coordinates(hit))
        assert got == pytest.approx(want, abs=1e-12)
    moved = end - start
    stop = start + (t - PULL_BACK)[:, None].clip(0) * moved
    assert not outside(LAKE, stop).any()


@pytest.mark.parametrize("water", [LAKE, L_SHAPED], ids=["island", "concave"])
@pytest.mark.parametrize("reach", [0.3, 10.0], ids=["grid", "every-edge"])
def test_first_exits_match_shapely(water, reach):
    """The compiled crossing (through the grid of a 0.3 m reach, with steps longer than it checking every edge,
    or with one cell holding every edge) finds shapely's first crossing of the shoreline, step by step."""
    rng = np.random.default_rng(5)
    start = inside_points(water, rng, 2000)
    end = start + rng.normal(scale=0.3, size=start.shape)
    t, edge = first_exits(shoreline(water, reach), start, end)
    want = first_crossing(water, start, end)
    crossed = want < 1.0
    assert crossed.sum() > 200 and ((edge >= 0) == crossed).all()
    np.testing.assert_allclose(t[crossed], want[crossed], atol=1e-12)


def test_the_env_with_a_wall_keeps_every_buoy_in_the_water(params):
    """Bedok-like concave water with an island, 9 buoys pushed flat out to the east for 60 steps."""
    water = shapely.Polygon([(-1.5, -1.5), (1.5, -1.5), (1.5, 0), (0, 0), (0, 1.5), (-1.5, 1.5)],
                            holes=[[(-1, -1), (-0.5, -1), (-0.5, -0.5), (-1, -0.5)]])
    world = dataclasses.replace(params.world, episode_length=60)
    env = CoverageEnv(Region("lake", water), world, params.coverage, n_envs=4, wall=True)
    env.reset(0, start="random")
    for _ in range(60):
        env.step(np.broadcast_to([1.0, 0.3], (4, world.n_agents, 2)))
        assert distance_outside(water, env.pos).max() == 0.0
    assert (env.pos[..., 0] > 1.0).any(), "buoys reached the eastern shore and stay on it"


def test_the_grid_changes_nothing(params):
    """The env checks only the edges a step from its cell can reach: the same trajectories as checking every
    edge of the shore for every step."""
    world = dataclasses.replace(params.world, episode_length=80)
    env = CoverageEnv(Region("lake", LAKE), world, params.coverage, n_envs=6, wall=True)
    assert 0.28 < env.shore.reach < 0.3 and (np.diff(env.shore.starts) == 0).any()  # open water checks nothing
    every_edge = shoreline(LAKE, 100.0)
    rng = np.random.default_rng(1)
    env.reset(0, start="random")
    pos, vel = env.pos.reshape(-1, 2).copy(), env.vel.reshape(-1, 2).copy()
    for _ in range(80):
        action = rng.uniform(-1, 1, size=(6, world.n_agents, 2))
        env.step(action)
        vel = vel * (1 - world.damping) + world.sensitivity * action.reshape(-1, 2) / world.mass * world.dt
        pos, vel = wall_step(LAKE, pos, pos + vel * world.dt, vel, every_edge)
        np.testing.assert_array_equal(env.pos.reshape(-1, 2), pos)
