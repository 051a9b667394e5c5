"""A deployment plan (``replicate plan``): a lake file, N buoys of a sensing radius in metres and a top speed in
m/s → where each buoy goes and when, for the general policy, tuned Lloyd (clairvoyant: every buoy, the whole lake),
decentralised Lloyd (what the policy sees: the buoys heard, the water sensed) and the clairvoyant planner (the best
layout, sailed to: ``compare.planner``) side by side, with the best layout found offline as the limit; everything
said in SI (``world.units``).

The lake keeps its real size: one simulation metre is ``radius_m / R`` metres, and one simulation second is as
many seconds as make the simulated top speed ``speed_ms`` (the transform is exact, ``world.units``). All four
start from the same positions, drawn in a square of side R·(start patch / R) around the launch point (default: the
paper's corner patch) and fly for the mission's duration (default: the horizon T of the lake's size, as
``evaluate --policy``), each step one control period. Coverage is SPEC §8's exact fraction of the lake, at every
step, so the plan says when each method reaches 90 % and 95 % of what it ends with.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import shapely
from pyproj import Transformer

from replicate.compare.best_layout import best_layout_once
from replicate.compare.evaluate import fleet_policy, read_general_policy, rollout
from replicate.compare.rivals import general_baselines
from replicate.core.params import Params
from replicate.core.schema import ConfigError
from replicate.core.sections import SensorsConfig
from replicate.core.studies import StartsConfig
from replicate.world.coverage import coverage_fraction
from replicate.world.env import launch_patch, start_patch
from replicate.world.regions import Region
from replicate.world.scenario import MAX_HORIZON, general_evaluation_env, horizon, scaled_setup
from replicate.world.units import BOB_SPEED, Units

CORNER = StartsConfig(start="corner")  # the paper's start: every buoy in the corner patch
MILESTONES = (0.9, 0.95)  # shares of a method's final coverage whose time the plan reports


@dataclass(frozen=True)
class Mission:
    """What a field team asks, in SI: ``buoys`` of coverage radius ``radius_m`` (m) and top speed ``speed_ms``
    (m/s), released at ``launch`` (lon, lat in WGS84; None: the corner patch), for ``duration_s`` (None: the
    horizon for the lake's size), in a uniform ``current_ms`` (east, north m/s; None: still water). The sensors'
    ranges ``comm_range_m`` and ``shore_range_m`` default to the policy's at this radius (4 R)."""

    buoys: int
    radius_m: float
    speed_ms: float = BOB_SPEED
    launch: tuple[float, float] | None = None
    duration_s: float | None = None
    current_ms: tuple[float, float] | None = None
    comm_range_m: float | None = None
    shore_range_m: float | None = None
    seed: int = 0


@dataclass(frozen=True)
class Track:
    """One method's mission: ``positions`` [T + 1, N, 2] (simulation metres) and the exact coverage fraction of
    the lake at every step, ``coverage`` [T + 1]."""

    method: str
    positions: np.ndarray
    coverage: np.ndarray

    def speeds(self, dt: float) -> np.ndarray:
        """Each buoy's ground speed over each step, simulation m/s → [T, N]."""
        return np.linalg.norm(np.diff(self.positions, axis=0), axis=-1) / dt

    def time_to(self, share: float, period_s: float) -> float:
        """Seconds until coverage first reaches ``share`` of its final value."""
        return float(np.argmax(self.coverage >= share * self.coverage[-1]) * period_s)


@dataclass(frozen=True)
class Plan:
    """A planned mission: the lake (simulation metres, with its map transform), the units, the two methods'
    tracks (the general policy first), the best layout found offline (positions [N, 2], coverage)."""

    region: Region
    units: Units
    mission: Mission
    params: Params
    sensors: SensorsConfig | None
    tracks: tuple[Track, ...]
    best_xy: np.ndarray
    best_coverage: float
    launch_patch: object

    @property
    def steps(self) -> int:
        return len(self.tracks[0].coverage) - 1


def plan(path: Path, params: Params, mission: Mission, policy: Path) -> Plan:
    """Plan ``mission`` on the lake in ``path`` with the general policy in ``policy`` (module docstring)."""
    region, params = scaled_setup(path, params, mission.buoys, mission.radius_m)
    return plan_on(region, params, mission, policy)


def plan_on(region: Region, params: Params, mission: Mission, policy: Path, starts: StartsConfig = CORNER,
            decentralised: bool = True) -> Plan:
    """Fly ``mission`` on ``region`` (simulation metres at the mission's scale): the general policy, tuned Lloyd
    and (``decentralised``) decentralised Lloyd from the same ``starts`` (drawn with ``mission.seed``; buoys lost
    as ``starts.lose`` says), and the best layout as the limit. ``cover`` and ``evaluate --policy`` write one
    episode of their own this way."""
    units = Units.of(params.world, params.coverage, mission.radius_m, mission.speed_ms)
    module, meta = read_general_policy(policy)
    sensors = mission_sensors(SensorsConfig(**meta["sensor_config"]), mission, units)
    steps = mission_steps(params, region, mission, units)
    current = None if mission.current_ms is None else tuple(units.sim_speed(np.asarray(mission.current_ms)))
    patch = None if mission.launch is None else launch_patch(region.polygon, launch_point(region, mission, units),
                                                             params.world.start_patch)
    rivals, _ = general_baselines(params, meta.get("baseline_gains"), geodesic=False, naive=False,
                                  decentralised=decentralised, planner=True, near_fleet=True)
    flight = Flight(params, region, mission, steps, current, patch, starts)
    tracks = (flight.fly("general policy", fleet_policy(module), sensors),
              *(flight.fly(name, rival, sensors if name == "decentralised_lloyd" else None)
                for name, rival in rivals.items()))
    best_xy, best = best_layout_once(region.polygon, mission.buoys - starts.lose, params.coverage.radius,
                                     params.coverage.edges)
    patch = patch if patch is not None else start_patch(region.polygon, params.world.start_patch)
    return Plan(region, units, mission, params, sensors, tracks, best_xy, best, patch)


def plan_of(region: Region, params: Params, traces: dict[str, np.ndarray], speed_ms: float = BOB_SPEED) -> Plan:
    """Episodes already flown from the corner patch ({method: positions [T + 1, N, 2]}, e.g. a per-region policy's
    and Lloyd's first evaluation episode) as a plan of buoys of top speed ``speed_ms``, with the best layout; an
    episode longer than the shortest is cut to it (one clock for all: Lloyd run to convergence shows the same
    minutes as the policy)."""
    c = params.coverage
    steps = min(len(xy) for xy in traces.values())
    n = next(iter(traces.values())).shape[1]
    mission = Mission(n, c.radius * region.scale, speed_ms)
    tracks = tuple(Track(method, xy[:steps], coverage_fraction(region.polygon, xy[:steps], c.radius, c.edges))
                   for method, xy in traces.items())
    best_xy, best = best_layout_once(region.polygon, n, c.radius, c.edges)
    return Plan(region, Units.of(params.world, c, mission.radius_m, speed_ms), mission, params, None, tracks,
                best_xy, best, start_patch(region.polygon, params.world.start_patch))


def mission_sensors(sensors: SensorsConfig, mission: Mission, units: Units) -> SensorsConfig:
    """The policy's sensors with the ranges the mission gives, converted to simulation metres."""
    if mission.comm_range_m is not None:
        sensors = dataclasses.replace(sensors, comm_range=float(units.sim_length(mission.comm_range_m)))
    if mission.shore_range_m is not None:
        sensors = dataclasses.replace(sensors, ray_range=float(units.sim_length(mission.shore_range_m)))
    return sensors


def mission_steps(params: Params, region: Region, mission: Mission, units: Units) -> int:
    """Control periods of the mission: its duration, or the horizon of the lake's size (``scenario.horizon``);
    refused beyond ``MAX_HORIZON``."""
    steps = (horizon(params.general, region, params.world.region_area) if mission.duration_s is None
             else units.steps_for(mission.duration_s))
    if steps > MAX_HORIZON:
        raise ConfigError(f"--duration-min {mission.duration_s / 60:g}: {steps} control periods of "
                          f"{units.period_s:.3g} s, more than {MAX_HORIZON}; give a shorter mission")
    return steps


def launch_point(region: Region, mission: Mission, units: Units) -> tuple[float, float]:
    """The launch point (lon, lat) in simulation metres, refused with its distance in metres when on land."""
    lon, lat = mission.launch
    x, y = Transformer.from_crs("EPSG:4326", region.utm_crs, always_xy=True).transform(lon, lat)
    point = ((x - region.offset[0]) / region.scale, (y - region.offset[1]) / region.scale)
    if not region.polygon.contains(shapely.Point(point)):
        off = region.polygon.distance(shapely.Point(point))
        raise ConfigError(f"--launch {lon:g},{lat:g}: the point lies {units.length_m(off):.0f} m outside "
                          f"{region.name}'s water; give a point in the lake (lon,lat in degrees, WGS84)")
    return point


@dataclass(frozen=True)
class Flight:
    """What every method of a plan flies in: the lake, the mission, its control periods, the drift (simulation
    m/s), the launch ``patch`` (None: the corner patch) and the ``starts`` (corner or scattered; buoys lost)."""

    params: Params
    region: Region
    mission: Mission
    steps: int
    current: tuple[float, float] | None
    patch: object
    starts: StartsConfig

    def fly(self, method: str, policy, sensors: SensorsConfig | None) -> Track:
        """One episode of ``policy`` (reading ``sensors``; None: positions, a baseline) → its track, with the
        exact coverage of every step (the buoys in service only)."""
        c = self.params.coverage
        env, _ = general_evaluation_env(self.params, self.region, self.mission.buoys, 1, sensors, self.current)
        if self.patch is not None:
            env.patch = self.patch
        trace = rollout(env, policy, self.steps, self.mission.seed, self.starts)
        positions, alive = trace["positions"][:, 0], trace["alive"][:, 0]
        if self.starts.lose:  # a lost buoy stays where it stopped and covers nothing
            cover = np.array([coverage_fraction(self.region.polygon, xy[up][None], c.radius, c.edges)[0]
                              for xy, up in zip(positions, alive, strict=True)])
        else:
            cover = coverage_fraction(self.region.polygon, positions, c.radius, c.edges)
        return Track(method, positions, cover)


def summary(p: Plan) -> dict:
    """What the plan says, in SI: the deployment, each method's final coverage and its times to ``MILESTONES``,
    its fastest ground speed, and the best layout's coverage."""
    u, period = p.units, p.units.period_s
    out = {
        "lake": p.region.name, "utm_crs": p.region.utm_crs, "area_m2": p.region.area * p.region.scale**2,
        "centre_lonlat": p.region.centre_lonlat(), "centre": p.region.centre_text(),
        "attribution": p.region.attribution, "buoys": p.mission.buoys,
        **u.describe(p.params.world, p.params.coverage, p.sensors),
        "launch_lonlat": list(p.mission.launch) if p.mission.launch else None,
        "current_ms": list(p.mission.current_ms) if p.mission.current_ms else None,
        "steps": p.steps, "mission_s": u.steps_time_s(p.steps),
        "best_layout": {"coverage": p.best_coverage, "note": "placed offline, no motion: the limit"},
        "methods": {},
    }
    for t in p.tracks:
        speed = t.speeds(p.params.world.dt)
        out["methods"][t.method] = {
            "coverage": float(t.coverage[-1]),
            **{f"seconds_to_{round(100 * q)}pct": t.time_to(q, period) for q in MILESTONES},
            "of_best_layout": float(t.coverage[-1] / p.best_coverage) if p.best_coverage > 0 else None,
            "max_speed_ms": float(u.speed_ms(speed.max(initial=0.0))),
        }
    return out
