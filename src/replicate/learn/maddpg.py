"""MADDPG (Lowe et al. 2017) for N agents with batched networks, after openai/maddpg (SPEC §5).

Centralised critics Q_i(x, a_1..a_N) see every observation and action; decentralised actors μ_i(o_i) see their
own observation. The N agents' networks are stacked (weights [N, in, out]) and evaluated with one batched
matmul per layer, so an update of all agents is one forward/backward pass, not a Python loop over agents. Because
each agent's parameters and Adam state are separate slices, this is the same algorithm as N separate learners.
Several independent runs (seeds) of the N agents can train in one process: their networks are stacked too
(weights [S·N, in, out]) and every array carries a leading run axis [S, ...]. A run's arithmetic does not depend on
the stack it trains in (each stacked matrix is multiplied, reduced and stepped on its own;
``tests/learn/test_training.py`` checks that a run's curve is bit for bit its single-run curve), and the per-operation
overhead that dominates an update at ``tuned``'s batch of 128 is paid once for the stack (``make bench``).
The backward pass is written out (two matmuls per layer) rather than left to autograd: 1.4× faster per update at
the paper's batch of 1024 and as fast at `tuned`'s 128 (``make bench`` section 2), because each matmul takes the
form the CPU BLAS runs fastest and the actor's gradient reads only the critic's own-action columns.

``reward_mode`` ``"shared"`` is the original collaborative MADDPG (every critic learns the team reward, the
agents' mean; for SW-MARL, which already returns one r to everyone, that is r itself); ``"individual"`` is the
paper's modified MADDPG (critic i learns agent i's own reward, eq. 6).
"""

from __future__ import annotations

import copy
from collections.abc import Sequence

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
    ``generator``. ``forward_saving`` and ``backward`` are the training pass: MADDPG's two losses need only
    these two-matmul-per-layer gradients, written out so that each matmul takes its fastest form
    (``stacked_matmul``) and the actor's gradient goes through the critic's own-action columns only.
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
        return self.forward_saving(x)[0]

    @torch.no_grad()
    def forward_saving(self, x: torch.Tensor) -> tuple[torch.Tensor, list[torch.Tensor]]:
        """→ (output [N, B, out], the input of every layer: x and the hidden ReLU outputs, for ``backward``)."""
        inputs, last = [], len(self.weights) - 1
        for k, (w, b) in enumerate(zip(self.weights, self.biases)):
            inputs.append(x)
            x = torch.baddbmm(b, x, w) if w.shape[2] >= 16 else stacked_matmul(x, w) + b
            if k < last:
                x = torch.relu_(x)
        return x, inputs

    @torch.no_grad()
    def backward(self, inputs: list[torch.Tensor], grad_out: torch.Tensor, weight_grads: bool = True) -> torch.Tensor:
        """Back-propagate ∂L/∂output [N, B, out]; store ∂L/∂W, ∂L/∂b in each parameter's ``.grad`` (if
        ``weight_grads``). → ∂L/∂(first layer's pre-activation) [N, B, h₁], from which a caller takes the
        gradient with respect to any input columns: ∂L/∂x = (that) @ W₁ᵀ."""
        d = grad_out
        for k in range(len(self.weights) - 1, -1, -1):
            w, b = self.weights[k], self.biases[k]
            if weight_grads:
                w.grad = stacked_matmul(inputs[k].mT, d).contiguous()  # ∂L/∂W = xᵀ d
                b.grad = d.sum(dim=1, keepdim=True)
            if k > 0:  # ∂L/∂x = d Wᵀ, then through the ReLU (its output is the saved input)
                d = stacked_matmul(d, w.mT)
                torch.ops.aten.threshold_backward.grad_input(d, inputs[k], 0, grad_input=d)
        return d


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
def adam_step(opt: torch.optim.Adam, runs: int = 1) -> None:
    """``opt.step()`` for a one-group fused Adam over ``runs`` stacked runs, without the ``Optimizer.step``
    wrapper: the same ``_fused_adam_`` kernel on the optimiser's own state, so the result and ``state_dict`` are the
    same. The wrapper's bookkeeping cost as much as the kernel on ``tuned``'s small tensors (``make bench``
    section 2)."""
    (group,) = opt.param_groups
    params = group["params"]
    for p in params:
        if p not in opt.state:  # the first step creates the state, as ``opt.step()`` does
            opt.state[p] = {"step": torch.zeros((), device=p.device), "exp_avg": torch.zeros_like(p),
                            "exp_avg_sq": torch.zeros_like(p)}
    state = [opt.state[p] for p in params]
    steps = [s["step"] for s in state]
    torch._foreach_add_(steps, 1)
    beta1, beta2 = group["betas"]
    torch._fused_adam_(
        per_run(params, runs), per_run([p.grad for p in params], runs), per_run([s["exp_avg"] for s in state], runs),
        per_run([s["exp_avg_sq"] for s in state], runs), [], [step for step in steps for _ in range(runs)],
        lr=group["lr"], beta1=beta1, beta2=beta2, weight_decay=group["weight_decay"], eps=group["eps"],
        amsgrad=False, maximize=False,
    )


@torch.no_grad()
def soft_update(target: list[torch.Tensor], online: list[torch.Tensor], tau: float, runs: int = 1) -> None:
    """θ' ← τθ + (1 − τ)θ' for parameter lists of ``runs`` stacked runs."""
    torch._foreach_lerp_(per_run(target, runs), per_run(online, runs), tau)


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
        self.actor_opt = torch.optim.Adam(self.actor.parameters(), lr=cfg.actor_lr, fused=True)
        self.critic_opt = torch.optim.Adam(self.critic.parameters(), lr=cfg.critic_lr, fused=True)
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

    @torch.no_grad()
    def update(self, batch: Batch) -> dict[str, np.ndarray]:
        """One gradient step of every agent's critic, then actor, then the soft target update, in every run.
        ``batch`` is [S, B, ...] (``Batch.stack``), or [B, ...] with one run. → each run's diagnostics, [S].

        The gradients are written out (``BatchedMLP.backward``); ``tests/learn/test_maddpg.py`` checks them against
        the per-agent autograd loop of ``tests/learn/loop_maddpg.py``."""
        cfg, n, s = self.cfg, self.n, self.runs
        obs, act, next_obs = (self._with_runs(t.to(self.device), 3) for t in (batch.obs, batch.act, batch.next_obs))
        rew, disc = self._with_runs(batch.rew.to(self.device), 2), self._with_runs(batch.disc.to(self.device), 1)
        bsz = obs.shape[1]

        def each_critic(t):  # [S, B, ...] → [S·N, B, ...]: every critic of run s sees run s's t
            return t.unsqueeze(1).expand(s, n, *t.shape[1:]).reshape(s * n, *t.shape[1:])

        def per_agent(t):  # [S, B, N, ...] → [S·N, B, ...]: agent i's own slice
            return t.transpose(1, 2).reshape(s * n, bsz, *t.shape[3:])

        r = per_agent(rew) if self.reward_mode == "individual" else each_critic(rew.mean(dim=2))  # [S·N, B]

        def joint_input(o, a):  # critic input [x, a_1..a_N], [S, B, N, ·] twice → [S·N, B, N·(od + ad)]
            return each_critic(torch.cat([o.reshape(s, bsz, -1), a.reshape(s, bsz, -1)], dim=-1))

        # Critic: y_i = r_i + γ Q'_i(x', μ'_1(o'_1), …, μ'_N(o'_N))   (paper eq. y; no terminal states; an m-step
        # transition holds r_i = Σ_k γᵏ r_i,t+k and disc = γᵐ, Sutton & Barto §7.1)
        next_act = torch.tanh(self.actor_target(per_agent(next_obs))).view(s, n, bsz, -1).transpose(1, 2)
        y = r + each_critic(disc) * self.critic_target(joint_input(next_obs, next_act)).squeeze(-1)
        q, saved = self.critic.forward_saving(joint_input(obs, act))
        td = q.squeeze(-1) - y  # [S·N, B]
        self.critic.backward(saved, (2.0 / bsz) * td.unsqueeze(-1))  # ∂L/∂Q_i = 2(Q_i − y_i)/B
        clip_grad_per_agent(self.params["critic"], cfg.grad_clip)
        adam_step(self.critic_opt, s)

        # Actor: ∇θ_i J = E[∇θ_i μ_i(o_i) ∇a_i Q_i(x, a_1, …, μ_i(o_i), …, a_N)] + 1e-3·mean(pre-tanh²)
        pre, actor_saved = self.actor.forward_saving(per_agent(obs))  # [S·N, B, ad]
        mu = torch.tanh(pre)
        joint = saved[0].clone()  # critic i sees the batch's observations and actions ...
        actions = joint.view(s, n, bsz, -1)[..., n * self.obs_dim:].view(s, n, bsz, n, -1)  # [S, N, B, N, ad]
        actions[:, self.agents, :, self.agents] = mu.view(s, n, bsz, -1).transpose(0, 1)  # ... but its own, μ_i(o_i)
        q_pi, saved = self.critic.forward_saving(joint)
        d_z1 = self.critic.backward(saved, torch.full_like(q_pi, -1.0 / bsz), weight_grads=False)  # −mean Q_i
        d_mu = stacked_matmul(d_z1, self.critic.weights[0][self.stacked, self.own_action_rows].mT)
        d_pre = d_mu * (1.0 - mu * mu) + (2.0 * cfg.actor_reg / pre[0].numel()) * pre  # through tanh; + reg
        self.actor.backward(actor_saved, d_pre)  # through μ_i only, not into Q's weights
        clip_grad_per_agent(self.params["actor"], cfg.grad_clip)
        adam_step(self.actor_opt, s)

        soft_update(self.params["critic_target"], self.params["critic"], cfg.tau, s)  # θ' ← τθ + (1 − τ)θ'
        soft_update(self.params["actor_target"], self.params["actor"], cfg.tau, s)
        losses = (td**2).mean(dim=1).view(s, n)  # each critic's loss
        return {
            "critic_loss": np.array([run.sum().item() / n for run in losses]),
            "q_abs": np.array([run.abs().mean().item() for run in q.view(s, -1)]),
        }
