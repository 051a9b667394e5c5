"""The one factory of environments: what it owns (pay, c1/c2) and that nothing else in the package builds one."""

from __future__ import annotations

import ast
import dataclasses

import numpy as np
import pytest

from replicate.core.params import run_config
from replicate.world.env import CoverageEnv, Pay
from replicate.world.regions import region_from_file
from replicate.world.scenario import cr_weights, general_env, grown_horizon, horizon, run_env
from replicate.world.sensors import on_shore

from ..conftest import ROOT


def test_only_the_scenario_builds_an_environment():
    """A config becomes an environment in ``world/scenario.py`` only (the fingerprint's fixed workload, which must
    not read the parameters, aside): changing the reward's terms touches one module."""
    builders = set()
    for path in (ROOT / "src" / "replicate").rglob("*.py"):
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.Call) and getattr(node.func, "id", None) == "CoverageEnv":
                builders.add(str(path.relative_to(ROOT / "src" / "replicate")))
    assert builders == {"world/scenario.py", "learn/fingerprint.py"}


def test_the_pay_is_the_reward_scaled_less_the_shore_penalty(params, regions):
    """``StepResult.pay`` = reward × scale − penalty × (on the shore and in service), per buoy; without a pay it is
    the reward itself."""
    world = dataclasses.replace(params.world, n_agents=4)
    kw = dict(n_envs=2, reward="cr", cr=params.cr_reward, observation="local", sensors_config=params.general.sensors,
              wall=True, seed=0)
    plain, paid = CoverageEnv(regions["square"], world, params.coverage, **kw), \
        CoverageEnv(regions["square"], world, params.coverage, pay=Pay(scale=0.5, shore_penalty=3.0), **kw)
    push = np.zeros((2, 4, 2))
    push[:, 0, 0] = -1.0  # buoy 0 drives west into the shore
    for env in (plain, paid):
        env.reset(seed=0, start="random")
        env.pos[:] = [[-0.4, 0.0], [0.4, 0.0], [0.0, -0.4], [0.0, 0.4]]
        env.vel[:] = 0.0
    for _ in range(30):
        a, b = plain.step(push), paid.step(push)
    np.testing.assert_array_equal(a.pay, a.reward)
    shore = on_shore(b.obs, paid.shore_rays)
    assert shore[:, 0].all() and not shore[:, 1:].any()
    np.testing.assert_array_equal(b.pay, b.reward * 0.5 - 3.0 * shore)
    with pytest.raises(ValueError, match="shore rays"):
        CoverageEnv(regions["square"], world, params.coverage, pay=Pay(shore_penalty=1.0))


def test_the_scenario_sets_the_union_weight_and_pay_of_each_config(params, regions):
    rc = run_config(params, "tuned", "cr", "square")
    env = run_env(regions["square"], rc, 1, 0)
    assert env.pay.scale == rc.algo.reward_scale
    assert env.cr.c2 == (params.cr_reward.c2 if rc.algo.union_weight is None else rc.algo.union_weight)
    gc = params.general
    general = general_env(params, gc, regions["square"], 5, 1, 0)
    assert (general.cr.c1, general.cr.c2) == (gc.cover_weight, gc.union_weight)
    assert general.pay == Pay(gc.reward_scale, gc.shore_penalty, gc.lloyd_shaping, gc.lloyd_move) and general.wall
    assert general_env(params, gc, regions["square"], 5, 1, 0, reward=False).reward_kind is None
    assert cr_weights(params.cr_reward) == params.cr_reward


@pytest.mark.parametrize("lake", ["mae_kuang_reservoir", "lake_silach", "lake_karaguz"])
def test_a_real_lake_at_the_papers_area_gets_the_papers_horizon(params, lake):
    """An outline scaled to the paper's 9 m² keeps a float sliver of its area (Mae Kuang 9.000000000000009 m²):
    its episode is still T steps, not T + 1; a lake of four times the area gets 2T, one a hair above that 2T + 1."""
    region = region_from_file(ROOT / "data" / "lakes" / f"{lake}.geojson", area=params.world.region_area)
    t, area = params.general.episode_length, params.world.region_area
    assert horizon(params.general, region, area) == t
    assert grown_horizon(t, 4 * area, area) == 2 * t
    assert grown_horizon(t, 4 * area * (1 + 1e-6), area) == 2 * t + 1
    assert grown_horizon(t, area / 4, area) == t  # never below T


def test_a_general_world_lasts_its_episode_length_unless_grown(params, regions):
    """A training world's episodes last ``general.episode_length`` (``grown_horizon`` off) or its evaluation's T
    (on); the evaluation's world lasts its T either way (``general_evaluation_env``)."""
    from replicate.world.regions import at_density
    from replicate.world.scenario import general_evaluation_env

    long = at_density(regions["rectangle"], params.world.n_agents, 20)  # 20 buoys at the paper's density
    t, grown = params.general.episode_length, horizon(params.general, long, params.world.region_area)
    assert grown > t
    assert general_env(params, params.general, long, 20, 1, 0).world.episode_length == t
    on = dataclasses.replace(params.general, grown_horizon=True)
    assert general_env(params, on, long, 20, 1, 0).world.episode_length == grown
    for gc in (params.general, on):
        env, steps = general_evaluation_env(dataclasses.replace(params, general=gc), long, 20, 1, None, None)
        assert steps == env.world.episode_length == grown
