"""MADDPG (Lowe et al. 2017) for N agents with batched networks, after openai/maddpg (SPEC §5).

Centralised critics Q_i(x, a_1..a_N) see every observation and action; decentralised actors μ_i(o_i) see their
own observation. The N agents' networks are stacked (weights [N, in, out]) and evaluated with one batched
matmul per layer, so an update of all agents is one forward/backward pass, not a Python loop over agents. Because
each agent's parameters and Adam state are separate slices, this is the same algorithm as N separate learners.
Several independent runs (seeds) of the N agents can train in one process: their networks are stacked too
(weights [S·N, in, out]) and every array carries a leading run axis [S, ...].

``MADDPG.update`` is the algorithm as it reads: two losses and autograd, the critic target one line that mirrors
eq. (y). ``tests/learn/test_maddpg.py`` checks its gradients against a per-agent loop of separate networks
(``tests/learn/loop_maddpg.py``), and a stack of runs against each run alone, bit for bit.

``reward_mode`` ``"shared"`` is the original collaborative MADDPG (every critic learns the team reward, the
agents' mean; for SW-MARL, which already returns one r to everyone, that is r itself); ``"individual"`` is the
paper's modified MADDPG (critic i learns agent i's own reward, eq. 6).
"""

from __future__ import annotations

import copy
import dataclasses
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import torch
from torch import nn

from replicate.core.sections import MADDPGConfig
from replicate.learn.replay import Batch


def stacked_matmul(a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
    """a @ b for stacks of matrices, [N, M, K] × [N, K, P] → [N, M, P], in the form the CPU BLAS runs fastest.

    ``bmm`` is slow on some skinny shapes (``make bench`` section 0 times them). An inner size of 1 is an outer
    product, a broadcast multiply. A narrow output (P < 16) of a transposed ``a`` (a weight gradient xᵀd of a 64 → 1
    or 64 → 2 layer) is computed as (bᵀ aᵀ)ᵀ, where aᵀ is the stored tensor and the wide dimension becomes the
    output's rows: 2-3x faster than ``bmm`` on the transposed view. A narrow output of a stored ``a`` (the forward
    pass of a 64 → 1 or 64 → 2 layer, with stored weights) is computed column by column as row-vector products
    (b[:, :, j]ᵀ aᵀ)ᵀ: on this project's AVX-512 CPU with MKL, 2-3.4x faster than ``bmm`` and the same bits (``bmm``
    takes a slow path for an output of one or two columns; a 64 → 2 layer as one (bᵀ aᵀ)ᵀ, or a transposed ``b``
    such as the actor gradient's own-action rows, would round differently).
    """
    if b.shape[1] == 1:
        return a * b
    if b.shape[2] < 16 and not a.is_contiguous():
        return torch.bmm(b.mT, a.mT).mT
    if b.shape[2] <= 2 and b.is_contiguous():
        return torch.cat([torch.bmm(b[:, :, j:j + 1].mT, a.mT) for j in range(b.shape[2])], dim=1).mT
    if b.shape[1] < 16 and not b.is_contiguous():
        b = b.contiguous()  # a tiny copy: bmm on a transposed [N, 2, 64] view was 5x slower, same bits
    return torch.bmm(a, b)


class BatchedMLP(nn.Module):
    """N independent ReLU MLPs evaluated at once: x [N, B, in] → [N, B, out].

    Glorot-uniform weights and zero biases (openai/maddpg's ``fully_connected`` defaults), drawn from
    ``generator``. Each layer's matmul takes the form the CPU BLAS runs fastest (``stacked_matmul``).
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

    @classmethod
    def stack(cls, nets: list[BatchedMLP]) -> BatchedMLP:
        """One network holding ``nets`` one after another along the stacked axis: [n₁ + n₂ + …, in, out]."""
        out = copy.deepcopy(nets[0])
        with torch.no_grad():
            for k in range(len(out.weights)):
                out.weights[k] = nn.Parameter(torch.cat([net.weights[k] for net in nets]))
                out.biases[k] = nn.Parameter(torch.cat([net.biases[k] for net in nets]))
        return out

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        """x [N, B, in] → [N, B, out] (the rollouts' form of every matmul)."""
        return self.layers(x)[0]

    def differentiable(self, x: torch.Tensor) -> torch.Tensor:
        """``forward`` in the form autograd differentiates fastest, one ``baddbmm`` per layer: the same function,
        its narrow layers rounded as ``bmm`` rounds them (``make bench`` section 2)."""
        last = len(self.weights) - 1
        for k, (w, b) in enumerate(zip(self.weights, self.biases)):
            x = torch.baddbmm(b, x, w)
            x = torch.relu(x) if k < last else x
        return x

    def layers(self, x: torch.Tensor) -> tuple[torch.Tensor, list[torch.Tensor]]:
        """→ (output [N, B, out], the input of every layer: x and the hidden ReLU outputs)."""
        inputs, last = [], len(self.weights) - 1
        for k, (w, b) in enumerate(zip(self.weights, self.biases)):
            inputs.append(x)
            x = torch.baddbmm(b, x, w) if w.shape[2] >= 16 else stacked_matmul(x, w) + b
            if k < last:
                x = torch.relu_(x)
        return x, inputs


def clip_grad_per_agent(params: list[torch.Tensor], max_norm: float) -> None:
    """openai/maddpg clips each variable's gradient by norm; here each agent's slice of each stacked tensor."""
    grads = [p.grad for p in params]
    norms = torch.stack([torch.linalg.vector_norm(g.flatten(1), dim=1) for g in grads])  # [variables, N]
    scales = (max_norm / norms.clamp_min_(1e-12)).clamp_(max=1.0)
    torch._foreach_mul_(grads, [s.view(-1, *([1] * (g.dim() - 1))) for s, g in zip(scales, grads)])


def per_run(tensors: list[torch.Tensor], runs: int) -> list[torch.Tensor]:
    """Each stacked tensor split into its ``runs`` runs' parts (views). An elementwise kernel vectorises a tensor
    in blocks and finishes its last few elements one by one, with different rounding; given one run's part as a
    tensor of its own, it rounds every element as it would in a one-run MADDPG."""
    return tensors if runs == 1 else [part for t in tensors for part in t.chunk(runs)]


@torch.no_grad()
def soft_update(target: list[torch.Tensor], online: list[torch.Tensor], tau: float, runs: int = 1) -> None:
    """θ' ← τθ + (1 − τ)θ' for parameter lists of ``runs`` stacked runs."""
    torch._foreach_lerp_(per_run(target, runs), per_run(online, runs), tau)


@dataclass
class Views:
    """A minibatch of S runs as the N critics and actors read it: obs/act/next_obs [S, B, N, ·]; ``r`` [S·N, B]
    (critic i's reward) and ``disc`` [S·N, B] (γᵐ), row s·N + i being run s's agent i."""

    runs: int
    n: int
    batch: int
    obs: torch.Tensor
    act: torch.Tensor
    next_obs: torch.Tensor
    r: torch.Tensor | None = None
    disc: torch.Tensor | None = None

    def each_critic(self, t: torch.Tensor) -> torch.Tensor:
        """[S, B, ...] → [S·N, B, ...]: every critic of run s sees run s's t."""
        return t.unsqueeze(1).expand(self.runs, self.n, *t.shape[1:]).reshape(self.runs * self.n, *t.shape[1:])

    def per_agent(self, t: torch.Tensor) -> torch.Tensor:
        """[S, B, N, ...] → [S·N, B, ...]: agent i's own slice."""
        return t.transpose(1, 2).reshape(self.runs * self.n, self.batch, *t.shape[3:])

    def joint(self, o: torch.Tensor, a: torch.Tensor) -> torch.Tensor:
        """The critics' input [x, a_1..a_N] from o, a [S, B, N, ·] → [S·N, B, N·(od + ad)]."""
        s, b = self.runs, self.batch
        return self.each_critic(torch.cat([o.reshape(s, b, -1), a.reshape(s, b, -1)], dim=-1))


NETWORKS = ("actor", "critic", "actor_target", "critic_target")
OPTIMISERS = ("actor_opt", "critic_opt")


class MADDPG:
    """N MADDPG learners with stacked networks, for S independent runs at once (one per seed).

    ``act`` for rollouts, ``update`` for one step of all agents of all runs. Arrays carry a leading run axis
    [S, ...]; with one seed it may be left out. ``run_stack`` reads and writes one run's part for its checkpoint."""

    def __init__(
        self,
        n_agents: int,
        obs_dim: int,
        act_dim: int,
        cfg: MADDPGConfig,
        reward_mode: str,
        seed: int | Sequence[int],
        device: str = "cpu",
    ):
        if reward_mode not in ("shared", "individual"):
            raise ValueError(f"reward_mode must be 'shared' or 'individual', got {reward_mode!r}")
        seeds = [seed] if isinstance(seed, int) else list(seed)
        if not seeds:
            raise ValueError("MADDPG needs at least one seed")
        self.n, self.runs, self.obs_dim, self.act_dim = n_agents, len(seeds), obs_dim, act_dim
        self.cfg, self.reward_mode, self.device = cfg, reward_mode, torch.device(device)
        joint = n_agents * (obs_dim + act_dim)
        actors, critics = [], []
        for s in seeds:  # each run draws its actor, then its critic, from its own generator
            g = torch.Generator().manual_seed(s)
            actors.append(BatchedMLP(n_agents, [obs_dim, cfg.hidden, cfg.hidden, act_dim], g))
            critics.append(BatchedMLP(n_agents, [joint, cfg.hidden, cfg.hidden, 1], g))
        self.actor = BatchedMLP.stack(actors).to(self.device)  # [S·N, ...]: run s holds rows s·N … s·N + N − 1
        self.critic = BatchedMLP.stack(critics).to(self.device)
        self.actor_target = copy.deepcopy(self.actor)
        self.critic_target = copy.deepcopy(self.critic)
        # the multi-tensor Adam rounds every element of a stacked tensor as it rounds it in a one-run tensor, so a
        # run in a stack is bit for bit the run alone; the fused kernel finishes a tensor's tail elements with other
        # rounding, and is no faster at these sizes (``make bench`` section 2)
        self.actor_opt = torch.optim.Adam(self.actor.parameters(), lr=cfg.actor_lr, foreach=True)
        self.critic_opt = torch.optim.Adam(self.critic.parameters(), lr=cfg.critic_lr, foreach=True)
        self.params = {k: list(getattr(self, k).parameters()) for k in NETWORKS}  # run_stack loads in place
        self.agents = torch.arange(n_agents, device=self.device)
        # rows of critic i's first layer that read agent i's own action: the joint input is [o_1..o_N, a_1..a_N]
        own = n_agents * obs_dim + self.agents[:, None] * act_dim + torch.arange(act_dim, device=self.device)
        self.own_action_rows = own.repeat(self.runs, 1)  # [S·N, ad]
        self.stacked = torch.arange(self.runs * n_agents, device=self.device)[:, None]  # [S·N, 1]

    def scale_learning_rates(self, factor: float) -> None:
        """Set the actor and critic learning rates to ``factor`` × their configured values."""
        self.actor_opt.param_groups[0]["lr"] = factor * self.cfg.actor_lr
        self.critic_opt.param_groups[0]["lr"] = factor * self.cfg.critic_lr

    def _with_runs(self, x, tail: int):
        """An array of one run gains the run axis; one that has it is checked: [S, ...] with ``tail`` axes after."""
        if x.ndim == tail and self.runs == 1:
            return x[None]
        if x.ndim != tail + 1 or x.shape[0] != self.runs:
            raise ValueError(f"expected a leading run axis of {self.runs}, got shape {tuple(x.shape)}")
        return x

    @torch.no_grad()
    def policy(self, obs: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Deterministic actions μ_i(o_i): obs [S, E, N, obs_dim] → (actions, pre-tanh), both [S, E, N, act_dim];
        with one run also [E, N, obs_dim] → [E, N, act_dim]."""
        runs = self._with_runs(obs, 3)
        s, e = runs.shape[:2]
        x = torch.from_numpy(np.ascontiguousarray(runs.transpose(0, 2, 1, 3).reshape(s * self.n, e, -1)))
        pre = self.actor(x.to(self.device)).view(s, self.n, e, -1).transpose(1, 2).cpu()
        pre = pre.reshape(*obs.shape[:-1], -1)
        return torch.tanh(pre).numpy(), pre.numpy()

    def act(self, obs: np.ndarray, sigma: float, rngs: list[np.random.Generator]) -> tuple[np.ndarray, np.ndarray]:
        """Exploration actions clip(μ(o) + σ·ε, −1, 1) and the deterministic μ(o), shaped as ``policy``'s; run s
        draws its ε from ``rngs[s]``."""
        mu, _ = self.policy(obs)
        if sigma <= 0:
            return mu.astype(np.float32), mu
        runs = mu.reshape(len(rngs), *mu.shape[-3:])
        noisy = np.stack([m + sigma * rng.standard_normal(m.shape) for m, rng in zip(runs, rngs, strict=True)])
        return np.clip(noisy, -1.0, 1.0).astype(np.float32).reshape(mu.shape), mu

    def unpack(self, batch: Batch) -> Views:
        """The minibatch as the critics and actors read it (``Views``)."""
        s, n = self.runs, self.n
        obs, act, next_obs = (self._with_runs(t.to(self.device), 3) for t in (batch.obs, batch.act, batch.next_obs))
        rew, disc = self._with_runs(batch.rew.to(self.device), 2), self._with_runs(batch.disc.to(self.device), 1)
        v = Views(s, n, obs.shape[1], obs, act, next_obs)
        r = v.per_agent(rew) if self.reward_mode == "individual" else v.each_critic(rew.mean(dim=2))
        return dataclasses.replace(v, r=r, disc=v.each_critic(disc))

    def with_own_actions(self, v: Views, joint: torch.Tensor, mu: torch.Tensor) -> torch.Tensor:
        """Critic i's joint input ``joint`` [S·N, B, N·(od + ad)] with agent i's action replaced by μ_i(o_i)
        (mu [S·N, B, ad]); the other agents keep the batch's actions."""
        s, n, bsz = v.runs, v.n, v.batch
        joint = joint.clone()
        actions = joint.view(s, n, bsz, -1)[..., n * self.obs_dim:].view(s, n, bsz, n, -1)  # [S, N, B, N, ad]
        actions[:, self.agents, :, self.agents] = mu.view(s, n, bsz, -1).transpose(0, 1)
        return joint

    def update(self, batch: Batch) -> dict[str, np.ndarray]:
        """One gradient step of every agent's critic, then actor, then the soft target update, in every run.
        ``batch`` is [S, B, ...] (``Batch.stack``), or [B, ...] with one run. → each run's diagnostics, [S]."""
        cfg, v = self.cfg, self.unpack(batch)

        # Critic: y_i = r_i + γ Q'_i(x', μ'_1(o'_1), …, μ'_N(o'_N))   (paper eq. y; no terminal states; an m-step
        # transition holds r_i = Σ_k γᵏ r_i,t+k and disc = γᵐ, Sutton & Barto §7.1)
        with torch.no_grad():
            next_act = torch.tanh(self.actor_target(v.per_agent(v.next_obs))).view(v.runs, v.n, v.batch, -1)
            y = v.r + v.disc * self.critic_target(v.joint(v.next_obs, next_act.transpose(1, 2))).squeeze(-1)
        joint = v.joint(v.obs, v.act)  # [S·N, B, N·(od + ad)]: the batch's observations and actions
        q = self.critic.differentiable(joint).squeeze(-1)  # [S·N, B]
        critic_loss = ((q - y) ** 2).mean(dim=1).sum()  # Σ_i of critic i's mean squared TD error
        self.critic_opt.zero_grad(set_to_none=True)
        critic_loss.backward()
        clip_grad_per_agent(self.params["critic"], cfg.grad_clip)
        self.critic_opt.step()

        # Actor: ∇θ_i J = E[∇θ_i μ_i(o_i) ∇a_i Q_i(x, a_1, …, μ_i(o_i), …, a_N)] + 1e-3·mean(pre-tanh²)
        pre = self.actor.differentiable(v.per_agent(v.obs))  # [S·N, B, ad]
        q_pi = self.critic.differentiable(self.with_own_actions(v, joint, torch.tanh(pre))).squeeze(-1)
        actor_loss = (-q_pi.mean(dim=1) + cfg.actor_reg * (pre**2).mean(dim=(1, 2))).sum()
        self.actor_opt.zero_grad(set_to_none=True)
        actor_loss.backward(inputs=self.params["actor"])  # through μ_i only, not into Q's weights
        clip_grad_per_agent(self.params["actor"], cfg.grad_clip)
        self.actor_opt.step()

        soft_update(self.params["critic_target"], self.params["critic"], cfg.tau, v.runs)  # θ' ← τθ + (1 − τ)θ'
        soft_update(self.params["actor_target"], self.params["actor"], cfg.tau, v.runs)
        return self.diagnostics(q.detach(), y, v)

    def diagnostics(self, q: torch.Tensor, y: torch.Tensor, v: Views) -> dict[str, np.ndarray]:
        """Each run's mean critic loss over its agents and mean |Q|, [S] each."""
        losses = ((q - y) ** 2).mean(dim=1).view(v.runs, v.n)  # each critic's loss
        return {
            "critic_loss": np.array([run.sum().item() / v.n for run in losses]),
            "q_abs": np.array([run.abs().mean().item() for run in q.view(v.runs, -1)]),
        }
