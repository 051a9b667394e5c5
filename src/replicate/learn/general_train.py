"""Training one policy for every lake: the shared actor and pooled critic (``shared_maddpg``) on many worlds.

The worlds (``worlds``): the named regions of ``general.regions`` and ``general.lakes`` generated lakes, each
with N buoys behind the shore wall, observing only their local sensors (``observation: local``), rewarded by CR's
eq. (5)-(6) with the difference credit. Each batch of E episodes plays in one world, the worlds in turn; a batch
may start scattered over the water instead of in the corner patch, lose up to a third of its buoys half-way, or
drift in a current.
Transitions of fleets of different sizes share one replay memory, padded to the largest fleet and masked.

The run keeps the actor that covered best on its validation starts (every named region from the corner, each
world scattered, fixed seeds drawn from the run's seed) and writes into its folder: ``actor.pt`` (weights and
the sensors it reads), ``curve.csv.gz`` (one row per batch), ``run.json``.
"""

from __future__ import annotations

import json
import math
import time
from pathlib import Path

import numpy as np
import torch
from tqdm import tqdm

from replicate.core import artifacts
from replicate.core.params import GeneralConfig, Params, to_dict
from replicate.learn.fingerprint import general_fingerprint
from replicate.learn.maddpg import NStepWriter
from replicate.learn.shared_maddpg import FleetBatch, SharedMADDPG
from replicate.learn.training_worlds import World, make_worlds
from replicate.world.currents import random_current
from replicate.world.env import observation_columns
from replicate.world.regions import Region
from replicate.world.scenario import general_env

CURVE_COLUMNS = ["batch", "episodes", "world", "n_agents", "start", "lost", "current", "coverage", "critic_loss",
                 "q_abs", "sigma", "validation"]


class FleetReplay:
    """A replay memory of m-step transitions of fleets up to ``n_max`` buoys, padded and masked."""

    def __init__(self, capacity: int, n_max: int, obs_dim: int):
        shapes = {"obs": (obs_dim,), "act": (2,), "rew": (), "next_obs": (obs_dim,), "pos": (2,), "next_pos": (2,)}
        self.data = {k: torch.zeros((capacity, n_max, *s)) for k, s in shapes.items()}
        self.live = torch.zeros((capacity, n_max), dtype=torch.bool)
        self.next_live = torch.zeros((capacity, n_max), dtype=torch.bool)
        self.disc = torch.zeros(capacity)
        self.capacity, self.size, self.ptr = capacity, 0, 0

    def add(self, live: np.ndarray, next_live: np.ndarray, disc: float, **arrays: np.ndarray) -> None:
        """E transitions of one fleet of N ≤ n_max buoys: arrays [E, N, ...], masks [E, N], bootstrapping at
        next_obs with ``disc`` (γᵐ for m steps)."""
        e, n = live.shape
        rows = (self.ptr + np.arange(e)) % self.capacity
        for key, value in arrays.items():
            self.data[key][rows] = 0.0
            self.data[key][rows, :n] = torch.as_tensor(value, dtype=torch.float32)
        self.live[rows], self.next_live[rows] = False, False
        self.live[rows, :n], self.next_live[rows, :n] = torch.as_tensor(live), torch.as_tensor(next_live)
        self.disc[rows] = disc
        self.ptr = (self.ptr + e) % self.capacity
        self.size = min(self.size + e, self.capacity)

    def sample(self, rng: np.random.Generator, batch: int) -> FleetBatch:
        idx = torch.as_tensor(rng.integers(0, self.size, batch))
        return FleetBatch(**{k: v[idx] for k, v in self.data.items()}, live=self.live[idx],
                          next_live=self.next_live[idx], disc=self.disc[idx])


class FleetNStep(NStepWriter):
    """``maddpg.NStepWriter`` for a ``FleetReplay``: a step also carries the buoys in service (``live``) and their
    positions (``pos``, ``next_pos``); a transition bootstraps with the buoys in service after its last step, so a
    buoy lost in between is not bootstrapped (its rewards after the loss are 0, its future none)."""

    def write(self, first: dict, ret: np.ndarray, end: dict, discount: float) -> None:
        self.buffer.add(first["live"], end["live"], discount, obs=first["obs"], act=first["act"], rew=ret,
                        next_obs=end["next_obs"], pos=first["pos"], next_pos=end["next_pos"])


def noise_sigma(gc: GeneralConfig, progress: float) -> float:
    """σ falls linearly from ``noise_start`` to ``noise_end`` over the first ``noise_decay`` of training."""
    return gc.noise_end + (gc.noise_start - gc.noise_end) * max(0.0, 1.0 - progress / max(gc.noise_decay, 1e-9))


class GeneralTrainer:
    """One seed of the general policy (module docstring). ``run`` trains and returns the run's summary."""

    def __init__(self, params: Params, seed: int, out: str | Path, progress: bool = True,
                 config: GeneralConfig | None = None, worlds: list[tuple[Region, int]] | None = None,
                 actor: dict | None = None):
        """``worlds`` [(region, N)] replace the training worlds of ``config`` (fine-tuning on one lake: its
        validation starts from the corner patch and scattered); ``actor``, a state dict of ``SharedActor``, starts
        the actor (and its target) from trained weights, validated before the first batch so that the run keeps
        them unless training improves on them."""
        self.params, self.gc, self.seed, self.out = params, config or params.general, seed, Path(out)
        self.progress = progress
        streams = np.random.SeedSequence(seed).spawn(5)  # worlds, events, noise, sampling, validation
        self.rng_events = np.random.default_rng(streams[1])
        self.noise = torch.Generator().manual_seed(int(streams[2].generate_state(1)[0]))
        self.rng_sample = np.random.default_rng(streams[3])
        if worlds is None:
            self.worlds = make_worlds(params, self.gc, np.random.default_rng(streams[0]), self.gc.n_envs)
        else:
            rng = np.random.default_rng(streams[0])
            self.worlds = [World(r, n, general_env(params, self.gc, r, n, self.gc.n_envs,
                                                 np.random.SeedSequence(int(rng.integers(2**31))))) for r, n in worlds]
        self.corner_validation = {w.region.name for w in self.worlds} if worlds else set(self.gc.regions)
        self.validation = self.validation_worlds(np.random.default_rng(streams[4]))
        columns = observation_columns("local", self.gc.sensors)
        obs_dim = len(columns)
        self.agent = SharedMADDPG(obs_dim, 2, self.gc.learner, seed=seed, columns=columns)
        self.initial_actor = actor
        if actor is not None:
            self.agent.actor.load_state_dict(actor)
            self.agent.actor_target.load_state_dict(actor)
        self.replay = FleetReplay(self.gc.buffer_size, max(w.n_agents for w in self.worlds), obs_dim)
        self.rows: list[list] = []
        self.best: dict | None = None
        self.pending = 0.0

    def validation_worlds(self, rng: np.random.Generator) -> list[tuple[World, str, int]]:
        """Fixed validation starts (world, start, seed): every named region from the corner patch, every world
        scattered; 4 episodes each."""
        out = []
        for w in self.worlds:
            env = general_env(self.params, self.gc, w.region, w.n_agents, 4, 0, reward=False)
            starts = ("corner", "random") if w.region.name in self.corner_validation else ("random",)
            out += [(World(w.region, w.n_agents, env), s, int(rng.integers(2**31))) for s in starts]
        return out

    def run(self) -> dict:
        gc = self.gc
        batches = gc.episodes // gc.n_envs
        t0, c0 = time.perf_counter(), time.process_time()
        if self.initial_actor is not None:
            self.validate(0)  # the starting weights are the ones to beat
        for batch in tqdm(range(batches), disable=not self.progress, unit="batch"):
            sigma = noise_sigma(gc, batch / batches)
            self.agent.scale_learning_rates(1.0 - (1.0 - gc.lr_end) * batch / batches)
            world = self.worlds[batch % len(self.worlds)]
            row = self.play(world, sigma)
            due = (batch + 1) % len(self.worlds) == 0 or batch == batches - 1
            score = self.validate((batch + 1) * gc.n_envs) if due else math.nan
            self.rows.append([batch, (batch + 1) * gc.n_envs, world.region.name, world.n_agents, *row, sigma, score])
        return self.finish(time.perf_counter() - t0, time.process_time() - c0)

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
        writer = FleetNStep(self.replay, gc.n_step, gc.gamma)
        losses, q_abs = [], []
        for t in range(gc.episode_length):
            if lose and t == gc.episode_length // 2:
                env.lose(lose, rng)
                obs = env.observe()
            live = np.ones((env.n_envs, world.n_agents), bool) if env.alive is None else env.alive.copy()
            pos = env.pos.copy()
            act = self.agent.act(obs, sigma, self.noise).numpy()
            step = env.step(act)
            writer.push(t == gc.episode_length - 1, live=live, obs=obs, act=act, rew=step.pay, pos=pos,
                        next_obs=step.obs, next_pos=env.pos.copy())
            obs = step.obs
            for stats in self.learn(env.n_envs):
                losses.append(stats["critic_loss"])
                q_abs.append(stats["q_abs"])
        coverage = float(np.mean(step.union_area / world.region.polygon.area))
        return [start, lose, 0.0 if current is None else current.max_speed(), coverage,
                float(np.mean(losses)) if losses else math.nan, float(np.mean(q_abs)) if q_abs else math.nan]

    def learn(self, transitions: int):
        """The updates due after ``transitions`` more: one per ``update_every`` once the memory holds
        ``learning_starts``."""
        gc = self.gc
        if self.replay.size < gc.learning_starts:
            return
        self.pending += transitions / gc.update_every
        while self.pending >= 1.0:
            self.pending -= 1.0
            yield self.agent.update(self.replay.sample(self.rng_sample, gc.batch_size))

    @torch.no_grad()
    def validate(self, episodes: int) -> float:
        """Mean final coverage of the deterministic policy over the validation starts; keeps the best actor
        (trained for ``episodes``)."""
        scores = []
        for world, start, seed in self.validation:
            env = world.env
            obs = env.reset(seed=seed, start=start)  # the same starts every time
            for _ in range(self.gc.episode_length):
                obs = env.step(self.agent.actor(torch.as_tensor(obs))[0].numpy()).obs
            scores.append(float(env.coverage_fraction().mean()))
        score = float(np.mean(scores))
        if self.best is None or score > self.best["validation"]:
            state = {k: v.clone() for k, v in self.agent.actor.state_dict().items()}
            self.best = {"validation": score, "episodes": episodes, "actor": state}
        return score

    def finish(self, wall: float, cpu: float) -> dict:
        gc = self.gc
        artifacts.torch_save(self.out / "actor.pt", {
            "format": artifacts.CHECKPOINT_FORMAT, "actor": self.best["actor"], "observation": "local",
            "sensors": to_dict(gc.sensors),
            "columns": observation_columns("local", gc.sensors), "hidden": gc.learner.hidden,
            "symmetry": gc.learner.symmetry,
            "selected_episode": self.best["episodes"], "seed": self.seed})
        artifacts.write_csv(self.out / "curve.csv.gz", CURVE_COLUMNS, self.rows)
        summary = {"status": "finished", "seed": self.seed, "general": to_dict(gc),
                   "worlds": [{"region": w.region.name, "n_agents": w.n_agents} for w in self.worlds],
                   "selected_episode": self.best["episodes"], "selected_validation_coverage": self.best["validation"],
                   "wall_seconds": round(wall, 2), "cpu_seconds": round(cpu, 2),
                   "arithmetic": general_fingerprint()}  # which numbers trained it (``arithmetic.py``)
        artifacts.write_json(self.out / "run.json", summary)
        return summary


# ---- a run's record: what makes two runs the same, where a stage keeps it -------------------------------
GENERAL_VERSION = 3  # raised when the general training's arithmetic changes: older runs are trained again
# 2: the update runs on the buoys in service only and applies φ's last layer to the pooled mean (float rounding)
# 3: a velocity over the ground is the buoy's displacement over the last step / dt (the shore's stop included)
KEPT_POLICY = "general.pt"  # the best-validated seed's policy, the one a user deploys
SEED_POLICY = "policy.pt"  # each seed's exported policy, in its run folder


def general_identity(params, seed: int) -> dict:
    """What makes two general runs the same run: the version, the seed and every value they train with."""
    trained = {k: v for k, v in to_dict(params.general).items() if k not in ("seeds", "suite")}  # not its evaluation
    if not trained["sensors"]["uncovered"]:  # an optional sensor, off: a run's identity names only what it used
        del trained["sensors"]["uncovered"]
    if trained["learner"]["symmetry"] == "none":  # so is an actor's symmetry
        del trained["learner"]["symmetry"]
    return {"general_version": GENERAL_VERSION, "seed": seed, "general": trained,
            "world": to_dict(params.world), "coverage": to_dict(params.coverage),
            "cr_reward": to_dict(params.cr_reward), "regions": to_dict(params.regions)}


def finished_general(out: Path, identity: dict) -> dict | None:
    """The summary of a finished general run in ``out`` with this identity, else None."""
    path = out / "run.json"
    if not (path.exists() and (out / "actor.pt").exists()):
        return None
    summary = json.loads(path.read_text())
    same = summary.get("identity") == json.loads(json.dumps(identity))
    return summary if same and summary.get("status") == "finished" else None


def seed_folder(out: Path, seed: int) -> Path:
    """A seed's run folder in a stage's output ``out``."""
    return out / "runs" / f"general-s{seed}"


def train_recorded(params, seed: int, out: Path, progress: bool = False) -> dict:
    """Train one seed of ``params.general`` into ``out`` and record its identity in ``run.json``, so that a stage
    finding it there with the same settings keeps it (``finished_general``). → the run's summary."""
    summary = GeneralTrainer(params, seed, out, progress=progress).run()
    summary["identity"] = general_identity(params, seed)
    artifacts.write_json(out / "run.json", summary)
    return summary
