"""Coverage geometry (SPEC §4): the 30-edge coverage polygon, the per-agent Cover term, the covered union.

Two paths compute the same quantities:

* the **reference** (``cover_terms_exact``, ``union_area_exact``): exact polygon algebra with shapely, one
  polygon per agent;
* the **fast path** (``CoverageGeometry``), used in training. Its exactness rests on Minkowski algebra: with K
  the coverage polygon centred at the origin (centrally symmetric, 30 is even),

  - ``Cov(p) ⊂ Reg``  ⇔  ``p ∈ Reg ⊖ K`` (the eroded region, an exact polygon),
  - ``Cov(p) ∩ Reg = ∅``  ⇔  ``p ∉ Reg ⊕ K`` (the dilated region), and then
    ``dist(Reg, Cov(p)) = dist(p, Reg ⊕ K)`` exactly;

  only ``A(Cov(p) ∩ Reg)`` in the partial band is interpolated, bilinearly from a table of exact shapely
  areas. The union area is ``Σ_a A(Cov(a) ∩ Reg)`` minus the overlap excess counted on a raster, so it is
  exact whenever no two coverage polygons overlap. ``tests/world/test_geometry.py`` bounds both errors against the
  reference on random configurations of every region.

Arrays are batched ``[E, N, ...]``: E parallel environments, N agents.
"""

from __future__ import annotations

import hashlib
import os
import tempfile
from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path

import numpy as np
import shapely
from shapely.geometry import Polygon

from replicate.core.progress import bar as progress_bar
from replicate.world.local_water import LocalWater
from replicate.world.overlap import near_another, overlap_runs


def polygon_offsets(radius: float, edges: int) -> np.ndarray:
    """Vertices of the regular ``edges``-gon of circumradius ``radius`` centred at the origin: [edges, 2]."""
    angles = 2.0 * np.pi * np.arange(edges) / edges
    return np.stack([radius * np.cos(angles), radius * np.sin(angles)], axis=1)


def coverage_polygons(xy: np.ndarray, radius: float, edges: int) -> np.ndarray:
    """Cov(a) for every agent (SPEC §4): shapely polygons, shape of ``xy`` without its last axis."""
    xy = np.asarray(xy, dtype=float)
    ring = xy[..., None, :] + polygon_offsets(radius, edges)
    return shapely.polygons(ring)


@dataclass(frozen=True)
class CoverTerms:
    """The three cases of eq. (5) per agent, arrays [E, N].

    ``area`` = A(Cov(a) ∩ Reg) (equals A(Cov(a)) when inside), ``inside`` = Cov(a) ⊂ Reg,
    ``disjoint`` = Cov(a) ∩ Reg = ∅, ``distance`` = dist(Reg, Cov(a)) (0 unless disjoint).
    """

    area: np.ndarray
    inside: np.ndarray
    disjoint: np.ndarray
    distance: np.ndarray


def cover_terms_exact(region: Polygon, xy: np.ndarray, radius: float, edges: int) -> CoverTerms:
    """Reference: exact shapely polygon algebra for eq. (5)'s cases. xy: [..., 2]."""
    cov = coverage_polygons(xy, radius, edges)
    inside = shapely.within(cov, region)
    disjoint = ~shapely.intersects(cov, region)
    area = shapely.area(shapely.intersection(cov, region))
    distance = np.where(disjoint, shapely.distance(cov, region), 0.0)
    return CoverTerms(area=area, inside=inside, disjoint=disjoint, distance=distance)


def union_area_exact(region: Polygon, xy: np.ndarray, radius: float, edges: int) -> np.ndarray:
    """Reference: A((∪_a Cov(a)) ∩ Reg) per environment, exact. xy: [E, N, 2] → [E]."""
    cov = coverage_polygons(xy, radius, edges)
    union = shapely.union_all(cov, axis=-1)
    return shapely.area(shapely.intersection(union, region))


def coverage_fraction_exact(region: Polygon, xy: np.ndarray, radius: float, edges: int) -> np.ndarray:
    """SPEC §8 coverage fraction A((∪ Cov) ∩ Reg) / A(Reg), exact. xy: [E, N, 2] → [E]."""
    return union_area_exact(region, xy, radius, edges) / region.area


def grid_in(region: Polygon, spacing: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Grid points ``spacing`` apart over ``region``'s box, the first half a spacing in from its lower-left
    corner: (xs [GX], ys [GY], inside [GX, GY], True where the point lies in the region). A region narrower than
    the spacing gets one point, at that corner."""
    minx, miny, maxx, maxy = region.bounds
    xs, ys = np.arange(minx + spacing / 2, maxx, spacing), np.arange(miny + spacing / 2, maxy, spacing)
    if not len(xs) or not len(ys):
        xs, ys = np.array([minx]), np.array([miny])
    gx, gy = np.meshgrid(xs, ys, indexing="ij")
    return xs, ys, shapely.contains_xy(region, gx, gy)


def grid_points(xs: np.ndarray, ys: np.ndarray, inside: np.ndarray) -> np.ndarray:
    """The points of a grid (``grid_in``) where ``inside`` holds, x-major → [M, 2]."""
    gx, gy = np.nonzero(inside)
    return np.stack([xs[gx], ys[gy]], axis=1)


def water_grid(region: Polygon, spacing: float) -> np.ndarray:
    """The grid points of ``grid_in`` inside the region → [M, 2]."""
    return grid_points(*grid_in(region, spacing))


def minkowski(region: Polygon, offsets: np.ndarray) -> tuple[Polygon, Polygon]:
    """(Reg ⊖ K, Reg ⊕ K) for a centrally symmetric convex K given by its vertices ``offsets`` [V, 2].

    The boundary swept by K is the union of the convex hulls of (edge ⊕ K) over every edge of every ring.
    """
    rings = [region.exterior, *region.interiors]
    hulls = []
    for ring in rings:
        pts = np.asarray(ring.coords)
        a, b = pts[:-1], pts[1:]
        cloud = np.concatenate([a[:, None, :] + offsets, b[:, None, :] + offsets], axis=1)
        hulls.append(shapely.convex_hull(shapely.multipoints(cloud)))
    band = shapely.union_all(np.concatenate(hulls))
    eroded = region.difference(band)
    dilated = region.union(band)
    return eroded, dilated


MAX_GRID_CELLS = 25_000_000  # a grid's cells: a few hundred MB while it is built (Bedok at the paper's scale: 0.2 M)


def check_grid_size(region: Polygon, radius: float, table_spacing: float, raster_spacing: float) -> None:
    """Refuse, before any allocation, a region whose area table or union raster would not fit in memory: a region
    hundreds of coverage radii across at the configured spacings (a tiny ``--radius-m`` on a large lake)."""
    minx, miny, maxx, maxy = region.bounds
    for key, h in (("coverage.table_spacing", table_spacing), ("coverage.raster_spacing", raster_spacing)):
        cells = ((maxx - minx + 6 * radius) / h) * ((maxy - miny + 6 * radius) / h)
        if cells > MAX_GRID_CELLS:
            raise ValueError(f"the region is {(maxx - minx) / radius:.3g} × {(maxy - miny) / radius:.3g} coverage "
                             f"radii: its grid at {key} = {h:g} would hold {cells:.3g} cells (at most "
                             f"{MAX_GRID_CELLS:.3g}); cover it with a larger radius or fewer buoys, or a coarser "
                             f"{key}")


class CoverageGeometry:
    """Fast, batched eq. (5)/(6) geometry for one region and one coverage polygon (see module docstring).

    eq. (5)'s cases read with closed sets, as the shapely reference does: a coverage polygon touching the shore
    from inside is "inside", one touching it from outside "partial" (area 0). A buoy clamped to the ``tuned``
    geofence at R from the region's side touches it from outside exactly, and the shore wall keeps buoys in
    contact all the time: both are scored as the exact geometry scores them."""

    def __init__(self, region: Polygon, radius: float, edges: int, table_spacing: float, raster_spacing: float):
        if not (0 < table_spacing <= radius / 2 and 0 < raster_spacing <= radius / 2):
            raise ValueError(f"table_spacing and raster_spacing must lie in (0, R/2] = (0, {radius / 2:g}] m: a "
                             "coarser grid does not resolve the coverage polygon")
        check_grid_size(region, radius, table_spacing, raster_spacing)
        self.region = region
        self.radius = radius
        self.edges = edges
        self.offsets = polygon_offsets(radius, edges)
        self.cov_area = float(Polygon(self.offsets).area)
        self.eroded, self.dilated = minkowski(region, self.offsets)
        shapely.prepare(self.eroded)
        shapely.prepare(self.dilated)
        self._build_table(table_spacing)
        self._build_raster(raster_spacing)

    # ---- per-agent terms of eq. (5) ------------------------------------------------------------------
    def _build_table(self, h: float) -> None:
        self.table_origin, self.table_h, self.table = _area_table(
            self.region.wkb, self.radius, self.edges, h, self.eroded.wkb, self.dilated.wkb
        )

    def cover_terms(self, xy: np.ndarray) -> CoverTerms:
        """eq. (5)'s cases for every agent. xy: [E, N, 2] → CoverTerms of [E, N] arrays."""
        flat = xy.reshape(-1, 2)
        x, y = flat[:, 0], flat[:, 1]
        inside = shapely.intersects_xy(self.eroded, x, y)  # closed sets: a boundary point is in
        touching = shapely.intersects_xy(self.dilated, x, y)
        disjoint = ~touching
        area = np.where(inside, self.cov_area, 0.0)
        partial = touching & ~inside
        if partial.any():
            area[partial] = np.clip(self._interpolate(flat[partial]), 0.0, self.cov_area)
        distance = np.zeros(len(flat))
        if disjoint.any():
            distance[disjoint] = shapely.distance(self.dilated, shapely.points(flat[disjoint]))
        shape = xy.shape[:-1]
        return CoverTerms(area.reshape(shape), inside.reshape(shape), disjoint.reshape(shape), distance.reshape(shape))

    def _interpolate(self, pts: np.ndarray) -> np.ndarray:
        u = (pts - self.table_origin) / self.table_h
        i = np.clip(np.floor(u).astype(np.int64), 0, np.array(self.table.shape) - 2)
        f = u - i
        t = self.table
        i0, j0 = i[:, 0], i[:, 1]
        fx, fy = f[:, 0], f[:, 1]
        return (
            t[i0, j0] * (1 - fx) * (1 - fy)
            + t[i0 + 1, j0] * fx * (1 - fy)
            + t[i0, j0 + 1] * (1 - fx) * fy
            + t[i0 + 1, j0 + 1] * fx * fy
        )

    # ---- union term of eq. (6) -----------------------------------------------------------------------
    def _build_raster(self, h: float, subpixel: int = 8) -> None:
        # The grid covers the region's box padded by the stencil's reach, so a stamp never leaves it: an agent
        # with A(Cov ∩ Reg) > 0 lies within R of the region. Cells outside the region are masked out.
        self.raster_h = h
        self.subpixel = subpixel
        w = int(np.ceil(self.radius / h)) + 1
        minx, miny, maxx, maxy = self.region.bounds
        pad = 2 * w + 2  # agent up to R outside the region, plus the stencil's reach
        self.raster_origin = np.array([minx - pad * h, miny - pad * h])
        self.nx = int(np.ceil((maxx - minx) / h)) + 2 * pad + 1
        self.ny = int(np.ceil((maxy - miny) / h)) + 2 * pad + 1
        cx = self.raster_origin[0] + (np.arange(self.nx) + 0.5) * h
        cy = self.raster_origin[1] + (np.arange(self.ny) + 0.5) * h
        gx, gy = np.meshgrid(cx, cy, indexing="ij")
        self.mask = shapely.contains_xy(self.region, gx.ravel(), gy.ravel())  # [nx * ny], x-major
        # Stencils: cells whose centre lies in K for an agent at sub-pixel offset ((q + 0.5) / subpixel) h. K is
        # convex, so each column dx of a stencil is one run of rows: stencil_lo/hi [subpixel², 2w + 1] hold the
        # run's first and last dy (lo > hi: an empty column).
        d = np.arange(-w, w + 1)
        dx, dy = np.meshgrid(d, d, indexing="ij")
        normals = self.offsets + np.roll(self.offsets, -1, axis=0)
        normals /= np.linalg.norm(normals, axis=1, keepdims=True)  # edge normals of K
        apothem = self.radius * np.cos(np.pi / self.edges)
        self.stencil_reach = w
        self.stencil_lo = np.full((subpixel * subpixel, 2 * w + 1), w + 1, np.int64)
        self.stencil_hi = np.full((subpixel * subpixel, 2 * w + 1), -w - 1, np.int64)
        for qx in range(subpixel):
            for qy in range(subpixel):
                fx, fy = (qx + 0.5) / subpixel, (qy + 0.5) / subpixel
                rel = np.stack([(dx + 0.5 - fx) * h, (dy + 0.5 - fy) * h], axis=-1)
                inside = (rel @ normals.T).max(axis=-1) <= apothem  # [2w + 1, 2w + 1]
                k = qx * subpixel + qy
                for col in np.nonzero(inside.any(axis=1))[0]:
                    rows = d[inside[col]]
                    assert len(rows) == rows[-1] - rows[0] + 1  # one run per column (K convex)
                    self.stencil_lo[k, col], self.stencil_hi[k, col] = rows[0], rows[-1]
        # each stencil's bounding box relative to the agent's cell, [subpixel², 4]: dx0, dx1, dy0, dy1 (inclusive)
        filled = self.stencil_lo <= self.stencil_hi
        lo, hi = self.stencil_lo, self.stencil_hi
        self.stencil_box = np.stack([
            np.where(filled, d, w + 1).min(axis=1), np.where(filled, d, -w - 1).max(axis=1),
            np.where(filled, lo, w + 1).min(axis=1), np.where(filled, hi, -w - 1).max(axis=1),
        ], axis=1)
        # the raster kernel needs a run in every column of a stencil's box: as many filled columns as box columns
        assert (filled.sum(axis=1) == self.stencil_box[:, 1] - self.stencil_box[:, 0] + 1).all()  # empty: never equal
        # per column, how many of its first r cells are in the region: [nx, ny + 1]
        self.mask_prefix = np.zeros((self.nx, self.ny + 1), np.int64)
        self.mask_prefix[:, 1:] = np.cumsum(self.mask.reshape(self.nx, self.ny), axis=1)

    def union_area(self, xy: np.ndarray, area: np.ndarray, marginal: bool = False):
        """A((∪_a Cov(a)) ∩ Reg) per environment: xy [E, N, 2], area [E, N] from ``cover_terms`` → [E].

        With ``marginal=True`` also returns each agent's own contribution
        A(∪_b Cov(b) ∩ Reg) − A(∪_{b≠a} Cov(b) ∩ Reg), [E, N] (the difference reward of SPEC §6).
        """
        n_env = area.shape[0]
        total = area.sum(axis=1)
        contribution = area.copy()
        # Only agents closer than 2R to another can overlap (the circumradius bounds K).
        involved = near_another(xy, (2 * self.radius) ** 2) & (area > 0)
        if not involved.any():
            return (total, contribution) if marginal else total
        env_idx, agent_idx = np.nonzero(involved)
        u = (xy[env_idx, agent_idx] - self.raster_origin) / self.raster_h
        cell = np.floor(u).astype(np.int64)
        q = ((u - cell) * self.subpixel).astype(np.int64)
        k = q[:, 0] * self.subpixel + q[:, 1]
        box = self.stencil_box[k] + cell[:, [0, 0, 1, 1]]  # each stamp's bounding box in cells, [M, 4]
        shared = overlap_runs(env_idx, cell, k, box, self.stencil_lo, self.stencil_hi, self.stencil_reach,
                               self.mask_prefix, marginal)
        cell_area = self.raster_h**2
        excess = np.bincount(env_idx, weights=shared[:, 0], minlength=n_env)
        if marginal:
            own = area[env_idx, agent_idx] - shared[:, 1] * cell_area
            contribution[env_idx, agent_idx] = np.maximum(own, 0.0)
            return total - excess * cell_area, contribution
        return total - excess * cell_area


TABLE_VERSION = 1
# A long shore: an outline of more vertices than this. Its area table, clairvoyant Lloyd's cells and the best
# layout's candidates are clipped to the water by ``local_water`` (the same areas and centroids to float rounding,
# 50x faster on Mae Kuang's 1,712 vertices); a shorter outline keeps shapely's overlay, so that every table a
# committed run trained on (the square, the rectangle, Bedok's 117 vertices, the generated training lakes' at
# most 315) and every tuned and evaluated baseline on them stays the bytes it was computed with.
LONG_SHORE_VERTICES = 400


def long_shore(region: Polygon) -> bool:
    """Whether ``region`` is clipped by ``local_water`` (``LONG_SHORE_VERTICES``)."""
    return shapely.get_num_coordinates(region) > LONG_SHORE_VERTICES


def cache_dir() -> Path:
    """Where area tables are cached: $REPLICATE_CACHE, else ~/.cache/replicate."""
    return Path(os.environ.get("REPLICATE_CACHE", Path.home() / ".cache" / "replicate"))


@lru_cache(maxsize=16)
def _area_table(region_wkb: bytes, radius: float, edges: int, h: float, eroded_wkb: bytes, dilated_wkb: bytes):
    """Exact A(Cov(p) ∩ Reg) on a grid of spacing h over the dilated region's box.

    Cached in memory and on disk (a few seconds of shapely work per region), keyed by every input."""
    how = ("local water",) if long_shore(shapely.from_wkb(region_wkb)) else ()
    key = hashlib.sha256(repr((TABLE_VERSION, region_wkb, radius, edges, h, *how)).encode()).hexdigest()[:24]
    path = cache_dir() / f"area-table-{key}.npz"
    if path.exists():
        try:
            with np.load(path) as z:
                return z["origin"], float(z["h"]), z["table"]
        except (OSError, ValueError, KeyError):
            pass  # a damaged cache file is rebuilt below
    origin, h, table = _build_area_table(region_wkb, radius, edges, h, eroded_wkb, dilated_wkb)
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(dir=path.parent, suffix=".npz")
        with os.fdopen(fd, "wb") as fh:
            np.savez(fh, origin=origin, h=h, table=table)
        os.replace(tmp, path)
    except OSError:
        pass  # a read-only home only costs the rebuild next time
    return origin, h, table


def _build_area_table(region_wkb, radius, edges, h, eroded_wkb, dilated_wkb):
    region = shapely.from_wkb(region_wkb)
    eroded = shapely.from_wkb(eroded_wkb)
    dilated = shapely.from_wkb(dilated_wkb)
    offsets = polygon_offsets(radius, edges)
    minx, miny, maxx, maxy = dilated.bounds
    origin = np.array([minx - 2 * h, miny - 2 * h])
    nx = int(np.ceil((maxx - minx) / h)) + 5
    ny = int(np.ceil((maxy - miny) / h)) + 5
    gx, gy = np.meshgrid(origin[0] + np.arange(nx) * h, origin[1] + np.arange(ny) * h, indexing="ij")
    x, y = gx.ravel(), gy.ravel()
    table = np.zeros(nx * ny)
    # Nodes within one cell diagonal of the band need exact areas; deeper nodes are A(K) or 0.
    pad = 2 * h
    grown = dilated.buffer(pad)
    shrunk = eroded.buffer(-pad) if not eroded.is_empty else eroded
    near = shapely.contains_xy(grown, x, y) & ~shapely.contains_xy(shrunk, x, y)
    deep_inside = shapely.contains_xy(shrunk, x, y)
    table[deep_inside] = Polygon(offsets).area
    pts = np.stack([x[near], y[near]], axis=1)
    if long_shore(region):
        table[near] = LocalWater.of(region, radius).overlap_areas(pts, offsets)
        return origin, h, table.reshape(nx, ny)
    areas = np.empty(len(pts))
    chunk = 20_000
    for start in progress_bar(None if len(pts) > 5 * chunk else False, iterable=range(0, len(pts), chunk),
                              desc="coverage area table (cached for later runs)", unit="chunk", leave=False):
        cov = shapely.polygons(pts[start:start + chunk, None, :] + offsets)
        areas[start:start + chunk] = shapely.area(shapely.intersection(cov, region))
    table[near] = areas
    return origin, h, table.reshape(nx, ny)


def region_key(region: Polygon) -> str:
    """A short stable hash of a region polygon (for caches and checkpoint metadata)."""
    return hashlib.sha256(region.wkb).hexdigest()[:16]
