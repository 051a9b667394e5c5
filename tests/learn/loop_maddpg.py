"""The same MADDPG update one agent at a time, in openai/maddpg's structure: N separate ``nn.Sequential``
actors and critics, N optimisers, a Python loop over agents.

It is not used for training. ``tests/learn/test_maddpg.py`` checks that the batched ``MADDPG.update`` gives the same
parameters as this loop, and ``make bench`` times the two.
"""

from __future__ import annotations

import torch
from torch import nn

from replicate.learn.maddpg import MADDPG
from replicate.learn.replay import Batch


def _sequential(net, i: int) -> nn.Sequential:
    layers: list[nn.Module] = []
    for k, (w, b) in enumerate(zip(net.weights, net.biases)):
        lin = nn.Linear(w.shape[1], w.shape[2])
        with torch.no_grad():
            lin.weight.copy_(w[i].T)
            lin.bias.copy_(b[i, 0])
        layers.append(lin)
        if k < len(net.weights) - 1:
            layers.append(nn.ReLU())
    return nn.Sequential(*layers)


class LoopMADDPG:
    """N independent learners initialised from a batched ``MADDPG`` (same weights, fresh Adam states)."""

    def __init__(self, batched: MADDPG):
        self.n, self.cfg, self.reward_mode = batched.n, batched.cfg, batched.reward_mode
        self.actors = [_sequential(batched.actor, i) for i in range(self.n)]
        self.critics = [_sequential(batched.critic, i) for i in range(self.n)]
        self.actor_targets = [_sequential(batched.actor_target, i) for i in range(self.n)]
        self.critic_targets = [_sequential(batched.critic_target, i) for i in range(self.n)]
        self.actor_opts = [torch.optim.Adam(a.parameters(), lr=self.cfg.actor_lr) for a in self.actors]
        self.critic_opts = [torch.optim.Adam(c.parameters(), lr=self.cfg.critic_lr) for c in self.critics]

    def update(self, batch: Batch) -> None:
        cfg, n = self.cfg, self.n
        obs, act, rew, next_obs = batch.obs, batch.act, batch.rew, batch.next_obs
        bsz = obs.shape[0]
        with torch.no_grad():
            next_act = torch.stack([torch.tanh(self.actor_targets[j](next_obs[:, j])) for j in range(n)], dim=1)
            x_next = torch.cat([next_obs.reshape(bsz, -1), next_act.reshape(bsz, -1)], dim=-1)
        x = torch.cat([obs.reshape(bsz, -1), act.reshape(bsz, -1)], dim=-1)
        for i in range(n):
            r = rew[:, i] if self.reward_mode == "individual" else rew.mean(dim=1)
            with torch.no_grad():
                y = r + batch.disc * self.critic_targets[i](x_next).squeeze(-1)
            loss = ((self.critics[i](x).squeeze(-1) - y) ** 2).mean()
            self.critic_opts[i].zero_grad()
            loss.backward()
            for p in self.critics[i].parameters():
                torch.nn.utils.clip_grad_norm_([p], cfg.grad_clip)
            self.critic_opts[i].step()

            pre = self.actors[i](obs[:, i])
            joint = act.clone()
            joint[:, i] = torch.tanh(pre)
            q = self.critics[i](torch.cat([obs.reshape(bsz, -1), joint.reshape(bsz, -1)], dim=-1))
            actor_loss = -q.mean() + cfg.actor_reg * (pre**2).mean()
            self.actor_opts[i].zero_grad()
            actor_loss.backward(inputs=list(self.actors[i].parameters()))  # the critic keeps its own grads
            for p in self.actors[i].parameters():
                torch.nn.utils.clip_grad_norm_([p], cfg.grad_clip)
            self.actor_opts[i].step()
        for targets, onlines in ((self.critic_targets, self.critics), (self.actor_targets, self.actors)):
            for target, online in zip(targets, onlines):
                for tp, p in zip(target.parameters(), online.parameters()):
                    tp.data.lerp_(p.data, cfg.tau)
