"""The per-region training: E parallel environments, MADDPG updates, per-episode curve, resumable checkpoints.

A run directory holds ``run.json`` (what was run), ``curve.csv.gz`` (one row per episode, gzip: 10,000 rows of
15 columns are 1.2 MB as text and ~0.4 MB compressed), while it trains ``checkpoint.pt`` (everything needed to
continue: networks, optimisers, replay buffer, generator states, the curve so far; deleted at the end) and,
at the end, ``actors.pt`` (the trained decentralised policies: the last ones, or with ``select_every`` the best on
the run's fixed validation starts, whose coverage is logged in ``validation.csv``).
"""

from __future__ import annotations

import dataclasses
import math
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from replicate.core import artifacts
from replicate.core.artifacts import CHECKPOINT_FORMAT, CheckpointError
from replicate.core.params import RunConfig
from replicate.core.progress import bar as progress_bar
from replicate.core.schema import ConfigError, to_dict
from replicate.learn import run_stack
from replicate.learn.fingerprint import fingerprint
from replicate.learn.loop import TrainingLoop
from replicate.learn.maddpg import MADDPG, BatchedMLP
from replicate.learn.replay import Replay
from replicate.learn.runs import run_identity
from replicate.world.regions import Region
from replicate.world.scenario import run_env

DIAGNOSTICS = ("critic_loss", "q_abs", "saturated", "noise")
CURVE = "curve.csv.gz"  # the per-episode curve of a run, in its folder


def curve_header(n_agents: int) -> list[str]:
    return ["episode", *[f"reward_{i}" for i in range(n_agents)], "team_reward", "coverage", *DIAGNOSTICS]


def kept_actor(best: dict | None) -> dict | None:
    """A checkpoint's kept actor as ``loop.TrainingLoop.keep`` holds it; a checkpoint written before the loop
    was shared names its fields ``episode`` and ``coverage``."""
    if best is None or "score" in best:
        return best
    return {"episodes": best["episode"], "score": best["coverage"], "actor": best["actor"]}


def check_schedule(rc: RunConfig, episodes: int, checkpoint_every: int) -> None:
    """Refuse a training schedule that cannot run, before anything is written: episodes, environments and
    checkpoints must be positive, and the episodes a whole number of batches of ``n_envs``."""
    n_envs = rc.algo.n_envs
    if n_envs < 1:
        raise ConfigError(f"n_envs must be at least 1, got {n_envs} (configs.{rc.config_name}.n_envs)")
    if episodes < 1:
        raise ConfigError(f"episodes must be positive, got {episodes}")
    if episodes % n_envs:
        raise ConfigError(f"episodes ({episodes}) must be a multiple of n_envs ({n_envs}); "
                          f"try {max(n_envs, episodes // n_envs * n_envs)}")
    if checkpoint_every < 1:
        raise ConfigError(f"checkpoint_every must be at least 1 episode, got {checkpoint_every}")


@dataclass
class Played:
    """What a batch of episodes gave, per run s and environment e: returns [S, E, N], the last step's coverage
    [S, E], the summed fraction of saturated actions [S], and each update's diagnostics (one [S] array each)."""

    returns: np.ndarray
    saturated: np.ndarray
    coverage: np.ndarray | None = None
    critic_loss: list = dataclasses.field(default_factory=list)
    q_abs: list = dataclasses.field(default_factory=list)


@dataclass
class Trainer:
    """S training runs of one config, method and region, one per seed of ``seeds``, written to the folders ``outs``
    (an int and a folder for one run). The runs step together: their environments are blocks of one batch
    (``CoverageEnv.seed``) and their networks one stack (``MADDPG``), so the per-operation cost of an update and
    an environment step is paid once for all of them. Each run still draws from its own generators, learns from
    its own replay buffer and writes its own folder, and its curve is bit for bit the one it gets alone
    (``tests/learn/test_training.py``). ``run`` trains to ``episodes``; ``load_checkpoint`` first, to continue."""

    rc: RunConfig
    region: Region
    episodes: int
    seeds: int | list[int]
    outs: str | Path | list
    checkpoint_every: int = 1000
    progress: bool = True

    def __post_init__(self) -> None:
        algo = self.rc.algo
        check_schedule(self.rc, self.episodes, self.checkpoint_every)
        self.seeds = [self.seeds] if isinstance(self.seeds, int) else list(self.seeds)
        self.outs = [Path(self.outs)] if isinstance(self.outs, (str, Path)) else [Path(o) for o in self.outs]
        if len(self.outs) != len(self.seeds) or len(set(self.seeds)) != len(self.seeds):
            raise ConfigError(f"need one folder per seed and distinct seeds, got seeds {self.seeds}")
        streams = [np.random.SeedSequence(seed).spawn(4) for seed in self.seeds]  # per run: env, noise, sample, val
        runs = len(self.seeds)
        self.env = run_env(self.region, self.rc, algo.n_envs * runs, [st[0] for st in streams])
        # validation starts: fixed per run, drawn apart from the evaluation seed so selection cannot fit it
        self.val_seeds = [int(st[3].generate_state(1)[0]) for st in streams]
        self.val_env = (run_env(self.region, self.rc, algo.select_episodes * runs, self.val_seeds, reward=False)
                        if algo.select_every else None)
        self.noise_rngs = [np.random.default_rng(st[1]) for st in streams]
        n, od = self.env.n_agents, self.env.obs_dim
        self.agent = MADDPG(n, od, 2, algo.maddpg, self.rc.method.reward_mode, seed=self.seeds)
        capacity = min(algo.maddpg.buffer_size, self.episodes * self.rc.world.episode_length)
        # per run: its replay memory sampled by its own generator; the kept actors when selecting
        self.loop = TrainingLoop(self.agent, algo.maddpg, [Replay(capacity, n, od) for _ in self.seeds],
                                 [np.random.default_rng(st[2]) for st in streams], stacked=True)
        self.rows: list[list] = [[] for _ in self.seeds]  # per run, one row per episode
        self.validation: list[list] = [[] for _ in self.seeds]  # per run, [episode, validation coverage]
        self.transitions = 0  # per run
        self.wall = 0.0  # of the whole stack
        self.cpu = 0.0  # of the whole stack: this process's CPU time, which other processes do not inflate

    def column(self, name: str) -> int:
        """The index of a named column (``curve_header``) in the rows of the curve."""
        return curve_header(self.env.n_agents).index(name)

    def identity(self, run: int = 0) -> dict:
        """What makes run ``run`` the run it is, checked on resume."""
        return run_identity(self.rc, self.region, self.episodes, self.seeds[run])

    def run_record(self, run: int = 0) -> dict:
        """Run ``run``'s identity and the fingerprint of the arithmetic training it (``fingerprint``; recorded,
        not compared: a run resumes or is kept whatever machine trained it)."""
        return {**self.identity(run), "arithmetic": fingerprint()}

    def _runs(self, x: np.ndarray) -> np.ndarray:
        """[S·E, ...] of the stacked environments → [S, E, ...], one block per run."""
        return x.reshape(len(self.seeds), -1, *x.shape[1:])

    def run(self) -> list[dict]:
        """Train every run to ``episodes``, checkpointing on the way; returns the runs' summaries. Each batch of
        ``n_envs`` episodes per run is played (``play``, which learns as the transitions come in: ``loop.learn``),
        recorded (``record``), then validated and checkpointed on their schedules."""
        algo = self.rc.algo
        n_env, runs = algo.n_envs, len(self.seeds)
        for k, out in enumerate(self.outs):
            artifacts.write_json(out / "run.json", {**self.run_record(k), "status": "running"})
        bar = progress_bar(self.progress, total=self.episodes * runs, initial=len(self.rows[0]) * runs,
                           desc="training", unit="episode", smoothing=0.05)
        t0, c0 = time.perf_counter() - self.wall, time.process_time() - self.cpu
        for batch in range(len(self.rows[0]) // n_env, self.episodes // n_env):
            sigma = self.loop.schedule(batch * n_env / self.episodes)
            played = self.play(sigma)
            self.record(batch, played, sigma)
            bar.update(n_env * runs)
            bar.set_postfix(reward=f"{played.returns.mean():.1f}", coverage=f"{played.coverage.mean():.2f}")
            done = (batch + 1) * n_env
            if algo.select_every and done % algo.select_every < n_env:
                self.validate(done)
            if done % self.checkpoint_every < n_env and done < self.episodes:
                self.wall, self.cpu = time.perf_counter() - t0, time.process_time() - c0
                self.save_checkpoint()
        bar.close()
        self.wall, self.cpu = time.perf_counter() - t0, time.process_time() - c0
        self.save_curves()
        self.save_actors()
        return self.finish()

    def play(self, sigma: float) -> Played:
        """One batch of episodes in every run's E environments with exploration ``sigma``: each step's
        transitions go to the runs' buffers (as n-step returns) and every update they are due triggers."""
        algo, n, horizon = self.rc.algo, self.env.n_agents, self.rc.world.episode_length
        runs, n_env = len(self.seeds), algo.n_envs
        obs = self._runs(self.env.reset())  # [S, E, N, od]
        played = Played(returns=np.zeros((runs, n_env, n)), saturated=np.zeros(runs))
        writers = self.loop.writers()
        for t in range(horizon):
            action, mu = self.agent.act(obs, sigma, self.noise_rngs)
            played.saturated += (np.abs(mu) > 0.99).mean(axis=(1, 2, 3))
            step = self.env.step(action.reshape(-1, n, 2))
            reward, pay, next_obs = self._runs(step.reward), self._runs(step.pay), self._runs(step.obs)
            for k, writer in enumerate(writers):
                writer.push(t == horizon - 1, obs=obs[k], act=action[k], rew=pay[k], next_obs=next_obs[k])
            played.returns += reward
            obs = next_obs
            self.transitions += n_env
            for stats in self.loop.learn(n_env):  # the updates due, each on a minibatch of every run's memory
                played.critic_loss.append(stats["critic_loss"])
                played.q_abs.append(stats["q_abs"])
        # CR's reward already measured the union at the last step; SW's did not
        coverage = step.union_area / self.region.area if self.rc.method.reward == "cr" else None
        played.coverage = self._runs(self.env.coverage_fraction() if coverage is None else coverage)
        return played

    def record(self, batch: int, played: Played, sigma: float) -> None:
        """One curve row per episode of the batch, per run (``curve_header``)."""
        n_env, horizon = self.rc.algo.n_envs, self.rc.world.episode_length
        for k in range(len(self.seeds)):
            loss = float(np.mean([d[k] for d in played.critic_loss])) if played.critic_loss else math.nan
            q_abs = float(np.mean([d[k] for d in played.q_abs])) if played.q_abs else math.nan
            for e in range(n_env):
                returns = played.returns[k, e]
                self.rows[k].append([batch * n_env + e, *returns.tolist(), float(returns.mean()),
                                     float(played.coverage[k, e]), loss, q_abs, float(played.saturated[k] / horizon),
                                     sigma])

    def finish(self) -> list[dict]:
        """Each run's summary in its ``run.json``; a finished run needs no checkpoint (100-250 MB), so it goes."""
        summaries = []
        for k, out in enumerate(self.outs):
            summary = {
                **self.run_record(k),
                "status": "finished",
                "wall_seconds": round(self.wall, 2),  # of the stack: every run of it took this long
                "cpu_seconds": round(self.cpu, 2),  # of the stack's process
                "runs_in_process": len(self.seeds),  # so one core's time per run is cpu_seconds / runs_in_process
                "update_seconds": round(self.loop.update_seconds, 2),
                "updates": self.loop.updates,
                "transitions": self.transitions,
                "final_coverage_last100": float(np.mean([r[self.column("coverage")] for r in self.rows[k][-100:]])),
                **self.loop.selection(k),
            }
            artifacts.write_json(out / "run.json", summary)
            (out / "checkpoint.pt").unlink(missing_ok=True)
            summaries.append(summary)
        return summaries

    # ---- selection of the kept actors ------------------------------------------------------------------
    def validate(self, episode: int) -> list[float]:
        """Each run's coverage with its current deterministic actors on its fixed validation starts; a run keeps a
        copy of its actors when that is its best so far (ties go to the later one)."""
        env = self.val_env
        obs = self._runs(env.reset(self.val_seeds))
        for _ in range(self.rc.world.episode_length):
            action, _ = self.agent.act(obs, 0.0, self.noise_rngs)
            obs = self._runs(env.step(action.reshape(-1, *action.shape[2:])).obs)
        coverages = [float(c.mean()) for c in self._runs(env.coverage_fraction())]
        for k, coverage in enumerate(coverages):
            self.validation[k].append([episode, coverage])
            self.loop.keep(k, coverage, episode, lambda k=k: run_stack.network_state(self.agent, "actor", k))
        return coverages

    # ---- persistence: one folder per run, in the same form whatever the stack -------------------------------
    def save_curves(self) -> None:
        """Each run's curve so far and, when selecting, its validations."""
        for k, out in enumerate(self.outs):
            artifacts.write_csv(out / CURVE, curve_header(self.env.n_agents), self.rows[k])
            if self.rc.algo.select_every:
                artifacts.write_csv(out / "validation.csv", ["episode", "coverage"], self.validation[k])

    def save_checkpoint(self) -> None:
        """The curves, and each run's checkpoint: everything needed to continue it, alone or in any stack."""
        self.save_curves()
        for k, out in enumerate(self.outs):
            state = {
                "format": CHECKPOINT_FORMAT,
                "identity": self.identity(k),
                "agent": run_stack.run_state(self.agent, k),
                "buffer": self.loop.memories[k].state_dict(),
                "rng": {
                    "env": self.env.rngs[k].bit_generator.state,
                    "noise": self.noise_rngs[k].bit_generator.state,
                    "sample": self.loop.sample_rngs[k].bit_generator.state,
                },
                "rows": self.rows[k],
                "transitions": self.transitions,
                "pending_updates": self.loop.pending_updates,
                "wall": self.wall,
                "cpu": self.cpu,
                "updates": self.loop.updates,
                "update_seconds": self.loop.update_seconds,
                "validation": self.validation[k],
                "best": self.loop.kept[k],
            }
            artifacts.torch_save(out / "checkpoint.pt", state)

    def load_checkpoint(self) -> None:
        """Continue every run from its folder's checkpoint; the runs of a stack must stand at the same point."""
        states = []
        for k, out in enumerate(self.outs):
            path = out / "checkpoint.pt"
            state = artifacts.torch_load(path)
            mine, theirs = self.identity(k), state.get("identity", {})
            diffs = sorted(key for key in mine if mine[key] != theirs.get(key))
            if diffs:
                raise CheckpointError(f"{path}: checkpoint does not match this run (differs in {', '.join(diffs)})")
            states.append((path, state))
        points = {(len(st.get("rows", ())), st.get("transitions"), st.get("updates")) for _, st in states}
        if len(points) > 1:
            raise CheckpointError(f"the checkpoints in {', '.join(map(str, self.outs))} stand at different points")
        for k, (path, state) in enumerate(states):
            try:
                run_stack.load_run_state(self.agent, state["agent"], k)
                self.loop.memories[k].load_state_dict(state["buffer"])
                self.env.rngs[k].bit_generator.state = state["rng"]["env"]
                self.noise_rngs[k].bit_generator.state = state["rng"]["noise"]
                self.loop.sample_rngs[k].bit_generator.state = state["rng"]["sample"]
                self.rows[k] = [list(r) for r in state["rows"]]
                self.validation[k] = [list(r) for r in state["validation"]]
                self.loop.kept[k] = kept_actor(state["best"])
                self.transitions = int(state["transitions"])
                self.loop.pending_updates, self.loop.updates = float(state["pending_updates"]), int(state["updates"])
                self.wall, self.loop.update_seconds = float(state["wall"]), float(state["update_seconds"])
                # a checkpoint without CPU time counts its wall time, as its run's summary does
                self.cpu = float(state.get("cpu", state["wall"]))
            except (KeyError, RuntimeError, ValueError, TypeError) as exc:
                raise CheckpointError(f"{path}: checkpoint is incomplete or mismatched ({exc})") from exc

    def save_actors(self) -> None:
        """Each run's ``actors.pt``: its kept actors (selected, or the last); with selection also ``actors_last.pt``."""
        for k, out in enumerate(self.outs):
            meta = {
                "format": CHECKPOINT_FORMAT,
                "identity": self.identity(k),
                "observation": self.rc.algo.observation,
                "obs_dim": self.env.obs_dim,
                **({"sensors": to_dict(self.rc.algo.sensors)} if self.rc.algo.observation == "local" else {}),
                "hidden": self.rc.algo.maddpg.hidden,
            }
            last = {**meta, "actor": run_stack.network_state(self.agent, "actor", k), "selected_episode": None}
            best = self.loop.kept[k]
            if best is None:
                artifacts.torch_save(out / "actors.pt", last)
                continue
            artifacts.torch_save(out / "actors_last.pt", last)
            kept = {**meta, "actor": best["actor"], "selected_episode": best["episodes"]}
            artifacts.torch_save(out / "actors.pt", kept)


def train_runs(
    rc: RunConfig,
    region: Region,
    episodes: int,
    seeds: list[int],
    outs: list[str | Path],
    checkpoint_every: int = 1000,
    resume: bool = False,
    progress: bool = True,
) -> list[dict]:
    """Train one run per seed, all in this process (``Trainer``), into ``outs``; ``resume`` continues them from
    their checkpoints, refusing mismatched ones. Leftovers of a writer that was killed (``.*.tmp``) are removed
    first. The process-wide settings of a training process (``training_process``) are its entry point's."""
    for out in outs:
        for leftover in Path(out).glob(".*.tmp"):
            leftover.unlink(missing_ok=True)
    trainer = Trainer(rc, region, episodes, list(seeds), [Path(o) for o in outs], checkpoint_every, progress)
    if resume:
        trainer.load_checkpoint()
    else:
        for out in trainer.outs:
            if (out / "checkpoint.pt").exists():
                raise CheckpointError(f"{out}: already holds a run; pass --resume to continue it or choose a new "
                                      "folder")
    return trainer.run()


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
    return train_runs(rc, region, episodes, [seed], [out], checkpoint_every, resume, progress)[0]


def load_actors(path: str | Path):
    """(actor network [N stacked], metadata) from an ``actors.pt`` written by a run."""

    state = artifacts.torch_load(path, "actors file")
    try:
        actor_state = state["actor"]
        n = actor_state["weights.0"].shape[0]
        net = BatchedMLP(n, [state["obs_dim"], state["hidden"], state["hidden"], 2], torch.Generator())
        net.load_state_dict(actor_state)
    except (KeyError, RuntimeError) as exc:
        raise CheckpointError(f"{path}: actors file is incomplete or mismatched ({exc})") from exc
    return net, state
