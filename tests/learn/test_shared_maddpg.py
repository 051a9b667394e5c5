"""The fleet-size-agnostic MADDPG (``replicate.learn.shared_maddpg``): one actor and one critic for any N, any order,
padding and lost buoys left out."""

import dataclasses

import numpy as np
import pytest
import torch

from replicate.core.sections import SensorsConfig, SharedLearnerConfig
from replicate.learn.replay import Batch
from replicate.learn.shared_maddpg import PooledCritic, SharedActor, SharedMADDPG
from replicate.world.env import observation_columns

OD, AD = 22, 2


def fleet(n: int, batch: int = 16, seed: int = 0, live=None) -> Batch:
    g = torch.Generator().manual_seed(seed)

    def r(*shape):
        return torch.randn(*shape, generator=g)

    live = torch.ones(batch, n, dtype=torch.bool) if live is None else live
    return Batch(obs=r(batch, n, OD), act=torch.rand(batch, n, AD, generator=g) * 2 - 1, rew=r(batch, n),
                 next_obs=r(batch, n, OD), pos=r(batch, n, 2) * 2, next_pos=r(batch, n, 2) * 2, live=live,
                 next_live=live, disc=torch.full((batch,), 0.9))


def pool(critic: PooledCritic, b: Batch, pos=None) -> torch.Tensor:
    """The pooled embedding of every slot of ``b`` (live or not) [B, N, embed], with positions ``pos``."""
    pos = b.pos if pos is None else pos
    every = torch.ones_like(b.live).nonzero(as_tuple=True)
    return critic.pooled(b.obs, b.act, critic.neighbours(pos, b.live, every)).reshape(*b.live.shape, -1)


def test_one_network_scores_any_fleet_size():
    torch.manual_seed(0)
    actor, critic = SharedActor(OD, AD, 64), PooledCritic(OD, AD, 64, 32)
    for n in (1, 5, 9, 20, 50):
        b = fleet(n, batch=4)
        a, pre = actor(b.obs)
        assert a.shape == pre.shape == (4, n, AD) and a.abs().max() <= 1
        assert critic(b.obs, a, b.pos, b.live).shape == (4, n)


def test_the_critic_does_not_care_about_order():
    torch.manual_seed(1)
    critic, b = PooledCritic(OD, AD, 64, 32), fleet(9)
    perm = torch.randperm(9)
    q = critic(b.obs, b.act, b.pos, b.live)
    q_perm = critic(b.obs[:, perm], b.act[:, perm], b.pos[:, perm], b.live[:, perm])
    torch.testing.assert_close(q_perm, q[:, perm], rtol=1e-5, atol=1e-5)


def test_padding_and_lost_buoys_change_nothing_for_the_others():
    """A fleet of 6 padded to 9, and the same 6 with 3 more buoys lost: the 6 get the same Q as alone."""
    torch.manual_seed(2)
    critic = PooledCritic(OD, AD, 64, 32)
    b = fleet(9)
    live = torch.zeros(16, 9, dtype=torch.bool)
    live[:, :6] = True
    q_padded = critic(b.obs, b.act, b.pos, live)[:, :6]
    q_alone = critic(b.obs[:, :6], b.act[:, :6], b.pos[:, :6], live[:, :6])
    torch.testing.assert_close(q_padded, q_alone, rtol=1e-5, atol=1e-6)


def test_updates_fit_a_fixed_batch_and_leave_padding_out():
    """On one fixed batch, 200 updates bring the critic's TD loss down; the rewards of padded buoys, however
    large, do not enter it."""
    agent = SharedMADDPG(OD, AD, SharedLearnerConfig(critic_lr=3e-3), seed=0)
    live = torch.ones(32, 12, dtype=torch.bool)
    live[:, 9:] = False
    b = fleet(12, batch=32, live=live)
    b.rew[:, 9:] = 1e6
    first = agent.update(b)["critic_loss"]
    for _ in range(200):
        stats = agent.update(b)
    assert np.isfinite(stats["critic_loss"]) and stats["critic_loss"] < 0.5 * first
    assert stats["q_abs"] < 100, "the padded buoys' rewards were left out"


def test_the_actor_step_leaves_the_critic_alone():
    agent = SharedMADDPG(OD, AD, SharedLearnerConfig(), seed=3)
    b = fleet(9)
    agent.update(b)
    before = [p.detach().clone() for p in agent.critic.parameters()]
    grads = [p.grad.clone() for p in agent.critic.parameters()]
    mu, pre = agent.actor(b.obs)
    (-agent.critic(b.obs, mu, b.pos, b.live).mean()).backward(inputs=list(agent.actor.parameters()))
    assert all(torch.equal(g, p.grad) for g, p in zip(grads, agent.critic.parameters()))
    assert all(torch.equal(x, p) for x, p in zip(before, agent.critic.parameters()))


def test_same_seed_same_networks_and_torch_stream_untouched():
    torch.manual_seed(123)
    expected = torch.rand(3)
    torch.manual_seed(123)
    a, b = SharedMADDPG(OD, AD, SharedLearnerConfig(), seed=7), SharedMADDPG(OD, AD, SharedLearnerConfig(), seed=7)
    assert torch.equal(torch.rand(3), expected), "building the networks drew nothing from torch's global stream"
    for p, q in zip(a.actor.parameters(), b.actor.parameters()):
        assert torch.equal(p, q)


def test_a_pool_range_leaves_far_buoys_out_of_the_critic():
    """With ``pool_range`` the critic pools only the buoys within it: moving a buoy that is out of range of all
    others further away changes nobody else's Q; the whole-fleet critic does see it."""
    torch.manual_seed(2)
    b = fleet(5, batch=3)
    b.pos[:, :4] = torch.rand(3, 4, 2)  # four buoys within 1.5 m of each other ...
    b.pos[:, 4] = torch.tensor([10.0, 10.0])  # ... and one far away
    moved = b.pos.clone()
    moved[:, 4] = torch.tensor([20.0, -5.0])
    near, whole = PooledCritic(OD, AD, 64, 32, pool_range=2.0), PooledCritic(OD, AD, 64, 32)
    whole.load_state_dict(near.state_dict())
    for critic, same in ((near, True), (whole, False)):
        q, q_moved = critic(b.obs, b.act, b.pos, b.live), critic(b.obs, b.act, moved, b.live)
        assert torch.equal(q[:, :4], q_moved[:, :4]) == same


def test_pooling_the_k_nearest_is_pooling_all_when_k_covers_the_fleet_and_ignores_the_rest_otherwise():
    torch.manual_seed(3)
    b = fleet(6, batch=4, live=torch.tensor([[True] * 6] * 3 + [[True, True, True, False, False, False]]))
    whole, k5, k2 = PooledCritic(OD, AD, 64, 32), PooledCritic(OD, AD, 64, 32, pool_neighbours=5), \
        PooledCritic(OD, AD, 64, 32, pool_neighbours=2)
    k5.load_state_dict(whole.state_dict())
    k2.load_state_dict(whole.state_dict())
    assert torch.equal(pool(whole, b), pool(k5, b))
    # with K = 2, moving each buoy's third-nearest and further ones away changes nothing for it
    d = (b.pos[:, :, None] - b.pos[:, None]).square().sum(-1)
    d = d.masked_fill(torch.eye(6, dtype=torch.bool) | ~b.live[:, None, :], float("inf"))
    i, near = 0, d[:, 0].topk(2, largest=False).indices  # buoy 0's two nearest live others, per sample
    moved = b.pos.clone()
    for s in range(4):
        for j in range(1, 6):
            if j not in near[s]:
                moved[s, j] += 100.0
    before, after = pool(k2, b), pool(k2, b, moved)
    assert torch.allclose(before[:, i], after[:, i], atol=1e-6)
    assert not torch.allclose(pool(whole, b)[:, i], pool(whole, b, moved)[:, i])


def test_pooling_the_k_nearest_averages_the_embeddings_of_exactly_those_buoys():
    """K = 3 of 6 (the gather path), with a sample whose buoy has fewer live others than K: each buoy's pooled
    vector is the mean of φ over its K nearest live others, computed here one buoy at a time."""
    torch.manual_seed(4)
    live = torch.ones(3, 6, dtype=torch.bool)
    live[2, 2:] = False  # two live buoys: each has one live other, fewer than K
    b = fleet(6, batch=3, live=live)
    critic = PooledCritic(OD, AD, 64, 32, pool_neighbours=3)
    pooled = pool(critic, b)
    for s in range(3):
        for i in range(6):
            others = [j for j in range(6) if j != i and b.live[s, j]]
            others.sort(key=lambda j: float((b.pos[s, j] - b.pos[s, i]).square().sum()))
            near = others[:3]
            x = torch.stack([torch.cat([b.obs[s, j], b.act[s, j], b.pos[s, j] - b.pos[s, i]]) for j in near])
            assert torch.allclose(pooled[s, i], critic.phi(x).mean(dim=0), atol=1e-5)


class PaddedReference(SharedMADDPG):
    """The update as it ran on padded [B, N] tensors before the rows (GENERAL_VERSION 1): every slot through the
    networks, the padding masked out of the pool and the losses. The reference the rows update is checked against."""

    def pooled(self, critic, obs, act, pos, live):  # [B, N, embed]
        n = obs.shape[1]
        rel = pos[:, None, :, :] - pos[:, :, None, :]  # [B, N (i), N (j), 2]
        other = torch.cat([obs, act], dim=-1)[:, None].expand(-1, n, -1, -1)
        others = live[:, None, :] & ~torch.eye(n, dtype=torch.bool)
        if critic.pool_range > 0:
            others = others & (rel.square().sum(-1) <= critic.pool_range**2)
        if 0 < critic.pool_neighbours < n - 1:
            far = rel.square().sum(-1).masked_fill(~others, torch.inf)
            nearest, idx = far.topk(critic.pool_neighbours, dim=2, largest=False)
            others = torch.isfinite(nearest)
            rel = rel.gather(2, idx[..., None].expand(-1, -1, -1, 2))
            other = other.gather(2, idx[..., None].expand(-1, -1, -1, other.shape[-1]))
        e = critic.phi(torch.cat([other, rel], dim=-1))
        w = others.to(e.dtype)
        return (e * w[..., None]).sum(dim=2) / w.sum(dim=2).clamp(min=1.0)[..., None]

    def q(self, critic, obs, act, pos, live, pooled=None):  # [B, N]
        pooled = self.pooled(critic, obs, act, pos, live) if pooled is None else pooled
        return critic.q(torch.cat([obs, act, pooled], dim=-1)).squeeze(-1)

    def update(self, b: Batch) -> dict[str, float]:
        cfg = self.cfg
        live, n_live = b.live.float(), b.live.float().sum().clamp(min=1.0)
        with torch.no_grad():
            next_act, _ = self.actor_target(b.next_obs)
            q_next = self.q(self.critic_target, b.next_obs, next_act, b.next_pos, b.next_live) * b.next_live
            y = b.rew + b.disc[:, None] * q_next
        q = self.q(self.critic, b.obs, b.act, b.pos, b.live)
        critic_loss = (((q - y) ** 2) * live).sum() / n_live
        self.critic_opt.zero_grad()
        critic_loss.backward()
        torch.nn.utils.clip_grad_norm_(self.critic.parameters(), cfg.grad_clip)
        self.critic_opt.step()
        with torch.no_grad():
            pooled = self.pooled(self.critic, b.obs, b.act, b.pos, b.live)
        mu, pre = self.actor(b.obs)
        q_pi = self.q(self.critic, b.obs, mu, b.pos, b.live, pooled)
        actor_loss = -(q_pi * live).sum() / n_live + cfg.actor_reg * ((pre**2).mean(-1) * live).sum() / n_live
        self.actor_opt.zero_grad()
        actor_loss.backward(inputs=list(self.actor.parameters()))
        torch.nn.utils.clip_grad_norm_(self.actor.parameters(), cfg.grad_clip)
        self.actor_opt.step()
        with torch.no_grad():
            for net, target in ((self.critic, self.critic_target), (self.actor, self.actor_target)):
                for p, tp in zip(net.parameters(), target.parameters()):
                    tp.lerp_(p, cfg.tau)
        return {"critic_loss": critic_loss.item()}


@pytest.mark.parametrize("pool", [{"pool_neighbours": 0}, {"pool_neighbours": 3}, {"pool_neighbours": 8},
                                  {"pool_neighbours": 3, "pool_range": 1.5}, {"pool_neighbours": 0, "pool_range": 1.5}])
def test_the_update_on_the_buoys_in_service_is_the_padded_update(pool):
    """Fleets of 1 to 9 padded to 9 (single buoys with no one to pool), some buoys lost before the bootstrap step:
    three updates on the rows leave the weights the padded reference leaves, to float rounding, for the K-nearest
    path, the all-pairs path (K = 0 and K ≥ N − 1) and a pool range."""
    g = torch.Generator().manual_seed(5)
    live = torch.arange(9)[None] < torch.randint(1, 10, (48,), generator=g)[:, None]
    b = fleet(9, batch=48, seed=5, live=live)
    b.next_live = live & (torch.rand(48, 9, generator=g) > 0.2)
    b.rew[~live] = 100.0  # what padding holds must not matter
    cfg = SharedLearnerConfig(**pool)
    rows, padded = SharedMADDPG(OD, AD, cfg, seed=1), PaddedReference(OD, AD, cfg, seed=1)
    for _ in range(3):
        assert abs(rows.update(b)["critic_loss"] - padded.update(b)["critic_loss"]) < 1e-5
    for net in ("actor", "critic", "actor_target", "critic_target"):
        for p, q in zip(getattr(rows, net).parameters(), getattr(padded, net).parameters()):
            torch.testing.assert_close(p, q, rtol=1e-4, atol=1e-5)


def test_imitation_moves_the_actor_toward_the_teacher():
    """``imitation: alone``: 60 updates on one minibatch whose teacher says (0.5, −0.5) for every buoy bring the
    actor's actions there (the critic's term left out); ``none`` ignores the teacher (the same update with or
    without its labels); ``beside`` adds the imitation term to the actor-critic loss, so its actor differs from
    both."""
    import dataclasses

    b = fleet(6, batch=32, seed=3)
    b.expert = torch.tensor([0.5, -0.5]).expand(32, 6, 2).clone()
    cfg = SharedLearnerConfig(hidden=32, embed=16, actor_lr=3e-3)
    actors = {}
    for mode in ("none", "beside", "alone"):
        learner = SharedMADDPG(OD, AD, dataclasses.replace(cfg, imitation=mode), seed=0)
        before = (learner.actor(b.obs)[0] - b.expert).abs().mean().item()
        for _ in range(60):
            learner.update(b)
        actors[mode] = learner.actor(b.obs)[0].detach()
        if mode == "alone":
            assert (actors[mode] - b.expert).abs().mean().item() < 0.1 < before
    unlabelled = SharedMADDPG(OD, AD, cfg, seed=0)
    b.expert = None
    for _ in range(60):
        unlabelled.update(b)
    torch.testing.assert_close(unlabelled.actor(b.obs)[0].detach(), actors["none"])
    assert not torch.allclose(actors["beside"], actors["none"]) and not torch.allclose(actors["beside"],
                                                                                         actors["alone"])


def test_imitation_before_hands_over_to_the_actor_critic():
    """``imitation: before``: the update imitates alone (as ``alone``, update for update) until ``hand_over``; after
    it the teacher's labels no longer move anything (two copies updated on opposite labels stay equal), and the
    actor-critic term moves the actor (unlike ``alone``'s, which stays where the labels hold it)."""
    import copy
    import dataclasses

    b = fleet(6, batch=32, seed=3)
    b.expert = torch.tensor([0.5, -0.5]).expand(32, 6, 2).clone()
    cfg = SharedLearnerConfig(hidden=32, embed=16, actor_lr=3e-3)
    before, alone = (SharedMADDPG(OD, AD, dataclasses.replace(cfg, imitation=m), seed=0) for m in ("before", "alone"))
    for _ in range(20):
        assert before.update(b) == alone.update(b)
    torch.testing.assert_close(before.actor(b.obs)[0], alone.actor(b.obs)[0])
    before.hand_over()
    flipped = copy.deepcopy(b)
    flipped.expert = -b.expert
    other = copy.deepcopy(before)
    for _ in range(20):
        assert before.update(b) == other.update(flipped)
        alone.update(b)
    torch.testing.assert_close(before.actor(b.obs)[0], other.actor(b.obs)[0])
    assert not torch.allclose(before.actor(b.obs)[0], alone.actor(b.obs)[0])


def test_the_averaged_actor_follows_the_trained_one_at_its_rate_and_is_the_one_deployed():
    """``average``: θ̄ ← θ̄ + average·(θ − θ̄) after every update; the policy (what is validated and deployed) is
    θ̄'s, the behaviour (``act``) the trained actor's; the updates themselves are the same as without it."""
    b = fleet(6, batch=32, seed=4)
    cfg = SharedLearnerConfig(hidden=32, embed=16, actor_lr=3e-3)
    plain, averaged = (SharedMADDPG(OD, AD, dataclasses.replace(cfg, average=a), seed=0) for a in (0.0, 0.1))
    assert plain.actor_average is None and plain.deployed is plain.actor
    expected = [p.detach().clone() for p in averaged.actor.parameters()]
    for _ in range(5):
        assert plain.update(b) == averaged.update(b)
        for e, p in zip(expected, averaged.actor.parameters()):
            e += 0.1 * (p.detach() - e)
    for e, p in zip(expected, averaged.actor_average.parameters()):
        torch.testing.assert_close(p, e)
    torch.testing.assert_close(averaged.policy(b.obs, None, None), averaged.actor_average(b.obs)[0])
    assert not torch.allclose(averaged.policy(b.obs, None, None), averaged.actor(b.obs)[0])
    noiseless = averaged.act(b.obs, 0.0, torch.Generator().manual_seed(0))
    torch.testing.assert_close(noiseless, averaged.actor(b.obs)[0].clamp(-1, 1))


def linear_layers(net: torch.nn.Module) -> int:
    return sum(isinstance(m, torch.nn.Linear) for m in net.modules())


@pytest.mark.parametrize("symmetry", ["none", "d4_frame"])
def test_layers_sets_the_depth_of_the_actor_and_the_critic_and_is_read_back_from_the_weights(symmetry):
    """``layers`` hidden layers in the actor's MLP and the critic's Q head (φ keeps one); a state dict alone gives
    back the width and the depth it was trained with (``replicate cover --finetune`` reads them so)."""
    columns = observation_columns("local", SensorsConfig()) if symmetry != "none" else None
    od = len(columns) if columns else OD
    for layers in (1, 2, 3):
        cfg = SharedLearnerConfig(hidden=24, embed=8, layers=layers, symmetry=symmetry)
        agent = SharedMADDPG(od, AD, cfg, seed=0, columns=columns)
        assert linear_layers(agent.actor) == layers + 1
        assert linear_layers(agent.critic.q) == layers + 1 and linear_layers(agent.critic.phi) == 2
        assert SharedActor.shape(agent.actor.state_dict(), symmetry) == (24, layers)


def test_a_lloyd_prior_steers_toward_the_local_centroid_and_the_network_corrects_it(tmp_path):
    """With ``lloyd_prior`` g, the action is tanh(f(o) + g · (centroid_dx, centroid_dy)): Lloyd's law alone where
    the network's output f is 0, which is what the actor's regulariser reads; padded fleets and the exported file
    act alike; an observation without the centroid's columns is refused."""
    from replicate.core import artifacts
    from replicate.core.schema import to_dict
    from replicate.learn.policy import load_policy
    from replicate.toolkit.export import export_general

    sensors = SensorsConfig(centroid=True)
    columns = observation_columns("local", sensors)
    cfg = SharedLearnerConfig(hidden=16, embed=8, symmetry="d4_frame", lloyd_prior=10.0)
    agent = SharedMADDPG(len(columns), AD, cfg, seed=0, columns=columns, sensors=sensors)
    obs = torch.randn(5, 7, len(columns), generator=torch.Generator().manual_seed(1))
    act, pre = agent.actor(obs)
    torch.testing.assert_close(act, torch.tanh(pre + 10.0 * obs[..., -2:]))
    with torch.no_grad():
        agent.actor.net.net[-1].weight.zero_()
        agent.actor.net.net[-1].bias.zero_()
    act, pre = agent.actor(obs)
    assert pre.abs().max() == 0
    torch.testing.assert_close(act, torch.tanh(10.0 * obs[..., -2:]))
    live = torch.ones(5, 7, dtype=torch.bool)
    live[:, 5:] = False
    fleet_act, fleet_pre = agent.actor.fleet(obs, torch.zeros(5, 7, 2), live)
    torch.testing.assert_close(fleet_act[live], act[live])
    assert fleet_act[~live].abs().max() == 0 and fleet_pre[~live].abs().max() == 0

    torch.manual_seed(2)
    agent = SharedMADDPG(len(columns), AD, cfg, seed=3, columns=columns, sensors=sensors)
    artifacts.torch_save(tmp_path / "actor.pt", {
        "format": artifacts.CHECKPOINT_FORMAT, "actor": agent.actor.state_dict(), "observation": "local",
        "sensors": to_dict(sensors), "columns": columns, "learner": to_dict(cfg), "hidden": 16,
        "symmetry": "d4_frame", "selected_episode": 0, "seed": 3})
    meta = export_general(tmp_path / "actor.pt", tmp_path / "policy.pt")
    module, _ = load_policy(tmp_path / "policy.pt")
    assert meta["lloyd_prior"]["gain_per_sim_m"] == 10.0
    with torch.no_grad():
        torch.testing.assert_close(module(obs), agent.actor(obs)[0])
    with pytest.raises(ValueError, match="needs its columns"):
        SharedActor.of(OD, AD, cfg, observation_columns("local", SensorsConfig()))


def test_a_lloyd_prior_added_at_deployment_steers_the_network_trained_without_it(tmp_path):
    """``export_general(..., added_prior=g)`` (``replicate export RUN --lloyd-prior G``): the file's observation gains
    the centroid sensor's columns, last; its action is tanh(μ(o[:, :K]) + g · (centroid_dx, centroid_dy)) with μ the
    trained network on the K columns it was trained on; an actor with a prior of its own is refused, and so is
    fine-tuning the file (its network never trained with the prior)."""
    from replicate.core import artifacts
    from replicate.core.schema import ConfigError, to_dict
    from replicate.learn.policy import load_policy
    from replicate.toolkit.cover import finetuned
    from replicate.toolkit.export import export_general

    def saved_actor(path, sensors, cfg):
        columns = observation_columns("local", sensors)
        agent = SharedMADDPG(len(columns), AD, cfg, seed=3, columns=columns, sensors=sensors)
        artifacts.torch_save(path, {
            "format": artifacts.CHECKPOINT_FORMAT, "actor": agent.actor.state_dict(), "observation": "local",
            "sensors": to_dict(sensors), "columns": columns, "learner": to_dict(cfg), "hidden": 16,
            "symmetry": "d4_frame", "selected_episode": 0, "seed": 3})
        return agent.actor, columns

    cfg = SharedLearnerConfig(hidden=16, embed=8, symmetry="d4_frame")
    actor, trained_on = saved_actor(tmp_path / "actor.pt", SensorsConfig(), cfg)
    meta = export_general(tmp_path / "actor.pt", tmp_path / "policy.pt", added_prior=3.0)
    module, _ = load_policy(tmp_path / "policy.pt")
    columns = meta["observation_layout"]
    assert columns == trained_on + ["centroid_dx", "centroid_dy"] and meta["sensor_config"]["centroid"] is True
    assert meta["lloyd_prior"] | {"gain_per_sim_m": 3.0, "added_at_deployment": True,
                                  "network_reads": len(trained_on)} == meta["lloyd_prior"]
    assert f"network(obs[..., :{len(trained_on)}])" in meta["lloyd_prior"]["action"]
    obs = torch.randn(2, 7, len(columns), generator=torch.Generator().manual_seed(4))
    with torch.no_grad():
        expected = torch.tanh(actor.net(obs[..., :len(trained_on)]) + 3.0 * obs[..., -2:])
        torch.testing.assert_close(module(obs), expected)
        torch.testing.assert_close(module(obs[0]), expected[0])
    with pytest.raises(ConfigError, match="fine-tune the run's own export"):
        finetuned(tmp_path / "policy.pt", module, meta, None, None, 10, 4, 0, tmp_path / "tuned", False)

    saved_actor(tmp_path / "prior.pt", SensorsConfig(centroid=True), dataclasses.replace(cfg, lloyd_prior=10.0))
    with pytest.raises(ConfigError, match="prior.pt: a Lloyd prior is added .* this one has its own prior"):
        export_general(tmp_path / "prior.pt", tmp_path / "twice.pt", added_prior=3.0)
    assert not (tmp_path / "twice.pt").exists()
