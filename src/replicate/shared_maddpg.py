"""MADDPG for a fleet of any size: one actor shared by every buoy, one centralised critic that pools the others.

The per-region MADDPG (``maddpg.py``) gives each of N buoys its own actor and a critic over the joint
observation of exactly N: it cannot run with another N, and each lake is a new training. Here (Lowe et al. 2017's
centralised training with decentralised execution, kept; parameters shared as in Gupta et al. 2017):

- the actor μ(o_i) maps one buoy's local observation (``sensors``) to its action, the same network for all;
- the critic scores buoy i's action with what the others do, whatever their number:
  Q(o_i, a_i, mean_{j ≠ i, live} φ(o_j, a_j, p_j − p_i)), φ an embedding of one other buoy seen from i
  (its observation, action and relative position; a mean, so any N and any order), over the whole fleet or,
  with ``pool_range``, over the buoys within that distance of i, and with ``pool_neighbours`` over its K nearest
  (φ then runs on [B, N, K], not [B, N, N]: the update's cost grows with N, not N²);
- each buoy's reward is its own (CR's eq. (5)–(6) with the difference credit), its loss its own TD error.

Batches are ``[B, N, ...]`` padded to the largest fleet of the batch; ``live`` [B, N] marks the real, working
buoys (padding and lost buoys are False): they are neither scored nor pooled.
"""

from __future__ import annotations

import copy
from dataclasses import dataclass

import torch
from torch import nn

from .config import SharedLearnerConfig


def mlp(sizes: list[int]) -> nn.Sequential:
    """ReLU MLP with a linear last layer."""
    layers: list[nn.Module] = []
    for k, (a, b) in enumerate(zip(sizes[:-1], sizes[1:])):
        layers.append(nn.Linear(a, b))
        if k < len(sizes) - 2:
            layers.append(nn.ReLU())
    return nn.Sequential(*layers)


class SharedActor(nn.Module):
    """a_i = tanh(μ(o_i)) for every buoy: obs [..., obs_dim] → (action, pre-tanh) [..., act_dim]."""

    def __init__(self, obs_dim: int, act_dim: int, hidden: int):
        super().__init__()
        self.net = mlp([obs_dim, hidden, hidden, act_dim])

    def forward(self, obs: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        pre = self.net(obs)
        return torch.tanh(pre), pre


class PooledCritic(nn.Module):
    """Q_i for every buoy of a fleet of any size: obs [B, N, od], act [B, N, ad], pos [B, N, 2], live [B, N]
    → [B, N]. ``pooled`` alone gives the others' mean embedding [B, N, embed]."""

    def __init__(self, obs_dim: int, act_dim: int, hidden: int, embed: int, pool_range: float = 0.0,
                 pool_neighbours: int = 0):
        super().__init__()
        self.phi = mlp([obs_dim + act_dim + 2, embed, embed])
        self.q = mlp([obs_dim + act_dim + embed, hidden, hidden, 1])
        self.pool_range, self.pool_neighbours = pool_range, pool_neighbours

    def pooled(self, obs, act, pos, live) -> torch.Tensor:
        n = obs.shape[1]
        rel = pos[:, None, :, :] - pos[:, :, None, :]  # [B, N (i), N (j), 2]: p_j − p_i
        other = torch.cat([obs, act], dim=-1)[:, None].expand(-1, n, -1, -1)  # [B, N (i), N (j), od + ad]
        others = live[:, None, :] & ~torch.eye(n, dtype=torch.bool, device=obs.device)  # j live, j ≠ i
        if self.pool_range > 0:  # only the buoys near i (the difference credit depends on no others)
            others = others & (rel.square().sum(-1) <= self.pool_range**2)
        if 0 < self.pool_neighbours < n - 1:  # only i's K nearest: φ on [B, N, K], not [B, N, N]
            far = rel.square().sum(-1).masked_fill(~others, torch.inf)
            nearest, idx = far.topk(self.pool_neighbours, dim=2, largest=False)  # [B, N, K]
            others = torch.isfinite(nearest)
            rel = rel.gather(2, idx[..., None].expand(-1, -1, -1, rel.shape[-1]))
            other = other.gather(2, idx[..., None].expand(-1, -1, -1, other.shape[-1]))
        e = self.phi(torch.cat([other, rel], dim=-1))  # [B, N, N or K, embed]
        w = others.to(e.dtype)
        return (e * w[..., None]).sum(dim=2) / w.sum(dim=2).clamp(min=1.0)[..., None]

    def forward(self, obs, act, pos, live, pooled: torch.Tensor | None = None) -> torch.Tensor:
        pooled = self.pooled(obs, act, pos, live) if pooled is None else pooled
        return self.q(torch.cat([obs, act, pooled], dim=-1)).squeeze(-1)


@dataclass
class FleetBatch:
    """Transitions of padded fleets, [B, N, ...]: ``rew`` [B, N] (m-step returns), ``disc`` [B] (γᵐ), ``live`` and
    ``next_live`` [B, N] bool."""

    obs: torch.Tensor
    act: torch.Tensor
    rew: torch.Tensor
    next_obs: torch.Tensor
    pos: torch.Tensor
    next_pos: torch.Tensor
    live: torch.Tensor
    next_live: torch.Tensor
    disc: torch.Tensor


class SharedMADDPG:
    """One shared actor and one pooled critic with their targets, and the update that trains them."""

    def __init__(self, obs_dim: int, act_dim: int, cfg: SharedLearnerConfig, seed: int = 0):
        self.cfg = cfg
        with torch.random.fork_rng():  # the initial weights from ``seed``, leaving torch's global stream as it was
            torch.manual_seed(seed)
            self.actor = SharedActor(obs_dim, act_dim, cfg.hidden)
            self.critic = PooledCritic(obs_dim, act_dim, cfg.hidden, cfg.embed, cfg.pool_range,
                                       cfg.pool_neighbours)
        self.actor_target, self.critic_target = copy.deepcopy(self.actor), copy.deepcopy(self.critic)
        self.actor_opt = torch.optim.Adam(self.actor.parameters(), lr=cfg.actor_lr)
        self.critic_opt = torch.optim.Adam(self.critic.parameters(), lr=cfg.critic_lr)

    def update(self, b: FleetBatch) -> dict[str, float]:
        cfg = self.cfg
        live, n_live = b.live.float(), b.live.float().sum().clamp(min=1.0)

        # Critic: y_i = r_i + γᵐ Q'(o'_i, μ'(o'_i), pool_j φ'(o'_j, μ'(o'_j), p'_j − p'_i))   (MADDPG's target)
        with torch.no_grad():  # a buoy lost before the bootstrap step has no future: its target is its return
            next_act, _ = self.actor_target(b.next_obs)
            q_next = self.critic_target(b.next_obs, next_act, b.next_pos, b.next_live) * b.next_live
            y = b.rew + b.disc[:, None] * q_next
        q = self.critic(b.obs, b.act, b.pos, b.live)
        critic_loss = (((q - y) ** 2) * live).sum() / n_live
        self.critic_opt.zero_grad()
        critic_loss.backward()
        nn.utils.clip_grad_norm_(self.critic.parameters(), cfg.grad_clip)
        self.critic_opt.step()

        # Actor: ∇J = E_i[∇μ(o_i) ∇_{a_i} Q(o_i, a_i, pool_{j≠i} φ(o_j, a_j, ·))|_{a_i = μ(o_i)}]: the others keep
        # their taken actions, so the pool does not depend on μ here
        with torch.no_grad():
            pooled = self.critic.pooled(b.obs, b.act, b.pos, b.live)
        mu, pre = self.actor(b.obs)
        q_pi = self.critic(b.obs, mu, b.pos, b.live, pooled=pooled)
        actor_loss = -(q_pi * live).sum() / n_live + cfg.actor_reg * ((pre**2).mean(-1) * live).sum() / n_live
        self.actor_opt.zero_grad()
        actor_loss.backward(inputs=list(self.actor.parameters()))  # through μ only, not into Q's weights
        nn.utils.clip_grad_norm_(self.actor.parameters(), cfg.grad_clip)
        self.actor_opt.step()

        with torch.no_grad():  # θ' ← τθ + (1 − τ)θ'
            for net, target in ((self.critic, self.critic_target), (self.actor, self.actor_target)):
                for p, tp in zip(net.parameters(), target.parameters()):
                    tp.lerp_(p, cfg.tau)
        return {"critic_loss": critic_loss.item(), "q_abs": ((q.detach().abs() * live).sum() / n_live).item()}

    def scale_learning_rates(self, factor: float) -> None:
        """Set the actor's and critic's learning rates to ``factor`` × their configured values."""
        self.actor_opt.param_groups[0]["lr"] = factor * self.cfg.actor_lr
        self.critic_opt.param_groups[0]["lr"] = factor * self.cfg.critic_lr

    @torch.no_grad()
    def act(self, obs, sigma: float, generator: torch.Generator) -> torch.Tensor:
        """Behaviour actions for obs [..., obs_dim]: μ(o) plus Gaussian noise σ, clipped to [−1, 1]."""
        mu, _ = self.actor(torch.as_tensor(obs, dtype=torch.float32))
        noise = torch.randn(mu.shape, generator=generator) * sigma
        return (mu + noise).clamp(-1.0, 1.0)
