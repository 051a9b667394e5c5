"""Baselines and references (SPEC §7), as policies of the same environment: ``policy(env) → actions [E, N, 2]``.

* random actions;
* naive swarming (after Zoss et al. 2018): attraction toward the region's interior plus avoidance of agents
  closer than a range, hand-set gains;
* Lloyd / centroidal Voronoi (Cortés et al. 2004): each agent steers toward the centroid of its Voronoi cell
  clipped to the region; its converged layout is the practical optimum of the coverage metric on a convex lake
  (on a lake with arms the centroid objective is not coverage: ``best_layout`` is the limit there);
* geodesic Lloyd: the same with cells and paths measured through the water (``geodesic``), for lakes with arms.
"""

from __future__ import annotations

import functools
from collections.abc import Callable

import numpy as np
import shapely
from shapely.geometry import Polygon

from replicate.core.studies import LloydConfig, NaiveConfig
from replicate.world.env import CoverageEnv
from replicate.world.geodesic import geodesic_targets, water_graph
from replicate.world.geometry import long_shore, minkowski, polygon_offsets
from replicate.world.local_water import Rings

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


@functools.lru_cache(maxsize=64)
def _middle(region_wkb: bytes) -> Polygon:
    region = shapely.from_wkb(region_wkb)
    depth = shapely.maximum_inscribed_circle(region).length  # the deepest point's distance to the shore
    return region.buffer(-0.5 * depth)


@functools.lru_cache(maxsize=64)
def _interior(region_wkb: bytes, radius: float, edges: int) -> Polygon:
    region = shapely.from_wkb(region_wkb)
    eroded = minkowski(region, polygon_offsets(radius, edges))[0]
    return eroded if not eroded.is_empty else _middle(region_wkb)


def interior(region: Polygon, radius: float, edges: int) -> Polygon:
    """Naive swarming's target: the interior Reg ⊖ Cov, where a buoy's coverage polygon (``edges``-gon of
    circumradius ``radius``) fits in the water, the polygon the environment's fast path erodes the lake to. Where
    the lake is nowhere that deep (its deepest point closer to the shore than R, so Reg ⊖ Cov is empty), the
    water at least half the deepest point's depth from the shore: a non-empty middle of the lake, never the
    whole lake (which would leave buoys on the shore with no pull at all). Computed once per lake, without the
    fast path's area table and raster, which a lake hundreds of radii across cannot hold."""
    return _interior(region.wkb, float(radius), int(edges))


def naive_swarming(cfg: NaiveConfig) -> Policy:
    """Attraction toward the interior (``interior``: the points where the coverage polygon fits, Reg ⊖ Cov) for
    agents outside it, plus linear repulsion from every agent closer than ``avoid_range``, minus a velocity
    damping."""

    def steer(env: CoverageEnv, pos: np.ndarray, vel: np.ndarray) -> np.ndarray:
        target_region = interior(env.region.polygon, env.coverage.radius, env.coverage.edges)
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


SEPARATION = 1e-6  # m: how far apart ``separate_coincident`` sets buoys that share a point, for the diagram only
COINCIDENT = 1e-9  # m: buoys closer than this share a point (GEOS fails on sites 1e-15 apart as on equal ones)
SLIVER = 1e-12  # a cell's clipped area below this share of its own holds no water (the clipping's rounding)


def separate_coincident(xy: np.ndarray, water: Polygon, eps: float = SEPARATION) -> np.ndarray:
    """The points [E, N, 2] with every group of m > 1 coincident points (``COINCIDENT``) of one environment spread
    onto a circle of radius ``eps`` about their point, member k at angle θ + π/m + 2πk/m (k in agent order), θ the
    direction from the point toward a point of ``water`` (``point_on_surface``). GEOS builds no Voronoi diagram of
    coincident points; spread this way, the group's shared cell splits into m wedges, one boundary of which points
    into the water, so a group that the shore wall pinned to one vertex has at least two wedges in the water and
    breaks up. Points that are not shared are returned as they are: a diagram without coincident points is
    unchanged."""
    same = (np.abs(xy[:, :, None] - xy[:, None]) <= COINCIDENT).all(axis=-1)  # [E, N, N]
    size = same.sum(axis=2)  # [E, N]: how many agents share agent i's point (itself included)
    if (size == 1).all():
        return xy
    rank = np.tril(same, k=-1).sum(axis=2)  # [E, N]: how many of them come before it
    toward = shapely.get_coordinates(water.point_on_surface())[0] - xy
    angle = np.arctan2(toward[..., 1], toward[..., 0]) + np.pi * (2 * rank + 1) / size
    offset = eps * np.stack([np.cos(angle), np.sin(angle)], axis=-1) * (size > 1)[..., None]
    return xy + offset


def voronoi_centroids(region: Polygon, xy: np.ndarray) -> np.ndarray:
    """Centroid of each agent's Voronoi cell clipped to the region (nearest region point if the cell misses
    it). xy [N, 2] or, for E environments at once, [E, N, 2] → the same shape.

    Each environment's diagram is its own (its frame is padded by its own agents' reach); GEOS runs once for all
    environments' diagrams, once for all clippings and once for all centroids (a Python loop over environments
    cost as much as GEOS). Agents at one point share its cell in equal wedges (``separate_coincident``); an
    environment whose diagram GEOS still cannot build has its agents head for the region's nearest point."""
    xy = np.asarray(xy, dtype=float)
    batch = xy[None] if xy.ndim == 2 else xy
    e, n = batch.shape[:2]
    if n == 1:
        cells, proper = np.full(e, region, dtype=object), np.ones(e, bool)
    else:
        sites = separate_coincident(batch, region)
        minx, miny, maxx, maxy = region.bounds
        pad = max(maxx - minx, maxy - miny) + np.abs(sites).max(axis=(1, 2))  # [E]
        frames = shapely.box(minx - pad, miny - pad, maxx + pad, maxy + pad)
        diagrams = shapely.voronoi_polygons(shapely.multipoints(sites), extend_to=frames, ordered=True)
        parts, owner = shapely.get_parts(diagrams, return_index=True)
        proper = np.bincount(owner, minlength=len(diagrams)) == n  # a diagram with a cell per agent
        cells = parts[proper[owner]]  # the proper environments' cells, n each, in agent order
    if long_shore(region) and n > 1:  # convex cells (one buoy's cell is the whole lake)
        target, empty, no_centroid = water_centroids(region, cells, n)
    else:
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


def water_centroids(region: Polygon, cells: np.ndarray, n: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``voronoi_centroids``' clipping on a long shore (``geometry.long_shore``): each convex cell [E' · N] against
    the region's rings in a compiled loop (``local_water``), the same centroids as shapely's to float rounding →
    (centroids [E', N, 2], cells without water [E', N], environments with a degenerate clipping [E', 1]). A cell
    whose water is a line, a point or under ``SLIVER`` of its area counts as dry (shapely's clipping would give
    the centroid of the line or sliver): its buoy heads for the nearest water."""
    if len(cells) == 0:  # no environment's diagram could be built
        return np.zeros((0, n, 2)), np.zeros((0, n), bool), np.zeros((0, 1), bool)
    coords, which = shapely.get_coordinates(cells, return_index=True)
    count = np.bincount(which, minlength=len(cells))
    # each cell's ring (closed) padded with its last vertex: a zero-length edge clips nothing
    slot = np.arange(len(coords)) - np.repeat(np.cumsum(count) - count, count)
    clips = np.repeat(coords[np.cumsum(count) - 1][:, None], count.max(), axis=1)
    clips[which, slot] = coords
    area, mx, my = region_rings(region.wkb).moments(clips).T
    empty = (area <= SLIVER * shapely.area(cells)).reshape(-1, n)  # float noise of a cell off the water is no water
    with np.errstate(invalid="ignore", divide="ignore"):
        target = np.stack([mx / area, my / area], axis=-1).reshape(-1, n, 2)
    no_centroid = (np.isnan(target).any(axis=-1) & ~empty).any(axis=1, keepdims=True)
    return target, empty, no_centroid


@functools.lru_cache(maxsize=16)
def region_rings(region_wkb: bytes) -> Rings:
    """The rings of a region (``local_water.Rings``), once per region in a process."""
    return Rings.of([shapely.from_wkb(region_wkb)])


def lloyd(cfg: LloydConfig) -> Policy:
    """Steer toward the clipped Voronoi centroid: a = gain·(c − p) − damping·v, clipped to [-1, 1]."""

    def steer(env: CoverageEnv, pos: np.ndarray, vel: np.ndarray) -> np.ndarray:
        target = voronoi_centroids(env.region.polygon, pos)
        return np.clip(cfg.gain * (target - pos) - cfg.damping * vel, -1.0, 1.0)

    return for_live_buoys(steer)


def geodesic_lloyd(cfg: LloydConfig, spacing: float, lookahead: float) -> Policy:
    """Lloyd through the water (``geodesic``): steer toward the centroid of the buoy's geodesic cell along the
    shortest path, a = gain·d·u − damping·v, clipped to [-1, 1], where d is the distance to sail and u the unit
    vector toward the path's waypoint ``lookahead`` metres ahead. On a convex lake it is Lloyd to the raster's
    ``spacing``; on a lake with arms, a buoy's cell ends where sailing, not flying, is shorter for another."""
    def steer(env: CoverageEnv, pos: np.ndarray, vel: np.ndarray) -> np.ndarray:
        g = water_graph(env.region.polygon, spacing)
        action = np.empty_like(pos)
        for e in range(len(pos)):  # one Dijkstra per environment (scipy runs all of its buoys at once)
            _, waypoint, distance = geodesic_targets(g, pos[e], lookahead)
            heading = waypoint - pos[e]
            heading /= np.maximum(np.linalg.norm(heading, axis=1, keepdims=True), 1e-9)
            action[e] = cfg.gain * distance[:, None] * heading
        return np.clip(action - cfg.damping * vel, -1.0, 1.0)

    return for_live_buoys(steer)
