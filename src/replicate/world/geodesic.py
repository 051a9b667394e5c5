"""Distances through the water: a raster graph of a lake, and the geodesic Voronoi cells of buoys on it.

Lloyd's cells (``baselines.voronoi_centroids``) are Euclidean: on a lake with arms, a buoy's cell reaches across a
spit of land into water it cannot sail to straight, and its centroid may lie on land. Geodesic cells measure the
distance a buoy would sail, through the water only (Lloyd's algorithm with the geodesic distance, the usual
extension of coverage control to non-convex regions). Here the water is a grid of points ``spacing`` apart; each
point links to its 16 neighbours where the segment between them stays in the water; a multi-source Dijkstra
(``scipy.sparse.csgraph``) from the buoys' nearest points gives every point its nearest buoy (the cells), its
distance through the water, and the shortest path back.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass

import numpy as np
import scipy.sparse
import shapely
from scipy.sparse.csgraph import dijkstra
from scipy.spatial import cKDTree
from shapely.geometry import Polygon

# half of the 16-neighbourhood (each undirected edge once): the knight's moves beside the 8 neighbours bring the
# graph's distances within 3 % of straight lines (8 neighbours: 8 %), so cells on open water are Voronoi cells
NEIGHBOURS = ((1, 0), (0, 1), (1, 1), (1, -1), (2, 1), (1, 2), (2, -1), (1, -2))


@dataclass(frozen=True)
class WaterGraph:
    """The raster graph of a lake: ``points`` [C, 2] in the water, ``graph`` [C, C] the lengths of the edges between
    neighbours whose segment stays in the water (symmetric), ``tree`` for the nearest point of any position."""

    points: np.ndarray
    graph: scipy.sparse.csr_matrix
    tree: cKDTree
    spacing: float


@functools.lru_cache(maxsize=32)
def _water_graph(water_wkb: bytes, spacing: float) -> WaterGraph:
    water = shapely.from_wkb(water_wkb)
    minx, miny, maxx, maxy = water.bounds
    xs = np.arange(minx + spacing / 2, maxx, spacing)
    ys = np.arange(miny + spacing / 2, maxy, spacing)
    gx, gy = np.meshgrid(xs, ys)  # [ny, nx]
    shapely.prepare(water)
    wet = shapely.contains_xy(water, gx, gy)
    index = np.full(wet.shape, -1)
    index[wet] = np.arange(wet.sum())
    points = np.stack([gx[wet], gy[wet]], axis=1)
    padded = np.pad(index, 2, constant_values=-1)
    ny, nx = index.shape
    rows, cols, lengths = [], [], []
    for dx, dy in NEIGHBOURS:
        a, b = index.ravel(), padded[2 + dy:2 + dy + ny, 2 + dx:2 + dx + nx].ravel()  # a point, its neighbour
        pair = (a >= 0) & (b >= 0)
        a, b = a[pair], b[pair]
        segments = shapely.linestrings(np.stack([points[a], points[b]], axis=1))
        keep = shapely.covers(water, segments)  # no edge across a spit of land or an island's tip
        rows.append(a[keep])
        cols.append(b[keep])
        lengths.append(np.full(keep.sum(), spacing * np.hypot(dx, dy)))
    r, c, w = (np.concatenate(v) for v in (rows, cols, lengths))
    graph = scipy.sparse.coo_matrix((np.r_[w, w], (np.r_[r, c], np.r_[c, r])), shape=(len(points),) * 2).tocsr()
    return WaterGraph(points, graph, cKDTree(points), spacing)


def water_graph(water: Polygon, spacing: float) -> WaterGraph:
    """The raster graph of ``water`` at ``spacing`` (built once per lake and spacing, then cached)."""
    if spacing <= 0:
        raise ValueError(f"the water graph's spacing must be > 0, got {spacing}")
    return _water_graph(water.wkb, float(spacing))


@dataclass(frozen=True)
class GeodesicCells:
    """Each water point's nearest buoy through the water: ``owner`` [C] (buoy index), ``distance`` [C] (m, from
    that buoy's point), ``predecessor`` [C] (next point on the way back to it; −9999 at the buoy's own), ``source``
    [N] (each buoy's point, ``distinct_nearest``)."""

    owner: np.ndarray
    distance: np.ndarray
    predecessor: np.ndarray
    source: np.ndarray


def distinct_nearest(g: WaterGraph, xy: np.ndarray) -> np.ndarray:
    """Each buoy's nearest water point [N], no two the same: in agent order, a buoy whose nearest point is taken
    gets its nearest free one (buoys the shore wall pinned to one vertex start from neighbouring points, so each
    has a cell of its own and they steer apart)."""
    if len(g.points) < len(xy):
        raise ValueError(f"the water graph has {len(g.points)} points for {len(xy)} buoys: the lake is narrow for its "
                         f"spacing of {g.spacing} m; lower evaluate.geodesic.spacing")
    k = len(xy)
    nearest = g.tree.query(xy, k=k)[1].reshape(len(xy), k)
    if len(np.unique(nearest[:, 0])) == len(xy):
        return nearest[:, 0]
    taken, out = set(), np.empty(len(xy), int)
    for i, row in enumerate(nearest):
        out[i] = next(int(c) for c in row if c not in taken)
        taken.add(out[i])
    return out


def geodesic_cells(g: WaterGraph, xy: np.ndarray) -> GeodesicCells:
    """The geodesic Voronoi cells of buoys at xy [N, 2] (N at most the graph's points), from ``distinct_nearest``
    points."""
    source = distinct_nearest(g, xy)
    distance, predecessor, nearest = dijkstra(g.graph, directed=False, indices=source, min_only=True,
                                              return_predecessors=True)
    buoy = np.full(len(g.points), -1)
    buoy[source] = np.arange(len(xy))
    owner = np.where(nearest >= 0, buoy[np.maximum(nearest, 0)], -1)  # −1: water no buoy can reach
    return GeodesicCells(owner, distance, predecessor, source)


def geodesic_targets(g: WaterGraph, xy: np.ndarray, lookahead: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """For buoys at xy [N, 2]: (target [N, 2], waypoint [N, 2], distance through the water to the target [N]).

    A buoy's target is the centroid of its geodesic cell when the grid point nearest the centroid is the cell's,
    otherwise the cell's point nearest to it. The waypoint is the point of the shortest path to the target at
    most ``lookahead`` metres of sailing from the buoy (the target itself when nearer), so the buoy heads around
    land, not into it."""
    cells = geodesic_cells(g, xy)
    n = len(xy)
    mine = cells.owner >= 0
    owner, points = cells.owner[mine], g.points[mine]
    count = np.bincount(owner, minlength=n)
    centroid = np.stack([np.bincount(owner, points[:, k], minlength=n) for k in (0, 1)], axis=1)
    centroid = centroid / np.maximum(count, 1)[:, None]
    # the cell's point nearest its centroid: sort the owned points by (owner, distance to the owner's centroid)
    d2 = ((points - centroid[owner]) ** 2).sum(axis=1)
    order = np.lexsort((d2, owner))
    firsts = order[np.r_[0, np.flatnonzero(np.diff(owner[order])) + 1]]
    target_point = np.flatnonzero(mine)[firsts]  # [buoys with a cell] water point indices
    target_index = np.empty(n, int)
    target_index[owner[firsts]] = target_point
    snapped = g.points[target_index]
    inside = np.abs(centroid - snapped).max(axis=1) <= 0.5 * g.spacing  # the centroid's grid square is the cell's
    target = np.where(inside[:, None], centroid, snapped)
    # walk back from the target along the shortest path until within the lookahead of sailing
    way = target_index.copy()
    while True:
        far = cells.distance[way] > lookahead
        if not far.any():
            break
        way[far] = cells.predecessor[way[far]]
    near = way == target_index
    waypoint = np.where(near[:, None], target, g.points[way])
    return target, waypoint, np.where(near, np.linalg.norm(target - xy, axis=1), cells.distance[target_index])
