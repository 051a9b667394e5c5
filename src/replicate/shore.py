"""The shore as a wall: a buoy's step that would leave the water ends at the shoreline, and the velocity component
out through the shore is removed, so no buoy is ever outside the water (islands included).

The region is a closed set: a point on the shoreline is in the water. Positions keep that invariant by
construction: a step's end is either checked to be in the water (``shapely.intersects_xy``, exact in GEOS) or is
the step's start, which was. A step that meets the shoreline ends at its first crossing (so a buoy never tunnels
through a spit of land thinner than a step), pulled back towards its start by ``PULL_BACK`` of the step, so that
rounding cannot put it outside.

Arrays are flat ``[M, 2]`` (M = E·N buoys); only the steps that start near the shore are worked on.
"""

from __future__ import annotations

import numpy as np
import shapely
from shapely.geometry import Polygon

PULL_BACK = 1e-9  # of the step's length: far below any scale of the world, far above rounding of the crossing


def outside(water: Polygon, xy: np.ndarray) -> np.ndarray:
    """Which points [M, 2] are outside the closed region. → [M] bool."""
    return ~shapely.intersects_xy(water, xy[:, 0], xy[:, 1])


def first_crossing(water: Polygon, start: np.ndarray, end: np.ndarray) -> np.ndarray:
    """Fraction t ∈ [0, 1] of each segment start → end [M, 2] at which it first meets the shoreline (any ring);
    1 for a segment that does not meet it. → [M]."""
    lines = shapely.linestrings(np.stack([start, end], axis=1))
    hits = shapely.intersection(lines, water.boundary)
    # every vertex of every hit: crossing points, or the ends of a stretch of the segment lying along the shore
    coords, owner = shapely.get_coordinates(hits, return_index=True)
    t = np.ones(len(start))
    if len(coords):
        along = shapely.line_locate_point(lines[owner], shapely.points(coords), normalized=True)
        np.minimum.at(t, owner, along)
    return t


def outward_normals(water: Polygon, xy: np.ndarray, heading: np.ndarray, h: float = 1e-7) -> np.ndarray:
    """Unit normals of the shoreline at points [M, 2] on it, turned to point along ``heading`` [M, 2] (out of the
    water, for a step that crossed there): perpendicular to the shore's direction between the points ``h`` before
    and after along it. → [M, 2]."""
    shore = water.boundary
    at = shapely.line_locate_point(shore, shapely.points(xy))
    ahead = shapely.get_coordinates(shapely.line_interpolate_point(shore, at + h))
    behind = shapely.get_coordinates(shapely.line_interpolate_point(shore, at - h))
    tangent = ahead - behind
    normal = np.stack([tangent[:, 1], -tangent[:, 0]], axis=1)
    normal /= np.linalg.norm(normal, axis=1, keepdims=True).clip(min=1e-300)
    return normal * np.where((normal * heading).sum(axis=1) < 0, -1.0, 1.0)[:, None]


def near_shore(water: Polygon, reach: float) -> Polygon:
    """The water within ``reach`` of the shore: a step no longer than ``reach`` that starts outside this band
    cannot meet the shoreline, so only the steps starting inside it need checking."""
    return water.difference(water.buffer(-reach))


def wall_step(water: Polygon, start: np.ndarray, end: np.ndarray, vel: np.ndarray,
              band: Polygon | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Positions and velocities [M, 2] after a step start → end against the shore: a step that meets the
    shoreline stops at its first crossing and loses its velocity component along the shore's outward normal there.
    ``start`` must be in the water. ``band`` (``near_shore`` of the longest step) limits the check to the steps
    that can reach the shore; without it every step is checked."""
    if band is None:
        check = np.arange(len(start))
    else:
        check = np.flatnonzero(shapely.intersects_xy(band, start[:, 0], start[:, 1]) | outside(water, end))
    if len(check) == 0:
        return end, vel
    t = first_crossing(water, start[check], end[check])
    rows = check[t < 1.0]
    if len(rows) == 0:
        return end, vel
    s, step, t = start[rows], end[rows] - start[rows], t[t < 1.0]
    stop = s + np.clip(t - PULL_BACK, 0.0, 1.0)[:, None] * step
    stop = np.where(outside(water, stop)[:, None], s, stop)  # rounding: the start is in the water
    n = outward_normals(water, s + t[:, None] * step, step)
    pos, vel = end.copy(), vel.copy()
    v = vel[rows]
    pos[rows] = stop
    vel[rows] = v - np.maximum((v * n).sum(axis=1), 0.0)[:, None] * n
    return pos, vel


def distance_outside(water: Polygon, xy: np.ndarray) -> np.ndarray:
    """How far each point [..., 2] is outside the water (0 inside or on the shore). → [...]."""
    flat = xy.reshape(-1, 2)
    return shapely.distance(water, shapely.points(flat)).reshape(xy.shape[:-1])
