"""The arithmetic fingerprint: which floating-point numbers this code gives, with these libraries, on this CPU.

A run is reproducible bit for bit only by code that computes what its code computed. ``TRAINING_VERSION``
(``train.py``) names deliberate changes of that arithmetic, but an edit can change a result in its last bit
without anyone meaning to: seeds 0-2 of the ``paper`` runs once differed from a rerun of the same version from the
first episode's reward (3.35099 against 3.35101), and nothing recorded it. So every run records ``fingerprint()``
in its ``run.json``: a digest of the numbers a fixed, tiny workload gives — a few steps of the coverage world with
each reward, credit and fence of the ``paper`` and ``tuned`` configurations, and two MADDPG updates at their
batch shapes — and the versions of the libraries that compute them. Two runs with the same fingerprint were
trained by the same arithmetic; the report counts the fingerprints its runs carry.

The workload's values are fixed here, not read from ``params.yaml``: changing a parameter does not change the
fingerprint, only changing how the numbers are computed does.
"""

from __future__ import annotations

import functools
import hashlib
from importlib.metadata import version

import numpy as np
import torch

from .config import CoverageConfig, CRRewardConfig, MADDPGConfig, SWRewardConfig, WorldConfig
from .env import CoverageEnv
from .maddpg import MADDPG, ReplayBuffer
from .regions import box_region

LIBRARIES = ("torch", "numpy", "numba", "shapely")
WORLD = WorldConfig(n_agents=9, agent_radius=0.08, sensitivity=5.0, mass=1.0, dt=0.1, damping=0.25,
                    episode_length=5, start_patch=0.5, region_area=9.0)
COVERAGE = CoverageConfig(radius=0.5, edges=30, table_spacing=0.01, raster_spacing=0.025)
SW = SWRewardConfig(r1=150.0, r2=200.0, alpha=150.0, beta=200.0, prop_range=(0.85, 1.2), coll_range=(0.0, 0.56))
CR = CRRewardConfig(r1=60.0, r2=30.0, r3=0.0, c1=1.0, c2=50.0)
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
        buffer = ReplayBuffer(2 * batch, 9, 2, 2)
        buffer.add(rng.normal(size=(2 * batch, 9, 2)).astype(np.float32),
                   rng.uniform(-1, 1, (2 * batch, 9, 2)).astype(np.float32),
                   rng.normal(size=(2 * batch, 9)).astype(np.float32),
                   rng.normal(size=(2 * batch, 9, 2)).astype(np.float32), cfg.gamma)
        agent = MADDPG(9, 2, 2, cfg, "individual", seed=0)
        for _ in range(2):
            agent.update(buffer.sample(rng, batch))
        for net in (agent.actor, agent.critic, agent.actor_target, agent.critic_target):
            for p in net.parameters():
                digest.update(p.detach().numpy().tobytes())
        digest.update(agent.policy(rng.normal(size=(50, 9, 2)).astype(np.float32))[1].tobytes())


@functools.cache
def fingerprint() -> str:
    """16 hex digits of the numbers the fixed workload gives here and the computing libraries' versions. Computed
    once per process (about 1-3 s), on one thread as training runs."""
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    try:
        digest = hashlib.sha256(" ".join(f"{lib}=={version(lib)}" for lib in LIBRARIES).encode())
        _world_numbers(digest)
        _update_numbers(digest)
    finally:
        torch.set_num_threads(threads)
    return digest.hexdigest()[:16]
