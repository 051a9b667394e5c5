"""The PettingZoo ParallelEnv passes PettingZoo's own API and seed tests."""

from __future__ import annotations

import numpy as np
import pytest
from pettingzoo.test import parallel_api_test, parallel_seed_test

from replicate.pettingzoo_env import CoverageParallelEnv


@pytest.mark.parametrize("reward", ["cr", "sw"])
def test_parallel_api(reward):
    parallel_api_test(CoverageParallelEnv("square", reward=reward, episode_length=30), num_cycles=100)


def test_parallel_seed():
    parallel_seed_test(lambda: CoverageParallelEnv("rectangle", observation="position_velocity"), num_cycles=60)


@pytest.mark.parametrize("n", [1, 4, 20])
def test_any_number_of_agents_and_radius(n):
    env = CoverageParallelEnv("bedok", n_agents=n, radius=0.3, geofence=0.5, episode_length=5)
    obs, _ = env.reset(seed=1)
    assert len(obs) == n and env.observation_space("buoy_0").shape == (2,)
    for _ in range(5):
        obs, rewards, terms, truncs, infos = env.step({a: env.action_space(a).sample() for a in env.agents})
    assert all(truncs.values()) and env.agents == []
    assert 0.0 <= infos["buoy_0"]["coverage"] <= 1.0
    assert np.isfinite(list(rewards.values())).all()
    with pytest.raises(RuntimeError, match="reset"):
        env.step({})
