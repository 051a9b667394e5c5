"""Baselines and references (SPEC §7), as policies of the same environment: ``policy(env) → actions [E, N, 2]``.

* random actions;
* naive swarming (after Zoss et al. 2018): attraction toward the region's interior plus avoidance of agents
  closer than a range, hand-set gains;
* Lloyd / centroidal Voronoi (Cortés et al. 2004): each agent steers toward the centroid of its Voronoi cell
  clipped to the region; its converged layout is the practical optimum of the coverage metric.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
import shapely
from shapely.geometry import Polygon

from .config import LloydConfig, NaiveConfig
from .env import CoverageEnv

Policy = Callable[[CoverageEnv], np.ndarray]


def nearest_in(polygon: Polygon, xy: np.ndarray) -> np.ndarray:
    """The point of ``polygon`` nearest each point (the point itself when inside). [M, 2] → [M, 2]."""
    lines = shapely.shortest_line(shapely.points(xy), polygon)
    return shapely.get_coordinates(lines).reshape(-1, 2, 2)[:, 1]


def random_policy(rng: np.random.Generator) -> Policy:
    """Uniform random actions in [-1, 1]² from ``rng``."""

    def policy(env: CoverageEnv) -> np.ndarray:
        return rng.uniform(-1.0, 1.0, size=(env.n_envs, env.n_agents, 2))

    return policy


def for_live_buoys(steer: Callable[[CoverageEnv, np.ndarray, np.ndarray], np.ndarray]) -> Policy:
    """A policy from ``steer(env, pos, vel) → actions``, all [E, M, 2], that sees only the buoys still in service:
    a lost buoy neither steers nor is seen by the others."""

    def policy(env: CoverageEnv) -> np.ndarray:
        action = steer(env, env.live(env.pos), env.live(env.vel))
        if env.alive is None:
            return action
        out = np.zeros((env.n_envs, env.n_agents, 2))
        out[env.alive] = action.reshape(-1, 2)
        return out

    return policy


def naive_swarming(cfg: NaiveConfig) -> Policy:
    """Attraction toward the interior (the points where the coverage polygon fits, Reg ⊖ Cov) for agents
    outside it, plus linear repulsion from every agent closer than ``avoid_range``, minus a velocity damping."""

    def steer(env: CoverageEnv, pos: np.ndarray, vel: np.ndarray) -> np.ndarray:
        target_region = env.geometry.eroded if not env.geometry.eroded.is_empty else env.region.polygon
        flat = pos.reshape(-1, 2)
        outside = ~shapely.contains_xy(target_region, flat[:, 0], flat[:, 1])
        attract = np.zeros_like(flat)
        if outside.any():
            delta = nearest_in(target_region, flat[outside]) - flat[outside]
            dist = np.linalg.norm(delta, axis=1, keepdims=True)
            attract[outside] = cfg.attraction * delta / np.maximum(dist, 0.2)
        diff = pos[:, :, None, :] - pos[:, None, :, :]  # [E, N, N, 2]: p_i − p_j
        d = np.linalg.norm(diff, axis=-1)
        weight = np.where((d > 0) & (d < cfg.avoid_range), 1.0 - d / cfg.avoid_range, 0.0)
        unit = diff / np.maximum(d, 1e-9)[..., None]
        avoid = cfg.avoidance * (weight[..., None] * unit).sum(axis=2)
        action = attract.reshape(pos.shape) + avoid - cfg.damping * vel
        return np.clip(action, -1.0, 1.0)

    return for_live_buoys(steer)


def voronoi_centroids(region: Polygon, xy: np.ndarray) -> np.ndarray:
    """Centroid of each agent's Voronoi cell clipped to the region (nearest region point if the cell misses
    it). xy [N, 2] or, for E environments at once, [E, N, 2] → the same shape.

    Each environment's diagram is its own (its frame is padded by its own agents' reach); GEOS runs once for all
    environments' diagrams, once for all clippings and once for all centroids (a Python loop over environments
    cost as much as GEOS). An environment whose agents coincide has no proper diagram: its agents head for the
    region's nearest point."""
    xy = np.asarray(xy, dtype=float)
    batch = xy[None] if xy.ndim == 2 else xy
    e, n = batch.shape[:2]
    if n == 1:
        cells, proper = np.full(e, region, dtype=object), np.ones(e, bool)
    else:
        same = (batch[:, :, None] == batch[:, None]).all(axis=-1)  # [E, N, N]
        proper = same.sum(axis=(1, 2)) == n  # no two agents at one point (GEOS refuses such a diagram)
        minx, miny, maxx, maxy = region.bounds
        pad = max(maxx - minx, maxy - miny) + np.abs(batch[proper]).max(axis=(1, 2))  # [E']
        frames = shapely.box(minx - pad, miny - pad, maxx + pad, maxy + pad)
        diagrams = shapely.voronoi_polygons(shapely.multipoints(batch[proper]), extend_to=frames, ordered=True)
        parts, owner = shapely.get_parts(diagrams, return_index=True)
        whole = np.bincount(owner, minlength=len(diagrams)) == n  # a diagram with a cell per agent
        proper[proper] = whole
        cells = parts[whole[owner]]  # the proper environments' cells, n each, in agent order
    clipped = shapely.intersection(cells, region).reshape(-1, n)  # [E', N]
    coords, which = shapely.get_coordinates(shapely.centroid(clipped).ravel(), return_index=True)
    target = np.full((*clipped.shape, 2), np.nan)  # [E', N, 2], NaN where a cell has no centroid
    target.reshape(-1, 2)[which] = coords
    empty = shapely.is_empty(clipped)
    no_centroid = (np.isnan(target).any(axis=-1) & ~empty).any(axis=1, keepdims=True)  # degenerate clipping
    out = np.empty((e, n, 2))
    out[proper] = target
    nearest = np.ones((e, n), bool)
    nearest[proper] = empty | no_centroid
    if nearest.any():
        out[nearest] = nearest_in(region, batch[nearest])
    return out[0] if xy.ndim == 2 else out


def lloyd(cfg: LloydConfig) -> Policy:
    """Steer toward the clipped Voronoi centroid: a = gain·(c − p) − damping·v, clipped to [-1, 1]."""

    def steer(env: CoverageEnv, pos: np.ndarray, vel: np.ndarray) -> np.ndarray:
        target = voronoi_centroids(env.region.polygon, pos)
        return np.clip(cfg.gain * (target - pos) - cfg.damping * vel, -1.0, 1.0)

    return for_live_buoys(steer)
