"""`make bench`: speed figures, each measured in this one run against a reference run beside it.

0. This machine: single-thread matmul throughput, each configuration's matmul GFLOP per update (the floor of an
   update at that throughput), and where an update's time goes (wide matmuls, skinny ones, elementwise ops and
   copies, optimiser), so run times measured on different machines and the room left for speed-ups can be read.
1. Time per 1,000 episodes of the paper and tuned configurations (CR-MARL and SW-MARL, square), split into
   environment + geometry + acting (+ validation) and MADDPG updates, and the projected wall time of a full
   10,000-episode run (the budget `tuned` was designed for: ``report.target_seconds`` of one core): for a run
   alone, and per run of a cell's seeds stacked in one process with a second such process beside it, as the
   pipeline's `train` stage runs them (two processes share the caches and the memory bus: each runs slower than
   alone), with the ratio.
   From the side-by-side figures, the projected `train` stage (every run of params.yaml's matrix and ablation)
   and the same with every update at its matmul floor; section 8 adds the other stages.
2. One update of all 9 agents, per configuration: the training's update (``MADDPG.update``, autograd over the
   stacked agents) against the per-agent loop of separate networks (``tests/learn/loop_maddpg.py``), as a ratio.
3. Environment throughput (agent-steps per second, random actions) at E = 1, 50 and 1,024 environments, with the
   CR reward on the square and with the shore wall on Bedok, against PettingZoo MPE2 ``simple_spread_v3`` (N = 9,
   continuous actions, one environment) and VMAS ``simple_spread`` (9 agents, the same E), as ratios.
4. The allocator setting of the training processes (``process.hold_freed_memory``): ``paper``'s CR-MARL stack of
   seeds trained in fresh processes with glibc's default allocator against the held one, one process alone and
   two side by side (as the pipeline runs them); time per update, page faults, and the ratios.
5. BenchMARL 1.5.2 MADDPG on VMAS ``simple_spread`` against the project's MADDPG, both on the ``paper`` schedule:
   seconds per 1,000 episodes end to end and one update at identical matrix shapes, as ratios, with the
   project's matmul floor at those shapes (the most any update of those matmuls could lead by)
   (``benchmarks/benchmarl_side_by_side.py``; sections 3's VMAS and 5 need the ``bench`` extra, which
   ``make bench`` installs).
6. One update of the general policy's learner (``shared_maddpg``: the shared actor and the pooled critic) on a
   minibatch shaped as its training samples it, against its matmul floor and against the same update with its two
   losses compiled by ``torch.compile`` (inductor), and where its time goes; then a general seed's projected CPU
   (batches timed across its training worlds, scaled to ``general.episodes``) with the actor as trained and with
   the averaged compass actor (``symmetry: d4``, its value before ``d4_frame``), against its target.
7. What a field team waits for (``benchmarks/field_bench.py``): `replicate --help`'s start-up, `act --stream`'s
   latency per step (9 buoys) and per buoy and step (50 buoys in one stream), `replicate plan` on a real lake, and
   `replicate evaluate --policy` on each real lake (wall time and peak memory against their targets).
8. The pipeline from scratch, stage by stage: ``train`` as section 1 projects it, the general seeds' stages from
   section 6's seed, the others as the last measured forced ``dvc repro`` (``benchmarks/from_scratch.json``), in
   all and with 8 reported general seeds, against its target.
Every target is read from ``params.yaml`` (``bench``; ``tuned``'s run from ``report.target_seconds``).

``--quick`` (``make bench ARGS=--quick``) prints every figure but section 4's from shorter timings (600 episodes,
fewer batches), within 15 minutes on two cores; the run's own duration is its last line.

Everything runs on one thread (``torch.set_num_threads(1)``), the budget of one core of the 2-core machine, and
sections 0-3 with the allocator setting of the pipeline's training processes.
``--full`` also trains the real 10,000-episode paper CR run on the square and prints its wall time.
"""

from __future__ import annotations

import argparse
import dataclasses
import math
import sys
import tempfile
import time
from pathlib import Path

import benchmarl_side_by_side as benchmarl_bench  # beside this file
import field_bench  # beside this file
import numpy as np
import torch
from torch import nn

from replicate.core.params import load_params, run_config
from replicate.learn.general_train import GeneralTrainer
from replicate.learn.maddpg import MADDPG
from replicate.learn.process import hold_freed_memory
from replicate.learn.replay import Batch, Replay
from replicate.learn.shared_maddpg import SharedMADDPG, live_rows
from replicate.learn.train import Trainer
from replicate.learn.training_worlds import baseline_worlds
from replicate.pipeline.matrix import cell_seeds, matrix_cells
from replicate.world.env import CoverageEnv, observation_columns
from replicate.world.regions import make_region

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # the repository, for the tests' reference update
from tests.learn.loop_maddpg import LoopMADDPG  # noqa: E402

torch.set_num_threads(1)


def best_of(fn, repeats=5):
    times = []
    for _ in range(repeats):
        t = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t)
    return min(times)


def training_split(params, square, config: str, method: str, episodes: int, runs: int = 1):
    """(env seconds per 1,000 episodes, seconds per update, projected 10k wall), each per run, from a short real
    training of ``runs`` seeds stacked in one process (``train.Trainer``)."""
    rc = run_config(params, config, method)
    with tempfile.TemporaryDirectory() as tmp:
        tr = Trainer(rc, square, episodes, list(range(runs)), [Path(tmp) / f"run{k}" for k in range(runs)],
                     checkpoint_every=episodes, progress=False)
        tr.run()
    env_s = (tr.wall - tr.loop.update_seconds) / episodes * 1000 / runs
    per_update = tr.loop.update_seconds / max(tr.loop.updates, 1) / runs
    return env_s, per_update, *projected_run(params, config, method, env_s, per_update)


def projected_run(params, config: str, method: str, env_s: float, per_update: float) -> tuple[float, float]:
    """(update seconds per 1,000 episodes once learning runs, projected seconds of a 10,000-episode run) on the
    square, from a run's environment seconds per 1,000 episodes and seconds per update."""
    rc = run_config(params, config, method)
    cfg = rc.algo.maddpg
    total = params.train.episodes * rc.world.episode_length
    full_updates = (total - cfg.learning_starts) / cfg.update_every
    steady_updates_per_1000 = 1000 * rc.world.episode_length / cfg.update_every
    return steady_updates_per_1000 * per_update, env_s * params.train.episodes / 1000 + full_updates * per_update


def split_probe(config: str, method: str, runs: int, episodes: int) -> None:
    """One ``training_split`` in this fresh process (section 1's side-by-side figures), printed as JSON."""
    import json

    hold_freed_memory()
    params = load_params("params.yaml")
    square = make_region("square", params.regions["square"], params.world.region_area)
    env_s, per_update, _, _ = training_split(params, square, config, method, episodes, runs=runs)
    print(json.dumps({"env_s": env_s, "per_update": per_update}))


def probes_side_by_side(args: list[str], processes: int) -> list[dict]:
    """Run ``processes`` fresh copies of this script with ``args`` (a hidden probe option) at once; → the JSON each
    printed last."""
    import json
    import subprocess

    cmd = [sys.executable, __file__, *args]
    procs = [subprocess.Popen(cmd, stdout=subprocess.PIPE, text=True) for _ in range(processes)]
    outputs = [p.communicate()[0] for p in procs]
    if any(p.returncode for p in procs):
        raise RuntimeError(f"probe failed: {' '.join(cmd)}")
    return [json.loads(o.strip().splitlines()[-1]) for o in outputs]


def side_by_side_split(config: str, method: str, runs: int, episodes: int) -> tuple[float, float]:
    """(env seconds per 1,000 episodes, seconds per update), per run, of ``runs`` seeds stacked in one process
    while a second, identical process trains beside it: the mean of the two."""
    probes = probes_side_by_side(["--split-probe", config, method, str(runs), "--episodes", str(episodes)], 2)
    return tuple(float(np.mean([pr[k] for pr in probes])) for k in ("env_s", "per_update"))


FROM_SCRATCH = Path(__file__).with_name("from_scratch.json")  # the last measured forced `dvc repro`


def record_from_scratch(clone: str) -> dict:
    """Write ``FROM_SCRATCH`` from a clone where a forced ``dvc repro`` ran from scratch (``runs/``, ``policies/``
    and the study files deleted first): each stage's wall seconds (its executed notebook's papermill duration),
    the clone's commit, and the core seconds its ``train`` stage's runs recorded."""
    import json
    import subprocess

    root = Path(clone)
    stages = {}
    for path in sorted((root / "notebooks" / "executed").glob("*.ipynb")):
        duration = json.loads(path.read_text())["metadata"].get("papermill", {}).get("duration")
        if duration is not None:
            stages[path.stem] = round(float(duration), 1)
    commit = subprocess.run(["git", "-C", str(root), "rev-parse", "--short", "HEAD"], capture_output=True,
                            text=True, check=True).stdout.strip()
    record = {"commit": commit, "stage_seconds": stages,
              "date": time.strftime("%Y-%m-%d", time.gmtime((root / "notebooks" / "executed").stat().st_mtime))}
    FROM_SCRATCH.write_text(json.dumps(record, indent=2, sort_keys=True) + "\n")
    return record


def train_stage_projection(params, splits, floors, workers: int = 2) -> tuple[int, float, float]:
    """(runs, projected seconds, seconds with updates at the matmul floor) of the pipeline's ``train`` stage:
    every cell of ``pipeline`` in params.yaml plus the ablation, × seeds, ``workers`` processes at a time, each
    training a cell's seeds as one stack (``splits`` are measured per run of such a stack, two processes side by
    side). A run costs
    the square's environment time of its config family and method (``splits``), scaled by its region's episode
    length, plus its update count times the measured update of the same batch size (``paper``'s for batch 1024,
    ``tuned``'s for 128)."""
    import yaml

    matrix = yaml.safe_load(Path("params.yaml").read_text())["pipeline"]
    cells = matrix_cells(params, matrix["configs"], matrix["methods"], matrix["regions"], matrix["ablation"])
    by_batch = {params.configs[f].maddpg.batch_size: f for f in CONFIGS}
    total = floor = 0.0
    for config, method, region in cells:
        rc = run_config(params, config, method, region)
        cfg = rc.algo.maddpg
        family = by_batch[cfg.batch_size]
        env_s = splits[("paper" if config == "paper" else "tuned", method)][0]
        per_update = splits[(family, method)][1]
        updates = (params.train.episodes * rc.world.episode_length - cfg.learning_starts) / cfg.update_every
        env = env_s * params.train.episodes / 1000 * rc.world.episode_length / params.world.episode_length
        seeds = len(cell_seeds(params, config))
        total += seeds * (env + updates * per_update)
        floor += seeds * (env + updates * floors[family])
    runs = sum(len(cell_seeds(params, config)) for config, _, _ in cells)
    return runs, total / workers, floor / workers


def machine_gemm_gflops(seconds=1.0) -> float:
    """Single-thread GFLOPS of the update's typical matmul (9 stacked [128, 54] x [54, 64]): the machine's speed,
    so run times measured on different machines can be compared."""
    x, w, b = torch.randn(9, 128, 54), torch.randn(9, 54, 64), torch.zeros(9, 1, 64)
    calls, t = 0, time.perf_counter()
    while time.perf_counter() - t < seconds:
        torch.baddbmm(b, x, w)
        calls += 1
    return 2 * 9 * 128 * 54 * 64 * calls / (time.perf_counter() - t) / 1e9


CONFIGS = ("paper", "tuned")


def agent_and_batch(params, config: str) -> tuple[MADDPG, object]:
    """A fresh training learner of ``config`` (9 agents, CR's per-agent rewards) and one minibatch of random
    transitions."""
    algo = params.configs[config]
    cfg, od = algo.maddpg, len(observation_columns(algo.observation, algo.sensors))
    rng = np.random.default_rng(0)
    size = 4 * cfg.batch_size
    buf = Replay(size, 9, od)
    buf.add(cfg.gamma, obs=rng.normal(size=(size, 9, od)).astype(np.float32),
            act=rng.uniform(-1, 1, (size, 9, 2)).astype(np.float32), rew=rng.normal(size=(size, 9)).astype(np.float32),
            next_obs=rng.normal(size=(size, 9, od)).astype(np.float32))
    return MADDPG(9, od, 2, cfg, "individual", seed=0), buf.sample(rng, cfg.batch_size)


def general_agent_and_batch(params) -> tuple[SharedMADDPG, Batch]:
    """A fresh general policy's learner and one minibatch as its training samples it: ``general.batch_size``
    transitions padded to the largest training fleet, each of a fleet size drawn from the training worlds'."""
    gc = params.general
    columns = observation_columns("local", gc.sensors)
    od = len(columns)
    fleets = [n for _, n in baseline_worlds(params, gc)]
    g = torch.Generator().manual_seed(0)
    b, n_max = gc.batch_size, max(fleets)
    n = torch.tensor(fleets)[torch.randint(len(fleets), (b,), generator=g)]
    live = torch.arange(n_max)[None] < n[:, None]

    def normal(*shape):
        return torch.randn(*shape, generator=g)

    batch = Batch(obs=normal(b, n_max, od), act=normal(b, n_max, 2).tanh(), rew=normal(b, n_max),
                  next_obs=normal(b, n_max, od), pos=normal(b, n_max, 2), next_pos=normal(b, n_max, 2),
                  live=live, next_live=live, disc=torch.full((b,), gc.gamma))
    return SharedMADDPG(od, 2, gc.learner, seed=0, columns=columns), batch


def update_gflop(agent, batch) -> float:
    """Matmul GFLOP of one update (forward and backward), counted by torch's FlopCounterMode."""
    from torch.utils.flop_counter import FlopCounterMode

    with FlopCounterMode(display=False) as counter:
        agent.update(batch)
    return counter.get_total_flops() / 1e9


def update_breakdown(agent, batch, updates: int = 5) -> dict[str, tuple[float, float]]:
    """Where one update's time goes: {kind: (ms per update, matmul GFLOPS or nan)}, timing every aten call
    (``TorchDispatchMode``). Matmuls are split into wide ones (every dimension ≥ 16) and skinny ones (an output
    width or inner size below 16: the last layers and their gradients). An inner size of 1 is a broadcast
    multiply in ``maddpg.stacked_matmul``, so it counts with the elementwise ops."""
    from collections import defaultdict

    from torch.utils._python_dispatch import TorchDispatchMode

    agent.update(batch)
    seconds, flops = defaultdict(float), defaultdict(float)

    class Timer(TorchDispatchMode):
        def __torch_dispatch__(self, func, types, args=(), kwargs=None):
            t = time.perf_counter()
            out = func(*args, **(kwargs or {}))
            dt = time.perf_counter() - t
            name = func.__name__.split(".")[0]
            if name in ("bmm", "baddbmm", "mm", "addmm"):
                a, b = args[:2] if name in ("bmm", "mm") else args[1:3]  # the two factors, after any bias
                m, k, n = a.shape[-2], a.shape[-1], b.shape[-1]
                kind = "matmul, wide" if min(m, k, n) >= 16 else "matmul, skinny"
                flops[kind] += 2 * a[..., 0, 0].numel() * m * k * n
            elif name.startswith(("_fused_adam", "_foreach")):
                kind = "optimiser, clip, soft update"
            else:
                kind = "elementwise, copies, reductions"
            seconds[kind] += dt
            return out

    with Timer():
        for _ in range(updates):
            agent.update(batch)
    return {k: (v / updates * 1e3, flops[k] / v / 1e9 if k in flops else float("nan")) for k, v in seconds.items()}


def update_times(params, config: str, rounds: int = 5) -> dict[str, float]:
    """Seconds per update of 9 agents: the training's update (``MADDPG.update``) and the per-agent loop, timed
    alternately (best of 5 × 5 updates, median over ``rounds``) so that the machine's drift hits both alike."""
    agent, batch = agent_and_batch(params, config)
    rivals = {"stacked": agent, "per-agent loop": LoopMADDPG(agent)}
    times = {k: [] for k in rivals}
    for agent in rivals.values():
        agent.update(batch)
    for _ in range(rounds):
        for k, agent in rivals.items():
            times[k].append(best_of(lambda agent=agent: [agent.update(batch) for _ in range(5)]) / 5)
    return {k: float(np.median(v)) for k, v in times.items()}


def env_throughput(params, region, n_envs: int, seconds=3.0, wall: bool = False):
    """Agent-steps per second of the coverage environment with the CR reward, random actions (``wall``: the shore
    is a wall, ``world.shore: wall``)."""
    env = CoverageEnv(region, params.world, params.coverage, n_envs=n_envs, reward="cr", cr=params.cr_reward, seed=0,
                      wall=wall)
    rng = np.random.default_rng(0)
    steps = 0
    env.reset()
    env.step(rng.uniform(-1, 1, (n_envs, 9, 2)))  # compiles the numba kernels outside the timing
    t = time.perf_counter()
    while time.perf_counter() - t < seconds:
        env.step(rng.uniform(-1, 1, (n_envs, 9, 2)))
        steps += 1
        if env.t >= params.world.episode_length:
            env.reset()
    return steps * n_envs * 9 / (time.perf_counter() - t)


def mpe2_throughput(seconds=3.0):
    from mpe2 import simple_spread_v3

    env = simple_spread_v3.parallel_env(N=9, continuous_actions=True, max_cycles=50)
    env.reset(seed=0)
    rng = np.random.default_rng(0)
    agents = list(env.agents)
    steps = 0
    t = time.perf_counter()
    while time.perf_counter() - t < seconds:
        actions = {a: rng.uniform(0, 1, 5).astype(np.float32) for a in agents}
        _, _, term, trunc, _ = env.step(actions)
        steps += 1
        if any(trunc.values()) or any(term.values()) or not env.agents:
            env.reset()
    return steps * 9 / (time.perf_counter() - t)


def vmas_throughput(n_envs: int, seconds=3.0) -> float:
    """Agent-steps per second of VMAS ``simple_spread`` (9 agents, continuous actions, CPU, one thread), random
    actions; needs the ``bench`` extra."""
    import vmas

    env = vmas.make_env("simple_spread", num_envs=n_envs, device="cpu", continuous_actions=True, seed=0,
                        n_agents=9, max_steps=50)
    env.reset()
    gen = torch.Generator().manual_seed(0)
    env.step([torch.rand(n_envs, 2, generator=gen) * 2 - 1 for _ in range(9)])
    steps = 1
    t = time.perf_counter()
    while time.perf_counter() - t < seconds:
        env.step([torch.rand(n_envs, 2, generator=gen) * 2 - 1 for _ in range(9)])
        steps += 1
        if steps % 50 == 0:
            env.reset()
    return steps * n_envs * 9 / (time.perf_counter() - t)


def allocator_probe(allocator: str, episodes: int) -> None:
    """One timed training in this fresh process (section 4), printed as JSON: ``paper`` CR-MARL, 3 seeds stacked,
    with glibc's ``default`` allocator or the ``held`` one."""
    import json
    import resource

    if allocator == "held":
        hold_freed_memory()
    params = load_params("params.yaml")
    square = make_region("square", params.regions["square"], params.world.region_area)
    before = resource.getrusage(resource.RUSAGE_SELF)
    _, per_update, _, _ = training_split(params, square, "paper", "cr", episodes, runs=3)
    after = resource.getrusage(resource.RUSAGE_SELF)
    print(json.dumps({"per_update": per_update, "faults": after.ru_minflt - before.ru_minflt,
                      "system_seconds": after.ru_stime - before.ru_stime}))


def allocator_comparison(episodes: int) -> dict[tuple[str, int], dict]:
    """{(allocator, processes side by side): the first process's probe} for both allocators, 1 and 2 processes."""
    return {(allocator, side_by_side): probes_side_by_side(
                ["--allocator-probe", allocator, "--episodes", str(episodes)], side_by_side)[0]
            for side_by_side in (1, 2) for allocator in ("default", "held")}


def machine_section(params) -> dict[str, float]:
    """Section 0; → each configuration's matmul floor of an update, in seconds."""
    print("== 0. this machine (one thread) ==")
    gflops = machine_gemm_gflops()
    print(f"matmul throughput {gflops:.1f} GFLOPS; per-run times below scale with it across machines")
    floors = {}
    for config in CONFIGS:
        gflop = update_gflop(*agent_and_batch(params, config))
        floors[config] = gflop / gflops
        print(f"{config}: one update of 9 agents is {gflop:.3f} GFLOP of matmuls: {floors[config] * 1e3:.1f} ms "
              f"at that throughput (the floor for an update)")
        parts = update_breakdown(*agent_and_batch(params, config))
        print(f"{config}: where an update's time goes (every aten call timed, so the total runs slower): " + "; ".join(
            f"{k} {ms:.2f} ms" + (f" at {gf:.1f} GFLOPS" if gf == gf else "") for k, (ms, gf) in sorted(parts.items())))
    gflop = update_gflop(*general_agent_and_batch(params))
    floors["general"] = gflop / gflops
    print(f"general policy (shared actor, pooled critic, batch {params.general.batch_size} fleets): one update is "
          f"{gflop:.3f} GFLOP of matmuls: {floors['general'] * 1e3:.1f} ms at that throughput")
    return floors


class CompiledSharedMADDPG(SharedMADDPG):
    """The general policy's update with its two losses compiled by ``torch.compile`` (inductor, CPU): the
    candidate the update is measured against. The rows and neighbours (data-dependent shapes) are selected eagerly
    as in ``SharedMADDPG.update``; the optimiser steps and the soft update stay eager."""

    def __init__(self, *args, **kwargs):
        super().__init__(*args, **kwargs)
        self.critic_loss = torch.compile(self._critic_loss, dynamic=False)
        self.actor_loss = torch.compile(self._actor_loss, dynamic=False)

    def _critic_loss(self, b: Batch, rows, now, then, next_rows):
        with torch.no_grad():
            next_act = b.act.new_zeros(b.act.shape)
            next_act[next_rows] = self.actor_target(b.next_obs[next_rows])[0]
            pool = self.critic_target.pooled(b.next_obs, next_act, then)
            q_next = self.critic_target.score(b.next_obs[rows], next_act[rows], pool) * b.next_live[rows]
            y = b.rew[rows] + b.disc[rows[0]] * q_next
        q = self.critic.score(b.obs[rows], b.act[rows], self.critic.pooled(b.obs, b.act, now))
        return ((q - y) ** 2).mean()

    def _actor_loss(self, b: Batch, rows, now):
        with torch.no_grad():
            pool = self.critic.pooled(b.obs, b.act, now)
        mu, pre = self.actor(b.obs[rows])
        return -self.critic.score(b.obs[rows], mu, pool).mean() + self.cfg.actor_reg * (pre**2).mean()

    def update(self, b: Batch) -> None:
        rows, next_rows = live_rows(b.live), live_rows(b.next_live)
        now, then = self.critic.neighbours(b.pos, b.live, rows), self.critic.neighbours(b.next_pos, b.next_live, rows)
        for loss, args, opt, net, inputs in (
                (self.critic_loss, (b, rows, now, then, next_rows), self.critic_opt, self.critic, None),
                (self.actor_loss, (b, rows, now), self.actor_opt, self.actor, list(self.actor.parameters()))):
            value = loss(*args)
            opt.zero_grad()
            value.backward(inputs=inputs)
            nn.utils.clip_grad_norm_(net.parameters(), self.cfg.grad_clip)
            opt.step()
        with torch.no_grad():
            for net, target in ((self.critic, self.critic_target), (self.actor, self.actor_target)):
                for p, tp in zip(net.parameters(), target.parameters()):
                    tp.lerp_(p, self.cfg.tau)


def general_update_section(params, floors: dict[str, float]) -> None:
    print("== 6. one update of the general policy (shared actor, pooled critic), at its training shapes ==")
    agent, batch = general_agent_and_batch(params)
    columns = observation_columns("local", params.general.sensors)
    compiled = CompiledSharedMADDPG(len(columns), 2, params.general.learner, seed=0, columns=columns)
    t = time.perf_counter()
    compiled.update(batch)
    compile_s = time.perf_counter() - t
    agent.update(batch)
    times = {k: [] for k in ("eager", "compiled")}
    for _ in range(3):  # alternately, so that the machine's drift hits both alike
        for k, a in (("eager", agent), ("compiled", compiled)):
            times[k].append(best_of(lambda a=a: [a.update(batch) for _ in range(5)]) / 5)
    per_update, with_compile = float(np.median(times["eager"])), float(np.median(times["compiled"]))
    n_max, live = batch.live.shape[1], batch.live.float().mean().item()
    print(f"{per_update * 1e3:.1f} ms per update ({batch.live.shape[0]} fleets padded to {n_max} buoys, {live:.0%} of "
          f"the slots live); the matmul floor {floors['general'] * 1e3:.1f} ms is {floors['general'] / per_update:.0%}"
          f" of it ({per_update / floors['general']:.2f}x the floor)")
    print(f"with its two losses compiled (torch.compile, inductor): {with_compile * 1e3:.1f} ms "
          f"({with_compile / per_update:.2f}x the eager update; {compile_s:.0f} s to compile)")
    parts = update_breakdown(*general_agent_and_batch(params))
    print("where it goes (every aten call timed, so the total runs slower): " + "; ".join(
        f"{k} {ms:.2f} ms" + (f" at {gf:.1f} GFLOPS" if gf == gf else "") for k, (ms, gf) in sorted(parts.items())))


def general_seed_cpu(params, symmetry: str, batches: int) -> float:
    """Projected CPU seconds of one general seed (``general.episodes``) with the actor's ``symmetry``: the trainer's
    set-up, ``batches`` batches after those that fill the replay to ``learning_starts`` (so that every timed batch
    makes its updates), spread over the training worlds, and one validation, each in process CPU, scaled to the
    seed's batches and validations."""
    gc = dataclasses.replace(params.general, learner=dataclasses.replace(params.general.learner, symmetry=symmetry))
    with tempfile.TemporaryDirectory() as tmp:
        start = time.process_time()
        trainer = GeneralTrainer(params, 0, Path(tmp) / "g", False, gc)
        setup = time.process_time() - start
        worlds = trainer.worlds
        while trainer.loop.memories[0].size < gc.learning_starts:
            trainer.play(worlds[0], gc.noise_start)
        start = time.process_time()
        for b in range(batches):
            trainer.play(worlds[(1 + b * len(worlds) // batches) % len(worlds)], gc.noise_start)
        per_batch = (time.process_time() - start) / batches
        start = time.process_time()
        trainer.validate(gc.n_envs)
        per_validation = time.process_time() - start
    total = gc.episodes // gc.n_envs
    return setup + per_batch * total + per_validation * (total // len(worlds) + 1)


def general_seed_section(params, batches: int) -> dict[str, float]:
    """Section 6's second part: a general seed's projected CPU, as trained and with the averaged compass actor
    ``d4`` (8 copies of the network; the training's ``d4_frame`` runs it once) → {symmetry: s}."""
    symmetry = params.general.learner.symmetry
    seconds = {s: general_seed_cpu(params, s, batches) for s in dict.fromkeys((symmetry, "d4"))}
    target = params.bench.general_seed_s
    for s, cpu in seconds.items():
        print(f"a general seed ({params.general.episodes:,} episodes, symmetry {s}): projected {cpu:.0f} s of one "
              f"core, alone ({batches} batches timed across the training worlds; two seeds side by side run slower, "
              f"as section 1's runs; target <= {target:.0f} s: {cpu / target:.2f}x)"
              + (f"; {cpu / seconds[symmetry]:.2f}x the {symmetry} actor's" if s != symmetry else ""))
    return seconds


def training_section(params, square, floors: dict[str, float], episodes: int) -> float:
    print("== 1. training time per run, square (one thread): a run alone, and a cell's seeds stacked in one process "
          "with a second such process beside it, as the pipeline's `train` stage runs them ==")
    splits = {}
    for config, target in (("paper", params.bench.paper_run_s), ("tuned", params.report.target_seconds)):
        seeds = len(cell_seeds(params, config))
        for method in ("cr", "sw"):
            alone = training_split(params, square, config, method, episodes)
            env_s, per_update = side_by_side_split(config, method, seeds, episodes)
            splits[(config, method)] = (env_s, per_update)
            stacked = (env_s, per_update, *projected_run(params, config, method, env_s, per_update))
            for label, (env_s, per_update, upd_1000, full) in (("alone", alone), (f"{seeds} stacked x2", stacked)):
                print(f"{config} {method.upper()}-MARL, {label:12s}: per 1,000 episodes: environment+geometry+acting "
                      f"{env_s:6.1f} s, updates {upd_1000:6.1f} s ({per_update * 1e3:.1f} ms per update of 9 "
                      f"agents); projected 10,000-episode run {full:6.1f} s (target {target:.0f} s); the matmul floor "
                      f"is {floors[config] / per_update:.0%} of an update's time")
            print(f"{config} {method.upper()}-MARL: {seeds} seeds stacked, two processes side by side, take "
                  f"{stacked[3] / alone[3]:.2f}x the time per run of a run alone")
    runs, projected, at_floor = train_stage_projection(params, splits, floors)
    print(f"pipeline `train` stage, {runs} runs, two processes at a time: projected {projected / 60:.0f} min at "
          f"these speeds; {at_floor / 60:.0f} min if every update ran at its matmul floor")
    return projected


def pipeline_section(params, train_s: float | None, seed_cpu: float | None, workers: int = 2) -> None:
    """The whole forced ``dvc repro`` from scratch, stage by stage: ``train`` and the general seeds' stages as
    projected in this run (``None``: not run, the last measured), the others as the last measured forced repro
    (``FROM_SCRATCH``) took them; with the reported general seeds as they are and with 8 of them."""
    print("== 8. the pipeline from scratch, stage by stage (two processes at a time) ==")
    if not FROM_SCRATCH.exists():
        print(f"no measured forced `dvc repro` to read the other stages from ({FROM_SCRATCH.name}: "
              "`bench.py --record-from-scratch CLONE` after one)")
        return
    import json

    record = json.loads(FROM_SCRATCH.read_text())
    stages = dict(record["stage_seconds"])
    how = {name: f"measured {record['date']}" for name in stages}
    if train_s is not None:
        stages["train"], how["train"] = train_s, "projected (section 1)"
    if seed_cpu is not None:
        rounds = {"train_general": len(params.general.seeds), "train_yardstick": len(params.yardstick.seeds)}
        for name, seeds in rounds.items():
            stages[name] = math.ceil(seeds / workers) * seed_cpu
            how[name] = f"projected: {seeds} seeds x {seed_cpu:.0f} s / {workers} processes (section 6)"
    for name, seconds in sorted(stages.items(), key=lambda kv: -kv[1]):
        print(f"  {name:24s} {seconds / 60:6.1f} min  ({how[name]})")
    total = sum(stages.values())
    extra = 0.0
    if seed_cpu is not None and len(params.general.seeds) < 8:  # the evaluation asks 8 reported seeds
        extra = (math.ceil(8 / workers) - math.ceil(len(params.general.seeds) / workers)) * seed_cpu
        extra += stages.get("evaluate_general", 0.0) * (8 / len(params.general.seeds) - 1)
    target = params.bench.from_scratch_min
    print(f"whole forced `dvc repro`: {total / 60:.0f} min; with 8 reported general seeds (their training, and the "
          f"suite's evaluation scaled by seeds) {(total + extra) / 60:.0f} min; target <= {target:.0f} min "
          f"({(total + extra) / 60 / target:.2f}x)")


def update_section(params) -> None:
    print("== 2. one MADDPG update of 9 agents ==")
    for config in CONFIGS:
        t = update_times(params, config)
        b = t["stacked"]
        print(f"{config} (batch {params.configs[config].maddpg.batch_size}): the stacked update {b * 1e3:.1f} ms; "
              f"the per-agent loop {t['per-agent loop'] * 1e3:.1f} ms ({t['per-agent loop'] / b:.2f}x)")


def environment_section(params, square) -> None:
    print("== 3. environment throughput, random actions, agent-steps per second ==")
    ref = mpe2_throughput()
    bedok = make_region("bedok", params.regions["bedok"], params.world.region_area)
    for n_envs in (1, params.configs["paper"].n_envs, 1024):
        ours = env_throughput(params, square, n_envs)
        walled = env_throughput(params, bedok, n_envs, wall=True)
        line = (f"E={n_envs:4d}: coverage env (CR reward) {ours:9.0f}, on Bedok with the shore wall {walled:9.0f}; "
                f"MPE2 simple_spread_v3 (N=9, continuous, one env) {ref:8.0f}, ratio {ours / ref:.1f}")
        if benchmarl_bench.available():
            v = vmas_throughput(n_envs)
            line += f"; VMAS simple_spread {v:9.0f}, ratio {ours / v:.2f} (walled {walled / v:.2f})"
        print(line)


def allocator_section(episodes: int) -> None:
    print("== 4. allocator of the training processes: paper CR-MARL, 3 seeds stacked, fresh processes ==")
    probes = allocator_comparison(episodes)
    for side_by_side in (1, 2):
        default, held = probes[("default", side_by_side)], probes[("held", side_by_side)]
        where = "alone" if side_by_side == 1 else "two processes side by side"
        print(f"{where}: glibc default {default['per_update'] * 1e3:.1f} ms per update ({default['faults']:,} page "
              f"faults, {default['system_seconds']:.1f} s in the kernel); held (train.hold_freed_memory) "
              f"{held['per_update'] * 1e3:.1f} ms ({held['faults']:,} faults, {held['system_seconds']:.1f} s); "
              f"ratio {held['per_update'] / default['per_update']:.2f}")


def benchmarl_section() -> None:
    print("== 5. BenchMARL 1.5.2 MADDPG on VMAS simple_spread beside the project, paper schedule, fresh processes "
          "alternating, median of 3 ==")
    if not benchmarl_bench.available():
        print("BenchMARL is not installed (pip install .[bench]; make bench installs it)")
        return
    sides = benchmarl_bench.side_by_side()
    ours, theirs = sides["project"], sides["benchmarl"]
    print(f"end to end, s per 1,000 episodes: project {ours['per_1000_episodes']:.1f}, BenchMARL "
          f"{theirs['per_1000_episodes']:.1f}, ratio {theirs['per_1000_episodes'] / ours['per_1000_episodes']:.2f}"
          f" (per update inside the runs: {ours['per_update'] * 1e3:.1f} vs {theirs['per_update'] * 1e3:.1f} ms)")
    print(f"one update at identical shapes (9 agents, observation width {benchmarl_bench.OBS_WIDTH}, batch "
          f"{benchmarl_bench.BATCH}): project {ours['update_alone'] * 1e3:.1f} ms, BenchMARL "
          f"{theirs['update_alone'] * 1e3:.1f} ms, ratio {theirs['update_alone'] / ours['update_alone']:.2f}")
    # the critics' first layers read 9 × 40 joint columns: at these shapes the matmuls alone bound the ratio
    floor = update_gflop(*benchmarl_bench.project_agent_and_batch()) / machine_gemm_gflops()
    lead = theirs["update_alone"] / floor
    print(f"  the project's matmul floor at these shapes: {floor * 1e3:.1f} ms; the update is "
          f"{ours['update_alone'] / floor:.2f}x it, BenchMARL's {lead:.2f}x: no update of these matmuls leads "
          f"BenchMARL by more than {lead:.2f}x on this machine")


def full_run(params, square) -> None:
    print("== full run: paper CR-MARL, square, 10,000 episodes ==")
    rc = run_config(params, "paper", "cr")
    with tempfile.TemporaryDirectory() as tmp:
        tr = Trainer(rc, square, params.train.episodes, 0, Path(tmp) / "run", progress=False)
        (summary,) = tr.run()
    print(f"wall {summary['wall_seconds']:.1f} s (updates {summary['update_seconds']:.1f} s, "
          f"{summary['updates']} updates)")


SECTIONS = (0, 1, 2, 3, 4, 5, 6, 7, 8)
QUICK = (0, 1, 2, 3, 5, 6, 7, 8)  # --quick leaves out the allocator's fresh processes (4) and times fewer episodes


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--episodes", type=int, default=None,
                        help="episodes of the timed training runs (default 1,000; 600 with --quick: updates start "
                             "after 512, at learning_starts)")
    parser.add_argument("--only", type=int, nargs="+", choices=SECTIONS, default=None,
                        help="the sections to run (default: all; 1 and 6 need 0's floors and run it too)")
    parser.add_argument("--quick", action="store_true",
                        help="every figure but section 4's, from shorter timings: within 15 minutes on two cores")
    parser.add_argument("--full", action="store_true", help="also train the full 10,000-episode CR run")
    parser.add_argument("--allocator-probe", choices=("default", "held"), help=argparse.SUPPRESS)
    parser.add_argument("--split-probe", nargs=3, metavar=("CONFIG", "METHOD", "RUNS"), help=argparse.SUPPRESS)
    parser.add_argument("--record-from-scratch", metavar="CLONE",
                        help=f"after a forced `dvc repro` from scratch in CLONE, write its stage times to "
                             f"benchmarks/{FROM_SCRATCH.name} (section 8 reads them) and stop")
    args = parser.parse_args(argv)
    episodes = args.episodes or (600 if args.quick else 1000)
    if args.record_from_scratch:
        print(record_from_scratch(args.record_from_scratch))
        return 0
    if args.split_probe:
        config, method, runs = args.split_probe
        split_probe(config, method, int(runs), episodes)
        return 0
    if args.allocator_probe:
        allocator_probe(args.allocator_probe, episodes)
        return 0
    started = time.perf_counter()
    hold_freed_memory()  # as the pipeline's training processes (section 4 measures it)
    params = load_params("params.yaml")
    square = make_region("square", params.regions["square"], params.world.region_area)
    only = set(args.only or (QUICK if args.quick else SECTIONS))
    floors = machine_section(params) if only & {0, 1, 6} else {}
    train_s = training_section(params, square, floors, episodes) if 1 in only else None
    if 2 in only:
        update_section(params)
    if 3 in only:
        environment_section(params, square)
    if 4 in only:
        allocator_section(episodes)
    if 5 in only:
        benchmarl_section()
    seed_cpu = None
    if 6 in only:
        general_update_section(params, floors)
        seed_cpu = general_seed_section(params, 4 if args.quick else 12)[params.general.learner.symmetry]
    if 7 in only:
        field_bench.field_section(params.bench)
    if 8 in only:
        pipeline_section(params, train_s, seed_cpu)
    if args.full:
        full_run(params, square)
    print(f"make bench{' --quick' if args.quick else ''}: {(time.perf_counter() - started) / 60:.1f} min")
    return 0


if __name__ == "__main__":
    sys.exit(main())
