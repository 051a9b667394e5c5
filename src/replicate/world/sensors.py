"""What a buoy senses around itself, with no absolute position: its own velocity, the buoys it hears, and how far
the shore is. A policy fed only these is the same function in every lake and for every fleet size.

Each sensor is one function over arrays batched ``[E, N, ...]`` (E environments, N buoys); ``local_observation``
concatenates them in the order of ``columns``, which the exported policy's metadata lists. Directions are the
world's (a compass), not the buoy's: a buoy has no heading.
"""

from __future__ import annotations

import numba
import numpy as np
import shapely
from shapely.geometry import Polygon
from shapely.geometry.polygon import orient

from replicate.world.local_map import (
    RASTER_CHANNELS,
    LocalCentroid,
    WaterMask,
    heard_cover,
    local_raster,
    raster_cells,
)


def own_velocity(vel: np.ndarray) -> np.ndarray:
    """The buoy's velocity in the world frame, [E, N, 2] → [E, N, 2]: through the water (what a log reads) or over
    the ground (its displacement over the last step / dt, what a GPS reads: the drift and the shore's stop
    included), as ``env.observe`` passes it for ``SensorsConfig.velocity``."""
    return vel


def neighbours(pos: np.ndarray, k: int, comm_range: float, alive: np.ndarray | None = None
               ) -> tuple[np.ndarray, np.ndarray]:
    """The ``k`` nearest other buoys within ``comm_range`` of each buoy, nearest first: their positions relative
    to it, [E, N, k, 2], and a mask, [E, N, k] (1 for a buoy heard, 0 for an empty slot, whose position is 0).
    Lost buoys (``alive`` [E, N] False) are not heard. pos: [E, N, 2]."""
    e, n = pos.shape[:2]
    rel = pos[:, None, :, :] - pos[:, :, None, :]  # [E, N (self), N (other), 2]: other − self
    dist = np.linalg.norm(rel, axis=-1)
    heard = dist <= comm_range
    heard[:, np.arange(n), np.arange(n)] = False
    if alive is not None:
        heard &= alive[:, None, :]
    dist = np.where(heard, dist, np.inf)
    slots = min(k, n - 1)
    order = np.argsort(dist, axis=-1, kind="stable")[..., :slots]  # [E, N, slots]
    near = np.take_along_axis(rel, order[..., None], axis=2)
    mask = np.take_along_axis(heard, order, axis=2)
    out_rel, out_mask = np.zeros((e, n, k, 2)), np.zeros((e, n, k))
    out_rel[:, :, :slots] = np.where(mask[..., None], near, 0.0)
    out_mask[:, :, :slots] = mask
    return out_rel, out_mask


def ray_directions(rays: int) -> np.ndarray:
    """Unit vectors of ``rays`` compass directions, east first, counter-clockwise. → [rays, 2]."""
    angle = 2 * np.pi * np.arange(rays) / rays
    unit = np.stack([np.cos(angle), np.sin(angle)], axis=1)
    return np.where(np.abs(unit) < 1e-12, 0.0, unit)  # due south is (0, −1), not (−1.8e-16, −1)


def shore_segments(water: Polygon) -> np.ndarray:
    """Every edge of the shoreline (outer ring and islands), oriented so that the water lies to its left.
    → [S, 4] rows (ax, ay, bx, by)."""
    oriented = orient(water, sign=1.0)  # exterior counter-clockwise, holes clockwise
    rows = []
    for ring in (oriented.exterior, *oriented.interiors):
        xy = np.asarray(ring.coords)
        rows.append(np.concatenate([xy[:-1], xy[1:]], axis=1))
    return np.concatenate(rows)


VERTEX = 1e-12  # of an edge's length: a ray through a corner meets both edges there despite rounding
GRAZING = 1e-9  # sine of the angle below which a ray runs along an edge (a buoy on the shore looking along it)
FEW_EDGES = 16  # a shore of at most this many edges is one cell (the walk costs more than it saves)
PAD = 1e-6  # of a grid cell (``ShoreGrid``): an edge is filed in every cell its box comes this near, and a ray
#             walks on this far past its nearest crossing, so rounding in the walk loses no crossing on a border


@numba.njit(cache=True)
def _first_crossing(px, py, dx, dy, segments, s, best):  # pragma: no cover - compiled
    """The distance along the ray (px, py) + t (dx, dy) at which it leaves the water through edge ``s``, when that
    is nearer than ``best``; else ``best``."""
    ax, ay, bx, by = segments[s, 0], segments[s, 1], segments[s, 2], segments[s, 3]
    if min(ax, bx) > px + best or max(ax, bx) < px - best or min(ay, by) > py + best or max(ay, by) < py - best:
        return best
    ex, ey = bx - ax, by - ay
    denom = dx * ey - dy * ex  # |e| sin(angle): > 0 when the ray crosses this edge from the water out
    if denom <= GRAZING * np.sqrt(ex * ex + ey * ey):  # into the water, or along the edge
        return best
    qx, qy = ax - px, ay - py
    t = (qx * ey - qy * ex) / denom
    u = (qx * dy - qy * dx) / denom
    return t if 0.0 <= t < best and -VERTEX <= u <= 1.0 + VERTEX else best


@numba.njit(cache=True)
def _ray_distances(origins, directions, segments, x0, y0, cell, nx, ny, first, items, max_range,
                   out):  # pragma: no cover - compiled
    pad = PAD * cell
    for m in range(origins.shape[0]):
        px, py = origins[m, 0], origins[m, 1]
        ix, iy = int(np.floor((px - x0) / cell)), int(np.floor((py - y0) / cell))
        inside = 0 <= ix < nx and 0 <= iy < ny
        for r in range(directions.shape[0]):
            dx, dy = directions[r, 0], directions[r, 1]
            best = max_range
            if not inside:  # off the grid (off the shore's bounding box): every edge
                for s in range(segments.shape[0]):
                    best = _first_crossing(px, py, dx, dy, segments, s, best)
                out[m, r] = best
                continue
            # the cells the ray passes through, nearest first (Amanatides & Woo 1987), until the next one starts
            # beyond the nearest crossing found: a crossing lies in the cell the ray is in when it crosses
            cx, cy = ix, iy
            step_x, step_y = (1 if dx > 0 else -1), (1 if dy > 0 else -1)
            next_x = (x0 + (cx + (dx > 0)) * cell - px) / dx if dx != 0 else np.inf
            next_y = (y0 + (cy + (dy > 0)) * cell - py) / dy if dy != 0 else np.inf
            span_x = cell / abs(dx) if dx != 0 else np.inf
            span_y = cell / abs(dy) if dy != 0 else np.inf
            while True:
                c = cy * nx + cx
                for k in range(first[c], first[c + 1]):
                    best = _first_crossing(px, py, dx, dy, segments, items[k], best)
                leave = min(next_x, next_y)
                if leave > best + pad:
                    break
                if next_x < next_y:
                    cx += step_x
                    next_x += span_x
                else:
                    cy += step_y
                    next_y += span_y
                if not (0 <= cx < nx and 0 <= cy < ny):
                    break
            out[m, r] = best


class ShoreGrid:
    """The shore's edges (``shore_segments``) filed in a uniform grid over their bounding box, about one edge per
    cell, for ``shore_distances``: a ray reads only the edges of the cells it passes through until its first
    crossing, not every edge of the lake (on a reservoir of 1,700 edges the rays were a fifth of an evaluation).
    The distances are those of reading every edge, to the bit: the same arithmetic per edge, and the nearest
    crossing is the same whichever edges farther away are skipped."""

    def __init__(self, segments: np.ndarray, cell: float | None = None):
        """``cell``: the grid's spacing; by default about one edge per cell (a shore of ``FEW_EDGES`` or fewer
        is one cell, as is any ``cell`` larger than the shore: every ray reads every edge)."""
        self.segments = np.ascontiguousarray(segments, dtype=np.float64)
        lo = np.minimum(self.segments[:, :2], self.segments[:, 2:]).min(axis=0)
        hi = np.maximum(self.segments[:, :2], self.segments[:, 2:]).max(axis=0)
        size = np.maximum(hi - lo, 1e-12)
        if cell is None:
            cell = size.max() * (1 + PAD) if len(self.segments) <= FEW_EDGES else \
                max(np.sqrt(size[0] * size[1] / len(self.segments)), size.max() / 1024)
        self.cell = float(cell)
        self.x0, self.y0 = float(lo[0]), float(lo[1])
        self.nx, self.ny = (int(v) for v in np.floor(size / self.cell) + 1)
        boxes = np.concatenate([np.minimum(self.segments[:, :2], self.segments[:, 2:]),
                                np.maximum(self.segments[:, :2], self.segments[:, 2:])], axis=1)
        pad = PAD * self.cell
        i0 = np.clip(np.floor((boxes[:, 0] - pad - self.x0) / self.cell), 0, self.nx - 1).astype(np.int64)
        j0 = np.clip(np.floor((boxes[:, 1] - pad - self.y0) / self.cell), 0, self.ny - 1).astype(np.int64)
        i1 = np.clip(np.floor((boxes[:, 2] + pad - self.x0) / self.cell), 0, self.nx - 1).astype(np.int64)
        j1 = np.clip(np.floor((boxes[:, 3] + pad - self.y0) / self.cell), 0, self.ny - 1).astype(np.int64)
        cells, edges = [], []
        for s in range(len(boxes)):  # once per lake
            ii, jj = np.meshgrid(np.arange(i0[s], i1[s] + 1), np.arange(j0[s], j1[s] + 1))
            cells.append((jj * self.nx + ii).ravel())
            edges.append(np.full(ii.size, s))
        cells, edges = np.concatenate(cells), np.concatenate(edges)
        order = np.argsort(cells, kind="stable")
        self.items = np.ascontiguousarray(edges[order], dtype=np.int64)
        self.first = np.searchsorted(cells[order], np.arange(self.nx * self.ny + 1)).astype(np.int64)


def shore_distances(pos: np.ndarray, segments: np.ndarray | ShoreGrid, directions: np.ndarray,
                    max_range: float) -> np.ndarray:
    """Distance from each buoy to where the shoreline takes it out of the water along each direction, capped at
    ``max_range``: [E, N, 2] → [E, N, rays]. Only crossings from the water out count, so a buoy resting on the
    shore reads 0 towards the land and the open water's width away from it. ``segments``: ``shore_segments``, or
    their ``ShoreGrid`` (built once per lake: an environment keeps one); ``directions``: ``ray_directions``."""
    grid = segments if isinstance(segments, ShoreGrid) else ShoreGrid(segments)
    flat = np.ascontiguousarray(pos.reshape(-1, 2), dtype=np.float64)
    out = np.empty((len(flat), len(directions)))
    _ray_distances(flat, np.ascontiguousarray(directions, dtype=np.float64), grid.segments, grid.x0, grid.y0,
                   grid.cell, grid.nx, grid.ny, grid.first, grid.items, float(max_range), out)
    return out.reshape(*pos.shape[:-1], len(directions))


def shore_distances_reference(pos: np.ndarray, water: Polygon, directions: np.ndarray, max_range: float
                              ) -> np.ndarray:
    """``shore_distances`` by shapely, for points strictly inside the water: the nearest point where each ray
    meets the shoreline. Slow; the tests' reference."""
    flat = pos.reshape(-1, 2)
    ends = flat[:, None, :] + max_range * directions[None, :, :]
    starts = np.repeat(flat[:, None], len(directions), 1)
    lines = shapely.linestrings(np.stack([starts, ends], axis=2).reshape(-1, 2, 2))
    hits = shapely.intersection(lines, water.boundary)
    starts = shapely.points(np.repeat(flat, len(directions), axis=0))
    dist = np.where(shapely.is_empty(hits), max_range, shapely.distance(starts, hits))
    return np.minimum(dist, max_range).reshape(*pos.shape[:-1], len(directions))


def uncovered_water(pos: np.ndarray, shore: np.ndarray, directions: np.ndarray, radii: tuple[float, ...],
                    radius: float, comm_range: float, alive: np.ndarray | None = None) -> np.ndarray:
    """How much of each ray's water no other buoy covers: the share of the points at ``radii`` m from the buoy in
    each direction that lie before the ray's first shore crossing (water, read from ``shore``, the buoy's
    ``shore_distances``) and farther than ``radius`` (the coverage range R) from every other buoy it hears (all
    within ``comm_range``, not only the k nearest it lists). Points on the ring at R mark where the buoy's own
    disc adds water to the fleet's union; points beyond it, where uncovered water lies. pos: [E, N, 2];
    shore: [E, N, rays]; directions: [rays, 2] → [E, N, rays] in [0, 1]."""
    r = np.asarray(radii, dtype=np.float64)
    offsets = r[None, :, None] * directions[:, None, :]  # [rays, P, 2], relative to the buoy
    covered = heard_cover(pos, offsets.reshape(-1, 2), radius, comm_range, alive).reshape(*shore.shape, len(r))
    water = r < shore[..., None]  # [E, N, rays, P]: before the ray's first shore crossing
    return (water & (covered == 0.0)).sum(-1) / len(r)


def columns(k: int, rays: int, uncovered: bool = False, raster: int = 0, centroid: bool = False) -> list[str]:
    """Names of ``local_observation``'s columns, in order (``uncovered``: with ``uncovered_water``'s; ``raster``:
    with ``local_raster``'s, ``raster_CHANNEL_A_B`` for the cell A east and B north of the buoy; ``centroid``: with
    the local centroid's offset, last)."""
    compass = [round(360 * r / rays) for r in range(rays)]
    return (["vx", "vy"] + [f"neighbour{j}_{c}" for j in range(k) for c in ("dx", "dy")]
            + [f"neighbour{j}_heard" for j in range(k)] + [f"shore_{d}deg" for d in compass]
            + ([f"uncovered_{d}deg" for d in compass] if uncovered else [])
            + [f"raster_{ch}_{a}_{b}" for ch in RASTER_CHANNELS for a, b in raster_cells(raster)]
            + (["centroid_dx", "centroid_dy"] if centroid else []))


def describe(config) -> list[dict]:
    """Each sensor of ``local_observation`` as the exported policy's metadata lists it: its function, its columns,
    its settings (``config``: a ``core.sections.SensorsConfig``)."""
    k, rays = config.neighbours, config.rays
    names = columns(k, rays, bool(config.uncovered), config.raster, config.centroid)
    described = [
        {"sensor": "own_velocity", "columns": names[:2], "shape": "[E, N, 2]", "units": "m/s",
         "frame": "over the ground (GPS)" if config.velocity == "ground" else "through the water (log)"},
        {"sensor": "neighbours", "columns": names[2:2 + 3 * k], "shape": f"[E, N, {k}, 2] and mask [E, N, {k}]",
         "k": k, "comm_range_m": config.comm_range, "units": "m, relative to the buoy; mask 1 = heard"},
        {"sensor": "shore_distances", "columns": names[2 + 3 * k:2 + 3 * k + rays], "shape": f"[E, N, {rays}]",
         "rays": rays, "ray_range_m": config.ray_range, "units": "m, capped at ray_range_m",
         "directions": "compass, east first, counter-clockwise"},
    ]
    if config.uncovered:
        described.append({"sensor": "uncovered_water", "columns": names[2 + 3 * k + rays:2 + 3 * k + 2 * rays],
                          "shape": f"[E, N, {rays}]",
                          "radii_m": list(config.uncovered), "comm_range_m": config.comm_range,
                          "units": "share of the points along each ray that are water no other buoy heard covers",
                          "directions": "those of shore_distances"})
    if config.raster:
        cells = config.raster
        described.append({"sensor": "local_raster", "columns": [c for c in names if c.startswith("raster_")],
                          "shape": f"[E, N, {len(RASTER_CHANNELS)}, {cells}, {cells}]", "cells": cells,
                          "half_side_m": config.ray_range, "cell_m": 2 * config.ray_range / cells,
                          "comm_range_m": config.comm_range,
                          "units": "1 or 0 at each cell's centre: water (from the lake's outline); within the coverage "
                                   "range of another buoy heard",
                          "cells_order": "raster_CHANNEL_A_B: A cells east and B north of the buoy"})
    if config.centroid:
        described.append({"sensor": "local_centroid", "columns": names[-2:], "shape": "[E, N, 2]",
                          "reach_m": config.ray_range, "comm_range_m": config.comm_range,
                          "units": "m, relative to the buoy: the centroid of the water within reach_m nearer to the "
                                   "buoy than to the buoys the neighbours sensor lists (0 with none)"})
    return described


def local_observation(pos: np.ndarray, vel: np.ndarray, segments: np.ndarray | ShoreGrid, directions: np.ndarray,
                      k: int,
                      comm_range: float, ray_range: float, alive: np.ndarray | None = None,
                      uncovered: tuple[float, ...] = (), radius: float = 0.0,
                      raster: tuple[WaterMask, np.ndarray] | None = None,
                      centroid: LocalCentroid | None = None) -> np.ndarray:
    """Every sensor of every buoy, concatenated in the order of ``columns``: [E, N, 2 + 3k + rays] float32, and
    ``rays`` more with ``uncovered`` (the radii of ``uncovered_water``'s points; ``radius``: the coverage range),
    2C more with ``raster`` (``local_raster``'s water mask and cell offsets [C, 2]) and 2 more with ``centroid``
    (the local centroid's sensor of the lake, reading the buoys each hears)."""
    rel, mask = neighbours(pos, k, comm_range, alive)
    e, n = pos.shape[:2]
    shore = shore_distances(pos, segments, directions, ray_range)
    parts = [own_velocity(vel), rel.reshape(e, n, 2 * k), mask, shore]
    if uncovered:
        parts.append(uncovered_water(pos, shore, directions, uncovered, radius, comm_range, alive))
    if raster is not None:
        parts.append(local_raster(pos, *raster, radius, comm_range, alive))
    if centroid is not None:
        parts.append(centroid(pos, rel, mask, alive))
    return np.concatenate(parts, axis=-1).astype(np.float32)


ON_SHORE = 1e-6  # m: a buoy the wall stopped rests ~1e-11 m inside the shoreline, not on it


def shore_rays(columns: list[str]) -> list[int]:
    """The observation's shore-ray columns (``sensors.columns``)."""
    return [k for k, name in enumerate(columns) if name.startswith("shore_")]


def on_shore(obs: np.ndarray, rays: list[int]) -> np.ndarray:
    """Which buoys rest on the shore: a shore ray (``rays``, from ``shore_rays``) shorter than ``ON_SHORE`` (a
    buoy the wall stopped). obs [E, N, d] → [E, N]."""
    return obs[..., rays].min(axis=-1) <= ON_SHORE
