"""The general policy's worlds: regions with a fleet each, and their environments behind the shore wall.

A world is a region and a fleet size: the named regions of ``general.regions`` with a fleet of ``general.fleet``,
``general.lakes`` generated training lakes (``lakes.training``, a stream apart from the test lakes') with their own
N, and with ``general.channel_fleet`` a long, crowded channel (``channel_world``). Every environment has the wall,
the local sensors and CR's eq. (5)-(6) with the difference credit (``general.cover_weight`` and ``union_weight`` as
c1 and c2). The training (``general_train``), the study of the baselines' gains (``tuning.tune_general_baselines``)
and the evaluation (``evaluate.evaluate_policy``) build their worlds here, so the baselines are tuned on exactly the
worlds the policy trains on.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np

from replicate.core.params import Params
from replicate.core.sections import GeneralConfig
from replicate.world.env import CoverageEnv
from replicate.world.lakes import lake_region, training
from replicate.world.regions import Region, at_density, make_region
from replicate.world.scenario import coverage_area, general_env, horizon


@dataclass
class World:
    """One training world: a region, its fleet size, and its E environments (CR reward, wall, local sensors)."""

    region: Region
    n_agents: int
    env: CoverageEnv

    @property
    def steps(self) -> int:
        """T, the steps of an episode in this world."""
        return self.env.world.episode_length


def training_lakes(params: Params, gc: GeneralConfig) -> list[tuple[Region, int]]:
    """(region, N) of the generated training lakes, the same for every seed."""
    return [(lake_region(spec, coverage_area(params)), spec.n_agents)
            for spec in training(gc.lakes, n_range=gc.lake_fleet, ratio_range=gc.lake_ratio)]


def baseline_worlds(params: Params, gc: GeneralConfig) -> list[tuple[Region, int]]:
    """The training distribution the baselines' gains are tuned on: every named region with every fleet size of
    ``fleet``, and every training lake with its own."""
    named = [(make_region(name, params.regions[name], params.world.region_area), n)
             for name in gc.regions for n in gc.fleet]
    return named + training_lakes(params, gc) + channel_world(params, gc)


def channel_world(params: Params, gc: GeneralConfig) -> list[tuple[Region, int]]:
    """(region, N) of the channel world, none when ``general.channel_fleet`` is 0: the rectangle at the paper's
    density with that many buoys, as long and crowded as the evaluation's channel cells (the rectangle at 20 and 50
    buoys), whose episodes last its evaluation's T (``scenario.horizon``)."""
    if not gc.channel_fleet:
        return []
    rectangle = make_region("rectangle", params.regions["rectangle"], params.world.region_area)
    channel = dataclasses.replace(at_density(rectangle, params.world.n_agents, gc.channel_fleet), name="channel")
    return [(channel, gc.channel_fleet)]


def make_worlds(params: Params, gc: GeneralConfig, rng: np.random.Generator, n_envs: int) -> list[World]:
    """The named regions with a fleet size drawn from ``fleet`` each (from ``rng``), the training lakes, then the
    channel world (its T grown with its size)."""
    worlds = []
    for name in gc.regions:
        region = make_region(name, params.regions[name], params.world.region_area)
        worlds.append((region, int(rng.choice(gc.fleet)), None))
    worlds += [(region, n, None) for region, n in training_lakes(params, gc)]
    worlds += [(region, n, horizon(gc, region, params.world.region_area)) for region, n in channel_world(params, gc)]
    return [World(region, n, general_env(params, gc, region, n, n_envs,
                                         np.random.SeedSequence(int(rng.integers(2**31))), steps=steps))
            for region, n, steps in worlds]
