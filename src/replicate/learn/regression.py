"""The reduced-episode regression of reward curves: a few dozen episodes of every config × method with a
fixed seed, compared with the reference CSVs in ``tests/reference/`` (``params.yaml`` section ``regression``).

Regenerate the references on purpose, after a change that is meant to alter the curves::

    make reference        # = python -m replicate.learn.regression --write tests/reference
"""

from __future__ import annotations

import argparse
import dataclasses
import tempfile
from pathlib import Path

import numpy as np

from replicate.core import artifacts
from replicate.core.artifacts import read_curve
from replicate.core.params import Params, load_params, run_config
from replicate.learn.process import training_process
from replicate.learn.train import CURVE, train
from replicate.world.regions import make_region

CASES = [(config, method) for config in ("paper", "tuned") for method in ("sw", "cr")]
COMPARED = ("team_reward", "coverage")


def reduced_curve(params: Params, config: str, method: str, out: Path) -> dict[str, np.ndarray]:
    """Train the reduced run of ``config`` × ``method`` into ``out`` and return its curve columns."""
    reg = params.regression
    rc = run_config(params, config, method, reg.region)
    maddpg = dataclasses.replace(rc.algo.maddpg, learning_starts=reg.learning_starts, batch_size=reg.batch_size)
    rc = dataclasses.replace(rc, algo=dataclasses.replace(rc.algo, n_envs=reg.n_envs, maddpg=maddpg))
    region = make_region(reg.region, params.regions[reg.region], params.world.region_area)
    train(rc, region, reg.episodes, reg.seed, out, checkpoint_every=reg.episodes, progress=False)
    return read_curve(Path(out) / CURVE)


def reference_path(root: Path, config: str, method: str) -> Path:
    return Path(root) / f"curve-{config}-{method}.csv"


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--write", required=True, help="folder to write the reference curves into")
    parser.add_argument("--params", default="params.yaml")
    args = parser.parse_args(argv)

    training_process()
    params = load_params(args.params)
    for config, method in CASES:
        with tempfile.TemporaryDirectory() as tmp:
            reduced_curve(params, config, method, Path(tmp) / "run")
            target = reference_path(Path(args.write), config, method)
            target.parent.mkdir(parents=True, exist_ok=True)
            target.write_text(artifacts.read_text(Path(tmp) / "run" / CURVE))
            print(f"wrote {target}")
    return 0


if __name__ == "__main__":  # pragma: no cover
    raise SystemExit(main())
