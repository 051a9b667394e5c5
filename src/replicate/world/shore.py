"""The shore as a wall: a buoy's step that would leave the water ends at the shoreline, and the velocity component
out through the shore is removed, so no buoy is ever outside the water (islands included).

The region is a closed set: a point on the shoreline is in the water. A step from the water can only leave it
by crossing an edge of the shoreline from the edge's water side to its land side, so a step that crosses no edge
that way ends in the water, and one that does ends at its first such crossing (a buoy never tunnels through a
spit of land thinner than a step), pulled back towards its start by ``PULL_BACK`` of the step. Crossings within
``TOUCH`` of an edge's ends or of the step's end count, so rounding errs towards stopping; a stopped position is
checked again by GEOS (exact) and falls back to the step's start, which was in the water.

The crossings are found by a compiled loop over the shore's edges (``first_exits``), and a grid (``Shoreline``)
lists for each cell the edges a step from there can reach, so a step far from the shore checks nothing. Arrays
are flat ``[M, 2]`` (M = E·N buoys).
"""

from __future__ import annotations

from dataclasses import dataclass

import numba
import numpy as np
import shapely
from shapely.geometry import Polygon

from replicate.world.sensors import shore_segments

PULL_BACK = 1e-9  # of the step's length: far below any scale of the world, far above rounding of the crossing
TOUCH = 1e-12  # a step that ends on the shore, or crosses it at an edge's end, counts as crossing it there


def outside(water: Polygon, xy: np.ndarray) -> np.ndarray:
    """Which points [M, 2] are outside the closed region. → [M] bool."""
    return ~shapely.intersects_xy(water, xy[:, 0], xy[:, 1])


def first_crossing(water: Polygon, start: np.ndarray, end: np.ndarray) -> np.ndarray:
    """Fraction t ∈ [0, 1] of each segment start → end [M, 2] at which it first meets the shoreline (any ring);
    1 for a segment that does not meet it. → [M]. By shapely, slow: the tests' reference for ``first_exits``."""
    lines = shapely.linestrings(np.stack([start, end], axis=1))
    hits = shapely.intersection(lines, water.boundary)
    # every vertex of every hit: crossing points, or the ends of a stretch of the segment lying along the shore
    coords, owner = shapely.get_coordinates(hits, return_index=True)
    t = np.ones(len(start))
    if len(coords):
        along = shapely.line_locate_point(lines[owner], shapely.points(coords), normalized=True)
        np.minimum.at(t, owner, along)
    return t


@dataclass(frozen=True)
class Shoreline:
    """The shore's edges with the water to their left (``sensors.shore_segments``), [S, 4] rows (ax, ay, bx, by),
    and a grid over the region: cell c lists in ``index[starts[c]:starts[c + 1]]`` every edge that a step of at
    most ``reach`` starting in the cell can meet, so a step near no shore checks nothing."""

    edges: np.ndarray
    origin: np.ndarray  # [2] lower-left corner of the grid
    reach: float  # the longest step the grid answers for
    cell: float  # the side of its cells: at least ``reach``, and at most 512 cells along the region's box
    shape: tuple[int, int]  # cells along x, y
    starts: np.ndarray  # [cells + 1]
    index: np.ndarray  # [entries] edge numbers


def shoreline(water: Polygon, reach: float) -> Shoreline:
    """The ``Shoreline`` of ``water`` for steps of at most ``reach`` (cells ``reach`` wide)."""
    edges = shore_segments(water)
    minx, miny, maxx, maxy = water.bounds
    cell = max(float(reach), max(maxx - minx, maxy - miny) / 512)  # wider cells only list more edges
    origin = np.array([minx, miny])
    shape = (int(np.ceil((maxx - minx) / cell)) + 1, int(np.ceil((maxy - miny) / cell)) + 1)
    lo = np.minimum(edges[:, :2], edges[:, 2:]) - reach  # an edge's box grown by a step
    hi = np.maximum(edges[:, :2], edges[:, 2:]) + reach
    first = np.clip(np.floor((lo - origin) / cell).astype(int), 0, np.array(shape) - 1)
    last = np.clip(np.floor((hi - origin) / cell).astype(int), 0, np.array(shape) - 1)
    lists: list[list[int]] = [[] for _ in range(shape[0] * shape[1])]
    for k, ((x0, y0), (x1, y1)) in enumerate(zip(first, last)):
        for ix in range(x0, x1 + 1):
            for iy in range(y0, y1 + 1):
                lists[ix * shape[1] + iy].append(k)
    starts = np.zeros(len(lists) + 1, dtype=np.int64)
    starts[1:] = np.cumsum([len(x) for x in lists])
    index = np.array([k for x in lists for k in x], dtype=np.int64)
    return Shoreline(edges, origin, float(reach), cell, shape, starts, index)


@numba.njit(cache=True)
def _first_exits(start, end, edges, origin, reach, cell, nx, ny, starts, index, t_out, edge_out):  # pragma: no cover
    for m in range(start.shape[0]):
        sx, sy = start[m, 0], start[m, 1]
        dx, dy = end[m, 0] - sx, end[m, 1] - sy
        t_out[m], edge_out[m] = 2.0, -1
        if dx == 0.0 and dy == 0.0:
            continue
        ix, iy = int(np.floor((sx - origin[0]) / cell)), int(np.floor((sy - origin[1]) / cell))
        local = dx * dx + dy * dy <= reach * reach and 0 <= ix < nx and 0 <= iy < ny
        lo, hi = (starts[ix * ny + iy], starts[ix * ny + iy + 1]) if local else (0, edges.shape[0])
        for j in range(lo, hi):
            k = index[j] if local else j
            ax, ay, bx, by = edges[k, 0], edges[k, 1], edges[k, 2], edges[k, 3]
            ex, ey = bx - ax, by - ay
            denom = dx * ey - dy * ex  # > 0: the step crosses the edge's line from the water out
            if denom <= 0.0:
                continue
            qx, qy = ax - sx, ay - sy
            t = (qx * ey - qy * ex) / denom
            u = (qx * dy - qy * dx) / denom
            if -TOUCH <= t <= 1.0 + TOUCH and -TOUCH <= u <= 1.0 + TOUCH and t < t_out[m]:
                t_out[m], edge_out[m] = t, k


def first_exits(shore: Shoreline, start: np.ndarray, end: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """For each step start → end [M, 2], the fraction t of it at which it first crosses the shoreline out of the
    water and the edge it crosses there; t = 2 and edge −1 for a step that stays in. → ([M], [M])."""
    t, edge = np.empty(len(start)), np.empty(len(start), dtype=np.int64)
    _first_exits(np.ascontiguousarray(start, dtype=np.float64), np.ascontiguousarray(end, dtype=np.float64),
                 shore.edges, shore.origin, shore.reach, shore.cell, shore.shape[0], shore.shape[1], shore.starts,
                 shore.index,
                 t, edge)
    return t, edge


def wall_step(water: Polygon, start: np.ndarray, end: np.ndarray, vel: np.ndarray,
              shore: Shoreline | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Positions and velocities [M, 2] after a step start → end against the shore: a step that meets the
    shoreline stops at its first crossing and loses its velocity component along the outward normal of the edge
    it crossed. ``start`` must be in the water. ``shore`` is ``shoreline(water, reach)`` for steps up to
    ``reach`` (longer ones check every edge); without it one is built for these steps."""
    if shore is None:
        shore = shoreline(water, max(float(np.linalg.norm(end - start, axis=1).max(initial=0.0)), 1e-9))
    t, edge = first_exits(shore, start, end)
    rows = np.flatnonzero(edge >= 0)
    if len(rows) == 0:
        return end, vel
    s, step = start[rows], end[rows] - start[rows]
    stop = s + np.clip(t[rows] - PULL_BACK, 0.0, 1.0)[:, None] * step
    stop = np.where(outside(water, stop)[:, None], s, stop)  # rounding: the start is in the water
    e = shore.edges[edge[rows]]
    n = np.stack([e[:, 3] - e[:, 1], e[:, 0] - e[:, 2]], axis=1)  # (ey, −ex): the land side of the edge
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    pos, vel = end.copy(), vel.copy()
    v = vel[rows]
    pos[rows] = stop
    vel[rows] = v - np.maximum((v * n).sum(axis=1), 0.0)[:, None] * n
    return pos, vel


def distance_outside(water: Polygon, xy: np.ndarray) -> np.ndarray:
    """How far each point [..., 2] is outside the water (0 inside or on the shore). → [...]."""
    flat = xy.reshape(-1, 2)
    return shapely.distance(water, shapely.points(flat)).reshape(xy.shape[:-1])
