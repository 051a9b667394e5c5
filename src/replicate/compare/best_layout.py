"""The best layout: the highest coverage found offline for N buoys in a region, with no physics and no horizon.

The limit every method is read against. Greedy placement puts each buoy in turn where its coverage polygon adds
the most water not yet covered, among candidate points on a grid over the water; a local search then moves one
buoy at a time to the best of eight points around it in the water, shrinking the step when no move helps, until
the step is below ``tolerance``; the best of five such searches is kept: four from greedy layouts on shifted
grids, one from Lloyd's layout (Voronoi centroids iterated from the first greedy layout: on a lake where the
greedy layouts end in one local optimum, Lloyd's ends in another, and on the suite's lakes it was at times the
better one). An evaluation adds a sixth start, the best final layout its policies reached (``best_coverage_from``): a
layout the fleet found may lie in a basin none of the five searches enters. Every place is in the
water (the region, shore included): a buoy behind the shore wall cannot sail onto a spit of land between two arms,
so a layout with a buoy there is not one a fleet could take. Every score is exact:
A(∪Cov ∩ Reg) by shapely, vectorised over the candidates, with only the candidates, neighbours and water within
reach of a change scored again (the same areas, 4-6x faster than scoring the whole fleet and lake); on a long shore
the candidates' water is clipped in the compiled loop of ``local_water`` (the same areas to float rounding, and on
Mae Kuang and Lake Silach the same layouts).
"""

from __future__ import annotations

import functools
from dataclasses import dataclass

import numpy as np
import shapely
from shapely.geometry import Polygon

from replicate.compare.baselines import nearest_in, voronoi_centroids
from replicate.world.geometry import coverage_polygons, long_shore, polygon_offsets
from replicate.world.local_water import LocalWater, Rings

TIE = 1e-9  # gains (m²) or coverages closer than this are equal: the same water scored through other overlays
# the candidate grid's origin, in grid spacings: the search ends in another local optimum from each. On 6 suite
# lakes at N = 9 and 20 the four differ by <= 0.0015 in coverage, on one lake by 0.014 (0.922 to 0.935)
GRID_OFFSETS = ((0.0, 0.0), (0.5, 0.5), (0.25, 0.75), (0.75, 0.25))
# candidate points of one grid at most: the suite's lakes (at most ~30 radii across) stay far below it, with
# their tenth-of-a-radius grids; a real lake at a 25 m radius (100+ radii across) gets a coarser grid
MAX_CANDIDATES = 200_000
LLOYD_ITERATIONS = 200  # Lloyd's layout: at most this many centroid steps (the suite's lakes converge in far fewer)
# candidate polygons clipped to the water once and kept (about 1 KB each): every grid of the suite's lakes. A larger
# grid (a real lake at a field radius: up to MAX_CANDIDATES points) keeps only their areas and clips a polygon
# again when it is scored, the same polygon and the same numbers: `replicate plan` on Lake Karaguz at 25 m peaked at
# 1,048 MB with every clip kept, 865 MB so (benchmarks/field_bench.py)
KEPT_CLIPS = 20_000


def covered_area(region: Polygon, xy: np.ndarray, radius: float, edges: int) -> float:
    """A(∪Cov(xy) ∩ Reg), exact."""
    return float(shapely.intersection(shapely.union_all(coverage_polygons(xy, radius, edges)), region).area)


def gains(region: Polygon, covered, candidates: np.ndarray, radius: float, edges: int) -> np.ndarray:
    """Water each candidate point [C, 2] would add to ``covered`` (a geometry, or None for nothing yet). → [C]."""
    return added(shapely.intersection(coverage_polygons(candidates, radius, edges), region), covered)


def added(polys: np.ndarray, covered) -> np.ndarray:
    """Area of each polygon [C] (already clipped to the water) outside ``covered`` (a geometry, or None). → [C]."""
    return shapely.area(polys if covered is None else shapely.difference(polys, covered))


def near(xy: np.ndarray, centre: np.ndarray, reach: float) -> np.ndarray:
    """Mask of the points [M, 2] within a square of half-side ``reach`` around ``centre`` [2] → [M] bool: the
    only coverage polygons a polygon at ``centre`` can touch when ``reach`` ≥ 2·radius."""
    return np.all(np.abs(xy - centre) <= reach, axis=1)


@dataclass(frozen=True)
class Candidates:
    """The candidate grid of a search: its points in the water, shore included [G, 2], and the water each one's
    coverage polygon holds [G]. On a short shore each polygon is clipped to the water by shapely, once and kept
    (``clipped`` [G]) on a grid of at most ``KEPT_CLIPS`` points, again whenever it is scored on a larger one; on a
    long one (``geometry.long_shore``) a compiled loop measures the water (``local_water``) and a polygon is
    clipped, against its tile's water, only when a buoy is placed on it."""

    grid: np.ndarray
    water: np.ndarray
    clipped: np.ndarray | None
    local: LocalWater | None
    offsets: np.ndarray  # [K, 2] the coverage polygon's vertices about its centre
    region: Polygon | None = None  # the water, where a short shore's clips are not kept

    @classmethod
    def of(cls, region: Polygon, spacing: float, offset: tuple[float, float], radius: float, edges: int,
           local: LocalWater | None = None) -> Candidates:
        """The grid of spacing ``spacing`` shifted by ``offset`` (in spacings) over ``region``; ``local`` its
        tiles on a long shore (None: shapely's overlay)."""
        minx, miny, maxx, maxy = region.bounds
        gx, gy = np.meshgrid(np.arange(minx + offset[0] * spacing, maxx + spacing, spacing),
                             np.arange(miny + offset[1] * spacing, maxy + spacing, spacing))
        grid = np.stack([gx.ravel(), gy.ravel()], axis=1)
        grid = grid[shapely.intersects_xy(region, grid[:, 0], grid[:, 1])]  # in the water, shore included
        offsets = polygon_offsets(radius, edges)
        if local is not None:
            return cls(grid, local.overlap_areas(grid, offsets), None, local, offsets)
        if len(grid) <= KEPT_CLIPS:
            clipped = shapely.intersection(coverage_polygons(grid, radius, edges), region)
            return cls(grid, shapely.area(clipped), clipped, None, offsets)
        parts = np.array_split(grid, -(-len(grid) // KEPT_CLIPS))  # a part's clips at a time
        water = np.concatenate([shapely.area(shapely.intersection(coverage_polygons(part, radius, edges), region))
                                for part in parts])
        return cls(grid, water, None, None, offsets, region)

    def polygons(self, chosen) -> np.ndarray:
        """The coverage polygons of candidates ``chosen`` (indices, a slice or a mask [G]) → [C], unclipped."""
        return shapely.polygons(self.grid[chosen][:, None] + self.offsets)

    def clips(self, chosen) -> np.ndarray:
        """The coverage polygons of candidates ``chosen`` clipped to the water → [C] geometries (a short shore's)."""
        if self.clipped is not None:
            return self.clipped[chosen]
        return shapely.intersection(self.polygons(chosen), self.region)

    def placed(self, i: int):
        """Candidate ``i``'s coverage polygon clipped to the water (a geometry)."""
        one = slice(i, i + 1)
        if self.local is None:
            return self.clips(one)[0]
        return self.local.clip(self.polygons(one), self.grid[one])[0]

    def added(self, touched: np.ndarray, covered) -> np.ndarray:
        """Water the candidates ``touched`` [G] bool would add to ``covered`` (a geometry in the water) → [T]:
        A(K ∩ Reg ∖ C) = A(K ∩ Reg) − A(K ∩ C) on a long shore, C being in the region."""
        if self.local is None:
            return added(self.clips(touched), covered)
        grid = self.grid[touched]
        gain = self.water[touched] - Rings.of([covered]).moments(grid[:, None] + self.offsets)[:, 0]
        lost = np.isnan(gain)
        if lost.any():  # a clip too long for the loop's buffers: shapely's difference
            polygons = shapely.polygons(grid[lost, None] + self.offsets)
            gain[lost] = added(self.local.clip(polygons, grid[lost]), covered)
        return gain


def greedy(c: Candidates, n_agents: int, radius: float, toward: np.ndarray | None = None) -> np.ndarray:
    """Each buoy in turn on the candidate point of ``c`` whose polygon adds the most water not yet covered
    → [N, 2]; among points that add as much, the first, or the nearest to ``toward`` [2] (on a lake far larger
    than the fleet's reach every full disc ties, and the layout then gathers where the fleet is). After a
    placement only the candidates within reach of it are scored again (the others' gains cannot change)."""
    score = c.water.copy()
    far = None if toward is None else np.linalg.norm(c.grid - toward, axis=1)
    xy, covered = [], None
    for _ in range(n_agents):
        ties = score >= score.max() - TIE  # float noise breaks no tie
        best = int(np.argmax(ties)) if far is None else int(np.flatnonzero(ties)[np.argmin(far[ties])])
        xy.append(c.grid[best])
        covered = c.placed(best) if covered is None else shapely.union(covered, c.placed(best))
        touched = near(c.grid, c.grid[best], 2 * radius)
        score[touched] = c.added(touched, covered)
    return np.array(xy)


def local_search(region: Polygon, xy: np.ndarray, step: float, radius: float, edges: int,
                 tolerance: float) -> np.ndarray:
    """Move one buoy at a time to the best of eight points ``step`` around it while that adds water, halving
    ``step`` when no buoy moves, down to ``tolerance`` → positions [N, 2]. A move is scored against its
    neighbours within reach and the water near it only: the same areas as against the whole fleet and lake."""
    xy = xy.copy()
    compass = np.array([[np.cos(a), np.sin(a)] for a in np.arange(8) * np.pi / 4])
    while step >= tolerance:
        improved, reach = False, 2 * radius + step  # a move of ``step`` touches polygons within reach
        for i in range(len(xy)):
            others = near(xy, xy[i], reach)
            others[i] = False
            rest = shapely.union_all(coverage_polygons(xy[others], radius, edges)) if others.any() else None
            x, y = xy[i]
            water = shapely.intersection(region, shapely.box(x - reach, y - reach, x + reach, y + reach))
            moves = np.concatenate([xy[i:i + 1], xy[i] + step * compass])
            moves = moves[np.r_[True, shapely.intersects_xy(region, moves[1:, 0], moves[1:, 1])]]  # in the water
            g = gains(water, rest, moves, radius, edges)
            k = int(np.argmax(g))
            if k > 0 and g[k] > g[0] + TIE:
                xy[i] = moves[k]
                improved = True
        if not improved:
            step /= 2
    return xy


def lloyd_layout(region: Polygon, xy: np.ndarray, iterations: int = LLOYD_ITERATIONS,
                 tolerance: float = 1e-4) -> np.ndarray:
    """Lloyd's algorithm without physics: every point moved to its Voronoi cell's centroid in the water, from xy
    [N, 2], until no point moves more than ``tolerance`` or after ``iterations`` → [N, 2] (centroids in the
    water, ``nearest_in`` where a centroid of a cell bent around land is not)."""
    for _ in range(iterations):
        nxt = voronoi_centroids(region, xy)
        outside = ~shapely.intersects_xy(region, nxt[:, 0], nxt[:, 1])
        if outside.any():
            nxt[outside] = nearest_in(region, nxt[outside])
        done = np.abs(nxt - xy).max() <= tolerance
        xy = nxt
        if done:
            break
    return xy


def grid_spacing(region: Polygon, radius: float) -> float:
    """The candidate grid's default spacing: a tenth of the radius, coarser where that grid would hold more than
    ``MAX_CANDIDATES`` points."""
    minx, miny, maxx, maxy = region.bounds
    return max(radius / 10, np.sqrt((maxx - minx + 2 * radius) * (maxy - miny + 2 * radius) / MAX_CANDIDATES))


def best_layout(region: Polygon, n_agents: int, radius: float, edges: int, spacing: float | None = None,
                tolerance: float = 1e-3, quick: bool = False,
                toward: tuple[float, float] | None = None) -> tuple[np.ndarray, float]:
    """(positions [N, 2], coverage fraction) of the best layout found (module docstring): greedy placement and
    local search from the candidate grid at each of ``GRID_OFFSETS`` and from Lloyd's layout, the best of them;
    ``quick``: from the first grid's greedy layout alone (a fifth of the time: the planner as a teacher, which
    needs a layout for every training world and fleet left after a loss); ``toward`` (x, y) breaks the greedy
    placement's ties toward that point (``greedy``). ``spacing`` of the grid defaults to a
    tenth of the radius, coarser where that grid would hold more than ``MAX_CANDIDATES`` points (a lake hundreds of
    radii across: the local search still refines every position down to ``tolerance``)."""
    spacing = grid_spacing(region, radius) if spacing is None else spacing
    shapely.prepare(region)
    starts = []
    local = LocalWater.of(region, radius) if long_shore(region) else None
    for offset in GRID_OFFSETS[:1] if quick else GRID_OFFSETS:
        c = Candidates.of(region, spacing, offset, radius, edges, local)
        starts.append(greedy(c, n_agents, radius, None if toward is None else np.asarray(toward)))
    if not quick:
        starts.append(lloyd_layout(region, starts[0]))
    best = (None, -1.0)
    for start in starts:
        xy = local_search(region, start, spacing, radius, edges, tolerance)
        cov = covered_area(region, xy, radius, edges) / region.area
        best = (xy, cov) if cov > best[1] + TIE else best
    return best


@functools.lru_cache(maxsize=512)
def _best_layout(region_wkb: bytes, n_agents: int, radius: float, edges: int, quick: bool,
                 toward: tuple[float, float] | None) -> tuple[np.ndarray, float]:
    return best_layout(shapely.from_wkb(region_wkb), n_agents, radius, edges, quick=quick, toward=toward)


def best_layout_once(region: Polygon, n_agents: int, radius: float, edges: int, quick: bool = False,
                     toward: tuple[float, float] | None = None) -> tuple[np.ndarray, float]:
    """``best_layout`` at the default grid, computed once per region, fleet, ``quick`` and ``toward`` in a process
    (an evaluation asks for it under every start and event, and its episode's map again) → (a copy of the
    positions, coverage)."""
    xy, cov = _best_layout(region.wkb, n_agents, radius, edges, quick, toward)
    return xy.copy(), cov


def best_coverage(region: Polygon, n_agents: int, radius: float, edges: int) -> float:
    """The best layout's coverage fraction (``best_layout_once``)."""
    return best_layout_once(region, n_agents, radius, edges)[1]


def best_coverage_from(region: Polygon, n_agents: int, radius: float, edges: int, start: np.ndarray,
                       tolerance: float = 1e-3) -> tuple[float, bool]:
    """The better of the best layout (``best_coverage``) and the local search from ``start`` [N, 2] (the best final
    layout a policy reached; its points outside the water first moved to the nearest water) → (coverage fraction,
    whether ``start`` gave it)."""
    best = best_coverage(region, n_agents, radius, edges)
    start = np.asarray(start, dtype=float).copy()
    outside = ~shapely.intersects_xy(region, start[:, 0], start[:, 1])
    if outside.any():
        start[outside] = nearest_in(region, start[outside])
    xy = local_search(region, start, grid_spacing(region, radius), radius, edges, tolerance)
    found = covered_area(region, xy, radius, edges) / region.area
    return (found, True) if found > best + TIE else (best, False)
