"""The general policy's worlds: regions with a fleet each, and their environments behind the shore wall.

A world is a region and a fleet size: the named regions of ``general.regions`` with a fleet of ``general.fleet``,
and ``general.lakes`` generated training lakes (``lakes.training``, a stream apart from the held-out lakes') with
their own N. Every environment has the wall, the local sensors and CR's eq. (5)-(6) with the difference credit
(``general.cover_weight`` and ``union_weight`` as c1 and c2). The training (``general_train``), the study of the
baselines' gains (``tuning.tune_general_baselines``) and the evaluation (``evaluate.evaluate_policy``) build
their worlds here, so the baselines are tuned on exactly the worlds the policy trains on.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np

from .config import GeneralConfig, Params, region_world
from .env import CoverageEnv
from .lakes import lake_region, training
from .metrics import cover_area
from .regions import Region, make_region


@dataclass
class World:
    """One training world: a region, its fleet size, and its E environments (CR reward, wall, local sensors)."""

    region: Region
    n_agents: int
    env: CoverageEnv


def world_env(params: Params, gc: GeneralConfig, region: Region, n_agents: int, n_envs: int, seed,
              reward: bool = True, sensors: bool = True) -> CoverageEnv:
    """E environments of one world. ``reward``: CR's reward (a policy being trained); ``sensors``: the local
    observation (a policy acting; the baselines read positions, and skip the shore rays each step)."""
    world = dataclasses.replace(region_world(params, None), n_agents=n_agents, episode_length=gc.episode_length)
    cr = dataclasses.replace(params.cr_reward, c1=gc.cover_weight, c2=gc.union_weight)
    return CoverageEnv(region, world, params.coverage, n_envs=n_envs, reward="cr" if reward else None, cr=cr,
                       observation="local" if sensors else "position", sensors_config=gc.sensors, wall=True,
                       union_credit="difference", seed=seed)


def coverage_area(params: Params) -> float:
    """A(Cov): the area of one buoy's coverage polygon (a regular ``edges``-gon of circumradius R)."""
    return cover_area(params.coverage.radius, params.coverage.edges)


def horizon(gc: GeneralConfig, region: Region, region_area: float) -> int:
    """Steps of an evaluation episode on ``region``: ``episode_length``, grown with the lake's linear size beyond
    the paper's area (a lake 4× as large gets twice the steps), so that buoys can cross any lake."""
    return max(gc.episode_length, int(np.ceil(gc.episode_length * np.sqrt(region.area / region_area))))


def named_lakes(params: Params, specs) -> dict[str, tuple[Region, int]]:
    """{name: (region, the fleet it is drawn for)} of generated lakes' recipes (``lakes.LakeSpec``)."""
    return {(r := lake_region(spec, coverage_area(params))).name: (r, spec.n_agents) for spec in specs}


def training_lakes(params: Params, gc: GeneralConfig) -> list[tuple[Region, int]]:
    """(region, N) of the generated training lakes, the same for every seed."""
    return [(lake_region(spec, coverage_area(params)), spec.n_agents)
            for spec in training(gc.lakes, n_range=gc.lake_fleet, ratio_range=gc.lake_ratio)]


def baseline_worlds(params: Params, gc: GeneralConfig) -> list[tuple[Region, int]]:
    """The training distribution the baselines' gains are tuned on: every named region with every fleet size of
    ``fleet``, and every training lake with its own."""
    named = [(make_region(name, params.regions[name], params.world.region_area), n)
             for name in gc.regions for n in gc.fleet]
    return named + training_lakes(params, gc)


def make_worlds(params: Params, gc: GeneralConfig, rng: np.random.Generator, n_envs: int) -> list[World]:
    """The named regions with a fleet size drawn from ``fleet`` each (from ``rng``), then the training lakes."""
    worlds = []
    for name in gc.regions:
        region = make_region(name, params.regions[name], params.world.region_area)
        worlds.append((region, int(rng.choice(gc.fleet))))
    worlds += training_lakes(params, gc)
    return [World(region, n, world_env(params, gc, region, n, n_envs, np.random.SeedSequence(int(rng.integers(2**31)))))
            for region, n in worlds]
