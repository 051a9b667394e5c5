"""Drift currents (``replicate.world.currents``): the water carries the buoys; behind the wall they still stay in it."""

import dataclasses

import numpy as np
import pytest

from replicate.world.currents import Current, random_current
from replicate.world.env import CoverageEnv
from replicate.world.shore import distance_outside


def test_a_buoy_at_rest_drifts_with_a_uniform_current(params, regions):
    env = CoverageEnv(regions["square"], params.world, params.coverage, n_envs=2, seed=0)
    env.reset(start="random")
    env.set_current(Current.uniform([[0.3, 0.0], [0.0, -0.2]]))
    before = env.pos.copy()
    env.step(np.zeros((2, 9, 2)))
    moved = env.pos - before  # the buoys start at rest: only the water moves them
    np.testing.assert_allclose(moved[0], np.broadcast_to([0.03, 0.0], (9, 2)), atol=1e-12)
    np.testing.assert_allclose(moved[1], np.broadcast_to([0.0, -0.02], (9, 2)), atol=1e-12)


def test_a_gps_velocity_feels_the_current_and_a_log_does_not(params, regions):
    """``sensors.velocity``: over the ground (GPS) a buoy reads its displacement over the last step / dt, its
    velocity through the water plus the drift in open water; through the water (a log) the drift is invisible.
    Lost buoys read 0, a new episode starts at rest, and at the shore the reading is the buoy's actual motion."""
    from replicate.core.sections import SensorsConfig

    def make(frame, wall=False):
        return CoverageEnv(regions["square"], params.world, params.coverage, n_envs=2, observation="local",
                           sensors_config=SensorsConfig(velocity=frame), wall=wall, seed=0)

    envs = {frame: make(frame) for frame in ("water", "ground")}  # the open square: no shore to stop at
    action = np.random.default_rng(1).uniform(-1, 1, (2, 9, 2))
    still = [env.reset(start="random") is not None and env.step(action).obs for env in envs.values()]
    np.testing.assert_allclose(still[0], still[1], atol=1e-6)  # in still water both read the same velocity
    drift = np.array([[0.3, 0.0], [0.0, -0.2]])
    for env in envs.values():
        env.reset(start="random")
        env.set_current(Current.uniform(drift))
    water, ground = (env.step(action).obs[..., :2] for env in envs.values())
    np.testing.assert_allclose(ground - water, np.broadcast_to(drift[:, None], (2, 9, 2)), atol=1e-6)
    np.testing.assert_array_equal(water, envs["water"].vel.astype(np.float32))
    gps = envs["ground"]
    gps.lose(3, np.random.default_rng(2))  # a lost buoy stops: it reads no velocity and no drift
    lost = ~gps.alive
    reading = gps.step(action).obs[..., :2]
    np.testing.assert_array_equal(reading[lost], 0.0)
    np.testing.assert_allclose(reading[~lost] - gps.vel[~lost], np.repeat(drift, 6, axis=0), atol=1e-6)
    gps.set_current(None)
    assert not gps.reset(start="random")[..., :2].any()  # released at rest
    walled = make("ground", wall=True)  # pushed onto the shore by the water, a buoy reads how it moved
    walled.reset(start="random")
    walled.set_current(Current.uniform([[2.0, 0.0], [2.0, 0.0]]))
    for _ in range(30):
        before = walled.pos.copy()
        reading = walled.step(np.zeros((2, 9, 2))).obs[..., :2]
        np.testing.assert_allclose(reading, (walled.pos - before) / params.world.dt, atol=1e-5)
    assert np.abs(reading[..., 0]).max() < 0.1  # held against the east shore, it no longer moves east


def test_the_vortex_turns_at_its_peak_speed_one_core_radius_out():
    current = Current.vortex([[1.0, 1.0]], peak=0.4, core=0.5)
    pos = np.array([[[1.5, 1.0], [1.0, 1.5], [1.0, 1.0], [4.0, 1.0]]])
    v = current.at(pos)[0]
    np.testing.assert_allclose(v[0], [0.0, 0.4], atol=1e-12)  # east of the centre, turning counter-clockwise
    np.testing.assert_allclose(v[1], [-0.4, 0.0], atol=1e-12)
    assert np.abs(v[2]).max() == 0.0 and np.linalg.norm(v[3]) < 0.4 * 1e-5  # still at the centre, fading far out
    speeds = np.linalg.norm(current.at(np.array([[[1.0 + r, 1.0] for r in np.linspace(0.05, 3, 60)]]))[0], axis=1)
    assert speeds.max() == pytest.approx(0.4, abs=1e-3)


def test_a_current_onto_the_shore_never_puts_a_buoy_on_land(params, regions):
    """A 0.6 m/s flow (30 % of top speed) and vortices push Bedok's buoys for 80 steps behind the wall."""
    world = dataclasses.replace(params.world, episode_length=80)
    env = CoverageEnv(regions["bedok"], world, params.coverage, n_envs=8, wall=True, seed=2)
    reach = env.shore.reach
    env.reset(start="random")
    env.set_current(random_current(np.random.default_rng(3), 8, regions["bedok"].polygon, 0.6))
    assert env.shore.reach > reach  # the shore's grid answers for the longer steps
    rng = np.random.default_rng(4)
    for _ in range(80):
        env.step(rng.uniform(-1, 1, (8, 9, 2)))
        assert distance_outside(regions["bedok"].polygon, env.pos).max() == 0.0


def test_random_currents_are_seeded_and_bounded(params, regions):
    water = regions["square"].polygon
    a, b = (random_current(np.random.default_rng(9), 16, water, 0.6) for _ in range(2))
    for x, y in zip(dataclasses.astuple(a), dataclasses.astuple(b)):
        np.testing.assert_array_equal(x, y)
    assert a.max_speed() <= 0.6 and (a.core > 0).any() and (np.linalg.norm(a.flow, axis=1) > 0).any()
    with pytest.raises(ValueError, match="environments"):
        CoverageEnv(regions["square"], params.world, params.coverage, n_envs=3).set_current(a)
