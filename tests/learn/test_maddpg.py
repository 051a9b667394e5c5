"""The batched MADDPG is the same algorithm as N separate learners (openai/maddpg structure), and its update with
the gradients written out (``MADDPGByHand``, the one the training runs) is its autograd update."""

from __future__ import annotations

import copy
import dataclasses

import numpy as np
import pytest
import torch

from replicate.learn import run_stack
from replicate.learn.maddpg import MADDPG, BatchedMLP, soft_update
from replicate.learn.maddpg_by_hand import MADDPGByHand, adam_step, backward
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


@pytest.mark.parametrize("sizes", [[6, 32, 32, 1], [4, 32, 32, 2], [3, 8, 20, 17]])
def test_hand_written_gradients_equal_autograd(sizes):
    """``backward`` against autograd, for the gradient of every parameter and of the input. Adam would
    hide a gradient off by a constant factor in an end-to-end test, so the gradients are checked here directly.
    The sizes reach every form of ``stacked_matmul``: an output of 1 (outer product), of 2 (transposed) and
    wide layers."""
    net = BatchedMLP(3, sizes, torch.Generator().manual_seed(0))
    x = torch.randn(3, 7, sizes[0], requires_grad=True)
    grad_out = torch.randn(3, 7, sizes[-1])
    out, saved = net.forward_saving(x.detach())
    d_z1 = backward(net, saved, grad_out)
    mine = [p.grad.clone() for p in net.parameters()]
    mine_x = d_z1 @ net.weights[0].detach().mT
    net.zero_grad()
    h = x
    for k, (w, b) in enumerate(zip(net.weights, net.biases)):
        h = h @ w + b
        h = torch.relu(h) if k < len(net.weights) - 1 else h
    torch.testing.assert_close(out, h.detach())
    (h * grad_out).sum().backward()
    for p, g in zip(net.parameters(), mine):
        torch.testing.assert_close(g, p.grad)
    torch.testing.assert_close(mine_x, x.grad)


LEARNERS = [MADDPG, MADDPGByHand]


@pytest.mark.parametrize("learner", LEARNERS)
@pytest.mark.parametrize("mode", ["individual", "shared"])
def test_batched_update_equals_per_agent_loop(params, mode, learner):
    cfg = dataclasses.replace(params.configs["paper"].maddpg, batch_size=64, actor_lr=1e-3, critic_lr=1e-3)
    n, od = 4, 4
    batched = learner(n, od, 2, cfg, mode, seed=3)
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


@pytest.mark.parametrize("learner", LEARNERS)
@pytest.mark.parametrize("mode", ["individual", "shared"])
def test_update_gradients_equal_the_per_agent_loop(params, mode, learner):
    """The gradients of both losses inside ``update`` (learning rates 0 and no clipping, so they are left in
    ``.grad`` unchanged and the actor sees the same critic), against the autograd loss of each agent."""
    cfg = dataclasses.replace(params.configs["paper"].maddpg, batch_size=64, grad_clip=1e9)
    batched = learner(4, 4, 2, cfg, mode, seed=5)
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


@pytest.mark.parametrize("config, mode, runs", [("paper", "individual", [0]), ("tuned", "shared", [1, 2])])
def test_the_update_by_hand_is_the_autograd_update(params, config, mode, runs):
    """Eight updates of a stack of runs by each (learning rates 1e-3): every parameter, Adam moment and diagnostic
    agree to float32 rounding grown over the updates (the two differ in the order of their sums only; Adam turns a
    gradient near 0 into a step of the learning rate whatever its rounding, so larger rates part them further; a
    gradient off by any factor would part them by orders more, and the per-agent loop tests check each update's
    gradients)."""
    cfg = dataclasses.replace(params.configs[config].maddpg, batch_size=128, actor_lr=1e-3, critic_lr=1e-3)
    readable, by_hand = MADDPG(5, 6, 2, cfg, mode, runs), MADDPGByHand(5, 6, 2, cfg, mode, runs)
    rng = np.random.default_rng(7)
    buffers = [filled_buffer(5, 6, rng) for _ in runs]
    for _ in range(8):
        batch = Batch.stack([b.sample(rng, cfg.batch_size) for b in buffers])
        got, want = by_hand.update(batch), readable.update(batch)
        np.testing.assert_allclose(got["critic_loss"], want["critic_loss"], rtol=1e-3)
        np.testing.assert_allclose(got["q_abs"], want["q_abs"], rtol=1e-3)
    for name in ("actor", "critic", "actor_target", "critic_target"):
        for p, q in zip(by_hand.params[name], readable.params[name]):
            torch.testing.assert_close(p, q, rtol=1e-3, atol=1e-4)
    for name in ("actor_opt", "critic_opt"):
        mine, theirs = getattr(by_hand, name).state_dict()["state"], getattr(readable, name).state_dict()["state"]
        for i, st in theirs.items():
            torch.testing.assert_close(mine[i]["exp_avg"], st["exp_avg"], rtol=1e-2, atol=1e-3)  # the gradients' mean


def test_gradient_clip_and_soft_update(params):
    cfg = dataclasses.replace(params.configs["paper"].maddpg, batch_size=32)
    agent = MADDPGByHand(3, 2, 2, cfg, "individual", seed=0)
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


def test_adam_step_is_the_optimizer_step():
    """The unwrapped fused Adam step gives the optimiser's numbers bit for bit, also on state loaded from a
    checkpoint (which replaces the state tensors)."""
    g = torch.Generator().manual_seed(0)
    nets = [BatchedMLP(3, [4, 8, 2], torch.Generator().manual_seed(0)) for _ in range(2)]
    opts = [torch.optim.Adam(n.parameters(), lr=0.01, fused=True) for n in nets]
    for step in range(6):
        grads = [torch.randn(p.shape, generator=g) for p in nets[0].parameters()]
        for net in nets:
            for p, grad in zip(net.parameters(), grads):
                p.grad = grad.clone()
        opts[0].step()
        adam_step(opts[1])
        if step == 2:
            opts[1].load_state_dict(copy.deepcopy(opts[0].state_dict()))  # as from a checkpoint file
        for p, q in zip(*(n.parameters() for n in nets)):
            assert torch.equal(p, q)
    assert opts[1].state_dict()["state"][0]["step"].item() == 6


@pytest.mark.parametrize("config, mode", [("tuned", "individual"), ("paper", "shared")])
def test_a_stack_of_runs_is_its_runs_bit_for_bit(params, config, mode):
    """The training's update over seeds [3, 8, 4] against three one-seed learners fed the same minibatches: every
    parameter, Adam moment and diagnostic is equal to the last bit after 30 updates (elementwise kernels round the
    last few elements of a tensor differently, so Adam and the soft update work on each run's part as its own
    tensor), and
    ``run_stack.run_state`` is the one-run state."""
    cfg = dataclasses.replace(params.configs[config].maddpg, batch_size=64)
    seeds = [3, 8, 4]
    stack = MADDPGByHand(9, 2, 2, cfg, mode, seeds)
    alone = [MADDPGByHand(9, 2, 2, cfg, mode, s) for s in seeds]
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
