"""The coverage world (SPEC §1): MPE point-mass physics for E parallel environments × N buoys.

Every array is batched ``[E, N, ...]``. The environment owns explicit ``numpy.random.Generator``s, one per block
of environments (one block unless several runs step together, see ``CoverageEnv.seed``); nothing else draws
random numbers. Episodes have a fixed length T, so all E environments start and end together.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass

import numpy as np
import shapely
from shapely.geometry import Polygon, box
from shapely.ops import nearest_points

from replicate.core.sections import CoverageConfig, CRRewardConfig, SensorsConfig, SWRewardConfig, WorldConfig
from replicate.world import local_map, rewards, sensors
from replicate.world.geometry import CoverageGeometry, coverage_fraction_exact, water_grid
from replicate.world.regions import Region, RegionError, signed_distance
from replicate.world.shore import shoreline, wall_step
from replicate.world.units import top_speed

OBSERVATIONS = ("position", "position_velocity", "local")  # local: no absolute position (``sensors``)


def observation_columns(observation: str, sensors_config: SensorsConfig | None = None) -> list[str]:
    """The names of an observation's columns, in order (the exported policy's layout)."""
    if observation == "local":
        sc = sensors_config or SensorsConfig()
        return sensors.columns(sc.neighbours, sc.rays, bool(sc.uncovered), sc.raster, sc.centroid)
    return ["x", "y"] if observation == "position" else ["x", "y", "vx", "vy"]


STARTS = ("corner", "opposite", "random")  # config.StartsConfig.start


@dataclass(frozen=True)
class Pay:
    """What a learner is paid each step beside the paper's reward: the reward × ``scale``, less ``shore_penalty``
    for each buoy in service resting on the shore (a shore ray shorter than ``sensors.ON_SHORE``; it needs the
    local observation), plus ``lloyd`` × Φ_i(s') − Φ_i(s), what the step took off Lloyd's locational cost of each
    buoy's cell (``rewards.lloyd_potential``), plus ``lloyd_move`` × ∂Φ_i/∂p_i(s) · Δp_i, what the buoy's own move
    took off the fleet's cost, to first order (``rewards.lloyd_pull``); the reward first mixed over ``reach``."""

    scale: float = 1.0
    shore_penalty: float = 0.0
    lloyd: float = 0.0
    lloyd_move: float = 0.0
    shared: float = 0.0  # β of the neighbourhood's share (``rewards.neighbourhood_share``)
    reach: float = 0.0


@dataclass
class StepResult:
    """One step of E environments: obs [E, N, obs_dim], reward [E, N] (the paper's), pay [E, N] (what a learner is
    paid, ``Pay``), union_area [E] (NaN for SW)."""

    obs: np.ndarray
    reward: np.ndarray
    union_area: np.ndarray
    done: bool
    pay: np.ndarray


def start_patch(region: Polygon, side: float, at: str = "lower_left", name: str = "the region",
                scale: float = 1.0) -> Polygon:
    """SPEC §1 start: a ``side`` × ``side`` square around the interior point nearest the lower-left corner of
    the region's box, clipped to the region (for a box region, exactly its lower-left corner square);
    ``at="upper_right"`` puts it at the opposite corner. A region too narrow for it is refused naming the region
    (``name``) and its widths in metres (``scale`` metres per simulation metre)."""
    minx, miny, maxx, maxy = region.bounds
    inner = region.buffer(-side / 2, join_style="mitre")
    if inner.is_empty:
        width = 2 * shapely.length(shapely.maximum_inscribed_circle(region, tolerance=side / 1000))  # islands too
        raise RegionError(
            f"{name} is too narrow for the buoys' start patch, {side * scale:.3g} m wide: the widest circle of open "
            f"water in it is {width * scale:.3g} m across (area {region.area * scale**2:.4g} m²). Use a wider "
            "outline; for a long, narrow water keep its real size with `cover --radius-m`, or set a smaller "
            "world.start_patch")
    corner = shapely.Point(minx, miny) if at == "lower_left" else shapely.Point(maxx, maxy)
    _, nearest = nearest_points(corner, inner)
    patch = box(nearest.x - side / 2, nearest.y - side / 2, nearest.x + side / 2, nearest.y + side / 2)
    return patch.intersection(region)


def launch_patch(region: Polygon, point: tuple[float, float], side: float) -> Polygon:
    """A ``side`` × ``side`` square around a launch ``point`` in the water, clipped to it: where the buoys are
    released from a boat or a jetty. A point on land is refused (the caller says how far, in its units)."""
    if not region.contains(shapely.Point(point)):
        raise RegionError("the launch point is not in the water; give a point in the lake")
    x, y = point
    return box(x - side / 2, y - side / 2, x + side / 2, y + side / 2).intersection(region)


def check_options(n_envs: int, world: WorldConfig, reward, sw, cr, observation: str, union_credit: str) -> None:
    """Refuse options the environment cannot run, by name."""
    if observation not in OBSERVATIONS:
        raise ValueError(f"observation must be one of {OBSERVATIONS}, got {observation!r}")
    if reward not in (None, "sw", "cr"):
        raise ValueError(f"reward must be 'sw', 'cr' or None, got {reward!r}")
    if reward == "sw" and sw is None or reward == "cr" and cr is None:
        raise ValueError(f"reward {reward!r} needs its reward config")
    if union_credit not in ("shared", "difference"):
        raise ValueError(f"union_credit must be 'shared' or 'difference', got {union_credit!r}")
    if n_envs < 1 or world.n_agents < 1:
        raise ValueError("n_envs and n_agents must be at least 1")


def fence_box(region: Polygon, margin: float) -> tuple[np.ndarray, np.ndarray]:
    """(lower-left, upper-right) of the geofence: the region's box grown by ``margin``."""
    minx, miny, maxx, maxy = region.bounds
    return np.array([minx, miny]) - margin, np.array([maxx, maxy]) + margin


class CoverageEnv:
    """E parallel copies of the buoy world over one region.

    ``reward`` is ``"sw"`` (eq. sw-RegAtt + sw-InterAg, shared), ``"cr"`` (eq. 5-6, per agent) or ``None``
    (no reward, for baselines). ``union_credit`` ``"difference"`` replaces eq. (6)'s shared union term by each
    agent's marginal contribution to it (SPEC §6 lead). ``geofence`` (metres, or ``None``) clamps positions
    to the region's box grown by that margin and stops the velocity component into the fence. ``wall=True``
    makes the shoreline a wall instead (``shore.wall_step``): no buoy ever leaves the water.
    """

    def __init__(
        self,
        region: Region,
        world: WorldConfig,
        coverage: CoverageConfig,
        *,
        n_envs: int = 1,
        reward: str | None = None,
        sw: SWRewardConfig | None = None,
        cr: CRRewardConfig | None = None,
        observation: str = "position",
        sensors_config: SensorsConfig | None = None,
        geofence: float | None = None,
        wall: bool = False,
        union_credit: str = "shared",
        pay: Pay = Pay(),
        seed: int | np.random.SeedSequence | list = 0,
    ):
        check_options(n_envs, world, reward, sw, cr, observation, union_credit)
        self.region = region
        self.world = world
        self.coverage = coverage
        self.n_envs = n_envs
        self.n_agents = world.n_agents
        self.reward_kind = reward
        self.sw, self.cr = sw, cr
        self.observation, self.union_credit, self.pay = observation, union_credit, pay
        self.sensor_config = sensors_config or SensorsConfig()
        columns = observation_columns(observation, self.sensor_config)
        self.obs_dim = len(columns)
        self.shore_rays = sensors.shore_rays(columns)
        if pay.shore_penalty and not self.shore_rays:
            raise ValueError("a shore penalty needs the shore rays of the local observation (observation='local')")
        self.raster = self.centroid = None  # the local raster's (water mask, cells' offsets), the centroid sensor
        if observation == "local":  # the shore's edges, the rays' directions and the maps ``SensorsConfig`` asks for
            self.shore_edges = sensors.ShoreGrid(sensors.shore_segments(region.polygon))
            self.ray_directions = sensors.ray_directions(self.sensor_config.rays)
            self.raster = local_map.for_sensors(region.polygon, self.sensor_config)
            self.centroid = local_map.centroid_for_sensors(region.polygon, self.sensor_config)
        # first: it refuses a region too narrow, naming it
        self.patch = start_patch(region.polygon, world.start_patch, name=region.name, scale=region.scale)
        self._geometry = None  # the fast path's tables: built below for a reward, on first use without one
        self.start = "corner"  # where ``reset`` releases the buoys (``STARTS``)
        self.alive: np.ndarray | None = None  # [E, N] bool once a buoy is lost (``lose``); None: all alive
        self.wall = wall
        self.shore = None  # the shore's edges on a grid (``shore.Shoreline``), with the wall
        self.current = None  # the water's drift (``currents.Current``), None: still water
        self.ground_vel = None  # each buoy's displacement over the last step / dt, [E, N, 2]: what a GPS reads
        if wall:
            self.shore = shoreline(region.polygon, self.step_reach())
        self.fence = None if geofence is None else fence_box(region.polygon, geofence)
        if reward is not None:
            self._geometry = self.geometry  # a region too large for its grids is refused before any step
        self.seed(seed)
        self.pos = np.zeros((n_envs, self.n_agents, 2))
        self.vel = np.zeros((n_envs, self.n_agents, 2))
        self.t = 0
        self.potential = None  # Lloyd's potential Φ [E, N] at the current positions, with ``Pay.lloyd``
        self.pull = None  # ∂Φ_i/∂p_i [E, N, 2] at the current positions, with ``Pay.lloyd_move``

    @property
    def geometry(self) -> CoverageGeometry:
        """The fast path of eq. (5)-(6) for this region (its area table and union raster). An environment without
        reward (an evaluation, a plan) builds it only if asked for coverage on the fast path: on a lake kept in
        metres its grids cost more than the whole evaluation."""
        if self._geometry is None:
            c = self.coverage
            self._geometry = CoverageGeometry(self.region.polygon, c.radius, c.edges, c.table_spacing,
                                              c.raster_spacing)
        return self._geometry

    # ---- episode -----------------------------------------------------------------------------------------
    def seed(self, seed: int | np.random.SeedSequence | list) -> None:
        """One seed for all E environments, or a list of S seeds: the E environments split into S equal blocks and
        block s draws its starts from seed s alone, so S independent runs step as one batch (``train.Trainer``)."""
        seeds = list(seed) if isinstance(seed, (list, tuple)) else [seed]
        if not seeds or self.n_envs % len(seeds):
            raise ValueError(f"{self.n_envs} environments do not split into {len(seeds)} equal blocks")
        self.rngs = [np.random.default_rng(s) for s in seeds]

    def start_area(self) -> Polygon:
        """Where ``reset`` releases the buoys: the start patch, the opposite patch, or the whole region."""
        if self.start == "corner":
            return self.patch
        if self.start == "opposite":
            return start_patch(self.region.polygon, self.world.start_patch, "upper_right")
        return self.region.polygon

    def sample_start(self, count: int, rng: np.random.Generator | None = None) -> np.ndarray:
        """``count`` positions uniform in the start area (rejection sampling from its box), drawn from ``rng``
        (default: the first block's). → [count, 2]."""
        rng = self.rngs[0] if rng is None else rng
        area = self.start_area()
        minx, miny, maxx, maxy = area.bounds
        out = np.empty((0, 2))
        while len(out) < count:
            cand = rng.uniform((minx, miny), (maxx, maxy), size=(2 * count, 2))
            out = np.concatenate([out, cand[shapely.contains_xy(area, cand[:, 0], cand[:, 1])]])
        return out[:count]

    def reset(self, seed: int | np.random.SeedSequence | list | None = None, start: str | None = None) -> np.ndarray:
        """Release all buoys at rest in the start area (``start``: one of ``STARTS``, kept for later resets;
        default the paper's corner patch). → obs [E, N, obs_dim]."""
        if start is not None:
            if start not in STARTS:
                raise ValueError(f"start must be one of {STARTS}, got {start!r}")
            self.start = start
        if seed is not None:
            self.seed(seed)
        per_block = self.n_envs // len(self.rngs) * self.n_agents
        starts = [self.sample_start(per_block, rng) for rng in self.rngs]
        self.pos = np.concatenate(starts).reshape(self.n_envs, self.n_agents, 2)
        self.vel = np.zeros_like(self.pos)
        self.ground_vel = np.zeros_like(self.pos)
        self.alive = None
        self.t = 0
        self.potential, self.pull = self.lloyd_terms()
        return self.observe()

    def lose(self, count: int, rng: np.random.Generator) -> None:
        """Lose ``count`` buoys of each environment, drawn uniformly among its live ones from ``rng``: a lost buoy
        stops where it is and no longer covers anything (``live_positions``), nor counts for the baselines."""
        alive = np.ones((self.n_envs, self.n_agents), bool) if self.alive is None else self.alive.copy()
        if count > int(alive.sum(axis=1).min()) - 1:
            raise ValueError(f"cannot lose {count} of {self.n_agents} buoys and keep one")
        for e in range(self.n_envs):  # E draws of a few indices: the loop is over environments, not agents
            alive[e, rng.choice(np.flatnonzero(alive[e]), size=count, replace=False)] = False
        self.alive = alive  # ``integrate`` holds the lost buoys still from here on
        self.potential, self.pull = self.lloyd_terms()  # a loss is not the survivors' doing: their cells grow unpaid

    def live(self, x: np.ndarray) -> np.ndarray:
        """The rows of the buoys still in service of a per-buoy array [E, N, ...] → [E, N_live, ...] (every
        environment has lost as many)."""
        return x if self.alive is None else x[self.alive].reshape(self.n_envs, -1, *x.shape[2:])

    def live_positions(self) -> np.ndarray:
        """Positions of the buoys still in service, [E, N_live, 2]."""
        return self.live(self.pos)

    def observe(self) -> np.ndarray:
        """Own position (paper), own position and velocity, or the local sensors that ``SensorsConfig`` names
        (``sensors.local_observation``). → [E, N, obs_dim] float32."""
        if self.observation == "local":
            sc = self.sensor_config
            vel = self.ground_vel if sc.velocity == "ground" else self.vel
            return sensors.local_observation(self.pos, vel, self.shore_edges, self.ray_directions,
                                             sc.neighbours, sc.comm_range, sc.ray_range, self.alive,
                                             sc.uncovered, self.coverage.radius, self.raster, self.centroid)
        obs = self.pos if self.observation == "position" else np.concatenate([self.pos, self.vel], axis=-1)
        return obs.astype(np.float32)

    # ---- dynamics ----------------------------------------------------------------------------------------
    def step_reach(self) -> float:
        """The longest step a buoy can make: |v|·dt with |v| ≤ √2·(F/m)·dt/damping (each action component in
        [−1, 1]), plus the current's fastest drift; without damping, the region's diagonal."""
        w = self.world
        minx, miny, maxx, maxy = self.region.polygon.bounds
        if w.damping <= 0:
            return float(np.hypot(maxx - minx, maxy - miny))
        drift = 0.0 if self.current is None else self.current.max_speed()
        return 1.01 * (top_speed(w) + drift) * w.dt

    def set_current(self, current) -> None:
        """Let the water move (``currents.Current`` of these E environments; None: still water). Behind the wall,
        the shore's grid grows to the longer steps."""
        if current is not None and len(current.flow) != self.n_envs:
            raise ValueError(f"a current for {len(current.flow)} environments, the env has {self.n_envs}")
        self.current = current
        if self.wall and self.step_reach() > self.shore.reach:
            self.shore = shoreline(self.region.polygon, self.step_reach())

    def integrate(self, action: np.ndarray) -> None:
        """MPE semi-implicit Euler: v ← v(1 − damping) + (F/m)dt, p ← p + (v + c(p)) dt, F = sensitivity·a, c the
        current's drift (0 in still water)."""
        w = self.world
        force = w.sensitivity * np.clip(action, -1.0, 1.0)
        self.vel = self.vel * (1.0 - w.damping) + (force / w.mass) * w.dt
        if self.alive is not None:  # lost buoys stay where they were lost
            self.vel = np.where(self.alive[..., None], self.vel, 0.0)
        drift = 0.0 if self.current is None else self.current.at(self.pos)  # the water carries the buoys
        if self.current is not None and self.alive is not None:
            drift = np.where(self.alive[..., None], drift, 0.0)
        start = self.pos
        end = self.pos + (self.vel + drift) * w.dt
        if self.wall:
            pos, vel = wall_step(self.region.polygon, self.pos.reshape(-1, 2), end.reshape(-1, 2),
                                 self.vel.reshape(-1, 2), self.shore)
            end, self.vel = pos.reshape(end.shape), vel.reshape(end.shape)
        self.pos = end
        if self.fence is not None:
            lo, hi = self.fence
            clamped = np.clip(self.pos, lo, hi)
            self.vel = np.where(clamped != self.pos, 0.0, self.vel)
            self.pos = clamped
        self.ground_vel = (self.pos - start) / w.dt  # the drift, the wall's stop and the fence's included

    def step(self, action: np.ndarray) -> StepResult:
        """Apply actions [E, N, 2] in [-1, 1] and return the new observation and the rewards."""
        action = np.asarray(action, dtype=float)
        if action.shape != (self.n_envs, self.n_agents, 2):
            raise ValueError(f"action must have shape {(self.n_envs, self.n_agents, 2)}, got {action.shape}")
        self.integrate(action)
        self.t += 1
        reward, union = self.reward()
        obs = self.observe()
        return StepResult(obs, reward, union, self.t >= self.world.episode_length, self.paid(reward, obs))

    def paid(self, reward: np.ndarray, obs: np.ndarray) -> np.ndarray:
        """What a learner is paid for ``reward`` [E, N] at observation ``obs`` (``Pay``) → [E, N]; the reward itself
        when the pay adds nothing (an evaluation's environment, a scale of 1), with no array made each step."""
        if self.pay == Pay():
            return reward
        if self.pay.shared:  # before the terms below, which are each buoy's own
            reward = rewards.neighbourhood_share(reward, self.pos, self.pay.reach, self.alive, self.pay.shared)
        pay = reward * self.pay.scale
        if self.pay.shore_penalty:
            live = np.ones((self.n_envs, self.n_agents), bool) if self.alive is None else self.alive
            pay = pay - self.pay.shore_penalty * (sensors.on_shore(obs, self.shore_rays) & live)
        if self.pay.lloyd or self.pay.lloyd_move:
            (before, pull), (self.potential, self.pull) = (self.potential, self.pull), self.lloyd_terms()
            if self.pay.lloyd:  # the sum over an episode telescopes to Φ(s_T) − Φ(s_0)
                pay = pay + self.pay.lloyd * (self.potential - before)
            if self.pay.lloyd_move:  # the pull at s times the buoy's displacement over the ground, s to s'
                pay = pay + self.pay.lloyd_move * (pull * self.ground_vel * self.world.dt).sum(-1)
        return pay

    def lloyd_terms(self) -> tuple[np.ndarray | None, np.ndarray | None]:
        """Lloyd's cost at the current positions as the pay asks for it: (Φ [E, N] with ``Pay.lloyd``,
        ∂Φ_i/∂p_i [E, N, 2] with ``Pay.lloyd_move``; ``rewards.lloyd_potential``, ``lloyd_pull``), None where off."""
        if not (self.pay.lloyd or self.pay.lloyd_move):
            return None, None
        at = (self.pos, self.alive, self.water_points, self.coverage.radius)
        return (rewards.lloyd_potential(*at) if self.pay.lloyd else None,
                rewards.lloyd_pull(*at) if self.pay.lloyd_move else None)

    @functools.cached_property
    def water_points(self) -> np.ndarray:
        """The water's points R/2 apart that Lloyd's cost is measured over, built on first use."""
        return water_grid(self.region.polygon, self.coverage.radius / 2)

    def reward(self) -> tuple[np.ndarray, np.ndarray]:
        """The configured reward at the current positions: ([E, N], union area [E] or NaN). After a loss the
        buoys still in service are rewarded among themselves; a lost buoy's reward is 0."""
        if self.alive is not None:
            live, union = self._reward(self.live_positions())
            out = np.zeros((self.n_envs, self.n_agents))
            out[self.alive] = live.ravel()
            return out, union
        return self._reward(self.pos)

    def _reward(self, pos: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        if self.reward_kind == "sw":
            d = signed_distance(self.region.polygon, pos)
            return rewards.sw_reward(d, pos, self.sw), np.full(self.n_envs, np.nan)
        if self.reward_kind == "cr":
            terms = self.geometry.cover_terms(pos)
            if self.union_credit == "difference":
                union, credit = self.geometry.union_area(pos, terms.area, marginal=True)
            else:
                union = credit = self.geometry.union_area(pos, terms.area)
            return rewards.cr_reward(terms, credit, self.cr, pos), union
        return np.zeros(pos.shape[:2]), np.full(self.n_envs, np.nan)

    def coverage_fraction(self, exact: bool = False) -> np.ndarray:
        """Fast-path coverage fraction of the buoys in service (SPEC §8 uses the exact one, ``exact``: shapely's,
        with no grid to build, for a lake kept in metres). → [E]."""
        pos = self.live_positions()
        if exact:
            return coverage_fraction_exact(self.region.polygon, pos, self.coverage.radius, self.coverage.edges)
        terms = self.geometry.cover_terms(pos)
        return self.geometry.union_area(pos, terms.area) / self.region.area
