"""The local sensors of a buoy (``replicate.world.sensors``) against shapely and a per-buoy loop."""

from pathlib import Path

import numpy as np
import pytest
import shapely
from shapely.geometry import Polygon, box

from replicate.world import sensors


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


def test_the_shores_grid_reads_what_every_edge_reads_to_the_bit():
    """``ShoreGrid``: the rays read only the edges of the cells they pass through, and the distances are those of
    reading every edge (one cell), to the bit: on a reservoir of 1,711 edges, from points in the water, on the
    shore (its vertices, where rays graze edges and pass through corners) and off the shore's bounding box."""
    import shapely

    from replicate.world.regions import region_from_file

    water = region_from_file("data/lakes/mae_kuang_reservoir.geojson", "mae_kuang", 9.0).polygon
    rng = np.random.default_rng(3)
    minx, miny, maxx, maxy = water.bounds
    off = np.array([[minx - 0.5, miny - 0.5], [maxx + 0.1, (miny + maxy) / 2], [(minx + maxx) / 2, maxy + 2.0]])
    pos = np.concatenate([points_inside(water, 400, rng), shapely.get_coordinates(water.exterior)[::7], off])
    segments = sensors.shore_segments(water)
    grid, whole = sensors.ShoreGrid(segments), sensors.ShoreGrid(segments, cell=1e9)
    assert grid.nx * grid.ny > 100 and whole.nx * whole.ny == 1
    for directions in (sensors.ray_directions(8), sensors.ray_directions(12)):
        for reach in (0.3, 2.0, 1e6):
            np.testing.assert_array_equal(sensors.shore_distances(pos, grid, directions, reach),
                                          sensors.shore_distances(pos, whole, directions, reach))


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

    from replicate.world.env import CoverageEnv
    from replicate.world.regions import Region

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
    from replicate.world.env import CoverageEnv

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


def uncovered_reference(pos, alive, water, directions, radii, radius, comm_range):
    """``uncovered_water`` by shapely and a loop: a point counts when the straight line from the buoy to it stays in
    the water and no other buoy in service within ``comm_range`` of the buoy is within ``radius`` of it."""
    e, n = pos.shape[:2]
    out = np.zeros((e, n, len(directions)))
    for b in range(e):
        for i in range(n):
            heard = [j for j in range(n) if j != i and alive[b, j]
                     and np.linalg.norm(pos[b, j] - pos[b, i]) <= comm_range]
            for r, d in enumerate(directions):
                free = 0
                for rad in radii:
                    point = pos[b, i] + rad * d
                    wet = water.covers(shapely.LineString([pos[b, i], point]))
                    free += wet and all(np.linalg.norm(point - pos[b, j]) > radius for j in heard)
                out[b, i, r] = free / len(radii)
    return out


def test_uncovered_water_matches_shapely_and_a_loop(regions):
    """In a concave lake (Bedok) and a square with an island, with lost buoys and a communication range shorter
    than the lake, the share of uncovered water along each ray agrees with shapely's segment-in-water test and a
    loop over the buoys heard."""
    rng = np.random.default_rng(11)
    radii = (0.25, 0.5, 0.75, 1.0)
    for water in (regions["bedok"].polygon, box(0, 0, 3, 3).difference(box(1.2, 1.2, 1.8, 1.8))):
        pos = points_inside(water, 4 * 12, rng).reshape(4, 12, 2)
        alive = rng.uniform(size=(4, 12)) > 0.25
        directions = sensors.ray_directions(8)
        shore = sensors.shore_distances(pos, sensors.shore_segments(water), directions, 2.0)
        ours = sensors.uncovered_water(pos, shore, directions, radii, 0.5, 1.5, alive)
        ref = uncovered_reference(pos, alive, water, directions, radii, 0.5, 1.5)
        assert ours.shape == (4, 12, 8)
        np.testing.assert_array_equal(ours, ref)
        assert 0 < ours.mean() < 1, "the draw has covered, uncovered and dry points"


def test_uncovered_water_marks_a_neighbours_disc_and_forgets_a_lost_one():
    """A lone buoy in open water reads 1 on every ray; a buoy 0.5 m east covers every point of the east ray (0.25
    to 1.0 m out, all within R = 0.5 of it) and, lost, covers none."""
    water = box(0, 0, 10, 10)
    pos = np.array([[[5.0, 5.0], [5.5, 5.0]]])
    directions = sensors.ray_directions(4)  # east, north, west, south
    shore = sensors.shore_distances(pos, sensors.shore_segments(water), directions, 2.0)
    radii = (0.25, 0.5, 0.75, 1.0)
    both = sensors.uncovered_water(pos, shore, directions, radii, 0.5, 2.0)
    assert both[0, 0, 0] == 0.0 and both[0, 1, 2] == 0.0, "each covers the other's side"
    assert both[0, 0, 2] == 1.0 and both[0, 0, 1] == 1.0, "away from it and across it (just outside its disc): free"
    lost = sensors.uncovered_water(pos, shore, directions, radii, 0.5, 2.0, np.array([[True, False]]))
    np.testing.assert_array_equal(lost[0, 0], [1.0, 1.0, 1.0, 1.0])
    far = sensors.uncovered_water(pos, shore, directions, radii, 0.5, 0.4)
    np.testing.assert_array_equal(far[0, 0], [1.0, 1.0, 1.0, 1.0])  # a buoy out of range is not heard


def test_the_uncovered_sensor_adds_its_columns_and_is_refused_beyond_the_rays(params, regions):
    from replicate.core.sections import SensorsConfig
    from replicate.world.env import CoverageEnv, observation_columns

    sc = SensorsConfig(velocity="ground", uncovered=(0.25, 0.5, 0.75, 1.0))
    names = observation_columns("local", sc)
    assert len(names) == 30 and names[-8] == "uncovered_0deg" and names[-9] == "shore_315deg"
    listed = sensors.describe(sc)  # the exported policy's metadata
    assert [d["sensor"] for d in listed][-1] == "uncovered_water" and listed[-1]["columns"] == names[-8:]
    assert sum(len(d["columns"]) for d in listed) == 30
    env = CoverageEnv(regions["bedok"], params.world, params.coverage, n_envs=2, observation="local",
                      sensors_config=sc, wall=True, seed=3)
    obs = env.reset(start="random")
    plain = CoverageEnv(regions["bedok"], params.world, params.coverage, n_envs=2, observation="local",
                        sensors_config=SensorsConfig(velocity="ground"), wall=True, seed=3).reset(start="random")
    assert obs.shape == (2, 9, 30) and env.obs_dim == 30
    np.testing.assert_array_equal(obs[..., :22], plain)  # the other sensors read the same
    assert ((obs[..., 22:] >= 0) & (obs[..., 22:] <= 1)).all()
    for beyond in ((0.5, 2.5), (1.0, 2.0)):  # a point at the rays' range cannot be known to be water
        with pytest.raises(ValueError, match="uncovered radii"):
            CoverageEnv(regions["bedok"], params.world, params.coverage, observation="local",
                        sensors_config=SensorsConfig(uncovered=beyond))
    assert SensorsConfig(uncovered=[0.5, 1.0]) == sc.__class__(uncovered=(0.5, 1.0))  # as a policy's metadata gives it
    from replicate.core.params import load_params
    from replicate.core.schema import ConfigError

    with pytest.raises(ConfigError, match="uncovered radii"):  # params.yaml's value is refused as it is read
        load_params(Path(__file__).parents[2] / "params.yaml", {"general.sensors.uncovered": [3.0]})
