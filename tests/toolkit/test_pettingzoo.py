"""The PettingZoo ParallelEnv passes PettingZoo's own API and seed tests."""

from __future__ import annotations

import re

import numpy as np
import pytest
from pettingzoo.test import parallel_api_test, parallel_seed_test

from replicate.toolkit.pettingzoo_env import CoverageParallelEnv

from ..conftest import ROOT


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


def test_tuned_config_gives_the_reward_that_learns(params):
    from replicate.toolkit.pettingzoo_env import parallel_env

    env = parallel_env(region="square", config="tuned")
    assert env.core.union_credit == "difference" and env.core.pay.scale == params.configs["tuned"].reward_scale
    assert env.core.cr.c2 == params.configs["tuned"].union_weight and env.core.fence is not None
    plain = parallel_env(region="square", config="tuned", union_credit="shared", geofence=None)
    assert plain.core.union_credit == "shared" and plain.core.fence is None  # a keyword overrides the config
    obs, infos = env.reset(seed=0)
    assert 0.0 <= infos["buoy_0"]["coverage"] <= 1.0, "coverage is in the reset infos too"
    _, rewards, *_ = env.step({a: np.zeros(2) for a in env.agents})
    unscaled = parallel_env(region="square", config="tuned", reward_scale=1.0)
    unscaled.reset(seed=0)
    _, raw, *_ = unscaled.step({a: np.zeros(2) for a in unscaled.agents})
    assert rewards["buoy_0"] == pytest.approx(raw["buoy_0"] * params.configs["tuned"].reward_scale)


def test_spaces_are_bounded_and_hold_every_observation_and_state():
    from replicate.toolkit.pettingzoo_env import parallel_env

    env = parallel_env(region="rectangle", observation="position_velocity", episode_length=40)
    assert np.isfinite(env.observation_space("buoy_0").low).all()
    assert env.state_space.shape == env.state().shape == (4 * 9,)
    obs, _ = env.reset(seed=3)
    rng = np.random.default_rng(0)
    while env.agents:
        push = np.sign(rng.normal(size=2))  # flat out in one direction per episode: the farthest a buoy gets
        obs, *_ = env.step({a: push for a in env.agents})
        assert all(env.observation_space(a).contains(o) for a, o in obs.items())
        assert env.state_space.contains(env.state())


def test_aec_env_passes_the_api_test():
    from pettingzoo.test import api_test

    from replicate.toolkit.pettingzoo_env import env

    api_test(env(region="square", config="tuned", episode_length=20), num_cycles=30)


def test_torchrl_sees_the_coverage_info():
    torchrl = pytest.importorskip("torchrl", reason="torchrl is an optional extra (pip install .[bench])")
    from torchrl.envs.libs.pettingzoo import PettingZooWrapper
    from torchrl.envs.utils import check_env_specs

    from replicate.toolkit.pettingzoo_env import parallel_env

    wrapped = PettingZooWrapper(parallel_env(region="square", config="tuned", episode_length=10), use_mask=True)
    check_env_specs(wrapped)
    assert torchrl is not None


@pytest.mark.slow
def test_the_readme_ppo_snippet_runs():
    """The README's SuperSuit + Stable-Baselines3 block, executed as written (about a minute)."""
    pytest.importorskip("supersuit", reason="SuperSuit is an optional extra (pip install .[sb3])")
    pytest.importorskip("stable_baselines3", reason="Stable-Baselines3 is an optional extra (pip install .[sb3])")
    readme = (ROOT / "README.md").read_text()
    block = re.search(r"```python\n(import supersuit.+?)```", readme, re.S)
    assert block, "the README shows the SuperSuit + SB3 path"
    scope: dict = {}
    exec(block.group(1), scope)  # noqa: S102 - the README's own code
    obs = scope["vec"].reset()
    assert scope["model"].predict(obs, deterministic=True)[0].shape == (36, 2)  # 4 copies × 9 buoys


def test_the_shore_wall_option_passes_the_api_and_seed_tests():
    """``shore="wall"`` on Bedok: PettingZoo's API and seed tests, and every observation inside the water."""
    from replicate.world.shore import distance_outside

    env = CoverageParallelEnv("bedok", config="tuned", shore="wall", episode_length=30)
    parallel_api_test(env, num_cycles=40)
    parallel_seed_test(lambda: CoverageParallelEnv("bedok", config="tuned", shore="wall", episode_length=30))
    obs, _ = env.reset(seed=1)
    while env.agents:
        obs, *_ = env.step({a: np.array([1.0, -1.0], np.float32) for a in env.agents})
        xy = np.stack([o[:2] for o in obs.values()]).astype(float)
        assert distance_outside(env.core.region.polygon, xy).max() < 1e-6  # float32 observations


def test_the_local_observation_passes_the_api_and_seed_tests():
    """``observation="local"`` (velocity, buoys heard, shore rays) behind the wall on Bedok: PettingZoo's API and
    seed tests, and every observation inside its space."""
    env = CoverageParallelEnv("bedok", config="tuned", observation="local", shore="wall", episode_length=30)
    parallel_api_test(env, num_cycles=40)
    parallel_seed_test(lambda: CoverageParallelEnv("bedok", observation="local", shore="wall", episode_length=30))
    space = env.observation_space("buoy_0")
    assert space.shape == (22,)
    obs, _ = env.reset(seed=3)
    while env.agents:
        assert all(space.contains(o) for o in obs.values())
        obs, *_ = env.step({a: np.array([1.0, 1.0], np.float32) for a in env.agents})


def test_starts_losses_and_a_current_pass_the_api_and_seed_tests():
    """The events of `replicate evaluate --policy`: scattered starts, buoys lost half-way (they terminate and
    leave ``agents``, the others no longer hear them), a drift."""
    def make():
        return CoverageParallelEnv("bedok", observation="local", shore="wall", episode_length=20, start="random",
                                   lose=3, current=(0.6, 0.0))

    parallel_api_test(make(), num_cycles=40)
    parallel_seed_test(make)
    env = make()
    env.reset(seed=3)
    for t in range(20):
        obs, rewards, terms, truncs, infos = env.step({a: env.action_space(a).sample() for a in env.agents})
        if t == 9:
            assert sum(terms.values()) == 3 and len(env.agents) == 6 and len(obs) == 9
            assert env.core.alive.sum() == 6
    assert env.agents == [] and len(obs) == 6 and all(truncs.values())
    again = make()
    again.reset(seed=3)
    for _ in range(10):
        again.step({a: np.zeros(2) for a in again.agents})
    assert (again.core.alive == env.core.alive).all()  # the losses come from the reset's seed
    kept = CoverageParallelEnv("bedok", observation="local", shore="wall", episode_length=20, lose=3,
                               keep_lost=True)  # a fixed agent set, as vector envs need
    parallel_api_test(kept, num_cycles=40)
    kept.reset(seed=3)
    for t in range(20):
        obs, rewards, terms, truncs, infos = kept.step({a: np.ones(2) for a in kept.agents})
        lost = [a for a in infos if infos[a].get("lost")]
        assert len(obs) == 9 and not any(terms.values()) and len(lost) == (3 if t >= 9 else 0)
        assert not any(obs[a].any() for a in lost)  # silent from the loss on
        assert t == 9 or all(rewards[a] == 0.0 for a in lost)  # paid for the step they were lost after
    assert kept.agents == [] and all(truncs.values())
    with pytest.raises(ValueError, match="lose must be between 0 and n_agents - 1"):
        CoverageParallelEnv("square", lose=9)
    with pytest.raises(ValueError, match="lose needs an episode of at least 2 steps"):
        CoverageParallelEnv("square", lose=1, episode_length=1)
    drifting = CoverageParallelEnv("square", current=(2.0, 0.0), episode_length=30)  # no wall, no fence
    obs, _ = drifting.reset(seed=0)
    while drifting.agents:
        obs, *_ = drifting.step({a: np.array([1.0, 0.0]) for a in drifting.agents})
        assert drifting.state_space.contains(drifting.state())  # the drift counts in the bounds
        assert all(drifting.observation_space(a).contains(o) for a, o in obs.items())
    with pytest.raises(ValueError, match="start must be one of"):
        CoverageParallelEnv("square", start="middle")


@pytest.mark.parametrize("shore", ["wall", None])
def test_a_gps_velocity_in_a_drift_stays_in_the_observation_space(shore):
    """Over the ground a buoy's velocity is its own plus the drift: the space's velocity bound grows with the
    current (a full push downstream, in the open and behind the wall)."""
    from replicate.core.sections import SensorsConfig

    env = CoverageParallelEnv("square", observation="local", sensors_config=SensorsConfig(velocity="ground"),
                              current=(0.6, 0.0), shore=shore, episode_length=30)
    obs, _ = env.reset(seed=0)
    fastest = 0.0
    while env.agents:
        obs, *_ = env.step({a: np.array([1.0, 1.0], np.float32) for a in env.agents})
        assert all(env.observation_space(a).contains(o) for a, o in obs.items())
        fastest = max([fastest, *(o[0] for o in obs.values())])
    assert fastest > 2.0  # beyond the terminal speed through the water: the drift is read
    with pytest.raises(ValueError, match=r"SensorsConfig.velocity: 'gps' is not one of \['water', 'ground'\]"):
        CoverageParallelEnv("square", observation="local", sensors_config=SensorsConfig(velocity="gps"))


def test_the_uncovered_water_sensor_passes_the_api_and_seed_tests():
    """``sensors.uncovered``: eight more columns, each a share in [0, 1], through losses and a drift."""
    from replicate.core.sections import SensorsConfig

    def make():
        return CoverageParallelEnv("bedok", observation="local", shore="wall", episode_length=20, start="random",
                                   lose=3, current=(0.6, 0.0),
                                   sensors_config=SensorsConfig(velocity="ground", uncovered=(0.25, 0.5, 0.75, 1.0)))

    parallel_api_test(make(), num_cycles=40)
    parallel_seed_test(make)
    env = make()
    assert env.observation_space("buoy_0").shape == (30,)
    obs, _ = env.reset(seed=1)
    shares = []
    while env.agents:
        assert all(env.observation_space(a).contains(o) for a, o in obs.items())
        shares += [o[22:] for o in obs.values()]
        obs, *_ = env.step({a: env.action_space(a).sample() for a in env.agents})
    shares = np.concatenate(shares)
    assert shares.min() < 1.0 and shares.max() == 1.0  # buoys covering each other's water, and open water


def test_the_local_raster_passes_the_api_and_seed_tests():
    """``sensors.raster``: 2 × 5 × 5 more columns, each 0 or 1, through losses and a drift; some cells dry, some
    covered by another buoy."""
    from replicate.core.sections import SensorsConfig

    def make():
        return CoverageParallelEnv("bedok", observation="local", shore="wall", episode_length=20, start="random",
                                   lose=3, current=(0.6, 0.0),
                                   sensors_config=SensorsConfig(velocity="ground", raster=5))

    parallel_api_test(make(), num_cycles=40)
    parallel_seed_test(make)
    env = make()
    assert env.observation_space("buoy_0").shape == (22 + 50,)
    obs, _ = env.reset(seed=1)
    cells = []
    while env.agents:
        assert all(env.observation_space(a).contains(o) for a, o in obs.items())
        cells += [o[22:] for o in obs.values()]
        obs, *_ = env.step({a: env.action_space(a).sample() for a in env.agents})
    cells = np.stack(cells)
    assert set(np.unique(cells)) == {0.0, 1.0}
    assert cells[:, :25].min() == 0 and cells[:, :25].max() == 1 and cells[:, 25:].max() == 1


def test_a_coverage_radius_is_resolved_with_as_many_cells_as_the_papers(params):
    """A small radius as finely as the paper's; a large one (a lake kept in metres, R = 25 m) as coarsely: its
    lookup grids would otherwise need 64.8 GiB."""
    from replicate.world.scenario import scaled_coverage

    small = scaled_coverage(params.coverage, 0.03)
    assert small.raster_spacing <= small.radius / 2 and small.table_spacing <= small.radius / 2
    assert small.radius / small.raster_spacing == pytest.approx(params.coverage.radius / params.coverage.raster_spacing)
    large = scaled_coverage(params.coverage, 25.0)
    assert large.raster_spacing == pytest.approx(params.coverage.raster_spacing * 50)
    assert large.table_spacing == pytest.approx(params.coverage.table_spacing * 50)


def test_a_lake_file_at_the_papers_scale_and_in_metres(params):
    """``parallel_env(region=FILE)``: the lake scaled to 9 m²; with ``radius_m`` kept in metres, its grids bounded
    (no 64 GiB table) and its clock in seconds; an unknown name is refused with the names and the fix."""
    from replicate.toolkit.pettingzoo_env import parallel_env
    from replicate.world.regions import RegionError

    lake = str(ROOT / "data" / "lakes" / "lake_karaguz.geojson")
    paper = parallel_env(region=lake, reward="cr")
    assert paper.core.region.area == pytest.approx(9.0)
    metric = parallel_env(region=lake, radius_m=25.0, speed_ms=1.0, reward=None, observation="local", shore="wall")
    assert metric.core.region.area * metric.units.metres**2 == pytest.approx(5.4496e6, rel=1e-3)
    obs, _ = metric.reset(seed=0)
    _, _, _, _, infos = metric.step({a: metric.action_space(a).sample() for a in metric.agents})
    assert infos["buoy_0"]["time_s"] == pytest.approx(metric.units.period_s) and metric.units.period_s > 14
    with pytest.raises(RegionError, match="neither a region of params.yaml"):
        parallel_env(region="lake_nowhere")


def test_the_local_centroid_passes_the_api_and_seed_tests():
    """``sensors.centroid``: 2 more columns, the offset to the local centroid within the shore sensor's reach,
    through losses and a drift."""
    from replicate.core.sections import SensorsConfig

    def make():
        return CoverageParallelEnv("bedok", observation="local", shore="wall", episode_length=20, start="random",
                                   lose=3, current=(0.6, 0.0),
                                   sensors_config=SensorsConfig(velocity="ground", centroid=True))

    parallel_api_test(make(), num_cycles=40)
    parallel_seed_test(make)
    env = make()
    assert env.observation_space("buoy_0").shape == (22 + 2,)
    obs, _ = env.reset(seed=1)
    offsets = []
    while env.agents:
        assert all(env.observation_space(a).contains(o) for a, o in obs.items())
        offsets += [o[22:] for o in obs.values()]
        obs, *_ = env.step({a: env.action_space(a).sample() for a in env.agents})
    assert np.abs(np.stack(offsets)).max() > 0.3
