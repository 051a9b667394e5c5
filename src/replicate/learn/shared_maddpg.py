"""MADDPG for a fleet of any size: one actor shared by every buoy, one centralised critic that pools the others.

The per-region MADDPG (``maddpg.py``) gives each of N buoys its own actor and a critic over the joint
observation of exactly N: it cannot run with another N, and each lake is a new training. Here (Lowe et al. 2017's
centralised training with decentralised execution, kept; parameters shared as in Gupta et al. 2017):

- the actor μ(o_i) maps one buoy's local observation (``sensors``) to its action, the same network for all; with
  ``hops`` it also hears what its neighbours send, over that many rounds of messages (``messages``);
- the critic scores buoy i's action with what the others do, whatever their number:
  Q(o_i, a_i, mean_{j ≠ i, live} φ(o_j, a_j, p_j − p_i)), φ an embedding of one other buoy seen from i
  (its observation, action and relative position; a mean, so any N and any order), over the whole fleet or,
  with ``pool_range``, over the buoys within that distance of i, and with ``pool_neighbours`` over its K nearest
  (φ then runs on [L, K], not [L, N]: the update's cost grows with N, not N²);
- each buoy's reward is its own (CR's eq. (5)–(6) with the difference credit), its loss its own TD error.

Batches are ``[B, N, ...]`` padded to the largest fleet of the batch; ``live`` [B, N] marks the real, working
buoys (padding and lost buoys are False): they are neither scored nor pooled. The networks run on the L buoys in
service only, as rows (b, i), so the padding costs no arithmetic: on fleets of 5-30 padded to 30 (57 % live) one
update took 46 ms against 122 ms for the padded update it replaced, timed side by side on one batch, with the same
losses to float rounding (``tests/learn/test_shared_maddpg.py`` keeps the padded update as the reference).
"""

from __future__ import annotations

import copy
from dataclasses import dataclass

import torch
from torch import nn

from replicate.core.sections import SensorsConfig, SharedLearnerConfig
from replicate.learn.messages import MessageActor
from replicate.learn.networks import mlp, observation_net
from replicate.learn.replay import Batch
from replicate.learn.schedules import prior_gain
from replicate.learn.symmetry import symmetric


class SharedActor(nn.Module):
    """a_i = tanh(μ(o_i)) for every buoy: obs [..., obs_dim] → (action, pre-tanh) [..., act_dim]. With a
    ``symmetry`` group (``symmetry.symmetric``; ``columns`` name the observation's), μ is the MLP averaged over
    the group's turns of the observation, and the policy turns with the world; with a local raster among the
    columns, μ reads it through a small CNN (``networks.observation_net``). With ``hops`` ≥ 1, μ is a
    ``messages.MessageActor`` over the buoys each hears (``sensors``: its K nearest within the range), which
    reads whole fleets: ``fleet``. With ``lloyd_prior`` g, a = tanh(μ(o_i) + g · (c_i − p_i)), c_i − p_i the offset
    to the buoy's local centroid (``local_map.LocalCentroid``): Lloyd's law, which the network corrects."""

    def __init__(self, obs_dim: int, act_dim: int, hidden: int, symmetry: str = "none",
                 columns: list[str] | None = None, hops: int = 0, sensors: SensorsConfig | None = None,
                 layers: int = 2, lloyd_prior: float = 0.0):
        super().__init__()
        self.hops = hops
        self.prior, self.centroid = lloyd_prior, 0  # μ(o) = f(o) + prior · o[centroid_dx, centroid_dy]
        if lloyd_prior:
            if "centroid_dx" not in (columns or []):
                raise ValueError("a Lloyd prior steers toward the local centroid: the observation needs its columns "
                                 "(sensors.centroid)")
            self.centroid = columns.index("centroid_dx")  # centroid_dy follows it (``sensors.columns``)
        if hops:
            sensors = sensors or SensorsConfig()
            self.net = MessageActor(obs_dim, act_dim, hidden, hops, columns or [], sensors.neighbours,
                                    sensors.comm_range, canonical=symmetry == "d4_frame")
        else:
            self.net = symmetric(observation_net(columns or [], obs_dim, hidden, act_dim, layers), columns or [],
                                 symmetry)

    @classmethod
    def of(cls, obs_dim: int, act_dim: int, cfg: SharedLearnerConfig, columns: list[str] | None = None,
           sensors: SensorsConfig | None = None):
        """The actor of a learner's configuration: the one place its network is read from ``general.learner``."""
        return cls(obs_dim, act_dim, cfg.hidden, cfg.symmetry, columns, cfg.hops, sensors, cfg.layers,
                   cfg.lloyd_prior)

    @classmethod
    def from_checkpoint(cls, saved: dict):
        """The actor of a general run's ``actor.pt`` (``general_train``), weights loaded: its learner's
        configuration as saved (files written before it was saved name only the width and the symmetry)."""
        learner = saved.get("learner") or {"hidden": saved["hidden"], "symmetry": saved.get("symmetry", "none")}
        cfg = SharedLearnerConfig(**learner)
        actor = cls.of(len(saved["columns"]), 2, cfg, saved["columns"],
                       SensorsConfig(**saved["sensors"]) if saved.get("sensors") else None)
        actor.load_state_dict(saved["actor"])
        actor.prior = cfg.deployed_prior  # a faded prior is kept at 0 (``general_train`` validates no other)
        return actor

    @staticmethod
    def shape(weights: dict[str, torch.Tensor], symmetry: str = "none") -> tuple[int, int]:
        """(width, hidden layers) of the MLP actor whose state dict is ``weights`` (a symmetric actor's MLP sits
        inside its average): what a checkpoint without its learner's configuration is read back with."""
        prefix = "net.net." if symmetry != "none" else "net."
        linear = [k for k in weights if k.startswith(prefix) and k.endswith(".weight")
                  and k[len(prefix):-len(".weight")].isdigit()]
        return int(weights[prefix + "0.weight"].shape[0]), len(linear) - 1

    def steer(self, obs: torch.Tensor, pre: torch.Tensor) -> torch.Tensor:
        """The action of the network's pre-tanh output ``pre`` [..., 2] for ``obs`` [..., obs_dim]: tanh(pre), with
        a Lloyd prior tanh(pre + prior · the offset to the local centroid)."""
        if self.prior:
            pre = pre + self.prior * obs[..., self.centroid:self.centroid + 2]
        return torch.tanh(pre)

    def forward(self, obs: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """(action, the network's pre-tanh output: what the actor's regulariser keeps small, so that with a Lloyd
        prior the actor departs from Lloyd's law only where that pays)."""
        pre = self.net(obs)
        return self.steer(obs, pre), pre

    def fleet(self, obs: torch.Tensor, pos: torch.Tensor, live: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """(action, pre-tanh) [B, N, act_dim] of padded fleets: obs [B, N, obs_dim], pos [B, N, 2], live [B, N];
        0 for a slot out of service. Without messages the buoys in service alone run through μ."""
        if self.hops:
            pre = self.net(obs, pos, live) * live[..., None]
        else:
            mine = self.net(obs[live])  # [L, act_dim]
            pre = mine.new_zeros(live.shape + mine.shape[-1:])
            pre[live] = mine
        return self.steer(obs, pre) * live[..., None] if self.prior else torch.tanh(pre), pre


Rows = tuple[torch.Tensor, torch.Tensor]  # (fleet b, buoy i) index tensors [L]: the buoys a pass scores


def live_rows(live: torch.Tensor) -> Rows:
    """The buoys in service of padded fleets ``live`` [B, N] as rows (b, i), [L] each."""
    return live.nonzero(as_tuple=True)


@dataclass
class Neighbours:
    """Whom each row pools, from positions alone (the same for the critic and its target, so an update selects
    them once per state): ``rows`` (b, i) [L]; ``j`` [L, M] the others' slots, ``rel`` [L, M, 2] p_j − p_i and
    ``w`` [L, M] 1.0 for a real other, 0.0 for a slot that is not (M = N, or K with ``pool_neighbours``)."""

    rows: Rows
    j: torch.Tensor
    rel: torch.Tensor
    w: torch.Tensor


class PooledCritic(nn.Module):
    """Q_i of the buoys ``rows`` (b, i) [L] of padded fleets: obs [B, N, od], act [B, N, ad], pos [B, N, 2], live
    [B, N] → [L]. Only the rows asked for are computed (a batch of fleets of 5 to 30 padded to 30 is about half
    padding). The steps, for an update that reuses them: ``neighbours`` (whom each row pools), ``pooled`` (their
    mean embedding [L, embed]) and ``score`` (Q from it)."""

    def __init__(self, obs_dim: int, act_dim: int, hidden: int, embed: int, pool_range: float = 0.0,
                 pool_neighbours: int = 0, layers: int = 2):
        super().__init__()
        self.phi = mlp([obs_dim + act_dim + 2, embed, embed])
        self.q = mlp([obs_dim + act_dim + embed, *[hidden] * layers, 1])
        self.pool_range, self.pool_neighbours = pool_range, pool_neighbours

    def neighbours(self, pos, live, rows: Rows) -> Neighbours:
        """The others each row pools: every live j ≠ i, within ``pool_range`` when set, the K nearest with
        ``pool_neighbours`` (then φ runs on [L, K], not [L, N])."""
        b, i = rows
        n = pos.shape[1]
        rel = pos[b] - pos[b, i][:, None, :]  # [L, N (j), 2]: p_j − p_i
        others = live[b]  # j live, j ≠ i (a copy: indexing with b gathers)
        others[torch.arange(len(b), device=pos.device), i] = False
        if self.pool_range > 0:  # only the buoys near i (the difference credit depends on no others)
            others = others & (rel.square().sum(-1) <= self.pool_range**2)
        if 0 < self.pool_neighbours < n - 1:
            far = rel.square().sum(-1).masked_fill(~others, torch.inf)
            nearest, j = far.topk(self.pool_neighbours, dim=1, largest=False)  # [L, K]
            return Neighbours(rows, j, rel.gather(1, j[..., None].expand(-1, -1, 2)),
                              torch.isfinite(nearest).to(pos.dtype))
        return Neighbours(rows, torch.arange(n, device=pos.device).expand(len(b), n), rel, others.to(pos.dtype))

    def pooled(self, obs, act, nb: Neighbours) -> torch.Tensor:
        """mean_j φ(o_j, a_j, p_j − p_i) over each row's neighbours ``nb`` → [L, embed] (0 with none)."""
        other = torch.cat([obs, act], dim=-1)[nb.rows[0][:, None], nb.j]  # [L, M, od + ad]
        # φ's last layer is linear: it maps the mean of φ's hidden layer (the same pool, 1/M of that layer's work)
        first, relu, last = self.phi
        h = relu(first(torch.cat([other, nb.rel], dim=-1)))  # [L, M, embed]
        count = nb.w.sum(dim=1, keepdim=True)  # [L, 1]
        mean = (h * nb.w[..., None]).sum(dim=1) / count.clamp(min=1.0)
        return last(mean) * (count > 0)

    def score(self, obs_i, act_i, pooled) -> torch.Tensor:
        """Q from a buoy's own observation [L, od] and action [L, ad] and its pool [L, embed] → [L]."""
        return self.q(torch.cat([obs_i, act_i, pooled], dim=-1)).squeeze(-1)

    def forward(self, obs, act, pos, live, rows: Rows | None = None) -> torch.Tensor:
        """Q of ``rows`` [L]; without ``rows``, of every buoy in service as [B, N] (0 for the others)."""
        if rows is None:
            q = obs.new_zeros(live.shape)
            q[live] = self(obs, act, pos, live, live_rows(live))
            return q
        return self.score(obs[rows], act[rows], self.pooled(obs, act, self.neighbours(pos, live, rows)))


class SharedMADDPG:
    """One shared actor and one pooled critic with their targets, and the update that trains them."""

    def __init__(self, obs_dim: int, act_dim: int, cfg: SharedLearnerConfig, seed: int = 0,
                 columns: list[str] | None = None, sensors: SensorsConfig | None = None):
        """``columns``: the observation's names, which ``cfg.symmetry`` turns (``symmetry``); ``sensors``: whom a
        buoy hears, which messages (``cfg.hops``) travel between."""
        self.cfg = cfg
        with torch.random.fork_rng():  # the initial weights from ``seed``, leaving torch's global stream as it was
            torch.manual_seed(seed)
            self.actor = SharedActor.of(obs_dim, act_dim, cfg, columns, sensors)
            self.critic = PooledCritic(obs_dim, act_dim, cfg.hidden, cfg.embed, cfg.pool_range,
                                       cfg.pool_neighbours, cfg.layers)
        self.actor_target, self.critic_target = copy.deepcopy(self.actor), copy.deepcopy(self.critic)
        self.actor_average = copy.deepcopy(self.actor) if cfg.average else None  # what is validated and deployed
        self.actor_opt = torch.optim.Adam(self.actor.parameters(), lr=cfg.actor_lr)
        self.critic_opt = torch.optim.Adam(self.critic.parameters(), lr=cfg.critic_lr)
        self.imitation = "alone" if cfg.imitation == "before" else cfg.imitation  # what the actor's loss is now

    def fade_prior(self, progress: float) -> bool:
        """The Lloyd prior's gain at this ``progress`` of the training (``schedules.prior_gain``), in the actor, its
        target and its average alike. → whether it is the gain of the actor a training keeps (``deployed_prior``)."""
        gain = prior_gain(self.cfg, progress)
        for actor in (self.actor, self.actor_target, self.actor_average):
            if actor is not None:
                actor.prior = gain
        return gain == self.cfg.deployed_prior

    def hand_over(self) -> None:
        """``imitation: before``: the imitation ends, the actor-critic alone trains the actor from now on (with the
        same optimiser: its moments, built on the imitation loss, carry on, as in fine-tuning from a cloned actor)."""
        self.imitation = "none"

    def update(self, b: Batch) -> dict[str, float]:
        """One step of the critic, the actor and the targets on the buoys in service of ``b`` (its rows: padding
        and lost buoys cost nothing); whom each buoy pools is selected once per state."""
        cfg, critic = self.cfg, self.critic
        rows = live_rows(b.live)
        if len(rows[0]) == 0:  # no buoy in service (a replay transition always has one): nothing to learn from
            return {"critic_loss": 0.0, "q_abs": 0.0}
        obs, act = b.obs[rows], b.act[rows]
        now, then = critic.neighbours(b.pos, b.live, rows), critic.neighbours(b.next_pos, b.next_live, rows)

        # Critic: y_i = r_i + γᵐ Q'(o'_i, μ'(o'_i), pool_j φ'(o'_j, μ'(o'_j), p'_j − p'_i))   (MADDPG's target)
        with torch.no_grad():  # a buoy lost before the bootstrap step has no future: its target is its return
            next_act = self.actor_target.fleet(b.next_obs, b.next_pos, b.next_live)[0]
            pool = self.critic_target.pooled(b.next_obs, next_act, then)
            q_next = self.critic_target.score(b.next_obs[rows], next_act[rows], pool) * b.next_live[rows]
            y = b.rew[rows] + b.disc[rows[0]] * q_next
        q = critic.score(obs, act, critic.pooled(b.obs, b.act, now))
        critic_loss = ((q - y) ** 2).mean()
        self.critic_opt.zero_grad()
        critic_loss.backward()
        nn.utils.clip_grad_norm_(critic.parameters(), cfg.grad_clip)
        self.critic_opt.step()

        # Actor: ∇J = E_i[∇μ(o_i) ∇_{a_i} Q(o_i, a_i, pool_{j≠i} φ(o_j, a_j, ·))|_{a_i = μ(o_i)}]: the others keep
        # their taken actions, so the pool does not depend on μ here
        with torch.no_grad():
            pool = critic.pooled(b.obs, b.act, now)
        mu, pre = (x[rows] for x in self.actor.fleet(b.obs, b.pos, b.live))
        actor_loss = cfg.actor_reg * (pre**2).mean()
        if self.imitation != "alone":
            actor_loss = actor_loss - critic.score(obs, mu, pool).mean()
        if self.imitation != "none":  # + λ·mean_i ‖μ(o_i) − a*_i‖²: the teacher's action in the learner's state
            actor_loss = actor_loss + cfg.imitation_weight * ((mu - b.expert[rows]) ** 2).sum(-1).mean()
        self.actor_opt.zero_grad()
        actor_loss.backward(inputs=list(self.actor.parameters()))  # through μ only, not into Q's weights
        nn.utils.clip_grad_norm_(self.actor.parameters(), cfg.grad_clip)
        self.actor_opt.step()

        with torch.no_grad():  # θ' ← τθ + (1 − τ)θ'; with ``average``, θ̄ ← θ̄ + average·(θ − θ̄)
            followers = [(critic, self.critic_target, cfg.tau), (self.actor, self.actor_target, cfg.tau)]
            if self.actor_average is not None:
                followers.append((self.actor, self.actor_average, cfg.average))
            for net, follower, rate in followers:
                for p, tp in zip(net.parameters(), follower.parameters()):
                    tp.lerp_(p, rate)
        return {"critic_loss": critic_loss.item(), "q_abs": q.detach().abs().mean().item()}

    def scale_learning_rates(self, factor: float) -> None:
        """Set the actor's and critic's learning rates to ``factor`` × their configured values."""
        self.actor_opt.param_groups[0]["lr"] = factor * self.cfg.actor_lr
        self.critic_opt.param_groups[0]["lr"] = factor * self.cfg.critic_lr

    @property
    def deployed(self) -> SharedActor:
        """The actor that is validated and deployed: the running average of the trained one with ``average``, else
        the trained one."""
        return self.actor if self.actor_average is None else self.actor_average

    def load_actor(self, state: dict) -> None:
        """Start every actor (the trained one, its target and its average) from the weights ``state``."""
        for actor in (self.actor, self.actor_target, self.actor_average):
            if actor is not None:
                actor.load_state_dict(state)

    @torch.no_grad()
    def policy(self, obs, pos, live, actor: SharedActor | None = None) -> torch.Tensor:
        """The deterministic actions [E, N, act_dim] of fleets of ``actor`` (default: the deployed one): obs [E, N,
        obs_dim], pos [E, N, 2], live [E, N] (None: every buoy in service; only an actor with messages reads pos
        and live)."""
        actor = self.deployed if actor is None else actor
        obs = torch.as_tensor(obs, dtype=torch.float32)
        if not actor.hops:
            return actor(obs)[0]
        live = torch.ones(obs.shape[:2], dtype=torch.bool) if live is None else torch.as_tensor(live)
        return actor.fleet(obs, torch.as_tensor(pos, dtype=torch.float32), live)[0]

    @torch.no_grad()
    def act(self, obs, sigma: float, generator: torch.Generator, pos=None, live=None) -> torch.Tensor:
        """Behaviour actions for obs [E, N, obs_dim] (pos and live as ``policy``): the trained μ plus Gaussian
        noise σ, clipped to [−1, 1]."""
        mu = self.policy(obs, pos, live, self.actor)
        noise = torch.randn(mu.shape, generator=generator) * sigma
        return (mu + noise).clamp(-1.0, 1.0)
