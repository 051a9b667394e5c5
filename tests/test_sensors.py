"""The local sensors of a buoy (``replicate.sensors``) against shapely and a per-buoy loop."""

import numpy as np
import pytest
import shapely
from shapely.geometry import Polygon, box

from replicate import sensors


def points_inside(water: Polygon, count: int, rng: np.random.Generator) -> np.ndarray:
    minx, miny, maxx, maxy = water.bounds
    xy = rng.uniform((minx, miny), (maxx, maxy), (8 * count, 2))
    inside = xy[shapely.contains_xy(water, xy[:, 0], xy[:, 1])]
    assert len(inside) >= count
    return inside[:count]


@pytest.mark.parametrize("name", ["bedok", "island"])
def test_shore_distances_match_shapely(name, regions):
    """Along 8 compass rays from points inside a concave lake (Bedok) and a square with an island, the distance to
    the shore agrees with shapely's intersection of the ray with the shoreline."""
    water = regions["bedok"].polygon if name == "bedok" else box(0, 0, 3, 3).difference(box(1.2, 1.2, 1.8, 1.8))
    rng = np.random.default_rng(7)
    pos = points_inside(water, 300, rng).reshape(30, 10, 2)
    directions = sensors.ray_directions(8)
    for reach in (2.0, 50.0):
        ours = sensors.shore_distances(pos, sensors.shore_segments(water), directions, reach)
        ref = sensors.shore_distances_reference(pos, water, directions, reach)
        assert ours.shape == (30, 10, 8)
        np.testing.assert_allclose(ours, ref, atol=1e-9)
    assert (ours < 50.0).all(), "every ray of a closed lake meets its shore"


def test_a_buoy_on_the_shore_sees_open_water_away_from_it():
    """A buoy resting on the shore (as the wall leaves it) reads 0 towards the land, not 0 in every direction."""
    water = box(0, 0, 3, 3)
    pos = np.array([[[0.0, 1.5], [1.5, 3.0]]])  # on the west and on the north shore
    d = sensors.shore_distances(pos, sensors.shore_segments(water), sensors.ray_directions(4), 10.0)
    # rays east, north, west, south
    np.testing.assert_allclose(d[0, 0], [3.0, 1.5, 0.0, 1.5], atol=1e-12)
    np.testing.assert_allclose(d[0, 1], [1.5, 0.0, 1.5, 3.0], atol=1e-12)


def test_neighbours_match_a_loop_over_buoys():
    rng = np.random.default_rng(3)
    pos = rng.uniform(0, 4, (20, 9, 2))
    alive = rng.uniform(size=(20, 9)) > 0.2
    k, reach = 4, 1.5
    rel, mask = sensors.neighbours(pos, k, reach, alive)
    assert rel.shape == (20, 9, 4, 2) and mask.shape == (20, 9, 4)
    for e in range(20):
        for i in range(9):
            others = [j for j in range(9) if j != i and alive[e, j] and np.linalg.norm(pos[e, j] - pos[e, i]) <= reach]
            others.sort(key=lambda j: np.linalg.norm(pos[e, j] - pos[e, i]))
            heard = others[:k]
            assert mask[e, i].tolist() == [1.0] * len(heard) + [0.0] * (k - len(heard))
            expect = np.zeros((k, 2))
            expect[: len(heard)] = pos[e, heard] - pos[e, i]
            np.testing.assert_allclose(rel[e, i], expect, atol=1e-12)


def test_fewer_buoys_than_slots_leave_empty_slots():
    pos = np.array([[[0.0, 0.0], [0.5, 0.0]]])
    rel, mask = sensors.neighbours(pos, 4, 2.0)
    assert mask[0, 0].tolist() == [1, 0, 0, 0] and rel[0, 0, 0].tolist() == [0.5, 0.0]
    assert not rel[0, 0, 1:].any()


def test_local_observation_has_its_named_columns(regions):
    water = regions["square"].polygon
    rng = np.random.default_rng(0)
    pos = points_inside(water, 18, rng).reshape(2, 9, 2)
    vel = rng.normal(size=(2, 9, 2))
    obs = sensors.local_observation(pos, vel, sensors.shore_segments(water), sensors.ray_directions(8), 4, 2.0, 2.0)
    names = sensors.columns(4, 8)
    assert obs.shape == (2, 9, len(names)) == (2, 9, 22) and obs.dtype == np.float32
    np.testing.assert_allclose(obs[..., names.index("vx")], vel[..., 0], rtol=1e-6)
    assert names[-8:][0] == "shore_0deg" and names[-1] == "shore_315deg"
    assert not np.isin(["x", "y"], names).any(), "no absolute position"


def test_the_local_observation_is_the_same_in_a_moved_lake(params, regions):
    """No absolute position: the same lake and buoys shifted by 100 m give the same observations."""
    from shapely import affinity

    from replicate.env import CoverageEnv
    from replicate.regions import Region

    water = regions["bedok"].polygon
    moved = affinity.translate(water, 100.0, -40.0)
    envs = [CoverageEnv(Region(name, poly), params.world, params.coverage, n_envs=3, observation="local",
                        wall=True, seed=5) for name, poly in (("here", water), ("there", moved))]
    for env in envs:
        env.reset(start="random")
    envs[1].pos = envs[0].pos + np.array([100.0, -40.0])
    rng = np.random.default_rng(0)
    for _ in range(10):
        action = rng.uniform(-1, 1, (3, 9, 2))
        a, b = (env.step(action).obs for env in envs)
        np.testing.assert_allclose(a, b, atol=1e-5)
    assert a.shape == (3, 9, 22)


def test_lost_buoys_are_not_heard(params, regions):
    from replicate.env import CoverageEnv

    env = CoverageEnv(regions["square"], params.world, params.coverage, n_envs=2, observation="local", seed=1)
    env.reset()
    env.lose(3, np.random.default_rng(0))
    obs = env.observe()
    heard = obs[..., 10:14]  # neighbour0..3_heard
    assert heard.max() == 1.0
    # a buoy hears at most the 5 others still in service, and every heard slot holds a live buoy's offset
    rel, mask = sensors.neighbours(env.pos, 4, 2.0, env.alive)
    np.testing.assert_array_equal(mask, heard)
    assert (mask.sum(axis=-1) <= 5).all()
    # and a lost buoy covers nothing: the coverage is the live fleet's
    live = env.live_positions()
    terms = env.geometry.cover_terms(live)
    np.testing.assert_allclose(env.coverage_fraction(), env.geometry.union_area(live, terms.area) / 9.0)
