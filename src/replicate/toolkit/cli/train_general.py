"""``replicate train-general``: One seed of the general policy (one network for any lake and fleet) into a run
folder."""

from __future__ import annotations

import argparse
import dataclasses
from pathlib import Path

from replicate.core.params import load_params
from replicate.core.schema import ConfigError, check_seed
from replicate.toolkit.cli.inputs import (
    check_episodes,
    overrides,
)


def add(sub, verb: dict, regions: str) -> None:
    """The ``train-general`` verb's options."""
    tg = sub.add_parser("train-general", help="train one policy for every lake and fleet (params.yaml general)",
                        **verb)
    tg.add_argument("--seed", type=int, default=0, help="training seed, 0 to 2**32 - 1 (default 0)")
    tg.add_argument("--episodes", type=int, default=None, help="episodes (default: general.episodes)")
    tg.add_argument("--out", required=True, help="the run folder to write (actor.pt, curve.csv.gz, run.json)")
    tg.add_argument("--force", action="store_true", help="replace a finished run in --out")
    tg.add_argument("--baseline-gains", default=None,
                    help="the general baselines' tuned gains (`replicate tune general-baselines`), with which the "
                         "planner steers when general.learner.imitation teaches with it (default: the hand-set "
                         "evaluate.lloyd)")
    tg.set_defaults(func=run)



def run(args: argparse.Namespace) -> int:
    """``train-general``: one seed of the general policy into ``--out`` (no checkpoints: an interrupted run starts
    again; 3,000 episodes take about half an hour of one core)."""
    from replicate.compare.planner import planner_teacher, teacher_identity
    from replicate.core.outputs import locked, replacing
    from replicate.learn.general_train import train_recorded
    from replicate.learn.process import training_process
    from replicate.toolkit.cli.export import read_baseline_gains

    params = load_params(args.params, overrides(args.set))
    gains = read_baseline_gains(args.baseline_gains)
    check_seed(args.seed)
    config = params.general
    check_episodes(args.episodes)
    if args.episodes is not None:
        if args.episodes < config.n_envs:
            raise ConfigError(f"--episodes must be at least general.n_envs ({config.n_envs}), got {args.episodes}")
        config = dataclasses.replace(config, episodes=args.episodes)
    out = Path(args.out)
    if out.exists() and not out.is_dir():
        raise ConfigError(f"--out {out}: a file, not a folder; choose a folder for the run")
    args.held.enter_context(locked(out))
    if out.exists() and any(out.iterdir()):
        if not args.force:
            raise ConfigError(f"--out {out}: holds a run already; choose a new folder or pass --force to replace it")
        args.held.enter_context(replacing(out))  # the old run stays until the new one is complete
    training_process()
    # recorded as the stages record a seed: train_general or train_yardstick keeps this run when its values match
    params = dataclasses.replace(params, general=config)
    summary = train_recorded(params, args.seed, out, not args.no_progress, planner_teacher(params, gains),
                             teacher_identity(params, gains))
    print(f"best validation coverage {summary['selected_validation_coverage']:.3f} at episode "
          f"{summary['selected_episode']}; wrote {out} (`replicate export {out}` makes its policy file)")
    return 0
