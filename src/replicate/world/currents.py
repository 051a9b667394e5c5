"""Water that moves: a drift current carries every buoy with it, p ← p + (v + c(p))·dt, where v is the buoy's own
velocity through the water (MPE's) and c the water's velocity where it floats.

A current is per environment: a uniform flow, a smooth vortex, or both, batched ``[E, ...]``. The vortex turns
about its centre with speed peak·(r/core)·exp((1 − r²/core²)/2) at distance r: 0 at the centre, ``peak`` at r =
core, fading beyond it (counter-clockwise for a positive peak).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from shapely.geometry import Polygon


@dataclass(frozen=True)
class Current:
    """The water's velocity in E environments: ``flow`` [E, 2] everywhere, plus a vortex of ``peak`` [E] (m/s,
    signed) at ``center`` [E, 2] with core radius ``core`` [E] (m; 0 where there is none)."""

    flow: np.ndarray
    center: np.ndarray
    peak: np.ndarray
    core: np.ndarray

    @classmethod
    def uniform(cls, flow) -> Current:
        flow = np.atleast_2d(np.asarray(flow, dtype=float))
        e = len(flow)
        return cls(flow, np.zeros((e, 2)), np.zeros(e), np.zeros(e))

    @classmethod
    def vortex(cls, center, peak, core) -> Current:
        center = np.atleast_2d(np.asarray(center, dtype=float))
        e = len(center)
        return cls(np.zeros((e, 2)), center, np.broadcast_to(np.asarray(peak, float), e).copy(),
                   np.broadcast_to(np.asarray(core, float), e).copy())

    def tiled(self, n_envs: int) -> Current:
        """One environment's current in each of ``n_envs`` environments."""
        if len(self.flow) != 1:
            raise ValueError(f"only one environment's current is tiled, this one has {len(self.flow)}")
        return Current(*(np.repeat(a, n_envs, axis=0) for a in (self.flow, self.center, self.peak, self.core)))

    def describe(self) -> dict:
        """One environment's current as a record says it (m/s, m): {"flow"} and, with a vortex, {"vortex": {"center",
        "peak", "core"}}."""
        out = {"flow": [float(v) for v in self.flow[0]]}
        if self.core[0] > 0:
            out["vortex"] = {"center": [float(v) for v in self.center[0]], "peak": float(self.peak[0]),
                             "core": float(self.core[0])}
        return out

    def at(self, pos: np.ndarray) -> np.ndarray:
        """The water's velocity at positions [E, N, 2] → [E, N, 2]."""
        rel = pos - self.center[:, None, :]
        core = np.where(self.core > 0, self.core, 1.0)[:, None]
        r2 = (rel**2).sum(axis=-1) / core**2  # (r / core)²
        # speed peak·(r/core)·exp((1 − r²/core²)/2) along the tangent (−y, x)/r: the r cancels
        scale = np.where(self.core[:, None] > 0, self.peak[:, None] / core * np.exp(0.5 * (1.0 - r2)), 0.0)
        swirl = np.stack([-rel[..., 1], rel[..., 0]], axis=-1) * scale[..., None]
        return self.flow[:, None, :] + swirl

    def max_speed(self) -> float:
        """The fastest the water moves anywhere, in any environment."""
        return float((np.linalg.norm(self.flow, axis=1) + np.abs(self.peak)).max(initial=0.0))


def lake_vortex(water: Polygon, peak: float) -> Current:
    """A vortex over a whole lake: centred in the middle of the water's box, its core a third of the box's larger
    side (the training's vortices' size, ``random_current``), turning at ``peak`` m/s (counter-clockwise when
    positive): the water near the middle still, the water around it moving most."""
    minx, miny, maxx, maxy = water.bounds
    return Current.vortex([(minx + maxx) / 2, (miny + maxy) / 2], peak, max(maxx - minx, maxy - miny) / 3)


def random_current(rng: np.random.Generator, n_envs: int, water: Polygon, max_speed: float) -> Current:
    """Each environment gets, by a fair coin, a uniform flow of random heading or a vortex centred in the water's
    box with a core a third of its size; every speed uniform in [0, ``max_speed``]."""
    minx, miny, maxx, maxy = water.bounds
    speed = rng.uniform(0, max_speed, n_envs)
    heading = rng.uniform(0, 2 * np.pi, n_envs)
    is_vortex = rng.uniform(size=n_envs) < 0.5
    flow = np.where(is_vortex[:, None], 0.0, speed[:, None] * np.stack([np.cos(heading), np.sin(heading)], 1))
    center = rng.uniform((minx, miny), (maxx, maxy), (n_envs, 2))
    sign = np.where(rng.uniform(size=n_envs) < 0.5, -1.0, 1.0)
    core = np.where(is_vortex, max(maxx - minx, maxy - miny) / 3, 0.0)
    return Current(flow, center, np.where(is_vortex, sign * speed, 0.0), core)
