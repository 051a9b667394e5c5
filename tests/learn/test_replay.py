"""The one replay memory (``replicate.learn.replay``): a fixed fleet (the per-region runs) and padded fleets with
losses (the general policy), and the n-step returns written into it."""

import numpy as np
import pytest
import torch

from replicate.learn.replay import Batch, NStepWriter, Replay


def step(value: float, e: int = 2, n: int = 2) -> dict:
    return {"obs": np.full((e, n, 2), value, np.float32), "act": np.zeros((e, n, 2), np.float32),
            "rew": np.full((e, n), value, np.float32), "next_obs": np.zeros((e, n, 2), np.float32)}


def test_the_memory_wraps_and_round_trips():
    memory = Replay(5, 2, 2)
    for k in range(3):
        memory.add(0.9**k, **step(k))
    assert memory.size == 5 and memory.ptr == 1
    assert memory.data["rew"][:, 0].tolist() == [2, 0, 1, 1, 2]  # the third batch wrapped onto slot 0
    other = Replay(5, 2, 2)
    other.load_state_dict(memory.state_dict())
    for k, v in memory.data.items():
        np.testing.assert_array_equal(other.data[k], v)
    np.testing.assert_array_equal(other.disc, memory.disc)
    assert (other.ptr, other.size) == (memory.ptr, memory.size)
    with pytest.raises(ValueError, match="does not fit"):
        Replay(5, 3, 2).load_state_dict(memory.state_dict())


def test_a_sample_is_the_rows_its_generator_draws():
    memory = Replay(8, 2, 2)
    memory.add(0.9, **step(1.0, e=8))
    memory.data["obs"][:, 0, 0] = np.arange(8)
    rows = np.random.default_rng(4).integers(0, 8, size=5)
    b = memory.sample(np.random.default_rng(4), 5)
    assert b.obs[:, 0, 0].tolist() == rows.tolist() and b.live is None and b.pos is None
    stacked = Batch.stack([b, b])
    assert stacked.obs.shape == (2, 5, 2, 2) and stacked.live is None


def test_small_fleets_are_padded_and_masked():
    memory = Replay(10, 4, 3, fleets=True)
    live = np.ones((2, 3), bool)
    arrays = {k: np.ones((2, 3, d)) if d else np.ones((2, 3)) for k, d in
              (("obs", 3), ("act", 2), ("rew", 0), ("next_obs", 3), ("pos", 2), ("next_pos", 2))}
    memory.add(0.9, live=live, next_live=live, **arrays)
    b = memory.sample(np.random.default_rng(0), 5)
    assert b.obs.shape == (5, 4, 3) and not b.live[:, 3].any() and b.live[:, :3].all()
    assert b.live.dtype == torch.bool and (b.rew[:, 3] == 0).all() and torch.equal(b.disc, torch.full((5,), 0.9))


def test_n_step_writer_sums_discounted_rewards_and_closes_the_episode():
    """Hand-computed 3-step returns over a 5-step episode of 2 environments: steps 0-2 hold full 3-step
    transitions (disc γ³); the time limit writes steps 3 and 4 with the 2 and 1 rewards left (γ², γ)."""
    gamma, n_env, n_agents, steps = 0.5, 2, 3, 5
    memory = Replay(20, n_agents, 2)
    writer = NStepWriter(memory, 3, gamma)
    rew = [np.full((n_env, n_agents), 10.0**t) for t in range(steps)]  # r_t = 10^t, every agent
    obs = [np.full((n_env, n_agents, 2), float(t), np.float32) for t in range(steps + 1)]
    for t in range(steps):
        writer.push(t == steps - 1, obs=obs[t], act=np.zeros((n_env, n_agents, 2), np.float32), rew=rew[t],
                    next_obs=obs[t + 1])
    assert memory.size == n_env * steps and not writer.open
    start = memory.data["obs"][: memory.size, 0, 0]  # the step each transition starts at
    for t in range(steps):
        m = min(3, steps - t)
        rows = np.nonzero(start == t)[0]
        assert len(rows) == n_env
        expected = sum(gamma**k * 10.0 ** (t + k) for k in range(m))
        np.testing.assert_allclose(memory.data["rew"][rows], expected, rtol=1e-6)
        np.testing.assert_allclose(memory.disc[rows], gamma**m, rtol=1e-6)
        np.testing.assert_array_equal(memory.data["next_obs"][rows, 0, 0], t + m)


def test_one_step_writer_is_the_plain_memory():
    """n = 1 writes each step as it comes, with disc γ: the paper's transitions, in the same order."""
    rng = np.random.default_rng(3)
    a, b = Replay(10, 2, 2), Replay(10, 2, 2)
    writer = NStepWriter(b, 1, 0.95)
    for t in range(4):
        fields = {k: rng.normal(size=s).astype(np.float32)
                  for k, s in (("obs", (2, 2, 2)), ("act", (2, 2, 2)), ("rew", (2, 2)), ("next_obs", (2, 2, 2)))}
        a.add(0.95, **fields)
        writer.push(t == 3, **fields)
    for name in a.data:
        np.testing.assert_array_equal(a.data[name], b.data[name])
    np.testing.assert_array_equal(a.disc, b.disc)


def test_n_step_transitions_stop_at_a_loss():
    """Three steps of one environment with two buoys, n = 2: r_t + γ r_{t+1}, bootstrapping at o_{t+2} with γ²;
    the episode's last step closes with one reward and γ; buoy 1, lost before the third step, is not bootstrapped
    from a transition that spans the loss."""
    gamma, memory = 0.5, Replay(10, 2, 1, fleets=True)
    writer = NStepWriter(memory, 2, gamma)
    live = [np.array([[True, True]]), np.array([[True, True]]), np.array([[True, False]])]
    for t in range(3):
        writer.push(t == 2, live=live[t], obs=np.full((1, 2, 1), t), act=np.zeros((1, 2, 2)),
                    rew=np.array([[1.0, 10.0]]) * (t + 1) * live[t], pos=np.zeros((1, 2, 2)),
                    next_obs=np.full((1, 2, 1), t + 1), next_pos=np.zeros((1, 2, 2)), next_live=live[t])
    assert memory.size == 3
    rew, disc, nxt = memory.data["rew"][:3], memory.disc[:3], memory.data["next_obs"][:3, 0, 0]
    np.testing.assert_allclose(rew[0], [1 + gamma * 2, 10 + gamma * 20])
    np.testing.assert_allclose(rew[1], [2 + gamma * 3, 20.0])  # buoy 1 earns nothing once lost
    np.testing.assert_allclose(rew[2], [3.0, 0.0])
    np.testing.assert_allclose(disc, [gamma**2, gamma**2, gamma])
    assert nxt.tolist() == [2.0, 3.0, 3.0]
    assert memory.data["next_live"][:3].tolist() == [[True, True], [True, False], [True, False]]
    assert memory.data["live"][:3].tolist() == [[True, True], [True, True], [True, False]]


def test_n_step_below_one_is_refused():
    with pytest.raises(ValueError, match="n >= 1"):
        NStepWriter(Replay(4, 2, 2), 0, 0.9)


def test_the_loop_keeps_the_best_actor_by_its_tie_rule():
    """``TrainingLoop.keep``: a better score replaces the kept actor; an equal one replaces it for the per-region
    runs ("later") and not for a fine-tuning, which keeps its starting weights unless training improves on them."""
    from replicate.learn.loop import TrainingLoop

    for ties, kept_on_tie in (("later", 2), ("earlier", 1)):
        loop = TrainingLoop(agent=None, cfg=None, memories=[Replay(4, 2, 2)], sample_rngs=[None], stacked=False)
        assert loop.keep(0, 0.5, 1, lambda: {"w": 1}, ties)
        assert not loop.keep(0, 0.4, 2, lambda: {"w": 2}, ties)
        assert loop.keep(0, 0.5, 2, lambda: {"w": 2}, ties) == (kept_on_tie == 2)
        assert loop.kept[0] == {"episodes": kept_on_tie, "score": 0.5, "actor": {"w": kept_on_tie}}
