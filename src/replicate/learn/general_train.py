"""Training one policy for every lake: the shared actor and pooled critic (``shared_maddpg``) on many worlds.

The worlds (``training_worlds``): the named regions of ``general.regions`` and ``general.lakes`` generated lakes, each
with N buoys behind the shore wall, observing only their local sensors (``observation: local``), rewarded by CR's
eq. (5)-(6) with the difference credit. Each batch of E episodes plays in one world, the worlds in turn; a batch
may start scattered over the water instead of in the corner patch, lose up to a third of its buoys half-way, or
drift in a current.
Transitions of fleets of different sizes share one replay memory, padded to the largest fleet and masked.

With ``general.learner.imitation``, a teacher (the clairvoyant planner, ``compare.planner``, which the caller
builds: this wing does not read the comparisons) gives its action for every buoy in every state the learner
visits; the memory keeps it beside the transition, and the actor's loss imitates it beside the actor-critic
term or alone (DAgger's relabelling of the learner's own states, Ross et al. 2011), or alone for the first
``imitation_until`` of the batches, after which the actor-critic alone trains the actor and the teacher is asked
no more.

The run keeps the actor that covered best on its validation starts (every named region and the channel from the
corner, each world scattered, fixed seeds drawn from the run's seed; with ``general.learner.average``, the running
average of the trained actor's weights is the one validated; with ``general.learner.lloyd_prior_fade``, only
once the actor's Lloyd prior has faded to 0) and writes into its folder: ``actor.pt``
(weights and the sensors it reads), ``curve.csv.gz`` (one row per batch), ``run.json``.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np
import torch

from replicate.core import artifacts
from replicate.core.params import Params
from replicate.core.progress import bar as progress_bar
from replicate.core.schema import to_dict
from replicate.core.sections import GeneralConfig
from replicate.learn.fingerprint import general_fingerprint
from replicate.learn.loop import TrainingLoop
from replicate.learn.replay import Replay
from replicate.learn.runs import general_identity
from replicate.learn.shared_maddpg import SharedMADDPG
from replicate.learn.training_worlds import World, channel_world, make_worlds
from replicate.world.currents import random_current
from replicate.world.env import CoverageEnv, observation_columns
from replicate.world.regions import Region
from replicate.world.scenario import general_env

CURVE_COLUMNS = ["batch", "episodes", "world", "n_agents", "start", "lost", "current", "coverage", "critic_loss",
                 "q_abs", "sigma", "validation"]


class GeneralTrainer:
    """One seed of the general policy (module docstring). ``run`` trains and returns the run's summary."""

    def __init__(self, params: Params, seed: int, out: str | Path, progress: bool = True,
                 config: GeneralConfig | None = None, worlds: list[tuple[Region, int]] | None = None,
                 actor: dict | None = None, teacher: Callable[[CoverageEnv], np.ndarray] | None = None):
        """``worlds`` [(region, N)] replace the training worlds of ``config`` (fine-tuning on one lake: its
        validation starts from the corner patch and scattered); ``actor``, a state dict of ``SharedActor``, starts
        the actor (its target and, with ``learner.average``, its average) from trained weights, validated before
        the first batch so that the run keeps them unless training improves on them (with a fading Lloyd prior
        they are not: only the faded actor is validated); ``teacher(env) → actions
        [E, N, 2]`` labels every state the learner visits, which ``general.learner.imitation`` needs."""
        self.params, self.gc, self.seed, self.out = params, config or params.general, seed, Path(out)
        self.progress = progress
        imitating = self.gc.learner.imitation != "none"
        if imitating and teacher is None:
            raise ValueError(f"general.learner.imitation: {self.gc.learner.imitation!r} learns from a teacher, and "
                             "none was given (the pipeline and `replicate train-general` give the planner)")
        self.teacher = teacher if imitating else None
        streams = np.random.SeedSequence(seed).spawn(5)  # worlds, events, noise, sampling, validation
        self.rng_events = np.random.default_rng(streams[1])
        self.noise = torch.Generator().manual_seed(int(streams[2].generate_state(1)[0]))
        if worlds is None:
            self.worlds = make_worlds(params, self.gc, np.random.default_rng(streams[0]), self.gc.n_envs)
        else:
            rng = np.random.default_rng(streams[0])
            self.worlds = [World(r, n, general_env(params, self.gc, r, n, self.gc.n_envs,
                                                 np.random.SeedSequence(int(rng.integers(2**31))))) for r, n in worlds]
        self.corner_validation = {w.region.name for w in self.worlds} if worlds else \
            set(self.gc.regions) | {r.name for r, _ in channel_world(params, self.gc)}
        self.validation = self.validation_worlds(np.random.default_rng(streams[4]))
        columns = observation_columns("local", self.gc.sensors)
        obs_dim = len(columns)
        self.agent = SharedMADDPG(obs_dim, 2, self.gc.learner, seed=seed, columns=columns, sensors=self.gc.sensors)
        self.initial_actor = actor
        if actor is not None:
            self.agent.load_actor(actor)
        memory = Replay(self.gc.buffer_size, max(w.n_agents for w in self.worlds), obs_dim, fleets=True,
                        expert=imitating)
        self.loop = TrainingLoop(self.agent, self.gc, [memory], [np.random.default_rng(streams[3])], stacked=False)
        self.rows: list[list] = []

    def validation_worlds(self, rng: np.random.Generator) -> list[tuple[World, str, int]]:
        """Fixed validation starts (world, start, seed): every named region and the channel from the corner
        patch, every world scattered; 4 episodes each."""
        out = []
        for w in self.worlds:
            env = general_env(self.params, self.gc, w.region, w.n_agents, 4, 0, reward=False, steps=w.steps)
            starts = ("corner", "random") if w.region.name in self.corner_validation else ("random",)
            out += [(World(w.region, w.n_agents, env), s, int(rng.integers(2**31))) for s in starts]
        return out

    def run(self) -> dict:
        gc = self.gc
        batches = gc.episodes // gc.n_envs
        t0, c0 = time.perf_counter(), time.process_time()
        if self.initial_actor is not None and self.agent.fade_prior(0.0):
            self.validate(0)  # the starting weights are the ones to beat
        for batch in progress_bar(self.progress, iterable=range(batches), desc="training", unit="batch"):
            sigma = self.loop.schedule(batch / batches)
            settled = self.agent.fade_prior((batch + 1) / batches)  # a batch plays with the gain of its end, so
            # that a fading prior is 0 in the last batch whatever the share; only an actor with the prior's deployed
            # gain is validated and kept
            if self.teacher is not None and gc.learner.imitation == "before" and \
                    batch >= gc.learner.imitation_until * batches:
                self.hand_over()
            world = self.worlds[batch % len(self.worlds)]
            row = self.play(world, sigma)
            due = settled and ((batch + 1) % len(self.worlds) == 0 or batch == batches - 1)
            score = self.validate((batch + 1) * gc.n_envs) if due else math.nan
            self.rows.append([batch, (batch + 1) * gc.n_envs, world.region.name, world.n_agents, *row, sigma, score])
        return self.finish(time.perf_counter() - t0, time.process_time() - c0)

    def hand_over(self) -> None:
        """The end of the imitation before the actor-critic: the actor's loss is the actor-critic's alone, and the
        memory's labels from now on are zeros that no update reads."""
        self.agent.hand_over()
        self.teacher = None

    def labels(self, env: CoverageEnv) -> dict[str, np.ndarray]:
        """The teacher's actions [E, N, 2] in ``env``'s state, as the memory keeps them: none without a teacher,
        zeros once it has handed over."""
        if self.gc.learner.imitation == "none":  # the memory keeps no labels
            return {}
        if self.teacher is None:
            return {"expert": np.zeros(env.pos.shape, np.float32)}
        return {"expert": self.teacher(env).astype(np.float32)}

    def play(self, world: World, sigma: float) -> list:
        """One batch of E episodes in ``world``: its events drawn, every step stored, every due update made.
        → [start, lost, current speed, final coverage, critic loss, |Q|]."""
        gc, env, rng = self.gc, world.env, self.rng_events
        start = "random" if rng.uniform() < gc.random_starts else "corner"
        lose = int(rng.integers(1, max(2, int(gc.lose_fraction * world.n_agents) + 1))) \
            if rng.uniform() < gc.lose_prob and world.n_agents > 2 else 0
        current = random_current(rng, env.n_envs, world.region.polygon, gc.current_speed) \
            if rng.uniform() < gc.current_prob else None
        env.set_current(current)
        obs = env.reset(start=start)
        (writer,) = self.loop.writers()
        losses, q_abs = [], []
        for t in range(world.steps):
            if lose and t == world.steps // 2:
                env.lose(lose, rng)
                obs = env.observe()
            live = np.ones((env.n_envs, world.n_agents), bool) if env.alive is None else env.alive.copy()
            pos = env.pos.copy()
            taught = self.labels(env)
            act = self.agent.act(obs, sigma, self.noise, pos, live).numpy()
            step = env.step(act)
            writer.push(t == world.steps - 1, live=live, obs=obs, act=act, rew=step.pay, pos=pos,
                        next_obs=step.obs, next_pos=env.pos.copy(), next_live=live,  # bootstrap on those in service
                        **taught)
            obs = step.obs
            for stats in self.loop.learn(env.n_envs):
                losses.append(stats["critic_loss"])
                q_abs.append(stats["q_abs"])
        coverage = float(np.mean(step.union_area / world.region.polygon.area))
        return [start, lose, 0.0 if current is None else current.max_speed(), coverage,
                float(np.mean(losses)) if losses else math.nan, float(np.mean(q_abs)) if q_abs else math.nan]

    @torch.no_grad()
    def validate(self, episodes: int) -> float:
        """Mean final coverage of the deterministic policy over the validation starts; keeps the best actor
        (trained for ``episodes``)."""
        scores = []
        for world, start, seed in self.validation:
            env = world.env
            obs = env.reset(seed=seed, start=start)  # the same starts every time
            for _ in range(world.steps):
                obs = env.step(self.agent.policy(obs, env.pos, env.alive).numpy()).obs
            scores.append(float(env.coverage_fraction().mean()))
        score = float(np.mean(scores))
        self.loop.keep(0, score, episodes,
                       lambda: {k: v.clone() for k, v in self.agent.deployed.state_dict().items()}, ties="earlier")
        return score

    def finish(self, wall: float, cpu: float) -> dict:
        gc, best = self.gc, self.loop.kept[0]
        artifacts.torch_save(self.out / "actor.pt", {
            "format": artifacts.CHECKPOINT_FORMAT, "actor": best["actor"], "observation": "local",
            "sensors": to_dict(gc.sensors),
            "columns": observation_columns("local", gc.sensors), "learner": to_dict(gc.learner),
            "hidden": gc.learner.hidden, "symmetry": gc.learner.symmetry,
            "selected_episode": best["episodes"], "seed": self.seed})
        artifacts.write_csv(self.out / "curve.csv.gz", CURVE_COLUMNS, self.rows)
        summary = {"status": "finished", "seed": self.seed, "general": to_dict(gc),
                   "worlds": [{"region": w.region.name, "n_agents": w.n_agents} for w in self.worlds],
                   **self.loop.selection(0), "wall_seconds": round(wall, 2), "cpu_seconds": round(cpu, 2),
                   "arithmetic": general_fingerprint()}  # which numbers trained it (``fingerprint``)
        artifacts.write_json(self.out / "run.json", summary)
        return summary


def train_recorded(params, seed: int, out: Path, progress: bool = False,
                   teacher: Callable[[CoverageEnv], np.ndarray] | None = None, taught_by: dict | None = None) -> dict:
    """Train one seed of ``params.general`` into ``out`` (with ``teacher`` where it imitates one, ``taught_by``
    saying which teacher it is) and record its identity in ``run.json``, so that a stage finding it there with the
    same settings keeps it (``finished_general``). → the run's summary."""
    summary = GeneralTrainer(params, seed, out, progress=progress, teacher=teacher).run()
    summary["identity"] = general_identity(params, seed, taught_by)
    artifacts.write_json(out / "run.json", summary)
    return summary
