"""The paper's two reward designs as pure functions (SPEC §3-§4). Arrays are batched [E, N]: E environments,
N agents. Every function returns rewards in the paper's units; any rescaling is the learner's business.
"""

from __future__ import annotations

import numpy as np

from replicate.core.sections import CRRewardConfig, SWRewardConfig
from replicate.world.geometry import CoverTerms


def sw_region_attraction(signed_distance: np.ndarray, r1: float, r2: float) -> np.ndarray:
    """eq. (sw-RegAtt): +R1 if D(x_a) < 0 (inside), else −R2 − D(x_a). [E, N] → [E, N]."""
    return np.where(signed_distance < 0, r1, -r2 - signed_distance)


def pair_distances(xy: np.ndarray) -> np.ndarray:
    """d(n, i) for every unordered pair i < n. xy: [E, N, 2] → [E, N(N−1)/2]."""
    i, n = np.triu_indices(xy.shape[1], k=1)
    return np.linalg.norm(xy[:, n] - xy[:, i], axis=-1)


def sw_inter_agent(
    xy: np.ndarray, alpha: float, beta: float, prop_range: tuple[float, float], coll_range: tuple[float, float]
) -> np.ndarray:
    """eq. (sw-InterAg) with eq. (3)-(4): α·#{pairs in [a, b]} − β·#{pairs in [c, d]}, closed ranges.

    xy: [E, N, 2] → [E].
    """
    d = pair_distances(xy)
    in_prop = (d >= prop_range[0]) & (d <= prop_range[1])
    in_coll = (d >= coll_range[0]) & (d <= coll_range[1])
    return alpha * in_prop.sum(axis=1) - beta * in_coll.sum(axis=1)


def sw_reward(signed_distance: np.ndarray, xy: np.ndarray, cfg: SWRewardConfig) -> np.ndarray:
    """SW-MARL shared reward r = Σ_a Reward(a) + Inter_Agent_Reward, the same r for every agent (SPEC §3).

    signed_distance: [E, N], xy: [E, N, 2] → [E, N] (each row constant).
    """
    per_agent = sw_region_attraction(signed_distance, cfg.r1, cfg.r2)
    r = per_agent.sum(axis=1) + sw_inter_agent(xy, cfg.alpha, cfg.beta, cfg.prop_range, cfg.coll_range)
    return np.repeat(r[:, None], xy.shape[1], axis=1)


def cover_reward(terms: CoverTerms, r1: float, r2: float, r3: float) -> np.ndarray:
    """eq. (5): R1 + A(Cov) inside; R2 + A(Cov ∩ Reg) overlapping; −R3 − dist(Reg, Cov) disjoint. [E, N]."""
    partial = ~terms.inside & ~terms.disjoint
    return np.where(terms.inside, r1 + terms.area, np.where(partial, r2 + terms.area, -r3 - terms.distance))


def overall_reward(cover: np.ndarray, union_term: np.ndarray, c1: float, c2: float) -> np.ndarray:
    """eq. (6): c1·Cover_Reward(a) + c2·Overall_Area_Coverage.

    cover: [E, N]; union_term: [E] (the paper: A((∪ Cov) ∩ Reg), shared by all agents) or [E, N] (a per-agent
    credit such as the marginal contribution) → [E, N].
    """
    if union_term.ndim == 1:
        union_term = union_term[:, None]
    return c1 * cover + c2 * union_term


def lloyd_cells(pos: np.ndarray, alive: np.ndarray | None, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Each of the water's P points q's nearest buoy in service (its Voronoi cell) and its squared distance to it:
    pos [E, N, 2], alive [E, N] (None: all), points [P, 2] → (cell [E, P] the flat index e·N + i, d² [E, P])."""
    e, n = pos.shape[:2]
    d2 = np.square(points[None, :, None, :] - pos[:, None, :, :]).sum(-1)  # [E, P, N]
    if alive is not None:
        d2 = np.where(alive[:, None, :], d2, np.inf)
    near = d2.argmin(axis=-1)  # [E, P]: each point's buoy
    cost = np.take_along_axis(d2, near[..., None], axis=-1)[..., 0]
    return np.arange(e)[:, None] * n + near, cost


def lloyd_potential(pos: np.ndarray, alive: np.ndarray | None, points: np.ndarray, radius: float) -> np.ndarray:
    """Φ_i = −(1/(P R²)) Σ_{q ∈ V_i} |q − p_i|²: Lloyd's locational cost of buoy i's Voronoi cell V_i over the
    water's P points q, negated, in units of R² per point. Σ_i Φ_i is minus the mean squared distance from the
    water to its nearest buoy, the cost Lloyd's algorithm descends, and ∂Φ_i/∂p_i is its gradient in p_i: a buoy
    is paid for moving toward its cell's centroid, as the front buoy of a channel whose next buoy is more than 2R
    behind is by nothing in eq. (5)-(6). pos [E, N, 2], alive [E, N] (None: all; a lost buoy has no cell and
    Φ = 0), points [P, 2] → [E, N]."""
    e, n = pos.shape[:2]
    cell, cost = lloyd_cells(pos, alive, points)
    total = np.bincount(cell.ravel(), weights=cost.ravel(), minlength=e * n).reshape(e, n)
    return -total / (len(points) * radius**2)


def lloyd_pull(pos: np.ndarray, alive: np.ndarray | None, points: np.ndarray, radius: float) -> np.ndarray:
    """∂(Σ_j Φ_j)/∂p_i = ∂Φ_i/∂p_i = (2/(P R²)) Σ_{q ∈ V_i} (q − p_i) (``lloyd_potential``; the neighbours' cells
    do not change the sum to first order, their shared edges being equidistant): how much buoy i's own move
    takes off the fleet's locational cost, per metre, toward its cell's centroid and weighted by the cell's water.
    Paid as pull · Δp_i, it is the first order of the difference credit of Lloyd's cost: what the buoy's move alone
    did, not its neighbours'. Same arguments as ``lloyd_potential`` → [E, N, 2] in 1/m (a lost buoy: 0)."""
    e, n = pos.shape[:2]
    cell, _ = lloyd_cells(pos, alive, points)
    flat = cell.ravel()
    mass = np.bincount(flat, minlength=e * n).reshape(e, n)
    first = np.stack([np.bincount(flat, weights=np.broadcast_to(points[:, k], cell.shape).ravel(),
                                  minlength=e * n).reshape(e, n) for k in range(2)], axis=-1)  # Σ q over each cell
    return 2.0 * (first - mass[..., None] * pos) / (len(points) * radius**2)


def neighbourhood_mean(reward: np.ndarray, pos: np.ndarray, reach: float, alive: np.ndarray | None) -> np.ndarray:
    """Each buoy's mean of ``reward`` [E, N] over itself and the other buoys in service within ``reach`` of it (the
    buoys it hears) → [E, N]. A buoy alone, or lost (``alive`` False), keeps its own; a lost one is nobody's
    neighbour."""
    d2 = ((pos[:, :, None, :] - pos[:, None, :, :]) ** 2).sum(-1)  # [E, N, N]
    near = d2 <= reach * reach
    if alive is not None:
        near &= alive[:, None, :] & alive[:, :, None]
    near |= np.eye(pos.shape[1], dtype=bool)
    return (near * reward[:, None, :]).sum(-1) / near.sum(-1)


def neighbourhood_share(reward: np.ndarray, pos: np.ndarray, reach: float, alive: np.ndarray | None,
                        share: float) -> np.ndarray:
    """(1 − ``share``) × each buoy's own ``reward`` [E, N] + ``share`` × its ``neighbourhood_mean``: a buoy shares
    in what the buoys it hears are paid, so making room for them pays. → [E, N]."""
    return (1.0 - share) * reward + share * neighbourhood_mean(reward, pos, reach, alive)


def cr_reward(terms: CoverTerms, union_term: np.ndarray, cfg: CRRewardConfig, xy: np.ndarray) -> np.ndarray:
    """CR-MARL per-agent reward Overall_Reward(a) (SPEC §4): eq. (6) over eq. (5). → [E, N].

    ``xy`` [E, N, 2] are the buoys' positions: eq. (5)-(6) read them only through ``terms`` and ``union_term``; a
    term of the buoys' neighbourhood (the paper's future work, ``CONTRIBUTING.md``) reads them here."""
    return overall_reward(cover_reward(terms, cfg.r1, cfg.r2, cfg.r3), union_term, cfg.c1, cfg.c2)
