"""The compass symmetries (``replicate.learn.symmetry``): turning or mirroring a lake with its buoys permutes their
observations as the group says, and the symmetric actor turns its pushes with them."""

import dataclasses

import numpy as np
import pytest
import torch
from shapely import affinity
from shapely.geometry import box

from replicate.core.params import load_params
from replicate.core.schema import ConfigError
from replicate.learn.shared_maddpg import SharedActor
from replicate.learn.symmetry import _signed_permutation, d4
from replicate.world import local_map, sensors

from ..conftest import ROOT
from ..world.test_sensors import points_inside

COLUMNS = sensors.columns(4, 8, uncovered=True)
RASTER_COLUMNS = sensors.columns(4, 8, uncovered=True, raster=5)
CENTROID_COLUMNS = sensors.columns(4, 8, centroid=True)


def turned(g: np.ndarray, obs: np.ndarray, columns: list[str] = COLUMNS) -> np.ndarray:
    """g·o for observations [..., D] with ``columns``."""
    index, sign = _signed_permutation(columns, g)
    return obs[..., index] * sign


def test_d4_is_a_group_of_eight_orthogonal_maps():
    group = d4()
    assert len({g.tobytes() for g in group}) == 8
    for g in group:
        np.testing.assert_array_equal(g @ g.T, np.eye(2))
        assert any((g @ h == np.eye(2)).all() for h in group), "its inverse is in the group"


@pytest.mark.parametrize("lake", ["bedok", "island"])
def test_a_turned_lake_turns_the_observation(regions, lake):
    """Every sensor (velocity, neighbours and their masks, shore rays, uncovered water, the local raster) of buoys
    in a lake turned or mirrored by g reads g·o, where o is what they read before: the group acts on the columns
    as claimed."""
    water = regions["bedok"].polygon if lake == "bedok" else box(0, 0, 3, 3).difference(box(1.2, 1.2, 1.8, 1.8))
    rng = np.random.default_rng(3)
    pos = points_inside(water, 3 * 10, rng).reshape(3, 10, 2)
    vel = rng.normal(size=(3, 10, 2))
    alive = rng.uniform(size=(3, 10)) > 0.2
    directions = sensors.ray_directions(8)
    wet = np.array([c.startswith("raster_water_") for c in RASTER_COLUMNS])

    def observe(poly, p, v):
        raster = (local_map.WaterMask.for_raster(poly, 5, 2.0), local_map.raster_offsets(5, 2.0))
        return sensors.local_observation(p, v, sensors.shore_segments(poly), directions, 4, 1.5, 2.0, alive,
                                         (0.25, 0.5, 0.75), 0.5, raster)

    before = observe(water, pos, vel)
    assert before.shape[-1] == len(RASTER_COLUMNS) and 0 < before[..., wet].mean() < 1
    for g in d4():
        after = observe(affinity.affine_transform(water, [*g[0], *g[1], 0, 0]), pos @ g.T, vel @ g.T)
        np.testing.assert_allclose(after, turned(g, before, RASTER_COLUMNS), atol=1e-5)
    assert not np.allclose(turned(d4()[1], before, RASTER_COLUMNS), before), "a quarter turn changes the readings"


@pytest.mark.parametrize("lake", ["bedok", "island"])
def test_a_turned_lake_turns_the_local_centroid(regions, lake):
    """The local centroid's offset turns as a vector: read in a lake turned or mirrored by g, it is g times what it
    was, to within a third of its points' spacing (its water grid is the lake's, not turned with it: a point by the
    shore may read otherwise), and every other column exactly."""
    water = regions["bedok"].polygon if lake == "bedok" else box(0, 0, 3, 3).difference(box(1.2, 1.2, 1.8, 1.8))
    rng = np.random.default_rng(4)
    pos = points_inside(water, 3 * 10, rng).reshape(3, 10, 2)
    vel = rng.normal(size=(3, 10, 2))
    directions = sensors.ray_directions(8)

    def observe(poly, p, v):
        return sensors.local_observation(p, v, sensors.shore_segments(poly), directions, 4, 1.5, 2.0,
                                         centroid=local_map.LocalCentroid(poly, 2.0))

    before = observe(water, pos, vel)
    assert before.shape[-1] == len(CENTROID_COLUMNS) and np.abs(before[..., -2:]).max() > 0.3
    for g in d4():
        after = observe(affinity.affine_transform(water, [*g[0], *g[1], 0, 0]), pos @ g.T, vel @ g.T)
        expected = turned(g, before, CENTROID_COLUMNS)
        np.testing.assert_allclose(after[..., :-2], expected[..., :-2], atol=1e-5)
        np.testing.assert_allclose(after[..., -2:], expected[..., -2:], atol=2.0 / local_map.CENTROID_STEPS / 3)


@pytest.mark.parametrize("columns", [COLUMNS, RASTER_COLUMNS, CENTROID_COLUMNS], ids=["sensors", "raster", "centroid"])
def test_the_symmetric_actor_turns_its_pushes_with_the_world(columns):
    """μ̄(g·o) = g μ̄(o) for every g of D4 (after the tanh too), averaged over the group or run in each
    observation's canonical frame, with the local raster read through its CNN too; an ordinary actor does not."""
    obs = torch.randn(50, len(columns), generator=torch.Generator().manual_seed(0))
    for symmetry, equivariant in (("d4", True), ("d4_frame", True), ("none", False)):
        torch.manual_seed(1)
        actor = SharedActor(len(columns), 2, 32, symmetry, columns)
        with torch.no_grad():
            act = actor(obs)[0]
            errors = [(actor(torch.as_tensor(turned(g, obs.numpy(), columns)).float())[0]
                       - act @ torch.as_tensor(g.T).float()).abs().max().item() for g in d4()]
        assert (max(errors) < 1e-5) == equivariant, (symmetry, errors)


def test_a_symmetric_actor_exports_and_fine_tunes_from_its_file(params, tmp_path):
    """A d4 actor's file exports (TorchScript) to the same pushes, names its symmetry, and its weights load back
    into a d4 actor, as `replicate cover --finetune` does."""
    from replicate.core import artifacts
    from replicate.core.schema import to_dict
    from replicate.learn.policy import load_policy
    from replicate.toolkit.export import export_general
    from replicate.world.env import observation_columns

    columns = observation_columns("local", params.general.sensors)  # the sensors the file names, their columns
    actor = SharedActor(len(columns), 2, 16, "d4", columns)
    artifacts.torch_save(tmp_path / "actor.pt", {
        "format": artifacts.CHECKPOINT_FORMAT, "actor": actor.state_dict(), "observation": "local",
        "sensors": to_dict(params.general.sensors), "columns": columns, "hidden": 16,
        "symmetry": "d4", "selected_episode": 0, "seed": 0})
    meta = export_general(tmp_path / "actor.pt", tmp_path / "policy.pt")
    module, saved = load_policy(tmp_path / "policy.pt")
    assert meta["symmetry"] == saved["symmetry"] == "d4"
    obs = torch.randn(7, len(columns))
    with torch.no_grad():
        torch.testing.assert_close(module(obs), actor(obs)[0])
    again = SharedActor(len(columns), 2, 16, "d4", columns)
    again.load_state_dict(dict(module.state_dict()))  # the fine-tuning trainer's starting weights


def test_a_symmetric_run_has_its_own_identity(params):
    """A run of the plain actor keeps the identity it had before the option existed; a D4 run names it."""
    from replicate.learn.runs import general_identity

    def with_symmetry(value):
        return dataclasses.replace(params, general=dataclasses.replace(
            params.general, learner=dataclasses.replace(params.general.learner, symmetry=value)))

    assert "symmetry" not in general_identity(with_symmetry("none"), 10)["general"]["learner"]
    assert general_identity(with_symmetry("d4"), 10)["general"]["learner"]["symmetry"] == "d4"


@pytest.mark.parametrize("overrides, message", [
    ({"general.learner.symmetry": "c8"}, r"general.learner.symmetry: 'c8' is not one of \['none', 'd4', 'd4_frame'\]"),
    ({"general.learner.symmetry": "d4", "general.sensors.rays": 6}, "multiple of 4"),
])
def test_a_symmetry_the_sensors_cannot_carry_is_refused(overrides, message):
    with pytest.raises(ConfigError, match=message):
        load_params(ROOT / "params.yaml", overrides)


def test_the_canonical_frame_is_unique_on_the_observations_of_a_fleet(params, regions):
    """``d4_frame`` is equivariant where its frame's argmax is unique: on the observations of 9 buoys moving at
    random on the 9 × 1 m rectangle (corner and scattered starts, 8 episodes each; 7,200 observations) it ties on
    8, one in 900: a buoy on the centre line of the narrow channel that hears no one sees both shores alike, and
    the mirror across the line leaves its observation unchanged. The bound is twice that."""
    from replicate.learn.symmetry import CompassCanonical
    from replicate.world.env import observation_columns
    from replicate.world.scenario import general_evaluation_env, horizon

    columns = observation_columns("local", params.general.sensors)
    canonical = CompassCanonical(torch.nn.Identity(), columns, d4())
    region, rng = regions["rectangle"], np.random.default_rng(0)
    env, _ = general_evaluation_env(params, region, 9, 8, params.general.sensors, None)
    seen = ties = 0
    for start in ("corner", "random"):
        obs = env.reset(seed=1, start=start)
        for _ in range(horizon(params.general, region, params.world.region_area)):
            scores = (torch.as_tensor(obs, dtype=torch.float32).reshape(-1, len(columns)) @ canonical.score)
            top = scores.sort(dim=-1, descending=True).values
            ties += int(((top[:, 0] - top[:, 1]) <= 1e-6 * top[:, 0].abs().clamp_min(1e-6)).sum())
            seen += len(top)
            obs = env.step(rng.uniform(-1, 1, (8, 9, 2))).obs
    assert seen > 7000 and ties < seen / 450
