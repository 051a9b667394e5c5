"""The training machinery the per-region runs (``train.Trainer``) and the general policy (``general_train``) share.

Both play batches of E episodes, write every step into a ``Replay`` as n-step returns, make one update per
``update_every`` transitions once the memory holds ``learning_starts``, follow the same exploration and learning-rate
schedules, and keep the actor that covered best on fixed validation starts. ``TrainingLoop`` is that part; a trainer
adds what it trains on (its worlds and their events) and the network it builds (``MADDPG`` or ``SharedMADDPG``).
"""

from __future__ import annotations

import time
from collections.abc import Callable, Iterator, Sequence
from typing import Protocol

import numpy as np

from replicate.learn.replay import Batch, NStepWriter, Replay
from replicate.learn.schedules import lr_factor, noise_sigma


class Learner(Protocol):
    """What the loop asks of a learner: one update on a minibatch, and its learning rates scaled."""

    def update(self, batch: Batch) -> dict: ...

    def scale_learning_rates(self, factor: float) -> None: ...


class TrainingLoop:
    """One or several runs' replay memories (``memories``, each sampled by its own generator of ``sample_rngs``),
    their n-step writers, the update clock, the schedules and the kept actors.

    ``cfg`` holds the update's settings (``n_step``, ``gamma``, ``batch_size``, ``learning_starts``, ``update_every``)
    and the schedules' (``noise_*``, ``lr_end``): a ``MADDPGConfig`` or the ``general`` section. With several
    memories (the per-region stack of S runs) a minibatch is the S runs' minibatches stacked, [S, B, ...]."""

    def __init__(self, agent: Learner, cfg, memories: Sequence[Replay], sample_rngs: Sequence[np.random.Generator],
                 stacked: bool):
        self.agent, self.cfg, self.stacked = agent, cfg, stacked
        self.memories, self.sample_rngs = list(memories), list(sample_rngs)
        self.pending_updates = 0.0  # updates earned by transitions and not yet made
        self.updates = 0
        self.update_seconds = 0.0  # time spent in updates (the rest is environment, geometry, acting)
        self.kept: list[dict | None] = [None] * len(self.memories)  # per run {"episodes", "score", "actor"}

    def writers(self) -> list[NStepWriter]:
        """A fresh n-step writer per memory, for an episode's steps."""
        return [NStepWriter(m, self.cfg.n_step, self.cfg.gamma) for m in self.memories]

    def schedule(self, progress: float) -> float:
        """Set the learning rates for ``progress`` (0 at the start, 1 at the end) and → the exploration σ."""
        self.agent.scale_learning_rates(lr_factor(self.cfg, progress))
        return noise_sigma(self.cfg, progress)

    def learn(self, transitions: int) -> Iterator[dict]:
        """The updates due after ``transitions`` more per run: one per ``update_every`` once the memories hold
        ``learning_starts``, each on a minibatch of every run's own memory. → each update's diagnostics."""
        cfg = self.cfg
        if self.memories[0].size < cfg.learning_starts:
            return
        self.pending_updates += transitions / cfg.update_every
        while self.pending_updates >= 1.0:
            self.pending_updates -= 1.0
            t = time.perf_counter()  # the minibatch's drawing counts as the update's time
            stats = self.agent.update(self.minibatch())
            self.update_seconds += time.perf_counter() - t
            self.updates += 1
            yield stats

    def minibatch(self) -> Batch:
        draws = [m.sample(rng, self.cfg.batch_size) for m, rng in zip(self.memories, self.sample_rngs)]
        return Batch.stack(draws) if self.stacked else draws[0]

    def selection(self, run: int) -> dict:
        """The actor run ``run`` keeps, as a trainer's summary records it: the episode it was trained for and its
        validation coverage (nothing when the run never validated)."""
        best = self.kept[run]
        return {} if best is None else {"selected_episode": best["episodes"],
                                        "selected_validation_coverage": best["score"]}

    def keep(self, run: int, score: float, episodes: int, actor: Callable[[], dict], ties: str = "later") -> bool:
        """Keep run ``run``'s actor (``actor()``, a copy of its weights) when ``score`` is its best validation so
        far; ``ties`` "later" keeps the newer actor on an equal score, "earlier" the one already kept (a
        fine-tuning keeps its starting weights unless training improves on them). → whether it was kept."""
        best = self.kept[run]
        if best is None or score > best["score"] or (ties == "later" and score == best["score"]):
            self.kept[run] = {"episodes": episodes, "score": score, "actor": actor()}
            return True
        return False
