"""``replicate train``: Train MADDPG (SW-MARL or CR-MARL) on one region: a new run, or ``--resume`` an
interrupted one."""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

from replicate.core import artifacts
from replicate.core.artifacts import CheckpointError
from replicate.core.outputs import locked
from replicate.core.params import Params, load_params, run_config
from replicate.core.schema import ConfigError, check_seed
from replicate.toolkit.cli.inputs import (
    check_episodes,
    claim_run_folder,
    overrides,
    read_record,
    resolve_region,
    resume_command,
)
from replicate.world.regions import (
    read_run_region,
    write_run_region,
)


def add(sub, verb: dict, regions: str) -> None:
    """The ``train`` verb's options."""
    t = sub.add_parser("train", help="train MADDPG (SW-MARL or CR-MARL) on a region", **verb)
    t.add_argument("--config", default="paper", help="configuration in params.yaml: paper or tuned")
    t.add_argument("--method", default="cr", help="sw (swarming, shared reward) or cr (coverage range)")
    t.add_argument("--region", default="square", help=regions)
    t.add_argument("--episodes", type=int, default=None,
                   help="training episodes, a multiple of the config's n_envs (default: train.episodes, 10,000)")
    t.add_argument("--seed", type=int, default=0, help="training seed, 0 to 2**32 - 1")
    t.add_argument("--out", default=None, help="run folder (default: my-runs/CONFIG-METHOD-REGION-sSEED)")
    t.add_argument("--checkpoint-every", type=int, default=None,
                   help="episodes between resumable checkpoints (default: train.checkpoint_every)")
    t.add_argument("--resume", default=None, metavar="RUN",
                   help="continue the interrupted run in folder RUN from its checkpoint, with the settings it was "
                        "started with (nothing else needed)")
    t.add_argument("--force", action="store_true",
                   help="train into --out even if it holds a run or other files (the folder is cleared first)")
    t.set_defaults(func=run)



def run(args: argparse.Namespace) -> int:
    from replicate.learn.train import check_schedule, train

    params = load_params(args.params, overrides(args.set))
    every = args.checkpoint_every if args.checkpoint_every is not None else params.train.checkpoint_every
    if args.resume:
        out = Path(args.resume)
        rc, region, episodes, seed = resumed_run(out, params)
    else:
        rc = run_config(params, args.config, args.method, args.region)
        region = resolve_region(args.region, params)
        episodes = args.episodes if args.episodes is not None else params.train.episodes
        seed = check_seed(args.seed)
        out = Path(args.out or f"my-runs/{args.config}-{args.method}-{region.name}-s{seed}")
    for note in region.notes:
        print(f"region {region.name}: {note}", file=sys.stderr)
    check_episodes(episodes)
    check_schedule(rc, episodes, every)
    created, replaced = False, False
    if args.resume:
        args.held.enter_context(locked(out))
    else:
        replaced = args.force and out.is_dir() and any(out.iterdir())
        created = claim_run_folder(out, args.force, args.held)
        write_run_region(out, region)  # so --resume, evaluate and export need only the folder
    args.interrupted_hint = lambda: interrupted_hint(out, replaced)
    t0 = time.perf_counter()
    try:
        summary = train(rc, region, episodes, seed, out,
                        checkpoint_every=every, resume=args.resume is not None, progress=not args.no_progress)
    except (ConfigError, ValueError):
        if created and not (out / "checkpoint.pt").exists():  # refused before training: leave nothing behind
            import shutil

            shutil.rmtree(out, ignore_errors=True)
        raise
    except BaseException as exc:
        mark_stopped(out, exc)
        raise
    wall = time.perf_counter() - t0
    print(
        f"trained {summary['config']}/{summary['method']} on {summary['region']} for {episodes} episodes "
        f"(seed {seed}) in {wall:.1f} s wall ({summary['wall_seconds']:.1f} s in the training loop); "
        f"coverage over the last 100 training episodes {summary['final_coverage_last100']:.3f}; wrote {out}/"
    )
    if "selected_episode" in summary:
        print(f"kept the actors of episode {summary['selected_episode']} (validation coverage "
              f"{summary['selected_validation_coverage']:.3f}; the last ones are in actors_last.pt)")
    return 0


def mark_stopped(out: Path, exc: BaseException) -> None:
    """A run that stopped (Ctrl-C, a full disk, a crash) says so in its run.json instead of "running", as far as
    the disk still lets it; ``--resume`` continues it from its last checkpoint."""
    from replicate.core import artifacts
    from replicate.core.artifacts import CheckpointError

    try:
        record = read_record(out / "run.json")
        if record.get("status") == "running":
            why = "interrupted" if isinstance(exc, KeyboardInterrupt) else f"{type(exc).__name__}: {exc}"
            artifacts.write_json(out / "run.json", {**record, "status": "stopped", "stopped_by": why})
    except (OSError, ConfigError, CheckpointError):
        pass  # the disk is full, or the record was never written: the checkpoint is what --resume reads


def interrupted_hint(out: Path, replaced: bool) -> str:
    """What to do after Ctrl-C, as the folder stands once the command has let go of it."""
    if replaced:
        return f"{out} holds the run it held before (nothing of the new one was kept)"
    if (out / "checkpoint.pt").exists():
        return f"`{resume_command(out)}` continues from the last checkpoint"
    return f"no checkpoint was written yet; start the run again (with --force, {out} is not empty)"


def resumed_run(run: Path, params: Params):
    """(run config, region, episodes, seed) of the interrupted run in ``run``, read from its own checkpoint: the
    settings it was started with, whatever params.yaml says now."""

    from replicate.core.params import RunConfig
    from replicate.core.schema import build
    from replicate.world.geometry import region_key

    if not run.is_dir():
        raise ConfigError(f"--resume {run}: no such run folder")
    if not (run / "checkpoint.pt").exists():
        status = read_record(run / "run.json").get("status")
        if status == "finished":
            raise ConfigError(f"--resume {run}: the run has already finished (nothing to continue); evaluate it "
                              f"with `replicate evaluate {run}`")
        raise ConfigError(f"--resume {run}: no checkpoint here (a run checkpoints every train.checkpoint_every "
                          "episodes; one stopped before its first checkpoint starts again with --force)")
    ident = artifacts.torch_load(run / "checkpoint.pt").get("identity", {})
    try:
        rc = build(RunConfig, ident["params"], f"{run}/checkpoint.pt")
        episodes, seed, name = int(ident["episodes"]), int(ident["seed"]), ident["region"]
    except (KeyError, TypeError, ValueError) as exc:
        raise CheckpointError(f"{run}/checkpoint.pt: checkpoint is incomplete or mismatched ({exc})") from exc
    region = read_run_region(run) or resolve_region(name, params)
    if region_key(region.polygon) != ident.get("region_key"):
        raise CheckpointError(f"{run}: region {name!r} is not the one the run was started on")
    return rc, region, episodes, seed
