"""The batched MADDPG is the same algorithm as N separate learners (openai/maddpg structure), and a stack of runs
is each run alone, bit for bit."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
import torch

from replicate.learn import run_stack
from replicate.learn.maddpg import MADDPG, BatchedMLP, soft_update
from replicate.learn.replay import Batch, Replay

from .loop_maddpg import LoopMADDPG


def filled_buffer(n, od, rng, size=2000):
    buf = Replay(size, n, od)
    for _ in range(size // 100):
        buf.add(
            0.95,
            obs=rng.normal(size=(100, n, od)).astype(np.float32),
            act=rng.uniform(-1, 1, (100, n, 2)).astype(np.float32),
            rew=rng.normal(size=(100, n)).astype(np.float32),
            next_obs=rng.normal(size=(100, n, od)).astype(np.float32),
        )
    return buf


def test_batched_mlp_equals_separate_networks():
    g = torch.Generator().manual_seed(0)
    net = BatchedMLP(4, [3, 8, 8, 2], g)
    x = torch.randn(4, 5, 3)
    out = net(x)
    for i in range(4):
        h = x[i]
        for k, (w, b) in enumerate(zip(net.weights, net.biases)):
            h = h @ w[i] + b[i, 0]
            if k < 2:
                h = torch.relu(h)
        torch.testing.assert_close(out[i], h)


@pytest.mark.parametrize("mode", ["individual", "shared"])
def test_batched_update_equals_per_agent_loop(params, mode):
    cfg = dataclasses.replace(params.configs["paper"].maddpg, batch_size=64, actor_lr=1e-3, critic_lr=1e-3)
    n, od = 4, 4
    batched = MADDPG(n, od, 2, cfg, mode, seed=3)
    loop = LoopMADDPG(batched)
    rng = np.random.default_rng(0)
    buf = filled_buffer(n, od, rng)
    for _ in range(3):
        batch = buf.sample(rng, cfg.batch_size)
        batched.update(batch)
        loop.update(batch)
    for i in range(n):
        for k, (w, b) in enumerate(zip(batched.critic.weights, batched.critic.biases)):
            torch.testing.assert_close(w[i].T, loop.critics[i][2 * k].weight, rtol=1e-4, atol=1e-5)
            torch.testing.assert_close(b[i, 0], loop.critics[i][2 * k].bias, rtol=1e-4, atol=1e-5)
        for k, (w, b) in enumerate(zip(batched.actor.weights, batched.actor.biases)):
            torch.testing.assert_close(w[i].T, loop.actors[i][2 * k].weight, rtol=1e-4, atol=1e-5)
            torch.testing.assert_close(b[i, 0], loop.actors[i][2 * k].bias, rtol=1e-4, atol=1e-5)
        for k, w in enumerate(batched.actor_target.weights):
            torch.testing.assert_close(w[i].T, loop.actor_targets[i][2 * k].weight, rtol=1e-4, atol=1e-5)


@pytest.mark.parametrize("mode", ["individual", "shared"])
def test_update_gradients_equal_the_per_agent_loop(params, mode):
    """The gradients of both losses inside ``update`` (learning rates 0 and no clipping, so they are left in
    ``.grad`` unchanged and the actor sees the same critic), against the autograd loss of each agent."""
    cfg = dataclasses.replace(params.configs["paper"].maddpg, batch_size=64, grad_clip=1e9)
    batched = MADDPG(4, 4, 2, cfg, mode, seed=5)
    batched.scale_learning_rates(0.0)
    loop = LoopMADDPG(batched)
    for opt in (*loop.actor_opts, *loop.critic_opts):
        opt.param_groups[0]["lr"] = 0.0
    rng = np.random.default_rng(1)
    batch = filled_buffer(4, 4, rng).sample(rng, cfg.batch_size)
    batched.update(batch)
    loop.update(batch)
    for net, nets in ((batched.critic, loop.critics), (batched.actor, loop.actors)):
        for i in range(4):
            for k, (w, b) in enumerate(zip(net.weights, net.biases)):
                torch.testing.assert_close(w.grad[i].T, nets[i][2 * k].weight.grad, rtol=1e-4, atol=1e-6)
                torch.testing.assert_close(b.grad[i, 0], nets[i][2 * k].bias.grad, rtol=1e-4, atol=1e-6)


def test_gradient_clip_and_soft_update(params):
    cfg = dataclasses.replace(params.configs["paper"].maddpg, batch_size=32)
    agent = MADDPG(3, 2, 2, cfg, "individual", seed=0)
    before = [p.detach().clone() for p in agent.critic_target.parameters()]
    agent.update(filled_buffer(3, 2, np.random.default_rng(1)).sample(np.random.default_rng(2), 32))
    for b, t, p in zip(before, agent.critic_target.parameters(), agent.critic.parameters()):
        # θ' ← τθ + (1 − τ)θ', with θ already updated
        torch.testing.assert_close(t.detach(), 0.99 * b + 0.01 * p.detach())
    a = BatchedMLP(2, [2, 4, 1], torch.Generator().manual_seed(0))
    b = BatchedMLP(2, [2, 4, 1], torch.Generator().manual_seed(1))
    soft_update(list(a.parameters()), list(b.parameters()), 1.0)
    for p, q in zip(a.parameters(), b.parameters()):
        torch.testing.assert_close(p, q)


@pytest.mark.parametrize("config, mode", [("tuned", "individual"), ("paper", "shared")])
def test_a_stack_of_runs_is_its_runs_bit_for_bit(params, config, mode):
    """The training's update over seeds [3, 8, 4] against three one-seed learners fed the same minibatches: every
    parameter, Adam moment and diagnostic is equal to the last bit after 30 updates (elementwise kernels round the
    last few elements of a tensor differently, so Adam and the soft update work on each run's part as its own
    tensor), and
    ``run_stack.run_state`` is the one-run state."""
    cfg = dataclasses.replace(params.configs[config].maddpg, batch_size=64)
    seeds = [3, 8, 4]
    stack = MADDPG(9, 2, 2, cfg, mode, seeds)
    alone = [MADDPG(9, 2, 2, cfg, mode, s) for s in seeds]
    rng = np.random.default_rng(0)
    buffers = [filled_buffer(9, 2, rng) for _ in seeds]
    for _ in range(30):
        batches = [b.sample(rng, cfg.batch_size) for b in buffers]
        got = stack.update(Batch.stack(batches))
        for k, (agent, batch) in enumerate(zip(alone, batches)):
            want = agent.update(batch)
            assert got["critic_loss"][k] == want["critic_loss"][0] and got["q_abs"][k] == want["q_abs"][0]
    for k, agent in enumerate(alone):
        mine, theirs = run_stack.run_state(stack, k), run_stack.run_state(agent)
        for name in ("actor", "critic", "actor_target", "critic_target"):
            for key, t in theirs[name].items():
                assert torch.equal(mine[name][key], t), (k, name, key)
        for name in ("actor_opt", "critic_opt"):
            for i, st in theirs[name]["state"].items():
                assert all(torch.equal(mine[name]["state"][i][f], st[f]) for f in ("step", "exp_avg", "exp_avg_sq"))
    obs = rng.normal(size=(3, 5, 9, 2)).astype(np.float32)
    actions, _ = stack.policy(obs)
    for k, agent in enumerate(alone):
        np.testing.assert_array_equal(actions[k], agent.policy(obs[k])[0])


def test_a_run_loads_into_any_place_of_a_stack(params):
    """One run's state goes into the second place of a fresh stack and comes out unchanged; a state of another
    shape, or runs of one stack at different Adam steps, are refused."""
    cfg = dataclasses.replace(params.configs["tuned"].maddpg, batch_size=32)
    rng = np.random.default_rng(2)
    one = MADDPG(3, 2, 2, cfg, "individual", 5)
    one.update(filled_buffer(3, 2, rng).sample(rng, 32))
    stack = MADDPG(3, 2, 2, cfg, "individual", [0, 1])
    run_stack.load_run_state(stack, run_stack.run_state(one), run=1)
    out, want = run_stack.run_state(stack, 1), run_stack.run_state(one)
    assert all(torch.equal(out["actor"][k], t) for k, t in want["actor"].items())
    assert torch.equal(out["critic_opt"]["state"][0]["exp_avg"], want["critic_opt"]["state"][0]["exp_avg"])
    with pytest.raises((KeyError, RuntimeError)):
        run_stack.load_run_state(stack, run_stack.run_state(MADDPG(4, 2, 2, cfg, "individual", 0)), run=0)
    two = MADDPG(3, 2, 2, cfg, "individual", 6)
    for _ in range(2):
        two.update(filled_buffer(3, 2, rng).sample(rng, 32))
    with pytest.raises(ValueError, match="different steps"):
        run_stack.load_run_state(stack, run_stack.run_state(two), run=0)


def test_individual_and_shared_rewards_differ(params):
    cfg = dataclasses.replace(params.configs["paper"].maddpg, batch_size=32)
    rng = np.random.default_rng(0)
    buf = filled_buffer(3, 2, rng)
    batch = buf.sample(rng, 32)
    ind, sha = MADDPG(3, 2, 2, cfg, "individual", 0), MADDPG(3, 2, 2, cfg, "shared", 0)
    ind.update(batch)
    sha.update(batch)
    assert not torch.allclose(ind.critic.weights[0], sha.critic.weights[0])
    with pytest.raises(ValueError, match="reward_mode"):
        MADDPG(3, 2, 2, cfg, "team", 0)
