"""The clairvoyant planner: the best layout, sailed to. A controller is read against it beside the layout.

The best layout (``best_layout``) is a limit with no physics and no horizon: its buoys are placed, not sailed. The
planner knows the map and every buoy and sails them there under the same physics, wall and drift as every other
controller:

1. the best layout of the buoys in service (``best_layout_once``: candidates in the water only);
2. each buoy assigned one place of it, the assignment that minimises the total distance sailed through the water
   (the Hungarian method, ``scipy.optimize.linear_sum_assignment``, on geodesic distances: one Dijkstra from each
   place over the water graph of ``geodesic``);
3. each buoy driven along its shortest path through the water toward its place with Lloyd's law,
   a = gain·d·u − damping·v scaled into the action box along its direction (d the distance left to sail, u toward
   the path's point ``lookahead`` metres ahead), which at Lloyd's tuned gains is top speed until the last few
   centimetres.

It plans again whenever the fleet in service changes (a loss): the layout and assignment of the buoys left. It
is a heuristic, not an optimum and not a limit at time T (the layout is the best found, the assignment minimises
the sum, not the time of the last arrival, and a buoy covers nothing new on its way: on the suite's generated test
lakes the general policy covers 1.12 times what the planner covers by T, `docs/GENERAL.md`), and it is the expert
a learned controller imitates (LPAC's clairvoyant CVT, here with the layout that maximises coverage rather than
the centroidal one).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.optimize import linear_sum_assignment
from scipy.sparse.csgraph import dijkstra

from replicate.compare.baselines import Policy
from replicate.compare.best_layout import best_layout_once
from replicate.core.schema import to_dict
from replicate.core.studies import LloydConfig
from replicate.world.env import CoverageEnv
from replicate.world.geodesic import WaterGraph, distinct_nearest, water_graph

UNREACHABLE = 1e9  # the cost of a place a buoy cannot sail to (another basin of the water graph)
MAX_GRAPH_POINTS = 200_000  # the water graph's points at most (the suite's lakes hold a few thousand at 0.1 m)


@dataclass(frozen=True)
class Places:
    """A layout of M places and the ways to it: ``xy`` [M, 2], ``point`` [M] (each place's water point),
    ``distance`` [M, C] (m, from every water point to the place through the water) and ``predecessor`` [M, C] (the
    next water point on the way to the place; −9999 at the place's own point)."""

    xy: np.ndarray
    point: np.ndarray
    distance: np.ndarray
    predecessor: np.ndarray


def places(g: WaterGraph, layout: np.ndarray) -> Places:
    """The ways through the water graph ``g`` to every place of ``layout`` [M, 2]."""
    point = distinct_nearest(g, layout)
    distance, predecessor = dijkstra(g.graph, directed=False, indices=point, return_predecessors=True)
    return Places(layout, point, distance, predecessor)


def assign(p: Places, start_points: np.ndarray) -> np.ndarray:
    """The place of each of M buoys at water points ``start_points`` [M]: the assignment of least total distance
    through the water (Hungarian method) → [M] place indices."""
    cost = p.distance[:, start_points].T  # [buoy, place]
    buoys, place = linear_sum_assignment(np.where(np.isfinite(cost), cost, UNREACHABLE))
    out = np.empty(len(start_points), int)
    out[buoys] = place
    return out


def waypoints(g: WaterGraph, p: Places, goal: np.ndarray, xy: np.ndarray,
              lookahead: float) -> tuple[np.ndarray, np.ndarray]:
    """For buoys at xy [K, 2] bound for places ``goal`` [K]: (the point of each one's shortest path ``lookahead``
    metres ahead, or the place itself when nearer [K, 2]; the distance left to sail [K])."""
    here = g.tree.query(xy)[1]
    left = p.distance[goal, here]
    at = here.copy()
    for _ in range(int(np.ceil(lookahead / g.spacing)) + 1):  # walk the path while within the lookahead
        nxt = p.predecessor[goal, at]
        step = (nxt >= 0) & (left - p.distance[goal, np.maximum(nxt, 0)] <= lookahead)
        if not step.any():
            break
        at = np.where(step, nxt, at)
    final = (at == p.point[goal]) | ~np.isfinite(left)  # the place's own point: head for the place itself
    waypoint = np.where(final[:, None], p.xy[goal], g.points[at])
    distance = np.where(final, np.linalg.norm(p.xy[goal] - xy, axis=1), left)
    return waypoint, distance


def in_the_box(action: np.ndarray) -> np.ndarray:
    """Actions [..., 2] scaled into the action box [−1, 1]² along their own direction: clipping each component
    alone turns a long action toward the diagonal, which on a large lake sent buoys into the shore beside their
    path (on Lake Karaguz at 25 m radius every buoy of the plan stalled on the shore after 25 control periods)."""
    return action / np.maximum(np.abs(action).max(axis=-1, keepdims=True), 1.0)


def planner_teacher(params, gains: dict | None) -> Policy | None:
    """The planner as the general training's teacher where ``general.learner.imitation`` asks for one (None
    otherwise): steering with the tuned
    Lloyd gains of ``gains`` (``tuning.general_baselines``' result) where given, else the hand-set
    ``evaluate.lloyd``, on the evaluation's water graph (``evaluate.geodesic``), to the best layout of one search
    start: it needs a layout for every training world and every fleet a loss leaves, ~6 s each with all five starts.
    The first 704 episodes of a seed (one pass over the worlds) took 141.7 CPU-s with all five, 58.1 with one,
    33.0 without a teacher (``replicate train-general --episodes 704``, on a busy machine)."""
    if params.general.learner.imitation == "none":
        return None
    ev = params.evaluate
    lloyd = ev.lloyd if not gains else LloydConfig(**gains["lloyd_tuned"]["gains"],
                                                   converged_steps=ev.lloyd.converged_steps)
    return clairvoyant_planner(lloyd, ev.geodesic.spacing, ev.geodesic.lookahead, quick=True)


def teacher_identity(params, gains: dict | None) -> dict | None:
    """What makes ``planner_teacher`` this teacher, for a run's identity (``learn.runs.general_identity``): the
    Lloyd gains it steers with (tuned, or the hand-set ``evaluate.lloyd``) and its water graph
    (``evaluate.geodesic``); None without imitation. A run taught with other gains is another run."""
    if params.general.learner.imitation == "none":
        return None
    return {"lloyd_gains": gains["lloyd_tuned"]["gains"] if gains else to_dict(params.evaluate.lloyd),
            "geodesic": to_dict(params.evaluate.geodesic)}


def graph_spacing(water, spacing: float) -> float:
    """The water graph's spacing: ``spacing``, coarser on a lake whose graph would hold more than
    ``MAX_GRAPH_POINTS`` (a real lake at a 25 m radius is hundreds of radii across)."""
    return max(spacing, float(np.sqrt(water.area / MAX_GRAPH_POINTS)))


def clairvoyant_planner(cfg: LloydConfig, spacing: float, lookahead: float, quick: bool = False,
                        near_fleet: bool = False) -> Policy:
    """The planner (module docstring) steering with Lloyd's law at ``cfg``'s gains, on the water graph of
    ``spacing`` metres (``evaluate.geodesic``; ``graph_spacing``); ``quick``: to the best layout of one search
    start (``best_layout``'s ``quick``); ``near_fleet``: to the best layout whose greedy placement breaks its ties
    toward the fleet's mean position when it plans (a mission on a lake far larger than the fleet's reach, where
    every layout of non-overlapping discs ties and the first one found may lie across the lake)."""
    state: dict = {}

    def layout_for(env: CoverageEnv, m: int) -> Places:
        key = (m, state.get("toward"))
        if key not in state["places"]:
            c = env.coverage
            xy, _ = best_layout_once(env.region.polygon, m, c.radius, c.edges, quick, state.get("toward"))
            state["places"][key] = places(state["graph"], xy)
        return state["places"][key]

    def policy(env: CoverageEnv) -> np.ndarray:
        if state.get("region") is not env.region:
            graph = water_graph(env.region.polygon, graph_spacing(env.region.polygon, spacing))
            state.update(region=env.region, graph=graph, places={})
        g = state["graph"]
        alive = np.ones(env.pos.shape[:2], bool) if env.alive is None else env.alive
        if env.t == 0 or state.get("alive") is None or not np.array_equal(state["alive"], alive):
            if near_fleet:  # where the fleet in service is now
                if len(alive) > 1:
                    raise ValueError("near_fleet plans one environment's mission (its layout gathers toward that "
                                     f"fleet), got {len(alive)} environments")
                state["toward"] = tuple(np.round(env.pos[alive].mean(axis=0), 6).tolist())
            goal = np.full(alive.shape, -1)  # a new episode or a loss: every environment plans again
            for e, live in enumerate(alive):
                p = layout_for(env, int(live.sum()))
                goal[e, live] = assign(p, g.tree.query(env.pos[e, live])[1])
            state.update(alive=alive.copy(), goal=goal)
        action = np.zeros_like(env.pos)
        for m in np.unique(alive.sum(axis=1)):  # environments with the same fleet in service share one layout
            rows = alive & (alive.sum(axis=1) == m)[:, None]
            xy = env.pos[rows]
            waypoint, distance = waypoints(g, layout_for(env, int(m)), state["goal"][rows], xy, lookahead)
            heading = waypoint - xy
            heading /= np.maximum(np.linalg.norm(heading, axis=1, keepdims=True), 1e-9)
            action[rows] = cfg.gain * distance[:, None] * heading - cfg.damping * env.vel[rows]
        return in_the_box(action)

    return policy
