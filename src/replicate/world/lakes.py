"""A seeded generator of lake-like regions, to train a policy across worlds and to test it on lakes it never saw.

A lake is a smooth blob (a radius with a few random harmonics), with arms (buffered random walks from its
shore outwards) and islands (small blobs cut out well inside), scaled so that N buoys' coverage polygons add up to
``ratio`` of its area: N·A(Cov)/A(Reg) from about 0.5 (more water than the fleet can cover) to 1.2 (more fleet
than water). Every draw comes from the ``numpy.random.Generator`` of the lake's seed, so a seed is a lake.

``training`` is the training set, ``yardstick`` the design lakes on which two versions of a training are compared,
``test_stream`` the evaluation suite's test lakes and ``held_out`` the lakes the suite read while the general
training was designed; each comes from a seed stream of its own (``TRAINING_ENTROPY``, ``YARDSTICK_ENTROPY``,
``TEST_ENTROPY``, ``HELD_OUT_ENTROPY``), so no test lake is trained on or chosen on.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import shapely
from shapely import affinity
from shapely.geometry import LineString, Polygon
from shapely.geometry.polygon import orient

from replicate.world.regions import Region

HELD_OUT_ENTROPY = 20_261_018  # the held-out lakes' seed stream (read while the general training was designed)
TEST_ENTROPY = 58_302_911  # the test lakes' seed stream: drawn after every choice, read by the report alone
YARDSTICK_ENTROPY = 41_170_093  # the yardstick's seed stream: choices between trainings are made here
TRAINING_ENTROPY = 7_310_442  # the training lakes' seed stream: the same lakes for every seed of a training
VERTICES = 96  # of a blob's outline


@dataclass(frozen=True)
class LakeSpec:
    """What a generated lake is made of. ``ratio`` is N·A(Cov)/A(Reg) for ``n_agents`` buoys."""

    seed: int
    n_agents: int
    ratio: float
    arms: int
    islands: int


def draw_spec(rng: np.random.Generator, n_range=(5, 30), ratio_range=(0.5, 1.2), max_arms: int = 3,
              max_islands: int = 2) -> LakeSpec:
    """A random lake's recipe: N, the coverage ratio, arms and islands, and a seed for its shape."""
    return LakeSpec(seed=int(rng.integers(2**31)), n_agents=int(rng.integers(n_range[0], n_range[1] + 1)),
                    ratio=float(rng.uniform(*ratio_range)), arms=int(rng.integers(0, max_arms + 1)),
                    islands=int(rng.integers(0, max_islands + 1)))


def blob(rng: np.random.Generator, radius: float, center=(0.0, 0.0), harmonics: int = 5,
         roughness: float = 0.35) -> Polygon:
    """A smooth star-shaped outline: r(θ) = radius·(1 + Σ_k a_k cos(kθ + φ_k)), k = 2..harmonics, the a_k shrinking
    as 1/k and the sum kept above −0.6, so r > 0.4·radius."""
    theta = np.linspace(0, 2 * np.pi, VERTICES, endpoint=False)
    k = np.arange(2, harmonics + 1)
    amp = rng.uniform(0, roughness, len(k)) / k
    phase = rng.uniform(0, 2 * np.pi, len(k))
    wobble = (amp[:, None] * np.cos(k[:, None] * theta + phase[:, None])).sum(axis=0)
    r = radius * (1 + np.clip(wobble, -0.6, None))
    return Polygon(np.stack([center[0] + r * np.cos(theta), center[1] + r * np.sin(theta)], axis=1))


def arm(rng: np.random.Generator, body: Polygon, size: float) -> Polygon:
    """A bay reaching out of ``body``: a random walk of 3-5 legs from a point of its shore, heading outwards
    with turns of up to 40°, 1-2.5 × ``size`` long, buffered to 0.5-0.9 × ``size`` wide (round ends)."""
    c = np.asarray(body.representative_point().coords[0])  # inside the water, so the ray meets its shore
    heading = rng.uniform(0, 2 * np.pi)
    direction = np.array([np.cos(heading), np.sin(heading)])
    crossings = shapely.get_coordinates(LineString([c, c + 100 * size * direction]).intersection(body.exterior))
    shore = crossings[np.argmax(crossings @ direction)]  # the outermost crossing along the heading
    start = shore - 0.2 * size * direction
    legs = int(rng.integers(3, 6))
    length = rng.uniform(1.0, 2.5) * size / legs
    points = [start]
    for _ in range(legs):
        heading += rng.uniform(-np.radians(40), np.radians(40))
        points.append(points[-1] + length * np.array([np.cos(heading), np.sin(heading)]))
    return LineString(points).buffer(rng.uniform(0.25, 0.45) * size, quad_segs=8)


def island(rng: np.random.Generator, water: Polygon, size: float, margin: float) -> Polygon | None:
    """A small blob (0.08-0.2 × ``size``) at a random point at least its radius + ``margin`` inside the shore;
    None if 50 tries find no room."""
    radius = rng.uniform(0.08, 0.2) * size
    room = water.buffer(-(radius + margin))
    if room.is_empty:
        return None
    minx, miny, maxx, maxy = room.bounds
    for _ in range(50):
        p = rng.uniform((minx, miny), (maxx, maxy))
        if room.contains(shapely.Point(p)):
            return blob(rng, radius, center=p, harmonics=3, roughness=0.3)
    return None


def largest(geom) -> Polygon:
    """The largest polygon of a (multi)polygon, made valid."""
    geom = shapely.make_valid(geom)
    parts = [g for g in getattr(geom, "geoms", [geom]) if isinstance(g, Polygon)]
    return max(parts, key=lambda g: g.area)


def generate(spec: LakeSpec, coverage_area: float, margin: float = 0.6) -> Polygon:
    """The lake of ``spec``: its area N·``coverage_area``/ratio, the lower-left corner of its box at the origin.
    Islands stay ``margin`` (scaled lake metres) and more inside the shore, so the lake stays one water."""
    rng = np.random.default_rng(spec.seed)
    area = spec.n_agents * coverage_area / spec.ratio
    size = 1.0
    body = blob(rng, size)
    for _ in range(spec.arms):
        body = largest(body.union(arm(rng, body, size)))
    scale = np.sqrt(area / body.area)
    body = affinity.scale(body, scale, scale, origin=(0, 0))
    for _ in range(spec.islands):
        hole = island(rng, body, size * scale, margin)
        if hole is not None:
            body = largest(body.difference(hole))
    body = affinity.scale(body, np.sqrt(area / body.area), np.sqrt(area / body.area), origin=(0, 0))
    minx, miny = body.bounds[:2]
    return orient(affinity.translate(body, -minx, -miny), sign=1.0)


def lake_name(spec: LakeSpec) -> str:
    """A generated lake's name: its recipe."""
    return f"lake-s{spec.seed}-n{spec.n_agents}-a{spec.arms}-i{spec.islands}"


def lake_region(spec: LakeSpec, coverage_area: float) -> Region:
    """A generated lake as a ``Region`` named by its recipe."""
    return Region(lake_name(spec), generate(spec, coverage_area))


def held_out(count: int = 20, **draw) -> list[LakeSpec]:
    """The lakes the evaluation suite read while the general training was designed: ``count`` recipes from the
    held-out stream, the same every time (no longer in the suite: its test lakes are ``test_stream``'s)."""
    rng = np.random.default_rng(np.random.SeedSequence(HELD_OUT_ENTROPY))
    return [draw_spec(rng, **draw) for _ in range(count)]


def test_stream(count: int = 20, **draw) -> list[LakeSpec]:
    """The evaluation suite's test lakes: ``count`` recipes from the test stream, which no choice of the general
    training, its baselines' gains or the report's rules has read (the held-out lakes were, while the training
    was designed)."""
    rng = np.random.default_rng(np.random.SeedSequence(TEST_ENTROPY))
    return [draw_spec(rng, **draw) for _ in range(count)]


def yardstick(count: int = 10, **draw) -> list[LakeSpec]:
    """The yardstick's lakes (``compare.yardstick``): ``count`` recipes from a stream of their own, on which two
    versions of a training are compared before one is kept, so that the choice never reads a lake the report
    judges it on (the test lakes) or one it trained on."""
    rng = np.random.default_rng(np.random.SeedSequence(YARDSTICK_ENTROPY))
    return [draw_spec(rng, **draw) for _ in range(count)]


def training(count: int, **draw) -> list[LakeSpec]:
    """The training lakes: ``count`` recipes from the training stream. Every seed of a training sees the same
    lakes (a fixed training distribution, whose coverage tables are built once and cached); the seeds differ in
    the networks' weights, the noise, the events and the sampling."""
    rng = np.random.default_rng(np.random.SeedSequence(TRAINING_ENTROPY))
    return [draw_spec(rng, **draw) for _ in range(count)]
