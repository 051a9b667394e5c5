"""The generator of lake-like regions (``replicate.world.lakes``): seeded, lake-like, usable by the walled world."""

import dataclasses

import numpy as np
import shapely

from replicate.world import lakes
from replicate.world.env import CoverageEnv
from replicate.world.shore import distance_outside

COVERAGE = 0.7797  # A(Cov) of the 30-gon of radius 0.5


def test_a_seed_is_a_lake():
    spec = lakes.LakeSpec(seed=11, n_agents=12, ratio=0.8, arms=2, islands=1)
    a, b = lakes.generate(spec, COVERAGE), lakes.generate(spec, COVERAGE)
    assert shapely.to_wkb(a) == shapely.to_wkb(b)
    other = lakes.generate(dataclasses.replace(spec, seed=12), COVERAGE)
    assert not a.equals(other)


def test_the_held_out_lakes_are_fixed_and_lake_like():
    specs = lakes.held_out(20)
    assert specs == lakes.held_out(20) and len({s.seed for s in specs}) == 20
    shapes = [lakes.generate(s, COVERAGE) for s in specs]
    for spec, poly in zip(specs, shapes):
        assert poly.is_valid and isinstance(poly, shapely.Polygon)
        assert abs(spec.n_agents * COVERAGE / poly.area - spec.ratio) < 1e-9  # N·A(Cov)/A(Reg) as drawn
        assert 0.5 <= spec.ratio <= 1.2 and 5 <= spec.n_agents <= 30
        assert len(poly.interiors) <= spec.islands
        assert poly.bounds[0] == 0.0 and poly.bounds[1] == 0.0
    concave = [poly.area / poly.convex_hull.area for spec, poly in zip(specs, shapes) if spec.arms]
    assert concave and max(concave) < 0.95, "a lake with arms is far from convex"
    assert sum(len(p.interiors) for p in shapes) >= 5, "some lakes have islands"


def test_many_recipes_make_valid_lakes():
    """200 training recipes, arms crossing arms included: every one a valid single polygon of its area."""
    for spec in lakes.training(200):
        poly = lakes.generate(spec, COVERAGE)
        assert poly.is_valid and isinstance(poly, shapely.Polygon) and poly.area > 0
        assert abs(spec.n_agents * COVERAGE / poly.area - spec.ratio) < 1e-9


def test_training_lakes_never_meet_the_held_out_lakes():
    held = {s.seed for s in lakes.held_out(20)}
    assert not held & {s.seed for s in lakes.training(500)}
    assert lakes.training(5) == lakes.training(500)[:5], "the same stream for every training"


def test_the_test_lakes_meet_no_other_stream():
    """The suite's test lakes (``lakes.test_stream``) are none of the training, design or held-out lakes."""
    test = {s.seed for s in lakes.test_stream(50)}
    assert len(test) == 50 and lakes.test_stream(3) == lakes.test_stream(50)[:3]
    for other in (lakes.training(500), lakes.yardstick(50), lakes.held_out(50)):
        assert not test & {s.seed for s in other}


def test_design_lakes_are_neither_trained_on_nor_reported():
    """The lakes where versions of a training are compared (``compare.yardstick``) come from a stream of their own."""
    chosen_on = {s.seed for s in lakes.yardstick(50)}
    assert len(chosen_on) == 50 and lakes.yardstick(3) == lakes.yardstick(50)[:3]
    assert not chosen_on & {s.seed for s in lakes.held_out(50)}
    assert not chosen_on & {s.seed for s in lakes.training(500)}


def test_buoys_behind_the_wall_stay_in_a_generated_lake(params):
    """The three smallest held-out lakes (each new lake builds its coverage tables once) take the start patch,
    and buoys pushed flat out stay in their water."""
    for spec in sorted(lakes.held_out(20), key=lambda s: s.n_agents / s.ratio)[:3]:
        region = lakes.lake_region(spec, COVERAGE)
        world = dataclasses.replace(params.world, n_agents=spec.n_agents, episode_length=40)
        env = CoverageEnv(region, world, params.coverage, n_envs=2, wall=True, seed=spec.seed % 1000)
        env.reset(start="random")
        rng = np.random.default_rng(0)
        heading = rng.uniform(-1, 1, (2, spec.n_agents, 2))
        for _ in range(40):
            env.step(heading)
            assert distance_outside(region.polygon, env.pos).max() == 0.0
