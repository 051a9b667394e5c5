"""The arithmetic fingerprint: which floating-point numbers this code gives, with these libraries, on this CPU.

A run is reproducible bit for bit only by code that computes what its code computed. ``TRAINING_VERSION``
(``runs``) names deliberate changes of that arithmetic, but an edit can change a result in its last bit
without anyone meaning to: seeds 0-2 of the ``paper`` runs once differed from a rerun of the same version from the
first episode's reward (3.35099 against 3.35101), and nothing recorded it. So every run records ``fingerprint()``
in its ``run.json``: a digest of the numbers a fixed, tiny workload gives — a few steps of the coverage world with
each reward, credit and fence of the ``paper`` and ``tuned`` configurations, and two MADDPG updates at their
batch shapes — and the versions of the libraries that compute them. Two runs with the same fingerprint were
trained by the same arithmetic; the report counts the fingerprints its runs carry.

The general policy computes with other kernels: its shared actor and pooled critic are ``nn.Linear`` layers (MKL's
``sgemm``, whose code path MKL picks per CPU: on an AVX-512 CPU, ``MKL_CBWR=AVX2`` changes its update's numbers
and leaves the per-region MADDPG's ``bmm`` numbers alone), and its worlds have the shore wall, the local sensors
and the events. ``general_fingerprint()`` digests that workload: a few steps of a generated lake
behind the wall with a loss and a drift, two updates of the shared learner, and the exported policy's actions.
Each general run records it.

A study is numbers of two kinds: its trials' scores (baselines stepping in the worlds, or MADDPG training), and
the values TPE proposes from them (numpy and scipy: two CPUs gave TPE's first proposal one ulp apart, and the two
studies parted from there on, ``docs/TUNING.md``). ``search_fingerprint()`` digests both worlds' steps,
the MADDPG updates and a fixed TPE study; every trial records it in the study's storage.

The workload's values are fixed here, not read from ``params.yaml``: changing a parameter does not change the
fingerprint, only changing how the numbers are computed does.
"""

from __future__ import annotations

import functools
import hashlib
from importlib.metadata import version

import numpy as np
import torch

from replicate.core.sections import (
    CoverageConfig,
    CRRewardConfig,
    MADDPGConfig,
    SensorsConfig,
    SharedLearnerConfig,
    SWRewardConfig,
    WorldConfig,
)
from replicate.learn.maddpg import MADDPG
from replicate.learn.policy import FleetPolicy
from replicate.learn.replay import Batch, Replay
from replicate.learn.shared_maddpg import SharedMADDPG
from replicate.world.coverage import cover_area
from replicate.world.currents import random_current
from replicate.world.env import CoverageEnv
from replicate.world.lakes import lake_region, training
from replicate.world.regions import box_region

LIBRARIES = ("torch", "numpy", "numba", "shapely")
WORLD = WorldConfig(n_agents=9, agent_radius=0.08, sensitivity=5.0, mass=1.0, dt=0.1, damping=0.25,
                    episode_length=5, start_patch=0.5, region_area=9.0)
COVERAGE = CoverageConfig(radius=0.5, edges=30, table_spacing=0.01, raster_spacing=0.025)
SW = SWRewardConfig(r1=150.0, r2=200.0, alpha=150.0, beta=200.0, prop_range=(0.85, 1.2), coll_range=(0.0, 0.56))
CR = CRRewardConfig(r1=60.0, r2=30.0, r3=0.0, c1=1.0, c2=50.0)
SENSORS = SensorsConfig(neighbours=4, comm_range=2.0, rays=8, ray_range=2.0, velocity="ground")
LEARNER = SharedLearnerConfig(hidden=64, embed=64, actor_lr=1e-3, critic_lr=1e-3, tau=0.01, grad_clip=0.5,
                              actor_reg=1e-3, pool_range=0.0, pool_neighbours=6)
# (reward, union credit, geofence): the paper's two methods in the open world and `tuned`'s in its box fence
WORLDS = (("sw", "shared", None), ("cr", "shared", None), ("cr", "difference", 0.5))
BATCHES = (1024, 128)  # `paper`'s and `tuned`'s minibatch: the update's matmul forms depend on the shapes


def _world_numbers(digest) -> None:
    """Five steps of 4 environments per world of ``WORLDS``, random actions: observations, rewards, unions."""
    region = box_region("square", 3.0, 3.0)
    for reward, credit, fence in WORLDS:
        env = CoverageEnv(region, WORLD, COVERAGE, n_envs=4, reward=reward, sw=SW, cr=CR, geofence=fence,
                          union_credit=credit, seed=0)
        actions = np.random.default_rng(1)
        digest.update(env.reset().tobytes())
        for _ in range(WORLD.episode_length):
            step = env.step(actions.uniform(-1, 1, (4, WORLD.n_agents, 2)).astype(np.float32))
            for array in (step.obs, step.reward, step.union_area):
                digest.update(np.ascontiguousarray(array).tobytes())


def _update_numbers(digest) -> None:
    """Two updates of 9 agents per minibatch size of ``BATCHES`` on random transitions: every parameter after them,
    and the actions of the updated actors."""
    for batch in BATCHES:
        cfg = MADDPGConfig(hidden=64, actor_lr=0.01, critic_lr=0.01, gamma=0.9, tau=0.01, batch_size=batch,
                           buffer_size=2 * batch, learning_starts=0, update_every=1, grad_clip=0.5, actor_reg=0.001,
                           noise_start=0.1, noise_end=0.1, noise_decay=0.0)
        rng = np.random.default_rng(2)
        buffer = Replay(2 * batch, 9, 2)
        buffer.add(cfg.gamma, obs=rng.normal(size=(2 * batch, 9, 2)).astype(np.float32),
                   act=rng.uniform(-1, 1, (2 * batch, 9, 2)).astype(np.float32),
                   rew=rng.normal(size=(2 * batch, 9)).astype(np.float32),
                   next_obs=rng.normal(size=(2 * batch, 9, 2)).astype(np.float32))
        agent = MADDPG(9, 2, 2, cfg, "individual", seed=0)
        for _ in range(2):
            agent.update(buffer.sample(rng, batch))
        for net in (agent.actor, agent.critic, agent.actor_target, agent.critic_target):
            for p in net.parameters():
                digest.update(p.detach().numpy().tobytes())
        digest.update(agent.policy(rng.normal(size=(50, 9, 2)).astype(np.float32))[1].tobytes())


def _general_world_numbers(digest) -> None:
    """Six steps of 4 environments on a generated lake behind the wall, local sensors, CR's reward with the
    difference credit, a drift, and a loss after three steps: observations, rewards, unions, positions."""
    spec = training(1, n_range=(9, 9), ratio_range=(0.9, 0.9))[0]
    lake = lake_region(spec, cover_area(COVERAGE.radius, COVERAGE.edges))
    cr = CRRewardConfig(r1=60.0, r2=30.0, r3=0.0, c1=0.0, c2=50.0)
    env = CoverageEnv(lake, WORLD, COVERAGE, n_envs=4, reward="cr", cr=cr, observation="local",
                      sensors_config=SENSORS, wall=True, union_credit="difference", seed=0)
    events = np.random.default_rng(3)
    env.set_current(random_current(events, 4, lake.polygon, 0.6))
    digest.update(env.reset(start="corner").tobytes())
    for t in range(6):
        if t == 3:
            env.lose(3, events)
        step = env.step(events.uniform(-1, 1, (4, WORLD.n_agents, 2)).astype(np.float32))
        for array in (step.obs, step.reward, step.union_area, env.pos):
            digest.update(np.ascontiguousarray(array).tobytes())


def _shared_update_numbers(digest) -> None:
    """Two updates of the shared actor and pooled critic on random fleets of 5-12 buoys padded to 12 (the observation
    of ``SENSORS``): every parameter after them, and the exported policy's actions."""

    g = torch.Generator().manual_seed(4)
    od, b, n_max = 22, 256, 12
    learner = SharedMADDPG(od, 2, LEARNER, seed=0)
    for _ in range(2):
        live = torch.arange(n_max)[None] < torch.randint(5, n_max + 1, (b, 1), generator=g)
        batch = Batch(obs=torch.randn(b, n_max, od, generator=g), act=torch.rand(b, n_max, 2, generator=g) * 2 - 1,
                      rew=torch.randn(b, n_max, generator=g), next_obs=torch.randn(b, n_max, od, generator=g),
                      pos=torch.randn(b, n_max, 2, generator=g), next_pos=torch.randn(b, n_max, 2, generator=g),
                      live=live, next_live=live, disc=torch.full((b,), 0.9))
        learner.update(batch)
    for net in (learner.actor, learner.critic, learner.actor_target, learner.critic_target):
        for p in net.parameters():
            digest.update(p.detach().numpy().tobytes())
    policy = torch.jit.script(FleetPolicy(learner.actor.net.eval()))
    with torch.no_grad():
        for n in (5, 9, 50):
            digest.update(policy(torch.randn(n, od, generator=g)).numpy().tobytes())


def _tpe_numbers(digest) -> None:
    """Fifteen trials of a seeded TPE study on a fixed function of two values: every proposal."""
    import optuna

    def objective(trial) -> float:  # a linear and a log-scaled value, as the gains' searches have
        x, y = trial.suggest_float("x", -1, 1), trial.suggest_float("y", 0.1, 10, log=True)
        return (x - 0.3) ** 2 + np.sin(3 * y)

    verbosity = optuna.logging.get_verbosity()
    optuna.logging.set_verbosity(optuna.logging.WARNING)  # no line per trial, the caller's level kept
    try:
        study = optuna.create_study(sampler=optuna.samplers.TPESampler(seed=0, n_startup_trials=10))
        study.optimize(objective, n_trials=15)
    finally:
        optuna.logging.set_verbosity(verbosity)
    digest.update(np.array([[t.params["x"], t.params["y"]] for t in study.trials]).tobytes())


def _digest(*workloads, libraries: tuple[str, ...] = LIBRARIES) -> str:
    """16 hex digits of the ``libraries``' versions and the numbers ``workloads`` give, on one thread as training
    runs."""
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    try:
        digest = hashlib.sha256(" ".join(f"{lib}=={version(lib)}" for lib in libraries).encode())
        for workload in workloads:
            workload(digest)
    finally:
        torch.set_num_threads(threads)
    return digest.hexdigest()[:16]


@functools.cache
def fingerprint() -> str:
    """The per-region runs' fingerprint: the coverage world's steps with the ``paper`` and ``tuned`` rewards and
    two MADDPG updates. Computed once per process (about 1-3 s)."""
    return _digest(_world_numbers, _update_numbers)


@functools.cache
def general_fingerprint() -> str:
    """The general policy's fingerprint: a generated lake behind the wall with events, two updates of the shared
    learner and the exported policy's actions. Computed once per process."""
    return _digest(_general_world_numbers, _shared_update_numbers)


@functools.cache
def search_fingerprint() -> str:
    """A study's fingerprint: the steps of both kinds of world, the MADDPG updates its trials may train with, and a
    fixed TPE study. Computed once per process."""
    return _digest(_world_numbers, _update_numbers, _general_world_numbers, _tpe_numbers,
                   libraries=(*LIBRARIES, "optuna", "scipy"))
