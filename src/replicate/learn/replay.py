"""The replay memory both trainings learn from, and the n-step returns written into it.

``Replay`` holds transitions of fleets of up to ``n_max`` buoys, padded and masked: the per-region runs are a fleet
of fixed N (no padding, no masks), the general policy's worlds fleets of any size with buoys lost on the way
(``fleets=True``: positions for the pooled critic, masks of the buoys in service). ``NStepWriter`` turns the steps of
E environments into m-step transitions for it; ``Batch`` is what a minibatch holds.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np
import torch


@dataclass
class Batch:
    """Sampled transitions, [B, N, ...]: obs/next_obs [B, N, obs_dim], act [B, N, act_dim], rew [B, N] (m-step
    returns), disc [B] (γᵐ of the bootstrap at next_obs). Of fleets (``Replay(fleets=True)``) also pos/next_pos
    [B, N, 2] and the buoys in service, live/next_live [B, N] bool; with a teacher (``Replay(expert=True)``) its
    action in each state, expert [B, N, act_dim]. A stack of S runs' minibatches has a leading [S] on each field
    (``stack``)."""

    obs: torch.Tensor
    act: torch.Tensor
    rew: torch.Tensor
    next_obs: torch.Tensor
    disc: torch.Tensor
    pos: torch.Tensor | None = None
    next_pos: torch.Tensor | None = None
    live: torch.Tensor | None = None
    next_live: torch.Tensor | None = None
    expert: torch.Tensor | None = None

    @classmethod
    def stack(cls, batches: list[Batch]) -> Batch:
        """The minibatches of S runs as one: every field gains a leading run axis [S, B, ...]."""
        fields = {f.name: [getattr(b, f.name) for b in batches] for f in dataclasses.fields(cls)}
        return cls(**{k: None if v[0] is None else torch.stack(v) for k, v in fields.items()})


class Replay:
    """A preallocated ring memory of m-step transitions (``Batch``'s fields, each [C, n_max, ...]; disc [C]).

    A fleet of n < n_max buoys fills the first n slots of its rows, the rest zeros (masks False). The arrays are
    numpy (zero pages cost no memory until written: a memory of 10⁶ transitions is allocated whole) and leave as
    tensors that share their memory."""

    def __init__(self, capacity: int, n_max: int, obs_dim: int, act_dim: int = 2, fleets: bool = False,
                 expert: bool = False):
        shapes = {"obs": ((obs_dim,), np.float32), "act": ((act_dim,), np.float32), "rew": ((), np.float32),
                  "next_obs": ((obs_dim,), np.float32)}
        if fleets:
            shapes |= {"pos": ((2,), np.float32), "next_pos": ((2,), np.float32), "live": ((), bool),
                       "next_live": ((), bool)}
        if expert:  # a teacher's action in the state of ``obs``
            shapes["expert"] = ((act_dim,), np.float32)
        self.data = {k: np.zeros((capacity, n_max, *tail), dtype) for k, (tail, dtype) in shapes.items()}
        self.disc = np.zeros(capacity, np.float32)
        self.capacity, self.n_max, self.ptr, self.size = capacity, n_max, 0, 0

    def add(self, discount: float, **arrays: np.ndarray) -> None:
        """E transitions of one fleet of n ≤ n_max buoys, every field of the memory as [E, n, ...], that bootstrap
        at next_obs with ``discount``. No transition is terminal: episodes end by time limit."""
        e, n = arrays["obs"].shape[:2]
        rows = (self.ptr + np.arange(e)) % self.capacity
        for key, store in self.data.items():
            if n < self.n_max:
                store[rows] = 0
            store[rows, :n] = arrays[key]
        self.disc[rows] = discount
        self.ptr = int((self.ptr + e) % self.capacity)
        self.size = min(self.size + e, self.capacity)

    def sample(self, rng: np.random.Generator, batch: int) -> Batch:
        """One minibatch of ``batch`` transitions drawn uniformly with ``rng``, for all agents at once
        (openai/maddpg draws one per agent; see docs/DEVIATIONS.md)."""
        idx = rng.integers(0, self.size, size=batch)
        return Batch(**{k: torch.from_numpy(v[idx]) for k, v in self.data.items()},
                     disc=torch.from_numpy(self.disc[idx]))

    def state_dict(self) -> dict:
        """The filled part of the memory, as tensors that share its memory (no copy of up to 250 MB): save them
        before the memory changes."""
        n = self.size
        return {**{k: torch.from_numpy(v[:n]) for k, v in self.data.items()}, "disc": torch.from_numpy(self.disc[:n]),
                "ptr": self.ptr, "size": self.size}

    def load_state_dict(self, state: dict) -> None:
        n = int(state["size"])
        if n > self.capacity or any(state[k].shape[1:] != v.shape[1:] for k, v in self.data.items()):
            raise ValueError("replay memory state does not fit this memory")
        for k, v in self.data.items():
            v[:n] = state[k].numpy()
        self.disc[:n] = state["disc"].numpy()
        self.ptr, self.size = int(state["ptr"]), n


class NStepWriter:
    """Writes the transitions of E environments that step in lockstep into a ``Replay`` as n-step returns
    (Sutton & Barto §7.1; n = 1 is the paper's one-step transition).

    A transition from step t is written once its n rewards are known: r = Σ_{k<n} γᵏ r_{t+k}, disc = γⁿ, and every
    ``next_*`` field (next_obs, next_pos, next_live) from step t + n − 1, the others from step t. The episode's last
    step (its time limit) writes the ones still open, each with the m < n rewards left, bootstrapping at the last
    observation with γᵐ. A fleet's transition bootstraps with the buoys in service at its last step, so a buoy lost
    in between is not bootstrapped (its rewards after the loss are 0, its future none)."""

    def __init__(self, memory: Replay, n: int, gamma: float):
        if n < 1:
            raise ValueError(f"n-step returns need n >= 1, got {n}")
        self.memory, self.n, self.gamma = memory, n, gamma
        self.open: list[dict] = []  # the unwritten steps, oldest first

    def push(self, last: bool, **step: np.ndarray) -> None:
        """One step of every environment, each field of the memory [E, n, ...] (``rew`` the step's reward);
        ``last``: the episode's time limit, which writes every open step."""
        self.open.append(step)
        if len(self.open) == self.n:
            self._write()
        while last and self.open:
            self._write()

    def _write(self) -> None:
        first, end = self.open[0], self.open[-1]
        ret = first["rew"]
        for k in range(1, len(self.open)):
            ret = ret + self.gamma**k * self.open[k]["rew"]
        fields = {k: end[k] if k.startswith("next_") else first[k] for k in first}
        self.memory.add(self.gamma ** len(self.open), **(fields | {"rew": ret}))
        self.open.pop(0)
