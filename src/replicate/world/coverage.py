"""Coverage as SPEC §8 measures it: the exact covered fraction of a region, one buoy's coverage area, the ceiling
N·A(Cov)/A(Reg), and the share of buoys whose coverage lies inside the water.

Arrays: positions [E, N, 2] (E episodes or environments, N agents).
"""

from __future__ import annotations

import math

import numpy as np
from shapely.geometry import Polygon

from replicate.world.geometry import cover_terms_exact, coverage_fraction_exact


def coverage_fraction(region: Polygon, xy: np.ndarray, radius: float, edges: int) -> np.ndarray:
    """A((∪_a Cov(a)) ∩ Reg) / A(Reg), exact shapely. xy [E, N, 2] → [E]."""
    return coverage_fraction_exact(region, xy, radius, edges)


def cover_area(radius: float, edges: int) -> float:
    """A(Cov): the area of one buoy's coverage polygon, a regular ``edges``-gon of circumradius ``radius``."""
    return 0.5 * edges * radius**2 * math.sin(2 * math.pi / edges)


def coverage_ceiling(region_area: float, n_agents: int, radius: float, edges: int) -> float:
    """min(1, N·A(Cov)/A(Reg)) (SPEC §7): 0.780 for 9 agents, R = 0.5, 30 edges, 9 m²."""
    return min(1.0, n_agents * cover_area(radius, edges) / region_area)


def fraction_inside(region: Polygon, xy: np.ndarray, radius: float, edges: int) -> np.ndarray:
    """Spread: fraction of agents whose coverage polygon lies fully inside the region. [E, N, 2] → [E]."""
    return cover_terms_exact(region, xy, radius, edges).inside.mean(axis=1)
