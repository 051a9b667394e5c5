"""Exploration and learning-rate schedules over a training's progress (0 at the first episode or batch, 1 at the
last): σ falls linearly from ``noise_start`` to ``noise_end`` over the first ``noise_decay`` of training, the
learning rates linearly from their configured values to ``lr_end`` × them at the end: the per-region and the
general training read the same two functions. The general actor's Lloyd prior, a third, falls linearly to 0 over
the first ``lloyd_prior_fade`` of training where that is set.
"""

from __future__ import annotations


def noise_sigma(cfg, progress: float) -> float:
    """Exploration σ: linear from noise_start to noise_end over the first ``noise_decay`` of training."""
    if cfg.noise_decay <= 0:
        return cfg.noise_end
    frac = min(progress / cfg.noise_decay, 1.0)
    return cfg.noise_start + frac * (cfg.noise_end - cfg.noise_start)


def lr_factor(cfg, progress: float) -> float:
    """Learning-rate multiplier: linear from 1 at the first episode to ``lr_end`` at the last."""
    return 1.0 + progress * (cfg.lr_end - 1.0)


def prior_gain(cfg, progress: float) -> float:
    """The Lloyd prior's gain (``SharedLearnerConfig``): ``lloyd_prior``, falling linearly to 0 over the first
    ``lloyd_prior_fade`` of training where that is above 0."""
    if not cfg.lloyd_prior_fade:
        return cfg.lloyd_prior
    return cfg.lloyd_prior * max(0.0, 1.0 - progress / cfg.lloyd_prior_fade)
