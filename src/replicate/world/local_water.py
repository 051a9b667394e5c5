"""Convex polygons against the water of a long shore: A(K ∩ Reg) and its centroid for many convex polygons K.

shapely intersects every polygon with the whole outline: on Mae Kuang's 1,712 vertices a few hundred thousand
coverage polygons (the area table of ``geometry``) took 44 s, and clairvoyant Lloyd's Voronoi cells most of an
evaluation. A convex polygon's overlap with a ring of any shape is the ring clipped against the polygon's edges
one half-plane at a time (Sutherland-Hodgman: on a non-convex ring the clipped ring may hold zero-area bridges,
which its signed area and first moments do not see), in a compiled loop, in coordinates about the polygon's first
vertex (so the rounding of a dry polygon's rings, which cancel, stays at the polygon's own scale). For a polygon of
known reach the region is cut into square tiles, each kept with the water within that reach (shapely, exact; a
tile is cut when a polygon first asks for it), so the polygon meets only its tile's rings. The same areas and
centroids as shapely's to float rounding (``tests/world/test_local_water.py``), 50x faster on Mae Kuang.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import shapely
from numba import njit
from shapely.geometry import Polygon

# the tile's side in reaches: smaller tiles hold fewer shore vertices each, down to where their margin of one reach
# holds most of a tile's water (on Mae Kuang 1, 0.5 and 0.25 coverage radii gave 133, 105 and 92 vertices a tile)
TILE_REACHES = 0.5
CHUNK = 50_000  # polygons per compiled call: their vertices are laid out flat, a few MB at a time


@dataclass(frozen=True)
class Rings:
    """The rings of some water: ``xy`` [V, 2] every ring's vertices in turn (each closed), ``start`` [R + 1] where
    each ring's vertices begin, ``sign`` [R] +1 for a ring that adds water, -1 for a hole, the ring's own
    orientation folded in (a ring's clipped signed area times its sign is the water it holds); ``group`` [G + 1]
    where the rings of each of the G geometries it was made of begin."""

    xy: np.ndarray
    start: np.ndarray
    sign: np.ndarray
    group: np.ndarray

    @classmethod
    def of(cls, geometries) -> Rings:
        """The rings of each geometry (a polygon, a multipolygon, a collection: its polygons' rings; lines,
        points and empty geometries hold no water) in ``geometries`` [G]."""
        xy, start, sign, group = [], [0], [], [0]
        for geometry in geometries:
            for polygon in shapely.get_parts(geometry):
                if not isinstance(polygon, Polygon) or polygon.is_empty:
                    continue
                for k, ring in enumerate([polygon.exterior, *polygon.interiors]):
                    coords = np.asarray(ring.coords)
                    xy.append(coords)
                    start.append(start[-1] + len(coords))
                    sign.append((1.0 if shoelace(coords) > 0 else -1.0) * (1.0 if k == 0 else -1.0))
            group.append(len(sign))
        return cls(np.concatenate(xy) if xy else np.zeros((0, 2)), np.array(start, np.int64), np.array(sign),
                   np.array(group, np.int64))

    def moments(self, clips: np.ndarray, groups: np.ndarray | None = None) -> np.ndarray:
        """(area, ∫x, ∫y) of each convex polygon ∩ this water: ``clips`` [M, K, 2] the polygons' vertices (either
        orientation, no closing vertex; a repeated vertex is a zero-length edge, which clips nothing), each against
        the rings of geometry ``groups`` [M] (None: every ring) → [M, 3]; NaN where a clip would overflow the
        loop's buffers (none seen)."""
        m = clips.shape[0]
        lo = np.zeros(m, np.int64) if groups is None else self.group[groups]
        hi = np.full(m, len(self.sign), np.int64) if groups is None else self.group[groups + 1]
        out = np.empty((m, 3))
        for s in range(0, m, CHUNK):
            out[s:s + CHUNK] = clipped_moments(np.ascontiguousarray(clips[s:s + CHUNK], dtype=float), lo[s:s + CHUNK],
                                               hi[s:s + CHUNK], self.xy, self.start, self.sign)
        return out


@dataclass(frozen=True)
class LocalWater:
    """``region`` cut into square tiles of side ``tile`` from ``origin`` (``shape`` tiles a side), each with the
    water within ``reach`` of it (``pieces``: {flat tile index: geometry}, cut when first asked for, so a lake
    hundreds of reaches across costs only the tiles its polygons fall in)."""

    region: Polygon
    origin: np.ndarray
    tile: float
    shape: tuple[int, int]
    reach: float
    pieces: dict[int, object] = field(default_factory=dict, compare=False)

    @classmethod
    def of(cls, region: Polygon, reach: float) -> LocalWater:
        """Tiles of side ``TILE_REACHES``·``reach`` over ``region``'s box (a polygon of that reach about a point
        of a tile lies in the box of the tile's water)."""
        tile = TILE_REACHES * reach
        minx, miny, maxx, maxy = region.bounds
        shape = (int(np.floor((maxx - minx) / tile)) + 1, int(np.floor((maxy - miny) / tile)) + 1)
        return cls(region, np.array([minx, miny]), float(tile), shape, float(reach))

    def tiles_of(self, points: np.ndarray) -> np.ndarray:
        """The tile of each point [M, 2] → [M] flat indices (points off the tiles clamped to the nearest, whose
        water holds all of the region's within ``reach`` of them)."""
        ij = np.floor((points - self.origin) / self.tile).astype(np.int64)
        ij = np.clip(ij, 0, np.array(self.shape) - 1)
        return ij[:, 0] * self.shape[1] + ij[:, 1]

    def water_of(self, tiles: np.ndarray) -> np.ndarray:
        """The water of each tile [T] (flat indices) → [T] geometries, cutting those not cut yet."""
        new = np.array(sorted(set(tiles.tolist()) - self.pieces.keys()), np.int64)
        if len(new):
            lo = self.origin + np.stack(np.divmod(new, self.shape[1]), axis=1) * self.tile - self.reach * (1 + 1e-6)
            hi = lo + self.tile + 2 * self.reach * (1 + 1e-6)
            cut = shapely.intersection(shapely.box(lo[:, 0], lo[:, 1], hi[:, 0], hi[:, 1]), self.region)
            self.pieces.update(zip(new.tolist(), cut))
        return np.array([self.pieces[t] for t in tiles.tolist()], dtype=object)

    def clip(self, polygons: np.ndarray, centres: np.ndarray) -> np.ndarray:
        """Each polygon [M] (within ``reach`` of its centre [M, 2]) ∩ the region, as shapely geometries → [M]:
        intersected with its tile's water, not the whole outline (the same water)."""
        return shapely.intersection(polygons, self.water_of(self.tiles_of(centres)))

    def overlap_areas(self, points: np.ndarray, offsets: np.ndarray) -> np.ndarray:
        """A(K(p) ∩ Reg) for each point [M, 2], K(p) the convex polygon of vertices ``offsets`` [K, 2] (within
        ``reach`` of the origin) moved to p → [M]."""
        points = np.asarray(points, dtype=float)
        areas = np.empty(len(points))
        for s in range(0, len(points), CHUNK):
            part = points[s:s + CHUNK]
            tiles, group = np.unique(self.tiles_of(part), return_inverse=True)
            rings = Rings.of(self.water_of(tiles))
            areas[s:s + CHUNK] = rings.moments(part[:, None] + offsets, group.ravel())[:, 0]
        lost = np.isnan(areas)
        if lost.any():  # a clip too long for the loop's buffers: shapely's area
            areas[lost] = shapely.area(shapely.intersection(shapely.polygons(points[lost, None] + offsets),
                                                            self.region))
        return areas


def shoelace(ring: np.ndarray) -> float:
    """The signed area of a closed ring [V, 2] (first vertex repeated last): positive counter-clockwise."""
    x, y = ring[:, 0], ring[:, 1]
    return 0.5 * float(np.sum(x[:-1] * y[1:] - x[1:] * y[:-1]))


@njit(cache=True)
def clipped_moments(clips, lo, hi, xy, start, sign):  # pragma: no cover
    """``Rings.moments``' loop: clips [M, K, 2], lo and hi [M] (each polygon's rings), xy [V, 2], start [R + 1],
    sign [R] → [M, 3]: per convex polygon p, Σ over rings lo[p]..hi[p] of sign · (the signed area, ∫x, ∫y) of the
    ring clipped to the polygon (Sutherland-Hodgman, one half-plane per polygon edge), computed about the polygon's
    first vertex and moved back."""
    m, k = clips.shape[0], clips.shape[1]
    longest = 1
    for r in range(start.shape[0] - 1):
        longest = max(longest, start[r + 1] - start[r])
    # a clipped ring holds its vertices inside, at most two points per edge crossing the polygon and the polygon's
    # corners along the zero-area bridges: far below this
    size = 8 * longest + 8 * k
    a, b = np.empty((size, 2)), np.empty((size, 2))
    out = np.zeros((m, 3))
    for p in range(m):
        ox, oy = clips[p, 0, 0], clips[p, 0, 1]  # the polygon's first vertex: every coordinate is taken about it
        twice = 0.0  # the polygon's orientation: its inside is left of its edges when counter-clockwise
        for e in range(k):
            f = (e + 1) % k
            twice += (clips[p, e, 0] - ox) * (clips[p, f, 1] - oy) - (clips[p, f, 0] - ox) * (clips[p, e, 1] - oy)
        turn = 1.0 if twice >= 0 else -1.0
        area, mx, my, overflow = 0.0, 0.0, 0.0, False
        for r in range(lo[p], hi[p]):
            n = start[r + 1] - start[r] - 1  # the closing vertex is not repeated in the work buffer
            for v in range(n):
                a[v, 0], a[v, 1] = xy[start[r] + v, 0] - ox, xy[start[r] + v, 1] - oy
            for e in range(k):
                if n == 0:
                    break
                if 2 * n > size:  # this clip could write past the buffers
                    overflow = True
                    break
                c0x, c0y = clips[p, e, 0] - ox, clips[p, e, 1] - oy
                f = (e + 1) % k
                n = half_plane(a, n, b, c0x, c0y, clips[p, f, 0] - ox - c0x, clips[p, f, 1] - oy - c0y, turn)
                a, b = b, a
            if overflow:
                break
            twice_area, mx6, my6 = polygon_moments(a, n)
            area += sign[r] * twice_area / 2
            mx += sign[r] * mx6 / 6
            my += sign[r] * my6 / 6
        if overflow:
            out[p, 0], out[p, 1], out[p, 2] = np.nan, np.nan, np.nan
        else:  # ∫x over the region about the first vertex o = ∫(x − o) + o·A
            out[p, 0], out[p, 1], out[p, 2] = area, mx + ox * area, my + oy * area
    return out


@njit(cache=True)
def half_plane(a, n, b, c0x, c0y, ex, ey, turn):  # pragma: no cover
    """The polygon a[:n] [n, 2] clipped to the half-plane left of the line through (c0x, c0y) along (ex, ey) (right
    of it when ``turn`` is -1), written into b → its vertex count. Scalars, not arrays: the loop that calls it once
    per polygon edge allocates nothing."""
    count = 0
    sx, sy = a[n - 1, 0], a[n - 1, 1]
    s_side = turn * (ex * (sy - c0y) - ey * (sx - c0x))
    for v in range(n):
        qx, qy = a[v, 0], a[v, 1]
        q_side = turn * (ex * (qy - c0y) - ey * (qx - c0x))
        if (q_side >= 0) != (s_side >= 0):  # the edge s → q crosses the line
            t = s_side / (s_side - q_side)
            b[count, 0], b[count, 1] = sx + t * (qx - sx), sy + t * (qy - sy)
            count += 1
        if q_side >= 0:
            b[count, 0], b[count, 1] = qx, qy
            count += 1
        sx, sy, s_side = qx, qy, q_side
    return count


@njit(cache=True)
def polygon_moments(a, n):  # pragma: no cover
    """(2·area, 6·∫x, 6·∫y) of the polygon a[:n] [n, 2] by the shoelace formula (signed: positive counter-clockwise)."""
    area2, mx6, my6 = 0.0, 0.0, 0.0
    for v in range(n):
        w = v + 1 if v + 1 < n else 0
        cross = a[v, 0] * a[w, 1] - a[w, 0] * a[v, 1]
        area2 += cross
        mx6 += (a[v, 0] + a[w, 0]) * cross
        my6 += (a[v, 1] + a[w, 1]) * cross
    return area2, mx6, my6
