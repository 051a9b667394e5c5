"""The coverage world as a PettingZoo ``ParallelEnv`` with Gymnasium spaces, for use in other MARL tools.

One environment (E = 1) of ``CoverageEnv``: any region, any N ≥ 1, any coverage radius, the SW or CR reward.
Agents are ``buoy_0 … buoy_{N−1}``; every episode is truncated after ``episode_length`` steps (no terminal
states, as in MPE, but for buoys lost with ``lose``, which terminate).

    >>> env = CoverageParallelEnv("square", reward="cr")
    >>> obs, infos = env.reset(seed=0)
    >>> obs, rewards, terms, truncs, infos = env.step({a: env.action_space(a).sample() for a in env.agents})
"""

from __future__ import annotations

import dataclasses
import functools
from pathlib import Path

import numpy as np
from gymnasium import spaces
from pettingzoo import ParallelEnv

from replicate.core.params import Params, load_params, packaged
from replicate.core.sections import SensorsConfig
from replicate.world import local_map
from replicate.world.currents import Current
from replicate.world.env import STARTS, CoverageEnv
from replicate.world.regions import Region
from replicate.world.scenario import UNSET, Unset, option_env, scaled_setup
from replicate.world.units import BOB_SPEED, Units


class CoverageParallelEnv(ParallelEnv):
    """PettingZoo parallel API over one ``CoverageEnv``.

    ``region`` is a name in params.yaml, a lake's vector file (scaled to the paper's 9 m²) or a ``Region``; with
    ``radius_m`` (and ``speed_ms``, default 1.0) a lake file keeps its size in metres for buoys of that sensing
    radius and top speed (``world.units``): observations and actions stay in the simulation's units a policy reads,
    ``env.units`` converts them, and infos carry ``time_s``. ``config`` (``"paper"`` or ``"tuned"``) takes a
    configuration's reward options and world bounds from params.yaml: its observation, geofence, reward scale,
    union credit and union weight (``config="tuned"`` is the CR reward that learns, see ``docs/TUNING.md``); the
    keyword arguments override them one by one. ``n_agents``, ``radius``, ``episode_length`` override the world;
    ``reward`` is ``"sw"``, ``"cr"`` or ``None``; ``shore="wall"`` keeps every buoy in the water. The events of
    ``replicate evaluate --policy``: ``start`` (``"corner"``, ``"opposite"`` or ``"random"``), ``lose`` buoys lost
    after half the episode (drawn from the reset's seed; they terminate and leave ``agents``), and a uniform
    ``current`` (vx, vy) in simulation m/s; ``keep_lost=True`` keeps a lost buoy among the agents to the end of
    the episode, observing zeros, paid nothing, its actions ignored and ``infos[a]["lost"]`` set (what a vector
    env of a fixed agent set needs: SuperSuit's ``pettingzoo_env_to_vec_env_v1`` refuses agents that leave, and
    its ``black_death_v3`` never ends an episode that truncates). Infos carry the
    coverage fraction (fast path) from the reset on, so wrappers that build their specs from ``reset()`` see it.
    Observations and the ``state()`` are bounded: no buoy can get further than T steps at top speed from the
    region (or past the geofence).
    """

    metadata = {"name": "buoy_coverage_v1", "render_modes": [], "is_parallelizable": True}

    def __init__(
        self,
        region: str | Region = "square",
        *,
        config: str | None = None,
        n_agents: int | None = None,
        radius: float | None = None,
        reward: str | None = "cr",
        observation: str | None = None,
        sensors_config: SensorsConfig | None = None,
        geofence: float | None | Unset = UNSET,
        reward_scale: float | None = None,
        union_credit: str | None = None,
        union_weight: float | None | Unset = UNSET,
        episode_length: int | None = None,
        shore: str | None = None,
        start: str = "corner",
        lose: int = 0,
        current: tuple[float, float] | None = None,
        params: Params | None = None,
        radius_m: float | None = None,
        speed_ms: float = BOB_SPEED,
        keep_lost: bool = False,
    ):
        params = params or load_params(packaged("params.yaml"))
        self.units = None
        if radius_m is not None:  # a lake file kept at its size in metres: the world's units say how (``units``)
            if not isinstance(region, str) or region in params.regions or radius is not None:
                raise ValueError("radius_m keeps a lake file at its real size; give region='LAKE_FILE' without "
                                 "radius (the simulation's coverage radius stays the paper's)")
            region, params = scaled_setup(Path(region), params, n_agents, radius_m)
            self.units = Units.of(params.world, params.coverage, radius_m, speed_ms)
            episode_length = episode_length or params.world.episode_length
        self.core = option_env(params, region, config=config, n_agents=n_agents, radius=radius, reward=reward,
                               observation=observation, sensors_config=sensors_config, geofence=geofence,
                               reward_scale=reward_scale, union_credit=union_credit, union_weight=union_weight,
                               episode_length=episode_length, shore=shore)
        world = self.core.world
        if start not in STARTS:
            raise ValueError(f"start must be one of {STARTS}, got {start!r}")
        if not 0 <= int(lose) < world.n_agents:
            raise ValueError(f"lose must be between 0 and n_agents - 1 ({world.n_agents - 1}), got {lose}")
        if lose and world.episode_length < 2:
            raise ValueError("lose needs an episode of at least 2 steps: the buoys are lost after half of it")
        self.start, self.lose, self.keep_lost = start, int(lose), keep_lost
        if current is not None:
            self.core.set_current(Current.uniform(np.asarray([current], dtype=float)))
        self._loss_rng = np.random.default_rng()
        self.possible_agents = [f"buoy_{i}" for i in range(world.n_agents)]
        self.agents: list[str] = []
        self.render_mode = None
        self._bounds = reachable_bounds(self.core)
        n = world.n_agents
        lo, hi = self._bounds
        self.state_space = spaces.Box(np.tile(lo, n).astype(np.float32), np.tile(hi, n).astype(np.float32),
                                      dtype=np.float32)

    @functools.cache  # noqa: B019 - PettingZoo expects the same space object per agent
    def observation_space(self, agent: str) -> spaces.Box:
        lo, hi = self._bounds if self.core.observation != "local" else local_bounds(self.core)
        d = self.core.obs_dim
        return spaces.Box(lo[:d].astype(np.float32), hi[:d].astype(np.float32), dtype=np.float32)

    @functools.cache  # noqa: B019
    def action_space(self, agent: str) -> spaces.Box:
        return spaces.Box(-1.0, 1.0, shape=(2,), dtype=np.float32)

    def _obs(self, obs: np.ndarray) -> dict:
        return {a: obs[0, i] for i, a in enumerate(self.possible_agents)}

    def reset(self, seed: int | None = None, options: dict | None = None):
        if seed is not None:
            self.core.seed(seed)
            self._loss_rng = np.random.default_rng([seed, 1])  # the losses of ``evaluate.rollout``
        obs = self.core.reset(start=self.start)
        self.agents = list(self.possible_agents)
        coverage = float(self.core.coverage_fraction(exact=self.units is not None)[0])
        return self._obs(obs), {a: {"coverage": coverage} for a in self.agents}

    def step(self, actions: dict):
        if not self.agents:
            raise RuntimeError("step() after the episode ended: call reset()")
        action = np.zeros((1, self.core.n_agents, 2))
        for i, a in enumerate(self.possible_agents):
            if a in actions:
                action[0, i] = np.asarray(actions[a], dtype=float)
        result = self.core.step(action)
        out = ~self.core.alive[0] if self.core.alive is not None else np.zeros(self.core.n_agents, bool)  # lost
        rewards = {a: 0.0 if out[i] else float(result.pay[0, i]) for i, a in enumerate(self.possible_agents)
                   if a in self.agents}
        truncated = bool(result.done)
        union = result.union_area[0]  # measured by the CR reward; NaN otherwise
        coverage = float(union / self.core.region.area if np.isfinite(union)
                         else self.core.coverage_fraction(exact=self.units is not None)[0])
        terminations = {a: False for a in self.agents}
        if self.lose and self.core.t == self.core.world.episode_length // 2:  # the loss, before the next step
            self.core.lose(self.lose, self._loss_rng)
            result = dataclasses.replace(result, obs=self.core.observe())  # the lost are no longer heard
            lost = [a for i, a in enumerate(self.possible_agents) if not self.core.alive[0, i]]
            terminations.update({a: not self.keep_lost for a in lost if a in self.agents})
            coverage = float(self.core.coverage_fraction(exact=self.units is not None)[0])  # the buoys in service
        obs = {a: o for a, o in self._obs(result.obs).items() if a in self.agents}
        truncations = {a: truncated for a in self.agents}
        info = {"coverage": coverage} if self.units is None else {"coverage": coverage,
                                                                  "time_s": self.units.steps_time_s(self.core.t)}
        infos = {a: dict(info) for a in self.agents}
        if self.keep_lost and self.core.alive is not None:  # a lost buoy stays, silent: zeros, no reward
            for i, a in enumerate(self.possible_agents):
                if a in obs and not self.core.alive[0, i]:
                    obs[a], rewards[a] = np.zeros_like(obs[a]), 0.0
                    infos[a]["lost"] = True
        self.agents = [] if truncated else [a for a in self.agents if not terminations[a]]
        return obs, rewards, terminations, truncations, infos

    def state(self) -> np.ndarray:
        """Every buoy's position and velocity, [x, y, vx, vy] per buoy: shape ``state_space.shape``."""
        return np.concatenate([self.core.pos[0], self.core.vel[0]], axis=1).ravel().astype(np.float32)

    def close(self) -> None:
        pass


def top_speed(core: CoverageEnv) -> float:
    """The largest velocity component a buoy reaches: the MPE update's terminal speed sensitivity·dt /
    (mass·damping) per component, or behind a wall, which turns a velocity along the shore, its norm (√2 times)."""
    w = core.world
    v_max = w.sensitivity * w.dt / (w.mass * w.damping)
    return v_max * np.sqrt(2.0) if core.wall else v_max


def reachable_bounds(core: CoverageEnv) -> tuple[np.ndarray, np.ndarray]:
    """Per-buoy bounds of [x, y, vx, vy]: a velocity component never exceeds ``top_speed``, v_max, and the water
    moves a buoy at most at the current's top speed, so a buoy released in the region is at most T·(v_max +
    current)·dt outside its box (or at the geofence; never outside the water behind a wall)."""
    w = core.world
    v_max = top_speed(core)
    drift = 0.0 if core.current is None else core.current.max_speed()
    minx, miny, maxx, maxy = core.region.polygon.bounds
    reach = w.episode_length * (v_max + drift) * w.dt if core.fence is None and not core.wall else 0.0
    box = (np.array([minx, miny]), np.array([maxx, maxy]))
    lo, hi = core.fence if core.fence is not None and not core.wall else box
    return (np.concatenate([lo - reach, [-v_max, -v_max]]) - 1e-6,
            np.concatenate([hi + reach, [v_max, v_max]]) + 1e-6)


def local_bounds(core: CoverageEnv) -> tuple[np.ndarray, np.ndarray]:
    """Bounds of the local observation (``sensors.columns``): velocity within ±v_max (over the ground, plus the
    current's top speed), a heard buoy within the communication range, its mask in [0, 1], a shore distance in
    [0, ray range], a share of uncovered water in [0, 1], a cell of the local raster in [0, 1], the local centroid's
    offset within the ray range."""
    sc = core.sensor_config
    v_max = top_speed(core)
    if sc.velocity == "ground" and core.current is not None:
        v_max += core.current.max_speed()
    k = sc.neighbours
    shares = (sc.rays if sc.uncovered else 0) + len(local_map.RASTER_CHANNELS) * sc.raster**2
    reach = [sc.ray_range] * (2 if sc.centroid else 0)
    lo = np.concatenate([[-v_max] * 2, [-sc.comm_range] * 2 * k, [0.0] * k, [0.0] * sc.rays, [0.0] * shares,
                         np.negative(reach)])
    hi = np.concatenate([[v_max] * 2, [sc.comm_range] * 2 * k, [1.0] * k, [sc.ray_range] * sc.rays, [1.0] * shares,
                         reach])
    return lo - 1e-6, hi + 1e-6


def parallel_env(**kwargs) -> CoverageParallelEnv:
    """The PettingZoo convention's parallel constructor: ``parallel_env(region="bedok", config="tuned")``."""
    return CoverageParallelEnv(**kwargs)


def env(**kwargs):
    """The same environment through PettingZoo's AEC API."""
    from pettingzoo.utils.conversions import parallel_to_aec

    return parallel_to_aec(parallel_env(**kwargs))
