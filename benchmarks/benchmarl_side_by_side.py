"""BenchMARL 1.5.2 MADDPG on VMAS ``simple_spread`` beside the project's MADDPG, on the ``paper`` schedule.

Both sides train 9 agents with 64-64 MLPs, a minibatch of 1,024, one update per 100 frames (a frame is one step
of one environment), 50 environments and T = 50 steps, on one thread. BenchMARL's MADDPG is configured to be the
paper's: a policy and a centralised critic per agent (no parameter sharing), lr 1e-2, γ 0.95, τ 0.01, gradient
norm clipped at 0.5, a replay memory of 10⁶ frames, no evaluation, logging or checkpoints.

Two figures per side, each timed in a fresh process (``--side``), the sides alternating, median of the rounds:
- ``end to end``: seconds per 1,000 episodes of steady training (collection + updates; the first iteration,
  which builds the collector and fills the first batch, is left out);
- ``update alone``: seconds per update of all 9 agents at identical matrix shapes (observation width 38, the
  width of ``simple_spread``'s observation with 9 agents and 9 landmarks: own position and velocity, the
  landmarks' and the other agents' relative positions).

BenchMARL needs the optional ``bench`` extra (``pip install .[bench]``, which ``make bench`` installs).
"""

from __future__ import annotations

import json
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

AGENTS, HIDDEN, BATCH, EVERY, ENVS, HORIZON = 9, 64, 1024, 100, 50, 50
OBS_WIDTH = 4 + 2 * AGENTS + 2 * (AGENTS - 1)  # simple_spread: pos, vel, landmarks, other agents
ITERATIONS = 6  # BenchMARL iterations of 50 episodes each (one leaves out as warm-up)
MARKS: list[tuple[str, float]] = []  # (event, time) of the running BenchMARL experiment

try:
    from benchmarl.experiment.callback import Callback
except ImportError:  # the bench extra is not installed: available() says so
    Callback = object


def available() -> bool:
    try:
        import benchmarl  # noqa: F401
        import vmas  # noqa: F401
    except ImportError:
        return False
    return True


def benchmarl_experiment(save_folder: str, iterations: int, callbacks=()):
    """A BenchMARL ``Experiment`` of MADDPG on VMAS simple_spread with the ``paper`` schedule (module docstring)."""
    import torch
    from benchmarl.algorithms import MaddpgConfig
    from benchmarl.environments import VmasTask
    from benchmarl.experiment import Experiment, ExperimentConfig
    from benchmarl.models.mlp import MlpConfig

    task = VmasTask.SIMPLE_SPREAD.get_from_yaml()
    task.config.update({"n_agents": AGENTS, "max_steps": HORIZON})
    algorithm = MaddpgConfig.get_from_yaml()
    algorithm.share_param_critic = False
    config = ExperimentConfig.get_from_yaml()
    frames = ENVS * HORIZON
    config.share_policy_params = False
    config.gamma, config.lr, config.polyak_tau = 0.95, 1e-2, 0.01
    config.clip_grad_norm, config.clip_grad_val = True, 0.5
    config.off_policy_n_envs_per_worker = ENVS
    config.off_policy_collected_frames_per_batch = frames
    config.off_policy_n_optimizer_steps = frames // EVERY
    config.off_policy_train_batch_size = BATCH
    config.off_policy_memory_size = 1_000_000
    config.max_n_frames, config.max_n_iters = None, iterations
    config.evaluation, config.render, config.loggers, config.create_json = False, False, [], False
    config.checkpoint_interval, config.checkpoint_at_end = 0, False
    config.save_folder = save_folder
    model = MlpConfig(num_cells=[HIDDEN, HIDDEN], layer_class=torch.nn.Linear, activation_class=torch.nn.ReLU)
    return Experiment(task=task, algorithm_config=algorithm, model_config=model, critic_model_config=model,
                      seed=0, config=config, callbacks=list(callbacks))


class Clock(Callback):
    """Stamps the time when each iteration's batch is collected and when its updates end, into ``MARKS`` (a
    module-level class: BenchMARL pickles its callbacks)."""

    def on_batch_collected(self, batch):
        MARKS.append(("collected", time.perf_counter()))

    def on_train_end(self, training_td, group):
        MARKS.append(("trained", time.perf_counter()))


def benchmarl_end_to_end() -> dict:
    """Seconds per 1,000 episodes of BenchMARL's steady training, and its seconds per update (inside the run)."""
    MARKS.clear()
    with tempfile.TemporaryDirectory() as tmp:
        benchmarl_experiment(tmp, ITERATIONS, [Clock()]).run()
    marks = list(MARKS)
    trained = [t for kind, t in marks if kind == "trained"]
    collected = [t for kind, t in marks if kind == "collected"]
    steady = trained[-1] - trained[0]  # iterations 2..N: collection + updates
    per_iteration = steady / (len(trained) - 1)
    updates = [e - c for c, e in zip(collected, trained)][1:]
    return {"per_1000_episodes": per_iteration * 1000 / ENVS,
            "per_update": statistics.median(updates) / (ENVS * HORIZON // EVERY)}


def seconds_per_call(fn, rounds: int, calls: int = 5, warmup: int = 3) -> float:
    """The best over ``rounds`` of the mean seconds of ``calls`` calls of ``fn``, after ``warmup`` calls."""
    for _ in range(warmup):
        fn()
    times = []
    for _ in range(rounds):
        t = time.perf_counter()
        for _ in range(calls):
            fn()
        times.append((time.perf_counter() - t) / calls)
    return min(times)


def benchmarl_update_alone(rounds: int = 5) -> float:
    """Seconds per BenchMARL MADDPG update of the 9 agents (loss, backward, clip, Adam, soft update), on a
    minibatch of 1,024 from a replay memory filled by one collected batch."""
    with tempfile.TemporaryDirectory() as tmp:
        experiment = benchmarl_experiment(tmp, 1)
        experiment.run()  # one iteration: fills the replay memory
        group = next(iter(experiment.train_group_map))
        return seconds_per_call(lambda: experiment._optimizer_loop(group), rounds)


def project_end_to_end(episodes: int = 1000) -> dict:
    """The project's ``paper`` CR-MARL run on the square, one seed: steady seconds per 1,000 episodes (environment
    + updates, with the replay memory past ``learning_starts``) and seconds per update."""
    from replicate.core.params import load_params, run_config
    from replicate.learn.train import Trainer
    from replicate.world.regions import make_region

    params = load_params("params.yaml")
    square = make_region("square", params.regions["square"], params.world.region_area)
    rc = run_config(params, "paper", "cr")
    with tempfile.TemporaryDirectory() as tmp:
        tr = Trainer(rc, square, episodes, 0, Path(tmp) / "run", checkpoint_every=episodes, progress=False)
        tr.run()
    env_per_1000 = (tr.wall - tr.loop.update_seconds) / episodes * 1000
    per_update = tr.loop.update_seconds / max(tr.loop.updates, 1)
    updates_per_1000 = 1000 * rc.world.episode_length / rc.algo.maddpg.update_every
    return {"per_1000_episodes": env_per_1000 + updates_per_1000 * per_update, "per_update": per_update}


def project_agent_and_batch():
    """The project's MADDPG of 9 agents at BenchMARL's shapes (observation width 38, the paper's networks and
    batch) and one minibatch of random transitions."""
    import numpy as np

    from replicate.core.params import load_params
    from replicate.learn.maddpg import MADDPG
    from replicate.learn.replay import Replay

    cfg = load_params("params.yaml").configs["paper"].maddpg
    rng = np.random.default_rng(0)
    size = 4 * BATCH
    buf = Replay(size, AGENTS, OBS_WIDTH)
    obs, next_obs = (rng.normal(size=(size, AGENTS, OBS_WIDTH)).astype(np.float32) for _ in range(2))
    act = rng.uniform(-1, 1, (size, AGENTS, 2)).astype(np.float32)
    buf.add(cfg.gamma, obs=obs, act=act, rew=rng.normal(size=(size, AGENTS)).astype(np.float32), next_obs=next_obs)
    return MADDPG(AGENTS, OBS_WIDTH, 2, cfg, "individual", seed=0), buf.sample(rng, BATCH)


def project_update_alone(rounds: int = 5) -> float:
    """Seconds per update of the project's MADDPG of 9 agents at BenchMARL's shapes (observation width 38)."""
    agent, batch = project_agent_and_batch()
    return seconds_per_call(lambda: agent.update(batch), rounds)


def measure(side: str) -> dict:
    """One side's figures, in this process (``--side``)."""
    import torch

    from replicate.learn.process import training_process

    training_process()
    torch.set_num_threads(1)
    if side == "benchmarl":
        return {**benchmarl_end_to_end(), "update_alone": benchmarl_update_alone()}
    return {**project_end_to_end(), "update_alone": project_update_alone()}


def side_by_side(rounds: int = 3) -> dict[str, dict[str, float]]:
    """{side: median figures} over ``rounds`` fresh processes per side, the sides alternating."""
    runs: dict[str, list[dict]] = {"project": [], "benchmarl": []}
    for _ in range(rounds):
        for side in runs:
            cmd = [sys.executable, __file__, "--side", side]
            done = subprocess.run(cmd, capture_output=True, text=True)
            if done.returncode:
                raise RuntimeError(f"{' '.join(cmd)} failed:\n{done.stderr[-2000:]}")
            runs[side].append(json.loads(done.stdout.strip().splitlines()[-1]))
    return {side: {k: statistics.median(r[k] for r in rs) for k in rs[0]} for side, rs in runs.items()}


if __name__ == "__main__":
    if sys.argv[1:2] == ["--side"]:
        print(json.dumps(measure(sys.argv[2])))
    else:
        print(json.dumps(side_by_side(), indent=1))
