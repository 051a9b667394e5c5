"""MADDPG (Lowe et al. 2017) for N agents with batched networks, after openai/maddpg (SPEC §5).

Centralised critics Q_i(x, a_1..a_N) see every observation and action; decentralised actors μ_i(o_i) see their
own observation. The N agents' networks are stacked (weights [N, in, out]) and evaluated with one ``baddbmm``
per layer, so an update of all agents is one forward/backward pass, not a Python loop over agents. Because
each agent's parameters and Adam state are separate slices, this is the same algorithm as N separate learners.

``reward_mode`` ``"shared"`` is the original collaborative MADDPG (every critic learns the team reward, the
agents' mean; for SW-MARL, which already returns one r to everyone, that is r itself); ``"individual"`` is the
paper's modified MADDPG (critic i learns agent i's own reward, eq. 6).
"""

from __future__ import annotations

import copy
from dataclasses import dataclass

import numpy as np
import torch
from torch import nn

from .config import MADDPGConfig


class BatchedMLP(nn.Module):
    """N independent ReLU MLPs evaluated at once: x [N, B, in] → [N, B, out].

    Glorot-uniform weights and zero biases (openai/maddpg's ``fully_connected`` defaults), drawn from
    ``generator``.
    """

    def __init__(self, n: int, sizes: list[int], generator: torch.Generator):
        super().__init__()
        self.weights = nn.ParameterList()
        self.biases = nn.ParameterList()
        for fan_in, fan_out in zip(sizes[:-1], sizes[1:]):
            bound = (6.0 / (fan_in + fan_out)) ** 0.5
            w = (torch.rand(n, fan_in, fan_out, generator=generator) * 2 - 1) * bound
            self.weights.append(nn.Parameter(w))
            self.biases.append(nn.Parameter(torch.zeros(n, 1, fan_out)))

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        last = len(self.weights) - 1
        for k, (w, b) in enumerate(zip(self.weights, self.biases)):
            x = torch.baddbmm(b, x, w)
            if k < last:
                x = torch.relu_(x)
        return x


class ReplayBuffer:
    """Preallocated ring buffer of joint transitions: obs/next_obs [C, N, obs_dim], act [C, N, act_dim],
    rew [C, N] (float32)."""

    def __init__(self, capacity: int, n_agents: int, obs_dim: int, act_dim: int):
        self.capacity = capacity
        self.obs = np.zeros((capacity, n_agents, obs_dim), np.float32)
        self.act = np.zeros((capacity, n_agents, act_dim), np.float32)
        self.rew = np.zeros((capacity, n_agents), np.float32)
        self.next_obs = np.zeros((capacity, n_agents, obs_dim), np.float32)
        self.ptr = 0
        self.size = 0

    def add(self, obs: np.ndarray, act: np.ndarray, rew: np.ndarray, next_obs: np.ndarray) -> None:
        """Add a batch of E transitions (leading axis E). No transition is terminal: episodes end by time limit."""
        idx = (self.ptr + np.arange(len(obs))) % self.capacity
        self.obs[idx], self.act[idx], self.rew[idx], self.next_obs[idx] = obs, act, rew, next_obs
        self.ptr = int((self.ptr + len(obs)) % self.capacity)
        self.size = min(self.size + len(obs), self.capacity)

    def sample(self, rng: np.random.Generator, batch: int) -> Batch:
        """One minibatch of joint transitions for all agents (openai/maddpg draws one per agent; see
        docs/DEVIATIONS.md). → tensors with leading [B]."""
        idx = rng.integers(0, self.size, size=batch)
        t = torch.from_numpy
        return Batch(t(self.obs[idx]), t(self.act[idx]), t(self.rew[idx]), t(self.next_obs[idx]))

    def state_dict(self) -> dict:
        n = self.size
        return {
            "obs": torch.from_numpy(self.obs[:n].copy()),
            "act": torch.from_numpy(self.act[:n].copy()),
            "rew": torch.from_numpy(self.rew[:n].copy()),
            "next_obs": torch.from_numpy(self.next_obs[:n].copy()),
            "ptr": self.ptr,
            "size": self.size,
        }

    def load_state_dict(self, state: dict) -> None:
        n = int(state["size"])
        if n > self.capacity or state["obs"].shape[1:] != self.obs.shape[1:]:
            raise ValueError("replay buffer state does not fit this buffer")
        self.obs[:n], self.act[:n] = state["obs"].numpy(), state["act"].numpy()
        self.rew[:n], self.next_obs[:n] = state["rew"].numpy(), state["next_obs"].numpy()
        self.ptr, self.size = int(state["ptr"]), n


@dataclass
class Batch:
    """Sampled joint transitions: obs/next_obs [B, N, obs_dim], act [B, N, act_dim], rew [B, N]."""

    obs: torch.Tensor
    act: torch.Tensor
    rew: torch.Tensor
    next_obs: torch.Tensor


def clip_grad_per_agent(params: list[torch.Tensor], max_norm: float) -> None:
    """openai/maddpg clips each variable's gradient by norm; here each agent's slice of each stacked tensor."""
    grads = [p.grad for p in params]
    norms = [torch.linalg.vector_norm(g.flatten(1), dim=1).clamp_min_(1e-12) for g in grads]
    scales = [(max_norm / m).clamp_(max=1.0).view(-1, *([1] * (g.dim() - 1))) for m, g in zip(norms, grads)]
    torch._foreach_mul_(grads, scales)


@torch.no_grad()
def soft_update(target: list[torch.Tensor], online: list[torch.Tensor], tau: float) -> None:
    """θ' ← τθ + (1 − τ)θ' for parameter lists."""
    torch._foreach_lerp_(target, online, tau)


class MADDPG:
    """N MADDPG learners with stacked networks. ``act`` for rollouts, ``update`` for one step of all agents."""

    def __init__(
        self,
        n_agents: int,
        obs_dim: int,
        act_dim: int,
        cfg: MADDPGConfig,
        reward_mode: str,
        seed: int,
        device: str = "cpu",
    ):
        if reward_mode not in ("shared", "individual"):
            raise ValueError(f"reward_mode must be 'shared' or 'individual', got {reward_mode!r}")
        self.n, self.obs_dim, self.act_dim = n_agents, obs_dim, act_dim
        self.cfg, self.reward_mode, self.device = cfg, reward_mode, torch.device(device)
        g = torch.Generator().manual_seed(seed)
        joint = n_agents * (obs_dim + act_dim)
        self.actor = BatchedMLP(n_agents, [obs_dim, cfg.hidden, cfg.hidden, act_dim], g).to(self.device)
        self.critic = BatchedMLP(n_agents, [joint, cfg.hidden, cfg.hidden, 1], g).to(self.device)
        self.actor_target = copy.deepcopy(self.actor)
        self.critic_target = copy.deepcopy(self.critic)
        self.actor_opt = torch.optim.Adam(self.actor.parameters(), lr=cfg.actor_lr, fused=True)
        self.critic_opt = torch.optim.Adam(self.critic.parameters(), lr=cfg.critic_lr, fused=True)
        nets = ("actor", "critic", "actor_target", "critic_target")
        self.params = {k: list(getattr(self, k).parameters()) for k in nets}  # load_state_dict copies in place
        self.agents = torch.arange(n_agents, device=self.device)

    @torch.no_grad()
    def policy(self, obs: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Deterministic actions μ_i(o_i): obs [E, N, obs_dim] → (actions [E, N, act_dim], pre-tanh [E, N, act_dim])."""
        x = torch.from_numpy(np.ascontiguousarray(obs.transpose(1, 0, 2))).to(self.device)
        pre = self.actor(x)
        return torch.tanh(pre).transpose(0, 1).cpu().numpy(), pre.transpose(0, 1).cpu().numpy()

    def act(self, obs: np.ndarray, sigma: float, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
        """Exploration actions clip(μ(o) + σ·ε, −1, 1) and the deterministic μ(o), both [E, N, act_dim]."""
        mu, _ = self.policy(obs)
        noisy = mu + sigma * rng.standard_normal(mu.shape) if sigma > 0 else mu
        return np.clip(noisy, -1.0, 1.0).astype(np.float32), mu

    def update(self, batch: Batch) -> dict[str, float]:
        """One gradient step of every agent's critic, then actor, then the soft target update."""
        cfg, n = self.cfg, self.n
        obs, act, rew, next_obs = (t.to(self.device) for t in (batch.obs, batch.act, batch.rew, batch.next_obs))
        bsz = obs.shape[0]
        own_obs = obs.transpose(0, 1)  # [N, B, od]: o_i for actor i
        r = rew.T if self.reward_mode == "individual" else rew.mean(dim=1).expand(n, bsz)  # [N, B]
        x = obs.reshape(1, bsz, -1).expand(n, bsz, n * self.obs_dim)  # every critic sees all observations

        # Critic: y_i = r_i + γ Q'_i(x', μ'_1(o'_1), …, μ'_N(o'_N))   (paper eq. y; no terminal states)
        with torch.no_grad():
            next_act = torch.tanh(self.actor_target(next_obs.transpose(0, 1)))  # [N, B, ad]
            x_next = torch.cat([next_obs.reshape(bsz, -1), next_act.transpose(0, 1).reshape(bsz, -1)], dim=-1)
            y = r + cfg.gamma * self.critic_target(x_next.expand(n, bsz, -1)).squeeze(-1)
        q = self.critic(torch.cat([x, act.reshape(1, bsz, -1).expand(n, bsz, -1)], dim=-1)).squeeze(-1)
        critic_loss = ((q - y) ** 2).mean(dim=1).sum()
        self.critic_opt.zero_grad(set_to_none=True)
        critic_loss.backward()
        clip_grad_per_agent(self.params["critic"], cfg.grad_clip)
        self.critic_opt.step()

        # Actor: ∇θ_i J = E[∇θ_i μ_i(o_i) ∇a_i Q_i(x, a_1, …, μ_i(o_i), …, a_N)] + 1e-3·mean(pre-tanh²)
        pre = self.actor(own_obs)  # [N, B, ad]
        joint = act.unsqueeze(0).repeat(n, 1, 1, 1)  # [N, B, N, ad]: critic i sees the batch's actions ...
        joint[self.agents, :, self.agents] = torch.tanh(pre)  # ... except its own agent's, μ_i(o_i)
        q_pi = self.critic(torch.cat([x, joint.flatten(2)], dim=-1)).squeeze(-1)
        actor_loss = (-q_pi.mean(dim=1) + cfg.actor_reg * (pre**2).mean(dim=(1, 2))).sum()
        self.actor_opt.zero_grad(set_to_none=True)
        actor_loss.backward(inputs=self.params["actor"])  # through Q into μ_i only, not into Q's weights
        clip_grad_per_agent(self.params["actor"], cfg.grad_clip)
        self.actor_opt.step()

        soft_update(self.params["critic_target"], self.params["critic"], cfg.tau)  # θ' ← τθ + (1 − τ)θ'
        soft_update(self.params["actor_target"], self.params["actor"], cfg.tau)
        return {
            "critic_loss": critic_loss.item() / n,
            "q_abs": q.detach().abs().mean().item(),
            "actor_loss": actor_loss.item() / n,
        }

    def state_dict(self) -> dict:
        return {
            "actor": self.actor.state_dict(),
            "critic": self.critic.state_dict(),
            "actor_target": self.actor_target.state_dict(),
            "critic_target": self.critic_target.state_dict(),
            "actor_opt": self.actor_opt.state_dict(),
            "critic_opt": self.critic_opt.state_dict(),
        }

    def load_state_dict(self, state: dict) -> None:
        for name in ("actor", "critic", "actor_target", "critic_target", "actor_opt", "critic_opt"):
            getattr(self, name).load_state_dict(state[name])
