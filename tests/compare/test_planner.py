"""The clairvoyant planner: its assignment by distances through the water, and a fleet it sails to the best layout."""

from __future__ import annotations

import numpy as np
import pytest
from shapely.geometry import box

from replicate.compare.best_layout import best_layout_once
from replicate.compare.evaluate import rollout
from replicate.compare.planner import assign, clairvoyant_planner, places, waypoints
from replicate.core.studies import LloydConfig, StartsConfig
from replicate.world.coverage import coverage_fraction
from replicate.world.env import CoverageEnv
from replicate.world.geodesic import water_graph

GAINS = LloydConfig(gain=55.4, damping=0.098, converged_steps=0)  # the tuned clairvoyant Lloyd's order of gains


def u_lake():
    """A 3 × 3 m lake whose middle is land from the bottom up to y = 2: two 1 m arms joined along the top."""
    return box(0, 0, 3, 3).difference(box(1, 0, 2, 2))


def test_the_assignment_minimises_the_distance_sailed_not_flown():
    """Two buoys at the bottoms of the two arms' inner sides, two places: the right arm's bottom and the left arm's
    top. Flown straight, each buoy is nearer the place across the land (1.7 m against 2.4 m); sailed around the
    land's tip, that place is 4.5 m away, so each goes up or down its own arm."""
    g = water_graph(u_lake(), 0.1)
    p = places(g, np.array([[2.5, 0.3], [0.5, 2.7]]))
    buoys = np.array([[0.8, 0.3], [2.2, 2.7]])
    goal = assign(p, g.tree.query(buoys)[1])
    assert goal.tolist() == [1, 0]
    cost = p.distance[:, g.tree.query(buoys)[1]].T
    assert cost[0, 0] > 4.4 and cost[0, 1] == pytest.approx(2.4, abs=0.15)


def test_a_waypoint_leads_around_the_land():
    """A buoy at the bottom of the left arm bound for the right arm's bottom heads up its own arm (its waypoint
    is above it, not across the land), and the distance left is the one sailed."""
    g = water_graph(u_lake(), 0.1)
    p = places(g, np.array([[2.5, 0.3]]))
    waypoint, left = waypoints(g, p, np.array([0]), np.array([[0.5, 0.3]]), lookahead=0.3)
    assert waypoint[0, 1] > 0.45 and abs(waypoint[0, 0] - 0.5) < 0.2
    assert left[0] > 4.4  # around the land's tip (1, 2)-(2, 2): 4.55 m sailed, 2 m flown
    near, left = waypoints(g, p, np.array([0]), np.array([[2.45, 0.35]]), lookahead=0.3)
    np.testing.assert_allclose(near[0], [2.5, 0.3])  # within reach of its place: the place itself
    assert left[0] == pytest.approx(np.hypot(0.05, 0.05))


def test_it_sails_the_fleet_to_the_best_layout(params, regions):
    """From the corner patch, 9 buoys on the square reach within 1 % of the best layout's coverage by T, and after
    three buoys are lost at T/2 the six left plan again and reach within 1 % of the best layout of six."""
    square = regions["square"].polygon
    env = CoverageEnv(regions["square"], params.world, params.coverage, n_envs=2)
    c = params.coverage
    trace = rollout(env, clairvoyant_planner(GAINS, 0.1, 0.3), 50, seed=1)
    best = best_layout_once(square, 9, c.radius, c.edges)[1]
    assert coverage_fraction(square, trace["live"], c.radius, c.edges).min() > 0.99 * best
    trace = rollout(env, clairvoyant_planner(GAINS, 0.1, 0.3), 100, seed=1, starts=StartsConfig("corner", lose=3))
    best6 = best_layout_once(square, 6, c.radius, c.edges)[1]
    assert trace["live"].shape[1] == 6
    assert coverage_fraction(square, trace["live"], c.radius, c.edges).min() > 0.99 * best6


def test_the_general_training_learns_from_the_planner(params, tmp_path):
    """``general.learner.imitation``: without a teacher the trainer refuses to start; with the planner it trains
    (two small worlds, 48 episodes) and every transition it stores carries the planner's action for the state the
    learner was in, within the action box and zero for no buoy in service."""
    import dataclasses

    from replicate.compare.planner import planner_teacher, teacher_identity
    from replicate.learn.general_train import GeneralTrainer
    from replicate.learn.runs import general_identity

    from ..learn.test_general_train import tiny

    gc = tiny(params)
    gc = dataclasses.replace(gc, learner=dataclasses.replace(gc.learner, imitation="beside"))
    assert planner_teacher(params, None) is None  # params.yaml imitates nothing: no teacher
    taught = dataclasses.replace(params, general=gc)
    gains = {"lloyd_tuned": {"gains": {"gain": 30.0, "damping": 0.1}}}
    assert general_identity(params, 4, teacher_identity(params, gains)) == general_identity(params, 4)
    assert general_identity(taught, 4, teacher_identity(taught, gains)) != \
        general_identity(taught, 4, teacher_identity(taught, None))  # taught with other gains: another run
    with pytest.raises(ValueError, match="teacher"):
        GeneralTrainer(params, 4, tmp_path / "none", progress=False, config=gc)
    trainer = GeneralTrainer(params, 4, tmp_path / "taught", progress=False, config=gc,
                             teacher=planner_teacher(dataclasses.replace(params, general=gc), None))
    summary = trainer.run()
    assert summary["status"] == "finished"
    memory = trainer.loop.memories[0]
    expert, live = memory.data["expert"][:memory.size], memory.data["live"][:memory.size]
    assert np.abs(expert).max() <= 1.0 and np.abs(expert[live]).max() > 0.5  # the planner steers hard
    assert not expert[~live].any()


def test_imitation_before_stops_asking_the_teacher(params, tmp_path):
    """``imitation: before`` with ``imitation_until`` 0.5: the first half of the batches carry the planner's labels,
    the second half zeros (the teacher is asked no more), and the actor-critic alone trains the actor at the end."""
    import dataclasses

    from replicate.compare.planner import planner_teacher
    from replicate.learn.general_train import GeneralTrainer

    from ..learn.test_general_train import tiny

    gc = tiny(params)
    gc = dataclasses.replace(gc, learner=dataclasses.replace(gc.learner, imitation="before", imitation_until=0.5))
    trainer = GeneralTrainer(params, 4, tmp_path / "before", progress=False, config=gc,
                             teacher=planner_teacher(dataclasses.replace(params, general=gc), None))
    trainer.run()
    memory = trainer.loop.memories[0]
    assert memory.size < memory.capacity  # no row overwritten: the rows are in the order they were played
    expert, live = memory.data["expert"][:memory.size], memory.data["live"][:memory.size]
    labelled = np.abs(expert).sum(-1).any(-1)  # [rows]: a batch with a label for a buoy
    half = memory.size // 2
    assert labelled[:half][live[:half].any(-1)].mean() > 0.9 and not labelled[half:].any()
    assert trainer.agent.imitation == "none" and trainer.teacher is None


def test_a_long_action_keeps_its_direction():
    """Scaled into the box along its direction, not clipped per component: (300, −100) becomes (1, −1/3)."""
    from replicate.compare.planner import in_the_box

    np.testing.assert_allclose(in_the_box(np.array([[300.0, -100.0], [0.5, -0.2]])), [[1.0, -1 / 3], [0.5, -0.2]])
