"""Every reward branch against values computed by hand (SPEC §3-§4)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from replicate.world import rewards
from replicate.world.geometry import CoverTerms, cover_terms_exact, polygon_offsets

R = 0.5
A_COV = 0.5 * 30 * R**2 * math.sin(2 * math.pi / 30)  # area of the regular 30-gon, 0.7796 m²


def test_region_attraction_inside_and_outside():
    d = np.array([[-0.3, 0.0, 0.7]])
    # inside: +150; on the boundary D = 0 is not < 0: −200 − 0; outside: −200 − 0.7
    np.testing.assert_allclose(rewards.sw_region_attraction(d, 150, 200), [[150.0, -200.0, -200.7]])


@pytest.mark.parametrize(
    "dist, prop, coll",
    [
        (0.0, 0, 1),
        (0.55, 0, 1),
        (0.56, 0, 1),  # the collision range [0, 0.56] is closed
        (0.57, 0, 0),
        (0.84, 0, 0),
        (0.85, 1, 0),  # the proper range [0.85, 1.2] is closed
        (1.0, 1, 0),
        (1.2, 1, 0),
        (1.21, 0, 0),
    ],
)
def test_inter_agent_pair_ranges(dist, prop, coll):
    xy = np.array([[[0.0, 0.0], [dist, 0.0]]])
    got = rewards.sw_inter_agent(xy, 150, 200, (0.85, 1.2), (0.0, 0.56))
    assert got[0] == pytest.approx(150 * prop - 200 * coll)


def test_inter_agent_counts_every_unordered_pair_once():
    # three agents on a line 1.0 apart: pairs (0,1) and (1,2) at 1.0 (proper), (0,2) at 2.0 (neither)
    xy = np.array([[[0.0, 0.0], [1.0, 0.0], [2.0, 0.0]]])
    assert rewards.sw_inter_agent(xy, 150, 200, (0.85, 1.2), (0.0, 0.56))[0] == pytest.approx(300.0)
    # three agents at one point: three colliding pairs
    xy = np.zeros((1, 3, 2))
    assert rewards.sw_inter_agent(xy, 150, 200, (0.85, 1.2), (0.0, 0.56))[0] == pytest.approx(-600.0)


def test_sw_reward_is_shared(params, regions):
    from replicate.world.regions import signed_distance

    square = regions["square"].polygon
    xy = np.array([[[0.0, 0.0], [1.0, 0.0], [2.0, 0.0]]])  # inside, inside, outside by 0.5
    d = signed_distance(square, xy)
    np.testing.assert_allclose(d, [[-1.5, -0.5, 0.5]])
    r = rewards.sw_reward(d, xy, params.sw_reward)
    expected = 150 + 150 + (-200 - 0.5) + 150 * 2  # two proper pairs at 1.0
    np.testing.assert_allclose(r, [[expected] * 3])


def test_cover_reward_three_cases(params, regions):
    square = regions["square"].polygon  # [-1.5, 1.5]²
    xy = np.array([[[0.0, 0.0], [1.5, 0.0], [3.0, 0.0]]])
    terms = cover_terms_exact(square, xy, R, 30)
    # inside: the whole 30-gon; on the right edge (a vertex points along +x): exactly half of it;
    # outside: the vertex at +x... the nearest point of the polygon is its vertex at x = 2.5, 1.0 from the edge
    np.testing.assert_array_equal(terms.inside, [[True, False, False]])
    np.testing.assert_array_equal(terms.disjoint, [[False, False, True]])
    np.testing.assert_allclose(terms.area, [[A_COV, A_COV / 2, 0.0]], atol=1e-12)
    # distance: the polygon's leftmost vertex is at 3.0 − 0.5 = 2.5, the square's edge at 1.5
    np.testing.assert_allclose(terms.distance, [[0.0, 0.0, 1.0]], atol=1e-12)
    cr = params.cr_reward
    cover = rewards.cover_reward(terms, cr.r1, cr.r2, cr.r3)
    np.testing.assert_allclose(cover, [[60 + A_COV, 30 + A_COV / 2, -0.0 - 1.0]], atol=1e-12)


def test_overall_reward_eq6(params):
    terms = CoverTerms(
        area=np.array([[0.2, 0.78]]),
        inside=np.array([[False, True]]),
        disjoint=np.array([[False, False]]),
        distance=np.zeros((1, 2)),
    )
    union = np.array([0.9])
    r = rewards.cr_reward(terms, union, params.cr_reward, np.zeros((1, 2, 2)))  # eq. (5)-(6) read no position
    np.testing.assert_allclose(r, [[1 * (30 + 0.2) + 5 * 0.9, 1 * (60 + 0.78) + 5 * 0.9]])
    # a per-agent union credit (difference reward) broadcasts per agent
    r = rewards.overall_reward(np.array([[1.0, 2.0]]), np.array([[0.1, 0.3]]), 1.0, 5.0)
    np.testing.assert_allclose(r, [[1.5, 3.5]])


def test_coverage_polygon_is_the_regular_30gon():
    off = polygon_offsets(R, 30)
    assert off.shape == (30, 2)
    np.testing.assert_allclose(np.linalg.norm(off, axis=1), R)
    x, y = off[:, 0], off[:, 1]
    assert 0.5 * abs(np.dot(x, np.roll(y, -1)) - np.dot(y, np.roll(x, -1))) == pytest.approx(A_COV)


def test_lloyd_potential_splits_lloyds_cost_among_the_cells():
    """Σ_i Φ_i is minus the mean squared distance from the water to its nearest buoy (in R²), a lost buoy has no
    cell, and its water goes to the others."""
    from shapely.geometry import box

    from replicate.world.geometry import water_grid

    points = water_grid(box(0, 0, 3, 1), 0.25)
    rng = np.random.default_rng(0)
    pos = rng.uniform([0, 0], [3, 1], size=(4, 5, 2))
    phi = rewards.lloyd_potential(pos, None, points, 0.5)
    nearest = np.square(points[None, :, None] - pos[:, None]).sum(-1).min(-1)  # [E, P]
    np.testing.assert_allclose(phi.sum(1), -nearest.mean(1) / 0.25)
    assert (phi < 0).all()
    alive = np.ones((4, 5), bool)
    alive[:, 2] = False
    lost = rewards.lloyd_potential(pos, alive, points, 0.5)
    assert (lost[:, 2] == 0).all() and (lost.sum(1) < phi.sum(1)).all()  # the others' water reaches farther


def test_lloyd_potential_pays_the_front_buoy_of_a_channel_for_going_on():
    """On the 9 × 1 m channel, two buoys at its west end (x = 0.5, 1) and the front one 1.5 m (3R) or more ahead:
    eq. (5)-(6) pay the front one the same wherever it is along the channel (it overlaps no one); its potential
    rises as it goes east, up to the centroid of its cell ((1 + x) / 2 + 9) / 2, which it passes at x = 6.3."""
    from shapely.geometry import box

    from replicate.world.geometry import water_grid

    points = water_grid(box(0, 0, 9, 1), 0.25)
    x = np.linspace(2.5, 6.0, 8)
    pos = np.full((len(x), 3, 2), 0.5)
    pos[:, 1, 0], pos[:, 2, 0] = 1.0, x
    front = rewards.lloyd_potential(pos, None, points, 0.5)[:, 2]
    assert (np.diff(front) > 0).all()
    beyond = pos.copy()
    beyond[:, 2, 0] = 8.0  # past its centroid: it is paid to come back
    assert (rewards.lloyd_potential(beyond, None, points, 0.5)[:, 2] < front[-1]).all()


def test_neighbourhood_mean_is_over_each_buoy_and_those_it_hears_in_service():
    """Three buoys on a line 1 m apart, reach 1.5 m: the ends hear the middle one, the middle one both; a buoy
    alone keeps its own reward, and a lost buoy is nobody's neighbour."""
    from replicate.world.rewards import neighbourhood_mean

    pos = np.array([[[0.0, 0.0], [1.0, 0.0], [2.0, 0.0]], [[0.0, 0.0], [1.0, 0.0], [5.0, 0.0]]])
    reward = np.array([[3.0, 6.0, 9.0], [3.0, 6.0, 9.0]])
    np.testing.assert_allclose(neighbourhood_mean(reward, pos, 1.5, None), [[4.5, 6.0, 7.5], [4.5, 4.5, 9.0]])
    alive = np.array([[True, False, True], [True, True, True]])
    lost = np.array([[3.0, 0.0, 9.0], [3.0, 6.0, 9.0]])  # a lost buoy's reward is 0
    np.testing.assert_allclose(neighbourhood_mean(lost, pos, 1.5, alive)[0], [3.0, 0.0, 9.0])
