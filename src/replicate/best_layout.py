"""The best layout: the highest coverage found offline for N buoys in a region, with no physics and no horizon.

The limit every method is read against. Greedy placement puts each buoy in turn where its coverage polygon adds
the most water not yet covered, among candidate points on a grid over the region; a local search then moves one
buoy at a time to the best of eight points around it, shrinking the step when no move helps, until the step is
below ``tolerance``. Every score is exact: A(∪Cov ∩ Reg) by shapely, vectorised over the candidates.
"""

from __future__ import annotations

import functools

import numpy as np
import shapely
from shapely.geometry import Polygon


def coverage_polygons(xy: np.ndarray, radius: float, edges: int) -> np.ndarray:
    """The coverage polygon (regular ``edges``-gon of circumradius ``radius``, as ``geometry``) at each point
    [M, 2] → [M] shapely polygons."""
    angle = 2 * np.pi * np.arange(edges) / edges
    ring = radius * np.stack([np.cos(angle), np.sin(angle)], axis=1)
    return shapely.polygons(xy[:, None, :] + ring[None])


def covered_area(region: Polygon, xy: np.ndarray, radius: float, edges: int) -> float:
    """A(∪Cov(xy) ∩ Reg), exact."""
    return float(shapely.intersection(shapely.union_all(coverage_polygons(xy, radius, edges)), region).area)


def gains(region: Polygon, covered, candidates: np.ndarray, radius: float, edges: int) -> np.ndarray:
    """Water each candidate point [C, 2] would add to ``covered`` (a geometry, or None for nothing yet). → [C]."""
    polys = shapely.intersection(coverage_polygons(candidates, radius, edges), region)
    if covered is None:
        return shapely.area(polys)
    return shapely.area(shapely.difference(polys, covered))


def best_layout(region: Polygon, n_agents: int, radius: float, edges: int, spacing: float | None = None,
                tolerance: float = 1e-3) -> tuple[np.ndarray, float]:
    """(positions [N, 2], coverage fraction) of the best layout found (module docstring). ``spacing`` of the
    candidate grid defaults to a tenth of the radius."""
    spacing = radius / 10 if spacing is None else spacing
    minx, miny, maxx, maxy = region.bounds
    gx, gy = np.meshgrid(np.arange(minx, maxx + spacing, spacing), np.arange(miny, maxy + spacing, spacing))
    grid = np.stack([gx.ravel(), gy.ravel()], axis=1)
    grid = grid[shapely.intersects_xy(region.buffer(radius), grid[:, 0], grid[:, 1])]  # a polygon can reach in
    xy, covered = [], None
    for _ in range(n_agents):  # greedy placement
        best = int(np.argmax(gains(region, covered, grid, radius, edges)))
        xy.append(grid[best])
        cov = shapely.intersection(coverage_polygons(grid[best:best + 1], radius, edges)[0], region)
        covered = cov if covered is None else shapely.union(covered, cov)
    xy = np.array(xy)
    step = spacing
    compass = np.array([[np.cos(a), np.sin(a)] for a in np.arange(8) * np.pi / 4])
    while step >= tolerance:  # local search, one buoy at a time
        improved = False
        for i in range(n_agents):
            others = np.delete(xy, i, axis=0)
            rest = shapely.union_all(coverage_polygons(others, radius, edges)) if len(others) else None
            rest = None if rest is None else shapely.intersection(rest, region)
            moves = np.concatenate([xy[i:i + 1], xy[i] + step * compass])
            g = gains(region, rest, moves, radius, edges)
            k = int(np.argmax(g))
            if k > 0 and g[k] > g[0] + 1e-12:
                xy[i] = moves[k]
                improved = True
        if not improved:
            step /= 2
    return xy, covered_area(region, xy, radius, edges) / region.area


@functools.lru_cache(maxsize=64)
def _best_coverage(region_wkb: bytes, n_agents: int, radius: float, edges: int) -> float:
    return best_layout(shapely.from_wkb(region_wkb), n_agents, radius, edges)[1]


def best_coverage(region: Polygon, n_agents: int, radius: float, edges: int) -> float:
    """The best layout's coverage fraction, computed once per region and fleet in a process (an evaluation asks
    for it under every start and event)."""
    return _best_coverage(region.wkb, n_agents, radius, edges)
