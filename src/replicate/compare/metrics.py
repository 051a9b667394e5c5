"""SPEC §8 metrics of spread and of learning curves: one definition each, used by every figure, table and test
(coverage itself is measured in ``world.coverage``).

Arrays: positions [E, N, 2] (E episodes or environments, N agents); curves [episodes].
"""

from __future__ import annotations

import math

import numpy as np
from scipy import stats


def mean_nearest_neighbour(xy: np.ndarray) -> np.ndarray:
    """Spread: mean over agents of the distance to the nearest other agent. xy [E, N, 2] → [E] (NaN if N = 1)."""
    n = xy.shape[1]
    if n < 2:
        return np.full(xy.shape[0], np.nan)
    d = np.linalg.norm(xy[:, :, None, :] - xy[:, None, :, :], axis=-1)
    d[:, np.arange(n), np.arange(n)] = np.inf
    return d.min(axis=2).mean(axis=1)


def moving_average(x: np.ndarray, window: int) -> np.ndarray:
    """Trailing moving average, defined from index window − 1 on. [T] → [T − window + 1]."""
    x = np.asarray(x, dtype=float)
    if len(x) < window:
        return np.empty(0)
    c = np.cumsum(np.insert(x, 0, 0.0))
    return (c[window:] - c[:-window]) / window


def convergence_episode(curve: np.ndarray, window: int = 200, tolerance: float = 0.05, final: int = 500) -> int | None:
    """First episode after which the ``window``-episode moving average of ``curve`` stays within ±tolerance
    of its final value (the mean of the last ``final`` episodes); ``None`` if there is none (SPEC §8).

    The band is ``tolerance·|final value|``. Returns the episode index at the end of the first qualifying
    window.
    """
    curve = np.asarray(curve, dtype=float)
    if len(curve) < max(window, final):
        return None
    target = curve[-final:].mean()
    ma = moving_average(curve, window)
    outside = np.abs(ma - target) > tolerance * abs(target)
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
