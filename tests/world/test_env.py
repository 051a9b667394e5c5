"""The environment: one MPE step written out by hand, the start patch, observations, geofence, seeding."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
import shapely
import shapely.affinity

from replicate.world.env import CoverageEnv, Pay


def make(params, region, **kw):
    return CoverageEnv(region, params.world, params.coverage, sw=params.sw_reward, cr=params.cr_reward, **kw)


def test_one_step_is_the_mpe_update(params, regions):
    env = make(params, regions["square"], n_envs=2, seed=0)
    env.reset()
    env.pos = np.array([[[0.1, 0.2]] * 9, [[-0.3, 0.4]] * 9], dtype=float)
    env.vel = np.full((2, 9, 2), 0.5)
    action = np.zeros((2, 9, 2))
    action[0, 0] = [1.0, -0.5]
    action[1, 3] = [2.0, 0.0]  # out of range: clipped to 1
    env.step(action)
    # MPE integrate_state: v ← v·(1 − 0.25); v ← v + (F/m)·dt with F = 5·a; p ← p + v·dt
    v0 = 0.5 * 0.75 + 5.0 * np.array([1.0, -0.5]) / 1.0 * 0.1  # = [0.875, 0.125]
    np.testing.assert_allclose(env.vel[0, 0], v0)
    np.testing.assert_allclose(env.pos[0, 0], np.array([0.1, 0.2]) + v0 * 0.1)
    np.testing.assert_allclose(env.vel[1, 3], [0.375 + 0.5, 0.375])
    np.testing.assert_allclose(env.vel[0, 1], [0.375, 0.375])  # no force: only damping


def test_terminal_speed_is_two_metres_per_second(params, regions):
    env = make(params, regions["square"], n_envs=1, seed=0)
    env.reset()
    for _ in range(200):
        env.integrate(np.ones((1, 9, 2)))
    np.testing.assert_allclose(env.vel, 2.0, rtol=1e-6)


@pytest.mark.parametrize("name", ["square", "rectangle", "bedok"])
def test_start_patch_inside_region_at_lower_left(params, regions, name):
    env = make(params, regions[name], n_envs=50, seed=3)
    env.reset()
    flat = env.pos.reshape(-1, 2)
    assert shapely.contains_xy(regions[name].polygon, flat[:, 0], flat[:, 1]).all()
    assert shapely.contains_xy(env.patch, flat[:, 0], flat[:, 1]).all()
    assert np.all(env.vel == 0)
    minx, miny, _, _ = env.patch.bounds
    assert env.patch.bounds[2] - minx <= 0.5 + 1e-9
    if name == "square":
        assert env.patch.bounds == pytest.approx((-1.5, -1.5, -1.0, -1.0))


def test_observation_modes(params, regions):
    env = make(params, regions["square"], n_envs=3, observation="position_velocity", seed=0)
    obs = env.reset()
    assert obs.shape == (3, 9, 4) and obs.dtype == np.float32
    step = env.step(np.ones((3, 9, 2)))
    np.testing.assert_allclose(step.obs[..., :2], env.pos, rtol=1e-6)
    np.testing.assert_allclose(step.obs[..., 2:], env.vel, rtol=1e-6)
    assert make(params, regions["square"], n_envs=3, seed=0).reset().shape == (3, 9, 2)


def test_geofence_clamps_to_grown_box(params, regions):
    env = make(params, regions["rectangle"], n_envs=2, geofence=0.5, seed=0)
    env.reset()
    for _ in range(100):
        env.step(np.ones((2, 9, 2)))
    np.testing.assert_allclose(env.pos[..., 0], 5.0)
    np.testing.assert_allclose(env.pos[..., 1], 1.0)
    assert np.all(env.vel == 0)  # the velocity into the fence is stopped


def test_unbounded_without_geofence(params, regions):
    env = make(params, regions["square"], n_envs=1, seed=0)
    env.reset()
    for _ in range(100):
        env.step(np.ones((1, 9, 2)))
    assert env.pos.min() > 15.0


def test_seeding(params, regions):
    a = make(params, regions["square"], n_envs=4, seed=7).reset()
    b = make(params, regions["square"], n_envs=4, seed=7).reset()
    c = make(params, regions["square"], n_envs=4, seed=8).reset()
    np.testing.assert_array_equal(a, b)
    assert not np.array_equal(a, c)


def test_blocks_of_environments_draw_from_their_own_seeds(params, regions):
    """Six environments seeded [4, 9] are two blocks of three: each block starts as three environments seeded
    alone, and steps as they do; the environments must split into equal blocks."""
    kw = dict(reward="cr", cr=params.cr_reward)
    both = CoverageEnv(regions["square"], params.world, params.coverage, n_envs=6, seed=[4, 9], **kw)
    alone = [CoverageEnv(regions["square"], params.world, params.coverage, n_envs=3, seed=s, **kw) for s in (4, 9)]
    for _ in range(2):  # a second episode continues each block's generator
        np.testing.assert_array_equal(both.reset(), np.concatenate([env.reset() for env in alone]))
    action = np.random.default_rng(0).uniform(-1, 1, (6, params.world.n_agents, 2))
    step = both.step(action)
    steps = [env.step(a) for env, a in zip(alone, np.split(action, 2))]
    np.testing.assert_array_equal(step.reward, np.concatenate([s.reward for s in steps]))
    with pytest.raises(ValueError, match="equal blocks"):
        CoverageEnv(regions["square"], params.world, params.coverage, n_envs=6, seed=[1, 2, 3, 4])


def test_rewards_have_shapes_and_sharing(params, regions):
    sw = make(params, regions["square"], n_envs=3, reward="sw", seed=0)
    sw.reset()
    r = sw.step(np.zeros((3, 9, 2))).reward
    assert r.shape == (3, 9) and np.all(r == r[:, :1])  # shared
    cr = make(params, regions["square"], n_envs=3, reward="cr", seed=0)
    cr.reset()
    step = cr.step(np.random.default_rng(0).uniform(-1, 1, (3, 9, 2)))
    assert step.reward.shape == (3, 9) and not np.all(step.reward == step.reward[:, :1])
    assert np.all(step.union_area > 0)


@pytest.mark.parametrize(
    "kwargs, message",
    [
        ({"observation": "pixels"}, "observation"),
        ({"reward": "dense"}, "reward"),
        ({"union_credit": "magic"}, "union_credit"),
        ({"n_envs": 0}, "n_envs"),
    ],
)
def test_bad_arguments_are_refused(params, regions, kwargs, message):
    with pytest.raises(ValueError, match=message):
        make(params, regions["square"], **kwargs)


def test_bad_action_shape(params, regions):
    env = make(params, regions["square"], n_envs=2, seed=0)
    env.reset()
    with pytest.raises(ValueError, match="shape"):
        env.step(np.zeros((2, 8, 2)))


def test_starts_opposite_corner_and_random(params, regions):
    from replicate.world.env import CoverageEnv

    region = regions["square"]
    env = CoverageEnv(region, params.world, params.coverage, n_envs=20)
    minx, miny, maxx, maxy = region.polygon.bounds
    corner = env.reset(1)
    assert (corner.max(axis=(0, 1)) <= np.array([minx, miny]) + params.world.start_patch + 1e-9).all()
    opposite = env.reset(1, start="opposite")
    assert (opposite.min(axis=(0, 1)) >= np.array([maxx, maxy]) - params.world.start_patch - 1e-9).all()
    assert env.reset(2).min() >= maxx - params.world.start_patch - 1e-9, "the start is kept for later resets"
    spread = env.reset(1, start="random")
    inside = shapely.contains_xy(region.polygon, spread[..., 0].ravel(), spread[..., 1].ravel())
    assert inside.all() and spread.std(axis=(0, 1)).min() > 0.5  # over the whole region, not a patch
    with pytest.raises(ValueError, match="start must be one of"):
        env.reset(1, start="middle")


def test_lost_buoys_stop_and_leave_the_baselines(params, regions):
    from replicate.compare.baselines import lloyd, voronoi_centroids
    from replicate.world.env import CoverageEnv

    region = regions["square"]
    env = CoverageEnv(region, params.world, params.coverage, n_envs=4)
    env.reset(3, start="random")
    env.vel[:] = 0.3
    env.lose(3, np.random.default_rng(0))
    assert env.alive.sum(axis=1).tolist() == [6] * 4 and env.live_positions().shape == (4, 6, 2)
    lost = env.pos[~env.alive].copy()
    policy = lloyd(params.evaluate.lloyd)
    action = policy(env)
    assert (action[~env.alive] == 0).all()
    live = env.live_positions()
    expected = np.clip(params.evaluate.lloyd.gain * (voronoi_centroids(region.polygon, live) - live)
                       - params.evaluate.lloyd.damping * env.live(env.vel), -1, 1)
    np.testing.assert_allclose(action[env.alive].reshape(4, 6, 2), expected)  # Lloyd of the six, not the nine
    env.step(action)
    np.testing.assert_array_equal(env.pos[~env.alive], lost)  # a lost buoy stays where it was lost
    with pytest.raises(ValueError, match="keep one"):
        env.lose(6, np.random.default_rng(0))
    env.reset(3)
    assert env.alive is None, "a reset brings every buoy back"


def test_a_region_narrower_than_the_start_patch_is_refused_by_name(params):
    """A river 3.8 km × 1 m scaled to the 9 m² world is 185 × 0.049 m: the 0.5 m start patch cannot fit. The env
    says so, with the width, before it builds any geometry table (that took minutes for such a strip)."""
    from replicate.world.regions import Region, RegionError

    strip = shapely.box(0, 0, 3800, 1)
    strip = shapely.affinity.scale(strip, (9 / strip.area) ** 0.5, (9 / strip.area) ** 0.5, origin=(0, 0))
    with pytest.raises(RegionError, match=r"river is too narrow for the buoys' start patch, 0.5 m wide: the widest "
                                          r"circle of open water in it is 0.048\d m across"):
        CoverageEnv(Region("river", strip), params.world, params.coverage)
    scaled = Region("river", strip, scale=20.0)  # a lake file at 20 m per simulation metre: said in metres
    with pytest.raises(RegionError, match=r"start patch, 10 m wide: .* is 0.9\d* m across \(area 3600 m²\)"):
        CoverageEnv(scaled, params.world, params.coverage)


def test_an_island_filling_the_lake_is_measured_by_the_water_around_it(params):
    """A 9 m² lake around an island that leaves a 0.3 m moat: the message gives the moat's width, not the lake's
    bounding box (3.4 m)."""
    from replicate.world.regions import Region, RegionError

    lake = shapely.box(0, 0, 3.4, 3.4).difference(shapely.box(0.3, 0.3, 3.1, 3.1))
    with pytest.raises(RegionError, match=r"moat is too narrow .* circle of open water in it is 0.3\d* m across"):
        CoverageEnv(Region("moat", lake), params.world, params.coverage)


def paid_with_and_without(params, regions, shaped_pay: Pay) -> tuple[CoverageEnv, CoverageEnv]:
    """Two environments on the rectangle (4 buoys, 2 episodes, CR's reward with the difference credit), one paid
    ``Pay(0.01)``, the other ``shaped_pay``, reset to the same corner start."""
    world = dataclasses.replace(params.world, n_agents=4, episode_length=10)
    options = {"n_envs": 2, "reward": "cr", "cr": params.cr_reward, "observation": "local", "wall": True,
               "union_credit": "difference"}
    envs = tuple(CoverageEnv(regions["rectangle"], world, params.coverage, pay=pay, **options)
                 for pay in (Pay(0.01), shaped_pay))
    for env in envs:
        env.reset(seed=3, start="corner")
    return envs


def test_lloyd_shaping_pays_the_progress_of_each_cell(params, regions):
    """``Pay.lloyd`` adds β(Φ(s') − Φ(s)) to each buoy's pay: over an episode the added pay sums to
    β(Φ(s_T) − Φ(s_0)) for every buoy, whatever the actions, and nothing else changes."""
    plain, shaped = paid_with_and_without(params, regions, Pay(0.01, lloyd=2.0))
    start, added = shaped.potential.copy(), np.zeros((2, 4))
    rng = np.random.default_rng(0)
    for _ in range(10):
        push = rng.uniform(-1, 1, (2, 4, 2))
        a, b = plain.step(push), shaped.step(push)
        np.testing.assert_array_equal(a.reward, b.reward)
        added += b.pay - a.pay
    np.testing.assert_allclose(added, 2.0 * (shaped.potential - start), atol=1e-12)
    assert plain.potential is None and np.abs(added).max() > 0


def test_lloyd_move_pays_the_first_order_of_each_buoys_own_move(params, regions):
    """``Pay.lloyd_move`` adds β ∂Φ_i/∂p_i · Δp_i: for a small move of one buoy it is what the move took off the
    fleet's Lloyd cost (Σ_j Φ_j, to first order), the others are paid nothing for it, and the pull points from each
    buoy toward its cell's centroid."""
    from replicate.world import rewards

    plain, shaped = paid_with_and_without(params, regions, Pay(0.01, lloyd_move=2.0))
    points, radius = shaped.water_points, params.coverage.radius
    cost = rewards.lloyd_potential(shaped.pos, None, points, radius).sum(-1)  # [E]
    push = np.zeros((2, 4, 2))
    push[:, 1] = [0.1, 0.03]  # buoy 1 alone moves, a little
    a, b = plain.step(push), shaped.step(push)
    np.testing.assert_array_equal(a.reward, b.reward)
    added = b.pay - a.pay
    np.testing.assert_array_equal(added[:, [0, 2, 3]], 0.0)
    gained = rewards.lloyd_potential(shaped.pos, None, points, radius).sum(-1) - cost
    np.testing.assert_allclose(added[:, 1], 2.0 * gained, rtol=0.05)
    assert np.abs(added[:, 1]).max() > 0.1
    pull = rewards.lloyd_pull(shaped.pos, None, points, radius)
    cell, _ = rewards.lloyd_cells(shaped.pos, None, points)
    for i in range(4):
        centroid = points[cell[0] == i].mean(axis=0)
        direction = centroid - shaped.pos[0, i]
        np.testing.assert_allclose(pull[0, i] / np.linalg.norm(pull[0, i]), direction / np.linalg.norm(direction))


def test_a_shared_pay_mixes_each_buoys_reward_with_its_neighbourhoods(params, regions):
    """``Pay.shared`` = β pays (1 − β) r_i + β × the mean of r over buoy i and the buoys within ``reach``: the paper's
    reward itself is unchanged, and over the buoys the pay's total is kept where every buoy hears every other."""
    from replicate.world.rewards import neighbourhood_mean

    plain, shared = paid_with_and_without(params, regions, Pay(0.01, shared=0.5, reach=2.0))
    rng = np.random.default_rng(0)
    for _ in range(5):
        push = rng.uniform(-1, 1, (2, 4, 2))
        a, b = plain.step(push), shared.step(push)
        np.testing.assert_array_equal(a.reward, b.reward)
        mean = neighbourhood_mean(a.reward, shared.pos, 2.0, None)
        np.testing.assert_allclose(b.pay, 0.01 * (0.5 * a.reward + 0.5 * mean))
    assert np.abs(b.pay - a.pay).max() > 0
    everyone = neighbourhood_mean(a.reward, shared.pos, 100.0, None)
    np.testing.assert_allclose(everyone.sum(-1), a.reward.sum(-1))
