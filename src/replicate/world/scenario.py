"""The one place a configuration becomes an environment.

Every environment the project steps is built here, from the typed parameters: a per-region run's (``run_env``:
the reward, credit, observation and fence of ``configs.*``), the same world for its evaluation and the baselines'
(``evaluation_env``), and the general policy's worlds (``general_env``: behind the shore wall, observing the local
sensors, CR's eq. (5)-(6) with the difference credit, ``general.cover_weight`` / ``union_weight`` as c1 and c2).
The terms a learner is paid beside the paper's reward (its scale and the shore penalty, ``Pay``) are set here too
and applied by the environment, so a trainer only reads ``StepResult.pay``.

To change the reward: the reward's arithmetic is in ``rewards``, which terms a scenario uses and with which weights
is in this module, and their values in ``params.yaml``.
"""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path

from shapely import affinity

from replicate.core.params import Params, RunConfig, region_world
from replicate.core.sections import CoverageConfig, CRRewardConfig, GeneralConfig, SensorsConfig
from replicate.world.coverage import cover_area
from replicate.world.currents import Current
from replicate.world.env import CoverageEnv, Pay
from replicate.world.lakes import lake_region
from replicate.world.regions import Region, RegionError, check_polygon, make_region, region_from_file


def cr_weights(cr: CRRewardConfig, c1: float | None = None, c2: float | None = None) -> CRRewardConfig:
    """Eq. (5)-(6) with the coverage term's weight ``c1`` and the union term's ``c2`` where given."""
    if c1 is not None:
        cr = dataclasses.replace(cr, c1=float(c1))
    if c2 is not None:
        cr = dataclasses.replace(cr, c2=float(c2))
    return cr


def run_env(region: Region, rc: RunConfig, n_envs: int, seed, reward: bool = True) -> CoverageEnv:
    """A per-region run's environment (reward, credit, observation, fence and pay of its config);
    ``reward=False`` gives the same world without reward, for validation rollouts."""
    algo = rc.algo
    return CoverageEnv(
        region, rc.world, rc.coverage, n_envs=n_envs, reward=rc.method.reward if reward else None,
        sw=rc.sw_reward, cr=cr_weights(rc.cr_reward, c2=algo.union_weight), observation=algo.observation,
        sensors_config=algo.sensors, geofence=algo.geofence, wall=algo.shore == "wall",
        union_credit=algo.union_credit, pay=Pay(scale=algo.reward_scale), seed=seed,
    )


def evaluation_env(region: Region, rc: RunConfig, n_envs: int, observation: str = "position") -> CoverageEnv:
    """The world of a per-region run without reward: where its actors (observing ``observation``) and the
    baselines (positions) are evaluated and the baselines' gains tuned."""
    return CoverageEnv(region, rc.world, rc.coverage, n_envs=n_envs, observation=observation,
                       sensors_config=rc.algo.sensors, geofence=rc.algo.geofence, wall=rc.algo.shore == "wall")


def general_env(params: Params, gc: GeneralConfig, region: Region, n_agents: int, n_envs: int, seed,
                reward: bool = True, sensors: bool = True, steps: int | None = None) -> CoverageEnv:
    """E environments of one general world. ``reward``: CR's reward and the general training's pay (a policy
    being trained); ``sensors``: the local observation (a policy acting; the baselines read positions, and skip the
    shore rays each step). Its episodes last ``steps``, by default ``gc.episode_length`` or, with
    ``gc.grown_horizon``, the region's ``horizon``."""
    if steps is None:
        steps = horizon(gc, region, params.world.region_area) if gc.grown_horizon else gc.episode_length
    world = dataclasses.replace(region_world(params, None), n_agents=n_agents, episode_length=steps)
    return CoverageEnv(region, world, params.coverage, n_envs=n_envs, reward="cr" if reward else None,
                       cr=cr_weights(params.cr_reward, gc.cover_weight, gc.union_weight),
                       observation="local" if sensors else "position", sensors_config=gc.sensors, wall=True,
                       union_credit="difference", seed=seed,  # no pay without a reward: nothing learns there
                       pay=general_pay(gc) if reward else Pay())


def general_pay(gc: GeneralConfig) -> Pay:
    """What a general policy in training is paid beside the reward (``Pay``): its scale, the shore penalty, the
    Lloyd terms and the share of the neighbours' reward, those heard within the communication range."""
    return Pay(gc.reward_scale, gc.shore_penalty, gc.lloyd_shaping, gc.lloyd_move, gc.neighbour_credit,
               gc.sensors.comm_range if gc.neighbour_credit else 0.0)


def general_evaluation_env(params: Params, region: Region, n_agents: int, n_envs: int, sensors,
                           current: Current | tuple[float, float] | None) -> tuple[CoverageEnv, int]:
    """The world a general policy is evaluated in → (environment, T): behind the wall, T for the region's size
    (``horizon``), in ``current`` when given (one environment's ``Current``, or a uniform flow in m/s); observing
    ``sensors`` (a ``SensorsConfig``, the policy's), or nothing for the baselines (None)."""
    config = dataclasses.replace(params.general, sensors=sensors or params.general.sensors)
    env = general_env(params, config, region, n_agents, n_envs, 0, reward=False, sensors=sensors is not None,
                      steps=horizon(config, region, params.world.region_area))
    steps = env.world.episode_length
    if current is not None:
        env.set_current((current if isinstance(current, Current) else Current.uniform(current)).tiled(n_envs))
    return env, steps


class Unset:
    """The default of an option whose ``None`` means something (no geofence, the paper's c2)."""


UNSET = Unset()


def scaled_coverage(coverage: CoverageConfig, radius: float) -> CoverageConfig:
    """``coverage`` with coverage radius ``radius``; its lookup grids scale with it (as many cells per radius), so
    that a small radius is resolved as finely as the paper's and a large one (a lake kept in metres, R = 25) costs
    no more memory than the paper's scale."""
    factor = radius / coverage.radius
    return dataclasses.replace(coverage, radius=radius, table_spacing=coverage.table_spacing * factor,
                               raster_spacing=coverage.raster_spacing * factor)


MAX_HORIZON = 5000  # steps of one episode or mission: a lake at most ~600 coverage radii across


def scaled_setup(path: Path, params: Params, n_agents: int | None, radius_m: float | None) -> tuple[Region, Params]:
    """The region and the params of a lake file at one of two scales. ``radius_m`` None: the paper's, the lake
    scaled to ``world.region_area`` (9 m²) with N buoys of coverage radius R = 0.5. Else real: the lake keeps its
    size in metres and the buoys get a coverage radius of ``radius_m``; the simulation metre becomes ``radius_m / R``
    metres (``world.units``), so the coverage polygon, the start patch and the physics keep their values in
    simulation units, and the episode grows with the lake's linear size, ``T = T_paper · sqrt(A_sim / 9)`` (never
    shorter)."""
    world = params.world if n_agents is None else dataclasses.replace(params.world, n_agents=int(n_agents))
    if world.n_agents < 1:
        raise RegionError("at least one buoy is needed")
    if radius_m is None:
        region = region_from_file(path, area=world.region_area)
    else:
        if radius_m <= 0:
            raise RegionError(f"the coverage radius must be positive, got {radius_m} m")
        real = region_from_file(path, area=None)
        across = 2 * math.sqrt(real.polygon.area / math.pi)  # m: the width of a round lake of the same area
        if radius_m > across:
            raise RegionError(f"--radius-m {radius_m:g}: one buoy's coverage is wider than the whole lake "
                              f"({real.polygon.area:.4g} m², about {across:.4g} m across); give a radius below that")
        unit = radius_m / params.coverage.radius  # metres per simulation metre
        sim = check_polygon(affinity.scale(real.polygon, 1 / unit, 1 / unit, origin=(0, 0)), real.name)
        region = dataclasses.replace(real, polygon=sim, scale=unit, notes=real.notes + (
            f"real scale: 1 simulation metre = {unit:g} m (coverage radius {radius_m:g} m)",))
        horizon = grown_horizon(world.episode_length, sim.area, world.region_area)
        if horizon > MAX_HORIZON:
            smallest = radius_m * math.sqrt(horizon / MAX_HORIZON) * 1.001
            raise RegionError(f"--radius-m {radius_m:g}: {real.name} ({real.polygon.area:.4g} m²) is so many coverage "
                              f"radii across that crossing it takes {horizon} steps (at most {MAX_HORIZON}); give a "
                              f"radius of at least {smallest:.3g} m")
        world = dataclasses.replace(world, episode_length=horizon)  # region_area stays the paper's: T's yardstick
    return region, dataclasses.replace(params, world=world)


def option_env(params: Params, region: str | Region, *, config: str | None = None, n_agents: int | None = None,
               radius: float | None = None, reward: str | None = "cr", observation: str | None = None,
               sensors_config: SensorsConfig | None = None, geofence: float | None | Unset = UNSET,
               reward_scale: float | None = None, union_credit: str | None = None,
               union_weight: float | None | Unset = UNSET, episode_length: int | None = None,
               shore: str | None = None) -> CoverageEnv:
    """One environment from keyword options (the PettingZoo environment's): ``config`` (``"paper"`` or
    ``"tuned"``) gives a configuration's reward options and world bounds, each option given overrides its value
    one by one; with neither, the paper's defaults."""
    algo = params.configs[config] if config is not None else None

    def pick(given, key: str, default):  # an option given, else the config's, else the paper's default
        if given is not None and given is not UNSET:
            return given
        return getattr(algo, key) if algo is not None else default

    world = region_world(params, region if isinstance(region, str) and region in params.regions else None)
    if n_agents is not None:
        world = dataclasses.replace(world, n_agents=int(n_agents))
    if episode_length is not None:
        world = dataclasses.replace(world, episode_length=int(episode_length))
    coverage = params.coverage if radius is None else scaled_coverage(params.coverage, float(radius))
    if isinstance(region, str):
        region = named_or_file(params, region, world.region_area)
    fence = geofence if geofence is not UNSET else (algo.geofence if algo is not None else None)
    weight = union_weight if union_weight is not UNSET else (algo.union_weight if algo is not None else None)
    return CoverageEnv(
        region, world, coverage, n_envs=1, reward=reward, sw=params.sw_reward,
        cr=cr_weights(params.cr_reward, c2=weight),
        observation=pick(observation, "observation", "position"),
        sensors_config=pick(sensors_config, "sensors", SensorsConfig()), geofence=fence,
        wall=pick(shore, "shore", "fence") == "wall", union_credit=pick(union_credit, "union_credit", "shared"),
        pay=Pay(scale=float(pick(reward_scale, "reward_scale", 1.0))),
    )


def named_or_file(params: Params, region: str, area: float) -> Region:
    """A region of ``params.regions`` by name, or the outline in a vector file, scaled to ``area``."""
    if region in params.regions:
        return make_region(region, params.regions[region], area)
    if Path(region).is_file():
        return region_from_file(region, area=area)
    raise RegionError(f"region {region!r}: neither a region of params.yaml ({', '.join(params.regions)}) nor a "
                      "vector file; give one of those names or the path of a lake's outline (GeoJSON, GeoPackage, "
                      "shapefile)")


def coverage_area(params: Params) -> float:
    """A(Cov): the area of one buoy's coverage polygon (a regular ``edges``-gon of circumradius R)."""
    return cover_area(params.coverage.radius, params.coverage.edges)


# Relative slack before the ceiling of a grown horizon: a real outline scaled to the paper's 9 m² keeps a float sliver
# of its area (Mae Kuang 9.000000000000009 m², Lake Silach 9.000000000000005 m²), on which the bare ceiling gives
# 51 steps where the rule gives 50. A lake would need an area within about 2e-9 of the next step's to lose one.
HORIZON_SLACK = 1e-9


def grown_horizon(episode_length: int, area: float, region_area: float) -> int:
    """``episode_length`` steps, grown with the linear size of a region of ``area`` beyond the paper's
    ``region_area`` (a lake 4× as large gets twice the steps), so that buoys can cross any lake."""
    grown = episode_length * math.sqrt(area / region_area)
    return max(episode_length, math.ceil(grown * (1 - HORIZON_SLACK)))


def horizon(gc: GeneralConfig, region: Region, region_area: float) -> int:
    """Steps of an evaluation episode on ``region`` (``grown_horizon`` of the general policy's ``episode_length``)."""
    return grown_horizon(gc.episode_length, region.area, region_area)


def named_lakes(params: Params, specs) -> dict[str, tuple[Region, int]]:
    """{name: (region, the fleet it is drawn for)} of generated lakes' recipes (``lakes.LakeSpec``)."""
    return {(r := lake_region(spec, coverage_area(params))).name: (r, spec.n_agents) for spec in specs}
