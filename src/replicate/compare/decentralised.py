"""Decentralised Lloyd: the baseline that sees what the general policy sees.

Clairvoyant Lloyd (``baselines.lloyd``) clips each buoy's Voronoi cell of *all* buoys to the *whole* lake: the
centralised expert of the learned-coverage literature (CoverageControl's ``ClairvoyantCVT``). Here, as in its
``DecentralizedCVT``, a buoy knows only what its sensors give it:

* the buoys it hears: its ``neighbours`` nearest within ``comm_range`` (the policy's neighbour sensor), so its cell
  is its Voronoi cell among itself and them;
* the water it has sensed so far: every point of the lake within ``ray_range`` (its shore sensor's reach) of
  where it has been since the release, so the cell is clipped to that known water, not to the lake.

It steers to the centroid of that cell with Lloyd's law, a = gain·(c − p) − damping·v. Cells and centroids are
computed on a raster of the lake (points ``spacing`` apart, uniform density) by two compiled loops over
environments, buoys and the raster points each buoy knows (``known`` [E, N, M]); a buoy whose cell holds no known
point stays where it is.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from replicate.compare.baselines import Policy
from replicate.core.studies import LloydConfig
from replicate.world.env import CoverageEnv
from replicate.world.geometry import grid_in, grid_points
from replicate.world.sensors import neighbours


class Raster:
    """The lake's raster: ``points`` [M, 2], grid points ``spacing`` apart inside the water, and ``index`` [GX, GY],
    each grid cell's point (−1 on land), whose cell (0, 0) is centred at ``origin``: the points near a position are
    read from the grid, not searched."""

    def __init__(self, region, spacing: float):
        xs, ys, inside = grid_in(region, spacing)  # a lake narrower than the spacing: one point, maybe dry
        self.points = grid_points(xs, ys, inside)  # the water's, read once
        self.index = np.full(inside.shape, -1, np.int64)
        self.index[inside] = np.arange(inside.sum())
        self.origin, self.spacing = np.array([xs[0], ys[0]]), float(spacing)


@njit(cache=True)
def _sense(known, pos, points, index, origin, spacing, reach):  # pragma: no cover - compiled
    """``sense``'s loop: each buoy marks the raster points of the grid cells around it within ``reach``."""
    e_count, n_count = pos.shape[0], pos.shape[1]
    span, reach2 = int(reach / spacing) + 1, reach * reach
    for e in range(e_count):
        for i in range(n_count):
            x, y = pos[e, i, 0], pos[e, i, 1]
            cx, cy = int(round((x - origin[0]) / spacing)), int(round((y - origin[1]) / spacing))
            for gx in range(max(0, cx - span), min(index.shape[0], cx + span + 1)):
                for gy in range(max(0, cy - span), min(index.shape[1], cy + span + 1)):
                    m = index[gx, gy]
                    if m >= 0 and not known[e, i, m]:
                        dx, dy = points[m, 0] - x, points[m, 1] - y
                        if dx * dx + dy * dy <= reach2:
                            known[e, i, m] = True


def sense(known: np.ndarray, pos: np.ndarray, raster: Raster, reach: float) -> np.ndarray:
    """Mark in ``known`` [E, N, M] the raster points each buoy senses now, within ``reach`` of it (read from the
    grid cells around it). pos [E, N, 2] → ``known``."""
    _sense(known, np.ascontiguousarray(pos, np.float64), raster.points, raster.index, raster.origin, raster.spacing,
           float(reach))
    return known


@njit(cache=True)
def _centroids(pos, known, points, rel, heard, out):  # pragma: no cover - compiled
    """``local_centroids``'s loop: a known point is in buoy i's cell unless a buoy it hears is nearer to it."""
    e_count, n_count, k_count = heard.shape
    for e in range(e_count):
        for i in range(n_count):
            x, y = pos[e, i, 0], pos[e, i, 1]
            sx, sy, count = 0.0, 0.0, 0
            for m in range(points.shape[0]):
                if not known[e, i, m]:
                    continue
                qx, qy = points[m, 0], points[m, 1]
                own = (qx - x) ** 2 + (qy - y) ** 2
                mine = True
                for k in range(k_count):
                    if heard[e, i, k] > 0:
                        ox, oy = x + rel[e, i, k, 0], y + rel[e, i, k, 1]
                        if (qx - ox) ** 2 + (qy - oy) ** 2 < own:
                            mine = False
                            break
                if mine:
                    sx, sy, count = sx + qx, sy + qy, count + 1
            if count > 0:
                out[e, i, 0], out[e, i, 1] = sx / count, sy / count


def local_centroids(pos: np.ndarray, known: np.ndarray, points: np.ndarray, k: int, comm_range: float,
                    alive: np.ndarray | None) -> np.ndarray:
    """Each buoy's centroid of the known water nearer to it than to any buoy it hears. pos [E, N, 2], known
    [E, N, M] bool, points [M, 2] → [E, N, 2] (the buoy's own position where that cell is empty)."""
    rel, heard = neighbours(pos, k, comm_range, alive)  # [E, N, k, 2] (other − self), [E, N, k]
    pos = np.ascontiguousarray(pos, np.float64)
    out = pos.copy()  # a buoy's own position where its cell holds no known point
    _centroids(pos, np.ascontiguousarray(known), np.ascontiguousarray(points, np.float64),
               np.ascontiguousarray(rel, np.float64), np.ascontiguousarray(heard), out)
    return out


def decentralised_lloyd(cfg: LloydConfig, spacing: float) -> Policy:
    """Lloyd's law toward ``local_centroids`` (module docstring), on a raster of ``spacing`` metres; the sensors'
    ranges and neighbour count are the environment's (``env.sensor_config``)."""
    state: dict = {}

    def policy(env: CoverageEnv) -> np.ndarray:
        sc = env.sensor_config
        if state.get("region") is not env.region:
            state.update(region=env.region, raster=Raster(env.region.polygon, spacing))
        raster = state["raster"]
        if env.t == 0 or state.get("known") is None or state["known"].shape[:2] != env.pos.shape[:2]:
            state["known"] = np.zeros((*env.pos.shape[:2], len(raster.points)), bool)  # a new episode: none known
        sense(state["known"], env.pos, raster, sc.ray_range)
        target = local_centroids(env.pos, state["known"], raster.points, sc.neighbours, sc.comm_range, env.alive)
        action = np.clip(cfg.gain * (target - env.pos) - cfg.damping * env.vel, -1.0, 1.0)
        return action if env.alive is None else np.where(env.alive[..., None], action, 0.0)

    return policy
