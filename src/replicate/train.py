"""The training loop: E parallel environments, MADDPG updates, per-episode curve, resumable checkpoints.

A run directory holds ``run.json`` (what was run), ``curve.csv.gz`` (one row per episode, gzip: 10,000 rows of
15 columns are 1.2 MB as text and ~0.4 MB compressed), ``checkpoint.pt``
(everything needed to continue: networks, optimisers, replay buffer, generator states, the curve so far) and,
at the end, ``actors.pt`` (the trained decentralised policies: the last ones, or with ``select_every`` the best on
the run's fixed validation starts, whose coverage is logged in ``validation.csv``).
"""

from __future__ import annotations

import copy
import dataclasses
import math
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import torch
from tqdm.auto import tqdm

from . import artifacts
from .artifacts import CHECKPOINT_FORMAT, CheckpointError
from .config import ConfigError, RunConfig, to_dict
from .env import CoverageEnv
from .geometry import region_key
from .maddpg import MADDPG, NStepWriter, ReplayBuffer
from .regions import Region

DIAGNOSTICS = ("critic_loss", "q_abs", "saturated", "noise")
CURVE = "curve.csv.gz"  # the per-episode curve of a run, in its folder
# Part of every run's identity: raise it with any change that alters the numbers a run produces (the update's
# arithmetic, the environment, the rewards), so that runs trained by older code are retrained, not reused.
# 1: autograd update (sessions 1-5); 2: hand-written gradients in their fastest matmul forms (maddpg.py).
TRAINING_VERSION = 2


def curve_header(n_agents: int) -> list[str]:
    return ["episode", *[f"reward_{i}" for i in range(n_agents)], "team_reward", "coverage", *DIAGNOSTICS]


def noise_sigma(cfg, progress: float) -> float:
    """Exploration σ: linear from noise_start to noise_end over the first ``noise_decay`` of training."""
    if cfg.noise_decay <= 0:
        return cfg.noise_end
    frac = min(progress / cfg.noise_decay, 1.0)
    return cfg.noise_start + frac * (cfg.noise_end - cfg.noise_start)


def lr_factor(cfg, progress: float) -> float:
    """Learning-rate multiplier: linear from 1 at the first episode to ``lr_end`` at the last."""
    return 1.0 + progress * (cfg.lr_end - 1.0)


def run_identity(rc: RunConfig, region: Region, episodes: int, seed: int) -> dict:
    """What makes two runs the same run: checked on resume, and by the pipeline to skip finished runs."""
    return {
        "training_version": TRAINING_VERSION,
        "config": rc.config_name,
        "method": rc.method_name,
        "region": region.name,
        "region_key": region_key(region.polygon),
        "seed": seed,
        "episodes": episodes,
        "params": to_dict(rc, drop_defaults=True),
    }


def finished_run(out: str | Path, identity: dict) -> dict | None:
    """The summary of a finished run in ``out`` with this identity, else None."""
    import json

    path = Path(out) / "run.json"
    if not (path.exists() and (Path(out) / "actors.pt").exists()):
        return None
    summary = json.loads(path.read_text())
    same = all(summary.get(k) == v for k, v in identity.items())
    return summary if same and summary.get("status") == "finished" else None


def make_env(region: Region, rc: RunConfig, n_envs: int, seed, reward: bool = True) -> CoverageEnv:
    """The training environment of a run config (reward, observation, geofence, credit from params.yaml);
    ``reward=False`` gives the same world without reward, for validation rollouts."""
    cr = rc.cr_reward
    if rc.algo.union_weight is not None:
        cr = dataclasses.replace(cr, c2=rc.algo.union_weight)
    return CoverageEnv(
        region,
        rc.world,
        rc.coverage,
        n_envs=n_envs,
        reward=rc.method.reward if reward else None,
        sw=rc.sw_reward,
        cr=cr,
        observation=rc.algo.observation,
        geofence=rc.algo.geofence,
        union_credit=rc.algo.union_credit,
        seed=seed,
    )


@dataclass
class Trainer:
    """One training run. ``run`` trains up to ``episodes``; construct with ``resume=True`` to continue."""

    rc: RunConfig
    region: Region
    episodes: int
    seed: int
    out: Path
    checkpoint_every: int = 1000
    progress: bool = True
    rows: list = field(default_factory=list)

    def __post_init__(self) -> None:
        algo = self.rc.algo
        if self.episodes < 1:
            raise ConfigError(f"episodes must be positive, got {self.episodes}")
        if self.episodes % algo.n_envs:
            raise ConfigError(f"episodes ({self.episodes}) must be a multiple of n_envs ({algo.n_envs})")
        self.out = Path(self.out)
        seeds = np.random.SeedSequence(self.seed).spawn(4)
        self.env = make_env(self.region, self.rc, algo.n_envs, seeds[0])
        # validation starts: fixed per run, drawn apart from the evaluation seed so selection cannot fit it
        self.val_seed = int(seeds[3].generate_state(1)[0])
        self.val_env = (make_env(self.region, self.rc, algo.select_episodes, self.val_seed, reward=False)
                        if algo.select_every else None)
        self.validation: list[list[float]] = []  # [episode, validation coverage]
        self.best: dict | None = None  # {"episode", "coverage", "actor"}: the actors kept when selecting
        self.noise_rng = np.random.default_rng(seeds[1])
        self.sample_rng = np.random.default_rng(seeds[2])
        n, od = self.env.n_agents, self.env.obs_dim
        self.agent = MADDPG(n, od, 2, algo.maddpg, self.rc.method.reward_mode, seed=self.seed)
        capacity = min(algo.maddpg.buffer_size, self.episodes * self.rc.world.episode_length)
        self.buffer = ReplayBuffer(capacity, n, od, 2)
        self.writer = NStepWriter(self.buffer, algo.maddpg.n_step, algo.maddpg.gamma)
        self.transitions = 0
        self.pending_updates = 0.0
        self.wall = 0.0
        self.update_seconds = 0.0  # time spent in MADDPG updates (the rest is environment, geometry, acting)
        self.updates = 0

    # ---- identity of a run, checked on resume ----------------------------------------------------------
    def identity(self) -> dict:
        return run_identity(self.rc, self.region, self.episodes, self.seed)

    def run(self) -> dict:
        """Train to ``episodes``, checkpointing on the way; returns the run summary."""
        algo, world = self.rc.algo, self.rc.world
        cfg = algo.maddpg
        n_env, n, horizon = algo.n_envs, self.env.n_agents, world.episode_length
        start_batch = len(self.rows) // n_env
        n_batches = self.episodes // n_env
        artifacts.write_json(self.out / "run.json", {**self.identity(), "status": "running"})
        bar = tqdm(total=self.episodes, initial=len(self.rows), disable=not self.progress, unit="ep", smoothing=0.05)
        t0 = time.perf_counter() - self.wall
        for batch in range(start_batch, n_batches):
            sigma = noise_sigma(cfg, batch * n_env / self.episodes)
            self.agent.scale_learning_rates(lr_factor(cfg, batch * n_env / self.episodes))
            obs = self.env.reset()
            returns = np.zeros((n_env, n))
            diag = {"critic_loss": [], "q_abs": []}
            saturated = 0.0
            for t in range(horizon):
                action, mu = self.agent.act(obs, sigma, self.noise_rng)
                saturated += float((np.abs(mu) > 0.99).mean())
                step = self.env.step(action)
                self.writer.add(obs, action, step.reward * algo.reward_scale, step.obs, last=t == horizon - 1)
                returns += step.reward
                obs = step.obs
                self.transitions += n_env
                if self.buffer.size >= cfg.learning_starts:
                    self.pending_updates += n_env / cfg.update_every
                    tu = time.perf_counter()
                    while self.pending_updates >= 1.0:
                        self.pending_updates -= 1.0
                        stats = self.agent.update(self.buffer.sample(self.sample_rng, cfg.batch_size))
                        diag["critic_loss"].append(stats["critic_loss"])
                        diag["q_abs"].append(stats["q_abs"])
                        self.updates += 1
                    self.update_seconds += time.perf_counter() - tu
            # CR's reward already measured the union at the last step; SW's did not
            coverage = step.union_area / self.region.area if self.rc.method.reward == "cr" else None
            coverage = self.env.coverage_fraction() if coverage is None else coverage
            loss = float(np.mean(diag["critic_loss"])) if diag["critic_loss"] else math.nan
            q_abs = float(np.mean(diag["q_abs"])) if diag["q_abs"] else math.nan
            for e in range(n_env):
                episode = batch * n_env + e
                team = float(returns[e].mean())
                self.rows.append(
                    [episode, *returns[e].tolist(), team, float(coverage[e]), loss, q_abs, saturated / horizon, sigma]
                )
            bar.update(n_env)
            bar.set_postfix(reward=f"{returns.mean():.1f}", coverage=f"{coverage.mean():.2f}")
            done = (batch + 1) * n_env
            if algo.select_every and done % algo.select_every < n_env:
                self.validate(done)
            if done % self.checkpoint_every < n_env and done < self.episodes:
                self.wall = time.perf_counter() - t0
                self.save_checkpoint()
        bar.close()
        self.wall = time.perf_counter() - t0
        self.save_checkpoint()
        self.save_actors()
        summary = {
            **self.identity(),
            "status": "finished",
            "wall_seconds": round(self.wall, 2),
            "update_seconds": round(self.update_seconds, 2),
            "updates": self.updates,
            "transitions": self.transitions,
            "final_coverage_last100": float(np.mean([r[n + 2] for r in self.rows[-100:]])),
        }
        if self.best is not None:
            summary["selected_episode"] = self.best["episode"]
            summary["selected_validation_coverage"] = self.best["coverage"]
        artifacts.write_json(self.out / "run.json", summary)
        return summary

    # ---- selection of the kept actors ------------------------------------------------------------------
    def validate(self, episode: int) -> float:
        """Coverage of the current deterministic actors on the run's fixed validation starts; keeps a copy of
        the actors when it is the best so far (ties go to the later one)."""
        env = self.val_env
        obs = env.reset(self.val_seed)
        for _ in range(self.rc.world.episode_length):
            action, _ = self.agent.act(obs, 0.0, self.noise_rng)
            obs = env.step(action).obs
        coverage = float(env.coverage_fraction().mean())
        self.validation.append([episode, coverage])
        if self.best is None or coverage >= self.best["coverage"]:
            actor = copy.deepcopy(self.agent.actor.state_dict())
            self.best = {"episode": episode, "coverage": coverage, "actor": actor}
        return coverage

    # ---- persistence ------------------------------------------------------------------------------------
    def save_checkpoint(self) -> None:
        header = curve_header(self.env.n_agents)
        artifacts.write_csv(self.out / CURVE, header, self.rows)
        state = {
            "format": CHECKPOINT_FORMAT,
            "identity": self.identity(),
            "agent": self.agent.state_dict(),
            "buffer": self.buffer.state_dict(),
            "rng": {
                "env": self.env.rng.bit_generator.state,
                "noise": self.noise_rng.bit_generator.state,
                "sample": self.sample_rng.bit_generator.state,
            },
            "rows": self.rows,
            "transitions": self.transitions,
            "pending_updates": self.pending_updates,
            "wall": self.wall,
            "updates": self.updates,
            "update_seconds": self.update_seconds,
            "validation": self.validation,
            "best": self.best,
        }
        if self.rc.algo.select_every:
            artifacts.write_csv(self.out / "validation.csv", ["episode", "coverage"], self.validation)
        artifacts.torch_save(self.out / "checkpoint.pt", state)

    def load_checkpoint(self) -> None:
        path = self.out / "checkpoint.pt"
        state = artifacts.torch_load(path)
        mine, theirs = self.identity(), state.get("identity", {})
        diffs = sorted(k for k in mine if mine[k] != theirs.get(k))
        if diffs:
            raise CheckpointError(f"{path}: checkpoint does not match this run (differs in {', '.join(diffs)})")
        try:
            self.agent.load_state_dict(state["agent"])
            self.buffer.load_state_dict(state["buffer"])
            self.env.rng.bit_generator.state = state["rng"]["env"]
            self.noise_rng.bit_generator.state = state["rng"]["noise"]
            self.sample_rng.bit_generator.state = state["rng"]["sample"]
            self.rows = [list(r) for r in state["rows"]]
            self.transitions = int(state["transitions"])
            self.pending_updates = float(state["pending_updates"])
            self.wall = float(state["wall"])
            self.updates = int(state["updates"])
            self.update_seconds = float(state["update_seconds"])
            self.validation = [list(r) for r in state["validation"]]
            self.best = state["best"]
        except (KeyError, RuntimeError, ValueError, TypeError) as exc:
            raise CheckpointError(f"{path}: checkpoint is incomplete or mismatched ({exc})") from exc

    def save_actors(self) -> None:
        """``actors.pt``: the kept actors (selected, or the last); with selection also ``actors_last.pt``."""
        meta = {
            "format": CHECKPOINT_FORMAT,
            "identity": self.identity(),
            "observation": self.rc.algo.observation,
            "obs_dim": self.env.obs_dim,
            "hidden": self.rc.algo.maddpg.hidden,
        }
        last = {**meta, "actor": self.agent.actor.state_dict(), "selected_episode": None}
        if self.best is None:
            artifacts.torch_save(self.out / "actors.pt", last)
            return
        artifacts.torch_save(self.out / "actors_last.pt", last)
        kept = {**meta, "actor": self.best["actor"], "selected_episode": self.best["episode"]}
        artifacts.torch_save(self.out / "actors.pt", kept)


def train(
    rc: RunConfig,
    region: Region,
    episodes: int,
    seed: int,
    out: str | Path,
    checkpoint_every: int = 1000,
    resume: bool = False,
    progress: bool = True,
) -> dict:
    """Train one run into ``out`` (``resume`` continues from its checkpoint, refusing a mismatched one)."""
    torch.set_num_threads(1)
    trainer = Trainer(rc, region, episodes, seed, Path(out), checkpoint_every, progress)
    if resume:
        trainer.load_checkpoint()
    elif (Path(out) / "checkpoint.pt").exists():
        raise CheckpointError(f"{out}: already holds a run; pass --resume to continue it or choose a new folder")
    return trainer.run()


def load_actors(path: str | Path):
    """(actor network [N stacked], metadata) from an ``actors.pt`` written by a run."""
    from .maddpg import BatchedMLP

    state = artifacts.torch_load(path, "actors file")
    try:
        actor_state = state["actor"]
        n = actor_state["weights.0"].shape[0]
        net = BatchedMLP(n, [state["obs_dim"], state["hidden"], state["hidden"], 2], torch.Generator())
        net.load_state_dict(actor_state)
    except (KeyError, RuntimeError) as exc:
        raise CheckpointError(f"{path}: actors file is incomplete or mismatched ({exc})") from exc
    return net, state
