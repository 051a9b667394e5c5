"""The coverage world as a PettingZoo ``ParallelEnv`` with Gymnasium spaces, for use in other MARL tools.

One environment (E = 1) of ``CoverageEnv``: any region, any N ≥ 1, any coverage radius, the SW or CR reward.
Agents are ``buoy_0 … buoy_{N−1}``; every episode is truncated after ``episode_length`` steps (no terminal
states, as in MPE).

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

from .config import Params, load_params, region_world
from .env import CoverageEnv
from .regions import Region, make_region

PACKAGE_PARAMS = Path(__file__).resolve().parents[2] / "params.yaml"


class CoverageParallelEnv(ParallelEnv):
    """PettingZoo parallel API over one ``CoverageEnv``.

    ``region`` is a name in params.yaml or a ``Region``; ``n_agents``, ``radius``, ``episode_length`` override
    params.yaml; ``reward`` is ``"sw"``, ``"cr"`` or ``None``; ``observation`` ``"position"`` or
    ``"position_velocity"``; ``geofence`` in metres or ``None``. Infos carry the fast-path coverage fraction.
    """

    metadata = {"name": "buoy_coverage_v0", "render_modes": [], "is_parallelizable": True}

    def __init__(
        self,
        region: str | Region = "square",
        *,
        n_agents: int | None = None,
        radius: float | None = None,
        reward: str | None = "cr",
        observation: str = "position",
        geofence: float | None = None,
        episode_length: int | None = None,
        params: Params | None = None,
    ):
        params = params or load_params(PACKAGE_PARAMS)
        world = region_world(params, region if isinstance(region, str) else None)
        if n_agents is not None:
            world = dataclasses.replace(world, n_agents=int(n_agents))
        if episode_length is not None:
            world = dataclasses.replace(world, episode_length=int(episode_length))
        coverage = params.coverage if radius is None else dataclasses.replace(params.coverage, radius=float(radius))
        if isinstance(region, str):
            region = make_region(region, params.regions[region], world.region_area, root=PACKAGE_PARAMS.parent)
        self.core = CoverageEnv(
            region, world, coverage, n_envs=1, reward=reward, sw=params.sw_reward, cr=params.cr_reward,
            observation=observation, geofence=geofence,
        )
        self.possible_agents = [f"buoy_{i}" for i in range(world.n_agents)]
        self.agents: list[str] = []
        self.render_mode = None

    @functools.cache  # noqa: B019 - PettingZoo expects the same space object per agent
    def observation_space(self, agent: str) -> spaces.Box:
        return spaces.Box(-np.inf, np.inf, shape=(self.core.obs_dim,), dtype=np.float32)

    @functools.cache  # noqa: B019
    def action_space(self, agent: str) -> spaces.Box:
        return spaces.Box(-1.0, 1.0, shape=(2,), dtype=np.float32)

    def _obs(self, obs: np.ndarray) -> dict:
        return {a: obs[0, i] for i, a in enumerate(self.possible_agents)}

    def reset(self, seed: int | None = None, options: dict | None = None):
        if seed is not None:
            self.core.seed(seed)
        obs = self.core.reset()
        self.agents = list(self.possible_agents)
        return self._obs(obs), {a: {} for a in self.agents}

    def step(self, actions: dict):
        if not self.agents:
            raise RuntimeError("step() after the episode ended: call reset()")
        action = np.zeros((1, self.core.n_agents, 2))
        for i, a in enumerate(self.possible_agents):
            if a in actions:
                action[0, i] = np.asarray(actions[a], dtype=float)
        result = self.core.step(action)
        obs = self._obs(result.obs)
        rewards = {a: float(result.reward[0, i]) for i, a in enumerate(self.possible_agents)}
        truncated = bool(result.done)
        union = result.union_area[0]  # measured by the CR reward; NaN otherwise
        coverage = float(union / self.core.region.area if np.isfinite(union) else self.core.coverage_fraction()[0])
        terminations = {a: False for a in self.agents}
        truncations = {a: truncated for a in self.agents}
        infos = {a: {"coverage": coverage} for a in self.agents}
        if truncated:
            self.agents = []
        return obs, rewards, terminations, truncations, infos

    def state(self) -> np.ndarray:
        return np.concatenate([self.core.pos[0].ravel(), self.core.vel[0].ravel()]).astype(np.float32)

    def close(self) -> None:
        pass
