"""The similarity transform (``world.units``): one trajectory in two unit systems, equal after conversion."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
import torch
from shapely import affinity

from replicate.core.params import packaged
from replicate.core.schema import ConfigError
from replicate.core.sections import SensorsConfig
from replicate.learn.policy import load_policy
from replicate.world.env import CoverageEnv, observation_columns
from replicate.world.units import (
    Units,
    column_unit,
    from_simulation,
    si_world,
    to_simulation,
    top_speed,
)

LAKE = ("Bedok", "bedok")


def test_the_paper_world_has_its_stated_top_speed_and_period(params):
    """At the BoB's 1 m/s and a 25 m radius: 50 m per simulation metre, a top speed of 2√2 simulation m/s, so
    one simulation second is 141 s and a step 14.1 s."""
    units = Units.of(params.world, params.coverage, radius_m=25.0, speed_ms=1.0)
    assert top_speed(params.world) == pytest.approx(2 * math.sqrt(2))
    assert units.metres == pytest.approx(50.0)
    assert units.seconds == pytest.approx(50 * 2 * math.sqrt(2))
    assert units.period_s == pytest.approx(14.142, abs=1e-3)
    assert units.speed_ms(top_speed(params.world)) == pytest.approx(1.0)
    assert units.sim_speed(units.speed_ms(0.37)) == pytest.approx(0.37)
    assert units.steps_for(units.period_s * 3) == 3 and units.steps_for(units.period_s * 3.01) == 4
    with pytest.raises(ConfigError, match="speed"):
        Units.of(params.world, params.coverage, radius_m=25.0, speed_ms=0.0)


def test_one_trajectory_in_two_unit_systems(params, regions):
    """The general policy steps the same lake twice: in simulation units, and in metres and seconds (25 m radius,
    0.7 m/s). Both worlds take the policy's action on the simulation's observation, so the float32 rounding of
    an observation is not fed back (the closed loop would amplify it about 1.5× per step). At every step the SI
    positions / ``metres`` are the simulation's (the wall, the sensors and the physics included), the SI
    observations converted by ``to_simulation`` are the simulation's, and the policy acts the same on them."""
    module, meta = load_policy(packaged("general.pt"))
    sensors = SensorsConfig(**meta["sensor_config"])
    region = regions["bedok"]
    units = Units.of(params.world, params.coverage, radius_m=25.0, speed_ms=0.7)
    world = dataclasses.replace(params.world, episode_length=30)
    sim = CoverageEnv(region, world, params.coverage, n_envs=2, observation="local", sensors_config=sensors,
                      wall=True)
    world_si, coverage_si, sensors_si = si_world(world, params.coverage, sensors, units)
    metric = dataclasses.replace(region, polygon=affinity.scale(region.polygon, units.metres, units.metres,
                                                                origin=(0, 0)))
    si = CoverageEnv(metric, world_si, coverage_si, n_envs=2, observation="local", sensors_config=sensors_si,
                     wall=True)
    columns = observation_columns("local", sensors)
    obs_sim, obs_si = sim.reset(seed=3, start="random"), si.reset(seed=3, start="random")
    speeds = []  # m/s, every buoy at every step
    for _ in range(world.episode_length):
        np.testing.assert_allclose(si.pos / units.metres, sim.pos, rtol=0, atol=1e-9)
        np.testing.assert_allclose(to_simulation(obs_si, columns, units), obs_sim, rtol=0, atol=2e-6)
        with torch.no_grad():
            action = module(torch.as_tensor(obs_sim)).numpy()
            read_in_si = module(torch.as_tensor(to_simulation(obs_si, columns, units), dtype=torch.float32)).numpy()
        np.testing.assert_allclose(read_in_si, action, rtol=0, atol=1e-4)
        obs_sim, obs_si = sim.step(action).obs, si.step(action).obs
        speeds.append(np.linalg.norm(si.ground_vel, axis=-1))
    np.testing.assert_allclose(si.pos / units.metres, sim.pos, rtol=0, atol=1e-9)
    assert np.max(speeds) <= 0.7 * (1 + 1e-9)  # never above the top speed, in m/s
    assert np.max(speeds) > 0.35  # and they did move: not buoys at rest
    assert si.t * world_si.dt == pytest.approx(30 * units.period_s)


def test_every_observation_column_has_a_unit(params):
    columns = observation_columns("local", SensorsConfig(uncovered=(0.5,), ray_range=2.0, raster=3))
    units = {c: column_unit(c) for c in columns}
    assert units["vx"] == "m/s" and units["neighbour0_dx"] == "m" and units["shore_90deg"] == "m"
    assert units["neighbour3_heard"] == "1" and units["uncovered_0deg"] == "1" and units["raster_water_-1_1"] == "1"
    u = Units.of(params.world, params.coverage, radius_m=10.0, speed_ms=2.0)
    obs = np.random.default_rng(0).normal(size=(4, len(columns)))
    np.testing.assert_allclose(from_simulation(to_simulation(obs, columns, u), columns, u), obs)
    with pytest.raises(ValueError, match="unknown observation column"):
        column_unit("x")
