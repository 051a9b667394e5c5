"""Messages over hops (``replicate.learn.messages``): the actor hears exactly the buoys its sensors list, as many
hops as it is set to, turns with the world, ignores buoys out of service, and runs the same exported."""

import dataclasses

import numpy as np
import pytest
import torch

from replicate.core.schema import ConfigError
from replicate.core.sections import SensorsConfig, SharedLearnerConfig
from replicate.learn.general_train import GeneralTrainer
from replicate.learn.shared_maddpg import SharedActor
from replicate.learn.symmetry import _signed_permutation, d4
from replicate.world.env import observation_columns

SENSORS = SensorsConfig(neighbours=4, comm_range=2.0, rays=8, ray_range=2.0)
COLUMNS = observation_columns("local", SENSORS)
D = len(COLUMNS)


def actor(hops: int, symmetry: str = "d4_frame", seed: int = 0) -> SharedActor:
    torch.manual_seed(seed)
    return SharedActor.of(D, 2, SharedLearnerConfig(hidden=32, symmetry=symmetry, hops=hops), COLUMNS, SENSORS)


def fleet(n: int, seed: int = 0, fleets: int = 3):
    """Generic observations and positions of ``fleets`` fleets of ``n`` buoys within a few ranges of each other."""
    gen = torch.Generator().manual_seed(seed)
    return (torch.randn(fleets, n, D, generator=gen), 3.0 * torch.rand(fleets, n, 2, generator=gen),
            torch.ones(fleets, n, dtype=torch.bool))


@pytest.mark.parametrize("hops", [1, 3])
def test_the_actor_turns_its_pushes_with_the_world(hops):
    """μ(g·O, g·P) = g·μ(O, P) for the 8 turns and mirrors: every buoy's observation and every position turned."""
    net = actor(hops)
    obs, pos, live = fleet(7)
    with torch.no_grad():
        before = net.fleet(obs, pos, live)[0]
        for g in d4():
            index, sign = _signed_permutation(COLUMNS, g)
            g_t = torch.as_tensor(g, dtype=torch.float32)
            after = net.fleet(obs[..., index] * torch.as_tensor(sign, dtype=torch.float32), pos @ g_t.T, live)[0]
            torch.testing.assert_close(after, before @ g_t.T, atol=1e-5, rtol=0)


def test_any_order_and_the_buoys_out_of_service_neither_send_nor_act():
    net = actor(2)
    obs, pos, live = fleet(6)
    perm = torch.randperm(6, generator=torch.Generator().manual_seed(1))
    with torch.no_grad():
        a = net.fleet(obs, pos, live)[0]
        torch.testing.assert_close(net.fleet(obs[:, perm], pos[:, perm], live)[0], a[:, perm])
        # a seventh buoy out of service (a lost one, or the padding of a batch of fleets), anywhere in the water
        extra = torch.cat([obs, torch.randn(3, 1, D)], 1), torch.cat([pos, pos[:, :1] + 0.1], 1)
        padded = net.fleet(*extra, torch.cat([live, torch.zeros(3, 1, dtype=torch.bool)], 1))[0]
        torch.testing.assert_close(padded[:, :6], a)
        assert (padded[:, 6] == 0).all()


@pytest.mark.parametrize("hops", [0, 1, 2])
def test_a_buoy_learns_of_water_as_many_hops_away_as_it_is_set_to(hops):
    """A chain 0 - 1 - 2 - 3, neighbours 1.5 m apart (the range is 2 m): what buoy 2 senses reaches buoy 0 over
    two hops, never over one; buoy 3, three hops away, does not reach it over two."""
    net = actor(hops)
    obs = torch.randn(1, 4, D, generator=torch.Generator().manual_seed(2))
    pos = torch.tensor([[[0.0, 0.0], [1.5, 0.0], [3.0, 0.0], [4.5, 0.0]]])
    live = torch.ones(1, 4, dtype=torch.bool)

    def first_when(k: int) -> torch.Tensor:  # buoy 0's push after buoy k's sensors read something else
        changed = obs.clone()
        changed[0, k] += 1.0
        with torch.no_grad():
            return net.fleet(changed, pos, live)[0][0, 0]

    with torch.no_grad():
        a = net.fleet(obs, pos, live)[0][0, 0]
    assert torch.equal(first_when(1), a) == (hops == 0)
    assert torch.equal(first_when(2), a) == (hops < 2)
    assert torch.equal(first_when(3), a)  # three hops away: beyond every setting here


def test_messages_run_in_each_buoys_frame_not_in_the_average():
    with pytest.raises(ConfigError, match="d4_frame"):
        SharedLearnerConfig(hops=2, symmetry="d4")


def test_a_run_with_messages_trains_exports_and_runs_the_same(params, regions, tmp_path):
    """Two hops through training, the run's actor, the exported file and the evaluation's runner: one policy."""
    from replicate.compare.evaluate import fleet_policy
    from replicate.learn.policy import load_policy
    from replicate.toolkit.deploy import Actor
    from replicate.toolkit.export import export_general
    from replicate.world.env import CoverageEnv

    gc = params.general
    gc = dataclasses.replace(gc, regions=("square",), fleet=(6,), lakes=1, lake_fleet=(5, 5), lake_ratio=(1.0, 1.0),
                             n_envs=4, episodes=16, episode_length=20, learning_starts=100, batch_size=16,
                             buffer_size=2000, update_every=16, learner=dataclasses.replace(gc.learner, hops=2))
    summary = GeneralTrainer(params, 3, tmp_path / "run", progress=False, config=gc).run()
    assert summary["status"] == "finished"
    meta = export_general(tmp_path / "run" / "actor.pt", tmp_path / "policy.pt")
    assert meta["messages"]["hops"] == 2
    module, _ = load_policy(tmp_path / "policy.pt")
    trained = SharedActor.from_checkpoint(torch.load(tmp_path / "run" / "actor.pt"))
    env = CoverageEnv(regions["square"], dataclasses.replace(params.world, n_agents=6), params.coverage, n_envs=2,
                      observation="local", sensors_config=gc.sensors, wall=True)
    env.reset(seed=1, start="random")
    obs, pos = torch.as_tensor(env.observe()), torch.as_tensor(env.pos, dtype=torch.float32)
    live = torch.ones(2, 6, dtype=torch.bool)
    with torch.no_grad():
        np.testing.assert_allclose(fleet_policy(module)(env), trained.fleet(obs, pos, live)[0].numpy(), atol=1e-6)
        np.testing.assert_allclose(module(obs[0], pos[0], live[0]).numpy(), module(obs, pos, live)[0].numpy(),
                                   atol=1e-6)
    with pytest.raises(ValueError, match="messages"):
        Actor(tmp_path / "policy.pt")

