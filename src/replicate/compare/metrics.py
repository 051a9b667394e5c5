"""SPEC §8 metrics of spread and of learning curves: one definition each, used by every figure, table and test
(coverage itself is measured in ``world.coverage``).

Arrays: positions [E, N, 2] (E episodes or environments, N agents); curves [episodes].
"""

from __future__ import annotations

import math

import numpy as np
import shapely
from scipy import stats
from shapely.geometry import Polygon


def mean_nearest_neighbour(xy: np.ndarray) -> np.ndarray:
    """Spread: mean over agents of the distance to the nearest other agent. xy [E, N, 2] → [E] (NaN if N = 1)."""
    n = xy.shape[1]
    if n < 2:
        return np.full(xy.shape[0], np.nan)
    d = np.linalg.norm(xy[:, :, None, :] - xy[:, None, :, :], axis=-1)
    d[:, np.arange(n), np.arange(n)] = np.inf
    return d.min(axis=2).mean(axis=1)


def nearest_neighbour_inside(region: Polygon, xy: np.ndarray) -> np.ndarray:
    """Spread over the region: mean over the agents inside it (the closed region) of the distance to the nearest
    other agent inside (an agent that leaves no longer inflates the spread); NaN where fewer than two are inside:
    no spread over the region to measure, which a 0 would count as agents bunched together. xy [E, N, 2] → [E]."""
    inside = shapely.intersects_xy(region, xy[..., 0], xy[..., 1])  # [E, N]
    d = np.linalg.norm(xy[:, :, None, :] - xy[:, None, :, :], axis=-1)
    n = xy.shape[1]
    d[:, np.arange(n), np.arange(n)] = np.inf
    d = np.where(inside[:, None, :], d, np.inf).min(axis=2)  # each agent's nearest other agent inside
    counted = inside & np.isfinite(d)
    return np.where(counted.sum(axis=1) >= 2, np.where(counted, d, 0.0).sum(axis=1) / np.maximum(counted.sum(1), 1),
                    np.nan)


def moving_average(x: np.ndarray, window: int) -> np.ndarray:
    """Trailing moving average, defined from index window − 1 on. [T] → [T − window + 1]."""
    x = np.asarray(x, dtype=float)
    if len(x) < window:
        return np.empty(0)
    c = np.cumsum(np.insert(x, 0, 0.0))
    return (c[window:] - c[:-window]) / window


BANDS = ("range", "final")  # the convergence band's width: a share of the curve's range, or of its final value


def convergence_episode(curve: np.ndarray, window: int = 200, tolerance: float = 0.05, final: int = 500,
                        band: str = "range") -> int | None:
    """First episode after which the ``window``-episode moving average of ``curve`` stays within ±tolerance
    of its final value (the mean of the last ``final`` episodes); ``None`` if there is none (SPEC §8).

    The band is ``tolerance`` × the moving average's range (max − min) with ``band="range"``, or ``tolerance`` ×
    |final value| with ``band="final"`` (SPEC §8's reading, which a final value near 0 makes narrow and a constant
    bonus wide). Returns the episode index at the end of the first qualifying window.
    """
    curve = np.asarray(curve, dtype=float)
    if len(curve) < max(window, final):
        return None
    if band not in BANDS:
        raise ValueError(f"band must be one of {BANDS}, got {band!r}")
    target = curve[-final:].mean()
    ma = moving_average(curve, window)
    width = ma.max() - ma.min() if band == "range" else abs(target)
    outside = np.abs(ma - target) > tolerance * width
    if outside[-1]:
        return None
    last_out = np.flatnonzero(outside)
    first_in = 0 if len(last_out) == 0 else last_out[-1] + 1
    return int(first_in + window - 1)


def mean_ci(values, level: float = 0.95) -> dict:
    """Mean and two-sided Student-t confidence interval of ``values`` (NaN half-width for one value)."""
    v = np.asarray(values, dtype=float)
    v = v[~np.isnan(v)]
    if len(v) == 0:
        return {"mean": math.nan, "lo": math.nan, "hi": math.nan, "n": 0}
    m = float(v.mean())
    if len(v) < 2:
        return {"mean": m, "lo": math.nan, "hi": math.nan, "n": 1}
    half = float(stats.t.ppf(0.5 + level / 2, len(v) - 1) * v.std(ddof=1) / math.sqrt(len(v)))
    return {"mean": m, "lo": m - half, "hi": m + half, "n": int(len(v))}
