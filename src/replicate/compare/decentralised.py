"""Decentralised Lloyd: the baseline that sees what the general policy sees.

Clairvoyant Lloyd (``baselines.lloyd``) clips each buoy's Voronoi cell of *all* buoys to the *whole* lake: the
centralised expert of the learned-coverage literature (CoverageControl's ``ClairvoyantCVT``). Here, as in its
``DecentralizedCVT``, a buoy knows only what its sensors give it:

* the buoys it hears: its ``neighbours`` nearest within ``comm_range`` (the policy's neighbour sensor), so its cell
  is its Voronoi cell among itself and them;
* the water it has sensed so far: every point of the lake within ``ray_range`` (its shore sensor's reach) of
  where it has been since the release, so the cell is clipped to that known water, not to the lake.

It steers to the centroid of that cell with Lloyd's law, a = gain·(c − p) − damping·v. Cells and centroids are
computed on a raster of the lake (points ``spacing`` apart, uniform density), batched ``[E, N, M]`` over
environments, buoys and raster points; a buoy whose cell holds no known point stays where it is.
"""

from __future__ import annotations

import numpy as np
import shapely
from scipy.spatial import cKDTree

from replicate.compare.baselines import Policy
from replicate.core.studies import LloydConfig
from replicate.world.env import CoverageEnv
from replicate.world.sensors import neighbours

CHUNK = 2_000_000  # env x buoy x neighbour x point distances computed at once (16 MB of float64)


def water_points(region, spacing: float) -> np.ndarray:
    """The raster: grid points ``spacing`` apart inside the lake → [M, 2]."""
    minx, miny, maxx, maxy = region.bounds
    gx, gy = np.meshgrid(np.arange(minx + spacing / 2, maxx, spacing), np.arange(miny + spacing / 2, maxy, spacing))
    grid = np.stack([gx.ravel(), gy.ravel()], axis=1)
    return grid[shapely.contains_xy(region, grid[:, 0], grid[:, 1])]


def sense(known: np.ndarray, pos: np.ndarray, tree, reach: float) -> np.ndarray:
    """Mark in ``known`` [E, N, M] the raster points (``tree``, a ``scipy.spatial.cKDTree`` of them) each buoy
    senses now, within ``reach`` of it. pos [E, N, 2] → ``known``."""
    e, n = pos.shape[:2]
    for flat, near in enumerate(tree.query_ball_point(pos.reshape(-1, 2), reach)):
        known[flat // n, flat % n, near] = True
    return known


def local_centroids(pos: np.ndarray, known: np.ndarray, points: np.ndarray, k: int, comm_range: float,
                    alive: np.ndarray | None) -> np.ndarray:
    """Each buoy's centroid of the known water nearer to it than to any buoy it hears. pos [E, N, 2], known
    [E, N, M] bool, points [M, 2] → [E, N, 2] (the buoy's own position where that cell is empty)."""
    rel, heard = neighbours(pos, k, comm_range, alive)  # [E, N, k, 2] (other − self), [E, N, k]
    e, n = pos.shape[:2]
    out = pos.copy()
    rows = max(1, CHUNK // max(1, n * (k + 1) * len(points)))
    for lo in range(0, e, rows):  # a few environments at a time: [rows, N, k, M] distances
        p, w = pos[lo:lo + rows], points[None, None]
        own = np.linalg.norm(w - p[:, :, None, :], axis=-1)  # [rows, N, M]
        others = p[:, :, None, :] + rel[lo:lo + rows]  # [rows, N, k, 2]
        theirs = np.linalg.norm(w[:, :, None] - others[..., None, :], axis=-1)  # [rows, N, k, M]
        theirs = np.where(heard[lo:lo + rows, ..., None] > 0, theirs, np.inf).min(axis=2)
        cell = known[lo:lo + rows] & (own <= theirs)
        count = cell.sum(axis=-1)
        centroid = (cell[..., None] * points).sum(axis=2) / np.maximum(count, 1)[..., None]
        out[lo:lo + rows] = np.where(count[..., None] > 0, centroid, p)
    return out


def decentralised_lloyd(cfg: LloydConfig, spacing: float) -> Policy:
    """Lloyd's law toward ``local_centroids`` (module docstring), on a raster of ``spacing`` metres; the sensors'
    ranges and neighbour count are the environment's (``env.sensor_config``)."""
    state: dict = {}

    def policy(env: CoverageEnv) -> np.ndarray:
        sc = env.sensor_config
        if state.get("region") is not env.region:
            points = water_points(env.region.polygon, spacing)
            state.update(region=env.region, points=points, tree=cKDTree(points))
        points = state["points"]
        if env.t == 0 or state.get("known") is None or state["known"].shape[:2] != env.pos.shape[:2]:
            state["known"] = np.zeros((*env.pos.shape[:2], len(points)), bool)  # a new episode: nothing known yet
        sense(state["known"], env.pos, state["tree"], sc.ray_range)
        seen = np.flatnonzero(state["known"].any(axis=(0, 1)))  # a cell holds only known points: the rest waits
        target = local_centroids(env.pos, state["known"][..., seen], points[seen], sc.neighbours, sc.comm_range,
                                 env.alive)
        action = np.clip(cfg.gain * (target - env.pos) - cfg.damping * env.vel, -1.0, 1.0)
        return action if env.alive is None else np.where(env.alive[..., None], action, 0.0)

    return policy
