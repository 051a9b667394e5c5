"""Lloyd's law on the cell a buoy senses, with no network: the controller a Lloyd prior starts the actor from
(`general.learner.lloyd_prior`), written as a general policy file so that `replicate compare` and
`benchmarks/channel.py` read it as they read a candidate's seeds.

    python benchmarks/lloyd_prior.py --gain 10 --out DIR
        DIR/general-s1..8/policy.pt (one per yardstick seed, the same policy in each: it draws nothing), each
        a = tanh(gain · (centroid_dx, centroid_dy)): the actor of `general.learner` with the centroid sensor on,
        its network's last layer 0. Then, as for any candidate:
    replicate --params params.yaml compare --candidate DIR/general-s{1..8}/policy.pt --out FILE
    python benchmarks/channel.py --candidate DIR --out FILE

Run from the repository root with the project's environment (`make setup`)."""

from __future__ import annotations

import argparse
import dataclasses
import sys
import tempfile
from pathlib import Path

import torch

from replicate.core import artifacts
from replicate.core.params import load_params
from replicate.core.schema import ConfigError, to_dict
from replicate.learn.shared_maddpg import SharedActor
from replicate.toolkit.cli.export import read_baseline_gains
from replicate.toolkit.export import export_general
from replicate.world.env import observation_columns

ROOT = Path(__file__).resolve().parents[1]
GAINS = ROOT / "metrics" / "tuning" / "general_baselines.json"  # what `replicate export` carries beside a seed


def prior_alone(params, gain: float, out: Path) -> list[Path]:
    """Write the prior alone at ``gain`` (per simulation metre) as DIR/general-sS/policy.pt for every yardstick
    seed S → the files."""
    gc = params.general
    sensors = dataclasses.replace(gc.sensors, centroid=True)
    learner = dataclasses.replace(gc.learner, lloyd_prior=gain)
    columns = observation_columns("local", sensors)
    actor = SharedActor.of(len(columns), 2, learner, columns, sensors)
    last = [m for m in actor.modules() if isinstance(m, torch.nn.Linear)][-1]
    with torch.no_grad():  # the network's part 0: the action is the prior's
        last.weight.zero_()
        last.bias.zero_()
    gains = read_baseline_gains(str(GAINS) if GAINS.is_file() else None)
    written = []
    with tempfile.TemporaryDirectory() as tmp:
        saved = Path(tmp) / "actor.pt"
        artifacts.torch_save(saved, {
            "format": artifacts.CHECKPOINT_FORMAT, "actor": actor.state_dict(), "observation": "local",
            "sensors": to_dict(sensors), "columns": columns, "learner": to_dict(learner),
            "hidden": learner.hidden, "symmetry": learner.symmetry, "selected_episode": 0, "seed": 0})
        for seed in params.yardstick.seeds:
            path = out / f"general-s{seed}" / "policy.pt"
            path.parent.mkdir(parents=True, exist_ok=True)
            export_general(saved, path, params.world.sensitivity, gains)
            written.append(path)
    return written


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--params", default="params.yaml")
    ap.add_argument("--gain", type=float, required=True, help="the prior's gain per simulation metre (> 0)")
    ap.add_argument("--out", type=Path, required=True, help="the folder to write general-sS/policy.pt into")
    ap.add_argument("--force", action="store_true", help="replace the files in --out")
    args = ap.parse_args(argv)
    if not args.gain > 0:
        ap.error(f"--gain must be above 0, got {args.gain}")
    try:
        params = load_params(args.params)
        taken = [s for s in params.yardstick.seeds if (args.out / f"general-s{s}" / "policy.pt").exists()]
        if taken and not args.force:
            print(f"error: {args.out}/general-s{taken[0]}/policy.pt exists; choose another --out or pass --force",
                  file=sys.stderr)
            return 2
        for path in prior_alone(params, args.gain, args.out):
            print(f"wrote {path}")
    except (ConfigError, OSError, ValueError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    sys.exit(main())
