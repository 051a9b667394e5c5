"""The map a buoy reads around itself (``local_raster``, a sensor of ``sensors.local_observation``): on a square
of cells centred on the buoy, in the world's compass, whether each cell's centre is water and whether another buoy
it hears covers it.

The lake's water is read off a fine grid of the lake (``WaterMask``), exactly: the grid decides a point in a cell
no shore edge passes through, the outline itself a point in a cell the shore may cross. The cover is a compiled
loop over the buoys each buoy hears (``heard_cover``), which the uncovered-water sensor (``sensors.uncovered_water``)
reads too.

A grid of the same kind, read at its cells' centres only, gives the centroid sensor (``LocalCentroid``): the offset
to the centroid of the water around the buoy that is nearer to it than to the buoys it hears, where Lloyd's law
would steer it on what it senses now.
"""

from __future__ import annotations

import numba
import numpy as np
import shapely
from shapely.geometry import Polygon

RASTER_CHANNELS = ("water", "covered")  # ``local_raster``'s channels, in column order


def raster_cells(cells: int) -> list[tuple[int, int]]:
    """The local raster's cells (a, b), east then north of the buoy in cells from −h to h (``cells`` = 2h + 1), in
    column order: row by row from the south, each row from the west."""
    h = (cells - 1) // 2
    return [(a, b) for b in range(-h, h + 1) for a in range(-h, h + 1)]


def raster_offsets(cells: int, half_side: float) -> np.ndarray:
    """Each raster cell's centre relative to the buoy, m: the square of half-side ``half_side`` cut into
    ``cells`` × ``cells``. → [cells², 2] in ``raster_cells``' order."""
    return np.array(raster_cells(cells), dtype=np.float64) * (2 * half_side / cells)


class WaterMask:
    """The water of a lake on a fine square grid (``cell`` m), for reading many points at once: a point in a cell
    no shore edge passes through is water as the cell's centre is (one lookup); a point in a cell the shore may
    cross (within the bounding box of one of its edges) is read from the outline (shapely), so every point reads
    exactly as ``shapely.contains_xy``. Off the grid is dry. Built once per lake with one vectorised call."""

    def __init__(self, water: Polygon, cell: float):
        minx, miny, maxx, maxy = water.bounds
        self.water, self.cell, self.x0, self.y0 = water, float(cell), float(minx), float(miny)
        self.nx, self.ny = int(np.ceil((maxx - minx) / cell)) + 1, int(np.ceil((maxy - miny) / cell)) + 1
        xs = self.x0 + (np.arange(self.nx) + 0.5) * self.cell
        ys = self.y0 + (np.arange(self.ny) + 0.5) * self.cell
        shapely.prepare(water)
        self.wet = shapely.contains_xy(water, xs[None, :], ys[:, None])  # [ny, nx]
        self.shore = np.zeros((self.ny, self.nx), dtype=bool)  # the cells an edge's bounding box touches
        edges = np.concatenate([np.hstack([r[:-1], r[1:]]) for r in
                                (np.asarray(ring.coords) for ring in (water.exterior, *water.interiors))])
        lo = np.floor((np.minimum(edges[:, :2], edges[:, 2:]) - (self.x0, self.y0)) / self.cell).astype(np.int64)
        hi = np.floor((np.maximum(edges[:, :2], edges[:, 2:]) - (self.x0, self.y0)) / self.cell).astype(np.int64)
        lo, hi = np.clip(lo - 1, 0, None), np.clip(hi + 1, None, (self.nx - 1, self.ny - 1))
        for (i0, j0), (i1, j1) in zip(lo, hi):  # once per lake, one box per edge
            self.shore[j0:j1 + 1, i0:i1 + 1] = True

    @classmethod
    def for_raster(cls, water: Polygon, cells: int, half_side: float, most: int = 4_000_000) -> WaterMask:
        """A grid an eighth of the raster's cell fine, coarser only where the lake would need more than ``most``
        grid cells."""
        minx, miny, maxx, maxy = water.bounds
        return cls(water, max(2 * half_side / cells / 8, np.sqrt((maxx - minx) * (maxy - miny) / most)))

    def at(self, xy: np.ndarray) -> np.ndarray:
        """Whether each point [..., 2] lies in the water → bool [...]."""
        i = np.floor((xy[..., 0] - self.x0) / self.cell).astype(np.int64)
        j = np.floor((xy[..., 1] - self.y0) / self.cell).astype(np.int64)
        inside = (i >= 0) & (i < self.nx) & (j >= 0) & (j < self.ny)
        i, j = np.clip(i, 0, self.nx - 1), np.clip(j, 0, self.ny - 1)
        wet = inside & self.wet[j, i]
        near = inside & self.shore[j, i]
        wet[near] = shapely.contains_xy(self.water, xy[..., 0][near], xy[..., 1][near])
        return wet


@numba.njit(cache=True)
def _covered(pos, alive, offsets, radius, comm_range, out):  # pragma: no cover - compiled
    e, n, cells = pos.shape[0], pos.shape[1], offsets.shape[0]
    for b in range(e):
        for i in range(n):
            for c in range(cells):
                out[b, i, c] = 0.0
            for j in range(n):
                if j == i or not alive[b, j]:
                    continue
                rx, ry = pos[b, j, 0] - pos[b, i, 0], pos[b, j, 1] - pos[b, i, 1]
                if np.sqrt(rx * rx + ry * ry) > comm_range:
                    continue  # not heard
                for c in range(cells):
                    gx, gy = offsets[c, 0] - rx, offsets[c, 1] - ry
                    if gx * gx + gy * gy <= radius * radius:
                        out[b, i, c] = 1.0


def heard_cover(pos: np.ndarray, offsets: np.ndarray, radius: float, comm_range: float,
                alive: np.ndarray | None = None) -> np.ndarray:
    """Whether another buoy that each buoy hears (within ``comm_range``) covers each point around it (within
    ``radius``, the coverage range R): pos [E, N, 2], offsets [K, 2] from the buoy → [E, N, K], 1.0 or 0.0."""
    live = np.ones(pos.shape[:2], dtype=np.bool_) if alive is None else np.ascontiguousarray(alive, dtype=np.bool_)
    out = np.empty((*pos.shape[:2], len(offsets)))
    _covered(np.ascontiguousarray(pos, dtype=np.float64), live, np.ascontiguousarray(offsets, dtype=np.float64),
             float(radius), float(comm_range), out)
    return out


def local_raster(pos: np.ndarray, water: WaterMask, offsets: np.ndarray, radius: float, comm_range: float,
                 alive: np.ndarray | None = None) -> np.ndarray:
    """A small map around each buoy, as LPAC's robots see theirs (Agarwal et al. 2025): at each cell's centre
    (``raster_offsets``, in the world's compass, not turned with the buoy), whether it is water (``water``, the
    lake's outline) and whether another buoy heard within ``comm_range`` covers it (within ``radius``, the coverage
    range R). pos [E, N, 2], offsets [C, 2] → [E, N, 2C] in ``RASTER_CHANNELS``' order, 1 or 0."""
    wet = water.at(pos[:, :, None, :] + offsets[None, None]).astype(np.float64)  # [E, N, C]
    return np.concatenate([wet, heard_cover(pos, offsets, radius, comm_range, alive)], axis=-1)


def centroid_for_sensors(water: Polygon, config) -> LocalCentroid | None:
    """The centroid sensor of ``config`` (a ``core.sections.SensorsConfig``) in ``water``, or None without it."""
    return LocalCentroid(water, config.ray_range) if config.centroid else None


def for_sensors(water: Polygon, config) -> tuple[WaterMask, np.ndarray] | None:
    """What ``sensors.local_observation`` needs for the raster of ``config`` (a ``core.sections.SensorsConfig``)
    in ``water``: (its water mask, its cells' offsets), or None without a raster."""
    if not config.raster:
        return None
    return WaterMask.for_raster(water, config.raster, config.ray_range), raster_offsets(config.raster, config.ray_range)


# ---- the local centroid ---------------------------------------------------------------------------------------
CENTROID_STEPS = 16  # the centroid sensor's points lie ray_range / 16 apart: 797 of them within its reach


@numba.njit(cache=True)
def _centroid(pos, live, rel, heard, offsets, wet, x0, y0, cell, out):  # pragma: no cover - compiled
    """``LocalCentroid``'s loop: the mean offset of the points around each buoy that are water and nearer to it
    than to every buoy it hears."""
    e, n, k_count = heard.shape
    ny, nx = wet.shape
    for b in range(e):
        for i in range(n):
            out[b, i, 0], out[b, i, 1] = 0.0, 0.0
            if not live[b, i]:
                continue
            sx, sy, count = 0.0, 0.0, 0
            for c in range(offsets.shape[0]):
                ox, oy = offsets[c, 0], offsets[c, 1]
                gx = int(np.floor((pos[b, i, 0] + ox - x0) / cell))
                gy = int(np.floor((pos[b, i, 1] + oy - y0) / cell))
                if gx < 0 or gx >= nx or gy < 0 or gy >= ny or not wet[gy, gx]:
                    continue
                own = ox * ox + oy * oy
                mine = True
                for k in range(k_count):
                    if heard[b, i, k] > 0:
                        dx, dy = ox - rel[b, i, k, 0], oy - rel[b, i, k, 1]
                        if dx * dx + dy * dy < own:
                            mine = False
                            break
                if mine:
                    sx, sy, count = sx + ox, sy + oy, count + 1
            if count > 0:
                out[b, i, 0], out[b, i, 1] = sx / count, sy / count


class LocalCentroid:
    """Where Lloyd's law would steer a buoy that knows only what it senses now: the offset from the buoy to the
    centroid of the water within ``reach`` (its shore sensor's range) that is nearer to it than to every buoy it
    lists (``sensors.neighbours``: its K nearest heard) — its cell of a decentralised Lloyd
    (``compare.decentralised``) with no memory of where it has been, so that a buoy at the front of a fleet sees the
    free water ahead and not the water it left behind.

    The water is read at points ``reach`` / ``CENTROID_STEPS`` apart within the reach, each as the centre of its
    cell of a fine grid of the lake (a quarter of that spacing, coarser only where the lake would need more than
    ``most`` cells: the shore is known to within a cell). A buoy whose cell holds no such point, or that is out of
    service, reads (0, 0)."""

    def __init__(self, water: Polygon, reach: float, most: int = 4_000_000):
        spacing = reach / CENTROID_STEPS
        axis = np.arange(-CENTROID_STEPS, CENTROID_STEPS + 1) * spacing
        ox, oy = np.meshgrid(axis, axis, indexing="ij")
        near = ox**2 + oy**2 <= reach**2 * (1 + 1e-9)
        self.offsets = np.stack([ox[near], oy[near]], axis=1)  # [P, 2]
        minx, miny, maxx, maxy = water.bounds
        self.mask = WaterMask(water, max(spacing / 4, np.sqrt((maxx - minx) * (maxy - miny) / most)))

    def __call__(self, pos: np.ndarray, rel: np.ndarray, heard: np.ndarray,
                 alive: np.ndarray | None = None) -> np.ndarray:
        """pos [E, N, 2]; the buoys each hears (``sensors.neighbours``): rel [E, N, k, 2] (other − self) and heard
        [E, N, k] → the offsets to the centroids, m, [E, N, 2]."""
        live = np.ones(pos.shape[:2], dtype=np.bool_) if alive is None else np.ascontiguousarray(alive, dtype=np.bool_)
        out = np.empty(pos.shape[:2] + (2,))
        m = self.mask
        _centroid(np.ascontiguousarray(pos, dtype=np.float64), live, np.ascontiguousarray(rel, dtype=np.float64),
                  np.ascontiguousarray(heard, dtype=np.float64), self.offsets, m.wet, m.x0, m.y0, m.cell, out)
        return out
