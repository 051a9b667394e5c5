"""Replay memories and the n-step returns written into them: ``ReplayBuffer`` (joint transitions of a fixed fleet,
numpy, the per-region runs) and ``FleetReplay`` (fleets of any size padded to the largest and masked, torch, the
general policy); ``NStepWriter`` turns the steps of E environments into m-step transitions for either."""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np
import torch


class ReplayBuffer:
    """Preallocated ring buffer of joint transitions: obs/next_obs [C, N, obs_dim], act [C, N, act_dim],
    rew [C, N], and the discount of the bootstrap at next_obs, disc [C] (γ for a one-step transition, γᵐ for an
    m-step one; float32)."""

    def __init__(self, capacity: int, n_agents: int, obs_dim: int, act_dim: int):
        self.capacity = capacity
        self.obs = np.zeros((capacity, n_agents, obs_dim), np.float32)
        self.act = np.zeros((capacity, n_agents, act_dim), np.float32)
        self.rew = np.zeros((capacity, n_agents), np.float32)
        self.next_obs = np.zeros((capacity, n_agents, obs_dim), np.float32)
        self.disc = np.zeros(capacity, np.float32)
        self.ptr = 0
        self.size = 0

    def add(self, obs: np.ndarray, act: np.ndarray, rew: np.ndarray, next_obs: np.ndarray, discount: float) -> None:
        """Add a batch of E transitions (leading axis E) that bootstrap at next_obs with ``discount``. No transition
        is terminal: episodes end by time limit."""
        idx = (self.ptr + np.arange(len(obs))) % self.capacity
        self.obs[idx], self.act[idx], self.rew[idx], self.next_obs[idx] = obs, act, rew, next_obs
        self.disc[idx] = discount
        self.ptr = int((self.ptr + len(obs)) % self.capacity)
        self.size = min(self.size + len(obs), self.capacity)

    def sample(self, rng: np.random.Generator, batch: int) -> Batch:
        """One minibatch of joint transitions for all agents (openai/maddpg draws one per agent; see
        docs/DEVIATIONS.md). → tensors with leading [B]."""
        idx = rng.integers(0, self.size, size=batch)
        t = torch.from_numpy
        return Batch(t(self.obs[idx]), t(self.act[idx]), t(self.rew[idx]), t(self.next_obs[idx]), t(self.disc[idx]))

    def state_dict(self) -> dict:
        """The filled part of the buffer, as tensors that share its memory (no copy of up to 250 MB): save them
        before the buffer changes."""
        n = self.size
        t = torch.from_numpy
        return {"obs": t(self.obs[:n]), "act": t(self.act[:n]), "rew": t(self.rew[:n]),
                "next_obs": t(self.next_obs[:n]), "disc": t(self.disc[:n]), "ptr": self.ptr, "size": self.size}

    def load_state_dict(self, state: dict) -> None:
        n = int(state["size"])
        if n > self.capacity or state["obs"].shape[1:] != self.obs.shape[1:]:
            raise ValueError("replay buffer state does not fit this buffer")
        self.obs[:n], self.act[:n] = state["obs"].numpy(), state["act"].numpy()
        self.rew[:n], self.next_obs[:n] = state["rew"].numpy(), state["next_obs"].numpy()
        self.disc[:n] = state["disc"].numpy()
        self.ptr, self.size = int(state["ptr"]), n


class NStepWriter:
    """Writes the transitions of E environments that step in lockstep into a ``ReplayBuffer`` as n-step returns
    (Sutton & Barto §7.1; n = 1 is the paper's one-step transition).

    A transition from step t is written once its n rewards are known: r = Σ_{k<n} γᵏ r_{t+k}, next_obs = o_{t+n},
    disc = γⁿ. The episode's last step (its time limit) writes the ones still open, each with the m < n rewards
    left, bootstrapping at the last observation with γᵐ. Arrays are [E, N, ...] as in ``ReplayBuffer.add``.
    A step is a dict of arrays with its reward under ``rew``; ``write`` stores one transition (another buffer's
    writer overrides it: ``general_train.FleetNStep``).
    """

    def __init__(self, buffer, n: int, gamma: float):
        if n < 1:
            raise ValueError(f"n-step returns need n >= 1, got {n}")
        self.buffer, self.n, self.gamma = buffer, n, gamma
        self.open: list[dict] = []  # the unwritten steps, oldest first

    def add(self, obs: np.ndarray, act: np.ndarray, rew: np.ndarray, next_obs: np.ndarray, last: bool) -> None:
        self.push(last, obs=obs, act=act, rew=rew, next_obs=next_obs)

    def push(self, last: bool, **step: np.ndarray) -> None:
        """One step of every environment; ``last``: the episode's time limit, which writes every open step."""
        self.open.append(step)
        if len(self.open) == self.n:
            self._write()
        while last and self.open:
            self._write()

    def _write(self) -> None:
        ret = self.open[0]["rew"]
        for k in range(1, len(self.open)):
            ret = ret + self.gamma**k * self.open[k]["rew"]
        self.write(self.open[0], ret, self.open[-1], self.gamma ** len(self.open))
        self.open.pop(0)

    def write(self, first: dict, ret: np.ndarray, end: dict, discount: float) -> None:
        """Store the transition of step ``first``: its m-step return ``ret``, bootstrapping after step ``end``."""
        self.buffer.add(first["obs"], first["act"], ret, end["next_obs"], discount)


@dataclass
class Batch:
    """Sampled joint transitions: obs/next_obs [B, N, obs_dim], act [B, N, act_dim], rew [B, N], disc [B]; a
    stack of S runs' minibatches has a leading [S] on each."""

    obs: torch.Tensor
    act: torch.Tensor
    rew: torch.Tensor
    next_obs: torch.Tensor
    disc: torch.Tensor

    @classmethod
    def stack(cls, batches: list[Batch]) -> Batch:
        """The minibatches of S runs as one: every field gains a leading run axis [S, B, ...]."""
        return cls(*(torch.stack([getattr(b, f.name) for b in batches]) for f in dataclasses.fields(cls)))


@dataclass
class FleetBatch:
    """Transitions of padded fleets, [B, N, ...]: ``rew`` [B, N] (m-step returns), ``disc`` [B] (γᵐ), ``live`` and
    ``next_live`` [B, N] bool."""

    obs: torch.Tensor
    act: torch.Tensor
    rew: torch.Tensor
    next_obs: torch.Tensor
    pos: torch.Tensor
    next_pos: torch.Tensor
    live: torch.Tensor
    next_live: torch.Tensor
    disc: torch.Tensor


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
    """``NStepWriter`` for a ``FleetReplay``: a step also carries the buoys in service (``live``) and their
    positions (``pos``, ``next_pos``); a transition bootstraps with the buoys in service after its last step, so a
    buoy lost in between is not bootstrapped (its rewards after the loss are 0, its future none)."""

    def write(self, first: dict, ret: np.ndarray, end: dict, discount: float) -> None:
        self.buffer.add(first["live"], end["live"], discount, obs=first["obs"], act=first["act"], rew=ret,
                        next_obs=end["next_obs"], pos=first["pos"], next_pos=end["next_pos"])
